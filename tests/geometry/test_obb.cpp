// Oriented bounding boxes: exact boxes of rotated boxes, invariants on point clouds.
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/obb.hpp"
#include "fascicle/geometry/primitives.hpp"

#include <gtest/gtest.h>

#include <random>

namespace fascicle {
namespace {

Mat3 random_rotation(std::mt19937_64& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  return Quat(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
}

TriMesh transformed(TriMesh m, const Mat3& R, const Vec3& t) {
  m.V = (m.V * R.transpose()).rowwise() + t.transpose();
  return m;
}

void expect_proper_axes(const OrientedBox& box) {
  EXPECT_NEAR((box.axes.transpose() * box.axes - Mat3::Identity()).norm(), 0.0, 1e-13);
  EXPECT_NEAR(box.axes.determinant(), 1.0, 1e-13);
  EXPECT_GE(box.half_extents[0], box.half_extents[1]);
  EXPECT_GE(box.half_extents[1], box.half_extents[2]);
}

// Every point is inside the box (up to rounding).
void expect_contains(const OrientedBox& box, const Points3& P) {
  const Points3 local = (P.rowwise() - box.centre.transpose()) * box.axes;
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    for (int k = 0; k < 3; ++k) {
      ASSERT_LE(std::abs(local(i, k)), box.half_extents[k] * (1 + 1e-12) + 1e-15);
    }
  }
}

TEST(OrientedBox, RotatedBoxMeshIsRecoveredExactly) {
  std::mt19937_64 rng(1);
  const Vec3 h(0.03, 0.02, 0.01);
  for (int trial = 0; trial < 20; ++trial) {
    const Mat3 R = random_rotation(rng);
    const Vec3 t(0.1 * trial, -0.2, 0.05);
    const TriMesh box = transformed(make_box(h), R, t);
    for (bool refine : {false, true}) {
      const OrientedBox obb = compute_oriented_box(box, refine);
      expect_proper_axes(obb);
      // PCA alone is exact here: distinct extents make the surface covariance's axes the box's.
      EXPECT_NEAR((obb.half_extents - h).norm(), 0.0, 1e-14);
      EXPECT_NEAR((obb.centre - t).norm(), 0.0, 1e-14);
      for (int k = 0; k < 3; ++k) EXPECT_NEAR(std::abs(obb.axes.col(k).dot(R.col(k))), 1.0, 1e-13);
      EXPECT_NEAR(obb.calc_volume(), 8 * h.prod(), 1e-12 * 8 * h.prod());
      expect_contains(obb, box.V);
    }
  }
}

TEST(OrientedBox, RotatedCubeNeedsRefinement) {
  // A cube's surface covariance is isotropic: PCA axes are arbitrary, and the refinement (about
  // the face normals) finds the exact box.
  std::mt19937_64 rng(2);
  const double h = 0.02;
  for (int trial = 0; trial < 10; ++trial) {
    const Mat3 R = random_rotation(rng);
    const TriMesh cube = transformed(make_box(Vec3::Constant(h)), R, Vec3(0.3, 0.1, -0.2));
    const OrientedBox pca = compute_oriented_box(cube, false);
    const OrientedBox obb = compute_oriented_box(cube, true);
    expect_proper_axes(obb);
    EXPECT_NEAR((obb.half_extents - Vec3::Constant(h)).norm(), 0.0, 1e-14);
    EXPECT_NEAR((obb.centre - Vec3(0.3, 0.1, -0.2)).norm(), 0.0, 1e-14);
    EXPECT_LE(obb.calc_volume(), pca.calc_volume());
    expect_contains(obb, cube.V);
  }
}

TEST(OrientedBox, PointSetOfBoxSurface) {
  // Points sampled on the faces of a rotated box with distinct extents (plus its corners).
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Vec3 h(0.05, 0.02, 0.012);
  const Mat3 R = random_rotation(rng);
  const Vec3 t(-0.4, 0.2, 0.9);
  Points3 P(2008, 3);
  for (int i = 0; i < 2000; ++i) {
    Vec3 q(u(rng) * h.x(), u(rng) * h.y(), u(rng) * h.z());
    const int axis = i % 3;
    q[axis] = (i % 2 == 0 ? 1.0 : -1.0) * h[axis];
    P.row(i) = (R * q + t).transpose();
  }
  for (int c = 0; c < 8; ++c) {
    const Vec3 q((c & 1 ? 1 : -1) * h.x(), (c & 2 ? 1 : -1) * h.y(), (c & 4 ? 1 : -1) * h.z());
    P.row(2000 + c) = (R * q + t).transpose();
  }
  const OrientedBox obb = compute_oriented_box(P);
  expect_proper_axes(obb);
  EXPECT_NEAR((obb.half_extents - h).norm(), 0.0, 1e-13);
  EXPECT_NEAR((obb.centre - t).norm(), 0.0, 1e-13);
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(std::abs(obb.axes.col(k).dot(R.col(k))), 1.0, 1e-12);
}

TEST(OrientedBox, EllipsoidAxesAndContainment) {
  std::mt19937_64 rng(4);
  const Vec3 radii(0.2, 0.05, 0.03);  // a long bone-like spheroid
  const Mat3 R = random_rotation(rng);
  const TriMesh m = transformed(make_ellipsoid(radii, 4), R, Vec3(1, 2, 3));
  const OrientedBox obb = compute_oriented_box(m);
  expect_proper_axes(obb);
  expect_contains(obb, m.V);
  // The subdivided icosahedron keeps the three coordinate mirror symmetries, so the surface
  // covariance is diagonal in the ellipsoid's frame: PCA gives its axes to rounding. The
  // minimum-volume box of the smooth ellipsoid is that one too (Hadamard's inequality); for the
  // polyhedron the refinement may tilt it slightly.
  const OrientedBox pca = compute_oriented_box(m, false);
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(std::abs(pca.axes.col(k).dot(R.col(k))), 1.0, 1e-12);
    EXPECT_NEAR(std::abs(obb.axes.col(k).dot(R.col(k))), 1.0, 1e-3);
    EXPECT_LE(obb.half_extents[k], radii[k] * (1 + 1e-12));
    EXPECT_GT(obb.half_extents[k], radii[k] * 0.99);
  }
  EXPECT_NEAR((obb.centre - Vec3(1, 2, 3)).norm(), 0.0, 1e-3 * radii.z());
  EXPECT_LE(obb.calc_volume(), pca.calc_volume());
  // The pose maps the box frame to the input frame.
  const Transform X = obb.calc_pose();
  EXPECT_NEAR((X * Vec3(obb.half_extents.x(), 0, 0) - obb.centre - obb.half_extents.x() * obb.axes.col(0)).norm(),
              0.0, 1e-15);
}

TEST(OrientedBox, RandomCloudsAreContainedAndRefinementNeverGrows) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> g(0.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    Points3 P(300, 3);
    const Vec3 s(1.0 + trial, 0.5, 0.2 + 0.1 * trial);
    for (Eigen::Index i = 0; i < P.rows(); ++i) P.row(i) = Eigen::RowVector3d(s.x() * g(rng), s.y() * g(rng), s.z() * g(rng));
    P = P * random_rotation(rng).transpose();
    const OrientedBox pca = compute_oriented_box(P, false);
    const OrientedBox refined = compute_oriented_box(P, true);
    expect_proper_axes(refined);
    expect_contains(pca, P);
    expect_contains(refined, P);
    EXPECT_LE(refined.calc_volume(), pca.calc_volume() * (1 + 1e-12));
  }
}

TEST(OrientedBox, BadInput) {
  EXPECT_THROW(compute_oriented_box(Points3(0, 3)), Error);
  Points3 P = Points3::Zero(3, 3);
  P(1, 1) = std::nan("");
  EXPECT_THROW(compute_oriented_box(P), Error);
  // A single point: a zero box at the point.
  const OrientedBox one = compute_oriented_box(Points3(Eigen::RowVector3d(1, 2, 3)));
  EXPECT_EQ(one.half_extents, Vec3::Zero());
  EXPECT_EQ(one.centre, Vec3(1, 2, 3));
}

}  // namespace
}  // namespace fascicle
