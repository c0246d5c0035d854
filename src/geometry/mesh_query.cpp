#include "fascicle/geometry/mesh_query.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/geometry/winding_number.hpp"

#include <embree3/rtcore.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <string>
#include <tuple>

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

TrianglePoint closest_point_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b,
                                        const Vec3& c) {
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
  if (!(area2 > 0.0)) return closest_on_degenerate(p, a, b, c);
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
  if (det == 0.0) {
    if (on_edge != nullptr) *on_edge = true;  // ray in the triangle's plane, or a degenerate one
    return std::nullopt;
  }
  const double t = (u * sz * A[kz] + v * sz * B[kz] + w * sz * C[kz]) / det;
  if (!(t > t_min && t < t_max)) return std::nullopt;
  RayHit hit;
  hit.t = t;
  hit.barycentric = Vec3(u, v, w) / det;
  const Vec3 n = (b - a).cross(c - a);
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
}  // namespace

struct MeshQuery::Bvh {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  RTCGeometry geometry = nullptr;  // the clusters (owned by the scene)
  bool refittable = false;         // two-level scene whose commits refit (see build_scene)
  // Triangles are stored in Morton order of their centroids ("slots"), so that triangles near in
  // space are near in memory. Embree primitives are clusters of kCluster consecutive slots: one
  // callback screens the whole cluster with a vectorised lower bound (calc_lower_bounds) and runs
  // the exact test only on the few survivors. Fewer, larger primitives also mean a smaller tree.
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
  unsigned slot_end(unsigned prim) const { return std::min(num_slots, (prim + 1) * kCluster); }
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
                         float limit2) {
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
    mask |= static_cast<unsigned>(h * h + e * e <= limit2) << k;
  }
  return mask;
}

// Which triangles of one cluster the line origin + t * direction may meet: bit k is set unless
// the line misses triangle k's bounding sphere (centre c, radius r + margin), tested as
// |(c - o) x d|^2 > (r + margin)^2 |d|^2 without a square root, in float relative to the cluster's
// anchor. The rounding error of the cross product is a few float ulps of |c - o| |d|; the caller's
// margin is 2^-18 (|o - anchor| + 2 * cluster extent). Vectorised like find_candidates.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(__SANITIZE_ADDRESS__)
__attribute__((target_clones("avx2", "default")))
#endif
unsigned find_ray_candidates(const float* __restrict block, float ox, float oy, float oz, float dx,
                             float dy, float dz, float margin) {
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
    mask |= static_cast<unsigned>(x * x + y * y + z * z <= reach * reach * d2) << k;
  }
  return mask;
}

}  // namespace

