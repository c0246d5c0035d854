// Trivariate B-spline solid evaluation (seed 000 ch. 3).
#include "fascicle/bspline/solid.hpp"

#include "basis_fixed.hpp"

#include "fascicle/core/error.hpp"

#include <fmt/format.h>

#include <Eigen/LU>

#include <cmath>

namespace fascicle {

BSplineSolid make_solid(std::array<BSplineBasis, 3> basis, Points3 P, FibreDirection fibre,
                        std::string name) {
  BSplineSolid s;
  s.basis = std::move(basis);
  s.P = std::move(P);
  s.fibre_direction = fibre;
  s.name = std::move(name);
  validate_solid(s);
  return s;
}

BSplineSolid make_surface_solid(BSplineBasis u, BSplineBasis v, Points3 P) {
  return make_solid({std::move(u), std::move(v), BSplineBasis{}}, std::move(P));
}

BSplineSolid make_curve_solid(BSplineBasis u, Points3 P) {
  return make_solid({std::move(u), BSplineBasis{}, BSplineBasis{}}, std::move(P));
}

void validate_solid(const BSplineSolid& s) {
  static constexpr const char* names[3] = {"knot vector u", "knot vector v", "knot vector w"};
  const std::string who = s.name.empty() ? std::string("B-spline solid") : s.name;
  for (int d = 0; d < 3; ++d) {
    try {
      validate_basis(s.basis[d], names[d]);
    } catch (const Error& e) {
      throw e.with_object(who);
    }
  }
  if (s.P.rows() != s.num_control_points()) {
    throw_bad_input(fmt::format("{} control points given, the lattice {}x{}x{} needs {}",
                                s.P.rows(), s.num_control(0), s.num_control(1), s.num_control(2),
                                s.num_control_points()),
                    ErrorContext{.object = who});
  }
  for (int r = 0; r < s.P.rows(); ++r) {
    if (!s.P.row(r).allFinite()) {
      const int nu = s.num_control(0), nv = s.num_control(1);
      throw_bad_input(fmt::format("control point ({},{},{}) is not finite", r % nu,
                                  (r / nu) % nv, r / (nu * nv)),
                      ErrorContext{.object = who, .suggestion = "fix the control points"});
    }
  }
}

Vec3 wrap_material_point(const BSplineSolid& s, const Vec3& uvw) {
  return {wrap_parameter(s.basis[0], uvw[0]), wrap_parameter(s.basis[1], uvw[1]),
          wrap_parameter(s.basis[2], uvw[2])};
}

namespace {

// Unrolled control index of direction d as a row offset: control_index without the division.
inline int wrap_index(const BSplineBasis& b, int i) {
  return (b.periodic && i >= b.num_control) ? i - b.num_control : i;
}

// Degree-specialised evaluation (degrees PU, PV, PW known at compile time): the 3 bases by the
// fixed-size recurrence, then the (PU+1)(PV+1)(PW+1) block of control points contracted u first
// (control points along u are adjacent in each coordinate column), then v, then w. The value is
// accumulated in the same order with and without the Jacobian, so calc_point and
// calc_point_and_jacobian agree to the last bit.
template <int PU, int PV, int PW, bool kJacobian>
SolidPoint evaluate_fixed(const BSplineSolid& s, const Points3& P, const Vec3& uvw) {
  using bspline_detail::calc_fixed_basis;
  const auto bu = calc_fixed_basis<PU, kJacobian>(s.basis[0], uvw[0]);
  const auto bv = calc_fixed_basis<PV, kJacobian>(s.basis[1], uvw[1]);
  const auto bw = calc_fixed_basis<PW, kJacobian>(s.basis[2], uvw[2]);
  const int nu = s.num_control(0), nuv = nu * s.num_control(1);
  int iu[PU + 1], jv[PV + 1], kw[PW + 1];
  for (int a = 0; a <= PU; ++a) iu[a] = wrap_index(s.basis[0], bu.first + a);
  for (int b = 0; b <= PV; ++b) jv[b] = nu * wrap_index(s.basis[1], bv.first + b);
  for (int c = 0; c <= PW; ++c) kw[c] = nuv * wrap_index(s.basis[2], bw.first + c);
  const Eigen::Index stride = P.rows();
  const double* px = P.data();
  if constexpr (PU == 3) {
    if (iu[3] == iu[0] + 3) {
      // Cubic in u on adjacent rows: the four u-neighbours of each coordinate are two SIMD pairs.
      // Every output accumulates coefficient * control point in pairs; the value uses the same
      // products with and without the Jacobian.
      using A2 = Eigen::Array2d;
      const A2 u0a(bu.N0[0], bu.N0[1]), u0b(bu.N0[2], bu.N0[3]);
      A2 u1a = A2::Zero(), u1b = A2::Zero();
      if constexpr (kJacobian) u1a = A2(bu.N1[0], bu.N1[1]), u1b = A2(bu.N1[2], bu.N1[3]);
      A2 acc[4][3];  // output (x, xu, xv, xw) x coordinate, lane-wise partial sums
      for (auto& o : acc) o[0] = o[1] = o[2] = A2::Zero();
      for (int c = 0; c <= PW; ++c) {
        A2 sv[3] = {A2::Zero(), A2::Zero(), A2::Zero()};
        A2 svu[3] = {A2::Zero(), A2::Zero(), A2::Zero()};
        A2 svv[3] = {A2::Zero(), A2::Zero(), A2::Zero()};
        for (int b = 0; b <= PV; ++b) {
          const double* row = px + jv[b] + kw[c] + iu[0];
          for (int q = 0; q < 3; ++q) {
            const A2 pa = Eigen::Map<const A2>(row + q * stride);
            const A2 pb = Eigen::Map<const A2>(row + q * stride + 2);
            const A2 t0 = u0a * pa + u0b * pb;
            sv[q] += bv.N0[b] * t0;
            if constexpr (kJacobian) {
              svu[q] += bv.N0[b] * (u1a * pa + u1b * pb);
              svv[q] += bv.N1[b] * t0;
            }
          }
        }
        for (int q = 0; q < 3; ++q) {
          acc[0][q] += bw.N0[c] * sv[q];
          if constexpr (kJacobian) {
            acc[1][q] += bw.N0[c] * svu[q];
            acc[2][q] += bw.N0[c] * svv[q];
            acc[3][q] += bw.N1[c] * sv[q];
          }
        }
      }
      const auto total = [&](int o, int q) { return acc[o][q].sum(); };
      SolidPoint out;
      out.x = Vec3(total(0, 0), total(0, 1), total(0, 2));
      if constexpr (kJacobian) {
        for (int d = 0; d < 3; ++d) out.J.col(d) = Vec3(total(d + 1, 0), total(d + 1, 1), total(d + 1, 2));
      }
      return out;
    }
  }
  double x[3] = {}, xu[3] = {}, xv[3] = {}, xw[3] = {};
  for (int c = 0; c <= PW; ++c) {
    double sv[3] = {}, svu[3] = {}, svv[3] = {};
    for (int b = 0; b <= PV; ++b) {
      const double* row = px + jv[b] + kw[c];
      double r0[3] = {}, r1[3] = {};
      for (int a = 0; a <= PU; ++a) {
        for (int q = 0; q < 3; ++q) {
          const double pq = row[iu[a] + q * stride];
          r0[q] += bu.N0[a] * pq;
          if constexpr (kJacobian) r1[q] += bu.N1[a] * pq;
        }
      }
      for (int q = 0; q < 3; ++q) {
        sv[q] += bv.N0[b] * r0[q];
        if constexpr (kJacobian) {
          svu[q] += bv.N0[b] * r1[q];
          svv[q] += bv.N1[b] * r0[q];
        }
      }
    }
    for (int q = 0; q < 3; ++q) {
      x[q] += bw.N0[c] * sv[q];
      if constexpr (kJacobian) {
        xu[q] += bw.N0[c] * svu[q];
        xv[q] += bw.N0[c] * svv[q];
        xw[q] += bw.N1[c] * sv[q];
      }
    }
  }
  SolidPoint out;
  out.x = Vec3(x[0], x[1], x[2]);
  if constexpr (kJacobian) {
    out.J << xu[0], xv[0], xw[0],
             xu[1], xv[1], xw[1],
             xu[2], xv[2], xw[2];
  }
  return out;
}

// Dispatch to a degree-specialised kernel for degrees 2 and 3 in every direction (cubic solids and
// the fitted (2,3,3) muscle lattices); false for other degrees (general path).
template <bool kJacobian, int... Ps>
bool evaluate_specialised(const BSplineSolid& s, const Points3& P, const Vec3& uvw,
                          SolidPoint& out) {
  constexpr int level = sizeof...(Ps);
  if constexpr (level == 3) {
    out = evaluate_fixed<Ps..., kJacobian>(s, P, uvw);
    return true;
  } else {
    switch (s.basis[level].degree) {
      case 2: return evaluate_specialised<kJacobian, Ps..., 2>(s, P, uvw, out);
      case 3: return evaluate_specialised<kJacobian, Ps..., 3>(s, P, uvw, out);
      default: return false;
    }
  }
}

template <bool kJacobian>
SolidPoint evaluate(const BSplineSolid& s, const Points3& P, const Vec3& uvw) {
  SolidPoint fast;
  if (evaluate_specialised<kJacobian>(s, P, uvw, fast)) return fast;
  const int nd = kJacobian ? 1 : 0;
  const BasisValues bu = calc_basis(s.basis[0], uvw[0], nd);
  const BasisValues bv = calc_basis(s.basis[1], uvw[1], nd);
  const BasisValues bw = calc_basis(s.basis[2], uvw[2], nd);
  const int pu = s.basis[0].degree, pv = s.basis[1].degree, pw = s.basis[2].degree;
  const int nu = s.num_control(0), nv = s.num_control(1);
  const double* px = P.data();
  const double* py = px + P.rows();
  const double* pz = py + P.rows();
  // x = sum_k Nw_k sum_j Nv_j sum_i Nu_i P_ijk, with u-derivatives carried along.
  double acc[4][3] = {};  // value, d/du, d/dv, d/dw
  int iu[kMaxBSplineDegree + 1];
  for (int a = 0; a <= pu; ++a) iu[a] = control_index(s.basis[0], bu.first + a);
  for (int c = 0; c <= pw; ++c) {
    const int k = control_index(s.basis[2], bw.first + c);
    double sv[2][3] = {}, svv[3] = {};  // sum over j of (Nv * row), (Nv' * row)
    for (int b = 0; b <= pv; ++b) {
      const int j = control_index(s.basis[1], bv.first + b);
      const int base = nu * (j + nv * k);
      double r0[3] = {}, r1[3] = {};
      for (int a = 0; a <= pu; ++a) {
        const int row = base + iu[a];
        const double x = px[row], y = py[row], z = pz[row];
        const double n0 = bu.N[0][a];
        r0[0] += n0 * x; r0[1] += n0 * y; r0[2] += n0 * z;
        if constexpr (kJacobian) {
          const double n1 = bu.N[1][a];
          r1[0] += n1 * x; r1[1] += n1 * y; r1[2] += n1 * z;
        }
      }
      const double m0 = bv.N[0][b];
      for (int q = 0; q < 3; ++q) sv[0][q] += m0 * r0[q];
      if constexpr (kJacobian) {
        const double m1 = bv.N[1][b];
        for (int q = 0; q < 3; ++q) {
          sv[1][q] += m0 * r1[q];
          svv[q] += m1 * r0[q];
        }
      }
    }
    const double w0 = bw.N[0][c];
    for (int q = 0; q < 3; ++q) acc[0][q] += w0 * sv[0][q];
    if constexpr (kJacobian) {
      const double w1 = bw.N[1][c];
      for (int q = 0; q < 3; ++q) {
        acc[1][q] += w0 * sv[1][q];
        acc[2][q] += w0 * svv[q];
        acc[3][q] += w1 * sv[0][q];
      }
    }
  }
  SolidPoint out;
  out.x = Vec3(acc[0][0], acc[0][1], acc[0][2]);
  if constexpr (kJacobian) {
    for (int d = 0; d < 3; ++d) out.J.col(d) = Vec3(acc[d + 1][0], acc[d + 1][1], acc[d + 1][2]);
  }
  return out;
}

}  // namespace

Vec3 calc_point(const BSplineSolid& s, const Vec3& uvw) { return evaluate<false>(s, s.P, uvw).x; }

SolidPoint calc_point_and_jacobian(const BSplineSolid& s, const Vec3& uvw) {
  return evaluate<true>(s, s.P, uvw);
}

SolidPoint calc_point_and_jacobian(const BSplineSolid& s, const Points3& P, const Vec3& uvw) {
  if (P.rows() != s.num_control_points()) {
    throw_usage(fmt::format("{} control points given for a lattice of {}", P.rows(),
                            s.num_control_points()));
  }
  return evaluate<true>(s, P, uvw);
}

Mat3 calc_deformation_gradient(const BSplineSolid& s, const Points3& rest, const Points3& current,
                               const Vec3& uvw) {
  const Mat3 J0 = calc_point_and_jacobian(s, rest, uvw).J;
  const Mat3 J1 = calc_point_and_jacobian(s, current, uvw).J;
  Eigen::FullPivLU<Mat3> lu(J0);
  if (!lu.isInvertible()) {
    throw_numerical(fmt::format("the rest Jacobian is singular at material point ({}, {}, {})",
                                uvw[0], uvw[1], uvw[2]),
                    ErrorContext{.object = s.name,
                                 .suggestion = "evaluate away from collapsed axes or poles"});
  }
  return J1 * lu.inverse();
}

}  // namespace fascicle
