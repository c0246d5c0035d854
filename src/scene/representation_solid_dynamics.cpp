// "solid_dynamics": the muscle as a volumetric B-spline solid in motion (seed 000 ch. 4; the solver
// is dynamics/solid_dynamics.hpp, the method docs/solid-dynamics.md). At set-up the rest surface is
// fitted with a cylindrical B-spline solid along the origin → insertion axis, its end layers are
// attached to the origin and insertion, the bones near the muscle become contact meshes, and the
// muscle's own rest mesh is embedded in the solid (free-form deformation, seed 000 §3.1.3). Each
// frame integrates the solid from the previous frame's time to this one (backward Euler, sub-steps,
// the scene's activation as the excitation) with the attachments and bones interpolated between
// the two frames' poses; the surface is the embedded rest mesh (same rows and faces as the
// Model's rest mesh), the fibres are iso-parametric curves of the solid's fibre direction.
#include "fascicle/bspline/fitting.hpp"
#include "fascicle/bspline/membership.hpp"
#include "fascicle/bspline/tessellation.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/deformation/mesh_operators.hpp"
#include "fascicle/dynamics/contact.hpp"
#include "fascicle/dynamics/solid_dynamics.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/model.hpp"
#include "fascicle/scene/state.hpp"
#include "muscle_setup.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <Eigen/Geometry>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <exception>
#include <functional>

