#include "fascicle/geometry/mesh_query.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/geometry/winding_number.hpp"

#include <embree3/rtcore.h>
#include <tbb/task_arena.h>

#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <mutex>
#include <new>
#include <string>

namespace fascicle {

// ---------------------------------------------------------------------------------------------
// Exact kernels
// ---------------------------------------------------------------------------------------------
namespace {

// Closest point of segment [a, b] to p, as the parameter s in [0, 1].
double closest_on_segment(const Vec3& p, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double len2 = ab.squaredNorm();
  if (!(len2 > 0.0)) return 0.0;
  return std::clamp((p - a).dot(ab) / len2, 0.0, 1.0);
}

// A zero-area triangle: the closest point lies on one of its edges.
TrianglePoint closest_on_degenerate(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const std::array<const Vec3*, 3> v{&a, &b, &c};
  TrianglePoint best;
  double best_d2 = std::numeric_limits<double>::infinity();
  for (int k = 0; k < 3; ++k) {
    const int k1 = (k + 1) % 3;
    const double s = closest_on_segment(p, *v[k], *v[k1]);
    const Vec3 q = (1.0 - s) * *v[k] + s * *v[k1];
    const double d2 = (p - q).squaredNorm();
    if (d2 < best_d2) {
      best_d2 = d2;
      best.point = q;
      best.barycentric.setZero();
      best.barycentric[k] = 1.0 - s;
      best.barycentric[k1] = s;
    }
  }
  return best;
}

}  // namespace

namespace {

// closest_point_on_triangle for any Eigen 3-vectors (the BVH passes its packed double corners as
// maps, without copies); the same operations in the same order, hence bit-identical results.
template <class A, class B, class C>
#if defined(__GNUC__)
__attribute__((always_inline))
#endif
inline TrianglePoint closest_on_triangle(const Vec3& p, const A& a, const B& b, const C& c) {
  // Ericson 2005, section 5.1.5: classify p against the Voronoi regions of the vertices, edges and
  // face using dot products of the edge vectors, from cheapest to most expensive test.
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return {a, Vec3(1, 0, 0)};
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return {b, Vec3(0, 1, 0)};
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return {c, Vec3(0, 0, 1)};
  // va + vb + vc = |ab x ac|^2 (Lagrange's identity): zero for a degenerate triangle.
  const double vc = d1 * d4 - d3 * d2;
  const double vb = d5 * d2 - d1 * d6;
  const double va = d3 * d6 - d5 * d4;
  const double area2 = ab.cross(ac).squaredNorm();
  if (!(area2 > 0.0)) return closest_on_degenerate(p, Vec3(a), Vec3(b), Vec3(c));
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {  // edge ab
    const double v = d1 / (d1 - d3);
    return {a + v * ab, Vec3(1.0 - v, v, 0.0)};
  }
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {  // edge ac
    const double w = d2 / (d2 - d6);
    return {a + w * ac, Vec3(1.0 - w, 0.0, w)};
  }
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {  // edge bc
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return {b + w * (c - b), Vec3(0.0, 1.0 - w, w)};
  }
  // Inside the face: barycentrics from the signed sub-areas.
  const double inv = 1.0 / (va + vb + vc);
  const double v = vb * inv, w = vc * inv;
  return {a + v * ab + w * ac, Vec3(1.0 - v - w, v, w)};
}

}  // namespace

TrianglePoint closest_point_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b,
                                        const Vec3& c) {
  return closest_on_triangle(p, a, b, c);
}

namespace {

// A ray whose direction makes an angle below this (radians) with a triangle's plane is treated as
// lying in the plane (intersect_ray_triangle): at 1e-8 the hit's t keeps ~6 correct digits for a
// ray 100 triangle sizes long, below it the watertight test's weights are dominated by rounding.
constexpr double kInPlaneTilt = 1e-8;

// For a ray whose line lies in the plane of triangle abc: whether some t in [t_min, t_max] puts
// origin + t direction on the closed triangle. Computed in the 2D projection that drops the axis
// of the normal's largest component (the in-plane direction keeps a non-zero image there), where
// each edge's half-plane bounds t on one side. Rounding can only decide a touch that is off by a
// few ulps of the coordinates, far inside the padding of any box that holds the triangle, so a
// traversal that skips the triangle's box never misses a graze another traversal reports. A
// degenerate triangle (zero normal) is reported as touched when its corners' span along the ray
// meets the range.
bool coplanar_ray_touches_triangle(const Vec3& origin, const Vec3& direction, const Vec3& a,
                                   const Vec3& b, const Vec3& c, double t_min, double t_max) {
  const Vec3 n = (b - a).cross(c - a);
  int kn = 0;
  n.cwiseAbs().maxCoeff(&kn);
  if (n[kn] == 0.0) {
    // Degenerate: touched when the corners' span along the ray meets [t_min, t_max] (the ray's
    // line already meets the triangle's line or lies along it: u = v = w = 0).
    const double d2 = direction.squaredNorm();
    const double ta = (a - origin).dot(direction) / d2, tb = (b - origin).dot(direction) / d2,
                 tc = (c - origin).dot(direction) / d2;
    return std::max({ta, tb, tc}) >= t_min && std::min({ta, tb, tc}) <= t_max;
  }
  const int kx = (kn + 1) % 3, ky = (kn + 2) % 3;
  const double orientation = n[kn] > 0.0 ? 1.0 : -1.0;  // the projected triangle's winding
  const std::array<const Vec3*, 3> corner{&a, &b, &c};
  double lo = t_min, hi = t_max;
  for (int e = 0; e < 3; ++e) {
    const Vec3& p = *corner[e];
    const Vec3& q = *corner[(e + 1) % 3];
    const double ex = q[kx] - p[kx], ey = q[ky] - p[ky];
    // Inside the edge's half-plane: orientation * cross(q - p, x - p) >= 0, linear in t.
    const double f0 = orientation * (ex * (origin[ky] - p[ky]) - ey * (origin[kx] - p[kx]));
    const double f1 = orientation * (ex * direction[ky] - ey * direction[kx]);
    if (f1 > 0.0) {
      lo = std::max(lo, -f0 / f1);
    } else if (f1 < 0.0) {
      hi = std::min(hi, -f0 / f1);
    } else if (f0 < 0.0) {
      return false;  // parallel to the edge, on its outer side
    }
    if (lo > hi) return false;
  }
  return true;
}

}  // namespace

std::optional<RayHit> intersect_ray_triangle(const Vec3& origin, const Vec3& direction,
                                             const Vec3& a, const Vec3& b, const Vec3& c,
                                             double t_min, double t_max, bool* on_edge) {
  // Woop, Benthin and Wald 2013: translate to the ray origin, permute so the dominant direction
  // axis is z, shear the ray onto +z, and test the 2D edge functions at the origin. Shared edges
  // give identical (negated) edge functions in both triangles, hence no gaps between them.
  if (on_edge != nullptr) *on_edge = false;
  int kz = 0;
  direction.cwiseAbs().maxCoeff(&kz);
  int kx = (kz + 1) % 3, ky = (kx + 1) % 3;
  if (direction[kz] < 0.0) std::swap(kx, ky);  // keep the winding of the permuted frame
  if (direction[kz] == 0.0) return std::nullopt;  // zero direction
  const double sx = direction[kx] / direction[kz];
  const double sy = direction[ky] / direction[kz];
  const double sz = 1.0 / direction[kz];
  const Vec3 A = a - origin, B = b - origin, C = c - origin;
  const double ax = A[kx] - sx * A[kz], ay = A[ky] - sy * A[kz];
  const double bx = B[kx] - sx * B[kz], by = B[ky] - sy * B[kz];
  const double cx = C[kx] - sx * C[kz], cy = C[ky] - sy * C[kz];
  const double u = cx * by - cy * bx;
  const double v = ax * cy - ay * cx;
  const double w = bx * ay - by * ax;
  if ((u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0)) return std::nullopt;
  const double det = u + v + w;
  const Vec3 n = (b - a).cross(c - a);
  if (det == 0.0 || std::abs(n.dot(direction)) <= kInPlaneTilt * n.norm() * direction.norm()) {
    // The ray's line lies in the triangle's plane, within kInPlaneTilt (or the triangle is
    // degenerate). Then u, v and w are rounding noise and their blend of the corners' t would
    // be too (it can lie several circumradii from the triangle along the ray, where no traversal
    // looks): no hit, but a graze when the part of the ray in [t_min, t_max] touches the
    // triangle.
    if (on_edge != nullptr) *on_edge = coplanar_ray_touches_triangle(origin, direction, a, b, c, t_min, t_max);
    return std::nullopt;
  }
  const double t = (u * sz * A[kz] + v * sz * B[kz] + w * sz * C[kz]) / det;
  if (!(t > t_min && t < t_max)) return std::nullopt;
  RayHit hit;
  hit.t = t;
  hit.barycentric = Vec3(u, v, w) / det;
  hit.normal = n.normalized();
  hit.front_facing = n.dot(direction) < 0.0;
  if (on_edge != nullptr) *on_edge = (u == 0.0 || v == 0.0 || w == 0.0) || n.dot(direction) == 0.0;
  return hit;
}

// ---------------------------------------------------------------------------------------------
// The Embree scene
// ---------------------------------------------------------------------------------------------
//
// Embree stores boxes in float. The triangles are an Embree *user geometry* whose bounds callback
// rounds each double box outward to float and pads it by `pad` (2^-18 times the scene scale), so
// every box contains its exact double triangle. Culling decisions made in float (query point and
// ray rounded to float) can therefore only visit too much, never too little, as long as the query
// radius handed to Embree is padded by the float rounding of the query point (closest_with_hint).
// All distances, hits and barycentrics are computed in double by the kernels above.
namespace {
// Upper limit on the steps of the greedy vertex descent (it stops much earlier in practice).
constexpr int kMaxDescentSteps = 256;
// The start-vertex grid has about this many cells per welded vertex (and at most kMaxGridCells).
constexpr double kGridCellsPerVertex = 1.0;
constexpr std::size_t kMaxGridCells = std::size_t{1} << 20;
// Embree SAH costs for the compact tree's builder (a node visit vs one triangle of a leaf; the
// float screen makes a triangle much cheaper than a node).
constexpr float kSahTraversalCost = 1.0f;
constexpr float kSahIntersectionCost = 0.1f;
// Leaves are made as soon as a subtree holds at most this many triangles (fuller leaves: the
// screen always evaluates 16 lanes) and the SAH counts triangles in blocks of this size.
constexpr unsigned kSahMinLeafSize = 16;
constexpr unsigned kSahBlockSize = 16;
}  // namespace

struct MeshQuery::Bvh {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  RTCGeometry geometry = nullptr;  // the clusters (owned by the scene)
  // Rays through the compact tree (trace_compact) instead of the Embree scene: set by the first
  // update_vertices of a compact-tree query of at most kRaysOnCompactClusters clusters, whose
  // Embree scene is then no longer refitted. A static query, or a large one, keeps Embree's
  // traversal (faster on big meshes); the answers are the same either way.
  static constexpr unsigned kRaysOnCompactClusters = 1024;
  bool rays_on_compact = false;
  bool refittable = false;         // two-level scene whose commits refit (see build_scene)
  // A refit's Embree commit waits for the first query that traverses the Embree scene (rays,
  // inside tests; closest points with embree_clusters): the solvers refit surfaces several times
  // between ray queries, and only the last positions need the scene's boxes. The refit computes
  // every box from the current slots (bounds_callback) over the topology of the first build, so
  // a late commit gives the boxes an eager one would. Queries are const and may run on several
  // threads: the first one commits under the mutex.
  mutable std::atomic<bool> commit_pending{false};
  mutable std::mutex commit_mutex;
  // Triangles are stored in "slots" so that triangles near in space are near in memory: in the
  // depth-first leaf order of the compact tree (default), or in Morton order of their centroids
  // (embree_clusters). Clusters are runs of at most kCluster consecutive slots (the compact tree's
  // leaves, or Morton runs of kCluster): one screen (find_candidates) bounds the whole cluster
  // vectorised and the exact test runs only on the few survivors. The Embree scene's primitives
  // are the clusters too (rays, inside tests, and closest points with embree_clusters).
  static constexpr unsigned kCluster = 16;
  // Per cluster, kSoaRows rows of kCluster floats (structure of arrays): the triangle's bounding
  // disc (centre x, y, z relative to the cluster's anchor; unit plane normal x, y, z, zero for
  // slivers; radius rounded up). Float halves the memory and doubles the SIMD lanes; the screens
  // widen their limits by a margin that covers float rounding (kFloatMargin).
  static constexpr std::size_t kSoaRows = 7;
  // Screens accept a triangle when its float bound is within limit + kFloatMargin * (limit +
  // 2 * cluster_extent) (+ the double margin): 2^-18 is 64 times the float unit roundoff, well above
  // the few roundings of the bound (each relative to |p - anchor| <= limit + 2 * cluster_extent for
  // any triangle within limit).
  static constexpr double kFloatMargin = 0x1p-18;
  unsigned num_slots = 0;
  // Cluster c holds slots [cluster_begin[c], cluster_begin[c + 1]) (at most kCluster of them): runs
  // of kCluster Morton-ordered slots for the Embree-scene closest points, the leaves of Embree's SAH
  // builder (compact patches) for the compact tree. Its float data sits at soa[kSoaRows*kCluster*c].
  std::vector<unsigned> cluster_begin;
  unsigned num_clusters() const { return static_cast<unsigned>(cluster_begin.size()) - 1u; }
  unsigned slot_begin(unsigned prim) const { return cluster_begin[prim]; }
  unsigned slot_end(unsigned prim) const { return cluster_begin[prim + 1]; }
  std::vector<double> corners;  // per slot: a, b, c (9 doubles), read by the exact kernels
  std::vector<float> soa;       // per cluster: kSoaRows * kCluster floats
  std::vector<double> anchors;  // per cluster: 3 doubles, the origin of its float centres
  double cluster_extent = 0.0;  // max over triangles of |centre - anchor| + radius
  std::vector<int> triangle_of;  // slot -> row of F
  std::vector<int> slot_of;      // row of F -> slot
  double pad = 0.0;
  double scale = 0.0;         // largest |coordinate| + diagonal of the mesh
  Vec3 middle = Vec3::Zero();  // centre of the mesh's bounding box
  Vec3 box_lo = Vec3::Zero(), box_hi = Vec3::Zero();  // the mesh's bounding box (all vertices)
  // Welded vertices (used mesh vertices, equal positions merged so triangle soups are connected
  // too), numbered by first use in slot order: positions, adjacency and incident slots (CSR).
  std::vector<double> vertex_xyz;        // 3 per welded vertex
  std::vector<int> welded_source;        // welded vertex -> the mesh vertex giving its position
  std::vector<unsigned> adjacent_start;  // welded vertex i -> adjacent[adjacent_start[i] ...)
  std::vector<unsigned> adjacent;
  std::vector<unsigned> ring_start;      // welded vertex i -> ring_slots[ring_start[i] ...)
  std::vector<unsigned> ring_slots;
  std::vector<unsigned> vertex_of_slot;  // slot -> welded vertex of its first corner
  // Start vertices of queries without a hint: a uniform grid over the (enlarged) bounding box
  // whose cells hold a welded vertex near the cell centre (an approximate nearest vertex; the
  // descent corrects it). Points outside the grid use the nearest boundary cell.
  Vec3 grid_lo = Vec3::Zero();
  double grid_inv_cell = 0.0;
  std::array<int, 3> grid_n{1, 1, 1};
  std::vector<unsigned> grid_vertex;  // x fastest
  // The welded vertices' positions when the grid was built: update_vertices keeps the grid while
  // every vertex is within a quarter of a cell of them (grid_is_current).
  std::vector<double> grid_built_xyz;
  unsigned find_start_vertex(const Vec3& p) const {
    std::size_t index = 0, stride = 1;
    for (int k = 0; k < 3; ++k) {
      const double u = (p[k] - grid_lo[k]) * grid_inv_cell;
      const int i = u <= 0.0 ? 0 : u >= grid_n[k] - 1 ? grid_n[k] - 1 : static_cast<int>(u);
      index += stride * static_cast<std::size_t>(i);
      stride *= static_cast<std::size_t>(grid_n[k]);
    }
    return grid_vertex[index];
  }

