// MeshQuery against exhaustive search: closest points, inside tests, ray casts; the exact kernels
// against independent checks.
#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/geometry/winding_number.hpp"

#include "binary_stl.hpp"
#include "test_support.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <limits>
#include <numbers>
#include <random>
#include <type_traits>

namespace fascicle {
namespace {

Vec3 vertex(const TriMesh& m, Eigen::Index f, int k) { return m.V.row(m.F(f, k)).transpose(); }

// Exhaustive closest point.
ClosestPoint brute_closest(const TriMesh& m, const Vec3& p) {
  ClosestPoint best;
  for (Eigen::Index f = 0; f < m.F.rows(); ++f) {
    const TrianglePoint tp = closest_point_on_triangle(p, vertex(m, f, 0), vertex(m, f, 1), vertex(m, f, 2));
    const double d = (p - tp.point).norm();
    if (d < best.distance) {
      best.distance = d;
      best.point = tp.point;
      best.triangle = static_cast<int>(f);
      best.barycentric = tp.barycentric;
    }
  }
  return best;
}

// Exhaustive ray hits (t > 0), sorted by t.
std::vector<RayHit> brute_hits(const TriMesh& m, const Vec3& o, const Vec3& d) {
  std::vector<RayHit> hits;
  for (Eigen::Index f = 0; f < m.F.rows(); ++f) {
    if (auto h = intersect_ray_triangle(o, d, vertex(m, f, 0), vertex(m, f, 1), vertex(m, f, 2))) {
      h->triangle = static_cast<int>(f);
      hits.push_back(*h);
    }
  }
  std::sort(hits.begin(), hits.end(), [](const RayHit& a, const RayHit& b) {
    return a.t != b.t ? a.t < b.t : a.triangle < b.triangle;
  });
  return hits;
}

// Random points: uniform in the bounding box enlarged by 20%, plus points near the surface (random
// surface points moved along the face normal by +-1e-3 and +-1e-7 of the box size).
Points3 sample_points(const TriMesh& m, int n_box, int n_near, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const Vec3 lo = m.V.colwise().minCoeff().transpose(), hi = m.V.colwise().maxCoeff().transpose();
  const Vec3 c = 0.5 * (lo + hi), h = 0.6 * (hi - lo);
  const double size = (hi - lo).norm();
  Points3 P(n_box + n_near, 3);
  for (int i = 0; i < n_box; ++i) {
    for (int k = 0; k < 3; ++k) P(i, k) = c[k] + (2.0 * u(rng) - 1.0) * h[k];
  }
  std::uniform_int_distribution<Eigen::Index> pick(0, m.F.rows() - 1);
  const double offsets[] = {1e-3, -1e-3, 1e-7, -1e-7};
  for (int i = 0; i < n_near; ++i) {
    const Eigen::Index f = pick(rng);
    double a = u(rng), b = u(rng);
    if (a + b > 1.0) { a = 1.0 - a; b = 1.0 - b; }
    const Vec3 A = vertex(m, f, 0), B = vertex(m, f, 1), C = vertex(m, f, 2);
    const Vec3 n = (B - A).cross(C - A).normalized();
    P.row(n_box + i) = (A + a * (B - A) + b * (C - A) + offsets[i % 4] * size * n).transpose();
  }
  return P;
}

// The same checks on any mesh: closest point and inside against exhaustive search.
void check_against_brute_force(const TriMesh& mesh, int n_box, int n_near, std::uint64_t seed) {
  const MeshQuery query(mesh);
  const Points3 P = sample_points(mesh, n_box, n_near, seed);
  const std::vector<ClosestPoint> batch = query.calc_closest_points(P);
  const InsideFlags inside = query.calc_is_inside(P);
  const VecX w = compute_winding_numbers(mesh, P);
  int checked_inside = 0;
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const Vec3 p = P.row(i).transpose();
    const ClosestPoint bf = brute_closest(mesh, p);
    const ClosestPoint one = query.calc_closest_point(p);
    const ClosestPoint& many = batch[static_cast<std::size_t>(i)];
    ASSERT_NEAR(one.distance, bf.distance, 1e-12 * bf.distance) << "point " << i;
    ASSERT_NEAR(many.distance, bf.distance, 1e-12 * bf.distance) << "point " << i;
    // The reported point is on the reported triangle, at the reported barycentrics and distance.
    const Vec3 q = one.barycentric[0] * vertex(mesh, one.triangle, 0) +
                   one.barycentric[1] * vertex(mesh, one.triangle, 1) +
                   one.barycentric[2] * vertex(mesh, one.triangle, 2);
    ASSERT_LT((q - one.point).norm(), 1e-12 * (1.0 + one.point.norm()));
    ASSERT_NEAR((p - one.point).norm(), one.distance, 1e-15 + 1e-14 * one.distance);
    ASSERT_NEAR(one.barycentric.sum(), 1.0, 1e-14);
    ASSERT_GE(one.barycentric.minCoeff(), -1e-15);
    // Inside agrees with the exact winding number away from the surface itself.
    if (bf.distance > 1e-9) {
      ASSERT_EQ(inside[i], w[i] > 0.5) << "point " << i << " w=" << w[i];
      ASSERT_EQ(query.calc_is_inside(p), w[i] > 0.5);
      const double sd = query.calc_signed_distance(p);
      ASSERT_EQ(sd < 0.0, w[i] > 0.5);
      ASSERT_NEAR(std::abs(sd), bf.distance, 1e-12 * bf.distance);
      ++checked_inside;
    }
  }
  EXPECT_GT(checked_inside, n_box);
}

TEST(ClosestPointOnTriangle, MatchesDenseSampling) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> g(0.0, 1.0);
  const int grid = 200;
  for (int trial = 0; trial < 200; ++trial) {
    const Vec3 a(g(rng), g(rng), g(rng)), b(g(rng), g(rng), g(rng)), c(g(rng), g(rng), g(rng));
    const Vec3 p = 1.5 * Vec3(g(rng), g(rng), g(rng));
    const TrianglePoint tp = closest_point_on_triangle(p, a, b, c);
    const double d = (p - tp.point).norm();
    double d_grid = std::numeric_limits<double>::infinity();
    for (int i = 0; i <= grid; ++i) {
      for (int j = 0; i + j <= grid; ++j) {
        const double s = double(i) / grid, t = double(j) / grid;
        d_grid = std::min(d_grid, (p - (a + s * (b - a) + t * (c - a))).norm());
      }
    }
    const double h = std::max({(b - a).norm(), (c - a).norm(), (c - b).norm()}) / grid;
    ASSERT_LE(d, d_grid + 1e-14) << "trial " << trial;  // never worse than any sample
    ASSERT_GE(d, d_grid - h) << "trial " << trial;      // and within the grid spacing of it
    ASSERT_LT((tp.barycentric[0] * a + tp.barycentric[1] * b + tp.barycentric[2] * c - tp.point).norm(), 1e-13);
  }
}