namespace fascicle {
namespace {

using namespace scene_detail;

// Drivers of the solver's StepInputs::X_now_rest: [0] origin end, [1] insertion end, [2 + k] bone k.
constexpr int kOriginDriver = 0, kInsertionDriver = 1, kFirstBoneDriver = 2;

// A rigid motion between two others: rotation by slerp, translation linearly.
Transform interpolate_motion(const Transform& a, const Transform& b, double t) {
  const Eigen::Quaterniond qa(a.linear()), qb(b.linear());
  Transform X = Transform::Identity();
  X.linear() = qa.slerp(t, qb).toRotationMatrix();
  X.translation() = (1.0 - t) * a.translation() + t * b.translation();
  return X;
}

// A point at arc length s along a polyline (from its first point), with the unit direction of the
// segment there; beyond the ends the first/last segment is extended.
std::pair<Vec3, Vec3> calc_point_at_arc(const Points3& line, double s) {
  const Eigen::Index n = line.rows();
  double start = 0.0;
  for (Eigen::Index i = 0; i + 1 < n; ++i) {
    const Vec3 a = line.row(i).transpose(), b = line.row(i + 1).transpose();
    const double l = (b - a).norm();
    if (!(l > 0.0)) continue;
    if (s <= start + l || i + 2 == n) return {a + (s - start) / l * (b - a), (b - a) / l};
    start += l;
  }
  return {line.row(0).transpose(), Vec3::UnitZ()};
}

// Arc length (from the polyline's first point) of the point of the polyline closest to p.
double find_closest_arc(const Points3& line, const Vec3& p) {
  double best = INFINITY, best_s = 0.0, start = 0.0;
  for (Eigen::Index i = 0; i + 1 < line.rows(); ++i) {
    const Vec3 a = line.row(i).transpose(), b = line.row(i + 1).transpose();
    const double l = (b - a).norm();
    if (!(l > 0.0)) continue;
    const double t = std::clamp((p - a).dot(b - a) / (l * l), 0.0, 1.0);
    const double d = (a + t * (b - a) - p).squaredNorm();
    if (d < best) best = d, best_s = start + t * l;
    start += l;
  }
  return best_s;
}

Points3 reversed_rows(const Points3& P) { return P.colwise().reverse().eval(); }

// An integer option of a muscle, checked before the conversion (casting NaN or a double beyond
// int's range is undefined): a finite whole number in [lo, hi], else bad input naming the muscle
// and the option.
int get_int_option(const Muscle& m, const std::string& key, int fallback, int lo, int hi) {
  const double v = get_option(m, key, fallback);
  if (!(v >= lo && v <= hi) || v != std::floor(v))
    throw_bad_input(fmt::format("solid_dynamics option {} = {} is not a whole number from {} to {}", key, v, lo, hi),
                    {.object = m.name,
                     .suggestion = fmt::format("set \"{}\" to a whole number from {} to {}, or leave it out for {}", key,
                                               lo, hi, fallback)});
  return static_cast<int>(v);
}

// A positive finite time option (s).
double get_time_option(const Muscle& m, const std::string& key, double fallback) {
  const double v = get_option(m, key, fallback);
  if (!(v > 0.0) || !std::isfinite(v))
    throw_bad_input(fmt::format("solid_dynamics option {} = {} s is not a positive finite time", key, v),
                    {.object = m.name,
                     .suggestion = fmt::format("set \"{}\" to a positive time in s, or leave it out for {}", key, fallback)});
  return v;
}

// Most sub-steps one frame may take: more means a tiny time_step or a huge frame interval.
constexpr double kMaxSubsteps = 1e6;

// How one end layer of the solid moves. An end whose attachment area lies on the rest surface
// follows its body rigidly. An end whose landmarks are away from the belly (e.g. a soleus ending in
// the Achilles tendon) keeps its arc length from that end of the action line, as through an
// inextensible tendon: it moves with the line's point at that arc length and turns with the line's
// direction there.
struct EndDriver {
  bool rigid = true;
  BodyIndex body;
  bool from_end = false;   // arc length measured from the insertion end of the line
  double arc_m = 0.0;
  Vec3 p_rest = Vec3::Zero(), d_rest = Vec3::UnitZ();
};

struct SolidOptions {
  std::array<int, 3> lattice{3, 8, 6};
  int degree = 2;
  double time_step_s = 0.005;
  int reuse_factorisation = SolverOptions{}.reuse_factorisation_steps;  // the solver's default policy
  int settle_steps = 8;
  double settle_step_s = 0.01;
};

class SolidDynamicsRepresentation final : public MuscleRepresentation {
 public:
  SolidDynamicsRepresentation(const Model& model, MuscleIndex mi) {
    const Muscle& m = model.get_muscle(mi);
    require_muscle_mesh(m, "solid_dynamics");
    name_ = m.name;
    options_.lattice = {get_int_option(m, "lattice_u", 3, 2, 256), get_int_option(m, "lattice_v", 8, 3, 256),
                        get_int_option(m, "lattice_w", 6, 2, 256)};
    options_.degree = get_int_option(m, "degree", 2, 1, 5);
    options_.time_step_s = get_time_option(m, "time_step", options_.time_step_s);
    options_.reuse_factorisation = get_int_option(m, "reuse_factorisation", options_.reuse_factorisation, 0, 1000000);
    options_.settle_steps = get_int_option(m, "settle_steps", options_.settle_steps, 1, 1000000);
    options_.settle_step_s = get_time_option(m, "settle_step", options_.settle_step_s);
    if (options_.lattice[0] < 2 || options_.lattice[1] < 3 || options_.lattice[2] < 2 || options_.degree < 1 ||
        !(options_.time_step_s > 0.0) || options_.settle_steps < 1)
      throw_bad_input("solid_dynamics options: need lattice_u >= 2, lattice_v >= 3, lattice_w >= 2, degree >= 1, "
                      "time_step > 0 and settle_steps >= 1",
                      {.object = m.name});

    SolidDynamicsSpec spec;
    spec.gravity_m_s2.setZero();  // scenes carry no gravity direction; the bones hold the muscle
    spec.density_kg_m3 = get_option(m, "density", spec.density_kg_m3);
    spec.ground.c1_Pa = get_option(m, "c1", 5e4);
    spec.ground.c2_Pa = get_option(m, "c2", 0.5 * spec.ground.c1_Pa);
    spec.rayleigh_alpha_1_s = get_option(m, "damping", 10.0);
    spec.pennation_rad = get_option(m, "pennation", 0.0);
    spec.tendon_fraction_start = spec.tendon_fraction_end = get_option(m, "tendon_fraction", 0.0);
    spec.tendon_modulus_Pa = get_option(m, "tendon_modulus", spec.tendon_modulus_Pa);
    spec.fibre.sigma_max_Pa = get_option(m, "max_stress", spec.fibre.sigma_max_Pa);
    const double penalty = get_option(m, "volume_penalty", 0.0);
    if (penalty > 0.0) {
      spec.volume = VolumeMethod::penalty;
      spec.volume_stiffness_Pa = penalty;
    }

    // Bones the muscle may touch: obstacle meshes whose rest box comes within bone_margin of the
    // muscle's. Boundary points of the solid already inside a bone at rest stay exempt.
    const double margin = get_option(m, "bone_margin", 0.02);
    Eigen::AlignedBox3d box(m.rest_mesh.V.colwise().minCoeff().transpose(), m.rest_mesh.V.colwise().maxCoeff().transpose());
    box.min().array() -= margin;
    box.max().array() += margin;
    if (get_option(m, "contact", 1.0) != 0.0)
      for (int b = 1; b < model.num_bodies(); ++b) {
        const Body& body = model.bodies[b];
        if (!body.rest_query || !body.mesh_is_obstacle || !body.rest_box.intersects(box)) continue;
        BoneContactSpec c;
        c.name = body.name;
        c.body = kFirstBoneDriver + static_cast<int>(bone_bodies_.size());
        c.mesh_rest = body.rest_query->get_mesh();
        c.exempt_rest_contact = true;
        spec.contact_bones.push_back(std::move(c));
        bone_bodies_.push_back(BodyIndex{b});
      }

    // Rest-mesh vertices within contact_margin of a contact bone (inside included).
    const double contact_margin = get_option(m, "contact_margin", 0.01);
    std::vector<char> near_bone(static_cast<std::size_t>(m.rest_mesh.V.rows()), 0);
    for (const BodyIndex b : bone_bodies_) {
      const VecX sd = model.get_body(b).rest_query->calc_signed_distances(m.rest_mesh.V);
      for (Eigen::Index i = 0; i < sd.size(); ++i)
        if (sd[i] < contact_margin) near_bone[static_cast<std::size_t>(i)] = 1;
    }
    spec.contact_stiffness_N_m = get_option(m, "contact_stiffness", 2000.0);

    // The solid: fitted along the origin → insertion axis, then (if that fit fails or comes out
    // inverted somewhere) without the parameter correction, then along the mesh's long axis.
    const Vec3 origin_c = model.X_ground_body_default[m.origin.body.v] * m.origin.p_body_centroid;
    const Vec3 insertion_c = model.X_ground_body_default[m.insertion.body.v] * m.insertion.p_body_centroid;
    Vec3 origin_layer = Vec3::Zero(), insertion_layer = Vec3::Zero();
    for (int attempt = 0; attempt < 4 && !model_; ++attempt) {
      BSplineSolid solid;
      try {
        solid = fit_rest_solid(model, m, attempt);
        // Contact samples at the material points of the rest-mesh vertices near a contact bone
        // (the output surface is embedded there), in addition to the boundary samples.
        locate_rest_surface(m, solid);
        embed_rest_surface(m, solid);
        spec.contact_material_points.clear();
        spec.contact_material_offsets.clear();
        for (std::size_t i = 0; i < vertex_material_.size(); ++i)
          if (near_bone[i]) {
            spec.contact_material_points.push_back(vertex_material_[i]);
            spec.contact_material_offsets.push_back(offset_material_.row(static_cast<Eigen::Index>(i)).transpose());
          }
        // Which end layer is the origin: the one nearer the origin landmarks' centroid.
        const auto layer_centroid = [&](int side) {
          Vec3 c = Vec3::Zero();
          const std::vector<int> layer = find_end_layer(solid, side);
          for (int i : layer) c += solid.P.row(i).transpose();
          return Vec3(c / static_cast<double>(layer.size()));
        };
        const Vec3 c0 = layer_centroid(0), c1 = layer_centroid(1);
        const int origin_side =
            (c0 - origin_c).norm() + (c1 - insertion_c).norm() <= (c1 - origin_c).norm() + (c0 - insertion_c).norm() ? 0 : 1;
        origin_layer = origin_side == 0 ? c0 : c1;
        insertion_layer = origin_side == 0 ? c1 : c0;
        spec.attachments = {{"origin", kOriginDriver, find_end_layer(solid, origin_side)},
                            {"insertion", kInsertionDriver, find_end_layer(solid, 1 - origin_side)}};
        model_ = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(solid, spec));
      } catch (const Error& e) {
        if (e.kind() != ErrorKind::bad_input || attempt == 3) {
          ErrorContext c = e.context();
          c.object = m.name;
          if (c.suggestion.empty() || e.kind() == ErrorKind::bad_input)
            c.suggestion = "the solid is fitted to slices of the muscle mesh (each must be one closed contour); "
                           "try the options lattice_u, lattice_v, lattice_w, degree, slices or end_inset";
          throw Error(e.kind(), "solid_dynamics: no valid B-spline solid for the muscle mesh: " + e.message(), c);
        }
        spdlog::debug("muscle '{}': solid fit {} rejected ({}); trying another", m.name, attempt, e.message());
      }
    }
    spdlog::debug("muscle '{}': solid dynamics with {} contact bones, {} contact samples ({} at rest-mesh vertices)",
                  m.name, bone_bodies_.size(), model_->contact_samples.size(), spec.contact_material_points.size());
    const Points3 rest_line = calc_rest_action_line(model, m);
    ends_[0] = make_end_driver(model, m, m.origin, false, rest_line, origin_layer);
    ends_[1] = make_end_driver(model, m, m.insertion, true, rest_line, insertion_layer);
    solver_options_.integrator = Integrator::backward_euler;
    solver_options_.reuse_factorisation_steps = std::max(0, options_.reuse_factorisation);

