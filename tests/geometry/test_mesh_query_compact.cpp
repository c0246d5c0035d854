// The compact closest-point tree (MeshQueryOptions::ClosestPointTree::compact: Embree's SAH builder,
// our 4-wide float layout and traversal) against exhaustive search and, bit for bit, against the
// Embree-scene path: random points in and around the box, points on the surface, far points,
// degenerate and duplicated triangles (ties), the Visible Human tibia, inside tests, rays and
// update_vertices (refit).
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/geometry/winding_number.hpp"

#include "binary_stl.hpp"
#include "test_support.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <fstream>
#include <random>

namespace fascicle {
namespace {

constexpr MeshQueryOptions kCompact{MeshQueryOptions::ClosestPointTree::compact};
constexpr MeshQueryOptions kClusters{MeshQueryOptions::ClosestPointTree::embree_clusters};

Vec3 vertex(const TriMesh& m, Eigen::Index f, int k) { return m.V.row(m.F(f, k)).transpose(); }

// Exhaustive search with MeshQuery's rule: smallest squared distance, then the lowest index.
ClosestPoint brute_closest(const TriMesh& m, const Vec3& p) {
  ClosestPoint best;
  double best_d2 = std::numeric_limits<double>::infinity();
  for (Eigen::Index f = 0; f < m.F.rows(); ++f) {
    const TrianglePoint tp = closest_point_on_triangle(p, vertex(m, f, 0), vertex(m, f, 1), vertex(m, f, 2));
    const double d2 = (p - tp.point).squaredNorm();
    if (d2 < best_d2) {
      best_d2 = d2;
      best.point = tp.point;
      best.triangle = static_cast<int>(f);
      best.barycentric = tp.barycentric;
      best.distance = std::sqrt(d2);
    }
  }
  return best;
}

// Points of four kinds: uniform in the bounding box enlarged by 20 %; on the surface (random
// barycentrics, and exact vertices); 1e-3 and 1e-7 of the box size off the surface along the face
// normal; far away (1 ... 30 box sizes from the centre in random directions).
Points3 sample_points(const TriMesh& m, int n_each, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_int_distribution<Eigen::Index> pick(0, m.F.rows() - 1);
  const Vec3 lo = m.V.colwise().minCoeff().transpose(), hi = m.V.colwise().maxCoeff().transpose();
  const Vec3 c = 0.5 * (lo + hi), h = 0.6 * (hi - lo);
  const double size = std::max((hi - lo).norm(), 1e-300);
  Points3 P(4 * n_each, 3);
  for (int i = 0; i < n_each; ++i) {
    for (int k = 0; k < 3; ++k) P(i, k) = c[k] + (2.0 * u(rng) - 1.0) * h[k];
  }
  for (int i = 0; i < 2 * n_each; ++i) {
    const Eigen::Index f = pick(rng);
    double a = u(rng), b = u(rng);
    if (a + b > 1.0) {
      a = 1.0 - a;
      b = 1.0 - b;
    }
    const Vec3 A = vertex(m, f, 0), B = vertex(m, f, 1), C = vertex(m, f, 2);
    Vec3 q = A + a * (B - A) + b * (C - A);
    if (i % 5 == 0) q = vertex(m, f, static_cast<int>(i % 3));  // exactly a vertex
    const Vec3 n = (B - A).cross(C - A);
    const double offsets[] = {0.0, 1e-3, -1e-3, 1e-7, -1e-7};
    const double off = i < n_each ? 0.0 : offsets[1 + i % 4];
    if (n.squaredNorm() > 0.0) q += off * size * n.normalized();
    P.row(n_each + i) = q.transpose();
  }
  for (int i = 0; i < n_each; ++i) {
    const Vec3 d = Vec3(g(rng), g(rng), g(rng)).normalized();
    P.row(3 * n_each + i) = (c + d * size * std::pow(30.0, u(rng))).transpose();
  }
  return P;
}

// The compact tree's closest points (single and batched) equal the exhaustive search (triangle,
// distance to 1e-12) and, bit for bit, the Embree-scene path's; inside tests and rays agree too.
void check_compact(const TriMesh& mesh, int n_each, std::uint64_t seed, bool check_rays = true) {
  const MeshQuery compact(mesh, kCompact);
  const MeshQuery clusters(mesh, kClusters);
  const Points3 P = sample_points(mesh, n_each, seed);
  const std::vector<ClosestPoint> batch = compact.calc_closest_points(P);
  const std::vector<ClosestPoint> batch_ref = clusters.calc_closest_points(P);
  std::mt19937_64 rng(seed + 1);
  std::normal_distribution<double> g(0.0, 1.0);
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const Vec3 p = P.row(i).transpose();
    const auto k = static_cast<std::size_t>(i);
    const ClosestPoint bf = brute_closest(mesh, p);
    const ClosestPoint one = compact.calc_closest_point(p);
    ASSERT_EQ(one.triangle, bf.triangle) << "point " << i;
    ASSERT_NEAR(one.distance, bf.distance, 1e-12 * bf.distance) << "point " << i;
    ASSERT_EQ(one.barycentric, bf.barycentric) << "point " << i;
    ASSERT_EQ(batch[k].triangle, bf.triangle) << "point " << i;
    ASSERT_EQ(batch[k].distance, one.distance) << "point " << i;
    const ClosestPoint ref = clusters.calc_closest_point(p);
    ASSERT_EQ(one.triangle, ref.triangle) << "point " << i;
    ASSERT_EQ(one.distance, ref.distance) << "point " << i;
    ASSERT_EQ(one.point, ref.point) << "point " << i;
    ASSERT_EQ(one.barycentric, ref.barycentric) << "point " << i;
    ASSERT_EQ(batch[k].point, batch_ref[k].point) << "point " << i;
    // A max distance just below the answer finds nothing; at the answer it finds it.
    if (bf.distance > 0.0 && i % 7 == 0) {
      ASSERT_EQ(compact.calc_closest_point(p, 0.999 * bf.distance).triangle, -1) << "point " << i;
      ASSERT_EQ(compact.calc_closest_point(p, 1.001 * bf.distance).triangle, bf.triangle) << "point " << i;
    }
    if (check_rays && i % 3 == 0) {
      ASSERT_EQ(compact.calc_is_inside(p), clusters.calc_is_inside(p)) << "point " << i;
      const Vec3 d(g(rng), g(rng), g(rng));
      const std::optional<RayHit> ra = compact.cast_ray(p, d), rb = clusters.cast_ray(p, d);
      ASSERT_EQ(ra.has_value(), rb.has_value()) << "ray " << i;
      if (ra) {
        ASSERT_EQ(ra->t, rb->t) << "ray " << i;
        ASSERT_EQ(ra->triangle, rb->triangle) << "ray " << i;
      }
      ASSERT_EQ(compact.cast_ray_all(p, d).size(), clusters.cast_ray_all(p, d).size()) << "ray " << i;
    }
  }
}

TEST(MeshQueryCompact, IcosphereTorusBoxAgainstBruteForce) {
  check_compact(make_icosphere(0.05, 3), 300, 1);
  check_compact(make_torus(0.04, 0.012, 40, 20), 300, 2);
  check_compact(make_box(Vec3(0.03, 0.01, 0.02)), 300, 3);  // axis-aligned faces, many ties
}

TEST(MeshQueryCompact, FarFromTheOrigin) {
  TriMesh m = make_ellipsoid(Vec3(0.02, 0.01, 0.015), 3);
  m.V.rowwise() += Eigen::RowVector3d(120.0, -75.0, 33.0);
  check_compact(m, 200, 4);
}

TEST(MeshQueryCompact, TinyMeshesAreOneLeaf) {
  TriMesh one;
  one.V = Points3(3, 3);
  one.V << 0, 0, 0, 1, 0, 0, 0, 1, 0;
  one.F = Triangles(1, 3);
  one.F << 0, 1, 2;
  check_compact(one, 50, 5);
  check_compact(make_box(Vec3(1, 2, 3)), 50, 6);  // 12 triangles
  TriMesh point;  // every vertex at the origin
  point.V = Points3::Zero(3, 3);
  point.F = one.F;
  const MeshQuery q(point, kCompact);
  EXPECT_DOUBLE_EQ(q.calc_closest_point(Vec3(0, 3, 4)).distance, 5.0);
}

TEST(MeshQueryCompact, DegenerateAndDuplicatedTrianglesAgainstBruteForce) {
  // An icosphere plus: a needle (three collinear vertices), triangles collapsed to a point,
  // slivers, and every 10th triangle repeated (same corners, higher index: ties must go to the
  // lower index), shuffled so the duplicates land in other leaves.
  TriMesh m = make_icosphere(0.05, 2);
  const Eigen::Index nv = m.V.rows(), nf = m.F.rows();
  m.V.conservativeResize(nv + 6, 3);
  m.V.row(nv + 0) = Eigen::RowVector3d(0.06, 0.0, 0.0);
  m.V.row(nv + 1) = Eigen::RowVector3d(0.08, 0.0, 0.0);
  m.V.row(nv + 2) = Eigen::RowVector3d(0.10, 0.0, 0.0);
  m.V.row(nv + 3) = Eigen::RowVector3d(0.0, 0.07, 0.0);
  m.V.row(nv + 4) = Eigen::RowVector3d(0.0, 0.0, 0.07);
  m.V.row(nv + 5) = Eigen::RowVector3d(1e-9, 0.0, 0.07);
  std::vector<Eigen::RowVector3i> extra = {
      {static_cast<int>(nv), static_cast<int>(nv + 1), static_cast<int>(nv + 2)},
      {static_cast<int>(nv + 3), static_cast<int>(nv + 3), static_cast<int>(nv + 3)},
      {static_cast<int>(nv + 4), static_cast<int>(nv + 5), static_cast<int>(nv + 3)},
  };
  for (Eigen::Index f = 0; f < nf; f += 10) extra.emplace_back(m.F.row(f));
  m.F.conservativeResize(nf + static_cast<Eigen::Index>(extra.size()), 3);
  for (std::size_t k = 0; k < extra.size(); ++k) m.F.row(nf + static_cast<Eigen::Index>(k)) = extra[k];
  check_compact(m, 250, 7, false);
  // Points around the needle and the duplicated triangles' vertices.
  const MeshQuery q(m, kCompact);
  std::mt19937_64 rng(8);
  std::normal_distribution<double> g(0.0, 0.005);
  int on_needle = 0, duplicates = 0;
  for (int i = 0; i < 400; ++i) {
    const Vec3 centre = i % 2 == 0 ? Vec3(0.09, 0.0, 0.0) : vertex(m, 10 * (i % 20), 0);
    const Vec3 p = centre + Vec3(g(rng), g(rng), g(rng));
    const ClosestPoint bf = brute_closest(m, p), c = q.calc_closest_point(p);
    ASSERT_EQ(c.triangle, bf.triangle) << "point " << i;
    ASSERT_EQ(c.barycentric, bf.barycentric) << "point " << i;
    ASSERT_NEAR(c.distance, bf.distance, 1e-12 * bf.distance) << "point " << i;
    on_needle += c.triangle == nf ? 1 : 0;
    duplicates += (c.triangle < nf && c.triangle % 10 == 0) ? 1 : 0;
  }
  EXPECT_GT(on_needle, 50);
  EXPECT_GT(duplicates, 10);  // ties between a triangle and its copy really occurred
}

// The seed (vertex descent, then the traversal starting bottom-up from that vertex's leaf) on cap
// centres of valence 48, on a mesh so far from the origin that float cannot tell its vertices
// apart (the float boxes are then padded far beyond the mesh; the answer must not depend on it),
// and on a cylinder with its triangles shuffled (neighbours far apart in the leaves).
TEST(MeshQueryCompact, SeedOnHighValenceAndUnresolvableMeshes) {
  const TriMesh cylinder = make_cylinder(0.02, 0.08, 48, 3);
  check_compact(cylinder, 200, 21);
  TriMesh far = make_ellipsoid(Vec3(0.02, 0.01, 0.015), 2);
  far.V.rowwise() += Eigen::RowVector3d(3.0e6, -2.0e6, 1.0e6);  // float spacing 0.25 m here
  check_compact(far, 60, 22, false);
  TriMesh shuffled = cylinder;
  std::mt19937_64 rng(23);
  for (Eigen::Index f = shuffled.F.rows() - 1; f > 0; --f) {
    const Eigen::Index g = std::uniform_int_distribution<Eigen::Index>(0, f)(rng);
    shuffled.F.row(f).swap(shuffled.F.row(g));
  }
  check_compact(shuffled, 100, 24);
}

const TriMesh& tibia() {
  static const TriMesh m =
      test::read_binary_stl_mm(test::data_path("visible_human_female/right/VHF_Right_Bone_Tibia_smooth.stl"));
  return m;
}

TEST(MeshQueryCompact, VisibleHumanTibiaAgainstBruteForce) {
  ASSERT_GT(tibia().F.rows(), 50000);
  check_compact(tibia(), 40, 9);
}

// A smooth deformation: twist about z, bulge in x, shift.
Points3 deform(const Points3& V, double amount) {
  Points3 W = V;
  const Vec3 lo = V.colwise().minCoeff().transpose(), hi = V.colwise().maxCoeff().transpose();
  const Vec3 c = 0.5 * (lo + hi);
  const double size = (hi - lo).norm();
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    const Vec3 x = V.row(i).transpose() - c;
    const double angle = amount * 2.0 * x.z() / size;
    Vec3 y(std::cos(angle) * x.x() - std::sin(angle) * x.y(), std::sin(angle) * x.x() + std::cos(angle) * x.y(),
           x.z());
    y.x() *= 1.0 + 0.3 * amount * std::sin(3.0 * x.z() / size);
    W.row(i) = (y + c + Vec3(0.01, -0.02, 0.03) * amount * size).transpose();
  }
  return W;
}

