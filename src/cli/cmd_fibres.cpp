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

#include <cmath>
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
  std::string attachments;          // "" (from the other options) or "aponeurosis"
  std::string architecture = "unipennate";
  double pennation_deg = 0.0;       // 0: fixed template rise
  std::string rise_crossing = "mean-thickness";  // or "mapped-crossing"
  std::string pennation_reference = "line";       // or "aponeurosis"
  // "" (default below), "thickness" (the thickness plane), "gradient", or "sheet-border" (towards
  // the interior aponeurosis' tendon-side border)
  std::string pennation_plane;
  std::string insertion_side;                     // mesh on the insertion (deep) side
  std::string aponeurosis;          // interior insertion aponeurosis mesh
};

// The plane the pennate field's fibres turn in: as given, else thickness with the line-of-action
// reference and gradient with the aponeurosis reference.
std::string effective_pennation_plane(const FibresArgs& a) {
  if (!a.pennation_plane.empty()) return a.pennation_plane;
  return a.pennation_reference == "aponeurosis" ? "gradient" : "thickness";
}

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
  const bool aponeurosis_areas = a.attachments == "aponeurosis";
  if (!a.attachments.empty() && !aponeurosis_areas)
    throw_usage("unknown --attachments '" + a.attachments + "'",
                {.suggestion = "use --attachments aponeurosis, or leave it out (landmarks, bones "
                               "or end regions from the other options)"});
  if (aponeurosis_areas && !(a.pennation_deg > 0.0))
    throw_usage("--attachments aponeurosis needs the muscle's pennation angle",
                {.suggestion = "add --pennation-deg, e.g. 9.9 for the medial gastrocnemius "
                               "(Ward et al. 2009)"});
  if (!a.aponeurosis.empty() && !aponeurosis_areas)
    throw_usage("--aponeurosis needs --attachments aponeurosis");
  if (!aponeurosis_areas && !a.insertion_side.empty())
    throw_usage("--insertion-side needs --attachments aponeurosis");
  if (a.pennation_reference == "aponeurosis" && (!aponeurosis_areas || opt.method != FibreMethod::harmonic))
    throw_usage("--pennation-reference aponeurosis needs --attachments aponeurosis and --method harmonic");
  if (!a.pennation_plane.empty() && (!aponeurosis_areas || opt.method != FibreMethod::harmonic))
    throw_usage("--pennation-plane needs --attachments aponeurosis and --method harmonic");
  if (a.pennation_plane == "sheet-border" && a.aponeurosis.empty())
    throw_usage("--pennation-plane sheet-border needs an interior aponeurosis (--aponeurosis)",
                {.suggestion = "give the segmented aponeurosis mesh, or use --pennation-plane "
                               "thickness"});
  if (a.pennation_plane == "sheet-border" && a.pennation_reference == "aponeurosis")
    throw_usage("--pennation-plane sheet-border needs --pennation-reference line",
                {.suggestion = "measured against the aponeuroses the border direction replaces their "
                               "normal (Bolsterlee TA 18.1 deg from the DTI tracts against 12.8 with the "
                               "line of action; docs/fibres.md)"});
  if (a.rise_crossing == "mapped-crossing" && (opt.method != FibreMethod::template_map || !(a.pennation_deg > 0.0)))
    throw_usage("--rise-crossing mapped-crossing needs --method template and --pennation-deg");
  if (aponeurosis_areas && (!a.origin.empty() || !a.bones.empty()))
    throw_usage("--attachments aponeurosis cannot be combined with landmarks or bones");
  const Architecture architecture = parse_architecture(a.architecture);
  opt.pennation_rad = a.pennation_deg * M_PI / 180.0;
  opt.rise_crossing = a.rise_crossing == "mapped-crossing"
                          ? DecomposeOptions::RiseCrossing::mapped_crossing
                          : DecomposeOptions::RiseCrossing::mean_thickness;
  const TriMesh muscle = load_solid(a.mesh, unit);
  Attachments areas;
  if (aponeurosis_areas) {
    AponeurosisOptions ao;
    ao.architecture = architecture;
    ao.pennation_rad = opt.pennation_rad;
    ao.end_fraction = a.end_fraction;
    TriMesh sheet;
    if (!a.aponeurosis.empty()) {
      sheet = read_mesh(a.aponeurosis, unit);
      ao.thickness_direction = calc_sheet_normal(sheet);
      opt.mapping.thickness_direction = ao.thickness_direction;
    }
    if (!a.insertion_side.empty()) {
      const TriMesh side = read_mesh(a.insertion_side, unit);
      if (side.num_vertices() == 0)
        throw_bad_input("the insertion-side mesh has no vertices", {.file = a.insertion_side});
      ao.insertion_face_towards =
          Vec3(side.V.colwise().mean()) - Vec3(muscle.V.colwise().mean());
      opt.mapping.insertion_side_towards = ao.insertion_face_towards;
    }
    if (a.pennation_reference == "aponeurosis")
      opt.harmonic.pennation_reference = HarmonicOptions::PennationReference::aponeurosis;
    if (opt.method == FibreMethod::template_map) {
      // The template's box follows the muscle's ends; the pennation sets the rise.
      areas = find_end_attachments(muscle, a.end_fraction);
    } else {
      areas = find_aponeurosis_attachments(muscle, ao);
      try {
        if (!a.aponeurosis.empty()) set_interior_aponeurosis(muscle, sheet, areas);
      } catch (const Error& e) {
        throw e.with_file(a.aponeurosis);
      }
      opt.harmonic.pennation_rad = opt.pennation_rad;
      // The fibres turn in the plane of the box's thickness direction unless asked otherwise
      // (session 9: DTI MG 14.2 -> 13.4 deg, TA 15.6 -> 13.6 deg; docs/fibres.md). With the angle
      // measured against the aponeuroses the default stays the aponeuroses' own potential: the
      // thickness plane would replace their level sets by the box's plane.
      if (effective_pennation_plane(a) == "thickness")
        opt.harmonic.transverse_direction = areas.thickness_direction;
      // Towards the border where the interior aponeurosis becomes its tendon (session 10: DTI TA
      // 13.6 -> 12.8 deg; docs/fibres.md).
      if (effective_pennation_plane(a) == "sheet-border") {
        try {
          opt.harmonic.transverse_targets = find_aponeurosis_border(
              muscle, areas.insertion_interior, areas.thickness_direction, ao.origin_towards);
        } catch (const Error& e) {
          throw e.with_file(a.aponeurosis);
        }
      }
    }
  } else if (!a.origin.empty() || !a.insertion.empty()) {
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
    if (aponeurosis_areas) {
      j["attachments"] = "aponeurosis";
      j["architecture"] = to_string(architecture);
      if (opt.method == FibreMethod::harmonic)
        j["pennation_plane"] = effective_pennation_plane(a);
    }
    if (a.pennation_deg > 0.0) j["target_pennation_deg"] = a.pennation_deg;
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
  cmd->add_option("--attachments", args->attachments,
                  "aponeurosis: origin and insertion aponeuroses derived from the architecture "
                  "and pennation (docs/fibres.md)");
  cmd->add_option("--architecture", args->architecture,
                  "unipennate or bipennate (with --attachments aponeurosis)");
  cmd->add_option("--pennation-deg", args->pennation_deg,
                  "Target pennation angle in degrees: sets the pennate templates' rise, and the "
                  "pennate harmonic field with --attachments aponeurosis")
      ->check(CLI::Range(0.0, 89.0));
  cmd->add_option("--rise-crossing", args->rise_crossing,
                  "With --pennation-deg and a pennate template: the in-slice distance the rise "
                  "is computed from, mean-thickness (default) or mapped-crossing (fibres then make "
                  "the target angle; docs/fibres.md)")
      ->check(CLI::IsMember({"mean-thickness", "mapped-crossing"}));
  cmd->add_option("--pennation-reference", args->pennation_reference,
                  "With --attachments aponeurosis --method harmonic: the pennation angle is "
                  "measured against the line of action (line, default) or the aponeuroses")
      ->check(CLI::IsMember({"line", "aponeurosis"}));
  cmd->add_option("--pennation-plane", args->pennation_plane,
                  "With --attachments aponeurosis --method harmonic: the plane the fibres turn in "
                  "away from the line of action, thickness (the aponeurosis box's thickness direction; "
                  "default with --pennation-reference line), gradient (the aponeurosis "
                  "potential's gradient; default with --pennation-reference aponeurosis) or "
                  "sheet-border (towards the border where the --aponeurosis sheet becomes its "
                  "tendon)")
      ->check(CLI::IsMember({"thickness", "gradient", "sheet-border"}));
  cmd->add_option("--insertion-side", args->insertion_side,
                  "With --attachments aponeurosis: a mesh on the insertion aponeurosis' side (the "
                  "insertion face is the one towards its centroid; e.g. the tibia for the medial "
                  "gastrocnemius, whose insertion aponeurosis is deep)");
  cmd->add_option("--aponeurosis", args->aponeurosis,
                  "Interior insertion aponeurosis mesh (with --attachments aponeurosis)");
  cmd->add_option("--out", args->out, "Output fibres (.vtp)")->required();
  cmd->add_option("--report", args->report, "Analysis report (JSON)");
  cmd->add_option("--csv", args->csv, "Per-fibre analysis (CSV)");
  cmd->callback([&run, args] { run.action = [args] { run_fibres(*args); }; });
}

}  // namespace fascicle::cli
