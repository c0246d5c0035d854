// Mesh readers/writers: round trips in every format and encoding, units, and real data
// (OpenSim .vtp bones, Visible Human STL).
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mesh_validation.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/mesh_io.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <vtkCellArray.h>
#include <vtkNew.h>
#include <vtkPolyData.h>
#include <vtkXMLPolyDataReader.h>

#include <fstream>
#include <limits>
#include <map>
#include <regex>

namespace fascicle {
namespace {

// An icosphere moved off the origin so that no coordinate is a "nice" number.
TriMesh test_mesh() {
  TriMesh m = make_icosphere(0.0371, 2);
  m.V.rowwise() += Vec3(0.1234567, -0.0456789, 0.3141593).transpose();
  return m;
}

std::string read_text(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// Same triangles corner by corner (face order kept), positions within `tol` (absolute, metres).
void expect_same_triangles(const TriMesh& a, const TriMesh& b, double tol) {
  ASSERT_EQ(a.F.rows(), b.F.rows());
  for (Eigen::Index f = 0; f < a.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const Vec3 pa = a.V.row(a.F(f, k)), pb = b.V.row(b.F(f, k));
      ASSERT_LE((pa - pb).cwiseAbs().maxCoeff(), tol) << "face " << f << " corner " << k;
    }
  }
}

struct RoundTrip {
  std::string file;
  MeshEncoding encoding;
  bool compress;
  bool exact;  // double precision kept
};

class MeshRoundTrip : public ::testing::TestWithParam<RoundTrip> {};

TEST_P(MeshRoundTrip, PositionsAndTopologySurvive) {
  const RoundTrip& c = GetParam();
  const TriMesh m = test_mesh();
  const auto path = test::scratch_dir("mesh_round_trip") / c.file;
  write_mesh(path, m, {.encoding = c.encoding, .compress = c.compress});
  const TriMesh r = read_mesh(path);
  // STL shares no vertices; joining identical corners must recover the original count
  EXPECT_EQ(r.V.rows(), m.V.rows());
  ASSERT_EQ(r.F.rows(), m.F.rows());
  if (c.exact) {
    EXPECT_EQ(r.F, m.F);
    EXPECT_EQ(r.V, m.V);  // bitwise: double precision kept
  } else {
    // float32 storage: relative rounding 2^-24 of coordinates below 0.4 m
    expect_same_triangles(m, r, 0.4 * std::numeric_limits<float>::epsilon());
  }
  EXPECT_TRUE(validate_mesh(r).is_solid());
}

INSTANTIATE_TEST_SUITE_P(
    AllFormats, MeshRoundTrip,
    ::testing::Values(RoundTrip{"m.obj", MeshEncoding::ascii, false, true},
                      RoundTrip{"m_ascii.stl", MeshEncoding::ascii, false, false},
                      RoundTrip{"m_binary.stl", MeshEncoding::binary, false, false},
                      RoundTrip{"m_ascii.ply", MeshEncoding::ascii, false, false},
                      RoundTrip{"m_binary.ply", MeshEncoding::binary, false, false},
                      RoundTrip{"m_ascii.vtp", MeshEncoding::ascii, false, true},
                      RoundTrip{"m_binary.vtp", MeshEncoding::binary, false, true},
                      RoundTrip{"m_binary_z.vtp", MeshEncoding::binary, true, true},
                      RoundTrip{"m_appended.vtp", MeshEncoding::appended, false, true},
                      RoundTrip{"m_appended_z.VTP", MeshEncoding::appended, true, true}),
    [](const auto& info) { return test::make_test_name(info.param.file, info.index); });

TEST(MeshIo, EncodingsAreWhatTheyClaim) {
  const auto dir = test::scratch_dir("mesh_encodings");
  const TriMesh m = test_mesh();
  write_mesh(dir / "a.stl", m, {.encoding = MeshEncoding::ascii});
  write_mesh(dir / "b.stl", m);
  write_mesh(dir / "a.vtp", m, {.encoding = MeshEncoding::ascii});
  write_mesh(dir / "p.vtp", m, {.encoding = MeshEncoding::appended, .compress = true});
  EXPECT_EQ(read_text(dir / "a.stl").rfind("solid", 0), 0u);
  EXPECT_EQ(std::filesystem::file_size(dir / "b.stl"), 84u + 50u * m.F.rows());
  EXPECT_NE(read_text(dir / "a.vtp").find("format=\"ascii\""), std::string::npos);
  const std::string p = read_text(dir / "p.vtp");
  EXPECT_NE(p.find("<AppendedData encoding=\"raw\">"), std::string::npos);
  EXPECT_NE(p.find("vtkZLibDataCompressor"), std::string::npos);
}

TEST(MeshIo, MillimetresAreScaledToMetres) {
  const auto dir = test::scratch_dir("mesh_units");
  TriMesh mm = make_box(Vec3(10, 20, 30));  // mm
  write_mesh(dir / "box.obj", mm);
  const TriMesh m = read_mesh(dir / "box.obj", LengthUnit::millimetre);
  EXPECT_DOUBLE_EQ(m.V.col(2).maxCoeff(), 0.030);
  EXPECT_DOUBLE_EQ(m.V.col(0).minCoeff(), -0.010);
  // and back out in millimetres
  write_mesh(dir / "box_mm.obj", m, {.unit = LengthUnit::millimetre});
  EXPECT_DOUBLE_EQ(read_mesh(dir / "box_mm.obj").V.col(1).maxCoeff(), 20.0);
}

TEST(MeshIo, ObjPolygonsAndRelativeIndicesAreTriangulated) {
  const auto path = test::scratch_dir("mesh_obj_poly") / "quad.obj";
  {
    std::ofstream out(path);
    out << "o thing\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nvt 0 0\n"
           "f 1/1/1 2/1/1 3/1/1 4/1/1\nf -4//1 -2//1 -1//1\n";
  }
  const TriMesh m = read_mesh(path);
  ASSERT_EQ(m.F.rows(), 3);
  EXPECT_EQ(m.F.row(0), Eigen::RowVector3i(0, 1, 2));
  EXPECT_EQ(m.F.row(1), Eigen::RowVector3i(0, 2, 3));
  EXPECT_EQ(m.F.row(2), Eigen::RowVector3i(0, 2, 3));
}

TEST(MeshIo, VtpPolygonsAndStripsAreTriangulated) {
  const auto path = test::scratch_dir("mesh_vtp_poly") / "poly.vtp";
  {
    std::ofstream out(path);
    out << R"(<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian">
<PolyData><Piece NumberOfPoints="5" NumberOfVerts="0" NumberOfLines="0" NumberOfStrips="1" NumberOfPolys="1">
<Points><DataArray type="Float32" NumberOfComponents="3" format="ascii">
0 0 0  1 0 0  1 1 0  0 1 0  0.5 1.5 0
</DataArray></Points>
<Polys><DataArray type="Int32" Name="connectivity" format="ascii">0 1 2 4 3</DataArray>
<DataArray type="Int32" Name="offsets" format="ascii">5</DataArray></Polys>
<Strips><DataArray type="Int32" Name="connectivity" format="ascii">0 1 3 2</DataArray>
<DataArray type="Int32" Name="offsets" format="ascii">4</DataArray></Strips>
</Piece></PolyData></VTKFile>
)";
  }
  const TriMesh m = read_mesh(path);
  ASSERT_EQ(m.F.rows(), 5);  // pentagon: 3 fan triangles; strip of 4: 2 triangles
  EXPECT_EQ(m.F.row(0), Eigen::RowVector3i(0, 1, 2));
  EXPECT_EQ(m.F.row(2), Eigen::RowVector3i(0, 4, 3));
  EXPECT_EQ(m.F.row(3), Eigen::RowVector3i(0, 1, 3));
  EXPECT_EQ(m.F.row(4), Eigen::RowVector3i(1, 2, 3));  // odd strip triangle reversed: same winding
  // all five triangles face +z
  for (Eigen::Index f = 0; f < 5; ++f) {
    const Vec3 a = m.V.row(m.F(f, 0)), b = m.V.row(m.F(f, 1)), c = m.V.row(m.F(f, 2));
    EXPECT_GT((b - a).cross(c - a).z(), 0.0) << f;
  }
}

TEST(MeshIo, ErrorsNameTheFile) {
  const auto dir = test::scratch_dir("mesh_errors");
  try {
    read_mesh(dir / "missing.stl");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("missing.stl"), std::string::npos);
  }
  EXPECT_THROW(read_mesh(dir / "mesh.xyz"), Error);
  {
    std::ofstream out(dir / "bad.obj");
    out << "v 0 0 0\nv 1 0 0\nv 0 one 0\nf 1 2 3\n";
  }
  try {
    read_mesh(dir / "bad.obj");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.context().line, 3);
  }
  TriMesh broken = make_box(Vec3(1, 1, 1));
  broken.F(3, 1) = 99;
  EXPECT_THROW(write_mesh(dir / "broken.stl", broken), Error);
  EXPECT_FALSE(std::filesystem::exists(dir / "broken.stl"));
}

