// Path evaluation: quarter-turn lengths and moment arms (OpenSim's analytic cases), a coupled
// coordinate with moving points, conditional points, several wraps, action lines, bad input.
// Moment arms come from the generalized-force method and are compared with central finite
// differences of the length.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "fascicle/core/error.hpp"
#include "fascicle/path/path_model.hpp"

using namespace fascicle;

namespace {

constexpr double kPi = std::numbers::pi;

Transform rot_z(double q, const Vec3& origin = Vec3::Zero()) {
  Transform X = Transform::Identity();
  X.linear() = Eigen::AngleAxisd(q, Vec3::UnitZ()).toRotationMatrix();
  X.translation() = origin;
  return X;
}

PathPointSpec fixed_point(const std::string& name, const std::string& body, const Vec3& p) {
  PathPointSpec s;
  s.name = name;
  s.body = body;
  s.p_body = p;
  return s;
}

// Two bodies on a pin at the ground origin about z: "ground" and "arm" (X = Rz(q)).
struct PinModel {
  PathNames names{{"ground", "arm"}, {"q"}};
  std::vector<Transform> X(double q) const { return {Transform::Identity(), rot_z(q)}; }
  BodyJacobians J() const {
    BodyJacobians j;
    j.J.assign(2, Eigen::Matrix<double, 6, Eigen::Dynamic>::Zero(6, 1));
    j.J[1](2, 0) = 1;  // ω = z, the arm point at the ground origin does not move
    j.dq_du = MatX::Identity(1, 1);
    return j;
  }
};

WrapObjectSpec quarter_turn_object(int shape, const std::string& body) {
  WrapObjectSpec w;
  w.name = "obstacle";
  w.body = body;
  w.shape = shape == 0 ? WrapShape::cylinder : shape == 1 ? WrapShape::sphere : WrapShape::ellipsoid;
  w.radius = 0.5;
  w.length = 1.0;
  w.radii = Vec3::Constant(0.5);
  return w;
}

// OpenSim's quarter-turn case (testWrapping / testMomentArms): length 2r - 0.1 + r q, moment arm
// -r, for cylinder, sphere and equal-radii ellipsoid, with the obstacle on ground or on the arm.
TEST(PathModel, QuarterTurnLengthAndMomentArm) {
  const double r = 0.5;
  PinModel pin;
  for (int shape = 0; shape < 3; ++shape) {
    for (const char* obstacle_body : {"ground", "arm"}) {
      PathSetSpec spec;
      spec.wrap_objects.push_back(quarter_turn_object(shape, obstacle_body));
      GeometryPathSpec path;
      path.name = "m";
      path.points = {fixed_point("o", "ground", {r - 0.1, r, 0}), fixed_point("i", "arm", {-r, r, 0})};
      path.wraps.push_back({.wrap_object = "obstacle"});
      spec.paths.push_back(path);
      const PathSetModel model = compile_paths(spec, pin.names);
      PathResult res;
      for (int k = 1; k <= 10; ++k) {
        const double q = 0.5 * kPi * k / 10;
        VecX qv(1);
        qv << q;
        calc_path(model, 0, pin.X(q), qv, res);
        EXPECT_NEAR(res.length_m, 2 * r - 0.1 + r * q, 1e-12) << shape << obstacle_body;
        const VecX ma = calc_moment_arms(model, 0, res, pin.X(q), qv, pin.J());
        EXPECT_NEAR(ma[0], -r, 1e-12) << shape << obstacle_body << " q=" << q;
        EXPECT_NEAR(calc_lengthening_speed(ma, VecX::Constant(1, 2.0)), 2 * r, 1e-12);
      }
    }
  }
}

// A knee-like chain: "thigh" pinned at the origin (q0), "shank" pinned on the thigh at (1, 0, 0)
// with a dependent coordinate q1 = c(q0) (a coupler constraint), a moving point on the shank whose
// location depends on q1, a via point and a cylinder on the thigh. One generalized speed u = q0'.
struct CoupledModel {
  PathNames names{{"ground", "thigh", "shank"}, {"q0", "q1"}};
  static double c(double q0) { return 0.5 * q0 + 0.2 * std::sin(q0); }
  static double dc(double q0) { return 0.5 + 0.2 * std::cos(q0); }
  VecX q(double q0) const { return (VecX(2) << q0, c(q0)).finished(); }
  std::vector<Transform> X(double q0) const {
    const Transform X_g_thigh = rot_z(q0);
    return {Transform::Identity(), X_g_thigh, X_g_thigh * rot_z(c(q0), Vec3(1, 0, 0))};
  }
  BodyJacobians J(double q0) const {
    BodyJacobians j;
    j.J.assign(3, Eigen::Matrix<double, 6, Eigen::Dynamic>::Zero(6, 1));
    j.J[1](2, 0) = 1;
    const Vec3 o2 = X(q0)[2].translation();
    j.J[2](2, 0) = 1 + dc(q0);
    // velocity of the shank point at the ground origin: ẑ×o2 - (1 + c') ẑ×o2
    j.J[2].bottomRows<3>().col(0) = -dc(q0) * Vec3::UnitZ().cross(o2);
    j.dq_du = (MatX(2, 1) << 1, dc(q0)).finished();
    return j;
  }
};

PathSetSpec coupled_spec(double tolerance) {
  PathSetSpec spec;
  WrapObjectSpec cyl;
  cyl.name = "condyle";
  cyl.body = "thigh";
  cyl.shape = WrapShape::cylinder;
  cyl.radius = 0.12;
  cyl.length = 1.0;
  cyl.X_body_wrap.translation() = Vec3(1, 0, 0);
  cyl.quadrant = WrapQuadrant::pos_y;
  spec.wrap_objects.push_back(cyl);
  GeometryPathSpec path;
  path.name = "vastus";
  path.points.push_back(fixed_point("origin", "ground", {0.1, 0.35, 0.05}));
  path.points.push_back(fixed_point("via", "thigh", {0.6, 0.2, 0.02}));
  PathPointSpec moving;
  moving.name = "tubercle";
  moving.body = "shank";
  moving.kind = PathPointKind::moving;
  moving.location[0] = {"q1", [](double x) { return 0.3 + 0.05 * std::sin(x); },
                        [](double x) { return 0.05 * std::cos(x); }};
  moving.location[1] = {"q1", [](double x) { return 0.1 + 0.02 * x * x; },
                        [](double x) { return 0.04 * x; }};
  moving.location[2] = constant_function(0.01);
  path.points.push_back(moving);
  path.points.push_back(fixed_point("insertion", "shank", {0.5, 0.05, 0.0}));
  path.wraps.push_back({.wrap_object = "condyle"});
  spec.paths.push_back(path);
  spec.options.tolerance_m = tolerance;
  return spec;
}

TEST(PathModel, CoupledCoordinateAndMovingPointMomentArmEqualsFiniteDifference) {
  const CoupledModel m;
  const PathSetModel model = compile_paths(coupled_spec(1e-12), m.names);
  PathResult res;
  auto length = [&](double q0) {
    calc_path(model, 0, m.X(q0), m.q(q0), res);
    return res.length_m;
  };
  int wrapped = 0;
  for (int k = 0; k <= 24; ++k) {
    const double q0 = -1.2 + 2.0 * k / 24;
    const double h = 1e-6;
    const double fd = -(length(q0 + h) - length(q0 - h)) / (2 * h);
    calc_path(model, 0, m.X(q0), m.q(q0), res);
    wrapped += res.wraps[0].wrapping;
    const VecX ma = calc_moment_arms(model, 0, res, m.X(q0), m.q(q0), m.J(q0));
    EXPECT_NEAR(ma[0], fd, 1e-7) << "q0=" << q0;
  }
  EXPECT_GT(wrapped, 3);
  EXPECT_LT(wrapped, 25);
}

TEST(PathModel, ConditionalPointActiveInsideItsRange) {
  PinModel pin;
  PathSetSpec spec;
  GeometryPathSpec path;
  path.name = "m";
  path.points = {fixed_point("o", "ground", {0, 1, 0}), fixed_point("v", "arm", {1, 1, 0}),
                 fixed_point("i", "arm", {2, 0, 0})};
  path.points[1].kind = PathPointKind::conditional;
  path.points[1].coordinate = "q";
  path.points[1].range_min = 0.0;
  path.points[1].range_max = 0.5;
  spec.paths.push_back(path);
  const PathSetModel model = compile_paths(spec, pin.names);
  PathResult res;
  for (double q : {-0.2, 0.0, 0.3, 0.5, 0.7}) {
    const VecX qv = VecX::Constant(1, q);
    calc_path(model, 0, pin.X(q), qv, res);
    const Vec3 o(0, 1, 0), v = rot_z(q) * Vec3(1, 1, 0), i = rot_z(q) * Vec3(2, 0, 0);
    const bool active = q >= 0.0 && q <= 0.5;
    EXPECT_EQ(res.vertices.size(), active ? 3u : 2u);
    EXPECT_NEAR(res.length_m, active ? (v - o).norm() + (i - v).norm() : (i - o).norm(), 1e-14);
    const VecX ma = calc_moment_arms(model, 0, res, pin.X(q), qv, pin.J());
    const double h = 1e-7;
    PathResult a, b;
    calc_path(model, 0, pin.X(q + h), VecX::Constant(1, q + h), a);
    calc_path(model, 0, pin.X(q - h), VecX::Constant(1, q - h), b);
    if ((q + h >= 0 && q + h <= 0.5) == (q - h >= 0 && q - h <= 0.5)) {
      EXPECT_NEAR(ma[0], -(a.length_m - b.length_m) / (2 * h), 1e-7);
    }
  }
}

// A path over two cylinders in series, one on ground and one on the arm, iterated to 1e-13 m.
PathSetSpec make_two_cylinder_path() {
  PathSetSpec spec;
  for (int k = 0; k < 2; ++k) {
    WrapObjectSpec c;
    c.name = k == 0 ? "c0" : "c1";
    c.body = k == 0 ? "ground" : "arm";
    c.shape = WrapShape::cylinder;
    c.radius = 0.1;
    c.length = 1.0;
    c.X_body_wrap.translation() = k == 0 ? Vec3(0.5, 0.0, 0) : Vec3(-0.5, 0.0, 0);
    c.quadrant = WrapQuadrant::pos_y;
    spec.wrap_objects.push_back(c);
  }
  GeometryPathSpec path;
  path.name = "m";
  path.points = {fixed_point("o", "ground", {1.0, -0.05, 0.02}),
                 fixed_point("i", "arm", {-1.0, -0.05, -0.03})};
  path.wraps = {{.wrap_object = "c0"}, {.wrap_object = "c1"}};
  spec.paths.push_back(path);
  spec.options.tolerance_m = 1e-13;
  spec.options.max_iterations = 100;
  return spec;
}

TEST(PathModel, TwoCylindersIterateToConvergence) {
  // A path over two cylinders in series, on ground and on the arm; the lengths and moment arms of
  // the converged path agree with finite differences.
  PinModel pin;
  PathSetSpec spec = make_two_cylinder_path();
  const PathSetModel model = compile_paths(spec, pin.names);
  PathResult res;
  auto length = [&](double q) {
    calc_path(model, 0, pin.X(q), VecX::Constant(1, q), res);
    return res.length_m;
  };
  for (double q : {0.05, 0.1, 0.2, 0.3}) {
    const double fd = -(length(q + 1e-6) - length(q - 1e-6)) / 2e-6;
    calc_path(model, 0, pin.X(q), VecX::Constant(1, q), res);
    ASSERT_TRUE(res.wraps[0].wrapping && res.wraps[1].wrapping) << q;
    EXPECT_EQ(res.vertices.size(), 6u);
    EXPECT_GT(res.iterations, 1);
    const VecX ma = calc_moment_arms(model, 0, res, pin.X(q), VecX::Constant(1, q), pin.J());
    EXPECT_NEAR(ma[0], fd, 1e-7) << q;
    // Straight-line length is a lower bound; the polyline has the same length as the path.
    EXPECT_GE(res.length_m, (res.vertices.back().p_ground - res.vertices.front().p_ground).norm());
    const Points3 poly = calc_path_polyline(res, 1e-4);
    double poly_len = 0;
    for (Eigen::Index i = 0; i + 1 < poly.rows(); ++i) poly_len += (poly.row(i + 1) - poly.row(i)).norm();
    EXPECT_NEAR(poly_len, res.length_m, 1e-6);
    EXPECT_LE(poly_len, res.length_m + 1e-15);
  }
}

// PathOptions::opensim_tangent_point_cache: OpenSim 4 caches each tangent point's ground position
// when a length sum first reads it (end of the first pass), so its reported length is the straight
// pieces between first-pass tangent points plus the last pass's arcs. Without the option the
// length is that of the converged path (its vertices and arcs).
TEST(PathModel, OpenSimTangentPointCacheKeepsFirstPassStraightPieces) {
  PinModel pin;
  PathSetSpec spec = make_two_cylinder_path();
  const PathSetModel consistent = compile_paths(spec, pin.names);
  spec.options.opensim_tangent_point_cache = true;
  const PathSetModel cached = compile_paths(spec, pin.names);
  spec.options.max_iterations = 1;
  const PathSetModel first_pass = compile_paths(spec, pin.names);
  for (double q : {0.1, 0.2, 0.3}) {
    const std::vector<Transform> X = pin.X(q);
    const VecX qv = VecX::Constant(1, q);
    PathResult a, b, f;
    calc_path(consistent, 0, X, qv, a);
    calc_path(cached, 0, X, qv, b);
    calc_path(first_pass, 0, X, qv, f);
    ASSERT_EQ(b.vertices.size(), 6u);
    ASSERT_EQ(f.vertices.size(), 6u);
    EXPECT_GT(b.iterations, 1);
    // The same converged path (vertices, arcs); only the reported length differs.
    EXPECT_NEAR(a.length_m, calc_path_length(a), 1e-15);
    EXPECT_NEAR(calc_path_length(b), a.length_m, 1e-12);
    double expected = 0;
    for (size_t i = 0; i + 1 < b.vertices.size(); ++i) {
      EXPECT_EQ(b.vertices[i].wrap, f.vertices[i].wrap);
      EXPECT_EQ(b.vertices[i].tangent, f.vertices[i].tangent);
      if (b.vertices[i].tangent == 1 && b.vertices[i + 1].wrap == b.vertices[i].wrap) {
        expected += b.wraps[b.vertices[i].wrap].result.arc_length;
      } else {
        expected += (f.vertices[i + 1].p_ground - f.vertices[i].p_ground).norm();
      }
    }
    EXPECT_NEAR(b.length_m, expected, 1e-12) << q;
    EXPECT_GT(std::abs(b.length_m - a.length_m), 1e-6) << q;  // the tangent points did move
  }
}

TEST(PathModel, ActionLineVariants) {
  PinModel pin;
  PathSetSpec spec;
  spec.wrap_objects.push_back(quarter_turn_object(0, "ground"));
  GeometryPathSpec path;
  path.name = "m";
  path.points = {fixed_point("o", "ground", {0.4, 0.5, 0}), fixed_point("v", "ground", {0.0, 0.9, 0}),
                 fixed_point("i", "arm", {-0.5, 0.5, 0})};
  path.wraps.push_back({.wrap_object = "obstacle"});
  for (ActionLine a : {ActionLine::straight, ActionLine::centroid}) {
    path.action_line = a;
    spec.paths.push_back(path);
  }
  const PathSetModel model = compile_paths(spec, pin.names);
  PathResult res;
  const double q = 0.8;
  const Vec3 o(0.4, 0.5, 0), v(0, 0.9, 0), i = rot_z(q) * Vec3(-0.5, 0.5, 0);
  calc_path(model, 0, pin.X(q), VecX::Constant(1, q), res);
  EXPECT_NEAR(res.length_m, (i - o).norm(), 1e-14);
  calc_path(model, 1, pin.X(q), VecX::Constant(1, q), res);
  EXPECT_NEAR(res.length_m, (v - o).norm() + (i - v).norm(), 1e-14);
}

TEST(PathModel, BadInputIsReported) {
  PinModel pin;
  PathSetSpec spec;
  GeometryPathSpec path;
  path.name = "lonely";
  path.points = {fixed_point("o", "ground", {0, 0, 0})};
  spec.paths.push_back(path);
  try {
    compile_paths(spec, pin.names);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("lonely"), std::string::npos);
  }
  spec.paths[0].points.push_back(fixed_point("i", "femur", {0, 0, 0}));
  EXPECT_THROW(compile_paths(spec, pin.names), Error);
  spec.paths[0].points[1].body = "arm";
  spec.paths[0].wraps.push_back({.wrap_object = "nowhere"});
  EXPECT_THROW(compile_paths(spec, pin.names), Error);
  spec.paths[0].wraps.clear();
  WrapObjectSpec bad = quarter_turn_object(0, "arm");
  bad.radius = -1;
  spec.wrap_objects.push_back(bad);
  EXPECT_THROW(compile_paths(spec, pin.names), Error);
}

}  // namespace
