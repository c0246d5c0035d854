// Parity with OpenSim: muscle-tendon lengths of OpenSim's own wrapping tests
// (opensim-core OpenSim/Tests/Wrapping, reference tables computed by OpenSim 4.4.1) at every frame.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "fascicle/io/table.hpp"
#include "fascicle/osim/analyze.hpp"
#include "test_support.hpp"

namespace fascicle {
namespace {

// Muscles known to miss 1e-6 m, with the bound they are held to (docs/analyze.md explains why).
struct KnownMiss {
  const char* muscle;
  double bound_m;
};

struct ParityCase {
  const char* model;
  const char* motion;
  const char* reference;
  double tolerance_m;
  std::vector<KnownMiss> known = {};
  CylinderMethod method = CylinderMethod::geodesic;
  // PathOptions::opensim_tangent_point_cache: OpenSim's reported length on multi-wrap paths.
  bool tangent_point_cache = true;
};

// Largest |L_fascicle − L_OpenSim| over frames and muscles, with the worst muscle and time.
struct ParityResult {
  double max_error = 0;
  std::string worst;
  int compared = 0;
  std::vector<std::pair<std::string, double>> per_muscle;  // largest error of each muscle
};

ParityResult run_parity(const ParityCase& c) {
  OsimImportOptions import;
  import.warn = false;
  PathOptions po;
  po.cylinder_method = c.method;
  po.opensim_tangent_point_cache = c.tangent_point_cache;
  const OsimAnalysisModel model = load_osim_model(test::data_path(c.model), import, po);
  const Table motion = read_table(test::data_path(c.motion));
  const Table reference = read_table(test::data_path(c.reference));
  const MotionColumns columns = match_motion_columns(model.skeleton, motion, c.motion, /*strict=*/false);
  EXPECT_EQ(motion.rows(), reference.rows());
  OsimFrame frame(model);
  PathResult path;
  ParityResult out;
  for (long row = 0; row < std::min(motion.rows(), reference.rows()); ++row) {
    EXPECT_NEAR(motion.time[row], reference.time[row], 1e-6);
    calc_frame(model, get_motion_pose(model.skeleton, motion, columns, row), frame, false);
    for (long col = 0; col < reference.columns(); ++col) {
      const std::string& label = reference.labels[col];  // /forceset/<muscle>|length
      const std::string name = label.substr(10, label.find('|') - 10);
      const int m = model.find_muscle(name);
      EXPECT_GE(m, 0) << label;
      if (m < 0) continue;
      const double L = calc_path_length(model, frame, model.muscle_path[m], path);
      const double e = std::abs(L - reference.data(row, col));
      ++out.compared;
      if (static_cast<long>(out.per_muscle.size()) <= col) out.per_muscle.resize(col + 1);
      out.per_muscle[col].first = name;
      out.per_muscle[col].second = std::max(out.per_muscle[col].second, e);
      if (e > out.max_error) {
        out.max_error = e;
        out.worst = name + " at t = " + std::to_string(reference.time[row]);
      }
    }
  }
  return out;
}

class Parity : public ::testing::TestWithParam<ParityCase> {};

TEST_P(Parity, MuscleLengthsEqualOpenSimAtEveryFrame) {
  const ParityResult r = run_parity(GetParam());
  std::printf("[parity] %s (%s cylinders): %d lengths, max |error| = %.3g m (%s)\n", GetParam().model,
              GetParam().method == CylinderMethod::geodesic ? "geodesic" : "OpenSim-iterative",
              r.compared,
              r.max_error, r.worst.c_str());
  EXPECT_GT(r.compared, 1000);
  for (const auto& [name, e] : r.per_muscle) {
    double bound = GetParam().tolerance_m;
    for (const KnownMiss& k : GetParam().known)
      if (name == k.muscle) bound = k.bound_m;
    if (e > GetParam().tolerance_m) std::printf("[parity]   %s: %.3g m\n", name.c_str(), e);
    EXPECT_LE(e, bound) << name;
  }
}

INSTANTIATE_TEST_SUITE_P(
    OpenSimWrappingTests, Parity,
    ::testing::Values(
        ParityCase{"opensim/models/walk_gait1018_subject01.osim",
                   "opensim/motions/walk_gait1018_state_reference.mot",
                   "opensim/tests/std_testGeometryPathWrapping_walk_gait1018_muscle_lengths.sto",
                   1e-6},
        // med_gas (two cylinders): OpenSim reports straight pieces between first-pass tangent
        // points and last-pass arcs (PathOptions::opensim_tangent_point_cache; without it the
        // error is 5.6 mm). What is left, a few µm, comes from OpenSim's iterative tangent
        // points, which its stale straight pieces feel to first order (docs/analyze.md).
        // psoas_r: OpenSim builds its single cylinder wrap from an apex plane, not the helix.
        ParityCase{"opensim/models/subject_walk_armless_18musc.osim",
                   "opensim/motions/subject_walk_armless_coordinates.mot",
                   "opensim/tests/std_testGeometryPathWrapping_subject_walk_armless_muscle_lengths.sto",
                   1e-6,
                   {{"med_gas_r", 4e-6}, {"med_gas_l", 4e-6}, {"psoas_r", 2e-6}}},
        // OpenSim's own cylinder construction (CylinderMethod::opensim_iterative) brings psoas_r
        // within 1e-6 m; med_gas is further off with it (8.9 µm) than with the helix.
        ParityCase{"opensim/models/subject_walk_armless_18musc.osim",
                   "opensim/motions/subject_walk_armless_coordinates.mot",
                   "opensim/tests/std_testGeometryPathWrapping_subject_walk_armless_muscle_lengths.sto",
                   1e-6, {{"med_gas_r", 9e-6}, {"med_gas_l", 9e-6}},
                   CylinderMethod::opensim_iterative}),
    [](const auto& info) { return test::make_test_name(info.param.model, info.index); });

}  // namespace
}  // namespace fascicle
