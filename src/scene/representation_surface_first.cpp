// "surface_first": the muscle's closed surface deformed by Laplacian editing along its action line
// with its enclosed volume held exactly and its vertices kept out of the bones (Kohout et al.,
// seed 002 §4; the solver is deformation/surface_first.hpp, the method docs/deformation.md).
// Fibres are the scene's rest fibres, or the fibres module's decomposition of the rest surface,
// carried by the deformation (deformation/fibre_embedding.hpp).
#include "fascicle/core/error.hpp"
#include "fascicle/deformation/fibre_embedding.hpp"
#include "fascicle/deformation/surface_first.hpp"
#include "fascicle/fibres/decompose.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/model.hpp"
#include "fascicle/scene/state.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

namespace fascicle {
namespace {

double get_option(const Muscle& m, const std::string& key, double fallback) {
  const auto it = m.options.find(key);
  return it == m.options.end() ? fallback : it->second;
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

double calc_polyline_length(const Points3& P) {
  double length = 0.0;
  for (Eigen::Index i = 1; i < P.rows(); ++i) length += (P.row(i) - P.row(i - 1)).norm();
  return length;
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

class SurfaceFirst final : public MuscleRepresentation {
 public:
  SurfaceFirst(const Model& model, MuscleIndex mi) {
    const Muscle& m = model.get_muscle(mi);
    if (m.rest_mesh.V.rows() == 0)
      throw_bad_input("representation 'surface_first' needs a muscle mesh",
                      {.object = m.name, .suggestion = "give the muscle a mesh, or use 'action_line'"});
    SurfaceFirstOptions options;
    options.line_weight = get_option(m, "line_weight", options.line_weight);
    options.contact_weight = get_option(m, "contact_weight", options.contact_weight);
    options.contact_margin_m = get_option(m, "contact_margin", options.contact_margin_m);
    options.line_samples = static_cast<int>(get_option(m, "line_samples", options.line_samples));
    options.max_volume_error = get_option(m, "max_volume_error", options.max_volume_error);
    options.max_contact_rounds = static_cast<int>(get_option(m, "max_contact_rounds", options.max_contact_rounds));

    // Bones the muscle may touch: meshes whose rest box comes within `bone_margin` of the muscle's.
    const double margin = get_option(m, "bone_margin", 0.02);
    Eigen::AlignedBox3d muscle_box(m.rest_mesh.V.colwise().minCoeff().transpose(),
                                   m.rest_mesh.V.colwise().maxCoeff().transpose());
    muscle_box.min().array() -= margin;
    muscle_box.max().array() += margin;
    BoneQueries bones;
    for (int b = 1; b < model.num_bodies(); ++b) {
      const Body& body = model.bodies[b];
      if (!body.rest_query || !body.rest_box.intersects(muscle_box)) continue;
      bones.push_back(body.rest_query.get());
      bone_bodies_.push_back(BodyIndex{b});
    }

    // Attachment areas that hold vertices (a segmented belly may not reach its landmarks).
    const std::vector<int> origin = find_area_vertices(model, m, m.origin);
    std::vector<int> insertion = find_area_vertices(model, m, m.insertion);
    // A vertex near both landmarks belongs to the nearer one only (the origin keeps it).
    insertion.erase(std::remove_if(insertion.begin(), insertion.end(),
                                   [&](int v) { return std::binary_search(origin.begin(), origin.end(), v); }),
                    insertion.end());
    std::vector<SurfaceAttachment> areas;
    if (!origin.empty()) {
      areas.push_back({"origin", origin});
      area_bodies_.push_back(m.origin.body);
    }
    if (!insertion.empty()) {
      areas.push_back({"insertion", insertion});
      area_bodies_.push_back(m.insertion.body);
    }
    const Points3 rest_line = calc_rest_action_line(model, m);
    binding_ = bind_surface(m.rest_mesh, rest_line, std::move(areas), bones, options, m.name);
    bones_ = std::move(bones);

    // Fibres: given, or decomposed from the rest surface (unless "fibres": 0).
    std::vector<Points3> fibres = m.rest_fibres;
    if (fibres.empty() && get_option(m, "fibres", 1.0) != 0.0) {
      const Vec3 towards_origin = (rest_line.row(0) - rest_line.row(rest_line.rows() - 1)).transpose().normalized();
      fibres = decompose_rest_fibres(m, origin, insertion, towards_origin);
    }
    if (!fibres.empty()) {
      FibreEmbeddingOptions embed_options;
      embed_options.max_weights = static_cast<int>(get_option(m, "fibre_weights", 64));
      embedding_ = embed_fibres(binding_, fibres, embed_options);
      rest_fibre_length_.resize(static_cast<Eigen::Index>(fibres.size()));
      for (size_t f = 0; f < fibres.size(); ++f) rest_fibre_length_[f] = calc_polyline_length(fibres[f]);
    }
  }

  struct Frame final : RepresentationState {
    explicit Frame(const SurfaceBinding& binding, BoneQueries bones) : solver(binding, std::move(bones)) {}
    SurfaceFirstSolver solver;
  };

  std::unique_ptr<RepresentationState> make_state() const override {
    return std::make_unique<Frame>(binding_, bones_);
  }

  void calc_geometry(const Model& model, MuscleIndex, const State& state, RepresentationState* rs,
                     MuscleFrame& out) const override {
    auto* frame = dynamic_cast<Frame*>(rs);
    if (!frame) throw_internal("surface_first: the State was not made for this Model (make_state)");
    SurfaceFrameInput input;
    input.action_line = out.action_line;
    for (BodyIndex b : area_bodies_) input.attachment_motions.push_back(calc_body_motion(model, state, b));
    for (BodyIndex b : bone_bodies_) input.bone_motions.push_back(calc_body_motion(model, state, b));
    out.surface = frame->solver.calc_frame(input);
    const SurfaceFrameInfo& info = frame->solver.get_info();
    out.volume_m3 = info.volume_m3;
    out.relative_volume_change = info.volume_m3 / binding_.rest_volume_m3 - 1.0;
    out.max_bone_penetration_m = info.max_penetration_beyond_rest_m;
    if (embedding_.fibre_start.size() > 1) {
      out.fibres = calc_embedded_fibres(embedding_, frame->solver);
      const FibreMetrics metrics = calc_fibre_metrics(out.fibres, out.action_line);
      out.fibre_length_m = metrics.length_m;
      out.fibre_pennation_rad = metrics.pennation_rad;
      out.fibre_strain = (metrics.length_m.array() / rest_fibre_length_.array() - 1.0).matrix();
      out.mean_fibre_length_m = metrics.mean_length_m;
      out.mean_pennation_rad = metrics.mean_pennation_rad;
    } else {
      out.fibres.clear();
    }
  }

 private:
  SurfaceBinding binding_;
  BoneQueries bones_;
  std::vector<BodyIndex> bone_bodies_;  // per bone of the binding
  std::vector<BodyIndex> area_bodies_;  // per attachment area of the binding
  FibreEmbedding embedding_;
  VecX rest_fibre_length_;
};

}  // namespace

std::unique_ptr<const MuscleRepresentation> make_surface_first(const Model& model, MuscleIndex m) {
  return std::make_unique<SurfaceFirst>(model, m);
}

}  // namespace fascicle
