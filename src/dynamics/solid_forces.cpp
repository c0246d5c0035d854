// Potential forces of the solid and their stiffness (seed 000 §4.4–4.7): hyperelastic ground
// substance and fibres by quadrature, springs, gravity, volume penalty, plane contact.
#include "fascicle/bspline/volume.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/musculotendon/curves.hpp"
#include "internal.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstring>

namespace fascicle {
namespace dynamics_detail {

Mat3 calc_deformation_gradient(const Points3& P, const int* idx, const Vec3* g, int count) {
  // F = Σ_a P_a g_aᵀ, reading the column-major #P x 3 storage directly.
  const Eigen::Index n = P.rows();
  const double* px = P.data();
  const double* py = px + n;
  const double* pz = py + n;
  Mat3 F = Mat3::Zero();
  for (int a = 0; a < count; ++a) {
    const int i = idx[a];
    const Vec3 x(px[i], py[i], pz[i]);
    F.col(0) += g[a][0] * x;
    F.col(1) += g[a][1] * x;
    F.col(2) += g[a][2] * x;
  }
  return F;
}

Eigen::SparseMatrix<double> make_pattern_matrix(const SolidDynamicsModel& m) {
  const int n = static_cast<int>(m.block_ptr.size()) - 1;
  Eigen::SparseMatrix<double> K(3 * n, 3 * n);
  const int nnz = 9 * m.block_ptr[n];
  K.resizeNonZeros(nnz);
  int* outer = K.outerIndexPtr();
  int* inner = K.innerIndexPtr();
  for (int J = 0; J < n; ++J) {
    const int deg = m.block_ptr[J + 1] - m.block_ptr[J];
    for (int c = 0; c < 3; ++c) {
      const int start = 9 * m.block_ptr[J] + 3 * c * deg;
      outer[3 * J + c] = start;
      for (int k = 0; k < deg; ++k)
        for (int r = 0; r < 3; ++r) inner[start + 3 * k + r] = 3 * m.block_row[m.block_ptr[J] + k] + r;
    }
  }
  outer[3 * n] = nnz;
  K.coeffs().setZero();
  return K;
}

int find_block(const SolidDynamicsModel& m, int I, int J) {
  const auto b = m.block_row.begin() + m.block_ptr[J], e = m.block_row.begin() + m.block_ptr[J + 1];
  const auto it = std::lower_bound(b, e, I);
  if (it == e || *it != I) throw_internal(fmt::format("no block ({}, {}) in the pattern", I, J));
  return static_cast<int>(it - m.block_row.begin());
}

Transform get_body_pose(const std::vector<Transform>& X, int b) {
  if (b < 0 || X.empty()) return Transform::Identity();
  if (b >= static_cast<int>(X.size()))
    throw_bad_input(fmt::format("solid dynamics: body {} has no pose ({} given)", b, X.size()),
                    {.suggestion = "pass one X_now_rest per body referenced by the attachments"});
  return X[b];
}

double calc_volume_and_flat_gradient(const SolidDynamicsModel& m, const Points3& P, VecX* grad) {
  VolumeAndGradient vg;
  if (m.volume_integrator) {
    if (!grad) return m.volume_integrator->calc_volume(P);
    vg = m.volume_integrator->calc(P);
  } else {
    BSplineSolid s = m.rest;
    s.P = P;
    vg = calc_volume_and_gradient(s);
  }
  if (grad) *grad = flatten_points(vg.gradient);
  return vg.volume_m3;
}

namespace {

// Stress and energy density of all material terms at one quadrature point.
// The force–velocity factor: fixed, or implicit in the step from the fibre stretch rate
// (λ(F) − λ_n)/h (so that its viscous effect enters the tangent). Clamped to [0, 1.8].
struct ForceVelocity {
  double fixed = 1.0;
  bool implicit = false;
  double lambda_n = 1.0, inv_h_vmax = 0.0;
  double calc(const Mat3& F, const Vec3& a0) const {
    if (!implicit) return fixed;
    const double v = ((F * a0).norm() - lambda_n) * inv_h_vmax;
    return std::clamp(degroote_force_velocity(v).value, 0.0, 1.8);
  }
  // f_v and ∂f_v/∂λ at fibre stretch λ (0 when fixed or clamped).
  CurvePoint calc_with_slope(double lambda) const {
    if (!implicit) return {fixed, 0.0};
    const CurvePoint c = degroote_force_velocity((lambda - lambda_n) * inv_h_vmax);
    if (c.value < 0.0) return {0.0, 0.0};
    if (c.value > 1.8) return {1.8, 0.0};
    return {c.value, c.derivative * inv_h_vmax};
  }
};

// The ground substance at a quadrature point: tendon regions are stiffer by a factor.
MooneyRivlinParameters get_ground_material(const SolidDynamicsSpec& s, const QuadraturePoint& q) {
  MooneyRivlinParameters g = s.ground;
  if (q.tendon) {
    g.c1_Pa *= s.tendon_stiffness_factor;
    g.c2_Pa *= s.tendon_stiffness_factor;
  }
  return g;
}

StressAndEnergy calc_material(const SolidDynamicsSpec& s, const QuadraturePoint& q, const Mat3& F,
                              double activation, const ForceVelocity& fvm) {
  StressAndEnergy out;
  const double fv = (activation > 0.0 && !q.tendon) ? fvm.calc(F, q.fibre_rest) : 1.0;
  if (s.hyperelastic) {
    out = calc_mooney_rivlin(get_ground_material(s, q), F);
    const StressAndEnergy fib = q.tendon ? calc_tendon_fibre(s.tendon_modulus_Pa, F, q.fibre_rest)
                                         : calc_blemker_fibre(s.fibre, F, q.fibre_rest,
                                                              activation, fv);
    out.energy_density_Pa += fib.energy_density_Pa;
    out.active_density_Pa = fib.active_density_Pa;
    out.P += fib.P;
  } else if (!q.tendon && activation > 0.0) {
    // Contraction without a hyperelastic potential: the active fibre stress alone.
    BlemkerFibreParameters f = s.fibre;
    const Vec3 Fa = F * q.fibre_rest;
    const double l = Fa.norm();
    const double dWdl = f.sigma_max_Pa / f.lambda_opt * activation * calc_blemker_active(f, l) * fv;
    out.P = (dWdl / l) * Fa * q.fibre_rest.transpose();
    out.active_density_Pa = f.sigma_max_Pa * activation * fv * calc_blemker_active_integral(f, l);
  }
  return out;
}

// Analytic ∂P/∂F of calc_material (same branches): Mooney–Rivlin in closed form, the fibre laws
// through φ = ∂W/∂λ and φ' (with the implicit force–velocity factor's slope).
Mat9 calc_material_tangent(const SolidDynamicsSpec& s, const QuadraturePoint& q, const Mat3& F,
                           double activation, const ForceVelocity& fvm) {
  Mat9 D = Mat9::Zero();
  const double lambda = (F * q.fibre_rest).norm();
  const BlemkerFibreParameters& f = s.fibre;
  const double scale = f.sigma_max_Pa / f.lambda_opt;
  auto add_active = [&](double& phi, double& dphi) {
    if (q.tendon || !(activation > 0.0)) return;
    const CurvePoint fv = fvm.calc_with_slope(lambda);
    const double fa = calc_blemker_active(f, lambda);
    phi += scale * activation * fa * fv.value;
    dphi += scale * activation * (calc_blemker_active_slope(f, lambda) * fv.value + fa * fv.derivative);
  };
  double phi = 0.0, dphi = 0.0;
  if (s.hyperelastic) {
    D = calc_mooney_rivlin_tangent(get_ground_material(s, q), F);
    if (q.tendon) {
      if (lambda > 1.0) {
        phi = s.tendon_modulus_Pa * (lambda - 1.0);
        dphi = s.tendon_modulus_Pa;
      }
    } else {
      phi = scale * calc_blemker_passive(f, lambda);
      dphi = scale * calc_blemker_passive_slope(f, lambda);
      add_active(phi, dphi);
    }
  } else {
    add_active(phi, dphi);
  }
  if (phi != 0.0 || dphi != 0.0) add_fibre_tangent(F, q.fibre_rest, phi, dphi, D);
  return D;
}

// Dense accumulation of one quadrature point's stiffness over its span's support (c points):
//   K_ab(i, k) += w Σ_jl g_a[j] ∂P_ij/∂F_kl g_b[l],
// stored Kl[((b·3 + k)·3 + i)·ld + a] so that the innermost loop runs over a, contiguous in both
// Kl and the g columns (gcols[j·c + a] = g_a[j]), and vectorises. With an increasing support
// only a >= b is formed (the lower blocks). D: ∂P/∂F, 9 x 9 column-major (see materials.hpp).
// ld: the padded length (a multiple of 4, >= c) of the g columns (zero beyond c) and of Kl's
// columns, so that every a-loop runs whole vectors from a multiple of 4 (the entries a < b and
// a >= c it also forms are never scattered; every formed entry sums in the same order as before).
[[gnu::always_inline]] inline void accumulate_tangent_body(const double* gcols, int c, int ld,
                                                           const double* D, double w,
                                                           bool lower_only, double* Kl) {
  const double* g0 = gcols;
  const double* g1 = gcols + ld;
  const double* g2 = gcols + 2 * ld;
  for (int b = 0; b < c; ++b) {
    const double wb0 = w * g0[b], wb1 = w * g1[b], wb2 = w * g2[b];
    double* dst_b = Kl + static_cast<std::ptrdiff_t>(9) * ld * b;
    const int a0 = lower_only ? (b & ~3) : 0;
    for (int k = 0; k < 3; ++k)
      for (int i = 0; i < 3; ++i) {
        // T_b(i + 3 j, k) = w Σ_l D(i + 3 j, k + 3 l) g_b[l]
        double t[3];
        for (int j = 0; j < 3; ++j) {
          const int r = i + 3 * j;
          t[j] = D[r + 9 * k] * wb0 + D[r + 9 * (k + 3)] * wb1 + D[r + 9 * (k + 6)] * wb2;
        }
        double* dst = dst_b + static_cast<std::ptrdiff_t>(3 * k + i) * ld;
        const double t0 = t[0], t1 = t[1], t2 = t[2];
        for (int a = a0; a < ld; ++a) dst[a] += g0[a] * t0 + g1[a] * t1 + g2[a] * t2;
      }
  }
}

// The AVX2 kernels are compiled without FMA (no contraction of a*b + c), so every lane rounds as
// the generic code does: forces and tangents are the same bits on every x86-64 machine.
bool cpu_has_avx2() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2");
}

// F of every point of a span: Fs[r ncol + col] = Σ_a p_r[a] Gt[a ncol + col] (p_r: the span's
// gathered control-point coordinates r; Gt: the span's g matrix transposed, ncol = 3 × points;
// F_rj at point i is Fs[r ncol + 3 i + j]). The sum runs over a in support order with separate
// multiply and add (AVX without FMA, or SSE2), vectorised across the columns, so that F is
// bitwise the per-point sum Σ_a P_a g_aᵀ: the fibre laws have a kink at λ = 1 that a rest or
// rigidly moved solid sits on, and their tangent must not depend on the rounding there.
[[gnu::always_inline]] inline void span_gradients_body(const double* Gt, int c, int ncol,
                                                       const double* p0, const double* p1,
                                                       const double* p2, double* __restrict Fs) {
  double* __restrict f0 = Fs;
  double* __restrict f1 = Fs + ncol;
  double* __restrict f2 = Fs + 2 * ncol;
  for (int col = 0; col < ncol; ++col) f0[col] = f1[col] = f2[col] = 0.0;
  for (int a = 0; a < c; ++a) {
    const double x0 = p0[a], x1 = p1[a], x2 = p2[a];
    const double* __restrict g = Gt + static_cast<std::ptrdiff_t>(a) * ncol;
    for (int col = 0; col < ncol; ++col) f0[col] += g[col] * x0;
    for (int col = 0; col < ncol; ++col) f1[col] += g[col] * x1;
    for (int col = 0; col < ncol; ++col) f2[col] += g[col] * x2;
  }
}
__attribute__((target("avx"))) void span_gradients_avx(const double* Gt, int c, int ncol,
                                                        const double* p0, const double* p1,
                                                        const double* p2, double* Fs) {
  span_gradients_body(Gt, c, ncol, p0, p1, p2, Fs);
}
void span_gradients_generic(const double* Gt, int c, int ncol, const double* p0, const double* p1,
                            const double* p2, double* Fs) {
  span_gradients_body(Gt, c, ncol, p0, p1, p2, Fs);
}
bool cpu_has_avx() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx");
}
// F of point i of the span from calc_span_gradients' layout.
Mat3 get_span_gradient(const std::vector<double>& Fs, int ncol, int i) {
  Mat3 F;
  for (int r = 0; r < 3; ++r)
    for (int j = 0; j < 3; ++j) F(r, j) = Fs[static_cast<std::size_t>(r) * ncol + 3 * i + j];
  return F;
}
// Span forces: f_r[a] += Σ_col G[col c + a] S[3 col + r] (S: w P of each point, 3 x ncol).
[[gnu::always_inline]] inline void span_forces_body(const double* G, int c, int ncol,
                                                    const double* S, double* __restrict f0,
                                                    double* __restrict f1, double* __restrict f2) {
  for (int col = 0; col < ncol; ++col) {
    const double* __restrict g = G + static_cast<std::ptrdiff_t>(col) * c;
    const double s0 = S[3 * col], s1 = S[3 * col + 1], s2 = S[3 * col + 2];
    for (int a = 0; a < c; ++a) {
      f0[a] += g[a] * s0;
      f1[a] += g[a] * s1;
      f2[a] += g[a] * s2;
    }
  }
}
__attribute__((target("avx2"))) void span_forces_avx2(const double* G, int c, int ncol,
                                                           const double* S, double* f0, double* f1,
                                                           double* f2) {
  span_forces_body(G, c, ncol, S, f0, f1, f2);
}
void span_forces_generic(const double* G, int c, int ncol, const double* S, double* f0, double* f1,
                         double* f2) {
  span_forces_body(G, c, ncol, S, f0, f1, f2);
}

__attribute__((target("avx2"))) void accumulate_tangent_avx2(const double* gcols, int c, int ld,
                                                                  const double* D, double w,
                                                                  bool lower_only, double* Kl) {
  accumulate_tangent_body(gcols, c, ld, D, w, lower_only, Kl);
}

void accumulate_tangent_generic(const double* gcols, int c, int ld, const double* D, double w,
                                bool lower_only, double* Kl) {
  accumulate_tangent_body(gcols, c, ld, D, w, lower_only, Kl);
}




// Gathers the span's control points of P (column-major #P x 3) into sc.p0..p2 and computes F of
// its points into sc.Fs (3 x 3m, column-major: F of point i is columns 3 i .. 3 i + 2).
void calc_span_gradients(const SolidDynamicsModel& m, const Points3& P, int k, SpanScratch& sc) {
  const Eigen::MatrixXd& Gt = m.group_gt[k];
  const int c = static_cast<int>(Gt.cols()), ncol = static_cast<int>(Gt.rows());
  const int* idx = &m.support_index[m.quadrature[m.group_points[m.group_ptr[k]]].first];
  const Eigen::Index n = P.rows();
  const double* px = P.data();
  sc.p0.resize(c);
  sc.p1.resize(c);
  sc.p2.resize(c);
  for (int a = 0; a < c; ++a) {
    sc.p0[a] = px[idx[a]];
    sc.p1[a] = px[n + idx[a]];
    sc.p2[a] = px[2 * n + idx[a]];
  }
  sc.Fs.resize(static_cast<std::size_t>(3) * ncol);
  (cpu_has_avx() ? span_gradients_avx : span_gradients_generic)(
      Gt.data(), c, ncol, sc.p0.data(), sc.p1.data(), sc.p2.data(), sc.Fs.data());
}

[[noreturn]] void throw_inverted(const SolidDynamicsModel& m, const QuadraturePoint& q, double J) {
  throw_numerical(
      fmt::format("solid '{}' inverted at material point ({:.4f}, {:.4f}, {:.4f}): det F = {:.3e}",
                  m.rest.name, q.material[0], q.material[1], q.material[2], J),
      {.object = m.rest.name,
       .suggestion = "reduce the time step, raise the ground-substance stiffness or check the "
                     "attachments' motion near that material location"});
}

}  // namespace