    make_fibre_grid(m);
    setup_penetration(model, m);
    rest_box_ = Eigen::AlignedBox3d(m.rest_mesh.V.colwise().minCoeff().transpose(),
                                    m.rest_mesh.V.colwise().maxCoeff().transpose());
  }

  struct Frame final : RepresentationState {
    Frame(std::shared_ptr<const SolidDynamicsModel> model, SolverOptions options)
        : solver(std::move(model), options) {}
    SolidDynamicsSolver solver;
    bool started = false;
    double time_s = 0.0;
    std::vector<Transform> X_prev;  // drivers at the previous frame
    std::vector<Transform> X_now;   // drivers at this frame (between begin_frame and end_frame)
    double activation = 0.0, dt = 0.0;
    std::vector<std::vector<Eigen::Index>> near_bone;  // per bone: surface vertices near it this frame
  };

  std::unique_ptr<RepresentationState> make_state() const override {
    return std::make_unique<Frame>(model_, solver_options_);
  }

  void calc_geometry(const Model& model, MuscleIndex mi, const State& state, RepresentationState* rs,
                     MuscleFrame& out) const override {
    Frame& frame = get_frame(rs);
    const int n = begin_frame(model, mi, state, frame, out);
    for (int k = 0; k < n; ++k) calc_substep(model, frame, k, n, Points3());
    end_frame(model, state, frame, out);
  }

  // The per-frame work in three parts, so that a group can step its muscles together and exchange
  // contact forces between sub-steps. begin_frame: the drivers and activation of this frame; settles
  // on the first frame (or when time goes backwards) and returns the number of sub-steps to take
  // (0 when settled or when time stands still).
  static Frame& get_frame(RepresentationState* rs) {
    auto* frame = dynamic_cast<Frame*>(rs);
    if (!frame) throw_internal("solid_dynamics: the State was not made for this Model (make_state)");
    return *frame;
  }

  int begin_frame(const Model& model, MuscleIndex mi, const State& state, Frame& frame, const MuscleFrame& out) const {
    const Muscle& m = model.get_muscle(mi);
    frame.activation = mi.v < state.activation.size() && std::isfinite(state.activation[mi.v]) ? state.activation[mi.v]
                                                                                               : m.activation;
    frame.X_now = calc_drivers(model, state, out.action_line);
    frame.dt = state.time_s - frame.time_s;
    if (!frame.started || frame.dt < 0.0) {
      settle(frame, frame.X_now, state.time_s);
      frame.dt = 0.0;
      return 0;
    }
    if (!(frame.dt > 0.0)) return 0;
    find_near_bone(model, frame);
    return count_substeps(frame.dt);
  }

  // Broad phase of the frame's bone contact: surface vertices within kNearBone_m of each bone (at
  // the previous frame's pose; a frame moves a vertex far less than that).
  void find_near_bone(const Model& model, Frame& frame) const {
    const Points3 S = calc_surface(frame.solver.get_state().P);
    frame.near_bone.assign(bone_bodies_.size(), {});
    for (std::size_t k = 0; k < bone_bodies_.size(); ++k) {
      const Body& body = model.get_body(bone_bodies_[k]);
      const Transform X_rest_now = frame.X_prev[kFirstBoneDriver + k].inverse();
      Eigen::AlignedBox3d box = body.rest_box;
      box.min().array() -= kNearBone_m;
      box.max().array() += kNearBone_m;
      std::vector<Eigen::Index> in_box;
      Points3 local(S.rows(), 3);
      for (Eigen::Index i = 0; i < S.rows(); ++i) {
        const Vec3 p = X_rest_now * Vec3(S.row(i).transpose());
        if (!box.contains(p)) continue;
        local.row(static_cast<Eigen::Index>(in_box.size())) = p.transpose();
        in_box.push_back(i);
      }
      const VecX sd = body.rest_query->calc_signed_distances(local.topRows(static_cast<Eigen::Index>(in_box.size())));
      for (std::size_t j = 0; j < in_box.size(); ++j)
        if (sd[static_cast<Eigen::Index>(j)] < kNearBone_m) frame.near_bone[k].push_back(in_box[j]);
    }
  }

  int count_substeps(double dt) const {
    const double n = std::ceil(dt / options_.time_step_s - 1e-9);
    if (!(n <= kMaxSubsteps))
      throw_bad_input(fmt::format("solid_dynamics: a frame interval of {} s needs {} sub-steps of time_step {} s (at "
                                  "most {} per frame)",
                                  dt, n, options_.time_step_s, kMaxSubsteps),
                      {.object = name_,
                       .suggestion = "check the motion's times (seconds, increasing) or increase \"time_step\""});
    return std::max(1, static_cast<int>(n));
  }

