// Compilation and per-frame evaluation of muscle paths (OpenSim GeometryPath semantics).
#include "fascicle/path/path_model.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <unordered_map>

#include "fascicle/core/error.hpp"

namespace fascicle {
namespace {

using NameIndex = std::unordered_map<std::string, int32_t>;

NameIndex index_names(const std::vector<std::string>& names) {
  NameIndex out;
  for (size_t i = 0; i < names.size(); ++i) out.emplace(names[i], static_cast<int32_t>(i));
  return out;
}

int32_t find_or_throw(const NameIndex& index, const std::string& name, const char* what,
                      const std::string& object) {
  const auto it = index.find(name);
  if (it == index.end()) {
    throw_bad_input(std::string("unknown ") + what + " '" + name + "'",
                    {.object = object, .suggestion = std::string("check the ") + what +
                                                     " names of the model"});
  }
  return it->second;
}

bool positive(double x) { return std::isfinite(x) && x > 0; }

void check_wrap_object(const WrapObjectSpec& w) {
  const std::string where = "wrap object " + w.name;
  bool ok = true;
  switch (w.shape) {
    case WrapShape::cylinder: ok = positive(w.radius) && positive(w.length); break;
    case WrapShape::sphere: ok = positive(w.radius); break;
    case WrapShape::ellipsoid: ok = positive(w.radii.x()) && positive(w.radii.y()) &&
                                    positive(w.radii.z()); break;
    case WrapShape::torus: ok = positive(w.radius) && positive(w.ring_radius) &&
                                w.radius < w.ring_radius; break;
  }
  if (!ok) {
    throw_bad_input("wrap object has invalid dimensions",
                    {.object = where,
                     .suggestion = "radii and lengths must be finite and > 0 (torus: tube radius "
                                   "< ring radius)"});
  }
}

CompiledPathPoint compile_point(const PathPointSpec& p, const NameIndex& bodies,
                                const NameIndex& coords, const std::string& object) {
  CompiledPathPoint c;
  c.body = find_or_throw(bodies, p.body, "body", object);
  c.kind = p.kind;
  c.p_body = p.p_body;
  if (!p.p_body.allFinite()) throw_bad_input("path point location is not finite", {.object = object});
  if (p.kind == PathPointKind::conditional) {
    c.coordinate = find_or_throw(coords, p.coordinate, "coordinate", object);
    if (!(p.range_min <= p.range_max)) {
      throw_bad_input("conditional path point has an empty or NaN range",
                      {.object = object, .suggestion = "give range_min <= range_max"});
    }
    c.range_min = p.range_min;
    c.range_max = p.range_max;
  }
  if (p.kind == PathPointKind::moving) {
    for (int a = 0; a < 3; ++a) {
      const CoordinateFunction& f = p.location[a];
      if (!f.value || !f.slope) {
        throw_bad_input("moving path point lacks a location function for axis " +
                            std::string(1, "xyz"[a]),
                        {.object = object});
      }
      c.location[a] = f;
      if (!f.coordinate.empty()) {
        c.location_coordinate[a] = find_or_throw(coords, f.coordinate, "coordinate", object);
      }
    }
  }
  return c;
}

// Station of a path point in its body frame for coordinates q.
Vec3 station(const CompiledPathPoint& p, const VecX& q) {
  if (p.kind != PathPointKind::moving) return p.p_body;
  Vec3 s;
  for (int a = 0; a < 3; ++a) {
    const int32_t c = p.location_coordinate[a];
    s[a] = p.location[a].value(c >= 0 ? q[c] : 0.0);
  }
  return s;
}

bool is_active(const CompiledPathPoint& p, const VecX& q) {
  if (p.kind != PathPointKind::conditional) return true;
  const double x = q[p.coordinate];
  return x >= p.range_min && x <= p.range_max;
}

// Removes the tangent-point pair of wrap w, if present.
void remove_wrap_vertices(std::vector<PathVertex>& v, int w) {
  v.erase(std::remove_if(v.begin(), v.end(), [w](const PathVertex& x) { return x.wrap == w; }),
          v.end());
}

// Position of a vertex as the length sums see it. With `first_use` (PathOptions::
// opensim_tangent_point_cache), a tangent point keeps the ground position it had when a length sum
// first read it in this pose, as OpenSim 4's cached Point::getLocationInGround does.
Vec3 reported_position(PathResult& out, const PathVertex& v, bool first_use) {
  if (!first_use || v.wrap < 0) return v.p_ground;
  PathWrapState& w = out.wraps[v.wrap];
  const int k = v.tangent - 1;
  if (!w.first_use_set[k]) {
    w.first_use_ground[k] = v.p_ground;
    w.first_use_set[k] = true;
  }
  return w.first_use_ground[k];
}

// Path length as calc_path_length, straight pieces between reported positions.
double calc_reported_length(PathResult& out, bool first_use) {
  if (!first_use) return calc_path_length(out);
  double length = 0;
  for (size_t i = 0; i + 1 < out.vertices.size(); ++i) {
    const PathVertex& a = out.vertices[i];
    const PathVertex& b = out.vertices[i + 1];
    if (a.tangent == 1 && b.wrap == a.wrap) {
      length += out.wraps[a.wrap].result.arc_length;
    } else {
      length += (reported_position(out, b, true) - reported_position(out, a, true)).norm();
    }
  }
  return length;
}

// Applies one path wrap (OpenSim GeometryPath::applyWrapObjects, one object).
void apply_wrap(const PathSetModel& model, const CompiledPath& path, int w,
                const std::vector<Transform>& X_ground_body, PathResult& out) {
  PathWrapState& ws = out.wraps[w];
  remove_wrap_vertices(out.vertices, w);
  ws.wrapping = false;
  ws.status = WrapStatus::no_wrap;
  const CompiledPathWrap& pw = path.wraps[w];
  const CompiledWrapObject& obj = model.wrap_objects[pw.object];
  if (!obj.spec.active) return;
  // First and last vertex whose path point lies in the wrap's range.
  int jfwd = -1, jrev = -1;
  for (int j = 0; j < static_cast<int>(out.vertices.size()); ++j) {
    const int32_t pt = out.vertices[j].point;
    if (pt >= pw.first_point && pt <= pw.last_point) {
      if (jfwd < 0) jfwd = j;
      jrev = j;
    }
  }
  if (jfwd < 0 || jfwd >= jrev) return;
  ws.X_ground_wrap = X_ground_body[obj.body] * obj.spec.X_body_wrap;
  const Transform X_wrap_ground = ws.X_ground_wrap.inverse();
  const bool first_use = model.options.opensim_tangent_point_cache;
  int best_at = -1;
  double best_change = std::numeric_limits<double>::infinity();
  for (int j = jfwd; j < jrev; ++j) {
    const PathVertex& a = out.vertices[j];
    const PathVertex& b = out.vertices[j + 1];
    if (a.wrap >= 0 && a.wrap == b.wrap) continue;  // the arc of another wrap
    const Vec3 p1 = X_wrap_ground * a.p_ground, p2 = X_wrap_ground * b.p_ground;
    const WrapResult r =
        obj.spec.shape == WrapShape::cylinder &&
                model.options.cylinder_method == CylinderMethod::opensim_iterative
            ? wrap_cylinder_opensim(p1, p2, obj.spec.radius, obj.spec.length, obj.spec.quadrant,
                                    path.wraps.size() == 1)
            : wrap_segment(obj.spec, p1, p2, model.options.cylinder_ends);
    ws.status = r.status;
    if (r.status == WrapStatus::mandatory) {
      best_at = j;
      ws.result = r;
      break;
    }
    // OpenSim (GeometryPath::calcPathLengthChange): of several wrapped segments, the one whose
    // length grows least by the wrap.
    if (r.status == WrapStatus::wrapped) {
      double change =
          (r.t1 - p1).norm() + r.arc_length + (p2 - r.t2).norm() - (p2 - p1).norm();
      if (first_use) {  // OpenSim measures from the ends' reported positions, in ground
        const Vec3 q1 = reported_position(out, out.vertices[j], true);
        const Vec3 q2 = reported_position(out, out.vertices[j + 1], true);
        change = (ws.X_ground_wrap * r.t1 - q1).norm() + r.arc_length +
                 (q2 - ws.X_ground_wrap * r.t2).norm() - (q2 - q1).norm();
      }
      if (change < best_change) {
        best_change = change;
        best_at = j;
        ws.result = r;
      }
    }
  }
  if (best_at < 0) return;
  ws.wrapping = true;
  const PathVertex t1{ws.X_ground_wrap * ws.result.t1, obj.body, -1, w, 1};
  const PathVertex t2{ws.X_ground_wrap * ws.result.t2, obj.body, -1, w, 2};
  out.vertices.insert(out.vertices.begin() + best_at + 1, {t1, t2});
}

}  // namespace

PathSetModel compile_paths(const PathSetSpec& spec, const PathNames& names) {
  const NameIndex bodies = index_names(names.bodies);
  const NameIndex coords = index_names(names.coordinates);
  PathSetModel model;
  model.options = spec.options;
  model.num_bodies = static_cast<int>(names.bodies.size());
  model.num_coordinates = static_cast<int>(names.coordinates.size());
  NameIndex objects;
  for (const WrapObjectSpec& w : spec.wrap_objects) {
    check_wrap_object(w);
    CompiledWrapObject c{w, find_or_throw(bodies, w.body, "body", "wrap object " + w.name)};
    objects.emplace(w.name, static_cast<int32_t>(model.wrap_objects.size()));
    model.wrap_objects.push_back(std::move(c));
  }
  for (const GeometryPathSpec& p : spec.paths) {
    const std::string object = "path " + p.name;
    if (p.points.size() < 2) {
      throw_bad_input("a path needs at least two path points (origin and insertion)",
                      {.object = object});
    }
    CompiledPath cp;
    cp.name = p.name;
    cp.action_line = p.action_line;
    for (const PathPointSpec& pt : p.points) {
      cp.points.push_back(compile_point(pt, bodies, coords, object + ", point " + pt.name));
    }
    const int n = static_cast<int>(p.points.size());
    for (const PathWrapSpec& w : p.wraps) {
      CompiledPathWrap cw;
      cw.object = find_or_throw(objects, w.wrap_object, "wrap object", object);
      cw.first_point = w.range_begin < 1 ? 0 : w.range_begin - 1;
      cw.last_point = w.range_end < 1 ? n - 1 : w.range_end - 1;
      if (cw.first_point >= n || cw.last_point >= n || cw.first_point > cw.last_point) {
        throw_bad_input("path wrap range is outside the path's points",
                        {.object = object + ", wrap " + w.wrap_object,
                         .suggestion = "use 1-based point indices, or -1 for the ends"});
      }
      cp.wraps.push_back(cw);
    }
    model.paths.push_back(std::move(cp));
  }
  return model;
}

double calc_path_length(const PathResult& result) {
  const auto& v = result.vertices;
  double length = 0;
  for (size_t i = 0; i + 1 < v.size(); ++i) {
    if (v[i].tangent == 1 && v[i + 1].wrap == v[i].wrap) {
      length += result.wraps[v[i].wrap].result.arc_length;
    } else {
      length += (v[i + 1].p_ground - v[i].p_ground).norm();
    }
  }
  return length;
}

void calc_path(const PathSetModel& model, int path, const std::vector<Transform>& X_ground_body,
               const VecX& q, PathResult& out) {
  const CompiledPath& p = model.paths[path];
  out.vertices.clear();
  out.wraps.assign(p.wraps.size(), PathWrapState{});
  out.iterations = 0;
  // Active points in ground.
  for (int i = 0; i < static_cast<int>(p.points.size()); ++i) {
    const CompiledPathPoint& pt = p.points[i];
    if (!is_active(pt, q)) continue;
    out.vertices.push_back({X_ground_body[pt.body] * station(pt, q), pt.body, i, -1, 0});
  }
  if (out.vertices.size() < 2) {
    throw_bad_input("fewer than two path points are active in this pose",
                    {.object = "path " + p.name,
                     .suggestion = "check the ranges of the conditional path points"});
  }
  if (p.action_line == ActionLine::straight) {
    out.vertices.erase(out.vertices.begin() + 1, out.vertices.end() - 1);
  }
  if (p.action_line != ActionLine::obstacle_set || p.wraps.empty()) {
    out.length_m = calc_path_length(out);
    return;
  }
  // Wraps in order; with two or more, repeat until the length settles (OpenSim).
  const int nw = static_cast<int>(p.wraps.size());
  std::vector<int> order(nw);
  for (int i = 0; i < nw; ++i) order[i] = i;
  const int max_iter = nw < 2 ? 1 : std::max(1, model.options.max_iterations);
  double last = std::numeric_limits<double>::infinity();
  for (int k = 0; k < max_iter; ++k) {
    for (int i = 0; i < nw; ++i) apply_wrap(model, p, order[i], X_ground_body, out);
    out.iterations = k + 1;
    out.length_m = calc_reported_length(out, model.options.opensim_tangent_point_cache);
    if (std::abs(out.length_m - last) < model.options.tolerance_m) break;
    last = out.length_m;
    // OpenSim: if the first object did not wrap and the second had a point inside it, swap them.
    if (k == 0 && nw > 1 && out.wraps[order[0]].status == WrapStatus::no_wrap &&
        out.wraps[order[1]].status == WrapStatus::inside) {
      std::swap(order[0], order[1]);
      remove_wrap_vertices(out.vertices, 0);
      out.wraps[0].wrapping = false;
    }
  }
}

Points3 calc_path_polyline(const PathResult& result, double arc_step_m) {
  std::vector<Vec3> pts;
  const auto& v = result.vertices;
  for (size_t i = 0; i < v.size(); ++i) {
    pts.push_back(v[i].p_ground);
    if (v[i].tangent == 1 && i + 1 < v.size() && v[i + 1].wrap == v[i].wrap) {
      const PathWrapState& w = result.wraps[v[i].wrap];
      const int n = std::max(1, static_cast<int>(w.result.arc_length / arc_step_m));
      for (int s = 1; s < n; ++s) {
        pts.push_back(w.X_ground_wrap * point_on_wrap_arc(w.result.arc, double(s) / n));
      }
    }
  }
  Points3 out(pts.size(), 3);
  for (size_t i = 0; i < pts.size(); ++i) out.row(i) = pts[i].transpose();
  return out;
}

void calc_path_unit_forces(const PathSetModel& model, int path, const PathResult& result,
                           const std::vector<Transform>& X_ground_body, const VecX& q,
                           PathUnitForces& out) {
  const CompiledPath& p = model.paths[path];
  const auto& v = result.vertices;
  const int nv = static_cast<int>(v.size());
  out.forces.clear();
  out.dL_dq_explicit.setZero(model.num_coordinates);
  // Net force of a unit tension on each vertex, as a point of its body. Straight segments pull
  // their two ends together; a wrap arc joins two points of the same obstacle and adds nothing
  // (its tangent points carry the pull of the adjacent segments onto the obstacle). This is exact
  // for shortest-path (geodesic) wraps, by the envelope theorem.
  std::vector<Vec3> f(nv, Vec3::Zero());
  // A wrap over a non-spherical ellipsoid is a central section, not a shortest path, so the
  // envelope argument fails there. Its piece p1 → t1 ⌒ t2 → p2 is instead differentiated as the
  // function L_w(p1, p2) it is (end points in the wrap frame W, the object fixed): the end points
  // get −∇L_w and the wrap body +∇L_w at the same points (the relative motion is what changes
  // L_w), so the moment arm is −dL/dq of the length actually computed. ∇L_w is taken by central
  // differences of the closed-form wrap (h = 1e-6 m; error ≈ 1e-9 m, measured in the tests).
  std::vector<char> skip(nv, 0);  // segment (i, i+1) already accounted for
  for (int i = 1; i + 2 < nv; ++i) {
    if (v[i].tangent != 1 || v[i + 1].wrap != v[i].wrap) continue;
    const PathWrapState& ws = result.wraps[v[i].wrap];
    const CompiledWrapObject& obj = model.wrap_objects[p.wraps[v[i].wrap].object];
    const Vec3& radii = obj.spec.radii;
    if (obj.spec.shape != WrapShape::ellipsoid ||
        radii.maxCoeff() - radii.minCoeff() <= 1e-12 * radii.maxCoeff())
      continue;
    const Transform X_wrap_ground = ws.X_ground_wrap.inverse();
    const Vec3 a = X_wrap_ground * v[i - 1].p_ground, b = X_wrap_ground * v[i + 2].p_ground;
    const auto length_w = [&](const Vec3& x1, const Vec3& x2) {
      return wrapped_segment_length(x1, x2, wrap_segment(obj.spec, x1, x2, model.options.cylinder_ends));
    };
    const double h = 1e-6;
    Vec3 ga, gb;
    for (int k = 0; k < 3; ++k) {
      Vec3 e = Vec3::Zero();
      e[k] = h;
      ga[k] = (length_w(a + e, b) - length_w(a - e, b)) / (2 * h);
      gb[k] = (length_w(a, b + e) - length_w(a, b - e)) / (2 * h);
    }
    const Mat3 R = ws.X_ground_wrap.linear();
    const Vec3 G1 = R * ga, G2 = R * gb;
    f[i - 1] -= G1;
    f[i + 2] -= G2;
    out.forces.push_back({obj.body, v[i - 1].p_ground, G1});
    out.forces.push_back({obj.body, v[i + 2].p_ground, G2});
    skip[i - 1] = skip[i + 1] = 1;
  }
  for (int i = 0; i + 1 < nv; ++i) {
    if (skip[i]) continue;
    if (v[i].tangent == 1 && v[i + 1].wrap == v[i].wrap) continue;
    const Vec3 d = v[i + 1].p_ground - v[i].p_ground;
    const double n = d.norm();
    if (n < 1e-15) continue;
    f[i] += d / n;
    f[i + 1] -= d / n;
  }
  for (int i = 0; i < nv; ++i) {
    out.forces.push_back({v[i].body, v[i].p_ground, f[i]});
    if (v[i].point < 0) continue;
    const CompiledPathPoint& pt = p.points[v[i].point];
    if (pt.kind != PathPointKind::moving) continue;
    // Explicit dL/dq_c = (dL/dp)·R ds/dq_c = -f·R e_a s_a'(q_c).
    const Mat3 R = X_ground_body[pt.body].linear();
    for (int a = 0; a < 3; ++a) {
      const int32_t c = pt.location_coordinate[a];
      if (c < 0) continue;
      out.dL_dq_explicit[c] -= f[i].dot(R.col(a)) * pt.location[a].slope(q[c]);
    }
  }
}

VecX calc_moment_arms(const PathSetModel& model, int path, const PathResult& result,
                      const std::vector<Transform>& X_ground_body, const VecX& q,
                      const BodyJacobians& jacobians) {
  PathUnitForces uf;
  calc_path_unit_forces(model, path, result, X_ground_body, q, uf);
  const Eigen::Index nu = jacobians.dq_du.cols();
  VecX r = -jacobians.dq_du.transpose() * uf.dL_dq_explicit;
  for (const PathPointForce& pf : uf.forces) {
    const auto& J = jacobians.J[pf.body];
    if (J.cols() != nu) continue;  // a body without mobility (ground) may have an empty Jacobian
    r += J.topRows<3>().transpose() * pf.p_ground.cross(pf.f_ground) +
         J.bottomRows<3>().transpose() * pf.f_ground;
  }
  return r;
}

}  // namespace fascicle
