// fascicle run: a scene file (docs/scene-format.md), or an OpenSim model with a motion
// (docs/opensim-volumes.md), through the frame driver.
#include "commands.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/log.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/osim/osim_model.hpp"
#include "fascicle/scene/driver.hpp"
#include "fascicle/scene/model.hpp"
#include "fascicle/scene/osim_scene.hpp"
#include "fascicle/scene/scene_json.hpp"

#include <cstdio>
#include <memory>

namespace fascicle::cli {
namespace {

struct RunArgs {
  std::string scene;
  std::string model;
  std::string out = "out/run";
  std::string motion;
  std::string activations;
  std::vector<std::string> muscles;
  std::vector<std::string> geometry;
  std::vector<std::string> outputs;
  std::string representation;
  double activation = -1.0;
  double specific_tension = 25.0;  // N/cm²
  bool no_pack_bellies = false;
  double fps = 0.0;
  int frames = 0;
};

void run(const RunArgs& args) {
  if (args.scene.empty() == args.model.empty())
    throw_usage("give either a scene file or --model M.osim", {.suggestion = "fascicle run SCENE.json --out DIR, "
                                                                              "or fascicle run --model M.osim --motion K.mot --out DIR"});
  const Registry registry = make_cli_registry();
  SceneSpec spec;
  if (!args.scene.empty()) {
    if (!args.muscles.empty() || args.specific_tension != 25.0 || args.no_pack_bellies)
      throw_usage("--muscles, --specific-tension and --no-pack-bellies apply to --model runs",
                  {.suggestion = "in a scene file, set \"muscles\", \"specific_tension\" or \"pack_bellies\" under \"opensim_model\""});
    spec = load_scene(args.scene, registry);
  } else {
    if (args.motion.empty())
      throw_usage("--model needs --motion", {.suggestion = "add --motion FILE.mot (e.g. an inverse-kinematics result)"});
    OsimSceneOptions options;
    options.muscles = args.muscles;
    options.activation = args.activation;
    options.belly.specific_tension_Pa = args.specific_tension * 1e4;
    options.belly.packing.enabled = !args.no_pack_bellies;
    if (!args.representation.empty()) options.representation = args.representation;
    // Mesh search: OpenSim's order, then --geometry folders, then ../Geometry beside the model's
    // folder (the layout of OpenSim's model distributions).
    OsimImportOptions import;
    for (const auto& g : args.geometry) import.geometry_dirs.emplace_back(g);
    import.geometry_dirs.push_back(std::filesystem::path(args.model).parent_path() / ".." / "Geometry");
    spec = make_scene_from_osim(read_osim(args.model, import), options);
  }
  if (!args.representation.empty()) {
    registry.check_representation(args.representation, {.suggestion = "see docs/scene-format.md"});
    for (auto& m : spec.muscles) m.representation = args.representation;
  }
  if (args.activation >= 0.0)
    for (auto& m : spec.muscles) m.activation = args.activation;
  spdlog::info("{}: {} muscles; binding them in the rest pose", spec.name, spec.muscles.size());
  const Model model = compile(spec, registry);

  std::filesystem::path motion_file = args.motion;
  if (motion_file.empty()) {
    if (!spec.motion)
      throw_usage("the scene has no \"motion\" and no --motion was given",
                  {.file = args.scene, .suggestion = "add --motion FILE.mot"});
    motion_file = spec.motion->file;
  }
  const double fps = args.fps > 0 ? args.fps : (spec.motion ? spec.motion->frame_rate_hz : 50.0);
  CoordinateTrajectory trajectory = make_trajectory(model, read_table(motion_file), fps);
  if (args.frames > 0 && args.frames < trajectory.time.size()) {
    trajectory.time.conservativeResize(args.frames);
    trajectory.q.conservativeResize(args.frames, Eigen::NoChange);
  }
  if (!args.activations.empty())
    add_activations(model, read_table(args.activations), args.activations, trajectory);

  std::vector<std::string> names = args.outputs;
  if (names.empty())
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

void add_run_commands(CLI::App& app, Invocation& run_action) {
  auto args = std::make_shared<RunArgs>();
  CLI::App* cmd = app.add_subcommand(
      "run", "Run a scene file (docs/scene-format.md), or an OpenSim model with generated muscle volumes, over a motion");
  cmd->add_option("scene", args->scene, "Scene JSON file");
  cmd->add_option("--model", args->model, "OpenSim model (.osim): every muscle becomes a generated volume");
  cmd->add_option("--out", args->out, "Output folder")->capture_default_str();
  cmd->add_option("--motion", args->motion, "Motion file (.mot/.sto/.csv); default: the scene's");
  cmd->add_option("--activations", args->activations,
                  "Activations over time (.sto/.csv; columns named after muscles or /forceset/<m>/activation)");
  cmd->add_option("--activation", args->activation, "Constant activation of every muscle")->check(CLI::Range(0.0, 1.0));
  cmd->add_option("--geometry", args->geometry, "Extra folders searched for the model's mesh files");
  cmd->add_option("--muscles", args->muscles, "Only these muscles of the model (comma-separated names or patterns such as '*_r')")->delimiter(',');
  cmd->add_option("--representation", args->representation,
                  "Muscle representation for every muscle (surface_first, blended_surface, action_line, ...)");
  cmd->add_option("--specific-tension", args->specific_tension,
                  "σ in N/cm² for generated volumes, V = F0/σ · l0")->check(CLI::PositiveNumber)->capture_default_str();
  cmd->add_flag("--no-pack-bellies", args->no_pack_bellies,
                "Leave the generated bellies as placed (overlapping); default: packed at the default pose");
  cmd->add_option("--outputs", args->outputs,
                  "Writers (comma-separated): paraview, sto, csv, summary, sketch, report; default: the scene's or all but sketch")
      ->delimiter(',');
  cmd->add_option("--fps", args->fps, "Output frame rate (Hz); default: the scene's")->check(CLI::PositiveNumber);
  cmd->add_option("--frames", args->frames, "Stop after this many frames")->check(CLI::PositiveNumber);
  cmd->callback([&run_action, args] { run_action.action = [args] { run(*args); }; });
}

}  // namespace fascicle::cli
