// OpenSim .osim import (see osim_model.hpp).
#include "fascicle/osim/osim_model.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <cmath>
#include <fstream>
#include <map>
#include <pugixml.hpp>
#include <set>
#include <sstream>

#include "fascicle/core/error.hpp"
#include "fascicle/musculotendon/osim_parameters.hpp"

namespace fascicle {
namespace {

using pugi::xml_node;

// Element name without an XML-namespace-like prefix ("OpenSim::Body" → "Body").
std::string local_name(const xml_node& n) {
  const std::string s = n.name();
  const auto k = s.rfind("::");
  return k == std::string::npos ? s : s.substr(k + 2);
}

xml_node child(const xml_node& n, const char* name) {
  for (xml_node c : n.children())
    if (c.type() == pugi::node_element && local_name(c) == name) return c;
  return {};
}

std::vector<xml_node> elements(const xml_node& n) {
  std::vector<xml_node> out;
  for (xml_node c : n.children())
    if (c.type() == pugi::node_element) out.push_back(c);
  return out;
}

// The last component of a component path ("/bodyset/femur_r" → "femur_r").
std::string last_component(std::string s) {
  while (!s.empty() && s.back() == '/') s.pop_back();
  const auto k = s.rfind('/');
  return k == std::string::npos ? s : s.substr(k + 1);
}

std::string trimmed(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return {};
  return s.substr(b, s.find_last_not_of(" \t\r\n") - b + 1);
}

struct Ctx {
  std::filesystem::path file;
  std::string text;  // whole file, for line numbers
  long line_of(const xml_node& n) const {
    const std::ptrdiff_t off = n.offset_debug();
    if (off < 0) return 0;
    return 1 + static_cast<long>(std::count(text.begin(), text.begin() + std::min<std::ptrdiff_t>(off, static_cast<std::ptrdiff_t>(text.size())), '\n'));
  }
  [[noreturn]] void fail(const xml_node& n, const std::string& msg, const std::string& object = {},
                         const std::string& hint = {}) const {
    ErrorContext c;
    c.file = file.string();
    c.line = line_of(n);
    c.object = object;
    c.suggestion = hint;
    throw_bad_input(msg, c);
  }
};

std::vector<double> numbers(const Ctx& ctx, const xml_node& n, const std::string& what) {
  std::vector<double> out;
  std::istringstream in(n.child_value());
  std::string tok;
  while (in >> tok) {
    char* end = nullptr;
    const double v = std::strtod(tok.c_str(), &end);
    if (end == tok.c_str() || *end != '\0' || !std::isfinite(v))
      ctx.fail(n, fmt::format("<{}>: '{}' is not a finite number", local_name(n), tok), what);
    out.push_back(v);
  }
  return out;
}

double number(const Ctx& ctx, const xml_node& parent, const char* name, double fallback,
              const std::string& what) {
  const xml_node n = child(parent, name);
  if (!n) return fallback;
  const auto v = numbers(ctx, n, what);
  if (v.empty()) return fallback;
  if (v.size() != 1) ctx.fail(n, fmt::format("<{}> must hold one number", name), what);
  return v[0];
}

Vec3 vec3(const Ctx& ctx, const xml_node& parent, const char* name, const Vec3& fallback,
          const std::string& what) {
  const xml_node n = child(parent, name);
  if (!n) return fallback;
  const auto v = numbers(ctx, n, what);
  if (v.empty()) return fallback;
  if (v.size() != 3) ctx.fail(n, fmt::format("<{}> must hold three numbers", name), what);
  return Vec3(v[0], v[1], v[2]);
}

bool flag(const xml_node& parent, const char* name, bool fallback) {
  const xml_node n = child(parent, name);
  if (!n) return fallback;
  const std::string v = trimmed(n.child_value());
  if (v.empty()) return fallback;
  return v == "true" || v == "1";
}

std::string text(const xml_node& parent, const char* name) {
  const xml_node n = child(parent, name);
  return n ? trimmed(n.child_value()) : std::string();
}

// OpenSim orientations are body-fixed X-Y-Z Euler angles.
Mat3 body_xyz(const Vec3& a) {
  return (Eigen::AngleAxisd(a.x(), Vec3::UnitX()) * Eigen::AngleAxisd(a.y(), Vec3::UnitY()) *
          Eigen::AngleAxisd(a.z(), Vec3::UnitZ())).toRotationMatrix();
}

Transform make_transform(const Vec3& translation, const Vec3& orientation) {
  Transform X = Transform::Identity();
  X.linear() = body_xyz(orientation);
  X.translation() = translation;
  return X;
}

// ---------------------------------------------------------------------------------------------
// Functions

bool is_function_type(const std::string& t) {
  static const std::set<std::string> known{"Constant", "LinearFunction", "SimmSpline",
                                           "NaturalCubicSpline", "PiecewiseLinearFunction",
                                           "PolynomialFunction", "MultiplierFunction", "GCVSpline",
                                           "PiecewiseConstantFunction", "StepFunction", "Sine",
                                           "MultivariatePolynomialFunction", "PiecewiseLinearFunction"};
  return known.count(t) > 0 || t.find("Function") != std::string::npos ||
         t.find("Spline") != std::string::npos;
}

Function parse_function_element(const Ctx& ctx, const xml_node& f, const std::string& what);

// The function held by a property element such as <function>, <x_location> (or null when empty).
std::optional<Function> parse_function_in(const Ctx& ctx, const xml_node& holder,
                                          const std::string& what) {
  if (!holder) return std::nullopt;
  for (const xml_node& e : elements(holder))
    if (is_function_type(local_name(e))) return parse_function_element(ctx, e, what);
  return std::nullopt;
}

// The function stored in property `prop` of `parent`: either <prop><SimmSpline>…</prop> or, as
// OpenSim 4.0 writes it, <SimmSpline name="prop">…</SimmSpline>.
std::optional<Function> find_function(const Ctx& ctx, const xml_node& parent, const char* prop,
                                      const std::string& what) {
  if (!parent) return std::nullopt;
  for (const xml_node& e : elements(parent)) {
    if (local_name(e) == prop) return parse_function_in(ctx, e, what);
    if (std::string(e.attribute("name").as_string()) == prop && is_function_type(local_name(e)))
      return parse_function_element(ctx, e, what);
  }
  return std::nullopt;
}

Function parse_function_element(const Ctx& ctx, const xml_node& f, const std::string& what) {
  const std::string t = local_name(f);
  if (t == "Constant") return make_constant(number(ctx, f, "value", 0.0, what));
  if (t == "LinearFunction") {
    const auto c = numbers(ctx, child(f, "coefficients"), what);
    if (c.size() != 2) ctx.fail(f, "LinearFunction needs two coefficients (slope, intercept)", what);
    return make_linear(c[0], c[1]);
  }
  if (t == "SimmSpline" || t == "NaturalCubicSpline" || t == "PiecewiseLinearFunction") {
    auto x = numbers(ctx, child(f, "x"), what);
    auto y = numbers(ctx, child(f, "y"), what);
    try {
      if (t == "SimmSpline") return make_simm_spline(x, y, what);
      if (t == "NaturalCubicSpline") return make_natural_cubic(x, y, what);
      return make_piecewise_linear(x, y, what);
    } catch (const Error& e) {
      ctx.fail(f, e.message(), what);
    }
  }
  if (t == "PolynomialFunction") return make_polynomial(numbers(ctx, child(f, "coefficients"), what));
  if (t == "MultiplierFunction") {
    const auto inner = find_function(ctx, f, "function", what);
    if (!inner) ctx.fail(f, "MultiplierFunction has no inner function", what);
    return make_multiplier(*inner, number(ctx, f, "scale", 1.0, what));
  }
  ctx.fail(f, fmt::format("function type '{}' is not supported", t), what,
           "supported: Constant, LinearFunction, SimmSpline, NaturalCubicSpline, "
           "PiecewiseLinearFunction, PolynomialFunction, MultiplierFunction");
}

// ---------------------------------------------------------------------------------------------
// Bodies, joints, coordinates

struct Importer {
  Ctx ctx;
  OsimImportOptions options;
  OsimModel model;
  std::set<std::string> unsupported;
  std::vector<std::string> adjusted;  // values changed on import as OpenSim does (logged)

