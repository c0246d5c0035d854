// A compiled Hill-type musculotendon actuator (immutable, shareable across threads), its static
// equilibrium and its first-order dynamics. Conventions: lengths m, forces N, velocities m/s
// (positive = lengthening), angles rad. Fixed-width (constant-height) pennation, h = l0 sin α0.
#pragma once

#include "fascicle/musculotendon/activation.hpp"
#include "fascicle/musculotendon/curves.hpp"
#include "fascicle/musculotendon/parameters.hpp"

#include <limits>

namespace fascicle {

// The parameters plus everything derived once: OpenSim's mode-dependent curve adjustments,
// pennation geometry, fibre-length bounds and (for Millard) the Bézier curves.
struct Musculotendon {
  MuscleParameters params;         // as given (validated)
  double minimum_activation = 0;   // in use (OpenSim may raise/lower it by mode)
  double fiber_damping = 0;        // β in use (0 when undamped)
  double parallelogram_height_m = 0;
  double max_pennation_rad = 0;     // acos(0.1) for all three models
  double min_fiber_length_m = 0;    // OpenSim's lower bound on the fibre length
  MillardCurveParameters millard_in_use;  // after OpenSim's damped/undamped adjustments
  MillardCurves millard;                  // empty unless model == millard2012
  ThelenCurveConstants thelen_constants;      // from params.thelen
  DeGrooteCurveConstants degroote_constants;  // from params.degroote
};

// Validates and compiles. Millard: damping ≥ 0.001 (or rigid tendon) → fal minimum 0, F-V slopes at
// ±vmax 0, a_min ≥ 0; undamped elastic → a_min ≥ 0.01, fal minimum ≥ 0.1, F-V end slopes ≥ 0.1
// (exactly as OpenSim's Millard2012EquilibriumMuscle::buildMuscle). Values raised in the undamped
// mode are logged once per call with spdlog::warn naming the muscle, each parameter and its old
// and new value; the damped-mode overrides (OpenSim's definition of that mode) at debug level.
Musculotendon compile_musculotendon(const MuscleParameters& params);

// Normalised curves of the compiled model (F-V takes activation: Thelen's depends on it).
CurvePoint calc_active_force_length(const Musculotendon& m, double norm_fiber_length);
CurvePoint calc_passive_force_length(const Musculotendon& m, double norm_fiber_length);
CurvePoint calc_tendon_force_length(const Musculotendon& m, double norm_tendon_length);
CurvePoint calc_force_velocity(const Musculotendon& m, double activation, double norm_fiber_velocity);
double calc_passive_energy_J(const Musculotendon& m, double fiber_length_m);  // F0 l0 ∫ f_PE
double calc_tendon_energy_J(const Musculotendon& m, double tendon_length_m);  // F0 lTs ∫ f_T
// Tendon length at which the tendon force is `norm_force` (inverse of the tendon curve).
double calc_tendon_length_for_force(const Musculotendon& m, double norm_force);
// Normalised fibre velocity at which the fibre develops `norm_fiber_force` (F/F0 along the fibre,
// including passive and damping parts) at activation a and normalised length l.
double calc_norm_fiber_velocity(const Musculotendon& m, double activation, double norm_fiber_length,
                                double norm_fiber_force);

// Per-muscle outputs (NaN until computed).
struct MuscleOutputs {
  static constexpr double nan = std::numeric_limits<double>::quiet_NaN();
  double activation = nan;
  double musculotendon_length_m = nan;
  double musculotendon_velocity_m_per_s = nan;
  double fiber_length_m = nan;
  double norm_fiber_length = nan;            // lM / l0
  double fiber_velocity_m_per_s = nan;       // + lengthening
  double norm_fiber_velocity = nan;          // vM / (l0 vmax)
  double pennation_rad = nan;
  double tendon_length_m = nan;
  double tendon_strain = nan;                // lT/lTs − 1
  double tendon_velocity_m_per_s = nan;
  double active_force_length_multiplier = nan;
  double force_velocity_multiplier = nan;
  double passive_force_multiplier = nan;
  double active_fiber_force_N = nan;         // F0 a fal fv
  double passive_fiber_force_N = nan;        // F0 fpe
  double damping_fiber_force_N = nan;        // F0 β vN
  double fiber_force_N = nan;                // sum of the three, along the fibre
  double fiber_force_along_tendon_N = nan;
  double tendon_force_N = nan;
  double norm_tendon_force = nan;
  double fiber_active_power_W = nan;         // −F_active vM (positive when shortening)
  double fiber_passive_energy_J = nan;
  double tendon_energy_J = nan;
  bool fiber_at_lower_bound = false;         // clamped at min_fiber_length_m
  int iterations = 0;                        // equilibrium solver iterations
};

// Static equilibrium: the fibre length at which the fibre force projected on the tendon equals
// the tendon force, for activation a (clamped to [a_min, 1] as OpenSim does), path length lMT and
// lengthening speed vMT. The fibre velocity is zero when |vMT| is negligible; otherwise it is the
// share of vMT given by the relative fibre/tendon stiffness (Thelen/Millard, as OpenSim) or the
// tendon velocity is zero (DeGroote). Rigid tendon: closed form. Bracketed, safeguarded Newton
// on [min fibre length, fibre length with a slack tendon]; with vMT ≠ 0 the fibre velocity is the
// root of g(vN) − vN (g: the stiffness-sharing rule at the length solved for vN), by fixed-point
// iteration then bracketed regula falsi, to |g − vN| < 1e-13 vmax. Where the rule switches at the
// slack tendon (no fixed point), the taut-side limit (tendon just slack) is returned. Throws
// fascicle::Error (numerical, naming the muscle and the state) rather than returning NaN or a
// velocity that is not a fixed point.
struct EquilibriumOptions {
  bool energies = true;  // false: skip the elastic energies (fields left NaN), ~10 % faster
};
MuscleOutputs calc_static_equilibrium(const Musculotendon& m, double activation,
                                      double musculotendon_length_m,
                                      double musculotendon_velocity_m_per_s = 0.0,
                                      const EquilibriumOptions& options = {});

// Dynamic state: activation, and fibre length (Thelen, Millard) or normalised tendon force
// (DeGroote) for an elastic tendon (ignored with a rigid tendon).
struct MuscleState {
  double activation = 0.0;
  double fiber_length_m = 0.0;
  double norm_tendon_force = 0.0;
};
struct MuscleStateRate {
  double activation = 0.0;         // 1/s
  double fiber_length = 0.0;       // m/s
  double norm_tendon_force = 0.0;  // 1/s
};

// The state at static equilibrium for (a, lMT, vMT).
MuscleState calc_equilibrium_state(const Musculotendon& m, double activation,
                                   double musculotendon_length_m,
                                   double musculotendon_velocity_m_per_s = 0.0);

// Outputs and state derivative for excitation u and path (lMT, vMT). `out` may be null.
MuscleStateRate calc_state_rate(const Musculotendon& m, const MuscleState& s, double excitation,
                                double musculotendon_length_m, double musculotendon_velocity_m_per_s,
                                MuscleOutputs* out);

// Activation rate of the model's own activation dynamics (OpenSim first-order for Thelen and
// Millard, tanh-smoothed for DeGroote).
double calc_activation_rate(const Musculotendon& m, double activation, double excitation);

}  // namespace fascicle