  // The compact tree (MeshQueryOptions::ClosestPointTree::compact). Topology from Embree's SAH
  // builder (rtcBuildBVH), stored as 4-wide nodes in depth-first preorder (children after their
  // parent, so a reverse sweep refits). Child boxes in float, structure of arrays, rounded outward
  // from the padded double boxes of the leaves, so one 4-lane sequence gives the 4 lower bounds of
  // the distance. A child reference c >= 0 is a node, c < 0 the leaf (cluster) ~c.
  // Leaf children also carry their slab-cylinder (see leaf_bound) in float, relative to the node's
  // double anchor, so the 4 cylinder bounds come from one 4-lane sequence too. Inner children get
  // R = h_hi = +inf, h_lo = -inf (their cylinder bound is 0).
  struct alignas(16) Node4 {
    float lo_x[4], lo_y[4], lo_z[4], hi_x[4], hi_y[4], hi_z[4];
    std::int32_t child[4];
    std::uint32_t valid = 0;   // bit k: child k exists
    std::uint32_t leaves = 0;  // bit k: child k is a leaf
    std::uint32_t unused[2] = {0, 0};
    float cx[4], cy[4], cz[4], nx[4], ny[4], nz[4], r[4], h_lo[4], h_hi[4];
    double anchor[3] = {0.0, 0.0, 0.0};
  };
  static constexpr std::size_t kLeafBoundSize = 9;  // centre (3), unit normal (3), R, h_lo, h_hi
  static constexpr int kMaxTreeDepth = 64;
  bool compact = false;
  std::vector<Node4> nodes;
  std::int32_t root = 0;
  // Parents for the bottom-up start of a traversal (closest_compact): node -> its parent node and
  // leaf (cluster) -> its parent node, -1 for the root. Each welded vertex's home leaf is the leaf
  // of its first incident slot: a query seeded at that vertex screens it first.
  std::vector<std::int32_t> node_parent;
  std::vector<std::int32_t> leaf_parent;
  std::vector<unsigned> home_leaf;
  // Per leaf: a slab-cylinder {x : h_lo <= n.(x - c) <= h_hi, |in-plane offset| <= R} that holds
  // all its triangles (c the anchor, n the area-weighted mean normal, zero if it vanishes).
  std::vector<double> leaf_bound;
  // Per cluster, from fill_slots (refit_compact_tree's input): the corners' box (lo x, y, z, hi x,
  // y, z) and the sum of the triangles' cross products (b - a) x (c - a) in slot order.
  std::vector<double> cluster_box;
  std::vector<double> cluster_normal;
  // Per leaf (cluster) of the compact tree: its padded box rounded outward to float (lo x, y, z,
  // hi x, y, z), the box the Embree scene's bounds callback would compute (it copies it).
  std::vector<float> leaf_box;
  // Max over the nodes' leaf children of |centre - anchor| + R + max(|h_lo|, |h_hi|): any point
  // within `limit` of such a leaf is within limit + node_extent of the anchor (float margins).
  double node_extent = 0.0;
  // Mean over the leaves of the slab-cylinder radius R (the batched queries' seed rule).
  double mean_leaf_radius = 0.0;

  Bvh() = default;
  Bvh(const Bvh&) = delete;
  Bvh& operator=(const Bvh&) = delete;
  ~Bvh() {
    if (scene != nullptr) rtcReleaseScene(scene);
    if (device != nullptr) rtcReleaseDevice(device);
  }
  Vec3 corner(unsigned tri, int k) const {
    const double* c = corners.data() + 9 * static_cast<std::size_t>(tri) + 3 * k;
    return {c[0], c[1], c[2]};
  }
  double vertex_distance2(unsigned v, const Vec3& p) const {
    const double* x = vertex_xyz.data() + 3 * static_cast<std::size_t>(v);
    const double dx = p.x() - x[0], dy = p.y() - x[1], dz = p.z() - x[2];
    return dx * dx + dy * dy + dz * dz;
  }
};

namespace {

// Which triangles of one cluster (structure of arrays, see Bvh::soa) may lie within `limit`
// of p: bit k of the result is set unless triangle k is certainly farther. The lower bound: with h
// the height of p above the triangle's plane (unit normal n, centre c) and l the in-plane offset of
// p from c, every point of the triangle lies within the disc of radius r about c in that plane, so
//   dist^2 >= h^2 + max(0, |l| - r)^2.
// A zero normal (slivers, whose computed normal is unreliable) reduces this to the bounding-sphere
// bound max(0, |p - c| - r)^2. That bound is the distance from p to the disc (a ball for slivers),
// a 1-Lipschitz function of p, c, and (times r) of n, so the float rounding of p - anchor, c, n and
// r and of the evaluation changes it by a few float ulps of |p - anchor| + r; callers widen the
// limit by Bvh::kFloatMargin for that. Written as a plain loop that compilers vectorise; with GCC on
// x86-64 it is compiled twice (AVX2 and baseline SSE2) and the CPU picks the clone at load time
// (neither uses FMA, so both round identically).
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(__SANITIZE_ADDRESS__)
__attribute__((target_clones("avx2", "default")))
#endif
unsigned find_candidates(const float* __restrict block, float px, float py, float pz,
                         float limit2, float* __restrict bounds) {
  constexpr unsigned K = MeshQuery::Bvh::kCluster;
  static_assert(K <= 32, "one bit per triangle of a cluster");
  const float* cx = block;
  const float* cy = block + K;
  const float* cz = block + 2 * K;
  const float* nx = block + 3 * K;
  const float* ny = block + 4 * K;
  const float* nz = block + 5 * K;
  const float* r = block + 6 * K;
  unsigned mask = 0;
  for (unsigned k = 0; k < K; ++k) {
    const float dx = px - cx[k], dy = py - cy[k], dz = pz - cz[k];
    const float h = dx * nx[k] + dy * ny[k] + dz * nz[k];
    const float lx = dx - h * nx[k], ly = dy - h * ny[k], lz = dz - h * nz[k];
    // max(s, 0) written without a comparison (s + |s| = 2s or 0, exactly), which GCC would not
    // if-convert under the default trapping-math rules and so would not vectorise.
    const float s = std::sqrt(lx * lx + ly * ly + lz * lz) - r[k];
    const float e = 0.5f * (s + std::abs(s));
    bounds[k] = h * h + e * e;
    mask |= static_cast<unsigned>(bounds[k] <= limit2) << k;
  }
  return mask;
}

// Which triangles of one cluster the line origin + t * direction may meet: bit k is set unless
// the line misses triangle k's bounding sphere (centre c, radius r + margin), tested as
// |(c - o) x d|^2 > (r + margin)^2 |d|^2 without a square root, in float relative to the cluster's
// anchor. The rounding error of the cross product is a few float ulps of |c - o| |d|; the caller's
// margin is 2^-18 (|o - anchor| + 2 * cluster extent). Vectorised like find_candidates.
// [s_lo, s_hi] (d a unit vector): the part of the line that matters, as distances from o along d
// (-inf, +inf for the whole line). A point of the sphere lies within r of c along d, but the t of
// a hit is not always the line's crossing point: for a ray almost in the triangle's plane the
// watertight test's t is a convex combination of the corners' t_i = (v_i - o)[z] / d[z] (z the
// direction's dominant axis, |d[z]| >= 1/sqrt(3)), which differ from the corners' distances along
// d by up to sqrt(3) times their distance from the line. With |v_i - c| <= r and c within
// reach = r + margin of the line (the first test), |t_i - s| <= |(v_i - c).d| + sqrt(3) (|lat(v_i
// - c)| + reach) <= 2 r + sqrt(3) reach < 4 reach (s = (c - o) . d; Cauchy-Schwarz for the first
// two terms). So spheres with s + 4 reach < s_lo or s - 4 reach > s_hi are left out too: neither a
// hit nor an in-plane graze of their triangle can have t in the range (the margin also covers the
// few float ulps of |c - o| in s).
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(__SANITIZE_ADDRESS__)
__attribute__((target_clones("avx2", "default")))
#endif
unsigned find_ray_candidates(const float* __restrict block, float ox, float oy, float oz, float dx,
                             float dy, float dz, float margin, float s_lo, float s_hi) {
  constexpr unsigned K = MeshQuery::Bvh::kCluster;
  const float* cx = block;
  const float* cy = block + K;
  const float* cz = block + 2 * K;
  const float* r = block + 6 * K;
  const float d2 = dx * dx + dy * dy + dz * dz;
  unsigned mask = 0;
  for (unsigned k = 0; k < K; ++k) {
    const float wx = cx[k] - ox, wy = cy[k] - oy, wz = cz[k] - oz;
    const float x = wy * dz - wz * dy, y = wz * dx - wx * dz, z = wx * dy - wy * dx;
    const float reach = r[k] + margin;
    const float along = wx * dx + wy * dy + wz * dz;
    const float span = 4.0f * reach;
    mask |= static_cast<unsigned>((x * x + y * y + z * z <= reach * reach * d2) & (along + span >= s_lo) &
                                  (along - span <= s_hi))
            << k;
  }
  return mask;
}

}  // namespace

namespace {

// The float nearest x, moved one float toward -inf (round_down) or +inf (round_up) when it lies on
// the wrong side of x. The step is done on the bits (what nextafter does, without the library call
// on the query path): a float's successor toward +inf has the next larger bit pattern when it is
// >= +0 and the next smaller when it is < 0 (-inf steps to -FLT_MAX; -0 cannot occur on that side).
float round_down(double x) {
  float f = static_cast<float>(x);
  if (static_cast<double>(f) > x) {
    const auto bits = std::bit_cast<std::uint32_t>(f);
    f = std::bit_cast<float>(f > 0.0f ? bits - 1u : f == 0.0f ? 0x80000001u : bits + 1u);
  }
  return f;
}

float round_up(double x) {
  float f = static_cast<float>(x);
  if (static_cast<double>(f) < x) {
    const auto bits = std::bit_cast<std::uint32_t>(f);
    f = std::bit_cast<float>(f < 0.0f ? bits - 1u : f == 0.0f ? 0x00000001u : bits + 1u);
  }
  return f;
}

// A non-negative double as float, infinity beyond float range (a plain cast would be undefined).
float to_float_or_infinity(double x) {
  return x > static_cast<double>(std::numeric_limits<float>::max()) ? std::numeric_limits<float>::infinity()
                                                                    : static_cast<float>(x);
}

// Padded, outward-rounded float box of one cluster of double triangles.
void bounds_callback(const RTCBoundsFunctionArguments* args) {
  const auto* bvh = static_cast<const MeshQuery::Bvh*>(args->geometryUserPtr);
  RTCBounds* b = args->bounds_o;
  if (bvh->compact && bvh->leaf_box.size() == 6 * static_cast<std::size_t>(bvh->num_clusters())) {
    // refit_compact_tree computed this very box (same corners, pad and rounding) just before.
    const float* box = bvh->leaf_box.data() + 6 * static_cast<std::size_t>(args->primID);
    b->lower_x = box[0];
    b->lower_y = box[1];
    b->lower_z = box[2];
    b->upper_x = box[3];
    b->upper_y = box[4];
    b->upper_z = box[5];
    return;
  }
  double lo[3], hi[3];
  for (int k = 0; k < 3; ++k) {
    lo[k] = std::numeric_limits<double>::infinity();
    hi[k] = -std::numeric_limits<double>::infinity();
  }
  for (unsigned t = bvh->slot_begin(args->primID); t < bvh->slot_end(args->primID); ++t) {
    const double* c = bvh->corners.data() + 9 * static_cast<std::size_t>(t);
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min({lo[k], c[k], c[3 + k], c[6 + k]});
      hi[k] = std::max({hi[k], c[k], c[3 + k], c[6 + k]});
    }
  }
  for (int k = 0; k < 3; ++k) {
    lo[k] -= bvh->pad;
    hi[k] += bvh->pad;
  }
  b->lower_x = round_down(lo[0]);
  b->lower_y = round_down(lo[1]);
  b->lower_z = round_down(lo[2]);
  b->upper_x = round_up(hi[0]);
  b->upper_y = round_up(hi[1]);
  b->upper_z = round_up(hi[2]);
}

// What a point query carries through Embree (its userPtr).
struct PointQueryState {
  const MeshQuery::Bvh* bvh;
  Vec3 p;
  double best_d2;
  double best_limit;  // sqrt(best_d2) * (1 + 1e-12): what a candidate must not exceed
  int best_slot;
  TrianglePoint best;
  double radius_pad;  // absolute padding for the float rounding of the query point
  double margin;      // absolute margin for the rounding of the lower bounds (calc_lower_bounds)
  int seed_vertex = -1;  // compact tree: the vertex whose distance seeded best_d2 (no slot chosen)
  int start_vertex = -1;  // compact tree: the local-minimum vertex of the descent (its leaf first)
};

