// Normalised muscle curves. Sources: Thelen 2003 and OpenSim's Thelen2003Muscle; Millard et al.
// 2013 and OpenSim's SmoothSegmentedFunctionFactory (curve construction reproduced from its
// documented algorithm); De Groote et al. 2016 (Ann Biomed Eng 44:2922), appendix.
#include "fascicle/musculotendon/curves.hpp"

#include "curve_jets.hpp"

#include "fascicle/core/error.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>

namespace fascicle {

// ============================================================================ Thelen 2003
namespace {
CurvePoint first_two(const CurveJet& j) { return {j.value, j.derivative}; }
}  // namespace

CurvePoint thelen_active_force_length(const ThelenCurveParameters& p, double l) {
  ThelenCurveConstants k;  // only the Gaussian's rate is needed
  k.active_rate = 1.0 / p.KshapeActive;
  return first_two(detail::thelen_active_jet(k, l));
}

ThelenCurveConstants make_thelen_constants(const ThelenCurveParameters& p) {
  ThelenCurveConstants k;
  k.passive_den = std::exp(p.KshapePassive) - 1.0;
  k.tendon_toe_strain = thelen_tendon_toe_strain(p.FmaxTendonStrain);
  k.tendon_linear_stiffness = thelen_tendon_linear_stiffness(p.FmaxTendonStrain);
  k.active_rate = 1.0 / p.KshapeActive;
  k.passive_rate = p.KshapePassive / p.FmaxMuscleStrain;
  k.inv_passive_den = 1.0 / k.passive_den;
  k.tendon_toe_rate = detail::kThelenToeShape / k.tendon_toe_strain;
  k.tendon_toe_scale = detail::kThelenToeForce / std::expm1(detail::kThelenToeShape);
  return k;
}

CurvePoint thelen_passive_force_length(const ThelenCurveParameters&, const ThelenCurveConstants& c,
                                       double l) {
  return first_two(detail::thelen_passive_jet(c, l));
}

CurvePoint thelen_passive_force_length(const ThelenCurveParameters& p, double l) {
  return thelen_passive_force_length(p, make_thelen_constants(p), l);
}

double thelen_passive_force_length_integral(const ThelenCurveParameters& p,
                                            const ThelenCurveConstants& c, double l) {
  if (l <= 1.0) return 0.0;
  const double k = p.KshapePassive, e0 = p.FmaxMuscleStrain;
  return (e0 / k * std::expm1(k * (l - 1.0) / e0) - (l - 1.0)) / c.passive_den;
}

double thelen_passive_force_length_integral(const ThelenCurveParameters& p, double l) {
  return thelen_passive_force_length_integral(p, make_thelen_constants(p), l);
}

double thelen_tendon_toe_strain(double e0) {
  const double e3 = std::exp(3.0);
  return 99.0 * e0 * e3 / (166.0 * e3 - 67.0);
}

double thelen_tendon_linear_stiffness(double e0) {
  return 0.67 / (e0 - thelen_tendon_toe_strain(e0));
}

using detail::kThelenToeForce;
using detail::kThelenToeShape;

CurvePoint thelen_tendon_force_length(const ThelenCurveConstants& k, double lt) {
  return first_two(detail::thelen_tendon_jet(k, lt));
}

CurvePoint thelen_tendon_force_length(const ThelenCurveParameters& p, double lt) {
  return thelen_tendon_force_length(make_thelen_constants(p), lt);
}

double thelen_tendon_force_length_integral(const ThelenCurveConstants& k, double lt) {
  const double x = lt - 1.0;
  if (x <= 0.0) return 0.0;
  const double etoe = k.tendon_toe_strain, klin = k.tendon_linear_stiffness;
  const double c = kThelenToeForce / std::expm1(kThelenToeShape);
  const auto toe = [&](double e) {
    return c * (etoe / kThelenToeShape * std::expm1(kThelenToeShape * e / etoe) - e);
  };
  if (x <= etoe) return toe(x);
  const double d = x - etoe;
  // toe(etoe), with the constant expm1(kToe) folded at compile time.
  const double toe_end = c * (etoe / kThelenToeShape * std::expm1(kThelenToeShape) - etoe);
  return toe_end + 0.5 * klin * d * d + kThelenToeForce * d;
}

double thelen_tendon_force_length_integral(const ThelenCurveParameters& p, double lt) {
  return thelen_tendon_force_length_integral(make_thelen_constants(p), lt);
}

namespace {
// Thelen's normalised velocity as a function of fv = F/(a·fal) on its two hyperbolic branches,
// with derivative; c = 0.25 + 0.75 a scales vmax with activation (Thelen 2003, eq. 6).
struct ThelenFv {
  double c, Af, Flen, K, T;  // K = 2 + 2/Af, T = threshold·Flen
  double g(double fv) const {
    if (fv <= 1.0) return c * (fv - 1.0) / (1.0 + fv / Af);
    return c * (fv - 1.0) * (Flen - 1.0) / (K * (Flen - fv));
  }
  double dg(double fv) const {
    if (fv <= 1.0) {
      const double q = 1.0 + fv / Af;
      return c * (1.0 + 1.0 / Af) / (q * q);
    }
    const double q = Flen - fv;
    return c * (Flen - 1.0) * (Flen - 1.0) / (K * q * q);
  }
};
ThelenFv make_thelen_fv(const ThelenCurveParameters& p, double a) {
  return {0.25 + 0.75 * a, p.Af, p.Flen, 2.0 + 2.0 / p.Af, p.fv_linear_extrap_threshold * p.Flen};
}
}  // namespace

double thelen_norm_fiber_velocity(const ThelenCurveParameters& p, double a, double fal,
                                  double active_force_norm) {
  const ThelenFv t = make_thelen_fv(p, a);
  const double afl = a * fal;
  const double fv = active_force_norm / afl;
  if (fv < 0.0) return t.g(0.0) + t.dg(0.0) * fv;
  if (fv > t.T) return t.g(t.T) + t.dg(t.T) * (fv - t.T);
  return t.g(fv);
}

CurvePoint thelen_force_velocity(const ThelenCurveParameters& p, double a, double v) {
  if (v == 0.0) {
    // Isometric shortcut, the same arithmetic as the general path below at fv = 1.
    const double c = 0.25 + 0.75 * a, q = 1.0 + 1.0 / p.Af;
    return {1.0, 1.0 / (c * (1.0 + 1.0 / p.Af) / (q * q))};
  }
  const ThelenFv t = make_thelen_fv(p, a);
  double fv = 0.0;
  if (v < t.g(0.0)) {
    fv = (v - t.g(0.0)) / t.dg(0.0);
    return {fv, 1.0 / t.dg(0.0)};
  }
  if (v > t.g(t.T)) {
    fv = t.T + (v - t.g(t.T)) / t.dg(t.T);
    return {fv, 1.0 / t.dg(t.T)};
  }
  if (v <= 0.0) {
    fv = (t.c + v) / (t.c - v / t.Af);
  } else {
    const double m = t.c * (t.Flen - 1.0);
    fv = (v * t.K * t.Flen + m) / (m + v * t.K);
  }
  return {fv, 1.0 / t.dg(fv)};
}

// ============================================================================ Bézier curves
namespace {
constexpr double kBinom5[6] = {1, 5, 10, 10, 5, 1};

// Power-form coefficients a[k] (k = 1..5) of p(u) − p[0] for the quintic Bernstein polynomial with
// control values p: a_k = C(5,k) Σ_{i≤k} (−1)^{k−i} C(k,i) (p_i − p_0).
std::array<double, 6> power_form(const std::array<double, 6>& p) {
  constexpr double kBinom[6][6] = {{1, 0, 0, 0, 0, 0},  {1, 1, 0, 0, 0, 0},   {1, 2, 1, 0, 0, 0},
                                   {1, 3, 3, 1, 0, 0},  {1, 4, 6, 4, 1, 0},   {1, 5, 10, 10, 5, 1}};
  std::array<double, 6> a{};
  for (int k = 1; k <= 5; ++k) {
    double s = 0.0;
    for (int i = 1; i <= k; ++i) s += (((k - i) % 2) ? -1.0 : 1.0) * kBinom[k][i] * (p[i] - p[0]);
    a[k] = kBinom5[k] * s;
  }
  return a;
}

// Σ_{k=1..5} a[k] u^k and its derivative (Horner).
inline double poly5(const std::array<double, 6>& a, double u) {
  return ((((a[5] * u + a[4]) * u + a[3]) * u + a[2]) * u + a[1]) * u;
}
inline double poly5_du(const std::array<double, 6>& a, double u) {
  return (((5.0 * a[5] * u + 4.0 * a[4]) * u + 3.0 * a[3]) * u + 2.0 * a[2]) * u + a[1];
}
inline double poly5_du2(const std::array<double, 6>& a, double u) {
  return ((20.0 * a[5] * u + 12.0 * a[4]) * u + 6.0 * a[3]) * u + 2.0 * a[2];
}
inline double poly5_du3(const std::array<double, 6>& a, double u) {
  return (60.0 * a[5] * u + 24.0 * a[4]) * u + 6.0 * a[3];
}

// x(u) − x and dx/du of a segment in the power form about the nearer end.
struct XResidual {
  double f, d;
};
template <class Fast>
inline XResidual x_residual(const Fast& s, double u, double x) {
  if (u < 0.5) return {poly5(s.ax0, u) - (x - s.x0), poly5_du(s.ax0, u)};
  const double w = 1.0 - u;
  return {poly5(s.ax1, w) - (x - s.x5), -poly5_du(s.ax1, w)};
}

// u ∈ [lo, hi] with x(u) = x, for x(u) non-decreasing: Newton from `u`, safeguarded by
// bisection. Stops after a Newton step below 1e-9 or when the bracket has collapsed.
template <class Fast>
double newton_u(const Fast& s, double x, double u, double lo, double hi) {
  for (int it = 0; it < 100; ++it) {
    const XResidual r = x_residual(s, u, x);
    if (r.f == 0.0) return u;
    if (r.f < 0.0) lo = u; else hi = u;
    if (hi - lo <= 4.0 * std::numeric_limits<double>::epsilon()) break;
    if (r.d > 0.0) {
      const double step = r.f / r.d;
      // Converged: the error after this step is of order step² · x''/(2x') ≤ 1e-17.
      if (std::abs(step) <= 1e-9) return u - step;
      u -= step;
      if (!(u > lo && u < hi)) u = 0.5 * (lo + hi);
    } else {
      u = 0.5 * (lo + hi);
    }
  }
  return u;
}

// Power-form coefficients of ∫_0^t y(τ) x'(τ) dτ for y = y0 + Σ ay[k] τ^k, x = Σ ax[k] τ^k.
std::array<double, 11> integral_form(double y0, const std::array<double, 6>& ax,
                                     const std::array<double, 6>& ay) {
  std::array<double, 6> yc = ay;
  yc[0] = y0;
  std::array<double, 11> ai{};
  for (int k = 0; k <= 5; ++k) {
    for (int j = 0; j <= 4; ++j) ai[k + j + 1] += yc[k] * (j + 1) * ax[j + 1] / (k + j + 1);
  }
  return ai;
}

inline double poly10(const std::array<double, 11>& a, double t) {
  double v = 0.0;
  for (int k = 10; k >= 1; --k) v = (v + a[k]) * t;
  return v;
}
}  // namespace

SmoothSegmentedCurve::SmoothSegmentedCurve(std::vector<Segment> segments, double dydx_left,
                                           double dydx_right)
    : segments_(std::move(segments)), dydx_left_(dydx_left), dydx_right_(dydx_right) {
  constexpr int N = kTableIntervals;
  double acc = 0.0;
  fast_.reserve(segments_.size());
  for (const Segment& s : segments_) {
    Fast f;
    f.x0 = s.x[0];
    f.x5 = s.x[5];
    f.y0 = s.y[0];
    f.y5 = s.y[5];
    const auto reversed = [](const std::array<double, 6>& p) {
      return std::array<double, 6>{p[5], p[4], p[3], p[2], p[1], p[0]};
    };
    f.ax0 = power_form(s.x);
    f.ay0 = power_form(s.y);
    f.ax1 = power_form(reversed(s.x));
    f.ay1 = power_form(reversed(s.y));
    f.ai0 = integral_form(f.y0, f.ax0, f.ay0);
    f.ai1 = integral_form(f.y5, f.ax1, f.ay1);  // ∫_0^w y dx/dw = −∫_{1−w}^1 y x' du
    f.total = poly10(f.ai0, 1.0);
    const auto fill_jet = [](const std::array<double, 6>& ax, const std::array<double, 6>& ay,
                             double odd, std::array<double, 34>& c) {
      // (x, y) pair n of the block starting at pair b
      const auto put = [&c](int b, int n, double x, double y) {
        c[2 * (b + n)] = x;
        c[2 * (b + n) + 1] = y;
      };
      for (int k = 1; k <= 5; ++k) put(0, k - 1, ax[k], ay[k]);
      for (int k = 1; k <= 5; ++k) put(5, k - 1, odd * (k * ax[k]), odd * (k * ay[k]));
      for (int k = 2; k <= 5; ++k) {
        const double f2 = k * (k - 1);
        put(10, k - 2, f2 * ax[k], f2 * ay[k]);
      }
      for (int k = 3; k <= 5; ++k) {
        const double f3 = k * (k - 1) * (k - 2);
        put(14, k - 3, odd * (f3 * ax[k]), odd * (f3 * ay[k]));
      }
    };
    fill_jet(f.ax0, f.ay0, 1.0, f.jet0);
    fill_jet(f.ax1, f.ay1, -1.0, f.jet1);
    f.dx = (f.x5 - f.x0) / N;
    f.inv_dx = (f.dx > 0.0) ? 1.0 / f.dx : 0.0;
    std::array<double, N + 1> dudx{};
    for (int j = 0; j <= N; ++j) {
      const double xj = (j == N) ? f.x5 : f.x0 + j * f.dx;
      const double guess = (f.x5 > f.x0) ? (xj - f.x0) / (f.x5 - f.x0) : 0.0;
      const double u = (j == 0) ? 0.0 : (j == N) ? 1.0 : newton_u(f, xj, guess, 0.0, 1.0);
      const double d = x_residual(f, u, xj).d;
      f.table_u[j] = u;
      dudx[j] = (d > 0.0) ? 1.0 / d : 0.0;  // 0: a flatter guess; Newton still brackets it
    }
    for (int j = 0; j < N; ++j) {
      const double u0 = f.table_u[j], u1 = f.table_u[j + 1];
      const double m0 = dudx[j] * f.dx, m1 = dudx[j + 1] * f.dx;
      f.guess[j] = {u0, m0, 3.0 * (u1 - u0) - 2.0 * m0 - m1, 2.0 * (u0 - u1) + m0 + m1};
    }
    integral_at_start_.push_back(acc);
    acc += f.total;
    fast_.push_back(f);
    segment_ends_.push_back(f.x5);
  }
  integral_at_start_.push_back(acc);
  x_begin_ = segments_.empty() ? 0.0 : segments_.front().x[0];
  // Inverse table for monotone curves (non-decreasing control ordinates ⇒ non-decreasing y(x)).
  bool monotone = dydx_left_ >= 0.0 && dydx_right_ >= 0.0;
  for (const Segment& s : segments_) {
    for (int i = 0; i < 5; ++i) monotone = monotone && s.y[i + 1] >= s.y[i];
  }
  const double y_begin = segments_.front().y[0], y_end = segments_.back().y[5];
  if (monotone && y_end > y_begin) {
    constexpr int M = 64;
    inverse_y0_ = y_begin;
    inverse_inv_dy_ = M / (y_end - y_begin);
    inverse_x_.resize(M + 1);
    for (int j = 0; j <= M; ++j) {
      inverse_x_[j] = (j == 0) ? get_x_begin() : (j == M) ? get_x_end()
                                                           : calc_inverse(y_begin + j / inverse_inv_dy_);
    }
  }
}

double SmoothSegmentedCurve::calc_inverse_estimate(double y) const {
  if (inverse_x_.empty()) return calc_inverse(y);
  const int M = static_cast<int>(inverse_x_.size()) - 1;
  const double t = (y - inverse_y0_) * inverse_inv_dy_;
  if (!(t > 0.0)) {  // also NaN: no integer conversion of it below
    return dydx_left_ > 0.0 ? get_x_begin() + (y - inverse_y0_) / dydx_left_ : get_x_begin();
  }
  if (t >= M) {
    const double y_end = segments_.back().y[5];
    return dydx_right_ > 0.0 ? get_x_end() + (y - y_end) / dydx_right_ : get_x_end();
  }
  const int j = static_cast<int>(t);
  const double s = t - j;
  return inverse_x_[j] + s * (inverse_x_[j + 1] - inverse_x_[j]);
}

[[gnu::always_inline]] inline double SmoothSegmentedCurve::guess_u(const Fast& f, double x, double& lo,
                                                                  double& hi) const {
  constexpr int N = kTableIntervals;
  const double t = std::clamp((x - f.x0) * f.inv_dx, 0.0, static_cast<double>(N));
  const int j = std::min(static_cast<int>(t), N - 1);
  const double s = t - j;
  const std::array<double, 4>& c = f.guess[j];
  const double u = c[0] + s * (c[1] + s * (c[2] + s * c[3]));
  lo = std::max(0.0, f.table_u[j] - 1e-12);
  hi = std::min(1.0, f.table_u[j + 1] + 1e-12);
  return std::clamp(u, lo, hi);
}

// The tabulated cubic-Hermite guess (bracketed by its table interval, widened by a hair for
// the rounding of its end points), then one Chebyshev step on x(u) = x when the Newton step
// from the guess is below 1e-7 (u error O(δ³) < 1e-20), else bracketed Newton.
double SmoothSegmentedCurve::solve_u(const Fast& f, double x) const {
  double lo = 0.0, hi = 1.0;
  const double u = guess_u(f, x, lo, hi);
  double r = 0.0, d = 0.0, d2 = 0.0;
  if (u < 0.5) {
    r = poly5(f.ax0, u) - (x - f.x0), d = poly5_du(f.ax0, u), d2 = poly5_du2(f.ax0, u);
  } else {
    const double w = 1.0 - u;
    r = poly5(f.ax1, w) - (x - f.x5), d = -poly5_du(f.ax1, w), d2 = poly5_du2(f.ax1, w);
  }
  if (d > 0.0) {
    const double dn = -r / d;
    if (std::abs(dn) <= 1e-7) return u + dn - 0.5 * d2 / d * dn * dn;
  }
  return newton_u(f, x, u, lo, hi);
}

[[gnu::always_inline]] inline int SmoothSegmentedCurve::find_segment(double x) const {
  if (x < x_begin_) return -1;
  // (A branch-free count was tried: slower, the predicted branch lets the solve start early.)
  const int n = static_cast<int>(segment_ends_.size());
  const double* ends = segment_ends_.data();
  for (int i = 0; i < n; ++i) {
    if (x <= ends[i]) return i;
  }
  return n;
}

CurvePoint SmoothSegmentedCurve::calc(double x) const {
  const int i = find_segment(x);
  if (i < 0) return {fast_.front().y0 + dydx_left_ * (x - fast_.front().x0), dydx_left_};
  if (i >= static_cast<int>(fast_.size())) {
    return {fast_.back().y5 + dydx_right_ * (x - fast_.back().x5), dydx_right_};
  }
  const Fast& f = fast_[i];
  const double u = solve_u(f, x);
  if (u < 0.5) return {f.y0 + poly5(f.ay0, u), poly5_du(f.ay0, u) / poly5_du(f.ax0, u)};
  const double w = 1.0 - u;
  return {f.y5 + poly5(f.ay1, w), poly5_du(f.ay1, w) / poly5_du(f.ax1, w)};
}

namespace {
typedef double V2 __attribute__((vector_size(16)));
inline V2 load_pair(const double* p) {
  V2 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
}  // namespace

template <bool kLocate>
[[gnu::always_inline]] inline CurveJet SmoothSegmentedCurve::calc_jet_impl(double x,
                                                                          Location* where) const {
  const int i = find_segment(x);
  if constexpr (kLocate) *where = {i, 0.0, x};
  if (i < 0) return {fast_.front().y0 + dydx_left_ * (x - fast_.front().x0), dydx_left_, 0.0};
  if (i >= static_cast<int>(fast_.size())) {
    return {fast_.back().y5 + dydx_right_ * (x - fast_.back().x5), dydx_right_, 0.0};
  }
  const Fast& f = fast_[i];
  double lo = 0.0, hi = 1.0;
  double u = guess_u(f, x, lo, hi);
  // x(u) − x, y(u) and their first three u-derivatives at u, in the power form about the
  // nearer end (w = 1 − u; end 1's odd coefficients are stored negated), x and y as one SIMD
  // pair per Horner chain. The same operations as poly5, poly5_du, poly5_du2, poly5_du3.
  const auto at = [&f, x](double v, double* X, double* Y) __attribute__((always_inline)) {
    const bool near0 = v < 0.5;
    const double* c = near0 ? f.jet0.data() : f.jet1.data();
    const double w = near0 ? v : 1.0 - v;
    const V2 W = {w, w};
    V2 p0 = load_pair(c + 8);
    p0 = p0 * W + load_pair(c + 6);
    p0 = p0 * W + load_pair(c + 4);
    p0 = p0 * W + load_pair(c + 2);
    p0 = (p0 * W + load_pair(c + 0)) * W;
    V2 p1 = load_pair(c + 18);
    p1 = p1 * W + load_pair(c + 16);
    p1 = p1 * W + load_pair(c + 14);
    p1 = p1 * W + load_pair(c + 12);
    p1 = p1 * W + load_pair(c + 10);
    V2 p2 = load_pair(c + 26);
    p2 = p2 * W + load_pair(c + 24);
    p2 = p2 * W + load_pair(c + 22);
    p2 = p2 * W + load_pair(c + 20);
    V2 p3 = load_pair(c + 32);
    p3 = p3 * W + load_pair(c + 30);
    p3 = p3 * W + load_pair(c + 28);
    X[0] = p0[0] - (x - (near0 ? f.x0 : f.x5));
    Y[0] = (near0 ? f.y0 : f.y5) + p0[1];
    X[1] = p1[0], X[2] = p2[0], X[3] = p3[0];
    Y[1] = p1[1], Y[2] = p2[1], Y[3] = p3[1];
  };
  double X[4], Y[4];
  at(u, X, Y);
  double du = 0.0;
  bool taylor = false;
  // Two reciprocals, 1/x'(u) at the guess and 1/x'(u + δ), instead of four divisions: the
  // solver's critical path runs through this chain.
  double inv_x1 = 1.0 / X[1];
  if (X[1] > 0.0) {
    // One Chebyshev step on x(u) = x from the tabulated guess (typically |δ| < 1e-9): the u
    // error after it is O(δ³) (< 1e-20) and y, y', y'' follow from their Taylor expansions
    // about the guess to third order, so no second evaluation is needed.
    const double dn = -X[0] * inv_x1;
    if (std::abs(dn) <= 1e-7) {
      du = dn - 0.5 * X[2] * inv_x1 * dn * dn;
      taylor = true;
    }
  }
  if (!taylor) {
    u = newton_u(f, x, u, lo, hi);
    at(u, X, Y);
  }
  const double h = 0.5 * du;
  const double yu = Y[1] + du * (Y[2] + h * Y[3]), xu = X[1] + du * (X[2] + h * X[3]);
  const double yuu = Y[2] + du * Y[3], xuu = X[2] + du * X[3];
  const double inv_xu = 1.0 / xu;
  const double dydx = yu * inv_xu;
  if constexpr (kLocate) where->u = u + du;
  return {Y[0] + du * (Y[1] + h * (Y[2] + du * Y[3] / 3.0)), dydx,
          (yuu - dydx * xuu) * (inv_xu * inv_xu)};
}

CurveJet SmoothSegmentedCurve::calc_jet(double x) const { return calc_jet_impl<false>(x, nullptr); }

CurveJet SmoothSegmentedCurve::calc_jet(double x, Location& where) const {
  return calc_jet_impl<true>(x, &where);
}

double SmoothSegmentedCurve::calc_integral(double x) const {
  const int i = find_segment(x);
  if (i < 0) {
    const double d = x - fast_.front().x0;
    return fast_.front().y0 * d + 0.5 * dydx_left_ * d * d;
  }
  if (i >= static_cast<int>(fast_.size())) {
    const double d = x - fast_.back().x5;
    return integral_at_start_.back() + fast_.back().y5 * d + 0.5 * dydx_right_ * d * d;
  }
  const Fast& f = fast_[i];
  const double u = solve_u(f, x);
  const double within = (u < 0.5) ? poly10(f.ai0, u) : f.total + poly10(f.ai1, 1.0 - u);
  return integral_at_start_[i] + within;
}

double SmoothSegmentedCurve::calc_integral_near(const Location& where, const CurveJet& jet,
                                                double x) const {
  const int i = where.segment;
  if (i < 0 || i >= static_cast<int>(fast_.size())) return calc_integral(x);
  const Fast& f = fast_[i];
  const double d = x - where.x;
  // the neglected term is y''' d⁴/24 ~ (d/width)³ d y: below rounding for d ≤ 1e-4 width
  if (!(std::abs(d) <= 1e-4 * (f.x5 - f.x0))) return calc_integral(x);
  const double u = where.u;
  const double at = integral_at_start_[i] + ((u < 0.5) ? poly10(f.ai0, u) : f.total + poly10(f.ai1, 1.0 - u));
  // y(where.x + t) = y0 + y' t + ½ y'' t², y(x) = jet.value: ∫ over the step = d (y − d (½ y' + ⅓ y'' d))
  return at + d * (jet.value - d * (0.5 * jet.derivative + jet.second_derivative * d / 3.0));
}

double SmoothSegmentedCurve::calc_inverse(double y) const {
  // Bracket in x (linear extrapolation beyond the ends), then safeguarded Newton.
  double lo = get_x_begin(), hi = get_x_end();
  double span = hi - lo;
  for (int i = 0; i < 60 && calc(lo).value > y; ++i) lo -= span, span *= 2.0;
  span = hi - lo;
  for (int i = 0; i < 60 && calc(hi).value < y; ++i) hi += span, span *= 2.0;
  double x = 0.5 * (lo + hi);
  for (int it = 0; it < 200; ++it) {
    const CurvePoint c = calc(x);
    const double f = c.value - y;
    if (f == 0.0) return x;
    if (f < 0.0) lo = x; else hi = x;
    if (hi - lo <= 1e-15 * std::max(1.0, std::abs(x))) break;
    double next = (c.derivative > 0.0) ? x - f / c.derivative : 0.5 * (lo + hi);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    x = next;
  }
  return x;
}

SmoothSegmentedCurve::Segment make_bezier_corner(double x0, double y0, double dydx0, double x1,
                                                 double y1, double dydx1, double curviness) {
  if (!(curviness >= 0.0 && curviness <= 1.0)) {
    throw_bad_input("Bezier corner curviness must be in [0, 1], got " + std::to_string(curviness));
  }
  const double c = 0.1 + 0.8 * curviness;
  // Intersection of the two tangent lines.
  const double xc = (std::abs(dydx0 - dydx1) > std::sqrt(std::numeric_limits<double>::epsilon()))
                        ? (y1 - y0 - x1 * dydx1 + x0 * dydx0) / (dydx0 - dydx1)
                        : 0.5 * (x0 + x1);
  const double yc = (xc - x1) * dydx1 + y1;
  const double a2 = (xc - x0) * (xc - x0) + (yc - y0) * (yc - y0);
  const double b2 = (xc - x1) * (xc - x1) + (yc - y1) * (yc - y1);
  const double c2 = (x1 - x0) * (x1 - x0) + (y1 - y0) * (y1 - y0);
  if (!(c2 > a2 && c2 > b2)) {
    throw_bad_input("curve parameters do not form a C-shaped Bezier corner between (" +
                        std::to_string(x0) + ", " + std::to_string(y0) + ") and (" +
                        std::to_string(x1) + ", " + std::to_string(y1) + ")",
                    {.suggestion = "check the slopes and strains of the Millard curve parameters"});
  }
  const double x0m = x0 + c * (xc - x0), y0m = y0 + c * (yc - y0);
  const double x1m = x1 + c * (xc - x1), y1m = y1 + c * (yc - y1);
  return {{x0, x0m, x0m, x1m, x1m, x1}, {y0, y0m, y0m, y1m, y1m, y1}};
}

SmoothSegmentedCurve make_millard_active_force_length(const MillardCurveParameters& p) {
  const double x0 = p.min_norm_active_fiber_length, x1 = p.transition_norm_fiber_length;
  const double x2 = 1.0, x3 = p.max_norm_active_fiber_length;
  const double ylow = p.minimum_value, dydx = p.shallow_ascending_slope;
  const double curviness = 1.0;  // fixed in OpenSim's ActiveForceLengthCurve
  // Five elbows: ascending limb, shallow plateau, shoulder, descending limb (OpenSim 4.x layout).
  const double xDelta = 0.05 * x2;
  const double xs = x2 - xDelta;
  const double y1 = 1.0 - dydx * (xs - x1);
  const double dydx01 = 1.25 * y1 / (x1 - x0);
  const double x01 = x0 + 0.5 * (x1 - x0), y01 = 0.5 * y1;
  const double x1s = x1 + 0.5 * (xs - x1), y1s = y1 + 0.5 * (1.0 - y1);
  const double x23 = (x2 + xDelta) + 0.5 * (x3 - (x2 + xDelta)), y23 = 0.5;
  const double dydx23 = -1.0 / ((x3 - xDelta) - (x2 + xDelta));
  std::vector<SmoothSegmentedCurve::Segment> s;
  s.push_back(make_bezier_corner(x0, ylow, 0.0, x01, y01, dydx01, curviness));
  s.push_back(make_bezier_corner(x01, y01, dydx01, x1s, y1s, dydx, curviness));
  s.push_back(make_bezier_corner(x1s, y1s, dydx, x2, 1.0, 0.0, curviness));
  s.push_back(make_bezier_corner(x2, 1.0, 0.0, x23, y23, dydx23, curviness));
  s.push_back(make_bezier_corner(x23, y23, dydx23, x3, ylow, 0.0, curviness));
  return SmoothSegmentedCurve(std::move(s), 0.0, 0.0);
}

SmoothSegmentedCurve make_millard_force_velocity(const MillardCurveParameters& p) {
  const double fmaxE = p.max_eccentric_velocity_force_multiplier;
  const double dC = p.concentric_slope_at_vmax, dNC = p.concentric_slope_near_vmax;
  const double dIso = p.isometric_slope;
  const double dE = p.eccentric_slope_at_vmax, dNE = p.eccentric_slope_near_vmax;
  const double xNC = -0.9, yNC = 0.5 * dNC * (xNC + 1.0) + 0.5 * dC * (xNC + 1.0);
  const double xNE = 0.9, yNE = fmaxE + 0.5 * dNE * (xNE - 1.0) + 0.5 * dE * (xNE - 1.0);
  std::vector<SmoothSegmentedCurve::Segment> s;
  s.push_back(make_bezier_corner(-1.0, 0.0, dC, xNC, yNC, dNC, p.concentric_curviness));
  s.push_back(make_bezier_corner(xNC, yNC, dNC, 0.0, 1.0, dIso, p.concentric_curviness));
  s.push_back(make_bezier_corner(0.0, 1.0, dIso, xNE, yNE, dNE, p.eccentric_curviness));
  s.push_back(make_bezier_corner(xNE, yNE, dNE, 1.0, fmaxE, dE, p.eccentric_curviness));
  return SmoothSegmentedCurve(std::move(s), dC, dE);
}

SmoothSegmentedCurve make_millard_passive_force_length(const MillardCurveParameters& p) {
  const double xZero = 1.0 + p.fiber_strain_at_zero_force;
  const double xIso = 1.0 + p.fiber_strain_at_one_norm_force;
  const double kLow = p.fiber_stiffness_at_low_force, kIso = p.fiber_stiffness_at_one_norm_force;
  const double deltaX = std::min(0.1 / kIso, 0.1 * (xIso - xZero));
  const double xLow = xZero + deltaX;
  const double xFoot = xZero + 0.5 * (xLow - xZero);
  const double yLow = kLow * (xLow - xFoot);
  std::vector<SmoothSegmentedCurve::Segment> s;
  s.push_back(make_bezier_corner(xZero, 0.0, 0.0, xLow, yLow, kLow, p.fiber_curviness));
  s.push_back(make_bezier_corner(xLow, yLow, kLow, xIso, 1.0, kIso, p.fiber_curviness));
  return SmoothSegmentedCurve(std::move(s), 0.0, kIso);
}

SmoothSegmentedCurve make_millard_tendon_force_length(const MillardCurveParameters& p) {
  const double eIso = p.tendon_strain_at_one_norm_force;
  const double kIso = p.tendon_stiffness_at_one_norm_force;
  const double fToe = p.tendon_norm_force_at_toe_end;
  const double xIso = 1.0 + eIso;
  const double xToe = (fToe - 1.0) / kIso + xIso;
  const double xFoot = 1.0 + (xToe - 1.0) / 10.0;
  const double yToeMid = 0.5 * fToe;
  const double xToeMid = (yToeMid - 1.0) / kIso + xIso;
  const double dydxToeMid = yToeMid / (xToeMid - xFoot);
  const double xToeCtrl = xFoot + 0.5 * (xToeMid - xFoot);
  const double yToeCtrl = dydxToeMid * (xToeCtrl - xFoot);
  std::vector<SmoothSegmentedCurve::Segment> s;
  s.push_back(make_bezier_corner(1.0, 0.0, 0.0, xToeCtrl, yToeCtrl, dydxToeMid, p.tendon_curviness));
  s.push_back(make_bezier_corner(xToeCtrl, yToeCtrl, dydxToeMid, xToe, fToe, kIso, p.tendon_curviness));
  return SmoothSegmentedCurve(std::move(s), 0.0, kIso);
}

MillardCurves make_millard_curves(const MillardCurveParameters& p) {
  return {make_millard_active_force_length(p), make_millard_force_velocity(p),
          make_millard_passive_force_length(p), make_millard_tendon_force_length(p)};
}

// ============================================================================ De Groote 2016
namespace {
using detail::kDeGrooteKPE;
constexpr double kDeGrooteMinFiber = 0.2;
constexpr double kC1 = detail::kDeGrooteC1, kC2 = detail::kDeGrooteC2, kC3 = detail::kDeGrooteC3;
constexpr double kD1 = -0.3211346127989808, kD2 = -8.149, kD3 = -0.374, kD4 = 0.8825327733249912;

double degroote_kT(const DeGrooteCurveParameters& p) {
  return std::log((1.0 + kC3) / kC1) / (1.0 + p.tendon_strain_at_one_norm_force - kC2);
}
}  // namespace

DeGrooteCurveConstants make_degroote_constants(const DeGrooteCurveParameters& p) {
  const double e0 = p.passive_fiber_strain_at_one_norm_force;
  const double offset = std::exp(kDeGrooteKPE * (kDeGrooteMinFiber - 1.0) / e0);
  return {offset, std::exp(kDeGrooteKPE) - offset, degroote_kT(p)};
}

CurvePoint degroote_active_force_length(const DeGrooteCurveParameters& p, double l) {
  return first_two(detail::degroote_active_jet(p, l));
}

CurvePoint degroote_passive_force_length(const DeGrooteCurveParameters& p,
                                         const DeGrooteCurveConstants& k, double l) {
  return first_two(detail::degroote_passive_jet(p, k, l));
}

CurvePoint degroote_passive_force_length(const DeGrooteCurveParameters& p, double l) {
  return degroote_passive_force_length(p, make_degroote_constants(p), l);
}

double degroote_passive_force_length_integral(const DeGrooteCurveParameters& p,
                                              const DeGrooteCurveConstants& k, double l) {
  const double e0 = p.passive_fiber_strain_at_one_norm_force;
  const double offset = k.passive_offset, den = k.passive_den;
  const auto prim = [&](double x) {
    return e0 / kDeGrooteKPE * std::exp(kDeGrooteKPE * (x - 1.0) / e0) - offset * x;
  };
  return (prim(l) - prim(kDeGrooteMinFiber)) / den;
}

double degroote_passive_force_length_integral(const DeGrooteCurveParameters& p, double l) {
  return degroote_passive_force_length_integral(p, make_degroote_constants(p), l);
}

CurvePoint degroote_tendon_force_length(const DeGrooteCurveConstants& k, double lt) {
  return first_two(detail::degroote_tendon_jet(k, lt));
}

CurvePoint degroote_tendon_force_length(const DeGrooteCurveParameters& p, double lt) {
  return degroote_tendon_force_length(make_degroote_constants(p), lt);
}

double degroote_tendon_force_length_integral(const DeGrooteCurveConstants& k, double lt) {
  const double kT = k.tendon_kT;
  const auto prim = [&](double x) { return kC1 / kT * std::exp(kT * (x - kC2)) - kC3 * x; };
  return prim(lt) - prim(1.0);
}

double degroote_tendon_force_length_integral(const DeGrooteCurveParameters& p, double lt) {
  return degroote_tendon_force_length_integral(make_degroote_constants(p), lt);
}

double degroote_norm_tendon_length(const DeGrooteCurveConstants& k, double f) {
  return kC2 + std::log((f + kC3) / kC1) / k.tendon_kT;
}

double degroote_norm_tendon_length(const DeGrooteCurveParameters& p, double f) {
  return kC2 + std::log((f + kC3) / kC1) / degroote_kT(p);
}

CurvePoint degroote_force_velocity(double v) {
  const double z = kD2 * v + kD3;
  const double r = std::sqrt(z * z + 1.0);
  return {kD1 * std::log(z + r) + kD4, kD1 * kD2 / r};
}

double degroote_force_velocity_inverse(double fv) {
  return (std::sinh((fv - kD4) / kD1) - kD3) / kD2;
}

}  // namespace fascicle
