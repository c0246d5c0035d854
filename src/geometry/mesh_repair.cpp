#include "fascicle/geometry/mesh_repair.hpp"

#include "mesh_validation_internal.hpp"

#include "fascicle/core/error.hpp"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <deque>
#include <sstream>
#include <unordered_map>

namespace fascicle {
namespace {

using mesh_detail::EdgeUse;

std::string join(const std::vector<std::string>& items) {
  std::string out;
  for (std::size_t i = 0; i < items.size(); ++i) out += (i ? ", " : "") + items[i];
  return out;
}

[[noreturn]] void refuse(const std::vector<std::string>& problems, const std::string& suggestion) {
  throw_bad_input("cannot repair the mesh safely: " + join(problems), {.suggestion = suggestion});
}

struct CellKey {
  std::int64_t x, y, z;
  bool operator==(const CellKey&) const = default;
};
struct CellHash {
  std::size_t operator()(const CellKey& k) const {
    std::uint64_t h = static_cast<std::uint64_t>(k.x) * 0x9E3779B97F4A7C15ull;
    h ^= static_cast<std::uint64_t>(k.y) + 0x7F4A7C159E3779B9ull + (h << 6) + (h >> 2);
    h ^= static_cast<std::uint64_t>(k.z) + 0x94D049BB133111EBull + (h << 6) + (h >> 2);
    return static_cast<std::size_t>(h);
  }
};

// Representative vertex per vertex: the lowest-index earlier vertex within `tol`, else itself.
// Exact positions for tol == 0; otherwise a hash grid of cell size tol (27 neighbour cells).
std::vector<int> find_merge_targets(const Points3& V, double tol) {
  const Eigen::Index n = V.rows();
  std::vector<int> target(static_cast<std::size_t>(n));
  std::unordered_map<CellKey, std::vector<int>, CellHash> grid;
  const auto cell_of = [&](const Vec3& p) {
    if (tol == 0.0) {
      std::int64_t b[3];
      for (int j = 0; j < 3; ++j) {
        const double v = p[j] == 0.0 ? 0.0 : p[j];  // -0 == +0
        std::memcpy(&b[j], &v, 8);
      }
      return CellKey{b[0], b[1], b[2]};
    }
    const auto q = [&](double v) {
      return static_cast<std::int64_t>(std::clamp(std::floor(v / tol), -4e18, 4e18));
    };
    return CellKey{q(p.x()), q(p.y()), q(p.z())};
  };
  for (Eigen::Index i = 0; i < n; ++i) {
    const Vec3 p = V.row(i);
    const CellKey c = cell_of(p);
    int best = -1;
    const int reach = tol == 0.0 ? 0 : 1;
    for (int dx = -reach; dx <= reach; ++dx) {
      for (int dy = -reach; dy <= reach; ++dy) {
        for (int dz = -reach; dz <= reach; ++dz) {
          const auto it = grid.find({c.x + dx, c.y + dy, c.z + dz});
          if (it == grid.end()) continue;
          for (const int r : it->second) {
            if ((best < 0 || r < best) && (V.row(r) - V.row(i)).norm() <= tol) best = r;
          }
        }
      }
    }
    if (best < 0) {
      grid[c].push_back(static_cast<int>(i));
      best = static_cast<int>(i);
    }
    target[static_cast<std::size_t>(i)] = best;
  }
  return target;
}

// Flip flag per face that makes every component consistently oriented (BFS over edges with two
// faces); components whose oriented signed volume is negative are flipped as a whole.
std::vector<char> find_orientation_flips(const TriMesh& mesh) {
  const std::size_t nf = static_cast<std::size_t>(mesh.F.rows());
  const std::vector<char> all(nf, 1);
  const std::vector<EdgeUse> uses = mesh_detail::collect_edge_uses(mesh, all);
  // neighbours: (face, same direction) across each two-face edge
  std::vector<std::vector<std::pair<int, bool>>> adj(nf);
  for (std::size_t s = 0; s + 1 < uses.size(); ++s) {
    if (uses[s].a != uses[s + 1].a || uses[s].b != uses[s + 1].b) continue;
    const bool same = uses[s].forward == uses[s + 1].forward;
    adj[static_cast<std::size_t>(uses[s].face)].push_back({uses[s + 1].face, same});
    adj[static_cast<std::size_t>(uses[s + 1].face)].push_back({uses[s].face, same});
  }
  std::vector<char> flip(nf, 0), seen(nf, 0);
  std::vector<int> component(nf, -1);
  int num_components = 0, non_orientable = 0;
  for (std::size_t seed = 0; seed < nf; ++seed) {
    if (seen[seed]) continue;
    const int label = num_components++;
    std::deque<int> queue{static_cast<int>(seed)};
    seen[seed] = 1;
    component[seed] = label;
    bool orientable = true;
    while (!queue.empty()) {
      const int f = queue.front();
      queue.pop_front();
      for (const auto& [g, same] : adj[static_cast<std::size_t>(f)]) {
        // neighbours traversing the shared edge the same way need opposite flips
        const char want = static_cast<char>(flip[static_cast<std::size_t>(f)] ^ (same ? 1 : 0));
        if (!seen[static_cast<std::size_t>(g)]) {
          seen[static_cast<std::size_t>(g)] = 1;
          flip[static_cast<std::size_t>(g)] = want;
          component[static_cast<std::size_t>(g)] = label;
          queue.push_back(g);
        } else if (flip[static_cast<std::size_t>(g)] != want) {
          orientable = false;
        }
      }
    }
    non_orientable += !orientable;
  }
  if (non_orientable > 0) {
    refuse({std::to_string(non_orientable) + " non-orientable components (Moebius-like)"},
           "the surface cannot be oriented; rebuild it in a mesh editor");
  }
  // outward: signed volume per component after the flips
  TriMesh oriented = mesh;
  for (std::size_t f = 0; f < nf; ++f) {
    if (flip[f]) std::swap(oriented.F(static_cast<Eigen::Index>(f), 1),
                           oriented.F(static_cast<Eigen::Index>(f), 2));
  }
  for (int c = 0; c < num_components; ++c) {
    std::vector<char> in_c(nf);
    for (std::size_t f = 0; f < nf; ++f) in_c[f] = component[f] == c;
    if (mesh_detail::calc_signed_volume(oriented, in_c) < 0.0) {
      for (std::size_t f = 0; f < nf; ++f) {
        if (in_c[f]) flip[f] ^= 1;
      }
    }
  }
  return flip;
}

}  // namespace

RepairResult repair_mesh(const TriMesh& mesh, const RepairOptions& options) {
  if (!(options.merge_tolerance >= 0.0) || !std::isfinite(options.merge_tolerance)) {
    throw_usage("the merge tolerance must be finite and >= 0");
  }
  // problems no repair can fix
  const MeshReport before = validate_mesh(mesh, {.check_self_intersections = false});
  std::vector<std::string> fatal;
  if (!before.nonfinite_vertices.empty()) {
    fatal.push_back(std::to_string(before.nonfinite_vertices.size()) +
                    " vertices with NaN/Inf coordinates (first: vertex " +
                    std::to_string(before.nonfinite_vertices[0]) + ")");
  }
  if (!before.out_of_range_faces.empty()) {
    fatal.push_back(std::to_string(before.out_of_range_faces.size()) +
                    " faces with out-of-range vertex indices (first: face " +
                    std::to_string(before.out_of_range_faces[0]) + ")");
  }
  if (!fatal.empty()) refuse(fatal, "the file is corrupt; re-export it from its source");

  RepairResult result;
  // 1. merge duplicate vertices
  const std::vector<int> target = find_merge_targets(mesh.V, options.merge_tolerance);
  long merged = 0;
  for (std::size_t i = 0; i < target.size(); ++i) merged += target[i] != static_cast<int>(i);
  Triangles F = mesh.F;
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) F(f, k) = target[static_cast<std::size_t>(F(f, k))];
  }
  if (merged > 0) {
    std::ostringstream s;
    s << "merged " << merged << " duplicate vertices (tolerance " << options.merge_tolerance
      << " m)";
    result.actions.push_back(s.str());
  }
  // 2. drop degenerate faces
  std::vector<Eigen::Index> keep;
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const int a = F(f, 0), b = F(f, 1), c = F(f, 2);
    const bool repeated = a == b || b == c || c == a;
    if (!repeated && !mesh_detail::has_zero_area(mesh.V.row(a), mesh.V.row(b), mesh.V.row(c))) {
      keep.push_back(f);
    }
  }
  if (keep.empty()) refuse({"no non-degenerate face is left"}, "check the input file");
  if (static_cast<Eigen::Index>(keep.size()) < F.rows()) {
    result.actions.push_back("dropped " + std::to_string(F.rows() - keep.size()) +
                             " degenerate faces (repeated vertex or zero area)");
  }
  // 3. compact: only referenced vertices, in their original order
  std::vector<int> new_index(static_cast<std::size_t>(mesh.V.rows()), -1);
  for (const Eigen::Index f : keep) {
    for (int k = 0; k < 3; ++k) new_index[static_cast<std::size_t>(F(f, k))] = 0;
  }
  int nv = 0;
  for (int& i : new_index) {
    if (i == 0) i = nv++;
  }
  TriMesh& out = result.mesh;
  out.V.resize(nv, 3);
  for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
    if (new_index[static_cast<std::size_t>(i)] >= 0) {
      out.V.row(new_index[static_cast<std::size_t>(i)]) = mesh.V.row(i);
    }
  }
  out.F.resize(static_cast<Eigen::Index>(keep.size()), 3);
  for (std::size_t r = 0; r < keep.size(); ++r) {
    for (int k = 0; k < 3; ++k) {
      out.F(static_cast<Eigen::Index>(r), k) = new_index[static_cast<std::size_t>(F(keep[r], k))];
    }
  }
  const long unreferenced = mesh.V.rows() - merged - nv;
  if (unreferenced > 0) {
    result.actions.push_back("removed " + std::to_string(unreferenced) + " unreferenced vertices");
  }
  // 4. topology that no safe repair can fix
  const MeshReport topo = validate_mesh(out, {.check_self_intersections = false});
  if (!topo.boundary_edges.empty()) {
    fatal.push_back(std::to_string(topo.boundary_edges.size()) +
                    " boundary edges (the surface has holes)");
  }
  if (!topo.nonmanifold_edges.empty()) {
    fatal.push_back(std::to_string(topo.nonmanifold_edges.size()) +
                    " non-manifold edges (shared by 3 or more faces)");
  }
  if (!fatal.empty()) {
    refuse(fatal, "close holes and separate touching parts in a mesh editor (e.g. MeshLab), or "
                  "try a merge tolerance if the parts should be joined");
  }
  // 5. orientation: consistent, then outward
  const std::vector<char> flip = find_orientation_flips(out);
  long flipped = 0;
  for (Eigen::Index f = 0; f < out.F.rows(); ++f) {
    if (flip[static_cast<std::size_t>(f)]) {
      std::swap(out.F(f, 1), out.F(f, 2));
      ++flipped;
    }
  }
  if (flipped > 0) {
    result.actions.push_back("flipped " + std::to_string(flipped) +
                             " faces (consistent, outward orientation)");
  }
  // 6. self-intersections cannot be repaired safely
  result.report = validate_mesh(out);
  if (!result.report.self_intersections.empty()) {
    refuse({std::to_string(result.report.self_intersections.size()) +
            " self-intersecting face pairs (first: faces " +
            std::to_string(result.report.self_intersections[0][0]) + " and " +
            std::to_string(result.report.self_intersections[0][1]) + " of the repaired mesh)"},
           "separate or boolean-union the overlapping parts in a mesh editor");
  }
  return result;
}

void require_closed_manifold(const TriMesh& mesh, const std::string& name,
                             bool check_self_intersections) {
  const MeshReport r = validate_mesh(mesh, {.check_self_intersections = check_self_intersections});
  if (r.is_solid()) return;
  throw_bad_input("the mesh is not a closed, manifold, outward-oriented solid: " +
                      join(r.list_problems()),
                  {.object = name,
                   .suggestion = "run `fascicle mesh info` on it, and `fascicle mesh repair IN "
                                 "OUT` for what can be fixed"});
}

}  // namespace fascicle
