// Length vs angle when a path slides off the end of a finite cylinder (OpenSim issue #3741):
// OpenSim's end rule jumps, the infinite-cylinder rule is continuous. Writes the curves as CSV and
// SVG into a scratch folder (docs/paths_cylinder_ends.svg is a copy).
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "fascicle/path/wrap_geometry.hpp"
#include "test_support.hpp"

using namespace fascicle;

namespace {

TEST(WrapCylinder, EndRuleLengthVersusAngle) {
  // Cylinder radius 0.05 m, length 0.1 m about z; origin fixed, insertion on a body rotating about
  // y through the cylinder centre, so the path rises off the cylinder's +z end as θ grows.
  const Vec3 origin(0.2, 0.01, 0.04);
  const int n = 241;
  std::vector<double> theta(n), L_opensim(n), L_infinite(n);
  for (int i = 0; i < n; ++i) {
    theta[i] = 0.6 * i / (n - 1);
    const Vec3 ins(-0.2 * std::cos(theta[i]), 0.01, 0.2 * std::sin(theta[i]));
    L_opensim[i] = wrapped_segment_length(
        origin, ins, wrap_cylinder(origin, ins, 0.05, 0.1, WrapQuadrant::pos_y));
    L_infinite[i] = wrapped_segment_length(
        origin, ins,
        wrap_cylinder(origin, ins, 0.05, 0.1, WrapQuadrant::pos_y, CylinderEndRule::infinite));
  }
  // The insertion moves 0.2 m/rad, so a continuous length changes by at most 0.2 Δθ per step.
  const double step_bound = 0.2 * 0.6 / (n - 1) * (1 + 1e-9);
  double max_jump_opensim = 0, max_jump_infinite = 0;
  for (int i = 0; i + 1 < n; ++i) {
    max_jump_opensim = std::max(max_jump_opensim, std::abs(L_opensim[i + 1] - L_opensim[i]));
    max_jump_infinite = std::max(max_jump_infinite, std::abs(L_infinite[i + 1] - L_infinite[i]));
  }
  EXPECT_LE(max_jump_infinite, step_bound);
  EXPECT_GT(max_jump_opensim, 5 * step_bound);  // the jump of #3741
  // Where OpenSim still wraps, the two rules agree.
  EXPECT_DOUBLE_EQ(L_opensim[0], L_infinite[0]);

  const auto dir = test::scratch_dir("paths_cylinder_ends");
  std::ofstream csv(dir / "cylinder_ends.csv");
  csv << "theta_rad,length_opensim_m,length_infinite_m\n";
  for (int i = 0; i < n; ++i) csv << theta[i] << ',' << L_opensim[i] << ',' << L_infinite[i] << '\n';
  // A small SVG plot: x = θ (0-0.6 rad), y = length.
  const double lo = *std::min_element(L_opensim.begin(), L_opensim.end()) - 0.002;
  const double hi = *std::max_element(L_infinite.begin(), L_infinite.end()) + 0.002;
  auto px = [](double t) { return 60 + 500 * t / 0.6; };
  auto py = [&](double l) { return 320 - 280 * (l - lo) / (hi - lo); };
  std::ofstream svg(dir / "cylinder_ends.svg");
  svg << "<svg xmlns='http://www.w3.org/2000/svg' width='600' height='370' font-family='sans-serif'"
         " font-size='12'>\n<rect width='600' height='370' fill='white'/>\n"
         "<line x1='60' y1='320' x2='560' y2='320' stroke='black'/>"
         "<line x1='60' y1='40' x2='60' y2='320' stroke='black'/>\n";
  for (int k = 0; k <= 6; ++k) {
    svg << "<text x='" << px(0.1 * k) - 8 << "' y='338'>" << 0.1 * k << "</text>\n";
  }
  for (int k = 0; k <= 4; ++k) {
    const double l = lo + (hi - lo) * k / 4;
    svg << "<text x='8' y='" << py(l) + 4 << "'>" << std::round(l * 1e4) / 1e4 << "</text>\n";
  }
  svg << "<text x='250' y='360'>joint angle θ (rad)</text>"
         "<text x='70' y='30'>path length (m): OpenSim end rule (red) vs infinite (blue)</text>\n";
  auto polyline = [&](const std::vector<double>& L, const char* colour, const char* dash) {
    svg << "<polyline fill='none' stroke='" << colour << "' stroke-width='2' stroke-dasharray='"
        << dash << "' points='";
    for (int i = 0; i < n; ++i) svg << px(theta[i]) << ',' << py(L[i]) << ' ';
    svg << "'/>\n";
  };
  polyline(L_infinite, "blue", "none");
  polyline(L_opensim, "red", "6,3");
  svg << "</svg>\n";
  EXPECT_TRUE(svg.good());
}

}  // namespace