std::vector<double> calc_fibre_stretches(const SolidDynamicsModel& m, const Points3& P) {
  std::vector<double> out(m.quadrature.size(), 1.0);
  SpanScratch sc;
  for (int k = 0; k < static_cast<int>(m.group_g.size()); ++k) {
    calc_span_gradients(m, P, k, sc);
    for (int i = 0; i < m.group_ptr[k + 1] - m.group_ptr[k]; ++i) {
      const int qi = m.group_points[m.group_ptr[k] + i];
      out[qi] = (get_span_gradient(sc.Fs, 3 * (m.group_ptr[k + 1] - m.group_ptr[k]), i) *
                 m.quadrature[qi].fibre_rest).norm();
    }
  }
  return out;
}

void calc_forces_into(const SolidDynamicsModel& m, const Points3& P, const Points3& V,
                      double activation, bool with_stiffness, const std::vector<Transform>& X,
                      ForceEvaluation& out, double volume_hessian_scale,
                      const std::vector<double>* lambda_start, double step_h,
                      ForceScratch* scratch) {
  const int n = static_cast<int>(P.rows());
  const SolidDynamicsSpec& s = m.spec;
  out.force.setZero(3 * n);
  out.energy_J = 0.0;
  out.active_energy_J = 0.0;
  if (with_stiffness) {
    if (out.stiffness.nonZeros() != 9 * m.block_ptr[n] || out.stiffness.rows() != 3 * n)
      out.stiffness = make_pattern_matrix(m);
    else
      out.stiffness.coeffs().setZero();
  }
  double* K = with_stiffness ? out.stiffness.valuePtr() : nullptr;

  // Gravity: generalised force ρ ∫ N_I g dX = m_I g (lumped row sums, exact).
  for (int i = 0; i < n; ++i) {
    out.force.segment<3>(3 * i) += m.lumped_mass[i] * s.gravity_m_s2;
    out.energy_J -= m.lumped_mass[i] * s.gravity_m_s2.dot(P.row(i).transpose());
  }

  // Material terms by quadrature, one knot span (group of points with one support) at a time:
  // the span's control points are gathered once, F of all its points is one product with the
  // span's g matrix, the forces one product back, and the stiffness is accumulated densely over
  // the span and scattered into the pattern once per span (docs/solid-dynamics.md, Performance).
  const bool any_material = s.hyperelastic || activation > 0.0 ||
                            (with_stiffness && volume_hessian_scale != 0.0);
  const double vmax = s.max_fibre_strain_rate_1_s * s.fibre.lambda_opt;
  const int ngroups = static_cast<int>(m.group_g.size());
  ForceScratch local_scratch;
  ForceScratch& fsc = scratch ? *scratch : local_scratch;
  SpanScratch& sc = fsc.span;
  SpanScratch& scv = fsc.velocity;
  const bool avx2 = cpu_has_avx2();
  for (int k = 0; any_material && k < ngroups; ++k) {
    const Eigen::MatrixXd& G = m.group_g[k];
    const int gp0 = m.group_ptr[k], npts = m.group_ptr[k + 1] - gp0;
    const QuadraturePoint& q0 = m.quadrature[m.group_points[gp0]];
    const int c = q0.count;
    const int* idx = &m.support_index[q0.first];
    calc_span_gradients(m, P, k, sc);
    const bool need_fdot = !(lambda_start && step_h > 0.0) && V.rows() == n && activation > 0.0;
    if (need_fdot) calc_span_gradients(m, V, k, scv);
    sc.S.resize(static_cast<std::size_t>(9) * npts);
    const int ld = (c + 3) & ~3;  // padded support length for the tangent kernel
    if (K) {
      sc.Kl.assign(static_cast<std::size_t>(9) * c * ld, 0.0);
      sc.gp.assign(static_cast<std::size_t>(3) * ld, 0.0);
    }
    for (int i = 0; i < npts; ++i) {
      const int qi = m.group_points[gp0 + i];
      const QuadraturePoint& q = m.quadrature[qi];
      const Mat3 F = get_span_gradient(sc.Fs, 3 * npts, i);
      const double J = F.determinant();
      if (!(J > 0.0)) throw_inverted(m, q, J);
      ForceVelocity fv;
      if (lambda_start && step_h > 0.0 && !q.tendon && activation > 0.0) {
        fv.implicit = true;
        fv.lambda_n = (*lambda_start)[qi];
        fv.inv_h_vmax = 1.0 / (step_h * vmax);
      } else if (need_fdot && !q.tendon) {
        const Mat3 Fdot = get_span_gradient(scv.Fs, 3 * npts, i);
        const Vec3 Fa = F * q.fibre_rest;
        const double ldot = Fa.dot(Fdot * q.fibre_rest) / Fa.norm();
        fv.fixed = std::clamp(degroote_force_velocity(ldot / vmax).value, 0.0, 1.8);
      }
      const StressAndEnergy se = calc_material(s, q, F, activation, fv);
      out.energy_J += q.weight_m3 * se.energy_density_Pa;
      out.active_energy_J += q.weight_m3 * se.active_density_Pa;
      Eigen::Map<Mat3>(sc.S.data() + 9 * i) = q.weight_m3 * se.P;
      if (!K) continue;
      // Tangent ∂P/∂F, analytic (with the implicit fv: its viscous part too).
      Mat9 D = calc_material_tangent(s, q, F, activation, fv);
      // Volume curvature: ∂cof(F)_ai/∂F_kl = ε_akc ε_ilm F_cm (det F = the volume density).
      if (volume_hessian_scale != 0.0) {
        auto eps = [](int a, int b, int c) { return static_cast<double>((a - b) * (b - c) * (c - a)) / 2.0; };
        for (int l = 0; l < 3; ++l)
          for (int kk = 0; kk < 3; ++kk)
            for (int a2 = 0; a2 < 3; ++a2)
              for (int ii = 0; ii < 3; ++ii) {
                double v = 0.0;
                for (int cc = 0; cc < 3; ++cc)
                  for (int mm = 0; mm < 3; ++mm) v += eps(a2, kk, cc) * eps(ii, l, mm) * F(cc, mm);
                D(a2 + 3 * ii, kk + 3 * l) += volume_hessian_scale * v;
              }
      }
      const double* gcols = G.data() + static_cast<std::ptrdiff_t>(3 * i) * c;
      for (int j = 0; j < 3; ++j)
        std::copy(gcols + j * c, gcols + (j + 1) * c, sc.gp.data() + static_cast<std::ptrdiff_t>(j) * ld);
      (avx2 ? accumulate_tangent_avx2 : accumulate_tangent_generic)(
          sc.gp.data(), c, ld, D.data(), q.weight_m3, m.group_ascending[k] != 0, sc.Kl.data());
    }
    // f_a = −Σ_q w_q P_q g_qa for the whole span.
    sc.f0.assign(c, 0.0);
    sc.f1.assign(c, 0.0);
    sc.f2.assign(c, 0.0);
    (avx2 ? span_forces_avx2 : span_forces_generic)(G.data(), c, 3 * npts, sc.S.data(),
                                                    sc.f0.data(), sc.f1.data(), sc.f2.data());
    double* fo = out.force.data();
    for (int a = 0; a < c; ++a) {
      fo[3 * idx[a]] -= sc.f0[a];
      fo[3 * idx[a] + 1] -= sc.f1[a];
      fo[3 * idx[a] + 2] -= sc.f2[a];
    }
    if (!K) continue;
    // Scatter the span's lower blocks (I >= J) into the pattern.
    for (int p = m.pair_first[m.group_points[gp0]]; p < m.pair_first[m.group_points[gp0] + 1]; ++p) {
      const auto& pr = m.pairs[p];
      const int Jn = idx[pr.b];
      const int deg = m.block_ptr[Jn + 1] - m.block_ptr[Jn];
      double* dst = K + find_value_position(m, Jn, pr.block, 0, 0);
      const double* src = sc.Kl.data() + static_cast<std::size_t>(9) * ld * pr.b + pr.a;
      for (int kk = 0; kk < 3; ++kk, dst += 3 * deg) {
        dst[0] += src[(3 * kk + 0) * ld];
        dst[1] += src[(3 * kk + 1) * ld];
        dst[2] += src[(3 * kk + 2) * ld];
      }
    }
  }

  // Springs in material coordinates: E = k/2 (|d| − L)^2.
  for (const auto& sp : m.springs) {
    const Vec3 d = (P.row(sp.b) - P.row(sp.a)).transpose();
    const double L = d.norm();
    if (!(L > 0.0)) continue;
    const Vec3 u = d / L;
    const double ext = L - sp.rest_length_m;
    out.energy_J += 0.5 * sp.stiffness_N_m * ext * ext;
    out.force.segment<3>(3 * sp.a) += sp.stiffness_N_m * ext * u;
    out.force.segment<3>(3 * sp.b) -= sp.stiffness_N_m * ext * u;
    if (!K) continue;
    // Hessian block, with the geometric term clamped at >= 0 so it stays positive semi-definite.
    const Mat3 Kb = sp.stiffness_N_m *
                    (std::max(0.0, 1.0 - sp.rest_length_m / L) * Mat3::Identity() +
                     std::min(1.0, sp.rest_length_m / L) * u * u.transpose());
    const int hi = std::max(sp.a, sp.b), lo = std::min(sp.a, sp.b);
    const int bd_hi = find_block(m, hi, hi), bd_lo = find_block(m, lo, lo), off = find_block(m, hi, lo);
    for (int c = 0; c < 3; ++c)
      for (int r = 0; r < 3; ++r) {
        K[find_value_position(m, hi, bd_hi, r, c)] += Kb(r, c);
        K[find_value_position(m, lo, bd_lo, r, c)] += Kb(r, c);
        K[find_value_position(m, lo, off, r, c)] -= Kb(r, c);
      }
  }

  // Volume (exact gradient from the bspline module) and its penalty.
  const bool need_gradient = s.volume != VolumeMethod::none;
  out.volume_m3 = calc_volume_and_flat_gradient(m, P, need_gradient ? &out.volume_gradient : nullptr);
  if (s.volume == VolumeMethod::penalty) {
    const double e = out.volume_m3 - m.rest_volume_m3;
    out.energy_J += 0.5 * s.volume_stiffness_Pa * e * e / m.rest_volume_m3;
    out.force -= (s.volume_stiffness_Pa * e / m.rest_volume_m3) * out.volume_gradient;
  }

  // Point-on-plane contact (one-sided, push only) at the boundary samples: planes, and bone
  // meshes through the tangent plane at the closest point.
  const double k = m.contact_stiffness_N_m;
  for (const ActiveContact& c : find_active_contacts(m, P, X)) {
    const auto& cs = m.contact_samples[c.sample];
    out.energy_J += 0.5 * k * c.depth * c.depth;
    for (std::size_t a = 0; a < cs.index.size(); ++a)
      out.force.segment<3>(3 * cs.index[a]) += k * c.depth * cs.N[a] * c.normal;
    if (!K) continue;
    const Mat3 nn = k * c.normal * c.normal.transpose();
    for (std::size_t a = 0; a < cs.index.size(); ++a)
      for (std::size_t b = 0; b < cs.index.size(); ++b) {
        const int I = cs.index[a], Jn = cs.index[b];
        if (I < Jn) continue;
        const int blk = find_block(m, I, Jn);
        for (int cc = 0; cc < 3; ++cc)
          for (int r = 0; r < 3; ++r)
            K[find_value_position(m, Jn, blk, r, cc)] += cs.N[a] * cs.N[b] * nn(r, cc);
      }
  }
}

