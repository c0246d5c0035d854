// The root of the volume cubic along a Gauss-Newton direction (mesh_operators.hpp).
#include "fascicle/deformation/mesh_operators.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace fascicle {
namespace {

double eval(const std::array<double, 4>& c, double t) { return c[0] + t * (c[1] + t * (c[2] + t * c[3])); }

TEST(VolumeCubic, NewtonFromTheLinearisedRoot) {
  const std::array<double, 4> c = {1.0, 2.0, 0.1, 0.01};
  const double t = solve_volume_cubic(c, 1.5);
  EXPECT_NEAR(eval(c, t), 1.5, 1e-14);
  EXPECT_NEAR(t, 0.25, 0.01);  // the root near the linearised one, 0.25
}

TEST(VolumeCubic, NewtonCycleFallsBackToTheBracketedRoot) {
  // t^3 - 2t + 2 = 0: Newton from the linearised root t = 1 cycles 1 -> 0 -> 1; the only real root
  // is -1.7692923542386314.
  const std::array<double, 4> c = {2.0, -2.0, 0.0, 1.0};
  const double t = solve_volume_cubic(c, 0.0);
  EXPECT_NEAR(t, -1.7692923542386314, 1e-13);
}

TEST(VolumeCubic, SmallestRootOfThreeAndDegenerateCases) {
  // (t - 3)(t + 0.5)(t - 10) = t^3 - 12.5 t^2 + 23.5 t + 15; Newton from t = -15/23.5 converges
  // to -0.5; with c1 = 0 the linearisation is undefined and bracketing finds the roots.
  const std::array<double, 4> c = {15.0, 23.5, -12.5, 1.0};
  EXPECT_NEAR(solve_volume_cubic(c, 0.0), -0.5, 1e-12);
  const std::array<double, 4> q = {-4.0, 0.0, 1.0, 0.0};  // t^2 = 4
  EXPECT_NEAR(std::abs(solve_volume_cubic(q, 0.0)), 2.0, 1e-12);
  const std::array<double, 4> none = {1.0, 0.0, 1.0, 0.0};  // t^2 + 1 = 0: no real root
  EXPECT_TRUE(std::isnan(solve_volume_cubic(none, 0.0)));
}

}  // namespace
}  // namespace fascicle
