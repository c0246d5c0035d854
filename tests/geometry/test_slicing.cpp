// Plane slicing: contour counts, closure, orientation, exact on-plane handling and convergence.
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/geometry/slicing.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

namespace fascicle {
namespace {

constexpr double pi = std::numbers::pi;

// Every point of every contour lies on the plane.
void expect_on_plane(const std::vector<Contour>& cs, const Vec3& p0, const Vec3& n, double tol) {
  for (const Contour& c : cs) {
    for (Eigen::Index i = 0; i < c.points.rows(); ++i) {
      EXPECT_NEAR((c.points.row(i).transpose() - p0).dot(n.normalized()), 0.0, tol);
    }
  }
}

TEST(Slicing, TorusThroughItsAxisGivesTwoTubeSections) {
  const double R = 0.04, r = 0.01;
  const int M = 32;
  const TriMesh torus = make_torus(R, r, 64, M);
  for (const Vec3& n : {Vec3(0, 1, 0), Vec3(1, 0, 0), Vec3(1, 1, 0), Vec3(-0.3, 0.8, 0)}) {
    const std::vector<Contour> cs = slice_mesh(torus, Vec3::Zero(), n);
    ASSERT_EQ(cs.size(), 2u) << n.transpose();
    expect_on_plane(cs, Vec3::Zero(), n, 1e-16);
    for (const Contour& c : cs) {
      EXPECT_TRUE(c.closed);
      // Each section is a closed polygon near the circle of radius r about (R, 0) in the plane:
      // area between the inscribed M-gon's and the circle's, positive (counter-clockwise about n).
      const double area = compute_contour_area(c, n);
      EXPECT_GT(area, 0.5 * M * r * r * std::sin(2 * pi / M) * (1 - 0.02));
      EXPECT_LT(area, pi * r * r);
      // Every point lies on the mesh: near the tube of radius r about the centre circle, within
      // the sagitta of the 64-gon around the axis and of the M-gon around the tube.
      for (Eigen::Index i = 0; i < c.points.rows(); ++i) {
        const double rho = std::hypot(std::hypot(c.points(i, 0), c.points(i, 1)) - R, c.points(i, 2));
        EXPECT_LE(rho, r + R * (1 - std::cos(pi / 64)));
        EXPECT_GE(rho, 0.98 * r);
      }
    }
  }
  // Through the vertex ring at angle 0 (every point is a mesh vertex): exactly the M-gon.
  const std::vector<Contour> ring = slice_mesh(torus, Vec3::Zero(), Vec3(0, 1, 0));
  for (const Contour& c : ring) {
    if (c.points.col(0).mean() < 0) continue;  // the ring at angle pi is not exactly on the plane
    EXPECT_EQ(c.points.rows(), M);
    EXPECT_NEAR(compute_contour_area(c, Vec3(0, 1, 0)), 0.5 * M * r * r * std::sin(2 * pi / M), 1e-17);
  }
}

TEST(Slicing, TorusAcrossItsAxisGivesOuterAndHole) {
  const double R = 0.04, r = 0.01;
  const TriMesh torus = make_torus(R, r, 96, 32);  // the outer and inner equators lie on z = 0
  const std::vector<Contour> cs = slice_mesh(torus, Vec3::Zero(), Vec3(0, 0, 1));
  ASSERT_EQ(cs.size(), 2u);
  double outer = 0, hole = 0;
  for (const Contour& c : cs) {
    EXPECT_TRUE(c.closed);
    const double a = compute_contour_area(c, Vec3(0, 0, 1));
    (a > 0 ? outer : hole) = a;
  }
  // Outer boundary counter-clockwise about +z, the hole clockwise.
  EXPECT_NEAR(outer, pi * (R + r) * (R + r), 0.01 * outer);
  EXPECT_NEAR(hole, -pi * (R - r) * (R - r), 0.01 * -hole);
  // Flipping the normal flips the orientation rule with it: areas about the new normal keep signs.
  const std::vector<Contour> flipped = slice_mesh(torus, Vec3::Zero(), Vec3(0, 0, -1));
  ASSERT_EQ(flipped.size(), 2u);
  double sum = 0.0;
  for (const Contour& c : flipped) sum += compute_contour_area(c, Vec3(0, 0, -1));
  EXPECT_NEAR(sum, outer + hole, 1e-3 * outer);
}

TEST(Slicing, SphereCircleLengthConverges) {
  const double z = 0.3, rho = std::sqrt(1.0 - z * z);
  double previous = 1.0;
  for (int sub = 1; sub <= 5; ++sub) {
    const TriMesh sphere = make_icosphere(1.0, sub);
    const std::vector<Contour> cs = slice_mesh(sphere, Vec3(0, 0, z), Vec3(0, 0, 2));
    ASSERT_EQ(cs.size(), 1u);
    ASSERT_TRUE(cs[0].closed);
    expect_on_plane(cs, Vec3(0, 0, z), Vec3(0, 0, 1), 1e-15);
    EXPECT_GT(compute_contour_area(cs[0], Vec3(0, 0, 1)), 0.0);
    const double err = std::abs(compute_contour_length(cs[0]) - 2 * pi * rho) / (2 * pi * rho);
    EXPECT_LT(err, previous) << "subdivision " << sub;
    previous = err;
  }
  EXPECT_LT(previous, 2e-3);
}

TEST(Slicing, PlaneThroughVerticesAndEdges) {
  // The equator z = 0 of an icosphere holds vertices and whole edges: still one closed contour,
  // its points exactly on the plane, on-plane vertices reproduced exactly, no duplicates.
  const TriMesh sphere = make_icosphere(1.0, 3);
  int on_plane_vertices = 0;
  for (Eigen::Index v = 0; v < sphere.V.rows(); ++v) on_plane_vertices += sphere.V(v, 2) == 0.0;
  ASSERT_GE(on_plane_vertices, 4);
  const std::vector<Contour> cs = slice_mesh(sphere, Vec3::Zero(), Vec3(0, 0, 1));
  ASSERT_EQ(cs.size(), 1u);
  ASSERT_TRUE(cs[0].closed);
  const Contour& c = cs[0];
  int at_vertices = 0;
  for (Eigen::Index i = 0; i < c.points.rows(); ++i) {
    EXPECT_EQ(c.points(i, 2), 0.0);
    EXPECT_LE(c.points.row(i).norm(), 1.0 + 1e-15);
    EXPECT_GT(c.points.row(i).norm(), 0.99);
    EXPECT_NE(c.points.row(i), c.points.row((i + 1) % c.points.rows()));
    for (Eigen::Index v = 0; v < sphere.V.rows(); ++v) at_vertices += c.points.row(i) == sphere.V.row(v);
  }
  EXPECT_EQ(at_vertices, on_plane_vertices);
  const double len = compute_contour_length(c);
  EXPECT_LT(len, 2 * pi);
  EXPECT_GT(len, 2 * pi * 0.995);
}

TEST(Slicing, BoxFacePlaneIsClassifiedConsistently) {
  const Vec3 h(0.03, 0.02, 0.01);
  const TriMesh box = make_box(h);
  // The plane of the +x face with normal +x: vertices on the plane count as above it, so the
  // section is the face rectangle (the box lies below).
  std::vector<Contour> cs = slice_mesh(box, Vec3(h.x(), 0, 0), Vec3(1, 0, 0));
  ASSERT_EQ(cs.size(), 1u);
  EXPECT_TRUE(cs[0].closed);
  EXPECT_EQ(cs[0].points.rows(), 4);
  EXPECT_NEAR(compute_contour_area(cs[0], Vec3(1, 0, 0)), 4 * h.y() * h.z(), 1e-18);
  EXPECT_NEAR(compute_contour_length(cs[0]), 4 * (h.y() + h.z()), 1e-16);
  // The same plane with normal -x: every vertex is on or above it, so nothing is cut.
  EXPECT_TRUE(slice_mesh(box, Vec3(h.x(), 0, 0), Vec3(-1, 0, 0)).empty());
  // A plane missing the box.
  EXPECT_TRUE(slice_mesh(box, Vec3(0, 0, 1), Vec3(0, 0, 1)).empty());
  // A mid-plane.
  cs = slice_mesh(box, Vec3(0, 0.005, 0), Vec3(0, 1, 0));
  ASSERT_EQ(cs.size(), 1u);
  EXPECT_NEAR(compute_contour_area(cs[0], Vec3(0, 1, 0)), 4 * h.x() * h.z(), 1e-18);
}

TEST(Slicing, OpenMeshGivesAnOpenChain) {
  // A box without its two +z triangles: the slice x = 0 is a U-shaped open chain.
  const Vec3 h(0.03, 0.02, 0.01);
  TriMesh box = make_box(h);
  TriMesh open = box;
  int kept = 0;
  open.F.resize(box.F.rows(), 3);
  for (Eigen::Index f = 0; f < box.F.rows(); ++f) {
    const bool top = box.V(box.F(f, 0), 2) > 0 && box.V(box.F(f, 1), 2) > 0 && box.V(box.F(f, 2), 2) > 0;
    if (!top) open.F.row(kept++) = box.F.row(f);
  }
  open.F.conservativeResize(kept, 3);
  ASSERT_EQ(kept, 10);
  const std::vector<Contour> cs = slice_mesh(open, Vec3::Zero(), Vec3(1, 0, 0));
  ASSERT_EQ(cs.size(), 1u);
  EXPECT_FALSE(cs[0].closed);
  const Contour& c = cs[0];
  EXPECT_NEAR(c.points(0, 2), h.z(), 1e-18);  // starts and ends on the open rim
  EXPECT_NEAR(c.points(c.points.rows() - 1, 2), h.z(), 1e-18);
  EXPECT_NEAR(compute_contour_length(c), 2 * h.y() + 4 * h.z(), 1e-16);
}

TEST(Slicing, ParallelPlanesEqualSingleSlices) {
  const TriMesh sphere = make_ellipsoid(Vec3(0.02, 0.03, 0.05), 4);
  VecX offsets = VecX::LinSpaced(21, -0.049, 0.049);
  const auto batch = slice_mesh_parallel(sphere, Vec3(0, 0, 3), offsets);
  ASSERT_EQ(batch.size(), 21u);
  for (Eigen::Index i = 0; i < offsets.size(); ++i) {
    const auto single = slice_mesh(sphere, Vec3(0, 0, offsets[i]), Vec3(0, 0, 1));
    ASSERT_EQ(batch[static_cast<std::size_t>(i)].size(), single.size());
    ASSERT_EQ(single.size(), 1u);
    EXPECT_EQ(batch[static_cast<std::size_t>(i)][0].points, single[0].points);
    // The polyhedron is convex and inscribed in the ellipsoid, so its section lies inside the
    // ellipse of area pi a b (1 - z^2/c^2): smaller, by a discretisation error of a few percent
    // (largest near the poles, where triangles are large relative to the section).
    const double zc = offsets[i] / 0.05;
    const double exact = pi * 0.02 * 0.03 * (1 - zc * zc);
    const double area = compute_contour_area(single[0], Vec3(0, 0, 1));
    EXPECT_LT(area, exact);
    EXPECT_GT(area, (std::abs(zc) < 0.5 ? 0.995 : 0.95) * exact);
  }
}

TEST(Slicing, BadPlaneIsRejected) {
  const TriMesh box = make_box(Vec3(1, 1, 1));
  EXPECT_THROW(slice_mesh(box, Vec3::Zero(), Vec3::Zero()), Error);
  EXPECT_THROW(slice_mesh(box, Vec3::Zero(), Vec3(std::nan(""), 0, 1)), Error);
}

}  // namespace
}  // namespace fascicle
