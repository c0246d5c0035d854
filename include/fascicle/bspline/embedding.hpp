// Nesting / embedding (seed 000 §3.1.3, Fig. 6; free-form deformation, Sederberg & Parry 1986):
// points, meshes or a child solid's control points are given material coordinates in a parent
// solid (by point membership) and then follow the parent's deformation: x = W P_parent + offset,
// where W holds the parent's basis products at the embedded material points and offset is the
// (fixed) gap of points outside the parent (zero for points inside).
#pragma once

#include "fascicle/bspline/membership.hpp"
#include "fascicle/bspline/tessellation.hpp"
#include "fascicle/geometry/tri_mesh.hpp"

namespace fascicle {

struct Embedding {
  Points3 material;         // #N x 3 material points in the parent
  Points3 offset;           // #N x 3 spatial offsets (m), zero inside the parent
  SparseRowMatrix weights;  // #N x #P_parent
  int num_outside = 0;      // points that were outside the parent (beyond its tolerance)
};

// Embeds points (#N x 3, m) in the parent the locator was built for.
Embedding embed_points(const SolidLocator& parent, const Points3& X);

// Positions of embedded points for parent control points P (same lattice).
Points3 calc_embedded_positions(const Embedding& e, const Points3& P);

// A mesh that follows the parent: same faces, vertices moved.
TriMesh calc_embedded_mesh(const Embedding& e, const TriMesh& rest, const Points3& P);

// A child solid whose control points follow the parent (nesting).
BSplineSolid calc_embedded_child(const Embedding& e, const BSplineSolid& child_rest,
                                 const Points3& P);

}  // namespace fascicle
