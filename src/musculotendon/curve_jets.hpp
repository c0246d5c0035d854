// Private to the musculotendon module: the Thelen 2003 and De Groote 2016 curves as inline
// "jets" (value, first and second derivative). The public curve functions in curves.cpp return
// the first two members of these, so the equilibrium solver (muscle.cpp), which also needs the
// second derivative, evaluates exactly the same arithmetic without a call per curve.
#pragma once

#include "fascicle/musculotendon/curves.hpp"

#include <cmath>

namespace fascicle::detail {

// ------------------------------------------------------------------------------ Thelen 2003
inline constexpr double kThelenToeShape = 3.0;   // kToe
inline constexpr double kThelenToeForce = 0.33;  // Ftoe

// exp(−d²/K), d = l − 1 (k.active_rate = 1/K).
inline CurveJet thelen_active_jet(const ThelenCurveConstants& k, double l) {
  const double d = l - 1.0;
  const double v = std::exp(-d * d * k.active_rate);
  const double d1 = -2.0 * k.active_rate * d * v;
  return {v, d1, -2.0 * k.active_rate * (v + d * d1)};
}

// (exp(kPE (l − 1)/e0) − 1)/(exp(kPE) − 1) for l > 1, else 0.
inline CurveJet thelen_passive_jet(const ThelenCurveConstants& k, double l) {
  if (l <= 1.0) return {0.0, 0.0, 0.0};
  const double ex = std::exp(k.passive_rate * (l - 1.0));
  const double d1 = k.passive_rate * ex * k.inv_passive_den;
  return {(ex - 1.0) * k.inv_passive_den, d1, k.passive_rate * d1};
}

// Exponential toe then linear, in strain x = lT/lTs − 1.
inline CurveJet thelen_tendon_jet(const ThelenCurveConstants& k, double lt) {
  const double x = lt - 1.0;
  const double etoe = k.tendon_toe_strain, klin = k.tendon_linear_stiffness;
  if (x > etoe) return {klin * (x - etoe) + kThelenToeForce, klin, 0.0};
  if (x > 0.0) {
    const double ex = std::exp(k.tendon_toe_rate * x);
    const double d1 = k.tendon_toe_scale * k.tendon_toe_rate * ex;
    return {k.tendon_toe_scale * (ex - 1.0), d1, k.tendon_toe_rate * d1};
  }
  return {0.0, 0.0, 0.0};
}

// ------------------------------------------------------------------------- De Groote 2016
struct DeGrooteGauss {
  double b1, b2, b3, b4;
};
inline constexpr DeGrooteGauss kDeGrooteActive[3] = {
    {0.814483478343008, 1.055033428970575, 0.162384573599574, 0.063303448465465},
    {0.433004984392647, 0.716775413397760, -0.029947116970696, 0.200356847296188},
    {0.1, 1.0, 0.353553390593274, 0.0}};
inline constexpr double kDeGrooteKPE = 4.0;
inline constexpr double kDeGrooteC1 = 0.2, kDeGrooteC2 = 1.0, kDeGrooteC3 = 0.2;

// Σ b1 exp(−½ (x − b2)²/(b3 + b4 x)²), x = 1 + (l − 1)/width_scale.
inline CurveJet degroote_active_jet(const DeGrooteCurveParameters& p, double l) {
  const double s = 1.0 / p.active_force_width_scale;
  const double x = 1.0 + (l - 1.0) * s;
  CurveJet out;
  for (const DeGrooteGauss& g : kDeGrooteActive) {
    const double den = g.b3 + g.b4 * x;
    const double num = x - g.b2;
    const double e = g.b1 * std::exp(-0.5 * num * num / (den * den));
    // e = b1 exp(G), G = −½ num²/den²: G' = −(num/den² − num² b4/den³),
    // G'' = −1/den² + 4 num b4/den³ − 3 num² b4²/den⁴; e'' = e (G'² + G'').
    const double G1 = -(num / (den * den)) + num * num * g.b4 / (den * den * den);
    const double rb = num / den * g.b4;
    const double G2 = (-1.0 + 4.0 * rb - 3.0 * rb * rb) / (den * den);
    out.value += e;
    out.derivative += e * G1 * s;
    out.second_derivative += e * (G1 * G1 + G2) * s * s;
  }
  return out;
}

// (exp(kPE (l − 1)/e0) − offset)/den.
inline CurveJet degroote_passive_jet(const DeGrooteCurveParameters& p,
                                     const DeGrooteCurveConstants& k, double l) {
  const double e0 = p.passive_fiber_strain_at_one_norm_force;
  const double ex = std::exp(kDeGrooteKPE * (l - 1.0) / e0);
  const double d1 = kDeGrooteKPE / e0 * ex / k.passive_den;
  return {(ex - k.passive_offset) / k.passive_den, d1, kDeGrooteKPE / e0 * d1};
}

// c1 exp(kT (lT − c2)) − c3.
inline CurveJet degroote_tendon_jet(const DeGrooteCurveConstants& k, double lt) {
  const double kT = k.tendon_kT;
  const double e = kDeGrooteC1 * std::exp(kT * (lt - kDeGrooteC2));
  return {e - kDeGrooteC3, kT * e, kT * kT * e};
}

}  // namespace fascicle::detail
