// Compiled musculotendon model, static equilibrium and first-order dynamics.
// Equilibrium definitions follow OpenSim 4.5: Thelen2003Muscle::initMuscleState and
// Millard2012EquilibriumMuscle::estimateMuscleFiberState (force error FmAT − FT, velocity shared
// between fibre and tendon by relative stiffness, fv = 1 and no damping force at zero speed).
#include "fascicle/musculotendon/muscle.hpp"

#include "fascicle/core/error.hpp"

#include "curve_jets.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <string>

namespace fascicle {

namespace {
constexpr double kMaxPennation = 1.4706289056333368;  // acos(0.1)
constexpr double kMinNonzeroDamping = 0.001;          // OpenSim MIN_NONZERO_DAMPING_COEFFICIENT

[[noreturn]] void fail_numerical(const Musculotendon& m, const std::string& what) {
  throw_numerical("muscle '" + m.params.name + "': " + what,
                  {.object = m.params.name,
                   .suggestion = "check the musculotendon length and the muscle parameters"});
}
}  // namespace

Musculotendon compile_musculotendon(const MuscleParameters& params) {
  validate(params);
  Musculotendon m;
  m.params = params;
  const double l0 = params.optimal_fiber_length_m;
  m.parallelogram_height_m = l0 * std::sin(params.pennation_at_optimal_rad);
  m.max_pennation_rad = kMaxPennation;
  const double pennated_min = m.parallelogram_height_m / std::sin(kMaxPennation);
  m.minimum_activation = params.minimum_activation;
  m.thelen_constants = make_thelen_constants(params.thelen);
  m.degroote_constants = make_degroote_constants(params.degroote);
  switch (params.model) {
    case MuscleModel::thelen2003:
      m.min_fiber_length_m = std::max(pennated_min, 0.01 * l0);
      m.fiber_damping = 0.0;
      break;
    case MuscleModel::degroote2016:
      m.min_fiber_length_m = std::max(pennated_min, 0.2 * l0);
      m.fiber_damping = params.degroote.fiber_damping;
      break;
    case MuscleModel::millard2012: {
      MillardCurveParameters c = params.millard;
      const bool damped = c.fiber_damping >= kMinNonzeroDamping;
      if (!params.rigid_tendon && !damped) {
        // OpenSim's undamped elastic-tendon mode avoids the singularities of the F-V inverse.
        m.minimum_activation = std::max(0.01, m.minimum_activation);
        c.minimum_value = std::max(0.1, c.minimum_value);
        if (c.concentric_slope_at_vmax < 0.1 || c.eccentric_slope_at_vmax < 0.1) {
          c.concentric_slope_at_vmax = 0.1;
          c.eccentric_slope_at_vmax = 0.1;
        }
      } else {
        c.minimum_value = 0.0;
        c.concentric_slope_at_vmax = 0.0;
        c.eccentric_slope_at_vmax = 0.0;
      }
      const MillardCurveParameters& given = params.millard;
      const bool changed = c.minimum_value != given.minimum_value ||
                           c.concentric_slope_at_vmax != given.concentric_slope_at_vmax ||
                           c.eccentric_slope_at_vmax != given.eccentric_slope_at_vmax ||
                           m.minimum_activation != params.minimum_activation;
      if (changed && !params.rigid_tendon && !damped) {
        // Raised (clamped) values: a warning, once per compiled muscle, naming each parameter.
        std::string what;
        const auto note = [&](const char* name, double from, double to) {
          if (from != to) what += fmt::format("{}{} {} -> {}", what.empty() ? "" : ", ", name, from, to);
        };
        note("minimum_activation", params.minimum_activation, m.minimum_activation);
        note("active-force-length minimum_value", given.minimum_value, c.minimum_value);
        note("force-velocity concentric_slope_at_vmax", given.concentric_slope_at_vmax,
             c.concentric_slope_at_vmax);
        note("force-velocity eccentric_slope_at_vmax", given.eccentric_slope_at_vmax,
             c.eccentric_slope_at_vmax);
        spdlog::warn("muscle '{}': Millard2012 undamped elastic-tendon mode (fiber_damping {} < "
                     "{}) raises, as OpenSim does: {}", params.name, given.fiber_damping,
                     kMinNonzeroDamping, what);
      } else if (changed) {
        // The damped (or rigid-tendon) mode's curve overrides are OpenSim's definition of that mode.
        spdlog::debug("muscle '{}': Millard2012 {} mode uses active-force-length minimum {} and "
                      "force-velocity slopes 0 at +-vmax (as OpenSim)", params.name,
                      params.rigid_tendon ? "rigid-tendon" : "damped", c.minimum_value);
      }
      m.fiber_damping = damped ? c.fiber_damping : 0.0;
      m.millard_in_use = c;
      m.millard = make_millard_curves(c);
      m.min_fiber_length_m = std::max(pennated_min, c.min_norm_active_fiber_length * l0);
      break;
    }
  }
  return m;
}

CurvePoint calc_active_force_length(const Musculotendon& m, double l) {
  switch (m.params.model) {
    case MuscleModel::thelen2003: return thelen_active_force_length(m.params.thelen, l);
    case MuscleModel::millard2012: return m.millard.active_force_length.calc(l);
    case MuscleModel::degroote2016: return degroote_active_force_length(m.params.degroote, l);
  }
  return {};
}

CurvePoint calc_passive_force_length(const Musculotendon& m, double l) {
  switch (m.params.model) {
    case MuscleModel::thelen2003:
      return thelen_passive_force_length(m.params.thelen, m.thelen_constants, l);
    case MuscleModel::millard2012: return m.millard.passive_force_length.calc(l);
    case MuscleModel::degroote2016:
      return degroote_passive_force_length(m.params.degroote, m.degroote_constants, l);
  }
  return {};
}

CurvePoint calc_tendon_force_length(const Musculotendon& m, double lt) {
  switch (m.params.model) {
    case MuscleModel::thelen2003: return thelen_tendon_force_length(m.thelen_constants, lt);
    case MuscleModel::millard2012: return m.millard.tendon_force_length.calc(lt);
    case MuscleModel::degroote2016: return degroote_tendon_force_length(m.degroote_constants, lt);
  }
  return {};
}

CurvePoint calc_force_velocity(const Musculotendon& m, double a, double v) {
  switch (m.params.model) {
    case MuscleModel::thelen2003:
      return thelen_force_velocity(m.params.thelen, std::clamp(a, m.minimum_activation, 1.0), v);
    case MuscleModel::millard2012:
      // The two middle Bezier segments join exactly at (0, 1) with the isometric slope.
      if (v == 0.0) return {1.0, m.millard_in_use.isometric_slope};
      return m.millard.force_velocity.calc(v);
    case MuscleModel::degroote2016: return degroote_force_velocity(v);
  }
  return {};
}

double calc_passive_energy_J(const Musculotendon& m, double lM) {
  const double l = lM / m.params.optimal_fiber_length_m;
  double e = 0.0;
  switch (m.params.model) {
    case MuscleModel::thelen2003:
      e = thelen_passive_force_length_integral(m.params.thelen, m.thelen_constants, l);
      break;
    case MuscleModel::millard2012: e = m.millard.passive_force_length.calc_integral(l); break;
    case MuscleModel::degroote2016:
      e = degroote_passive_force_length_integral(m.params.degroote, m.degroote_constants, l);
      break;
  }
  return e * m.params.max_isometric_force_N * m.params.optimal_fiber_length_m;
}

double calc_tendon_energy_J(const Musculotendon& m, double lT) {
  const double t = lT / m.params.tendon_slack_length_m;
  double e = 0.0;
  switch (m.params.model) {
    case MuscleModel::thelen2003: e = thelen_tendon_force_length_integral(m.thelen_constants, t); break;
    case MuscleModel::millard2012: e = m.millard.tendon_force_length.calc_integral(t); break;
    case MuscleModel::degroote2016:
      e = degroote_tendon_force_length_integral(m.degroote_constants, t);
      break;
  }
  return e * m.params.max_isometric_force_N * m.params.tendon_slack_length_m;
}

double calc_tendon_length_for_force(const Musculotendon& m, double f) {
  const double lTs = m.params.tendon_slack_length_m;
  if (m.params.model == MuscleModel::degroote2016) {
    return lTs * degroote_norm_tendon_length(m.degroote_constants, f);
  }
  if (f <= 0.0) return lTs;
  if (m.params.model == MuscleModel::millard2012) {
    return lTs * m.millard.tendon_force_length.calc_inverse(f);
  }
  // Thelen: invert the toe exponential or the linear part in closed form.
  const double etoe = m.thelen_constants.tendon_toe_strain;
  const double klin = m.thelen_constants.tendon_linear_stiffness;
  if (f >= 0.33) return lTs * (1.0 + etoe + (f - 0.33) / klin);
  const double c = 0.33 / std::expm1(3.0);
  return lTs * (1.0 + etoe / 3.0 * std::log1p(f / c));
}

double calc_norm_fiber_velocity(const Musculotendon& m, double a, double l, double force) {
  a = std::clamp(a, m.minimum_activation, 1.0);
  const double fal = calc_active_force_length(m, l).value;
  const double fpe = calc_passive_force_length(m, l).value;
  const double beta = m.fiber_damping;
  if (m.params.model == MuscleModel::thelen2003) {
    return thelen_norm_fiber_velocity(m.params.thelen, a, fal, force - fpe);
  }
  if (beta == 0.0 && a * fal > 0.0) {
    const double fv = (force - fpe) / (a * fal);
    if (m.params.model == MuscleModel::degroote2016) {
      return std::clamp(degroote_force_velocity_inverse(fv), -5.0, 5.0);
    }
    return m.millard.force_velocity.calc_inverse(fv);
  }
  // g(v) = a fal fv(v) + fpe + β v − force is increasing; bracket, then safeguarded Newton.
  const auto g = [&](double v) {
    const CurvePoint fv = calc_force_velocity(m, a, v);
    return CurvePoint{a * fal * fv.value + fpe + beta * v - force, a * fal * fv.derivative + beta};
  };
  double lo = -1.0, hi = 1.0;
  double g_lo = g(lo).value, g_hi = g(hi).value;
  while (g_lo > 0.0 && lo > -5.0) g_lo = g(lo *= 2.0).value;
  while (g_hi < 0.0 && hi < 5.0) g_hi = g(hi *= 2.0).value;
  if (g_lo > 0.0) return lo;
  if (g_hi < 0.0) return hi;
  double v = 0.0;
  for (int it = 0; it < 100; ++it) {
    const CurvePoint r = g(v);
    if (std::abs(r.value) < 1e-14) break;
    if (r.value < 0.0) lo = v; else hi = v;
    double next = r.derivative > 0.0 ? v - r.value / r.derivative : 0.5 * (lo + hi);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    if (hi - lo < 1e-15) break;
    v = next;
  }
  return v;
}

namespace {
struct Geometry {
  double lM, cos_phi, sin_phi, lT;
};
// Fixed-width pennation: the fibre's projection on the tendon is w = lM cos α = √(lM² − h²).
// (w from lM directly: the tendon length does not wait for the division 1/lM.)
Geometry fiber_geometry(const Musculotendon& m, double lM, double lMT) {
  const double h = m.parallelogram_height_m;
  const double w = std::sqrt(std::max(0.0, lM * lM - h * h));
  const double inv_lM = 1.0 / lM;
  return {lM, w * inv_lM, h * inv_lM, lMT - w};
}

// Curve values already computed at the state's fibre and tendon lengths (reused, not recomputed).
struct KnownCurves {
  double fal, fpe, ft;
  double fv = std::numeric_limits<double>::quiet_NaN();  // NaN: not known
  const struct LengthJets* jets = nullptr;  // Millard: the solved jets (energies from their u)
};

// F0 l0 ∫ f_PE at a fibre length where f_PE is known. Thelen: expm1 of the exponent is
// f_PE·(exp(kPE) − 1), exact to a few ulps once f_PE·den ≥ 1 (the integral then exceeds
// 0.3 e0/kPE, so its relative error stays below 1e-14); below that, or for the other models, the
// integral is evaluated directly.
double calc_passive_energy_known(const Musculotendon& m, double lM, double fpe) {
  const ThelenCurveConstants& k = m.thelen_constants;
  if (m.params.model != MuscleModel::thelen2003 || !(fpe * k.passive_den >= 1.0)) {
    return calc_passive_energy_J(m, lM);
  }
  const double l0 = m.params.optimal_fiber_length_m;
  const double e = (fpe * k.passive_den / k.passive_rate - (lM / l0 - 1.0)) / k.passive_den;
  return e * m.params.max_isometric_force_N * l0;
}

// The three length-dependent curves with their first and second derivatives at normalised fibre
// length l and normalised tendon length t (one switch, inlined curve kernels); the tendon curve
// is left zero when `tendon` is false. Written in place (the solver's Eval holds it).
struct LengthJets {
  CurveJet fal, fpe, ft;
  // Millard: where the passive and tendon curves were solved (their energies reuse the solve)
  SmoothSegmentedCurve::Location fpe_at, ft_at;
};
inline void calc_length_jets(const Musculotendon& m, double l, double t, bool tendon,
                             LengthJets& j) {
  switch (m.params.model) {
    case MuscleModel::thelen2003:
      j.fal = detail::thelen_active_jet(m.thelen_constants, l);
      j.fpe = detail::thelen_passive_jet(m.thelen_constants, l);
      j.ft = tendon ? detail::thelen_tendon_jet(m.thelen_constants, t) : CurveJet{};
      return;
    case MuscleModel::millard2012:
      j.fal = m.millard.active_force_length.calc_jet(l);
      j.fpe = m.millard.passive_force_length.calc_jet(l, j.fpe_at);
      if (tendon) {
        j.ft = m.millard.tendon_force_length.calc_jet(t, j.ft_at);
      } else {
        j.ft = CurveJet{};
        j.ft_at = {};
      }
      return;
    case MuscleModel::degroote2016:
      j.fal = detail::degroote_active_jet(m.params.degroote, l);
      j.fpe = detail::degroote_passive_jet(m.params.degroote, m.degroote_constants, l);
      j.ft = tendon ? detail::degroote_tendon_jet(m.degroote_constants, t) : CurveJet{};
      return;
  }
}

// True when a curve is not twice differentiable between the two states (Thelen only: the passive
// curve starts at l = 1, the tendon toe at lT = lTs and its linear part at lT = lTs (1 + ε_toe);
// Millard's quintic-Bézier curves are C² and De Groote's are smooth).
inline bool crosses_kink(const Musculotendon& m, double l_a, double l_b, double t_a, double t_b) {
  if (m.params.model != MuscleModel::thelen2003) return false;
  const auto between = [](double k, double a, double b) { return (a - k) * (b - k) <= 0.0; };
  const double t_lin = 1.0 + m.thelen_constants.tendon_toe_strain;
  return between(1.0, l_a, l_b) || between(1.0, t_a, t_b) || between(t_lin, t_a, t_b);
}

// Fills the outputs for a fully known kinematic state.
void fill_outputs(const Musculotendon& m, double a, const Geometry& g, double vM, double lMT,
                  double vMT, bool rigid, MuscleOutputs& o, const KnownCurves* known = nullptr,
                  bool energies = true) {
  const auto& p = m.params;
  const double F0 = p.max_isometric_force_N, l0 = p.optimal_fiber_length_m;
  o.activation = a;
  o.musculotendon_length_m = lMT;
  o.musculotendon_velocity_m_per_s = vMT;
  o.fiber_length_m = g.lM;
  o.norm_fiber_length = g.lM / l0;
  o.fiber_velocity_m_per_s = vM;
  o.norm_fiber_velocity = vM / (l0 * p.max_contraction_velocity);
  o.pennation_rad = std::asin(std::min(1.0, g.sin_phi));
  o.tendon_length_m = g.lT;
  o.tendon_strain = g.lT / p.tendon_slack_length_m - 1.0;
  o.tendon_velocity_m_per_s = vMT - vM / g.cos_phi;
  o.active_force_length_multiplier =
      known ? known->fal : calc_active_force_length(m, o.norm_fiber_length).value;
  o.passive_force_multiplier =
      known ? known->fpe : calc_passive_force_length(m, o.norm_fiber_length).value;
  o.force_velocity_multiplier = (known && !std::isnan(known->fv))
                                    ? known->fv
                                    : calc_force_velocity(m, a, o.norm_fiber_velocity).value;
  o.active_fiber_force_N = F0 * a * o.active_force_length_multiplier * o.force_velocity_multiplier;
  o.passive_fiber_force_N = F0 * o.passive_force_multiplier;
  o.damping_fiber_force_N = F0 * m.fiber_damping * o.norm_fiber_velocity;
  o.fiber_force_N = o.active_fiber_force_N + o.passive_fiber_force_N + o.damping_fiber_force_N;
  o.fiber_force_along_tendon_N = o.fiber_force_N * g.cos_phi;
  if (rigid) {
    o.tendon_force_N = o.fiber_force_along_tendon_N;
    o.tendon_velocity_m_per_s = 0.0;
  } else {
    o.tendon_force_N =
        F0 * (known ? known->ft : calc_tendon_force_length(m, g.lT / p.tendon_slack_length_m).value);
  }
  o.norm_tendon_force = o.tendon_force_N / F0;
  o.fiber_active_power_W = -o.active_fiber_force_N * vM;
  if (!energies) return;  // left NaN
  if (known && known->jets && p.model == MuscleModel::millard2012) {
    const LengthJets& j = *known->jets;
    o.fiber_passive_energy_J =
        m.millard.passive_force_length.calc_integral_near(j.fpe_at, j.fpe, g.lM / l0) * F0 * l0;
    const double lTs = p.tendon_slack_length_m;
    o.tendon_energy_J = rigid ? 0.0
                              : m.millard.tendon_force_length.calc_integral_near(
                                    j.ft_at, j.ft, g.lT / lTs) * F0 * lTs;
    return;
  }
  o.fiber_passive_energy_J =
      known ? calc_passive_energy_known(m, g.lM, known->fpe) : calc_passive_energy_J(m, g.lM);
  o.tendon_energy_J = rigid ? 0.0 : calc_tendon_energy_J(m, g.lT);
}

void require_finite_input(const Musculotendon& m, double a, double lMT, double vMT) {
  if (!std::isfinite(a) || a < 0.0 || a > 1.0) {
    throw_bad_input("muscle '" + m.params.name + "': activation " + std::to_string(a) +
                        " is outside [0, 1]",
                    {.object = m.params.name});
  }
  if (!std::isfinite(lMT) || lMT <= 0.0 || !std::isfinite(vMT)) {
    throw_bad_input("muscle '" + m.params.name + "': musculotendon length " +
                        std::to_string(lMT) + " m / speed " + std::to_string(vMT) +
                        " m/s is not a finite positive length",
                    {.object = m.params.name});
  }
}

// Starting fibre length for the equilibrium solve, from the state with a just-slack tendon
// (fibre force along the tendon f_slack·F0, its slope dFmAT/dlM there, cos α there): the tendon
// must carry about that force, less what the fibre loses by shortening while the tendon
// stretches. lT1 = f_T⁻¹(f_slack) (tabulated/closed-form inverse), then one Newton step on
// f_T(lT) = f_slack − k (lT − lTs) with k = dFmAT/dlM · cos α (dlM/dlT = −cos α).
double calc_equilibrium_start(const Musculotendon& m, double f_slack, double dFmAT_dlM,
                              double cos_slack, double lMT) {
  const double lTs = m.params.tendon_slack_length_m, h = m.parallelogram_height_m;
  double t1 = 1.0;  // normalised tendon length carrying f_slack
  CurvePoint ft;    // the tendon curve there (closed forms where the inverse is exact)
  switch (m.params.model) {
    case MuscleModel::millard2012:
    {
      t1 = m.millard.tendon_force_length.calc_inverse_estimate(f_slack);
      const CurveJet j = m.millard.tendon_force_length.calc_jet(t1);  // shorter chain than calc
      ft = {j.value, j.derivative};
      break;
    }
    case MuscleModel::thelen2003: {
      const ThelenCurveConstants& k = m.thelen_constants;
      if (f_slack >= detail::kThelenToeForce) {
        t1 = 1.0 + k.tendon_toe_strain + (f_slack - detail::kThelenToeForce) / k.tendon_linear_stiffness;
        ft = {f_slack, k.tendon_linear_stiffness};
      } else if (f_slack > 0.0) {  // toe: f = c (exp(ρ x) − 1), f' = ρ (f + c)
        t1 = 1.0 + std::log1p(f_slack / k.tendon_toe_scale) / k.tendon_toe_rate;
        ft = {f_slack, k.tendon_toe_rate * (f_slack + k.tendon_toe_scale)};
      }
      break;
    }
    case MuscleModel::degroote2016: {  // f = c1 exp(kT (t − 1)) − c3, f' = kT (f + c3)
      const DeGrooteCurveConstants& k = m.degroote_constants;
      t1 = degroote_norm_tendon_length(k, f_slack);
      ft = {f_slack, k.tendon_kT * (f_slack + detail::kDeGrooteC3)};
      break;
    }
  }
  double lT = lTs * t1;
  const double k = dFmAT_dlM * cos_slack;  // normalised force per metre of tendon stretch
  const double kT = ft.derivative / lTs;
  if (kT + k > 0.0) lT -= (ft.value - f_slack + k * (lT - lTs)) / (kT + k);
  const double lMAT = std::max(0.0, lMT - lT);
  return std::sqrt(lMAT * lMAT + h * h);
}

MuscleOutputs rigid_outputs(const Musculotendon& m, double a, double lMT, double vMT) {
  MuscleOutputs o;
  const double h = m.parallelogram_height_m;
  const double lMAT = lMT - m.params.tendon_slack_length_m;
  double lM = std::sqrt(std::max(0.0, lMAT) * std::max(0.0, lMAT) + h * h);
  bool clamped = false;
  if (lM <= m.min_fiber_length_m || lMAT <= 0.0) {
    lM = m.min_fiber_length_m;
    clamped = true;
  }
  Geometry g = fiber_geometry(m, lM, lMT);
  g.lT = m.params.tendon_slack_length_m;
  const double vM = clamped ? 0.0 : vMT * g.cos_phi;
  fill_outputs(m, a, g, vM, lMT, vMT, true, o);
  o.fiber_at_lower_bound = clamped;
  return o;
}
}  // namespace

MuscleOutputs calc_static_equilibrium(const Musculotendon& m, double activation, double lMT,
                                      double vMT, const EquilibriumOptions& options) {
  require_finite_input(m, activation, lMT, vMT);
  const double a = std::clamp(activation, m.minimum_activation, 1.0);
  if (m.params.rigid_tendon) return rigid_outputs(m, a, lMT, vMT);

  const auto& p = m.params;
  const double F0 = p.max_isometric_force_N, l0 = p.optimal_fiber_length_m;
  const double lTs = p.tendon_slack_length_m, h = m.parallelogram_height_m;
  const double beta = m.fiber_damping;
  const bool moving = std::abs(vMT) > 1e-14;
  const double vscale = l0 * p.max_contraction_velocity;

  // Normalised force error r = FmAT/F0 − FT/F0 and its first two derivatives with respect to
  // lM at fixed normalised fibre velocity vN (with cos α' = h²/(lM³ cos α),
  // cos α'' = −3 cos α'/lM − cos α'²/cos α and dlT/dlM = −1/cos α).
  struct Eval {
    double r, dr, d2r, dFmAT_dlM, dFt_dlT;
    Geometry g;
    LengthJets jets;  // fal, fpe in l = lM/l0 and f_T in lT/lTs
  };
  // fv depends on the pass's fixed velocity only: computed once per pass, passed in. Written
  // into `e` (no copies of the jets); reciprocals keep divisions off the Newton chain.
  // `tendon` false: the slack-end evaluation, where f_T and its derivatives are taken as zero.
  const double inv_l0 = 1.0 / l0, inv_lTs = 1.0 / lTs;
  const auto evaluate = [&](Eval& e, double lM, double vN, double fv, bool tendon) {
    // as fiber_geometry, with 1/cos α = lM/w
    const double w = std::sqrt(std::max(0.0, lM * lM - h * h));
    const double inv_lM = 1.0 / lM;
    const double s = h * inv_lM, c = w * inv_lM;
    e.g = {lM, c, s, lMT - w};
    calc_length_jets(m, lM * inv_l0, e.g.lT * inv_lTs, tendon, e.jets);
    const LengthJets& j = e.jets;
    const double inv_c = lM / w;
    const double fm = a * j.fal.value * fv + j.fpe.value + beta * vN;
    const double dfm = (a * fv * j.fal.derivative + j.fpe.derivative) * inv_l0;
    const double d2fm = (a * fv * j.fal.second_derivative + j.fpe.second_derivative) * inv_l0 * inv_l0;
    const double dcos = (c > 0.0) ? s * s * inv_lM * inv_c : 0.0;  // h²/(lM³ cos α)
    const double d2cos = (c > 0.0) ? -dcos * (3.0 * inv_lM + dcos * inv_c) : 0.0;
    e.dFmAT_dlM = dfm * c + fm * dcos;
    e.dFt_dlT = j.ft.derivative * inv_lTs;
    e.r = fm * c - j.ft.value;
    e.dr = e.dFmAT_dlM + e.dFt_dlT * inv_c;
    e.d2r = d2fm * c + 2.0 * dfm * dcos + fm * d2cos -
            (j.ft.second_derivative * inv_lTs * inv_lTs + e.dFt_dlT * dcos) * inv_c * inv_c;
  };

  // Bracket: [minimum fibre length, fibre length at which the tendon is exactly slack].
  const double lo0 = m.min_fiber_length_m;
  const Geometry glo = fiber_geometry(m, lo0, lMT);
  MuscleOutputs o;
  if (glo.lT <= lTs) {
    // The path is too short even for the shortest fibre: slack tendon, fibre at its lower bound.
    fill_outputs(m, a, glo, 0.0, lMT, vMT, false, o);
    o.fiber_at_lower_bound = true;
    return o;
  }
  const double lMAT_slack = lMT - lTs;
  const double hi0 = std::sqrt(lMAT_slack * lMAT_slack + h * h);
  // Starting point (computed from the first pass's slack-end evaluation, see below).
  double start = 0.0;

  // Each pass solves r(lM; vN) = 0 at a fixed fibre velocity and ends with `last` evaluated at
  // the returned fibre length (reused for the outputs). The slack end is evaluated first (a
  // non-positive error there means a slack tendon); the lower end only when Newton heads for it.
  double lM = std::numeric_limits<double>::quiet_NaN();
  double vN_solved = 0.0;  // the velocity the final fibre length was solved with
  double fv = 1.0, fv_solved = 1.0;  // fv(vN) of this pass, and of the pass that was solved
  int total_iterations = 0;
  Eval last{};
  bool at_lower = false, have_start = false;
  // One pass: solves r(lM; vN) = 0 at the fixed normalised fibre velocity vN, leaves `last` at the
  // solved length and returns the fibre velocity OpenSim's stiffness-sharing rule gives there
  // (vN itself when static or at the lower bound).
  const auto solve_at_velocity = [&](double vN) -> double {
    vN_solved = vN;
    at_lower = false;
    double lo = lo0, hi = hi0;
    bool lo_checked = false;
    // fv(0) = 1 exactly for Thelen and Millard (De Groote's smooth curve is 1 only to rounding).
    fv = (vN == 0.0 && p.model != MuscleModel::degroote2016) ? 1.0
                                                             : calc_force_velocity(m, a, vN).value;
    fv_solved = fv;
    evaluate(last, hi, vN, fv, false);
    if (last.r <= 0.0) evaluate(last, hi, vN, fv, true);  // slack: the tendon curve at lT = lTs
    if (last.r <= 0.0) {
      lM = hi;
    } else {
      if (!have_start) start = calc_equilibrium_start(m, last.r + last.jets.ft.value, last.dFmAT_dlM,
                                                     last.g.cos_phi, lMT);
      have_start = true;
      double x = start;  // every pass from the same start (keeps the previous passes' results)
      if (!(x > lo && x < hi)) x = 0.5 * (lo + hi);
      bool converged = false;
      // Moves the solution from x to `to` without a confirming evaluation: the curve values
      // follow from their second-order Taylor expansions (error O(δ³), ≈ 1e-18 relative for the
      // steps allowed below); refused when a Thelen curve has a kink in between.
      const auto advance_to = [&](double to) {
        const Geometry g = fiber_geometry(m, to, lMT);
        const double dl = (to - x) / l0, dt = (g.lT - last.g.lT) / lTs;
        const double l_x = x / l0, t_x = last.g.lT / lTs;
        if (crosses_kink(m, l_x, l_x + dl, t_x, t_x + dt)) return false;
        const auto taylor = [](CurveJet& c, double d) {
          c.value += d * (c.derivative + 0.5 * d * c.second_derivative);
        };
        taylor(last.jets.fal, dl);
        taylor(last.jets.fpe, dl);
        taylor(last.jets.ft, dt);
        last.g = g;
        x = to;
        return true;
      };
      for (int it = 0; it < 200; ++it, ++total_iterations) {
        evaluate(last, x, vN, fv, true);
        if (!std::isfinite(last.r)) fail_numerical(m, "non-finite force error in equilibrium");
        const bool newton_ok = last.dr > 0.0 && std::isfinite(last.dr);
        const double inv_dr = 1.0 / last.dr;
        const double dn = newton_ok ? -last.r * inv_dr : 0.0;
        // Chebyshev's third-order step δ = δN − (r''/2r') δN² (Newton's when the correction is
        // not small against δN, e.g. far away or across a kink of a Thelen curve).
        const double q = newton_ok ? 0.5 * last.d2r * inv_dr : 0.0;
        const double step = (std::abs(q * dn) < 0.25) ? dn - q * dn * dn : dn;
        // A final step is taken without a confirming evaluation when its error,
        // O(δN³ (r''/r')²), is below 1e-17 l0.
        const bool final_step = !moving && newton_ok && std::abs(dn) <= 1e-6 * l0 &&
                                q * q * std::abs(dn * dn * dn) <= 1e-17 * l0;
        if (std::abs(last.r) <= 1e-13) {
          // Converged on the residual; where the slope is small that still leaves a length
          // error r/r', removed by one last step when it is safe.
          if (final_step) advance_to(x + step);
          converged = true;
          break;
        }
        if (last.r < 0.0) { lo = x; lo_checked = true; } else { hi = x; }
        if (hi - lo <= 1e-15 * hi) { converged = true; break; }
        double next = newton_ok ? x + step : -1.0;
        if (final_step && next > lo && next < hi && advance_to(next)) {
          ++total_iterations;
          converged = true;
          break;
        }
        if (!(next > lo && next < hi) && !lo_checked) {
          // Newton (or bisection) needs the lower end: is the fibre stronger than the tendon
          // even at the minimum fibre length?
          lo_checked = true;
          Eval elo;
          evaluate(elo, lo0, vN, fv, true);
          if (elo.r >= 0.0) {
            last = elo;
            at_lower = true;
            converged = true;
            break;
          }
        }
        if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
        x = next;
      }
      if (!converged) fail_numerical(m, "static equilibrium did not converge in 200 iterations");
      lM = at_lower ? lo0 : x;
    }
    if (!moving || at_lower) return vN;
    // Velocity estimate for the next pass (from the evaluation at the solved length).
    const Eval& e = last;
    double vT = 0.0;
    if (p.model != MuscleModel::degroote2016) {
      const double kM = e.dFmAT_dlM * e.g.cos_phi * F0;  // along-tendon fibre stiffness
      const double kT = e.dFt_dlT * F0;
      vT = (std::abs(kM + kT) > 1e-12 && e.g.lT > lTs) ? kM / (kM + kT) * vMT : vMT;
    }
    return (vMT - vT) * e.g.cos_phi / vscale;
  };

  // The velocity-dependent equilibrium is the root of G(vN) = g(vN) − vN, g being the pass above.
  // Fixed-point iteration vN ← g(vN) first (it settles in a few passes in most states); it is
  // stopped when it does not contract (|Δ| shrinking by less than 0.7 per pass over three passes,
  // or 60 passes), and the root is then found by regula falsi (Illinois) with bisection on a
  // bracket of G taken from the passes so far or from vN ∈ {0, vMT/vscale}.
  constexpr double kVelocityTolerance = 1e-13;  // on |G|, normalised velocity
  double v_iter = 0.0;
  bool settled = !moving;
  // Bracket ends: G(v_pos) = G_pos > 0 > G(v_neg) = G_neg; g_pos, g_neg are the (Illinois-scaled)
  // values used for the regula-falsi point.
  double v_pos = std::numeric_limits<double>::quiet_NaN(), g_pos = 0.0, G_pos = 0.0;
  double v_neg = std::numeric_limits<double>::quiet_NaN(), g_neg = 0.0, G_neg = 0.0;
  const auto record = [&](double v, double G) {
    if (G > 0.0) { v_pos = v; g_pos = G_pos = G; } else { v_neg = v; g_neg = G_neg = G; }
  };
  double previous_step = std::numeric_limits<double>::infinity();
  int slow_passes = 0;
  for (int outer = 0; outer < 60; ++outer) {
    const double v_next = solve_at_velocity(v_iter);
    if (!moving || at_lower) { settled = true; break; }
    const double G = v_next - v_iter;
    if (std::abs(G) < kVelocityTolerance) { settled = true; break; }
    if (!std::isfinite(G)) fail_numerical(m, "non-finite fibre velocity in equilibrium");
    record(v_iter, G);
    slow_passes = (std::abs(G) > 0.7 * previous_step) ? slow_passes + 1 : 0;
    previous_step = std::abs(G);
    v_iter = v_next;
    if (slow_passes >= 3 && outer >= 5) break;
  }
  if (!settled) {
    const auto state = [&] {
      return fmt::format("a={:.17g}, lMT={:.17g} m, vMT={:.17g} m/s", a, lMT, vMT);
    };
    const auto probe = [&](double v) {
      const double G = solve_at_velocity(v) - v;
      if (!std::isfinite(G)) fail_numerical(m, "non-finite fibre velocity in equilibrium (" + state() + ")");
      return G;
    };
    const double v_full = vMT / vscale;  // all of the path velocity in the fibre (cos α = 1)
    for (double v : {0.0, v_full}) {
      if (!std::isnan(v_pos) && !std::isnan(v_neg)) break;
      const double G = probe(v);
      if (at_lower || std::abs(G) < kVelocityTolerance) { settled = true; break; }
      record(v, G);
    }
    if (!settled && (std::isnan(v_pos) || std::isnan(v_neg))) {
      fail_numerical(m, "no fibre velocity satisfies OpenSim's stiffness-sharing rule (" + state() +
                            "); the fibre and tendon stiffnesses have opposite signs");
    }
    int side = 0;
    for (int it = 0; !settled && it < 200; ++it) {
      if (std::abs(v_pos - v_neg) <= 1e-15 * std::max(std::abs(v_pos), std::abs(v_neg))) break;
      double v = (v_neg * g_pos - v_pos * g_neg) / (g_pos - g_neg);
      const double lo_v = std::min(v_pos, v_neg), hi_v = std::max(v_pos, v_neg);
      if (!(v > lo_v && v < hi_v)) v = 0.5 * (v_pos + v_neg);
      const double G = probe(v);
      if (at_lower || std::abs(G) < kVelocityTolerance) { settled = true; break; }
      // Illinois: halve the retained end's value when the same end is kept twice.
      record(v, G);
      if (G > 0.0) {
        if (side == +1) g_neg *= 0.5;
        side = +1;
      } else {
        if (side == -1) g_pos *= 0.5;
        side = -1;
      }
    }
    if (!settled) {
      // The bracket has shrunk to rounding level without |G| < 1e-13. Either G is continuous and
      // the rest is the inner solve's noise (its 1e-13 F0 force tolerance moves g by up to a few
      // 1e-10 where g is steep): the better end is taken when it satisfies the rule to 1e-10.
      // Or g jumps because the rule switches at the slack tendon (g = 0, all of vMT in the
      // tendon, on the slack side, G = −vN exactly): no fixed point exists and the limit from
      // the taut side is returned, where the tendon is just at its slack length and carries no
      // force, so both sides agree on the forces. Any other jump (the fibre length leaving one
      // branch of a non-monotone force error for another) is reported as a numerical error.
      const bool noise = std::min(G_pos, -G_neg) <= 1e-10;
      const bool slack_switch = (G_pos == -v_pos) != (G_neg == -v_neg);
      if (noise || slack_switch) {
        const double v = noise ? (G_pos < -G_neg ? v_pos : v_neg)
                               : (G_pos == -v_pos ? v_neg : v_pos);
        probe(v);
        settled = true;
      }
    }
    if (!settled) {
      fail_numerical(m, fmt::format("the velocity-dependent equilibrium did not converge ({}): "
                                    "OpenSim's stiffness-sharing rule g(vN) jumps past vN between "
                                    "vN = {:.17g} (g − vN = {:.3g}) and {:.17g} (g − vN = {:.3g}) "
                                    "vmax", state(), v_neg, G_neg, v_pos, G_pos));
    }
  }
  if (!std::isfinite(lM)) fail_numerical(m, "static equilibrium produced a non-finite fibre length");
  // The outputs use the velocity the length was solved with (|G| < 1e-13 there).
  double vM = vN_solved * vscale;
  if (at_lower && vM < 0.0) vM = 0.0;
  const double fv_known = (vM == vN_solved * vscale) ? fv_solved : MuscleOutputs::nan;
  const KnownCurves known{last.jets.fal.value, last.jets.fpe.value, last.jets.ft.value, fv_known,
                          &last.jets};
  fill_outputs(m, a, last.g, vM, lMT, vMT, false, o, &known, options.energies);
  o.fiber_at_lower_bound = at_lower;
  o.iterations = total_iterations;
  return o;
}

double calc_activation_rate(const Musculotendon& m, double a, double u) {
  ActivationParameters ap{m.params.activation_time_constant_s, m.params.deactivation_time_constant_s,
                          m.minimum_activation, m.params.degroote.activation_dynamics_smoothing};
  if (m.params.model == MuscleModel::degroote2016) return calc_activation_rate_degroote(ap, a, u);
  return calc_activation_rate_opensim(ap, a, u);
}

MuscleState calc_equilibrium_state(const Musculotendon& m, double a, double lMT, double vMT) {
  const MuscleOutputs o = calc_static_equilibrium(m, a, lMT, vMT);
  return {std::clamp(a, m.minimum_activation, 1.0), o.fiber_length_m, o.norm_tendon_force};
}

MuscleStateRate calc_state_rate(const Musculotendon& m, const MuscleState& s, double u,
                                double lMT, double vMT, MuscleOutputs* out) {
  require_finite_input(m, std::clamp(s.activation, 0.0, 1.0), lMT, vMT);
  MuscleStateRate rate;
  rate.activation = calc_activation_rate(m, s.activation, u);
  const double a = std::clamp(s.activation, m.minimum_activation, 1.0);
  MuscleOutputs o;
  if (m.params.rigid_tendon) {
    o = rigid_outputs(m, a, lMT, vMT);
    if (out) *out = o;
    return rate;
  }
  const auto& p = m.params;
  const double l0 = p.optimal_fiber_length_m, lTs = p.tendon_slack_length_m;
  const double vscale = l0 * p.max_contraction_velocity;
  const double h = m.parallelogram_height_m;
  if (p.model == MuscleModel::degroote2016) {
    const double lT = lTs * degroote_norm_tendon_length(m.degroote_constants, s.norm_tendon_force);
    const double lMAT = lMT - lT;
    double lM = std::sqrt(std::max(0.0, lMAT) * std::max(0.0, lMAT) + h * h);
    const bool clamped = lM < m.min_fiber_length_m;
    lM = std::max(lM, m.min_fiber_length_m);
    Geometry g = fiber_geometry(m, lM, lMT);
    g.lT = lT;
    double vN = calc_norm_fiber_velocity(m, a, lM / l0, s.norm_tendon_force / g.cos_phi);
    if (clamped && vN < 0.0) vN = 0.0;
    const double vM = vN * vscale;
    fill_outputs(m, a, g, vM, lMT, vMT, false, o);
    o.fiber_at_lower_bound = clamped;
    const double vT = vMT - vM / g.cos_phi;
    rate.norm_tendon_force = degroote_tendon_force_length(m.degroote_constants, lT / lTs).derivative * vT / lTs;
    if (!std::isfinite(rate.norm_tendon_force)) fail_numerical(m, "non-finite tendon-force rate");
  } else {
    const bool clamped = s.fiber_length_m <= m.min_fiber_length_m;
    const double lM = std::max(s.fiber_length_m, m.min_fiber_length_m);
    const Geometry g = fiber_geometry(m, lM, lMT);
    const double ft = calc_tendon_force_length(m, g.lT / lTs).value;
    double vN = calc_norm_fiber_velocity(m, a, lM / l0, ft / g.cos_phi);
    if (clamped && vN < 0.0) vN = 0.0;
    const double vM = vN * vscale;
    fill_outputs(m, a, g, vM, lMT, vMT, false, o);
    o.fiber_at_lower_bound = clamped;
    rate.fiber_length = vM;
    if (!std::isfinite(vM)) fail_numerical(m, "non-finite fibre velocity");
  }
  if (out) *out = o;
  return rate;
}

}  // namespace fascicle
