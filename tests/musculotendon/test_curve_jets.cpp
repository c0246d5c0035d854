// Second derivatives used by the third-order equilibrium solver: the curve jets against central
// differences of their own slopes, the jets against the public curve functions, and the
// equilibrium outputs (whose last step is taken without a confirming evaluation) against fresh
// curve evaluations at the returned lengths.
#include "fascicle/musculotendon/curves.hpp"
#include "fascicle/musculotendon/muscle.hpp"

// Private kernels of the module (inline, header only).
#include "../../src/musculotendon/curve_jets.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>

using namespace fascicle;

namespace {
// Checks d1 against the central difference of the value and d2 against that of d1 over [a, b],
// skipping points near a listed kink. The tolerance is the change of the difference quotient
// between steps h and h/2 (an estimate of its truncation error, large where the curvature rises
// steeply, e.g. at the tendon's toe) plus 1e-7 relative: a wrong derivative stands out.
void expect_consistent_jet(const std::function<CurveJet(double)>& f, double a, double b,
                           std::initializer_list<double> kinks, const std::string& name) {
  const double h = 1e-5;
  int checked = 0;
  for (int i = 0; i <= 400; ++i) {
    const double x = a + (b - a) * i / 400.0;
    bool near_kink = false;
    for (double k : kinks) near_kink = near_kink || std::abs(x - k) < 2.0 * h;
    if (near_kink) continue;
    const auto fd = [&](double step, bool second) {
      const CurveJet lo = f(x - step), hi = f(x + step);
      return second ? (hi.derivative - lo.derivative) / (2.0 * step)
                    : (hi.value - lo.value) / (2.0 * step);
    };
    const CurveJet j = f(x);
    const double d1h = fd(h, false), d1 = fd(0.5 * h, false);
    const double d2h = fd(h, true), d2 = fd(0.5 * h, true);
    EXPECT_NEAR(j.derivative, d1, std::abs(d1h - d1) + 1e-7 * (1.0 + std::abs(d1)))
        << name << " at " << x;
    EXPECT_NEAR(j.second_derivative, d2, std::abs(d2h - d2) + 1e-7 * (1.0 + std::abs(d2)))
        << name << " at " << x;
    ++checked;
  }
  EXPECT_GT(checked, 380) << name;
}
}  // namespace

TEST(CurveJets, ThelenSecondDerivativesMatchDifferences) {
  ThelenCurveParameters p;
  p.FmaxTendonStrain = 0.033;  // gait2392's values
  p.KshapeActive = 0.5;
  p.KshapePassive = 4.0;
  const ThelenCurveConstants k = make_thelen_constants(p);
  expect_consistent_jet([&](double l) { return detail::thelen_active_jet(k, l); }, 0.3, 1.8, {},
                        "thelen active");
  expect_consistent_jet([&](double l) { return detail::thelen_passive_jet(k, l); }, 0.6, 1.9,
                        {1.0}, "thelen passive");
  expect_consistent_jet([&](double t) { return detail::thelen_tendon_jet(k, t); }, 0.99, 1.06,
                        {1.0, 1.0 + k.tendon_toe_strain}, "thelen tendon");
  // The jets are what the public functions return (same arithmetic).
  for (double l : {0.45, 0.9, 1.0, 1.2, 1.6}) {
    EXPECT_EQ(thelen_active_force_length(p, l).value, detail::thelen_active_jet(k, l).value);
    EXPECT_EQ(thelen_passive_force_length(p, k, l).derivative,
              detail::thelen_passive_jet(k, l).derivative);
  }
  // Thelen's toe/linear transition is C¹: the jet is continuous in value and slope there.
  const double t_lin = 1.0 + k.tendon_toe_strain;
  const CurveJet below = detail::thelen_tendon_jet(k, std::nextafter(t_lin, 0.0));
  const CurveJet above = detail::thelen_tendon_jet(k, std::nextafter(t_lin, 2.0));
  EXPECT_NEAR(below.value, above.value, 1e-12);
  EXPECT_NEAR(below.derivative, above.derivative, 1e-6 * above.derivative);
}

TEST(CurveJets, DeGrooteSecondDerivativesMatchDifferences) {
  DeGrooteCurveParameters p;
  const DeGrooteCurveConstants k = make_degroote_constants(p);
  expect_consistent_jet([&](double l) { return detail::degroote_active_jet(p, l); }, 0.3, 1.8, {},
                        "degroote active");
  p.active_force_width_scale = 1.3;
  expect_consistent_jet([&](double l) { return detail::degroote_active_jet(p, l); }, 0.3, 1.8, {},
                        "degroote active, wider");
  expect_consistent_jet([&](double l) { return detail::degroote_passive_jet(p, k, l); }, 0.2, 1.8,
                        {}, "degroote passive");
  expect_consistent_jet([&](double t) { return detail::degroote_tendon_jet(k, t); }, 0.98, 1.06,
                        {}, "degroote tendon");
}

