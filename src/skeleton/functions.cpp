// Scalar functions of one coordinate (see functions.hpp).
#include "fascicle/skeleton/functions.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include "fascicle/core/error.hpp"

namespace fascicle {
namespace {

void check_knots(const std::vector<double>& x, const std::vector<double>& y, std::size_t min_size,
                 const std::string& kind, const std::string& what) {
  ErrorContext ctx;
  ctx.object = what;
  if (x.size() != y.size())
    throw_bad_input(kind + ": x has " + std::to_string(x.size()) + " values but y has " +
                        std::to_string(y.size()), ctx);
  if (x.size() < min_size)
    throw_bad_input(kind + " needs at least " + std::to_string(min_size) + " points, got " +
                        std::to_string(x.size()), ctx);
  for (std::size_t i = 0; i < x.size(); ++i) {
    if (!std::isfinite(x[i]) || !std::isfinite(y[i]))
      throw_bad_input(kind + ": point " + std::to_string(i + 1) + " is not finite", ctx);
    if (i > 0 && !(x[i] > x[i - 1]))
      throw_bad_input(kind + ": x must increase strictly (point " + std::to_string(i + 1) + ")",
                      ctx);
  }
}

// Index k of the interval [x_k, x_k+1] containing t (t inside [x_0, x_n-1]).
std::size_t find_interval(const std::vector<double>& x, double t) {
  const auto it = std::upper_bound(x.begin(), x.end(), t);
  const std::size_t k = static_cast<std::size_t>(it - x.begin());
  return std::min(k == 0 ? 0 : k - 1, x.size() - 2);
}

// Solves the cubic-spline tridiagonal system and turns the second-derivative unknowns into the
// per-interval polynomial coefficients. `natural` selects zero end curvature; otherwise the end
// conditions match the third derivative at each end to that of the cubic through the four end
// points (Forsythe, Malcolm & Moler, "Computer Methods for Mathematical Computations", 1977, §4.4),
// which is what SIMM and OpenSim's SimmSpline use.
void fit_cubic(Function& f, bool natural) {
  const std::vector<double>& x = f.x;
  const std::vector<double>& y = f.y;
  const std::size_t n = x.size();
  std::vector<double> h(n - 1), slope(n - 1);
  for (std::size_t i = 0; i + 1 < n; ++i) {
    h[i] = x[i + 1] - x[i];
    slope[i] = (y[i + 1] - y[i]) / h[i];
  }
  f.b.assign(n, 0.0);
  f.c.assign(n, 0.0);
  f.d.assign(n, 0.0);
  if (n == 2) {  // a straight line
    f.b[0] = f.b[1] = slope[0];
    return;
  }
  // Unknowns s_i = y''_i / 2... written as sigma_i with the FMM scaling: diag, sub/super diag, rhs.
  std::vector<double> diag(n), off(n - 1), rhs(n);
  for (std::size_t i = 1; i + 1 < n; ++i) {
    diag[i] = 2.0 * (h[i - 1] + h[i]);
    rhs[i] = slope[i] - slope[i - 1];
  }
  for (std::size_t i = 0; i + 1 < n; ++i) off[i] = h[i];
  if (natural) {
    diag[0] = 1.0;
    off[0] = 0.0;
    rhs[0] = 0.0;
    diag[n - 1] = 1.0;
    rhs[n - 1] = 0.0;
    // the last row's sub-diagonal is off[n-2]; zero it by using a separate coefficient
  } else {
    diag[0] = -h[0];
    diag[n - 1] = -h[n - 2];
    rhs[0] = 0.0;
    rhs[n - 1] = 0.0;
    if (n > 3) {
      // Third divided differences at both ends.
      const double dd0 = rhs[2] / (x[3] - x[1]) - rhs[1] / (x[2] - x[0]);
      const double dd1 = rhs[n - 2] / (x[n - 1] - x[n - 3]) - rhs[n - 3] / (x[n - 2] - x[n - 4]);
      rhs[0] = dd0 * h[0] * h[0] / (x[3] - x[0]);
      rhs[n - 1] = -dd1 * h[n - 2] * h[n - 2] / (x[n - 1] - x[n - 4]);
    }
  }
  // Tridiagonal elimination (symmetric off-diagonals, except the natural end rows).
  std::vector<double> sub(n, 0.0), sup(n, 0.0);
  for (std::size_t i = 0; i + 1 < n; ++i) {
    sup[i] = off[i];
    sub[i + 1] = off[i];
  }
  if (natural) {
    sup[0] = 0.0;
    sub[n - 1] = 0.0;
  }
  for (std::size_t i = 1; i < n; ++i) {
    const double t = sub[i] / diag[i - 1];
    diag[i] -= t * sup[i - 1];
    rhs[i] -= t * rhs[i - 1];
  }
  std::vector<double> sigma(n);
  sigma[n - 1] = rhs[n - 1] / diag[n - 1];
  for (std::size_t i = n - 1; i-- > 0;) sigma[i] = (rhs[i] - sup[i] * sigma[i + 1]) / diag[i];
  // sigma_i = y''_i / 6: polynomial coefficients per interval.
  for (std::size_t i = 0; i + 1 < n; ++i) {
    f.b[i] = slope[i] - h[i] * (sigma[i + 1] + 2.0 * sigma[i]);
    f.c[i] = 3.0 * sigma[i];
    f.d[i] = (sigma[i + 1] - sigma[i]) / h[i];
  }
  f.b[n - 1] = slope[n - 2] + h[n - 2] * (2.0 * sigma[n - 1] + sigma[n - 2]);
  f.c[n - 1] = 3.0 * sigma[n - 1];
  f.d[n - 1] = f.d[n - 2];
}

FunctionValue eval_cubic(const Function& f, double t) {
  const std::size_t n = f.x.size();
  if (t < f.x.front()) return {f.y.front() + (t - f.x.front()) * f.b.front(), f.b.front(), 0.0};
  if (t > f.x.back()) return {f.y.back() + (t - f.x.back()) * f.b.back(), f.b.back(), 0.0};
  const std::size_t k = find_interval(f.x, t);
  (void)n;
  const double dx = t - f.x[k];
  return {f.y[k] + dx * (f.b[k] + dx * (f.c[k] + dx * f.d[k])),
          f.b[k] + dx * (2.0 * f.c[k] + 3.0 * dx * f.d[k]), 2.0 * f.c[k] + 6.0 * dx * f.d[k]};
}

FunctionValue eval_piecewise_linear(const Function& f, double t) {
  const std::size_t k = find_interval(f.x, t);  // end intervals extend beyond the knots
  const double s = (f.y[k + 1] - f.y[k]) / (f.x[k + 1] - f.x[k]);
  return {f.y[k] + s * (t - f.x[k]), s, 0.0};
}

}  // namespace

Function make_constant(double value) {
  Function f;
  f.kind = FunctionKind::constant;
  f.coefficients = {value};
  return f;
}

Function make_linear(double slope, double intercept) {
  Function f;
  f.kind = FunctionKind::linear;
  f.coefficients = {slope, intercept};
  return f;
}

Function make_simm_spline(std::vector<double> x, std::vector<double> y, const std::string& what) {
  check_knots(x, y, 2, "SimmSpline", what);
  Function f;
  f.kind = FunctionKind::simm_spline;
  f.x = std::move(x);
  f.y = std::move(y);
  fit_cubic(f, false);
  return f;
}

Function make_natural_cubic(std::vector<double> x, std::vector<double> y, const std::string& what) {
  check_knots(x, y, 2, "natural cubic spline", what);
  Function f;
  f.kind = FunctionKind::natural_cubic;
  f.x = std::move(x);
  f.y = std::move(y);
  fit_cubic(f, true);
  return f;
}

Function make_piecewise_linear(std::vector<double> x, std::vector<double> y,
                               const std::string& what) {
  check_knots(x, y, 2, "PiecewiseLinearFunction", what);
  Function f;
  f.kind = FunctionKind::piecewise_linear;
  f.x = std::move(x);
  f.y = std::move(y);
  return f;
}

Function make_polynomial(std::vector<double> coefficients_highest_first) {
  Function f;
  f.kind = FunctionKind::polynomial;
  f.coefficients = std::move(coefficients_highest_first);
  if (f.coefficients.empty()) f.coefficients = {0.0};
  return f;
}

Function make_multiplier(Function inner, double scale) {
  Function f;
  f.kind = FunctionKind::multiplier;
  f.scale = scale;
  f.inner.push_back(std::move(inner));
  return f;
}

FunctionValue calc_function(const Function& f, double t) {
  switch (f.kind) {
    case FunctionKind::constant: return {f.coefficients.empty() ? 0.0 : f.coefficients[0], 0, 0};
    case FunctionKind::linear:
      return {f.coefficients[0] * t + f.coefficients[1], f.coefficients[0], 0.0};
    case FunctionKind::simm_spline:
    case FunctionKind::natural_cubic: return eval_cubic(f, t);
    case FunctionKind::piecewise_linear: return eval_piecewise_linear(f, t);
    case FunctionKind::polynomial: {
      // Horner's scheme carrying the first and second derivatives.
      double p = 0.0, dp = 0.0, ddp = 0.0;
      for (const double a : f.coefficients) {
        ddp = ddp * t + 2.0 * dp;
        dp = dp * t + p;
        p = p * t + a;
      }
      return {p, dp, ddp};
    }
    case FunctionKind::multiplier: {
      if (f.inner.size() != 1) throw_internal("MultiplierFunction without its inner function");
      const FunctionValue v = calc_function(f.inner[0], t);
      return {f.scale * v.value, f.scale * v.slope, f.scale * v.curvature};
    }
  }
  throw_internal("unknown function kind");
}

double calc_value(const Function& f, double x) { return calc_function(f, x).value; }
double calc_slope(const Function& f, double x) { return calc_function(f, x).slope; }

bool is_constant(const Function& f) {
  if (f.kind == FunctionKind::constant) return true;
  if (f.kind == FunctionKind::multiplier) return f.inner.size() == 1 && is_constant(f.inner[0]);
  return false;
}

}  // namespace fascicle
