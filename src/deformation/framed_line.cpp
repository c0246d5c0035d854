// Action-line resampling and rotation-minimising frames (see framed_line.hpp).
#include "fascicle/deformation/framed_line.hpp"

#include "fascicle/core/error.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace fascicle {

namespace {

// The polyline without repeated points (consecutive points closer than a relative epsilon).
Points3 drop_repeated_points(const Points3& polyline) {
  double scale = 0.0;
  for (Eigen::Index i = 1; i < polyline.rows(); ++i)
    scale += (polyline.row(i) - polyline.row(i - 1)).norm();
  const double eps = 1e-12 * scale;
  Points3 out(polyline.rows(), 3);
  Eigen::Index n = 0;
  for (Eigen::Index i = 0; i < polyline.rows(); ++i) {
    if (n > 0 && (polyline.row(i) - out.row(n - 1)).norm() <= eps) continue;
    out.row(n++) = polyline.row(i);
  }
  return out.topRows(n);
}

}  // namespace

Quat calc_minimal_rotation(const Vec3& a, const Vec3& b) {
  const double c = a.dot(b);
  if (c < -1.0 + 1e-12) {
    // half turn about an axis perpendicular to a
    Eigen::Index k;
    a.cwiseAbs().minCoeff(&k);
    const Vec3 axis = a.cross(Vec3::Unit(k)).normalized();
    return Quat(Eigen::AngleAxisd(M_PI, axis));
  }
  // q = (1 + a.b, a x b) normalised: the half-angle formula of the rotation about a x b
  Quat q(1.0 + c, 0.0, 0.0, 0.0);
  q.vec() = a.cross(b);
  return q.normalized();
}

Quat calc_default_start_frame(const Points3& polyline) {
  const Points3 p = drop_repeated_points(polyline);
  if (p.rows() < 2) throw_bad_input("action line has fewer than two distinct points");
  const Vec3 t = (p.row(1) - p.row(0)).transpose().normalized();
  Eigen::Index k;
  t.cwiseAbs().minCoeff(&k);
  const Vec3 y = (Vec3::Unit(k) - t * t[k]).normalized();
  Mat3 R;
  R.col(0) = t;
  R.col(1) = y;
  R.col(2) = t.cross(y);
  return Quat(R);
}

FramedLine calc_framed_line(const Points3& polyline, int samples, const Quat& start_reference) {
  if (samples < 2) throw_usage("a framed action line needs at least 2 samples");
  if (!polyline.allFinite()) throw_bad_input("action line has non-finite coordinates");
  const Points3 p = drop_repeated_points(polyline);
  if (p.rows() < 2)
    throw_bad_input("action line has fewer than two distinct points",
                    {.suggestion = "check the muscle's path points for this frame"});

  // cumulative arc length
  VecX cum(p.rows());
  cum[0] = 0.0;
  for (Eigen::Index i = 1; i < p.rows(); ++i) cum[i] = cum[i - 1] + (p.row(i) - p.row(i - 1)).norm();
  FramedLine line;
  line.length_m = cum[p.rows() - 1];

  // equal arc-length samples
  line.points.resize(samples, 3);
  Eigen::Index seg = 0;
  for (int k = 0; k < samples; ++k) {
    const double target = line.length_m * k / (samples - 1);
    while (seg + 2 < p.rows() && cum[seg + 1] < target) ++seg;
    const double len = cum[seg + 1] - cum[seg];
    const double u = std::clamp((target - cum[seg]) / len, 0.0, 1.0);
    line.points.row(k) = (1.0 - u) * p.row(seg) + u * p.row(seg + 1);
  }
  line.points.row(samples - 1) = p.row(p.rows() - 1);

  // tangents: central differences inside, one-sided at the ends
  std::vector<Vec3> tangents(samples);
  for (int k = 0; k < samples; ++k) {
    const int a = std::max(k - 1, 0), b = std::min(k + 1, samples - 1);
    tangents[k] = (line.points.row(b) - line.points.row(a)).transpose().normalized();
  }

  // parallel transport of the start frame
  line.frames.resize(samples);
  const Vec3 ref_x = start_reference * Vec3::UnitX();
  line.frames[0] = (calc_minimal_rotation(ref_x.normalized(), tangents[0]) * start_reference).normalized();
  for (int k = 1; k < samples; ++k)
    line.frames[k] =
        (calc_minimal_rotation(tangents[k - 1], tangents[k]) * line.frames[k - 1]).normalized();
  return line;
}

LinePoint calc_line_point(const FramedLine& line, double s) {
  const int m = line.num_samples();
  const double x = std::clamp(s, 0.0, 1.0) * (m - 1);
  const int k = std::min(static_cast<int>(std::floor(x)), m - 2);
  const double u = x - k;
  LinePoint out;
  out.point = ((1.0 - u) * line.points.row(k) + u * line.points.row(k + 1)).transpose();
  out.frame = line.frames[k].slerp(u, line.frames[k + 1]);
  return out;
}

LinePointInterpolator::LinePointInterpolator(const FramedLine& line) : line_(line) {
  const int m = line.num_samples();
  segments_.resize(static_cast<std::size_t>(std::max(m - 1, 0)));
  // the s-independent part of Eigen's QuaternionBase::slerp, in its arithmetic
  const double one = 1.0 - std::numeric_limits<double>::epsilon();
  for (int k = 0; k + 1 < m; ++k) {
    Segment& g = segments_[static_cast<std::size_t>(k)];
    g.cosine = line.frames[k].dot(line.frames[k + 1]);
    const double abs_cosine = std::abs(g.cosine);
    g.linear = abs_cosine >= one;
    if (!g.linear) {
      g.angle = std::acos(abs_cosine);
      g.sin_angle = std::sin(g.angle);
    }
  }
}

LinePoint LinePointInterpolator::operator()(double s) const {
  // the same k, u and point as calc_line_point; the frame as Eigen's slerp(u, frames[k + 1])
  const int m = line_.num_samples();
  const double x = std::clamp(s, 0.0, 1.0) * (m - 1);
  const int k = std::min(static_cast<int>(std::floor(x)), m - 2);
  const double u = x - k;
  LinePoint out;
  out.point = ((1.0 - u) * line_.points.row(k) + u * line_.points.row(k + 1)).transpose();
  const Segment& g = segments_[static_cast<std::size_t>(k)];
  double scale0, scale1;
  if (g.linear) {
    scale0 = 1.0 - u;
    scale1 = u;
  } else {
    scale0 = std::sin((1.0 - u) * g.angle) / g.sin_angle;
    scale1 = std::sin(u * g.angle) / g.sin_angle;
  }
  if (g.cosine < 0.0) scale1 = -scale1;
  out.frame = Quat(scale0 * line_.frames[k].coeffs() + scale1 * line_.frames[k + 1].coeffs());
  return out;
}

LineParameter find_closest_line_parameter(const FramedLine& line, const Vec3& p) {
  const int m = line.num_samples();
  LineParameter best;
  double best_d2 = std::numeric_limits<double>::infinity();
  for (int k = 0; k + 1 < m; ++k) {
    const Vec3 a = line.points.row(k).transpose();
    const Vec3 d = line.points.row(k + 1).transpose() - a;
    const double dd = d.squaredNorm();
    const double u = dd > 0.0 ? std::clamp((p - a).dot(d) / dd, 0.0, 1.0) : 0.0;
    const double d2 = (a + u * d - p).squaredNorm();
    if (d2 < best_d2) {
      best_d2 = d2;
      best.s = (k + u) / (m - 1);
    }
  }
  best.distance_m = std::sqrt(best_d2);
  return best;
}

}  // namespace fascicle