// ---------------------------------------------------------------------------------------------
// Real data

TEST(MeshIoRealData, EveryOpenSimVtpReadsLikeVtkReadsIt) {
  const auto dir = test::data_path("opensim/Geometry");
  int files = 0, closed = 0;
  long ngon_files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.path().extension() != ".vtp") continue;
    ++files;
    const TriMesh m = read_mesh(entry.path());
    // what VTK's reader itself says
    vtkNew<vtkXMLPolyDataReader> reader;
    reader->SetFileName(entry.path().string().c_str());
    reader->Update();
    vtkPolyData* pd = reader->GetOutput();
    EXPECT_EQ(m.V.rows(), pd->GetNumberOfPoints()) << entry.path();
    long expected_triangles = 0;
    bool has_ngons = false;
    vtkCellArray* polys = pd->GetPolys();
    for (vtkIdType c = 0; c < polys->GetNumberOfCells(); ++c) {
      const vtkIdType n = polys->GetCellSize(c);
      has_ngons = has_ngons || n > 3;
      expected_triangles += n >= 3 ? n - 2 : 0;
    }
    ngon_files += has_ngons;
    EXPECT_EQ(m.F.rows(), expected_triangles) << entry.path();
    // and the XML header, read independently
    const std::string text = read_text(entry.path());
    std::smatch match;
    ASSERT_TRUE(std::regex_search(text, match, std::regex("NumberOfPoints=\"([0-9]+)\"")));
    EXPECT_EQ(m.V.rows(), std::stol(match[1])) << entry.path();
    const MeshReport report = validate_mesh(m, {.check_self_intersections = false});
    EXPECT_TRUE(report.out_of_range_faces.empty()) << entry.path();
    closed += report.is_closed();
  }
  EXPECT_EQ(files, 131);
  EXPECT_GT(ngon_files, 0);  // the README: some files hold quads/n-gons
  RecordProperty("closed_files", closed);
  std::printf("OpenSim Geometry: %d .vtp files, %d closed, %ld with n-gons\n", files, closed,
              ngon_files);
}

