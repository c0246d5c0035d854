// Editable description of muscle paths: path points (fixed, conditional, moving), wrap objects
// (cylinder, sphere, ellipsoid, torus) and the wraps of each path. This is plain data, as read
// from an OpenSim GeometryPath or built in code; compile_paths() (path_model.hpp) resolves the
// names to indices and checks it once. Units are SI (m, rad); frames are named X_A_B (maps
// points given in B to A).
#pragma once

#include <array>
#include <functional>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include "fascicle/core/types.hpp"

namespace fascicle {

inline constexpr double kPathNaN = std::numeric_limits<double>::quiet_NaN();

// ----------------------------------------------------------------------------------------------
// Wrap objects
// ----------------------------------------------------------------------------------------------

enum class WrapShape { cylinder, sphere, ellipsoid, torus };

// OpenSim's "quadrant": the half-space of the wrap frame the path must wrap over ("+x", "-y", ...;
// "x" means "+x"), or "all" (the path wraps only where its straight segment crosses the object).
enum class WrapQuadrant { all, pos_x, neg_x, pos_y, neg_y, pos_z, neg_z };

// Parses OpenSim's quadrant text ("all", "x", "+x", "-x", ..., case-insensitive, blanks ignored).
// Throws a bad-input error naming the accepted values.
WrapQuadrant parse_wrap_quadrant(std::string_view text);
std::string to_string(WrapQuadrant quadrant);

// OpenSim's PathWrap method (hybrid, midpoint, axial: how its ellipsoid wrap searches tangent
// points). fascicle uses one robust method for every value (docs/paths.md) and keeps the value
// only so that a model round-trips.
enum class WrapMethod { hybrid, midpoint, axial };
WrapMethod parse_wrap_method(std::string_view text);

// A rigid wrap surface fixed on a body. The surface is given in its own frame W:
//  cylinder : axis along z of W, centred at the origin, finite `length` (see CylinderEndRule);
//  sphere   : centred at the origin;
//  ellipsoid: centred at the origin, semi-axes `radii` along x, y, z of W;
//  torus    : central circle of radius `ring_radius` in the xy-plane of W about z, tube radius
//             `radius` (OpenSim: outer_radius = ring_radius, inner_radius = radius). The path
//             wraps over the inner side of the tube (it threads the hole), as in OpenSim.
struct WrapObjectSpec {
  std::string name;
  std::string body;                              // body the object is fixed on
  WrapShape shape = WrapShape::cylinder;
  Transform X_body_wrap = Transform::Identity();  // pose of W in the body frame
  double radius = kPathNaN;                       // m: cylinder, sphere, torus tube
  double length = kPathNaN;                       // m: cylinder length along z of W
  Vec3 radii = Vec3::Constant(kPathNaN);          // m: ellipsoid semi-axes
  double ring_radius = kPathNaN;                  // m: torus central circle
  WrapQuadrant quadrant = WrapQuadrant::all;
  bool active = true;                             // inactive objects are ignored
};

// ----------------------------------------------------------------------------------------------
// Path points
// ----------------------------------------------------------------------------------------------

// A scalar function y = f(x) of one coordinate value x (rad or m), with its slope dy/dx. The OpenSim
// importer wraps the skeleton's functions (SimmSpline, PiecewiseLinear, ...) into these.
// With an empty `coordinate`, the function is the constant value(0).
struct CoordinateFunction {
  std::string coordinate;
  std::function<double(double)> value;
  std::function<double(double)> slope;
};

// A constant coordinate function (used for unmoved axes of a MovingPathPoint).
CoordinateFunction constant_function(double value);

enum class PathPointKind {
  fixed,        // station p_body on its body
  conditional,  // station p_body, active only while coordinate ∈ [range_min, range_max]
  moving,       // station (x(q_x), y(q_y), z(q_z)) in the body frame (OpenSim MovingPathPoint)
};

struct PathPointSpec {
  std::string name;
  std::string body;
  PathPointKind kind = PathPointKind::fixed;
  Vec3 p_body = Vec3::Zero();  // m, body frame (fixed and conditional points)
  // Conditional points: the coordinate and its closed active range (rad or m).
  std::string coordinate;
  double range_min = kPathNaN;
  double range_max = kPathNaN;
  // Moving points: x, y, z of the station in the body frame as functions of coordinates.
  std::array<CoordinateFunction, 3> location;
};

// ----------------------------------------------------------------------------------------------
// Wraps and paths
// ----------------------------------------------------------------------------------------------

// One wrap object used by a path over a range of its path points. `range_begin`/`range_end` are
// OpenSim's 1-based indices into the path's point list (inactive points included); a value < 1
// means the first (resp. last) point. Only segments between points of the range are wrapped.
struct PathWrapSpec {
  std::string wrap_object;
  int range_begin = -1;
  int range_end = -1;
  WrapMethod method = WrapMethod::hybrid;
};

// Seed 001 §2.5.3 action-line variants:
//  straight     : one segment between the first and last active point (attachment centroids);
//  centroid     : piecewise line through all active points (via points as section centroids),
//                 no wrapping;
//  obstacle_set : the centroid line wrapped over the path's wrap objects (default; OpenSim).
enum class ActionLine { obstacle_set, centroid, straight };

struct GeometryPathSpec {
  std::string name;                   // muscle / actuator name
  std::vector<PathPointSpec> points;  // origin first, insertion last; at least two
  std::vector<PathWrapSpec> wraps;    // applied in this order
  ActionLine action_line = ActionLine::obstacle_set;
};

// What happens past the ends of a finite cylinder (OpenSim issue #3741):
//  opensim  : no wrap when both tangent points lie beyond the cylinder's ends (|z| > length/2),
//             as OpenSim does; the length jumps when the path slides off an end;
//  infinite : the cylinder is treated as infinitely long: length is continuous (recommended for
//             optimisation and for moment arms).
enum class CylinderEndRule { opensim, infinite };

// How a wrap cylinder is solved:
//  geodesic          : the exact shortest (helical) path; exact moment arms (default);
//  opensim_iterative : OpenSim 4's WrapCylinder construction (tangent candidates, apex plane and,
//                      on paths with two or more wraps, its iterative axial sliding of the tangent
//                      points to 0.1° tangency). Reproduces OpenSim's numbers where they differ
//                      from the shortest path (docs/analyze.md); its moment arms are approximate.
enum class CylinderMethod { geodesic, opensim_iterative };

struct PathOptions {
  CylinderEndRule cylinder_ends = CylinderEndRule::opensim;
  CylinderMethod cylinder_method = CylinderMethod::geodesic;
  // Paths with two or more wraps re-apply all wraps until the length changes by less than
  // `tolerance_m`, at most `max_iterations` times (OpenSim: 8 and 0.0005 m).
  int max_iterations = 8;
  double tolerance_m = 5e-4;
  // Reproduce OpenSim 4's reported length on paths with two or more wraps (parity only; off by
  // default). OpenSim caches a tangent point's ground position the first time a length sum reads
  // it in a pose (Point::getLocationInGround is a Stage::Position cache) and re-wrapping does not
  // invalidate it, so its straight pieces end at tangent points of an earlier pass while the arcs
  // come from the last one. The reported length is then not the length of one path.
  bool opensim_tangent_point_cache = false;
};

// All paths of a model and the wrap objects they share.
struct PathSetSpec {
  std::vector<WrapObjectSpec> wrap_objects;
  std::vector<GeometryPathSpec> paths;
  PathOptions options;
};

}  // namespace fascicle
