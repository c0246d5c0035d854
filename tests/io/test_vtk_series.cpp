// PolyData .vtp output read back by VTK's own reader, .pvd collections, atomic writes.
#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/polydata.hpp"
#include "fascicle/io/vtk_series.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <string>
#include <thread>

namespace fs = std::filesystem;
using namespace fascicle;

namespace {

// A surface plus two polylines, with a scalar and a vector point field and a cell field.
PolyData make_sample() {
  PolyData d = make_polydata(make_icosphere(0.05, 2));
  const long n = d.points.rows();
  d.lines = {{0, 1, 2, 3}, {4, 5}};
  DataField height{"height", d.points.col(2)};
  DataField normal{"direction", d.points.rowwise().normalized()};
  MatX cell(d.num_cells(), 1);
  for (long c = 0; c < d.num_cells(); ++c) cell(c, 0) = 0.5 * static_cast<double>(c);
  d.point_fields = {height, normal};
  d.cell_fields = {{"cell_id_half", cell}};
  EXPECT_EQ(n, 162);
  return d;
}

}  // namespace

TEST(VtkSeries, PolyDataRoundTripThroughVtkReader) {
  const fs::path dir = test::scratch_dir("vtp_roundtrip");
  const PolyData d = make_sample();
  write_polydata(dir / "a.vtp", d);
  const PolyData r = read_polydata(dir / "a.vtp");
  ASSERT_EQ(r.points.rows(), 162);
  EXPECT_EQ(r.triangles.rows(), 320);
  ASSERT_EQ(r.lines.size(), 2u);
  EXPECT_EQ(r.lines[0], (std::vector<int>{0, 1, 2, 3}));
  EXPECT_EQ(r.num_cells(), 322);
  EXPECT_EQ((r.points - d.points).cwiseAbs().maxCoeff(), 0.0);  // stored as float64
  EXPECT_EQ((r.triangles - d.triangles).cwiseAbs().maxCoeff(), 0);
  ASSERT_EQ(r.point_fields.size(), 2u);
  EXPECT_EQ(r.point_fields[1].name, "direction");
  EXPECT_EQ(r.point_fields[1].values.cols(), 3);
  EXPECT_NEAR((r.point_fields[1].values - d.point_fields[1].values).norm(), 0.0, 1e-15);
  ASSERT_EQ(r.cell_fields.size(), 1u);
  EXPECT_EQ(r.cell_fields[0].values.rows(), 322);
  // lines come first in VTK's cell order
  EXPECT_DOUBLE_EQ(r.cell_fields[0].values(321, 0), 160.5);
}

TEST(VtkSeries, FieldSizeMismatchIsRejectedBeforeWriting) {
  const fs::path dir = test::scratch_dir("vtp_bad_field");
  PolyData d = make_sample();
  d.point_fields[0].values.resize(3, 1);
  EXPECT_THROW(write_polydata(dir / "bad.vtp", d), Error);
  EXPECT_FALSE(fs::exists(dir / "bad.vtp"));
}

TEST(VtkSeries, FailingWriteLeavesNoFileAndKeepsOldOne) {
  const fs::path dir = test::scratch_dir("vtp_atomic");
  const PolyData d = make_sample();
  write_polydata(dir / "keep.vtp", d);
  const auto size_before = fs::file_size(dir / "keep.vtp");
  PolyData bad = d;
  bad.triangles(0, 0) = 100000;  // invalid: nothing may be written
  EXPECT_THROW(write_polydata(dir / "keep.vtp", bad), Error);
  EXPECT_EQ(fs::file_size(dir / "keep.vtp"), size_before);
  EXPECT_NO_THROW(read_polydata(dir / "keep.vtp"));
  // no temporary files left behind
  int files = 0;
  for (const auto& e : fs::directory_iterator(dir)) files += e.is_regular_file() ? 1 : 0;
  EXPECT_EQ(files, 1);
}

