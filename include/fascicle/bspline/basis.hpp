// B-spline bases along one parametric direction: knot vectors (clamped, unclamped uniform,
// non-uniform, periodic), span search and the non-zero basis functions with derivatives.
// Notation follows seed 000 ch. 3 and Piegl & Tiller, "The NURBS Book" (2nd ed., 1997), ch. 2:
// N_{i,p}(t) by the Cox–de Boor recurrence, derivatives by
//   N'_{i,p} = p N_{i,p-1}/(t_{i+p}-t_i) - p N_{i+1,p-1}/(t_{i+p+1}-t_{i+1})  (P&T eq. 2.7).
// Parameters are dimensionless material coordinates.
#pragma once

#include <array>
#include <vector>

namespace fascicle {

// Highest supported degree: basis evaluation uses fixed-size stack arrays of this size.
inline constexpr int kMaxBSplineDegree = 7;

// One parametric direction of a B-spline curve, surface or solid.
// Non-periodic: knots has num_control + degree + 1 entries; the domain is
//   [knots[degree], knots[num_control]].
// Periodic: the control points wrap around; the basis is stored unrolled with
//   num_control + degree spanning functions (function i uses control point i mod num_control) and
//   knots has num_control + 2 degree + 1 entries whose spacings repeat with period num_control.
// Degree 0 with a single control point (knots {0, 1}) is a collapsed direction: surfaces and curves
// are solids with one or two collapsed directions.
struct BSplineBasis {
  int degree = 0;
  int num_control = 1;
  bool periodic = false;
  std::vector<double> knots{0.0, 1.0};

  int num_functions() const { return periodic ? num_control + degree : num_control; }
  double get_lower() const { return knots[degree]; }
  double get_upper() const { return knots[num_functions()]; }
  // True when the end knots have multiplicity degree + 1 (the boundary interpolates the end
  // control points).
  bool is_clamped() const;
};

// Clamped (open) uniform knots on [lower, upper]: degree+1 equal knots at each end.
BSplineBasis make_clamped_uniform_basis(int degree, int num_control, double lower = 0.0,
                                        double upper = 1.0);
// Unclamped uniform knots t_i = i with the domain mapped onto [lower, upper].
BSplineBasis make_unclamped_uniform_basis(int degree, int num_control, double lower = 0.0,
                                          double upper = 1.0);
// Periodic uniform basis on [lower, upper) with num_control distinct control points.
BSplineBasis make_periodic_uniform_basis(int degree, int num_control, double lower = 0.0,
                                         double upper = 1.0);
// Clamped non-uniform basis: the given interior knots (num_control - degree - 1 of them, strictly
// inside (lower, upper), non-decreasing) between clamped ends.
BSplineBasis make_clamped_basis(int degree, int num_control, const std::vector<double>& interior,
                                double lower = 0.0, double upper = 1.0);
// A basis from a full knot vector; validates everything (see validate_basis).
BSplineBasis make_basis(int degree, int num_control, std::vector<double> knots, bool periodic);

// Throws fascicle::Error (bad_input) naming `what` when the degree is out of [0, kMaxBSplineDegree],
// degree >= num_control (for degree > 0), the knot vector has the wrong length, is not
// non-decreasing, holds NaN/Inf, has an empty domain, a knot of multiplicity > degree + 1, or
// (periodic) spacings that do not repeat.
void validate_basis(const BSplineBasis& basis, const char* what = "knot vector");

// Greville abscissae (mean of `degree` consecutive knots), one per distinct control point. Placing
// control points at an affine image of these reproduces that affine map exactly.
std::vector<double> calc_greville_abscissae(const BSplineBasis& basis);

// Maps t into the domain: clamps (non-periodic) or wraps into [lower, upper) (periodic).
double wrap_parameter(const BSplineBasis& basis, double t);

// The span s with knots[s] <= t < knots[s+1], degree <= s < num_functions(); t is first wrapped.
// t at the upper end belongs to the last non-empty span.
int find_span(const BSplineBasis& basis, double t);

// The degree+1 non-zero basis functions at t and their first and second derivatives:
// N[k][r] = d^k/dt^k N_{first+r, p}(t), first = span - degree. No heap allocation.
struct BasisValues {
  int first = 0;  // index of the first non-zero function (unrolled; use control_index)
  std::array<std::array<double, kMaxBSplineDegree + 1>, 3> N{};
};

// Evaluates up to `num_derivatives` (0, 1 or 2) derivatives at parameter t (wrapped first).
BasisValues calc_basis(const BSplineBasis& basis, double t, int num_derivatives = 1);

// The control point of unrolled basis function i (i mod num_control when periodic).
inline int control_index(const BSplineBasis& basis, int i) {
  return basis.periodic ? i % basis.num_control : i;
}

// Dense values of all num_control basis functions (periodic functions folded) at t, derivative
// order k: reference evaluation for tests and set-up code, not for hot loops.
std::vector<double> calc_all_basis_values(const BSplineBasis& basis, double t, int k = 0);

}  // namespace fascicle
