// Rigid-body skeletons: an editable SkeletonSpec (bodies, joints, coordinates, coordinate
// couplers), compiled once into an immutable Skeleton built on Simbody, and a per-frame
// SkeletonState holding the pose (body transforms) and the workspace.
//
// Conventions (docs/skeleton.md): SI units; angles in rad. X_A_B maps points given in frame B to
// frame A. Every joint connects a frame F fixed on the parent (X_parent_F) to a frame M fixed on the
// child (X_child_M); the joint's motion is the transform X_F_M(q). Every joint type is a Simbody
// MobilizedBody::FunctionBased (a Weld is a MobilizedBody::Weld), as OpenSim builds its CustomJoint,
// except the ellipsoid and scapulothoracic joints (MobilizedBody::Custom); in all of them
// generalized speeds equal coordinate derivatives (u = q̇) and generalized forces are conjugate to
// the coordinates: τ_i = Σ f·∂p/∂q_i.
//
// This header is C++17 and never includes Simbody (the module's implementation does).
#pragma once

#include <array>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "fascicle/core/types.hpp"
#include "fascicle/skeleton/functions.hpp"

namespace fascicle {

// ----------------------------------------------------------------------------------------------
// Spec: plain, editable data
// ----------------------------------------------------------------------------------------------

struct MeshReference {
  std::string file;                             // as given in the model (resolved by the importer)
  Vec3 scale = Vec3::Ones();                    // per-axis scale of the mesh vertices
  Transform X_body_mesh = Transform::Identity();  // pose of the mesh frame in the body frame
};

struct BodySpec {
  std::string name;
  double mass = 0.0;                 // kg
  Vec3 com = Vec3::Zero();           // m, centre of mass in the body frame
  Mat3 inertia = Mat3::Zero();       // kg·m², about the centre of mass, body-frame axes
  std::vector<MeshReference> meshes;
};

enum class MotionType { rotational, translational, coupled };

struct CoordinateSpec {
  std::string name;
  MotionType motion_type = MotionType::rotational;
  double default_value = 0.0;  // rad or m
  double range_min = -std::numeric_limits<double>::infinity();
  double range_max = std::numeric_limits<double>::infinity();
  bool locked = false;   // held at default_value by calc_pose
  bool clamped = false;  // calc_pose clamps to [range_min, range_max] when PoseOptions::clamp
};

// One axis of a CustomJoint's SpatialTransform: a rotation about (axes 0–2) or a translation along
// (axes 3–5) `axis`, given in F, by the amount function(q_coordinate). An empty coordinate means a
// constant amount function(0).
struct TransformAxisSpec {
  std::string coordinate;
  Vec3 axis = Vec3::UnitX();
  Function function = make_constant(0.0);
};

// OpenSim's SpatialTransform: X_F_M = [R1·R2·R3, t] where Ri rotates about axis i (axes 0–2,
// applied in order as successive body-fixed rotations) and t = Σ_{i=3..5} f_i·axis_i (in F).
struct SpatialTransformSpec {
  std::array<TransformAxisSpec, 6> axes;
};

enum class JointType {
  weld, pin, slider, universal, ball, free, custom,
  gimbal, planar, ellipsoid, scapulothoracic
};

// Coordinates per type, in this order:
//  weld: none; pin: rotation about z of F; slider: translation along x of F;
//  universal: rotations about x, then the new y; ball: body-fixed x, y, z rotations;
//  free: body-fixed x, y, z rotations then translations along x, y, z of F;
//  custom: as the spatial transform names them (each name listed once in `coordinates`);
//  gimbal: body-fixed x, y, z rotations (as ball); planar: rotation about z of F, then
//  translations along x and y of F;
//  ellipsoid: body-fixed x, y, z rotations R = Rx·Ry·Rz with M's origin at diag(radii)·(R·ẑ) on
//  the ellipsoid `ellipsoid_radii` centred at F's origin (Simbody's Ellipsoid mobilizer);
//  scapulothoracic: abduction, elevation, upward rotation (an ellipsoid joint on the thoracic
//  ellipsoid `ellipsoid_radii`, given along F's axes, turned 90° about F's z) and winging about
//  the axis of direction `winging_direction` through `winging_origin` (OpenSim's
//  ScapulothoracicJoint, Seth et al. 2016). docs/skeleton.md has the formulas.
// All joints use u = q̇ (generalized speeds are the coordinate derivatives).
struct JointSpec {
  std::string name;
  JointType type = JointType::weld;
  std::string parent;                          // parent body name ("ground" for the ground)
  std::string child;                           // child body name
  Transform X_parent_F = Transform::Identity();
  Transform X_child_M = Transform::Identity();
  std::vector<CoordinateSpec> coordinates;
  SpatialTransformSpec spatial_transform;      // custom joints only
  Vec3 ellipsoid_radii = Vec3::Zero();         // m; ellipsoid and scapulothoracic joints only
  Vec2 winging_origin = Vec2::Zero();          // m; scapulothoracic only (x, y of the joint frame)
  double winging_direction = 0.0;              // rad; scapulothoracic only
};

// q_dependent = function(q_independent): OpenSim's CoordinateCouplerConstraint with one
// independent coordinate.
struct CouplerSpec {
  std::string name;
  std::string dependent;
  std::string independent;
  Function function = make_linear(1.0, 0.0);
};

struct SkeletonSpec {
  std::string name;
  // Bodies other than the ground; a body named "ground" here only contributes its meshes.
  std::vector<BodySpec> bodies;
  std::vector<MeshReference> ground_meshes;
  std::vector<JointSpec> joints;  // a tree: every body is the child of exactly one joint
  std::vector<CouplerSpec> couplers;
  Vec3 gravity = Vec3(0.0, -9.80665, 0.0);  // m/s²
};

// ----------------------------------------------------------------------------------------------
// Compiled skeleton (immutable) and per-frame state
// ----------------------------------------------------------------------------------------------

struct CoordinateInfo {
  CoordinateSpec spec;
  int joint = -1;           // index into joints()
  int dependent_on = -1;    // for a coupled (dependent) coordinate: the coupler index, else -1
};

class Skeleton {
 public:
  ~Skeleton();
  Skeleton(Skeleton&&) noexcept;
  Skeleton& operator=(Skeleton&&) noexcept;
  Skeleton(const Skeleton&) = delete;
  Skeleton& operator=(const Skeleton&) = delete;

