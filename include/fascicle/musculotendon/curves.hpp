// Normalised Hill-model curves of OpenSim 4.5's Thelen2003Muscle, Millard2012EquilibriumMuscle and
// DeGrooteFregly2016Muscle, each with its analytic first derivative and its integral (the
// normalised elastic energy). Lengths are normalised by l0 (fibre) or lTs (tendon), velocities by
// l0·vmax (negative = shortening), forces by F0. Pure functions: no model, no state.
#pragma once

#include "fascicle/musculotendon/parameters.hpp"

#include <array>
#include <vector>

namespace fascicle {

// A curve sample: y(x) and dy/dx.
struct CurvePoint {
  double value = 0.0;
  double derivative = 0.0;
};
// A curve sample with its second derivative d²y/dx² too (for second-order solvers).
struct CurveJet {
  double value = 0.0;
  double derivative = 0.0;
  double second_derivative = 0.0;
};

// ---------------------------------------------------------------- Thelen 2003 (OpenSim form)
// Active force-length: exp(-(l-1)²/KshapeActive).
CurvePoint thelen_active_force_length(const ThelenCurveParameters& p, double norm_fiber_length);
// Passive force-length: (exp(kPE(l-1)/e0) - 1)/(exp(kPE) - 1) for l > 1, else 0.
CurvePoint thelen_passive_force_length(const ThelenCurveParameters& p, double norm_fiber_length);
// ∫_1^l f_PE dl' (normalised passive energy, F0·l0 units).
double thelen_passive_force_length_integral(const ThelenCurveParameters& p, double norm_fiber_length);
// Tendon: exponential toe (kToe = 3, Ftoe = 0.33) then linear, in tendon strain ε = lT/lTs - 1.
CurvePoint thelen_tendon_force_length(const ThelenCurveParameters& p, double norm_tendon_length);
// ∫_1^lT f_T dl' (normalised tendon energy, F0·lTs units).
double thelen_tendon_force_length_integral(const ThelenCurveParameters& p, double norm_tendon_length);
// Strain at the end of the toe region, 99 e0 e³/(166 e³ − 67), and the linear stiffness
// 67/(100 (e0 − ε_toe)) (OpenSim's exact forms of Thelen's rounded 0.609 e0 and 1.712/e0).
double thelen_tendon_toe_strain(double fmax_tendon_strain);
double thelen_tendon_linear_stiffness(double fmax_tendon_strain);
// OpenSim Thelen2003Muscle::calcdlceN: normalised fibre velocity (l0·vmax units) at which the
// fibre develops the active force a·fal·fv, with the linear extrapolations of OpenSim.
double thelen_norm_fiber_velocity(const ThelenCurveParameters& p, double activation, double fal,
                                  double active_force_norm);
// Its inverse: fv(v; a) (value, ∂fv/∂v). fv is independent of fal.
CurvePoint thelen_force_velocity(const ThelenCurveParameters& p, double activation,
                                 double norm_fiber_velocity);

// Parameter-only constants of the Thelen curves, computed once per muscle (the functions above
// recompute them; the overloads below take them and give bit-identical results, faster).
struct ThelenCurveConstants {
  double passive_den = 0.0;           // exp(KshapePassive) − 1
  double tendon_toe_strain = 0.0;     // thelen_tendon_toe_strain(FmaxTendonStrain)
  double tendon_linear_stiffness = 0.0;
  // Reciprocals and rates, so that the curves need no division (filled by make_thelen_constants).
  double active_rate = 0.0;           // 1/KshapeActive
  double passive_rate = 0.0;          // KshapePassive/FmaxMuscleStrain
  double inv_passive_den = 0.0;       // 1/passive_den
  double tendon_toe_rate = 0.0;       // kToe/ε_toe
  double tendon_toe_scale = 0.0;      // Ftoe/(exp(kToe) − 1)
};
ThelenCurveConstants make_thelen_constants(const ThelenCurveParameters& p);
CurvePoint thelen_passive_force_length(const ThelenCurveParameters& p, const ThelenCurveConstants& k,
                                       double norm_fiber_length);
double thelen_passive_force_length_integral(const ThelenCurveParameters& p,
                                            const ThelenCurveConstants& k, double norm_fiber_length);
CurvePoint thelen_tendon_force_length(const ThelenCurveConstants& k, double norm_tendon_length);
double thelen_tendon_force_length_integral(const ThelenCurveConstants& k, double norm_tendon_length);

// ---------------------------------------------------------------- Millard 2012 (quintic Bézier)
// A C²-continuous curve of quintic Bézier segments, extrapolated linearly outside (OpenSim's
// SmoothSegmentedFunction). Built once; evaluation solves x(u) = x for the Bézier parameter u.
// Fast path (built by the constructor): each segment keeps x(u), y(u) and ∫y dx in power form
// and a table of u at equally spaced x with du/dx, so a cubic-Hermite guess for u is typically
// within 1e-9 and one or two bracketed Newton steps reach machine precision.
class SmoothSegmentedCurve {
 public:
  struct Segment {
    std::array<double, 6> x{};  // control-point abscissae (increasing)
    std::array<double, 6> y{};  // control-point ordinates
  };
  static constexpr int kTableIntervals = 64;  // per segment, uniform in x
  SmoothSegmentedCurve() = default;
  // dydx_left/right: slopes of the linear extrapolations (OpenSim's dydx0 / dydx1).
  SmoothSegmentedCurve(std::vector<Segment> segments, double dydx_left, double dydx_right);

