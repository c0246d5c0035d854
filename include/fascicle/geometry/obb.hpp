// Oriented bounding boxes of point sets and triangle meshes.
//
// Start: principal component analysis. For a mesh the covariance is that of the surface with
// uniform area density (each triangle's exact second moment, so the result does not depend on how
// finely or unevenly the surface is triangulated); for a point set, that of the points.
// Refinement (optional, default on): for each candidate axis (the principal axes and, for a mesh,
// the dominant face-normal directions) the points are projected onto the plane normal to it and
// the minimum-area enclosing rectangle of their convex hull is found (it has a side collinear
// with a hull edge: Freeman and Shapira 1975, CACM 18(7)); the smallest box wins, and the search
// repeats about its axes until the volume stops decreasing. This finds the exact box of boxes
// and prisms and never returns a larger box than PCA.
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"

namespace fascicle {

struct OrientedBox {
  Vec3 centre = Vec3::Zero();
  Mat3 axes = Mat3::Identity();       // columns: unit axes, right-handed (det +1), ordered by
                                      // decreasing half extent
  Vec3 half_extents = Vec3::Zero();   // along each axis, same length unit as the input

  double calc_volume() const { return 8.0 * half_extents.prod(); }
  // Pose of the box frame B in the input frame A: p_A = X_AB * p_B, box = [-h, h] in B.
  Transform calc_pose() const;
};

// Box of #P x 3 points. Throws fascicle::Error (bad input) if there are no points or any is not
// finite.
OrientedBox compute_oriented_box(const Points3& points, bool refine = true);

// Box of a mesh (of its vertices, with the area-weighted surface covariance as the start).
OrientedBox compute_oriented_box(const TriMesh& mesh, bool refine = true);

}  // namespace fascicle