  void note_unsupported(const xml_node& n) {
    const std::string name = n.attribute("name").as_string();
    unsupported.insert(local_name(n) + (name.empty() ? "" : " '" + name + "'"));
  }

  MeshReference mesh(const std::string& file, const Vec3& scale, const Transform& X) {
    MeshReference m;
    const auto found = find_mesh_file(file, ctx.file, options.geometry_dirs);
    m.file = found.empty() ? file : found.string();
    if (found.empty()) model.missing_meshes.push_back(file);
    m.scale = scale;
    m.X_body_mesh = X;
    return m;
  }

  void read_geometry(const xml_node& body, std::vector<MeshReference>& out) {
    // 4.x: <attached_geometry><Mesh><mesh_file>, scale_factors (in the body frame).
    if (const xml_node ag = child(body, "attached_geometry"))
      for (const xml_node& g : elements(ag)) {
        if (local_name(g) != "Mesh") continue;
        const std::string f = text(g, "mesh_file");
        if (!f.empty())
          out.push_back(mesh(f, vec3(ctx, g, "scale_factors", Vec3::Ones(), f), Transform::Identity()));
      }
    // 4.x: meshes attached to offset frames of the body (<components>/<frames>).
    for (const char* holder : {"components", "frames"})
      if (const xml_node comps = child(body, holder))
        for (const xml_node& fr : elements(comps)) {
          if (local_name(fr) != "PhysicalOffsetFrame") continue;
          const Transform X = make_transform(vec3(ctx, fr, "translation", Vec3::Zero(), ""),
                                             vec3(ctx, fr, "orientation", Vec3::Zero(), ""));
          std::vector<MeshReference> sub;
          read_geometry(fr, sub);
          for (auto& m : sub) {
            m.X_body_mesh = X * m.X_body_mesh;
            out.push_back(m);
          }
        }
    // 3.x: <VisibleObject><GeometrySet><objects><DisplayGeometry> or <geometry_files>.
    if (const xml_node vo = child(body, "VisibleObject")) {
      const Vec3 scale = vec3(ctx, vo, "scale_factors", Vec3::Ones(), "");
      if (const xml_node gs = child(child(vo, "GeometrySet"), "objects"))
        for (const xml_node& g : elements(gs)) {
          const std::string f = text(g, "geometry_file");
          if (f.empty()) continue;
          Transform X = Transform::Identity();
          if (const xml_node t = child(g, "transform")) {
            const auto v = numbers(ctx, t, f);
            if (v.size() == 6) X = make_transform(Vec3(v[3], v[4], v[5]), Vec3(v[0], v[1], v[2]));
          }
          const Vec3 s = vec3(ctx, g, "scale_factors", Vec3::Ones(), f);
          out.push_back(mesh(f, Vec3(s.cwiseProduct(scale)), X));
        }
      std::istringstream files(text(vo, "geometry_files"));
      std::string f;
      while (files >> f) out.push_back(mesh(f, scale, Transform::Identity()));
    }
  }