TEST(ClosestPointOnTriangle, AnalyticRegions) {
  const Vec3 a(0, 0, 0), b(2, 0, 0), c(0, 2, 0);
  // Above the face: the foot of the perpendicular.
  TrianglePoint tp = closest_point_on_triangle(Vec3(0.5, 0.25, 3.0), a, b, c);
  EXPECT_NEAR((tp.point - Vec3(0.5, 0.25, 0)).norm(), 0.0, 1e-15);
  EXPECT_NEAR((tp.barycentric - Vec3(0.625, 0.25, 0.125)).norm(), 0.0, 1e-15);
  // Beyond the hypotenuse: its midpoint.
  tp = closest_point_on_triangle(Vec3(2, 2, -1), a, b, c);
  EXPECT_NEAR((tp.point - Vec3(1, 1, 0)).norm(), 0.0, 1e-15);
  EXPECT_NEAR((tp.barycentric - Vec3(0, 0.5, 0.5)).norm(), 0.0, 1e-15);
  // Behind vertex a.
  tp = closest_point_on_triangle(Vec3(-1, -3, 0.5), a, b, c);
  EXPECT_EQ(tp.point, a);
  // A degenerate (collinear) triangle behaves like its longest edge.
  tp = closest_point_on_triangle(Vec3(1, 1, 0), a, b, Vec3(1, 0, 0));
  EXPECT_NEAR((tp.point - Vec3(1, 0, 0)).norm(), 0.0, 1e-15);
  EXPECT_NEAR(tp.barycentric.sum(), 1.0, 1e-15);
}

TEST(RayTriangle, AnalyticHitAndWatertightEdge) {
  const Vec3 a(0, 0, 0), b(1, 0, 0), c(0, 1, 0), d(1, 1, 0);
  auto hit = intersect_ray_triangle(Vec3(0.2, 0.3, 2.0), Vec3(0, 0, -0.5), a, b, c);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->t, 4.0, 1e-15);
  EXPECT_NEAR((hit->barycentric - Vec3(0.5, 0.2, 0.3)).norm(), 0.0, 1e-15);
  EXPECT_NEAR((hit->normal - Vec3(0, 0, 1)).norm(), 0.0, 1e-15);
  EXPECT_TRUE(hit->front_facing);
  EXPECT_FALSE(intersect_ray_triangle(Vec3(0.8, 0.8, 2.0), Vec3(0, 0, -1), a, b, c));
  // Rays aimed at points of the shared diagonal b-c of the quad (a b c), (b d c) hit at least one.
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int i = 0; i < 10000; ++i) {
    const double s = u(rng);
    const Vec3 target = (1.0 - s) * b + s * c;
    const Vec3 origin(u(rng) - 0.5, u(rng) - 0.5, 1.0 + u(rng));
    const Vec3 dir = target - origin;
    const bool h1 = intersect_ray_triangle(origin, dir, a, b, c).has_value();
    const bool h2 = intersect_ray_triangle(origin, dir, b, d, c).has_value();
    ASSERT_TRUE(h1 || h2) << i;
  }
}

