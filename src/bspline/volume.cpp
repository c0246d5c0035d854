// Exact B-spline solid volume and gradient (seed 000 §3.1.1); see volume.hpp for the formulas.
#include "fascicle/bspline/volume.hpp"

#include "fascicle/core/error.hpp"

#include <fmt/format.h>

#include <Eigen/QR>

#include <algorithm>
#include <memory>
#include <cmath>
#include <limits>
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

JacobianMinimum find_min_jacobian_determinant(const BSplineSolid& s, int points_per_span) {
  std::array<std::vector<SpanPoint>, 3> g;
  for (int d = 0; d < 3; ++d)
    g[d] = calc_span_quadrature(s.basis[d], points_per_span > 0 ? points_per_span : s.basis[d].degree + 1);
  JacobianMinimum out{std::numeric_limits<double>::infinity(), Vec3::Zero()};
  for (const auto& pw : g[2])
    for (const auto& pv : g[1])
      for (const auto& pu : g[0]) {
        const Vec3 uvw(pu.t, pv.t, pw.t);
        const double det = calc_point_and_jacobian(s, uvw).J.determinant();
        if (!(det >= out.det_J)) {  // NaN counts as inverted
          out.det_J = det, out.material = uvw;
          if (std::isnan(det)) return out;
        }
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

namespace {
// __builtin_cpu_init makes the query safe even from static initialisers (idempotent, cheap).
bool cpu_has_avx2() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2");
}
}  // namespace

BoundaryVolumeIntegrator::BoundaryVolumeIntegrator(const BSplineSolid& lattice, bool allow_avx2)
    : basis_(lattice.basis), lanes_(allow_avx2 && cpu_has_avx2() ? 4 : 2) {
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
    D.padded_points = (D.num_points + lanes_ - 1) / lanes_ * lanes_;
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
        D.band_lo[i] = std::min(D.band_lo[i], q / lanes_ * lanes_);
        D.band_hi[i] = std::max(D.band_hi[i], q / lanes_ * lanes_ + lanes_);
      }
    for (int i = 0; i < D.num_control; ++i) D.band_hi[i] = std::max(D.band_hi[i], D.band_lo[i]);
  }
}

namespace {

// SIMD vectors of K doubles (GCC vector extensions: K = 2 is one SSE2 register, K = 4 one AVX
// register in the functions compiled for AVX2). Loads and stores go through memcpy (unaligned).
// Every helper taking or returning a vector is inlined into the kernels, so no vector crosses a
// call and GCC's note about the AVX calling convention (-Wpsabi) does not apply.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wpsabi"
template <int K>
struct Simd {
  typedef double V __attribute__((vector_size(8 * K)));
};
#define FASCICLE_LOAD(V, p) ([](const double* q_) __attribute__((always_inline)) { \
  V v_;                                                                              \
  __builtin_memcpy(&v_, q_, sizeof v_);                                              \
  return v_;                                                                         \
}(p))

