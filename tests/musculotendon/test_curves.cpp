// Curve values at checkpoints (OpenSim's own checks), derivatives vs finite differences, integrals.
#include "fascicle/musculotendon/curves.hpp"
#include "fascicle/musculotendon/muscle.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>

using namespace fascicle;

namespace {
// Central difference with step h; returns the relative/absolute error against the analytic value.
void expect_derivative(const std::function<CurvePoint(double)>& f, double x, double tol,
                       const char* what) {
  const double h = 1e-6;
  const double fd = (f(x + h).value - f(x - h).value) / (2 * h);
  EXPECT_NEAR(f(x).derivative, fd, tol * std::max(1.0, std::abs(fd))) << what << " at x=" << x;
}
}  // namespace

TEST(ThelenCurves, TendonToeStrainAndStiffness) {
  EXPECT_NEAR(thelen_tendon_toe_strain(0.033), 0.0200843127, 1e-10);
  EXPECT_NEAR(thelen_tendon_linear_stiffness(0.033), 51.874901, 1e-6);
  ThelenCurveParameters p;
  p.FmaxTendonStrain = 0.033;
  // F_T(e0) = 1 by construction, continuity at the toe.
  EXPECT_NEAR(thelen_tendon_force_length(p, 1.033).value, 1.0, 1e-12);
  const double etoe = thelen_tendon_toe_strain(0.033);
  EXPECT_NEAR(thelen_tendon_force_length(p, 1 + etoe - 1e-12).value, 0.33, 1e-9);
}

TEST(ThelenCurves, DerivativesAndIntegrals) {
  ThelenCurveParameters p;
  for (double x : {0.5, 0.9, 1.0 + 1e-3, 1.2, 1.5, 1.7}) {
    expect_derivative([&](double l) { return thelen_active_force_length(p, l); }, x, 1e-7, "fal");
    expect_derivative([&](double l) { return thelen_passive_force_length(p, l); }, x, 1e-6, "fpe");
  }
  for (double x : {1.005, 1.02, 1.03, 1.05}) {
    expect_derivative([&](double l) { return thelen_tendon_force_length(p, l); }, x, 1e-6, "fT");
  }
  // Integral: d/dx ∫ = f.
  for (double x : {1.1, 1.4, 1.7}) {
    const double h = 1e-6;
    EXPECT_NEAR((thelen_passive_force_length_integral(p, x + h) -
                 thelen_passive_force_length_integral(p, x - h)) / (2 * h),
                thelen_passive_force_length(p, x).value, 1e-7);
  }
  for (double x : {1.01, 1.03, 1.06}) {
    const double h = 1e-7;
    EXPECT_NEAR((thelen_tendon_force_length_integral(p, x + h) -
                 thelen_tendon_force_length_integral(p, x - h)) / (2 * h),
                thelen_tendon_force_length(p, x).value, 1e-6);
  }
  // Force-velocity: fv(0) = 1, fv(-1) = 0 at a = 1, inverse of calcdlceN.
  EXPECT_NEAR(thelen_force_velocity(p, 1.0, 0.0).value, 1.0, 1e-15);
  EXPECT_NEAR(thelen_force_velocity(p, 1.0, -1.0).value, 0.0, 1e-15);
  for (double a : {0.1, 0.5, 1.0}) {
    for (double v : {-1.2, -0.8, -0.3, 0.0, 0.2, 0.5, 1.0}) {
      const double fv = thelen_force_velocity(p, a, v).value;
      EXPECT_NEAR(thelen_norm_fiber_velocity(p, a, 0.8, a * 0.8 * fv), v, 1e-12);
      // Thelen's F-V has a slope discontinuity at v = 0 (concentric vs eccentric hyperbola).
      if (v != 0.0) {
        expect_derivative([&](double x) { return thelen_force_velocity(p, a, x); }, v, 1e-6, "fv");
      }
    }
  }
}

TEST(MillardCurves, OpenSimIntegralChecks) {
  MillardCurveParameters p;
  const SmoothSegmentedCurve tendon = make_millard_tendon_force_length(p);
  const SmoothSegmentedCurve passive = make_millard_passive_force_length(p);
  // OpenSim's TendonForceLengthCurve / FiberForceLengthCurve tests: integral up to one normalised
  // force, relative 1e-4.
  const double x_tendon_one = tendon.calc_inverse(1.0);
  EXPECT_NEAR(x_tendon_one, 1.049, 1e-12);
  EXPECT_NEAR(tendon.calc_integral(x_tendon_one), 0.019800189393937052, 0.019800189393937052 * 1e-4);
  const double x_passive_one = passive.calc_inverse(1.0);
  EXPECT_NEAR(x_passive_one, 1.7, 1e-12);
  EXPECT_NEAR(passive.calc_integral(x_passive_one), 0.2109609995660500, 0.21096099956605 * 1e-4);
}

