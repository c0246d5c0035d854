// Residual of OpenSim's stiffness-sharing rule for the fibre velocity at a returned equilibrium
// state, recomputed from the public curves (shared by the musculotendon tests).
#pragma once

#include "fascicle/musculotendon/muscle.hpp"

#include <cmath>

namespace fascicle::test {

// |vN − g(state)| in units of vmax: g is OpenSim's stiffness-sharing fibre velocity (Thelen,
// Millard; DeGroote keeps the tendon force constant, vT = 0)
// vT = kM/(kM + kT)·vMT (vMT when the tendon is slack), vN = (vMT − vT) cos α/(l0 vmax), with
// kM = d(FM cos α)/dlM at fixed velocity and kT = F0 f_T'/lTs.
inline double velocity_residual(const Musculotendon& m, const MuscleOutputs& o) {
  const auto& p = m.params;
  const double F0 = p.max_isometric_force_N, l0 = p.optimal_fiber_length_m;
  const double lTs = p.tendon_slack_length_m, h = m.parallelogram_height_m;
  const double lM = o.fiber_length_m, c = std::cos(o.pennation_rad);
  const double l = lM / l0, a = o.activation, fv = o.force_velocity_multiplier;
  const double fm = o.fiber_force_N / F0;
  const double dfm = (a * fv * calc_active_force_length(m, l).derivative +
                      calc_passive_force_length(m, l).derivative) / l0;
  const double dcos = h * h / (lM * lM * lM * c);
  const double kM = (dfm * c + fm * dcos) * c * F0;
  const double kT = calc_tendon_force_length(m, o.tendon_length_m / lTs).derivative * F0 / lTs;
  const double vMT = o.musculotendon_velocity_m_per_s;
  double vT = (std::abs(kM + kT) > 1e-12 && o.tendon_length_m > lTs) ? kM / (kM + kT) * vMT : vMT;
  if (p.model == MuscleModel::degroote2016) vT = 0.0;  // DeGroote: constant tendon force
  const double expected = (vMT - vT) * c / (l0 * p.max_contraction_velocity);
  return std::abs(o.norm_fiber_velocity - expected);
}
}  // namespace fascicle::test
