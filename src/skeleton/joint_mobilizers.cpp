// Ellipsoid and scapulothoracic joints as Simbody MobilizedBody::Custom mobilizers.
//
// Both move the joint frame M over an ellipsoid fixed in F with Simbody's Ellipsoid-mobilizer
// kinematics (Simbody 3.x, MobilizedBody::Ellipsoid): with body-fixed x-y-z Euler angles q0..q2,
//   R_FM = Rx(q0)·Ry(q1)·Rz(q2),   p_FM = diag(a, b, c)·n,   n = R_FM·ẑ = Rx(q0)·Ry(q1)·ẑ,
// so M's origin lies on the ellipsoid x²/a² + y²/b² + z²/c² = 1 (|n| = 1) and Mz is the direction n.
// The scapulothoracic joint (Seth, Matias, Veloso & Delp 2016, PLoS ONE 11(1):e0141028) is that
// mobilizer on the thoracic ellipsoid, turned by +90° about z of the parent joint frame so that
// positive abduction/elevation move the scapula laterally/upwards (the radii are given along the
// thorax frame axes, hence a = r_y, b = r_x, c = r_z in the turned frame), followed by the winging
// rotation q3 about the axis d = (−sin w, cos w, 0) through (o_x, o_y, 0) of the intermediate frame:
//   X_FM = Z(+90°) · E(q0, q1, q2) · Z(−90°) · Wing(q3).
//
// Unlike Simbody's own Ellipsoid mobilizer (u = angular velocity), these mobilizers use u = q̇, as
// every other fascicle joint, so that generalized forces are conjugate to the coordinates and the
// generalized-force moment arm is −∂L/∂q. H, Ḣ and their transposes are exact: the transform is
// evaluated in hyper-dual numbers (value, two first-order directions and their mixed second
// derivative), which differentiates the closed form without truncation error.
#include "joint_mobilizers.hpp"

#include <array>
#include <cmath>

namespace fascicle::detail {
namespace {

// Hyper-dual number a + b·ε1 + c·ε2 + d·ε1ε2 with ε1² = ε2² = 0.
struct HD {
  double a = 0.0, b = 0.0, c = 0.0, d = 0.0;
};
inline HD operator+(const HD& x, const HD& y) { return {x.a + y.a, x.b + y.b, x.c + y.c, x.d + y.d}; }
inline HD operator-(const HD& x, const HD& y) { return {x.a - y.a, x.b - y.b, x.c - y.c, x.d - y.d}; }
inline HD operator-(const HD& x) { return {-x.a, -x.b, -x.c, -x.d}; }
inline HD operator*(const HD& x, const HD& y) {
  return {x.a * y.a, x.a * y.b + x.b * y.a, x.a * y.c + x.c * y.a,
          x.a * y.d + x.b * y.c + x.c * y.b + x.d * y.a};
}
inline HD operator*(double s, const HD& x) { return {s * x.a, s * x.b, s * x.c, s * x.d}; }
inline HD operator*(const HD& x, double s) { return s * x; }
inline HD operator-(double s, const HD& x) { return {s - x.a, -x.b, -x.c, -x.d}; }
inline HD sin(const HD& x) {
  const double s = std::sin(x.a), c = std::cos(x.a);
  return {s, c * x.b, c * x.c, c * x.d - s * x.b * x.c};
}
inline HD cos(const HD& x) {
  const double s = std::sin(x.a), c = std::cos(x.a);
  return {c, -s * x.b, -s * x.c, -s * x.d - c * x.b * x.c};
}
using std::cos;
using std::sin;

template <class T>
struct Xf {
  T R[3][3];
  T p[3];
};

template <class T>
T make(double v);
template <>
double make<double>(double v) {
  return v;
}
template <>
HD make<HD>(double v) {
  return HD{v, 0.0, 0.0, 0.0};
}

template <class T>
Xf<T> constant(const Mat3& R, const Vec3& p) {
  Xf<T> X;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) X.R[i][j] = make<T>(R(i, j));
    X.p[i] = make<T>(p[i]);
  }
  return X;
}

template <class T>
Xf<T> compose(const Xf<T>& A, const Xf<T>& B) {
  Xf<T> X;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) X.R[i][j] = A.R[i][0] * B.R[0][j] + A.R[i][1] * B.R[1][j] + A.R[i][2] * B.R[2][j];
    X.p[i] = A.p[i] + (A.R[i][0] * B.p[0] + A.R[i][1] * B.p[1] + A.R[i][2] * B.p[2]);
  }
  return X;
}