// After update_vertices the compact tree (refitted) gives exactly the fresh build's answers.
void check_refit(const TriMesh& rest, const std::vector<double>& amounts, int n_each, std::uint64_t seed,
                 const MeshQueryOptions& options = kCompact) {
  MeshQuery query(rest, options);
  for (const double amount : amounts) {
    TriMesh deformed = rest;
    deformed.V = deform(rest.V, amount);
    query.update_vertices(deformed.V);
    const MeshQuery fresh(deformed, options);
    const Points3 P = sample_points(deformed, n_each, seed);
    const std::vector<ClosestPoint> a = query.calc_closest_points(P), b = fresh.calc_closest_points(P);
    for (Eigen::Index i = 0; i < P.rows(); ++i) {
      const Vec3 p = P.row(i).transpose();
      const auto k = static_cast<std::size_t>(i);
      const ClosestPoint one = query.calc_closest_point(p), ref = fresh.calc_closest_point(p);
      ASSERT_EQ(one.triangle, ref.triangle) << "amount " << amount << " point " << i;
      ASSERT_EQ(one.point, ref.point) << "amount " << amount << " point " << i;
      ASSERT_EQ(one.barycentric, ref.barycentric) << "amount " << amount << " point " << i;
      ASSERT_EQ(a[k].triangle, b[k].triangle) << "amount " << amount << " point " << i;
      ASSERT_EQ(a[k].distance, b[k].distance) << "amount " << amount << " point " << i;
      if (i % 4 == 0) {
        const ClosestPoint bf = brute_closest(deformed, p);
        ASSERT_EQ(one.triangle, bf.triangle) << "amount " << amount << " point " << i;
        ASSERT_EQ(query.calc_is_inside(p), fresh.calc_is_inside(p)) << "amount " << amount << " point " << i;
      }
    }
  }
}

