// Muscle–muscle overlap measure of a scene frame: the deepest vertex of one muscle surface inside
// another closed muscle surface (MuscleFrame::max_muscle_overlap_m). Measured, not resolved.
//
// The inside test is the winding-number propagation of deformation/surface_first.hpp
// (calc_surface_overlap(V, F, other)): vertices of a outside b's (padded) bounding box have winding
// number 0; the winding number is carried along a's edges into the box, one short segment crossing
// count per edge. Here only the part of a's edge graph that can matter is handed to that
// propagation: a's vertices inside b's box and their direct neighbours outside it, in a's own vertex
// order, so the propagation visits the same edges in the same order and gives the same numbers as
// calc_surface_overlap(V, F, other), bit for bit (tests/scene/test_overlap.cpp checks it on Visible
// Human muscles), at a cost that scales with the vertices in the box instead of all vertices.
#pragma once

#include "fascicle/core/types.hpp"
#include "fascicle/geometry/mesh_query.hpp"

#include <limits>
#include <memory>
#include <vector>

namespace fascicle {

// Vertex neighbours of a closed triangle surface in compressed rows, as make_vertex_adjacency
// (deformation/surface_first.hpp) orders them: neighbours of i are neighbours[start[i] ..
// start[i+1]), each once.
struct SurfaceGraph {
  std::vector<int> start;
  std::vector<int> neighbours;
};
SurfaceGraph make_surface_graph(const Triangles& F, Eigen::Index num_vertices);

// The result of one ordered pair (vertices of a inside surface b).
struct MuscleOverlap {
  int vertices_inside = 0;
  double max_depth_m = 0.0;  // largest distance from an inside vertex of a to surface b
};

// The bounding box calc_surface_overlap uses to seed the propagation: the vertices' box padded by
// 1e-9 of its diagonal on every side.
Eigen::AlignedBox3d calc_padded_bounding_box(const Points3& V);

// A box with any fixed orientation around a surface's vertices: the points x with
// lo <= axes^T x <= hi (axes: orthonormal columns). Like the axis-aligned box it is convex and holds
// the whole surface, so a point outside it is outside the surface (winding number 0); for long,
// obliquely lying muscles it is much tighter than the axis-aligned box.
struct OrientedBounds {
  Mat3 axes = Mat3::Identity();
  Vec3 lo = Vec3::Zero(), hi = Vec3::Zero();
  bool contains(const Vec3& x) const {
    const Vec3 u = axes.transpose() * x;
    return (u.array() >= lo.array()).all() && (u.array() <= hi.array()).all();
  }
};
// Bounds of V along `axes`, padded as calc_padded_bounding_box pads (1e-9 of the box diagonal).
OrientedBounds calc_padded_oriented_bounds(const Points3& V, const Mat3& axes);

// Vertices of the closed surface (V, graph) inside the closed surface behind `other`, whose padded
// box (calc_padded_bounding_box of other's vertices) is `other_box`. Same numbers as
// calc_surface_overlap(V, F, other) for graph = make_surface_graph(F, V.rows()); falls back to it
// (per-vertex ray vote) in the same cases. `other_bounds` (optional): oriented bounds of other's
// vertices; vertices outside them are known to be outside as well, so fewer vertices need the
// propagation (the winding numbers found are the same).
// An upper bound of a point x's distance to a surface: bound >= |x - z| for a point z of the
// surface's triangle `triangle`. After the point and the surface's vertices move, bound + |x' - x|
// + (that triangle's largest vertex motion) is again such a bound (for z's barycentric point).
struct DepthBound {
  double bound = std::numeric_limits<double>::infinity();
  int triangle = -1;
};
// `depth_bound` (optional; used when it has one entry per vertex of V, an empty one means no
// bound known): upper bounds of the vertices' distances to other's surface, e.g. carried from an
// earlier frame (calc_pair_depths in state.cpp widens them by the motions). Vertices whose bound
// lies below the deepest depth measured so far are not measured; the maximum is the same (the
// deepest vertex is always measured). On return it holds bounds for this call's surfaces: when
// some vertex is inside, one entry per vertex (the measured depth, or the tightest bound known,
// for the vertices found inside; +inf for the others); when none is, it is empty (most pairs of a
// scene: no per-vertex array to fill now and to widen at the next frame).
MuscleOverlap calc_muscle_overlap(const Points3& V, const SurfaceGraph& graph, const MeshQuery& other,
                                  const Eigen::AlignedBox3d& other_box,
                                  const OrientedBounds* other_bounds = nullptr,
                                  std::vector<DepthBound>* depth_bound = nullptr);

// What the overlap measure keeps from frame to frame, per muscle (owned by State, created empty by
// make_state(); filled on first use). Never changes results: a State whose cache is empty and one
// whose cache was filled by earlier frames measure the same numbers.
struct MuscleOverlapCache {
  std::vector<SurfaceGraph> graph;                 // per muscle: edge graph of its rest triangles
  std::vector<std::unique_ptr<MeshQuery>> query;   // per muscle: query of its latest measured surface
  std::vector<Mat3> axes;  // per muscle: axes of its rest mesh's oriented box (fixed; bounds per frame)
  std::vector<char> has_axes;
  // Per ordered pair (a, b), at [a * #muscles + b]: the depth of a's rest-mesh vertices inside b's
  // rest mesh (0 when their rest boxes do not meet). A function of the Model, measured once.
  std::vector<double> rest_depth;
  // Per muscle: the surface of the last call (to bound how far its points moved since); per
  // ordered pair: calc_muscle_overlap's depth bounds from that call. Only skip measurements.
  std::vector<Points3> previous;
  std::vector<std::vector<DepthBound>> depth_bound;
};

}  // namespace fascicle
