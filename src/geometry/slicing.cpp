#include "fascicle/geometry/slicing.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"

#include <cmath>
#include <cstdint>
#include <unordered_map>

namespace fascicle {
namespace {

Vec3 unit_normal(const Vec3& n) {
  const double len = n.norm();
  if (!(len > 0.0) || !std::isfinite(len)) {
    throw_bad_input("slicing plane needs a finite, non-zero normal",
                    {.suggestion = "pass a plane normal such as (0, 0, 1)"});
  }
  return n / len;
}

// Contour graph: one node per mesh edge crossing the plane, one directed segment per crossed
// triangle (from its edge going positive->negative to its edge going negative->positive, in the
// triangle's counter-clockwise order; this puts the solid on the left seen from +n).
struct SliceGraph {
  std::vector<Vec3> node_points;
  std::vector<std::vector<int>> out;  // node -> segment ids
  std::vector<int> in_degree;
  std::vector<std::pair<int, int>> segments;  // (from node, to node)
};

SliceGraph build_graph(const TriMesh& mesh, const VecX& s) {
  SliceGraph g;
  std::unordered_map<std::uint64_t, int> node_of_edge;
  auto node = [&](int u, int v) {
    const int a = std::min(u, v), b = std::max(u, v);
    const std::uint64_t key = (static_cast<std::uint64_t>(a) << 32) | static_cast<std::uint32_t>(b);
    auto [it, inserted] = node_of_edge.try_emplace(key, static_cast<int>(g.node_points.size()));
    if (inserted) {
      // The same point from both triangles: computed from the ordered edge (a, b) only. A vertex
      // on the plane (s = 0) is returned exactly.
      const double sa = s[a], sb = s[b];
      Vec3 p;
      if (sa == 0.0) {
        p = mesh.V.row(a).transpose();
      } else if (sb == 0.0) {
        p = mesh.V.row(b).transpose();
      } else {
        const double t = sa / (sa - sb);
        p = mesh.V.row(a).transpose() + t * (mesh.V.row(b) - mesh.V.row(a)).transpose();
      }
      g.node_points.push_back(p);
      g.out.emplace_back();
      g.in_degree.push_back(0);
    }
    return it->second;
  };
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    int from = -1, to = -1;
    for (int k = 0; k < 3; ++k) {
      const int u = mesh.F(f, k), v = mesh.F(f, (k + 1) % 3);
      const bool pu = s[u] >= 0.0, pv = s[v] >= 0.0;
      if (pu && !pv) from = node(u, v);
      if (!pu && pv) to = node(u, v);
    }
    if (from < 0) continue;  // all on one side
    const int id = static_cast<int>(g.segments.size());
    g.segments.emplace_back(from, to);
    g.out[static_cast<std::size_t>(from)].push_back(id);
    ++g.in_degree[static_cast<std::size_t>(to)];
  }
  return g;
}

// Appends p unless it equals the previous point (zero-length pieces at on-plane vertices).
void push_point(std::vector<Vec3>& pts, const Vec3& p) {
  if (pts.empty() || pts.back() != p) pts.push_back(p);
}

Contour make_contour(std::vector<Vec3> pts, bool closed) {
  if (closed && pts.size() > 1 && pts.front() == pts.back()) pts.pop_back();
  Contour c;
  c.closed = closed;
  c.points.resize(static_cast<Eigen::Index>(pts.size()), 3);
  for (std::size_t i = 0; i < pts.size(); ++i) c.points.row(static_cast<Eigen::Index>(i)) = pts[i];
  return c;
}

std::vector<Contour> trace_contours(const SliceGraph& g) {
  std::vector<char> used(g.segments.size(), 0);
  std::vector<std::size_t> next_out(g.out.size(), 0);  // first possibly unused out-segment
  auto take = [&](int node) -> int {
    auto& k = next_out[static_cast<std::size_t>(node)];
    const auto& outs = g.out[static_cast<std::size_t>(node)];
    while (k < outs.size() && used[static_cast<std::size_t>(outs[k])]) ++k;
    return k < outs.size() ? outs[k] : -1;
  };
  // Follows unused segments from `start` until it returns to `start` or gets stuck.
  auto walk = [&](int start, std::vector<Vec3>& pts) {
    int node = start;
    push_point(pts, g.node_points[static_cast<std::size_t>(node)]);
    while (true) {
      const int seg = take(node);
      if (seg < 0) return false;
      used[static_cast<std::size_t>(seg)] = 1;
      node = g.segments[static_cast<std::size_t>(seg)].second;
      if (node == start) return true;
      push_point(pts, g.node_points[static_cast<std::size_t>(node)]);
    }
  };
  std::vector<Contour> closed, open;
  // Open chains start where more segments leave a node than arrive (mesh boundary, non-manifold).
  for (std::size_t n = 0; n < g.out.size(); ++n) {
    const int surplus = static_cast<int>(g.out[n].size()) - g.in_degree[n];
    for (int k = 0; k < surplus && take(static_cast<int>(n)) >= 0; ++k) {
      std::vector<Vec3> pts;
      const bool is_closed = walk(static_cast<int>(n), pts);
      (is_closed ? closed : open).push_back(make_contour(std::move(pts), is_closed));
    }
  }
  // The rest are loops.
  for (std::size_t n = 0; n < g.out.size(); ++n) {
    while (take(static_cast<int>(n)) >= 0) {
      std::vector<Vec3> pts;
      const bool is_closed = walk(static_cast<int>(n), pts);
      (is_closed ? closed : open).push_back(make_contour(std::move(pts), is_closed));
    }
  }
  closed.insert(closed.end(), std::make_move_iterator(open.begin()), std::make_move_iterator(open.end()));
  return closed;
}

}  // namespace

