// Spatial queries on a triangle mesh: closest point, signed distance, inside/outside, ray casts.
//
// Two ways to use it (geometry-central style):
//   - MeshQuery: built once per mesh (a BVH from Embree 3), immutable afterwards; every query is
//     const and thread-safe, and the batched versions run in parallel with deterministic results.
//   - one-off free functions (closest_point_on_triangle, intersect_ray_triangle) that are the exact
//     double-precision kernels the BVH calls, usable on their own.
//
// Conventions: positions in the mesh's length unit (metres in fascicle), triangles counter-clockwise
// seen from outside (outward normals). Signed distance is negative inside, positive outside.
// Barycentric coordinates (w0, w1, w2) refer to the triangle's vertices F(t,0), F(t,1), F(t,2):
// point = w0*V(F(t,0)) + w1*V(F(t,1)) + w2*V(F(t,2)), w >= 0, sum 1.
// All computations on the geometry are in double; Embree's float bounds are only used for culling
// and are rounded outward and padded, so the results equal an exhaustive search (docs/geometry-queries.md).
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"

#include <limits>
#include <memory>
#include <optional>
#include <vector>

namespace fascicle {

// One flag per query point (bytes, so parallel writes to neighbours are safe).
using InsideFlags = Eigen::Array<bool, Eigen::Dynamic, 1>;

// The closest point of a triangle to a query point.
struct TrianglePoint {
  Vec3 point = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
  Vec3 barycentric = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());  // of (a, b, c)
};

// The closest point on a mesh surface to a query point.
struct ClosestPoint {
  Vec3 point = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
  int triangle = -1;  // row of F
  Vec3 barycentric = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
  double distance = std::numeric_limits<double>::infinity();  // |query - point|
};

// A ray-triangle intersection. The ray is origin + t * direction (direction need not be unit; t is
// in units of |direction|).
struct RayHit {
  double t = std::numeric_limits<double>::infinity();
  int triangle = -1;
  Vec3 barycentric = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
  Vec3 normal = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());  // unit, geometric, outward
  bool front_facing = false;  // the ray enters through the triangle's front (dot(normal, dir) < 0)
};

// Exact closest point of triangle (a, b, c) to p, by Voronoi regions (Ericson 2005, "Real-Time
// Collision Detection", section 5.1.5), in double. Degenerate (zero-area) triangles are handled
// by their edges.
TrianglePoint closest_point_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c);

// Watertight ray-triangle intersection (Woop, Benthin and Wald 2013, JCGT 2(1)), in double: a ray
// through a shared edge hits at least one of the two triangles. Returns a hit with t in
// (t_min, t_max), or nothing. `on_edge` (optional) is set when the ray passes exactly through an
// edge or vertex (a barycentric coordinate is exactly 0), when the ray lies in the triangle's
// plane (within 1e-8 rad: no hit is reported then, its t would be rounding noise) and its part
// with t in [t_min, t_max] touches the triangle, or when the triangle is degenerate and its
// corners' span along the ray meets the range.
std::optional<RayHit> intersect_ray_triangle(const Vec3& origin, const Vec3& direction,
                                             const Vec3& a, const Vec3& b, const Vec3& c,
                                             double t_min = 0.0,
                                             double t_max = std::numeric_limits<double>::infinity(),
                                             bool* on_edge = nullptr);

// How a MeshQuery is built. Every choice gives identical results (the exhaustive answer); they
// differ only in speed (docs/geometry-queries.md).
struct MeshQueryOptions {
  // The tree that answers closest-point queries.
  //   compact (default): leaves of <= 16 triangles made by Embree's SAH builder (rtcBuildBVH),
  //     stored in a 4-wide float tree with per-leaf slab-cylinder bounds and traversed nearest
  //     child first without callbacks. About 45 % fewer instructions per closest-point query
  //     than embree_clusters; the build takes ~1.7x as long.
  //   embree_clusters: Embree's own point query over an Embree scene whose primitives are runs of
  //     16 Morton-ordered triangles (callbacks per cluster); the previous default.
  // Rays and inside tests always use an Embree scene over the same clusters.
  enum class ClosestPointTree { embree_clusters, compact };
  ClosestPointTree closest_point_tree = ClosestPointTree::compact;
};

