// `fascicle fibres`: decompose a muscle surface into fibres (docs/fibres.md).
#include "commands.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/core/units.hpp"
#include "fascicle/fibres/analysis.hpp"
#include "fascicle/fibres/decompose.hpp"
#include "fascicle/geometry/mesh_repair.hpp"
#include "fascicle/io/mesh_io.hpp"

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include <memory>
#include <sstream>

namespace fascicle::cli {

namespace {

struct FibresArgs {
  std::string mesh, units = "m", origin, insertion, bones, attach_distance = "2mm";
  bool split_by_bone = false;
  double end_fraction = 0.08;
  std::string fibre_template = "parallel", method = "template";
  int count = 100, resolution = 15;
  std::string out, report, csv;
};

std::vector<std::string> split_list(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

TriMesh load_solid(const std::string& path, LengthUnit unit) {
  const TriMesh raw = read_mesh(path, unit);
  try {
    RepairResult r = repair_mesh(raw);
    for (const auto& a : r.actions) spdlog::info("{}: repaired: {}", path, a);
    return std::move(r.mesh);
  } catch (const Error& e) {
    throw e.with_file(path);
  }
}

void run_fibres(const FibresArgs& a) {
  // Usage errors first, before any file is read.
  DecomposeOptions opt;
  opt.method = parse_fibre_method(a.method);
  opt.fibre_template = parse_fibre_template(a.fibre_template);
  opt.count = a.count;
  opt.resolution = a.resolution;
  const LengthUnit unit = parse_length_unit(a.units);
  const double m_per_unit = metres_per(unit);
  const TriMesh muscle = load_solid(a.mesh, unit);
  Attachments areas;
  if (!a.origin.empty() || !a.insertion.empty()) {
    if (a.origin.empty() || a.insertion.empty())
      throw_usage("--origin and --insertion must be given together");
    areas = find_landmark_attachments(muscle, read_landmarks_csv(a.origin, m_per_unit),
                                      read_landmarks_csv(a.insertion, m_per_unit));
  } else if (!a.bones.empty()) {
    std::vector<TriMesh> bones;
    for (const auto& b : split_list(a.bones)) bones.push_back(read_mesh(b, unit));
    areas = find_bone_attachments(muscle, bones, parse_length(a.attach_distance), a.split_by_bone,
                                  a.end_fraction);
  } else {
    areas = find_end_attachments(muscle, a.end_fraction);
  }
  spdlog::info("attachment areas: origin {:.1f} mm^2 ({} vertices), insertion {:.1f} mm^2 ({} "
               "vertices)",
               areas.origin.area_m2 * 1e6, areas.origin.vertices.size(),
               areas.insertion.area_m2 * 1e6, areas.insertion.vertices.size());
  const Decomposition d = decompose_muscle(muscle, areas, opt);
  const FibreAnalysis analysis = analyse_fibres(muscle, areas, d.fibres);
  write_fibres_vtp(a.out, d.fibres, &analysis);
  spdlog::info("{} fibres ({} method) written to {}; mean length {:.1f} mm, PCSA {:.2f} cm^2",
               d.fibres.size(), to_string(d.method_used), a.out,
               analysis.mean_fibre_length_m * 1e3, analysis.pcsa_m2 * 1e4);
  if (!a.report.empty()) {
    nlohmann::json j = nlohmann::json::parse(to_json(analysis));
    j["method"] = to_string(d.method_used);
    j["template"] = to_string(opt.fibre_template);
    j["warnings"] = d.warnings;
    write_file_atomically(a.report, [&](std::ostream& out) { out << j.dump(2) << '\n'; });
  }
  if (!a.csv.empty()) write_fibre_csv(a.csv, analysis);
}

}  // namespace

void add_fibres_commands(CLI::App& app, Invocation& run) {
  auto args = std::make_shared<FibresArgs>();
  CLI::App* cmd = app.add_subcommand(
      "fibres", "Decompose a muscle surface into fibres (template or harmonic method)");
  cmd->add_option("--mesh", args->mesh, "Muscle surface (STL, OBJ, PLY, VTP)")->required();
  cmd->add_option("--units", args->units, "Length unit of the input files: m, cm or mm");
  cmd->add_option("--origin", args->origin, "Origin landmarks (CSV x,y,z)");
  cmd->add_option("--insertion", args->insertion, "Insertion landmarks (CSV x,y,z)");
  cmd->add_option("--bones", args->bones, "Bone meshes B1,B2,... for the attachment areas");
  cmd->add_option("--attach-distance", args->attach_distance,
                  "Muscle surface within this distance of a bone is attached (e.g. 2mm)");
  cmd->add_flag("--split-by-bone", args->split_by_bone,
                "Origin on the first bone, insertion on the others (default: split along the "
                "principal axis)");
  cmd->add_option("--end-fraction", args->end_fraction,
                  "Fraction of the muscle's length taken as an end region without bones")
      ->check(CLI::Range(0.01, 0.45));
  cmd->add_option("--template", args->fibre_template,
                  "parallel, pennate, bipennate, curved or fanned");
  cmd->add_option("--method", args->method, "template or harmonic");
  cmd->add_option("--count", args->count, "Number of fibres")->check(CLI::Range(1, 1000000));
  cmd->add_option("--resolution", args->resolution, "Points per fibre")->check(CLI::Range(2, 100000));
  cmd->add_option("--out", args->out, "Output fibres (.vtp)")->required();
  cmd->add_option("--report", args->report, "Analysis report (JSON)");
  cmd->add_option("--csv", args->csv, "Per-fibre analysis (CSV)");
  cmd->callback([&run, args] { run.action = [args] { run_fibres(*args); }; });
}

}  // namespace fascicle::cli