  void read_wrap_objects(const xml_node& body, const std::string& body_name) {
    const xml_node set = child(child(body, "WrapObjectSet"), "objects");
    if (!set) return;
    for (const xml_node& w : elements(set)) {
      const std::string t = local_name(w);
      WrapObjectSpec o;
      o.name = w.attribute("name").as_string();
      o.body = body_name;
      if (t == "WrapCylinder") {
        o.shape = WrapShape::cylinder;
        o.radius = number(ctx, w, "radius", kPathNaN, o.name);
        o.length = number(ctx, w, "length", 1.0, o.name);
      } else if (t == "WrapSphere") {
        o.shape = WrapShape::sphere;
        o.radius = number(ctx, w, "radius", kPathNaN, o.name);
      } else if (t == "WrapEllipsoid") {
        o.shape = WrapShape::ellipsoid;
        o.radii = vec3(ctx, w, "dimensions", Vec3::Constant(kPathNaN), o.name);
      } else if (t == "WrapTorus") {
        o.shape = WrapShape::torus;
        o.ring_radius = number(ctx, w, "outer_radius", kPathNaN, o.name);
        o.radius = number(ctx, w, "inner_radius", kPathNaN, o.name);
      } else {
        note_unsupported(w);
        continue;
      }
      o.X_body_wrap = make_transform(vec3(ctx, w, "translation", Vec3::Zero(), o.name),
                                     vec3(ctx, w, "xyz_body_rotation", Vec3::Zero(), o.name));
      const std::string q = text(w, "quadrant");
      try {
        o.quadrant = parse_wrap_quadrant(q.empty() ? "all" : q);
      } catch (const Error& e) {
        ctx.fail(w, e.message(), o.name);
      }
      o.active = flag(w, "active", true);
      model.paths.wrap_objects.push_back(o);
    }
  }

