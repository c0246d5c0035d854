// OpenSim 4's cylinder wrap (WrapCylinder::wrapLine and its spiral construction), re-derived from
// its documented behaviour for parity: OpenSim does not compute the exact helix; it picks tangent
// points in the plane, slides them along the axis onto the plane through p1, p2 and an "apex" on
// the cylinder, and, on paths with several wraps, slides them further until the straight segments
// meet the spiral at tangency to 0.1°. Frame W: cylinder axis z through the origin.
#include <algorithm>
#include <cmath>
#include <numbers>

#include "fascicle/path/wrap_geometry.hpp"

namespace fascicle {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kTangency = 0.1 * kPi / 180.0;  // OpenSim: tangency to 0.1°
constexpr int kMaxSlides = 100;                  // OpenSim: at most 100 restarts
constexpr double kSampleStep = 0.002;            // OpenSim samples the spiral every 2 mm

int sign_of(double x) { return x >= 0 ? 1 : -1; }  // OpenSim's DSIGN: 0 counts as +

Vec3 unit(const Vec3& v) {
  const double n = v.norm();
  return n > 0 ? Vec3(v / n) : Vec3::Zero();
}

// Closest points of the lines a0 + s (a1 − a0) and b0 + t (b1 − b0); s and t are fractions of the
// given segments. Returns false for parallel lines.
bool closest_points_of_lines(const Vec3& a0, const Vec3& a1, const Vec3& b0, const Vec3& b1,
                             Vec3& on_a, double& s, Vec3& on_b, double& t) {
  const Vec3 da = a1 - a0, db = b1 - b0;
  const Vec3 n = da.cross(db);
  const double nn = n.squaredNorm();
  if (nn < 1e-30 * std::max(1.0, da.squaredNorm() * db.squaredNorm())) {
    on_a = a0;
    on_b = b0;
    s = t = 0;
    return false;
  }
  const Vec3 w = b0 - a0;
  s = w.cross(db).dot(n) / nn;
  t = w.cross(da).dot(n) / nn;
  on_a = a0 + s * da;
  on_b = b0 + t * db;
  return true;
}

// Intersection of the segment a → b with the plane n·x + d = 0.
bool segment_plane(const Vec3& a, const Vec3& b, const Vec3& n, double d, Vec3& x) {
  const Vec3 ab = b - a;
  const double den = ab.dot(n);
  if (std::abs(den) < 1e-12) return false;
  const double t = (-d - n.dot(a)) / den;
  if (t < 0 || t > 1) return false;
  x = a + t * ab;
  return true;
}

Vec3 on_axis(const Vec3& p) { return Vec3(0, 0, p.z()); }

// The two tangent points of the circle of the cylinder in the plane z = p.z seen from p.
void tangent_candidates(const Vec3& p, double r, Vec3& a, Vec3& b, double& distance) {
  const Vec3 c = on_axis(p);
  const Vec3 radial = p - c;
  distance = radial.norm();
  const Vec3 e = unit(radial);
  const double along = r * r / distance;  // r sinθ with sinθ = r/d
  const Vec3 foot = c + along * e;
  const double half = std::sqrt(std::max(0.0, r * r - along * along));
  const Vec3 side = Vec3::UnitZ().cross(e);
  a = foot + half * side;
  b = foot - half * side;
}

double angle_between(const Vec3& a, const Vec3& b) {
  return std::acos(std::clamp(a.dot(b) / (a.norm() * b.norm()), -1.0, 1.0));
}

// Spiral of the wrap: from the axis point under t1 around `axis` by sense·s·θ, rising linearly.
struct Spiral {
  Vec3 base, rise, u, axis;
  double theta = 0, sense = 1, radius = 0;
  Vec3 at(double s) const {
    const Eigen::AngleAxisd R(sense * s * theta, axis);
    return base + radius * (R * u) + s * rise;
  }
};

// OpenSim's slide of a tangent point along the axis when the segment p → t and the spiral's first
// chord t → w leave the axis at angles differing by more than 0.1°: move t 1.5 times towards the
// point of its axial line nearest the line p → w. Returns whether t moved.
bool slide_tangent_point(const Vec3& p, Vec3& t, const Vec3& w) {
  const Vec3 z = Vec3::UnitZ();
  const double a = std::acos(std::clamp(unit(t - p).dot(z), -1.0, 1.0));
  const double b = std::acos(std::clamp(unit(w - t).dot(z), -1.0, 1.0));
  if (std::abs(a - b) <= kTangency) return false;
  const Vec3 pa = t + (p - t).dot(z) * z;  // p projected on the axial line through t
  const Vec3 wa = t + (w - t).dot(z) * z;
  Vec3 on_pw, on_line;
  double s, u;
  closest_points_of_lines(p, w, pa, wa, on_pw, s, on_line, u);
  t += 1.5 * (on_line - t);
  return true;
}

}  // namespace