TEST(MeshIoRealData, VisibleHumanStlAreClosedManifoldOutward) {
  const auto dir = test::data_path("visible_human_female/right");
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.path().extension() != ".stl") continue;
    ++files;
    const TriMesh m = read_mesh(entry.path(), LengthUnit::millimetre);
    const MeshReport r = validate_mesh(m, {.check_self_intersections = false});
    EXPECT_TRUE(r.is_closed()) << entry.path();
    EXPECT_TRUE(r.is_manifold()) << entry.path();
    EXPECT_TRUE(r.is_consistently_oriented()) << entry.path();
    EXPECT_EQ(r.orientation, SurfaceOrientation::outward) << entry.path();
    EXPECT_TRUE(r.degenerate_faces.empty()) << entry.path();
    // in metres now: every part of a leg is smaller than a metre
    EXPECT_LT((m.V.colwise().maxCoeff() - m.V.colwise().minCoeff()).maxCoeff(), 1.0);
  }
  EXPECT_EQ(files, 60);
}

TEST(MeshIoRealData, VisibleHumanCounts) {
  // binary STL: (bytes - 84) / 50 triangles; closed genus-0 surfaces have F/2 + 2 vertices
  const std::map<std::string, std::array<long, 2>> expected = {
      {"VHF_Right_Bone_Tibia_smooth.stl", {30183, 60362}},
      {"VHF_Right_Bone_Patella_smooth.stl", {3296, 6588}},
      {"VHF_Right_Muscle_Plantaris_smooth.stl", {838, 1672}},
  };
  for (const auto& [name, counts] : expected) {
    const TriMesh m = read_mesh(test::data_path("visible_human_female/right/" + name));
    EXPECT_EQ(m.V.rows(), counts[0]) << name;
    EXPECT_EQ(m.F.rows(), counts[1]) << name;
  }
}

}  // namespace
}  // namespace fascicle
