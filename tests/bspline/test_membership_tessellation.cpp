// Point membership (§3.1.3), cached tessellation (§3.1.4), fibres, embedding and file I/O.
#include "fascicle/bspline/embedding.hpp"
#include "fascicle/bspline/fibres.hpp"
#include "fascicle/bspline/lattice.hpp"
#include "fascicle/bspline/membership.hpp"
#include "fascicle/bspline/solid_io.hpp"
#include "fascicle/bspline/tessellation.hpp"
#include "fascicle/bspline/volume.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mass_properties.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <map>
#include <numbers>
#include <random>

namespace fascicle {
namespace {

// A bent, tapered cylinder (curved solid with a periodic direction and a collapsed axis).
BSplineSolid make_bent_cylinder() {
  auto s = make_cylindrical_lattice(0.01, 0.1, {3, 3, 3}, {4, 8, 6}).solid;
  for (int r = 0; r < s.P.rows(); ++r) {
    const double z = s.P(r, 2);
    s.P(r, 0) *= 1.0 - 3.0 * z;   // taper
    s.P(r, 1) += 3.0 * z * z;     // bend
  }
  return s;
}

Vec3 outward_normal(const BSplineSolid& s, const Vec3& uvw, int d, int side) {
  const Mat3 J = calc_point_and_jacobian(s, uvw).J;
  const Vec3 n = J.col((d + 1) % 3).cross(J.col((d + 2) % 3));
  return (side == 1 ? n : Vec3(-n)).normalized();
}

TEST(Membership, InsideOnAndJustOutsideBentCylinder) {
  const auto s = make_bent_cylinder();
  const SolidLocator loc(s);
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> U(0, 1);
  int worst_iterations = 0;
  for (int n = 0; n < 300; ++n) {
    // inside: avoid the axis (collapsed, many material points) for the material check
    const Vec3 uvw(0.05 + 0.95 * U(rng), U(rng), U(rng));
    const Vec3 p = calc_point(s, uvw);
    const PointLocation l = loc.locate(p);
    EXPECT_TRUE(l.inside) << n;
    EXPECT_LT((calc_point(s, l.material) - p).norm(), 1e-10);
    worst_iterations = std::max(worst_iterations, l.iterations);
  }
  EXPECT_LT(worst_iterations, 40);
  std::printf("worst iterations inside: %d\n", worst_iterations);
  for (int n = 0; n < 200; ++n) {
    // on the outer face u = 1 (includes the periodic seam v ~ 0/1), then 1 mm outside along the
    // outward normal: the closest point is the face point (curvature radius >> 1 mm)
    const double v = n < 20 ? 1e-9 * n : U(rng);
    const Vec3 uvw(1.0, v, 0.05 + 0.9 * U(rng));
    const Vec3 on = calc_point(s, uvw);
    EXPECT_TRUE(loc.locate(on).inside);
    const Vec3 p = on + 1e-3 * outward_normal(s, uvw, 0, 1);
    const PointLocation l = loc.locate(p);
    EXPECT_FALSE(l.inside);
    EXPECT_NEAR(l.distance, 1e-3, 1e-9) << n;
    EXPECT_LT((l.closest - on).norm(), 1e-8);
  }
  // just outside the caps w = 0 and w = 1
  for (int side = 0; side < 2; ++side)
    for (int n = 0; n < 50; ++n) {
      const Vec3 uvw(0.2 + 0.7 * U(rng), U(rng), side);
      const Vec3 on = calc_point(s, uvw);
      const Vec3 p = on + 2e-4 * outward_normal(s, uvw, 2, side);
      const PointLocation l = loc.locate(p);
      EXPECT_FALSE(l.inside);
      EXPECT_NEAR(l.distance, 2e-4, 1e-9);
    }
}

TEST(Membership, AgreesWithBruteForceSampling) {
  const auto s = make_bent_cylinder();
  const SolidLocator loc(s);
  // dense boundary samples for brute-force distances
  const auto t = make_boundary_tessellation(s, 24);
  const double spacing = 0.1 / (3 * 24);  // about the sample spacing along w (coarsest)
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> X(-0.03, 0.03), Y(-0.02, 0.06), Z(-0.03, 0.13);
  int outside = 0;
  for (int n = 0; n < 150; ++n) {
    const Vec3 p(X(rng), Y(rng), Z(rng));
    const PointLocation l = loc.locate(p);
    const double brute = (t.mesh.V.rowwise() - p.transpose()).rowwise().norm().minCoeff();
    if (l.inside) {
      // inside: p is reproduced by the solid map
      EXPECT_LT((calc_point(s, l.material) - p).norm(), 1e-10);
    } else {
      ++outside;
      // LM finds the true closest point: never farther than any sample, and not much closer
      EXPECT_LE(l.distance, brute + 1e-12);
      EXPECT_GE(l.distance, brute - spacing) << n;
      EXPECT_NEAR((calc_point(s, l.material) - p).norm(), l.distance, 1e-12);
    }
  }
  EXPECT_GT(outside, 50);
}

TEST(Tessellation, ClosedOutwardAndUpdatedBySparseProduct) {
  const auto box = make_cubical_lattice(Vec3(0, 0, 0), Vec3(0.02, 0.03, 0.05), {3, 3, 3}, {5, 5, 6});
  const auto tb = make_boundary_tessellation(box.solid, 3);
  // planar faces: the mesh volume is exact
  EXPECT_NEAR(calc_mass_properties(tb.mesh).volume_m3, 0.02 * 0.03 * 0.05, 1e-15);

  const auto s = make_bent_cylinder();
  auto t = make_boundary_tessellation(s, 6);
  // every edge shared by exactly two triangles (closed, merged at the axis)
  std::map<std::pair<int, int>, int> edges;
  for (Eigen::Index f = 0; f < t.mesh.F.rows(); ++f)
    for (int c = 0; c < 3; ++c) {
      const int a = t.mesh.F(f, c), b = t.mesh.F(f, (c + 1) % 3);
      ++edges[{std::min(a, b), std::max(a, b)}];
    }
  for (const auto& [e, count] : edges) EXPECT_EQ(count, 2);
  const double exact = calc_boundary_volume(s);
  const double v6 = calc_mass_properties(t.mesh).volume_m3;
  const double v12 = calc_mass_properties(make_boundary_tessellation(s, 12).mesh).volume_m3;
  EXPECT_LT(std::abs(v12 - exact), 0.3 * std::abs(v6 - exact));  // level of detail converges
  EXPECT_LT(std::abs(v12 - exact), 2e-3 * exact);
  // normals point outwards: against the mesh, a small step along the normal leaves the solid
  const SolidLocator loc(s);
  for (Eigen::Index v = 0; v < t.mesh.V.rows(); v += 7) {
    const Vec3 p = t.mesh.V.row(v).transpose() + 1e-4 * t.normals.row(v).transpose();
    EXPECT_FALSE(loc.locate(p).inside) << v;
  }
  // moving control points: the sparse update equals a fresh tessellation
  auto moved = s;
  moved.P.col(0) *= 1.3;
  moved.P.col(2) += 0.01 * moved.P.col(1);
  update_tessellation(t, moved.P);
  const auto fresh = make_boundary_tessellation(moved, 6);
  ASSERT_EQ(fresh.mesh.V.rows(), t.mesh.V.rows());
  EXPECT_LT((fresh.mesh.V - t.mesh.V).cwiseAbs().maxCoeff(), 1e-15);
  EXPECT_LT((fresh.normals - t.normals).cwiseAbs().maxCoeff(), 1e-12);

  auto hex = make_volume_tessellation(s, 2);
  EXPECT_EQ(hex.hexes.rows(), 2 * 16 * 6);  // cells: u 1 span x 2, v 8 periodic spans x 2, w 3 x 2
  update_tessellation(hex, moved.P);
  for (Eigen::Index v = 0; v < hex.V.rows(); v += 5) {
    EXPECT_LT((hex.V.row(v).transpose() - calc_point(moved, hex.material.row(v).transpose())).norm(), 1e-15);
  }
}

TEST(Fibres, CurvesStreamlinesAndTemplates) {
  const auto box = make_cubical_lattice(Vec3(0, 0, 0), Vec3(0.02, 0.02, 0.1), {3, 3, 3}, {4, 4, 6}).solid;
  // fibre curves of an affine solid are straight segments along the fibre direction (w -> z)
  const auto curves = calc_fibre_curves(box, 3, 3, 11);
  ASSERT_EQ(curves.size(), 9u);
  for (const auto& c : curves) {
    EXPECT_NEAR(c(0, 2), 0.0, 1e-15);
    EXPECT_NEAR(c(10, 2), 0.1, 1e-15);
    EXPECT_NEAR(c(0, 0), c(10, 0), 1e-15);
  }
  EXPECT_LT((calc_fibre_direction(box, Vec3(0.3, 0.4, 0.5)) - Vec3(0, 0, 1)).norm(), 1e-15);
  // pennate template at 20 degrees (material units): a straight streamline with slope tan(20°)
  const double a = 20.0 * std::numbers::pi / 180.0;
  Points3 M;
  const Points3 line = trace_streamline(box, make_pennate_field(FibreDirection::w, 0, a),
                                        Vec3(0.5, 0.5, 0.5), {.step = 0.01}, &M);
  ASSERT_GT(M.rows(), 10);
  for (Eigen::Index i = 0; i < M.rows(); ++i) {
    EXPECT_NEAR(M(i, 0) - 0.5, std::tan(a) * (M(i, 2) - 0.5), 1e-12);
  }
  // the streamline ends on the boundary
  EXPECT_TRUE(std::abs(M(0, 0)) < 1e-12 || std::abs(M(0, 2)) < 1e-12);
  // fanned template: the exact streamline is a(t) = 0.5 + (a0 - 0.5)(1 - c t)
  const double c = 0.6;
  trace_streamline(box, make_fanned_field(FibreDirection::w, 0, c), Vec3(0.9, 0.5, 0.0),
                   {.step = 0.005}, &M);
  const Eigen::Index last = M.rows() - 1;
  EXPECT_NEAR(M(last, 2), 1.0, 1e-12);
  EXPECT_NEAR(M(last, 0), 0.5 + 0.4 * (1 - c), 1e-7);
}

TEST(Embedding, PointsMeshesAndChildSolidsFollowTheParent) {
  const auto parent = make_cubical_lattice(Vec3(0, 0, 0), Vec3(0.04, 0.04, 0.1), {3, 3, 3}, {5, 5, 6}).solid;
  const SolidLocator loc(parent);
  auto child = make_cylindrical_lattice(0.01, 0.05, {2, 3, 2}, {3, 6, 4}).solid;
  child.P.rowwise() += Eigen::RowVector3d(0.02, 0.02, 0.02);
  const Embedding e = embed_points(loc, child.P);
  EXPECT_EQ(e.num_outside, 0);
  // an affine deformation of the parent moves embedded points by the same affine map (FFD)
  Mat3 A;
  A << 1.2, 0.1, 0, 0, 0.9, 0.05, 0.02, 0, 1.1;
  Points3 P = parent.P;
  for (int r = 0; r < P.rows(); ++r) P.row(r) = (A * parent.P.row(r).transpose()).transpose();
  const BSplineSolid moved = calc_embedded_child(e, child, P);
  for (int r = 0; r < child.P.rows(); ++r) {
    EXPECT_LT((moved.P.row(r).transpose() - A * child.P.row(r).transpose()).norm(), 1e-12);
  }
  // nested volume scales by det A
  EXPECT_NEAR(calc_volume(moved), A.determinant() * calc_volume(child), 1e-12 * calc_volume(child));
  // a point outside keeps its offset
  Points3 X(1, 3);
  X << 0.05, 0.02, 0.05;
  const Embedding eo = embed_points(loc, X);
  EXPECT_EQ(eo.num_outside, 1);
  EXPECT_LT((calc_embedded_positions(eo, parent.P) - X).norm(), 1e-12);
}

TEST(SolidIO, RoundTripAndBadInput) {
  const auto s = make_bent_cylinder();
  const auto dir = test::scratch_dir("bspline_io");
  write_solid(dir / "s.json", s);
  const auto r = read_solid(dir / "s.json");
  EXPECT_EQ(r.P, s.P);
  for (int d = 0; d < 3; ++d) {
    EXPECT_EQ(r.basis[d].knots, s.basis[d].knots);
    EXPECT_EQ(r.basis[d].periodic, s.basis[d].periodic);
  }
  EXPECT_EQ(calc_volume(r), calc_volume(s));
  // millimetre files are scaled
  std::string text = format_solid(s);
  const auto mm = parse_solid(text.replace(text.find("\"m\""), 3, "\"mm\""));
  EXPECT_NEAR(mm.P(5, 2), 1e-3 * s.P(5, 2), 1e-18);
  // bad knots name the basis
  std::string bad = format_solid(make_cubical_lattice(Vec3(0, 0, 0), Vec3(1, 1, 1), {1, 1, 1}, {2, 2, 2}).solid);
  const auto pos = bad.find("0.0,\n   1.0");
  try {
    auto j = bad;
    j.replace(j.find("\"degree\": 1"), 11, "\"degree\": 2");
    parse_solid(j, "x.json");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("/bases/0"), std::string::npos) << e.what();
  }
  (void)pos;
  try {
    auto j = bad;
    j.replace(j.rfind("1.0"), 3, "null");
    parse_solid(j, "x.json");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("not finite"), std::string::npos) << e.what();
  }
  EXPECT_THROW(parse_solid("{", "x.json"), Error);
  // export
  const auto t = make_volume_tessellation(s, 2);
  write_hexahedra_vtu(dir / "v.vtu", t.V, t.hexes);
  write_polylines_vtp(dir / "f.vtp", calc_fibre_curves(s, 2, 4, 20));
  std::ifstream in(dir / "v.vtu");
  std::string head((std::istreambuf_iterator<char>(in)), {});
  EXPECT_NE(head.find("UnstructuredGrid"), std::string::npos);
  EXPECT_NE(head.find("NumberOfCells=\"" + std::to_string(t.hexes.rows()) + "\""), std::string::npos);
}

}  // namespace
}  // namespace fascicle
