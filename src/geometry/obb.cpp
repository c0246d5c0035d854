#include "fascicle/geometry/obb.hpp"

#include "fascicle/core/error.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <vector>

namespace fascicle {
namespace {

void require_points(const Points3& P) {
  if (P.rows() == 0) {
    throw_bad_input("oriented box of an empty point set", {.suggestion = "pass at least one point"});
  }
  if (!P.allFinite()) {
    throw_bad_input("oriented box: points have non-finite (NaN or Inf) coordinates",
                    {.suggestion = "repair the mesh or filter the points first"});
  }
}

// Box with the given orthonormal axes (columns) fitted tightly to the points.
OrientedBox fit(const Points3& P, const Mat3& R) {
  const Points3 Q = P * R;  // coordinates along the axes
  const Vec3 lo = Q.colwise().minCoeff().transpose(), hi = Q.colwise().maxCoeff().transpose();
  OrientedBox box;
  box.axes = R;
  box.half_extents = 0.5 * (hi - lo);
  box.centre = R * (0.5 * (lo + hi));
  return box;
}

// Orders the axes by decreasing half extent and makes them right-handed.
OrientedBox canonical(OrientedBox box) {
  std::array<int, 3> idx{0, 1, 2};
  std::stable_sort(idx.begin(), idx.end(),
                   [&](int a, int b) { return box.half_extents[a] > box.half_extents[b]; });
  OrientedBox out = box;
  for (int k = 0; k < 3; ++k) {
    out.axes.col(k) = box.axes.col(idx[k]);
    out.half_extents[k] = box.half_extents[idx[k]];
  }
  out.axes.col(2) = out.axes.col(0).cross(out.axes.col(1)).normalized();
  return out;
}

// Orthonormal basis whose third column is u (unit).
Mat3 basis_with(const Vec3& u) {
  const Vec3 helper = std::abs(u.x()) < 0.6 ? Vec3::UnitX() : Vec3::UnitY();
  const Vec3 e1 = u.cross(helper).normalized();
  Mat3 B;
  B.col(0) = e1;
  B.col(1) = u.cross(e1);
  B.col(2) = u;
  return B;
}

double cross2(const Vec2& o, const Vec2& a, const Vec2& b) {
  return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
}

// Drops the points that lie strictly inside (by a margin) the convex polygon of the extreme
// points in eight directions (Akl and Toussaint 1978): they cannot be hull vertices, and the
// monotone chain below would push and pop them again. The hull is unchanged; the sort that
// dominates its cost runs on the few points left (on a muscle's projected vertices, ~5 %).
void drop_interior_points(std::vector<Vec2>& p) {
  if (p.size() < 64) return;
  // extreme points for the directions at 0, 45, ..., 315 degrees (counter-clockwise order)
  const std::array<Vec2, 8> dirs{Vec2(1, 0), Vec2(1, 1), Vec2(0, 1), Vec2(-1, 1),
                                 Vec2(-1, 0), Vec2(-1, -1), Vec2(0, -1), Vec2(1, -1)};
  std::array<std::size_t, 8> best{};
  std::array<double, 8> value;
  value.fill(-std::numeric_limits<double>::infinity());
  double scale = 0.0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    scale = std::max(scale, p[i].cwiseAbs().maxCoeff());
    for (std::size_t k = 0; k < 8; ++k) {
      const double v = dirs[k].dot(p[i]);
      if (v > value[k]) {
        value[k] = v;
        best[k] = i;
      }
    }
  }
  std::vector<Vec2> poly;
  for (std::size_t k = 0; k < 8; ++k)
    if (poly.empty() || p[best[k]] != poly.back()) poly.push_back(p[best[k]]);
  while (poly.size() > 1 && poly.front() == poly.back()) poly.pop_back();
  if (poly.size() < 3) return;
  // strictly inside: at least `margin` (a relative 1e-9 of the coordinates) from every edge
  const double margin = 1e-9 * scale;
  std::vector<Vec2> edge(poly.size());
  std::vector<double> length(poly.size());
  for (std::size_t k = 0; k < poly.size(); ++k) {
    edge[k] = poly[(k + 1) % poly.size()] - poly[k];
    length[k] = edge[k].norm();
  }
  std::size_t kept = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    bool inside = true;
    for (std::size_t k = 0; k < poly.size() && inside; ++k) {
      const Vec2 q = p[i] - poly[k];
      inside = edge[k].x() * q.y() - edge[k].y() * q.x() > margin * length[k];
    }
    if (!inside) p[kept++] = p[i];
  }
  p.resize(kept);
}

