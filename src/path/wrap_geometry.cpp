// Wrapping kernels. The common core is the planar problem: two points outside a circle, the two
// ways around it (counter-clockwise "positive" and clockwise "negative"), each made of a tangent
// line, an arc and a tangent line. Cylinder, sphere, ellipsoid and torus reduce to it.
#include "fascicle/path/wrap_geometry.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace fascicle {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kTwoPi = 2 * std::numbers::pi;

// Angle in [0, 2π).
double mod_two_pi(double a) {
  a = std::fmod(a, kTwoPi);
  return a < 0 ? a + kTwoPi : a;
}

// OpenSim's DSIGN: zero counts as positive.
int dsign(double x) { return x < 0 ? -1 : 1; }

// Quadrant as (axis, sign); axis -1 means "all".
struct QuadrantAxis {
  int axis = -1;
  int sign = 0;
};

QuadrantAxis decode(WrapQuadrant q) {
  switch (q) {
    case WrapQuadrant::pos_x: return {0, 1};
    case WrapQuadrant::neg_x: return {0, -1};
    case WrapQuadrant::pos_y: return {1, 1};
    case WrapQuadrant::neg_y: return {1, -1};
    case WrapQuadrant::pos_z: return {2, 1};
    case WrapQuadrant::neg_z: return {2, -1};
    case WrapQuadrant::all: break;
  }
  return {};
}

// A point seen from a circle of radius r at the origin: polar angle, half-angle of the visible
// cap (acos(r/d)) and tangent length sqrt(d² - r²).
struct TangentView {
  double phi, delta, length;
};

TangentView tangent_view(const Vec2& p, double r) {
  const double d = p.norm();
  return {std::atan2(p.y(), p.x()), std::acos(std::clamp(r / d, -1.0, 1.0)),
          std::sqrt(std::max(0.0, d * d - r * r))};
}

// One way around the circle: start angle and signed sweep (positive = counter-clockwise).
struct Sweep {
  double theta0, dtheta;
};

// The counter-clockwise and clockwise ways from a to b around the circle.
void circle_sweeps(const TangentView& a, const TangentView& b, Sweep& pos, Sweep& neg) {
  pos.theta0 = a.phi + a.delta;
  pos.dtheta = mod_two_pi(b.phi - b.delta - pos.theta0);
  neg.theta0 = a.phi - a.delta;
  neg.dtheta = -mod_two_pi(neg.theta0 - (b.phi + b.delta));
}

// OpenSim's decision whether to wrap. crosses: the straight segment crosses the obstacle; a_k, b_k,
// near_k: the quadrant-axis component of p1, p2 and of the point of the line nearest the obstacle.
WrapStatus decide(bool crosses, QuadrantAxis q, double a_k, double b_k, double near_k) {
  if (q.axis < 0) return crosses ? WrapStatus::mandatory : WrapStatus::no_wrap;
  const bool a_on = dsign(a_k) == q.sign;
  const bool b_on = dsign(b_k) == q.sign;
  if (a_on || b_on) {
    if (crosses) return WrapStatus::mandatory;
    if (a_on != b_on && dsign(near_k) != q.sign) return WrapStatus::wrapped;
    return WrapStatus::no_wrap;
  }
  // Both ends on the inactive side: the path must go over the active side.
  return WrapStatus::wrapped;
}

// Chooses between the two sweeps. Unconstrained: the shorter path (len_pos vs len_neg).
// Constrained: the sweep whose arc midpoint lies on the active side (score > 0); if both do, the
// shorter one; if neither, the one closer to the active side.
bool choose_positive(double len_pos, double len_neg, bool constrained, double score_pos,
                     double score_neg) {
  if (!constrained) return len_pos <= len_neg;
  const bool pos_ok = score_pos > 0, neg_ok = score_neg > 0;
  if (pos_ok && neg_ok) return len_pos <= len_neg;
  if (pos_ok != neg_ok) return pos_ok;
  return score_pos >= score_neg;
}