  BodySpec read_body(const xml_node& b) {
    BodySpec s;
    s.name = b.attribute("name").as_string();
    s.mass = number(ctx, b, "mass", 0.0, s.name);
    s.com = vec3(ctx, b, "mass_center", Vec3::Zero(), s.name);
    if (const xml_node in = child(b, "inertia")) {  // 4.x: Ixx Iyy Izz Ixy Ixz Iyz
      const auto v = numbers(ctx, in, s.name);
      if (v.size() != 6) ctx.fail(in, "<inertia> must hold six numbers", s.name);
      s.inertia << v[0], v[3], v[4], v[3], v[1], v[5], v[4], v[5], v[2];
    } else {
      const auto g = [&](const char* n) { return number(ctx, b, n, 0.0, s.name); };
      s.inertia << g("inertia_xx"), g("inertia_xy"), g("inertia_xz"), g("inertia_xy"),
          g("inertia_yy"), g("inertia_yz"), g("inertia_xz"), g("inertia_yz"), g("inertia_zz");
    }
    // OpenSim (Body::getInertia) zeroes the inertia of a massless body and replaces a diagonal
    // that violates the triangle inequality by a sphere's, |diag|/√3 on each axis, with a warning.
    const Vec3 d = s.inertia.diagonal();
    if (std::abs(s.mass) <= 1e-12 && !s.inertia.isZero(0.0)) {
      s.inertia.setZero();
      adjusted.push_back("body '" + s.name + "' is massless: inertia set to zero");
    } else if (d.allFinite() && (d.x() + d.y() < d.z() - 1e-12 || d.x() + d.z() < d.y() - 1e-12 ||
                                 d.y() + d.z() < d.x() - 1e-12)) {
      s.inertia = Mat3::Identity() * (d.norm() / std::sqrt(3.0));
      adjusted.push_back("body '" + s.name +
                         "' has an inertia that violates the triangle inequality: replaced by a "
                         "sphere's (as OpenSim does)");
    }
    read_geometry(b, s.meshes);
    read_wrap_objects(b, s.name);
    return s;
  }

  CoordinateSpec read_coordinate(const xml_node& c) {
    CoordinateSpec s;
    s.name = c.attribute("name").as_string();
    s.default_value = number(ctx, c, "default_value", 0.0, s.name);
    if (const xml_node r = child(c, "range")) {
      const auto v = numbers(ctx, r, s.name);
      if (v.size() == 2) {
        s.range_min = v[0];
        s.range_max = v[1];
      }
    }
    s.locked = flag(c, "locked", false);
    s.clamped = flag(c, "clamped", false);
    const std::string mt = text(c, "motion_type");
    s.motion_type = mt == "translational" ? MotionType::translational
                    : mt == "coupled"     ? MotionType::coupled
                                          : MotionType::rotational;
    return s;
  }

  // A joint's frame reference (4.x socket): an offset frame of the joint or a body.
  std::pair<std::string, Transform> resolve_frame(const xml_node& joint, const std::string& path) {
    const std::string name = last_component(path);
    if (const xml_node frames = child(joint, "frames"))
      for (const xml_node& f : elements(frames))
        if (std::string(f.attribute("name").as_string()) == name) {
          const std::string parent = last_component(text(f, "socket_parent"));
          return {parent, make_transform(vec3(ctx, f, "translation", Vec3::Zero(), name),
                                         vec3(ctx, f, "orientation", Vec3::Zero(), name))};
        }
    return {name, Transform::Identity()};
  }