TEST(RayTriangle, RayInThePlaneGrazesOnlyWhereItTouchesTheTriangle) {
  // Triangle in the plane z = 0.25 (exactly representable); rays in that plane.
  const Vec3 a(0, 0, 0.25), b(1, 0, 0.25), c(0, 1, 0.25);
  const auto grazes = [&](const Vec3& o, const Vec3& d, double t_min, double t_max) {
    bool on_edge = false;
    const auto hit = intersect_ray_triangle(o, d, a, b, c, t_min, t_max, &on_edge);
    EXPECT_FALSE(hit.has_value());
    return on_edge;
  };
  const double inf = std::numeric_limits<double>::infinity();
  // Through the triangle's interior, in front of the origin.
  EXPECT_TRUE(grazes(Vec3(-1, 0.25, 0.25), Vec3(1, 0, 0), 0.0, inf));
  // The same line, but the triangle lies behind the origin, or beyond t_max.
  EXPECT_FALSE(grazes(Vec3(2, 0.25, 0.25), Vec3(1, 0, 0), 0.0, inf));
  EXPECT_FALSE(grazes(Vec3(-1, 0.25, 0.25), Vec3(1, 0, 0), 0.0, 0.5));
  // Ends inside the triangle: the range [0, 1.2] reaches x = 0.2.
  EXPECT_TRUE(grazes(Vec3(-1, 0.25, 0.25), Vec3(1, 0, 0), 0.0, 1.2));
  // In the plane but beside the triangle (the line x + y = 1.5 misses it), either way round.
  EXPECT_FALSE(grazes(Vec3(1.5, 0, 0.25), Vec3(-1, 1, 0), -inf, inf));
  EXPECT_FALSE(grazes(Vec3(0, 1.5, 0.25), Vec3(1, -1, 0), -inf, inf));
  // Along the hypotenuse x + y = 1 and touching only the corner b.
  EXPECT_TRUE(grazes(Vec3(2, -1, 0.25), Vec3(-1, 1, 0), 0.0, inf));
  EXPECT_TRUE(grazes(Vec3(2, 0, 0.25), Vec3(-1, 0, 0), 0.0, inf));
  EXPECT_TRUE(grazes(Vec3(1, -1, 0.25), Vec3(0, 1, 0), 0.0, 1.0));
  EXPECT_FALSE(grazes(Vec3(1, -1, 0.25), Vec3(0, 1, 0), 0.0, 0.999));
  // The result does not depend on the triangle's winding.
  bool on_edge = true;
  intersect_ray_triangle(Vec3(1.5, 0, 0.25), Vec3(-1, 1, 0), a, c, b, -inf, inf, &on_edge);
  EXPECT_FALSE(on_edge);
  intersect_ray_triangle(Vec3(-1, 0.25, 0.25), Vec3(1, 0, 0), a, c, b, 0.0, inf, &on_edge);
  EXPECT_TRUE(on_edge);
}

TEST(WindingNumber, ClosedMeshIsOneInsideZeroOutside) {
  const TriMesh m = make_torus(1.0, 0.3, 48, 24);
  EXPECT_NEAR(compute_winding_number(m, Vec3(1.0, 0.0, 0.0)), 1.0, 1e-12);
  EXPECT_NEAR(compute_winding_number(m, Vec3(0.0, 0.0, 0.0)), 0.0, 1e-12);
  EXPECT_NEAR(compute_winding_number(m, Vec3(0.0, 0.0, 0.5)), 0.0, 1e-12);
  EXPECT_NEAR(compute_winding_number(m, Vec3(5.0, 3.0, 1.0)), 0.0, 1e-12);
  // One triangle seen from far along its normal: solid angle ~ area / r^2, positive from behind.
  const Vec3 a(0, 0, 0), b(1e-3, 0, 0), c(0, 1e-3, 0);
  EXPECT_NEAR(compute_solid_angle(Vec3(0, 0, -1), a, b, c), 0.5e-6, 1e-11);
  EXPECT_NEAR(compute_solid_angle(Vec3(0, 0, 1), a, b, c), -0.5e-6, 1e-11);
}

TEST(MeshQuery, IcosphereAgainstBruteForce) {
  check_against_brute_force(make_icosphere(0.05, 3), 1500, 500, 11);
}

TEST(MeshQuery, TorusAgainstBruteForce) {
  check_against_brute_force(make_torus(0.04, 0.012, 40, 20), 1500, 500, 12);
}

TEST(MeshQuery, BoxAgainstBruteForce) {
  check_against_brute_force(make_box(Vec3(0.03, 0.01, 0.02)), 2000, 1000, 13);
}

TEST(MeshQuery, FarAwayAndOffsetMesh) {
  // A small mesh far from the origin: float rounding of coordinates is larger than its features.
  TriMesh m = make_ellipsoid(Vec3(0.02, 0.01, 0.015), 3);
  m.V.rowwise() += Eigen::RowVector3d(120.0, -75.0, 33.0);
  check_against_brute_force(m, 800, 400, 14);
}

TEST(MeshQuery, MeshCollapsedToOnePoint) {
  // Every vertex at the origin: no extent for the start-vertex grid, yet queries stay exact.
  TriMesh m;
  m.V = Points3::Zero(3, 3);
  m.F = Triangles(1, 3);
  m.F << 0, 1, 2;
  const MeshQuery query(m);
  for (const Vec3& p : {Vec3(1.0, 0.0, 0.0), Vec3(0.0, -2.0, 3.0), Vec3(0.0, 0.0, 0.0)}) {
    const ClosestPoint c = query.calc_closest_point(p);
    EXPECT_EQ(c.triangle, 0);
    EXPECT_DOUBLE_EQ(c.distance, p.norm());
  }
  Points3 P(2, 3);
  P << 1, 0, 0, 0, 0, 4;
  const std::vector<ClosestPoint> batch = query.calc_closest_points(P);
  EXPECT_DOUBLE_EQ(batch[0].distance, 1.0);
  EXPECT_DOUBLE_EQ(batch[1].distance, 4.0);
}

