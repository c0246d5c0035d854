// Mean-value coordinates and fibre embedding (see fibre_embedding.hpp).
#include "fascicle/deformation/fibre_embedding.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <numeric>

namespace fascicle {

VecX calc_mean_value_coordinates(const TriMesh& mesh, const Vec3& x) {
  const Eigen::Index n = mesh.V.rows();
  const double scale = (mesh.V.colwise().maxCoeff() - mesh.V.colwise().minCoeff()).norm();
  const double eps = 1e-12 * scale;
  VecX w = VecX::Zero(n);
  VecX d(n);
  Points3 u(n, 3);
  for (Eigen::Index j = 0; j < n; ++j) {
    const Vec3 v = mesh.V.row(j).transpose() - x;
    d[j] = v.norm();
    if (d[j] < eps) {  // x is a vertex
      w[j] = 1.0;
      return w;
    }
    u.row(j) = v.transpose() / d[j];
  }
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    const int id[3] = {mesh.F(f, 0), mesh.F(f, 1), mesh.F(f, 2)};
    // θ_i = 2 asin(l_i / 2) for the chord l_i between the unit vectors; then exactly
    // sin θ_i = l_i sqrt(1 - l_i²/4) and cos θ_i = 1 - l_i²/2, so a triangle costs three asin and
    // one sin/cos of h instead of a dozen sines.
    double theta[3], sin_theta[3], cos_theta[3], c[3], s[3];
    for (int i = 0; i < 3; ++i) {
      const double l = std::min((u.row(id[(i + 1) % 3]) - u.row(id[(i + 2) % 3])).norm(), 2.0);
      theta[i] = 2.0 * std::asin(0.5 * l);
      sin_theta[i] = l * std::sqrt(std::max(0.0, 1.0 - 0.25 * l * l));
      cos_theta[i] = 1.0 - 0.5 * l * l;
    }
    const double h = 0.5 * (theta[0] + theta[1] + theta[2]);
    if (M_PI - h < 1e-10) {
      // x lies on this triangle: barycentric coordinates from the angles
      w.setZero();
      for (int i = 0; i < 3; ++i)
        w[id[i]] = sin_theta[i] * d[id[(i + 2) % 3]] * d[id[(i + 1) % 3]];
      return w / w.sum();
    }
    const double sin_h = std::sin(h), cos_h = std::cos(h);
    Mat3 U;
    U << u.row(id[0]), u.row(id[1]), u.row(id[2]);
    const double sign = U.determinant() < 0.0 ? -1.0 : 1.0;
    bool coplanar = false;
    for (int i = 0; i < 3; ++i) {
      const double sin_h_minus = sin_h * cos_theta[i] - cos_h * sin_theta[i];  // sin(h - θ_i)
      c[i] = 2.0 * sin_h * sin_h_minus / (sin_theta[(i + 1) % 3] * sin_theta[(i + 2) % 3]) - 1.0;
      s[i] = sign * std::sqrt(std::max(0.0, 1.0 - c[i] * c[i]));
      if (std::abs(s[i]) <= 1e-10) coplanar = true;
    }
    if (coplanar) continue;  // x in the triangle's plane, outside it: no contribution
    for (int i = 0; i < 3; ++i) {
      const int a = (i + 1) % 3, b = (i + 2) % 3;
      w[id[i]] += (theta[i] - c[a] * theta[b] - c[b] * theta[a]) / (d[id[i]] * sin_theta[a] * s[b]);
    }
  }
  const double sum = w.sum();
  if (!(std::abs(sum) > 0.0) || !std::isfinite(sum))
    throw_numerical("mean-value coordinates undefined (point far outside or degenerate surface)");
  return w / sum;
}

namespace {

// Keeps the k largest |w| and corrects them (minimum norm) so that sum w = 1 and sum w_j v_j = x.
std::vector<std::pair<int, double>> truncate_affine(const TriMesh& mesh, const Vec3& x,
                                                    const VecX& w, int k) {
  std::vector<int> idx(w.size());
  std::iota(idx.begin(), idx.end(), 0);
  if (k > 0 && k < w.size()) {
    std::nth_element(idx.begin(), idx.begin() + k, idx.end(),
                     [&](int a, int b) { return std::abs(w[a]) > std::abs(w[b]); });
    idx.resize(k);
    std::sort(idx.begin(), idx.end());
  }
  const int m = static_cast<int>(idx.size());
  VecX wk(m);
  Eigen::MatrixXd A(4, m);
  double scale = 0.0;
  for (int j = 0; j < m; ++j) scale = std::max(scale, (mesh.V.row(idx[j]).transpose() - x).norm());
  for (int j = 0; j < m; ++j) {
    wk[j] = w[idx[j]];
    A.block<3, 1>(0, j) = (mesh.V.row(idx[j]).transpose() - x) / scale;
    A(3, j) = 1.0;
  }
  if (m < w.size()) {
    // minimum-norm correction: A dw = r (rank-revealing, exact when the kept vertices span 3-D)
    const Vec4 r = Vec4(0, 0, 0, 1) - A * wk;
    wk += A.completeOrthogonalDecomposition().solve(r);
  }
  std::vector<std::pair<int, double>> out;
  for (int j = 0; j < m; ++j)
    if (wk[j] != 0.0) out.emplace_back(idx[j], wk[j]);
  return out;
}

}  // namespace

