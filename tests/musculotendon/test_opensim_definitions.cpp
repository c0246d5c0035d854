// Definitions checked against OpenSim 4.5's sources (transcribed independently here as formulas):
// DeGrooteFregly2016Muscle's activation dynamics and its smoothing default, and
// Thelen2003Muscle::calcdlceN's linear force-velocity extrapolation beyond its thresholds.
#include "fascicle/musculotendon/curves.hpp"
#include "fascicle/musculotendon/muscle.hpp"
#include "fascicle/musculotendon/osim_parameters.hpp"

#include <gtest/gtest.h>
#include <pugixml.hpp>

#include <cmath>

using namespace fascicle;

namespace {
// DeGrooteFregly2016Muscle::computeStateVariableDerivatives:
//   f = ½ tanh(b (e − a)), z = 0.5 + 1.5 a, ȧ = [(f + ½)/(τa z) + (½ − f) z/τd] (e − a).
double opensim_degroote_rate(double b, double ta, double td, double a, double e) {
  const double f = 0.5 * std::tanh(b * (e - a));
  const double z = 0.5 + 1.5 * a;
  return ((f + 0.5) / (ta * z) + (0.5 - f) * z / td) * (e - a);
}

// Thelen2003Muscle::calcdlceN written in OpenSim's variables: Fm = a·fal·fv, afl = a·fal, the
// concentric asymptote 0 and the eccentric threshold asyE_thresh·Flen·afl; beyond them the
// velocity continues along the tangent dlceN/dFm taken at the threshold.
double opensim_thelen_dlceN(const ThelenCurveParameters& p, double act, double fal, double Fm) {
  const double af = p.Af, flen = p.Flen, afl = act * fal;
  const double c = 0.25 + 0.75 * act;
  const double asyE = afl * flen * p.fv_linear_extrap_threshold;
  const auto b_of = [&](double F) {
    return F <= afl ? afl + F / af : (2 + 2 / af) * (afl * flen - F) / (flen - 1);
  };
  const auto db_of = [&](double F) { return F <= afl ? 1 / af : -(2 + 2 / af) / (flen - 1); };
  if (Fm > 0 && Fm < asyE) return c * (Fm - afl) / b_of(Fm);
  const double F0 = Fm <= 0 ? 0.0 : asyE;
  const double b = b_of(F0), db = db_of(F0);
  const double dlce0 = c * (F0 - afl) / b;
  const double slope = c / b - c * (F0 - afl) / (b * b) * db;
  return dlce0 + slope * (Fm - F0);
}
}  // namespace

TEST(OpenSimDefinitions, DeGrooteActivationSmoothingDefaultIsOpenSims) {
  // OpenSim's property activation_dynamics_smoothing defaults to 0.1 (the published model).
  EXPECT_EQ(DeGrooteCurveParameters{}.activation_dynamics_smoothing, 0.1);
  EXPECT_EQ(ActivationParameters{}.smoothing, 0.1);
  MuscleParameters p = default_muscle_parameters(MuscleModel::degroote2016);
  EXPECT_EQ(p.degroote.activation_dynamics_smoothing, 0.1);
  EXPECT_EQ(p.activation_time_constant_s, 0.015);
  EXPECT_EQ(p.deactivation_time_constant_s, 0.060);
  const Musculotendon m = compile_musculotendon(p);
  for (double a : {0.0, 0.2, 0.7, 1.0}) {
    for (double u : {0.0, 0.1, 0.5, 1.0}) {
      const double expected = opensim_degroote_rate(0.1, 0.015, 0.060, a, u);
      EXPECT_NEAR(calc_activation_rate(m, a, u), expected, 1e-12 * std::max(1.0, std::abs(expected)))
          << "a=" << a << " u=" << u;
    }
  }
  // As b → 0 the switch turns off (f → 0): the rate tends to the mean of the activation and
  // deactivation rates, [1/(2 τa z) + z/(2 τd)] (u − a); b = 10 approaches OpenSim's first-order
  // model instead (the recommended, non-default setting).
  ActivationParameters ap{0.015, 0.060, 0.0, 1e-9};
  const double mean = (0.5 / (0.015 * 0.8) + 0.5 * 0.8 / 0.060) * 0.8;
  EXPECT_NEAR(calc_activation_rate_degroote(ap, 0.2, 1.0), mean, 1e-8 * mean);
  ap.smoothing = 10.0;
  const double first_order = calc_activation_rate_opensim(ap, 0.2, 1.0);
  EXPECT_NEAR(calc_activation_rate_degroote(ap, 0.2, 1.0), first_order, 1e-3 * first_order);
}

TEST(OpenSimDefinitions, DeGrooteSmoothingFromOsimFile) {
  pugi::xml_document doc;
  ASSERT_TRUE(doc.load_string(R"(<DeGrooteFregly2016Muscle name="tib_ant">
      <max_isometric_force>900</max_isometric_force><optimal_fiber_length>0.098</optimal_fiber_length>
      <tendon_slack_length>0.223</tendon_slack_length><pennation_angle_at_optimal>0.087</pennation_angle_at_optimal>
    </DeGrooteFregly2016Muscle>)"));
  EXPECT_EQ(parse_osim_muscle(doc.first_child(), "inline.osim").degroote.activation_dynamics_smoothing, 0.1);
  doc.first_child().append_child("activation_dynamics_smoothing").text().set("10");
  EXPECT_EQ(parse_osim_muscle(doc.first_child(), "inline.osim").degroote.activation_dynamics_smoothing, 10.0);
}

TEST(OpenSimDefinitions, ThelenForceVelocityExtrapolationMatchesCalcdlceN) {
  // gait2392's Thelen values and OpenSim's C++ defaults.
  ThelenCurveParameters gait;
  gait.Af = 0.3;
  gait.Flen = 1.8;
  gait.KshapeActive = 0.5;
  for (const ThelenCurveParameters& p : {ThelenCurveParameters{}, gait}) {
    for (double act : {0.01, 0.3, 1.0}) {
      for (double fal : {0.2, 0.8, 1.0}) {
        const double afl = act * fal;
        const double T = p.fv_linear_extrap_threshold * p.Flen;
        // fv from far below 0 (concentric extrapolation) to far above the eccentric threshold.
        for (double fv : {-0.5, -0.05, 0.0, 0.3, 0.99, 1.0, 1.2, T - 1e-3, T, T + 1e-3, T + 0.2, 2.5}) {
          const double expected = opensim_thelen_dlceN(p, act, fal, afl * fv);
          const double v = thelen_norm_fiber_velocity(p, act, fal, afl * fv);
          EXPECT_NEAR(v, expected, 1e-12 * std::max(1.0, std::abs(expected)))
              << "a=" << act << " fal=" << fal << " fv=" << fv;
          // The inverse returns the same fv (also on the extrapolated lines).
          EXPECT_NEAR(thelen_force_velocity(p, act, v).value, fv, 1e-11) << "fv=" << fv;
        }
        // C¹ at the thresholds: one-sided slopes dv/dfv agree.
        for (double F : {0.0, T}) {
          const double h = 1e-7;
          const double left = (opensim_thelen_dlceN(p, act, fal, afl * F) -
                               opensim_thelen_dlceN(p, act, fal, afl * (F - h))) / h;
          const double right = (thelen_norm_fiber_velocity(p, act, fal, afl * (F + h)) -
                                thelen_norm_fiber_velocity(p, act, fal, afl * F)) / h;
          EXPECT_NEAR(left, right, 1e-5 * std::abs(right));
        }
      }
    }
  }
}