  void read_joint(const xml_node& j, const std::string& child_body_3x) {
    JointSpec s;
    s.name = j.attribute("name").as_string();
    const std::string t = local_name(j);
    static const std::map<std::string, JointType> types{
        {"WeldJoint", JointType::weld},     {"PinJoint", JointType::pin},
        {"SliderJoint", JointType::slider}, {"UniversalJoint", JointType::universal},
        {"BallJoint", JointType::ball},     {"FreeJoint", JointType::free},
        {"CustomJoint", JointType::custom}, {"GimbalJoint", JointType::gimbal},
        {"PlanarJoint", JointType::planar}, {"EllipsoidJoint", JointType::ellipsoid},
        {"ScapulothoracicJoint", JointType::scapulothoracic}};
    const auto it = types.find(t);
    if (it == types.end())
      ctx.fail(j, fmt::format("joint type '{}' is not supported", t), s.name,
               "supported: WeldJoint, PinJoint, SliderJoint, UniversalJoint, BallJoint, FreeJoint, "
               "CustomJoint, GimbalJoint, PlanarJoint, EllipsoidJoint, ScapulothoracicJoint");
    s.type = it->second;
    if (!child_body_3x.empty()) {  // 3.x: the joint lives in its child body
      s.parent = text(j, "parent_body");
      s.child = child_body_3x;
      s.X_parent_F = make_transform(vec3(ctx, j, "location_in_parent", Vec3::Zero(), s.name),
                                    vec3(ctx, j, "orientation_in_parent", Vec3::Zero(), s.name));
      s.X_child_M = make_transform(vec3(ctx, j, "location", Vec3::Zero(), s.name),
                                   vec3(ctx, j, "orientation", Vec3::Zero(), s.name));
      if (flag(j, "reverse", false))
        ctx.fail(j, "reversed joints are not supported", s.name);
    } else {
      auto [parent, X_PF] = resolve_frame(j, text(j, "socket_parent_frame"));
      auto [childb, X_BM] = resolve_frame(j, text(j, "socket_child_frame"));
      s.parent = parent;
      s.child = childb;
      s.X_parent_F = X_PF;
      s.X_child_M = X_BM;
    }
    const xml_node coords = child(j, "coordinates") ? child(j, "coordinates")
                                                    : child(child(j, "CoordinateSet"), "objects");
    for (const xml_node& c : elements(coords))
      if (local_name(c) == "Coordinate") s.coordinates.push_back(read_coordinate(c));
    if (s.type == JointType::ellipsoid)
      s.ellipsoid_radii = vec3(ctx, j, "radii_x_y_z", Vec3::Constant(NAN), s.name);
    if (s.type == JointType::scapulothoracic) {
      s.ellipsoid_radii = vec3(ctx, j, "thoracic_ellipsoid_radii_x_y_z", Vec3::Constant(NAN), s.name);
      if (const xml_node o = child(j, "scapula_winging_axis_origin")) {
        const auto v = numbers(ctx, o, s.name);
        if (v.size() != 2) ctx.fail(o, "<scapula_winging_axis_origin> must hold two numbers", s.name);
        s.winging_origin = Vec2(v[0], v[1]);
      }
      s.winging_direction = number(ctx, j, "scapula_winging_axis_direction", 0.0, s.name);
    }
    if ((s.type == JointType::ellipsoid || s.type == JointType::scapulothoracic) &&
        !(s.ellipsoid_radii.allFinite() && s.ellipsoid_radii.minCoeff() > 0.0))
      ctx.fail(j, "the joint's ellipsoid radii are missing or not positive", s.name,
               s.type == JointType::ellipsoid ? "give <radii_x_y_z> as three positive numbers (m)"
                                              : "give <thoracic_ellipsoid_radii_x_y_z> as three "
                                                "positive numbers (m)");
    if (s.type == JointType::custom) {
      const xml_node st = child(j, "SpatialTransform");
      int i = 0;
      for (const xml_node& a : elements(st)) {
        if (local_name(a) != "TransformAxis" || i >= 6) continue;
        TransformAxisSpec& ax = s.spatial_transform.axes[i];
        std::istringstream names(text(a, "coordinates"));
        std::vector<std::string> cs;
        for (std::string c; names >> c;) cs.push_back(c);
        if (cs.size() > 1)
          ctx.fail(a, "transform axes driven by several coordinates are not supported", s.name);
        ax.coordinate = cs.empty() ? std::string() : cs[0];
        ax.axis = vec3(ctx, a, "axis", i < 3 ? Vec3::Unit(i) : Vec3::Unit(i - 3), s.name);
        const auto f = find_function(ctx, a, "function", s.name);
        ax.function = f ? *f : (ax.coordinate.empty() ? make_constant(0.0) : make_linear(1.0, 0.0));
        ++i;
      }
    }
    // 4.x files do not store motion_type: it follows from the axes a coordinate drives.
    const xml_node coord_list = coords;
    std::size_t k = 0;
    for (const xml_node& c : elements(coord_list)) {
      if (local_name(c) != "Coordinate") continue;
      CoordinateSpec& cs = s.coordinates[k];
      if (text(c, "motion_type").empty()) {
        bool rotates = false;
        if (s.type == JointType::custom) {
          for (int a = 0; a < 3; ++a) rotates = rotates || s.spatial_transform.axes[a].coordinate == cs.name;
        } else {
          rotates = s.type != JointType::slider && !(s.type == JointType::free && k >= 3) &&
                    !(s.type == JointType::planar && k >= 1);
        }
        cs.motion_type = rotates ? MotionType::rotational : MotionType::translational;
      }
      ++k;
    }
    model.skeleton.joints.push_back(s);
  }