// Embree's radius: the exact distance, rounded up and padded so float culling stays conservative.
float padded_radius(double d, double radius_pad) {
  if (!std::isfinite(d)) return std::numeric_limits<float>::infinity();
  return round_up(d * (1.0 + 1e-6) + radius_pad);
}

// Exact test of one slot against the best so far; true if it became the best. (Inlined into the
// screens: a call per candidate costs ~20 % of its work.)
#if defined(__GNUC__)
__attribute__((always_inline))
#endif
inline bool test_slot(PointQueryState* q, unsigned t) {
  const double* x = q->bvh->corners.data() + 9 * static_cast<std::size_t>(t);
  const TrianglePoint tp = closest_on_triangle(q->p, Eigen::Map<const Vec3>(x), Eigen::Map<const Vec3>(x + 3),
                                               Eigen::Map<const Vec3>(x + 6));
  const double d2 = (q->p - tp.point).squaredNorm();
  // Ties go to the lower triangle index, so the answer does not depend on traversal order.
  if (d2 < q->best_d2 ||
      (d2 == q->best_d2 &&
       (q->best_slot < 0 || q->bvh->triangle_of[t] < q->bvh->triangle_of[q->best_slot]))) {
    q->best_d2 = d2;
    q->best_limit = std::sqrt(d2) * (1.0 + 1e-12);
    q->best_slot = static_cast<int>(t);
    q->best = tp;
    return true;
  }
  return false;
}

// Greedy descent over the welded vertices: move to the closest adjacent vertex while it is
// strictly closer to p. Ends at a local minimum of the vertex distance (on a smooth surface usually
// the nearest vertex), whose incident triangles then give a nearly exact upper bound.
unsigned descend(const MeshQuery::Bvh& bvh, const Vec3& p, unsigned v) {
  double best = bvh.vertex_distance2(v, p);
  for (int step = 0; step < kMaxDescentSteps; ++step) {
    unsigned next = v;
    for (unsigned k = bvh.adjacent_start[v]; k < bvh.adjacent_start[v + 1]; ++k) {
      const unsigned u = bvh.adjacent[k];
      const double d2 = bvh.vertex_distance2(u, p);
      if (d2 < best) {
        best = d2;
        next = u;
      }
    }
    if (next == v) break;
    v = next;
  }
  return v;
}

// Seeds the best distance with the exact distances to the triangles around the local-minimum
// vertex reached from v. Any triangle's distance is a valid upper bound, so this never changes
// the answer (test_slot keeps the tie rule); it only lets Embree start with a tight sphere.
void seed_from_vertex(PointQueryState* q, unsigned v) {
  const MeshQuery::Bvh& bvh = *q->bvh;
  v = descend(bvh, q->p, v);
  if (bvh.compact) {
    // The compact traversal visits the nearest leaves first and so tests the triangles around v
    // anyway: seed only the bound. The vertex lies on the surface, so its distance is an upper
    // bound of the exact answer; no triangle is chosen yet. The nearest triangle's *computed*
    // distance may exceed the vertex distance by rounding (p almost straight above v, where the
    // closest point is not returned as the vertex itself), and test_slot only accepts distances
    // below the bound, so the bound is widened by the absolute rounding margin, not only
    // relatively; closest_with_hint still tests v's triangles if nothing was accepted.
    q->start_vertex = static_cast<int>(v);
    const double d = std::sqrt(bvh.vertex_distance2(v, q->p)) + q->margin;
    const double d2 = d * d * (1.0 + 1e-12);
    if (d2 < q->best_d2) {
      q->best_d2 = d2;
      q->best_limit = std::sqrt(d2) * (1.0 + 1e-12);
      q->seed_vertex = static_cast<int>(v);
    }
    return;
  }
  for (unsigned k = bvh.ring_start[v]; k < bvh.ring_start[v + 1]; ++k) test_slot(q, bvh.ring_slots[k]);
}

// Screens one cluster against the best distance so far and tests the survivors exactly; true if
// the best improved.
bool screen_cluster(PointQueryState* q, unsigned cluster) {
  constexpr unsigned K = MeshQuery::Bvh::kCluster;
  const MeshQuery::Bvh& bvh = *q->bvh;
  const unsigned first = bvh.slot_begin(cluster);
  const unsigned count = bvh.slot_end(cluster) - first;
  // A triangle is tested exactly unless its lower bound exceeds the best distance (plus the
  // rounding margin): such a triangle can neither win nor tie.
  const auto limit2 = [&] {
    const double limit = q->best_limit + q->margin +
                         MeshQuery::Bvh::kFloatMargin * (q->best_limit + 2.0 * bvh.cluster_extent);
    return to_float_or_infinity(limit * limit * (1.0 + 1e-6));
  };
  const double* anchor = bvh.anchors.data() + 3 * static_cast<std::size_t>(cluster);
  alignas(32) float bounds[K];
  unsigned mask = find_candidates(bvh.soa.data() + MeshQuery::Bvh::kSoaRows * K * cluster,
                                  static_cast<float>(q->p.x() - anchor[0]),
                                  static_cast<float>(q->p.y() - anchor[1]),
                                  static_cast<float>(q->p.z() - anchor[2]), limit2(), bounds);
  if (count < K) mask &= (1u << count) - 1u;  // clusters may be partly empty
  bool improved = false;
  // Several candidates: test them in increasing order of their bound, dropping those whose bound
  // exceeds the improved limit (any order gives the same answer: ties go by triangle index).
  while (mask != 0) {
    unsigned best_k = static_cast<unsigned>(std::countr_zero(mask));
    if ((mask & (mask - 1u)) != 0) {
      for (unsigned rest = mask & (mask - 1u); rest != 0; rest &= rest - 1u) {
        const auto k = static_cast<unsigned>(std::countr_zero(rest));
        if (bounds[k] < bounds[best_k]) best_k = k;
      }
    }
    mask &= ~(1u << best_k);
    if (test_slot(q, first + best_k)) {
      improved = true;
      const float l2 = limit2();
      for (unsigned rest = mask; rest != 0; rest &= rest - 1u) {
        const auto k = static_cast<unsigned>(std::countr_zero(rest));
        if (!(bounds[k] <= l2)) mask &= ~(1u << k);
      }
    }
  }
  return improved;
}

bool point_query_callback(RTCPointQueryFunctionArguments* args) {
  auto* q = static_cast<PointQueryState*>(args->userPtr);
  const bool improved = screen_cluster(q, args->primID);
  if (improved) args->query->radius = padded_radius(q->best_limit, q->radius_pad);
  return improved;
}

// Whether a leaf of the compact tree may hold a triangle within the best distance (plus the
// margin): false when p is farther from the leaf's slab-cylinder (h = n.(p - c) in [h_lo, h_hi],
// in-plane offset within R; the distance to that convex set is sqrt(dh^2 + dl^2)).
[[maybe_unused]] bool leaf_may_qualify(const PointQueryState* q, unsigned cluster) {
  const double* b = q->bvh->leaf_bound.data() + MeshQuery::Bvh::kLeafBoundSize * cluster;
  const double dx = q->p.x() - b[0], dy = q->p.y() - b[1], dz = q->p.z() - b[2];
  const double h = dx * b[3] + dy * b[4] + dz * b[5];
  const double dh = std::max({b[7] - h, h - b[8], 0.0});
  const double lx = dx - h * b[3], ly = dy - h * b[4], lz = dz - h * b[5];
  const double dl = std::max(std::sqrt(lx * lx + ly * ly + lz * lz) - b[6], 0.0);
  const double limit = q->best_limit + q->margin;
  return dh * dh + dl * dl <= limit * limit;
}

// Squared float radius for the compact traversal: the padded radius squared (the padding covers the
// few float roundings of the box distances, ~1e-7 relative, many times over).
float padded_radius2(double d, double radius_pad) {
  const float r = padded_radius(d, radius_pad);
  return r * r;
}

// Closest point by the compact tree: a stack of (child, squared box distance), children pushed
// farthest first so the nearest is visited next; entries farther than the current best (padded,
// in float) are dropped when popped. Same exactness argument as Embree's culling: every float box
// contains its padded double triangles, and the radius covers the float rounding of p.
//
// The traversal starts bottom-up from `start_leaf` (the home leaf of the seed vertex; -1: from the
// root): that leaf is screened first, which usually gives the exact answer's distance at once,
// then each ancestor in turn, from the leaf's parent up to the root, offers its *other* children
// to the usual top-down stack, which is emptied before the next ancestor. Every leaf of the tree
// is the start leaf or lies under exactly one such offered child, so the same leaves pass the
// culling as from the root, only with a tighter radius from the start.
void closest_compact(PointQueryState* q, std::int32_t start_leaf) {
  const MeshQuery::Bvh& bvh = *q->bvh;
  struct Entry {
    std::int32_t item;
    float d2;
  };
  std::array<Entry, 3 * MeshQuery::Bvh::kMaxTreeDepth + 4> stack;
  std::size_t top = 0;
  float r2 = padded_radius2(q->best_limit, q->radius_pad);
  // The leaf children's slab-cylinder test in float, relative to the node's anchor: accepted
  // within the best distance plus the rounding margin plus kFloatMargin of the magnitudes involved
  // (like the screens: |p - anchor| <= limit + node_extent for any leaf within the limit).
  const auto cylinder_limit2 = [&] {
    const double limit = q->best_limit + q->margin +
                         MeshQuery::Bvh::kFloatMargin * (q->best_limit + 2.0 * bvh.node_extent);
    return to_float_or_infinity(limit * limit * (1.0 + 1e-6));
  };
  float c2 = cylinder_limit2();
  const float px = static_cast<float>(q->p.x()), py = static_cast<float>(q->p.y()),
              pz = static_cast<float>(q->p.z());
#if defined(__SSE2__)
  const __m128 px4 = _mm_set1_ps(px), py4 = _mm_set1_ps(py), pz4 = _mm_set1_ps(pz);
  const __m128 zero = _mm_setzero_ps();
#endif
  const auto screen = [&](unsigned cluster) {
    if (screen_cluster(q, cluster)) {
      r2 = padded_radius2(q->best_limit, q->radius_pad);
      c2 = cylinder_limit2();
    }
  };
  // Pushes the children of node `index` that pass the box and slab-cylinder tests, except the
  // child reference `skip`, farthest first.
  const auto expand = [&](std::int32_t index, std::int32_t skip) {
    const MeshQuery::Bvh::Node4& node = bvh.nodes[static_cast<std::size_t>(index)];
    alignas(16) float d2[4];
#if defined(__SSE2__)
    const __m128 dx = _mm_max_ps(_mm_max_ps(_mm_sub_ps(_mm_loadu_ps(node.lo_x), px4),
                                            _mm_sub_ps(px4, _mm_loadu_ps(node.hi_x))), zero);
    const __m128 dy = _mm_max_ps(_mm_max_ps(_mm_sub_ps(_mm_loadu_ps(node.lo_y), py4),
                                            _mm_sub_ps(py4, _mm_loadu_ps(node.hi_y))), zero);
    const __m128 dz = _mm_max_ps(_mm_max_ps(_mm_sub_ps(_mm_loadu_ps(node.lo_z), pz4),
                                            _mm_sub_ps(pz4, _mm_loadu_ps(node.hi_z))), zero);
    const __m128 dd = _mm_add_ps(_mm_add_ps(_mm_mul_ps(dx, dx), _mm_mul_ps(dy, dy)), _mm_mul_ps(dz, dz));
    _mm_store_ps(d2, dd);
    unsigned mask = static_cast<unsigned>(_mm_movemask_ps(_mm_cmple_ps(dd, _mm_set1_ps(r2)))) & node.valid;
    if ((mask & node.leaves) != 0) {
      // Slab-cylinders of the leaf children (inner children have R = inf and pass).
      const __m128 rx = _mm_set1_ps(static_cast<float>(q->p.x() - node.anchor[0]));
      const __m128 ry = _mm_set1_ps(static_cast<float>(q->p.y() - node.anchor[1]));
      const __m128 rz = _mm_set1_ps(static_cast<float>(q->p.z() - node.anchor[2]));
      const __m128 ux = _mm_sub_ps(rx, _mm_loadu_ps(node.cx));
      const __m128 uy = _mm_sub_ps(ry, _mm_loadu_ps(node.cy));
      const __m128 uz = _mm_sub_ps(rz, _mm_loadu_ps(node.cz));
      const __m128 nx = _mm_loadu_ps(node.nx), ny = _mm_loadu_ps(node.ny), nz = _mm_loadu_ps(node.nz);
      const __m128 h = _mm_add_ps(_mm_add_ps(_mm_mul_ps(ux, nx), _mm_mul_ps(uy, ny)), _mm_mul_ps(uz, nz));
      const __m128 dh = _mm_max_ps(_mm_max_ps(_mm_sub_ps(_mm_loadu_ps(node.h_lo), h),
                                              _mm_sub_ps(h, _mm_loadu_ps(node.h_hi))), zero);
      const __m128 lx = _mm_sub_ps(ux, _mm_mul_ps(h, nx));
      const __m128 ly = _mm_sub_ps(uy, _mm_mul_ps(h, ny));
      const __m128 lz = _mm_sub_ps(uz, _mm_mul_ps(h, nz));
      const __m128 l = _mm_sqrt_ps(_mm_add_ps(_mm_add_ps(_mm_mul_ps(lx, lx), _mm_mul_ps(ly, ly)), _mm_mul_ps(lz, lz)));
      const __m128 dl = _mm_max_ps(_mm_sub_ps(l, _mm_loadu_ps(node.r)), zero);
      const __m128 cyl = _mm_add_ps(_mm_mul_ps(dh, dh), _mm_mul_ps(dl, dl));
      mask &= static_cast<unsigned>(_mm_movemask_ps(_mm_cmple_ps(cyl, _mm_set1_ps(c2))));
    }
#else
    unsigned mask = 0;
    for (unsigned k = 0; k < 4; ++k) {
      const float dx = std::max({node.lo_x[k] - px, px - node.hi_x[k], 0.0f});
      const float dy = std::max({node.lo_y[k] - py, py - node.hi_y[k], 0.0f});
      const float dz = std::max({node.lo_z[k] - pz, pz - node.hi_z[k], 0.0f});
      d2[k] = dx * dx + dy * dy + dz * dz;
      if (d2[k] <= r2 && ((node.leaves & (1u << k)) == 0 || leaf_may_qualify(q, static_cast<unsigned>(~node.child[k])))) {
        mask |= 1u << k;
      }
    }
    mask &= node.valid;
#endif
    // Push the surviving children farthest first (insertion into the stack top, at most 4).
    const std::size_t base = top;
    while (mask != 0) {
      const auto k = static_cast<unsigned>(std::countr_zero(mask));
      mask &= mask - 1u;
      if (node.child[k] == skip) continue;
      const Entry c{node.child[k], d2[k]};
      std::size_t j = top++;
      while (j > base && stack[j - 1].d2 < c.d2) {
        stack[j] = stack[j - 1];
        --j;
      }
      stack[j] = c;
    }
  };
  // Top-down: empties the stack.
  const auto drain = [&] {
    while (top > 0) {
      const Entry e = stack[--top];
      if (!(e.d2 <= r2)) continue;
      if (e.item < 0) {
        // Leaves passed the slab-cylinder test when pushed; the best may have improved since.
        screen(static_cast<unsigned>(~e.item));
      } else {
        expand(e.item, std::numeric_limits<std::int32_t>::min());
      }
    }
  };
  if (start_leaf < 0) {
    stack[top++] = {bvh.root, 0.0f};
    drain();
    return;
  }
  screen(static_cast<unsigned>(start_leaf));
  std::int32_t from = ~start_leaf;
  for (std::int32_t node = bvh.leaf_parent[static_cast<std::size_t>(start_leaf)]; node >= 0;
       node = bvh.node_parent[static_cast<std::size_t>(node)]) {
    expand(node, from);
    drain();
    from = node;
  }
}

