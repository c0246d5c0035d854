// Set-up helpers shared by the built-in muscle representations.
#include "muscle_setup.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/deformation/fibre_embedding.hpp"
#include "fascicle/fibres/decompose.hpp"
#include "fascicle/fibres/fibre_set.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

namespace fascicle::scene_detail {

double get_option(const Muscle& m, const std::string& key, double fallback) {
  const auto it = m.options.find(key);
  return it == m.options.end() ? fallback : it->second;
}

void require_muscle_mesh(const Muscle& m, const std::string& representation) {
  if (m.rest_mesh.V.rows() == 0)
    throw_bad_input("representation '" + representation + "' needs a muscle mesh",
                    {.object = m.name, .suggestion = "give the muscle a mesh, or use 'action_line'"});
}

// Rigid motion of body b from the default pose: X_ground_b(now) · X_ground_b(default)⁻¹.
Transform calc_body_motion(const Model& model, const State& state, BodyIndex b) {
  return state.X_ground_body[b.v] * model.X_ground_body_default[b.v].inverse();
}

// Rest surface vertices within `radius` of the attachment's landmarks (ground, default pose).
std::vector<int> find_area_vertices(const Model& model, const Muscle& m, const Attachment& a) {
  std::vector<int> vertices;
  if (!(a.radius_m > 0.0)) return vertices;
  const Transform& X = model.X_ground_body_default[a.body.v];
  const Points3 landmarks = ((a.p_body * X.linear().transpose()).rowwise() + X.translation().transpose()).eval();
  const Points3& V = m.rest_mesh.V;
  for (Eigen::Index i = 0; i < V.rows(); ++i)
    for (Eigen::Index k = 0; k < landmarks.rows(); ++k)
      if ((V.row(i) - landmarks.row(k)).squaredNorm() <= a.radius_m * a.radius_m) {
        vertices.push_back(static_cast<int>(i));
        break;
      }
  return vertices;
}

Points3 calc_rest_action_line(const Model& model, const Muscle& m) {
  const auto& X = model.X_ground_body_default;
  Points3 line(static_cast<Eigen::Index>(m.via_points.size() + 2), 3);
  line.row(0) = (X[m.origin.body.v] * m.origin.p_body_centroid).transpose();
  for (size_t v = 0; v < m.via_points.size(); ++v)
    line.row(static_cast<Eigen::Index>(v + 1)) = (X[m.via_points[v].body.v] * m.via_points[v].p_body).transpose();
  line.row(line.rows() - 1) = (X[m.insertion.body.v] * m.insertion.p_body_centroid).transpose();
  return line;
}


// The rest fibres of a muscle without given ones: the fibres module's template decomposition of
// the rest surface between the attachment areas (or, when an area has no triangle, the end
// regions of the surface along the origin–insertion direction).
std::vector<Points3> decompose_rest_fibres(const Muscle& m, const std::vector<int>& origin,
                                           const std::vector<int>& insertion, const Vec3& towards_origin) {
  Attachments areas;
  bool use_landmarks = !origin.empty() && !insertion.empty();
  if (use_landmarks) {
    try {
      areas.origin = make_attachment_area(m.rest_mesh, origin, "origin");
      areas.insertion = make_attachment_area(m.rest_mesh, insertion, "insertion");
      check_attachments(m.rest_mesh, areas);
    } catch (const Error&) {
      use_landmarks = false;
    }
  }
  if (!use_landmarks) areas = find_end_attachments(m.rest_mesh, 0.08, towards_origin);
  DecomposeOptions options;
  options.fibre_template = m.fibre_template.empty() ? FibreTemplate::parallel : parse_fibre_template(m.fibre_template);
  options.count = static_cast<int>(get_option(m, "fibre_count", 60));
  options.resolution = static_cast<int>(get_option(m, "fibre_resolution", 15));
  Decomposition d = decompose_muscle(m.rest_mesh, areas, options);
  for (const std::string& w : d.warnings) spdlog::warn("muscle '{}': {}", m.name, w);
  return std::move(d.fibres.fibres);
}

std::vector<Points3> get_or_decompose_rest_fibres(const Model& model, const Muscle& m) {
  if (!m.rest_fibres.empty() || get_option(m, "fibres", 1.0) == 0.0 || m.rest_mesh.V.rows() == 0) return m.rest_fibres;
  const std::vector<int> origin = find_area_vertices(model, m, m.origin);
  std::vector<int> insertion = find_area_vertices(model, m, m.insertion);
  insertion.erase(std::remove_if(insertion.begin(), insertion.end(),
                                 [&](int v) { return std::binary_search(origin.begin(), origin.end(), v); }),
                  insertion.end());
  const Points3 line = calc_rest_action_line(model, m);
  const Vec3 towards_origin = (line.row(0) - line.row(line.rows() - 1)).transpose().normalized();
  return decompose_rest_fibres(m, origin, insertion, towards_origin);
}

void set_fibre_metrics(const VecX& rest_length, MuscleFrame& out) {
  const FibreMetrics metrics = calc_fibre_metrics(out.fibres, out.action_line);
  out.fibre_length_m = metrics.length_m;
  out.fibre_pennation_rad = metrics.pennation_rad;
  out.fibre_strain = (metrics.length_m.array() / rest_length.array() - 1.0).matrix();
  out.mean_fibre_length_m = metrics.mean_length_m;
  out.mean_pennation_rad = metrics.mean_pennation_rad;
}

}  // namespace fascicle::scene_detail
