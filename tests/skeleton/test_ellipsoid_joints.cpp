// Ellipsoid, scapulothoracic, gimbal and planar joints: body transforms against an independent
// evaluation of the formulas (Eigen angle-axis products), the surface constraint of the ellipsoid,
// body Jacobians, station velocities and bias accelerations (Ḣ) against central differences, and
// generalized forces (u = q̇) against finite differences of the work of a point force.
#include <gtest/gtest.h>

#include <cmath>

#include "fascicle/core/error.hpp"
#include "fascicle/skeleton/skeleton.hpp"

namespace fascicle {
namespace {

Mat3 rot(const Vec3& axis, double angle) {
  return Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
}
Transform make_X(const Mat3& R, const Vec3& p) {
  Transform X = Transform::Identity();
  X.linear() = R;
  X.translation() = p;
  return X;
}

BodySpec body(const std::string& name) {
  BodySpec b;
  b.name = name;
  b.mass = 0.5;
  b.com = Vec3(0.01, -0.02, 0.03);
  b.inertia = Mat3::Identity() * 0.002;
  return b;
}

CoordinateSpec coordinate(const std::string& name, MotionType t = MotionType::rotational) {
  CoordinateSpec c;
  c.name = name;
  c.motion_type = t;
  return c;
}

// Thorax (pinned to the ground so the parent moves too) → scapula by the joint under test.
SkeletonSpec make_spec(JointType type) {
  SkeletonSpec spec;
  spec.bodies = {body("thorax"), body("scapula")};
  JointSpec root;
  root.name = "root";
  root.type = JointType::pin;
  root.parent = "ground";
  root.child = "thorax";
  root.X_parent_F = make_X(rot(Vec3(1, 0.3, 0), 0.4), Vec3(0.1, 1.0, -0.2));
  root.coordinates = {coordinate("tilt")};
  JointSpec j;
  j.name = "st";
  j.type = type;
  j.parent = "thorax";
  j.child = "scapula";
  j.X_parent_F = make_X(rot(Vec3(0, 1, 0), -0.87), Vec3(-0.0294, -0.0173, 0.0703));
  j.X_child_M = make_X(rot(Vec3(-0.5, -1.1, -0.3), 1.3), Vec3(-0.0598, -0.039, -0.056));
  if (type == JointType::ellipsoid) {
    j.ellipsoid_radii = Vec3(0.09, 0.27, 0.08);
    j.coordinates = {coordinate("rx"), coordinate("ry"), coordinate("rz")};
  } else if (type == JointType::scapulothoracic) {
    j.ellipsoid_radii = Vec3(0.083, 0.2, 0.0831);
    j.winging_origin = Vec2(0.012, -0.007);
    j.winging_direction = 0.35;
    j.coordinates = {coordinate("abduction"), coordinate("elevation"), coordinate("upward_rot"),
                     coordinate("winging")};
  } else if (type == JointType::gimbal) {
    j.coordinates = {coordinate("g1"), coordinate("g2"), coordinate("g3")};
  } else if (type == JointType::planar) {
    j.coordinates = {coordinate("theta"), coordinate("tx", MotionType::translational),
                     coordinate("ty", MotionType::translational)};
  }
  spec.joints = {root, j};
  return spec;
}

// Simbody's ellipsoid mobilizer (written independently of the implementation): Euler x-y-z.
Transform ellipsoid_X_FM(const Vec3& r, double q0, double q1, double q2) {
  const Mat3 R = rot(Vec3::UnitX(), q0) * rot(Vec3::UnitY(), q1) * rot(Vec3::UnitZ(), q2);
  const Vec3 n = R.col(2);
  return make_X(R, r.cwiseProduct(n));
}

Transform expected_X_FM(const JointSpec& j, const VecX& q) {
  switch (j.type) {
    case JointType::ellipsoid: return ellipsoid_X_FM(j.ellipsoid_radii, q[0], q[1], q[2]);
    case JointType::scapulothoracic: {
      const Vec3 r(j.ellipsoid_radii.y(), j.ellipsoid_radii.x(), j.ellipsoid_radii.z());
      const Transform turn = make_X(rot(Vec3::UnitZ(), M_PI / 2), Vec3::Zero());
      const Vec3 d(-std::sin(j.winging_direction), std::cos(j.winging_direction), 0.0);
      const Vec3 o(j.winging_origin.x(), j.winging_origin.y(), 0.0);
      const Transform wing = make_X(Mat3::Identity(), o) * make_X(rot(d, q[3]), Vec3::Zero()) *
                             make_X(Mat3::Identity(), -o);
      return turn * ellipsoid_X_FM(r, q[0], q[1], q[2]) * turn.inverse() * wing;
    }
    case JointType::gimbal:
      return make_X(rot(Vec3::UnitX(), q[0]) * rot(Vec3::UnitY(), q[1]) * rot(Vec3::UnitZ(), q[2]),
                    Vec3::Zero());
    case JointType::planar: return make_X(rot(Vec3::UnitZ(), q[0]), Vec3(q[1], q[2], 0.0));
    default: return Transform::Identity();
  }
}

class EllipsoidJoints : public ::testing::TestWithParam<JointType> {};

TEST_P(EllipsoidJoints, BodyTransformMatchesIndependentFormula) {
  const SkeletonSpec spec = make_spec(GetParam());
  const Skeleton sk = compile(spec);
  SkeletonState state(sk);
  const JointSpec& root = spec.joints[0];
  const JointSpec& j = spec.joints[1];
  const int n = static_cast<int>(j.coordinates.size());
  for (int trial = 0; trial < 5; ++trial) {
    VecX q(1 + n);
    for (int i = 0; i < q.size(); ++i) q[i] = 0.3 * std::sin(1.7 * trial + 2.3 * i + 0.4) + 0.05 * i;
    calc_pose(sk, q, state);
    const Transform X_G_thorax = root.X_parent_F * make_X(rot(Vec3::UnitZ(), q[0]), Vec3::Zero());
    const Transform expected = X_G_thorax * j.X_parent_F * expected_X_FM(j, q.tail(n)) *
                               j.X_child_M.inverse();
    const Transform& got = state.get_body_transform(sk.find_body("scapula"));
    EXPECT_LT((got.matrix() - expected.matrix()).cwiseAbs().maxCoeff(), 1e-13) << "trial " << trial;
    if (j.type == JointType::ellipsoid || j.type == JointType::scapulothoracic) {
      // Before winging, the joint origin lies on the ellipsoid with the given radii along F's
      // axes (for the scapulothoracic joint: the thoracic ellipsoid in thorax-frame axes).
      VecX q0 = q.tail(n);
      if (n == 4) q0[3] = 0.0;
      const Vec3 p = expected_X_FM(j, q0).translation();
      const Vec3 pf = (X_G_thorax * j.X_parent_F).inverse() *
                      (X_G_thorax * j.X_parent_F * expected_X_FM(j, q0)).translation();
      EXPECT_NEAR(p.cwiseQuotient(j.ellipsoid_radii).squaredNorm(), 1.0, 1e-12);
      EXPECT_NEAR(pf.cwiseQuotient(j.ellipsoid_radii).squaredNorm(), 1.0, 1e-12);
    }
  }
}

TEST_P(EllipsoidJoints, JacobiansVelocitiesAndGeneralizedForcesMatchFiniteDifferences) {
  const SkeletonSpec spec = make_spec(GetParam());
  const Skeleton sk = compile(spec);
  SkeletonState state(sk);
  const int nc = sk.num_coordinates();
  const int scap = sk.find_body("scapula");
  const Vec3 station(0.03, -0.05, 0.02);
  VecX q(nc), qdot(nc);
  for (int i = 0; i < nc; ++i) {
    q[i] = 0.4 * std::cos(0.9 * i + 0.2) - 0.1;
    qdot[i] = 0.7 * std::sin(1.3 * i + 0.5) + 0.2;
  }
  calc_pose(sk, q, state);
  std::vector<Eigen::Matrix<double, 6, Eigen::Dynamic>> J;
  calc_body_jacobians(sk, state, J);
  const Vec3 p = calc_station_location(state, scap, station);
  const Vec3 f(1.3, -0.4, 2.2);
  const VecX tau = calc_generalized_forces(sk, state, {PointForce{scap, station, f}});
  SkeletonState probe(sk);
  const double h = 1e-6;
  Vec3 v_fd = Vec3::Zero();
  for (int c = 0; c < nc; ++c) {
    VecX qp = q, qm = q;
    qp[c] += h;
    qm[c] -= h;
    calc_pose(sk, qp, probe);
    const Vec3 pp = calc_station_location(probe, scap, station);
    const Mat3 Rp = probe.get_body_transform(scap).linear();
    calc_pose(sk, qm, probe);
    const Vec3 pm = calc_station_location(probe, scap, station);
    const Mat3 Rm = probe.get_body_transform(scap).linear();
    const Vec3 dp = (pp - pm) / (2 * h);
    const Vec3 v_J = J[scap].col(c).tail<3>() + J[scap].col(c).head<3>().cross(p);
    EXPECT_LT((v_J - dp).norm(), 1e-8) << "coordinate " << c;
    // Angular velocity: vee((Rp − Rm)/(2h) · Rᵀ).
    const Mat3 W = (Rp - Rm) / (2 * h) * state.get_body_transform(scap).linear().transpose();
    const Vec3 w(W(2, 1), W(0, 2), W(1, 0));
    EXPECT_LT((J[scap].col(c).head<3>() - w).norm(), 1e-8) << "coordinate " << c;
    EXPECT_NEAR(tau[c], f.dot(dp), 1e-8) << "coordinate " << c;  // u = q̇: τ = f·∂p/∂q
    v_fd += dp * qdot[c];
  }
  calc_velocity(sk, qdot, state);
  EXPECT_LT((calc_station_velocity(sk, state, scap, station) - v_fd).norm(), 1e-8);
}

// Ḣ (the mobilizers' multiplyByHDot*): the station bias acceleration J̇·q̇ equals the central
// difference of the station velocity J(q)·q̇ along q̇.
TEST_P(EllipsoidJoints, BiasAccelerationMatchesFiniteDifferenceOfVelocity) {
  const SkeletonSpec spec = make_spec(GetParam());
  const Skeleton sk = compile(spec);
  const int nc = sk.num_coordinates();
  const int scap = sk.find_body("scapula");
  const Vec3 station(0.02, -0.01, 0.04);
  VecX q(nc), qdot(nc);
  for (int i = 0; i < nc; ++i) {
    q[i] = 0.3 + 0.2 * i;
    qdot[i] = 0.7 - 0.4 * i;
  }
  SkeletonState state(sk), plus(sk), minus(sk);
  calc_pose(sk, q, state);
  calc_velocity(sk, qdot, state);
  const double h = 1e-6;
  calc_pose(sk, q + h * qdot, plus);
  calc_velocity(sk, qdot, plus);
  calc_pose(sk, q - h * qdot, minus);
  calc_velocity(sk, qdot, minus);
  const Vec3 fd = (calc_station_velocity(sk, plus, scap, station) -
                   calc_station_velocity(sk, minus, scap, station)) / (2 * h);
  const Vec3 bias = calc_station_bias_acceleration(sk, state, scap, station);
  EXPECT_GT(bias.norm(), 1e-3);
  EXPECT_LT((bias - fd).norm(), 1e-7);
}

INSTANTIATE_TEST_SUITE_P(Joints, EllipsoidJoints,
                         ::testing::Values(JointType::ellipsoid, JointType::scapulothoracic,
                                           JointType::gimbal, JointType::planar));

TEST(EllipsoidJoints, RejectsBadRadiiAndCoordinateCounts) {
  SkeletonSpec spec = make_spec(JointType::ellipsoid);
  spec.joints[1].ellipsoid_radii = Vec3(0.1, 0.0, 0.1);
  EXPECT_THROW(compile(spec), Error);
  spec = make_spec(JointType::scapulothoracic);
  spec.joints[1].coordinates.pop_back();
  EXPECT_THROW(compile(spec), Error);
}

}  // namespace
}  // namespace fascicle
