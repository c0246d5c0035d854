#include "fascicle/geometry/primitives.hpp"

#include <gtest/gtest.h>

#include <map>
#include <numbers>

namespace fascicle {
namespace {

// Signed volume by the divergence theorem (sum of signed tetrahedra to the origin).
double signed_volume(const TriMesh& m) {
  double v = 0.0;
  for (Eigen::Index f = 0; f < m.F.rows(); ++f) {
    const Vec3 a = m.V.row(m.F(f, 0)), b = m.V.row(m.F(f, 1)), c = m.V.row(m.F(f, 2));
    v += a.dot(b.cross(c)) / 6.0;
  }
  return v;
}

// Every directed edge appears once and its reverse once: closed, manifold, consistently oriented.
bool closed_and_oriented(const TriMesh& m) {
  std::map<std::pair<int, int>, int> directed;
  for (Eigen::Index f = 0; f < m.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) ++directed[{m.F(f, k), m.F(f, (k + 1) % 3)}];
  }
  for (const auto& [e, n] : directed) {
    if (n != 1) return false;
    auto it = directed.find({e.second, e.first});
    if (it == directed.end() || it->second != 1) return false;
  }
  return true;
}

TEST(Primitives, BoxIsClosedWithExactVolume) {
  const TriMesh box = make_box(Vec3(0.5, 1.0, 1.5));
  EXPECT_TRUE(closed_and_oriented(box));
  EXPECT_NEAR(signed_volume(box), 6.0, 1e-14);
}

TEST(Primitives, SphereVolumeConvergesFromBelow) {
  const double exact = 4.0 / 3.0 * std::numbers::pi;
  double previous_error = exact - signed_volume(make_icosphere(1.0, 0));
  for (int level = 1; level <= 4; ++level) {
    const TriMesh s = make_icosphere(1.0, level);
    ASSERT_TRUE(closed_and_oriented(s));
    const double err = exact - signed_volume(s);
    EXPECT_GT(err, 0.0);
    EXPECT_LT(err, previous_error / 3.0);  // second order: ~4x per level (3.1x at the first)
    previous_error = err;
  }
}

TEST(Primitives, CylinderTorusSpindleAreClosedAndOutward) {
  const TriMesh c = make_cylinder(0.5, 2.0, 64, 3);
  EXPECT_TRUE(closed_and_oriented(c));
  const double inscribed = 0.5 * 64 * 0.25 * std::sin(2 * std::numbers::pi / 64) * 2.0;
  EXPECT_NEAR(signed_volume(c), inscribed, 1e-12);
  const TriMesh t = make_torus(2.0, 0.5, 48, 24);
  EXPECT_TRUE(closed_and_oriented(t));
  // a regular 24-gon swept by 48 chordal wedges: V = M sin(2pi/M) * area * centroid radius
  const double polygon_area = 0.5 * 24 * 0.25 * std::sin(2 * std::numbers::pi / 24);
  EXPECT_NEAR(signed_volume(t), 48 * std::sin(2 * std::numbers::pi / 48) * polygon_area * 2.0, 1e-12);
  const TriMesh s = make_spindle(0.0, 1.0, 16, 10, [](double u) { return 0.1 + 0.2 * u * (1 - u); });
  EXPECT_TRUE(closed_and_oriented(s));
  EXPECT_GT(signed_volume(s), 0.0);
  EXPECT_THROW(make_box(Vec3(1, -1, 1)), std::exception);
}

}  // namespace
}  // namespace fascicle
