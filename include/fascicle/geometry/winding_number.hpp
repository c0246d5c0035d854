// Generalised winding number of a triangle mesh (Jacobson, Kavan and Sorkine-Hornung 2013,
// "Robust Inside-Outside Segmentation using Generalized Winding Numbers", ACM TOG 32(4)).
//
// w(p) = (1 / 4 pi) * sum over triangles of the signed solid angle the triangle subtends at p.
// For a closed, outward-oriented mesh w = 1 inside and 0 outside (2 inside two overlapping
// shells, ...); for a mesh with small holes it varies smoothly and w > 1/2 is a robust inside test.
// These are the exact O(#F) sums: the reference for the fast inside test of MeshQuery, and fine
// for small meshes or few points.
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"

namespace fascicle {

// Signed solid angle (steradians, in [-2 pi, 2 pi]) of triangle (a, b, c) seen from p; positive
// when p is behind the triangle (on the side opposite its counter-clockwise normal).
// Van Oosterom and Strackee 1983, IEEE Trans. Biomed. Eng. 30(2).
double compute_solid_angle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c);

// Exact generalised winding number of `mesh` at p. O(#F).
double compute_winding_number(const TriMesh& mesh, const Vec3& p);

// The same for #P x 3 points, in parallel (fascicle::parallel_for; deterministic). O(#P #F).
VecX compute_winding_numbers(const TriMesh& mesh, const Points3& P);

}  // namespace fascicle