TEST(MeshQuery, UnusedVerticesAndDegenerateTrianglesAgainstBruteForce) {
  // The vertex k-d tree that seeds closest-point queries must skip unused vertices, and the plane
  // lower bound must not reject zero-area triangles (no normal): a needle of three collinear
  // vertices sticks out of a sphere, and unused vertices sit right where the queries are.
  TriMesh m = make_icosphere(0.05, 2);
  const Eigen::Index nv = m.V.rows(), nf = m.F.rows();
  m.V.conservativeResize(nv + 5, 3);
  m.V.row(nv + 0) = Eigen::RowVector3d(0.06, 0.0, 0.0);
  m.V.row(nv + 1) = Eigen::RowVector3d(0.08, 0.0, 0.0);
  m.V.row(nv + 2) = Eigen::RowVector3d(0.10, 0.0, 0.0);
  m.V.row(nv + 3) = Eigen::RowVector3d(0.09, 0.004, 0.0);   // unused
  m.V.row(nv + 4) = Eigen::RowVector3d(0.0, 0.0, 0.0601);   // unused
  m.F.conservativeResize(nf + 1, 3);
  m.F.row(nf) = Eigen::RowVector3i(static_cast<int>(nv), static_cast<int>(nv + 1), static_cast<int>(nv + 2));
  const MeshQuery query(m);
  std::mt19937_64 rng(21);
  std::normal_distribution<double> g(0.0, 0.006);
  Points3 P(600, 3);
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const Vec3 centre = i % 2 == 0 ? Vec3(0.09, 0.0, 0.0) : Vec3(0.0, 0.0, 0.06);
    P.row(i) = (centre + Vec3(g(rng), g(rng), g(rng))).transpose();
  }
  const std::vector<ClosestPoint> batch = query.calc_closest_points(P);
  int on_needle = 0;
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const Vec3 p = P.row(i).transpose();
    const ClosestPoint bf = brute_closest(m, p);
    const ClosestPoint one = query.calc_closest_point(p);
    ASSERT_NEAR(one.distance, bf.distance, 1e-12 * bf.distance) << "point " << i;
    ASSERT_NEAR(batch[static_cast<std::size_t>(i)].distance, bf.distance, 1e-12 * bf.distance) << "point " << i;
    if (one.triangle == nf) ++on_needle;
  }
  EXPECT_GT(on_needle, 100);  // the degenerate triangle really is the answer for many points
}

TEST(MeshQuery, FarPointsAndTriangleSoupAgainstBruteForce) {
  // Query points far outside the start-vertex grid (up to 30 mesh sizes away, in every
  // direction), on a torus stored as a triangle soup (no shared vertex indices: the vertex descent
  // must weld equal positions) whose vertex order is shuffled.
  const TriMesh shared = make_torus(0.04, 0.012, 30, 16);
  TriMesh soup;
  soup.V.resize(3 * shared.F.rows(), 3);
  soup.F.resize(shared.F.rows(), 3);
  std::vector<int> perm(static_cast<std::size_t>(soup.V.rows()));
  for (std::size_t i = 0; i < perm.size(); ++i) perm[i] = static_cast<int>(i);
  std::mt19937_64 rng(51);
  std::shuffle(perm.begin(), perm.end(), rng);
  for (Eigen::Index f = 0; f < shared.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int v = perm[static_cast<std::size_t>(3 * f + k)];
      soup.V.row(v) = shared.V.row(shared.F(f, k));
      soup.F(f, k) = v;
    }
  }
  const MeshQuery query(soup);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Points3 P(400, 3);
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const Vec3 d = Vec3(g(rng), g(rng), g(rng)).normalized();
    P.row(i) = (d * 0.1 * std::pow(30.0, u(rng))).transpose();  // 0.1 ... 3 m from the centre
  }
  const std::vector<ClosestPoint> batch = query.calc_closest_points(P);
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const Vec3 p = P.row(i).transpose();
    const ClosestPoint bf = brute_closest(soup, p);
    const ClosestPoint one = query.calc_closest_point(p);
    ASSERT_NEAR(one.distance, bf.distance, 1e-12 * bf.distance) << "point " << i;
    ASSERT_EQ(one.triangle, batch[static_cast<std::size_t>(i)].triangle) << "point " << i;
    ASSERT_EQ(one.distance, batch[static_cast<std::size_t>(i)].distance) << "point " << i;
  }
}

TEST(MeshQuery, SphereSignedDistanceIsAnalyticAtVertices) {
  // Points on rays through the vertices: the closest point of the inscribed polyhedron is that
  // vertex when outside, so the distance is |p| - r exactly; inside it is at most r - |p|.
  const double r = 0.1;
  const TriMesh m = make_icosphere(r, 2);
  const MeshQuery q(m);
  for (Eigen::Index v = 0; v < m.V.rows(); ++v) {
    const Vec3 dir = m.V.row(v).transpose() / r;
    EXPECT_NEAR(q.calc_signed_distance(1.3 * r * dir), 0.3 * r, 1e-15);
    const double inside = q.calc_signed_distance(0.5 * r * dir);
    EXPECT_LT(inside, 0.0);
    EXPECT_LE(-inside, 0.5 * r + 1e-15);
    EXPECT_GT(-inside, 0.5 * r * 0.95);  // the polyhedron is within 5% of the sphere
  }
}

TEST(MeshQuery, RaysAgainstBruteForce) {
  const TriMesh m = make_torus(0.04, 0.012, 40, 20);
  const MeshQuery q(m);
  std::mt19937_64 rng(21);
  std::normal_distribution<double> g(0.0, 1.0);
  int hit_count = 0;
  for (int i = 0; i < 1500; ++i) {
    const Vec3 o = 0.05 * Vec3(g(rng), g(rng), 0.3 * g(rng));
    const Vec3 d = Vec3(g(rng), g(rng), g(rng)) * (0.5 + std::abs(g(rng)));  // not unit
    const std::vector<RayHit> bf = brute_hits(m, o, d);
    const std::vector<RayHit> all = q.cast_ray_all(o, d);
    ASSERT_EQ(all.size(), bf.size()) << "ray " << i;
    for (std::size_t k = 0; k < bf.size(); ++k) {
      ASSERT_EQ(all[k].triangle, bf[k].triangle);
      ASSERT_EQ(all[k].t, bf[k].t);
    }
    const std::optional<RayHit> first = q.cast_ray(o, d);
    ASSERT_EQ(first.has_value(), !bf.empty());
    if (first) {
      ++hit_count;
      ASSERT_EQ(first->t, bf.front().t);
      ASSERT_EQ(first->triangle, bf.front().triangle);
      const Vec3 x = o + first->t * d;
      const Eigen::Index f = first->triangle;
      const Vec3 y = first->barycentric[0] * vertex(m, f, 0) + first->barycentric[1] * vertex(m, f, 1) +
                     first->barycentric[2] * vertex(m, f, 2);
      ASSERT_LT((x - y).norm(), 1e-14);
    }
    // A limited interval: hits within (t0, t1) only.
    const auto limited = q.cast_ray_all(o, d, 0.01, 0.05);
    const auto n_in = std::count_if(bf.begin(), bf.end(), [](const RayHit& h) { return h.t > 0.01 && h.t < 0.05; });
    ASSERT_EQ(static_cast<long>(limited.size()), n_in);
  }
  EXPECT_GT(hit_count, 300);
}

