// The fast quintic-Bézier evaluation (power form + tabulated Hermite guess for the Bézier
// parameter) against the previous implementation, kept here verbatim as the reference: Bernstein
// evaluation and Newton on u from a linear guess to machine precision, integrals by 5-point
// Gauss-Legendre. Values, slopes and integrals must agree to 1e-12 relative at many points.
#include "fascicle/musculotendon/curves.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>

using namespace fascicle;

namespace {
using Segment = SmoothSegmentedCurve::Segment;

double ref_bezier(const std::array<double, 6>& p, double u) {
  constexpr double kBinom5[6] = {1, 5, 10, 10, 5, 1};
  const double w = 1.0 - u;
  double upow[6], wpow[6];
  upow[0] = wpow[0] = 1.0;
  for (int i = 1; i < 6; ++i) {
    upow[i] = upow[i - 1] * u;
    wpow[i] = wpow[i - 1] * w;
  }
  double s = 0.0;
  for (int i = 0; i < 6; ++i) s += kBinom5[i] * upow[i] * wpow[5 - i] * p[i];
  return s;
}

double ref_bezier_du(const std::array<double, 6>& p, double u) {
  constexpr double kBinom4[5] = {1, 4, 6, 4, 1};
  const double w = 1.0 - u;
  double upow[5], wpow[5];
  upow[0] = wpow[0] = 1.0;
  for (int i = 1; i < 5; ++i) {
    upow[i] = upow[i - 1] * u;
    wpow[i] = wpow[i - 1] * w;
  }
  double s = 0.0;
  for (int i = 0; i < 5; ++i) s += kBinom4[i] * upow[i] * wpow[4 - i] * (p[i + 1] - p[i]);
  return 5.0 * s;
}

double ref_solve_u(const Segment& s, double x) {
  double lo = 0.0, hi = 1.0;
  double u = std::clamp((x - s.x[0]) / (s.x[5] - s.x[0]), 0.0, 1.0);
  for (int it = 0; it < 100; ++it) {
    const double f = ref_bezier(s.x, u) - x;
    if (f == 0.0) return u;
    if (f < 0.0) lo = u; else hi = u;
    if (hi - lo <= 4.0 * std::numeric_limits<double>::epsilon()) break;
    const double d = ref_bezier_du(s.x, u);
    double next = (d > 0.0) ? u - f / d : 0.5 * (lo + hi);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    if (std::abs(next - u) <= 1e-16) { u = next; break; }
    u = next;
  }
  return u;
}

double ref_segment_integral(const Segment& s, double u) {
  constexpr double kNodes[5] = {-0.9061798459386640, -0.5384693101056831, 0.0, 0.5384693101056831,
                                0.9061798459386640};
  constexpr double kWeights[5] = {0.2369268850561891, 0.4786286704993665, 0.5688888888888889,
                                  0.4786286704993665, 0.2369268850561891};
  double sum = 0.0;
  for (int i = 0; i < 5; ++i) {
    const double t = 0.5 * u * (kNodes[i] + 1.0);
    sum += kWeights[i] * ref_bezier(s.y, t) * ref_bezier_du(s.x, t);
  }
  return 0.5 * u * sum;
}

struct Ref {
  double value, derivative, integral;
};

// Previous SmoothSegmentedCurve::calc and calc_integral (inside the curve's knots).
Ref ref_eval(const std::vector<Segment>& segs, double x) {
  double before = 0.0;
  for (const Segment& s : segs) {
    if (x <= s.x[5]) {
      const double u = ref_solve_u(s, x);
      return {ref_bezier(s.y, u), ref_bezier_du(s.y, u) / ref_bezier_du(s.x, u),
              before + ref_segment_integral(s, u)};
    }
    before += ref_segment_integral(s, 1.0);
  }
  return {NAN, NAN, NAN};
}

// Agreement to 1e-12 relative (on a floor of 1e-3 for values and slopes near zero), beyond what
// a few-ulp change of x causes: the previous Bernstein evaluation of x(u) − x loses accuracy
// where x(u) is near a knot far from zero (e.g. the tendon curve just above lT = 1), the power
// form about the nearer end does not (checked against 128-bit arithmetic while developing).
void expect_same_as_reference(const SmoothSegmentedCurve& c, const char* name) {
  const double x0 = c.get_x_begin(), x1 = c.get_x_end();
  const auto check = [&](double x, double& worst_value, double& worst_slope, double& worst_integral) {
    const Ref r = ref_eval(c.get_segments(), x);
    const double h = 1e-7 * (x1 - x0);
    const double xa = std::max(x0, x - h), xb = std::min(x1, x + h);
    const double curvature = (ref_eval(c.get_segments(), xb).derivative -
                              ref_eval(c.get_segments(), xa).derivative) / (xb - xa);
    const double dx = 8.0 * std::numeric_limits<double>::epsilon() * std::abs(x);
    const CurvePoint p = c.calc(x);
    const double I = c.calc_integral(x);
    const auto excess = [](double got, double want, double floor, double allowance) {
      return std::max(0.0, std::abs(got - want) - allowance) / std::max(std::abs(want), floor);
    };
    worst_value = std::max(worst_value, excess(p.value, r.value, 1e-3, dx * std::abs(r.derivative)));
    worst_slope = std::max(worst_slope, excess(p.derivative, r.derivative, 1e-3, dx * std::abs(curvature)));
    worst_integral = std::max(worst_integral, excess(I, r.integral, 1e-6, dx * std::abs(r.value)));
  };
  double worst_value = 0, worst_slope = 0, worst_integral = 0;
  const int n = 4001;
  for (int i = 0; i < n; ++i) check(x0 + (x1 - x0) * i / (n - 1.0), worst_value, worst_slope, worst_integral);
  // Knots, just inside them and segment midpoints (table ends, both power forms).
  for (const Segment& s : c.get_segments()) {
    for (double x : {s.x[0], std::nextafter(s.x[0], 1e9), s.x[5], std::nextafter(s.x[5], -1e9),
                     0.5 * (s.x[0] + s.x[5])}) {
      check(x, worst_value, worst_slope, worst_integral);
    }
  }
  EXPECT_LE(worst_value, 1e-12) << name;
  EXPECT_LE(worst_slope, 1e-12) << name;
  EXPECT_LE(worst_integral, 1e-12) << name;
}
}  // namespace

