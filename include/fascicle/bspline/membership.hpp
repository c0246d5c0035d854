// Point membership and closest point for B-spline solids (seed 000 §3.1.3): minimise
// f(U) = 1/2 |x(U) - p|^2 over the parametric box by Levenberg–Marquardt in material coordinates.
// Bound constraints are handled by an active set (a coordinate on a bound whose gradient pushes
// outwards is frozen) plus projection of the step onto the box; periodic directions wrap. The
// initial guess is the nearest point of a cached sample grid (nanoflann k-d tree); points that end
// outside are retried from the next nearest samples and the best answer is kept.
#pragma once

#include "fascicle/bspline/solid.hpp"

#include <memory>

namespace fascicle {

struct LocateOptions {
  int samples_per_span = 3;        // sample grid density per knot span and direction
  int max_iterations = 60;
  int restarts = 4;                // extra starts (nearest boundary samples) for points found outside
  double inside_tolerance = 1e-9;  // relative to the bounding-box diagonal of the control points
};

struct PointLocation {
  bool inside = false;             // p is in the solid (distance <= tolerance)
  Vec3 material = Vec3::Zero();    // material point U of the closest solid point
  Vec3 closest = Vec3::Zero();     // x(U), metres
  double distance = 0.0;           // |p - x(U)|, metres (0 up to the tolerance when inside)
  int iterations = 0;              // LM iterations summed over all starts
  int starts = 0;                  // number of starts used
};

// The reusable solver: builds the sample grid and k-d tree once for a solid (copied).
class SolidLocator {
 public:
  explicit SolidLocator(BSplineSolid solid, LocateOptions options = {});
  ~SolidLocator();
  SolidLocator(SolidLocator&&) noexcept;
  SolidLocator& operator=(SolidLocator&&) noexcept;

  // Thread-safe (const, no shared scratch).
  PointLocation locate(const Vec3& p) const;
  // Runs LM from a given material point (no sample search).
  PointLocation locate_from(const Vec3& p, const Vec3& start) const;

  const BSplineSolid& get_solid() const { return solid_; }
  double get_tolerance() const { return tolerance_; }

 private:
  struct SampleTree;
  BSplineSolid solid_;
  LocateOptions options_;
  double tolerance_ = 0.0;
  std::unique_ptr<SampleTree> tree_;           // samples through the volume
  std::unique_ptr<SampleTree> boundary_tree_;  // samples on the boundary faces
};

// One-off form (builds a SolidLocator).
PointLocation locate_point(const BSplineSolid& solid, const Vec3& p, LocateOptions options = {});

}  // namespace fascicle