// Short segments near the surface, as the winding propagation casts them (cast_ray_all over
// (0, 1) of an edge p -> q), on both ray traversals: Embree's (a fresh query) and the compact
// tree's (a refitted query of a small mesh). Every hit strictly inside the range must be found:
// the screen drops triangles whose bounding sphere lies outside the segment's range, so segments
// that end just before, on and just after a face, and that start on one, are included.
TEST(MeshQuery, ShortSegmentsAgainstBruteForceOnBothTraversals) {
  const TriMesh m = make_torus(0.04, 0.012, 40, 20);
  const MeshQuery fresh(m);
  MeshQuery refitted(m);
  refitted.update_vertices(m.V);  // small mesh: rays through the compact tree from now on
  std::mt19937_64 rng(33);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_int_distribution<Eigen::Index> face(0, m.F.rows() - 1);
  int crossing_segments = 0;
  for (int i = 0; i < 4000; ++i) {
    const Eigen::Index f = face(rng);
    const Vec3 c = (vertex(m, f, 0) + vertex(m, f, 1) + vertex(m, f, 2)) / 3.0;
    const Vec3 dir = Vec3(g(rng), g(rng), g(rng)).normalized();
    const double length = 0.001 * (0.2 + std::abs(g(rng)));
    // the face centroid at t = 1 (on the open end), at t = 0 (the start), just inside the end,
    // just beyond it, or somewhere in between
    const double at = std::array<double, 5>{1.0, 0.0, 1.0 - 1e-9, 1.0 + 1e-9, 0.5}[i % 5];
    const Vec3 o = c - at * length * dir;
    const Vec3 d = length * dir;
    std::vector<RayHit> expected;
    for (const RayHit& h : brute_hits(m, o, d))
      if (h.t > 0.0 && h.t < 1.0) expected.push_back(h);
    crossing_segments += !expected.empty();
    for (const MeshQuery* q : std::array<const MeshQuery*, 2>{&fresh, &refitted}) {
      const std::vector<RayHit> all = q->cast_ray_all(o, d, 0.0, 1.0);
      ASSERT_EQ(all.size(), expected.size()) << "segment " << i << (q == &fresh ? " (Embree)" : " (compact)");
      for (std::size_t k = 0; k < all.size(); ++k) {
        ASSERT_EQ(all[k].triangle, expected[k].triangle);
        ASSERT_EQ(all[k].t, expected[k].t);
      }
      const std::optional<RayHit> first = q->cast_ray(o, d, 0.0, 1.0);
      ASSERT_EQ(first.has_value(), !expected.empty());
      if (first) {
        ASSERT_EQ(first->triangle, expected.front().triangle);
      }
    }
  }
  EXPECT_GT(crossing_segments, 1000);
}

TEST(RayCasts, NearlyInPlaneRaysAgainstBruteForceOnBothTraversals) {
  // Rays almost in a face's plane: the watertight test's t is then a blend of the corners' t along
  // the dominant axis, not the line's crossing point, so the range screen must allow for it. Hits
  // in a range and crossing counts (with their grazes) must equal the exhaustive answers on
  // Embree's traversal and on the compact tree's.
  const TriMesh m = make_torus(0.04, 0.012, 40, 20);
  const MeshQuery fresh(m);
  MeshQuery refitted(m);
  refitted.update_vertices(m.V);  // small mesh: rays through the compact tree from now on
  std::mt19937_64 rng(35);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<Eigen::Index> face(0, m.F.rows() - 1);
  int in_range_hits = 0, grazed = 0;
  for (int i = 0; i < 6000; ++i) {
    const Eigen::Index f = face(rng);
    const Vec3 a = vertex(m, f, 0), b = vertex(m, f, 1), c = vertex(m, f, 2);
    // From a point of the face's plane towards another one (both rounded, so within a few ulps
    // of the plane), as affine combinations of the corners; every other ray tilted out of the
    // plane by 1e-6.
    std::uniform_real_distribution<double> affine(-3.0, 3.0);
    Vec3 o = a + affine(rng) * (b - a) + affine(rng) * (c - a);
    const Vec3 p = a + affine(rng) * (b - a) + affine(rng) * (c - a);
    Vec3 d = p - o;
    if (d.norm() < 1e-4) continue;
    if (i % 2 == 1) d += 1e-6 * d.norm() * (b - a).cross(c - a).normalized();
    // ranges ending anywhere within four circumradii of the face's centroid along the ray
    const Vec3 centroid = (a + b + c) / 3.0;
    const double radius = std::max({(a - centroid).norm(), (b - centroid).norm(), (c - centroid).norm()});
    const double s_t = (centroid - o).dot(d) / d.squaredNorm();
    double t_max = s_t + (8.0 * unit(rng) - 4.0) * radius / d.norm();
    if (!(t_max > 0.0)) {  // keep the range non-empty: start earlier along the same line
      const double shift = 1.0 - t_max;
      o -= shift * d;
      t_max += shift;
    }
    std::vector<RayHit> expected;
    for (const RayHit& h : brute_hits(m, o, d))
      if (h.t > 0.0 && h.t < t_max) expected.push_back(h);
    in_range_hits += static_cast<int>(expected.size());
    // exhaustive crossing count from the point (t > 0), undecided on any graze
    bool any_graze = false;
    int crossings = 0;
    for (Eigen::Index k = 0; k < m.F.rows(); ++k) {
      bool on_edge = false;
      const auto h = intersect_ray_triangle(o, d, vertex(m, k, 0), vertex(m, k, 1), vertex(m, k, 2), 0.0,
                                            std::numeric_limits<double>::infinity(), &on_edge);
      any_graze = any_graze || on_edge;
      if (h) crossings += h->front_facing ? -1 : 1;
    }
    grazed += any_graze;
    for (const MeshQuery* q : std::array<const MeshQuery*, 2>{&fresh, &refitted}) {
      const char* which = q == &fresh ? " (Embree)" : " (compact)";
      const std::vector<RayHit> all = q->cast_ray_all(o, d, 0.0, t_max);
      ASSERT_EQ(all.size(), expected.size()) << "ray " << i << which;
      for (std::size_t k = 0; k < all.size(); ++k) {
        ASSERT_EQ(all[k].triangle, expected[k].triangle) << "ray " << i << which;
        ASSERT_EQ(all[k].t, expected[k].t) << "ray " << i << which;
      }
      const std::optional<int> w = q->calc_crossing_number(o, d);
      ASSERT_EQ(w.has_value(), !any_graze) << "ray " << i << which;
      if (w) {
        ASSERT_EQ(*w, crossings) << "ray " << i << which;
      }
    }
  }
  EXPECT_GT(in_range_hits, 1000);
  EXPECT_GT(grazed, 4);
}