TEST(MeshQueryCompact, UpdateVerticesEqualsFreshBuild) {
  check_refit(make_ellipsoid(Vec3(0.03, 0.02, 0.12), 4), {0.1, 0.5, 1.0, 0.0}, 150, 21);
  // The Embree-scene path keeps its refit too.
  check_refit(make_ellipsoid(Vec3(0.03, 0.02, 0.12), 4), {0.1, 0.5, 1.0, 0.0}, 100, 23, kClusters);
}

// Many small refits, as a deforming muscle surface gets several per frame: the start-vertex grid
// is kept while the vertices stay within a quarter of a cell of where it was built, and the
// Embree commit waits for the next ray. Queries after every third update (closest points, inside
// tests, all ray hits, with rays only there) equal a fresh build's, and the closest points a
// brute-force scan's.
TEST(MeshQueryCompact, SmallRefitStepsGiveTheFreshBuildsAnswers) {
  const TriMesh rest = make_ellipsoid(Vec3(0.03, 0.02, 0.12), 4);
  for (const MeshQueryOptions& options : {kCompact, kClusters}) {
    MeshQuery query(rest, options);
    for (int step = 1; step <= 30; ++step) {
      TriMesh deformed = rest;
      deformed.V = deform(rest.V, 0.01 * step);
      query.update_vertices(deformed.V);
      if (step % 3 != 0) continue;
      const MeshQuery fresh(deformed, options);
      const Points3 P = sample_points(deformed, 60, 40u + static_cast<std::uint64_t>(step));
      for (Eigen::Index i = 0; i < P.rows(); ++i) {
        const Vec3 p = P.row(i).transpose();
        const ClosestPoint one = query.calc_closest_point(p), ref = fresh.calc_closest_point(p);
        ASSERT_EQ(one.triangle, ref.triangle) << "step " << step << " point " << i;
        ASSERT_EQ(one.point, ref.point) << "step " << step << " point " << i;
        ASSERT_EQ(one.triangle, brute_closest(deformed, p).triangle) << "step " << step << " point " << i;
        ASSERT_EQ(query.calc_is_inside(p), fresh.calc_is_inside(p)) << "step " << step << " point " << i;
        const Vec3 d = Vec3(std::sin(1.0 + i), std::cos(2.0 * i), 0.3).normalized();
        const std::vector<RayHit> a = query.cast_ray_all(p, d), b = fresh.cast_ray_all(p, d);
        ASSERT_EQ(a.size(), b.size()) << "step " << step << " ray " << i;
        for (std::size_t k = 0; k < a.size(); ++k) {
          ASSERT_EQ(a[k].triangle, b[k].triangle) << "step " << step << " ray " << i;
          ASSERT_EQ(a[k].t, b[k].t) << "step " << step << " ray " << i;
        }
      }
    }
  }
}

