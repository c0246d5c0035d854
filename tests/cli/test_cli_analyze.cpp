// End-to-end: `fascicle analyze` and `fascicle paths` on the shared OpenSim models and motions
// (a few frames each, to keep CI short), and their bad-input behaviour (exit codes, nothing written).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "fascicle/io/table.hpp"
#include "test_support.hpp"

namespace fascicle {
namespace {

namespace fs = std::filesystem;

int run(const std::string& args) {
  const std::string cmd = std::string(FASCICLE_CLI_PATH) + " -q " + args + " 2>/dev/null";
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

std::string q(const fs::path& p) { return "'" + p.string() + "'"; }

// The first `rows` frames of a motion, written to the scratch folder.
fs::path motion_subset(const std::string& rel, long rows, const fs::path& dir) {
  Table t = read_table(test::data_path(rel));
  rows = std::min(rows, t.rows());
  t.time = t.time.head(rows).eval();
  t.data = t.data.topRows(rows).eval();
  t.header.emplace_back("inDegrees", t.in_degrees ? "yes" : "no");
  const fs::path out = dir / fs::path(rel).filename();
  write_sto(out, t);
  return out;
}

long count_files(const fs::path& dir) {
  if (!fs::exists(dir)) return 0;
  long n = 0;
  for (const auto& e : fs::directory_iterator(dir)) n += e.is_regular_file();
  return n;
}

struct EndToEnd {
  const char* model;
  const char* motion;
  const char* stem;       // the model's name
  int muscles;
  const char* coordinate; // one coordinate expected among the moment-arm tables
};

class CliAnalyze : public ::testing::TestWithParam<EndToEnd> {};

TEST_P(CliAnalyze, WritesMuscleAnalysisTables) {
  const EndToEnd& c = GetParam();
  const fs::path dir = test::scratch_dir("cli_analyze_" + fs::path(c.model).stem().string());
  const fs::path motion = motion_subset(c.motion, 4, dir);
  const fs::path out = dir / "out";
  ASSERT_EQ(run("analyze --model " + q(test::data_path(c.model)) + " --motion " + q(motion) +
                " --geometry-dir " + q(test::data_path("opensim/Geometry")) + " --out " + q(out)),
            0);
  for (const char* quantity : {"Length", "FiberLength", "PennationAngle", "TendonLength",
                               "NormalizedFiberLength", "TendonForce", "ActiveFiberForce",
                               "PassiveFiberForce"}) {
    const fs::path f = out / (std::string(c.stem) + "_MuscleAnalysis_" + quantity + ".sto");
    ASSERT_TRUE(fs::exists(f)) << f;
    const Table t = read_table(f);
    EXPECT_EQ(t.rows(), 4);
    EXPECT_EQ(t.columns(), c.muscles);
    EXPECT_TRUE(t.data.allFinite()) << f;
  }
  const Table length = read_table(out / (std::string(c.stem) + "_MuscleAnalysis_Length.sto"));
  EXPECT_GT(length.data.minCoeff(), 0.01);
  EXPECT_LT(length.data.maxCoeff(), 1.5);
  const fs::path ma =
      out / (std::string(c.stem) + "_MuscleAnalysis_MomentArm_" + c.coordinate + ".sto");
  ASSERT_TRUE(fs::exists(ma)) << ma;
  const Table r = read_table(ma);
  EXPECT_GT(r.data.cwiseAbs().maxCoeff(), 0.005);  // some muscle acts on the coordinate
  EXPECT_LT(r.data.cwiseAbs().maxCoeff(), 0.2);
}

INSTANTIATE_TEST_SUITE_P(
    SharedModels, CliAnalyze,
    ::testing::Values(
        EndToEnd{"opensim/models/gait2392_thelen2003muscle.osim",
                 "opensim/motions/subject01_walk1_ik.mot", "3DGaitModel2392", 92,
                 "knee_angle_r"},
        EndToEnd{"opensim/models/gait2392_millard2012muscle.osim",
                 "opensim/motions/subject01_walk1_ik.mot", "3DGaitModel2392", 92,
                 "ankle_angle_l"},
        EndToEnd{"opensim/models/Rajagopal/Rajagopal2016.osim",
                 "opensim/motions/subject_walk_armless_coordinates.mot", "Rajagopal2016", 80,
                 "hip_flexion_r"},
        EndToEnd{"opensim/models/arm26.osim", "opensim/motions/arm26_InverseKinematics.mot",
                 "arm26", 6, "r_elbow_flex"}),
    [](const auto& info) { return test::make_test_name(info.param.model, info.index); });

TEST(CliAnalyze, RequestedCoordinatesOnly) {
  const fs::path dir = test::scratch_dir("cli_analyze_coords");
  const fs::path out = dir / "out";
  ASSERT_EQ(run("analyze --model " + q(test::data_path("opensim/models/arm26.osim")) +
                " --motion " + q(test::data_path("opensim/motions/arm26_InverseKinematics.mot")) +
                " --coordinates r_elbow_flex --out " + q(out)),
            0);
  EXPECT_EQ(count_files(out), 9);
  EXPECT_TRUE(fs::exists(out / "arm26_MuscleAnalysis_MomentArm_r_elbow_flex.sto"));
}

// `--opensim-lengths` reports multi-wrap lengths as OpenSim 4 does (docs/analyze.md, med_gas):
// against OpenSim's own reference table for frames where both of med_gas_r's cylinders wrap, the
// flag brings the length from millimetres off to micrometres off.
TEST(CliAnalyze, OpenSimLengthsMatchOpenSimOnTwoWrapFrames) {
  const fs::path dir = test::scratch_dir("cli_analyze_opensim_lengths");
  const Table full = read_table(test::data_path("opensim/motions/subject_walk_armless_coordinates.mot"));
  // Rows around t = 0.25 s, and only the armless model's coordinates (the arm columns come last).
  const auto arm = std::find(full.labels.begin(), full.labels.end(), "arm_flex_r");
  ASSERT_NE(arm, full.labels.end());
  const long columns = arm - full.labels.begin();
  const long first = 20, rows = 11;
  ASSERT_GE(full.rows(), first + rows);
  Table motion = full;
  motion.labels.resize(static_cast<std::size_t>(columns));
  motion.time = full.time.segment(first, rows).eval();
  motion.data = full.data.block(first, 0, rows, columns).eval();
  motion.header.emplace_back("inDegrees", full.in_degrees ? "yes" : "no");
  write_sto(dir / "walk.mot", motion);

  const Table reference = read_table(test::data_path(
      "opensim/tests/std_testGeometryPathWrapping_subject_walk_armless_muscle_lengths.sto"));
  const auto ref_col = std::find(reference.labels.begin(), reference.labels.end(),
                                 "/forceset/med_gas_r|length");
  ASSERT_NE(ref_col, reference.labels.end());
  const long rc = ref_col - reference.labels.begin();

  // Largest |length − OpenSim| of med_gas_r over the rows, for one run of the CLI.
  auto max_error = [&](const std::string& flags, const std::string& name) {
    const fs::path out = dir / name;
    EXPECT_EQ(run("analyze --model " +
                  q(test::data_path("opensim/models/subject_walk_armless_18musc.osim")) +
                  " --motion " + q(dir / "walk.mot") + " --geometry-dir " +
                  q(test::data_path("opensim/Geometry")) + " --coordinates knee_angle_r " + flags +
                  " --out " + q(out)),
              0);
    const Table length = read_table(out / "subject_scale_walk_MuscleAnalysis_Length.sto");
    const auto col = std::find(length.labels.begin(), length.labels.end(), "med_gas_r");
    EXPECT_NE(col, length.labels.end());
    if (col == length.labels.end()) return 1.0;
    double worst = 0;
    for (long i = 0; i < length.rows(); ++i) {
      long j = 0;
      while (j < reference.rows() && std::abs(reference.time(j) - length.time(i)) > 1e-9) ++j;
      EXPECT_LT(j, reference.rows()) << "no reference row at t = " << length.time(i);
      if (j == reference.rows()) return 1.0;
      worst = std::max(worst, std::abs(length.data(i, col - length.labels.begin()) -
                                        reference.data(j, rc)));
    }
    return worst;
  };
  EXPECT_LT(max_error("--cylinder-method opensim --opensim-lengths", "cached"), 1e-5);
  EXPECT_GT(max_error("--cylinder-method opensim", "plain"), 1e-3);
}

TEST(CliAnalyzeBadInput, ExitCodesAndNothingWritten) {
  const fs::path dir = test::scratch_dir("cli_analyze_bad");
  const std::string model = q(test::data_path("opensim/models/arm26.osim"));
  // Unknown coordinate column: bad input (3), no table written.
  Table t = read_table(test::data_path("opensim/motions/arm26_InverseKinematics.mot"));
  t.labels[0] = "r_wrist_dev";
  t.header.emplace_back("inDegrees", "yes");
  write_sto(dir / "unknown.mot", t);
  EXPECT_EQ(run("analyze --model " + model + " --motion " + q(dir / "unknown.mot") + " --out " +
                q(dir / "out1")),
            3);
  EXPECT_EQ(count_files(dir / "out1"), 0);
  // NaN in a motion.
  {
    std::ofstream f(dir / "nan.mot");
    f << "Coordinates\nversion=1\nnRows=2\nnColumns=3\ninDegrees=yes\nendheader\n"
         "time\tr_shoulder_elev\tr_elbow_flex\n0\t0\t10\n0.1\tnan\t12\n";
  }
  EXPECT_EQ(run("analyze --model " + model + " --motion " + q(dir / "nan.mot") + " --out " +
                q(dir / "out2")),
            3);
  EXPECT_EQ(count_files(dir / "out2"), 0);
  // Malformed XML.
  {
    std::ofstream f(dir / "broken.osim");
    f << "<OpenSimDocument Version=\"40000\"><Model name=\"x\"><BodySet></Model>";
  }
  EXPECT_EQ(run("analyze --model " + q(dir / "broken.osim") + " --motion " +
                q(test::data_path("opensim/motions/arm26_InverseKinematics.mot")) + " --out " +
                q(dir / "out3")),
            3);
  EXPECT_EQ(count_files(dir / "out3"), 0);
  // Unknown coordinate in --coordinates: usage (2).
  EXPECT_EQ(run("analyze --model " + model + " --motion " +
                q(test::data_path("opensim/motions/arm26_InverseKinematics.mot")) +
                " --coordinates nope --out " + q(dir / "out4")),
            2);
  // Missing required option: usage.
  EXPECT_EQ(run("analyze --model " + model + " --out " + q(dir / "out5")), 2);
}

TEST(CliPaths, WritesPathsAndBones) {
  const fs::path dir = test::scratch_dir("cli_paths");
  ASSERT_EQ(run("paths --model " + q(test::data_path("opensim/models/arm26.osim")) +
                " --pose r_elbow_flex=90deg,r_shoulder_elev=0.3 --geometry-dir " +
                q(test::data_path("opensim/Geometry")) + " --out " + q(dir)),
            0);
  EXPECT_GT(fs::file_size(dir / "arm26_paths.vtp"), 100u);
  EXPECT_GT(fs::file_size(dir / "arm26_bones.vtp"), 1000u);
  EXPECT_EQ(run("paths --model " + q(test::data_path("opensim/models/arm26.osim")) +
                " --pose nope=1 --out " + q(dir / "bad")),
            2);
}

}  // namespace
}  // namespace fascicle
