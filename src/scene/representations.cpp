// Built-in muscle representations: "blended_surface" (interim deformation) and "action_line".
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/model.hpp"
#include "fascicle/scene/state.hpp"

#include "muscle_setup.hpp"

#include <algorithm>

namespace fascicle {
namespace {

// The rest-pose action line of a muscle (ground) and the bodies its points move with.
struct RestLine {
  std::vector<Vec3> points;
  std::vector<BodyIndex> bodies;
};

RestLine calc_rest_line(const Model& model, const Muscle& m) {
  RestLine line;
  const auto& X = model.X_ground_body_default;
  line.points.push_back(X[m.origin.body.v] * m.origin.p_body_centroid);
  line.bodies.push_back(m.origin.body);
  for (const ViaPoint& v : m.via_points) {
    line.points.push_back(X[v.body.v] * v.p_body);
    line.bodies.push_back(v.body);
  }
  line.points.push_back(X[m.insertion.body.v] * m.insertion.p_body_centroid);
  line.bodies.push_back(m.insertion.body);
  return line;
}

// Distance of p to the attachment's landmark points (ground, rest pose).
double calc_distance_to_landmarks(const Vec3& p, const Attachment& a, const Transform& X_ground_body) {
  double d = std::numeric_limits<double>::infinity();
  for (Eigen::Index i = 0; i < a.p_body.rows(); ++i)
    d = std::min(d, (p - X_ground_body * Vec3(a.p_body.row(i).transpose())).norm());
  return d;
}

// How one rest point moves: the blend (1 − w)·T_a + w·T_b of two bodies' rigid motions.
struct Binding {
  int body_a = 0, body_b = 0;
  double weight = 0.0;
};

Binding bind_point(const Vec3& p, const Model& model, const Muscle& m, const RestLine& line) {
  const auto& X = model.X_ground_body_default;
  // Attachment areas follow their bone rigidly.
  if (m.origin.radius_m > 0 && calc_distance_to_landmarks(p, m.origin, X[m.origin.body.v]) <= m.origin.radius_m)
    return {m.origin.body.v, m.origin.body.v, 0.0};
  if (m.insertion.radius_m > 0 &&
      calc_distance_to_landmarks(p, m.insertion, X[m.insertion.body.v]) <= m.insertion.radius_m)
    return {m.insertion.body.v, m.insertion.body.v, 0.0};
  // Nearest segment of the rest action line and the position s along it; w = smoothstep(s).
  Binding bind;
  double best = std::numeric_limits<double>::infinity();
  for (size_t k = 0; k + 1 < line.points.size(); ++k) {
    const Vec3 d = line.points[k + 1] - line.points[k];
    const double len2 = d.squaredNorm();
    const double s = len2 > 0 ? std::clamp((p - line.points[k]).dot(d) / len2, 0.0, 1.0) : 0.0;
    const double dist = (p - (line.points[k] + s * d)).norm();
    if (dist < best) {
      best = dist;
      bind = {line.bodies[k].v, line.bodies[k + 1].v, s * s * (3.0 - 2.0 * s)};
    }
  }
  return bind;
}

std::vector<Binding> bind_points(const Points3& P, const Model& model, const Muscle& m, const RestLine& line) {
  std::vector<Binding> b(static_cast<size_t>(P.rows()));
  for (Eigen::Index i = 0; i < P.rows(); ++i) b[i] = bind_point(P.row(i).transpose(), model, m, line);
  return b;
}

void apply_bindings(const Points3& rest, const std::vector<Binding>& bind, const std::vector<Transform>& T,
                    Points3& out) {
  out.resize(rest.rows(), 3);
  for (Eigen::Index i = 0; i < rest.rows(); ++i) {
    const Vec3 p = rest.row(i).transpose();
    const Binding& b = bind[i];
    out.row(i) = ((1.0 - b.weight) * (T[b.body_a] * p) + b.weight * (T[b.body_b] * p)).transpose();
  }
}

class BlendedSurface final : public MuscleRepresentation {
 public:
  BlendedSurface(const Model& model, MuscleIndex mi) {
    const Muscle& m = model.get_muscle(mi);
    scene_detail::require_muscle_mesh(m, "blended_surface");
    const RestLine line = calc_rest_line(model, m);
    surface_ = bind_points(m.rest_mesh.V, model, m, line);
    for (const Points3& f : m.rest_fibres) fibres_.push_back(bind_points(f, model, m, line));
  }

  void calc_geometry(const Model& model, MuscleIndex mi, const State& state, RepresentationState*,
                     MuscleFrame& out) const override {
    const Muscle& m = model.get_muscle(mi);
    // Rigid motion of each body from the default pose: T_b = X_ground_b · X_ground_b(default)⁻¹.
    std::vector<Transform> T(model.bodies.size());
    for (size_t b = 0; b < T.size(); ++b)
      T[b] = state.X_ground_body[b] * model.X_ground_body_default[b].inverse();
    apply_bindings(m.rest_mesh.V, surface_, T, out.surface);
    if (!out.surface.allFinite()) throw_numerical("blended surface has non-finite vertices");
    out.fibres.resize(fibres_.size());
    for (size_t k = 0; k < fibres_.size(); ++k) apply_bindings(m.rest_fibres[k], fibres_[k], T, out.fibres[k]);
    out.volume_m3 = calc_enclosed_volume(out.surface, m.rest_mesh.F, out.surface.colwise().mean().transpose());
    out.relative_volume_change = out.volume_m3 / m.rest_volume_m3 - 1.0;
  }

 private:
  std::vector<Binding> surface_;
  std::vector<std::vector<Binding>> fibres_;
};

class ActionLineOnly final : public MuscleRepresentation {
 public:
  void calc_geometry(const Model&, MuscleIndex, const State&, RepresentationState*, MuscleFrame& out) const override {
    out.surface.resize(0, 3);
    out.fibres.clear();
  }
};

}  // namespace

std::unique_ptr<const MuscleRepresentation> make_blended_surface(const Model& model, MuscleIndex m) {
  return std::make_unique<BlendedSurface>(model, m);
}
std::unique_ptr<const MuscleRepresentation> make_action_line_only(const Model&, MuscleIndex) {
  return std::make_unique<ActionLineOnly>();
}

}  // namespace fascicle
