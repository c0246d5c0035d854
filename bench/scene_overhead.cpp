// Per-frame scene overhead outside the muscle representations, on the Visible Human female right
// shank example (examples/vh_shank: 7 surface-first muscles, 4.4k–14k vertices each, a moving foot
// bone of ~100k triangles), one thread:
//   - OverlapMeasure/reused: calc_muscle_overlaps on the surfaces of two consecutive frames in turn,
//     with the State's cache filled by earlier frames (what every frame after the first costs in
//     `fascicle run`);
//   - OverlapMeasure/fresh: the same with an empty cache every time (each surface query built anew);
//   - OverlapMeasureBefore: the measure as it was before (queries built every frame, deformation's
//     calc_surface_overlap on every pair, sequential);
//   - ParaViewFrame: the "paraview" writer's write_frame for one frame (bone, 7 surfaces, 7 fibre
//     sets, 7 action lines), alternating between two frames so the moving foot is rewritten;
//     finish() included (it waits for any file still being written).
// The scene is compiled and two frames solved once in the setup (several seconds).
#include "fascicle/core/parallel.hpp"
#include "fascicle/deformation/surface_first.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/driver.hpp"
#include "fascicle/scene/scene_json.hpp"

#include <benchmark/benchmark.h>

#include <cstdlib>
#include <filesystem>
#include <stdexcept>
#include <memory>

namespace fascicle {
namespace {

namespace fs = std::filesystem;

// The example: $FASCICLE_SOURCE_DIR/examples/vh_shank, else the first folder above this program
// (the build folder lies in the repository) that holds it.
fs::path find_scene() {
  const fs::path rel = fs::path("examples") / "vh_shank" / "scene.json";
  if (const char* env = std::getenv("FASCICLE_SOURCE_DIR"); env != nullptr && *env != '\0') return fs::path(env) / rel;
  for (fs::path p = fs::canonical("/proc/self/exe").parent_path(); p.has_relative_path(); p = p.parent_path())
    if (fs::exists(p / rel)) return p / rel;
  throw std::runtime_error("examples/vh_shank not found above this program; set FASCICLE_SOURCE_DIR");
}

struct Shank {
  Registry registry = make_default_registry();
  std::unique_ptr<Model> model;
  std::vector<State> states;  // frames 40 and 41 of the example's motion

  Shank() {
    ThreadLimit limit(2);
    const SceneSpec spec = load_scene(find_scene(), registry);
    model = std::make_unique<Model>(compile(spec, registry));
    const CoordinateTrajectory traj = make_trajectory(*model, read_table(spec.motion->file), spec.motion->frame_rate_hz);
    State s = make_state(*model);
    for (int f = 0; f < 40; ++f) {  // the frames before, in order (each warm-starts the next)
      s.time_s = traj.time[f];
      s.q = traj.q.row(f).transpose();
      forward(*model, s);
    }
    // Two states at consecutive frames (surfaces, transforms and metrics; caches stay empty).
    for (int k = 0; k < 2; ++k) {
      const int f = 40 + k;
      s.time_s = traj.time[f];
      s.q = traj.q.row(f).transpose();
      forward(*model, s);
      State copy = make_state(*model);
      copy.time_s = s.time_s;
      copy.q = s.q;
      copy.X_ground_body = s.X_ground_body;
      copy.muscles = s.muscles;
      copy.stage = s.stage;
      states.push_back(std::move(copy));
    }
  }
};

Shank& get_shank() {
  static Shank shank;  // set up once for all benchmarks of this program
  return shank;
}

void BM_OverlapMeasure(benchmark::State& bm, bool reuse) {
  Shank& shank = get_shank();
  ThreadLimit limit(1);
  // Surfaces of frames 40 and 41 in turn, as consecutive frames of a run.
  State& s = shank.states[0];
  std::vector<MuscleFrame> other = shank.states[1].muscles;
  calc_muscle_overlaps(*shank.model, s);
  for (auto _ : bm) {
    std::swap(s.muscles, other);
    if (!reuse) s.overlap_cache = MuscleOverlapCache{};
    calc_muscle_overlaps(*shank.model, s);
    benchmark::DoNotOptimize(s.muscles[0].max_muscle_overlap_m);
  }
  double worst = 0.0;
  for (const MuscleFrame& f : s.muscles) worst = std::max(worst, f.max_muscle_overlap_m);
  bm.counters["max_overlap_mm"] = 1e3 * worst;
}
BENCHMARK_CAPTURE(BM_OverlapMeasure, reused, true)->Unit(benchmark::kMillisecond);

// The measure as it was before the State's cache: a MeshQuery built per muscle per frame and
// deformation's calc_surface_overlap(V, F, query) per pair (whole edge graph rebuilt each call).
void BM_OverlapMeasureBefore(benchmark::State& bm) {
  Shank& shank = get_shank();
  ThreadLimit limit(1);
  const Model& model = *shank.model;
  std::vector<MuscleFrame> frames[2] = {shank.states[0].muscles, shank.states[1].muscles};
  int k = 0;
  double worst = 0.0;
  for (auto _ : bm) {
    const std::vector<MuscleFrame>& f = frames[k++ % 2];
    const size_t n = f.size();
    std::vector<Eigen::AlignedBox3d> box(n);
    for (size_t m = 0; m < n; ++m)
      box[m] = Eigen::AlignedBox3d(f[m].surface.colwise().minCoeff().transpose(),
                                   f[m].surface.colwise().maxCoeff().transpose());
    std::vector<std::unique_ptr<MeshQuery>> query(n);
    for (size_t b = 0; b < n; ++b) query[b] = std::make_unique<MeshQuery>(TriMesh{f[b].surface, model.muscles[b].rest_mesh.F});
    worst = 0.0;
    for (size_t a = 0; a < n; ++a)
      for (size_t b = 0; b < n; ++b)
        if (a != b && box[a].intersects(box[b]))
          worst = std::max(worst, calc_surface_overlap(f[a].surface, model.muscles[a].rest_mesh.F, *query[b]).max_depth_m);
  }
  bm.counters["max_overlap_mm"] = 1e3 * worst;
}
BENCHMARK(BM_OverlapMeasureBefore)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_OverlapMeasure, fresh, false)->Unit(benchmark::kMillisecond);

void BM_ParaViewFrame(benchmark::State& bm) {
  Shank& shank = get_shank();
  ThreadLimit limit(1);
  const fs::path out = fs::temp_directory_path() / "fascicle_bench_scene_overhead";
  fs::remove_all(out);
  fs::create_directories(out);
  auto writer = make_paraview_writer();
  writer->begin(*shank.model, RunInfo{out, "vh_shank", 1 << 20, 50.0});
  int frame = 0;
  for (auto _ : bm) {
    writer->write_frame(*shank.model, shank.states[frame % 2], frame);
    ++frame;
  }
  writer->finish(*shank.model);
  std::uintmax_t bytes = 0;
  for (const auto& e : fs::directory_iterator(out / "vh_shank_frames")) bytes += e.file_size();
  bm.counters["MB_per_frame"] = static_cast<double>(bytes) / 1e6 / frame;
  fs::remove_all(out);
}
BENCHMARK(BM_ParaViewFrame)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace fascicle

BENCHMARK_MAIN();
