#include "fascicle/geometry/mass_properties.hpp"

#include "fascicle/core/error.hpp"

#include <Eigen/Eigenvalues>

#include <array>
#include <cmath>
#include <limits>
#include <string>

namespace fascicle {
namespace {

// Eberly's per-coordinate subexpressions of the three corner values w0, w1, w2 of a triangle.
struct Sub {
  double f1, f2, f3, g0, g1, g2;
};
Sub subexpressions(double w0, double w1, double w2) {
  const double t0 = w0 + w1;
  const double t1 = w0 * w0;
  const double t2 = t1 + w1 * t0;
  Sub s;
  s.f1 = t0 + w2;
  s.f2 = t2 + w2 * s.f1;
  s.f3 = w0 * t1 + w1 * t2 + w2 * s.f2;
  s.g0 = s.f2 + w0 * (s.f1 + w0);
  s.g1 = s.f2 + w1 * (s.f1 + w1);
  s.g2 = s.f2 + w2 * (s.f1 + w2);
  return s;
}

void check_input(const TriMesh& mesh, double density) {
  if (!(density > 0.0) || !std::isfinite(density)) {
    throw_bad_input("density must be positive and finite, got " + std::to_string(density),
                    {.suggestion = "give kg/m^3, e.g. 1060 for muscle"});
  }
  if (mesh.F.rows() == 0) throw_bad_input("mass properties of a mesh without faces");
  const Eigen::Index nv = mesh.V.rows();
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int i = mesh.F(f, k);
      if (i < 0 || i >= nv) {
        throw_bad_input("face " + std::to_string(f) + " refers to vertex " + std::to_string(i) +
                            " of " + std::to_string(nv),
                        {.suggestion = "validate the mesh (fascicle mesh info)"});
      }
      if (!mesh.V.row(i).allFinite()) {
        throw_bad_input("vertex " + std::to_string(i) + " has a NaN/Inf coordinate",
                        {.suggestion = "validate the mesh (fascicle mesh info)"});
      }
    }
  }
}

}  // namespace

MassProperties calc_mass_properties(const TriMesh& mesh, double density) {
  check_input(mesh, density);
  // integrate about the bounding-box centre o, shift the centroid back at the end
  const Vec3 o = 0.5 * (mesh.V.colwise().minCoeff() + mesh.V.colwise().maxCoeff()).transpose();
  // integrals of 1, x, y, z, x^2, y^2, z^2, xy, yz, zx (unscaled), and the area
  std::array<double, 10> in{};
  double area2 = 0.0;
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    const Vec3 p0 = mesh.V.row(mesh.F(f, 0)).transpose() - o;
    const Vec3 p1 = mesh.V.row(mesh.F(f, 1)).transpose() - o;
    const Vec3 p2 = mesh.V.row(mesh.F(f, 2)).transpose() - o;
    const Vec3 d = (p1 - p0).cross(p2 - p0);  // twice the area times the unit normal
    area2 += d.norm();
    const Sub x = subexpressions(p0.x(), p1.x(), p2.x());
    const Sub y = subexpressions(p0.y(), p1.y(), p2.y());
    const Sub z = subexpressions(p0.z(), p1.z(), p2.z());
    in[0] += d.x() * x.f1;
    in[1] += d.x() * x.f2;
    in[2] += d.y() * y.f2;
    in[3] += d.z() * z.f2;
    in[4] += d.x() * x.f3;
    in[5] += d.y() * y.f3;
    in[6] += d.z() * z.f3;
    in[7] += d.x() * (p0.y() * x.g0 + p1.y() * x.g1 + p2.y() * x.g2);
    in[8] += d.y() * (p0.z() * y.g0 + p1.z() * y.g1 + p2.z() * y.g2);
    in[9] += d.z() * (p0.x() * z.g0 + p1.x() * z.g1 + p2.x() * z.g2);
  }
  constexpr std::array<double, 10> scale{1.0 / 6,  1.0 / 24, 1.0 / 24, 1.0 / 24,  1.0 / 60,
                                         1.0 / 60, 1.0 / 60, 1.0 / 120, 1.0 / 120, 1.0 / 120};
  for (int i = 0; i < 10; ++i) in[i] *= scale[i];

  MassProperties mp;
  mp.area_m2 = 0.5 * area2;
  mp.volume_m3 = in[0];
  if (!(std::abs(in[0]) > 0.0) || !std::isfinite(in[0])) {
    throw_bad_input("the mesh encloses no volume",
                    {.suggestion = "mass properties need a closed surface"});
  }
  const Vec3 c(in[1] / in[0], in[2] / in[0], in[3] / in[0]);  // relative to o
  mp.centroid = o + c;
  mp.mass_kg = density * in[0];
  // second moments about the centroid (parallel-axis shift from o), times density
  const double v = in[0];
  const double xx = in[4] - v * c.x() * c.x(), yy = in[5] - v * c.y() * c.y(),
               zz = in[6] - v * c.z() * c.z();
  const double xy = in[7] - v * c.x() * c.y(), yz = in[8] - v * c.y() * c.z(),
               zx = in[9] - v * c.z() * c.x();
  mp.inertia << yy + zz, -xy, -zx,  //
      -xy, xx + zz, -yz,            //
      -zx, -yz, xx + yy;
  mp.inertia *= density;
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(mp.inertia);
  mp.principal_moments = eig.eigenvalues();
  mp.principal_axes = eig.eigenvectors();
  if (mp.principal_axes.determinant() < 0) mp.principal_axes.col(2) *= -1.0;
  return mp;
}

double calc_enclosed_volume(const Points3& V, const Triangles& F, const Vec3& origin) {
  double sum = 0.0;
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const Vec3 a = V.row(F(f, 0)).transpose() - origin;
    const Vec3 b = V.row(F(f, 1)).transpose() - origin;
    const Vec3 c = V.row(F(f, 2)).transpose() - origin;
    sum += a.dot(b.cross(c));
  }
  return sum / 6.0;
}

double calc_enclosed_volume(const TriMesh& mesh) {
  if (mesh.V.rows() == 0) return 0.0;
  return calc_enclosed_volume(mesh.V, mesh.F, mesh.V.colwise().mean().transpose());
}

}  // namespace fascicle
