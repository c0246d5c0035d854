// A small SVG line-plot writer: axes with "nice" ticks and labels, several series with a legend,
// units in the axis titles. Output is written atomically.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace fascicle {

struct PlotSeries {
  std::string name;          // legend entry
  std::vector<double> x, y;  // same length; non-finite points break the line
  bool markers = false;      // draw points instead of a line
  double marker_radius_px = 3.5;
  std::string colour;        // CSS colour; empty: the palette's next colour
};

struct PlotSpec {
  std::string title;
  std::string x_label;  // include units, e.g. "fibre length / l0 (-)"
  std::string y_label;  // e.g. "force (N)"
  std::vector<PlotSeries> series;
  int width_px = 720;
  int height_px = 460;
};

// Tick positions covering [lo, hi] with about `target` steps of 1, 2 or 5 × 10^k.
std::vector<double> calc_nice_ticks(double lo, double hi, int target = 6);

// Renders the plot as an SVG document.
std::string render_svg_plot(const PlotSpec& spec);

// Writes render_svg_plot(spec) to `path` atomically; throws fascicle::Error on I/O failure or when
// a series has mismatched x/y sizes.
void write_svg_plot(const std::filesystem::path& path, const PlotSpec& spec);

}  // namespace fascicle
