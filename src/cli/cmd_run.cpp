// fascicle run SCENE.json --out DIR: a scene file through the frame driver (docs/scene-format.md).
#include "commands.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/log.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/scene/driver.hpp"
#include "fascicle/scene/model.hpp"
#include "fascicle/scene/scene_json.hpp"

#include <cstdio>
#include <memory>

namespace fascicle::cli {
namespace {

struct RunArgs {
  std::string scene;
  std::string out = "out/run";
  std::string motion;
  double fps = 0.0;
};

void run_scene(const RunArgs& args) {
  const Registry registry = make_cli_registry();
  const SceneSpec spec = load_scene(args.scene, registry);
  const Model model = compile(spec, registry);
  std::filesystem::path motion_file = args.motion;
  if (motion_file.empty()) {
    if (!spec.motion)
      throw_usage("the scene has no \"motion\" and no --motion was given",
                  {.file = args.scene, .suggestion = "add --motion FILE.mot"});
    motion_file = spec.motion->file;
  }
  const double fps = args.fps > 0 ? args.fps : (spec.motion ? spec.motion->frame_rate_hz : 50.0);
  const CoordinateTrajectory trajectory = make_trajectory(model, read_table(motion_file), fps);
  std::vector<std::string> names;
  for (const auto& w : spec.outputs) names.push_back(w.type);
  if (names.empty()) names = get_default_writer_names();
  auto writers = make_writers(registry, names);
  std::vector<FrameWriter*> use;
  for (auto& w : writers) use.push_back(w.get());
  DriverOptions options;
  options.out_dir = args.out;
  options.basename = spec.name;
  options.frame_rate_hz = fps;
  options.progress = !quiet();
  const DriverResult result = run_frames(model, trajectory, options, use);
  if (!quiet()) {
    std::printf("fascicle run: %d frames in %.2f s written to %s\n", result.frames_written, result.seconds,
                args.out.c_str());
    for (const auto& p : result.outputs) std::printf("  %s\n", p.string().c_str());
  }
}

}  // namespace

void add_run_commands(CLI::App& app, Invocation& run) {
  auto args = std::make_shared<RunArgs>();
  CLI::App* cmd = app.add_subcommand("run", "Run a scene file (docs/scene-format.md) over its motion");
  cmd->add_option("scene", args->scene, "Scene JSON file")->required();
  cmd->add_option("--out", args->out, "Output folder")->capture_default_str();
  cmd->add_option("--motion", args->motion, "Motion file (.mot/.sto/.csv); default: the scene's");
  cmd->add_option("--fps", args->fps, "Output frame rate (Hz); default: the scene's")->check(CLI::PositiveNumber);
  cmd->callback([&run, args] { run.action = [args] { run_scene(*args); }; });
}

}  // namespace fascicle::cli
