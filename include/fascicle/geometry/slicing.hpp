// Plane slicing of triangle meshes into ordered contours (cross-sections for areas, fibre and
// B-spline fitting).
//
// Orientation: seen from the tip of the plane normal n, the solid's cross-section lies to the
// left of each contour, so outer boundaries run counter-clockwise about n (positive signed area)
// and holes clockwise. This needs a consistently oriented mesh with outward normals.
// Robustness: every vertex is classified once by the sign of n.(v - plane_point), and a vertex
// exactly on the plane counts as positive (symbolic perturbation: the plane is moved an
// infinitesimal distance against n). Each crossing edge gives one contour point, computed the
// same way from both triangles sharing it, so contours of closed manifold meshes are closed and
// exactly consistent; vertices on the plane give points exactly at those vertices.
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"

#include <vector>

namespace fascicle {

// A polyline of #P x 3 points. A closed contour connects its last point back to its first (the
// first point is not repeated); an open one (a slice through an open mesh, or through non-manifold
// parts) runs from first to last.
struct Contour {
  Points3 points;
  bool closed = false;
};

// Slices `mesh` with the plane through plane_point with normal plane_normal (any length > 0).
// Returns the closed contours first, then any open chains, in a deterministic order.
// Throws fascicle::Error (bad input) for a zero or non-finite normal.
std::vector<Contour> slice_mesh(const TriMesh& mesh, const Vec3& plane_point, const Vec3& plane_normal);

// Slices with the parallel planes {x : u.x = offsets[i]}, u = plane_normal / |plane_normal|, in
// parallel (fascicle::parallel_for; result i belongs to offsets[i]).
std::vector<std::vector<Contour>> slice_mesh_parallel(const TriMesh& mesh, const Vec3& plane_normal,
                                                      const VecX& offsets);

// Length of the polyline, including the closing segment of a closed contour.
double compute_contour_length(const Contour& contour);

// Signed area enclosed by a closed contour, projected onto the plane with normal `normal`:
// positive when the contour runs counter-clockwise about the normal. (Vector area
// 1/2 sum p_i x p_{i+1}, dotted with the unit normal.)
double compute_contour_area(const Contour& contour, const Vec3& normal);

}  // namespace fascicle
