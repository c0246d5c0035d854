#include "fascicle/musculotendon/params_json.hpp"

#include "fascicle/core/error.hpp"

#include <nlohmann/json.hpp>

#include <fstream>
#include <map>
#include <numbers>
#include <sstream>

namespace fascicle {

namespace {
using Json = nlohmann::json;

struct Ctx {
  const std::string& file;
  std::string name;
};

double get_number(const Json& v, const std::string& path, const Ctx& c) {
  if (!v.is_number()) {
    throw_bad_input("'" + path + "' must be a number", {.file = c.file, .json_path = path,
                                                        .object = c.name});
  }
  return v.get<double>();
}

// Reads the members of `obj` listed in `fields` (name → destination); unknown keys are errors.
void read_fields(const Json& obj, const std::string& path, const std::map<std::string, double*>& fields,
                 const Ctx& c) {
  if (!obj.is_object()) {
    throw_bad_input("'" + path + "' must be an object", {.file = c.file, .json_path = path});
  }
  for (const auto& [key, value] : obj.items()) {
    const auto it = fields.find(key);
    if (it == fields.end()) {
      std::string known;
      for (const auto& f : fields) known += (known.empty() ? "" : ", ") + f.first;
      throw_bad_input("unknown key '" + key + "' in '" + path + "'",
                      {.file = c.file, .json_path = path + "/" + key, .object = c.name,
                       .suggestion = "known keys: " + known});
    }
    *it->second = get_number(value, path + "/" + key, c);
  }
}
}  // namespace

MuscleParameters parse_muscle_parameters_json(const std::string& text, const std::string& file) {
  Json j;
  try {
    j = Json::parse(text);
  } catch (const Json::parse_error& e) {
    throw_bad_input(std::string("invalid JSON: ") + e.what(),
                    {.file = file, .suggestion = "fix the JSON syntax"});
  }
  if (!j.is_object()) throw_bad_input("the parameter file must hold a JSON object", {.file = file});
  MuscleModel model = MuscleModel::millard2012;
  if (j.contains("model")) {
    if (!j["model"].is_string())
      throw_bad_input("'model' must be a string", {.file = file, .json_path = "/model"});
    try {
      model = parse_muscle_model(j["model"].get<std::string>());
    } catch (const Error& e) {
      throw_bad_input(e.message(), {.file = file, .json_path = "/model",
                                    .suggestion = "use thelen, millard or degroote"});
    }
  }
  MuscleParameters p = default_muscle_parameters(model);
  Ctx c{file, ""};
  if (j.contains("name")) {
    if (!j["name"].is_string()) throw_bad_input("'name' must be a string", {.file = file, .json_path = "/name"});
    p.name = j["name"].get<std::string>();
  }
  c.name = p.name;
  double volume = -1.0, sigma = kDefaultSpecificTension_Pa, pennation_deg = -1.0;
  double rigid = p.rigid_tendon ? 1.0 : 0.0;
  const std::map<std::string, double*> top = {
      {"max_isometric_force_N", &p.max_isometric_force_N},
      {"optimal_fiber_length_m", &p.optimal_fiber_length_m},
      {"tendon_slack_length_m", &p.tendon_slack_length_m},
      {"pennation_at_optimal_rad", &p.pennation_at_optimal_rad},
      {"pennation_at_optimal_deg", &pennation_deg},
      {"max_contraction_velocity_l0_per_s", &p.max_contraction_velocity},
      {"activation_time_constant_s", &p.activation_time_constant_s},
      {"deactivation_time_constant_s", &p.deactivation_time_constant_s},
      {"minimum_activation", &p.minimum_activation},
      {"volume_m3", &volume},
      {"specific_tension_Pa", &sigma}};
  Json flat = Json::object();
  for (const auto& [key, value] : j.items()) {
    if (key == "model" || key == "name" || key == "thelen" || key == "millard" ||
        key == "degroote")
      continue;
    if (key == "rigid_tendon") {
      if (!value.is_boolean())
        throw_bad_input("'rigid_tendon' must be true or false", {.file = file, .json_path = "/rigid_tendon"});
      rigid = value.get<bool>() ? 1.0 : 0.0;
      continue;
    }
    flat[key] = value;
  }
  read_fields(flat, "", top, c);
  p.rigid_tendon = rigid != 0.0;
  if (pennation_deg >= 0.0) p.pennation_at_optimal_rad = pennation_deg * std::numbers::pi / 180.0;
  if (j.contains("thelen")) {
    auto& t = p.thelen;
    read_fields(j["thelen"], "/thelen",
                {{"FmaxTendonStrain", &t.FmaxTendonStrain}, {"FmaxMuscleStrain", &t.FmaxMuscleStrain},
                 {"KshapeActive", &t.KshapeActive}, {"KshapePassive", &t.KshapePassive},
                 {"Af", &t.Af}, {"Flen", &t.Flen},
                 {"fv_linear_extrap_threshold", &t.fv_linear_extrap_threshold}},
                c);
  }
  if (j.contains("millard")) {
    auto& m = p.millard;
    read_fields(j["millard"], "/millard",
                {{"min_norm_active_fiber_length", &m.min_norm_active_fiber_length},
                 {"transition_norm_fiber_length", &m.transition_norm_fiber_length},
                 {"max_norm_active_fiber_length", &m.max_norm_active_fiber_length},
                 {"shallow_ascending_slope", &m.shallow_ascending_slope},
                 {"minimum_value", &m.minimum_value},
                 {"concentric_slope_at_vmax", &m.concentric_slope_at_vmax},
                 {"concentric_slope_near_vmax", &m.concentric_slope_near_vmax},
                 {"isometric_slope", &m.isometric_slope},
                 {"eccentric_slope_at_vmax", &m.eccentric_slope_at_vmax},
                 {"eccentric_slope_near_vmax", &m.eccentric_slope_near_vmax},
                 {"max_eccentric_velocity_force_multiplier", &m.max_eccentric_velocity_force_multiplier},
                 {"concentric_curviness", &m.concentric_curviness},
                 {"eccentric_curviness", &m.eccentric_curviness},
                 {"fiber_strain_at_zero_force", &m.fiber_strain_at_zero_force},
                 {"fiber_strain_at_one_norm_force", &m.fiber_strain_at_one_norm_force},
                 {"fiber_stiffness_at_low_force", &m.fiber_stiffness_at_low_force},
                 {"fiber_stiffness_at_one_norm_force", &m.fiber_stiffness_at_one_norm_force},
                 {"fiber_curviness", &m.fiber_curviness},
                 {"tendon_strain_at_one_norm_force", &m.tendon_strain_at_one_norm_force},
                 {"tendon_stiffness_at_one_norm_force", &m.tendon_stiffness_at_one_norm_force},
                 {"tendon_norm_force_at_toe_end", &m.tendon_norm_force_at_toe_end},
                 {"tendon_curviness", &m.tendon_curviness},
                 {"fiber_damping", &m.fiber_damping}},
                c);
  }
  if (j.contains("degroote")) {
    auto& d = p.degroote;
    read_fields(j["degroote"], "/degroote",
                {{"passive_fiber_strain_at_one_norm_force", &d.passive_fiber_strain_at_one_norm_force},
                 {"tendon_strain_at_one_norm_force", &d.tendon_strain_at_one_norm_force},
                 {"active_force_width_scale", &d.active_force_width_scale},
                 {"fiber_damping", &d.fiber_damping},
                 {"activation_dynamics_smoothing", &d.activation_dynamics_smoothing}},
                c);
  }
  if (volume >= 0.0) {
    if (j.contains("max_isometric_force_N")) {
      throw_bad_input("give either max_isometric_force_N or volume_m3, not both",
                      {.file = file, .json_path = "/volume_m3", .object = p.name});
    }
    try {
      p.max_isometric_force_N = calc_max_isometric_force(
          calc_pcsa(volume, p.optimal_fiber_length_m, p.pennation_at_optimal_rad), sigma);
    } catch (const Error& e) {
      throw e.with_file(file);
    }
  }
  try {
    validate(p);
  } catch (const Error& e) {
    throw e.with_file(file);
  }
  return p;
}

MuscleParameters read_muscle_parameters_json(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) {
    throw_bad_input("cannot open muscle parameter file", {.file = path.string(),
                                                          .suggestion = "check the path"});
  }
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_muscle_parameters_json(ss.str(), path.string());
}

}  // namespace fascicle