// What a ray carries through Embree. The Embree context must be the first member: the intersect
// callback receives a pointer to it and recovers the whole struct.
enum class RayMode { first, all, crossings };
struct RayState {
  RTCIntersectContext context;
  const MeshQuery::Bvh* bvh;
  Vec3 origin, direction;
  double t_min, t_max;
  RayMode mode;
  RayHit first;                  // RayMode::first
  std::vector<RayHit>* all;      // RayMode::all
  int crossings;                 // RayMode::crossings: signed sum
  bool grazed;                   // RayMode::crossings: a hit on an edge/vertex or in-plane
  double margin;                 // absolute margin of the bounding-sphere screen
  std::array<float, 3> unit_direction;  // direction / |direction| in float, for the screen
  // The screen's range along unit_direction: t_min |direction| and t_max |direction| rounded
  // outward (every mode; see find_ray_candidates).
  float s_lo, s_hi;
};

void intersect_slot(const RTCIntersectFunctionNArguments* args, RayState* r, unsigned t) {
  // First-hit mode: hits at the current best t are still tested, so that equal t goes to the
  // lower triangle index whatever the traversal order (a refitted and a fresh tree agree).
  const double t_max = r->mode == RayMode::first && r->first.triangle >= 0
                           ? std::min(r->t_max, std::nextafter(r->first.t, std::numeric_limits<double>::infinity()))
                           : r->t_max;
  bool on_edge = false;
  std::optional<RayHit> hit =
      intersect_ray_triangle(r->origin, r->direction, r->bvh->corner(t, 0), r->bvh->corner(t, 1),
                             r->bvh->corner(t, 2), r->t_min, t_max, &on_edge);
  if (r->mode == RayMode::crossings) {
    if (on_edge) r->grazed = true;
    // Leaving through an outward face (+1) minus entering (-1): the winding number at the origin.
    if (hit) r->crossings += hit->front_facing ? -1 : 1;
    return;
  }
  if (!hit) return;
  hit->triangle = r->bvh->triangle_of[t];
  if (r->mode == RayMode::all) {
    r->all->push_back(*hit);
    return;
  }
  if (r->first.triangle >= 0 && hit->t == r->first.t && hit->triangle > r->first.triangle) return;
  r->first = *hit;
  if (args == nullptr) return;  // the compact tree's traversal (trace_compact) prunes by r->first
  // Shrink Embree's far distance (rounded up, padded) so farther boxes are culled.
  auto* rayhit = reinterpret_cast<RTCRayHit*>(args->rayhit);
  const float tf = round_up(hit->t * (1.0 + 1e-6) + r->bvh->pad / r->direction.norm());
  rayhit->ray.tfar = std::min(rayhit->ray.tfar, tf);
  rayhit->hit.geomID = args->geomID;
  rayhit->hit.primID = args->primID;
}

// The exact tests of one cluster's triangles against ray r (Embree's callback, args set; or the
// compact tree's traversal, args null).
void visit_ray_cluster(RayState* r, unsigned cluster, const RTCIntersectFunctionNArguments* args) {
  constexpr unsigned K = MeshQuery::Bvh::kCluster;
  const unsigned first = r->bvh->slot_begin(cluster);
  const unsigned count = r->bvh->slot_end(cluster) - first;
  // Exact (double) tests only for the triangles whose bounding sphere the ray's range meets: the others
  // can neither be hit nor grazed.
  const double* anchor = r->bvh->anchors.data() + 3 * static_cast<std::size_t>(cluster);
  const Vec3 oa(r->origin.x() - anchor[0], r->origin.y() - anchor[1], r->origin.z() - anchor[2]);
  const double margin =
      r->margin + MeshQuery::Bvh::kFloatMargin * (oa.norm() + 2.0 * r->bvh->cluster_extent);
  unsigned mask = find_ray_candidates(
      r->bvh->soa.data() + MeshQuery::Bvh::kSoaRows * K * cluster, static_cast<float>(oa.x()),
      static_cast<float>(oa.y()), static_cast<float>(oa.z()), r->unit_direction[0],
      r->unit_direction[1], r->unit_direction[2], to_float_or_infinity(margin), r->s_lo, r->s_hi);
  if (count < K) mask &= (1u << count) - 1u;
  while (mask != 0) {
    const auto k = static_cast<unsigned>(std::countr_zero(mask));
    mask &= mask - 1u;
    intersect_slot(args, r, first + k);
  }
}

void intersect_callback(const RTCIntersectFunctionNArguments* args) {
  if (args->N != 1 || args->valid[0] == 0) return;
  visit_ray_cluster(reinterpret_cast<RayState*>(args->context), args->primID, args);
}

// One axis of find_ray_children for the four children: narrows each lane's parameter interval
// [en, le] to the slab [lo - pad, hi + pad] (or clears `inside` when the direction's component is 0
// and the origin lies outside the slab). Written as selects on plain arrays so that GCC vectorises
// it; each lane runs the operations of the former one-child test in the same order (std::max(x, y)
// is x < y ? y : x, std::min(x, y) is y < x ? y : x).
inline void narrow_ray_children(const float* __restrict lo, const float* __restrict hi, double o, double inv,
                                bool zero, double pad, double* __restrict en, double* __restrict le,
                                double* __restrict inside) {
  if (zero) {
    for (int k = 0; k < 4; ++k) {
      const double l = static_cast<double>(lo[k]) - pad, h = static_cast<double>(hi[k]) + pad;
      inside[k] = (o < l || o > h) ? 0.0 : inside[k];
    }
    return;
  }
  for (int k = 0; k < 4; ++k) {
    const double l = static_cast<double>(lo[k]) - pad, h = static_cast<double>(hi[k]) + pad;
    const double t0 = (l - o) * inv, t1 = (h - o) * inv;
    const bool swap = t0 > t1;
    const double near = swap ? t1 : t0, far = swap ? t0 : t1;
    const double widen = 1e-9 * (std::abs(near) + std::abs(far));
    const double enter = near - widen, leave = far + widen;
    en[k] = en[k] < enter ? enter : en[k];
    le[k] = leave < le[k] ? leave : le[k];
  }
}

// Which of a node's four children the ray's segment [enter, leave] meets (bit k: child k), for
// trace_compact: child k's box [lo - pad, hi + pad], axis by axis (a direction component of 0
// needs the origin within the slab; otherwise the slab's parameter interval, widened by 1e-9 of
// its magnitudes, must overlap). Every lane runs the operations of the former one-child test in
// the same order, only without its early exits: enter only grows and leave only shrinks, so the
// answer is the same, and the four lanes run at once (2 or 4 doubles per SSE2/AVX2 register).
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(__SANITIZE_ADDRESS__)
__attribute__((target_clones("avx2", "default")))
#endif
unsigned find_ray_children(const MeshQuery::Bvh::Node4& node, const double* __restrict o,
                           const double* __restrict inv, const bool* __restrict zero, double pad,
                           double enter, double leave) {
  double en[4] = {enter, enter, enter, enter}, le[4] = {leave, leave, leave, leave};
  double inside[4] = {1.0, 1.0, 1.0, 1.0};
  narrow_ray_children(node.lo_x, node.hi_x, o[0], inv[0], zero[0], pad, en, le, inside);
  narrow_ray_children(node.lo_y, node.hi_y, o[1], inv[1], zero[1], pad, en, le, inside);
  narrow_ray_children(node.lo_z, node.hi_z, o[2], inv[2], zero[2], pad, en, le, inside);
  unsigned mask = 0;
  for (unsigned k = 0; k < 4; ++k) mask |= static_cast<unsigned>((inside[k] != 0.0) & (en[k] <= le[k])) << k;
  return mask & node.valid;
}

// A ray through the compact tree (MeshQueryOptions::ClosestPointTree::compact), without Embree:
// depth-first over the 4-wide nodes, entering every child whose box, widened by 1e-7 of the
// mesh's scale, the ray's segment [t_min, t_max] meets (a slab test in double, four children at
// once: find_ray_children), and testing the clusters reached as Embree's callback does. Every
// cluster holding a triangle that the ray hits or grazes is reached (its box holds the triangle;
// the widening covers the slab test's rounding many times over), and a cluster the ray misses adds
// neither a hit nor a graze, so the crossings, the hits and the first hit (ties to the lower
// triangle index) are those of the Embree scene.
// Used for small deforming surfaces (Bvh::rays_on_compact), whose refits then need no Embree work.
void trace_compact(const MeshQuery::Bvh& bvh, RayState& r) {
  const double pad = 1e-7 * bvh.scale;
  double o[3], inv[3];
  bool zero[3];
  for (int k = 0; k < 3; ++k) {
    o[k] = r.origin[k];
    zero[k] = r.direction[k] == 0.0;
    inv[k] = zero[k] ? 0.0 : 1.0 / r.direction[k];
  }
  std::int32_t stack[4 * MeshQuery::Bvh::kMaxTreeDepth + 4];
  int top = 0;
  stack[top++] = bvh.root;
  while (top > 0) {
    const std::int32_t item = stack[--top];
    if (item < 0) {
      visit_ray_cluster(&r, static_cast<unsigned>(~item), nullptr);
      continue;
    }
    const MeshQuery::Bvh::Node4& node = bvh.nodes[static_cast<std::size_t>(item)];
    // The segment: [t_min, t_max], in first-hit mode cut at the best hit so far; padded.
    double enter = r.t_min, leave = r.t_max;
    if (r.mode == RayMode::first && r.first.triangle >= 0) leave = std::min(leave, r.first.t);
    const double slack = 1e-9 * (std::abs(enter) + (std::isfinite(leave) ? std::abs(leave) : 0.0)) + 1e-300;
    enter -= slack;
    leave += slack;
    const unsigned mask = find_ray_children(node, o, inv, zero, pad, enter, leave);
    for (unsigned k = 0; k < 4; ++k)
      if ((mask & (1u << k)) != 0) stack[top++] = node.child[k];
  }
}

void occluded_callback(const RTCOccludedFunctionNArguments* /*args*/) {}

// Commits a refit left pending by update_vertices (see Bvh::commit_pending); a no-op otherwise.
void commit_pending_refit(const MeshQuery::Bvh& bvh) {
  if (!bvh.commit_pending.load(std::memory_order_acquire)) return;
  const std::lock_guard lock(bvh.commit_mutex);
  if (!bvh.commit_pending.load(std::memory_order_relaxed)) return;
  // Isolated: while this thread waits for the commit's own tasks it must not pick up another
  // query task that would wait on commit_mutex, which this thread holds.
  tbb::this_task_arena::isolate([&] {
    rtcCommitGeometry(bvh.geometry);
    rtcCommitScene(bvh.scene);
  });
  if (const RTCError err = rtcGetDeviceError(bvh.device); err != RTC_ERROR_NONE) {
    throw_internal("Embree failed to refit the BVH (error code " +
                   std::to_string(static_cast<int>(err)) + ")");
  }
  bvh.commit_pending.store(false, std::memory_order_release);
}

// Runs one ray through the scene with the given mode.
void trace(const MeshQuery::Bvh& bvh, RayState& state) {
  if (bvh.rays_on_compact) {
    trace_compact(bvh, state);
    return;
  }
  commit_pending_refit(bvh);
  rtcInitIntersectContext(&state.context);
  RTCRayHit rh;
  rh.ray.org_x = static_cast<float>(state.origin.x());
  rh.ray.org_y = static_cast<float>(state.origin.y());
  rh.ray.org_z = static_cast<float>(state.origin.z());
  rh.ray.dir_x = static_cast<float>(state.direction.x());
  rh.ray.dir_y = static_cast<float>(state.direction.y());
  rh.ray.dir_z = static_cast<float>(state.direction.z());
  // The float ray deviates from the double one by rounding: widen its interval a little.
  rh.ray.tnear = std::max(0.0f, round_down(state.t_min * (1.0 - 1e-6) - 1e-6));
  rh.ray.tfar = std::isfinite(state.t_max) ? round_up(state.t_max * (1.0 + 1e-6) + 1e-6)
                                           : std::numeric_limits<float>::infinity();
  rh.ray.time = 0.0f;
  rh.ray.mask = 0xFFFFFFFFu;
  rh.ray.id = 0;
  rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(bvh.scene, &state.context, &rh);
}

