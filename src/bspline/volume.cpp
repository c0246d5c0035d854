// Exact B-spline solid volume and gradient (seed 000 §3.1.1); see volume.hpp for the formulas.
#include "fascicle/bspline/volume.hpp"

#include "fascicle/core/error.hpp"

#include <fmt/format.h>

#include <Eigen/QR>

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
    for (const SpanPoint& sp : make_span_points(basis_[d])) {
      points_[d].push_back({sp.weight, calc_basis(basis_[d], sp.t, 1)});
    }
  }
}

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
  const Vec3 c0 = P.row(0).transpose();
  const auto index = [&](int i, int j, int k) { return i + n[0] * (j + n[1] * k); };
  double volume = 0.0;
  std::vector<Vec3> R0, R1, T;
  for (int c = 0; c < 3; ++c) {
    if (basis_[c].periodic) continue;
    const int a = (c + 1) % 3, b = (c + 2) % 3;
    const BSplineBasis& Ba = basis_[a];
    const BSplineBasis& Bb = basis_[b];
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
      R0.assign(n[b], Vec3::Zero());
      R1.assign(n[b], Vec3::Zero());
      double face = 0.0;
      for (const QuadPoint& qa : points_[a]) {
        // R0_j = sum_i Na_i (Q_ij - c0), R1_j = sum_i Na'_i (Q_ij - c0)
        for (int jb = 0; jb < n[b]; ++jb) {
          Vec3 r0 = Vec3::Zero(), r1 = Vec3::Zero();
          for (int ra = 0; ra <= Ba.degree; ++ra) {
            const Vec3 q = P.row(face_index(control_index(Ba, qa.basis.first + ra), jb))
                               .transpose() - c0;
            r0 += qa.basis.N[0][ra] * q;
            r1 += qa.basis.N[1][ra] * q;
          }
          R0[jb] = r0;
          R1[jb] = r1;
        }
        if constexpr (kGradient) T.assign(n[b], Vec3::Zero());
        double line = 0.0;
        for (const QuadPoint& qb : points_[b]) {
          Vec3 x = Vec3::Zero(), xa = Vec3::Zero(), xb = Vec3::Zero();
          for (int rb = 0; rb <= Bb.degree; ++rb) {
            const int jb = control_index(Bb, qb.basis.first + rb);
            x += qb.basis.N[0][rb] * R0[jb];
            xa += qb.basis.N[0][rb] * R1[jb];
            xb += qb.basis.N[1][rb] * R0[jb];
          }
          const Vec3 nrm = xa.cross(xb);
          line += qb.weight * x.dot(nrm);
          if constexpr (kGradient) {
            for (int rb = 0; rb <= Bb.degree; ++rb) {
              T[control_index(Bb, qb.basis.first + rb)] += (qb.weight * qb.basis.N[0][rb]) * nrm;
            }
          }
        }
        face += qa.weight * line;
        if constexpr (kGradient) {
          for (int ra = 0; ra <= Ba.degree; ++ra) {
            const int ia = control_index(Ba, qa.basis.first + ra);
            const double f = sign * qa.weight * qa.basis.N[0][ra];
            for (int jb = 0; jb < n[b]; ++jb) {
              gradient->row(face_index(ia, jb)) += f * T[jb].transpose();
            }
          }
        }
      }
      volume += sign * face;
    }
  }
  return volume / 3.0;
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
