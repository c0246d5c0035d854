// Fibre analysis (after Kohout's analysis filter): per-fibre length and pennation, volume shares,
// volume and PCSA; and the comparison of fibre directions with DTI tracts. docs/fibres.md defines
// every quantity.
#pragma once

#include "fascicle/fibres/attachment.hpp"
#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/fibres/fibre_set.hpp"

#include <filesystem>
#include <string>
#include <vector>

namespace fascicle {

struct FibreMeasures {
  double length_m = 0.0;
  // Angle between the fibre's end tangent and the line of action (origin centroid -> insertion
  // centroid), rad in [0, pi/2].
  double pennation_proximal_rad = 0.0;
  double pennation_distal_rad = 0.0;
  // Angle between the end tangent and the attachment area's tangent plane (pi/2 minus the angle to
  // its mean normal), rad in [0, pi/2].
  double surface_angle_proximal_rad = 0.0;
  double surface_angle_distal_rad = 0.0;
  double volume_share = 0.0;  // fraction of the muscle volume nearest to this fibre
};

struct FibreAnalysis {
  std::vector<FibreMeasures> fibres;
  double volume_m3 = 0.0;              // enclosed volume of the surface (divergence theorem)
  double mean_fibre_length_m = 0.0;
  double mean_pennation_rad = 0.0;     // mean over fibres of (proximal + distal) / 2
  double pcsa_m2 = 0.0;                // volume / mean fibre length
  double pcsa_ravichandiran_m2 = 0.0;  // sum_i share_i * volume * cos(pennation_i) / length_i
  double origin_area_m2 = 0.0;
  double insertion_area_m2 = 0.0;
};

// Analyses fibres of `muscle`. Volume shares assign the points of a regular interior grid
// (about `volume_samples` points) to their nearest fibre point.
FibreAnalysis analyse_fibres(const TriMesh& muscle, const Attachments& areas,
                             const FibreSet& fibres, int volume_samples = 20000);

// calc_enclosed_volume(mesh): geometry/mass_properties.hpp.

// Fibre direction vs DTI: for the midpoint of every tract segment, the angle (rad, in [0, pi/2],
// sign of direction ignored) between the segment and the fibre segment nearest to that midpoint
// (found among the fibre segments cut into pieces of at most `fibre_spacing_m`; <= 0: whole
// segments by their midpoints, the measure before 2026-11-24).
struct DirectionDeviation {
  double mean_rad = 0.0;
  double stddev_rad = 0.0;
  double median_rad = 0.0;
  std::size_t segments = 0;
};
DirectionDeviation compare_directions(const FibreSet& fibres, const FibreSet& tracts,
                                      double fibre_spacing_m = 5e-4);

// Reads DTI tracts: one tract per line, "x1 y1 z1 x2 y2 z2 ...", scaled by metres_per_unit.
FibreSet read_tracts(const std::filesystem::path& path, double metres_per_unit = 1.0);

// JSON report (fields in SI with unit suffixes) and per-fibre CSV.
std::string to_json(const FibreAnalysis& analysis);
void write_fibre_csv(const std::filesystem::path& path, const FibreAnalysis& analysis);

// Writes fibres as VTK XML PolyData polylines, atomically: point data "parameter" (0 at origin,
// 1 at insertion, by arc length), cell data "length", "pennation_proximal_deg",
// "pennation_distal_deg", "volume_share". `analysis` may be null (geometry only).
void write_fibres_vtp(const std::filesystem::path& path, const FibreSet& fibres,
                      const FibreAnalysis* analysis = nullptr);

}  // namespace fascicle
