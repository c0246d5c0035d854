// Wrapping kernels: OpenSim's analytic cylinder cases, the quarter-turn cases, quadrants, cylinder
// ends, a torus case with a closed-form answer, and properties (length >= straight line,
// continuity, gradients = finite differences).
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "fascicle/path/wrap_geometry.hpp"

using namespace fascicle;

namespace {

constexpr double kPi = std::numbers::pi;

// OpenSim testWrapCylinder: "wrap length" is the length on the surface between tangent points.
TEST(WrapCylinder, OpenSimAnalyticCases) {
  const WrapResult a = wrap_cylinder({2, 0.9, 0}, {-2, 1, 0}, 1.0, 10.0, WrapQuadrant::all);
  ASSERT_EQ(a.status, WrapStatus::mandatory);
  EXPECT_NEAR(a.arc_length, 0.0505974872969326, 1e-9);
  const WrapResult b = wrap_cylinder({2, -2, 0}, {-2, 2.1, 0}, 1.0, 10.0, WrapQuadrant::all);
  ASSERT_EQ(b.status, WrapStatus::mandatory);
  EXPECT_NEAR(b.arc_length, 0.689036814042993, 1e-9);
  // Tangent points lie on the surface and the tangent lines are perpendicular to the radius.
  for (const WrapResult* r : {&a, &b}) {
    EXPECT_NEAR(r->t1.head<2>().norm(), 1.0, 1e-12);
    EXPECT_NEAR(r->t2.head<2>().norm(), 1.0, 1e-12);
  }
  EXPECT_NEAR((Vec3(2, 0.9, 0) - a.t1).dot(Vec3(a.t1.x(), a.t1.y(), 0)), 0.0, 1e-12);
}

// OpenSim's quarter-turn case: r = 0.5, origin (r - 0.1, r, 0), insertion (-r, r, 0) rotated by q
// about z. L = 2r - 0.1 + r q for cylinder, sphere and ellipsoid with equal radii.
TEST(Wrap, QuarterTurnAllShapes) {
  const double r = 0.5;
  const Vec3 origin(r - 0.1, r, 0);
  for (int shape = 0; shape < 3; ++shape) {
    for (int i = 1; i <= 20; ++i) {
      const double q = 0.5 * kPi * i / 20;
      const Vec3 ins = Eigen::AngleAxisd(q, Vec3::UnitZ()) * Vec3(-r, r, 0);
      WrapResult w;
      if (shape == 0) w = wrap_cylinder(origin, ins, r, 1.0, WrapQuadrant::all);
      if (shape == 1) w = wrap_sphere(origin, ins, r, WrapQuadrant::all);
      if (shape == 2) w = wrap_ellipsoid(origin, ins, Vec3::Constant(r), WrapQuadrant::all);
      ASSERT_TRUE(is_wrapping(w.status)) << shape << " q=" << q;
      EXPECT_NEAR(wrapped_segment_length(origin, ins, w), 2 * r - 0.1 + r * q, 1e-12)
          << "shape " << shape << " q=" << q;
    }
  }
}

TEST(WrapCylinder, HelixIsGeodesic) {
  // Points at different heights: unrolled, the path is a straight line of length
  // sqrt((l1 + r dθ + l2)² + dz²).
  const Vec3 p1(3, 0.2, -1), p2(-2.5, 0.4, 2);
  const WrapResult w = wrap_cylinder(p1, p2, 1.0, 100.0, WrapQuadrant::all);
  ASSERT_EQ(w.status, WrapStatus::mandatory);
  const double l1 = std::sqrt(p1.head<2>().squaredNorm() - 1);
  const double l2 = std::sqrt(p2.head<2>().squaredNorm() - 1);
  const double planar = l1 + std::abs(w.arc.dtheta) + l2;
  EXPECT_NEAR(wrapped_segment_length(p1, p2, w), std::hypot(planar, 3.0), 1e-12);
}

TEST(WrapCylinder, QuadrantForcesWrapOverActiveSide) {
  // Both points below the cylinder, segment misses it; +y forces the path over the top.
  const Vec3 p1(2, -1.5, 0), p2(-2, -1.5, 0);
  EXPECT_EQ(wrap_cylinder(p1, p2, 1.0, 10.0, WrapQuadrant::all).status, WrapStatus::no_wrap);
  const WrapResult w = wrap_cylinder(p1, p2, 1.0, 10.0, WrapQuadrant::pos_y);
  ASSERT_EQ(w.status, WrapStatus::wrapped);
  EXPECT_GT(point_on_wrap_arc(w.arc, 0.5).y(), 0.99);
  // -y: the crossing segment (both ends on the inactive side) must go below.
  const WrapResult m = wrap_cylinder({2, 0.2, 0}, {-2, 0.2, 0}, 1.0, 10.0, WrapQuadrant::neg_y);
  ASSERT_EQ(m.status, WrapStatus::wrapped);
  EXPECT_LT(point_on_wrap_arc(m.arc, 0.5).y(), -0.99);
  // Points on the active side whose segment misses: no wrap.
  EXPECT_EQ(wrap_cylinder({2, 1.5, 0}, {-2, 1.5, 0}, 1.0, 10.0, WrapQuadrant::pos_y).status,
            WrapStatus::no_wrap);
}

TEST(WrapCylinder, EndsOpenSimVersusInfinite) {
  const Vec3 p1(2, 0.1, 6), p2(-2, 0.1, 6);
  EXPECT_EQ(wrap_cylinder(p1, p2, 1.0, 10.0, WrapQuadrant::all).status, WrapStatus::no_wrap);
  const WrapResult w =
      wrap_cylinder(p1, p2, 1.0, 10.0, WrapQuadrant::all, CylinderEndRule::infinite);
  EXPECT_EQ(w.status, WrapStatus::mandatory);
  EXPECT_NEAR(w.t1.z(), 6.0, 1e-12);
}

TEST(WrapCylinder, InsideIsReported) {
  EXPECT_EQ(wrap_cylinder({0.5, 0, 0}, {-2, 0, 0}, 1.0, 10.0, WrapQuadrant::all).status,
            WrapStatus::inside);
  EXPECT_EQ(wrap_sphere({0.1, 0, 0}, {-2, 0, 0}, 1.0, WrapQuadrant::all).status,
            WrapStatus::inside);
}

TEST(WrapTorus, ThreadingTheHoleClosedForm) {
  // Ring radius 1, tube 0.3; the path at x = 0.8 through the hole wraps the inner side of the tube
  // in the plane y = 0: a circle of radius 0.3 centred at (1, 0, 0).
  const double R = 1.0, r = 0.3;
  const Vec3 p1(0.8, 0, 1), p2(0.8, 0, -1);
  const WrapResult w = wrap_torus(p1, p2, R, r, WrapQuadrant::all);
  ASSERT_TRUE(is_wrapping(w.status));
  const double d = std::hypot(0.2, 1.0);
  const double alpha = std::atan2(1.0, -0.2), delta = std::acos(r / d);
  const double sweep = 2 * (kPi - (alpha + delta));
  EXPECT_NEAR(wrapped_segment_length(p1, p2, w), 2 * std::sqrt(d * d - r * r) + r * sweep, 1e-9);
  EXPECT_NEAR((w.t1 - Vec3(1, 0, 0)).norm(), r, 1e-9);
  EXPECT_LT(point_on_wrap_arc(w.arc, 0.5).x(), 0.7 + 1e-9);
}

// Random segments around each shape: length >= straight line, gradients match central differences
// (shortest-path shapes), and small motions give small length changes.
TEST(Wrap, PropertiesOverRandomSegments) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> U(-3, 3);
  const Vec3 radii(1.0, 0.7, 0.5);
  int wrapped = 0;
  for (int shape = 0; shape < 3; ++shape) {
    for (int trial = 0; trial < 300; ++trial) {
      const Vec3 p1(U(rng), U(rng), U(rng)), p2(U(rng), U(rng), U(rng));
      auto eval = [&](const Vec3& a, const Vec3& b) {
        if (shape == 0) {
          return wrap_cylinder(a, b, 1.0, 1.0, WrapQuadrant::all, CylinderEndRule::infinite);
        }
        if (shape == 1) return wrap_sphere(a, b, 1.0, WrapQuadrant::all);
        return wrap_ellipsoid(a, b, radii, WrapQuadrant::all);
      };
      const WrapResult w = eval(p1, p2);
      if (!is_wrapping(w.status)) continue;
      ++wrapped;
      const double L = wrapped_segment_length(p1, p2, w);
      EXPECT_GE(L, (p2 - p1).norm() - 1e-12);
      // Continuity: a 1e-7 m motion changes a shortest path by at most 1e-7 m (Lipschitz 1);
      // the ellipsoid's central section by a bounded multiple of it.
      const Vec3 e = Vec3(0.3, -0.5, 0.8).normalized() * 1e-7;
      const WrapResult w2 = eval(p1 + e, p2);
      EXPECT_NEAR(wrapped_segment_length(p1 + e, p2, w2), L, shape == 2 ? 1e-6 : 1.0001e-7)
          << "shape " << shape;
      if (shape == 2) continue;  // central sections of an ellipsoid are not geodesics
      const double h = 1e-6;
      for (int k = 0; k < 3; ++k) {
        Vec3 dk = Vec3::Zero();
        dk[k] = h;
        const double fd1 = (wrapped_segment_length(p1 + dk, p2, eval(p1 + dk, p2)) -
                            wrapped_segment_length(p1 - dk, p2, eval(p1 - dk, p2))) / (2 * h);
        const double fd2 = (wrapped_segment_length(p1, p2 + dk, eval(p1, p2 + dk)) -
                            wrapped_segment_length(p1, p2 - dk, eval(p1, p2 - dk))) / (2 * h);
        EXPECT_NEAR(w.g1[k], fd1, 1e-7) << "shape " << shape;
        EXPECT_NEAR(w.g2[k], fd2, 1e-7) << "shape " << shape;
      }
    }
  }
  EXPECT_GT(wrapped, 100);
}

TEST(WrapEllipsoid, ArcLengthOfEllipseQuarter) {
  // Points far out along +x and +y over an ellipse z = 0 section (radii 2, 1, 1.5); the wrap
  // between the tangent points is an ellipse arc whose length is checked against fine summation.
  const Vec3 radii(2, 1, 1.5);
  const WrapResult w = wrap_ellipsoid({2.5, -0.5, 0}, {-2.5, -0.4, 0}, radii, WrapQuadrant::pos_y);
  ASSERT_TRUE(is_wrapping(w.status));
  double sum = 0;
  const int n = 200000;
  for (int i = 0; i < n; ++i) {
    sum += (point_on_wrap_arc(w.arc, double(i + 1) / n) - point_on_wrap_arc(w.arc, double(i) / n))
               .norm();
  }
  EXPECT_NEAR(w.arc_length, sum, 1e-9);
  EXPECT_NEAR(w.t1.x() * w.t1.x() / 4 + w.t1.y() * w.t1.y(), 1.0, 1e-12);
  EXPECT_GT(point_on_wrap_arc(w.arc, 0.5).y(), 0.9);
}

}  // namespace
