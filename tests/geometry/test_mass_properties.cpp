// calc_mass_properties against analytic solids, refinement convergence and invariances.
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/geometry/primitives.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

namespace fascicle {
namespace {

double rel(double a, double b) { return std::abs(a - b) / std::abs(b); }

TEST(MassProperties, OffsetBoxIsExact) {
  const double a = 0.3, b = 0.05, c = 0.12;  // edge lengths (m)
  const double rho = 1060.0;
  TriMesh box = make_box(Vec3(a / 2, b / 2, c / 2));
  const Vec3 offset(1.25, -0.7, 3.5);
  box.V.rowwise() += offset.transpose();
  const MassProperties mp = calc_mass_properties(box, rho);
  const double m = rho * a * b * c;
  EXPECT_LE(rel(mp.volume_m3, a * b * c), 1e-12);
  EXPECT_LE(rel(mp.mass_kg, m), 1e-12);
  EXPECT_LE(rel(mp.area_m2, 2 * (a * b + b * c + c * a)), 1e-12);
  for (int i = 0; i < 3; ++i) EXPECT_LE(rel(mp.centroid[i], offset[i]), 1e-12);
  EXPECT_LE(rel(mp.inertia(0, 0), m * (b * b + c * c) / 12), 1e-12);
  EXPECT_LE(rel(mp.inertia(1, 1), m * (a * a + c * c) / 12), 1e-12);
  EXPECT_LE(rel(mp.inertia(2, 2), m * (a * a + b * b) / 12), 1e-12);
  EXPECT_LE(std::abs(mp.inertia(0, 1)) + std::abs(mp.inertia(1, 2)) + std::abs(mp.inertia(0, 2)),
            1e-12 * mp.inertia(0, 0));
  // principal moments ascending: about x... smallest is about the long (x) axis
  EXPECT_LE(rel(mp.principal_moments[0], m * (b * b + c * c) / 12), 1e-12);
  EXPECT_NEAR(std::abs(mp.principal_axes(0, 0)), 1.0, 1e-12);
  EXPECT_NEAR(mp.principal_axes.determinant(), 1.0, 1e-12);
}

TEST(MassProperties, SphereConvergesWithRefinement) {
  const double r = 0.04;
  const double v_exact = 4.0 / 3.0 * std::numbers::pi * r * r * r;
  const double i_exact = 0.4 * v_exact * r * r;  // density 1
  double prev_v = 1.0, prev_i = 1.0;
  for (int level = 1; level <= 5; ++level) {
    const MassProperties mp = calc_mass_properties(make_icosphere(r, level));
    const double ev = rel(mp.volume_m3, v_exact), ei = rel(mp.inertia(2, 2), i_exact);
    // inscribed polyhedron: error ~ h^2, a factor ~4 per subdivision
    EXPECT_LT(mp.volume_m3, v_exact);
    EXPECT_LT(ev, prev_v / 3.5) << level;
    EXPECT_LT(ei, prev_i / 3.5) << level;
    EXPECT_LT(mp.centroid.norm(), 1e-15);
    // isotropic up to the discretisation
    EXPECT_LT((mp.principal_moments.maxCoeff() - mp.principal_moments.minCoeff()) /
                  mp.principal_moments.maxCoeff(),
              ei + 1e-12);
    prev_v = ev;
    prev_i = ei;
  }
  EXPECT_LT(prev_v, 1e-3);
}

TEST(MassProperties, CylinderConvergesWithRefinement) {
  const double r = 0.03, h = 0.25;
  const double v_exact = std::numbers::pi * r * r * h;
  const double izz = 0.5 * v_exact * r * r, ixx = v_exact * (3 * r * r + h * h) / 12;
  double prev = 1.0;
  for (const int segments : {8, 16, 32, 64, 128}) {
    const MassProperties mp = calc_mass_properties(make_cylinder(r, h, segments, 3));
    const double err = std::max({rel(mp.volume_m3, v_exact), rel(mp.inertia(2, 2), izz),
                                 rel(mp.inertia(0, 0), ixx)});
    EXPECT_LT(err, prev / 3.5) << segments;
    prev = err;
  }
  EXPECT_LT(prev, 1e-3);
}

TEST(MassProperties, TranslationAndRotationInvariance) {
  const TriMesh base = make_ellipsoid(Vec3(0.05, 0.02, 0.12), 3);
  const MassProperties m0 = calc_mass_properties(base, 1000.0);
  const Mat3 R = (Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()) *
                  Eigen::AngleAxisd(-1.1, Vec3::UnitX()))
                     .toRotationMatrix();
  const Vec3 t(10.0, -20.0, 5.0);  // far from the origin
  TriMesh moved = base;
  moved.V = (base.V * R.transpose()).rowwise() + t.transpose();
  const MassProperties m1 = calc_mass_properties(moved, 1000.0);
  EXPECT_LE(rel(m1.volume_m3, m0.volume_m3), 1e-12);
  EXPECT_LE(rel(m1.area_m2, m0.area_m2), 1e-12);
  EXPECT_LE((m1.centroid - (R * m0.centroid + t)).norm(), 1e-12 * t.norm());
  const Mat3 expected = R * m0.inertia * R.transpose();
  EXPECT_LE((m1.inertia - expected).norm(), 1e-9 * m0.inertia.norm());
  EXPECT_LE((m1.principal_moments - m0.principal_moments).norm(),
            1e-9 * m0.principal_moments.norm());
  // principal axes diagonalise the inertia
  const Mat3 D = m1.principal_axes.transpose() * m1.inertia * m1.principal_axes;
  EXPECT_LE((D - Mat3(m1.principal_moments.asDiagonal())).norm(), 1e-12 * m1.inertia.norm());
  EXPECT_NEAR(m1.principal_axes.determinant(), 1.0, 1e-12);
  // ellipsoid: I_zz = m (a^2 + b^2) / 5 within the discretisation error of level 3
  EXPECT_LT(rel(m0.inertia(2, 2), m0.mass_kg * (0.05 * 0.05 + 0.02 * 0.02) / 5), 2e-2);
}

TEST(MassProperties, InwardMeshHasNegativeVolumeAndBadInputThrows) {
  TriMesh m = make_box(Vec3(1, 1, 1));
  m.F.col(1).swap(m.F.col(2));
  EXPECT_NEAR(calc_mass_properties(m).volume_m3, -8.0, 1e-12);
  TriMesh bad = make_box(Vec3(1, 1, 1));
  bad.F(0, 0) = 8;
  EXPECT_THROW(calc_mass_properties(bad), Error);
  EXPECT_THROW(calc_mass_properties(make_box(Vec3(1, 1, 1)), -1.0), Error);
  EXPECT_THROW(calc_mass_properties(TriMesh{}), Error);
}

TEST(EnclosedVolume, BoxAnyOriginAndOrientation) {
  TriMesh box = make_box(Vec3(0.1, 0.2, 0.3));
  box.V.rowwise() += Vec3(120.0, -40.0, 7.0).transpose();  // far from the coordinate origin
  const double exact = 8 * 0.1 * 0.2 * 0.3;
  // 1e-13: the translated corners themselves are rounded (ulp(120) ≈ 1.4e-14)
  EXPECT_NEAR(calc_enclosed_volume(box), exact, 1e-13);
  EXPECT_NEAR(calc_enclosed_volume(box.V, box.F, Vec3(120.0, -40.0, 7.0)), exact, 1e-13);
  EXPECT_NEAR(calc_enclosed_volume(box.V, box.F, Vec3::Zero()), exact, 1e-9);  // digits lost, not the value
  box.F.col(1).swap(box.F.col(2));
  EXPECT_NEAR(calc_enclosed_volume(box), -exact, 1e-13);
  EXPECT_EQ(calc_enclosed_volume(TriMesh{}), 0.0);
}

}  // namespace
}  // namespace fascicle
