// One-call decomposition with fallback from the template to the harmonic method.
#include "fascicle/fibres/decompose.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mesh_query.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cctype>

namespace fascicle {

FibreMethod parse_fibre_method(std::string_view name) {
  std::string s(name);
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  if (s == "template") return FibreMethod::template_map;
  if (s == "harmonic" || s == "laplace") return FibreMethod::harmonic;
  throw_usage("unknown fibre method '" + s + "'", {.suggestion = "use template or harmonic"});
}

std::string to_string(FibreMethod m) {
  return m == FibreMethod::harmonic ? "harmonic" : "template";
}

Decomposition decompose_muscle(const TriMesh& muscle, const Attachments& areas,
                               const DecomposeOptions& options) {
  check_attachments(muscle, areas);
  Decomposition d;
  if (options.method == FibreMethod::template_map) {
    const TemplateMapper mapper(muscle, areas, options.mapping);
    if (mapper.is_mappable()) {
      const double rise =
          options.pennation_rad > 0.0
              ? calc_pennate_rise(options.pennation_rad,
                                  options.rise_crossing ==
                                          DecomposeOptions::RiseCrossing::mapped_crossing
                                      ? mapper.get_mean_crossing()
                                      : mapper.get_mean_thickness(),
                                  mapper.get_axial_length())
              : default_pennate_rise;
      // Parallel fibres start in proportion to the cross-section they map to (the other
      // templates' start parameters have other meanings: the R2 sequence in the unit square).
      const FibreSet unit =
          options.fibre_template == FibreTemplate::parallel && options.count >= 1
              ? make_template_fibres(options.fibre_template,
                                     mapper.calc_section_samples(options.count),
                                     options.resolution, rise)
              : make_template_fibres(options.fibre_template, options.count, options.resolution,
                                     rise);
      d.fibres = mapper.calc_fibres(unit, is_end_to_end(options.fibre_template));
      d.method_used = FibreMethod::template_map;
      return d;
    }
    std::string where;
    for (const SliceIssue& s : mapper.get_issues())
      where += fmt::format("{}{:.1f} mm ({} contours)", where.empty() ? "" : ", ",
                           s.axial_position_m * 1e3, s.num_contours);
    d.warnings.push_back("the " + to_string(options.fibre_template) +
                         " template cannot be mapped: slices with several contours at " + where +
                         " from the origin level; falling back to the harmonic method");
    spdlog::warn("{}", d.warnings.back());
  }
  const HarmonicField field = calc_harmonic_field(muscle, areas, options.harmonic);
  // Pennate fields start on the origin area, except those turning towards transverse targets
  // (the sheet border, session 10): their fibres drift sideways, so seeds on the origin area leave
  // the side away from the targets empty (Bolsterlee TA coverage 0.81); they start in the volume
  // as plain fields do (0.98).
  const bool origin_seeds =
      options.harmonic.pennation_rad > 0.0 && options.harmonic.transverse_targets.rows() == 0;
  d.fibres = trace_harmonic_fibres(field, areas.origin,
                                   {.count = options.count,
                                    .resolution = options.resolution,
                                    .stop_potential = areas.insertion_interior.rows() > 0
                                                          ? 0.99
                                                          : 1.0 - 1e-9,
                                    .end_on_boundary = options.harmonic.pennation_rad > 0.0,
                                    .seeding = origin_seeds ? TraceOptions::Seeding::origin_area
                                                            : options.harmonic_seeding,
                                    .seed_by_flux = options.harmonic_seed_by_flux,
                                    .area_seed_fraction = options.harmonic_area_seed_fraction,
                                    .candidate_factor = options.harmonic_candidate_factor,
                                    .area_candidate_factor = options.harmonic_area_candidate_factor},
                                   &areas.insertion);
  // Every point inside the surface: the streamline points lie in the tets, but resampled points
  // on a chord across a concave stretch of surface, or ends cut at the boundary, can fall a few
  // hundredths of a millimetre outside; they move 10 um inside, as in the template method.
  {
    const MeshQuery query(muscle);
    constexpr double inside_margin = 1e-5;
    for (Points3& P : d.fibres.fibres) {
      const VecX s = query.calc_signed_distances(P);
      for (Eigen::Index k = 0; k < P.rows(); ++k) {
        if (!(s(k) > 0.0)) continue;
        const ClosestPoint c = query.calc_closest_point(P.row(k).transpose());
        const auto t = muscle.F.row(c.triangle);
        const Vec3 a = muscle.V.row(t(0)), b = muscle.V.row(t(1)), e = muscle.V.row(t(2));
        P.row(k) = (c.point - inside_margin * (b - a).cross(e - a).normalized()).transpose();
      }
    }
  }
  d.method_used = FibreMethod::harmonic;
  return d;
}

}  // namespace fascicle
