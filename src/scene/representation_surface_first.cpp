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
#include "muscle_setup.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>

namespace fascicle {
namespace {

using namespace scene_detail;

class SurfaceFirst final : public MuscleRepresentation {
 public:
  SurfaceFirst(const Model& model, MuscleIndex mi) {
    const auto start = std::chrono::steady_clock::now();
    const Muscle& m = model.get_muscle(mi);
    require_muscle_mesh(m, "surface_first");
    SurfaceFirstOptions options;
    options.line_weight = get_option(m, "line_weight", options.line_weight);
    options.contact_weight = get_option(m, "contact_weight", options.contact_weight);
    options.contact_margin_m = get_option(m, "contact_margin", options.contact_margin_m);
    options.line_samples = static_cast<int>(get_option(m, "line_samples", options.line_samples));
    options.max_volume_error = get_option(m, "max_volume_error", options.max_volume_error);
    options.max_contact_rounds = static_cast<int>(get_option(m, "max_contact_rounds", options.max_contact_rounds));
    options.max_low_rank = static_cast<int>(get_option(m, "max_low_rank", options.max_low_rank));

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
    const std::vector<Points3> fibres = get_or_decompose_rest_fibres(model, m);
    if (!fibres.empty()) {
      FibreEmbeddingOptions embed_options;
      embed_options.max_weights = static_cast<int>(get_option(m, "fibre_weights", 64));
      embedding_ = embed_fibres(binding_, fibres, embed_options);
      rest_fibre_length_.resize(static_cast<Eigen::Index>(fibres.size()));
      for (size_t f = 0; f < fibres.size(); ++f) rest_fibre_length_[f] = calc_polyline_length(fibres[f]);
    }
    spdlog::debug("surface_first '{}': bound in {:.1f} ms ({} vertices, {} fibres)", m.name,
                  1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(),
                  m.rest_mesh.V.rows(), fibres.size());
  }

  struct Frame final : RepresentationState {
    explicit Frame(const SurfaceBinding& binding, BoneQueries bones) : solver(binding, std::move(bones)) {}
    SurfaceFirstSolver solver;
  };

  std::unique_ptr<RepresentationState> make_state() const override {
    return std::make_unique<Frame>(binding_, bones_);
  }

  void calc_geometry(const Model& model, MuscleIndex mi, const State& state, RepresentationState* rs,
                     MuscleFrame& out) const override {
    auto* frame = dynamic_cast<Frame*>(rs);
    if (!frame) throw_internal("surface_first: the State was not made for this Model (make_state)");
    const auto start = std::chrono::steady_clock::now();
    SurfaceFrameInput input;
    input.action_line = out.action_line;
    for (BodyIndex b : area_bodies_) input.attachment_motions.push_back(calc_body_motion(model, state, b));
    for (BodyIndex b : bone_bodies_) input.bone_motions.push_back(calc_body_motion(model, state, b));
    out.surface = frame->solver.calc_frame(input);
    const SurfaceFrameInfo& info = frame->solver.get_info();
    spdlog::debug("surface_first '{}' t = {:.3f} s: {:.1f} ms, {} contacts, {} rounds, {} solves, {} factorisations "
                  "and {} low-rank updates so far",
                  model.get_muscle(mi).name, state.time_s,
                  1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(),
                  info.active_contacts, info.contact_rounds, info.volume_iterations, info.factorisations,
                  info.low_rank_updates);
    out.volume_m3 = info.volume_m3;
    out.relative_volume_change = info.volume_m3 / binding_.rest_volume_m3 - 1.0;
    out.max_bone_penetration_m = info.max_penetration_beyond_rest_m;
    if (embedding_.fibre_start.size() > 1) {
      out.fibres = calc_embedded_fibres(embedding_, frame->solver);
      set_fibre_metrics(rest_fibre_length_, out);
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