  // Sub-step k of n of the frame, with optional external generalised forces (#P × 3, N).
  void calc_substep(const Model& model, Frame& frame, int k, int n, const Points3& external) const {
    StepInputs in;
    in.excitation = frame.activation;
    in.external_forces = external;
    in.X_now_rest.resize(frame.X_now.size());
    for (std::size_t d = 0; d < frame.X_now.size(); ++d)
      in.X_now_rest[d] = interpolate_motion(frame.X_prev[d], frame.X_now[d], static_cast<double>(k + 1) / n);
    frame.solver.step(frame.dt / n, in);
    project_bone_contact(model, frame.solver, in.X_now_rest, frame.near_bone);
  }

  void end_frame(const Model& model, const State& state, Frame& frame, MuscleFrame& out) const {
    frame.X_prev = frame.X_now;
    frame.time_s = state.time_s;
    fill_frame(model, state, frame.solver, frame.X_now, out);
  }

  const SolidDynamicsModel& get_model() const { return *model_; }
  // The muscle's rest mesh box (m), for the group's rest-pose adjacency.
  const Eigen::AlignedBox3d& get_rest_box() const { return rest_box_; }

 private:
  // attempt 0: along the origin → insertion axis; 1: the same without the fit's parameter
  // correction and mesh-vertex samples; 2, 3: the same two along the mesh's long axis.
  BSplineSolid fit_rest_solid(const Model& model, const Muscle& m, int attempt) const {
    MeshFitOptions o;
    o.count = options_.lattice;
    o.degree = {std::min(options_.degree, std::min(2, o.count[0] - 1)), options_.degree,
                std::min(options_.degree, o.count[2] - 1)};
    o.num_slices = get_int_option(m, "slices", 48, 3, 100000);
    // End caps a little inside the mesh's tips: a tapered (spindle) belly fitted to its very tips
    // gives nearly collapsed end layers, badly conditioned for the dynamics.
    o.end_inset = get_option(m, "end_inset", 0.05);
    o.name = m.name;
    if (attempt % 2 == 1) {
      o.reparametrise_iterations = 0;
      o.mesh_vertex_samples = false;
    }
    if (attempt < 2) {
      o.origin = model.X_ground_body_default[m.origin.body.v] * m.origin.p_body_centroid;
      o.insertion = model.X_ground_body_default[m.insertion.body.v] * m.insertion.p_body_centroid;
    }
    return fit_solid_to_mesh(m.rest_mesh, o).solid;
  }

  EndDriver make_end_driver(const Model& model, const Muscle& m, const Attachment& att, bool from_end,
                            const Points3& rest_line, const Vec3& layer_centroid) const {
    EndDriver d;
    d.body = att.body;
    d.from_end = from_end;
    d.rigid = !find_area_vertices(model, m, att).empty() || get_option(m, "rigid_ends", 0.0) != 0.0;
    if (d.rigid) return d;
    const Points3 line = from_end ? reversed_rows(rest_line) : rest_line;
    d.arc_m = find_closest_arc(line, layer_centroid);
    std::tie(d.p_rest, d.d_rest) = calc_point_at_arc(line, d.arc_m);
    return d;
  }

  std::vector<Transform> calc_drivers(const Model& model, const State& state, const Points3& action_line) const {
    std::vector<Transform> X(kFirstBoneDriver + bone_bodies_.size(), Transform::Identity());
    for (int e = 0; e < 2; ++e) {
      const EndDriver& d = ends_[e];
      if (d.rigid || action_line.rows() < 2) {
        X[e] = calc_body_motion(model, state, d.body);
        continue;
      }
      const Points3 line = d.from_end ? reversed_rows(action_line) : action_line;
      const auto [p, dir] = calc_point_at_arc(line, d.arc_m);
      Transform T = Transform::Identity();
      T.linear() = Eigen::Quaterniond::FromTwoVectors(d.d_rest, dir).toRotationMatrix();
      T.translation() = p - T.linear() * d.p_rest;
      X[e] = T;
    }
    for (std::size_t k = 0; k < bone_bodies_.size(); ++k)
      X[kFirstBoneDriver + k] = calc_body_motion(model, state, bone_bodies_[k]);
    return X;
  }

  // First frame (or time went backwards): start from rest, passive, then bring the attachments and
  // bones from the rest pose to this frame's in quasi-static steps. Activation starts at 0 and
  // follows the scene's (as excitation) through activation dynamics from then on. (A quasi-static
  // active muscle between fixed ends has no unique equilibrium on the force–length curve.)
  void settle(Frame& frame, const std::vector<Transform>& X_now, double time_s) const {
    SolidState s;
    s.P = model_->rest.P;
    s.V = Points3::Zero(s.P.rows(), 3);
    s.activation = 0.0;
    bool at_rest = true;
    for (const Transform& X : X_now) at_rest = at_rest && X.isApprox(Transform::Identity(), 1e-12);
    if (!at_rest) {
      SolidDynamicsSolver quasi(model_, solver_options_);
      quasi.set_state(s);
      const std::vector<Transform> I(X_now.size(), Transform::Identity());
      StepInputs in;
      in.excitation = s.activation;
      for (int k = 0; k < options_.settle_steps; ++k) {
        in.X_now_rest.resize(X_now.size());
        for (std::size_t d = 0; d < X_now.size(); ++d)
          in.X_now_rest[d] = interpolate_motion(I[d], X_now[d], static_cast<double>(k + 1) / options_.settle_steps);
        quasi.step(options_.settle_step_s, in);
      }
      s = quasi.get_state();
      s.V.setZero();
    }
    s.time_s = time_s;
    s.activation = 0.0;
    frame.solver.set_state(std::move(s));
    frame.started = true;
  }

  // The rest mesh in the solid: each vertex at material point U_i with the offset o_i to its
  // closest solid point (vertices slightly outside the fitted solid). The offset is carried to
  // first order by the solid's local map: x_i = x(U_i) + J(U_i) J_rest(U_i)⁻¹ o_i (exact for rigid
  // and affine motions).
  // Closest material point of each rest-mesh vertex in `solid` (vertex_material_).
  void locate_rest_surface(const Muscle& m, const BSplineSolid& solid) {
    const Points3& X = m.rest_mesh.V;
    const SolidLocator locator(solid);
    vertex_material_.assign(static_cast<std::size_t>(X.rows()), Vec3::Zero());
    parallel_for(vertex_material_.size(), [&](std::size_t i) {
      vertex_material_[i] = locator.locate(X.row(static_cast<Eigen::Index>(i)).transpose()).material;
    });
  }