RayState make_ray(const MeshQuery::Bvh& bvh, const Vec3& origin, const Vec3& direction,
                  double t_min, double t_max, RayMode mode) {
  if (!origin.allFinite() || !direction.allFinite() || direction.squaredNorm() == 0.0) {
    throw_bad_input("ray cast needs a finite origin and a finite, non-zero direction",
                    {.suggestion = "check the ray's origin and direction"});
  }
  // Embree's traversal starts at t = 0 (tnear >= 0) and the other paths honour the range as
  // given, so a negative t_min would make them disagree; NaN would make every test false.
  if (!(t_min >= 0.0 && t_min <= t_max)) {
    throw_bad_input("ray cast needs a range 0 <= t_min <= t_max (got t_min = " + std::to_string(t_min) +
                        ", t_max = " + std::to_string(t_max) + ")",
                    {.suggestion = "cast from the origin (t_min = 0) or move the origin back along the ray"});
  }
  RayState s{};
  s.bvh = &bvh;
  s.origin = origin;
  s.direction = direction;
  s.t_min = t_min;
  s.t_max = t_max;
  s.mode = mode;
  s.all = nullptr;
  s.crossings = 0;
  s.grazed = false;
  s.margin = 1e-10 * ((origin - bvh.middle).norm() + bvh.scale);
  const double length = direction.norm();
  const Vec3 unit = direction / length;
  s.unit_direction = {static_cast<float>(unit.x()), static_cast<float>(unit.y()), static_cast<float>(unit.z())};
  constexpr float kInf = std::numeric_limits<float>::infinity();
  s.s_lo = -kInf;
  s.s_hi = kInf;
  // Every mode, crossings included: a triangle is hit or grazed only by the ray's part in
  // [t_min, t_max] (intersect_ray_triangle), so a sphere wholly outside it can be screened out.
  // (Beyond float range the bound stays infinite.)
  if (std::abs(t_min * length) < 1e30) s.s_lo = round_down(t_min * length);
  if (std::abs(t_max * length) < 1e30) s.s_hi = round_up(t_max * length);
  return s;
}

// Five well-spread unit directions with no zero components (axis-aligned meshes have edges along
// the axes), for the inside vote. Roughly the vertices of a trigonal bipyramid, tilted.
const std::array<Vec3, 5> kVoteDirections = {
    Vec3(0.2672612419124244, 0.5345224838248488, 0.8017837257372732),
    Vec3(0.7071067811865476, -0.5773502691896258, -0.4082482904638630).normalized(),
    Vec3(-0.8164965809277260, -0.3015113445777636, 0.4923659639173310).normalized(),
    Vec3(-0.3244428422615251, 0.8111071056538127, -0.4866642633922876).normalized(),
    Vec3(0.1740776559556978, -0.1523179489612356, -0.9728857850229200).normalized(),
};

// Morton code of a point quantised to 10 bits per axis inside [lo, hi].
std::uint32_t morton_code(const Vec3& p, const Vec3& lo, const Vec3& inv_extent) {
  auto spread = [](std::uint32_t x) {  // insert two zero bits between the 10 low bits
    x &= 0x3FFu;
    x = (x | (x << 16)) & 0x030000FFu;
    x = (x | (x << 8)) & 0x0300F00Fu;
    x = (x | (x << 4)) & 0x030C30C3u;
    x = (x | (x << 2)) & 0x09249249u;
    return x;
  };
  std::uint32_t code = 0;
  for (int k = 0; k < 3; ++k) {
    const double u = std::clamp((p[k] - lo[k]) * inv_extent[k], 0.0, 1.0);
    code |= spread(static_cast<std::uint32_t>(u * 1023.0)) << k;
  }
  return code;
}

constexpr std::size_t kBlock = 256;  // points per coherent block in the batched queries
// Batched closest points on the compact tree start from the previous answer's triangle (its exact
// distance as the bound, instead of the vertex descent) when the step from the previous point is at
// most this fraction of the previous distance: the bound is then within 35 % of the answer. Measured
// (callgrind, docs/geometry-queries.md pass 6): 0.5 saves a little more on dense near-surface
// batches but costs sparse far batches 4.6 %; 0.35 costs them 2 %.
constexpr double kExactHintStep = 0.35;
// ... and only near the surface: the previous distance at most this many mean leaf radii. Farther
// points take the descent: there the exact seed cut instructions by 5 % but not CPU time (pass 6).
constexpr double kExactHintReach = 2.0;

// Points in Morton order, so that consecutive queries are near each other.
std::vector<Eigen::Index> spatial_order(const Points3& P) {
  const auto n = static_cast<std::size_t>(P.rows());
  std::vector<Eigen::Index> order(n);
  if (n == 0) return order;
  const Vec3 lo = P.colwise().minCoeff().transpose();
  const Vec3 hi = P.colwise().maxCoeff().transpose();
  Vec3 inv;
  for (int k = 0; k < 3; ++k) inv[k] = hi[k] > lo[k] ? 1.0 / (hi[k] - lo[k]) : 0.0;
  std::vector<std::uint32_t> code(n), code_next(n);
  std::vector<Eigen::Index> order_next(n);
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const Vec3 p = P.row(i).transpose();
    code[static_cast<std::size_t>(i)] = p.allFinite() ? morton_code(p, lo, inv) : 0u;
    order[static_cast<std::size_t>(i)] = i;
  }
  // Stable least-significant-digit radix sort of the 30-bit codes, 10 bits per pass, starting from
  // the index order: the result is sorted by (code, index), as a comparison sort of the pairs
  // would give, in linear time.
  constexpr unsigned kBits = 10, kBuckets = 1u << kBits;
  std::array<std::size_t, kBuckets> start;
  for (unsigned shift = 0; shift < 30; shift += kBits) {
    start.fill(0);
    for (std::size_t i = 0; i < n; ++i) ++start[(code[i] >> shift) & (kBuckets - 1)];
    std::size_t sum = 0;
    for (std::size_t& s : start) {
      const std::size_t c = s;
      s = sum;
      sum += c;
    }
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t to = start[(code[i] >> shift) & (kBuckets - 1)]++;
      code_next[to] = code[i];
      order_next[to] = order[i];
    }
    code.swap(code_next);
    order.swap(order_next);
  }
  return order;
}

}  // namespace

namespace {

// Fills the per-slot data from the mesh's current vertices (slot order already fixed): corners,
// the clusters' bounding discs, the bounding box, scale, pad and middle. Used by the constructor and
// by update_vertices (same slots, new positions).
void fill_slots(MeshQuery::Bvh& bvh, const TriMesh& mesh) {
  constexpr unsigned K = MeshQuery::Bvh::kCluster;
  const std::size_t num_clusters = bvh.num_clusters();
  bvh.corners.resize(9 * static_cast<std::size_t>(bvh.num_slots));
  // Lanes past a cluster's triangles stay zero from the first fill (refits write the same lanes):
  // cleared on a new layout only.
  if (bvh.soa.size() != MeshQuery::Bvh::kSoaRows * K * num_clusters)
    bvh.soa.assign(MeshQuery::Bvh::kSoaRows * K * num_clusters, 0.0f);
  bvh.cluster_box.resize(6 * num_clusters);
  bvh.cluster_normal.resize(3 * num_clusters);
  bvh.anchors.resize(3 * num_clusters);
  // The largest over the clusters of an upper bound of max(|centre - anchor| + radius) (max |rel|
  // + max radius).
  double max_extent = 0.0;
  // Serial on purpose: a parallel_for here made the build ~20 % dearer in CPU time (TBB's
  // workers spinning), and callers refit several meshes in parallel anyway. The square roots
  // and divisions of a cluster's triangles run in a loop of their own, so they overlap instead of
  // waiting on each other (the same operations on the same values as one loop).
  for (std::size_t cluster = 0; cluster < num_clusters; ++cluster) {
    const std::size_t first = bvh.cluster_begin[cluster];
    const std::size_t count = bvh.cluster_begin[cluster + 1] - first;
    std::array<Vec3, K> centres;
    Vec3 anchor = Vec3::Zero();
    for (std::size_t k = 0; k < count; ++k) {
      const std::size_t slot = first + k;
      const Eigen::Index f = bvh.triangle_of[slot];
      double* c = bvh.corners.data() + 9 * slot;
      for (int v = 0; v < 3; ++v) {
        const Eigen::Index row = mesh.F(f, v);
        for (int j = 0; j < 3; ++j) c[3 * v + j] = mesh.V(row, j);
      }
      centres[k] = Vec3((c[0] + c[3] + c[6]) / 3.0, (c[1] + c[4] + c[7]) / 3.0, (c[2] + c[5] + c[8]) / 3.0);
      anchor += centres[k];
    }
    anchor /= static_cast<double>(count);
    for (int j = 0; j < 3; ++j) bvh.anchors[3 * cluster + static_cast<std::size_t>(j)] = anchor[j];
    float* block = bvh.soa.data() + MeshQuery::Bvh::kSoaRows * K * cluster;
    // The cluster's corner box (refit_compact_tree and Embree's bounds callback reuse it).
    double lo[3], hi[3];
    for (int j = 0; j < 3; ++j) {
      lo[j] = std::numeric_limits<double>::infinity();
      hi[j] = -std::numeric_limits<double>::infinity();
    }
    // per triangle: the squared radius of its disc about its centre, its normal n, |n|^2 and
    // whether the normal is trusted
    std::array<double, K> r2, n_len2, trusted;
    std::array<Vec3, K> normal;
    for (std::size_t k = 0; k < count; ++k) {
      const auto slot = static_cast<unsigned>(first + k);
      const Vec3 a = bvh.corner(slot, 0), b = bvh.corner(slot, 1), cc = bvh.corner(slot, 2);
      for (int j = 0; j < 3; ++j) {
        lo[j] = std::min(lo[j], std::min(a[j], std::min(b[j], cc[j])));
        hi[j] = std::max(hi[j], std::max(a[j], std::max(b[j], cc[j])));
      }
      const Vec3& centre = centres[k];
      r2[k] = std::max({(a - centre).squaredNorm(), (b - centre).squaredNorm(), (cc - centre).squaredNorm()});
      // The computed normal's direction error is about 1e-16 / sin(angle at a): trust it only when
      // that angle is not tiny (error < 1e-12), otherwise fall back to the sphere bound (n = 0).
      const Vec3 ab = b - a, ac = cc - a;
      normal[k] = ab.cross(ac);
      n_len2[k] = normal[k].squaredNorm();
      trusted[k] = n_len2[k] > 1e-8 * ab.squaredNorm() * ac.squaredNorm() ? 1.0 : 0.0;
    }
    std::array<double, K> r, n_len;
    for (std::size_t k = 0; k < count; ++k) {
      r[k] = std::sqrt(r2[k]);
      n_len[k] = std::sqrt(n_len2[k]);
    }
    double max_rel2 = 0.0, max_r = 0.0;
    Vec3 normal_sum = Vec3::Zero();
    for (std::size_t k = 0; k < count; ++k) {
      normal_sum += normal[k];
      const Vec3 unit = trusted[k] != 0.0 ? Vec3(normal[k] / n_len[k]) : Vec3::Zero();
      const Vec3 rel = centres[k] - anchor;
      block[0 * K + k] = static_cast<float>(rel.x());
      block[1 * K + k] = static_cast<float>(rel.y());
      block[2 * K + k] = static_cast<float>(rel.z());
      block[3 * K + k] = static_cast<float>(unit.x());
      block[4 * K + k] = static_cast<float>(unit.y());
      block[5 * K + k] = static_cast<float>(unit.z());
      block[6 * K + k] = round_up(r[k]);  // rounded up: the disc still holds the triangle
      max_rel2 = std::max(max_rel2, rel.squaredNorm());
      max_r = std::max(max_r, r[k]);
    }
    max_extent = std::max(max_extent, std::sqrt(max_rel2) + max_r);
    for (int j = 0; j < 3; ++j) {
      bvh.cluster_box[6 * cluster + static_cast<std::size_t>(j)] = lo[j];
      bvh.cluster_box[6 * cluster + 3 + static_cast<std::size_t>(j)] = hi[j];
      bvh.cluster_normal[3 * cluster + static_cast<std::size_t>(j)] = normal_sum[j];
    }
  }
  bvh.cluster_extent = max_extent;
  bvh.box_lo = mesh.V.colwise().minCoeff().transpose();
  bvh.box_hi = mesh.V.colwise().maxCoeff().transpose();
  const double scale = std::max(bvh.box_lo.cwiseAbs().maxCoeff(), bvh.box_hi.cwiseAbs().maxCoeff()) +
                       (bvh.box_hi - bvh.box_lo).norm();
  bvh.pad = std::ldexp(std::max(scale, std::numeric_limits<double>::min()), -18);
  bvh.scale = scale;
  bvh.middle = 0.5 * (bvh.box_lo + bvh.box_hi);
}

// Builds the start-vertex grid from the welded vertices' current positions (fill_slots first).
void build_start_grid(MeshQuery::Bvh& bvh) {
  const Vec3 lo = bvh.box_lo, hi = bvh.box_hi;
  const double scale = bvh.scale;
  const auto num_welded = static_cast<unsigned>(bvh.vertex_xyz.size() / 3);
  bvh.grid_built_xyz = bvh.vertex_xyz;
  // Start-vertex grid: cubic cells over the bounding box enlarged by 10% of its diagonal. Each
  // cell holding vertices keeps the one nearest its centre; two raster sweeps (forward with the
  // -x, -y, -z neighbours, backward with +x, +y, +z) then pass to every cell the nearest-to-centre
  // of its neighbours' vertices (an approximate nearest-vertex map; any vertex is a valid start).
  const Vec3 margin = Vec3::Constant(0.1 * (hi - lo).norm() + std::ldexp(scale, -30));
  const Vec3 extent = (hi - lo) + 2.0 * margin;
  const double cells_wanted = std::min(static_cast<double>(kMaxGridCells),
                                       std::max(1.0, kGridCellsPerVertex * num_welded));
  // A mesh collapsed to one point has no extent: one cell of any positive size then serves.
  const double cell_fit = std::cbrt(extent.prod() / cells_wanted);
  const double cell = (cell_fit > 0.0 && std::isfinite(cell_fit)) ? cell_fit : 1.0;
  bvh.grid_lo = lo - margin;
  bvh.grid_inv_cell = 1.0 / cell;
  std::size_t cells = 1;
  for (int k = 0; k < 3; ++k) {
    bvh.grid_n[k] = std::clamp(static_cast<int>(std::ceil(extent[k] / cell)), 1, 1 << 10);
    cells *= static_cast<std::size_t>(bvh.grid_n[k]);
  }
  constexpr unsigned kNone = std::numeric_limits<unsigned>::max();
  bvh.grid_vertex.assign(cells, kNone);
  // The distance of each cell's current vertex to the cell centre (the same value offer would
  // recompute, so the choices are unchanged).
  std::vector<double> grid_d2(cells, std::numeric_limits<double>::infinity());
  const int nx = bvh.grid_n[0], ny = bvh.grid_n[1], nz = bvh.grid_n[2];
  // Cell centres per axis (centre of cell (i, j, k) = (cx[i], cy[j], cz[k])).
  std::vector<double> cx(static_cast<std::size_t>(nx)), cy(static_cast<std::size_t>(ny)), cz(static_cast<std::size_t>(nz));
  for (int i = 0; i < nx; ++i) cx[static_cast<std::size_t>(i)] = bvh.grid_lo.x() + (i + 0.5) * cell;
  for (int j = 0; j < ny; ++j) cy[static_cast<std::size_t>(j)] = bvh.grid_lo.y() + (j + 0.5) * cell;
  for (int k = 0; k < nz; ++k) cz[static_cast<std::size_t>(k)] = bvh.grid_lo.z() + (k + 0.5) * cell;
  unsigned* const grid = bvh.grid_vertex.data();
  double* const d2_of = grid_d2.data();
  // Offers vertex v to the cell with index `c` and centre `centre`: kept if nearer to the centre
  // than the current one.
  const auto offer = [&](std::size_t c, const Vec3& centre, unsigned v) {
    if (v == kNone) return;
    if (v == grid[c]) return;  // the sweeps pass most cells their own vertex again: no change
    const double d2 = bvh.vertex_distance2(v, centre);
    if (grid[c] == kNone || d2 < d2_of[c]) {
      grid[c] = v;
      d2_of[c] = d2;
    }
  };
  const std::size_t sx = 1, sy = static_cast<std::size_t>(nx), sz = static_cast<std::size_t>(nx) * static_cast<std::size_t>(ny);
  for (unsigned v = 0; v < num_welded; ++v) {
    const Vec3 x(bvh.vertex_xyz[3 * v], bvh.vertex_xyz[3 * v + 1], bvh.vertex_xyz[3 * v + 2]);
    int ijk[3];
    for (int k = 0; k < 3; ++k) {
      ijk[k] = std::clamp(static_cast<int>((x[k] - bvh.grid_lo[k]) / cell), 0, bvh.grid_n[k] - 1);
    }
    const auto i = static_cast<std::size_t>(ijk[0]), j = static_cast<std::size_t>(ijk[1]), k = static_cast<std::size_t>(ijk[2]);
    offer(i * sx + j * sy + k * sz, Vec3(cx[i], cy[j], cz[k]), v);
  }
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      const std::size_t row = static_cast<std::size_t>(j) * sy + static_cast<std::size_t>(k) * sz;
      for (int i = 0; i < nx; ++i) {
        const std::size_t c = row + static_cast<std::size_t>(i);
        const Vec3 centre(cx[static_cast<std::size_t>(i)], cy[static_cast<std::size_t>(j)], cz[static_cast<std::size_t>(k)]);
        if (i > 0) offer(c, centre, grid[c - sx]);
        if (j > 0) offer(c, centre, grid[c - sy]);
        if (k > 0) offer(c, centre, grid[c - sz]);
      }
    }
  }
  for (int k = nz - 1; k >= 0; --k) {
    for (int j = ny - 1; j >= 0; --j) {
      const std::size_t row = static_cast<std::size_t>(j) * sy + static_cast<std::size_t>(k) * sz;
      for (int i = nx - 1; i >= 0; --i) {
        const std::size_t c = row + static_cast<std::size_t>(i);
        const Vec3 centre(cx[static_cast<std::size_t>(i)], cy[static_cast<std::size_t>(j)], cz[static_cast<std::size_t>(k)]);
        if (i + 1 < nx) offer(c, centre, grid[c + sx]);
        if (j + 1 < ny) offer(c, centre, grid[c + sy]);
        if (k + 1 < nz) offer(c, centre, grid[c + sz]);
      }
    }
  }
}

