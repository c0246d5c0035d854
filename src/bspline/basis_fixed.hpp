// Internal: degree-specialised B-spline basis evaluation for the hot paths (point evaluation,
// Jacobians). Same mathematics as calc_basis (Piegl & Tiller 1997, algorithm A2.2 for the values;
// eq. 2.7 for the first derivative from the degree p-1 values), with the degree a compile-time
// constant so every loop unrolls into straight-line code on stack arrays.
#pragma once

#include "fascicle/bspline/basis.hpp"

#include <algorithm>
#include <cmath>

namespace fascicle::bspline_detail {

// t wrapped into the domain: clamped (non-periodic) or reduced modulo the period.
inline double wrap_fast(const BSplineBasis& b, double t) {
  const double lo = b.knots[b.degree], hi = b.knots[b.num_functions()];
  if (!b.periodic) return t < lo ? lo : (t > hi ? hi : t);
  if (t >= lo && t < hi) return t;
  return wrap_parameter(b, t);
}

// The span s (degree <= s < num_functions) with knots[s] <= t < knots[s+1] for an already wrapped
// t; t at the upper end belongs to the last non-empty span. Branch-free binary search (the
// comparisons compile to conditional moves, so random parameters do not mispredict).
inline int find_span_wrapped(const BSplineBasis& b, double t) {
  const double* k = b.knots.data();
  const int p = b.degree, n = b.num_functions();
  if (t >= k[n]) {
    int s = n - 1;
    while (s > p && k[s] == k[s + 1]) --s;
    return s;
  }
  // largest s in [p, n-1] with k[s] <= t
  const double* base = k + p;
  int len = n - p;
  while (len > 1) {
    const int half = len / 2;
    base = (base[half] <= t) ? base + half : base;
    len -= half;
  }
  return static_cast<int>(base - k);
}

// The P+1 non-zero basis functions of degree P at t (wrapped), and their first derivatives when
// kDerivative; first = span - P (unrolled function index).
template <int P, bool kDerivative>
struct FixedBasis {
  int first = 0;
  double N0[P + 1];
  double N1[P + 1];
};

template <int P, bool kDerivative>
inline FixedBasis<P, kDerivative> calc_fixed_basis(const BSplineBasis& b, double t) {
  static_assert(P >= 1);
  FixedBasis<P, kDerivative> out;
  t = wrap_fast(b, t);
  const int s = find_span_wrapped(b, t);
  const double* k = b.knots.data();
  out.first = s - P;
  double left[P + 1], right[P + 1];
  for (int j = 1; j <= P; ++j) {
    left[j] = t - k[s + 1 - j];
    right[j] = k[s + j] - t;
  }
  // N holds the degree-j values on the span (functions s-j .. s). The divisor
  // right[r+1] + left[j-r] = k_{s+r+1} - k_{s+r+1-j} spans the non-empty knot interval
  // [k_s, k_{s+1}], so it is never zero.
  double N[P + 1];
  N[0] = 1.0;
  double prev[P];  // degree P-1 values, for the derivative
  for (int j = 1; j <= P; ++j) {
    if (j == P) {
      for (int r = 0; r < P; ++r) prev[r] = N[r];
    }
    double saved = 0.0;
    for (int r = 0; r < j; ++r) {
      const double tmp = N[r] / (right[r + 1] + left[j - r]);
      N[r] = saved + right[r + 1] * tmp;
      saved = left[j - r] * tmp;
    }
    N[j] = saved;
  }
  for (int r = 0; r <= P; ++r) out.N0[r] = N[r];
  if constexpr (kDerivative) {
    // N'_{i,P} = P (N_{i,P-1}/(k_{i+P}-k_i) - N_{i+1,P-1}/(k_{i+P+1}-k_{i+1})), i = s-P+r;
    // prev[r] is N_{s-P+1+r, P-1}.
    double a[P];
    for (int r = 0; r < P; ++r) a[r] = P * prev[r] / (k[s + 1 + r] - k[s + 1 + r - P]);
    out.N1[0] = -a[0];
    for (int r = 1; r < P; ++r) out.N1[r] = a[r - 1] - a[r];
    out.N1[P] = a[P - 1];
  }
  return out;
}

}  // namespace fascicle::bspline_detail
