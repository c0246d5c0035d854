// "fibres_first": the muscles of a scene as particle/spring fibre bundles solved together
// (Kohout et al., seed 002 §5; the solver is deformation/fibres_first.hpp, the method and the
// comparison with surface-first docs/representations.md).
#include "fascicle/core/error.hpp"
#include "fascicle/deformation/fibres_first.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/model.hpp"
#include "fascicle/scene/state.hpp"
#include "muscle_setup.hpp"
#include <spdlog/spdlog.h>
#include <fmt/format.h>

#include <limits>
#include <cmath>

namespace fascicle {
namespace {

using namespace scene_detail;

class FibresFirst final : public MuscleGroupRepresentation {
 public:
  FibresFirst(const Model& model, const std::vector<MuscleIndex>& muscles) {
    // Bones: every body with an obstacle mesh, in body order; and the origin and insertion bodies
    // of the group's muscles even when their mesh is drawn only (an open OpenSim mesh): fibre ends
    // are fixed to them, and their contacts are only as good as that mesh's inside test.
    std::vector<char> attached(model.bodies.size(), 0);
    for (MuscleIndex mi : muscles) {
      attached[model.get_muscle(mi).origin.body.v] = 1;
      attached[model.get_muscle(mi).insertion.body.v] = 1;
    }
    std::vector<int> bone_of_body(model.bodies.size(), -1);
    std::vector<const MeshQuery*> bones;
    for (int b = 1; b < model.num_bodies(); ++b) {
      const Body& body = model.bodies[b];
      const MeshQuery* query = body.rest_query.get();
      if (!query && attached[b] && body.mesh.V.rows() > 0) {
        const Transform& X = model.X_ground_body_default[b];
        own_queries_.push_back(std::make_unique<const MeshQuery>(TriMesh{
            ((body.mesh.V * X.linear().transpose()).rowwise() + X.translation().transpose()).eval(), body.mesh.F}));
        query = own_queries_.back().get();
      }
      if (!query) continue;
      bone_of_body[b] = static_cast<int>(bones.size());
      bones.push_back(query);
      bone_bodies_.push_back(BodyIndex{b});
    }
    const Muscle& first = model.get_muscle(muscles.front());
    // The options configure one solver for the whole group, so every muscle must give the same
    // value (or leave it out for the same default): a conflict is bad input naming both muscles.
    const auto option = [&](const std::string& key, double fallback) {
      const double v = get_option(first, key, fallback);
      for (MuscleIndex mi : muscles) {
        const Muscle& m = model.get_muscle(mi);
        const double w = get_option(m, key, fallback);
        if (!(w == v) && !(std::isnan(w) && std::isnan(v)))
          throw_bad_input(fmt::format("fibres_first option {} differs between muscles '{}' ({}) and '{}' ({}); "
                                      "the fibres-first muscles of a scene are solved as one group",
                                      key, first.name, v, m.name, w),
                          {.object = m.name,
                           .suggestion = fmt::format("give \"{}\" the same value in every fibres-first muscle", key)});
      }
      return v;
    };
    // A switch: 0 (off) or 1 (on).
    const auto flag = [&](const std::string& key, bool fallback) {
      const double v = option(key, fallback ? 1.0 : 0.0);
      if (v != 0.0 && v != 1.0)
        throw_bad_input(fmt::format("fibres_first option {} = {} is not 0 (off) or 1 (on)", key, v),
                        {.object = first.name, .suggestion = fmt::format("set \"{}\" to 0 or 1", key)});
      return v == 1.0;
    };
    FibresFirstOptions o;
    o.particles_per_fibre = static_cast<int>(option("particles_per_fibre", o.particles_per_fibre));
    o.along_stiffness = option("along_stiffness", o.along_stiffness);
    o.across_stiffness = option("across_stiffness", o.across_stiffness);
    o.bending_stiffness = option("bending_stiffness", o.bending_stiffness);
    o.muscle_margin_m = option("muscle_margin", o.muscle_margin_m);
    o.bone_margin_m = option("bone_margin", o.bone_margin_m);
    // display-surface separation (experimental, off by default: see fibres_first.hpp; pairs
    // overlapping at rest by more than surface_rest_overlap_resolved metres keep their rest depths)
    o.separate_surfaces = flag("separate_surfaces", false);
    o.surface_margin_m = option("surface_margin", o.surface_margin_m);
    o.surface_rest_overlap_resolved_m =
        option("surface_rest_overlap_resolved", o.surface_rest_overlap_resolved_m);
    // surface particles (see fibres_first.hpp): the loft's vertices as particles of the system
    o.surface_particles = flag("surface_particles", o.surface_particles);
    o.surface_stiffness = option("surface_stiffness", o.surface_stiffness);
    o.surface_bending = flag("surface_bending", false);
    // NaN: not given (the default, which acts only with surface particles)
    const double frame_stiffness = option("surface_frame_stiffness", std::numeric_limits<double>::quiet_NaN());
    if (!std::isnan(frame_stiffness)) o.surface_frame_stiffness = frame_stiffness;
    o.dynamic = flag("dynamic", false);
    o.damping_per_s = option("damping", o.damping_per_s);
    o.max_iterations = static_cast<int>(option("iterations", o.max_iterations));
    o.stall_iterations = static_cast<int>(option("stall_iterations", o.stall_iterations));
    o.max_contact_rounds = static_cast<int>(option("contact_rounds", o.max_contact_rounds));
    // Fibre ends within this distance of their bone are fixed to it; the others are carried along
    // the action line by a tendon (keeping their rest arc-length fraction; with the option
    // "inextensible_tendon": 1 their rest arc length from the nearer end of the line), so a
    // tendon-less belly does not turn rigidly with a far bone. Default: every end fixed (the library's rigid-tendon default): carrying the ends of
    // gait2392's generated bellies breaks the 0.5 % volume hold at the first frame (ext_hal_r
    // 0.71 % with the tendon rule, 0.54 % with the arc-length-fraction rule), so scenes opt in
    // (examples/vh_shank uses 5 mm).
    o.end_attachment_distance_m =
        option("end_attachment_distance", std::numeric_limits<double>::infinity());
    o.carry_inextensible_tendon = flag("inextensible_tendon", false);
    if (o.surface_bending && !o.surface_particles)
      throw_bad_input("fibres_first option surface_bending needs surface_particles (the bending springs join surface particles)",
                      {.object = first.name, .suggestion = "add \"surface_particles\": 1, or leave surface_bending out"});
    if (frame_stiffness > 0.0 && !o.surface_particles)
      throw_bad_input("fibres_first option surface_frame_stiffness needs surface_particles (the ring frames pull surface particles)",
                      {.object = first.name, .suggestion = "add \"surface_particles\": 1, or leave surface_frame_stiffness out"});

    std::vector<FibreBundleSpec> specs;
    for (MuscleIndex mi : muscles) {
      const Muscle& m = model.get_muscle(mi);
      FibreBundleSpec s;
      s.name = m.name;
      s.fibres = get_or_decompose_rest_fibres(model, m);
      if (s.fibres.empty())
        throw_bad_input("representation 'fibres_first' needs fibres: rest fibres, or a mesh to decompose",
                        {.object = m.name, .suggestion = "give the muscle a mesh (and a fibre_template)"});
      // Fibres run from origin to insertion: reverse those whose first point is nearer the
      // insertion (decompositions and generated pennate fibres may run either way).
      const Points3 line = calc_rest_action_line(model, m);
      const Vec3 o0 = line.row(0).transpose(), i0 = line.row(line.rows() - 1).transpose();
      for (Points3& f : s.fibres) {
        const Vec3 a = f.row(0).transpose(), b = f.row(f.rows() - 1).transpose();
        if ((a - o0).norm() + (b - i0).norm() > (a - i0).norm() + (b - o0).norm()) f = f.colwise().reverse().eval();
      }
      s.origin_bone = bone_of_body[m.origin.body.v];
      s.insertion_bone = bone_of_body[m.insertion.body.v];
      if (s.origin_bone < 0 || s.insertion_bone < 0)
        throw_bad_input("representation 'fibres_first' fixes fibre ends to the origin and insertion bodies, "
                        "which need meshes",
                        {.object = m.name, .suggestion = "give body '" +
                                                         model.bodies[(s.origin_bone < 0 ? m.origin : m.insertion).body.v].name +
                                                         "' a mesh, or use 'surface_first'"});
      s.volume_m3 = m.rest_volume_m3;
      s.action_line = line;
      s.rest_surface = m.rest_mesh;  // the boundary fibres follow its outline
      specs.push_back(std::move(s));
    }
    model_ = build_fibres_first_model(specs, bones, o);
    // The display surfaces at rest: the solver's own reconstruction with every bone at rest.
    const std::vector<FibreBundleFrame> at_rest = calc_fibres_first_frame(model_, FibresFirstInput{});
    rest_surfaces_.resize(muscles.size());
    rest_fibre_length_.resize(muscles.size());
    for (size_t k = 0; k < muscles.size(); ++k) {
      const FibreBundle& bundle = model_.muscles[k];
      rest_surfaces_[k].F = bundle.surface_triangles;
      rest_surfaces_[k].V = at_rest[k].surface_vertices;
      const std::vector<Points3> fibres = calc_rest_fibres(static_cast<int>(k));
      rest_fibre_length_[k].resize(static_cast<Eigen::Index>(fibres.size()));
      for (size_t f = 0; f < fibres.size(); ++f) rest_fibre_length_[k][f] = calc_polyline_length(fibres[f]);
    }
  }