// Whether the start-vertex grid may be kept after a refit: every welded vertex is within a
// quarter of a cell of where it was when the grid was built. Any vertex is a valid start (the
// descent and the exact traversal find the same closest point from every start, ties going to
// the lower triangle index), so the grid only steers where the search begins; rebuilding it at
// every refit cost as much as a third of update_vertices for the small deforming surfaces that
// the fibres-first solver refits several times per frame.
bool grid_is_current(const MeshQuery::Bvh& bvh) {
  if (bvh.grid_built_xyz.size() != bvh.vertex_xyz.size() || bvh.grid_vertex.empty()) return false;
  const double reach = 0.25 / bvh.grid_inv_cell;
  const double reach2 = reach * reach;
  for (std::size_t i = 0; i < bvh.vertex_xyz.size(); i += 3) {
    const double dx = bvh.vertex_xyz[i] - bvh.grid_built_xyz[i];
    const double dy = bvh.vertex_xyz[i + 1] - bvh.grid_built_xyz[i + 1];
    const double dz = bvh.vertex_xyz[i + 2] - bvh.grid_built_xyz[i + 2];
    if (!(dx * dx + dy * dy + dz * dz <= reach2)) return false;
  }
  return true;
}

// (Re)creates the Embree scene over the clusters. A static scene is one BVH of high quality. A
// refittable one is two-level (scene quality LOW, the only mode in which Embree honours the
// geometry's REFIT quality): its first commit builds an SAH tree, later commits only refit the
// boxes. The extra level costs ~20 % more instructions per closest-point query (callgrind), so a
// MeshQuery starts static and turns refittable at its first update_vertices.
void build_scene(MeshQuery::Bvh& bvh, bool refittable) {
  if (bvh.scene != nullptr) {
    rtcReleaseScene(bvh.scene);
    bvh.scene = nullptr;
    bvh.geometry = nullptr;
  }
  bvh.commit_pending.store(false, std::memory_order_relaxed);
  bvh.scene = rtcNewScene(bvh.device);
  rtcSetSceneFlags(bvh.scene, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(bvh.scene, refittable ? RTC_BUILD_QUALITY_LOW : RTC_BUILD_QUALITY_HIGH);
  RTCGeometry geom = rtcNewGeometry(bvh.device, RTC_GEOMETRY_TYPE_USER);
  if (refittable) rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_REFIT);
  rtcSetGeometryUserPrimitiveCount(geom, bvh.num_clusters());
  rtcSetGeometryUserData(geom, &bvh);
  rtcSetGeometryBoundsFunction(geom, bounds_callback, nullptr);
  rtcSetGeometryIntersectFunction(geom, intersect_callback);
  rtcSetGeometryOccludedFunction(geom, occluded_callback);
  rtcCommitGeometry(geom);
  rtcAttachGeometry(bvh.scene, geom);
  rtcReleaseGeometry(geom);
  bvh.geometry = geom;
  bvh.refittable = refittable;
  rtcCommitScene(bvh.scene);
  if (const RTCError err = rtcGetDeviceError(bvh.device); err != RTC_ERROR_NONE) {
    throw_internal("Embree failed to build the BVH (error code " +
                   std::to_string(static_cast<int>(err)) + ")");
  }
}

// ----- The compact tree: Embree's SAH builder, our layout and traversal -----------------------

// Build items handed back by rtcBuildBVH's callbacks (allocated by Embree's thread-local
// allocator, freed with the RTCBVH).
struct BuildItem {
  bool leaf;
  unsigned count;
};
struct BuildNode {
  BuildItem head;
  void* children[4];
};
struct BuildLeaf {
  BuildItem head;
  unsigned prims[RTC_BUILD_MAX_PRIMITIVES_PER_LEAF];
};

void* create_build_node(RTCThreadLocalAllocator alloc, unsigned child_count, void* /*user*/) {
  void* mem = rtcThreadLocalAlloc(alloc, sizeof(BuildNode), 16);
  auto* node = new (mem) BuildNode{};
  node->head = {false, child_count};
  return node;
}

void set_build_children(void* node_ptr, void** children, unsigned child_count, void* /*user*/) {
  auto* node = static_cast<BuildNode*>(node_ptr);
  for (unsigned k = 0; k < child_count && k < 4; ++k) node->children[k] = children[k];
  node->head.count = std::min(child_count, 4u);
}

void set_build_bounds(void* /*node*/, const RTCBounds** /*bounds*/, unsigned /*count*/, void* /*user*/) {
  // Unused: the node boxes are recomputed from the double triangles (refit_compact_tree).
}

void* create_build_leaf(RTCThreadLocalAllocator alloc, const RTCBuildPrimitive* prims, std::size_t count,
                        void* /*user*/) {
  void* mem = rtcThreadLocalAlloc(alloc, sizeof(BuildLeaf), 16);
  auto* leaf = new (mem) BuildLeaf{};
  leaf->head = {true, static_cast<unsigned>(std::min<std::size_t>(count, RTC_BUILD_MAX_PRIMITIVES_PER_LEAF))};
  for (unsigned k = 0; k < leaf->head.count; ++k) leaf->prims[k] = prims[k].primID;
  std::sort(leaf->prims, leaf->prims + leaf->head.count);
  return leaf;
}

// Copies Embree's pointer tree into Bvh::nodes (depth-first preorder) and appends the leaves'
// triangles to `order` (the slot order); returns the child reference of `item`.
std::int32_t flatten_build_tree(MeshQuery::Bvh& bvh, const void* item, int depth, std::int32_t parent,
                                std::vector<Eigen::Index>& order, int& max_depth) {
  max_depth = std::max(max_depth, depth);
  if (depth > MeshQuery::Bvh::kMaxTreeDepth) throw_internal("MeshQuery: the SAH tree is too deep");
  const auto* head = static_cast<const BuildItem*>(item);
  if (head->leaf) {
    const auto* leaf = static_cast<const BuildLeaf*>(item);
    if (leaf->head.count == 0 || leaf->head.count > MeshQuery::Bvh::kCluster) {
      throw_internal("MeshQuery: Embree's builder made a leaf of " + std::to_string(leaf->head.count) +
                     " triangles (expected 1 to 16)");
    }
    const auto cluster = static_cast<std::int32_t>(bvh.cluster_begin.size()) - 1;
    for (unsigned k = 0; k < leaf->head.count; ++k) order.push_back(static_cast<Eigen::Index>(leaf->prims[k]));
    bvh.cluster_begin.push_back(static_cast<unsigned>(order.size()));
    bvh.leaf_parent.push_back(parent);
    return ~cluster;
  }
  const auto* node = static_cast<const BuildNode*>(item);
  const auto index = static_cast<std::int32_t>(bvh.nodes.size());
  bvh.nodes.emplace_back();
  bvh.node_parent.push_back(parent);
  MeshQuery::Bvh::Node4 flat{};
  for (unsigned k = 0; k < 4; ++k) {
    flat.lo_x[k] = flat.lo_y[k] = flat.lo_z[k] = std::numeric_limits<float>::infinity();
    flat.hi_x[k] = flat.hi_y[k] = flat.hi_z[k] = -std::numeric_limits<float>::infinity();
  }
  for (unsigned k = 0; k < node->head.count; ++k) {
    flat.child[k] = flatten_build_tree(bvh, node->children[k], depth + 1, index, order, max_depth);
    flat.valid |= 1u << k;
    if (flat.child[k] < 0) flat.leaves |= 1u << k;
  }
  bvh.nodes[static_cast<std::size_t>(index)] = flat;
  return index;
}

// Builds the compact tree's topology with Embree's SAH builder over the triangles' float boxes
// (binned SAH, no spatial splits, so every triangle lands in exactly one leaf) and returns the
// slot order: the leaves' triangles in depth-first order. Sets cluster_begin, nodes and root; the
// boxes and leaf bounds come from refit_compact_tree once the slots are filled.
std::vector<Eigen::Index> build_compact_tree(MeshQuery::Bvh& bvh, const TriMesh& mesh) {
  const Eigen::Index nf = mesh.F.rows();
  std::vector<RTCBuildPrimitive> prims(static_cast<std::size_t>(nf));
  for (Eigen::Index f = 0; f < nf; ++f) {
    double lo[3], hi[3];
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min({mesh.V(mesh.F(f, 0), k), mesh.V(mesh.F(f, 1), k), mesh.V(mesh.F(f, 2), k)});
      hi[k] = std::max({mesh.V(mesh.F(f, 0), k), mesh.V(mesh.F(f, 1), k), mesh.V(mesh.F(f, 2), k)});
    }
    RTCBuildPrimitive& p = prims[static_cast<std::size_t>(f)];
    p.lower_x = round_down(lo[0]);
    p.lower_y = round_down(lo[1]);
    p.lower_z = round_down(lo[2]);
    p.upper_x = round_up(hi[0]);
    p.upper_y = round_up(hi[1]);
    p.upper_z = round_up(hi[2]);
    p.geomID = 0;
    p.primID = static_cast<unsigned>(f);
  }
  RTCBVH builder = rtcNewBVH(bvh.device);
  RTCBuildArguments args = rtcDefaultBuildArguments();
  args.byteSize = sizeof(args);
  args.buildQuality = RTC_BUILD_QUALITY_MEDIUM;  // binned SAH; HIGH would add spatial splits
  args.buildFlags = RTC_BUILD_FLAG_NONE;
  args.maxBranchingFactor = 4;
  args.maxDepth = MeshQuery::Bvh::kMaxTreeDepth;
  args.sahBlockSize = kSahBlockSize;
  args.minLeafSize = kSahMinLeafSize;
  args.maxLeafSize = MeshQuery::Bvh::kCluster;
  args.traversalCost = kSahTraversalCost;
  args.intersectionCost = kSahIntersectionCost;
  args.bvh = builder;
  args.primitives = prims.data();
  args.primitiveCount = prims.size();
  args.primitiveArrayCapacity = prims.size();
  args.createNode = create_build_node;
  args.setNodeChildren = set_build_children;
  args.setNodeBounds = set_build_bounds;
  args.createLeaf = create_build_leaf;
  args.splitPrimitive = nullptr;
  args.buildProgress = nullptr;
  args.userPtr = nullptr;
  void* root = rtcBuildBVH(&args);
  std::vector<Eigen::Index> order;
  order.reserve(static_cast<std::size_t>(nf));
  bvh.nodes.clear();
  bvh.node_parent.clear();
  bvh.leaf_parent.clear();
  bvh.cluster_begin.assign(1, 0u);
  int max_depth = 0;
  try {
    if (root == nullptr || rtcGetDeviceError(bvh.device) != RTC_ERROR_NONE) {
      throw_internal("Embree's BVH builder failed (rtcBuildBVH)");
    }
    bvh.root = flatten_build_tree(bvh, root, 0, -1, order, max_depth);
  } catch (...) {
    rtcReleaseBVH(builder);
    throw;
  }
  rtcReleaseBVH(builder);
  if (order.size() != static_cast<std::size_t>(nf)) {
    throw_internal("MeshQuery: Embree's builder lost or duplicated triangles (" + std::to_string(order.size()) +
                   " of " + std::to_string(nf) + ")");
  }
  return order;
}

