// fascicle export --gltf OUT_DIR --frame N --out scene.glb: one frame as glTF 2.0 binary.
#include "commands.hpp"

#include "fascicle/core/log.hpp"
#include "fascicle/report/gltf_export.hpp"

#include <memory>

namespace fascicle::cli {
namespace {

struct ExportArgs {
  std::string run_dir;
  int frame = 0;
  std::string out = "scene.glb";
};

void run_export(const ExportArgs& args) {
  const GltfExportCounts c = export_gltf_frame(args.run_dir, args.frame, args.out);
  spdlog::info("wrote {}: {} bones, {} muscle surfaces, {} fibre sets, {} action lines", args.out, c.bones,
               c.muscles, c.fibre_sets, c.action_lines);
}

}  // namespace

void add_export_commands(CLI::App& app, Invocation& run) {
  auto args = std::make_shared<ExportArgs>();
  CLI::App* cmd = app.add_subcommand("export", "Export one frame of a run (glTF 2.0 binary for Blender, three.js)");
  cmd->add_option("--gltf", args->run_dir, "Output folder of `fascicle run` or `fascicle demo`")->required();
  cmd->add_option("--frame", args->frame, "Frame number (0-based)")->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_option("--out", args->out, "The .glb file to write")->capture_default_str();
  cmd->callback([&run, args] { run.action = [args] { run_export(*args); }; });
}

}  // namespace fascicle::cli
