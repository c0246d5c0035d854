// Scalar functions y = f(x) of one coordinate, as OpenSim uses them for joint axes, coordinate
// couplers and moving path points: Constant, LinearFunction, SimmSpline, a natural cubic spline,
// PiecewiseLinearFunction, PolynomialFunction and MultiplierFunction. A Function is a small value
// type (copyable, no virtual calls); the make_* functions check their input and precompute spline
// coefficients once. C++17-compatible (the skeleton module compiles as C++17).
#pragma once

#include <string>
#include <vector>

namespace fascicle {

enum class FunctionKind {
  constant,          // y = c
  linear,            // y = slope·x + intercept
  simm_spline,       // OpenSim's SimmSpline: cubic spline whose end conditions match the third
                     // derivative to divided differences (Forsythe, Malcolm & Moler 1977, the
                     // algorithm SIMM and OpenSim use); linear extrapolation with the end slopes
  natural_cubic,     // natural cubic spline (zero curvature at both ends); linear extrapolation
  piecewise_linear,  // linear interpolation; extrapolation continues the end segments
  polynomial,        // y = Σ c_k x^(n−k), coefficients from the highest power (OpenSim order)
  multiplier,        // y = scale · inner(x)
};

struct Function {
  FunctionKind kind = FunctionKind::constant;
  std::vector<double> x, y;          // knots of splines and piecewise-linear functions
  std::vector<double> coefficients;  // constant {c}; linear {slope, intercept}; polynomial
  double scale = 1.0;                // multiplier
  std::vector<Function> inner;       // multiplier: exactly one inner function
  // Spline coefficients on [x_i, x_i+1]: y_i + b_i·dx + c_i·dx² + d_i·dx³ (set by make_*).
  std::vector<double> b, c, d;
};

Function make_constant(double value);
Function make_linear(double slope, double intercept);
// Throws a bad-input error (with `what` as the object name) when x and y differ in size, there are
// fewer than two knots (one for piecewise linear is also rejected), x is not strictly increasing, or
// a value is not finite.
Function make_simm_spline(std::vector<double> x, std::vector<double> y, const std::string& what = {});
Function make_natural_cubic(std::vector<double> x, std::vector<double> y, const std::string& what = {});
Function make_piecewise_linear(std::vector<double> x, std::vector<double> y,
                               const std::string& what = {});
Function make_polynomial(std::vector<double> coefficients_highest_first);
Function make_multiplier(Function inner, double scale);

// Value, first and second derivative with respect to x.
struct FunctionValue {
  double value = 0.0;
  double slope = 0.0;
  double curvature = 0.0;
};
FunctionValue calc_function(const Function& f, double x);
double calc_value(const Function& f, double x);
double calc_slope(const Function& f, double x);

// True when the function does not depend on x (a constant, or a multiplier of one).
bool is_constant(const Function& f);

}  // namespace fascicle