// Boxes of the compact tree and the leaves' slab-cylinder bounds from the current slots (after
// fill_slots): every leaf box is its double box padded by `pad` and rounded outward to float (so it
// contains the exact triangles); a node's child box is the union of that child's boxes.
void refit_compact_tree(MeshQuery::Bvh& bvh) {
  const unsigned num_clusters = bvh.num_clusters();
  bvh.leaf_bound.resize(MeshQuery::Bvh::kLeafBoundSize * num_clusters);  // every entry set below
  bvh.leaf_box.resize(6 * static_cast<std::size_t>(num_clusters));
  std::vector<float>& leaf_box = bvh.leaf_box;
  for (unsigned c = 0; c < num_clusters; ++c) {
    // The corners' box and the area-weighted normal (sum of cross products), from fill_slots.
    const double* lo = bvh.cluster_box.data() + 6 * static_cast<std::size_t>(c);
    const double* hi = lo + 3;
    const double* ns = bvh.cluster_normal.data() + 3 * static_cast<std::size_t>(c);
    const Vec3 normal(ns[0], ns[1], ns[2]);
    float* box = leaf_box.data() + 6 * static_cast<std::size_t>(c);
    for (int k = 0; k < 3; ++k) {
      box[k] = round_down(lo[k] - bvh.pad);
      box[3 + k] = round_up(hi[k] + bvh.pad);
    }
    // Slab-cylinder about the anchor: the area-weighted normal (zero if the patch's normals cancel,
    // which leaves a ball), the heights' range and the largest in-plane offset of the corners.
    const Vec3 centre(bvh.anchors[3 * c], bvh.anchors[3 * c + 1], bvh.anchors[3 * c + 2]);
    const double n_len = normal.norm();
    const Vec3 n = n_len > 0.0 && std::isfinite(n_len) ? Vec3(normal / n_len) : Vec3::Zero();
    double h_lo = std::numeric_limits<double>::infinity(), h_hi = -h_lo, radius2 = 0.0;
    for (unsigned t = bvh.slot_begin(c); t < bvh.slot_end(c); ++t) {
      for (int v = 0; v < 3; ++v) {
        const Vec3 d = bvh.corner(t, v) - centre;
        const double h = n.dot(d);
        h_lo = std::min(h_lo, h);
        h_hi = std::max(h_hi, h);
        radius2 = std::max(radius2, (d - h * n).squaredNorm());
      }
    }
    double* b = bvh.leaf_bound.data() + MeshQuery::Bvh::kLeafBoundSize * c;
    for (int k = 0; k < 3; ++k) {
      b[k] = centre[k];
      b[3 + k] = n[k];
    }
    // Rounding of these few operations is ~1e-16 of the patch size; the query's margin (1e-10 of
    // the scale) covers it many times over.
    b[6] = std::sqrt(radius2);
    b[7] = h_lo;
    b[8] = h_hi;
  }
  bvh.mean_leaf_radius = 0.0;
  for (unsigned c = 0; c < num_clusters; ++c) bvh.mean_leaf_radius += bvh.leaf_bound[MeshQuery::Bvh::kLeafBoundSize * c + 6];
  if (num_clusters > 0) bvh.mean_leaf_radius /= num_clusters;
  // Leaf children's slab-cylinders in float, relative to the mean of their centres.
  constexpr float kInf = std::numeric_limits<float>::infinity();
  bvh.node_extent = 0.0;
  for (MeshQuery::Bvh::Node4& node : bvh.nodes) {
    Vec3 anchor = Vec3::Zero();
    int leaves = 0;
    for (unsigned k = 0; k < 4; ++k) {
      if ((node.leaves & (1u << k)) == 0) continue;
      const double* b = bvh.leaf_bound.data() + MeshQuery::Bvh::kLeafBoundSize * static_cast<unsigned>(~node.child[k]);
      anchor += Vec3(b[0], b[1], b[2]);
      ++leaves;
    }
    if (leaves > 0) anchor /= static_cast<double>(leaves);
    for (int j = 0; j < 3; ++j) node.anchor[j] = anchor[j];
    for (unsigned k = 0; k < 4; ++k) {
      if ((node.leaves & (1u << k)) == 0) {
        node.cx[k] = node.cy[k] = node.cz[k] = node.nx[k] = node.ny[k] = node.nz[k] = 0.0f;
        node.r[k] = kInf;
        node.h_lo[k] = -kInf;
        node.h_hi[k] = kInf;
        continue;
      }
      const double* b = bvh.leaf_bound.data() + MeshQuery::Bvh::kLeafBoundSize * static_cast<unsigned>(~node.child[k]);
      const Vec3 rel = Vec3(b[0], b[1], b[2]) - anchor;
      node.cx[k] = static_cast<float>(rel.x());
      node.cy[k] = static_cast<float>(rel.y());
      node.cz[k] = static_cast<float>(rel.z());
      node.nx[k] = static_cast<float>(b[3]);
      node.ny[k] = static_cast<float>(b[4]);
      node.nz[k] = static_cast<float>(b[5]);
      node.r[k] = round_up(b[6]);
      node.h_lo[k] = round_down(b[7]);
      node.h_hi[k] = round_up(b[8]);
      bvh.node_extent = std::max(bvh.node_extent, rel.norm() + b[6] + std::max(std::abs(b[7]), std::abs(b[8])));
    }
  }
  // Reverse preorder: a node's children are refitted before it.
  for (std::size_t i = bvh.nodes.size(); i-- > 0;) {
    MeshQuery::Bvh::Node4& node = bvh.nodes[i];
    for (unsigned k = 0; k < 4; ++k) {
      if ((node.valid & (1u << k)) == 0) continue;
      float box[6];
      const std::int32_t child = node.child[k];
      if (child < 0) {
        std::copy_n(leaf_box.data() + 6 * static_cast<std::size_t>(~child), 6, box);
      } else {
        const MeshQuery::Bvh::Node4& sub = bvh.nodes[static_cast<std::size_t>(child)];
        for (int j = 0; j < 3; ++j) box[j] = std::numeric_limits<float>::infinity();
        for (int j = 3; j < 6; ++j) box[j] = -std::numeric_limits<float>::infinity();
        for (unsigned m = 0; m < 4; ++m) {
          if ((sub.valid & (1u << m)) == 0) continue;
          box[0] = std::min(box[0], sub.lo_x[m]);
          box[1] = std::min(box[1], sub.lo_y[m]);
          box[2] = std::min(box[2], sub.lo_z[m]);
          box[3] = std::max(box[3], sub.hi_x[m]);
          box[4] = std::max(box[4], sub.hi_y[m]);
          box[5] = std::max(box[5], sub.hi_z[m]);
        }
      }
      node.lo_x[k] = box[0];
      node.lo_y[k] = box[1];
      node.lo_z[k] = box[2];
      node.hi_x[k] = box[3];
      node.hi_y[k] = box[4];
      node.hi_z[k] = box[5];
    }
  }
}

