// `fascicle paths`: the muscle paths (with wrap arcs) and bones of a posed OpenSim model as
// ParaView .vtp files. See docs/analyze.md.
#include "commands.hpp"

#include <spdlog/spdlog.h>

#include <memory>

#include "fascicle/core/error.hpp"
#include "fascicle/osim/analyze.hpp"

namespace fascicle::cli {
namespace {

struct PathsOptions {
  std::string model, out;
  std::vector<std::string> pose, geometry_dirs;
  double arc_step = 0.002;
};

void run_paths(const PathsOptions& o) {
  OsimImportOptions import;
  for (const auto& d : o.geometry_dirs) import.geometry_dirs.emplace_back(d);
  const OsimAnalysisModel model = load_osim_model(o.model, import);
  const VecX q = parse_pose(model.skeleton, o.pose);
  const auto files = write_path_geometry(o.out, model, q, o.arc_step);
  for (const auto& f : files) spdlog::info("wrote {}", f.string());
}

}  // namespace

void add_paths_commands(CLI::App& app, Invocation& run) {
  auto o = std::make_shared<PathsOptions>();
  CLI::App* c = app.add_subcommand(
      "paths", "Muscle paths (with wrap arcs) and bones of a posed OpenSim model as .vtp files");
  c->add_option("--model", o->model, "OpenSim model (.osim)")->required()->check(CLI::ExistingFile);
  c->add_option("--pose", o->pose,
                "Coordinate values name=value,... in rad or m (a rotational value may end in "
                "'deg'); others keep their defaults")
      ->delimiter(',');
  c->add_option("--geometry-dir", o->geometry_dirs,
                "Folder searched for bone meshes after the model's folder and its Geometry/");
  c->add_option("--arc-step", o->arc_step, "Sampling step of wrap arcs (m, default 0.002)")
      ->check(CLI::PositiveNumber);
  c->add_option("--out", o->out, "Output folder")->required();
  c->callback([o, &run] { run.action = [o] { run_paths(*o); }; });
}

}  // namespace fascicle::cli
