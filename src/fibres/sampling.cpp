// Stratified sampling of weighted triangle sets (see sampling.hpp).
#include "sampling.hpp"

#include "fascicle/fibres/fibre_set.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cstdint>
#include <cmath>
#include <numeric>

namespace fascicle::detail {

std::vector<WeightedTriangle> make_area_weighted(const Points3& V, const Triangles& F,
                                                 const std::vector<int>& faces) {
  std::vector<WeightedTriangle> tris;
  tris.reserve(faces.size());
  for (int f : faces) {
    WeightedTriangle t;
    for (int k = 0; k < 3; ++k) t.corner[k] = V.row(F(f, k)).transpose();
    t.weight = 0.5 * (t.corner[1] - t.corner[0]).cross(t.corner[2] - t.corner[0]).norm();
    t.tag = f;
    tris.push_back(t);
  }
  return tris;
}

CumulativePick pick_cumulative(const std::vector<double>& cumulative, double target) {
  const std::size_t k = std::min<std::size_t>(
      static_cast<std::size_t>(std::lower_bound(cumulative.begin(), cumulative.end(), target) -
                               cumulative.begin()),
      cumulative.size() - 1);
  const double lo = k == 0 ? 0.0 : cumulative[k - 1];
  return {k, std::clamp((target - lo) / std::max(cumulative[k] - lo, 1e-300), 0.0, 1.0)};
}

std::vector<TriangleSample> sample_triangles(const std::vector<WeightedTriangle>& tris, int count) {
  std::vector<TriangleSample> out;
  const std::size_t n = tris.size();
  double total = 0.0;
  for (const WeightedTriangle& t : tris) total += std::max(t.weight, 0.0);
  if (n == 0 || count <= 0 || !(total > 0.0)) return out;
  // Principal directions of the weighted centroids.
  std::vector<Vec3> c(n);
  Vec3 mean = Vec3::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    c[i] = (tris[i].corner[0] + tris[i].corner[1] + tris[i].corner[2]) / 3.0;
    mean += std::max(tris[i].weight, 0.0) * c[i];
  }
  mean /= total;
  Mat3 cov = Mat3::Zero();
  for (std::size_t i = 0; i < n; ++i)
    cov += std::max(tris[i].weight, 0.0) * (c[i] - mean) * (c[i] - mean).transpose();
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(cov);
  const Vec3 e1 = eig.eigenvectors().col(2), e2 = eig.eigenvectors().col(1);
  std::vector<double> s1(n), s2(n);
  for (std::size_t i = 0; i < n; ++i) {
    s1[i] = (c[i] - mean).dot(e1);
    s2[i] = (c[i] - mean).dot(e2);
  }
  const auto [lo2, hi2] = std::minmax_element(s2.begin(), s2.end());
  const auto [lo1, hi1] = std::minmax_element(s1.begin(), s1.end());
  const double w1 = std::max(*hi1 - *lo1, 1e-300), w2 = *hi2 - *lo2;
  // Strips across e2: m strips of count / m samples each have about square cells.
  const double ratio = std::min(std::sqrt(count * w2 / w1), static_cast<double>(count));
  const int strips = std::clamp(static_cast<int>(std::lround(ratio)), 1, count);
  std::vector<int> strip(n);
  for (std::size_t i = 0; i < n; ++i)
    strip[i] = w2 > 0.0 ? std::clamp(static_cast<int>((s2[i] - *lo2) / w2 * strips), 0, strips - 1)
                        : 0;
  std::vector<int> order(n);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    if (strip[a] != strip[b]) return strip[a] < strip[b];
    const double ka = strip[a] % 2 == 0 ? s1[a] : -s1[a], kb = strip[b] % 2 == 0 ? s1[b] : -s1[b];
    return ka != kb ? ka < kb : a < b;
  });
  std::vector<double> cumulative(n);
  double run = 0.0;
  for (std::size_t k = 0; k < n; ++k) {
    run += std::max(tris[order[k]].weight, 0.0);
    cumulative[k] = run;
  }
  out.reserve(count);
  for (int i = 0; i < count; ++i) {
    const Vec2 r = get_r2_point(i);
    const double target = r.x() * total;
    const auto [k, s] = pick_cumulative(cumulative, target);
    const WeightedTriangle& t = tris[order[k]];
    const double q = std::sqrt(s);
    out.push_back({(1.0 - q) * t.corner[0] + q * (1.0 - r.y()) * t.corner[1] + q * r.y() * t.corner[2],
                   order[k]});
  }
  return out;
}

