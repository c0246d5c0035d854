// Muscle–muscle overlap: winding-number propagation restricted to the vertices in the other box.
#include "fascicle/scene/overlap.hpp"

#include "fascicle/deformation/surface_first.hpp"

#include <algorithm>
#include <limits>

namespace fascicle {

SurfaceGraph make_surface_graph(const Triangles& F, Eigen::Index num_vertices) {
  VertexAdjacency a = make_vertex_adjacency(F, num_vertices);
  return SurfaceGraph{std::move(a.start), std::move(a.neighbours)};
}

Eigen::AlignedBox3d calc_padded_bounding_box(const Points3& V) {
  Eigen::AlignedBox3d box(V.colwise().minCoeff().transpose(), V.colwise().maxCoeff().transpose());
  const double pad = 1e-9 * box.diagonal().norm();
  box.min().array() -= pad;
  box.max().array() += pad;
  return box;
}

OrientedBounds calc_padded_oriented_bounds(const Points3& V, const Mat3& axes) {
  OrientedBounds b;
  b.axes = axes;
  const Points3 U = V * axes;
  b.lo = U.colwise().minCoeff().transpose();
  b.hi = U.colwise().maxCoeff().transpose();
  const double pad = 1e-9 * (b.hi - b.lo).norm();
  b.lo.array() -= pad;
  b.hi.array() += pad;
  return b;
}

MuscleOverlap calc_muscle_overlap(const Points3& V, const SurfaceGraph& graph, const MeshQuery& other,
                                  const Eigen::AlignedBox3d& other_box, const OrientedBounds* other_bounds,
                                  std::vector<DepthBound>* depth_bound) {
  MuscleOverlap out;
  const Eigen::Index n = V.rows();
  constexpr double inf = std::numeric_limits<double>::infinity();
  // The bounds carried in (used only when they have one entry per vertex). The bounds returned
  // (set at the end) exist only when some vertex is inside: then one entry per vertex, +inf for
  // the vertices outside; otherwise depth_bound is left empty (no bound known, as +inf).
  std::vector<DepthBound> carried;
  if (depth_bound) {
    carried.swap(*depth_bound);
    depth_bound->clear();
  }
  const bool have_carried = carried.size() == static_cast<std::size_t>(n);
  // The unknown vertices: those in other's box (and oriented bounds); every other vertex lies
  // outside a convex set holding other's surface, so its winding number is 0.
  std::vector<int> unknown_vertices;
  for (Eigen::Index i = 0; i < n; ++i) {
    const Vec3 x = V.row(i).transpose();
    if (other_box.contains(x) && (!other_bounds || other_bounds->contains(x)))
      unknown_vertices.push_back(static_cast<int>(i));
  }
  const auto unknown = static_cast<int>(unknown_vertices.size());
  if (unknown == 0) return out;
  // The sub-graph: unknown vertices plus their known neighbours, kept in a's vertex order. The full
  // propagation queues every known vertex in that order; known vertices without an unknown
  // neighbour reach nothing, so leaving them out keeps the visiting order unchanged.
  std::vector<int> local(static_cast<std::size_t>(n), -1);  // -1: left out; -2: unknown; -3: known neighbour
  for (const int i : unknown_vertices) local[static_cast<std::size_t>(i)] = -2;
  for (const int i : unknown_vertices)
    for (int k = graph.start[i]; k < graph.start[i + 1]; ++k)
      if (local[graph.neighbours[k]] == -1) local[graph.neighbours[k]] = -3;
  std::vector<int> keep;
  std::vector<char> in_box;  // per kept vertex: 1 unknown, 0 known neighbour
  keep.reserve(static_cast<std::size_t>(unknown) * 2);
  in_box.reserve(static_cast<std::size_t>(unknown) * 2);
  for (Eigen::Index i = 0; i < n; ++i)
    if (local[i] != -1) {
      in_box.push_back(local[i] == -2);
      local[i] = static_cast<int>(keep.size());
      keep.push_back(static_cast<int>(i));
    }
  const auto m = static_cast<Eigen::Index>(keep.size());
  Points3 P(m, 3);
  VertexAdjacency sub;
  sub.start.assign(static_cast<std::size_t>(m) + 1, 0);
  sub.neighbours.reserve(static_cast<std::size_t>(m) * 6);
  std::vector<int> winding(static_cast<std::size_t>(m), 0);
  for (Eigen::Index l = 0; l < m; ++l) {
    const int g = keep[l];
    P.row(l) = V.row(g);
    winding[l] = in_box[l] ? -1 : 0;
    // A known vertex's known neighbours are skipped by the propagation: leave them out.
    for (int k = graph.start[g]; k < graph.start[g + 1]; ++k)
      if (const int q = local[graph.neighbours[k]]; q >= 0) sub.neighbours.push_back(q);
    sub.start[l + 1] = static_cast<int>(sub.neighbours.size());
  }
  // Same whole-ray budget as calc_surface_overlap (it depends on a's full vertex count).
  const int max_whole_rays = std::max(64, static_cast<int>(n / 16));
  if (!propagate_winding(P, sub, other, winding, max_whole_rays)) {
    const OverlapInfo vote = calc_surface_overlap(V, other);
    return {vote.vertices_inside, vote.max_depth_m};
  }
  // Depth of the inside vertices. The distance to a surface is 1-Lipschitz, so a vertex whose
  // measured neighbour bounds its depth (neighbour depth + edge length) below the deepest found so
  // far cannot change the maximum and is not measured (the margin covers rounding). A carried
  // bound (depth_bound) prunes the same way; the vertex with the largest finite carried bound (in
  // a run: near the previous frame's deepest) is measured first so that the maximum is high early.
  // Which vertices are measured never changes the result: the deepest vertex cannot be pruned.
  std::vector<double> bound(static_cast<std::size_t>(m), inf);
  std::vector<int> triangle(static_cast<std::size_t>(m), -1);  // of the point realising the bound
  if (have_carried)
    for (Eigen::Index l = 0; l < m; ++l) {
      bound[l] = carried[static_cast<std::size_t>(keep[l])].bound;
      triangle[l] = carried[static_cast<std::size_t>(keep[l])].triangle;
    }
  std::vector<char> measured(static_cast<std::size_t>(m), 0);
  const auto measure = [&](Eigen::Index l) {
    const Vec3 p = P.row(l).transpose();
    const ClosestPoint cp = other.calc_closest_point(p);
    const double depth = cp.distance;
    measured[l] = 1;
    bound[l] = depth;
    triangle[l] = cp.triangle;
    out.max_depth_m = std::max(out.max_depth_m, depth);
    for (int k = sub.start[l]; k < sub.start[l + 1]; ++k) {
      const int q = sub.neighbours[k];
      const double via = depth + (Vec3(P.row(q).transpose()) - p).norm();
      if (via < bound[q]) {
        bound[q] = via;
        triangle[q] = cp.triangle;
      }
    }
  };
  if (have_carried) {
    Eigen::Index first = -1;
    for (Eigen::Index l = 0; l < m; ++l)
      if (winding[l] > 0 && bound[l] < inf && (first < 0 || bound[l] > bound[first])) first = l;
    if (first >= 0) measure(first);
  }
  for (Eigen::Index l = 0; l < m; ++l) {
    if (winding[l] <= 0) continue;
    ++out.vertices_inside;
    if (measured[l] || bound[l] * (1.0 + 1e-9) + 1e-15 < out.max_depth_m) continue;
    measure(l);
  }
  if (depth_bound && out.vertices_inside > 0) {
    carried.assign(static_cast<std::size_t>(n), {});  // its storage reused
    for (Eigen::Index l = 0; l < m; ++l)
      if (winding[l] > 0) carried[static_cast<std::size_t>(keep[l])] = {bound[l], triangle[l]};
    depth_bound->swap(carried);
  }
  return out;
}

}  // namespace fascicle
