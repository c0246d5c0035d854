// Private to the deformation module: a nanoflann k-d tree over the rows of a #P x 3 array, the
// fibres-first inside test of a point against a bone, and arc-length fractions on polylines.
#pragma once

#include "fascicle/core/types.hpp"
#include "fascicle/geometry/mesh_query.hpp"

#include <nanoflann.hpp>

#include <algorithm>
#include <cstddef>
#include <cmath>
#include <limits>

namespace fascicle::detail {

// nanoflann's dataset adaptor: the rows of P (not copied; P must outlive the tree).
struct PointCloud {
  const Points3& P;
  std::size_t kdtree_get_point_count() const { return static_cast<std::size_t>(P.rows()); }
  double kdtree_get_pt(std::size_t i, std::size_t d) const { return P(i, d); }
  template <class Box>
  bool kdtree_get_bbox(Box&) const { return false; }
};
using PointTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, PointCloud>,
                                                      PointCloud, 3, std::size_t>;

// Which side of a bone's surface the point with closest point cp lies on. When the closest point
// is inside a face, the side of that face decides exactly; on an edge or a vertex, MeshQuery's
// ray-crossing vote does. The fibres-first model (rest depths) and solver (contacts, penetration)
// both use this one rule, so a particle's rest state and its per-frame state are measured alike
// (on open meshes the two tests can disagree). `face_normal`: the closest face's normal, not unit.
inline bool calc_is_behind_bone(const MeshQuery& bone, const Vec3& p, const ClosestPoint& cp,
                                Vec3* face_normal = nullptr) {
  const TriMesh& mesh = bone.get_mesh();
  const Vec3 a = mesh.V.row(mesh.F(cp.triangle, 0)), b = mesh.V.row(mesh.F(cp.triangle, 1)),
             c = mesh.V.row(mesh.F(cp.triangle, 2));
  const Vec3 n = (b - a).cross(c - a);
  if (face_normal) *face_normal = n;
  const bool on_face = cp.barycentric.minCoeff() > 1e-9 && n.norm() > 0.0;
  return on_face ? (p - cp.point).dot(n) < 0.0 : bone.calc_is_inside(p);
}

// Arc-length fraction in [0, 1] of the point of polyline `line` (>= 2 rows) closest to p.
inline double calc_line_fraction(const Points3& line, const Vec3& p) {
  double total = 0.0, best_d2 = std::numeric_limits<double>::infinity(), best_s = 0.0;
  for (Eigen::Index k = 0; k + 1 < line.rows(); ++k) {
    const Vec3 a = line.row(k).transpose(), b = line.row(k + 1).transpose();
    const double len2 = (b - a).squaredNorm();
    const double u = len2 > 0.0 ? std::clamp((p - a).dot(b - a) / len2, 0.0, 1.0) : 0.0;
    const double d2 = (a + u * (b - a) - p).squaredNorm();
    if (d2 < best_d2) {
      best_d2 = d2;
      best_s = total + u * std::sqrt(len2);
    }
    total += std::sqrt(len2);
  }
  return total > 0.0 ? best_s / total : 0.0;
}

// Length of polyline `line`.
inline double calc_line_length(const Points3& line) {
  double total = 0.0;
  for (Eigen::Index k = 0; k + 1 < line.rows(); ++k) total += (line.row(k + 1) - line.row(k)).norm();
  return total;
}

// Arc-length fraction on a line of length `length` of the point whose rest fraction on a line of
// length `rest_length` was s, when the arc length from the nearer end (in the rest pose) is kept:
// an inextensible tendon between the point and that end. Clamped to [0, 1].
inline double calc_tendon_fraction(double s, double rest_length, double length) {
  if (!(length > 0.0)) return s;
  const double kept = s <= 0.5 ? s * rest_length / length : 1.0 - (1.0 - s) * rest_length / length;
  return std::clamp(kept, 0.0, 1.0);
}

// The point of polyline `line` (>= 2 rows) at arc-length fraction s, and the unit direction of
// the segment it lies on (zero for a degenerate line).
inline void calc_line_point(const Points3& line, double s, Vec3& point, Vec3& tangent) {
  double total = 0.0;
  for (Eigen::Index k = 0; k + 1 < line.rows(); ++k) total += (line.row(k + 1) - line.row(k)).norm();
  const double target = std::clamp(s, 0.0, 1.0) * total;
  double walked = 0.0;
  point = line.row(line.rows() - 1).transpose();
  tangent = Vec3::Zero();
  for (Eigen::Index k = 0; k + 1 < line.rows(); ++k) {
    const Vec3 a = line.row(k).transpose(), b = line.row(k + 1).transpose();
    const double len = (b - a).norm();
    if (len <= 0.0) continue;
    tangent = (b - a) / len;
    if (walked + len >= target || k + 2 == line.rows()) {
      point = a + std::clamp((target - walked) / len, 0.0, 1.0) * (b - a);
      return;
    }
    walked += len;
  }
}

}  // namespace fascicle::detail