// Spatial query object over one triangle mesh. Build once (O(F log F)); queries are const,
// allocation-free for single points, and safe to call from many threads at once.
class MeshQuery {
 public:
  // Copies the mesh (kept in double for all exact computations) and builds the BVH. Throws
  // fascicle::Error (bad input) on an empty mesh, non-finite coordinates or out-of-range indices.
  explicit MeshQuery(const TriMesh& mesh);
  MeshQuery(const TriMesh& mesh, const MeshQueryOptions& options);
  ~MeshQuery();
  MeshQuery(MeshQuery&&) noexcept;
  MeshQuery& operator=(MeshQuery&&) noexcept;
  MeshQuery(const MeshQuery&) = delete;
  MeshQuery& operator=(const MeshQuery&) = delete;

  const TriMesh& get_mesh() const { return mesh_; }

  // New vertex positions for the same mesh (same vertex count, same triangles), e.g. a deforming
  // muscle between frames. Refits the BVH (the compact tree, which rays of a surface of at most
  // 1024 clusters use too; otherwise Embree's REFIT build as well, committed at the first ray after the update) and updates every auxiliary
  // structure instead of rebuilding: all queries afterwards return exactly what a MeshQuery built
  // on the deformed mesh returns (the exhaustive answer), only the culling may be a little less
  // tight when the deformation is large. Throws fascicle::Error (bad input) on a different vertex
  // count or non-finite coordinates (the query is then unchanged). Not thread-safe with queries.
  void update_vertices(const Points3& V);

  // Closest point on the surface; if nothing lies within max_distance, triangle = -1.
  ClosestPoint calc_closest_point(
      const Vec3& p, double max_distance = std::numeric_limits<double>::infinity()) const;

  // Inside test by a majority vote of signed ray crossings over up to 5 fixed, well-spread
  // directions (the signed crossing count along a ray equals the winding number of a closed
  // mesh). Rays that graze an edge or vertex abstain; if no majority remains, the exact generalised
  // winding number decides (threshold 1/2). Tolerates small holes and nested/overlapping shells.
  bool calc_is_inside(const Vec3& p) const;

  // Signed distance: -distance inside, +distance outside (sign from calc_is_inside).
  double calc_signed_distance(const Vec3& p) const;

  // First hit along origin + t*direction with t in (t_min, t_max), or nothing. The range must
  // satisfy 0 <= t_min <= t_max (t_max may be infinite); otherwise fascicle::Error (bad_input).
  std::optional<RayHit> cast_ray(const Vec3& origin, const Vec3& direction, double t_min = 0.0,
                                 double t_max = std::numeric_limits<double>::infinity()) const;

  // Every hit along the ray with t in (t_min, t_max), sorted by t (then triangle index). Same
  // range rules as cast_ray.
  std::vector<RayHit> cast_ray_all(
      const Vec3& origin, const Vec3& direction, double t_min = 0.0,
      double t_max = std::numeric_limits<double>::infinity()) const;

  // Sum of signed crossings (+1 leaving through a face, i.e. along its outward normal; -1 entering)
  // along the ray from p:
  // the winding number at p for a closed mesh. Returns nothing when the ray grazes an edge or vertex.
  std::optional<int> calc_crossing_number(const Vec3& p, const Vec3& direction) const;

  // Batched versions over #P x 3 points, in parallel (fascicle::parallel_for); results depend only
  // on the inputs, not on the thread count. Points are processed in spatially coherent blocks so
  // each query starts from the previous query's triangle as an upper bound.
  std::vector<ClosestPoint> calc_closest_points(const Points3& P) const;
  VecX calc_distances(const Points3& P) const;
  VecX calc_signed_distances(const Points3& P) const;
  InsideFlags calc_is_inside(const Points3& P) const;

  // Implementation detail: the Embree device and scene plus the packed double triangles its
  // callbacks read (defined in the .cpp so Embree stays out of this header; heap-allocated so its
  // address survives moves of the MeshQuery).
  struct Bvh;

 private:
  ClosestPoint closest_with_hint(const Vec3& p, int hint_triangle, double max_distance) const;

  TriMesh mesh_;
  std::unique_ptr<Bvh> bvh_;
};

}  // namespace fascicle