FibreEmbedding embed_fibres(const SurfaceBinding& binding, const std::vector<Points3>& fibres,
                            const FibreEmbeddingOptions& options) {
  const TriMesh& rest_surface = binding.rest;
  FibreEmbedding e;
  std::vector<Vec3> points;
  e.fibre_start.push_back(0);
  for (const Points3& f : fibres) {
    if (!f.allFinite()) throw_bad_input("fibre has non-finite points");
    for (Eigen::Index i = 0; i < f.rows(); ++i) points.push_back(f.row(i).transpose());
    e.fibre_start.push_back(static_cast<int>(points.size()));
  }
  std::vector<std::vector<std::pair<int, double>>> rows(points.size());
  parallel_for(points.size(), [&](std::size_t p) {
    const VecX w = calc_mean_value_coordinates(rest_surface, points[p]);
    rows[p] = truncate_affine(rest_surface, points[p], w, options.max_weights);
  });
  std::vector<Eigen::Triplet<double>> t;
  for (std::size_t p = 0; p < rows.size(); ++p)
    for (const auto& [j, v] : rows[p]) t.emplace_back(static_cast<int>(p), j, v);
  e.weights.resize(static_cast<Eigen::Index>(points.size()), rest_surface.V.rows());
  e.weights.setFromTriplets(t.begin(), t.end());

  // binding to the rest action line, as for the surface vertices
  const Eigen::Index np = static_cast<Eigen::Index>(points.size());
  e.point_s.resize(np);
  e.point_offset_local.resize(np, 3);
  for (Eigen::Index p = 0; p < np; ++p) {
    e.point_s[p] = find_closest_line_parameter(binding.rest_line, points[p]).s;
    const LinePoint lp = calc_line_point(binding.rest_line, e.point_s[p]);
    e.point_offset_local.row(p) = (lp.frame.conjugate() * (points[p] - lp.point)).transpose();
  }
  return e;
}

namespace {

std::vector<Points3> split_fibres(const FibreEmbedding& embedding, const Points3& P) {
  std::vector<Points3> out;
  for (std::size_t f = 0; f + 1 < embedding.fibre_start.size(); ++f)
    out.emplace_back(P.middleRows(embedding.fibre_start[f],
                                  embedding.fibre_start[f + 1] - embedding.fibre_start[f]));
  return out;
}

}  // namespace

std::vector<Points3> calc_embedded_fibres_mvc(const FibreEmbedding& embedding, const Points3& V) {
  return split_fibres(embedding, embedding.weights * V);
}

std::vector<Points3> calc_embedded_fibres(const FibreEmbedding& embedding,
                                          const SurfaceFirstSolver& solver) {
  const FramedLine& line = solver.get_line();
  if (line.num_samples() < 2 || solver.get_skinned_vertices().rows() != embedding.weights.cols())
    throw_usage("calc_embedded_fibres needs a solver that has solved a frame of this muscle");
  Points3 P = embedding.weights * (solver.get_vertices() - solver.get_skinned_vertices());
  for (Eigen::Index p = 0; p < P.rows(); ++p) {
    const LinePoint lp = calc_line_point(line, embedding.point_s[p]);
    P.row(p) += (lp.point + lp.frame * Vec3(embedding.point_offset_local.row(p).transpose())).transpose();
  }
  return split_fibres(embedding, P);
}

FibreMetrics calc_fibre_metrics(const std::vector<Points3>& fibres, const Points3& action_line) {
  const FramedLine line = calc_framed_line(action_line, 64, calc_default_start_frame(action_line));
  FibreMetrics m;
  const Eigen::Index n = static_cast<Eigen::Index>(fibres.size());
  m.length_m = VecX::Zero(n);
  m.pennation_rad = VecX::Zero(n);
  for (Eigen::Index f = 0; f < n; ++f) {
    const Points3& P = fibres[f];
    double length = 0.0, angle_sum = 0.0;
    for (Eigen::Index i = 0; i + 1 < P.rows(); ++i) {
      const Vec3 seg = (P.row(i + 1) - P.row(i)).transpose();
      const double l = seg.norm();
      if (!(l > 0.0)) continue;
      const Vec3 mid = 0.5 * (P.row(i) + P.row(i + 1)).transpose();
      const Vec3 t = calc_line_point(line, find_closest_line_parameter(line, mid).s).frame * Vec3::UnitX();
      angle_sum += l * std::acos(std::min(1.0, std::abs(t.dot(seg) / l)));
      length += l;
    }
    m.length_m[f] = length;
    m.pennation_rad[f] = length > 0.0 ? angle_sum / length : 0.0;
  }
  if (n > 0) {
    m.mean_length_m = m.length_m.mean();
    m.mean_pennation_rad = m.pennation_rad.mean();
  }
  return m;
}

}  // namespace fascicle
