#include "fascicle/musculotendon/parameters.hpp"

#include "fascicle/core/error.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <numbers>

namespace fascicle {

MuscleModel parse_muscle_model(const std::string& text) {
  std::string t = text;
  std::transform(t.begin(), t.end(), t.begin(), [](unsigned char c) { return std::tolower(c); });
  if (t == "thelen" || t == "thelen2003" || t == "thelen2003muscle") return MuscleModel::thelen2003;
  if (t == "millard" || t == "millard2012" || t == "millard2012equilibriummuscle")
    return MuscleModel::millard2012;
  if (t == "degroote" || t == "degroote2016" || t == "degrootefregly2016muscle")
    return MuscleModel::degroote2016;
  throw_usage("unknown muscle model '" + text + "'",
              {.suggestion = "use one of: thelen, millard, degroote"});
}

const char* to_string(MuscleModel model) {
  switch (model) {
    case MuscleModel::thelen2003: return "thelen";
    case MuscleModel::millard2012: return "millard";
    case MuscleModel::degroote2016: return "degroote";
  }
  return "?";
}

const char* opensim_class(MuscleModel model) {
  switch (model) {
    case MuscleModel::thelen2003: return "Thelen2003Muscle";
    case MuscleModel::millard2012: return "Millard2012EquilibriumMuscle";
    case MuscleModel::degroote2016: return "DeGrooteFregly2016Muscle";
  }
  return "?";
}

MuscleParameters default_muscle_parameters(MuscleModel model) {
  MuscleParameters p;
  p.model = model;
  switch (model) {
    case MuscleModel::thelen2003:
      p.activation_time_constant_s = 0.015;
      p.deactivation_time_constant_s = 0.050;
      p.minimum_activation = 0.01;
      break;
    case MuscleModel::millard2012:
      p.activation_time_constant_s = 0.010;
      p.deactivation_time_constant_s = 0.040;
      p.minimum_activation = 0.01;
      break;
    case MuscleModel::degroote2016:
      p.activation_time_constant_s = 0.015;
      p.deactivation_time_constant_s = 0.060;
      p.minimum_activation = 0.0;
      break;
  }
  return p;
}

namespace {
void require(bool ok, const MuscleParameters& p, const std::string& parameter,
             const std::string& what, double value) {
  if (ok) return;
  throw_bad_input("muscle '" + p.name + "': parameter " + parameter + " = " +
                      std::to_string(value) + " " + what,
                  {.object = p.name, .suggestion = "correct " + parameter + " in the input"});
}
bool finite(double v) { return std::isfinite(v); }
}  // namespace

void validate(const MuscleParameters& p) {
  require(finite(p.max_isometric_force_N) && p.max_isometric_force_N > 0, p,
          "max_isometric_force", "must be positive (N)", p.max_isometric_force_N);
  require(finite(p.optimal_fiber_length_m) && p.optimal_fiber_length_m > 0, p,
          "optimal_fiber_length", "must be positive (m)", p.optimal_fiber_length_m);
  require(finite(p.tendon_slack_length_m) && p.tendon_slack_length_m > 0, p,
          "tendon_slack_length", "must be positive (m)", p.tendon_slack_length_m);
  require(finite(p.pennation_at_optimal_rad) && p.pennation_at_optimal_rad >= 0 &&
              p.pennation_at_optimal_rad < std::numbers::pi / 2 - 1e-9,
          p, "pennation_angle_at_optimal", "must be in [0, pi/2) rad", p.pennation_at_optimal_rad);
  require(finite(p.max_contraction_velocity) && p.max_contraction_velocity > 0, p,
          "max_contraction_velocity", "must be positive (l0/s)", p.max_contraction_velocity);
  require(finite(p.activation_time_constant_s) && p.activation_time_constant_s > 0, p,
          "activation_time_constant", "must be positive (s)", p.activation_time_constant_s);
  require(finite(p.deactivation_time_constant_s) && p.deactivation_time_constant_s > 0, p,
          "deactivation_time_constant", "must be positive (s)", p.deactivation_time_constant_s);
  require(finite(p.minimum_activation) && p.minimum_activation >= 0 && p.minimum_activation < 1,
          p, "minimum_activation", "must be in [0, 1)", p.minimum_activation);
  switch (p.model) {
    case MuscleModel::thelen2003: {
      const auto& t = p.thelen;
      require(t.FmaxTendonStrain > 0, p, "FmaxTendonStrain", "must be positive", t.FmaxTendonStrain);
      require(t.FmaxMuscleStrain > 0, p, "FmaxMuscleStrain", "must be positive", t.FmaxMuscleStrain);
      require(t.KshapeActive > 0, p, "KshapeActive", "must be positive", t.KshapeActive);
      require(t.KshapePassive > 0, p, "KshapePassive", "must be positive", t.KshapePassive);
      require(t.Af > 0, p, "Af", "must be positive", t.Af);
      require(t.Flen > 1, p, "Flen", "must be greater than 1", t.Flen);
      require(t.fv_linear_extrap_threshold > 1.0 / t.Flen && t.fv_linear_extrap_threshold < 1, p,
              "fv_linear_extrap_threshold", "must be in (1/Flen, 1)", t.fv_linear_extrap_threshold);
      break;
    }
    case MuscleModel::millard2012: {
      const auto& m = p.millard;
      require(m.min_norm_active_fiber_length >= 0 &&
                  m.transition_norm_fiber_length > m.min_norm_active_fiber_length &&
                  m.transition_norm_fiber_length < 1.0 && m.max_norm_active_fiber_length > 1.0,
              p, "ActiveForceLengthCurve lengths",
              "must satisfy 0 <= min_norm_active < transition < 1 < max_norm_active",
              m.transition_norm_fiber_length);
      require(m.minimum_value >= 0 && m.minimum_value < 1, p, "minimum_value", "must be in [0, 1)",
              m.minimum_value);
      require(m.shallow_ascending_slope >= 0 &&
                  m.shallow_ascending_slope < 1.0 / (1.0 - m.transition_norm_fiber_length),
              p, "shallow_ascending_slope", "must be in [0, 1/(1 - transition))",
              m.shallow_ascending_slope);
      require(m.max_eccentric_velocity_force_multiplier > 1, p,
              "max_eccentric_velocity_force_multiplier", "must be greater than 1",
              m.max_eccentric_velocity_force_multiplier);
      require(m.concentric_slope_at_vmax >= 0 && m.concentric_slope_at_vmax < 1, p,
              "concentric_slope_at_vmax", "must be in [0, 1)", m.concentric_slope_at_vmax);
      require(m.concentric_slope_near_vmax > m.concentric_slope_at_vmax &&
                  m.concentric_slope_near_vmax <= 1,
              p, "concentric_slope_near_vmax", "must be in (concentric_slope_at_vmax, 1]",
              m.concentric_slope_near_vmax);
      require(m.isometric_slope > 1, p, "isometric_slope", "must be greater than 1",
              m.isometric_slope);
      const double emax = m.max_eccentric_velocity_force_multiplier - 1;
      require(m.eccentric_slope_at_vmax >= 0 && m.eccentric_slope_at_vmax < emax, p,
              "eccentric_slope_at_vmax", "must be in [0, fmaxE - 1)", m.eccentric_slope_at_vmax);
      require(m.eccentric_slope_near_vmax >= m.eccentric_slope_at_vmax &&
                  m.eccentric_slope_near_vmax < emax,
              p, "eccentric_slope_near_vmax", "must be in [eccentric_slope_at_vmax, fmaxE - 1)",
              m.eccentric_slope_near_vmax);
      for (double c : {m.concentric_curviness, m.eccentric_curviness, m.fiber_curviness,
                       m.tendon_curviness}) {
        require(c >= 0 && c <= 1, p, "curviness", "must be in [0, 1]", c);
      }
      const double de = m.fiber_strain_at_one_norm_force - m.fiber_strain_at_zero_force;
      require(de > 0, p, "strain_at_one_norm_force (fibre)", "must exceed strain_at_zero_force",
              m.fiber_strain_at_one_norm_force);
      require(m.fiber_stiffness_at_one_norm_force > 1.0 / de, p,
              "stiffness_at_one_norm_force (fibre)", "must exceed 1/(e1 - e0)",
              m.fiber_stiffness_at_one_norm_force);
      require(m.fiber_stiffness_at_low_force > 0 && m.fiber_stiffness_at_low_force < 1.0 / de, p,
              "stiffness_at_low_force", "must be in (0, 1/(e1 - e0))", m.fiber_stiffness_at_low_force);
      require(m.tendon_strain_at_one_norm_force > 0, p, "strain_at_one_norm_force (tendon)",
              "must be positive", m.tendon_strain_at_one_norm_force);
      require(m.tendon_stiffness_at_one_norm_force > 1.0 / m.tendon_strain_at_one_norm_force, p,
              "stiffness_at_one_norm_force (tendon)", "must exceed 1/strain_at_one_norm_force",
              m.tendon_stiffness_at_one_norm_force);
      require(m.tendon_norm_force_at_toe_end > 0 && m.tendon_norm_force_at_toe_end < 1, p,
              "norm_force_at_toe_end", "must be in (0, 1)", m.tendon_norm_force_at_toe_end);
      require(finite(m.fiber_damping) && m.fiber_damping >= 0, p, "fiber_damping",
              "must be non-negative", m.fiber_damping);
      break;
    }
    case MuscleModel::degroote2016: {
      const auto& d = p.degroote;
      require(d.passive_fiber_strain_at_one_norm_force > 0, p,
              "passive_fiber_strain_at_one_norm_force", "must be positive",
              d.passive_fiber_strain_at_one_norm_force);
      require(d.tendon_strain_at_one_norm_force > 0, p, "tendon_strain_at_one_norm_force",
              "must be positive", d.tendon_strain_at_one_norm_force);
      require(d.active_force_width_scale >= 1, p, "active_force_width_scale",
              "must be at least 1", d.active_force_width_scale);
      require(d.fiber_damping >= 0, p, "fiber_damping", "must be non-negative", d.fiber_damping);
      require(d.activation_dynamics_smoothing > 0, p, "activation_dynamics_smoothing",
              "must be positive", d.activation_dynamics_smoothing);
      break;
    }
  }
}

double calc_pcsa(double volume_m3, double l0, double pennation_rad) {
  if (!(volume_m3 > 0) || !(l0 > 0)) {
    throw_bad_input("PCSA needs a positive volume and optimal fibre length (got V = " +
                    std::to_string(volume_m3) + " m^3, l0 = " + std::to_string(l0) + " m)");
  }
  return volume_m3 * std::cos(pennation_rad) / l0;
}

double calc_max_isometric_force(double pcsa_m2, double sigma_Pa) {
  if (!(pcsa_m2 > 0) || !(sigma_Pa > 0)) {
    throw_bad_input("F0 = sigma * PCSA needs positive PCSA and specific tension (got PCSA = " +
                    std::to_string(pcsa_m2) + " m^2, sigma = " + std::to_string(sigma_Pa) + " Pa)");
  }
  return sigma_Pa * pcsa_m2;
}

}  // namespace fascicle