std::vector<TetSample> sample_tets(const Points3& V, const Eigen::Matrix<int, Eigen::Dynamic, 4>& T,
                                   int count) {
  std::vector<TetSample> out;
  const Eigen::Index n = T.rows();
  if (n == 0 || count <= 0) return out;
  std::vector<double> vol(n);
  std::vector<Vec3> c(n);
  double total = 0.0;
  Vec3 mean = Vec3::Zero();
  for (Eigen::Index t = 0; t < n; ++t) {
    const Vec3 x0 = V.row(T(t, 0)), x1 = V.row(T(t, 1)), x2 = V.row(T(t, 2)), x3 = V.row(T(t, 3));
    vol[t] = std::max(std::abs((x1 - x0).cross(x2 - x0).dot(x3 - x0)) / 6.0, 0.0);
    c[t] = (x0 + x1 + x2 + x3) / 4.0;
    total += vol[t];
    mean += vol[t] * c[t];
  }
  if (!(total > 0.0)) return out;
  mean /= total;
  Mat3 cov = Mat3::Zero();
  for (Eigen::Index t = 0; t < n; ++t) cov += vol[t] * (c[t] - mean) * (c[t] - mean).transpose();
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(cov);
  const Vec3 e1 = eig.eigenvectors().col(2), e2 = eig.eigenvectors().col(1),
             e3 = eig.eigenvectors().col(0);
  const double h = std::cbrt(total / count);
  Eigen::Matrix<double, Eigen::Dynamic, 3> s(n, 3);
  for (Eigen::Index t = 0; t < n; ++t)
    s.row(t) << (c[t] - mean).dot(e1), (c[t] - mean).dot(e2), (c[t] - mean).dot(e3);
  const Eigen::RowVector3d lo = s.colwise().minCoeff(), hi = s.colwise().maxCoeff();
  const int m2 = std::max(1, static_cast<int>(std::lround((hi(1) - lo(1)) / h)));
  const int m3 = std::max(1, static_cast<int>(std::lround((hi(2) - lo(2)) / h)));
  std::vector<std::int64_t> cell(n);
  std::vector<double> key(n);
  for (Eigen::Index t = 0; t < n; ++t) {
    const int k = std::clamp(static_cast<int>((s(t, 2) - lo(2)) / std::max(hi(2) - lo(2), 1e-300) * m3), 0, m3 - 1);
    int j = std::clamp(static_cast<int>((s(t, 1) - lo(1)) / std::max(hi(1) - lo(1), 1e-300) * m2), 0, m2 - 1);
    if (k % 2 == 1) j = m2 - 1 - j;  // serpentine over e2 within each e3 layer
    const std::int64_t strip = static_cast<std::int64_t>(k) * m2 + j;
    cell[t] = strip;
    key[t] = strip % 2 == 0 ? s(t, 0) : -s(t, 0);  // and along e1 within each strip
  }
  std::vector<int> order(n);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    if (cell[a] != cell[b]) return cell[a] < cell[b];
    return key[a] != key[b] ? key[a] < key[b] : a < b;
  });
  std::vector<double> cumulative(n);
  double run = 0.0;
  for (Eigen::Index k = 0; k < n; ++k) cumulative[k] = run += vol[order[k]];
  out.reserve(count);
  for (int i = 0; i < count; ++i) {
    const Vec2 r = get_r2_point(i);
    const double target = r.x() * total;
    const auto [k, a_k] = pick_cumulative(cumulative, target);
    double a = a_k;
    double b = r.y(), cc = std::fmod(a * 7.0 + r.y() * 3.0, 1.0);
    // Fold the unit cube onto the tet (Rocchini & Cignoni 2000).
    if (a + b > 1.0) {
      a = 1.0 - a;
      b = 1.0 - b;
    }
    if (b + cc > 1.0) {
      const double t = cc;
      cc = 1.0 - a - b;
      b = 1.0 - t;
    } else if (a + b + cc > 1.0) {
      const double t = cc;
      cc = a + b + cc - 1.0;
      a = 1.0 - b - t;
    }
    const int t = order[k];
    const Vec3 x0 = V.row(T(t, 0)), x1 = V.row(T(t, 1)), x2 = V.row(T(t, 2)), x3 = V.row(T(t, 3));
    out.push_back({x0 + a * (x1 - x0) + b * (x2 - x0) + cc * (x3 - x0), t});
  }
  return out;
}

}  // namespace fascicle::detail
