#include "fascicle/io/svg_plot.hpp"

#include "fascicle/core/error.hpp"
#include "test_support.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

using namespace fascicle;

TEST(SvgPlot, NiceTicks) {
  const auto t = calc_nice_ticks(0.0, 1.0, 5);
  ASSERT_EQ(t.size(), 6u);
  EXPECT_DOUBLE_EQ(t.front(), 0.0);
  EXPECT_NEAR(t[1], 0.2, 1e-15);
  EXPECT_NEAR(t.back(), 1.0, 1e-12);
  const auto u = calc_nice_ticks(-37.0, 1234.0, 6);
  EXPECT_LE(u.front(), -37.0);
  EXPECT_GE(u.back(), 1234.0);
  EXPECT_NEAR(u[1] - u[0], 500.0, 1e-9);  // span 1271 / 6 = 212 -> next nice step 500
}

TEST(SvgPlot, WritesSeriesLegendAndLabels) {
  PlotSpec s{"Force-length", "fibre length / l0 (-)", "force (N)",
             {{"active", {0.5, 1.0, 1.5}, {10, 100, 20}}, {"passive & <x>", {0.5, 1.0}, {0, 1}, true}}};
  const auto dir = test::scratch_dir("svg_plot");
  write_svg_plot(dir / "p.svg", s);
  std::ifstream in(dir / "p.svg");
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string svg = ss.str();
  EXPECT_NE(svg.find("<svg"), std::string::npos);
  EXPECT_NE(svg.find("fibre length / l0 (-)"), std::string::npos);
  EXPECT_NE(svg.find("passive &amp; &lt;x&gt;"), std::string::npos);
  EXPECT_NE(svg.find("<path d=\" M"), std::string::npos);
  EXPECT_EQ(std::count(svg.begin(), svg.end(), '\n') > 10, true);
  EXPECT_NE(svg.find("</svg>"), std::string::npos);
  PlotSpec bad{"x", "x", "y", {{"bad", {1, 2}, {1}}}};
  EXPECT_THROW(write_svg_plot(dir / "bad.svg", bad), Error);
}
