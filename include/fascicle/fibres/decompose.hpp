// One-call muscle fibre decomposition: template method with fallback to the harmonic method.
#pragma once

#include "fascicle/fibres/attachment.hpp"
#include "fascicle/fibres/fibre_set.hpp"
#include "fascicle/fibres/harmonic.hpp"
#include "fascicle/fibres/template_mapping.hpp"

#include <string>
#include <vector>

namespace fascicle {

enum class FibreMethod { template_map, harmonic };
FibreMethod parse_fibre_method(std::string_view name);  // "template" | "harmonic"
std::string to_string(FibreMethod m);

struct DecomposeOptions {
  FibreMethod method = FibreMethod::template_map;
  FibreTemplate fibre_template = FibreTemplate::parallel;
  int count = 100;
  int resolution = 15;
  // > 0: the pennate templates' rise is derived from this target pennation angle, the distance
  // a template fibre crosses in a slice, and the box's axial length (calc_pennate_rise); 0: the
  // fixed default rise.
  double pennation_rad = 0.0;
  // The crossing distance used for that rise: the box's mean thickness (contour area / width;
  // the default, unchanged) or the mapped crossing (TemplateMapper::get_mean_crossing: the mapped
  // fibres then make the target angle with the box axis; docs/fibres.md compares both).
  enum class RiseCrossing { mean_thickness, mapped_crossing };
  RiseCrossing rise_crossing = RiseCrossing::mean_thickness;
  TemplateMapOptions mapping;
  HarmonicOptions harmonic;
  // Where the streamlines of plain harmonic fields (harmonic.pennation_rad == 0) start
  // (TraceOptions::Seeding; docs/fibres.md compares them). Pennate fields start on the origin
  // area, except those with HarmonicOptions::transverse_targets, which use this seeding too.
  TraceOptions::Seeding harmonic_seeding = TraceOptions::Seeding::volume;
  bool harmonic_seed_by_flux = false;  // level-set seeds by flux instead of area
  double harmonic_area_seed_fraction = 0.0;  // TraceOptions::area_seed_fraction (volume seeding)
  // TraceOptions::candidate_factor (volume seeding; 8 since session 7, docs/fibres.md).
  int harmonic_candidate_factor = 8;
  int harmonic_area_candidate_factor = 1;  // TraceOptions::area_candidate_factor (session 7)
};

struct Decomposition {
  FibreSet fibres;
  FibreMethod method_used = FibreMethod::template_map;
  std::vector<std::string> warnings;  // e.g. slices with several contours and the fallback
};

// Decomposes `muscle` into fibres. With the template method, a shape the template cannot take
// (slices with several contours) logs a warning naming the slice positions and falls back to the
// harmonic method.
Decomposition decompose_muscle(const TriMesh& muscle, const Attachments& areas,
                               const DecomposeOptions& options);

}  // namespace fascicle