// An open grid surface z = curvature (x^2 - y^2) (a plane when curvature = 0), tilted and placed
// about half a metre from the origin, with `n` x `n` vertices 2 mm apart.
TriMesh make_tilted_grid(int n, double curvature) {
  TriMesh m;
  m.V.resize(static_cast<Eigen::Index>(n) * n, 3);
  const Mat3 R = (Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized())).toRotationMatrix();
  const Vec3 origin(0.5, 0.31, 0.43);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const double x = 0.002 * (i - n / 2), y = 0.002 * (j - n / 2);
      m.V.row(i * n + j) = (origin + R * Vec3(x, y, curvature * (x * x - y * y))).transpose();
    }
  m.F.resize(2 * (n - 1) * (n - 1), 3);
  Eigen::Index f = 0;
  for (int i = 0; i + 1 < n; ++i)
    for (int j = 0; j + 1 < n; ++j) {
      const int a = i * n + j, b = a + 1, c = a + n, d = c + 1;
      m.F.row(f++) << a, c, b;
      m.F.row(f++) << b, c, d;
    }
  return m;
}

// Points almost straight above a vertex (h = 1e-9 ... 1e-4 m along the vertex normal, coordinates
// about 0.5 m): the nearest triangle's computed distance can exceed the vertex distance by
// rounding, which once let the compact tree's seeded bound reject every triangle (no answer).
TEST(MeshQueryCompact, PointsJustAboveAVertexFindTheirTriangle) {
  for (const double curvature : {0.0, 20.0, -35.0}) {
    const TriMesh grid = make_tilted_grid(24, curvature);
    const MeshQuery compact(grid, kCompact), clusters(grid, kClusters);
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    int checked = 0;
    for (Eigen::Index v = 0; v < grid.V.rows(); v += 7) {
      // Vertex normal: the sum of the incident triangles' area normals.
      Vec3 normal = Vec3::Zero();
      for (Eigen::Index f = 0; f < grid.F.rows(); ++f)
        for (int k = 0; k < 3; ++k)
          if (grid.F(f, k) == v)
            normal += (vertex(grid, f, 1) - vertex(grid, f, 0)).cross(vertex(grid, f, 2) - vertex(grid, f, 0));
      normal.normalize();
      for (const double h : {1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4}) {
        for (const double side : {1.0, -1.0}) {
          Vec3 p = grid.V.row(v).transpose() + side * h * normal;
          if (checked % 3 == 0) p += 1e-12 * Vec3(u(rng), u(rng), u(rng));
          const ClosestPoint c = compact.calc_closest_point(p);
          const ClosestPoint e = clusters.calc_closest_point(p);
          const ClosestPoint bf = brute_closest(grid, p);
          ASSERT_GE(c.triangle, 0) << "curvature " << curvature << " vertex " << v << " h " << h;
          ASSERT_EQ(c.triangle, bf.triangle) << "curvature " << curvature << " vertex " << v << " h " << h;
          ASSERT_EQ(c.point, bf.point) << "curvature " << curvature << " vertex " << v << " h " << h;
          ASSERT_EQ(c.triangle, e.triangle) << "curvature " << curvature << " vertex " << v << " h " << h;
          ASSERT_LE(c.distance, h * (1.0 + 1e-6) + 2e-12);  // jitter <= sqrt(3) 1e-12
          ++checked;
        }
      }
    }
    EXPECT_GT(checked, 900);
  }
}