// One boundary face of the sum-factorised integral (see BoundaryVolumeIntegrator) for b-width WB
// (degree + 1) known at compile time and K a points per SIMD vector. G[coordinate][b control]
// [a control]: the face's control points minus the reference point. The face term uses the
// divergence theorem with the field (0, 0, z) (∇· = 1): V = Σ_faces ± ∫∫ z (x_a × x_b)_z da db,
// which needs z, x_a and x_b but not x, y. With kGradient, dV/dQ = ∫∫ N n da db (unsigned) needs
// the whole normal n = x_a × x_b, and is written over G (same layout). Returns the face integral.
//
// Layout (a points in blocks of K, p = block): L[b control][p][k][lane], k = 0..2 the
// a-derivative of the coordinates, k = 3..5 their values; T[b control][p][q][lane]. One b
// control's data for a block is contiguous, so the sweep addresses each of the WB rows with one
// pointer. Every lane does the same operations in the same order whatever K is, except the final
// sums over lanes.
template <bool kGradient, int WB, int K, class Dir>
[[gnu::always_inline]] inline double face_kernel(const Dir& A, const Dir& B, double* G,
                                                 double* scratch) {
  typedef typename Simd<K>::V V;
  const auto add_to = [](double* p, const V& v) __attribute__((always_inline)) {
    V t;
    __builtin_memcpy(&t, p, sizeof t);
    t += v;
    __builtin_memcpy(p, &t, sizeof t);
  };
  const int na = A.num_control, nb = B.num_control, Qb = B.num_points;
  const int Qp = A.padded_points;  // a points padded to whole blocks (padding: zero weight)
  const int np = Qp / K;
  const std::size_t lsize = static_cast<std::size_t>(nb) * Qp * 6;
  double* L = scratch;      // nb * Qp * 6
  double* T = L + lsize;    // nb * Qp * 3 (gradient)
  double* wa = T + lsize / 2;  // Qp
  for (int qa = 0; qa < Qp; ++qa) wa[qa] = qa < A.num_points ? A.weight[qa] : 0.0;
  // dense, band-limited contraction along a: L[jb][p] = Σ_ia G[.][jb][ia] (N'_ia, N_ia)(p)
  std::fill(L, L + lsize, 0.0);
  for (int jb = 0; jb < nb; ++jb) {
    double* l = L + static_cast<std::size_t>(jb) * Qp * 6;
    for (int ia = 0; ia < na; ++ia) {
      const V gx = V{} + G[(0 * nb + jb) * na + ia];
      const V gy = V{} + G[(1 * nb + jb) * na + ia];
      const V gz = V{} + G[(2 * nb + jb) * na + ia];
      const double* d0 = &A.dense0[ia * Qp];
      const double* d1 = &A.dense1[ia * Qp];
      for (int qa = A.band_lo[ia]; qa < A.band_hi[ia]; qa += K) {
        double* c = l + qa * 6;  // block qa / K
        const V v1 = FASCICLE_LOAD(V, d1 + qa), v0 = FASCICLE_LOAD(V, d0 + qa);
        add_to(c + 0 * K, gx * v1);
        add_to(c + 1 * K, gy * v1);
        add_to(c + 2 * K, gz * v1);
        add_to(c + 3 * K, gx * v0);
        add_to(c + 4 * K, gy * v0);
        add_to(c + 5 * K, gz * v0);
      }
    }
  }
  if constexpr (kGradient) std::fill(T, T + lsize / 2, 0.0);
  // Sweep the b points; at each (a block, b point): x_a, x_b, z, n = x_a × x_b, the volume term,
  // and (gradient) T[jb][p][q] += w_b N_b(jb) n_q: the b half of ∫∫ N_I n.
  V face = V{};
  for (int qb = 0; qb < Qb; ++qb) {
    const double w = B.weight[qb];
    V n0[WB], n1[WB], wn0[WB];
    const double* rowL[WB];
    double* rowT[WB];
    for (int r = 0; r < WB; ++r) {
      const int jb = B.index[qb * WB + r];
      n0[r] = V{} + B.N0[qb * WB + r];
      n1[r] = V{} + B.N1[qb * WB + r];
      wn0[r] = V{} + w * B.N0[qb * WB + r];
      rowL[r] = L + static_cast<std::size_t>(jb) * Qp * 6;
      rowT[r] = T + static_cast<std::size_t>(jb) * Qp * 3;
    }
    V row = V{};
    for (int p = 0; p < np; ++p) {
      const double* l = rowL[0] + p * 6 * K;
      V xa0 = n0[0] * FASCICLE_LOAD(V, l + 0 * K), xa1 = n0[0] * FASCICLE_LOAD(V, l + 1 * K);
      V xa2 = n0[0] * FASCICLE_LOAD(V, l + 2 * K), xb0 = n1[0] * FASCICLE_LOAD(V, l + 3 * K);
      V xb1 = n1[0] * FASCICLE_LOAD(V, l + 4 * K);
      const V lz0 = FASCICLE_LOAD(V, l + 5 * K);
      V xb2 = n1[0] * lz0, z = n0[0] * lz0;
      for (int r = 1; r < WB; ++r) {
        l = rowL[r] + p * 6 * K;
        xa0 += n0[r] * FASCICLE_LOAD(V, l + 0 * K);
        xa1 += n0[r] * FASCICLE_LOAD(V, l + 1 * K);
        xa2 += n0[r] * FASCICLE_LOAD(V, l + 2 * K);
        xb0 += n1[r] * FASCICLE_LOAD(V, l + 3 * K);
        xb1 += n1[r] * FASCICLE_LOAD(V, l + 4 * K);
        const V lz = FASCICLE_LOAD(V, l + 5 * K);
        xb2 += n1[r] * lz;
        z += n0[r] * lz;
      }
      const V cz = xa0 * xb1 - xa1 * xb0;
      row += FASCICLE_LOAD(V, wa + p * K) * (z * cz);
      if constexpr (kGradient) {
        const V cx = xa1 * xb2 - xa2 * xb1, cy = xa2 * xb0 - xa0 * xb2;
        for (int r = 0; r < WB; ++r) {
          double* t = rowT[r] + p * 3 * K;
          add_to(t + 0 * K, wn0[r] * cx);
          add_to(t + 1 * K, wn0[r] * cy);
          add_to(t + 2 * K, wn0[r] * cz);
        }
      }
    }
    face += w * row;
  }
  if constexpr (kGradient) {
    // dV/dQ(ia, jb) = Σ_qa w_a N_a(ia) T[jb][qa], written over G.
    for (int jb = 0; jb < nb; ++jb) {
      const double* t = T + static_cast<std::size_t>(jb) * Qp * 3;
      for (int ia = 0; ia < na; ++ia) {
        const double* dw = &A.dense_w[ia * Qp];
        V sx = V{}, sy = V{}, sz = V{};
        for (int qa = A.band_lo[ia]; qa < A.band_hi[ia]; qa += K) {
          const V d = FASCICLE_LOAD(V, dw + qa);
          const double* c = t + qa * 3;  // block qa / K
          sx += d * FASCICLE_LOAD(V, c + 0 * K);
          sy += d * FASCICLE_LOAD(V, c + 1 * K);
          sz += d * FASCICLE_LOAD(V, c + 2 * K);
        }
        double s[3] = {0.0, 0.0, 0.0};
        for (int k = 0; k < K; ++k) s[0] += sx[k], s[1] += sy[k], s[2] += sz[k];
        for (int q = 0; q < 3; ++q) G[(q * nb + jb) * na + ia] = s[q];
      }
    }
  }
  double sum = 0.0;
  for (int k = 0; k < K; ++k) sum += face[k];
  return sum;
}
#undef FASCICLE_LOAD
#pragma GCC diagnostic pop

