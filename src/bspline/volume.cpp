// Exact B-spline solid volume and gradient (seed 000 §3.1.1); see volume.hpp for the formulas.
#include "fascicle/bspline/volume.hpp"

#include "fascicle/core/error.hpp"

#include <fmt/format.h>

#include <Eigen/QR>

#include <algorithm>
#include <memory>
#include <cmath>
#include <numbers>

namespace fascicle {

void calc_gauss_legendre(int n, std::vector<double>& nodes, std::vector<double>& weights) {
  nodes.assign(n, 0.0);
  weights.assign(n, 0.0);
  for (int i = 0; i < n; ++i) {
    // Newton iteration on P_n from the Chebyshev-like guess; P_n by the three-term recurrence.
    double x = std::cos(std::numbers::pi * (i + 0.75) / (n + 0.5));
    double dp = 1.0;
    for (int it = 0; it < 100; ++it) {
      double p0 = 1.0, p1 = x;
      for (int k = 2; k <= n; ++k) {
        const double p2 = ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k;
        p0 = p1;
        p1 = p2;
      }
      if (n == 1) p0 = 1.0, p1 = x;
      dp = n * (x * p1 - p0) / (x * x - 1.0);
      const double dx = p1 / dp;
      x -= dx;
      if (std::abs(dx) < 1e-16) break;
    }
    // recompute derivative at the converged node
    double p0 = 1.0, p1 = x;
    for (int k = 2; k <= n; ++k) {
      const double p2 = ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k;
      p0 = p1;
      p1 = p2;
    }
    dp = n * (x * p1 - p0) / (x * x - 1.0);
    nodes[n - 1 - i] = x;
    weights[n - 1 - i] = 2.0 / ((1.0 - x * x) * dp * dp);
  }
}

int find_volume_quadrature_order(int degree) { return std::max(1, (3 * degree + 1) / 2); }

std::vector<SpanPoint> calc_span_quadrature(const BSplineBasis& b, int points_per_span) {
  std::vector<double> xi, wi;
  calc_gauss_legendre(points_per_span, xi, wi);
  std::vector<SpanPoint> out;
  for (int s = b.degree; s < b.num_functions(); ++s) {
    const double a = b.knots[s], c = b.knots[s + 1];
    if (!(c > a)) continue;
    for (std::size_t q = 0; q < xi.size(); ++q)
      out.push_back({0.5 * (a + c) + 0.5 * (c - a) * xi[q], 0.5 * (c - a) * wi[q]});
  }
  return out;
}

namespace {

std::vector<SpanPoint> make_span_points(const BSplineBasis& b) {
  return calc_span_quadrature(b, find_volume_quadrature_order(b.degree));
}

}  // namespace

double calc_volume(const BSplineSolid& s) {
  std::array<std::vector<SpanPoint>, 3> g;
  for (int d = 0; d < 3; ++d) g[d] = make_span_points(s.basis[d]);
  double v = 0.0;
  for (const auto& pw : g[2]) {
    for (const auto& pv : g[1]) {
      double row = 0.0;
      for (const auto& pu : g[0]) {
        row += pu.weight * calc_point_and_jacobian(s, Vec3(pu.t, pv.t, pw.t)).J.determinant();
      }
      v += pw.weight * pv.weight * row;
    }
  }
  return v;
}

VolumeAndGradient calc_volume_and_gradient(const BSplineSolid& s) {
  std::array<std::vector<SpanPoint>, 3> g;
  for (int d = 0; d < 3; ++d) g[d] = make_span_points(s.basis[d]);
  VolumeAndGradient out;
  out.gradient = Points3::Zero(s.P.rows(), 3);
  const int pu = s.basis[0].degree, pv = s.basis[1].degree, pw = s.basis[2].degree;
  for (const auto& qw : g[2]) {
    const BasisValues bw = calc_basis(s.basis[2], qw.t, 1);
    for (const auto& qv : g[1]) {
      const BasisValues bv = calc_basis(s.basis[1], qv.t, 1);
      for (const auto& qu : g[0]) {
        const BasisValues bu = calc_basis(s.basis[0], qu.t, 1);
        const double w = qu.weight * qv.weight * qw.weight;
        const Mat3 J = calc_point_and_jacobian(s, Vec3(qu.t, qv.t, qw.t)).J;
        out.volume_m3 += w * J.determinant();
        const Vec3 cu = J.col(1).cross(J.col(2));  // multiplies dN/du
        const Vec3 cv = J.col(2).cross(J.col(0));
        const Vec3 cw = J.col(0).cross(J.col(1));
        for (int c = 0; c <= pw; ++c) {
          const int k = control_index(s.basis[2], bw.first + c);
          for (int b = 0; b <= pv; ++b) {
            const int j = control_index(s.basis[1], bv.first + b);
            for (int a = 0; a <= pu; ++a) {
              const int i = control_index(s.basis[0], bu.first + a);
              const Vec3 gI = bu.N[1][a] * bv.N[0][b] * bw.N[0][c] * cu +
                              bu.N[0][a] * bv.N[1][b] * bw.N[0][c] * cv +
                              bu.N[0][a] * bv.N[0][b] * bw.N[1][c] * cw;
              out.gradient.row(s.index(i, j, k)) += w * gI.transpose();
            }
          }
        }
      }
    }
  }
  return out;
}

BoundaryVolumeIntegrator::BoundaryVolumeIntegrator(const BSplineSolid& lattice)
    : basis_(lattice.basis) {
  for (int d = 0; d < 3; ++d) {
    if (!basis_[d].periodic && !basis_[d].is_clamped()) {
      throw_bad_input(
          fmt::format("the boundary volume formula needs clamped knots, direction {} is not",
                      "uvw"[d]),
          ErrorContext{.object = lattice.name,
                       .suggestion = "use calc_volume (quadrature of det J) or clamp the knots"});
    }
    Direction& D = dir_[d];
    D.num_control = basis_[d].num_control;
    D.width = basis_[d].degree + 1;
    for (const SpanPoint& sp : make_span_points(basis_[d])) {
      const BasisValues bv = calc_basis(basis_[d], sp.t, 1);
      D.weight.push_back(sp.weight);
      for (int r = 0; r < D.width; ++r) {
        D.N0.push_back(bv.N[0][r]);
        D.N1.push_back(bv.N[1][r]);
        D.index.push_back(control_index(basis_[d], bv.first + r));
      }
    }
    D.num_points = static_cast<int>(D.weight.size());
    D.padded_points = (D.num_points + 1) & ~1;
    const int Qp = D.padded_points;
    D.dense0.assign(static_cast<std::size_t>(D.num_control) * Qp, 0.0);
    D.dense1 = D.dense0;
    D.dense_w = D.dense0;
    D.band_lo.assign(D.num_control, Qp);
    D.band_hi.assign(D.num_control, 0);
    for (int q = 0; q < D.num_points; ++q)
      for (int r = 0; r < D.width; ++r) {
        const int i = D.index[q * D.width + r];
        D.dense0[i * Qp + q] += D.N0[q * D.width + r];
        D.dense1[i * Qp + q] += D.N1[q * D.width + r];
        D.dense_w[i * Qp + q] += D.weight[q] * D.N0[q * D.width + r];
        D.band_lo[i] = std::min(D.band_lo[i], q & ~1);
        D.band_hi[i] = std::max(D.band_hi[i], (q & ~1) + 2);
      }
    for (int i = 0; i < D.num_control; ++i) D.band_hi[i] = std::max(D.band_hi[i], D.band_lo[i]);
  }
}

namespace {

// One boundary face of the sum-factorised integral (see BoundaryVolumeIntegrator), for a-widths
// WA and b-widths WB (degree + 1) known at compile time. G[coordinate][b control][a control]:
// the face's control points minus the reference point. The face term uses the divergence theorem
// with the field (0, 0, z) (∇· = 1): V = Σ_faces ± ∫∫ z (x_a × x_b)_z da db, which needs z, x_a
// and x_b but not x, y. With kGradient, dV/dQ = ± ∫∫ N n da db needs the whole normal
// n = x_a × x_b. Returns the face integral; adds the gradient rows (times sign) into grad.
//
// Layout (a points in SIMD pairs, p = pair): L[b control][p][k][lane], k = 0..2 the a-derivative
// of the coordinates, k = 3..5 their values; T[b control][p][q][lane]. One b control's data for a
// pair is contiguous, so the sweep addresses each of the WB rows with one pointer.
template <bool kGradient, int WA, int WB, class Dir, class FaceIndex>
double integrate_face(const Dir& A, const Dir& B, double* G, double* scratch, double sign,
                      const FaceIndex& face_index, Points3* grad) {
  using A2 = Eigen::Array2d;
  const auto load = [](const double* p) { return A2(Eigen::Map<const A2>(p)); };
  const auto add_to = [](double* p, const A2& v) { Eigen::Map<A2>(p) += v; };
  const int na = A.num_control, nb = B.num_control, Qb = B.num_points;
  const int Qp = A.padded_points;  // a points padded to whole SIMD pairs (padding: zero weight)
  const int np = Qp / 2;
  double* L = scratch;                                   // nb * np * 12
  double* T = L + static_cast<std::size_t>(nb) * np * 12;  // nb * np * 6 (gradient)
  double* wa = T + static_cast<std::size_t>(nb) * np * 6;  // Qp
  for (int qa = 0; qa < Qp; ++qa) wa[qa] = qa < A.num_points ? A.weight[qa] : 0.0;
  // dense, band-limited contraction along a: L[jb][p] = Σ_ia G[.][jb][ia] (N'_ia, N_ia)(p)
  std::fill(L, L + static_cast<std::size_t>(nb) * np * 12, 0.0);
  for (int jb = 0; jb < nb; ++jb) {
    double* l = L + static_cast<std::size_t>(jb) * np * 12;
    for (int ia = 0; ia < na; ++ia) {
      const A2 gx = A2::Constant(G[(0 * nb + jb) * na + ia]);
      const A2 gy = A2::Constant(G[(1 * nb + jb) * na + ia]);
      const A2 gz = A2::Constant(G[(2 * nb + jb) * na + ia]);
      const double* d0 = &A.dense0[ia * Qp];
      const double* d1 = &A.dense1[ia * Qp];
      for (int qa = A.band_lo[ia]; qa < A.band_hi[ia]; qa += 2) {
        double* c = l + qa * 6;  // pair qa / 2
        const A2 v1 = load(d1 + qa), v0 = load(d0 + qa);
        add_to(c + 0, gx * v1);
        add_to(c + 2, gy * v1);
        add_to(c + 4, gz * v1);
        add_to(c + 6, gx * v0);
        add_to(c + 8, gy * v0);
        add_to(c + 10, gz * v0);
      }
    }
  }
  if constexpr (kGradient) std::fill(T, T + static_cast<std::size_t>(nb) * np * 6, 0.0);
  // Sweep the b points; at each (a pair, b point): x_a, x_b, z, n = x_a × x_b, the volume term,
  // and (gradient) T[jb][p][q] += w_b N_b(jb) n_q: the b half of ∫∫ N_I n.
  A2 face = A2::Zero();
  for (int qb = 0; qb < Qb; ++qb) {
    const double w = B.weight[qb];
    A2 n0[WB], n1[WB], wn0[WB];
    const double* rowL[WB];
    double* rowT[WB];
    for (int r = 0; r < WB; ++r) {
      const int jb = B.index[qb * WB + r];
      n0[r] = A2::Constant(B.N0[qb * WB + r]);
      n1[r] = A2::Constant(B.N1[qb * WB + r]);
      wn0[r] = A2::Constant(w * B.N0[qb * WB + r]);
      rowL[r] = L + static_cast<std::size_t>(jb) * np * 12;
      rowT[r] = T + static_cast<std::size_t>(jb) * np * 6;
    }
    A2 row = A2::Zero();
    for (int p = 0; p < np; ++p) {
      const double* l = rowL[0] + p * 12;
      A2 xa0 = n0[0] * load(l + 0), xa1 = n0[0] * load(l + 2), xa2 = n0[0] * load(l + 4);
      A2 xb0 = n1[0] * load(l + 6), xb1 = n1[0] * load(l + 8), xb2 = n1[0] * load(l + 10);
      A2 z = n0[0] * load(l + 10);
      for (int r = 1; r < WB; ++r) {
        l = rowL[r] + p * 12;
        xa0 += n0[r] * load(l + 0);
        xa1 += n0[r] * load(l + 2);
        xa2 += n0[r] * load(l + 4);
        xb0 += n1[r] * load(l + 6);
        xb1 += n1[r] * load(l + 8);
        const A2 lz = load(l + 10);
        xb2 += n1[r] * lz;
        z += n0[r] * lz;
      }
      const A2 cz = xa0 * xb1 - xa1 * xb0;
      row += load(wa + 2 * p) * (z * cz);
      if constexpr (kGradient) {
        const A2 cx = xa1 * xb2 - xa2 * xb1, cy = xa2 * xb0 - xa0 * xb2;
        for (int r = 0; r < WB; ++r) {
          double* t = rowT[r] + p * 6;
          add_to(t + 0, wn0[r] * cx);
          add_to(t + 2, wn0[r] * cy);
          add_to(t + 4, wn0[r] * cz);
        }
      }
    }
    face += w * row;
  }
  if constexpr (kGradient) {
    // dV/dQ(ia, jb) = sign Σ_qa w_a N_a(ia) T[jb][qa], added to the solid's rows.
    for (int jb = 0; jb < nb; ++jb) {
      const double* t = T + static_cast<std::size_t>(jb) * np * 6;
      for (int ia = 0; ia < na; ++ia) {
        const double* dw = &A.dense_w[ia * Qp];
        A2 sx = A2::Zero(), sy = A2::Zero(), sz = A2::Zero();
        for (int qa = A.band_lo[ia]; qa < A.band_hi[ia]; qa += 2) {
          const A2 d = load(dw + qa);
          const double* c = t + qa * 3;  // pair qa / 2
          sx += d * load(c + 0);
          sy += d * load(c + 2);
          sz += d * load(c + 4);
        }
        const int row = face_index(ia, jb);
        (*grad)(row, 0) += sign * sx.sum();
        (*grad)(row, 1) += sign * sy.sum();
        (*grad)(row, 2) += sign * sz.sum();
      }
    }
  }
  return face.sum();
}

// Widths 2..4 (degrees 1..3) get compiled kernels; the rest the generic ones up to
// kMaxBSplineDegree (all supported degrees are covered, so this never fails).
template <bool kGradient, int WA, class Dir, class FaceIndex>
double dispatch_b(const Dir& A, const Dir& B, double* G, double* scratch, double sign,
                  const FaceIndex& fi, Points3* grad) {
  if constexpr (WA > kMaxBSplineDegree + 1) {
    throw_internal("B-spline degree above the supported maximum");
  } else {
    switch (B.width) {
#define FASCICLE_WB(n) \
  case n: return integrate_face<kGradient, WA, n>(A, B, G, scratch, sign, fi, grad);
      FASCICLE_WB(1) FASCICLE_WB(2) FASCICLE_WB(3) FASCICLE_WB(4) FASCICLE_WB(5) FASCICLE_WB(6)
      FASCICLE_WB(7) FASCICLE_WB(8)
#undef FASCICLE_WB
      default: throw_internal("B-spline degree above the supported maximum");
    }
  }
}

template <bool kGradient, class Dir, class FaceIndex>
double dispatch_face(const Dir& A, const Dir& B, double* G, double* scratch, double sign,
                     const FaceIndex& fi, Points3* grad) {
  switch (A.width) {
#define FASCICLE_WA(n) case n: return dispatch_b<kGradient, n>(A, B, G, scratch, sign, fi, grad);
    FASCICLE_WA(1) FASCICLE_WA(2) FASCICLE_WA(3) FASCICLE_WA(4) FASCICLE_WA(5) FASCICLE_WA(6)
    FASCICLE_WA(7) FASCICLE_WA(8)
#undef FASCICLE_WA
    default: throw_internal("B-spline degree above the supported maximum");
  }
}

}  // namespace

template <bool kGradient>
double BoundaryVolumeIntegrator::integrate(const Points3& P, Points3* gradient) const {
  const int n[3] = {basis_[0].num_control, basis_[1].num_control, basis_[2].num_control};
  if (P.rows() != n[0] * n[1] * n[2]) {
    throw_usage(fmt::format("{} control points given for a lattice of {}", P.rows(),
                            n[0] * n[1] * n[2]));
  }
  // Integrate about a boundary control point (index 0 lies on a face of every non-periodic
  // direction), so results do not lose digits far from the origin and do not depend on interior
  // control points even in rounding.
  const double c0[3] = {P(0, 0), P(0, 1), P(0, 2)};
  const auto index = [&](int i, int j, int k) { return i + n[0] * (j + n[1] * k); };
  // scratch, sized for the largest face: G, L (values and derivatives), T (gradient), a weights
  std::size_t need = 0;
  for (int c = 0; c < 3; ++c) {
    const Direction& A = dir_[(c + 1) % 3];
    const Direction& B = dir_[(c + 2) % 3];
    const std::size_t g = 3 * static_cast<std::size_t>(A.num_control) * B.num_control;
    const std::size_t qp = A.num_points + 1;  // padded to even
    const std::size_t l = 3 * static_cast<std::size_t>(B.num_control) * qp;
    need = std::max(need, g + 3 * l + 2 * qp);
  }
  const std::unique_ptr<double[]> scratch(new double[need]);  // uninitialised: every use writes first
  double volume = 0.0;
  for (int c = 0; c < 3; ++c) {
    if (basis_[c].periodic) continue;
    const int a = (c + 1) % 3, b = (c + 2) % 3;
    const Direction& A = dir_[a];
    const Direction& B = dir_[b];
    const int na = A.num_control, nb = B.num_control;
    double* G = scratch.get();  // [q][jb][ia]
    for (int side = 0; side < 2; ++side) {
      const int ic = side == 0 ? 0 : n[c] - 1;
      const double sign = side == 0 ? -1.0 : 1.0;
      // control point of the face at in-plane indices (ia, ib)
      const auto face_index = [&](int ia, int ib) {
        int ijk[3];
        ijk[c] = ic;
        ijk[a] = ia;
        ijk[b] = ib;
        return index(ijk[0], ijk[1], ijk[2]);
      };
      for (int jb = 0; jb < nb; ++jb)
        for (int ia = 0; ia < na; ++ia) {
          const int row = face_index(ia, jb);
          for (int q = 0; q < 3; ++q) G[(q * nb + jb) * na + ia] = P(row, q) - c0[q];
        }
      const double face = dispatch_face<kGradient>(A, B, G, G + 3 * na * nb, sign, face_index,
                                                   gradient);
      volume += sign * face;
    }
  }
  return volume;
}

VolumeAndGradient BoundaryVolumeIntegrator::calc(const Points3& P) const {
  VolumeAndGradient out;
  out.gradient = Points3::Zero(P.rows(), 3);
  out.volume_m3 = integrate<true>(P, &out.gradient);
  return out;
}

double BoundaryVolumeIntegrator::calc_volume(const Points3& P) const {
  return integrate<false>(P, nullptr);
}

double calc_boundary_volume(const BSplineSolid& s) {
  return BoundaryVolumeIntegrator(s).calc_volume(s.P);
}

VolumeAndGradient calc_boundary_volume_and_gradient(const BSplineSolid& s) {
  return BoundaryVolumeIntegrator(s).calc(s.P);
}

Points3 calc_volume_gradient_wrt_spatial_points(const BSplineSolid& s, const Points3& material) {
  const int m = static_cast<int>(material.rows()), n = s.num_control_points();
  if (m < n) {
    throw_bad_input(fmt::format("{} spatial points cannot determine {} control points", m, n),
                    ErrorContext{.object = s.name, .suggestion = "give at least as many points"});
  }
  MatX A = MatX::Zero(m, n);
  for (int r = 0; r < m; ++r) {
    const Vec3 uvw = material.row(r).transpose();
    const BasisValues bu = calc_basis(s.basis[0], uvw[0], 0);
    const BasisValues bv = calc_basis(s.basis[1], uvw[1], 0);
    const BasisValues bw = calc_basis(s.basis[2], uvw[2], 0);
    for (int c = 0; c <= s.basis[2].degree; ++c)
      for (int b = 0; b <= s.basis[1].degree; ++b)
        for (int a = 0; a <= s.basis[0].degree; ++a) {
          A(r, s.index(control_index(s.basis[0], bu.first + a),
                       control_index(s.basis[1], bv.first + b),
                       control_index(s.basis[2], bw.first + c))) +=
              bu.N[0][a] * bv.N[0][b] * bw.N[0][c];
        }
  }
  Eigen::ColPivHouseholderQR<MatX> qr(A);
  if (qr.rank() < n) {
    throw_bad_input("the spatial points do not determine the control points (rank deficient)",
                    ErrorContext{.object = s.name,
                                 .suggestion = "spread the material points over every knot span"});
  }
  // P = A^+ X  =>  dV/dX = A (A^T A)^{-1} dV/dP = (A^+)^T dV/dP
  const MatX G = calc_volume_and_gradient(s).gradient;
  const MatX AtA = A.transpose() * A;
  return A * AtA.ldlt().solve(G);
}

}  // namespace fascicle