// Convex hull, counter-clockwise, without collinear points (Andrew's monotone chain, 1979).
std::vector<Vec2> convex_hull(std::vector<Vec2> p) {
  drop_interior_points(p);
  std::sort(p.begin(), p.end(), [](const Vec2& a, const Vec2& b) {
    return a.x() != b.x() ? a.x() < b.x() : a.y() < b.y();
  });
  p.erase(std::unique(p.begin(), p.end()), p.end());
  if (p.size() < 3) return p;
  std::vector<Vec2> h(2 * p.size());
  std::size_t k = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {  // lower hull
    while (k >= 2 && cross2(h[k - 2], h[k - 1], p[i]) <= 0.0) --k;
    h[k++] = p[i];
  }
  for (std::size_t i = p.size() - 1, t = k + 1; i-- > 0;) {  // upper hull
    while (k >= t && cross2(h[k - 2], h[k - 1], p[i]) <= 0.0) --k;
    h[k++] = p[i];
  }
  h.resize(k - 1);
  return h;
}

// Direction (unit) of one side of the minimum-area rectangle enclosing a convex polygon: a side
// is collinear with a hull edge (Freeman and Shapira 1975), so every edge direction is tried.
Vec2 min_area_rectangle_direction(const std::vector<Vec2>& hull) {
  Vec2 best_dir(1.0, 0.0);
  double best_area = std::numeric_limits<double>::infinity();
  const std::size_t n = hull.size();
  for (std::size_t i = 0; i < n; ++i) {
    const Vec2 e = hull[(i + 1) % n] - hull[i];
    const double len = e.norm();
    if (!(len > 0.0)) continue;
    const Vec2 d = e / len, m(-d.y(), d.x());
    double lo_d = 0, hi_d = 0, lo_m = 0, hi_m = 0;
    for (std::size_t j = 0; j < n; ++j) {
      const Vec2 q = hull[j] - hull[i];
      lo_d = std::min(lo_d, q.dot(d));
      hi_d = std::max(hi_d, q.dot(d));
      lo_m = std::min(lo_m, q.dot(m));
      hi_m = std::max(hi_m, q.dot(m));
    }
    const double area = (hi_d - lo_d) * (hi_m - lo_m);
    if (area < best_area) {
      best_area = area;
      best_dir = d;
    }
  }
  return best_dir;
}

// The smallest box with one axis along u (unit).
OrientedBox best_box_about(const Points3& P, const Vec3& u) {
  const Mat3 B = basis_with(u);
  const Eigen::Matrix<double, Eigen::Dynamic, 2> Q = P * B.leftCols<2>();
  std::vector<Vec2> pts(static_cast<std::size_t>(Q.rows()));
  for (Eigen::Index i = 0; i < Q.rows(); ++i) pts[static_cast<std::size_t>(i)] = Q.row(i).transpose();
  const Vec2 d = min_area_rectangle_direction(convex_hull(std::move(pts)));
  Mat3 R;
  R.col(0) = (d.x() * B.col(0) + d.y() * B.col(1)).normalized();
  R.col(1) = u.cross(R.col(0)).normalized();
  R.col(2) = u;
  return fit(P, R);
}

// Dominant face-normal directions (up to sign), by total area, at most `count`.
std::vector<Vec3> dominant_normals(const TriMesh& mesh, std::size_t count) {
  struct Cluster {
    Vec3 n;
    double area;
  };
  std::vector<std::pair<double, Vec3>> faces;
  faces.reserve(static_cast<std::size_t>(mesh.F.rows()));
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    const Vec3 a = mesh.V.row(mesh.F(f, 0)), b = mesh.V.row(mesh.F(f, 1)), c = mesh.V.row(mesh.F(f, 2));
    const Vec3 n = (b - a).cross(c - a);
    const double len = n.norm();
    if (len > 0.0) faces.emplace_back(0.5 * len, n / len);
  }
  std::stable_sort(faces.begin(), faces.end(),
                   [](const auto& x, const auto& y) { return x.first > y.first; });
  std::vector<Cluster> clusters;
  constexpr std::size_t kMaxClusters = 64;
  for (const auto& [area, n] : faces) {
    bool merged = false;
    for (Cluster& c : clusters) {
      if (std::abs(c.n.dot(n)) > 1.0 - 1e-9) {
        c.area += area;
        merged = true;
        break;
      }
    }
    if (!merged && clusters.size() < kMaxClusters) clusters.push_back({n, area});
  }
  std::stable_sort(clusters.begin(), clusters.end(),
                   [](const Cluster& x, const Cluster& y) { return x.area > y.area; });
  std::vector<Vec3> out;
  for (std::size_t i = 0; i < std::min(count, clusters.size()); ++i) out.push_back(clusters[i].n);
  return out;
}