TEST(RayCasts, RangesOutsideZeroToTMaxAreBadInput) {
  const TriMesh m = make_icosphere(1.0, 2);
  const MeshQuery q(m);
  const Vec3 o(0.0031, -0.002, -3.0), d(0.0123, 0.0457, 1.0);
  ASSERT_TRUE(q.cast_ray(o, d, 0.0, 10.0).has_value());
  EXPECT_EQ(q.cast_ray_all(o, d, 0.0, 10.0).size(), 2u);
  EXPECT_TRUE(q.cast_ray_all(o, d, 1.0, 1.0).empty());  // an empty range is allowed
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (const auto& [lo, hi] : std::array<std::pair<double, double>, 4>{
           {{-1.0, 10.0}, {2.0, 1.0}, {nan, 10.0}, {0.0, nan}}}) {
    EXPECT_THROW(q.cast_ray(o, d, lo, hi), Error) << lo << " " << hi;
    EXPECT_THROW(q.cast_ray_all(o, d, lo, hi), Error) << lo << " " << hi;
  }
}

TEST(MeshQuery, CrossingNumberIsWindingNumberOfClosedMesh) {
  // Every primitive must be counted exactly once per ray: the signed sum is 1 inside, 0 outside.
  const TriMesh m = make_icosphere(1.0, 3);
  const MeshQuery q(m);
  std::mt19937_64 rng(5);
  std::normal_distribution<double> g(0.0, 1.0);
  for (int i = 0; i < 2000; ++i) {
    const Vec3 p(g(rng), g(rng), g(rng));
    const Vec3 d(g(rng), g(rng), g(rng));
    if (std::abs(p.norm() - 1.0) < 0.02) continue;  // between the polyhedron and the sphere
    const std::optional<int> w = q.calc_crossing_number(p, d);
    ASSERT_TRUE(w.has_value());
    ASSERT_EQ(*w, p.norm() < 1.0 ? 1 : 0) << "point " << i;
  }
}

TEST(MeshQuery, InsideTestToleratesASmallHole) {
  // Remove the three triangles around one vertex... of an icosphere: a small hole. Parity along a
  // single ray is wrong for every ray through the hole; the vote and the winding number are not.
  TriMesh closed = make_icosphere(1.0, 3);
  TriMesh open = closed;
  std::vector<Eigen::Index> keep;
  const Vec3 hole_centre = closed.V.row(0).transpose();
  for (Eigen::Index f = 0; f < closed.F.rows(); ++f) {
    const Vec3 c = (vertex(closed, f, 0) + vertex(closed, f, 1) + vertex(closed, f, 2)) / 3.0;
    if ((c - hole_centre).norm() > 0.12) keep.push_back(f);
  }
  ASSERT_LT(keep.size(), static_cast<std::size_t>(closed.F.rows()));  // a hole was made
  ASSERT_GT(keep.size(), static_cast<std::size_t>(closed.F.rows() - 8));  // and it is small
  open.F.resize(static_cast<Eigen::Index>(keep.size()), 3);
  for (std::size_t i = 0; i < keep.size(); ++i) open.F.row(static_cast<Eigen::Index>(i)) = closed.F.row(keep[i]);
  const MeshQuery q(open);
  std::mt19937_64 rng(9);
  std::normal_distribution<double> g(0.0, 1.0);
  int rays_through_hole = 0;
  for (int i = 0; i < 3000; ++i) {
    Vec3 p(g(rng), g(rng), g(rng));
    if (std::abs(p.norm() - 1.0) < 0.05) continue;
    const bool truth = p.norm() < 1.0;
    ASSERT_EQ(q.calc_is_inside(p), truth) << "point " << p.transpose();
    ASSERT_EQ(compute_winding_number(open, p) > 0.5, truth);
    // Count how often a single ray towards the hole gets it wrong (the hole is really open).
    const std::optional<int> w = q.calc_crossing_number(p, hole_centre - p);
    if (w && (*w > 0) != truth) ++rays_through_hole;
  }
  EXPECT_GT(rays_through_hole, 100);
}