  struct Frame final : RepresentationState {
    explicit Frame(const FibresFirstModel& model) : solver(model) {}
    FibresFirstSolver solver;
    double last_time_s = std::numeric_limits<double>::quiet_NaN();
  };

  std::unique_ptr<RepresentationState> make_state() const override { return std::make_unique<Frame>(model_); }

  const TriMesh* get_rest_surface(int member) const override { return &rest_surfaces_.at(member); }

  void calc_geometry(const Model& model, const std::vector<MuscleIndex>& muscles, const State& state,
                     RepresentationState* rs, const std::vector<MuscleFrame*>& out) const override {
    auto* frame = dynamic_cast<Frame*>(rs);
    if (!frame) throw_internal("fibres_first: the State was not made for this Model (make_state)");
    FibresFirstInput input;
    for (BodyIndex b : bone_bodies_) input.bone_motions.push_back(calc_body_motion(model, state, b));
    for (size_t k = 0; k < muscles.size(); ++k) input.action_lines.push_back(out[k]->action_line);
    if (std::isfinite(frame->last_time_s) && state.time_s > frame->last_time_s)
      input.time_step_s = state.time_s - frame->last_time_s;
    frame->solver.calc_frame(input);
    const FibresFirstInfo& info = frame->solver.get_info();
    spdlog::debug("fibres_first t = {:.3f} s: {} iterations, {} solves, {} contact rounds, {} final passes{}",
                  state.time_s, info.iterations, info.solves, info.contact_rounds, info.final_passes,
                  info.final_state_restored ? fmt::format(" (ended in the state of stage {})", info.final_state_restored)
                                            : std::string());
    frame->last_time_s = state.time_s;
    const auto& results = frame->solver.get_muscles();
    for (size_t k = 0; k < muscles.size(); ++k) {
      MuscleFrame& o = *out[k];
      const FibreBundleFrame& r = results[k];
      o.surface = r.surface_vertices;
      o.volume_m3 = r.volume_m3;
      o.relative_volume_change = r.volume_m3 / model_.muscles[k].rest_volume_m3 - 1.0;
      o.max_bone_penetration_m = r.max_bone_penetration_m;
      o.fibres = frame->solver.calc_fibres(static_cast<int>(k));
      set_fibre_metrics(rest_fibre_length_[k], o);
    }
  }

 private:
  std::vector<Points3> calc_rest_fibres(int k) const {
    const FibreBundle& bundle = model_.muscles[k];
    const int P = model_.options.particles_per_fibre;
    std::vector<Points3> fibres;
    for (int f = 0; f < bundle.num_fibres; ++f) fibres.push_back(model_.rest.middleRows(bundle.first_particle + f * P, P));
    return fibres;
  }

  std::vector<std::unique_ptr<const MeshQuery>> own_queries_;  // drawn-only attachment bodies
  FibresFirstModel model_;
  std::vector<BodyIndex> bone_bodies_;  // per bone of the model
  std::vector<TriMesh> rest_surfaces_;  // per member
  std::vector<VecX> rest_fibre_length_; // per member, per fibre
};

}  // namespace

std::unique_ptr<const MuscleGroupRepresentation> make_fibres_first(const Model& model,
                                                                   const std::vector<MuscleIndex>& muscles) {
  return std::make_unique<FibresFirst>(model, muscles);
}

}  // namespace fascicle