std::vector<ActiveContact> find_active_contacts(const SolidDynamicsModel& m, const Points3& P,
                                                const std::vector<Transform>& X) {
  std::vector<ActiveContact> out;
  if (m.contact_samples.empty()) return out;
  std::vector<Vec3> x(m.contact_samples.size(), Vec3::Zero());
  for (std::size_t s = 0; s < x.size(); ++s) {
    const auto& cs = m.contact_samples[s];
    for (std::size_t a = 0; a < cs.index.size(); ++a) x[s] += cs.N[a] * P.row(cs.index[a]).transpose();
  }
  for (const auto& plane : m.spec.contact_planes) {
    const Transform X_b = get_body_pose(X, plane.body);
    const Vec3 p0 = X_b * plane.point_rest;
    const Vec3 nrm = (X_b.linear() * plane.normal_rest).normalized();
    for (std::size_t s = 0; s < x.size(); ++s) {
      const double gap = nrm.dot(x[s] - p0);
      if (gap < 0.0) out.push_back({static_cast<int>(s), nrm, -gap});
    }
  }
  for (std::size_t b = 0; b < m.bone_queries.size(); ++b) {
    const MeshQuery& q = *m.bone_queries[b];
    const Transform X_b = get_body_pose(X, m.spec.contact_bones[b].body);
    const Transform X_rest_now = X_b.inverse();
    const Vec3 lo = q.get_mesh().V.colwise().minCoeff(), hi = q.get_mesh().V.colwise().maxCoeff();
    const std::vector<double>& rest_depth = m.bone_rest_depth[b];
    for (std::size_t s = 0; s < x.size(); ++s) {
      const Vec3 p = X_rest_now * x[s];  // in the bone's rest frame
      if ((p.array() < lo.array()).any() || (p.array() > hi.array()).any()) continue;
      if (!q.calc_is_inside(p)) continue;
      const ClosestPoint c = q.calc_closest_point(p);
      const Vec3 d = c.point - p;
      const double full = d.norm();
      // Only the penetration beyond the rest contact is pushed back.
      const double depth = full - rest_depth[s];
      if (!(depth > 0.0)) continue;
      out.push_back({static_cast<int>(s), X_b.linear() * (d / full), depth});
    }
  }
  return out;
}

}  // namespace dynamics_detail

