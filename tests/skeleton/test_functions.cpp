// Scalar functions: analytic values, spline reproduction properties, derivatives vs differences.
#include <gtest/gtest.h>

#include <cmath>

#include "fascicle/core/error.hpp"
#include "fascicle/skeleton/functions.hpp"

namespace fascicle {
namespace {

double cubic(double x) { return 0.5 * x * x * x - 2.0 * x * x + x - 3.0; }

TEST(Functions, SimmSplineReproducesACubicExactly) {
  // The FMM end conditions match the third derivative of the cubic through the end points, so
  // data sampled from any cubic (uneven knots) is reproduced exactly, derivatives included.
  std::vector<double> x{-1.0, -0.2, 0.5, 1.1, 2.0, 3.3};
  std::vector<double> y;
  for (double v : x) y.push_back(cubic(v));
  const Function f = make_simm_spline(x, y);
  for (double t = -1.0; t <= 3.3; t += 0.037) {
    const FunctionValue v = calc_function(f, t);
    EXPECT_NEAR(v.value, cubic(t), 1e-12) << t;
    EXPECT_NEAR(v.slope, 1.5 * t * t - 4.0 * t + 1.0, 1e-11) << t;
    EXPECT_NEAR(v.curvature, 3.0 * t - 4.0, 1e-10) << t;
  }
  // Linear extrapolation with the end slopes.
  const double s0 = 1.5 - (-4.0) + 1.0;  // slope at -1: 1.5 + 4 + 1
  EXPECT_NEAR(calc_value(f, -2.0), cubic(-1.0) - s0, 1e-11);
  EXPECT_NEAR(calc_slope(f, 10.0), 1.5 * 3.3 * 3.3 - 4.0 * 3.3 + 1.0, 1e-10);
}

TEST(Functions, NaturalCubicKnownValues) {
  // Through (0,0), (1,1), (2,0) with zero end curvature: y''(1) = -3, so on [0,1]
  // y = 1.5x − 0.5x³; y(0.5) = 0.6875, y'(0) = 1.5, symmetric about x = 1.
  const Function f = make_natural_cubic({0.0, 1.0, 2.0}, {0.0, 1.0, 0.0});
  EXPECT_NEAR(calc_value(f, 0.5), 0.6875, 1e-15);
  EXPECT_NEAR(calc_value(f, 1.5), 0.6875, 1e-15);
  EXPECT_NEAR(calc_slope(f, 0.0), 1.5, 1e-15);
  EXPECT_NEAR(calc_function(f, 1.0).curvature, -3.0, 1e-14);
  EXPECT_NEAR(calc_function(f, 0.0).curvature, 0.0, 1e-15);
  EXPECT_NEAR(calc_function(f, 2.0).curvature, 0.0, 1e-14);
}

TEST(Functions, DerivativesMatchCentralDifferences) {
  const std::vector<Function> fs{
      make_simm_spline({0.0, 0.3, 0.9, 1.4, 2.0}, {0.1, -0.2, 0.4, 0.35, 1.0}),
      make_simm_spline({0.0, 0.5, 1.0}, {0.0, 1.0, 0.5}),
      make_natural_cubic({0.0, 0.3, 0.9, 1.4, 2.0}, {0.1, -0.2, 0.4, 0.35, 1.0}),
      make_polynomial({0.3, -1.0, 2.0, 0.5}),
      make_multiplier(make_simm_spline({0.0, 1.0, 2.0, 3.0}, {0.0, 0.5, 0.2, 0.9}), -2.5)};
  const double h = 1e-6;
  for (const Function& f : fs)
    for (double t : {0.13, 0.77, 1.21, 1.9}) {
      const FunctionValue v = calc_function(f, t);
      EXPECT_NEAR(v.slope, (calc_value(f, t + h) - calc_value(f, t - h)) / (2 * h), 1e-8);
      EXPECT_NEAR(v.curvature, (calc_slope(f, t + h) - calc_slope(f, t - h)) / (2 * h), 1e-6);
    }
}

TEST(Functions, PiecewiseLinearPolynomialLinearConstant) {
  const Function p = make_piecewise_linear({0.0, 1.0, 3.0}, {0.0, 2.0, 1.0});
  EXPECT_DOUBLE_EQ(calc_value(p, 0.5), 1.0);
  EXPECT_DOUBLE_EQ(calc_value(p, 2.0), 1.5);
  EXPECT_DOUBLE_EQ(calc_value(p, 4.0), 0.5);   // extends the last segment
  EXPECT_DOUBLE_EQ(calc_value(p, -1.0), -2.0);  // and the first
  EXPECT_DOUBLE_EQ(calc_value(make_polynomial({2.0, 0.0, -1.0}), 3.0), 17.0);  // 2x² − 1
  EXPECT_DOUBLE_EQ(calc_value(make_linear(2.0, 0.5), 1.5), 3.5);
  EXPECT_DOUBLE_EQ(calc_value(make_constant(0.7), 100.0), 0.7);
  EXPECT_TRUE(is_constant(make_multiplier(make_constant(1.0), 3.0)));
  EXPECT_FALSE(is_constant(make_linear(1.0, 0.0)));
}

TEST(Functions, BadKnotsAreRejected) {
  EXPECT_THROW(make_simm_spline({0.0, 1.0}, {0.0}), Error);
  EXPECT_THROW(make_simm_spline({0.0, 0.0, 1.0}, {0.0, 1.0, 2.0}), Error);
  EXPECT_THROW(make_natural_cubic({0.0}, {0.0}), Error);
  EXPECT_THROW(make_piecewise_linear({0.0, NAN}, {0.0, 1.0}), Error);
}

}  // namespace
}  // namespace fascicle