TEST(MeshQuery, BatchedResultsDoNotDependOnThreadCount) {
  const TriMesh m = make_torus(0.04, 0.012, 40, 20);
  const MeshQuery q(m);
  const Points3 P = sample_points(m, 5000, 1000, 31);
  std::vector<ClosestPoint> one, two;
  VecX sd1, sd2;
  {
    ThreadLimit limit(1);
    one = q.calc_closest_points(P);
    sd1 = q.calc_signed_distances(P);
  }
  {
    ThreadLimit limit(2);
    two = q.calc_closest_points(P);
    sd2 = q.calc_signed_distances(P);
  }
  for (std::size_t i = 0; i < one.size(); ++i) {
    ASSERT_EQ(one[i].triangle, two[i].triangle);
    ASSERT_EQ(one[i].distance, two[i].distance);
    ASSERT_EQ(one[i].point, two[i].point);
  }
  EXPECT_EQ(sd1, sd2);
}

TEST(MeshQuery, BadInputIsRejectedWithAClearError) {
  EXPECT_THROW(MeshQuery{TriMesh{}}, Error);
  TriMesh m = make_box(Vec3(1, 1, 1));
  m.F(3, 1) = 99;
  try {
    MeshQuery q(m);
    FAIL() << "out-of-range index accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("out of range"), std::string::npos);
  }
  m = make_box(Vec3(1, 1, 1));
  m.V(2, 2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(MeshQuery{m}, Error);
  const MeshQuery q(make_box(Vec3(1, 1, 1)));
  EXPECT_THROW(q.cast_ray(Vec3::Zero(), Vec3::Zero()), Error);
  EXPECT_THROW(q.calc_closest_point(Vec3(std::nan(""), 0, 0)), Error);
  // A max distance that excludes the whole mesh gives no triangle.
  EXPECT_EQ(q.calc_closest_point(Vec3(5, 0, 0), 1.0).triangle, -1);
  EXPECT_NEAR(q.calc_closest_point(Vec3(5, 0, 0), 4.5).distance, 4.0, 1e-15);
}

TEST(MeshQuery, VisibleHumanTibiaAgainstBruteForce) {
  const TriMesh tibia =
      test::read_binary_stl_mm(test::data_path("visible_human_female/right/VHF_Right_Bone_Tibia_smooth.stl"));
  ASSERT_GT(tibia.F.rows(), 50000);
  check_against_brute_force(tibia, 100, 50, 41);
  // The contact case: points 0.5-5 mm off the bone along the face normal, both sides; closest
  // triangle (lowest index on ties) identical to the exhaustive search.
  const MeshQuery query(tibia);
  std::mt19937_64 rng(42);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::uniform_int_distribution<Eigen::Index> pick(0, tibia.F.rows() - 1);
  Points3 P(60, 3);
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const Eigen::Index f = pick(rng);
    const Vec3 a = vertex(tibia, f, 0), b = vertex(tibia, f, 1), c = vertex(tibia, f, 2);
    const double offset = (i % 2 == 0 ? 1.0 : -1.0) * (0.5e-3 + 4.5e-3 * u(rng));
    P.row(i) = ((a + b + c) / 3.0 + offset * (b - a).cross(c - a).normalized()).transpose();
  }
  const std::vector<ClosestPoint> batch = query.calc_closest_points(P);
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const Vec3 p = P.row(i).transpose();
    const ClosestPoint bf = brute_closest(tibia, p);
    const ClosestPoint one = query.calc_closest_point(p);
    ASSERT_EQ(one.triangle, bf.triangle) << "point " << i;
    ASSERT_EQ(batch[static_cast<std::size_t>(i)].triangle, bf.triangle) << "point " << i;
    ASSERT_NEAR(one.distance, bf.distance, 1e-12 * bf.distance) << "point " << i;
  }
}


// A smooth, large deformation: twist about z, bulge in x, shear in y (moves every vertex).
Points3 deform(const Points3& V, double amount) {
  Points3 W = V;
  const Vec3 lo = V.colwise().minCoeff().transpose(), hi = V.colwise().maxCoeff().transpose();
  const Vec3 c = 0.5 * (lo + hi);
  const double size = (hi - lo).norm();
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    const Vec3 x = V.row(i).transpose() - c;
    const double angle = amount * 2.0 * x.z() / size;
    const double cs = std::cos(angle), sn = std::sin(angle);
    Vec3 y(cs * x.x() - sn * x.y(), sn * x.x() + cs * x.y(), x.z());
    y.x() *= 1.0 + 0.3 * amount * std::sin(3.0 * x.z() / size);
    y.y() += 0.2 * amount * x.z();
    W.row(i) = (y + c + Vec3(0.01, -0.02, 0.03) * amount * size).transpose();
  }
  return W;
}

