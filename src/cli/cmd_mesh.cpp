// fascicle mesh info | convert | repair
#include "commands.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/log.hpp"
#include "fascicle/core/units.hpp"
#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/geometry/mesh_repair.hpp"
#include "fascicle/geometry/mesh_validation.hpp"
#include "fascicle/io/mesh_io.hpp"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <iostream>
#include <memory>
#include <optional>

namespace fascicle::cli {
namespace {

struct MeshArgs {
  std::string input, output;
  std::string units = "m", out_units = "m";
  bool json = false, strict = false, ascii = false, appended = false, no_compress = false;
  bool no_self_intersections = false;
  double density = 1060.0;
  std::string merge_tolerance = "0";
};

// Mass properties only make sense for a closed, manifold, consistently oriented, finite surface.
std::optional<MassProperties> mass_properties_if_meaningful(const TriMesh& mesh,
                                                            const MeshReport& r, double density) {
  if (!r.nonfinite_vertices.empty() || !r.out_of_range_faces.empty() || !r.is_closed() ||
      !r.is_manifold() || !r.is_consistently_oriented() || r.signed_volume == 0.0) {
    return std::nullopt;
  }
  return calc_mass_properties(mesh, density);
}

nlohmann::json to_json(const MassProperties& mp, double density) {
  const auto vec = [](const Vec3& v) { return nlohmann::json{v.x(), v.y(), v.z()}; };
  const auto mat = [&](const Mat3& m) {
    return nlohmann::json{vec(m.row(0)), vec(m.row(1)), vec(m.row(2))};
  };
  return {{"density_kg_per_m3", density},
          {"volume_m3", mp.volume_m3},
          {"area_m2", mp.area_m2},
          {"mass_kg", mp.mass_kg},
          {"centroid_m", vec(mp.centroid)},
          {"inertia_about_centroid_kg_m2", mat(mp.inertia)},
          {"principal_moments_kg_m2", vec(mp.principal_moments)},
          {"principal_axes_columns", mat(mp.principal_axes)}};
}

std::string format_mass_properties(const MassProperties& mp, double density) {
  const auto v3 = [](const Vec3& v) { return fmt::format("[{:.9g}, {:.9g}, {:.9g}]", v.x(), v.y(), v.z()); };
  std::string out = fmt::format("mass properties (density {} kg/m^3):\n", density);
  out += fmt::format("  volume {:.9g} m^3, area {:.9g} m^2, mass {:.9g} kg\n", mp.volume_m3,
                     mp.area_m2, mp.mass_kg);
  out += "  centroid " + v3(mp.centroid) + " m\n";
  out += "  inertia about the centroid (kg m^2):\n";
  for (int i = 0; i < 3; ++i) out += "    " + v3(mp.inertia.row(i)) + "\n";
  out += "  principal moments " + v3(mp.principal_moments) + " kg m^2\n";
  out += "  principal axes (columns):\n";
  for (int i = 0; i < 3; ++i) out += "    " + v3(mp.principal_axes.row(i)) + "\n";
  return out;
}

void run_info(const MeshArgs& a) {
  const LengthUnit unit = parse_length_unit(a.units);
  const TriMesh mesh = read_mesh(a.input, unit);
  const MeshReport report =
      validate_mesh(mesh, {.check_self_intersections = !a.no_self_intersections});
  const std::optional<MassProperties> mp = mass_properties_if_meaningful(mesh, report, a.density);
  if (a.json) {
    nlohmann::json j;
    j["file"] = a.input;
    j["format"] = to_string(find_mesh_format(a.input));
    j["units"] = to_string(unit);
    j["validation"] = to_json(report);
    j["mass_properties"] = mp ? to_json(*mp, a.density) : nlohmann::json(nullptr);
    std::cout << j.dump(2) << std::endl;
  } else {
    std::cout << a.input << " (" << to_string(find_mesh_format(a.input)) << ", read in "
              << to_string(unit) << ")\n"
              << format_report(report);
    if (mp) std::cout << format_mass_properties(*mp, a.density);
    else std::cout << "mass properties: not computed (needs a closed, consistently oriented "
                      "surface)\n";
    std::cout.flush();
  }
  if (a.strict && !report.is_solid()) {
    throw_bad_input("--strict: the mesh is not a clean solid", {.file = a.input,
                    .suggestion = "see the report; `fascicle mesh repair` fixes what it safely can"});
  }
}

MeshWriteOptions write_options(const MeshArgs& a) {
  MeshWriteOptions o;
  o.encoding = a.ascii ? MeshEncoding::ascii
                       : (a.appended ? MeshEncoding::appended : MeshEncoding::binary);
  o.compress = !a.no_compress;
  o.unit = parse_length_unit(a.out_units);
  return o;
}

void run_convert(const MeshArgs& a) {
  const MeshWriteOptions options = write_options(a);
  find_mesh_format(a.output);  // usage error before any reading
  const TriMesh mesh = read_mesh(a.input, parse_length_unit(a.units));
  write_mesh(a.output, mesh, options);
  spdlog::info("wrote {} ({} vertices, {} triangles)", a.output, mesh.V.rows(), mesh.F.rows());
}

void run_repair(const MeshArgs& a) {
  const MeshWriteOptions options = write_options(a);
  find_mesh_format(a.output);
  const TriMesh mesh = read_mesh(a.input, parse_length_unit(a.units));
  RepairResult result;
  try {
    result = repair_mesh(mesh, {.merge_tolerance = parse_length(a.merge_tolerance)});
  } catch (const Error& e) {
    std::cout << a.input << ": cannot be repaired\n" << format_report(validate_mesh(mesh));
    std::cout.flush();
    throw e.with_file(a.input);
  }
  if (result.actions.empty()) std::cout << "nothing to repair\n";
  for (const std::string& action : result.actions) std::cout << "repaired: " << action << "\n";
  std::cout << format_report(result.report);
  std::cout.flush();
  write_mesh(a.output, result.mesh, options);
}

void add_common(CLI::App* cmd, MeshArgs& a) {
  cmd->add_option("--units", a.units, "Length unit of the input file: m, cm or mm")
      ->capture_default_str();
}

void add_output(CLI::App* cmd, MeshArgs& a) {
  cmd->add_option("--out-units", a.out_units, "Length unit of the output file: m, cm or mm")
      ->capture_default_str();
  cmd->add_flag("--ascii", a.ascii, "Write text (STL, PLY, VTP) instead of binary");
  cmd->add_flag("--appended", a.appended, "VTP: raw appended data block (as ParaView writes)");
  cmd->add_flag("--no-compress", a.no_compress, "VTP: no zlib compression");
}

}  // namespace

void add_mesh_commands(CLI::App& app, Invocation& run) {
  CLI::App* mesh = app.add_subcommand("mesh", "Mesh files: validation, mass properties, "
                                              "conversion, repair (OBJ, STL, PLY, VTP)");
  mesh->require_subcommand(1);
  auto args = std::make_shared<MeshArgs>();

  CLI::App* info = mesh->add_subcommand("info", "Validation report and mass properties");
  info->add_option("FILE", args->input, "Mesh file (.obj .stl .ply .vtp)")->required();
  add_common(info, *args);
  info->add_flag("--json", args->json, "Print the report as JSON");
  info->add_option("--density", args->density, "Density for the mass properties (kg/m^3)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  info->add_flag("--strict", args->strict, "Exit with code 3 unless the mesh is a clean solid");
  info->add_flag("--no-self-intersections", args->no_self_intersections,
                 "Skip the self-intersection search");
  info->callback([&run, args] { run.action = [args] { run_info(*args); }; });

  CLI::App* convert = mesh->add_subcommand("convert", "Convert between mesh formats");
  convert->add_option("IN", args->input, "Input mesh")->required();
  convert->add_option("OUT", args->output, "Output mesh (format by extension)")->required();
  add_common(convert, *args);
  add_output(convert, *args);
  convert->callback([&run, args] { run.action = [args] { run_convert(*args); }; });

  CLI::App* repair = mesh->add_subcommand(
      "repair", "Merge duplicate vertices, drop degenerate faces, orient outward");
  repair->add_option("IN", args->input, "Input mesh")->required();
  repair->add_option("OUT", args->output, "Repaired mesh (format by extension)")->required();
  add_common(repair, *args);
  add_output(repair, *args);
  repair->add_option("--merge-tol", args->merge_tolerance,
                     "Merge vertices closer than this (e.g. 1e-6, 0.01mm; default: identical "
                     "positions only)")
      ->capture_default_str();
  repair->callback([&run, args] { run.action = [args] { run_repair(*args); }; });
}

}  // namespace fascicle::cli
