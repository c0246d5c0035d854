// B-spline bases: knot vectors and Cox–de Boor evaluation (Piegl & Tiller 1997, ch. 2).
#include "fascicle/bspline/basis.hpp"

#include "fascicle/core/error.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace fascicle {

bool BSplineBasis::is_clamped() const {
  if (periodic) return false;
  const int n = num_control;
  for (int i = 0; i < degree; ++i) {
    if (knots[i] != knots[degree] || knots[n + 1 + i] != knots[n]) return false;
  }
  return true;
}

void validate_basis(const BSplineBasis& b, const char* what) {
  const auto fail = [&](const std::string& msg, const std::string& fix) {
    throw_bad_input(fmt::format("{}: {}", what, msg), ErrorContext{.suggestion = fix});
  };
  if (b.degree < 0 || b.degree > kMaxBSplineDegree) {
    fail(fmt::format("degree {} is outside [0, {}]", b.degree, kMaxBSplineDegree),
         "use a degree between 1 and 7 (3 = cubic is usual)");
  }
  if (b.num_control < 1) fail("needs at least one control point", "add control points");
  if (b.degree > 0 && b.degree >= b.num_control) {
    fail(fmt::format("degree {} must be smaller than the number of control points {}", b.degree,
                     b.num_control),
         "lower the degree or add control points along this direction");
  }
  const std::size_t expected = static_cast<std::size_t>(b.num_functions() + b.degree + 1);
  if (b.knots.size() != expected) {
    fail(fmt::format("has {} knots but degree {} with {} control points{} needs {}",
                     b.knots.size(), b.degree, b.num_control, b.periodic ? " (periodic)" : "",
                     expected),
         "knots = control points + degree + 1 (periodic: control points + 2 degree + 1)");
  }
  for (std::size_t i = 0; i < b.knots.size(); ++i) {
    if (!std::isfinite(b.knots[i])) fail(fmt::format("knot {} is not finite", i), "fix the knot");
    if (i > 0 && b.knots[i] < b.knots[i - 1]) {
      fail(fmt::format("knots are not non-decreasing: knot {} = {} < knot {} = {}", i, b.knots[i],
                       i - 1, b.knots[i - 1]),
           "sort the knot vector");
    }
  }
  if (!(b.get_upper() > b.get_lower())) {
    fail("the parameter domain [knots[degree], knots[n]] is empty", "spread the knots");
  }
  for (std::size_t i = 0; i + b.degree + 1 < b.knots.size(); ++i) {
    if (b.degree > 0 && b.knots[i + b.degree + 1] == b.knots[i] &&
        i + b.degree + 1 < b.knots.size()) {
      fail(fmt::format("knot {} has multiplicity above degree + 1", b.knots[i]),
           "remove repeated knots");
    }
  }
  if (b.periodic) {
    const double period = b.get_upper() - b.get_lower();
    const int n = b.num_control;
    for (std::size_t i = 0; i + n < b.knots.size(); ++i) {
      const double d = b.knots[i + n] - b.knots[i] - period;
      if (std::abs(d) > 1e-12 * std::max(1.0, std::abs(period))) {
        fail(fmt::format("periodic knot spacings do not repeat (knot {})", i),
             "use make_periodic_uniform_basis or repeat the spacings with period n");
      }
    }
  }
}

BSplineBasis make_basis(int degree, int num_control, std::vector<double> knots, bool periodic) {
  BSplineBasis b;
  b.degree = degree;
  b.num_control = num_control;
  b.periodic = periodic;
  b.knots = std::move(knots);
  validate_basis(b);
  return b;
}

BSplineBasis make_clamped_basis(int degree, int num_control, const std::vector<double>& interior,
                                double lower, double upper) {
  std::vector<double> k(degree + 1, lower);
  k.insert(k.end(), interior.begin(), interior.end());
  k.insert(k.end(), degree + 1, upper);
  return make_basis(degree, num_control, std::move(k), false);
}

BSplineBasis make_clamped_uniform_basis(int degree, int num_control, double lower, double upper) {
  const int spans = std::max(1, num_control - degree);
  std::vector<double> interior;
  for (int i = 1; i < spans; ++i) interior.push_back(lower + (upper - lower) * i / spans);
  if (degree >= num_control && degree > 0) {
    // let make_basis report it with the standard message
    return make_basis(degree, num_control, std::vector<double>(num_control + degree + 1, 0.0),
                      false);
  }
  return make_clamped_basis(degree, num_control, interior, lower, upper);
}

BSplineBasis make_unclamped_uniform_basis(int degree, int num_control, double lower,
                                          double upper) {
  const double h = (upper - lower) / std::max(1, num_control - degree);
  std::vector<double> k(num_control + degree + 1);
  for (int i = 0; i < static_cast<int>(k.size()); ++i) k[i] = lower + (i - degree) * h;
  return make_basis(degree, num_control, std::move(k), false);
}

