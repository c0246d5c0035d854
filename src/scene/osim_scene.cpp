// OpenSim model → scene, with generated muscle bellies (docs/opensim-volumes.md).
#include "fascicle/scene/osim_scene.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/deformation/framed_line.hpp"
#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/geometry/mesh_validation.hpp"
#include "fascicle/io/mesh_io.hpp"
#include "fascicle/path/path_model.hpp"
#include "fascicle/scene/registry.hpp"

#include <spdlog/spdlog.h>

#include <fnmatch.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

namespace fascicle {
namespace {

std::string get_model_name(MuscleModel m) { return to_string(m); }

}  // namespace

Points3 calc_sub_polyline(const Points3& polyline, double a, double b) {
  if (polyline.rows() < 2 || !(b > a)) throw_bad_input("sub-polyline: need >= 2 points and a < b");
  std::vector<Vec3> out;
  double s = 0.0;
  for (Eigen::Index i = 0; i + 1 < polyline.rows(); ++i) {
    const Vec3 p = polyline.row(i).transpose(), q = polyline.row(i + 1).transpose();
    const double len = (q - p).norm();
    const double s1 = s + len;
    if (len > 0.0) {
      if (out.empty() && a <= s1) out.push_back(p + (std::max(a, s) - s) / len * (q - p));
      if (!out.empty() && b <= s1) {
        out.push_back(p + (b - s) / len * (q - p));
        break;
      }
      if (!out.empty()) out.push_back(q);
    }
    s = s1;
  }
  if (out.size() < 2) out.push_back(polyline.row(polyline.rows() - 1).transpose());
  Points3 P(static_cast<Eigen::Index>(out.size()), 3);
  for (size_t i = 0; i < out.size(); ++i) P.row(static_cast<Eigen::Index>(i)) = out[i].transpose();
  return P;
}

BellySpan calc_belly_span(double path_length_m, double volume_m3, const MuscleParameters& p, double k) {
  const double l0_along = p.optimal_fiber_length_m * std::cos(p.pennation_at_optimal_rad);
  double belly = std::cbrt(volume_m3 / (2.0 * k * k));
  belly = std::min(std::max(belly, l0_along), 0.9 * path_length_m);
  const double start = 0.5 * (path_length_m - belly);
  return {start, start + belly};
}

namespace {

// The fibres of a circular (unpacked) belly: the profile R √sin(πu) of the shape rule.
std::vector<Points3> calc_circular_fibres(const BellyShape& b) {
  const int n = b.rings;
  const double R = b.R;
  const FramedLine& line = b.line;
  std::vector<Points3> fibres;
  // Fibres: sunflower pattern in the unit disc (golden angle), scaled by the local radius.
  const double golden = M_PI * (3.0 - std::sqrt(5.0));
  const double length = line.length_m;
  const auto radius_at = [&](double u) { return R * std::sqrt(std::max(0.0, std::sin(M_PI * std::clamp(u, 0.0, 1.0)))); };
  if (b.pennation_rad > 5.0 * M_PI / 180.0) {
    // Pennate: from the axis at u0 (spread over the middle of the belly) towards the origin tip
    // at angle α, in the half-plane of angle φ, until the distance from the axis reaches the
    // local radius (found by bisection in the fibre parameter).
    const double ca = std::cos(b.pennation_rad), sa = std::sin(b.pennation_rad);
    for (int i = 0; i < b.fibres; ++i) {
      const double u0 = 0.2 + 0.75 * (i + 0.5) / b.fibres;
      const double phi = i * golden;
      // 95 % of the profile radius: the polygonal sections lie inside the smooth profile.
      const auto gap = [&](double tau) { return tau * sa - 0.95 * radius_at(u0 - tau * ca / length); };
      double lo = 0.0, hi = u0 * length / ca;  // gap(hi) >= 0: the tip has radius 0
      for (int it = 0; it < 60; ++it) (gap(0.5 * (lo + hi)) < 0.0 ? lo : hi) = 0.5 * (lo + hi);
      const int samples = 8;
      Points3 fibre(samples, 3);
      for (int k = 0; k < samples; ++k) {
        const double tau = hi * k / (samples - 1);
        const LinePoint lp = calc_line_point(line, u0 - tau * ca / length);
        const Mat3 F = lp.frame.toRotationMatrix();
        fibre.row(k) = (lp.point + tau * sa * (std::cos(phi) * F.col(1) + std::sin(phi) * F.col(2))).transpose();
      }
      fibres.push_back(std::move(fibre));
    }
    return fibres;
  }
  for (int i = 0; i < b.fibres; ++i) {
    const double rho = 0.9 * std::sqrt((i + 0.5) / b.fibres);
    const double phi = i * golden;
    Points3 fibre(n + 2, 3);
    for (int k = 0; k < n + 2; ++k) {
      const double u = static_cast<double>(k) / (n + 1);
      const double r = R * rho * std::sqrt(std::max(0.0, std::sin(M_PI * u)));
      const Mat3 F = line.frames[k].toRotationMatrix();
      fibre.row(k) = line.points.row(k) + (r * (std::cos(phi) * F.col(1) + std::sin(phi) * F.col(2))).transpose();
    }
    fibres.push_back(std::move(fibre));
  }
  return fibres;
}

}  // namespace

GeneratedBelly make_fusiform_belly(const Points3& centreline, double volume_m3, const GeneratedBellyOptions& o,
                                   double pennation_rad) {
  const BellyShape shape = make_belly_shape(centreline, volume_m3, o.rings, o.segments, o.fibres, pennation_rad);
  GeneratedBelly belly;
  belly.mesh.V = shape.calc_vertices();
  belly.mesh.F = shape.F;
  belly.fibres = calc_circular_fibres(shape);
  return belly;
}

SceneSpec make_scene_from_osim(const OsimModel& osim, const OsimSceneOptions& options, PackingReport* packing_report) {
  SceneSpec spec;
  spec.name = osim.name.empty() ? osim.file.stem().string() : osim.name;
  spec.source = osim.file;
  spec.geometry_frame = GeometryFrame::body;
  spec.skeleton = osim.skeleton;
  spec.paths = osim.paths;

  // Bone meshes, in body frames: obstacles when every part is a closed, outward, manifold surface.
  std::vector<std::string> display_only;
  for (const BodySpec& b : osim.skeleton.bodies) {
    TriMesh all;
    bool closed = true;
    std::string files;
    for (const MeshReference& ref : b.meshes) {
      if (!std::filesystem::exists(ref.file)) continue;  // the importer warned about it
      TriMesh part;
      try {
        part = read_mesh(ref.file);
      } catch (const Error& e) {
        spdlog::warn("body '{}': mesh '{}' not read ({}); it is left out", b.name, ref.file, e.message());
        continue;
      }
      part.V = ((part.V.array().rowwise() * ref.scale.transpose().array()).matrix() *
                    ref.X_body_mesh.linear().transpose()).rowwise() + ref.X_body_mesh.translation().transpose();
      ValidationOptions vo;
      vo.check_self_intersections = false;
      const MeshReport report = validate_mesh(part, vo);
      closed = closed && report.is_closed() && report.is_manifold() && report.is_consistently_oriented() &&
               report.signed_volume > 0.0;
      const auto nv = all.V.rows(), nf = all.F.rows();
      all.V.conservativeResize(nv + part.V.rows(), 3);
      all.V.bottomRows(part.V.rows()) = part.V;
      all.F.conservativeResize(nf + part.F.rows(), 3);
      all.F.bottomRows(part.F.rows()) = part.F.array() + static_cast<int>(nv);
      files += (files.empty() ? "" : ";") + ref.file;
    }
    if (all.V.rows() == 0) continue;
    SceneBodySpec sb;
    sb.name = b.name;
    sb.mesh = std::move(all);
    sb.mesh_file = files;
    sb.mesh_is_obstacle = closed;
    if (!closed) display_only.push_back(b.name);
    spec.bodies.push_back(std::move(sb));
  }
  if (!display_only.empty()) {
    std::string list;
    for (const auto& n : display_only) list += (list.empty() ? "" : ", ") + n;
    spdlog::warn("{}: open or non-manifold bone meshes are drawn but are not obstacles: {}", osim.file.string(), list);
  }

  // The rest pose and the paths there.
  const Skeleton skeleton = compile(osim.skeleton);
  SkeletonState pose(skeleton);
  calc_pose(skeleton, skeleton.get_default_q(), pose);
  PathNames names;
  for (int b = 0; b < skeleton.num_bodies(); ++b) names.bodies.push_back(skeleton.get_body_name(b));
  for (int c = 0; c < skeleton.num_coordinates(); ++c) names.coordinates.push_back(skeleton.get_coordinate(c).spec.name);
  const PathSetModel paths = compile_paths(osim.paths, names);

  std::vector<std::string> valid;
  for (const OsimPathActuator& a : osim.actuators)
    if (a.muscle) valid.push_back(a.name);
  // A selection entry is a name or a shell pattern ("*_r"); each must select at least one muscle.
  const auto selects = [](const std::string& pattern, const std::string& name) {
    return fnmatch(pattern.c_str(), name.c_str(), 0) == 0;
  };
  for (const std::string& pattern : options.muscles)
    if (std::none_of(valid.begin(), valid.end(), [&](const std::string& n) { return selects(pattern, n); }))
      throw_unknown_name("muscle", pattern, valid, {.file = osim.file.string(), .suggestion = "see --muscles"});

  int skipped = 0;
  std::vector<BellyShape> shapes;  // one per muscle of spec.muscles
  for (const OsimPathActuator& a : osim.actuators) {
    if (!a.muscle) {
      ++skipped;
      continue;
    }
    if (!options.muscles.empty() &&
        std::none_of(options.muscles.begin(), options.muscles.end(),
                     [&](const std::string& pattern) { return selects(pattern, a.name); }))
      continue;
    const MuscleParameters& p = *a.muscle;
    PathResult result;
    calc_path(paths, a.path, pose.get_body_transforms(), pose.get_q(), result);
    const Points3 polyline = calc_path_polyline(result, 0.002);
    const double volume = p.max_isometric_force_N / options.belly.specific_tension_Pa * p.optimal_fiber_length_m;
    const BellySpan span = calc_belly_span(result.length_m, volume, p, options.belly.slenderness);
    MuscleSpec m;
    m.name = a.name;
    m.representation = options.representation;
    try {
      shapes.push_back(make_belly_shape(calc_sub_polyline(polyline, span.start_m, span.end_m), volume,
                                        options.belly.rings, options.belly.segments, options.belly.fibres,
                                        p.pennation_at_optimal_rad));
      shapes.back().name = a.name;
    } catch (const Error& e) {
      throw e.with_object(a.name);
    }
    m.mesh_file = "generated:" + a.name;
    const GeometryPathSpec& path = osim.paths.paths.at(a.path);
    m.origin = {path.points.front().body, {path.points.front().p_body}, 0.0};
    m.insertion = {path.points.back().body, {path.points.back().p_body}, 0.0};
    m.path = a.path;
    m.actuator.type = "hill";
    m.actuator.model = get_model_name(p.model);
    m.actuator.max_isometric_force_N = p.max_isometric_force_N;
    m.actuator.optimal_fiber_length_m = p.optimal_fiber_length_m;
    m.actuator.tendon_slack_length_m = p.tendon_slack_length_m;
    m.actuator.pennation_at_optimal_rad = p.pennation_at_optimal_rad;
    m.actuator.rigid_tendon = p.rigid_tendon;
    m.actuator.parameters = p;
    m.activation = options.activation >= 0.0 ? options.activation : std::clamp(a.default_activation, 0.0, 1.0);
    m.fibre_template = p.pennation_at_optimal_rad > 5.0 * M_PI / 180.0 ? "pennate" : "parallel";
    m.options = options.muscle_options;
    spec.muscles.push_back(std::move(m));
  }
  // Packing at the default pose against each other and the obstacle bones (in ground).
  PackingReport packed;
  if (options.belly.packing.enabled && !shapes.empty()) {
    std::vector<PackingObstacle> obstacles;
    for (const SceneBodySpec& b : spec.bodies) {
      if (!b.mesh_is_obstacle || !b.mesh) continue;
      const Transform& X = pose.get_body_transform(skeleton.find_body(b.name));
      PackingObstacle o{b.name, *b.mesh};
      o.mesh.V = (o.mesh.V * X.linear().transpose()).rowwise() + X.translation().transpose();
      obstacles.push_back(std::move(o));
    }
    packed = pack_bellies(shapes, obstacles, options.belly.packing);
    const auto deepest = [](const std::vector<PackingContact>& c) { return c.empty() ? 0.0 : c.front().depth_m; };
    spdlog::info("{}: generated bellies packed at the default pose in {} iterations: deepest overlap {:.2f} mm -> {:.3f} mm",
                 spec.name, packed.iterations, 1e3 * deepest(packed.before), 1e3 * deepest(packed.after));
  }
  for (size_t i = 0; i < shapes.size(); ++i) {
    MuscleSpec& m = spec.muscles[i];
    m.mesh = TriMesh{shapes[i].calc_vertices(), shapes[i].F};
    // A belly packing folded and then kept unpacked takes the packed-belly fibre rule too: it keeps
    // fibre points inside where the path bends sharply (flex_dig_r's circular fibres leave it by
    // up to 0.7 mm).
    const bool changed = i < packed.changed.size() && packed.changed[i];
    const bool folded = std::any_of(packed.folds.begin(), packed.folds.end(),
                                    [&](const PackingFold& f) { return f.name == shapes[i].name; });
    m.rest_fibres = changed || folded ? calc_belly_fibres(shapes[i]) : calc_circular_fibres(shapes[i]);
  }
  if (packing_report) *packing_report = std::move(packed);
  if (skipped > 0)
    spdlog::info("{}: {} path actuators without Hill parameters are not made volumetric", osim.file.string(), skipped);
  return spec;
}

}  // namespace fascicle