// Rotation by `angle` about the unit axis a (Rodrigues), with no translation.
template <class T>
Xf<T> axis_rotation(const Vec3& a, const T& angle) {
  const T c = cos(angle), s = sin(angle);
  const T one_c = make<T>(1.0) - c;
  Xf<T> X;
  const double K[3][3] = {{0, -a.z(), a.y()}, {a.z(), 0, -a.x()}, {-a.y(), a.x(), 0}};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j)
      X.R[i][j] = a[i] * a[j] * one_c + K[i][j] * s + (i == j ? c : make<T>(0.0));
    X.p[i] = make<T>(0.0);
  }
  return X;
}

// Simbody's ellipsoid-mobilizer transform E(q0, q1, q2) for semi-axes r.
template <class T>
Xf<T> ellipsoid_transform(const Vec3& r, const T* q) {
  Xf<T> X = compose(compose(axis_rotation<T>(Vec3::UnitX(), q[0]), axis_rotation<T>(Vec3::UnitY(), q[1])),
                    axis_rotation<T>(Vec3::UnitZ(), q[2]));
  for (int i = 0; i < 3; ++i) X.p[i] = r[i] * X.R[i][2];  // Rz leaves the third column alone
  return X;
}

struct EllipsoidModel {
  bool scapulothoracic = false;
  Vec3 radii = Vec3::Ones();  // semi-axes of the mobilizer's own ellipsoid
  Vec3 wing_axis = Vec3::UnitY();
  Vec3 wing_origin = Vec3::Zero();
  int nq = 3;
};

EllipsoidModel make_model(const JointSpec& j) {
  EllipsoidModel m;
  m.scapulothoracic = j.type == JointType::scapulothoracic;
  if (m.scapulothoracic) {
    m.radii = Vec3(j.ellipsoid_radii.y(), j.ellipsoid_radii.x(), j.ellipsoid_radii.z());
    m.wing_axis = Vec3(-std::sin(j.winging_direction), std::cos(j.winging_direction), 0.0);
    m.wing_origin = Vec3(j.winging_origin.x(), j.winging_origin.y(), 0.0);
    m.nq = 4;
  } else {
    m.radii = j.ellipsoid_radii;
  }
  return m;
}

template <class T>
Xf<T> joint_transform(const EllipsoidModel& m, const T* q) {
  if (!m.scapulothoracic) return ellipsoid_transform(m.radii, q);
  const Mat3 Rz = Eigen::AngleAxisd(0.5 * M_PI, Vec3::UnitZ()).toRotationMatrix();
  Xf<T> wing = axis_rotation<T>(m.wing_axis, q[3]);
  for (int i = 0; i < 3; ++i)  // rotation about the axis through o: p = o − R·o
    wing.p[i] = m.wing_origin[i] -
                (wing.R[i][0] * m.wing_origin[0] + wing.R[i][1] * m.wing_origin[1] + wing.R[i][2] * m.wing_origin[2]);
  return compose(compose(compose(constant<T>(Rz, Vec3::Zero()), ellipsoid_transform(m.radii, q)),
                         constant<T>(Rz.transpose(), Vec3::Zero())),
                 wing);
}

// Spatial velocity (ω, v) from the ε1 parts, and its derivative along ε2, of a hyper-dual transform:
// ω = vee(Ṙ·Rᵀ), v = ṗ; d/dt ω = vee(R̈·Rᵀ + Ṙ·Ṙ₂ᵀ), d/dt v = p̈.
SimTK::SpatialVec velocity_part(const Xf<HD>& X) {
  double S[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) S[i][j] = X.R[i][0].b * X.R[j][0].a + X.R[i][1].b * X.R[j][1].a + X.R[i][2].b * X.R[j][2].a;
  const SimTK::Vec3 w(0.5 * (S[2][1] - S[1][2]), 0.5 * (S[0][2] - S[2][0]), 0.5 * (S[1][0] - S[0][1]));
  return SimTK::SpatialVec(w, SimTK::Vec3(X.p[0].b, X.p[1].b, X.p[2].b));
}
SimTK::SpatialVec velocity_derivative_part(const Xf<HD>& X) {
  double S[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      S[i][j] = 0.0;
      for (int k = 0; k < 3; ++k) S[i][j] += X.R[i][k].d * X.R[j][k].a + X.R[i][k].b * X.R[j][k].c;
    }
  const SimTK::Vec3 w(0.5 * (S[2][1] - S[1][2]), 0.5 * (S[0][2] - S[2][0]), 0.5 * (S[1][0] - S[0][1]));
  return SimTK::SpatialVec(w, SimTK::Vec3(X.p[0].d, X.p[1].d, X.p[2].d));
}

