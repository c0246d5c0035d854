// FibreSet: muscle fibres as polylines, and the Blemker & Delp (2005) fibre templates.
//
// Blemker SS, Delp SL (2005) "Three-dimensional representation of complex muscle architectures
// and geometries", Ann Biomed Eng 33(5):661-673: a muscle's fibre geometry is described in a unit
// cube, then mapped into the muscle. Cube axes: z runs from the origin face (z = 0) to the
// insertion face (z = 1); x is the "thickness" direction in which pennate fibres run across the
// muscle; y is the "width" direction. See docs/fibres.md.
#pragma once

#include "fascicle/core/types.hpp"

#include <string>
#include <string_view>
#include <vector>

namespace fascicle {

// A set of fibres, each a polyline of #P x 3 points ordered from origin to insertion (metres,
// or unit-cube coordinates for templates).
struct FibreSet {
  std::vector<Points3> fibres;

  std::size_t size() const { return fibres.size(); }
};

enum class FibreTemplate { parallel, pennate, bipennate, curved, fanned };

// Parses "parallel", "pennate" (or "unipennate"), "bipennate", "curved", "fanned"; throws a usage
// error listing the accepted names.
FibreTemplate parse_fibre_template(std::string_view name);
std::string to_string(FibreTemplate t);

// Point i (0-based) of the 2-D R2 low-discrepancy sequence in [0,1)^2 (Roberts 2018, generalised
// golden ratio: alpha = (1/g, 1/g^2), g^3 = g + 1), started at offset 1/2.
Vec2 get_r2_point(int i);

// Fibres of `t` in the unit cube: `count` fibres (>= 1) of `resolution` points (>= 2) each.
// Fibre start positions sample the template's cross-section with the R2 sequence; every point
// lies in [0,1]^3. Template geometry (docs/fibres.md):
//   parallel:  (x0, y0, s) for s in [0,1];
//   pennate:   from the aponeurosis x = 0 at height z0 to the face x = 1 at z0 + h (h = 0.35);
//   bipennate: from the central aponeurosis x = 1/2 to x = 0 or x = 1, rising by h/2;
//   curved:    parallel, bowed in x by 0.15 sin(pi s) (scaled to stay inside the cube);
//   fanned:    converging in y towards the origin: y = 1/2 + (y0 - 1/2)(0.25 + 0.75 s).
// Throws a usage error for count < 1 or resolution < 2.
FibreSet make_template_fibres(FibreTemplate t, int count, int resolution);

// The same with the pennate templates' rise h (fraction of the cube's z extent a fibre climbs while
// crossing x from 0 to 1; bipennate fibres cross half of x and climb h/2), 0 < h <= 1. Throws a
// usage error for h outside (0, 1].
FibreSet make_template_fibres(FibreTemplate t, int count, int resolution, double rise);

// The same with given start parameters r in [0, 1]^2 (one fibre each) in place of the R2
// sequence: r.x() and r.y() take the places of the sequence's coordinates in the rules above
// (parallel: x0, y0 = 0.02 + 0.96 r). E.g. TemplateMapper::calc_section_samples.
FibreSet make_template_fibres(FibreTemplate t, const std::vector<Vec2>& starts, int resolution,
                              double rise);

// Default rise of the pennate templates (make_template_fibres without `rise`).
inline constexpr double default_pennate_rise = 0.35;

// The rise h that gives a fibre the pennation angle `pennation_rad` (angle to the box's z axis, the
// line of action) in a box of thickness `thickness_m` and axial length `axial_length_m`:
// tan(pennation) = thickness / (h * axial length), clamped to [0.02, 1]. The same h serves the
// bipennate template (half the thickness over half the rise).
double calc_pennate_rise(double pennation_rad, double thickness_m, double axial_length_m);

// True for templates whose fibres run from the z = 0 face to the z = 1 face (parallel, curved,
// fanned), whose ends therefore lie on the attachment areas; pennate fibres end on aponeuroses.
bool is_end_to_end(FibreTemplate t);

// Resamples a polyline to `resolution` points equally spaced in arc length (first and last point
// kept). A polyline of zero length gives `resolution` copies of its first point.
Points3 resample_polyline(const Points3& polyline, int resolution);

// Arc length of a polyline (sum of segment lengths).
double calc_polyline_length(const Points3& polyline);

}  // namespace fascicle