TEST(MillardCurveReference, DefaultCurvesMatchPreviousImplementation) {
  MillardCurveParameters damped;
  damped.minimum_value = 0.0;
  damped.concentric_slope_at_vmax = 0.0;
  damped.eccentric_slope_at_vmax = 0.0;
  MillardCurveParameters undamped;  // OpenSim's undamped-mode adjustments
  undamped.minimum_value = 0.1;
  undamped.concentric_slope_at_vmax = 0.1;
  undamped.eccentric_slope_at_vmax = 0.1;
  for (const MillardCurveParameters& p : {damped, undamped}) {
    const MillardCurves c = make_millard_curves(p);
    expect_same_as_reference(c.active_force_length, "active");
    expect_same_as_reference(c.force_velocity, "force-velocity");
    expect_same_as_reference(c.passive_force_length, "passive");
    expect_same_as_reference(c.tendon_force_length, "tendon");
  }
}

TEST(MillardCurveReference, VariedParametersMatchPreviousImplementation) {
  // Sharper and flatter corners than the defaults (curviness 0 and 1), stiffer tendon.
  MillardCurveParameters p;
  p.concentric_curviness = 0.0;
  p.eccentric_curviness = 1.0;
  p.fiber_curviness = 0.0;
  p.tendon_curviness = 1.0;
  p.tendon_strain_at_one_norm_force = 0.033;
  p.tendon_stiffness_at_one_norm_force = 1.375 / 0.033;
  p.fiber_strain_at_one_norm_force = 0.5;
  p.fiber_stiffness_at_one_norm_force = 2.0 / 0.5;
  const MillardCurves c = make_millard_curves(p);
  expect_same_as_reference(c.force_velocity, "force-velocity");
  expect_same_as_reference(c.passive_force_length, "passive");
  expect_same_as_reference(c.tendon_force_length, "tendon");
}

TEST(MillardCurveReference, ExtrapolationAndIntegralBeyondTheKnots) {
  const MillardCurves c = make_millard_curves(MillardCurveParameters{});
  const SmoothSegmentedCurve& t = c.tendon_force_length;
  const double x_end = t.get_x_end(), k = 1.375 / 0.049;
  const double y_end = t.calc(x_end).value, I_end = t.calc_integral(x_end);
  EXPECT_NEAR(t.calc(x_end + 0.01).value, y_end + k * 0.01, 1e-14);
  EXPECT_NEAR(t.calc_integral(x_end + 0.01), I_end + y_end * 0.01 + 0.5 * k * 1e-4, 1e-15);
  EXPECT_EQ(t.calc(0.9).value, 0.0);
  EXPECT_EQ(t.calc_integral(0.9), 0.0);
}
