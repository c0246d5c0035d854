// `fascicle analyze`: OpenSim MuscleAnalysis-style tables (lengths, fibre quantities at static
// equilibrium, moment arms) of a model over a motion. See docs/analyze.md.
#include "commands.hpp"

#include <spdlog/spdlog.h>

#include <chrono>
#include <filesystem>
#include <memory>
#include <sstream>

#include "fascicle/core/error.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/osim/analyze.hpp"

namespace fascicle::cli {
namespace {

struct AnalyzeOptions {
  std::string model, motion, activations, coordinates, out;
  std::vector<std::string> geometry_dirs;
  bool cylinder_infinite = false;
  std::string cylinder_method = "geodesic";
  bool opensim_lengths = false;
};

std::vector<std::string> split_commas(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

void run_analyze(const AnalyzeOptions& o) {
  const auto start = std::chrono::steady_clock::now();
  OsimImportOptions import;
  for (const auto& d : o.geometry_dirs) import.geometry_dirs.emplace_back(d);
  PathOptions path_options;
  if (o.cylinder_infinite) path_options.cylinder_ends = CylinderEndRule::infinite;
  if (o.cylinder_method == "opensim") {
    path_options.cylinder_method = CylinderMethod::opensim_iterative;
  } else if (o.cylinder_method != "geodesic") {
    throw_usage("--cylinder-method must be 'geodesic' or 'opensim', not '" + o.cylinder_method + "'");
  }
  path_options.opensim_tangent_point_cache = o.opensim_lengths;
  const OsimAnalysisModel model = load_osim_model(o.model, import, path_options);
  const Table motion = read_table(o.motion);
  Table activations;
  MuscleAnalysisOptions opt;
  opt.motion_file = o.motion;
  opt.coordinates = split_commas(o.coordinates);
  if (!o.activations.empty()) {
    activations = read_table(o.activations);
    opt.activations = &activations;
    opt.activations_file = o.activations;
  }
  const MuscleAnalysis a = calc_muscle_analysis(model, motion, opt);
  const auto files = write_muscle_analysis(o.out, a);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  spdlog::info("{}: {} muscles x {} frames, moment arms for {} coordinates; {} tables in {} ({:.2f} s)",
               model.osim.name, a.muscles.size(), a.time.size(), a.moment_arm_coordinates.size(),
               files.size(), o.out, seconds);
}

}  // namespace

void add_analyze_commands(CLI::App& app, Invocation& run) {
  auto o = std::make_shared<AnalyzeOptions>();
  CLI::App* c = app.add_subcommand(
      "analyze",
      "OpenSim MuscleAnalysis tables of a model over a motion: path lengths, fibre and tendon "
      "lengths and forces at static equilibrium, moment arms");
  c->add_option("--model", o->model, "OpenSim model (.osim)")->required()->check(CLI::ExistingFile);
  c->add_option("--motion", o->motion, "Coordinates over time (.mot/.sto)")
      ->required()
      ->check(CLI::ExistingFile);
  c->add_option("--activations", o->activations,
                "Activations over time (.sto/.mot/.csv, one column per muscle); default: each "
                "muscle's default activation")
      ->check(CLI::ExistingFile);
  c->add_option("--coordinates", o->coordinates,
                "Coordinates for moment arms, comma separated; default: every unlocked "
                "coordinate spanned by a muscle");
  c->add_option("--geometry-dir", o->geometry_dirs,
                "Folder searched for bone meshes after the model's folder and its Geometry/");
  c->add_flag("--cylinder-infinite", o->cylinder_infinite,
              "Treat wrap cylinders as infinitely long (continuous lengths; OpenSim cuts the wrap "
              "off past the cylinder ends)");
  c->add_option("--cylinder-method", o->cylinder_method,
                "geodesic (exact shortest path, exact moment arms; default) or opensim (OpenSim "
                "4's iterative cylinder construction, for parity)");
  c->add_flag("--opensim-lengths", o->opensim_lengths,
              "Report lengths of multi-wrap paths as OpenSim 4 does (straight pieces between "
              "first-pass tangent points, docs/analyze.md); for comparison with OpenSim only: "
              "such a length is not that of one path, and moment arms stay the real path's");
  c->add_option("--out", o->out, "Output folder")->required();
  c->callback([o, &run] { run.action = [o] { run_analyze(*o); }; });
}

}  // namespace fascicle::cli