  void read_constraints(const xml_node& set) {
    for (const xml_node& c : elements(child(set, "objects"))) {
      if (local_name(c) != "CoordinateCouplerConstraint") {
        note_unsupported(c);
        continue;
      }
      CouplerSpec s;
      s.name = c.attribute("name").as_string();
      if (flag(c, "isDisabled", false) || !flag(c, "isEnforced", true)) continue;
      std::istringstream names(text(c, "independent_coordinate_names"));
      std::vector<std::string> ind;
      for (std::string n; names >> n;) ind.push_back(n);
      if (ind.size() != 1)
        ctx.fail(c, "couplers with other than one independent coordinate are not supported", s.name);
      s.independent = ind[0];
      s.dependent = text(c, "dependent_coordinate_name");
      const auto f = find_function(ctx, c, "coupled_coordinates_function", s.name);
      if (!f) ctx.fail(c, "coupler has no coupled_coordinates_function", s.name);
      const double scale = number(ctx, c, "scale_factor", 1.0, s.name);
      s.function = scale == 1.0 ? *f : make_multiplier(*f, scale);
      model.skeleton.couplers.push_back(s);
    }
  }

  // ---------------------------------------------------------------------------------------------
  // Paths

  CoordinateFunction coordinate_function(const xml_node& p, const char* coord_tag,
                                         const char* socket_tag, const char* location_tag,
                                         const std::string& what) {
    std::string coord = text(p, coord_tag);
    if (coord.empty()) coord = last_component(text(p, socket_tag));
    const auto f = find_function(ctx, p, location_tag, what);
    if (!f) return constant_function(0.0);
    if (coord.empty() || is_constant(*f)) return constant_function(calc_value(*f, 0.0));
    CoordinateFunction cf;
    cf.coordinate = coord;
    const Function fn = *f;
    cf.value = [fn](double x) { return calc_value(fn, x); };
    cf.slope = [fn](double x) { return calc_slope(fn, x); };
    return cf;
  }

  std::string point_body(const xml_node& p) {
    const std::string b = text(p, "body");
    return b.empty() ? last_component(text(p, "socket_parent_frame")) : b;
  }

  GeometryPathSpec read_path(const xml_node& gp, const std::string& name) {
    GeometryPathSpec s;
    s.name = name;
    for (const xml_node& p : elements(child(child(gp, "PathPointSet"), "objects"))) {
      const std::string t = local_name(p);
      PathPointSpec pt;
      pt.name = p.attribute("name").as_string();
      pt.body = point_body(p);
      pt.p_body = vec3(ctx, p, "location", Vec3::Zero(), name);
      if (t == "PathPoint") {
        pt.kind = PathPointKind::fixed;
      } else if (t == "ConditionalPathPoint") {
        pt.kind = PathPointKind::conditional;
        pt.coordinate = text(p, "coordinate");
        if (pt.coordinate.empty()) pt.coordinate = last_component(text(p, "socket_coordinate"));
        const auto r = numbers(ctx, child(p, "range"), name);
        if (r.size() != 2) ctx.fail(p, "ConditionalPathPoint needs a range of two numbers", name);
        pt.range_min = r[0];
        pt.range_max = r[1];
      } else if (t == "MovingPathPoint") {
        pt.kind = PathPointKind::moving;
        pt.location[0] = coordinate_function(p, "x_coordinate", "socket_x_coordinate", "x_location", name);
        pt.location[1] = coordinate_function(p, "y_coordinate", "socket_y_coordinate", "y_location", name);
        pt.location[2] = coordinate_function(p, "z_coordinate", "socket_z_coordinate", "z_location", name);
      } else {
        ctx.fail(p, fmt::format("path point type '{}' is not supported", t), name);
      }
      s.points.push_back(pt);
    }
    if (s.points.size() < 2)
      ctx.fail(gp, fmt::format("path has {} point(s); at least two are needed", s.points.size()),
               name);
    for (const xml_node& w : elements(child(child(gp, "PathWrapSet"), "objects"))) {
      if (local_name(w) != "PathWrap") {
        note_unsupported(w);
        continue;
      }
      PathWrapSpec pw;
      pw.wrap_object = text(w, "wrap_object");
      if (pw.wrap_object.empty()) pw.wrap_object = last_component(text(w, "socket_wrap_object"));
      const std::string method = text(w, "method");
      try {
        pw.method = parse_wrap_method(method.empty() ? "hybrid" : method);
      } catch (const Error& e) {
        ctx.fail(w, e.message(), name);
      }
      if (const xml_node r = child(w, "range")) {
        const auto v = numbers(ctx, r, name);
        if (v.size() == 2) {
          pw.range_begin = static_cast<int>(v[0]);
          pw.range_end = static_cast<int>(v[1]);
        }
      }
      s.wraps.push_back(pw);
    }
    return s;
  }

