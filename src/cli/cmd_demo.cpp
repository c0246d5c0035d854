// fascicle demo [--out DIR]: the procedural right lower leg through the pipeline (docs/demo.md).
#include "commands.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/log.hpp"
#include "fascicle/scene/demo.hpp"
#include "fascicle/scene/driver.hpp"
#include "fascicle/scene/model.hpp"
#include "fascicle/scene/registry.hpp"

#include <fmt/format.h>

#include <cstdio>
#include <memory>

namespace fascicle::cli {
namespace {

struct DemoArgs {
  std::string out = "out/demo";
  double fps = 50.0;
  int resolution = 1;
};

void run_demo(const DemoArgs& args) {
  const Registry registry = make_cli_registry();
  const DemoScene demo = make_demo_leg(100.0, args.resolution);
  const Model model = compile(demo.spec, registry);
  const CoordinateTrajectory trajectory = make_trajectory(model, demo.motion, args.fps);
  auto writers = make_writers(registry, get_default_writer_names());
  std::vector<FrameWriter*> use;
  for (auto& w : writers) use.push_back(w.get());
  DriverOptions options;
  options.out_dir = args.out;
  options.basename = "demo";
  options.frame_rate_hz = args.fps;
  options.progress = !quiet();
  spdlog::info("demo: {} bodies, {} muscles, {} frames at {} Hz", model.num_bodies() - 1,
               model.num_muscles(), trajectory.time.size(), args.fps);
  const DriverResult result = run_frames(model, trajectory, options, use);
  if (!quiet()) {
    std::printf("fascicle demo: %d frames in %.2f s written to %s\n", result.frames_written, result.seconds,
                args.out.c_str());
    for (const auto& p : result.outputs) std::printf("  %s\n", p.string().c_str());
    std::printf("Open %s/demo.pvd in ParaView (File > Open, Apply, then play).\n", args.out.c_str());
  }
}

}  // namespace

void add_demo_commands(CLI::App& app, Invocation& run) {
  auto args = std::make_shared<DemoArgs>();
  CLI::App* cmd = app.add_subcommand(
      "demo", "Run the embedded procedural lower leg (knee and ankle motion, 4 calf muscles)");
  cmd->add_option("--out", args->out, "Output folder")->capture_default_str();
  cmd->add_option("--fps", args->fps, "Frames per second of the output")
      ->check(CLI::PositiveNumber)->capture_default_str();
  cmd->add_option("--resolution", args->resolution, "Muscle mesh density factor (1: ~1.4k triangles)")
      ->check(CLI::Range(1, 8))->capture_default_str();
  cmd->callback([&run, args] { run.action = [args] { run_demo(*args); }; });
}

}  // namespace fascicle::cli
