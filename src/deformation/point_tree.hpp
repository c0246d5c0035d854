// Private to the deformation module: a nanoflann k-d tree over the rows of a #P x 3 array, and the
// fibres-first inside test of a point against a bone.
#pragma once

#include "fascicle/core/types.hpp"
#include "fascicle/geometry/mesh_query.hpp"

#include <nanoflann.hpp>

#include <cstddef>

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

}  // namespace fascicle::detail