TEST(VtkSeries, PvdCollectionRoundTrip) {
  const fs::path dir = test::scratch_dir("pvd");
  VtkSeriesWriter series(dir / "run.pvd");
  const int bone = series.find_or_add_part("tibia");
  const int muscle = series.find_or_add_part("soleus");
  EXPECT_EQ(series.find_or_add_part("tibia"), bone);
  for (int f = 0; f < 3; ++f) {
    series.add(0.02 * f, bone, "frames/tibia_" + std::to_string(f) + ".vtp");
    series.add(0.02 * f, muscle, "frames/soleus_" + std::to_string(f) + ".vtp");
    series.commit();
  }
  const auto read = read_pvd(dir / "run.pvd");
  ASSERT_EQ(read.size(), 6u);
  EXPECT_EQ(read[3].name, "soleus");
  EXPECT_EQ(read[3].part, 1);
  EXPECT_EQ(read[4].time_s, 0.04);  // 17 digits: exact
  EXPECT_EQ(read[5].file, "frames/soleus_2.vtp");
}

// commit() keeps the text of the datasets it has written and appends the new ones: after every
// commit the file has exactly the bytes write_pvd gives for the same datasets (escaped names too).
TEST(VtkSeries, IncrementalCommitsGiveTheBytesOfWritePvd) {
  const fs::path dir = test::scratch_dir("pvd_incremental");
  const auto read_bytes = [](const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  VtkSeriesWriter series(dir / "run.pvd");
  const int a = series.find_or_add_part("bone_a&b");
  const int b = series.find_or_add_part("muscle \"<x>\"");
  series.commit();  // no dataset yet
  write_pvd(dir / "reference.pvd", series.get_datasets());
  EXPECT_EQ(read_bytes(dir / "run.pvd"), read_bytes(dir / "reference.pvd"));
  for (int f = 0; f < 4; ++f) {
    series.add(0.1 * f, a, "frames/a_" + std::to_string(f) + ".vtp");
    if (f != 2) series.add(0.1 * f, b, "frames/b&_" + std::to_string(f) + ".vtp");
    series.commit();
    write_pvd(dir / "reference.pvd", series.get_datasets());
    EXPECT_EQ(read_bytes(dir / "run.pvd"), read_bytes(dir / "reference.pvd")) << f;
  }
  series.commit();  // nothing new: same file
  EXPECT_EQ(read_bytes(dir / "run.pvd"), read_bytes(dir / "reference.pvd"));
  const auto read = read_pvd(dir / "run.pvd");
  ASSERT_EQ(read.size(), 7u);
  EXPECT_EQ(read[1].name, "muscle \"<x>\"");
  EXPECT_EQ(read[6].file, "frames/b&_3.vtp");
  EXPECT_EQ(read[6].time_s, 0.1 * 3);
}

TEST(VtkSeries, ReadingGarbageIsBadInput) {
  const fs::path dir = test::scratch_dir("pvd_garbage");
  std::ofstream(dir / "x.pvd") << "<VTKFile type=\"PolyData\"></VTKFile>";
  std::ofstream(dir / "x.vtp") << "not xml at all";
  try {
    read_pvd(dir / "x.pvd");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
  }
  EXPECT_THROW(read_polydata(dir / "x.vtp"), Error);
  EXPECT_THROW(read_pvd(dir / "missing.pvd"), Error);
}

// Large arrays span several 32 KiB compression blocks (one of them exactly 8 full blocks): every
// value comes back bit for bit through VTK's reader, compressed (LZ4) or not, and writing twice
// gives the same bytes.
TEST(VtkSeries, LargeArraysRoundTripExactlyAndBytesAreDeterministic) {
  const fs::path dir = test::scratch_dir("vtp_large");
  PolyData d = make_polydata(make_icosphere(0.05, 5));  // 10242 points, 20480 triangles
  const long n = d.points.rows();
  MatX wavy(n, 3);
  for (long i = 0; i < n; ++i) wavy.row(i) << std::sin(0.37 * i), std::cos(1e3 * i) * 1e-7, 1.0 / (i + 1.0);
  d.point_fields = {{"wavy_m", wavy}};
  d.cell_fields = {{"force_N", MatX::Constant(d.num_cells(), 1, 740.018677180001)}};
  d.lines = {};
  PolyData exact;  // a lines-only PolyData whose field fills exactly 8 blocks (32768 doubles)
  exact.points = Points3::Random(32768, 3);
  for (int k = 0; k < 32768; k += 2) exact.lines.push_back({k, k + 1});
  exact.cell_fields = {{"weird <&\"> name", VecX::LinSpaced(16384, -1.0, 1.0)}};
  const auto read_bytes = [](const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  for (const VtpCompression compression : {VtpCompression::lz4, VtpCompression::none})
  for (const auto& [name, data] : {std::pair{"large", d}, std::pair{"exact", exact}}) {
    const fs::path file = dir / (std::string(name) + (compression == VtpCompression::lz4 ? "_lz4" : "_raw") + ".vtp");
    write_polydata(file, data, compression);
    const std::string header = read_bytes(file).substr(0, 300);
    EXPECT_EQ(header.find("compressor=\"vtkLZ4DataCompressor\"") != std::string::npos,
              compression == VtpCompression::lz4) << header;
    const PolyData r = read_polydata(file);
    ASSERT_EQ(r.points.rows(), data.points.rows()) << name;
    EXPECT_EQ(r.points, data.points) << name;
    EXPECT_EQ(r.triangles, data.triangles) << name;
    EXPECT_EQ(r.lines, data.lines) << name;
    ASSERT_EQ(r.point_fields.size(), data.point_fields.size()) << name;
    for (size_t f = 0; f < r.point_fields.size(); ++f) {
      EXPECT_EQ(r.point_fields[f].name, data.point_fields[f].name);
      EXPECT_EQ(r.point_fields[f].values, data.point_fields[f].values) << name;
    }
    ASSERT_EQ(r.cell_fields.size(), data.cell_fields.size()) << name;
    for (size_t f = 0; f < r.cell_fields.size(); ++f) {
      EXPECT_EQ(r.cell_fields[f].name, data.cell_fields[f].name);
      EXPECT_EQ(r.cell_fields[f].values, data.cell_fields[f].values) << name;
    }
    const std::string first = read_bytes(file);
    write_polydata(file, data, compression);
    EXPECT_EQ(read_bytes(file), first) << name;
  }
  // the constant force field is what LZ4 gains on; the raw file holds every byte
  EXPECT_LT(fs::file_size(dir / "large_lz4.vtp") + 20480 * 8 * 9 / 10, fs::file_size(dir / "large_raw.vtp"));
}

// The encoding buffer is reused from file to file (per thread): a small file written after a
// large one has exactly the bytes it has when written first, and is read back whole.
TEST(VtkSeries, SmallFileAfterLargeOneHasTheSameBytes) {
  const fs::path dir = test::scratch_dir("vtp_reuse");
  const auto read_bytes = [](const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  const PolyData small = make_sample();
  PolyData large = make_polydata(make_icosphere(0.05, 5));
  large.point_fields = {{"x", large.points.col(0)}};
  // References from fresh threads (each with a new, empty encoding buffer).
  std::thread([&] { write_polydata(dir / "small_first.vtp", small); }).join();
  std::thread([&] { write_polydata(dir / "large_first.vtp", large, VtpCompression::none); }).join();
  write_polydata(dir / "large.vtp", large, VtpCompression::none);
  write_polydata(dir / "small_after.vtp", small);
  EXPECT_GT(fs::file_size(dir / "large.vtp"), 10 * fs::file_size(dir / "small_first.vtp"));
  EXPECT_EQ(read_bytes(dir / "small_after.vtp"), read_bytes(dir / "small_first.vtp"));
  EXPECT_EQ(read_polydata(dir / "small_after.vtp").points, small.points);
  // Written concurrently (two threads, large and small interleaved, VTK's own TBB work inside):
  // every file has its reference's bytes.
  const ThreadLimit two(2);
  parallel_for(16, [&](std::size_t i) {
    const fs::path file = dir / ("parallel_" + std::to_string(i) + ".vtp");
    if (i % 2 == 0)
      write_polydata(file, large, VtpCompression::none);
    else
      write_polydata(file, small);
  });
  for (std::size_t i = 0; i < 16; ++i)
    EXPECT_EQ(read_bytes(dir / ("parallel_" + std::to_string(i) + ".vtp")),
              read_bytes(dir / (i % 2 == 0 ? "large_first.vtp" : "small_first.vtp")))
        << i;
}