  void embed_rest_surface(const Muscle& m, const BSplineSolid& solid) {
    const Points3& X = m.rest_mesh.V;
    const int n = solid.num_control_points();
    const auto rows = X.rows();
    std::array<std::vector<Eigen::Triplet<double>>, 4> t;
    for (Eigen::Index i = 0; i < rows; ++i) {
      const Vec3 U = vertex_material_[static_cast<std::size_t>(i)];
      append_basis_row(solid, U, {0, 0, 0}, static_cast<int>(i), t[0]);
      append_basis_row(solid, U, {1, 0, 0}, static_cast<int>(i), t[1]);
      append_basis_row(solid, U, {0, 1, 0}, static_cast<int>(i), t[2]);
      append_basis_row(solid, U, {0, 0, 1}, static_cast<int>(i), t[3]);
    }
    for (int d = 0; d < 4; ++d) {
      surface_w_[d].resize(rows, n);
      surface_w_[d].setFromTriplets(t[d].begin(), t[d].end());
    }
    const Points3 x0 = surface_w_[0] * solid.P;
    const Points3 J0[3] = {surface_w_[1] * solid.P, surface_w_[2] * solid.P, surface_w_[3] * solid.P};
    offset_material_ = Points3::Zero(rows, 3);
    offset_fixed_ = Points3::Zero(rows, 3);
    int outside = 0;
    for (Eigen::Index i = 0; i < rows; ++i) {
      const Vec3 o = (X.row(i) - x0.row(i)).transpose();
      if (o.norm() > 1e-9) ++outside;
      Mat3 J;
      for (int d = 0; d < 3; ++d) J.col(d) = J0[d].row(i).transpose();
      const Vec3 dU = J.fullPivLu().solve(o);
      if (dU.allFinite() && (J * dU - o).norm() <= 1e-9 + 1e-6 * o.norm())
        offset_material_.row(i) = dU.transpose();
      else
        offset_fixed_.row(i) = o.transpose();
    }
    // The whole map in one matrix: x_i = Σ_I (N_I(U_i) + ∇_U N_I(U_i)·dU_i) P_I + fixed offset.
    surface_map_ = surface_w_[0];
    for (int d = 0; d < 3; ++d)
      surface_map_ += (offset_material_.col(d).asDiagonal() * surface_w_[1 + d]).eval();
    surface_map_.prune(0.0);
    spdlog::debug("muscle '{}': {} of {} surface vertices outside the fitted solid", m.name, outside, rows);
  }

  Points3 calc_surface(const Points3& P) const { return surface_map_ * P + offset_fixed_; }

  // A surface vertex inside a contact bone beyond its rest depth: world unit normal towards the
  // bone's closest surface point and the depth beyond the rest contact (m).
  struct SurfaceContact {
    Eigen::Index vertex = 0;
    Vec3 normal = Vec3::Zero();
    double depth = 0.0;
  };

  // Only the vertices of `near[k]` are tested against bone k (the frame's broad phase).
  std::vector<SurfaceContact> find_surface_contacts(const Model& model, const Points3& S, const std::vector<Transform>& X,
                                                    const std::vector<std::vector<Eigen::Index>>& near) const {
    std::vector<SurfaceContact> out;
    for (std::size_t k = 0; k < bone_bodies_.size() && k < near.size(); ++k) {
      const Body& body = model.get_body(bone_bodies_[k]);
      const Transform& X_now = X[kFirstBoneDriver + k];
      const Transform X_rest_now = X_now.inverse();
      std::vector<Eigen::Index> in_box;
      Points3 local(static_cast<Eigen::Index>(near[k].size()), 3);
      for (const Eigen::Index i : near[k]) {
        const Vec3 p = X_rest_now * Vec3(S.row(i).transpose());
        if (!body.rest_box.contains(p)) continue;
        local.row(static_cast<Eigen::Index>(in_box.size())) = p.transpose();
        in_box.push_back(i);
      }
      if (in_box.empty()) continue;
      const VecX sd = body.rest_query->calc_signed_distances(local.topRows(static_cast<Eigen::Index>(in_box.size())));
      for (std::size_t j = 0; j < in_box.size(); ++j) {
        const Eigen::Index i = in_box[j];
        const double depth = -sd[static_cast<Eigen::Index>(j)] - rest_depth_[k][i];
        if (!(depth > kContactTolerance_m)) continue;
        const Vec3 p = local.row(static_cast<Eigen::Index>(j)).transpose();
        const Vec3 d = body.rest_query->calc_closest_point(p).point - p;
        if (!(d.norm() > 0.0)) continue;
        out.push_back({i, X_now.linear() * d.normalized(), depth});
      }
    }
    return out;
  }