ForceEvaluation calc_forces(const SolidDynamicsModel& model, const Points3& P, const Points3& V,
                            double activation, bool with_stiffness,
                            const std::vector<Transform>& X_now_rest) {
  ForceEvaluation out;
  dynamics_detail::calc_forces_into(model, P, V, activation, with_stiffness, X_now_rest, out);
  return out;
}

VecX calc_internal_forces(const SolidDynamicsModel& m, const Points3& P, double activation) {
  VecX f = VecX::Zero(3 * P.rows());
  for (const QuadraturePoint& q : m.quadrature) {
    const int* idx = &m.support_index[q.first];
    const Vec3* g = &m.support_g[q.first];
    Mat3 F = Mat3::Zero();
    for (int a = 0; a < q.count; ++a) F += P.row(idx[a]).transpose() * g[a].transpose();
    const SolidDynamicsSpec& s = m.spec;
    StressAndEnergy se;
    if (s.hyperelastic) {
      MooneyRivlinParameters gr = s.ground;
      if (q.tendon) gr.c1_Pa *= s.tendon_stiffness_factor, gr.c2_Pa *= s.tendon_stiffness_factor;
      se = calc_mooney_rivlin(gr, F);
    }
    if (!q.tendon) se.P += calc_blemker_fibre(s.fibre, F, q.fibre_rest, activation, 1.0).P;
    for (int a = 0; a < q.count; ++a) f.segment<3>(3 * idx[a]) -= q.weight_m3 * (se.P * g[a]);
  }
  return f;
}

std::optional<Vec3> find_inverted_point(const SolidDynamicsModel& m, const Points3& P) {
  for (const QuadraturePoint& q : m.quadrature) {
    Mat3 F = Mat3::Zero();
    for (int a = 0; a < q.count; ++a)
      F += P.row(m.support_index[q.first + a]).transpose() * m.support_g[q.first + a].transpose();
    if (!(F.determinant() > 0.0)) return q.material;
  }
  return std::nullopt;
}

}  // namespace fascicle