class EllipsoidMobilizer : public SimTK::MobilizedBody::Custom::Implementation {
 public:
  EllipsoidMobilizer(SimTK::SimbodyMatterSubsystem& matter, const EllipsoidModel& model)
      : Implementation(matter, model.nq, model.nq, 0), model_(model) {}
  Implementation* clone() const override { return new EllipsoidMobilizer(*this); }

  SimTK::Transform calcMobilizerTransformFromQ(const SimTK::State&, int nq, const SimTK::Real* q) const override {
    const Xf<double> X = joint_transform(model_, q);
    SimTK::Mat33 R;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) R(i, j) = X.R[i][j];
    (void)nq;
    return SimTK::Transform(SimTK::Rotation(R, true), SimTK::Vec3(X.p[0], X.p[1], X.p[2]));
  }

  SimTK::SpatialVec multiplyByHMatrix(const SimTK::State& s, int /*nu*/, const SimTK::Real* u) const override {
    return velocity_part(eval(getQ(s), u, nullptr));
  }
  void multiplyByHTranspose(const SimTK::State& s, const SimTK::SpatialVec& F, int nu,
                            SimTK::Real* f) const override {
    const SimTK::Vector q = getQ(s);
    for (int i = 0; i < nu; ++i) {
      const SimTK::SpatialVec H = velocity_part(eval(q, unit(i).data(), nullptr));
      f[i] = ~F[0] * H[0] + ~F[1] * H[1];
    }
  }
  SimTK::SpatialVec multiplyByHDotMatrix(const SimTK::State& s, int /*nu*/, const SimTK::Real* u) const override {
    const SimTK::Vector qdot = getU(s);  // u = q̇
    return velocity_derivative_part(eval(getQ(s), u, &qdot[0]));
  }
  void multiplyByHDotTranspose(const SimTK::State& s, const SimTK::SpatialVec& F, int nu,
                               SimTK::Real* f) const override {
    const SimTK::Vector q = getQ(s);
    const SimTK::Vector qdot = getU(s);
    for (int i = 0; i < nu; ++i) {
      const SimTK::SpatialVec H = velocity_derivative_part(eval(q, unit(i).data(), &qdot[0]));
      f[i] = ~F[0] * H[0] + ~F[1] * H[1];
    }
  }

 private:
  std::array<double, 4> unit(int i) const {
    std::array<double, 4> e{0.0, 0.0, 0.0, 0.0};
    e[i] = 1.0;
    return e;
  }
  // The transform with q̇ directions d1 (ε1) and d2 (ε2, optional).
  Xf<HD> eval(const SimTK::Vector& q, const double* d1, const double* d2) const {
    HD x[4];
    for (int i = 0; i < model_.nq; ++i) x[i] = HD{q[i], d1[i], d2 ? d2[i] : 0.0, 0.0};
    return joint_transform(model_, x);
  }
  EllipsoidModel model_;
};

}  // namespace

Transform calc_ellipsoid_joint_transform(const JointSpec& joint, const double* q) {
  const Xf<double> X = joint_transform(make_model(joint), q);
  Transform out = Transform::Identity();
  Mat3 R;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) R(i, j) = X.R[i][j];
  out.linear() = R;
  out.translation() = Vec3(X.p[0], X.p[1], X.p[2]);
  return out;
}

SimTK::MobilizedBodyIndex add_ellipsoid_mobilizer(SimTK::SimbodyMatterSubsystem& matter,
                                                  SimTK::MobilizedBody& parent,
                                                  const SimTK::Transform& X_PF,
                                                  const SimTK::Body& body,
                                                  const SimTK::Transform& X_BM,
                                                  const JointSpec& joint) {
  SimTK::MobilizedBody::Custom mb(parent, new EllipsoidMobilizer(matter, make_model(joint)), X_PF,
                                  body, X_BM);
  return mb.getMobilizedBodyIndex();
}

}  // namespace fascicle::detail