namespace {

float round_down(double x) {
  float f = static_cast<float>(x);
  if (static_cast<double>(f) > x) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
  return f;
}

float round_up(double x) {
  float f = static_cast<float>(x);
  if (static_cast<double>(f) < x) f = std::nextafter(f, std::numeric_limits<float>::infinity());
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
  double lo[3], hi[3];
  for (int k = 0; k < 3; ++k) {
    lo[k] = std::numeric_limits<double>::infinity();
    hi[k] = -std::numeric_limits<double>::infinity();
  }
  for (unsigned t = args->primID * MeshQuery::Bvh::kCluster; t < bvh->slot_end(args->primID); ++t) {
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
  RTCBounds* b = args->bounds_o;
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
};

// Embree's radius: the exact distance, rounded up and padded so float culling stays conservative.
float padded_radius(double d, double radius_pad) {
  if (!std::isfinite(d)) return std::numeric_limits<float>::infinity();
  return round_up(d * (1.0 + 1e-6) + radius_pad);
}

// Exact test of one slot against the best so far; true if it became the best.
bool test_slot(PointQueryState* q, unsigned t) {
  const TrianglePoint tp =
      closest_point_on_triangle(q->p, q->bvh->corner(t, 0), q->bvh->corner(t, 1), q->bvh->corner(t, 2));
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
  for (unsigned k = bvh.ring_start[v]; k < bvh.ring_start[v + 1]; ++k) test_slot(q, bvh.ring_slots[k]);
}

bool point_query_callback(RTCPointQueryFunctionArguments* args) {
  constexpr unsigned K = MeshQuery::Bvh::kCluster;
  auto* q = static_cast<PointQueryState*>(args->userPtr);
  const MeshQuery::Bvh& bvh = *q->bvh;
  const unsigned first = args->primID * K;
  const unsigned count = bvh.slot_end(args->primID) - first;
  // A triangle is tested exactly unless its lower bound exceeds the best distance (plus the
  // rounding margin): such a triangle can neither win nor tie.
  const double limit = q->best_limit + q->margin +
                       MeshQuery::Bvh::kFloatMargin * (q->best_limit + 2.0 * bvh.cluster_extent);
  const double* anchor = bvh.anchors.data() + 3 * static_cast<std::size_t>(args->primID);
  unsigned mask = find_candidates(bvh.soa.data() + MeshQuery::Bvh::kSoaRows * K * args->primID,
                                  static_cast<float>(q->p.x() - anchor[0]),
                                  static_cast<float>(q->p.y() - anchor[1]),
                                  static_cast<float>(q->p.z() - anchor[2]),
                                  to_float_or_infinity(limit * limit * (1.0 + 1e-6)));
  if (count < K) mask &= (1u << count) - 1u;  // the last cluster may be partly empty
  bool improved = false;
  while (mask != 0) {
    const auto k = static_cast<unsigned>(std::countr_zero(mask));
    mask &= mask - 1u;
    improved = test_slot(q, first + k) || improved;
  }
  if (improved) args->query->radius = padded_radius(q->best_limit, q->radius_pad);
  return improved;
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
  // Shrink Embree's far distance (rounded up, padded) so farther boxes are culled.
  auto* rayhit = reinterpret_cast<RTCRayHit*>(args->rayhit);
  const float tf = round_up(hit->t * (1.0 + 1e-6) + r->bvh->pad / r->direction.norm());
  rayhit->ray.tfar = std::min(rayhit->ray.tfar, tf);
  rayhit->hit.geomID = args->geomID;
  rayhit->hit.primID = args->primID;
}

void intersect_callback(const RTCIntersectFunctionNArguments* args) {
  if (args->N != 1 || args->valid[0] == 0) return;
  auto* r = reinterpret_cast<RayState*>(args->context);
  constexpr unsigned K = MeshQuery::Bvh::kCluster;
  const unsigned first = args->primID * K;
  const unsigned count = r->bvh->slot_end(args->primID) - first;
  // Exact (double) tests only for the triangles whose bounding sphere the line meets: the others
  // can neither be hit nor grazed.
  const double* anchor = r->bvh->anchors.data() + 3 * static_cast<std::size_t>(args->primID);
  const Vec3 oa(r->origin.x() - anchor[0], r->origin.y() - anchor[1], r->origin.z() - anchor[2]);
  const double margin =
      r->margin + MeshQuery::Bvh::kFloatMargin * (oa.norm() + 2.0 * r->bvh->cluster_extent);
  unsigned mask = find_ray_candidates(
      r->bvh->soa.data() + MeshQuery::Bvh::kSoaRows * K * args->primID, static_cast<float>(oa.x()),
      static_cast<float>(oa.y()), static_cast<float>(oa.z()), r->unit_direction[0],
      r->unit_direction[1], r->unit_direction[2], to_float_or_infinity(margin));
  if (count < K) mask &= (1u << count) - 1u;
  while (mask != 0) {
    const auto k = static_cast<unsigned>(std::countr_zero(mask));
    mask &= mask - 1u;
    intersect_slot(args, r, first + k);
  }
}

void occluded_callback(const RTCOccludedFunctionNArguments* /*args*/) {}

// Runs one ray through the scene with the given mode.
void trace(const MeshQuery::Bvh& bvh, RayState& state) {
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
  const Vec3 unit = direction.normalized();
  s.unit_direction = {static_cast<float>(unit.x()), static_cast<float>(unit.y()), static_cast<float>(unit.z())};
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

// Points in Morton order, so that consecutive queries are near each other.
std::vector<Eigen::Index> spatial_order(const Points3& P) {
  std::vector<Eigen::Index> order(static_cast<std::size_t>(P.rows()));
  if (P.rows() == 0) return order;
  const Vec3 lo = P.colwise().minCoeff().transpose();
  const Vec3 hi = P.colwise().maxCoeff().transpose();
  Vec3 inv;
  for (int k = 0; k < 3; ++k) inv[k] = hi[k] > lo[k] ? 1.0 / (hi[k] - lo[k]) : 0.0;
  std::vector<std::pair<std::uint32_t, Eigen::Index>> keyed(order.size());
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const Vec3 p = P.row(i).transpose();
    keyed[static_cast<std::size_t>(i)] = {p.allFinite() ? morton_code(p, lo, inv) : 0u, i};
  }
  std::sort(keyed.begin(), keyed.end());
  for (std::size_t i = 0; i < keyed.size(); ++i) order[i] = keyed[i].second;
  return order;
}

}  // namespace

namespace {

// Fills the per-slot data from the mesh's current vertices (slot order already fixed): corners,
// the clusters' bounding discs, the bounding box, scale, pad and middle. Used by the constructor and
// by update_vertices (same slots, new positions).
void fill_slots(MeshQuery::Bvh& bvh, const TriMesh& mesh) {
  constexpr unsigned K = MeshQuery::Bvh::kCluster;
  const std::size_t num_clusters = (bvh.num_slots + K - 1) / K;
  bvh.corners.resize(9 * static_cast<std::size_t>(bvh.num_slots));
  bvh.soa.assign(MeshQuery::Bvh::kSoaRows * K * num_clusters, 0.0f);
  bvh.anchors.resize(3 * num_clusters);
  // Per cluster: an upper bound of max(|centre - anchor| + radius) (max |rel| + max radius).
  std::vector<double> extent(num_clusters, 0.0);
  // Serial on purpose: a parallel_for here made the build ~20 % dearer in CPU time (TBB's
  // workers spinning), and callers refit several meshes in parallel anyway.
  for (std::size_t cluster = 0; cluster < num_clusters; ++cluster) {
    const std::size_t first = cluster * K;
    const std::size_t count = std::min<std::size_t>(K, bvh.num_slots - first);
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
    double max_rel2 = 0.0, max_r = 0.0;
    for (std::size_t k = 0; k < count; ++k) {
      const auto slot = static_cast<unsigned>(first + k);
      const Vec3 a = bvh.corner(slot, 0), b = bvh.corner(slot, 1), cc = bvh.corner(slot, 2);
      const Vec3& centre = centres[k];
      const double r = std::sqrt(std::max({(a - centre).squaredNorm(), (b - centre).squaredNorm(),
                                           (cc - centre).squaredNorm()}));
      // The computed normal's direction error is about 1e-16 / sin(angle at a): trust it only when
      // that angle is not tiny (error < 1e-12), otherwise fall back to the sphere bound (n = 0).
      const Vec3 ab = b - a, ac = cc - a;
      const Vec3 n = ab.cross(ac);
      const double n_len2 = n.squaredNorm();
      const Vec3 unit = n_len2 > 1e-8 * ab.squaredNorm() * ac.squaredNorm() ? Vec3(n / std::sqrt(n_len2))
                                                                           : Vec3::Zero();
      const Vec3 rel = centre - anchor;
      block[0 * K + k] = static_cast<float>(rel.x());
      block[1 * K + k] = static_cast<float>(rel.y());
      block[2 * K + k] = static_cast<float>(rel.z());
      block[3 * K + k] = static_cast<float>(unit.x());
      block[4 * K + k] = static_cast<float>(unit.y());
      block[5 * K + k] = static_cast<float>(unit.z());
      block[6 * K + k] = round_up(r);  // rounded up: the disc still holds the triangle
      max_rel2 = std::max(max_rel2, rel.squaredNorm());
      max_r = std::max(max_r, r);
    }
    extent[cluster] = std::sqrt(max_rel2) + max_r;
  }
  bvh.cluster_extent = num_clusters > 0 ? *std::max_element(extent.begin(), extent.end()) : 0.0;
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
  const int nx = bvh.grid_n[0], ny = bvh.grid_n[1], nz = bvh.grid_n[2];
  const auto centre_of = [&](int i, int j, int k) {
    return Vec3(bvh.grid_lo.x() + (i + 0.5) * cell, bvh.grid_lo.y() + (j + 0.5) * cell,
                bvh.grid_lo.z() + (k + 0.5) * cell);
  };
  const auto cell_index = [&](int i, int j, int k) {
    return static_cast<std::size_t>(i) + static_cast<std::size_t>(nx) * (static_cast<std::size_t>(j) + static_cast<std::size_t>(ny) * static_cast<std::size_t>(k));
  };
  // Offers vertex v to cell (i, j, k): kept if nearer to its centre than the current one.
  const auto offer = [&](int i, int j, int k, unsigned v) {
    if (v == kNone) return;
    unsigned& current = bvh.grid_vertex[cell_index(i, j, k)];
    const Vec3 c = centre_of(i, j, k);
    if (current == kNone || bvh.vertex_distance2(v, c) < bvh.vertex_distance2(current, c)) current = v;
  };
  for (unsigned v = 0; v < num_welded; ++v) {
    const Vec3 x(bvh.vertex_xyz[3 * v], bvh.vertex_xyz[3 * v + 1], bvh.vertex_xyz[3 * v + 2]);
    int ijk[3];
    for (int k = 0; k < 3; ++k) {
      ijk[k] = std::clamp(static_cast<int>((x[k] - bvh.grid_lo[k]) / cell), 0, bvh.grid_n[k] - 1);
    }
    offer(ijk[0], ijk[1], ijk[2], v);
  }
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        if (i > 0) offer(i, j, k, bvh.grid_vertex[cell_index(i - 1, j, k)]);
        if (j > 0) offer(i, j, k, bvh.grid_vertex[cell_index(i, j - 1, k)]);
        if (k > 0) offer(i, j, k, bvh.grid_vertex[cell_index(i, j, k - 1)]);
      }
    }
  }
  for (int k = nz - 1; k >= 0; --k) {
    for (int j = ny - 1; j >= 0; --j) {
      for (int i = nx - 1; i >= 0; --i) {
        if (i + 1 < nx) offer(i, j, k, bvh.grid_vertex[cell_index(i + 1, j, k)]);
        if (j + 1 < ny) offer(i, j, k, bvh.grid_vertex[cell_index(i, j + 1, k)]);
        if (k + 1 < nz) offer(i, j, k, bvh.grid_vertex[cell_index(i, j, k + 1)]);
      }
    }
  }
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
  bvh.scene = rtcNewScene(bvh.device);
  rtcSetSceneFlags(bvh.scene, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(bvh.scene, refittable ? RTC_BUILD_QUALITY_LOW : RTC_BUILD_QUALITY_HIGH);
  RTCGeometry geom = rtcNewGeometry(bvh.device, RTC_GEOMETRY_TYPE_USER);
  if (refittable) rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_REFIT);
  rtcSetGeometryUserPrimitiveCount(geom, (bvh.num_slots + MeshQuery::Bvh::kCluster - 1) / MeshQuery::Bvh::kCluster);
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