TEST(MillardCurves, ShapeAndDerivatives) {
  MillardCurveParameters p;
  const MillardCurves c = make_millard_curves(p);
  EXPECT_NEAR(c.active_force_length.calc_value(1.0), 1.0, 1e-14);
  EXPECT_NEAR(c.active_force_length.calc(1.0).derivative, 0.0, 1e-12);
  EXPECT_NEAR(c.active_force_length.calc_value(0.4441), 0.1, 1e-14);
  EXPECT_NEAR(c.active_force_length.calc_value(2.0), 0.1, 1e-14);
  EXPECT_NEAR(c.force_velocity.calc_value(0.0), 1.0, 1e-14);
  EXPECT_NEAR(c.force_velocity.calc(0.0).derivative, 5.0, 1e-12);
  EXPECT_NEAR(c.force_velocity.calc_value(-1.0), 0.0, 1e-14);
  EXPECT_NEAR(c.force_velocity.calc_value(1.0), 1.4, 1e-14);
  EXPECT_NEAR(c.passive_force_length.calc_value(1.0), 0.0, 1e-14);
  EXPECT_NEAR(c.passive_force_length.calc(1.7).derivative, 2.0 / 0.7, 1e-10);
  EXPECT_NEAR(c.tendon_force_length.calc(1.049).derivative, 1.375 / 0.049, 1e-9);
  for (double x : {0.3, 0.5, 0.6, 0.73, 0.9, 0.99, 1.1, 1.4, 1.7, 1.9}) {
    expect_derivative([&](double l) { return c.active_force_length.calc(l); }, x, 1e-6, "fal");
  }
  for (double x : {-1.1, -0.95, -0.5, -0.1, 0.1, 0.5, 0.95, 1.1}) {
    expect_derivative([&](double v) { return c.force_velocity.calc(v); }, x, 1e-6, "fv");
  }
  for (double x : {1.01, 1.05, 1.3, 1.65, 1.8}) {
    expect_derivative([&](double l) { return c.passive_force_length.calc(l); }, x, 1e-6, "fpe");
  }
  for (double x : {1.001, 1.01, 1.02, 1.04, 1.06}) {
    expect_derivative([&](double l) { return c.tendon_force_length.calc(l); }, x, 1e-6, "fT");
  }
  // Integral derivative = value (also across segment joins and in the extrapolated region).
  for (double x : {1.003, 1.03, 1.2, 1.69, 1.75}) {
    const double h = 1e-6;
    EXPECT_NEAR((c.passive_force_length.calc_integral(x + h) -
                 c.passive_force_length.calc_integral(x - h)) / (2 * h),
                c.passive_force_length.calc_value(x), 1e-8);
  }
}

TEST(DeGrooteCurves, PublishedValues) {
  DeGrooteCurveParameters p;
  EXPECT_NEAR(degroote_force_velocity(1.0).value, 1.794, 5e-4);
  EXPECT_NEAR(degroote_force_velocity(0.0).value, 1.0, 1e-3);
  EXPECT_NEAR(degroote_force_velocity(-1.0).value, 0.0, 1e-3);
  EXPECT_NEAR(degroote_passive_force_length(p, 1.0).value, 0.0182288, 1e-7);
  EXPECT_NEAR(degroote_tendon_force_length(p, 1.0).value, 0.0, 1e-15);
  EXPECT_NEAR(degroote_tendon_force_length(p, 1.049).value, 1.0, 1e-12);
  EXPECT_NEAR(degroote_active_force_length(p, 1.0).value, 1.0, 2e-3);
  for (double v : {-0.9, -0.2, 0.0, 0.4, 1.0}) {
    EXPECT_NEAR(degroote_force_velocity_inverse(degroote_force_velocity(v).value), v, 1e-12);
    expect_derivative([](double x) { return degroote_force_velocity(x); }, v, 1e-7, "fv");
  }
  for (double l : {0.5, 0.8, 1.0, 1.2, 1.6}) {
    expect_derivative([&](double x) { return degroote_active_force_length(p, x); }, l, 1e-7, "fal");
    expect_derivative([&](double x) { return degroote_passive_force_length(p, x); }, l, 1e-7, "fpe");
    const double h = 1e-6;
    EXPECT_NEAR((degroote_passive_force_length_integral(p, l + h) -
                 degroote_passive_force_length_integral(p, l - h)) / (2 * h),
                degroote_passive_force_length(p, l).value, 1e-8);
  }
  for (double t : {0.99, 1.0, 1.02, 1.05}) {
    expect_derivative([&](double x) { return degroote_tendon_force_length(p, x); }, t, 1e-7, "fT");
    EXPECT_NEAR(degroote_norm_tendon_length(p, degroote_tendon_force_length(p, t).value), t, 1e-12);
  }
}