  // Sliding bone contact as a constraint (seed 000 §4.7), after each step: the smallest
  // mass-weighted change of the free control points that brings every surface vertex found inside
  // a bone beyond its rest depth back onto the bone's tangent plane (n·Δx_i ≥ depth_i, push only),
  // keeping the volume to first order (∇V·ΔP = 0). The vertices are linear in P (x = A P + c), so
  // with multipliers λ ≥ 0 the change is ΔP = M⁻¹ Aᵀ (n λ); λ from projected Gauss–Seidel on the
  // rows. Then the inward normal velocity of those vertices is removed the same way (inelastic,
  // frictionless). Repeated while the new positions reach other triangles of the bone.
  void project_bone_contact(const Model& model, SolidDynamicsSolver& solver, const std::vector<Transform>& X,
                            const std::vector<std::vector<Eigen::Index>>& near) const {
    if (bone_bodies_.empty()) return;
    const SolidDynamicsModel& sm = solver.get_model();
    const Eigen::Index n = sm.rest.num_control_points();
    VecX inv_mass = VecX::Zero(n);
    for (Eigen::Index I = 0; I < n; ++I)
      if (!sm.fixed[static_cast<std::size_t>(I)] && sm.lumped_mass[I] > 0.0) inv_mass[I] = 1.0 / sm.lumped_mass[I];
    SolidState s = solver.get_state();
    std::vector<SurfaceContact> first;
    for (int round = 0; round < 4; ++round) {
      const std::vector<SurfaceContact> contacts = find_surface_contacts(model, calc_surface(s.P), X, near);
      if (contacts.empty()) break;
      if (round == 0) first = contacts;
      VecX target(static_cast<Eigen::Index>(contacts.size()));
      for (std::size_t c = 0; c < contacts.size(); ++c) target[static_cast<Eigen::Index>(c)] = contacts[c].depth;
      const Points3 dP = solve_contact_rows(sm, s, X, contacts, target, inv_mass);
      // A correction that would invert the solid somewhere is shortened (the penalty of the next
      // steps does the rest).
      double scale = 1.0;
      while (scale > 0.1 && find_inverted_point(sm, s.P + scale * dP)) scale *= 0.5;
      if (!(scale > 0.1)) break;
      s.P += scale * dP;
    }
    if (first.empty()) return;
    // Inelastic: no vertex of the contact set keeps moving into the bone.
    const Points3 v = surface_map_ * s.V;
    VecX target(static_cast<Eigen::Index>(first.size()));
    for (std::size_t c = 0; c < first.size(); ++c)
      target[static_cast<Eigen::Index>(c)] = -first[c].normal.dot(v.row(first[c].vertex).transpose());
    s.V += solve_contact_rows(sm, s, X, first, target, inv_mass);
    // A correction, not a restart: the energy guard keeps its reference and the factorisation
    // is kept.
    solver.correct_state(s.P, s.V);
  }

  // ΔP = M⁻¹ (Σ_c a_c λ_c + ∇V μ) with λ ≥ 0 and a_c·ΔP ≥ target_c (a_c = n_c ⊗ row of the vertex in
  // the surface map), ∇V·ΔP = 0: projected Gauss–Seidel on the multipliers.
  Points3 solve_contact_rows(const SolidDynamicsModel& sm, const SolidState& s, const std::vector<Transform>& X,
                             const std::vector<SurfaceContact>& contacts, const VecX& target,
                             const VecX& inv_mass) const {
    const Eigen::Index n = inv_mass.size();
    Points3 dP = Points3::Zero(n, 3);
    std::vector<double> diag(contacts.size(), 0.0), lambda(contacts.size(), 0.0);
    for (std::size_t c = 0; c < contacts.size(); ++c)
      for (SparseRowMatrix::InnerIterator it(surface_map_, contacts[c].vertex); it; ++it)
        diag[c] += it.value() * it.value() * inv_mass[it.col()];
    Points3 g;
    double g_diag = 0.0;
    if (sm.spec.volume != VolumeMethod::none) {
      const ForceEvaluation fe = calc_forces(sm, s.P, s.V, s.activation, false, X);
      if (fe.volume_gradient.size() == 3 * n) {
        g = unflatten_points(fe.volume_gradient);
        for (Eigen::Index I = 0; I < n; ++I) g_diag += inv_mass[I] * g.row(I).squaredNorm();
      }
    }
    double scale = 0.0;
    for (Eigen::Index c = 0; c < target.size(); ++c) scale = std::max(scale, std::abs(target[c]));
    if (!(scale > 0.0)) return dP;
    for (int sweep = 0; sweep < 200; ++sweep) {
      double change = 0.0;
      for (std::size_t c = 0; c < contacts.size(); ++c) {
        if (!(diag[c] > 0.0)) continue;
        const Vec3& nc = contacts[c].normal;
        double moved = 0.0;
        for (SparseRowMatrix::InnerIterator it(surface_map_, contacts[c].vertex); it; ++it)
          moved += it.value() * nc.dot(dP.row(it.col()).transpose());
        const double next = std::max(0.0, lambda[c] + (target[static_cast<Eigen::Index>(c)] - moved) / diag[c]);
        const double delta = next - lambda[c];
        if (delta == 0.0) continue;
        lambda[c] = next;
        for (SparseRowMatrix::InnerIterator it(surface_map_, contacts[c].vertex); it; ++it)
          dP.row(it.col()) += (inv_mass[it.col()] * it.value() * delta) * nc.transpose();
        change = std::max(change, std::abs(delta) * diag[c]);
      }
      if (g_diag > 0.0) {
        const double mu = -(g.array() * dP.array()).sum() / g_diag;
        dP += (inv_mass.asDiagonal() * g * mu).eval();
      }
      if (change <= 1e-4 * scale) break;
    }
    return dP;
  }

  // Iso-parametric curves of the fibre direction on a grid of the cross-section.
  void make_fibre_grid(const Muscle& m) {
    const BSplineSolid& solid = model_->rest;
    const int f = static_cast<int>(solid.fibre_direction), a = (f + 1) % 3, b = (f + 2) % 3;
    const int na = get_int_option(m, "fibre_rings", 2, 1, 1000);
    const int nb = get_int_option(m, "fibre_count_around", 8, 1, 1000);
    fibre_samples_ = get_int_option(m, "fibre_samples", 16, 2, 1000);
    const Vec3 lo = solid.get_lower(), hi = solid.get_upper();
    std::vector<Eigen::Triplet<double>> t;
    int row = 0;
    for (int i = 0; i < na; ++i)
      for (int j = 0; j < nb; ++j)
        for (int s = 0; s < fibre_samples_; ++s) {
          Vec3 U;
          U[a] = lo[a] + (hi[a] - lo[a]) * (i + 0.5) / na;
          U[b] = lo[b] + (hi[b] - lo[b]) * (solid.basis[b].periodic ? j / static_cast<double>(nb) : (j + 0.5) / nb);
          U[f] = lo[f] + (hi[f] - lo[f]) * s / (fibre_samples_ - 1.0);
          append_basis_row(solid, U, {0, 0, 0}, row++, t);
        }
    fibre_w_.resize(row, solid.num_control_points());
    fibre_w_.setFromTriplets(t.begin(), t.end());
    num_fibres_ = na * nb;
    const std::vector<Points3> rest = calc_fibres(solid.P);
    rest_fibre_length_.resize(num_fibres_);
    for (int k = 0; k < num_fibres_; ++k) rest_fibre_length_[k] = calc_polyline_length(rest[static_cast<std::size_t>(k)]);
  }