// Positions of the welded vertices from the mesh (each welded vertex takes its first mesh vertex).
void update_welded_positions(MeshQuery::Bvh& bvh, const TriMesh& mesh) {
  bvh.vertex_xyz.resize(3 * bvh.welded_source.size());
  for (std::size_t i = 0; i < bvh.welded_source.size(); ++i) {
    for (int k = 0; k < 3; ++k) bvh.vertex_xyz[3 * i + static_cast<std::size_t>(k)] = mesh.V(bvh.welded_source[i], k);
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// MeshQuery
// ---------------------------------------------------------------------------------------------

MeshQuery::MeshQuery(const TriMesh& mesh) : MeshQuery(mesh, MeshQueryOptions{}) {}

MeshQuery::MeshQuery(const TriMesh& mesh, const MeshQueryOptions& options)
    : mesh_(mesh), bvh_(std::make_unique<Bvh>()) {
  const Eigen::Index nv = mesh_.V.rows(), nf = mesh_.F.rows();
  if (nf == 0 || nv == 0) {
    throw_bad_input("mesh query needs a mesh with at least one triangle",
                    {.suggestion = "check that the mesh file holds triangles"});
  }
  if (!mesh_.V.allFinite()) {
    throw_bad_input("mesh has non-finite (NaN or Inf) vertex coordinates",
                    {.suggestion = "repair the mesh (fascicle mesh repair) before querying it"});
  }
  if (mesh_.F.minCoeff() < 0 || mesh_.F.maxCoeff() >= nv) {
    throw_bad_input("mesh has triangle vertex indices out of range [0, " + std::to_string(nv) + ")",
                    {.suggestion = "repair the mesh (fascicle mesh repair) before querying it"});
  }
  Bvh& bvh = *bvh_;
  Points3 centroids(nf, 3);
  for (Eigen::Index f = 0; f < nf; ++f) {
    centroids.row(f) = (mesh_.V.row(mesh_.F(f, 0)) + mesh_.V.row(mesh_.F(f, 1)) + mesh_.V.row(mesh_.F(f, 2))) / 3.0;
  }
  bvh.device = rtcNewDevice(nullptr);
  if (bvh.device == nullptr) throw_internal("Embree: cannot create a device");
  bvh.compact = options.closest_point_tree == MeshQueryOptions::ClosestPointTree::compact;
  std::vector<Eigen::Index> order;
  if (bvh.compact) {
    order = build_compact_tree(bvh, mesh_);  // slots = the SAH leaves in depth-first order
  } else {
    order = spatial_order(centroids);
    bvh.cluster_begin.clear();
    for (unsigned first = 0; first < static_cast<unsigned>(nf); first += Bvh::kCluster) bvh.cluster_begin.push_back(first);
    bvh.cluster_begin.push_back(static_cast<unsigned>(nf));
  }
  bvh.num_slots = static_cast<unsigned>(nf);
  bvh.triangle_of.resize(static_cast<std::size_t>(nf));
  bvh.slot_of.resize(static_cast<std::size_t>(nf));
  for (std::size_t slot = 0; slot < order.size(); ++slot) {
    const Eigen::Index f = order[slot];
    bvh.triangle_of[slot] = static_cast<int>(f);
    bvh.slot_of[static_cast<std::size_t>(f)] = static_cast<int>(slot);
  }
  fill_slots(bvh, mesh_);

  // Welded vertices: used vertices with equal coordinates merged, numbered by first use in slot
  // order; their adjacency and incident slots; the start-vertex grid.
  {
    std::vector<int> rank_of(static_cast<std::size_t>(nv), -1);  // mesh vertex -> first-use rank
    std::vector<int> used;                                        // rank -> mesh vertex
    for (unsigned slot = 0; slot < bvh.num_slots; ++slot) {
      for (int k = 0; k < 3; ++k) {
        const int v = mesh_.F(bvh.triangle_of[slot], k);
        if (rank_of[static_cast<std::size_t>(v)] < 0) {
          rank_of[static_cast<std::size_t>(v)] = static_cast<int>(used.size());
          used.push_back(v);
        }
      }
    }
    // Each rank's representative: the lowest rank with the same position. An open-addressing hash
    // table over the positions (ranks inserted in increasing order, so the first of each position
    // stays); -0.0 is hashed as +0.0 since they compare equal. Linear in the vertex count (a sort of
    // the keyed vertices was ~40 % of the build).
    std::vector<unsigned> representative(used.size());
    {
      constexpr unsigned kEmpty = std::numeric_limits<unsigned>::max();
      const std::size_t capacity = std::bit_ceil(std::max<std::size_t>(2 * used.size(), 16));
      std::vector<unsigned> table(capacity, kEmpty);
      const auto bits = [](double x) { return std::bit_cast<std::uint64_t>(x + 0.0); };
      for (std::size_t i = 0; i < used.size(); ++i) {
        const double x = mesh_.V(used[i], 0), y = mesh_.V(used[i], 1), z = mesh_.V(used[i], 2);
        std::uint64_t h = bits(x) * 0x9E3779B97F4A7C15ull;
        h = (h ^ bits(y) ^ (h >> 29)) * 0xBF58476D1CE4E5B9ull;
        h = (h ^ bits(z) ^ (h >> 31)) * 0x94D049BB133111EBull;
        std::size_t slot = static_cast<std::size_t>(h ^ (h >> 32)) & (capacity - 1);
        while (true) {
          const unsigned r = table[slot];
          if (r == kEmpty) {
            table[slot] = static_cast<unsigned>(i);
            representative[i] = static_cast<unsigned>(i);
            break;
          }
          if (mesh_.V(used[r], 0) == x && mesh_.V(used[r], 1) == y && mesh_.V(used[r], 2) == z) {
            representative[i] = r;
            break;
          }
          slot = (slot + 1) & (capacity - 1);
        }
      }
    }
    std::vector<unsigned> weld_of_rank(used.size());
    unsigned num_welded = 0;
    for (std::size_t i = 0; i < used.size(); ++i) {
      weld_of_rank[i] = representative[i] == i ? num_welded++ : weld_of_rank[representative[i]];
      if (representative[i] == i) {
        bvh.welded_source.push_back(used[i]);
      }
    }
    std::vector<std::array<unsigned, 3>> welded(bvh.num_slots);  // slot -> its welded corners
    bvh.vertex_of_slot.resize(bvh.num_slots);
    for (unsigned slot = 0; slot < bvh.num_slots; ++slot) {
      for (int k = 0; k < 3; ++k) {
        welded[slot][static_cast<std::size_t>(k)] =
            weld_of_rank[static_cast<std::size_t>(rank_of[static_cast<std::size_t>(mesh_.F(bvh.triangle_of[slot], k))])];
      }
      bvh.vertex_of_slot[slot] = welded[slot][0];
    }
    // Incident slots, by counting (a triangle repeating a welded vertex is listed once), and
    // adjacent vertices (each edge both ways; duplicates removed per vertex).
    bvh.ring_start.assign(num_welded + 1, 0);
    bvh.adjacent_start.assign(num_welded + 1, 0);
    const auto is_first = [](const std::array<unsigned, 3>& w, int k) {
      return (k < 1 || w[static_cast<std::size_t>(k)] != w[0]) && (k < 2 || w[2] != w[1]);
    };
    for (const auto& w : welded) {
      for (int k = 0; k < 3; ++k) {
        if (is_first(w, k)) ++bvh.ring_start[w[static_cast<std::size_t>(k)] + 1];
        bvh.adjacent_start[w[static_cast<std::size_t>(k)] + 1] += 2;
      }
    }
    for (unsigned v = 0; v < num_welded; ++v) {
      bvh.ring_start[v + 1] += bvh.ring_start[v];
      bvh.adjacent_start[v + 1] += bvh.adjacent_start[v];
    }
    bvh.ring_slots.resize(bvh.ring_start.back());
    bvh.adjacent.resize(bvh.adjacent_start.back());
    std::vector<unsigned> ring_fill(bvh.ring_start.begin(), bvh.ring_start.end() - 1);
    std::vector<unsigned> adjacent_fill(bvh.adjacent_start.begin(), bvh.adjacent_start.end() - 1);
    for (unsigned slot = 0; slot < bvh.num_slots; ++slot) {
      const auto& w = welded[slot];
      for (int k = 0; k < 3; ++k) {
        const unsigned v = w[static_cast<std::size_t>(k)];
        if (is_first(w, k)) bvh.ring_slots[ring_fill[v]++] = slot;
        bvh.adjacent[adjacent_fill[v]++] = w[static_cast<std::size_t>((k + 1) % 3)];
        bvh.adjacent[adjacent_fill[v]++] = w[static_cast<std::size_t>((k + 2) % 3)];
      }
    }
    // Compact the adjacency: sort each vertex's short list, drop duplicates and itself.
    unsigned out = 0;
    for (unsigned v = 0; v < num_welded; ++v) {
      const unsigned begin = bvh.adjacent_start[v], end = bvh.adjacent_start[v + 1];
      std::sort(bvh.adjacent.begin() + begin, bvh.adjacent.begin() + end);
      bvh.adjacent_start[v] = out;
      for (unsigned k = begin; k < end; ++k) {
        const unsigned u = bvh.adjacent[k];
        if (u != v && (out == bvh.adjacent_start[v] || bvh.adjacent[out - 1] != u)) bvh.adjacent[out++] = u;
      }
    }
    bvh.adjacent_start[num_welded] = out;
    bvh.adjacent.resize(out);
    if (bvh.compact) {
      // Home leaf of each welded vertex: the leaf holding its first incident slot.
      std::vector<unsigned> cluster_of_slot(bvh.num_slots);
      for (unsigned c = 0; c < bvh.num_clusters(); ++c) {
        for (unsigned t = bvh.slot_begin(c); t < bvh.slot_end(c); ++t) cluster_of_slot[t] = c;
      }
      bvh.home_leaf.resize(num_welded);
      for (unsigned v = 0; v < num_welded; ++v) bvh.home_leaf[v] = cluster_of_slot[bvh.ring_slots[bvh.ring_start[v]]];
    }

  }
  update_welded_positions(bvh, mesh_);
  build_start_grid(bvh);
  if (bvh.compact) refit_compact_tree(bvh);
  build_scene(bvh, false);
}

void MeshQuery::update_vertices(const Points3& V) {
  if (V.rows() != mesh_.V.rows()) {
    throw_bad_input("MeshQuery::update_vertices got " + std::to_string(V.rows()) +
                        " vertices for a mesh of " + std::to_string(mesh_.V.rows()),
                    {.suggestion = "pass the deformed positions of the same mesh (same vertex count and "
                                   "triangles); for a different mesh build a new MeshQuery"});
  }
  if (!V.allFinite()) {
    throw_bad_input("MeshQuery::update_vertices got non-finite (NaN or Inf) vertex coordinates",
                    {.suggestion = "check the deformed mesh for NaN or Inf before updating the query"});
  }
  Bvh& bvh = *bvh_;
  mesh_.V = V;
  // Same slots (Morton order of the original centroids), same clusters, same welded-vertex graph:
  // only positions change. The clusters' boxes are refitted by Embree from the bounds callback.
  fill_slots(bvh, mesh_);
  update_welded_positions(bvh, mesh_);
  if (!grid_is_current(bvh)) build_start_grid(bvh);
  if (bvh.compact) refit_compact_tree(bvh);
  // a small deforming surface: rays through the compact tree from now on, no Embree work
  if (bvh.compact && bvh.num_clusters() <= Bvh::kRaysOnCompactClusters) bvh.rays_on_compact = true;
  if (bvh.rays_on_compact) return;
  if (!bvh.refittable) {
    build_scene(bvh, true);  // first update: one build of the refittable tree
    return;
  }
  bvh.commit_pending.store(true, std::memory_order_release);  // committed at the next ray
}

MeshQuery::~MeshQuery() = default;
MeshQuery::MeshQuery(MeshQuery&&) noexcept = default;
MeshQuery& MeshQuery::operator=(MeshQuery&&) noexcept = default;

namespace {

// Batched closest point on the compact tree seeded by the previous (nearby) query's answer: the
// exact distance to that triangle bounds the answer (within the step between the two points of
// the previous distance), and the traversal starts bottom-up from the leaf of the triangle's first
// corner. Replaces the vertex descent when consecutive points are close (calc_closest_points).
ClosestPoint closest_from_previous(const MeshQuery::Bvh& bvh, const Vec3& p, int previous_triangle) {
  PointQueryState q;
  q.bvh = &bvh;
  q.p = p;
  q.best_d2 = std::numeric_limits<double>::infinity();
  q.best_limit = std::numeric_limits<double>::infinity();
  q.best_slot = -1;
  q.radius_pad = bvh.pad + p.cwiseAbs().maxCoeff() * 0x1p-20;
  q.margin = 1e-10 * ((p - bvh.middle).norm() + bvh.scale);
  const auto slot = static_cast<unsigned>(bvh.slot_of[static_cast<std::size_t>(previous_triangle)]);
  test_slot(&q, slot);
  closest_compact(&q, static_cast<std::int32_t>(bvh.home_leaf[bvh.vertex_of_slot[slot]]));
  ClosestPoint out;
  out.point = q.best.point;
  out.triangle = bvh.triangle_of[static_cast<std::size_t>(q.best_slot)];
  out.barycentric = q.best.barycentric;
  out.distance = std::sqrt(q.best_d2);
  return out;
}

}  // namespace

ClosestPoint MeshQuery::closest_with_hint(const Vec3& p, int hint_triangle,
                                          double max_distance) const {
  PointQueryState q;
  q.bvh = bvh_.get();
  q.p = p;
  q.best_d2 = max_distance * max_distance;
  q.best_limit = max_distance * (1.0 + 1e-12);
  q.best_slot = -1;
  // The float query point is off by half an ulp per axis; cover it (and float arithmetic in the
  // box distance) with a few ulps of its largest coordinate.
  q.radius_pad = bvh_->pad + p.cwiseAbs().maxCoeff() * 0x1p-20;  // = ldexp(.., -20), exact
  q.margin = 1e-10 * ((p - bvh_->middle).norm() + bvh_->scale);
  // Seeds: exact distances to the triangles around the vertex nearest to p (found by greedy
  // descent from the hint's vertex, or from the start-vertex grid) bound the answer from
  // above, so Embree's traversal starts with a nearly exact sphere and prunes almost every node.
  unsigned start = bvh_->find_start_vertex(p);
  if (hint_triangle >= 0) {
    // The previous query's vertex, when nearer than the grid's (coherent batches).
    const auto hint_slot = static_cast<std::size_t>(bvh_->slot_of[static_cast<std::size_t>(hint_triangle)]);
    const unsigned hint_vertex = bvh_->vertex_of_slot[hint_slot];
    if (bvh_->vertex_distance2(hint_vertex, p) < bvh_->vertex_distance2(start, p)) start = hint_vertex;
  }
  seed_from_vertex(&q, start);
  RTCPointQuery query;
  query.x = static_cast<float>(p.x());
  query.y = static_cast<float>(p.y());
  query.z = static_cast<float>(p.z());
  query.time = 0.0f;
  query.radius = padded_radius(q.best_limit, q.radius_pad);
  if (bvh_->compact) {
    closest_compact(&q, q.start_vertex >= 0 ? static_cast<std::int32_t>(bvh_->home_leaf[static_cast<std::size_t>(q.start_vertex)]) : -1);
  } else {
    commit_pending_refit(*bvh_);
    RTCPointQueryContext context;
    rtcInitPointQueryContext(&context);
    rtcPointQuery(bvh_->scene, &query, &context, point_query_callback, &q);
  }

  if (q.best_slot < 0 && q.seed_vertex >= 0) {
    // Nothing beat the seeded vertex bound (possible only through rounding): the answer is then
    // among the triangles around that vertex, whose exact distance is at most the bound.
    q.best_d2 = max_distance * max_distance;
    const auto v = static_cast<unsigned>(q.seed_vertex);
    for (unsigned k = bvh_->ring_start[v]; k < bvh_->ring_start[v + 1]; ++k)
      test_slot(&q, bvh_->ring_slots[k]);
  }
  ClosestPoint out;
  if (q.best_slot < 0) return out;
  out.point = q.best.point;
  out.triangle = bvh_->triangle_of[static_cast<std::size_t>(q.best_slot)];
  out.barycentric = q.best.barycentric;
  out.distance = std::sqrt(q.best_d2);
  return out;
}

ClosestPoint MeshQuery::calc_closest_point(const Vec3& p, double max_distance) const {
  if (!p.allFinite()) {
    throw_bad_input("closest-point query at a non-finite point",
                    {.suggestion = "check the query points for NaN or Inf"});
  }
  return closest_with_hint(p, -1, max_distance);
}

std::optional<int> MeshQuery::calc_crossing_number(const Vec3& p, const Vec3& direction) const {
  RayState r = make_ray(*bvh_, p, direction, 0.0, std::numeric_limits<double>::infinity(),
                        RayMode::crossings);
  trace(*bvh_, r);
  if (r.grazed) return std::nullopt;
  return r.crossings;
}

bool MeshQuery::calc_is_inside(const Vec3& p) const {
  if (!p.allFinite()) {
    throw_bad_input("inside test at a non-finite point",
                    {.suggestion = "check the query points for NaN or Inf"});
  }
  // Majority of 5: stop as soon as one side has 3 votes.
  int inside = 0, outside = 0;
  for (const Vec3& d : kVoteDirections) {
    const std::optional<int> w = calc_crossing_number(p, d);
    if (!w) continue;  // grazing ray: abstain
    (*w > 0 ? inside : outside) += 1;
    if (inside >= 3) return true;
    if (outside >= 3) return false;
  }
  return compute_winding_number(mesh_, p) > 0.5;
}

double MeshQuery::calc_signed_distance(const Vec3& p) const {
  const double d = calc_closest_point(p).distance;
  return calc_is_inside(p) ? -d : d;
}

std::optional<RayHit> MeshQuery::cast_ray(const Vec3& origin, const Vec3& direction, double t_min,
                                          double t_max) const {
  RayState r = make_ray(*bvh_, origin, direction, t_min, t_max, RayMode::first);
  trace(*bvh_, r);
  if (r.first.triangle < 0) return std::nullopt;
  return r.first;
}

std::vector<RayHit> MeshQuery::cast_ray_all(const Vec3& origin, const Vec3& direction,
                                            double t_min, double t_max) const {
  std::vector<RayHit> hits;
  RayState r = make_ray(*bvh_, origin, direction, t_min, t_max, RayMode::all);
  r.all = &hits;
  trace(*bvh_, r);
  std::sort(hits.begin(), hits.end(), [](const RayHit& a, const RayHit& b) {
    return a.t != b.t ? a.t < b.t : a.triangle < b.triangle;
  });
  return hits;
}

std::vector<ClosestPoint> MeshQuery::calc_closest_points(const Points3& P) const {
  if (!P.allFinite()) {
    throw_bad_input("closest-point query at non-finite points",
                    {.suggestion = "check the query points for NaN or Inf"});
  }
  std::vector<ClosestPoint> out(static_cast<std::size_t>(P.rows()));
  commit_pending_refit(*bvh_);  // once here, not by the first task while the others wait
  const std::vector<Eigen::Index> order = spatial_order(P);
  const std::size_t blocks = (order.size() + kBlock - 1) / kBlock;
  // Each block starts without a hint, so the result does not depend on how blocks are scheduled.
  parallel_for(blocks, [&](std::size_t b) {
    int hint = -1;
    Vec3 previous = Vec3::Zero();
    double previous_distance = 0.0;
    const std::size_t end = std::min(order.size(), (b + 1) * kBlock);
    for (std::size_t k = b * kBlock; k < end; ++k) {
      const Eigen::Index i = order[k];
      ClosestPoint& c = out[static_cast<std::size_t>(i)];
      const Vec3 p = P.row(i).transpose();
      if (hint >= 0 && bvh_->compact && previous_distance <= kExactHintReach * bvh_->mean_leaf_radius &&
          (p - previous).norm() <= kExactHintStep * previous_distance) {
        c = closest_from_previous(*bvh_, p, hint);
      } else {
        c = closest_with_hint(p, hint, std::numeric_limits<double>::infinity());
      }
      hint = c.triangle;
      previous = p;
      previous_distance = c.distance;
    }
  });
  return out;
}

VecX MeshQuery::calc_distances(const Points3& P) const {
  const std::vector<ClosestPoint> c = calc_closest_points(P);
  VecX d(P.rows());
  for (Eigen::Index i = 0; i < P.rows(); ++i) d[i] = c[static_cast<std::size_t>(i)].distance;
  return d;
}

InsideFlags MeshQuery::calc_is_inside(const Points3& P) const {
  InsideFlags inside(P.rows());
  const std::size_t n = static_cast<std::size_t>(P.rows());
  const std::size_t blocks = (n + kBlock - 1) / kBlock;
  commit_pending_refit(*bvh_);  // once here, not by the first task while the others wait
  parallel_for(blocks, [&](std::size_t b) {
    const std::size_t end = std::min(n, (b + 1) * kBlock);
    for (std::size_t k = b * kBlock; k < end; ++k) {
      const auto i = static_cast<Eigen::Index>(k);
      inside[i] = calc_is_inside(Vec3(P.row(i).transpose()));
    }
  });
  return inside;
}

VecX MeshQuery::calc_signed_distances(const Points3& P) const {
  VecX d = calc_distances(P);
  const InsideFlags inside = calc_is_inside(P);
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    if (inside[i]) d[i] = -d[i];
  }
  return d;
}

}  // namespace fascicle