MeshQuery::MeshQuery(const TriMesh& mesh) : mesh_(mesh), bvh_(std::make_unique<Bvh>()) {
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
  const std::vector<Eigen::Index> order = spatial_order(centroids);
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
    struct Keyed {
      double x, y, z;
      unsigned rank;
    };
    std::vector<Keyed> by_position(used.size());
    for (std::size_t i = 0; i < used.size(); ++i) {
      by_position[i] = {mesh_.V(used[i], 0), mesh_.V(used[i], 1), mesh_.V(used[i], 2), static_cast<unsigned>(i)};
    }
    std::sort(by_position.begin(), by_position.end(), [](const Keyed& a, const Keyed& b) {
      return std::tie(a.x, a.y, a.z, a.rank) < std::tie(b.x, b.y, b.z, b.rank);
    });
    // Each rank's representative: the lowest rank with the same position (first in its run).
    std::vector<unsigned> representative(used.size());
    for (std::size_t i = 0; i < by_position.size(); ++i) {
      const Keyed& a = by_position[i];
      const bool same = i > 0 && a.x == by_position[i - 1].x && a.y == by_position[i - 1].y &&
                        a.z == by_position[i - 1].z;
      representative[a.rank] = same ? representative[by_position[i - 1].rank] : a.rank;
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

  }
  update_welded_positions(bvh, mesh_);
  build_start_grid(bvh);

  bvh.device = rtcNewDevice(nullptr);
  if (bvh.device == nullptr) throw_internal("Embree: cannot create a device");
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
  build_start_grid(bvh);
  if (!bvh.refittable) {
    build_scene(bvh, true);  // first update: one build of the refittable tree
    return;
  }
  rtcCommitGeometry(bvh.geometry);
  rtcCommitScene(bvh.scene);
  if (const RTCError err = rtcGetDeviceError(bvh.device); err != RTC_ERROR_NONE) {
    throw_internal("Embree failed to refit the BVH (error code " +
                   std::to_string(static_cast<int>(err)) + ")");
  }
}

MeshQuery::~MeshQuery() = default;
MeshQuery::MeshQuery(MeshQuery&&) noexcept = default;
MeshQuery& MeshQuery::operator=(MeshQuery&&) noexcept = default;

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
  q.radius_pad = bvh_->pad + std::ldexp(p.cwiseAbs().maxCoeff(), -20);
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
  RTCPointQueryContext context;
  rtcInitPointQueryContext(&context);
  rtcPointQuery(bvh_->scene, &query, &context, point_query_callback, &q);

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
  const std::vector<Eigen::Index> order = spatial_order(P);
  const std::size_t blocks = (order.size() + kBlock - 1) / kBlock;
  // Each block starts without a hint, so the result does not depend on how blocks are scheduled.
  parallel_for(blocks, [&](std::size_t b) {
    int hint = -1;
    const std::size_t end = std::min(order.size(), (b + 1) * kBlock);
    for (std::size_t k = b * kBlock; k < end; ++k) {
      const Eigen::Index i = order[k];
      ClosestPoint& c = out[static_cast<std::size_t>(i)];
      c = closest_with_hint(P.row(i).transpose(), hint, std::numeric_limits<double>::infinity());
      hint = c.triangle;
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