  std::vector<Points3> calc_fibres(const Points3& P) const {
    const Points3 X = fibre_w_ * P;
    std::vector<Points3> out(static_cast<std::size_t>(num_fibres_));
    for (int k = 0; k < num_fibres_; ++k) out[static_cast<std::size_t>(k)] = X.middleRows(k * fibre_samples_, fibre_samples_);
    return out;
  }

  // Rest depth of each surface vertex inside each nearby bone (bones given as rest-pose queries),
  // so that the frame's penetration counts only what lies beyond the rest contact.
  void setup_penetration(const Model& model, const Muscle& m) {
    for (std::size_t k = 0; k < bone_bodies_.size(); ++k) {
      const MeshQuery& q = *model.get_body(bone_bodies_[k]).rest_query;
      rest_depth_.push_back((-q.calc_signed_distances(m.rest_mesh.V)).cwiseMax(0.0));
    }
  }

  double calc_penetration(const Model& model, const Points3& S, const std::vector<Transform>& X) const {
    double worst = 0.0;
    for (std::size_t k = 0; k < bone_bodies_.size(); ++k) {
      const Body& body = model.get_body(bone_bodies_[k]);
      const Transform X_rest_now = X[kFirstBoneDriver + k].inverse();
      Points3 local = ((S * X_rest_now.linear().transpose()).rowwise() + X_rest_now.translation().transpose()).eval();
      std::vector<Eigen::Index> in_box;
      for (Eigen::Index i = 0; i < local.rows(); ++i)
        if (body.rest_box.contains(local.row(i).transpose())) in_box.push_back(i);
      if (in_box.empty()) continue;
      Points3 P(static_cast<Eigen::Index>(in_box.size()), 3);
      for (std::size_t j = 0; j < in_box.size(); ++j) P.row(static_cast<Eigen::Index>(j)) = local.row(in_box[j]);
      const VecX sd = body.rest_query->calc_signed_distances(P);
      for (std::size_t j = 0; j < in_box.size(); ++j)
        worst = std::max(worst, -sd[static_cast<Eigen::Index>(j)] - rest_depth_[k][in_box[j]]);
    }
    return worst;
  }

  void fill_frame(const Model& model, const State&, const SolidDynamicsSolver& solver,
                  const std::vector<Transform>& X, MuscleFrame& out) const {
    const Points3& P = solver.get_state().P;
    out.surface = calc_surface(P);
    StepInputs in;
    in.X_now_rest = X;
    const SolidMetrics mm = solver.calc_metrics(in);
    out.volume_m3 = mm.volume_m3;
    out.relative_volume_change = mm.volume_error;
    out.max_bone_penetration_m = calc_penetration(model, out.surface, X);
    out.fibres = calc_fibres(P);
    set_fibre_metrics(rest_fibre_length_, out);
  }

  std::string name_;  // the muscle's, for errors
  SolidOptions options_;
  SolverOptions solver_options_;
  std::shared_ptr<const SolidDynamicsModel> model_;
  std::array<EndDriver, 2> ends_;
  std::vector<BodyIndex> bone_bodies_;           // bone k drives X_now_rest[kFirstBoneDriver + k]
  std::vector<Vec3> vertex_material_;            // material point of each rest-mesh vertex
  std::vector<VecX> rest_depth_;                 // per bone: rest depth of each surface vertex
  std::array<SparseRowMatrix, 4> surface_w_;     // basis and its u, v, w derivatives at the vertices
  Eigen::AlignedBox3d rest_box_;
  SparseRowMatrix surface_map_;                  // surface vertices = surface_map_ P + offset_fixed_
  static constexpr double kContactTolerance_m = 1e-6;
  static constexpr double kNearBone_m = 0.005;
  Points3 offset_material_, offset_fixed_;
  SparseRowMatrix fibre_w_;
  int num_fibres_ = 0, fibre_samples_ = 2;
  VecX rest_fibre_length_;
};

// Runs body(i) for every i in parallel; the first error in index order is rethrown after all
// have run (deterministic whichever thread fails first).
void run_each(std::size_t n, const std::function<void(std::size_t)>& body) {
  std::vector<std::exception_ptr> errors(n);
  parallel_for(n, [&](std::size_t i) {
    try {
      body(i);
    } catch (...) {
      errors[i] = std::current_exception();
    }
  });
  for (const auto& e : errors)
    if (e) std::rethrow_exception(e);
}

// The scene's solid-dynamics muscles stepped together (seed 000 §4.7: muscles push each other
// but never pull). Each member is a SolidDynamicsRepresentation; per frame all members take the
// same number of sub-steps, and before each sub-step the contact forces of every pair that can
// touch (rest-pose adjacency: rest mesh boxes within muscle_margin; broad phase per sub-step on
// the control-point boxes, find_contact_pairs) come from calc_muscle_contact (point membership,
// forces only where one solid's boundary samples are inside the other) and enter the members'
// steps as external forces. A group of one muscle runs exactly as the muscle alone.
class SolidDynamicsGroup final : public MuscleGroupRepresentation {
 public:
  SolidDynamicsGroup(const Model& model, const std::vector<MuscleIndex>& muscles) {
    check_group_options(model, muscles);
    // The same in every member (check_group_options).
    const Muscle& first = model.get_muscle(muscles.front());
    contact_ = get_option(first, "muscle_contact", 1.0) != 0.0;
    // 50 N/m per sample: at 200 N/m the explicit exchange inverted the VH tibialis anterior, whose
    // mesh overlaps its neighbours at rest.
    stiffness_N_m_ = get_option(first, "muscle_contact_stiffness", 50.0);
    samples_per_span_ = get_int_option(first, "muscle_contact_samples", 2, 1, 64);
    const double margin = get_option(first, "muscle_margin", 0.005);
    if (!(stiffness_N_m_ >= 0.0) || !std::isfinite(stiffness_N_m_) || !(margin >= 0.0) || !std::isfinite(margin))
      throw_bad_input("solid_dynamics options: need finite muscle_contact_stiffness >= 0 (N/m) and muscle_margin >= 0 (m)",
                      {.object = first.name});
    members_.resize(muscles.size());
    run_each(muscles.size(), [&](std::size_t k) {
      try {
        members_[k] = std::make_unique<SolidDynamicsRepresentation>(model, muscles[k]);
      } catch (const Error& e) {
        throw e.with_object(model.get_muscle(muscles[k]).name);
      }
    });
    for (std::size_t i = 0; i < members_.size(); ++i)
      for (std::size_t j = i + 1; j < members_.size(); ++j) {
        Eigen::AlignedBox3d a = members_[i]->get_rest_box();
        a.min().array() -= margin;
        a.max().array() += margin;
        if (a.intersects(members_[j]->get_rest_box())) adjacency_.emplace_back(static_cast<int>(i), static_cast<int>(j));
      }
    if (!contact_ || stiffness_N_m_ == 0.0) adjacency_.clear();
    spdlog::debug("solid_dynamics group: {} muscles, {} pairs that can touch", members_.size(), adjacency_.size());
  }