Vec3 unit_or(const Vec3& v, const Vec3& fallback) {
  const double n = v.norm();
  return n > 1e-14 ? Vec3(v / n) : fallback;
}

// Fills g1, g2 for a shortest-path wrap: unit vectors from the tangent points to the end points;
// when an end point lies on the surface, minus the arc's tangent there.
void set_geodesic_gradients(const Vec3& p1, const Vec3& p2, WrapResult& r) {
  const WrapArc& a = r.arc;
  const Vec3 d0 = a.dtheta * (-std::sin(a.theta0) * a.u + std::cos(a.theta0) * a.v) + a.dz * a.w;
  const double th1 = a.theta0 + a.dtheta;
  const Vec3 d1 = a.dtheta * (-std::sin(th1) * a.u + std::cos(th1) * a.v) + a.dz * a.w;
  r.g1 = unit_or(p1 - r.t1, unit_or(-d0, Vec3::Zero()));
  r.g2 = unit_or(p2 - r.t2, unit_or(d1, Vec3::Zero()));
}

// Orthonormal e1 = p1/|p1|, e2 in the plane of the centre, p1 and p2 (towards p2). When the three
// are collinear, the plane also contains the quadrant axis (or any axis not along p1).
void section_plane(const Vec3& p1, const Vec3& p2, QuadrantAxis q, Vec3& e1, Vec3& e2) {
  e1 = p1.normalized();
  Vec3 n = p1.cross(p2);
  if (n.norm() < 1e-12 * p1.norm() * std::max(p2.norm(), 1e-300)) {
    Vec3 helper = Vec3::Zero();
    helper[q.axis >= 0 ? q.axis : 0] = 1;
    if (std::abs(helper.dot(e1)) > 0.9) helper = Vec3(0, 1, 0);
    if (std::abs(helper.dot(e1)) > 0.9) helper = Vec3(0, 0, 1);
    n = e1.cross(helper);
  }
  e2 = n.normalized().cross(e1);
}

// Gauss–Legendre (8 points) on [-1, 1].
constexpr double kGaussX[8] = {-0.9602898564975363, -0.7966664774136267, -0.5255324099163290,
                               -0.1834346424956498, 0.1834346424956498,  0.5255324099163290,
                               0.7966664774136267,  0.9602898564975363};
constexpr double kGaussW[8] = {0.1012285362903763, 0.2223810344533745, 0.3137066458778873,
                               0.3626837833783620, 0.3626837833783620, 0.3137066458778873,
                               0.2223810344533745, 0.1012285362903763};

// Length of the ellipse arc θ ↦ A cos θ f1 + B sin θ f2 from theta0 over dtheta (panels of at
// most π/16, 8-point Gauss–Legendre each: relative error far below 1e-12 for axis ratios < 4).
double ellipse_arc_length(double A, double B, double theta0, double dtheta) {
  const int panels = std::max(1, static_cast<int>(std::ceil(std::abs(dtheta) / (kPi / 16))));
  const double h = dtheta / panels;
  double sum = 0;
  for (int p = 0; p < panels; ++p) {
    const double mid = theta0 + (p + 0.5) * h;
    for (int i = 0; i < 8; ++i) {
      const double th = mid + 0.5 * h * kGaussX[i];
      const double s = std::sin(th), c = std::cos(th);
      sum += kGaussW[i] * std::sqrt(A * A * s * s + B * B * c * c);
    }
  }
  return std::abs(0.5 * h * sum);
}

}  // namespace

Vec3 point_on_wrap_arc(const WrapArc& arc, double s) {
  const double th = arc.theta0 + s * arc.dtheta;
  return arc.c + std::cos(th) * arc.u + std::sin(th) * arc.v + (arc.z0 + s * arc.dz) * arc.w;
}

double wrapped_segment_length(const Vec3& p1, const Vec3& p2, const WrapResult& r) {
  if (!is_wrapping(r.status)) return (p2 - p1).norm();
  return (r.t1 - p1).norm() + r.arc_length + (p2 - r.t2).norm();
}