TEST(CurveJets, MillardBezierJetsMatchDifferencesAndCalc) {
  const MillardCurves c = make_millard_curves(MillardCurveParameters{});
  const struct {
    const SmoothSegmentedCurve* curve;
    const char* name;
  } curves[] = {{&c.active_force_length, "active"},
                {&c.passive_force_length, "passive"},
                {&c.tendon_force_length, "tendon"},
                {&c.force_velocity, "force-velocity"}};
  for (const auto& [curve, name] : curves) {
    const double a = curve->get_x_begin() - 0.05, b = curve->get_x_end() + 0.05;
    expect_consistent_jet([&](double x) { return curve->calc_jet(x); }, a, b, {}, name);
    for (int i = 0; i <= 200; ++i) {
      const double x = a + (b - a) * i / 200.0;
      const CurveJet j = curve->calc_jet(x);
      const CurvePoint p = curve->calc(x);
      EXPECT_NEAR(j.value, p.value, 1e-14 * (1.0 + std::abs(p.value))) << name << " at " << x;
      EXPECT_NEAR(j.derivative, p.derivative, 1e-12 * (1.0 + std::abs(p.derivative)))
          << name << " at " << x;
    }
  }
}

// The integral next to a located jet (the equilibrium's energies: the closed form at the solved
// Bezier parameter plus the Taylor integral over the solver's last, unevaluated step) equals the
// direct closed form; steps of 1e-9..1e-5 (past the 1e-4-of-a-segment limit it falls back).
TEST(CurveJets, MillardIntegralNearLocatedJetEqualsClosedForm) {
  const MillardCurves c = make_millard_curves(MillardCurveParameters{});
  for (const SmoothSegmentedCurve* curve : {&c.passive_force_length, &c.tendon_force_length}) {
    const double a = curve->get_x_begin() - 0.05, b = curve->get_x_end() + 0.05;
    for (int i = 0; i <= 300; ++i) {
      const double x0 = a + (b - a) * i / 300.0;
      SmoothSegmentedCurve::Location at;
      const CurveJet j0 = curve->calc_jet(x0, at);
      EXPECT_EQ(at.x, x0);
      for (double d : {0.0, 1e-9, -3e-7, 2e-6, -1e-5}) {
        // the jet as a Taylor step leaves it: value moved to x0 + d, derivatives from x0
        CurveJet j = j0;
        j.value += d * (j0.derivative + 0.5 * d * j0.second_derivative);
        const double exact = curve->calc_integral(x0 + d);
        EXPECT_NEAR(curve->calc_integral_near(at, j, x0 + d), exact, 1e-15 * (1.0 + std::abs(exact)))
            << "x0 " << x0 << " d " << d;
      }
    }
  }
}

// The last Newton step of the static equilibrium is taken without re-evaluating the curves (their
// values are advanced by second-order Taylor expansions): the reported multipliers and forces
// must still be those of the curves at the reported lengths.
TEST(CurveJets, EquilibriumOutputsEqualFreshCurveValues) {
  for (MuscleModel model :
       {MuscleModel::thelen2003, MuscleModel::millard2012, MuscleModel::degroote2016}) {
    MuscleParameters p = default_muscle_parameters(model);
    p.name = "fresh";
    p.max_isometric_force_N = 1000.0;
    p.optimal_fiber_length_m = 0.08;
    p.tendon_slack_length_m = 0.2;
    p.pennation_at_optimal_rad = 0.3;
    const Musculotendon m = compile_musculotendon(p);
    int solved = 0;
    for (double a : {0.02, 0.3, 1.0}) {
      for (double lMT = 0.21; lMT < 0.36; lMT += 0.0013) {
        const MuscleOutputs o = calc_static_equilibrium(m, a, lMT);
        if (o.fiber_at_lower_bound || o.tendon_length_m <= p.tendon_slack_length_m) continue;
        const double l = o.fiber_length_m / p.optimal_fiber_length_m;
        const double t = o.tendon_length_m / p.tendon_slack_length_m;
        const std::string where = std::string(to_string(model)) + " a=" + std::to_string(a) +
                                  " lMT=" + std::to_string(lMT);
        EXPECT_NEAR(o.active_force_length_multiplier, calc_active_force_length(m, l).value, 1e-13)
            << where;
        EXPECT_NEAR(o.passive_force_multiplier, calc_passive_force_length(m, l).value, 1e-13)
            << where;
        EXPECT_NEAR(o.norm_tendon_force, calc_tendon_force_length(m, t).value, 1e-13) << where;
        // Equilibrium itself, to the solver's tolerance (1e-13 F0) plus rounding.
        EXPECT_NEAR(o.fiber_force_along_tendon_N, o.tendon_force_N, 2e-13 * p.max_isometric_force_N)
            << where;
        ++solved;
      }
    }
    EXPECT_GT(solved, 200) << to_string(model);
  }
}