  // Where calc_jet found its x: the segment (−1 / size() on the left / right extrapolation) and
  // the Bézier parameter, so a caller can take the integral there without a second solve.
  struct Location {
    int segment = -1;
    double u = 0.0, x = 0.0;
  };
  CurvePoint calc(double x) const;
  // y, dy/dx and d²y/dx² (zero on the linear extrapolations) in one solve for u; `where`
  // receives the location.
  CurveJet calc_jet(double x) const;
  CurveJet calc_jet(double x, Location& where) const;
  // ∫_{x_begin}^{x} y dx for x next to a location found by calc_jet, given the jet at x (value at
  // x, derivatives at where.x — as a solver's Taylor step leaves them): the closed form at
  // where.u plus the third-order Taylor integral over the step (exact to rounding for steps below
  // 1e-4 of the segment); falls back to calc_integral for longer steps and the extrapolations.
  double calc_integral_near(const Location& where, const CurveJet& jet, double x) const;
  double calc_value(double x) const { return calc(x).value; }
  // ∫_{x_begin}^{x} y dx (exact: the degree-9 polynomial y(u)·x'(u) integrated in closed form).
  double calc_integral(double x) const;
  // x such that y(x) = y, for curves that are strictly increasing (bisection-safeguarded Newton).
  double calc_inverse(double y) const;
  // A cheap estimate of calc_inverse(y) (linear interpolation in a table built for curves whose
  // control ordinates never decrease; exact on the linear extrapolations), for starting solvers.
  // Falls back to calc_inverse for other curves.
  double calc_inverse_estimate(double y) const;
  double get_x_begin() const { return segments_.front().x[0]; }
  double get_x_end() const { return segments_.back().x[5]; }
  const std::vector<Segment>& get_segments() const { return segments_; }
  bool empty() const { return segments_.empty(); }

 private:
  // One segment in power form about both ends (each used on its half, for accuracy where the
  // curve flattens): x(u) = x0 + Σ_{k≥1} ax0[k] u^k = x5 + Σ ax1[k] w^k with w = 1 − u, the same
  // for y; ∫_0^u y x' du = Σ ai0[k] u^k = total + Σ ai1[k] w^k; table_*[j] = (u, du/dx) at
  // x0 + j (x5 − x0)/kTableIntervals.
  struct Fast {
    double x0 = 0, x5 = 0, y0 = 0, y5 = 0, inv_dx = 0, dx = 0, total = 0;
    std::array<double, 6> ax0{}, ay0{}, ax1{}, ay1{};
    std::array<double, 11> ai0{}, ai1{};
    std::array<double, kTableIntervals + 1> table_u{};
    // Cubic Hermite guess on table interval j: u ≈ Σ guess[j][k] s^k, s ∈ [0, 1] across it.
    std::array<std::array<double, 4>, kTableIntervals> guess{};
    // The jet's coefficients per end (0: in u, 1: in w = 1 − u), interleaved (x, y) pairs so
    // both polynomials are evaluated in one SIMD Horner chain: d⁰ a_1..a_5, d¹ k a_k (k = 1..5),
    // d² k(k−1) a_k (k = 2..5), d³ k(k−1)(k−2) a_k (k = 3..5); the odd derivatives of end 1
    // negated (d/du = −d/dw). The products are the ones poly5_du* form, so results are the same.
    alignas(16) std::array<double, 34> jet0{}, jet1{};
  };
  template <bool kLocate>
  CurveJet calc_jet_impl(double x, Location* where) const;
  double solve_u(const Fast& f, double x) const;
  double guess_u(const Fast& f, double x, double& lo, double& hi) const;
  int find_segment(double x) const;  // -1 left of the curve, size() right of it