WrapResult wrap_cylinder(const Vec3& p1, const Vec3& p2, double radius, double length,
                         WrapQuadrant quadrant, CylinderEndRule ends) {
  WrapResult out;
  QuadrantAxis q = decode(quadrant);
  if (q.axis == 2) q = {};  // a z-quadrant does not restrict a cylinder about z
  const Vec2 a = p1.head<2>(), b = p2.head<2>();
  const double r2 = radius * radius;
  if (a.squaredNorm() < r2 || b.squaredNorm() < r2) {
    out.status = WrapStatus::inside;
    return out;
  }
  // Does the segment's projection cross the circle (closest point strictly inside the segment)?
  const Vec2 d = b - a;
  const double dd = d.squaredNorm();
  const double tc = dd > 0 ? -a.dot(d) / dd : 0.0;
  const Vec2 near = a + tc * d;
  const bool crosses = dd > 0 && tc > 0 && tc < 1 && near.squaredNorm() < r2;
  const double ak = q.axis >= 0 ? a[q.axis] : 0, bk = q.axis >= 0 ? b[q.axis] : 0;
  out.status = decide(crosses, q, ak, bk, q.axis >= 0 ? near[q.axis] : 0);
  if (!is_wrapping(out.status)) return out;

  // The two ways around; the tangent lengths are the same for both, so "shorter" = smaller sweep.
  const TangentView va = tangent_view(a, radius), vb = tangent_view(b, radius);
  Sweep pos, neg;
  circle_sweeps(va, vb, pos, neg);
  auto score = [&](const Sweep& s) {
    const double m = s.theta0 + 0.5 * s.dtheta;
    return q.axis < 0 ? 0.0 : q.sign * (q.axis == 0 ? std::cos(m) : std::sin(m));
  };
  const Sweep sw = choose_positive(pos.dtheta, -neg.dtheta, q.axis >= 0, score(pos), score(neg))
                       ? pos
                       : neg;

  // Geodesic: unrolled, tangent line + helix + tangent line is one straight line, so the height
  // varies linearly with the unrolled distance.
  const double arc_planar = radius * std::abs(sw.dtheta);
  const double total = va.length + arc_planar + vb.length;
  const double dz = p2.z() - p1.z();
  const double z1 = total > 0 ? p1.z() + dz * va.length / total : p1.z();
  const double z2 = total > 0 ? p1.z() + dz * (va.length + arc_planar) / total : p2.z();
  if (ends == CylinderEndRule::opensim) {
    const double half = 0.5 * length;
    if (std::abs(z1) > half && std::abs(z2) > half) {
      out.status = WrapStatus::no_wrap;
      return out;
    }
  }
  out.arc = {.c = Vec3::Zero(), .u = Vec3(radius, 0, 0), .v = Vec3(0, radius, 0),
             .w = Vec3(0, 0, 1), .theta0 = sw.theta0, .dtheta = sw.dtheta, .z0 = z1,
             .dz = z2 - z1};
  out.t1 = point_on_wrap_arc(out.arc, 0);
  out.t2 = point_on_wrap_arc(out.arc, 1);
  out.arc_length = std::hypot(arc_planar, z2 - z1);
  set_geodesic_gradients(p1, p2, out);
  return out;
}

