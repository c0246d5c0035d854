// Muscle-path throughput on real OpenSim models over real motions, one core:
//  gait2392 (92 muscles, via/conditional/moving points) over subject01_walk1_ik.mot (211 frames),
//  Rajagopal2016 (80 muscles, 40 wrap cylinders, coupled knee) over
//  subject_walk_armless_coordinates.mot (238 frames).
// Each iteration runs the whole motion. The counter `per_muscle_frame` is the time per muscle and
// frame, the skeleton pose (Simbody realize) and, for moment arms, the body Jacobians included.
//   Poses        : skeleton pose only (shared by all muscles of a frame)
//   PosesJacobians: pose + body Jacobians
//   Lengths      : pose + every muscle's path length (wrapping included)
//   MomentArms   : pose + body Jacobians + lengths + moment arms for every coordinate
//   Analysis     : calc_muscle_analysis (lengths, moment arms of the spanned coordinates, static
//                  equilibrium of every muscle), serial
#include <benchmark/benchmark.h>

#include <string>

#include "fascicle/core/parallel.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/osim/analyze.hpp"

using namespace fascicle;

namespace {

struct Case {
  OsimAnalysisModel model;
  Table motion;
  std::vector<VecX> poses;
};

Case load_case(const std::string& model_rel, const std::string& motion_rel) {
  const std::string root = FASCICLE_DEFAULT_DATA_DIR;
  OsimImportOptions import;
  import.warn = false;
  Case c{load_osim_model(root + "/" + model_rel, import), read_table(root + "/" + motion_rel), {}};
  const MotionColumns mc = match_motion_columns(c.model.skeleton, c.motion, motion_rel, false);
  for (long r = 0; r < c.motion.rows(); ++r)
    c.poses.push_back(get_motion_pose(c.model.skeleton, c.motion, mc, r));
  return c;
}

const Case& gait2392() {
  static const Case c = load_case("opensim/models/gait2392_thelen2003muscle.osim",
                                  "opensim/motions/subject01_walk1_ik.mot");
  return c;
}

const Case& rajagopal() {
  static const Case c = load_case("opensim/models/Rajagopal/Rajagopal2016.osim",
                                  "opensim/motions/subject_walk_armless_coordinates.mot");
  return c;
}

enum class Work { poses, jacobians, lengths, moment_arms };

void run(benchmark::State& state, const Case& c, Work work) {
  OsimFrame frame(c.model);
  PathResult result;
  const int nm = c.model.num_muscles();
  double sink = 0;
  for (auto _ : state) {
    for (const VecX& q : c.poses) {
      calc_frame(c.model, q, frame, work == Work::moment_arms || work == Work::jacobians);
      if (work == Work::poses || work == Work::jacobians) continue;
      for (int m = 0; m < nm; ++m) {
        const int p = c.model.muscle_path[m];
        sink += calc_path_length(c.model, frame, p, result);
        if (work == Work::moment_arms) sink += calc_path_moment_arms(c.model, frame, p, result)[0];
      }
    }
    benchmark::DoNotOptimize(sink);
  }
  const double items = static_cast<double>(c.poses.size()) * nm;
  state.counters["per_muscle_frame"] = benchmark::Counter(
      items, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
  state.counters["muscles"] = nm;
  state.counters["frames"] = static_cast<double>(c.poses.size());
}

void run_analysis(benchmark::State& state, const Case& c) {
  const ThreadLimit one(1);
  MuscleAnalysisOptions opt;
  opt.progress = false;
  for (auto _ : state) {
    const MuscleAnalysis a = calc_muscle_analysis(c.model, c.motion, opt);
    benchmark::DoNotOptimize(a.length.data());
  }
  const double items = static_cast<double>(c.motion.rows()) * c.model.num_muscles();
  state.counters["per_muscle_frame"] = benchmark::Counter(
      items, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

void BM_Gait2392_Poses(benchmark::State& s) { run(s, gait2392(), Work::poses); }
void BM_Gait2392_PosesJacobians(benchmark::State& s) { run(s, gait2392(), Work::jacobians); }
void BM_Gait2392_Lengths(benchmark::State& s) { run(s, gait2392(), Work::lengths); }
void BM_Gait2392_LengthsMomentArms(benchmark::State& s) { run(s, gait2392(), Work::moment_arms); }
void BM_Gait2392_Analysis(benchmark::State& s) { run_analysis(s, gait2392()); }
void BM_Rajagopal_Poses(benchmark::State& s) { run(s, rajagopal(), Work::poses); }
void BM_Rajagopal_PosesJacobians(benchmark::State& s) { run(s, rajagopal(), Work::jacobians); }
void BM_Rajagopal_Lengths(benchmark::State& s) { run(s, rajagopal(), Work::lengths); }
void BM_Rajagopal_LengthsMomentArms(benchmark::State& s) { run(s, rajagopal(), Work::moment_arms); }
void BM_Rajagopal_Analysis(benchmark::State& s) { run_analysis(s, rajagopal()); }

}  // namespace

BENCHMARK(BM_Gait2392_Poses)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Gait2392_PosesJacobians)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Gait2392_Lengths)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Gait2392_LengthsMomentArms)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Gait2392_Analysis)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Rajagopal_Poses)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Rajagopal_PosesJacobians)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Rajagopal_Lengths)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Rajagopal_LengthsMomentArms)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Rajagopal_Analysis)->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();