// Batches as the contact and fibre code issues them, where consecutive Morton-ordered points are
// near each other (the batched path seeds each query from the previous one): a dense patch of
// near-surface points, exact duplicates, points along a line through the bone, a far point; batch
// sizes 1, 257 (a full block of 256 and one more) and the odd total. Every answer equals the
// exhaustive search (triangle with the lowest-index tie rule, barycentrics bit for bit) and the
// single query (point and distance bit for bit).
TEST(MeshQueryCompact, CoherentBatchesOnTheTibiaAgainstBruteForce) {
  const TriMesh& m = tibia();
  const MeshQuery query(m);
  std::mt19937_64 rng(31);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const Vec3 lo = m.V.colwise().minCoeff().transpose(), hi = m.V.colwise().maxCoeff().transpose();
  std::vector<Vec3> points;
  // A patch of 3 x 3 mm around a surface point, 0.5 ... 5 mm off along the face normal, both sides.
  const Eigen::Index f0 = m.F.rows() / 3;
  const Vec3 a = vertex(m, f0, 0), b = vertex(m, f0, 1), c = vertex(m, f0, 2);
  const Vec3 n = (b - a).cross(c - a).normalized();
  const Vec3 t1 = (b - a).normalized(), t2 = n.cross(t1);
  const Vec3 centre = (a + b + c) / 3.0;
  for (int i = 0; i < 60; ++i) {
    const double off = (i % 2 == 0 ? 1.0 : -1.0) * (0.5e-3 + 4.5e-3 * u(rng));
    points.push_back(centre + 3e-3 * (u(rng) - 0.5) * t1 + 3e-3 * (u(rng) - 0.5) * t2 + off * n);
  }
  // Exact duplicates (a degenerate group: zero extent).
  for (int i = 0; i < 20; ++i) points.push_back(points[static_cast<std::size_t>(i % 3)]);
  // Points on a line across the bone's middle (collinear: a flat group box), and on the surface.
  const Vec3 mid = 0.5 * (lo + hi);
  for (int i = 0; i < 40; ++i) {
    const double s = static_cast<double>(i) / 39.0;
    points.push_back(Vec3(lo.x() - 0.01 + s * (hi.x() - lo.x() + 0.02), mid.y(), mid.z()));
  }
  for (int i = 0; i < 10; ++i) points.push_back(vertex(m, f0 + 7 * i, i % 3));
  points.push_back(mid + Vec3(0.3, -0.2, 0.1));  // far away
  std::vector<ClosestPoint> expected;
  for (const Vec3& p : points) expected.push_back(brute_closest(m, p));
  const auto check = [&](const std::vector<std::size_t>& rows) {
    Points3 P(static_cast<Eigen::Index>(rows.size()), 3);
    for (std::size_t r = 0; r < rows.size(); ++r) P.row(static_cast<Eigen::Index>(r)) = points[rows[r]].transpose();
    const std::vector<ClosestPoint> batch = query.calc_closest_points(P);
    const VecX distances = query.calc_distances(P);
    ASSERT_EQ(batch.size(), rows.size());
    for (std::size_t r = 0; r < rows.size(); ++r) {
      const ClosestPoint& e = expected[rows[r]];
      const ClosestPoint one = query.calc_closest_point(points[rows[r]]);
      ASSERT_EQ(batch[r].triangle, e.triangle) << "row " << r << " of " << rows.size();
      ASSERT_EQ(batch[r].barycentric, e.barycentric) << "row " << r;
      ASSERT_NEAR(batch[r].distance, e.distance, 1e-12 * e.distance + 1e-300) << "row " << r;
      ASSERT_EQ(batch[r].point, one.point) << "row " << r;
      ASSERT_EQ(batch[r].distance, one.distance) << "row " << r;
      ASSERT_EQ(distances[static_cast<Eigen::Index>(r)], one.distance) << "row " << r;
    }
  };
  std::vector<std::size_t> all(points.size());
  for (std::size_t i = 0; i < all.size(); ++i) all[i] = i;
  ASSERT_EQ(all.size() % 256 == 0, false);
  check(all);
  std::vector<std::size_t> block;  // 257 rows: the points twice over, shuffled
  for (std::size_t i = 0; i < 257; ++i) block.push_back((i * 7919) % points.size());
  check(block);
  for (std::size_t i = 0; i < points.size(); i += 13) check({i});  // one-point batches
}