namespace {

// Sphere and ellipsoid share the central-section construction: the plane through the centre, p1
// and p2 cuts an ellipse (a circle for a sphere) with semi-axes A along f1 and B along f2; in the
// scaled coordinates (x·f1/A, x·f2/B) it is the unit circle, where tangency is solved exactly (an
// affine map keeps tangency).
WrapResult wrap_central_section(const Vec3& p1, const Vec3& p2, const Vec3& radii,
                                WrapQuadrant quadrant) {
  WrapResult out;
  const QuadrantAxis q = decode(quadrant);
  const Vec3 inv = radii.cwiseInverse();
  const Vec3 s1 = p1.cwiseProduct(inv), s2 = p2.cwiseProduct(inv);
  if (s1.squaredNorm() < 1 || s2.squaredNorm() < 1) {
    out.status = WrapStatus::inside;
    return out;
  }
  // Crossing test in the scaled space, where the ellipsoid is the unit sphere.
  const Vec3 sd = s2 - s1;
  const double dd = sd.squaredNorm();
  const double tc = dd > 0 ? -s1.dot(sd) / dd : 0.0;
  const bool crosses = dd > 0 && tc > 0 && tc < 1 && (s1 + tc * sd).squaredNorm() < 1;
  const Vec3 near = p1 + tc * (p2 - p1);
  const double ak = q.axis >= 0 ? p1[q.axis] : 0, bk = q.axis >= 0 ? p2[q.axis] : 0;
  out.status = decide(crosses, q, ak, bk, q.axis >= 0 ? near[q.axis] : 0);
  if (!is_wrapping(out.status)) return out;

  // The section ellipse: quadratic form M = Eᵀ diag(1/r²) E in the plane basis, diagonalised.
  Vec3 e1, e2;
  section_plane(p1, p2, q, e1, e2);
  const Vec3 D = inv.cwiseProduct(inv);
  const double m11 = e1.dot(D.cwiseProduct(e1)), m22 = e2.dot(D.cwiseProduct(e2));
  const double m12 = e1.dot(D.cwiseProduct(e2));
  const double psi = 0.5 * std::atan2(2 * m12, m11 - m22);
  const Vec3 f1 = std::cos(psi) * e1 + std::sin(psi) * e2;
  const Vec3 f2 = -std::sin(psi) * e1 + std::cos(psi) * e2;
  const double A = 1 / std::sqrt(f1.dot(D.cwiseProduct(f1)));
  const double B = 1 / std::sqrt(f2.dot(D.cwiseProduct(f2)));
  const Vec2 a(p1.dot(f1) / A, p1.dot(f2) / B), b(p2.dot(f1) / A, p2.dot(f2) / B);
  const TangentView va = tangent_view(a, 1.0), vb = tangent_view(b, 1.0);
  Sweep pos, neg;
  circle_sweeps(va, vb, pos, neg);

  auto point = [&](double th) -> Vec3 { return A * std::cos(th) * f1 + B * std::sin(th) * f2; };
  auto total = [&](const Sweep& s) {
    return (point(s.theta0) - p1).norm() + ellipse_arc_length(A, B, s.theta0, s.dtheta) +
           (p2 - point(s.theta0 + s.dtheta)).norm();
  };
  auto score = [&](const Sweep& s) {
    return q.axis < 0 ? 0.0 : q.sign * point(s.theta0 + 0.5 * s.dtheta)[q.axis];
  };
  const Sweep sw =
      choose_positive(total(pos), total(neg), q.axis >= 0, score(pos), score(neg)) ? pos : neg;
  out.arc = {.c = Vec3::Zero(), .u = A * f1, .v = B * f2, .w = Vec3::Zero(),
             .theta0 = sw.theta0, .dtheta = sw.dtheta, .z0 = 0, .dz = 0};
  out.t1 = point_on_wrap_arc(out.arc, 0);
  out.t2 = point_on_wrap_arc(out.arc, 1);
  out.arc_length = ellipse_arc_length(A, B, sw.theta0, sw.dtheta);
  set_geodesic_gradients(p1, p2, out);
  return out;
}

}  // namespace

WrapResult wrap_sphere(const Vec3& p1, const Vec3& p2, double radius, WrapQuadrant quadrant) {
  return wrap_central_section(p1, p2, Vec3::Constant(radius), quadrant);
}

WrapResult wrap_ellipsoid(const Vec3& p1, const Vec3& p2, const Vec3& radii,
                          WrapQuadrant quadrant) {
  return wrap_central_section(p1, p2, radii, quadrant);
}