// Every query of `updated` equals a MeshQuery built on the same vertices, bit for bit, and the
// closest points equal the exhaustive search.
void expect_same_as_fresh(const MeshQuery& updated, const TriMesh& deformed, int n_box, int n_near,
                          int n_brute, std::uint64_t seed) {
  const MeshQuery fresh(deformed);
  ASSERT_EQ(updated.get_mesh().V, deformed.V);
  const Points3 P = sample_points(deformed, n_box, n_near, seed);
  const std::vector<ClosestPoint> a = updated.calc_closest_points(P), b = fresh.calc_closest_points(P);
  const VecX sa = updated.calc_signed_distances(P), sb = fresh.calc_signed_distances(P);
  const InsideFlags ia = updated.calc_is_inside(P), ib = fresh.calc_is_inside(P);
  std::mt19937_64 rng(seed + 1);
  std::normal_distribution<double> g(0.0, 1.0);
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const Vec3 p = P.row(i).transpose();
    const auto k = static_cast<std::size_t>(i);
    const ClosestPoint one = updated.calc_closest_point(p), ref = fresh.calc_closest_point(p);
    ASSERT_EQ(one.triangle, ref.triangle) << "point " << i;
    ASSERT_EQ(one.distance, ref.distance) << "point " << i;
    ASSERT_EQ(one.point, ref.point) << "point " << i;
    ASSERT_EQ(one.barycentric, ref.barycentric) << "point " << i;
    ASSERT_EQ(a[k].triangle, b[k].triangle) << "point " << i;
    ASSERT_EQ(a[k].distance, b[k].distance) << "point " << i;
    ASSERT_EQ(sa[i], sb[i]) << "point " << i;
    ASSERT_EQ(ia[i], ib[i]) << "point " << i;
    ASSERT_EQ(updated.calc_is_inside(p), fresh.calc_is_inside(p)) << "point " << i;
    ASSERT_EQ(updated.calc_signed_distance(p), fresh.calc_signed_distance(p)) << "point " << i;
    const Vec3 d(g(rng), g(rng), g(rng));
    const std::optional<RayHit> ra = updated.cast_ray(p, d), rb = fresh.cast_ray(p, d);
    ASSERT_EQ(ra.has_value(), rb.has_value()) << "ray " << i;
    if (ra) {
      ASSERT_EQ(ra->t, rb->t) << "ray " << i;
      ASSERT_EQ(ra->triangle, rb->triangle) << "ray " << i;
      ASSERT_EQ(ra->barycentric, rb->barycentric) << "ray " << i;
    }
    const std::vector<RayHit> all_a = updated.cast_ray_all(p, d), all_b = fresh.cast_ray_all(p, d);
    ASSERT_EQ(all_a.size(), all_b.size()) << "ray " << i;
    for (std::size_t h = 0; h < all_a.size(); ++h) {
      ASSERT_EQ(all_a[h].t, all_b[h].t);
      ASSERT_EQ(all_a[h].triangle, all_b[h].triangle);
    }
    if (i < n_brute) {
      // Exhaustive search with MeshQuery's rule: smallest squared distance, then lowest index.
      ClosestPoint bf;
      double bf_d2 = std::numeric_limits<double>::infinity();
      for (Eigen::Index f = 0; f < deformed.F.rows(); ++f) {
        const TrianglePoint tp = closest_point_on_triangle(p, vertex(deformed, f, 0),
                                                           vertex(deformed, f, 1), vertex(deformed, f, 2));
        const double d2 = (p - tp.point).squaredNorm();
        if (d2 < bf_d2) {
          bf_d2 = d2;
          bf.triangle = static_cast<int>(f);
          bf.distance = std::sqrt(d2);
        }
      }
      ASSERT_EQ(one.triangle, bf.triangle) << "point " << i;
      ASSERT_NEAR(one.distance, bf.distance, 1e-12 * bf.distance) << "point " << i;
      const std::vector<RayHit> bh = brute_hits(deformed, p, d);
      ASSERT_EQ(all_a.size(), bh.size()) << "ray " << i;
      if (!bh.empty()) {
        ASSERT_EQ(ra->t, bh.front().t);
        ASSERT_EQ(ra->triangle, bh.front().triangle);
      }
    }
  }
}

TEST(MeshQuery, UpdateVerticesEqualsFreshBuild) {
  static_assert(std::is_nothrow_move_constructible_v<MeshQuery>);
  const TriMesh rest = make_ellipsoid(Vec3(0.03, 0.02, 0.12), 4);
  MeshQuery query(rest);
  // Several frames of growing deformation, then back to rest.
  for (const double amount : {0.1, 0.5, 1.0, 0.0}) {
    TriMesh deformed = rest;
    deformed.V = deform(rest.V, amount);
    query.update_vertices(deformed.V);
    expect_same_as_fresh(query, deformed, 300, 300, 200, 7 + static_cast<std::uint64_t>(10 * amount));
  }
  // A moved-from-and-into query keeps working.
  TriMesh deformed = rest;
  deformed.V = deform(rest.V, 0.7);
  query.update_vertices(deformed.V);
  const MeshQuery moved(std::move(query));
  expect_same_as_fresh(moved, deformed, 100, 100, 50, 99);
}

TEST(MeshQuery, UpdateVerticesRejectsADifferentMesh) {
  const TriMesh rest = make_icosphere(0.05, 2);
  MeshQuery query(rest);
  Points3 fewer = rest.V.topRows(rest.V.rows() - 1);
  try {
    query.update_vertices(fewer);
    FAIL() << "a different vertex count was accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("vertices for a mesh of"), std::string::npos) << e.what();
  }
  Points3 bad = rest.V;
  bad(3, 1) = std::numeric_limits<double>::infinity();
  EXPECT_THROW(query.update_vertices(bad), Error);
  // The query is unchanged after the rejected updates.
  expect_same_as_fresh(query, rest, 100, 100, 50, 5);
}

TEST(MeshQuery, UpdateVerticesOnTheVisibleHumanTibia) {
  const TriMesh tibia =
      test::read_binary_stl_mm(test::data_path("visible_human_female/right/VHF_Right_Bone_Tibia_smooth.stl"));
  MeshQuery query(tibia);
  TriMesh deformed = tibia;
  query.update_vertices(deform(tibia.V, 0.15));  // the first update builds the refittable tree
  deformed.V = deform(tibia.V, 0.3);
  query.update_vertices(deformed.V);  // later ones refit it
  expect_same_as_fresh(query, deformed, 150, 150, 40, 43);
}

}  // namespace
}  // namespace fascicle
