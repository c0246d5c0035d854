// Skeleton kinematics on Simbody: hand-computed transforms, joint equivalences, coupler assembly
// and generalized forces against finite differences of station positions.
#include <gtest/gtest.h>

#include <cmath>

#include "fascicle/core/error.hpp"
#include "fascicle/skeleton/skeleton.hpp"

namespace fascicle {
namespace {

Transform translation(double x, double y, double z) {
  Transform X = Transform::Identity();
  X.translation() = Vec3(x, y, z);
  return X;
}
Mat3 rot(const Vec3& axis, double angle) { return Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix(); }

BodySpec body(const std::string& name) {
  BodySpec b;
  b.name = name;
  b.mass = 1.0;
  b.inertia = Mat3::Identity() * 0.01;
  return b;
}

CoordinateSpec coordinate(const std::string& name, MotionType type = MotionType::rotational) {
  CoordinateSpec c;
  c.name = name;
  c.motion_type = type;
  return c;
}

JointSpec joint(const std::string& name, JointType type, const std::string& parent,
                const std::string& child, std::vector<CoordinateSpec> coords) {
  JointSpec j;
  j.name = name;
  j.type = type;
  j.parent = parent;
  j.child = child;
  j.coordinates = std::move(coords);
  return j;
}

TEST(Skeleton, DoublePendulumTransformsMatchHandComputation) {
  const double L1 = 0.7, L2 = 0.45;
  SkeletonSpec spec;
  spec.bodies = {body("upper"), body("lower")};
  JointSpec j1 = joint("shoulder", JointType::pin, "ground", "upper", {coordinate("q1")});
  j1.X_child_M = translation(0, L1, 0);  // the hinge is L1 above the body origin
  JointSpec j2 = joint("elbow", JointType::pin, "upper", "lower", {coordinate("q2")});
  j2.X_child_M = translation(0, L2, 0);
  spec.joints = {j1, j2};
  const Skeleton sk = compile(spec);
  ASSERT_EQ(sk.num_bodies(), 3);
  ASSERT_EQ(sk.num_coordinates(), 2);
  SkeletonState st(sk);
  for (const auto& [q1, q2] : {std::pair{0.3, -1.1}, std::pair{-2.0, 0.4}, std::pair{1.0, 2.5}}) {
    calc_pose(sk, Eigen::Vector2d(q1, q2), st);
    const Vec3 p1 = rot(Vec3::UnitZ(), q1) * Vec3(0, -L1, 0);
    const Vec3 p2 = p1 + rot(Vec3::UnitZ(), q1 + q2) * Vec3(0, -L2, 0);
    EXPECT_LT((st.get_body_transform(1).translation() - p1).norm(), 1e-14);
    EXPECT_LT((st.get_body_transform(2).translation() - p2).norm(), 1e-14);
    EXPECT_LT((st.get_body_transform(2).linear() - rot(Vec3::UnitZ(), q1 + q2)).norm(), 1e-14);
    EXPECT_LT((calc_station_location(st, 2, Vec3(0, -L2, 0)) -
               (p2 + rot(Vec3::UnitZ(), q1 + q2) * Vec3(0, -L2, 0))).norm(), 1e-14);
  }
  EXPECT_EQ(sk.find_body("lower"), 2);
  EXPECT_EQ(sk.find_coordinate("q2"), 1);
  EXPECT_EQ(sk.get_parent_body(2), 1);
}

TEST(Skeleton, CustomJointEqualsPinJointAndBallIsBodyFixedXYZ) {
  const Vec3 axis = Vec3(0.3, -0.5, 0.8).normalized();
  Transform X_PF = translation(0.1, 0.2, -0.3);
  X_PF.linear() = rot(Vec3(1, 2, 3), 0.7);
  Transform X_BM = translation(-0.05, 0.4, 0.02);
  X_BM.linear() = rot(Vec3(-1, 0.5, 0.2), 0.3);
  // Pin about `axis`: a pin rotates about z of F, so rotate F to carry z onto the axis.
  JointSpec pin = joint("pin", JointType::pin, "ground", "a", {coordinate("qa")});
  pin.X_parent_F = X_PF;
  pin.X_parent_F.linear() = X_PF.linear() * Eigen::Quaterniond::FromTwoVectors(Vec3::UnitZ(), axis).toRotationMatrix();
  pin.X_child_M = X_BM;
  pin.X_child_M.linear() = X_BM.linear() * Eigen::Quaterniond::FromTwoVectors(Vec3::UnitZ(), axis).toRotationMatrix();
  JointSpec custom = joint("custom", JointType::custom, "ground", "b", {coordinate("qb")});
  custom.X_parent_F = X_PF;
  custom.X_child_M = X_BM;
  custom.spatial_transform.axes[0].coordinate = "qb";
  custom.spatial_transform.axes[0].axis = axis;
  custom.spatial_transform.axes[0].function = make_linear(1.0, 0.0);
  custom.spatial_transform.axes[1].axis = Vec3::UnitY();
  custom.spatial_transform.axes[2].axis = Vec3::UnitY();  // parallel: replaced (constant 0)
  JointSpec ball = joint("ball", JointType::ball, "ground", "c",
                         {coordinate("bx"), coordinate("by"), coordinate("bz")});
  JointSpec free = joint("free", JointType::free, "ground", "d",
                         {coordinate("fx"), coordinate("fy"), coordinate("fz"),
                          coordinate("tx", MotionType::translational),
                          coordinate("ty", MotionType::translational),
                          coordinate("tz", MotionType::translational)});
  free.X_parent_F = X_PF;
  SkeletonSpec spec;
  spec.bodies = {body("a"), body("b"), body("c"), body("d")};
  spec.joints = {pin, custom, ball, free};
  const Skeleton sk = compile(spec);
  SkeletonState st(sk);
  VecX q(sk.num_coordinates());
  q << 0.9, 0.9, 0.4, -0.7, 1.2, 0.3, 0.2, -0.6, 0.11, -0.22, 0.33;
  calc_pose(sk, q, st);
  EXPECT_LT((st.get_body_transform(1).matrix() - st.get_body_transform(2).matrix()).norm(), 1e-13);
  const Mat3 R_ball = rot(Vec3::UnitX(), 0.4) * rot(Vec3::UnitY(), -0.7) * rot(Vec3::UnitZ(), 1.2);
  EXPECT_LT((st.get_body_transform(3).linear() - R_ball).norm(), 1e-14);
  Transform X_FM = translation(0.11, -0.22, 0.33);
  X_FM.linear() = rot(Vec3::UnitX(), 0.3) * rot(Vec3::UnitY(), 0.2) * rot(Vec3::UnitZ(), -0.6);
  EXPECT_LT(((X_PF * X_FM).matrix() - st.get_body_transform(4).matrix()).norm(), 1e-14);
}

// A knee-like chain: thigh on a pin hip; shank on a custom knee whose translation follows splines of
// the knee angle; a patella on a custom joint driven by a dependent coordinate coupled to the knee.
SkeletonSpec knee_spec() {
  SkeletonSpec spec;
  spec.bodies = {body("thigh"), body("shank"), body("patella")};
  JointSpec hip = joint("hip", JointType::pin, "ground", "thigh", {coordinate("hip_flexion")});
  hip.X_parent_F = translation(0.0, 1.0, 0.1);
  JointSpec knee = joint("knee", JointType::custom, "thigh", "shank", {coordinate("knee_angle")});
  knee.X_parent_F = translation(0.0, -0.4, 0.0);
  auto& kt = knee.spatial_transform.axes;
  kt[0] = {"knee_angle", Vec3::UnitZ(), make_linear(1.0, 0.0)};
  kt[1].axis = Vec3::UnitX();
  kt[2].axis = Vec3::UnitY();
  kt[3] = {"knee_angle", Vec3::UnitX(),
           make_simm_spline({-2.09, -1.22, -0.52, -0.35, 0.0}, {-0.0032, 0.00179, 0.00411, 0.0041, 0.00212})};
  kt[4] = {"knee_angle", Vec3::UnitY(),
           make_simm_spline({-2.09, -1.22, -0.52, 0.0}, {-0.4226, -0.4082, -0.399, -0.3952})};
  kt[5].axis = Vec3::UnitZ();
  JointSpec pat = joint("patellofemoral", JointType::custom, "thigh", "patella",
                        {coordinate("patella_beta")});
  pat.X_parent_F = translation(0.05, -0.38, 0.0);
  auto& pt = pat.spatial_transform.axes;
  pt[0] = {"patella_beta", Vec3::UnitZ(), make_linear(1.0, 0.0)};
  pt[1].axis = Vec3::UnitX();
  pt[2].axis = Vec3::UnitY();
  pt[3] = {"patella_beta", Vec3::UnitX(), make_polynomial({0.01, 0.02, 0.0})};
  pt[4].axis = Vec3::UnitY();
  pt[5].axis = Vec3::UnitZ();
  spec.joints = {hip, knee, pat};
  CouplerSpec c;
  c.name = "patella_coupler";
  c.dependent = "patella_beta";
  c.independent = "knee_angle";
  c.function = make_simm_spline({-2.09, -1.5, -1.0, -0.5, 0.0}, {-1.2, -0.9, -0.55, -0.25, 0.0});
  spec.couplers = {c};
  return spec;
}

TEST(Skeleton, CouplerIsSatisfiedAfterAssembly) {
  const SkeletonSpec spec = knee_spec();
  const Skeleton sk = compile(spec);
  SkeletonState st(sk);
  const int knee = sk.find_coordinate("knee_angle");
  const int beta = sk.find_coordinate("patella_beta");
  EXPECT_EQ(sk.get_coordinate(beta).dependent_on, 0);
  for (double k : {-1.9, -1.0, -0.3, 0.0}) {
    VecX q = VecX::Zero(3);
    q[knee] = k;
    q[beta] = 123.0;  // ignored: the coupler decides it
    calc_pose(sk, q, st);
    EXPECT_NEAR(st.get_q()[beta], calc_value(spec.couplers[0].function, k), 1e-15);
    EXPECT_LT(calc_constraint_error(sk, st), 1e-14);  // Simbody's own coupler residual
    EXPECT_NEAR(st.get_coupling()(beta, knee), calc_slope(spec.couplers[0].function, k), 1e-15);
  }
}

TEST(Skeleton, GeneralizedForcesEqualFiniteDifferencesOfStations) {
  const Skeleton sk = compile(knee_spec());
  SkeletonState st(sk), probe(sk);
  const std::vector<PointForce> forces{{1, Vec3(0.02, -0.1, 0.01), Vec3(1.0, -2.0, 0.5)},
                                       {2, Vec3(0.01, 0.05, -0.02), Vec3(-0.3, 0.8, 1.1)},
                                       {3, Vec3(0.03, 0.01, 0.0), Vec3(0.7, 0.2, -0.4)}};
  VecX q(3);
  q << 0.4, -1.1, 0.0;
  calc_pose(sk, q, st);
  VecX uncoupled;
  const VecX tau = calc_generalized_forces(sk, st, forces, &uncoupled);
  const double h = 1e-6;
  for (int j : {0, 1}) {  // the independent coordinates
    VecX qp = q, qm = q;
    qp[j] += h;
    qm[j] -= h;
    double work = 0.0;
    for (const PointForce& f : forces) {
      calc_pose(sk, qp, probe);
      const Vec3 pp = calc_station_location(probe, f.body, f.p_body);
      calc_pose(sk, qm, probe);
      const Vec3 pm = calc_station_location(probe, f.body, f.p_body);
      work += f.f_ground.dot((pp - pm) / (2 * h));
    }
    EXPECT_NEAR(tau[j], work, 1e-8) << "coordinate " << j;
  }
  EXPECT_EQ(tau[2], 0.0);  // the dependent coordinate
  // The coupling changes the knee's entry: the patella force contributes through the coupler.
  EXPECT_GT(std::abs(tau[1] - uncoupled[1]), 1e-3);
}

TEST(Skeleton, StationVelocityEqualsDerivativeOfPosition) {
  const Skeleton sk = compile(knee_spec());
  SkeletonState st(sk), probe(sk);
  VecX q(3), qdot(3);
  q << 0.2, -0.8, 0.0;
  qdot << 1.3, -0.7, 0.0;
  calc_pose(sk, q, st);
  calc_velocity(sk, qdot, st);
  const Vec3 p(0.03, 0.01, 0.0);
  const double h = 1e-6;
  calc_pose(sk, q + h * qdot, probe);
  const Vec3 a = calc_station_location(probe, 3, p);
  calc_pose(sk, q - h * qdot, probe);
  const Vec3 b = calc_station_location(probe, 3, p);
  EXPECT_LT((calc_station_velocity(sk, st, 3, p) - (a - b) / (2 * h)).norm(), 1e-8);
}

TEST(Skeleton, LocksAndBadSpecs) {
  SkeletonSpec spec = knee_spec();
  spec.joints[0].coordinates[0].locked = true;
  spec.joints[0].coordinates[0].default_value = 0.25;
  const Skeleton sk = compile(spec);
  SkeletonState st(sk);
  calc_pose(sk, VecX::Zero(3), st);
  EXPECT_EQ(st.get_q()[0], 0.25);
  EXPECT_THROW(calc_pose(sk, VecX::Zero(2), st), Error);

  SkeletonSpec bad = knee_spec();
  bad.joints[1].parent = "femur";
  EXPECT_THROW(compile(bad), Error);
  bad = knee_spec();
  bad.couplers.push_back({"loop", "knee_angle", "patella_beta", make_linear(1.0, 0.0)});
  EXPECT_THROW(compile(bad), Error);
  bad = knee_spec();
  bad.joints[1].spatial_transform.axes[3].coordinate = "hip_flexion";
  try {
    compile(bad);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.context().object, "knee");
  }
}

}  // namespace
}  // namespace fascicle