WrapResult wrap_torus(const Vec3& p1, const Vec3& p2, double ring_radius, double tube_radius,
                      WrapQuadrant quadrant) {
  WrapResult out;
  const QuadrantAxis q = decode(quadrant);
  // Squared distance of the segment point x(u) = p1 + u (p2 - p1) from the ring.
  const Vec3 d = p2 - p1;
  auto dist2 = [&](double u) {
    const Vec3 x = p1 + u * d;
    const double rho = x.head<2>().norm();
    return (rho - ring_radius) * (rho - ring_radius) + x.z() * x.z();
  };
  // Coarse scan then golden-section refinement of the nearest point to the ring on the segment.
  constexpr int kScan = 32;
  int best = 0;
  for (int i = 1; i <= kScan; ++i) {
    if (dist2(double(i) / kScan) < dist2(double(best) / kScan)) best = i;
  }
  double lo = std::max(0.0, (best - 1.0) / kScan), hi = std::min(1.0, (best + 1.0) / kScan);
  const double g = 0.5 * (std::sqrt(5.0) - 1);
  for (int it = 0; it < 60; ++it) {
    const double m1 = hi - g * (hi - lo), m2 = lo + g * (hi - lo);
    if (dist2(m1) < dist2(m2)) {
      hi = m2;
    } else {
      lo = m1;
    }
  }
  const Vec3 x = p1 + 0.5 * (lo + hi) * d;
  if (q.axis >= 0 && dsign(x[q.axis]) != q.sign) return out;  // nearest point on inactive half
  const double rho = x.head<2>().norm();
  if (rho < 1e-300) return out;
  // Local cylinder: origin on the ring, x towards the torus axis, z along the ring tangent.
  const Vec3 cx = Vec3(-x.x() / rho, -x.y() / rho, 0);
  const Vec3 cy(0, 0, -1);
  const Vec3 cz = cx.cross(cy);
  Mat3 R_torus_cyl;
  R_torus_cyl << cx, cy, cz;
  const Vec3 origin = -ring_radius * cx;
  const Vec3 a = R_torus_cyl.transpose() * (p1 - origin);
  const Vec3 b = R_torus_cyl.transpose() * (p2 - origin);
  WrapResult c = wrap_cylinder(a, b, tube_radius, 0, WrapQuadrant::pos_x,
                               CylinderEndRule::infinite);
  if (!is_wrapping(c.status)) {
    out.status = c.status;
    return out;
  }
  out.status = WrapStatus::wrapped;
  out.t1 = origin + R_torus_cyl * c.t1;
  out.t2 = origin + R_torus_cyl * c.t2;
  out.arc_length = c.arc_length;
  out.arc = {.c = origin + R_torus_cyl * c.arc.c, .u = R_torus_cyl * c.arc.u,
             .v = R_torus_cyl * c.arc.v, .w = R_torus_cyl * c.arc.w, .theta0 = c.arc.theta0,
             .dtheta = c.arc.dtheta, .z0 = c.arc.z0, .dz = c.arc.dz};
  out.g1 = R_torus_cyl * c.g1;
  out.g2 = R_torus_cyl * c.g2;
  return out;
}

WrapResult wrap_segment(const WrapObjectSpec& spec, const Vec3& p1, const Vec3& p2,
                        CylinderEndRule ends) {
  switch (spec.shape) {
    case WrapShape::cylinder:
      return wrap_cylinder(p1, p2, spec.radius, spec.length, spec.quadrant, ends);
    case WrapShape::sphere: return wrap_sphere(p1, p2, spec.radius, spec.quadrant);
    case WrapShape::ellipsoid: return wrap_ellipsoid(p1, p2, spec.radii, spec.quadrant);
    case WrapShape::torus:
      return wrap_torus(p1, p2, spec.ring_radius, spec.radius, spec.quadrant);
  }
  return {};
}

}  // namespace fascicle