std::vector<Contour> slice_mesh(const TriMesh& mesh, const Vec3& plane_point, const Vec3& plane_normal) {
  const Vec3 n = unit_normal(plane_normal);
  if (!plane_point.allFinite()) throw_bad_input("slicing plane point is not finite");
  const VecX s = mesh.V * n - VecX::Constant(mesh.V.rows(), n.dot(plane_point));
  return trace_contours(build_graph(mesh, s));
}

std::vector<std::vector<Contour>> slice_mesh_parallel(const TriMesh& mesh, const Vec3& plane_normal,
                                                      const VecX& offsets) {
  const Vec3 n = unit_normal(plane_normal);
  if (!offsets.allFinite()) throw_bad_input("slicing plane offsets must be finite");
  const VecX s0 = mesh.V * n;
  std::vector<std::vector<Contour>> out(static_cast<std::size_t>(offsets.size()));
  parallel_for(out.size(), [&](std::size_t i) {
    const VecX s = s0.array() - offsets[static_cast<Eigen::Index>(i)];
    out[i] = trace_contours(build_graph(mesh, s));
  });
  return out;
}

double compute_contour_length(const Contour& c) {
  const Eigen::Index n = c.points.rows();
  double len = 0.0;
  for (Eigen::Index i = 0; i + 1 < n; ++i) len += (c.points.row(i + 1) - c.points.row(i)).norm();
  if (c.closed && n > 1) len += (c.points.row(0) - c.points.row(n - 1)).norm();
  return len;
}

double compute_contour_area(const Contour& c, const Vec3& normal) {
  const Eigen::Index n = c.points.rows();
  if (n < 3) return 0.0;
  // Relative to the first point, for accuracy far from the origin.
  const Vec3 o = c.points.row(0).transpose();
  Vec3 area = Vec3::Zero();
  for (Eigen::Index i = 1; i + 1 < n; ++i) {
    area += (c.points.row(i).transpose() - o).cross(c.points.row(i + 1).transpose() - o);
  }
  return 0.5 * area.dot(unit_normal(normal));
}

}  // namespace fascicle
