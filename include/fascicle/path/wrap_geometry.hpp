// Wrapping of one straight path segment p1→p2 over a rigid obstacle: pure functions over Eigen in
// the style of MuJoCo's mju_wrap. Inputs are the two straddling points expressed in the obstacle
// frame W (see WrapObjectSpec for each shape's frame); outputs are the tangent points, the arc
// between them and whether the segment wraps, following OpenSim's semantics:
//  - quadrant "all": wrap only when the straight segment crosses the obstacle;
//  - quadrant ±x/±y/±z: the path must pass over that half of the obstacle; it also wraps when the
//    straight segment misses the obstacle on the wrong side (OpenSim's "wrapped" status).
// Cylinder: geodesic (helix) over the infinite cylinder, the exact shortest path; the finite
// length only decides whether to wrap (CylinderEndRule). Sphere: great-circle arc. Ellipsoid:
// arc of the central plane section through p1, p2 and the centre (robust replacement of OpenSim's
// iterative search, issue #2883). Torus: a cylinder of the tube radius placed tangent to the ring
// where the segment passes closest to it, wrapped on the hole side (OpenSim's construction).
// All lengths in metres. See docs/paths.md.
#pragma once

#include "fascicle/core/types.hpp"
#include "fascicle/path/path_spec.hpp"

namespace fascicle {

enum class WrapStatus {
  no_wrap,    // the straight segment is the path
  inside,     // p1 or p2 lies inside the obstacle: no wrap (OpenSim "insideRadius")
  wrapped,    // wrapped because the quadrant requires it, the segment does not cross the obstacle
  mandatory,  // the straight segment crosses the obstacle
};

inline bool is_wrapping(WrapStatus s) {
  return s == WrapStatus::wrapped || s == WrapStatus::mandatory;
}

// The surface curve between the tangent points, s ∈ [0, 1]:
//   x(s) = c + cos θ(s) u + sin θ(s) v + z(s) w,  θ(s) = theta0 + s dtheta,  z(s) = z0 + s dz.
// (cylinder: helix; sphere: great circle; ellipsoid: ellipse arc; all in frame W.)
struct WrapArc {
  Vec3 c = Vec3::Zero(), u = Vec3::Zero(), v = Vec3::Zero(), w = Vec3::Zero();
  double theta0 = 0, dtheta = 0, z0 = 0, dz = 0;
};

struct WrapResult {
  WrapStatus status = WrapStatus::no_wrap;
  Vec3 t1 = Vec3::Constant(kPathNaN);  // tangent point on the p1 side, frame W
  Vec3 t2 = Vec3::Constant(kPathNaN);  // tangent point on the p2 side, frame W
  // Length along the surface from t1 to t2 (OpenSim's "wrap length"), m; 0 when not wrapping.
  double arc_length = 0;
  // Gradients of the wrapped segment length |p1 - t1| + arc_length + |t2 - p2| with respect to
  // p1 and p2 (frame W). For shortest paths (cylinder, sphere) these are the unit vectors from the
  // tangent points to the end points (envelope theorem); used for moment arms.
  Vec3 g1 = Vec3::Zero(), g2 = Vec3::Zero();
  WrapArc arc;
};

// Point of the arc at s ∈ [0, 1] (s = 0 → t1, s = 1 → t2), frame W.
Vec3 point_on_wrap_arc(const WrapArc& arc, double s);

// Length of the wrapped segment p1 → t1 → arc → t2 → p2, or |p2 − p1| when not wrapping.
double wrapped_segment_length(const Vec3& p1, const Vec3& p2, const WrapResult& r);

WrapResult wrap_cylinder(const Vec3& p1, const Vec3& p2, double radius, double length,
                         WrapQuadrant quadrant, CylinderEndRule ends = CylinderEndRule::opensim);
// OpenSim 4's WrapCylinder::wrapLine (CylinderMethod::opensim_iterative): same decisions as
// wrap_cylinder; tangent points from OpenSim's candidate choice and apex plane, and, unless
// `single_wrap` (the path has one wrap), its iterative axial sliding of the tangent points.
WrapResult wrap_cylinder_opensim(const Vec3& p1, const Vec3& p2, double radius, double length,
                                 WrapQuadrant quadrant, bool single_wrap);
WrapResult wrap_sphere(const Vec3& p1, const Vec3& p2, double radius, WrapQuadrant quadrant);
WrapResult wrap_ellipsoid(const Vec3& p1, const Vec3& p2, const Vec3& radii,
                          WrapQuadrant quadrant);
// ring_radius: central circle radius (OpenSim outer_radius); tube_radius (OpenSim inner_radius).
WrapResult wrap_torus(const Vec3& p1, const Vec3& p2, double ring_radius, double tube_radius,
                      WrapQuadrant quadrant);

// Dispatches on spec.shape using the spec's dimensions and quadrant (p1, p2 in frame W).
WrapResult wrap_segment(const WrapObjectSpec& spec, const Vec3& p1, const Vec3& p2,
                        CylinderEndRule ends = CylinderEndRule::opensim);

}  // namespace fascicle
