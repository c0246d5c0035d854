// Parameters of a Hill-type musculotendon actuator (seed 001 §2.5.2; OpenSim 4.5 muscle models).
// All lengths in metres, forces in newtons, angles in radians, times in seconds; the maximum
// contraction velocity is in optimal fibre lengths per second (l0/s), as in OpenSim.
#pragma once

#include <string>

namespace fascicle {

// Which published model the curves and the equilibrium definitions follow.
enum class MuscleModel {
  thelen2003,    // OpenSim Thelen2003Muscle (Thelen 2003, J Biomech Eng 125:70)
  millard2012,   // OpenSim Millard2012EquilibriumMuscle (Millard et al. 2013, J Biomech Eng 135)
  degroote2016,  // OpenSim DeGrooteFregly2016Muscle (De Groote et al. 2016, Ann Biomed Eng 44)
};

// "thelen", "millard", "degroote" (also the OpenSim class names); throws bad_input otherwise.
MuscleModel parse_muscle_model(const std::string& text);
const char* to_string(MuscleModel model);      // "thelen" | "millard" | "degroote"
const char* opensim_class(MuscleModel model);  // e.g. "Thelen2003Muscle"

// Thelen2003Muscle curve parameters. Defaults are OpenSim's C++ defaults (gait2392 overrides them).
struct ThelenCurveParameters {
  double FmaxTendonStrain = 0.04;   // tendon strain at F0
  double FmaxMuscleStrain = 0.6;    // passive fibre strain at F0
  double KshapeActive = 0.45;       // Gaussian width of the active force-length curve
  double KshapePassive = 5.0;       // exponential shape of the passive curve
  double Af = 0.25;                 // force-velocity shape factor
  double Flen = 1.4;                // maximum normalised lengthening force
  double fv_linear_extrap_threshold = 0.95;  // fv beyond which the F-V inverse is linear
};

// Millard2012EquilibriumMuscle curve parameters (OpenSim 4.5 defaults).
struct MillardCurveParameters {
  // ActiveForceLengthCurve
  double min_norm_active_fiber_length = 0.4441;
  double transition_norm_fiber_length = 0.73;
  double max_norm_active_fiber_length = 1.8123;
  double shallow_ascending_slope = 0.8616;
  double minimum_value = 0.1;
  // ForceVelocityCurve
  double concentric_slope_at_vmax = 0.0;
  double concentric_slope_near_vmax = 0.25;
  double isometric_slope = 5.0;
  double eccentric_slope_at_vmax = 0.0;
  double eccentric_slope_near_vmax = 0.15;
  double max_eccentric_velocity_force_multiplier = 1.4;
  double concentric_curviness = 0.6;
  double eccentric_curviness = 0.9;
  // FiberForceLengthCurve (passive)
  double fiber_strain_at_zero_force = 0.0;
  double fiber_strain_at_one_norm_force = 0.7;
  double fiber_stiffness_at_low_force = 0.2;
  double fiber_stiffness_at_one_norm_force = 2.0 / 0.7;
  double fiber_curviness = 0.75;
  // TendonForceLengthCurve
  double tendon_strain_at_one_norm_force = 0.049;
  double tendon_stiffness_at_one_norm_force = 1.375 / 0.049;
  double tendon_norm_force_at_toe_end = 2.0 / 3.0;
  double tendon_curviness = 0.5;
  // Fibre damping (normalised, β in F0·s/(l0·vmax)); < 0.001 selects OpenSim's undamped mode.
  double fiber_damping = 0.1;
};

// DeGrooteFregly2016Muscle curve parameters (OpenSim 4.5 defaults).
struct DeGrooteCurveParameters {
  double passive_fiber_strain_at_one_norm_force = 0.6;
  double tendon_strain_at_one_norm_force = 0.049;
  double active_force_width_scale = 1.0;
  double fiber_damping = 0.0;
  // b in f = 0.5 tanh(b (u − a)). OpenSim's property activation_dynamics_smoothing defaults to
  // 0.1, the published model's value (OpenSim recommends 10 for activation/deactivation speeds
  // closer to the time constants; set it explicitly for that).
  double activation_dynamics_smoothing = 0.1;
};

// Everything needed to evaluate one musculotendon actuator.
struct MuscleParameters {
  std::string name = "muscle";
  MuscleModel model = MuscleModel::millard2012;
  double max_isometric_force_N = 1000.0;       // F0
  double optimal_fiber_length_m = 0.1;         // l0
  double tendon_slack_length_m = 0.2;          // lTs
  double pennation_at_optimal_rad = 0.0;       // α0
  double max_contraction_velocity = 10.0;      // vmax, l0/s
  double activation_time_constant_s = 0.015;   // τa
  double deactivation_time_constant_s = 0.050; // τd
  double minimum_activation = 0.01;            // a_min
  bool rigid_tendon = false;                   // OpenSim ignore_tendon_compliance
  ThelenCurveParameters thelen;
  MillardCurveParameters millard;
  DeGrooteCurveParameters degroote;
};

// The OpenSim C++ defaults of a model (time constants, minimum activation and curve parameters).
MuscleParameters default_muscle_parameters(MuscleModel model);

// Throws fascicle::Error (bad_input) naming the muscle and the parameter when a value is
// non-physical: non-positive lengths/forces/time constants, α0 outside [0, 90°), activation bounds
// outside [0, 1], or curve parameters that OpenSim's curve constructors reject.
void validate(const MuscleParameters& p);

// Physiological cross-sectional area from volume: PCSA = V·cos(α0) / l0 (m², with V in m³ and l0
// in m; Sacks & Roy 1982 / Ward et al. 2009 convention).
double calc_pcsa(double volume_m3, double optimal_fiber_length_m, double pennation_rad);

// Default specific tension σ = 25 N/cm² = 2.5e5 Pa (seed 001, Zajac 1989). Rajagopal 2016 uses 60.
inline constexpr double kDefaultSpecificTension_Pa = 25.0e4;

// F0 = σ·PCSA (N).
double calc_max_isometric_force(double pcsa_m2, double specific_tension_Pa = kDefaultSpecificTension_Pa);

}  // namespace fascicle