  const SkeletonSpec& get_spec() const;
  // Body 0 is the ground; bodies 1… follow spec.bodies in order.
  int num_bodies() const;
  const std::string& get_body_name(int body) const;
  const BodySpec& get_body(int body) const;  // the ground has mass 0 and spec.ground_meshes
  int find_body(const std::string& name) const;  // -1 if absent
  int num_coordinates() const;
  const CoordinateInfo& get_coordinate(int coordinate) const;
  int find_coordinate(const std::string& name) const;  // -1 if absent
  const std::vector<JointSpec>& get_joints() const;
  // The parent body index of a body (-1 for the ground).
  int get_parent_body(int body) const;
  // Default coordinate values (dependent ones already assembled).
  VecX get_default_q() const;

  struct Impl;
  const Impl& impl() const { return *impl_; }

 private:
  friend Skeleton compile(const SkeletonSpec& spec);
  explicit Skeleton(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Checks the spec (unique names, known bodies and coordinates, a tree rooted at the ground, finite
// numbers, supported function/axis setups, acyclic couplers) and builds the Simbody system. Throws
// a bad-input error naming the element.
Skeleton compile(const SkeletonSpec& spec);

enum class SkeletonStage { none, pose, velocity };

struct PoseOptions {
  bool apply_locks = true;   // locked coordinates take their default value
  bool clamp = false;        // clamped coordinates are clamped to their range
};


class SkeletonState {
 public:
  explicit SkeletonState(const Skeleton& skeleton);
  ~SkeletonState();
  SkeletonState(SkeletonState&&) noexcept;
  SkeletonState& operator=(SkeletonState&&) noexcept;
  SkeletonState(const SkeletonState&);
  SkeletonState& operator=(const SkeletonState&) = delete;

  SkeletonStage stage() const { return stage_; }
  // Coordinate values of the last pose (dependent coordinates assembled), #coordinates.
  const VecX& get_q() const { return q_; }
  const VecX& get_qdot() const { return qdot_; }
  // Requires stage() >= pose. X_ground_body for body b.
  const Transform& get_body_transform(int body) const;
  const std::vector<Transform>& get_body_transforms() const;
  // Requires stage() >= pose. C (#coordinates × #coordinates): column j is ∂q/∂q_j along the
  // constraint manifold (identity for independent coordinates, the coupler slopes in the rows of
  // dependent ones; columns of dependent coordinates are zero).
  const MatX& get_coupling() const { return coupling_; }

  struct Impl;
  Impl& impl() { return *impl_; }
  const Impl& impl() const { return *impl_; }

 private:
  friend void calc_pose(const Skeleton&, const VecX&, SkeletonState&, const PoseOptions&);
  friend void calc_velocity(const Skeleton&, const VecX&, SkeletonState&);
  std::unique_ptr<Impl> impl_;
  SkeletonStage stage_ = SkeletonStage::none;
  VecX q_, qdot_;
  std::vector<Transform> X_ground_body_;
  MatX coupling_;
};

// Poses the skeleton: takes q (#coordinates; values of dependent coordinates are ignored), applies
// locks/clamps, assembles the couplers (dependent = f(independent), in dependency order) and
// computes every X_ground_body. Throws a bad-input error for a wrong size or a non-finite value.
void calc_pose(const Skeleton& skeleton, const VecX& q, SkeletonState& state,
               const PoseOptions& options = PoseOptions());

// Sets coordinate speeds (#coordinates; dependent ones follow the couplers) on a posed state.
void calc_velocity(const Skeleton& skeleton, const VecX& qdot, SkeletonState& state);

// Requires stage() >= pose. Position of station p_body (m, body frame) in ground.
Vec3 calc_station_location(const SkeletonState& state, int body, const Vec3& p_body);

// Requires stage() >= velocity. Velocity (m/s, in ground) of a station fixed on a body.
Vec3 calc_station_velocity(const Skeleton& skeleton, const SkeletonState& state, int body,
                           const Vec3& p_body);

// Requires stage() >= velocity. The acceleration (m/s², in ground) of a station fixed on a body
// when every q̈ is zero: J̇·q̇, the velocity-product ("bias") term of the station's acceleration
// (Simbody's calcBiasForStationJacobian; coupler constraints are not applied here).
Vec3 calc_station_bias_acceleration(const Skeleton& skeleton, const SkeletonState& state, int body,
                                    const Vec3& p_body);

// A force f_ground (N, ground axes) applied at station p_body of a body.
struct PointForce {
  int body = 0;
  Vec3 p_body = Vec3::Zero();
  Vec3 f_ground = Vec3::Zero();
};

// Requires stage() >= pose. Generalized forces of point forces on the coordinates, with the
// constraint coupling: τ = Cᵀ·Jᵀ·f, i.e. τ_j = Σ_k f_k·dp_k/dq_j along the constraint manifold
// (Simbody's system Jacobian transpose; the same construction as OpenSim's MomentArmSolver). For a
// path of unit tension whose points pull towards their path neighbours, τ_j is the moment arm
// −dL/dq_j. Entries of dependent coordinates are zero. Also returns the uncoupled Jᵀ·f in
// `uncoupled` when it is not null.
VecX calc_generalized_forces(const Skeleton& skeleton, const SkeletonState& state,
                             const std::vector<PointForce>& forces, VecX* uncoupled = nullptr);

// Requires stage() >= pose. Velocity Jacobians of every body (#bodies, the ground included) along
// the constraint manifold: J[b] is 6×#coordinates; rows 0–2 are the angular velocity of body b,
// rows 3–5 the velocity of the point of body b that is at the ground origin, both in ground, per
// unit speed of coordinate j. Column j already carries the coupling (J_uncoupled·C): a dependent
// coordinate moves with its independent one, and the columns of dependent coordinates are zero.
// The body point at the ground origin makes the velocity of any station p (in ground) of body b
// v = J[b].bottomRows(3)·q̇ + (J[b].topRows(3)·q̇) × p.
void calc_body_jacobians(const Skeleton& skeleton, const SkeletonState& state,
                         std::vector<Eigen::Matrix<double, 6, Eigen::Dynamic>>& J);

// Requires stage() >= pose. The largest absolute position-constraint error of the Simbody system
// (coupler residuals) — zero after calc_pose up to rounding.
double calc_constraint_error(const Skeleton& skeleton, const SkeletonState& state);

}  // namespace fascicle
