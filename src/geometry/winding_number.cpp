#include "fascicle/geometry/winding_number.hpp"

#include "fascicle/core/parallel.hpp"

#include <cmath>
#include <numbers>

namespace fascicle {

double compute_solid_angle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  // tan(Omega / 2) = det[a b c] / (|a||b||c| + (a.b)|c| + (b.c)|a| + (c.a)|b|), vertices relative
  // to p. atan2 keeps the quadrant, so the formula holds for solid angles beyond pi.
  const Vec3 ra = a - p, rb = b - p, rc = c - p;
  const double la = ra.norm(), lb = rb.norm(), lc = rc.norm();
  const double det = ra.dot(rb.cross(rc));
  const double den = la * lb * lc + ra.dot(rb) * lc + rb.dot(rc) * la + rc.dot(ra) * lb;
  // det > 0 when p lies behind the counter-clockwise face: this triangle's contribution to the
  // winding number at p is positive there.
  return 2.0 * std::atan2(det, den);
}

double compute_winding_number(const TriMesh& mesh, const Vec3& p) {
  double sum = 0.0;
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    sum += compute_solid_angle(p, mesh.V.row(mesh.F(f, 0)), mesh.V.row(mesh.F(f, 1)),
                               mesh.V.row(mesh.F(f, 2)));
  }
  return sum / (4.0 * std::numbers::pi);
}

VecX compute_winding_numbers(const TriMesh& mesh, const Points3& P) {
  VecX w(P.rows());
  parallel_for(static_cast<std::size_t>(P.rows()), [&](std::size_t i) {
    const auto r = static_cast<Eigen::Index>(i);
    w[r] = compute_winding_number(mesh, P.row(r).transpose());
  });
  return w;
}

}  // namespace fascicle