  std::vector<Segment> segments_;
  std::vector<Fast> fast_;
  std::vector<double> integral_at_start_;  // ∫ from x_begin to each segment's start
  std::vector<double> segment_ends_;       // x at each segment's end (contiguous, for lookup)
  double x_begin_ = 0.0;
  std::vector<double> inverse_x_;           // x at equally spaced y (monotone curves only)
  double inverse_y0_ = 0.0, inverse_inv_dy_ = 0.0;
  double dydx_left_ = 0.0, dydx_right_ = 0.0;
};

// Corner control points between (x0, y0, slope dydx0) and (x1, y1, dydx1), curviness c ∈ [0, 1]
// scaled to 0.1 + 0.8 c (SegmentedQuinticBezierToolkit::calcQuinticBezierCornerControlPoints).
// Throws bad_input when the two lines do not form a "C"-shaped corner.
SmoothSegmentedCurve::Segment make_bezier_corner(double x0, double y0, double dydx0, double x1,
                                                 double y1, double dydx1, double curviness);

// The four curves of a Millard muscle, built from its parameters exactly as OpenSim 4.5's
// SmoothSegmentedFunctionFactory does.
struct MillardCurves {
  SmoothSegmentedCurve active_force_length;
  SmoothSegmentedCurve force_velocity;
  SmoothSegmentedCurve passive_force_length;
  SmoothSegmentedCurve tendon_force_length;
};
SmoothSegmentedCurve make_millard_active_force_length(const MillardCurveParameters& p);
SmoothSegmentedCurve make_millard_force_velocity(const MillardCurveParameters& p);
SmoothSegmentedCurve make_millard_passive_force_length(const MillardCurveParameters& p);
SmoothSegmentedCurve make_millard_tendon_force_length(const MillardCurveParameters& p);
MillardCurves make_millard_curves(const MillardCurveParameters& p);

// ---------------------------------------------------------------- De Groote et al. 2016
// Active force-length: sum of three Gaussian-like terms (widths scaled by active_force_width_scale).
CurvePoint degroote_active_force_length(const DeGrooteCurveParameters& p, double norm_fiber_length);
// Passive: (exp(kPE (l−1)/e0) − exp(kPE (0.2−1)/e0)) / (exp(kPE) − exp(kPE (0.2−1)/e0)), kPE = 4.
CurvePoint degroote_passive_force_length(const DeGrooteCurveParameters& p, double norm_fiber_length);
double degroote_passive_force_length_integral(const DeGrooteCurveParameters& p,
                                              double norm_fiber_length);  // ∫ from l = 0.2
// Tendon: c1 exp(kT (lT − c2)) − c3 with c1 = 0.2, c2 = 1, c3 = 0.2, kT = ln(6)/εT.
CurvePoint degroote_tendon_force_length(const DeGrooteCurveParameters& p, double norm_tendon_length);
double degroote_tendon_force_length_integral(const DeGrooteCurveParameters& p,
                                             double norm_tendon_length);  // ∫ from lT = 1
double degroote_norm_tendon_length(const DeGrooteCurveParameters& p, double norm_tendon_force);
// Force-velocity: d1 ln(d2 v + d3 + sqrt((d2 v + d3)² + 1)) + d4, and its closed-form inverse.
CurvePoint degroote_force_velocity(double norm_fiber_velocity);
double degroote_force_velocity_inverse(double fv);

// Parameter-only constants of the DeGroote curves (bit-identical overloads, as for Thelen).
struct DeGrooteCurveConstants {
  double passive_offset = 0.0;  // exp(kPE (0.2 − 1)/e0)
  double passive_den = 0.0;     // exp(kPE) − passive_offset
  double tendon_kT = 0.0;       // ln(6)/εT
};
DeGrooteCurveConstants make_degroote_constants(const DeGrooteCurveParameters& p);
CurvePoint degroote_passive_force_length(const DeGrooteCurveParameters& p,
                                         const DeGrooteCurveConstants& k, double norm_fiber_length);
double degroote_passive_force_length_integral(const DeGrooteCurveParameters& p,
                                              const DeGrooteCurveConstants& k,
                                              double norm_fiber_length);
CurvePoint degroote_tendon_force_length(const DeGrooteCurveConstants& k, double norm_tendon_length);
double degroote_tendon_force_length_integral(const DeGrooteCurveConstants& k,
                                             double norm_tendon_length);
double degroote_norm_tendon_length(const DeGrooteCurveConstants& k, double norm_tendon_force);

}  // namespace fascicle
