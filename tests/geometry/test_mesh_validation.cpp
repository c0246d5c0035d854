// validate_mesh, triangles_intersect, repair_mesh and require_closed_manifold on inline meshes.
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mesh_repair.hpp"
#include "fascicle/geometry/mesh_validation.hpp"
#include "fascicle/geometry/primitives.hpp"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <limits>
#include <random>

namespace fascicle {
namespace {

TriMesh tetrahedron() {
  TriMesh m;
  m.V.resize(4, 3);
  m.V << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  m.F.resize(4, 3);
  m.F << 0, 2, 1, 0, 1, 3, 1, 2, 3, 2, 0, 3;
  return m;
}

TriMesh concat(const TriMesh& a, const TriMesh& b) {
  TriMesh m;
  m.V.resize(a.V.rows() + b.V.rows(), 3);
  m.V << a.V, b.V;
  m.F.resize(a.F.rows() + b.F.rows(), 3);
  m.F << a.F, (b.F.array() + static_cast<int>(a.V.rows())).matrix();
  return m;
}

TEST(MeshValidation, PrimitivesAreSolids) {
  for (const TriMesh& m : {make_box(Vec3(1, 2, 3)), make_icosphere(1.0, 3),
                           make_cylinder(0.5, 2.0, 32, 4), make_spindle(0, 1, 12, 5, [](double t) {
                             return 0.1 + t * (1 - t);
                           })}) {
    const MeshReport r = validate_mesh(m);
    EXPECT_TRUE(r.is_solid()) << format_report(r);
    EXPECT_EQ(r.num_components, 1);
    EXPECT_EQ(r.euler_characteristic, 2);  // sphere topology
    EXPECT_EQ(r.num_edges, 3 * m.F.rows() / 2);
    EXPECT_TRUE(r.self_intersections_checked);
  }
  const MeshReport torus = validate_mesh(make_torus(1.0, 0.3, 24, 12));
  EXPECT_TRUE(torus.is_solid());
  EXPECT_EQ(torus.euler_characteristic, 0);  // genus 1
}

TEST(MeshValidation, FlippedMeshIsInward) {
  TriMesh m = make_icosphere(1.0, 1);
  m.F.col(1).swap(m.F.col(2));
  const MeshReport r = validate_mesh(m);
  EXPECT_EQ(r.orientation, SurfaceOrientation::inward);
  EXPECT_LT(r.signed_volume, 0.0);
  EXPECT_FALSE(r.is_solid());
}

TEST(MeshValidation, ReportsEveryKindOfProblemWithoutIndexingOutOfRange) {
  TriMesh m = make_box(Vec3(1, 1, 1));  // 8 vertices, 12 faces
  // one NaN vertex, one out-of-range face, one flipped face, one repeated-index face
  m.V(7, 1) = std::numeric_limits<double>::quiet_NaN();
  m.F.conservativeResize(14, 3);
  m.F.row(12) << 0, 1, 1000;
  m.F.row(13) << 2, 2, 3;
  std::swap(m.F(0, 1), m.F(0, 2));
  const MeshReport r = validate_mesh(m);
  EXPECT_EQ(r.nonfinite_vertices, std::vector<int>{7});
  EXPECT_EQ(r.out_of_range_faces, std::vector<int>{12});
  EXPECT_EQ(r.degenerate_faces, std::vector<int>{13});
  EXPECT_EQ(r.inconsistent_edges.size(), 3u);  // the flipped face's three edges
  EXPECT_TRUE(r.boundary_edges.empty());
  EXPECT_FALSE(r.is_solid());
  EXPECT_EQ(r.orientation, SurfaceOrientation::undefined);
  const nlohmann::json j = to_json(r);
  EXPECT_EQ(j["out_of_range_faces"]["count"], 1);
  EXPECT_EQ(j["out_of_range_faces"]["items"][0], 12);
  EXPECT_EQ(j["inconsistent_edges"]["count"], 3);
  EXPECT_FALSE(j["solid"].get<bool>());
  EXPECT_GE(j["problems"].size(), 4u);
}

TEST(MeshValidation, OpenAndNonManifoldEdges) {
  TriMesh open = tetrahedron();
  open.F.conservativeResize(3, 3);
  const MeshReport r = validate_mesh(open);
  EXPECT_EQ(r.boundary_edges.size(), 3u);
  EXPECT_FALSE(r.is_closed());
  EXPECT_EQ(r.euler_characteristic, 1);  // a disc

  // a fin: a third triangle on edge (0,1) of the tetrahedron
  TriMesh fin = tetrahedron();
  fin.V.conservativeResize(5, 3);
  fin.V.row(4) << 0.5, -1, 0;
  fin.F.conservativeResize(5, 3);
  fin.F.row(4) << 0, 1, 4;
  const MeshReport rf = validate_mesh(fin);
  ASSERT_EQ(rf.nonmanifold_edges.size(), 1u);
  EXPECT_EQ(rf.nonmanifold_edges[0], (std::array<int, 2>{0, 1}));
  EXPECT_EQ(rf.boundary_edges.size(), 2u);
}

TEST(MeshValidation, ComponentsAndUnreferencedVertices) {
  TriMesh two = concat(make_icosphere(1, 1), make_box(Vec3(0.5, 0.5, 0.5)));
  two.V.rowwise() += Vec3(0, 0, 0).transpose();
  two.V.bottomRows(8).rowwise() += Vec3(5, 0, 0).transpose();
  two.V.conservativeResize(two.V.rows() + 2, 3);
  two.V.bottomRows(2).setZero();
  const MeshReport r = validate_mesh(two);
  EXPECT_EQ(r.num_components, 2);
  EXPECT_EQ(r.euler_characteristic, 4);
  EXPECT_EQ(r.num_unreferenced_vertices, 2);
  EXPECT_TRUE(r.is_solid());
}

TEST(TriangleIntersection, KnownCases) {
  const Vec3 a0(0, 0, 0), a1(1, 0, 0), a2(0, 1, 0);
  // piercing
  EXPECT_TRUE(triangles_intersect(a0, a1, a2, Vec3(0.2, 0.2, -1), Vec3(0.3, 0.2, 1),
                                  Vec3(0.2, 0.3, 1)));
  // above the plane
  EXPECT_FALSE(triangles_intersect(a0, a1, a2, Vec3(0.2, 0.2, 0.1), Vec3(0.3, 0.2, 1),
                                   Vec3(0.2, 0.3, 1)));
  // crossing the plane outside the triangle
  EXPECT_FALSE(triangles_intersect(a0, a1, a2, Vec3(2, 2, -1), Vec3(3, 2, 1), Vec3(2, 3, 1)));
  // touching at a point of the other's edge
  EXPECT_TRUE(triangles_intersect(a0, a1, a2, Vec3(0.5, 0, 0), Vec3(0.5, -1, 1),
                                  Vec3(0.5, -1, -1)));
  // coplanar overlapping, coplanar disjoint, coplanar nested
  EXPECT_TRUE(triangles_intersect(a0, a1, a2, Vec3(0.5, 0.5, 0) - Vec3(0.4, 0, 0),
                                  Vec3(1.5, 0.2, 0), Vec3(0.6, 1.5, 0)));
  EXPECT_FALSE(triangles_intersect(a0, a1, a2, Vec3(1, 1, 0), Vec3(2, 1, 0), Vec3(1, 2, 0)));
  EXPECT_TRUE(triangles_intersect(a0, a1, a2, Vec3(0.1, 0.1, 0), Vec3(0.2, 0.1, 0),
                                  Vec3(0.1, 0.2, 0)));
}

TEST(TriangleIntersection, AgreesWithSamplingOnRandomPairs) {
  // a pair found intersecting by dense sampling must be reported; the test is symmetric
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  const auto rnd = [&] { return Vec3(u(rng), u(rng), u(rng)); };
  int hits = 0;
  for (int n = 0; n < 2000; ++n) {
    const Vec3 a0 = rnd(), a1 = rnd(), a2 = rnd(), b0 = rnd(), b1 = rnd(), b2 = rnd();
    const bool ab = triangles_intersect(a0, a1, a2, b0, b1, b2);
    EXPECT_EQ(ab, triangles_intersect(b1, b2, b0, a2, a0, a1)) << n;
    hits += ab;
    // segment a_i a_j crossing triangle b (computed independently) implies intersection
    const Vec3 nb = (b1 - b0).cross(b2 - b0);
    for (int e = 0; e < 3; ++e) {
      const Vec3 p = e == 0 ? a0 : (e == 1 ? a1 : a2), q = e == 0 ? a1 : (e == 1 ? a2 : a0);
      const double dp = nb.dot(p - b0), dq = nb.dot(q - b0);
      if (dp * dq >= 0) continue;
      const Vec3 x = p + (q - p) * (dp / (dp - dq));
      const double s0 = nb.dot((b1 - b0).cross(x - b0)), s1 = nb.dot((b2 - b1).cross(x - b1)),
                   s2 = nb.dot((b0 - b2).cross(x - b2));
      if (s0 > 1e-9 && s1 > 1e-9 && s2 > 1e-9) {
        EXPECT_TRUE(ab) << n;
      }
    }
  }
  EXPECT_GT(hits, 100);
  EXPECT_LT(hits, 1900);
}

TEST(SelfIntersections, OverlappingBoxesAndDisjointBoxes) {
  TriMesh a = make_box(Vec3(0.5, 0.5, 0.5)), b = a;
  b.V.rowwise() += Vec3(0.5, 0.5, 0.5).transpose();
  const FacePairs hits = calc_self_intersections(concat(a, b));
  EXPECT_FALSE(hits.empty());
  for (const auto& p : hits) {
    EXPECT_LT(p[0], 12);  // each pair: one face of each box
    EXPECT_GE(p[1], 12);
  }
  b.V.rowwise() += Vec3(1.0, 0, 0).transpose();  // now 0.5 apart in x
  EXPECT_TRUE(calc_self_intersections(concat(a, b)).empty());
  // a sphere folded through itself: move one vertex through the opposite side
  TriMesh s = make_icosphere(1.0, 2);
  s.V.row(0) *= -1.5;
  EXPECT_FALSE(calc_self_intersections(s).empty());
}

TEST(MeshRepair, MergesDropsAndOrients) {
  // a box whose faces do not share vertices (like STL), with flipped faces and a sliver
  const TriMesh box = make_box(Vec3(1, 1, 1));
  TriMesh soup;
  soup.V.resize(3 * box.F.rows(), 3);
  soup.F.resize(box.F.rows() + 1, 3);
  for (Eigen::Index f = 0; f < box.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      soup.V.row(3 * f + k) = box.V.row(box.F(f, k)) + Vec3::Constant(1e-9 * k).transpose();
      soup.F(f, k) = static_cast<int>(3 * f + k);
    }
    if (f % 3 == 0) std::swap(soup.F(f, 1), soup.F(f, 2));
  }
  soup.F.row(box.F.rows()) << 0, 0, 1;
  EXPECT_THROW(repair_mesh(soup), Error);  // nothing merges exactly: every edge is a boundary
  const RepairResult r = repair_mesh(soup, {.merge_tolerance = 1e-6});
  EXPECT_EQ(r.mesh.V.rows(), 8);
  EXPECT_EQ(r.mesh.F.rows(), 12);
  EXPECT_TRUE(r.report.is_solid()) << format_report(r.report);
  EXPECT_NEAR(r.report.signed_volume, 8.0, 1e-6);
  EXPECT_EQ(r.actions.size(), 3u);  // merged, dropped, flipped
  // an all-inward mesh is turned outward
  TriMesh inward = make_icosphere(1, 2);
  inward.F.col(1).swap(inward.F.col(2));
  const RepairResult ro = repair_mesh(inward);
  EXPECT_EQ(ro.report.orientation, SurfaceOrientation::outward);
  EXPECT_EQ(ro.mesh.F.rows(), inward.F.rows());
  // a clean mesh needs nothing
  EXPECT_TRUE(repair_mesh(make_icosphere(1, 2)).actions.empty());
}

TEST(MeshRepair, RefusesWhatItCannotRepair) {
  TriMesh open = make_box(Vec3(1, 1, 1));
  open.F.conservativeResize(10, 3);
  try {
    repair_mesh(open);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(e.message().find("4 boundary edges"), std::string::npos) << e.what();
    EXPECT_FALSE(e.context().suggestion.empty());
  }
  TriMesh nan = make_box(Vec3(1, 1, 1));
  nan.V(3, 0) = std::numeric_limits<double>::infinity();
  EXPECT_THROW(repair_mesh(nan), Error);
  TriMesh bad = make_box(Vec3(1, 1, 1));
  bad.F(5, 2) = -3;
  EXPECT_THROW(repair_mesh(bad), Error);
  TriMesh a = make_box(Vec3(0.5, 0.5, 0.5)), b = a;
  b.V.rowwise() += Vec3(0.5, 0.5, 0.5).transpose();
  try {
    repair_mesh(concat(a, b));
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(e.message().find("self-intersecting"), std::string::npos) << e.what();
  }
}

TEST(MeshRepair, RequireClosedManifold) {
  EXPECT_NO_THROW(require_closed_manifold(make_icosphere(1, 2), "ball"));
  TriMesh open = make_box(Vec3(1, 1, 1));
  open.F.conservativeResize(11, 3);
  try {
    require_closed_manifold(open, "soleus");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.context().object, "soleus");
    EXPECT_NE(e.message().find("boundary edges"), std::string::npos);
  }
}

}  // namespace
}  // namespace fascicle