// Principal axes of a symmetric covariance, as a right-handed rotation.
Mat3 principal_axes(const Mat3& covariance) {
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(covariance);
  Mat3 R = eig.eigenvectors();
  if (R.determinant() < 0.0) R.col(2) = -R.col(2);
  return R;
}

OrientedBox solve(const Points3& P, const Mat3& start_axes, const std::vector<Vec3>& extra_axes,
                  bool refine) {
  OrientedBox best = fit(P, start_axes);
  if (refine) {
    auto improve = [&](const Vec3& u) {
      const OrientedBox b = best_box_about(P, u.normalized());
      if (b.calc_volume() < best.calc_volume() * (1.0 - 1e-12)) {
        best = b;
        return true;
      }
      return false;
    };
    for (int k = 0; k < 3; ++k) improve(start_axes.col(k));
    for (const Vec3& u : extra_axes) improve(u);
    // Re-optimise about the winner's own axes until no axis improves it.
    for (int iteration = 0; iteration < 8; ++iteration) {
      const Mat3 axes = best.axes;
      bool changed = false;
      for (int k = 0; k < 3; ++k) changed = improve(axes.col(k)) || changed;
      if (!changed) break;
    }
  }
  return canonical(best);
}

}  // namespace

Transform OrientedBox::calc_pose() const {
  Transform X = Transform::Identity();
  X.linear() = axes;
  X.translation() = centre;
  return X;
}

OrientedBox compute_oriented_box(const Points3& points, bool refine) {
  require_points(points);
  const Eigen::RowVector3d mean = points.colwise().mean();
  const Points3 centred = points.rowwise() - mean;
  const Mat3 covariance = centred.transpose() * centred / static_cast<double>(points.rows());
  return solve(points, principal_axes(covariance), {}, refine);
}

OrientedBox compute_oriented_box(const TriMesh& mesh, bool refine) {
  require_points(mesh.V);
  if (mesh.F.rows() > 0 && (mesh.F.minCoeff() < 0 || mesh.F.maxCoeff() >= mesh.V.rows())) {
    throw_bad_input("oriented box: mesh has triangle vertex indices out of range",
                    {.suggestion = "repair the mesh (fascicle mesh repair) first"});
  }
  // Surface covariance with uniform area density. A triangle's second moment about the origin is
  // A/12 (a a^T + b b^T + c c^T + 9 m m^T), m its centroid; coordinates relative to the vertex mean
  // for accuracy.
  const Vec3 origin = mesh.V.colwise().mean().transpose();
  double area = 0.0;
  Vec3 first = Vec3::Zero();
  Mat3 second = Mat3::Zero();
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    const Vec3 a = mesh.V.row(mesh.F(f, 0)).transpose() - origin;
    const Vec3 b = mesh.V.row(mesh.F(f, 1)).transpose() - origin;
    const Vec3 c = mesh.V.row(mesh.F(f, 2)).transpose() - origin;
    const double A = 0.5 * (b - a).cross(c - a).norm();
    const Vec3 m = (a + b + c) / 3.0;
    area += A;
    first += A * m;
    second += A / 12.0 * (a * a.transpose() + b * b.transpose() + c * c.transpose() + 9.0 * m * m.transpose());
  }
  if (!(area > 0.0)) return compute_oriented_box(mesh.V, refine);  // no area: use the points
  const Vec3 mu = first / area;
  const Mat3 covariance = second / area - mu * mu.transpose();
  return solve(mesh.V, principal_axes(covariance), dominant_normals(mesh, 6), refine);
}

}  // namespace fascicle
