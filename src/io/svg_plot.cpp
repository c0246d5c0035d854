#include "fascicle/io/svg_plot.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace fascicle {

std::vector<double> calc_nice_ticks(double lo, double hi, int target) {
  if (!(hi > lo)) {
    const double pad = std::max(1.0, std::abs(lo)) * 0.5;
    lo -= pad;
    hi += pad;
  }
  const double raw = (hi - lo) / std::max(1, target);
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  double step = mag;
  for (double m : {1.0, 2.0, 5.0, 10.0}) {
    step = m * mag;
    if (step >= raw) break;
  }
  std::vector<double> ticks;
  const double first = std::floor(lo / step + 1e-9) * step;
  for (double t = first; t <= hi + step * 1e-9 + step; t += step) {
    ticks.push_back(std::abs(t) < step * 1e-9 ? 0.0 : t);
    if (t >= hi - step * 1e-9) break;
  }
  return ticks;
}

namespace {
std::string escape(const std::string& s) {
  std::string o;
  for (char c : s) {
    switch (c) {
      case '&': o += "&amp;"; break;
      case '<': o += "&lt;"; break;
      case '>': o += "&gt;"; break;
      case '"': o += "&quot;"; break;
      default: o += c;
    }
  }
  return o;
}
std::string fmt_tick(double v) {
  std::ostringstream s;
  s.precision(6);
  s << v;
  return s.str();
}
constexpr const char* kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd",
                                    "#8c564b", "#e377c2", "#17becf", "#7f7f7f", "#bcbd22"};
}  // namespace

std::string render_svg_plot(const PlotSpec& spec) {
  double xmin = std::numeric_limits<double>::infinity(), xmax = -xmin, ymin = xmin, ymax = -xmin;
  for (const PlotSeries& s : spec.series) {
    if (s.x.size() != s.y.size()) {
      throw_internal("plot series '" + s.name + "' has " + std::to_string(s.x.size()) +
                     " x values but " + std::to_string(s.y.size()) + " y values");
    }
    for (size_t i = 0; i < s.x.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      xmin = std::min(xmin, s.x[i]), xmax = std::max(xmax, s.x[i]);
      ymin = std::min(ymin, s.y[i]), ymax = std::max(ymax, s.y[i]);
    }
  }
  if (!std::isfinite(xmin)) xmin = 0, xmax = 1, ymin = 0, ymax = 1;
  const std::vector<double> xt = calc_nice_ticks(xmin, xmax);
  const std::vector<double> yt = calc_nice_ticks(ymin, ymax);
  const double x0 = xt.front(), x1 = xt.back(), y0 = yt.front(), y1 = yt.back();
  const double W = spec.width_px, H = spec.height_px;
  const double left = 80, right = 180, top = 40, bottom = 60;
  const double pw = W - left - right, ph = H - top - bottom;
  const auto X = [&](double x) { return left + (x - x0) / (x1 - x0) * pw; };
  const auto Y = [&](double y) { return top + ph - (y - y0) / (y1 - y0) * ph; };
  std::ostringstream o;
  o.precision(7);
  o << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
    << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << W << "\" height=\"" << H
    << "\" viewBox=\"0 0 " << W << ' ' << H << "\" font-family=\"Helvetica, Arial, sans-serif\">\n"
    << "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  o << "<text x=\"" << left + pw / 2 << "\" y=\"24\" text-anchor=\"middle\" font-size=\"16\">"
    << escape(spec.title) << "</text>\n";
  // Grid and ticks.
  for (double t : xt) {
    o << "<line x1=\"" << X(t) << "\" y1=\"" << top << "\" x2=\"" << X(t) << "\" y2=\"" << top + ph
      << "\" stroke=\"#e6e6e6\"/>\n<text x=\"" << X(t) << "\" y=\"" << top + ph + 18
      << "\" text-anchor=\"middle\" font-size=\"12\">" << fmt_tick(t) << "</text>\n";
  }
  for (double t : yt) {
    o << "<line x1=\"" << left << "\" y1=\"" << Y(t) << "\" x2=\"" << left + pw << "\" y2=\"" << Y(t)
      << "\" stroke=\"#e6e6e6\"/>\n<text x=\"" << left - 8 << "\" y=\"" << Y(t) + 4
      << "\" text-anchor=\"end\" font-size=\"12\">" << fmt_tick(t) << "</text>\n";
  }
  o << "<rect x=\"" << left << "\" y=\"" << top << "\" width=\"" << pw << "\" height=\"" << ph
    << "\" fill=\"none\" stroke=\"black\"/>\n";
  o << "<text x=\"" << left + pw / 2 << "\" y=\"" << H - 16
    << "\" text-anchor=\"middle\" font-size=\"14\">" << escape(spec.x_label) << "</text>\n";
  o << "<text transform=\"translate(20," << top + ph / 2
    << ") rotate(-90)\" text-anchor=\"middle\" font-size=\"14\">" << escape(spec.y_label)
    << "</text>\n";
  // Series.
  for (size_t k = 0; k < spec.series.size(); ++k) {
    const PlotSeries& s = spec.series[k];
    const std::string colour = s.colour.empty() ? std::string(kColours[k % std::size(kColours)]) : escape(s.colour);
    if (s.markers) {
      for (size_t i = 0; i < s.x.size(); ++i) {
        if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
        o << "<circle cx=\"" << X(s.x[i]) << "\" cy=\"" << Y(s.y[i]) << "\" r=\"" << s.marker_radius_px << "\" fill=\""
          << colour << "\"/>\n";
      }
    } else {
      std::string d;
      bool pen = false;
      std::ostringstream p;
      p.precision(7);
      for (size_t i = 0; i < s.x.size(); ++i) {
        if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) { pen = false; continue; }
        p << (pen ? " L" : " M") << X(s.x[i]) << ',' << Y(s.y[i]);
        pen = true;
      }
      o << "<path d=\"" << p.str() << "\" fill=\"none\" stroke=\"" << colour
        << "\" stroke-width=\"2\"/>\n";
    }
    const double ly = top + 10 + 20 * k;
    o << "<line x1=\"" << left + pw + 12 << "\" y1=\"" << ly << "\" x2=\"" << left + pw + 36
      << "\" y2=\"" << ly << "\" stroke=\"" << colour << "\" stroke-width=\"3\"/>\n<text x=\""
      << left + pw + 42 << "\" y=\"" << ly + 4 << "\" font-size=\"12\">" << escape(s.name)
      << "</text>\n";
  }
  o << "</svg>\n";
  return o.str();
}

void write_svg_plot(const std::filesystem::path& path, const PlotSpec& spec) {
  const std::string svg = render_svg_plot(spec);
  write_file_atomically(path, [&](std::ostream& out) { out << svg; });
}

}  // namespace fascicle