  void read_forces(const xml_node& set) {
    for (const xml_node& f : elements(child(set, "objects"))) {
      const std::string t = local_name(f);
      const xml_node gp = child(f, "GeometryPath");
      if (!gp) {
        note_unsupported(f);
        continue;
      }
      OsimPathActuator a;
      a.name = f.attribute("name").as_string();
      a.type = t;
      // OpenSim accepts a rigid tendon of zero slack length (ThoracoscapularShoulderModel's
      // SerratusAnterior_I/II); the musculotendon module requires a positive one, so such a
      // muscle is kept as a path only and listed in the unsupported warning.
      const bool zero_rigid_tendon = is_osim_muscle_element(f) &&
                                     flag(f, "ignore_tendon_compliance", false) &&
                                     number(ctx, f, "tendon_slack_length", 1.0, a.name) == 0.0;
      if (zero_rigid_tendon) {
        unsupported.insert(t + " '" + a.name +
                           "' (rigid tendon of zero slack length: path only, no fibre quantities)");
      } else if (is_osim_muscle_element(f)) {
        a.muscle = parse_osim_muscle(f, ctx.file.string());
        a.default_activation = number(ctx, f, "default_activation", 0.05, a.name);
      } else if (t != "PathActuator" && t != "PathSpring" && t != "Ligament") {
        note_unsupported(f);  // a path-based force we do not model: its path is still read
      }
      a.path = static_cast<int>(model.paths.paths.size());
      model.paths.paths.push_back(read_path(gp, a.name));
      model.actuators.push_back(a);
    }
  }
};

}  // namespace

std::filesystem::path find_mesh_file(const std::string& mesh_file,
                                     const std::filesystem::path& model_file,
                                     const std::vector<std::filesystem::path>& geometry_dirs) {
  namespace fs = std::filesystem;
  const fs::path f(mesh_file);
  std::error_code ec;
  if (f.is_absolute()) return fs::exists(f, ec) ? f : fs::path();
  const fs::path dir = model_file.parent_path();
  std::vector<fs::path> candidates{dir / f, dir / "Geometry" / f};
  for (const auto& g : geometry_dirs) candidates.push_back(g / f);
  for (const auto& c : candidates)
    if (fs::exists(c, ec)) return c;
  return {};
}

OsimModel read_osim(const std::filesystem::path& path, const OsimImportOptions& options) {
  Importer im;
  im.ctx.file = path;
  im.options = options;
  {
    std::ifstream in(path, std::ios::binary);
    if (!in)
      throw_bad_input("cannot open the model file", ErrorContext{path.string(), std::nullopt, {}, {}, "check the path"});
    std::ostringstream ss;
    ss << in.rdbuf();
    im.ctx.text = ss.str();
  }
  pugi::xml_document doc;
  const pugi::xml_parse_result r = doc.load_buffer(im.ctx.text.data(), im.ctx.text.size());
  if (!r) {
    const long line = 1 + static_cast<long>(std::count(im.ctx.text.begin(), im.ctx.text.begin() + std::min<std::ptrdiff_t>(r.offset, static_cast<std::ptrdiff_t>(im.ctx.text.size())), '\n'));
    throw_bad_input(std::string("malformed XML: ") + r.description(),
                    ErrorContext{path.string(), line, {}, {}, {}});
  }
  const xml_node root = doc.document_element();
  if (local_name(root) != "OpenSimDocument")
    im.ctx.fail(root, "not an OpenSim model (root element is not <OpenSimDocument>)");
  im.model.version = root.attribute("Version").as_int();
  const xml_node m = child(root, "Model");
  if (!m) im.ctx.fail(root, "no <Model> element");
  im.model.file = path;
  im.model.name = m.attribute("name").as_string();
  im.model.skeleton.name = im.model.name;
  im.model.skeleton.gravity = vec3(im.ctx, m, "gravity", Vec3(0, -9.80665, 0), "gravity");
  // Ground (4.x element, or a body named ground in 3.x).
  if (const xml_node g = child(m, "Ground")) {
    im.read_geometry(g, im.model.skeleton.ground_meshes);
    im.read_wrap_objects(g, "ground");
  }
  for (const xml_node& b : elements(child(child(m, "BodySet"), "objects"))) {
    if (local_name(b) != "Body") {
      im.note_unsupported(b);
      continue;
    }
    BodySpec body = im.read_body(b);
    if (body.name == "ground") {
      im.model.skeleton.ground_meshes.insert(im.model.skeleton.ground_meshes.end(),
                                             body.meshes.begin(), body.meshes.end());
    } else {
      im.model.skeleton.bodies.push_back(body);
    }
    // 3.x: the body's joint.
    for (const xml_node& j : elements(child(b, "Joint"))) im.read_joint(j, body.name);
  }
  for (const xml_node& j : elements(child(child(m, "JointSet"), "objects"))) im.read_joint(j, "");
  im.read_constraints(child(m, "ConstraintSet"));
  im.read_forces(child(m, "ForceSet"));
  for (const char* other : {"MarkerSet", "ContactGeometrySet", "ControllerSet", "ProbeSet", "ComponentSet"})
    for (const xml_node& e : elements(child(child(m, other), "objects"))) im.note_unsupported(e);
  im.model.unsupported.assign(im.unsupported.begin(), im.unsupported.end());
  if (options.warn) {
    if (!im.model.unsupported.empty()) {
      std::string list;
      for (const auto& u : im.model.unsupported) list += (list.empty() ? "" : ", ") + u;
      spdlog::warn("{}: {} element(s) not supported and skipped: {}", path.string(),
                   im.model.unsupported.size(), list);
    }
    for (const auto& a : im.adjusted) spdlog::warn("{}: {}", path.string(), a);
    for (const auto& mf : im.model.missing_meshes)
      spdlog::warn("{}: mesh file '{}' not found (model folder, Geometry/, geometry dirs)",
                   path.string(), mf);
  }
  return std::move(im.model);
}

MotionColumns match_motion_columns(const Skeleton& skeleton, const Table& motion,
                                   const std::string& motion_file, bool strict) {
  MotionColumns mc;
  mc.column_of_coordinate.assign(skeleton.num_coordinates(), -1);
  mc.scale.assign(skeleton.num_coordinates(), 1.0);
  for (long c = 0; c < motion.columns(); ++c) {
    const std::string& label = motion.labels[c];
    const std::string coord = find_coordinate_of_label(label);
    if (coord.empty()) continue;  // speeds and other outputs
    const int i = skeleton.find_coordinate(coord);
    if (i < 0) {
      if (strict)
        throw_bad_input(fmt::format("column {} ('{}') names no coordinate of the model", c + 2, label),
                        ErrorContext{motion_file, std::nullopt, {}, label,
                                     "check the motion belongs to this model"});
      continue;
    }
    mc.column_of_coordinate[i] = static_cast<int>(c);
    if (motion.in_degrees &&
        skeleton.get_coordinate(i).spec.motion_type == MotionType::rotational)
      mc.scale[i] = M_PI / 180.0;
  }
  return mc;
}

VecX get_motion_pose(const Skeleton& skeleton, const Table& motion, const MotionColumns& mc,
                     long row) {
  VecX q = skeleton.get_default_q();
  for (int i = 0; i < skeleton.num_coordinates(); ++i)
    if (mc.column_of_coordinate[i] >= 0 && skeleton.get_coordinate(i).dependent_on < 0)
      q[i] = motion.data(row, mc.column_of_coordinate[i]) * mc.scale[i];
  return q;
}

}  // namespace fascicle
