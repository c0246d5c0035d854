// Every file of shared/data/negative gives the outcome documented in docs/geometry.md.
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mesh_repair.hpp"
#include "fascicle/geometry/mesh_validation.hpp"
#include "fascicle/io/mesh_io.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <set>

namespace fascicle {
namespace {

std::filesystem::path negative(const std::string& name) {
  return test::data_path("negative/" + name);
}

// read_mesh must throw bad_input naming the file, with `fragment` in the message.
void expect_read_error(const std::string& name, const std::string& fragment) {
  try {
    read_mesh(negative(name));
    FAIL() << name << " was read";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input) << e.what();
    EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    EXPECT_NE(e.message().find(fragment), std::string::npos) << e.what();
  }
}

// repair_mesh must refuse with `fragment` in the message.
void expect_repair_refused(const TriMesh& m, const std::string& fragment) {
  try {
    repair_mesh(m);
    FAIL() << "repaired";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(e.message().find(fragment), std::string::npos) << e.what();
    EXPECT_FALSE(e.context().suggestion.empty());
  }
}

TEST(NegativeFiles, UnreadableFiles) {
  expect_read_error("empty.stl", "empty");
  expect_read_error("truncated.stl", "declares 1000 triangles");
  expect_read_error("garbage.vtp", "not a VTK XML PolyData file");
}

TEST(NegativeFiles, BadIndex) {
  const TriMesh m = read_mesh(negative("bad_index.obj"));
  const MeshReport r = validate_mesh(m);
  EXPECT_EQ(r.out_of_range_faces, std::vector<int>{1});
  expect_repair_refused(m, "1 faces with out-of-range vertex indices");
}

TEST(NegativeFiles, NanVertex) {
  const TriMesh m = read_mesh(negative("nan_vertex.obj"));
  const MeshReport r = validate_mesh(m);
  EXPECT_EQ(r.nonfinite_vertices, std::vector<int>{3});
  EXPECT_TRUE(r.is_closed());  // topology alone is a closed tetrahedron
  expect_repair_refused(m, "1 vertices with NaN/Inf coordinates");
}

TEST(NegativeFiles, DegenerateFacesAreDropped) {
  const TriMesh m = read_mesh(negative("degenerate_faces.obj"));
  const MeshReport r = validate_mesh(m);
  EXPECT_EQ(r.degenerate_faces, (std::vector<int>{4, 5}));  // zero area; repeated index
  const RepairResult fixed = repair_mesh(m);
  EXPECT_EQ(fixed.mesh.F.rows(), 4);
  EXPECT_EQ(fixed.mesh.V.rows(), 4);  // vertex 5 was only used by the sliver
  EXPECT_TRUE(fixed.report.is_solid());
  EXPECT_NEAR(fixed.report.signed_volume, 1.0 / 6.0, 1e-15);
}

TEST(NegativeFiles, FlippedFaceIsReoriented) {
  const TriMesh m = read_mesh(negative("flipped_face_cube.obj"));
  const MeshReport r = validate_mesh(m);
  EXPECT_TRUE(r.is_closed());
  EXPECT_EQ(r.inconsistent_edges.size(), 3u);
  EXPECT_FALSE(r.is_solid());
  const RepairResult fixed = repair_mesh(m);
  ASSERT_EQ(fixed.actions.size(), 1u);
  EXPECT_EQ(fixed.actions[0], "flipped 1 faces (consistent, outward orientation)");
  EXPECT_TRUE(fixed.report.is_solid());
  EXPECT_NEAR(fixed.report.signed_volume, 1.0, 1e-15);
  // the flipped face was the last one; all others are unchanged
  EXPECT_EQ(fixed.mesh.F.topRows(11), m.F.topRows(11));
}

TEST(NegativeFiles, OpenCube) {
  const TriMesh m = read_mesh(negative("open_cube.obj"));
  const MeshReport r = validate_mesh(m);
  EXPECT_EQ(r.boundary_edges.size(), 4u);
  EXPECT_FALSE(r.is_closed());
  EXPECT_EQ(r.euler_characteristic, 1);
  expect_repair_refused(m, "4 boundary edges");
}

TEST(NegativeFiles, NonManifoldEdge) {
  const TriMesh m = read_mesh(negative("nonmanifold_edge.obj"));
  const MeshReport r = validate_mesh(m);
  ASSERT_EQ(r.nonmanifold_edges.size(), 1u);
  EXPECT_EQ(r.nonmanifold_edges[0], (std::array<int, 2>{0, 1}));
  EXPECT_TRUE(r.boundary_edges.empty());
  expect_repair_refused(m, "1 non-manifold edges");
}

TEST(NegativeFiles, SelfIntersecting) {
  const TriMesh m = read_mesh(negative("self_intersecting.obj"));
  const MeshReport r = validate_mesh(m);
  EXPECT_TRUE(r.is_closed());
  EXPECT_TRUE(r.is_manifold());
  EXPECT_EQ(r.num_components, 2);
  EXPECT_FALSE(r.self_intersections.empty());
  std::set<int> faces;
  for (const auto& p : r.self_intersections) {
    EXPECT_LT(p[0], 12);  // one face of each box
    EXPECT_GE(p[1], 12);
  }
  expect_repair_refused(m, "self-intersecting face pairs");
}

TEST(NegativeFiles, RealNonManifoldMuscles) {
  for (const std::string name : {"left_biceps_brachii.stl", "left_triceps_brachii.stl"}) {
    const TriMesh m = read_mesh(negative(name), LengthUnit::millimetre);
    const MeshReport r = validate_mesh(m, {.check_self_intersections = false});
    EXPECT_GE(r.nonmanifold_edges.size(), 100u) << name;
    std::printf("%s: %ld vertices, %ld faces, %zu non-manifold, %zu boundary edges\n",
                name.c_str(), r.num_vertices, r.num_faces, r.nonmanifold_edges.size(),
                r.boundary_edges.size());
    expect_repair_refused(m, "non-manifold edges");
  }
}

}  // namespace
}  // namespace fascicle