// A point equidistant from two triangles (above their shared edge) gets the lower index, in single
// and batched queries, whichever order the triangles are listed in.
TEST(MeshQueryCompact, TiesGoToTheLowestTriangleIndex) {
  for (const bool swapped : {false, true}) {
    TriMesh m;
    m.V.resize(4, 3);
    m.V << 0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0;
    m.F.resize(2, 3);
    if (swapped) {
      m.F << 0, 2, 3, 0, 1, 2;
    } else {
      m.F << 0, 1, 2, 0, 2, 3;
    }
    const MeshQuery query(m);
    Points3 P(5, 3);
    P << 0.5, 0.5, 0.3, 0.25, 0.25, -0.2, 0.5, 0.5, 0.3, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0;
    const std::vector<ClosestPoint> batch = query.calc_closest_points(P);
    for (Eigen::Index i = 0; i < P.rows(); ++i) {
      const Vec3 p = P.row(i).transpose();
      const ClosestPoint bf = brute_closest(m, p);
      EXPECT_EQ(bf.triangle, 0);  // every point lies on the shared diagonal's vertical plane
      EXPECT_EQ(query.calc_closest_point(p).triangle, 0) << "point " << i << " swapped " << swapped;
      EXPECT_EQ(batch[static_cast<std::size_t>(i)].triangle, 0) << "point " << i << " swapped " << swapped;
      EXPECT_EQ(batch[static_cast<std::size_t>(i)].barycentric, bf.barycentric) << "point " << i;
    }
  }
}

TEST(MeshQueryCompact, DefaultIsTheCompactTree) {
  EXPECT_EQ(MeshQueryOptions{}.closest_point_tree, MeshQueryOptions::ClosestPointTree::compact);
}

TEST(MeshQueryCompact, UpdateVerticesOnTheVisibleHumanTibia) {
  check_refit(tibia(), {0.15, 0.3}, 30, 22);
}

}  // namespace
}  // namespace fascicle