BSplineBasis make_periodic_uniform_basis(int degree, int num_control, double lower, double upper) {
  const double h = (upper - lower) / std::max(1, num_control);
  std::vector<double> k(num_control + 2 * degree + 1);
  for (int i = 0; i < static_cast<int>(k.size()); ++i) k[i] = lower + (i - degree) * h;
  k[degree] = lower;
  k[num_control + degree] = upper;
  return make_basis(degree, num_control, std::move(k), true);
}

std::vector<double> calc_greville_abscissae(const BSplineBasis& b) {
  std::vector<double> g(b.num_control);
  for (int i = 0; i < b.num_control; ++i) {
    if (b.degree == 0) {
      g[i] = 0.5 * (b.knots[i] + b.knots[i + 1]);
      continue;
    }
    double s = 0.0;
    for (int j = 1; j <= b.degree; ++j) s += b.knots[i + j];
    g[i] = s / b.degree;
  }
  return g;
}

double wrap_parameter(const BSplineBasis& b, double t) {
  const double lo = b.get_lower(), hi = b.get_upper();
  if (!b.periodic) return std::clamp(t, lo, hi);
  const double period = hi - lo;
  double s = std::fmod(t - lo, period);
  if (s < 0) s += period;
  if (s >= period) s = 0.0;
  return lo + s;
}

int find_span(const BSplineBasis& b, double t) {
  t = wrap_parameter(b, t);
  const int n = b.num_functions();
  if (t >= b.knots[n]) {
    int s = n - 1;
    while (s > b.degree && b.knots[s] == b.knots[s + 1]) --s;
    return s;
  }
  // first knot > t among knots[degree+1 .. n]
  const auto it = std::upper_bound(b.knots.begin() + b.degree + 1, b.knots.begin() + n + 1, t);
  return static_cast<int>(it - b.knots.begin()) - 1;
}

namespace {

// One step of the derivative recurrence: from the d values of degree d-1 on span s (functions
// s-d+1 .. s) to the d+1 derivatives of degree d (functions s-d .. s).
void raise_derivative(const std::vector<double>& t, int s, int d, const double* in, double* out) {
  for (int r = 0; r <= d; ++r) {
    const int i = s - d + r;
    double v = 0.0;
    if (r >= 1) {
      const double den = t[i + d] - t[i];
      if (den > 0) v += in[r - 1] / den;
    }
    if (r <= d - 1) {
      const double den = t[i + d + 1] - t[i + 1];
      if (den > 0) v -= in[r] / den;
    }
    out[r] = d * v;
  }
}

}  // namespace

BasisValues calc_basis(const BSplineBasis& b, double t, int num_derivatives) {
  t = wrap_parameter(b, t);
  const int p = b.degree;
  const int s = find_span(b, t);
  const std::vector<double>& k = b.knots;
  // tri[d][r]: non-zero basis functions of degree d on span s (functions s-d+r).
  double tri[kMaxBSplineDegree + 1][kMaxBSplineDegree + 1];
  tri[0][0] = 1.0;
  for (int d = 1; d <= p; ++d) {
    for (int r = 0; r <= d; ++r) {
      const int i = s - d + r;
      double v = 0.0;
      if (r >= 1) {
        const double den = k[i + d] - k[i];
        if (den > 0) v += (t - k[i]) / den * tri[d - 1][r - 1];
      }
      if (r <= d - 1) {
        const double den = k[i + d + 1] - k[i + 1];
        if (den > 0) v += (k[i + d + 1] - t) / den * tri[d - 1][r];
      }
      tri[d][r] = v;
    }
  }
  BasisValues out;
  out.first = s - p;
  for (int r = 0; r <= p; ++r) out.N[0][r] = tri[p][r];
  if (num_derivatives >= 1 && p >= 1) {
    raise_derivative(k, s, p, tri[p - 1], out.N[1].data());
  }
  if (num_derivatives >= 2 && p >= 2) {
    double d1[kMaxBSplineDegree + 1];
    raise_derivative(k, s, p - 1, tri[p - 2], d1);
    raise_derivative(k, s, p, d1, out.N[2].data());
  }
  return out;
}

std::vector<double> calc_all_basis_values(const BSplineBasis& b, double t, int k) {
  std::vector<double> v(b.num_control, 0.0);
  const BasisValues bv = calc_basis(b, t, k);
  for (int r = 0; r <= b.degree; ++r) v[control_index(b, bv.first + r)] += bv.N[k][r];
  return v;
}

}  // namespace fascicle