  // The contact options act on pairs of muscles, so every member must give the same values (or
  // leave them at the defaults): a conflict is bad input naming the first muscle and the other.
  static void check_group_options(const Model& model, const std::vector<MuscleIndex>& muscles) {
    const Muscle& first = model.get_muscle(muscles.front());
    for (const auto& [key, fallback] : {std::pair<const char*, double>{"muscle_contact", 1.0},
                                        {"muscle_contact_stiffness", 50.0},
                                        {"muscle_contact_samples", 2.0},
                                        {"muscle_margin", 0.005}}) {
      const std::string k = key;
      const auto value = [&](const Muscle& m) {
        const double v = get_option(m, k, fallback);
        return k == "muscle_contact" ? static_cast<double>(v != 0.0) : v;  // on/off
      };
      const double a = value(first);
      for (std::size_t i = 1; i < muscles.size(); ++i) {
        const Muscle& other = model.get_muscle(muscles[i]);
        const double b = value(other);
        if (a == b || (std::isnan(a) && std::isnan(b))) continue;
        throw_bad_input(fmt::format("solid_dynamics muscles '{}' and '{}' give different {} ({} and {}); the "
                                    "solid_dynamics muscles of a scene are stepped as one group with one value",
                                    first.name, other.name, k, a, b),
                        {.object = other.name,
                         .suggestion = fmt::format("give \"{}\" the same value in every solid_dynamics muscle (or "
                                                   "leave it out everywhere for {})",
                                                   k, fallback)});
      }
    }
  }

  struct GroupFrame final : RepresentationState {
    std::vector<std::unique_ptr<RepresentationState>> members;
  };

  std::unique_ptr<RepresentationState> make_state() const override {
    auto s = std::make_unique<GroupFrame>();
    for (const auto& m : members_) s->members.push_back(m->make_state());
    return s;
  }

  void calc_geometry(const Model& model, const std::vector<MuscleIndex>& muscles, const State& state,
                     RepresentationState* rs, const std::vector<MuscleFrame*>& out) const override {
    auto* group = dynamic_cast<GroupFrame*>(rs);
    if (!group || group->members.size() != members_.size())
      throw_internal("solid_dynamics: the State was not made for this Model (make_state)");
    const std::size_t nm = members_.size();
    std::vector<SolidDynamicsRepresentation::Frame*> frames(nm);
    for (std::size_t k = 0; k < nm; ++k) frames[k] = &SolidDynamicsRepresentation::get_frame(group->members[k].get());
    std::vector<int> count(nm, 0);
    run_each(nm, [&](std::size_t k) {
      try {
        count[k] = members_[k]->begin_frame(model, muscles[k], state, *frames[k], *out[k]);
      } catch (const Error& e) {
        throw e.with_object(model.get_muscle(muscles[k]).name);
      }
    });
    // Common sub-steps: the finest any member asks for (they all span the same frame interval).
    const int n = *std::max_element(count.begin(), count.end());
    for (int step = 0; step < n; ++step) {
      const std::vector<Points3> forces = calc_contact_forces(frames);
      run_each(nm, [&](std::size_t k) {
        if (count[k] == 0) return;
        try {
          members_[k]->calc_substep(model, *frames[k], step, n, forces[k]);
        } catch (const Error& e) {
          throw e.with_object(model.get_muscle(muscles[k]).name);
        }
      });
    }
    run_each(nm, [&](std::size_t k) { members_[k]->end_frame(model, state, *frames[k], *out[k]); });
  }

 private:
  // Contact forces on each member (#P × 3, N; empty when none) from the pairs that overlap now.
  // Pairs are evaluated in parallel and summed in pair order (deterministic).
  std::vector<Points3> calc_contact_forces(const std::vector<SolidDynamicsRepresentation::Frame*>& frames) const {
    std::vector<Points3> forces(frames.size());
    if (adjacency_.empty()) return forces;
    std::vector<Points3> P;
    for (const auto* f : frames) P.push_back(f->solver.get_state().P);
    const std::vector<std::pair<int, int>> pairs = find_contact_pairs(P, adjacency_);
    std::vector<MuscleContactResult> results(pairs.size());
    run_each(pairs.size(), [&](std::size_t c) {
      const auto [i, j] = pairs[c];
      results[c] = calc_muscle_contact(members_[i]->get_model(), P[i], members_[j]->get_model(), P[j], stiffness_N_m_,
                                       samples_per_span_);
    });
    for (std::size_t c = 0; c < pairs.size(); ++c) {
      if (results[c].num_contacts == 0) continue;
      const auto [i, j] = pairs[c];
      for (const auto& [k, f] : {std::pair<int, const Points3*>{i, &results[c].forces_a}, {j, &results[c].forces_b}}) {
        if (forces[k].rows() == 0) forces[k] = Points3::Zero(P[k].rows(), 3);
        forces[k] += *f;
      }
    }
    return forces;
  }

  std::vector<std::unique_ptr<const SolidDynamicsRepresentation>> members_;
  std::vector<std::pair<int, int>> adjacency_;  // members that can touch (rest boxes within the margin)
  bool contact_ = true;
  double stiffness_N_m_ = 50.0;
  int samples_per_span_ = 2;
};

}  // namespace

std::unique_ptr<const MuscleGroupRepresentation> make_solid_dynamics_group(const Model& model,
                                                                           const std::vector<MuscleIndex>& muscles) {
  return std::make_unique<SolidDynamicsGroup>(model, muscles);
}

}  // namespace fascicle
