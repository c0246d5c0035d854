// Compiled muscle paths (immutable, shared across threads) and their per-frame evaluation:
// active points, wrapping (OpenSim's GeometryPath semantics), length, and exact moment arms by the
// generalized-force method. The skeleton supplies body transforms X_ground_body, coordinate
// values q and, for moment arms, body velocity Jacobians; this module never calls the skeleton,
// so it is testable with hand-made kinematics. See docs/paths.md.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "fascicle/core/types.hpp"
#include "fascicle/path/path_spec.hpp"
#include "fascicle/path/wrap_geometry.hpp"

namespace fascicle {

// Body and coordinate names, in the order of the skeleton's body and coordinate indices.
struct PathNames {
  std::vector<std::string> bodies;
  std::vector<std::string> coordinates;
};

struct CompiledPathPoint {
  int32_t body = -1;
  PathPointKind kind = PathPointKind::fixed;
  Vec3 p_body = Vec3::Zero();
  int32_t coordinate = -1;  // conditional points
  double range_min = 0, range_max = 0;
  std::array<int32_t, 3> location_coordinate{-1, -1, -1};  // moving points (-1: constant)
  std::array<CoordinateFunction, 3> location;
};

struct CompiledWrapObject {
  WrapObjectSpec spec;
  int32_t body = -1;
};

struct CompiledPathWrap {
  int32_t object = -1;
  int32_t first_point = 0, last_point = 0;  // 0-based, inclusive, into the path's points
};

struct CompiledPath {
  std::string name;
  std::vector<CompiledPathPoint> points;
  std::vector<CompiledPathWrap> wraps;
  ActionLine action_line = ActionLine::obstacle_set;
};

struct PathSetModel {
  std::vector<CompiledWrapObject> wrap_objects;
  std::vector<CompiledPath> paths;
  PathOptions options;
  int num_bodies = 0;
  int num_coordinates = 0;
};

// Resolves names and checks the spec. Throws a bad-input error naming the path, point or wrap
// object (fewer than two points, unknown body/coordinate/wrap object, non-positive or NaN
// dimensions, empty conditional range, moving point without functions).
PathSetModel compile_paths(const PathSetSpec& spec, const PathNames& names);

// One vertex of the evaluated path: an active path point, or a tangent point of a wrap.
struct PathVertex {
  Vec3 p_ground = Vec3::Zero();
  int32_t body = -1;   // body the vertex moves with (the wrap object's body for tangent points)
  int32_t point = -1;  // index of the path point, or -1 for a tangent point
  int32_t wrap = -1;   // index of the path wrap for tangent points, -1 otherwise
  int8_t tangent = 0;  // 1 for the first tangent point of a wrap, 2 for the second
};

// A wrap in effect this frame.
struct PathWrapState {
  bool wrapping = false;
  WrapStatus status = WrapStatus::no_wrap;  // status of the last segment tried
  WrapResult result;                        // tangent points, arc: frame of the wrap object
  Transform X_ground_wrap = Transform::Identity();
  // PathOptions::opensim_tangent_point_cache: ground positions of the tangent points (1, 2) when
  // a length sum first read them in this pose.
  std::array<Vec3, 2> first_use_ground{Vec3::Zero(), Vec3::Zero()};
  std::array<bool, 2> first_use_set{false, false};
};

// Position-level result of one path (every number NaN until computed).
struct PathResult {
  double length_m = kPathNaN;
  std::vector<PathVertex> vertices;  // origin ... insertion, with tangent-point pairs
  std::vector<PathWrapState> wraps;  // one per path wrap
  int iterations = 0;                // wrap passes done
};

// Computes the path's vertices and length for body transforms X_ground_body (#bodies) and
// coordinate values q (#coordinates). Reuses out's memory.
void calc_path(const PathSetModel& model, int path, const std::vector<Transform>& X_ground_body,
               const VecX& q, PathResult& out);

// Path length of already computed vertices (arcs for tangent pairs, straight lines otherwise).
double calc_path_length(const PathResult& result);

// The polyline of the path with each wrap arc sampled at about `arc_step_m` (for drawing), #P×3.
Points3 calc_path_polyline(const PathResult& result, double arc_step_m = 0.002);

// Velocity Jacobians of the bodies with respect to the generalized speeds u (#u):
// J[b] is 6×#u, rows 0-2 the angular velocity of body b, rows 3-5 the velocity of the point of
// body b at the ground origin, both in ground, per unit u_k. dq_du (#coordinates × #u) maps speeds
// to coordinate rates, coupled (dependent) coordinates included: the skeleton fills both with
// constraint coupling resolved.
struct BodyJacobians {
  std::vector<Eigen::Matrix<double, 6, Eigen::Dynamic>> J;
  MatX dq_du;
};

// A force on a body at a point, both in ground.
struct PathPointForce {
  int32_t body = -1;
  Vec3 p_ground = Vec3::Zero();
  Vec3 f_ground = Vec3::Zero();
};

// The forces of a unit tension in the path on the bodies (path points pulled along the path, wrap
// objects pushed by the wrapped segment), and the explicit derivative of the length with respect to
// each coordinate through MovingPathPoints' location functions (#coordinates). The generalized
// forces of these forces minus dq_duᵀ·dL_dq_explicit are the moment arms.
struct PathUnitForces {
  std::vector<PathPointForce> forces;
  VecX dL_dq_explicit;
};
void calc_path_unit_forces(const PathSetModel& model, int path, const PathResult& result,
                           const std::vector<Transform>& X_ground_body, const VecX& q,
                           PathUnitForces& out);

// Moment arms r = -∂L/∂u (#u), exact by the generalized-force method (seed 001 §2.5; OpenSim's
// MomentArmSolver): r_k = Σ_forces (ω_kᵀ (p × f) + v_kᵀ f) - Σ_c dq_du(c,k) ∂L/∂q_c|explicit.
VecX calc_moment_arms(const PathSetModel& model, int path, const PathResult& result,
                      const std::vector<Transform>& X_ground_body, const VecX& q,
                      const BodyJacobians& jacobians);

// Lengthening speed dL/dt = -r·u (m/s) for generalized speeds u.
inline double calc_lengthening_speed(const VecX& moment_arms, const VecX& u) {
  return -moment_arms.dot(u);
}

}  // namespace fascicle