WrapResult wrap_cylinder_opensim(const Vec3& p1, const Vec3& p2, double r, double length,
                                 WrapQuadrant quadrant, bool single_wrap) {
  WrapResult out;
  int axis = -1, want = 0;
  switch (quadrant) {
    case WrapQuadrant::pos_x: axis = 0; want = 1; break;
    case WrapQuadrant::neg_x: axis = 0; want = -1; break;
    case WrapQuadrant::pos_y: axis = 1; want = 1; break;
    case WrapQuadrant::neg_y: axis = 1; want = -1; break;
    case WrapQuadrant::pos_z: axis = 2; want = 1; break;
    case WrapQuadrant::neg_z: axis = 2; want = -1; break;
    case WrapQuadrant::all: break;
  }
  const bool constrained = axis >= 0;
  const double r2 = r * r;
  if (p1.head<2>().squaredNorm() < r2 || p2.head<2>().squaredNorm() < r2) {
    out.status = WrapStatus::inside;
    return out;
  }
  // Nearest approach of the segment and the axis.
  Vec3 near_line, near_axis;
  double t_line, t_axis;
  closest_points_of_lines(p1, p2, Vec3(0, 0, -0.5 * length), Vec3(0, 0, 0.5 * length), near_line,
                          t_line, near_axis, t_axis);
  const bool crosses = (near_line - near_axis).squaredNorm() < r2 && t_line > 0 && t_line < 1;
  WrapStatus status = WrapStatus::wrapped;
  if (!constrained) {
    if (!crosses) return out;
    status = WrapStatus::mandatory;
  }
  Vec3 a1, b1, a2, b2;
  double d1, d2;
  tangent_candidates(p1, r, a1, b1, d1);
  tangent_candidates(p2, r, a2, b2, d2);
  const Vec3 c1 = on_axis(p1), c2 = on_axis(p2);
  Vec3 t1, t2;
  bool far_side = false, long_wrap = false;
  if (constrained) {
    if (sign_of(p1[axis]) == want || sign_of(p2[axis]) == want) {
      if (crosses) {
        status = WrapStatus::mandatory;
      } else if (!(sign_of(p1[axis]) != sign_of(p2[axis]) && sign_of(near_line[axis]) != want)) {
        return out;
      }
    }
    const double alpha = angle_between(a1 - c1, b2 - c2);
    const double beta = angle_between(b1 - c1, a2 - c2);
    const bool a1_on = sign_of(a1[axis]) == want, b1_on = sign_of(b1[axis]) == want;
    // Pairs (a1, b2) and (b1, a2) go around opposite ways; which one is "far" follows alpha/beta.
    auto use_a1b2 = [&] { t1 = a1; t2 = b2; far_side = alpha > beta; };
    auto use_b1a2 = [&] { t1 = b1; t2 = a2; far_side = !(alpha > beta); };
    if (a1_on && b1_on) {
      if (sign_of(a2[axis]) == want) use_b1a2(); else use_a1b2();
    } else if (a1_on) {
      use_a1b2();
    } else if (b1_on) {
      use_b1a2();
    } else if (sign_of(a2[axis]) == want) {
      use_b1a2();
    } else if (sign_of(b2[axis]) == want) {
      use_a1b2();
    } else {
      if (alpha > beta) { t1 = a1; t2 = b2; } else { t1 = b1; t2 = a2; }
      far_side = true;
    }
    const Vec3 towards_points = (t1 - p1) + (t2 - p2);
    const Vec3 from_axis = (t1 - c1) + (t2 - c2);
    long_wrap = from_axis.dot(towards_points) < 0;
  } else {
    // The pair whose radial directions agree most (the shorter way).
    const Vec3 ua1 = unit(a1 - c1), ub1 = unit(b1 - c1), ua2 = unit(a2 - c2), ub2 = unit(b2 - c2);
    const double k1 = ua1.dot(ua2), k2 = ua1.dot(ub2), k3 = ub1.dot(ua2), k4 = ub1.dot(ub2);
    if (k1 > k2 && k1 > k3 && k1 > k4) { t1 = a1; t2 = a2; }
    else if (k2 > k3 && k2 > k4) { t1 = a1; t2 = b2; }
    else if (k3 > k4) { t1 = b1; t2 = a2; }
    else { t1 = b1; t2 = b2; }
  }
  // Apex: on the cylinder, at the axial height of the point of p1p2 split in the ratio d1 : d2,
  // towards (or, for a far-side wrap, away from) that point.
  const Vec3 mid = p1 + d1 / (d1 + d2) * (p2 - p1);
  const Vec3 axis_pt = on_axis(mid);
  const Vec3 n0 = unit(unit(p1 - axis_pt).cross(unit(p2 - axis_pt)));
  const Vec3 apex_a = axis_pt + r * unit(Vec3::UnitZ().cross(n0));
  const Vec3 apex_b = axis_pt + r * unit(n0.cross(Vec3::UnitZ()));
  const bool a_closer = (mid - apex_a).squaredNorm() < (mid - apex_b).squaredNorm();
  const Vec3 apex = (a_closer != far_side) ? apex_a : apex_b;
  // Slide t1, t2 along the axis onto the plane through p1, p2 and the apex (only when the slide
  // keeps each on its own side of the other end's height).
  const Vec3 n = unit(unit(p1 - apex).cross(unit(p2 - apex)));
  const double d = -p1.dot(n);
  Vec3 x;
  if (segment_plane(t1 - 10 * Vec3::UnitZ(), t1 + 10 * Vec3::UnitZ(), n, d, x) &&
      std::abs(x.z() - c2.z()) < std::abs(c1.z() - c2.z()))
    t1 = x;
  if (segment_plane(t2 - 10 * Vec3::UnitZ(), t2 + 10 * Vec3::UnitZ(), n, d, x) &&
      std::abs(x.z() - c1.z()) < std::abs(c2.z() - c1.z()))
    t2 = x;
  const double half = 0.5 * length;
  if (std::abs(t1.z()) > half && std::abs(t2.z()) > half) return out;  // past both ends
  // Spiral from t1 to t2, and OpenSim's tangency iteration on multi-wrap paths.
  Spiral sp;
  sp.radius = r;
  sp.sense = long_wrap ? -1.0 : 1.0;
  double wrap_length = 0;
  for (int slides = 0;; ++slides) {
    sp.base = on_axis(t1);
    sp.rise = on_axis(t2) - sp.base;
    sp.u = (t1 - sp.base) / r;
    const Vec3 v = (t2 - on_axis(t2)) / r;
    sp.theta = angle_between(sp.u, v);
    if (long_wrap) sp.theta = 2 * kPi - sp.theta;
    sp.axis = unit(sp.u.cross(v));
    wrap_length = std::hypot(r * sp.theta, sp.rise.norm());
    if (single_wrap || slides >= kMaxSlides) break;
    const int samples = std::max(1, static_cast<int>(wrap_length / kSampleStep));
    if (samples < 2) break;
    const double s = 1.0 / samples;
    const bool moved1 = slide_tangent_point(p1, t1, sp.at(s));
    const bool moved2 = slide_tangent_point(p2, t2, sp.at(1 - s));
    if (!moved1 && !moved2) break;
  }
  out.status = status;
  out.t1 = t1;
  out.t2 = t2;
  out.arc_length = wrap_length;
  // The spiral as a WrapArc (for drawing): angle about +z from t1.
  const double signed_sweep = sp.sense * sp.theta * (sp.axis.z() >= 0 ? 1.0 : -1.0);
  out.arc = {.c = Vec3::Zero(), .u = Vec3(r, 0, 0), .v = Vec3(0, r, 0), .w = Vec3(0, 0, 1),
             .theta0 = std::atan2(t1.y(), t1.x()), .dtheta = signed_sweep, .z0 = t1.z(),
             .dz = t2.z() - t1.z()};
  out.g1 = unit(p1 - t1);
  out.g2 = unit(p2 - t2);
  return out;
}

}  // namespace fascicle
