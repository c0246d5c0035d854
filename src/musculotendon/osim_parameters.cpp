#include "fascicle/musculotendon/osim_parameters.hpp"

#include "fascicle/core/error.hpp"

#include <pugixml.hpp>

#include <cstdlib>
#include <cctype>
#include <functional>
#include <optional>
#include <string_view>

namespace fascicle {

namespace {
std::string_view local_name(const pugi::xml_node& n) {
  std::string_view s = n.name();
  const auto pos = s.rfind("::");
  return pos == std::string_view::npos ? s : s.substr(pos + 2);
}

std::optional<MuscleModel> model_of(const pugi::xml_node& n) {
  const std::string_view s = local_name(n);
  if (s == "Thelen2003Muscle") return MuscleModel::thelen2003;
  if (s == "Millard2012EquilibriumMuscle") return MuscleModel::millard2012;
  if (s == "DeGrooteFregly2016Muscle") return MuscleModel::degroote2016;
  return std::nullopt;
}

pugi::xml_node child(const pugi::xml_node& parent, const char* name) {
  for (pugi::xml_node c : parent.children()) {
    if (local_name(c) == name) return c;
  }
  return {};
}

struct Reader {
  const pugi::xml_node& element;
  const std::string& file;
  const std::string& muscle;

  std::optional<double> number(const pugi::xml_node& parent, const char* name) const {
    const pugi::xml_node c = child(parent, name);
    if (!c) return std::nullopt;
    const std::string text = c.text().as_string();
    char* end = nullptr;
    const double v = std::strtod(text.c_str(), &end);
    while (end && *end && std::isspace(static_cast<unsigned char>(*end))) ++end;
    if (text.empty() || end == text.c_str() || (end && *end)) {
      throw_bad_input("muscle '" + muscle + "': property <" + name + "> is not a number: '" +
                          text + "'",
                      {.file = file, .line = static_cast<long>(c.offset_debug()), .object = muscle,
                       .suggestion = "write a plain decimal number"});
    }
    return v;
  }
  void read(const pugi::xml_node& parent, const char* name, double& out) const {
    if (auto v = number(parent, name)) out = *v;
  }
  void read_bool(const pugi::xml_node& parent, const char* name, bool& out) const {
    const pugi::xml_node c = child(parent, name);
    if (!c) return;
    const std::string t = c.text().as_string();
    if (t == "true" || t == "1") out = true;
    else if (t == "false" || t == "0") out = false;
    else
      throw_bad_input("muscle '" + muscle + "': property <" + name + "> must be true or false",
                      {.file = file, .object = muscle});
  }
};
}  // namespace

bool is_osim_muscle_element(const pugi::xml_node& element) {
  return model_of(element).has_value();
}

MuscleParameters parse_osim_muscle(const pugi::xml_node& e, const std::string& file) {
  const std::string name = e.attribute("name").as_string();
  const auto model = model_of(e);
  if (!model) {
    throw_bad_input("element <" + std::string(e.name()) + "> '" + name +
                        "' is not a supported muscle type",
                    {.file = file, .object = name,
                     .suggestion = "use Thelen2003Muscle, Millard2012EquilibriumMuscle or "
                                   "DeGrooteFregly2016Muscle"});
  }
  MuscleParameters p = default_muscle_parameters(*model);
  p.name = name.empty() ? std::string("(unnamed)") : name;
  const Reader r{e, file, p.name};
  r.read(e, "max_isometric_force", p.max_isometric_force_N);
  r.read(e, "optimal_fiber_length", p.optimal_fiber_length_m);
  r.read(e, "tendon_slack_length", p.tendon_slack_length_m);
  r.read(e, "pennation_angle_at_optimal", p.pennation_at_optimal_rad);
  r.read(e, "max_contraction_velocity", p.max_contraction_velocity);
  r.read(e, "activation_time_constant", p.activation_time_constant_s);
  r.read(e, "deactivation_time_constant", p.deactivation_time_constant_s);
  r.read(e, "minimum_activation", p.minimum_activation);
  r.read_bool(e, "ignore_tendon_compliance", p.rigid_tendon);
  switch (*model) {
    case MuscleModel::thelen2003: {
      auto& t = p.thelen;
      r.read(e, "FmaxTendonStrain", t.FmaxTendonStrain);
      r.read(e, "FmaxMuscleStrain", t.FmaxMuscleStrain);
      r.read(e, "KshapeActive", t.KshapeActive);
      r.read(e, "KshapePassive", t.KshapePassive);
      r.read(e, "Af", t.Af);
      r.read(e, "Flen", t.Flen);
      r.read(e, "fv_linear_extrap_threshold", t.fv_linear_extrap_threshold);
      break;
    }
    case MuscleModel::millard2012: {
      auto& m = p.millard;
      r.read(e, "fiber_damping", m.fiber_damping);
      if (const pugi::xml_node c = child(e, "ActiveForceLengthCurve")) {
        r.read(c, "min_norm_active_fiber_length", m.min_norm_active_fiber_length);
        r.read(c, "transition_norm_fiber_length", m.transition_norm_fiber_length);
        r.read(c, "max_norm_active_fiber_length", m.max_norm_active_fiber_length);
        r.read(c, "shallow_ascending_slope", m.shallow_ascending_slope);
        r.read(c, "minimum_value", m.minimum_value);
      }
      if (const pugi::xml_node c = child(e, "ForceVelocityCurve")) {
        r.read(c, "concentric_slope_at_vmax", m.concentric_slope_at_vmax);
        r.read(c, "concentric_slope_near_vmax", m.concentric_slope_near_vmax);
        r.read(c, "isometric_slope", m.isometric_slope);
        r.read(c, "eccentric_slope_at_vmax", m.eccentric_slope_at_vmax);
        r.read(c, "eccentric_slope_near_vmax", m.eccentric_slope_near_vmax);
        r.read(c, "max_eccentric_velocity_force_multiplier",
               m.max_eccentric_velocity_force_multiplier);
        r.read(c, "concentric_curviness", m.concentric_curviness);
        r.read(c, "eccentric_curviness", m.eccentric_curviness);
      }
      if (const pugi::xml_node c = child(e, "FiberForceLengthCurve")) {
        r.read(c, "strain_at_zero_force", m.fiber_strain_at_zero_force);
        r.read(c, "strain_at_one_norm_force", m.fiber_strain_at_one_norm_force);
        // OpenSim: optional stiffnesses/curviness default to values fitted to the strains.
        const double de = m.fiber_strain_at_one_norm_force - m.fiber_strain_at_zero_force;
        m.fiber_stiffness_at_one_norm_force = r.number(c, "stiffness_at_one_norm_force")
                                                  .value_or(2.0 / de);
        m.fiber_stiffness_at_low_force = r.number(c, "stiffness_at_low_force").value_or(0.2);
        m.fiber_curviness = r.number(c, "curviness").value_or(0.75);
      }
      if (const pugi::xml_node c = child(e, "TendonForceLengthCurve")) {
        r.read(c, "strain_at_one_norm_force", m.tendon_strain_at_one_norm_force);
        const double eIso = m.tendon_strain_at_one_norm_force;
        m.tendon_stiffness_at_one_norm_force =
            r.number(c, "stiffness_at_one_norm_force").value_or(1.375 / eIso);
        m.tendon_norm_force_at_toe_end = r.number(c, "norm_force_at_toe_end").value_or(2.0 / 3.0);
        m.tendon_curviness = r.number(c, "curviness").value_or(0.5);
      }
      break;
    }
    case MuscleModel::degroote2016: {
      auto& d = p.degroote;
      r.read(e, "passive_fiber_strain_at_one_norm_force", d.passive_fiber_strain_at_one_norm_force);
      r.read(e, "tendon_strain_at_one_norm_force", d.tendon_strain_at_one_norm_force);
      r.read(e, "active_force_width_scale", d.active_force_width_scale);
      r.read(e, "fiber_damping", d.fiber_damping);
      r.read(e, "activation_dynamics_smoothing", d.activation_dynamics_smoothing);
      break;
    }
  }
  try {
    validate(p);
  } catch (const Error& err) {
    throw err.with_file(file);
  }
  return p;
}

MuscleParameters read_osim_muscle(const std::filesystem::path& path, const std::string& muscle) {
  pugi::xml_document doc;
  const pugi::xml_parse_result ok = doc.load_file(path.c_str());
  if (!ok) {
    throw_bad_input(std::string("cannot read OpenSim model: ") + ok.description(),
                    {.file = path.string(), .line = static_cast<long>(ok.offset),
                     .suggestion = "check that the path is an .osim XML file"});
  }
  pugi::xml_node found;
  for (const pugi::xpath_node& x : doc.select_nodes("//*[@name]")) {
    const pugi::xml_node n = x.node();
    if (is_osim_muscle_element(n) && muscle == n.attribute("name").as_string()) {
      found = n;
      break;
    }
  }
  if (!found) {
    throw_bad_input("no Thelen2003Muscle, Millard2012EquilibriumMuscle or DeGrooteFregly2016Muscle "
                    "named '" + muscle + "'",
                    {.file = path.string(), .object = muscle,
                     .suggestion = "check the muscle name (case-sensitive) in the model's ForceSet"});
  }
  return parse_osim_muscle(found, path.string());
}

}  // namespace fascicle
