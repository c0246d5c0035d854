// The stages of a frame: pose → action lines → forces → muscle geometry.
#include "fascicle/scene/state.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/geometry/obb.hpp"
#include "muscle_setup.hpp"

#include <algorithm>
#include <cmath>

namespace fascicle {
namespace {

void require_stage(const State& s, Stage needed, const char* what) {
  if (static_cast<int>(s.stage) < static_cast<int>(needed))
    throw_internal(std::string(what) + " called before the previous stage was computed");
}

// Runs body(m) for every muscle in parallel; an error names the muscle.
template <class Body>
void for_each_muscle(const Model& model, const Body& body) {
  parallel_for(model.muscles.size(), [&](std::size_t m) {
    try {
      body(static_cast<int>(m));
    } catch (const Error& e) {
      throw e.with_object(model.muscles[m].name);
    }
  });
}

}  // namespace

State make_state(const Model& model) {
  State s;
  s.q = model.default_q;
  s.X_ground_body.assign(model.bodies.size(), Transform::Identity());
  s.muscles.resize(model.muscles.size());
  s.representation_states.resize(model.muscles.size());
  // In parallel over muscles: a representation's state is built from the immutable Model alone
  // (surface-first: each muscle's first sparse factorisation, tens of ms for the large ones), and
  // does not depend on the order (orderings that may use METIS take the process-wide ordering lock).
  parallel_for(model.muscles.size(), [&](std::size_t m) {
    if (model.muscles[m].representation)
      s.representation_states[m] = model.muscles[m].representation->make_state();
  });
  for (const MuscleGroup& g : model.muscle_groups) s.group_states.push_back(g.group->make_state());
  s.skeleton.emplace(*model.skeleton);
  return s;
}

void calc_pose(const Model& model, State& state) {
  if (!state.q.allFinite()) throw_numerical("coordinate values are not finite");
  if (!state.skeleton) state.skeleton.emplace(*model.skeleton);
  calc_pose(*model.skeleton, state.q, *state.skeleton);
  state.X_ground_body = state.skeleton->get_body_transforms();
  state.muscles.resize(model.muscles.size());
  state.stage = Stage::pose;
}

void calc_action_lines(const Model& model, State& state) {
  require_stage(state, Stage::pose, "calc_action_lines");
  for_each_muscle(model, [&](int m) {
    const Muscle& muscle = model.muscles[m];
    MuscleFrame& out = state.muscles[m];
    if (muscle.path >= 0) {
      // A wrapping path (path module): its polyline, arcs sampled every 5 mm.
      PathResult path;
      calc_path(model.paths, muscle.path, state.X_ground_body, state.skeleton->get_q(), path);
      out.action_line = calc_path_polyline(path, 0.005);
      out.action_line_bodies.assign(static_cast<size_t>(out.action_line.rows()), BodyIndex{});
      out.musculotendon_length_m = path.length_m;
      if (!std::isfinite(out.musculotendon_length_m))
        throw_numerical("the muscle path has a non-finite length");
      return;
    }
    const auto n = static_cast<Eigen::Index>(muscle.via_points.size() + 2);
    out.action_line.resize(n, 3);
    out.action_line_bodies.resize(n);
    const auto put = [&](Eigen::Index i, BodyIndex b, const Vec3& p_body) {
      out.action_line.row(i) = (state.X_ground_body[b.v] * p_body).transpose();
      out.action_line_bodies[i] = b;
    };
    put(0, muscle.origin.body, muscle.origin.p_body_centroid);
    for (size_t v = 0; v < muscle.via_points.size(); ++v)
      put(static_cast<Eigen::Index>(v + 1), muscle.via_points[v].body, muscle.via_points[v].p_body);
    put(n - 1, muscle.insertion.body, muscle.insertion.p_body_centroid);
    double length = 0.0;
    for (Eigen::Index i = 0; i + 1 < n; ++i)
      length += (out.action_line.row(i + 1) - out.action_line.row(i)).norm();
    out.musculotendon_length_m = length;
  });
  state.stage = Stage::action_lines;
}

void calc_forces(const Model& model, State& state) {
  require_stage(state, Stage::action_lines, "calc_forces");
  for_each_muscle(model, [&](int m) {
    const Muscle& muscle = model.muscles[m];
    MuscleFrame& out = state.muscles[m];
    out.hill = MuscleOutputs{};
    if (!muscle.actuator) return;
    const double a = m < state.activation.size() && std::isfinite(state.activation[m]) ? state.activation[m]
                                                                                      : muscle.activation;
    out.hill = muscle.actuator->calc_outputs(a, out.musculotendon_length_m);
    if (!std::isfinite(out.hill.tendon_force_N))
      throw_numerical("the musculotendon equilibrium gave a non-finite tendon force");
  });
  state.stage = Stage::forces;
}

void calc_muscle_geometry(const Model& model, State& state) {
  scene_detail::calc_muscle_shapes(model, state);
  calc_muscle_overlaps(model, state);
  state.stage = Stage::geometry;
}

void scene_detail::calc_muscle_shapes(const Model& model, State& state) {
  require_stage(state, Stage::forces, "calc_muscle_geometry");
  if (state.representation_states.size() != model.muscles.size() ||
      state.group_states.size() != model.muscle_groups.size())
    throw_internal("calc_muscle_geometry: the State was not made by make_state() for this Model");
  for_each_muscle(model, [&](int m) {
    MuscleFrame& out = state.muscles[m];
    if (!model.muscles[m].representation) return;  // a group member
    model.muscles[m].representation->calc_geometry(model, MuscleIndex{m}, state,
                                                   state.representation_states[m].get(), out);
  });
  for (size_t g = 0; g < model.muscle_groups.size(); ++g) {
    const MuscleGroup& group = model.muscle_groups[g];
    std::vector<MuscleFrame*> out;
    for (MuscleIndex m : group.muscles) out.push_back(&state.muscles[m.v]);
    group.group->calc_geometry(model, group.muscles, state, state.group_states[g].get(), out);
  }
}

namespace {

// Depth of a's vertices inside b for every ordered pair (a, b) of closed surfaces whose boxes meet,
// at [a * n + b] (0 for the other pairs). surface[m] is null for a muscle without a closed surface.
// Keeps (and refits) the cache's per-muscle graph and query.
std::vector<double> calc_pair_depths(const Model& model, const std::vector<const Points3*>& surface,
                                     MuscleOverlapCache& cache) {
  const size_t n = model.muscles.size();
  cache.graph.resize(n);
  cache.query.resize(n);
  cache.axes.resize(n, Mat3::Identity());
  cache.has_axes.resize(n, 0);
  cache.previous.resize(n);
  cache.depth_bound.resize(n * n);
  // Broad phase: bounding boxes of the closed surfaces.
  std::vector<Eigen::AlignedBox3d> box(n);
  for (size_t m = 0; m < n; ++m) {
    if (!surface[m]) continue;
    const Points3& V = *surface[m];
    box[m] = Eigen::AlignedBox3d(V.colwise().minCoeff().transpose(), V.colwise().maxCoeff().transpose());
  }
  // Ordered pairs (a, b): vertices of a inside b, for boxes that meet.
  std::vector<std::pair<int, int>> pairs;
  std::vector<char> is_a(n, 0), is_b(n, 0);
  for (size_t a = 0; a < n; ++a)
    for (size_t b = 0; b < n; ++b)
      if (a != b && surface[a] && surface[b] && box[a].intersects(box[b])) {
        pairs.emplace_back(static_cast<int>(a), static_cast<int>(b));
        is_a[a] = is_b[b] = 1;
      }
  // Per muscle: the edge graph (once per run) and the query of this surface.
  std::vector<Eigen::AlignedBox3d> padded(n);
  std::vector<OrientedBounds> bounds(n);
  // How far each vertex moved since the previous call (the depth bounds carried from it widen by
  // the motion of both surfaces; empty: no previous surface, the bounds are dropped).
  std::vector<VecX> moved(n);
  std::vector<double> max_moved(n, 0.0);
  parallel_for(n, [&](size_t m) {
    if (!is_a[m] && !is_b[m]) return;
    const Points3& V = *surface[m];
    if (cache.previous[m].rows() == V.rows() && cache.previous[m].cols() == 3) {
      moved[m] = (V - cache.previous[m]).rowwise().norm();
      max_moved[m] = moved[m].maxCoeff();
    }
    cache.previous[m] = V;
    if (is_a[m] && cache.graph[m].start.size() != static_cast<size_t>(V.rows()) + 1)
      cache.graph[m] = make_surface_graph(model.muscles[m].rest_mesh.F, V.rows());
    if (!is_b[m]) return;
    padded[m] = calc_padded_bounding_box(V);
    // Oriented bounds along the rest mesh's box axes (fixed per muscle, so every frame's bounds
    // and results depend on that frame's surfaces only).
    if (!cache.has_axes[m]) {
      cache.axes[m] = compute_oriented_box(model.muscles[m].rest_mesh).axes;
      cache.has_axes[m] = 1;
    }
    bounds[m] = calc_padded_oriented_bounds(V, cache.axes[m]);
    // A query kept from an earlier call is refitted to the new vertices (its answers equal a new
    // query's, geometry/mesh_query.hpp); the first call builds it.
    if (cache.query[m] && cache.query[m]->get_mesh().V.rows() == V.rows() &&
        cache.query[m]->get_mesh().F.rows() == model.muscles[m].rest_mesh.F.rows())
      cache.query[m]->update_vertices(V);
    else
      cache.query[m] = std::make_unique<MeshQuery>(TriMesh{V, model.muscles[m].rest_mesh.F});
  });
  // Depth bounds are carried only from the call just before (the motion is measured since then):
  // drop those of pairs not measured now.
  std::vector<char> measured_now(n * n, 0);
  for (const auto& [a, b] : pairs) measured_now[static_cast<size_t>(a) * n + static_cast<size_t>(b)] = 1;
  for (size_t k = 0; k < n * n; ++k)
    if (!measured_now[k]) cache.depth_bound[k].clear();
  // Narrow phase, in parallel over pairs; each pair's result depends on its two surfaces only.
  std::vector<double> depth(n * n, 0.0);
  parallel_for(pairs.size(), [&](size_t k) {
    const auto [a, b] = pairs[k];
    std::vector<DepthBound>& bound = cache.depth_bound[static_cast<size_t>(a) * n + static_cast<size_t>(b)];
    if (moved[a].size() > 0 && moved[b].size() > 0 && bound.size() == static_cast<size_t>(moved[a].size())) {
      // A bound |x - y| + |y - z| with z on triangle T of b: after the motion, the point of T
      // with z's barycentric coordinates moved by at most T's largest vertex motion, and x by
      // |x' - x|, so the bound widens by both (distance to a surface is 1-Lipschitz).
      const Triangles& Fb = model.muscles[b].rest_mesh.F;
      const VecX& mb = moved[b];
      for (size_t i = 0; i < bound.size(); ++i) {
        DepthBound& d = bound[i];
        if (!std::isfinite(d.bound)) continue;
        const double other_motion =
            d.triangle >= 0 && d.triangle < Fb.rows()
                ? std::max({mb[Fb(d.triangle, 0)], mb[Fb(d.triangle, 1)], mb[Fb(d.triangle, 2)]})
                : max_moved[b];
        d.bound += moved[a][static_cast<Eigen::Index>(i)] + other_motion;
      }
    } else {
      bound.clear();
    }
    depth[static_cast<size_t>(a) * n + static_cast<size_t>(b)] =
        calc_muscle_overlap(*surface[a], cache.graph[a], *cache.query[b], padded[b], &bounds[b], &bound).max_depth_m;
  });
  return depth;
}

}  // namespace

void calc_muscle_overlaps(const Model& model, State& state) {
  const size_t n = model.muscles.size();
  MuscleOverlapCache& cache = state.overlap_cache;
  // The rest pose's pair depths (rest meshes), once; the queries built for them are refitted below.
  if (cache.rest_depth.size() != n * n) {
    std::vector<const Points3*> rest(n, nullptr);
    for (size_t m = 0; m < n; ++m)
      if (model.muscles[m].rest_mesh.V.rows() > 0 && model.muscles[m].rest_mesh.F.rows() > 0)
        rest[m] = &model.muscles[m].rest_mesh.V;
    cache.rest_depth = calc_pair_depths(model, rest, cache);
  }
  std::vector<const Points3*> now(n, nullptr);
  for (size_t m = 0; m < n; ++m) {
    const Points3& V = state.muscles[m].surface;
    if (V.rows() > 0 && V.rows() == model.muscles[m].rest_mesh.V.rows() && model.muscles[m].rest_mesh.F.rows() > 0)
      now[m] = &V;
  }
  const std::vector<double> depth = calc_pair_depths(model, now, cache);
  for (size_t a = 0; a < n; ++a) {
    MuscleFrame& f = state.muscles[a];
    f.max_muscle_overlap_m = now[a] ? 0.0 : MuscleFrame::nan;
    f.max_muscle_overlap_growth_m = now[a] ? 0.0 : MuscleFrame::nan;
    if (!now[a]) continue;
    for (size_t b = 0; b < n; ++b) {
      const double d = depth[a * n + b];
      f.max_muscle_overlap_m = std::max(f.max_muscle_overlap_m, d);
      f.max_muscle_overlap_growth_m = std::max(f.max_muscle_overlap_growth_m, d - cache.rest_depth[a * n + b]);
    }
  }
}

void forward(const Model& model, State& state) {
  calc_pose(model, state);
  calc_action_lines(model, state);
  calc_forces(model, state);
  calc_muscle_geometry(model, state);
}

}  // namespace fascicle