// The kernel for pairs of points (SSE2, the x86-64 baseline) and for blocks of four compiled for
// AVX2 (selected at run time by the integrator; no FMA contraction, so each lane rounds exactly
// as in the SSE2 kernel).
template <bool kGradient, int WB, class Dir>
double face_kernel_sse2(const Dir& A, const Dir& B, double* G, double* scratch) {
  return face_kernel<kGradient, WB, 2>(A, B, G, scratch);
}
template <bool kGradient, int WB, class Dir>
__attribute__((target("avx2"))) double face_kernel_avx2(const Dir& A, const Dir& B, double* G,
                                                        double* scratch) {
  return face_kernel<kGradient, WB, 4>(A, B, G, scratch);
}

// Widths 1..8 (degrees 0..7, every supported degree).
template <bool kGradient, class Dir>
double dispatch_face(const Dir& A, const Dir& B, double* G, double* scratch, int lanes) {
  switch (B.width) {
#define FASCICLE_WB(n)                                                             \
  case n:                                                                          \
    return lanes == 4 ? face_kernel_avx2<kGradient, n>(A, B, G, scratch)           \
                      : face_kernel_sse2<kGradient, n>(A, B, G, scratch);
    FASCICLE_WB(1) FASCICLE_WB(2) FASCICLE_WB(3) FASCICLE_WB(4) FASCICLE_WB(5) FASCICLE_WB(6)
    FASCICLE_WB(7) FASCICLE_WB(8)
#undef FASCICLE_WB
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
    const std::size_t qp = A.padded_points;
    const std::size_t l = 3 * static_cast<std::size_t>(B.num_control) * qp;
    need = std::max(need, g + 3 * l + qp);
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
      const double face = dispatch_face<kGradient>(A, B, G, G + 3 * na * nb, lanes_);
      volume += sign * face;
      if constexpr (kGradient) {
        for (int jb = 0; jb < nb; ++jb)
          for (int ia = 0; ia < na; ++ia) {
            const int row = face_index(ia, jb);
            for (int q = 0; q < 3; ++q) (*gradient)(row, q) += sign * G[(q * nb + jb) * na + ia];
          }
      }
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
