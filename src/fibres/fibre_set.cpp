// Blemker & Delp (2005) fibre templates in the unit cube; polyline helpers.
#include "fascicle/fibres/fibre_set.hpp"

#include "fascicle/core/error.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>

namespace fascicle {

FibreTemplate parse_fibre_template(std::string_view name) {
  std::string s(name);
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  if (s == "parallel") return FibreTemplate::parallel;
  if (s == "pennate" || s == "unipennate") return FibreTemplate::pennate;
  if (s == "bipennate") return FibreTemplate::bipennate;
  if (s == "curved") return FibreTemplate::curved;
  if (s == "fanned") return FibreTemplate::fanned;
  throw_usage("unknown fibre template '" + s + "'",
              {.suggestion = "use one of parallel, pennate, bipennate, curved, fanned"});
}

std::string to_string(FibreTemplate t) {
  switch (t) {
    case FibreTemplate::parallel: return "parallel";
    case FibreTemplate::pennate: return "pennate";
    case FibreTemplate::bipennate: return "bipennate";
    case FibreTemplate::curved: return "curved";
    case FibreTemplate::fanned: return "fanned";
  }
  return "?";
}

bool is_end_to_end(FibreTemplate t) {
  return t == FibreTemplate::parallel || t == FibreTemplate::curved || t == FibreTemplate::fanned;
}

Vec2 get_r2_point(int i) {
  // Plastic number g: the real root of g^3 = g + 1.
  constexpr double g = 1.32471795724474602596;
  constexpr double a1 = 1.0 / g, a2 = 1.0 / (g * g);
  const double k = static_cast<double>(i);
  return {std::fmod(0.5 + a1 * k, 1.0), std::fmod(0.5 + a2 * k, 1.0)};
}

FibreSet make_template_fibres(FibreTemplate t, int count, int resolution) {
  return make_template_fibres(t, count, resolution, default_pennate_rise);
}

double calc_pennate_rise(double pennation_rad, double thickness_m, double axial_length_m) {
  if (!(pennation_rad > 0.0 && pennation_rad < 0.5 * M_PI))
    throw_usage("the pennation angle must be in (0, 90) degrees");
  if (!(thickness_m > 0.0 && axial_length_m > 0.0))
    throw_bad_input("the muscle box has no thickness or no length");
  return std::clamp(thickness_m / (axial_length_m * std::tan(pennation_rad)), 0.02, 1.0);
}

FibreSet make_template_fibres(FibreTemplate t, int count, int resolution, double rise) {
  if (count < 1) throw_usage("fibre count must be at least 1", {.suggestion = "use --count 100"});
  std::vector<Vec2> starts;
  starts.reserve(count);
  for (int i = 0; i < count; ++i) starts.push_back(get_r2_point(i));
  return make_template_fibres(t, starts, resolution, rise);
}

FibreSet make_template_fibres(FibreTemplate t, const std::vector<Vec2>& starts, int resolution,
                              double rise) {
  if (!(rise > 0.0 && rise <= 1.0))
    throw_usage("the pennate rise must be in (0, 1]", {.suggestion = "use a rise such as 0.35"});
  const int count = static_cast<int>(starts.size());
  if (count < 1) throw_usage("fibre count must be at least 1", {.suggestion = "use --count 100"});
  if (resolution < 2)
    throw_usage("fibre resolution must be at least 2 points", {.suggestion = "use --resolution 15"});
  const double h = rise;  // rise of a pennate fibre across the cube
  // Keep sample points off the cube faces so mapped fibres stay off the surface.
  constexpr double inset = 0.02;
  const auto squeeze = [](double v) { return inset + (1.0 - 2.0 * inset) * v; };
  FibreSet set;
  set.fibres.reserve(count);
  for (int i = 0; i < count; ++i) {
    const Vec2 r = starts[i].cwiseMax(0.0).cwiseMin(1.0);
    Points3 P(resolution, 3);
    for (int k = 0; k < resolution; ++k) {
      const double s = static_cast<double>(k) / (resolution - 1);
      Vec3 p;
      switch (t) {
        case FibreTemplate::parallel:
          p = {squeeze(r.x()), squeeze(r.y()), s};
          break;
        case FibreTemplate::curved: {
          const double x0 = 0.15 + 0.7 * squeeze(r.x());
          p = {x0 + 0.15 * std::sin(M_PI * s), squeeze(r.y()), s};
          break;
        }
        case FibreTemplate::fanned: {
          const double y0 = squeeze(r.y());
          p = {squeeze(r.x()), 0.5 + (y0 - 0.5) * (0.25 + 0.75 * s), s};
          break;
        }
        case FibreTemplate::pennate: {
          const double z0 = r.x() * (1.0 - h);
          p = {s, squeeze(r.y()), z0 + h * s};
          break;
        }
        case FibreTemplate::bipennate: {
          // Alternate sides by the sequence's first coordinate, so both halves get half the fibres.
          const bool left = r.x() < 0.5;
          const double z0 = (left ? 2.0 * r.x() : 2.0 * r.x() - 1.0) * (1.0 - 0.5 * h);
          p = {left ? 0.5 - 0.5 * s : 0.5 + 0.5 * s, squeeze(r.y()), z0 + 0.5 * h * s};
          break;
        }
      }
      P.row(k) = p.transpose();
    }
    set.fibres.push_back(std::move(P));
  }
  return set;
}

double calc_polyline_length(const Points3& polyline) {
  double length = 0.0;
  for (Eigen::Index k = 1; k < polyline.rows(); ++k)
    length += (polyline.row(k) - polyline.row(k - 1)).norm();
  return length;
}

Points3 resample_polyline(const Points3& polyline, int resolution) {
  const Eigen::Index n = polyline.rows();
  Points3 out(resolution, 3);
  if (n == 0) throw_internal("resample_polyline: empty polyline");
  VecX cumulative(n);
  cumulative(0) = 0.0;
  for (Eigen::Index k = 1; k < n; ++k)
    cumulative(k) = cumulative(k - 1) + (polyline.row(k) - polyline.row(k - 1)).norm();
  const double total = cumulative(n - 1);
  if (total <= 0.0 || n == 1) {
    for (int k = 0; k < resolution; ++k) out.row(k) = polyline.row(0);
    return out;
  }
  Eigen::Index seg = 0;
  for (int k = 0; k < resolution; ++k) {
    const double target = total * k / (resolution - 1);
    while (seg < n - 2 && cumulative(seg + 1) < target) ++seg;
    const double len = cumulative(seg + 1) - cumulative(seg);
    const double a = len > 0.0 ? std::clamp((target - cumulative(seg)) / len, 0.0, 1.0) : 0.0;
    out.row(k) = (1.0 - a) * polyline.row(seg) + a * polyline.row(seg + 1);
  }
  out.row(0) = polyline.row(0);
  out.row(resolution - 1) = polyline.row(n - 1);
  return out;
}

}  // namespace fascicle
