// FramedLine: a muscle's action line resampled by normalised arc length, with a rotation-minimising
// (parallel-transport) frame at every sample. The surface-first deformation binds each surface
// vertex to a parameter s in [0, 1] along this line (docs/deformation.md).
//
// Frames are rotations R_world_frame whose first column is the unit tangent. They are propagated
// sample to sample by the smallest rotation taking one tangent to the next (the discrete
// rotation-minimising frame, Wang, Juettler, Zheng and Liu 2008, ACM TOG 27(1), "double reflection"
// is the smooth-curve refinement; for a polyline the two-vector rotation is exact parallel
// transport), so the frames do not twist about the line. The twist at the start is fixed by a
// reference frame (for the rest pose: any; for later frames: the rest start frame rotated by the
// origin bone's rotation), which makes the frames follow a rigid motion of the line exactly.
#pragma once

#include "fascicle/core/types.hpp"

#include <vector>

namespace fascicle {

struct FramedLine {
  Points3 points;            // M x 3 samples, sample k at normalised arc length k/(M-1)
  std::vector<Quat> frames;  // per sample: R_world_frame (x axis = tangent)
  double length_m = 0.0;     // arc length of the input polyline

  int num_samples() const { return static_cast<int>(points.rows()); }
};

// Position and frame of a framed line at normalised arc length s (clamped to [0, 1]); linear in
// position and slerp in rotation between samples.
struct LinePoint {
  Vec3 point = Vec3::Zero();
  Quat frame = Quat::Identity();
};

// Resamples `polyline` (>= 2 points, positive length; repeated points are skipped) to `samples`
// (>= 2) points equally spaced in arc length and builds rotation-minimising frames. The first frame
// is the smallest rotation taking start_reference's x axis to the first tangent, applied to
// start_reference. Throws fascicle::Error (bad input) for a degenerate or non-finite polyline.
FramedLine calc_framed_line(const Points3& polyline, int samples, const Quat& start_reference);

// A start reference for a line with no prior frame: x along the first tangent, y along the world
// axis least aligned with it (projected), z = x cross y.
Quat calc_default_start_frame(const Points3& polyline);

LinePoint calc_line_point(const FramedLine& line, double s);

// calc_line_point for many parameters on one line, with the same bits: the parts of each
// segment's slerp that do not depend on s (the cosine of the angle between its two frames, the
// angle and its sine: one acos and one sin) are computed once per segment instead of per point.
// Keeps a reference to `line`, which must outlive it.
class LinePointInterpolator {
 public:
  explicit LinePointInterpolator(const FramedLine& line);
  LinePoint operator()(double s) const;

 private:
  struct Segment {
    double cosine = 1.0;     // frames[k] . frames[k+1]
    double angle = 0.0;      // acos |cosine| (unused when `linear`)
    double sin_angle = 0.0;  // sin(angle)
    bool linear = true;      // |cosine| >= 1 - eps: Eigen's slerp blends linearly
  };
  const FramedLine& line_;
  std::vector<Segment> segments_;
};

// Normalised arc length of the point of the line closest to p, and the distance to it.
struct LineParameter {
  double s = 0.0;
  double distance_m = 0.0;
};
LineParameter find_closest_line_parameter(const FramedLine& line, const Vec3& p);

// Smallest rotation taking unit vector a to unit vector b (for antiparallel vectors: a half turn
// about an axis perpendicular to a).
Quat calc_minimal_rotation(const Vec3& a, const Vec3& b);

}  // namespace fascicle
