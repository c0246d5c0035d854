// Tables: OpenSim .mot/.sto and CSV reading on the shared motions and reference tables, writing
// round trips, resampling and malformed input.
#include <gtest/gtest.h>

#include <fstream>

#include "fascicle/core/error.hpp"
#include "fascicle/io/table.hpp"
#include "test_support.hpp"

namespace fascicle {
namespace {

struct Expected {
  const char* file;
  long rows;
  long columns;
  bool in_degrees;
  const char* first_label;
  double first_time;
  double first_value;
  double last_time;
};

class SharedTables : public ::testing::TestWithParam<Expected> {};

TEST_P(SharedTables, CountsAndFirstValues) {
  const Expected& e = GetParam();
  const Table t = read_table(test::data_path(e.file));
  EXPECT_EQ(t.rows(), e.rows);
  EXPECT_EQ(t.columns(), e.columns);
  EXPECT_EQ(t.data.rows(), e.rows);
  EXPECT_EQ(t.data.cols(), e.columns);
  EXPECT_EQ(t.in_degrees, e.in_degrees);
  EXPECT_EQ(t.labels.front(), e.first_label);
  EXPECT_DOUBLE_EQ(t.time[0], e.first_time);
  EXPECT_DOUBLE_EQ(t.data(0, 0), e.first_value);
  EXPECT_DOUBLE_EQ(t.time[t.rows() - 1], e.last_time);
}

INSTANTIATE_TEST_SUITE_P(
    OpenSimData, SharedTables,
    ::testing::Values(
        Expected{"opensim/motions/arm26_InverseKinematics.mot", 121, 2, true, "r_shoulder_elev", 0.0,
                 -0.03394423, 1.0},
        Expected{"opensim/motions/subject01_walk1_ik.mot", 211, 23, true, "pelvis_tilt", 0.5,
                 4.76281529, 4.0},
        Expected{"opensim/motions/subject_walk_armless_coordinates.mot", 238, 39, true,
                 "pelvis_tilt", 0.0, 0.50294757, 2.37},
        Expected{"opensim/motions/walk_gait1018_state_reference.mot", 151, 10, true,
                 "/jointset/ground_pelvis/pelvis_tilt/value", 0.0, 10.32995988, 2.5},
        Expected{"opensim/tests/std_testGeometryPathWrapping_subject_walk_armless_muscle_lengths.sto",
                 238, 18, false, "/forceset/bifemsh_r|length", 0.0, 0.1933032028885762, 2.37},
        Expected{"opensim/tests/std_testGeometryPathWrapping_walk_gait1018_muscle_lengths.sto", 151,
                 18, false, "/forceset/hamstrings_r|length", 0.0, 0.4510537601596267, 2.5}),
    [](const auto& info) { return test::make_test_name(info.param.file, info.index); });

TEST(Table, HeaderKeysAndName) {
  const Table t = read_table(test::data_path("opensim/motions/subject01_walk1_ik.mot"));
  EXPECT_EQ(t.name, "Coordinates");
  bool found_rows = false;
  for (const auto& [k, v] : t.header)
    if (k == "nRows") {
      found_rows = true;
      EXPECT_EQ(v, "211");
    }
  EXPECT_TRUE(found_rows);
  const long knee = find_column(t, "knee_angle_r");
  ASSERT_GE(knee, 0);
  EXPECT_DOUBLE_EQ(t.data(0, knee), -19.85408256);
  EXPECT_EQ(find_column(t, "no_such"), -1);
}

TEST(Table, CoordinateOfLabel) {
  EXPECT_EQ(find_coordinate_of_label("/jointset/knee_r/knee_angle_r/value"), "knee_angle_r");
  EXPECT_EQ(find_coordinate_of_label("knee_angle_r"), "knee_angle_r");
  EXPECT_EQ(find_coordinate_of_label("/jointset/knee_r/knee_angle_r/speed"), "");
}

Table small_table() {
  Table t;
  t.name = "small";
  t.labels = {"a", "b"};
  t.time.resize(3);
  t.time << 0.0, 0.1, 0.3;
  t.data.resize(3, 2);
  t.data << 1.0, -2.0, 2.0, 0.1234567890123456789, 4.0, 1e-17;
  t.in_degrees = true;
  return t;
}

TEST(Table, StoAndCsvRoundTripExactly) {
  const auto dir = test::scratch_dir("table_roundtrip");
  const Table t = small_table();
  for (const char* name : {"t.sto", "t.mot", "t.csv"}) {
    const auto p = dir / name;
    if (p.extension() == ".csv")
      write_csv(p, t);
    else
      write_sto(p, t);
    const Table r = read_table(p);
    EXPECT_EQ(r.labels, t.labels) << name;
    EXPECT_EQ(r.time, t.time) << name;
    EXPECT_EQ(r.data, t.data) << name;  // bitwise: shortest round-trip formatting
    if (p.extension() != ".csv") EXPECT_TRUE(r.in_degrees);
  }
}

TEST(Table, ResampleLinear) {
  const Table t = small_table();
  const Table r = resample_linear(t, 20.0);  // 0, 0.05, ..., 0.3
  ASSERT_EQ(r.rows(), 7);
  EXPECT_NEAR(r.time[6], 0.3, 1e-15);
  EXPECT_NEAR(r.data(1, 0), 1.5, 1e-14);                  // midway between 1 and 2
  EXPECT_NEAR(r.data(3, 0), 2.5, 1e-14);                  // t=0.15: quarter of the way 2→4
  EXPECT_NEAR(r.data(0, 1), -2.0, 1e-15);
  EXPECT_NEAR(calc_row_at(t, 1.0)[0], 4.0, 0.0);          // clamped past the end
  EXPECT_THROW(resample_linear(t, 0.0), Error);
}

void write_text(const std::filesystem::path& p, const std::string& s) {
  std::ofstream(p) << s;
}

// The error must name the file and the 1-based line; the message says what is wrong.
void expect_bad(const std::filesystem::path& p, long line, const std::string& fragment) {
  try {
    (void)read_table(p);
    FAIL() << "no error for " << p;
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_EQ(e.context().file, p.string());
    ASSERT_TRUE(e.context().line.has_value()) << e.what();
    EXPECT_EQ(*e.context().line, line) << e.what();
    EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
  }
}

TEST(Table, MalformedInputIsRejectedWithLineAndColumn) {
  const auto dir = test::scratch_dir("table_bad");
  const std::string head = "Coordinates\nversion=1\ninDegrees=no\nendheader\ntime\tq1\tq2\n";
  write_text(dir / "nan.mot", head + "0\t1\t2\n0.1\t1\tnan\n");
  expect_bad(dir / "nan.mot", 7, "column 3 ('q2')");
  write_text(dir / "short.mot", head + "0\t1\t2\n0.1\t1\n");
  expect_bad(dir / "short.mot", 7, "2 values");
  write_text(dir / "time.mot", head + "0\t1\t2\n0.2\t1\t2\n0.1\t1\t2\n");
  expect_bad(dir / "time.mot", 8, "does not increase");
  write_text(dir / "word.mot", head + "0\t1\tabc\n");
  expect_bad(dir / "word.mot", 6, "'abc'");
  write_text(dir / "noend.mot", "Coordinates\nversion=1\ntime\tq\n0\t1\n");
  expect_bad(dir / "noend.mot", 4, "endheader");
  write_text(dir / "notime.csv", "t,q\n0,1\n");
  expect_bad(dir / "notime.csv", 1, "'time'");
  write_text(dir / "deg.mot", "x\ninDegrees=maybe\nendheader\ntime\tq\n0\t1\n");
  expect_bad(dir / "deg.mot", 2, "inDegrees");
  EXPECT_THROW(read_table(dir / "missing.mot"), Error);
}

TEST(Table, CsvWithSpacesAndSemicolons) {
  const auto dir = test::scratch_dir("table_csv");
  write_text(dir / "a.csv", "time; x ;y\n0;1;2\n1;3;4\n");
  const Table t = read_table(dir / "a.csv");
  ASSERT_EQ(t.labels.size(), 2u);
  EXPECT_EQ(t.labels[0], "x");
  EXPECT_DOUBLE_EQ(t.data(1, 1), 4.0);
}

}  // namespace
}  // namespace fascicle
