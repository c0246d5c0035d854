// Time integration of the solid (seed 000 §4.1): symplectic Euler with a stable sub-step from the
// largest frequency, backward Euler by Newton iterations on the incremental potential with a sparse
// LDLᵀ solve (volume penalty as a rank-one Sherman–Morrison update), a quasi-static mode, step
// halving on failure and the exact volume projection per step (§4.4).
#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/sparse/cholmod_view.hpp"
#include "fascicle/sparse/supernodal_solve.hpp"
#include "internal.hpp"

#include <Eigen/SparseCholesky>
#include <cholmod.h>
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstring>

namespace fascicle {

namespace {

// CHOLMOD's LLᵀ of the free block of the backward-Euler matrix (the rows and columns of attached
// dofs are identity with zero right-hand sides, so they are left out: fewer unknowns and no
// fill through them). The block is permuted once, with the fill-reducing ordering CHOLMOD picks
// for it, into its lower triangle, and CHOLMOD then factorises it in the natural ordering: no
// permuted transposes per factorisation (with a lower-stored input and its own permutation
// CHOLMOD transposes twice) and no permutation in the solves. Solves reuse CHOLMOD's dense
// workspaces (cholmod_solve2), so they allocate nothing after the first.
class FreeBlockCholesky {
 public:
  FreeBlockCholesky() {
    cholmod_start(&c_);
    c_.print = 0;
    c_.error_handler = nullptr;  // not positive definite is an expected outcome
  }
  ~FreeBlockCholesky() {
    if (L_) cholmod_free_factor(&L_, &c_);
    for (cholmod_dense** d : {&B_, &X1_, &Y1_, &E1_, &X2_, &Y2_, &E2_})
      if (*d) cholmod_free_dense(d, &c_);
    cholmod_finish(&c_);
  }
  FreeBlockCholesky(const FreeBlockCholesky&) = delete;
  FreeBlockCholesky& operator=(const FreeBlockCholesky&) = delete;

  bool is_analysed() const { return L_ != nullptr; }

  // A: the full matrix's lower pattern; fixed: per dof. simplicial: CHOLMOD's simplicial LLᵀ.
  void analyse(const Eigen::SparseMatrix<double>& A, const std::vector<char>& fixed, bool simplicial) {
    full_ = static_cast<int>(A.rows());
    std::vector<int> free_index(full_, -1), free_dofs;
    for (int i = 0; i < full_; ++i)
      if (!fixed[i]) {
        free_index[i] = static_cast<int>(free_dofs.size());
        free_dofs.push_back(i);
      }
    nf_ = static_cast<int>(free_dofs.size());
    // The free block with the positions of its entries in A's values (exact in doubles).
    auto build = [&](const std::vector<int>& map) {
      std::vector<Eigen::Triplet<double>> t;
      for (int col = 0; col < full_; ++col)
        for (int p = A.outerIndexPtr()[col]; p < A.outerIndexPtr()[col + 1]; ++p) {
          const int row = A.innerIndexPtr()[p];
          if (row < col || free_index[row] < 0 || free_index[col] < 0) continue;
          const int r = map[free_index[row]], c = map[free_index[col]];
          t.emplace_back(std::max(r, c), std::min(r, c), static_cast<double>(p));
        }
      Eigen::SparseMatrix<double> S(nf_, nf_);
      S.setFromTriplets(t.begin(), t.end());
      S.makeCompressed();
      p_.assign(S.outerIndexPtr(), S.outerIndexPtr() + nf_ + 1);
      i_.assign(S.innerIndexPtr(), S.innerIndexPtr() + S.nonZeros());
      src_.resize(S.nonZeros());
      for (Eigen::Index q = 0; q < S.nonZeros(); ++q) src_[q] = static_cast<int>(S.valuePtr()[q]);
      x_.assign(S.nonZeros(), 0.0);
    };
    std::vector<int> identity(nf_);
    for (int k = 0; k < nf_; ++k) identity[k] = k;
    build(identity);
    // CHOLMOD's own choice of ordering (AMD or METIS, postordered) on the free block.
    cholmod_sparse S0 = get_view();
    cholmod_factor* L0 = nullptr;
    {
      const std::lock_guard lock(get_ordering_mutex());  // the ordering may be METIS's
      L0 = cholmod_analyze(&S0, &c_);
    }
    if (!L0) throw_internal("CHOLMOD could not analyse the backward-Euler matrix");
    std::vector<int> perm(static_cast<const int*>(L0->Perm), static_cast<const int*>(L0->Perm) + nf_);
    cholmod_free_factor(&L0, &c_);
    std::vector<int> inverse(nf_);
    for (int k = 0; k < nf_; ++k) inverse[perm[k]] = k;
    build(inverse);
    dof_.resize(nf_);
    for (int k = 0; k < nf_; ++k) dof_[k] = free_dofs[perm[k]];
    c_.nmethods = 1;
    c_.method[0].ordering = CHOLMOD_NATURAL;
    c_.postorder = 0;
    if (simplicial) {
      c_.supernodal = CHOLMOD_SIMPLICIAL;
      c_.final_asis = 0;
      c_.final_super = 0;
      c_.final_ll = 1;
      c_.final_pack = 1;
      c_.final_monotonic = 1;
      c_.final_resymbol = 0;
    } else {
      c_.supernodal = CHOLMOD_SUPERNODAL;
    }
    cholmod_sparse S1 = get_view();
    L_ = cholmod_analyze(&S1, &c_);
    if (!L_) throw_internal("CHOLMOD could not analyse the permuted backward-Euler matrix");
    B_ = cholmod_allocate_dense(nf_, 2, nf_, CHOLMOD_REAL, &c_);
    // The supernodal solve below is used on the natural ordering only (nothing to permute).
    own_solve_ = !simplicial && L_->is_super && L_->itype == CHOLMOD_INT;
    if (own_solve_ && L_->Perm) {
      const int* P = static_cast<const int*>(L_->Perm);
      for (int k = 0; k < nf_; ++k) own_solve_ = own_solve_ && P[k] == k;
    }
  }

  // Factorises the free block of the matrix whose values (in the analysed pattern) are given;
  // false when it is not positive definite.
  bool factorise(const double* A_values) {
    for (std::size_t q = 0; q < x_.size(); ++q) x_[q] = A_values[src_[q]];
    cholmod_sparse S = get_view();
    cholmod_factorize(&S, L_, &c_);
    return c_.status == CHOLMOD_OK && L_->minor == L_->n;
  }

  // X = A⁻¹ B for ncols (1 or 2) right-hand sides of the full length, column-major; the
  // solution is zero on attached dofs (whose right-hand sides are zero).
  void solve(const double* B, int ncols, double* X) {
    double* b = static_cast<double*>(B_->x);
    for (int j = 0; j < ncols; ++j)
      for (int k = 0; k < nf_; ++k) b[k + nf_ * j] = B[dof_[k] + full_ * j];
    // Our own application of CHOLMOD's supernodal factor (fascicle/sparse): no BLAS calls per
    // supernode for these one or two right-hand sides.
    if (own_solve_ && solve_supernodal_llt(L_, b, ncols, nf_, own_workspace_)) {
      std::fill(X, X + static_cast<std::ptrdiff_t>(full_) * ncols, 0.0);
      for (int j = 0; j < ncols; ++j)
        for (int k = 0; k < nf_; ++k) X[dof_[k] + full_ * j] = b[k + nf_ * j];
      return;
    }
    cholmod_dense Bv = *B_;
    Bv.ncol = ncols;
    Bv.nzmax = static_cast<std::size_t>(nf_) * ncols;
    cholmod_dense** Xh = ncols == 1 ? &X1_ : &X2_;
    cholmod_solve2(CHOLMOD_A, L_, &Bv, nullptr, Xh, nullptr, ncols == 1 ? &Y1_ : &Y2_,
                   ncols == 1 ? &E1_ : &E2_, &c_);
    if (!*Xh) throw_numerical("CHOLMOD could not solve the backward-Euler system");
    const double* x = static_cast<const double*>((*Xh)->x);
    std::fill(X, X + static_cast<std::ptrdiff_t>(full_) * ncols, 0.0);
    for (int j = 0; j < ncols; ++j)
      for (int k = 0; k < nf_; ++k) X[dof_[k] + full_ * j] = x[k + nf_ * j];
  }

 private:
  cholmod_sparse get_view() {
    return view_symmetric_lower(static_cast<std::size_t>(nf_), x_.size(), p_.data(), i_.data(), x_.data());
  }
  cholmod_common c_{};
  cholmod_factor* L_ = nullptr;
  cholmod_dense *B_ = nullptr, *X1_ = nullptr, *Y1_ = nullptr, *E1_ = nullptr, *X2_ = nullptr,
                *Y2_ = nullptr, *E2_ = nullptr;
  std::vector<int> p_, i_, src_, dof_;
  std::vector<double> x_;
  SupernodalSolveWorkspace own_workspace_;  // scratch of the supernodal solve
  int nf_ = 0, full_ = 0;
  bool own_solve_ = false;
};

}  // namespace

using dynamics_detail::calc_forces_into;
using dynamics_detail::calc_volume_and_flat_gradient;
using dynamics_detail::find_block;
using dynamics_detail::find_value_position;
using dynamics_detail::get_body_pose;

struct SolidDynamicsSolver::Workspace {
  ForceEvaluation fe;
  ForceEvaluation trial_fe, full_fe;  // line-search evaluations (kept: no allocations per step)
  dynamics_detail::ForceScratch scratch;
  Eigen::SparseMatrix<double> A;     // system matrix, lower block pattern
  Eigen::SparseMatrix<double> D;     // Rayleigh damping, same pattern (values), may be empty
  Eigen::SparseMatrix<double> D_stiff;  // its β K(rest) part alone (empty when β = 0): the α M
                                        // part is applied with the node-level mass matrix
  VecX inertia_values;               // M in the pattern's value layout
  std::vector<int> zero_positions;   // entries coupling fixed dofs
  std::vector<int> diag_positions;   // diagonal entries of fixed dofs
  std::vector<char> fixed_dof;
  VecX inv_mass;                     // per dof, 0 on fixed
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>, Eigen::Lower> ldlt;
  FreeBlockCholesky llt;
  bool analysed = false, use_llt = false;
  int factor_age = -1;       // steps since the factorisation (−1: none valid)
  double factor_h = 0.0;     // time step the factorisation was made for
  VecX solve(const VecX& b) {
    if (!use_llt) return ldlt.solve(b);
    VecX x(b.size());
    llt.solve(b.data(), 1, x.data());
    return x;
  }
  // Two right-hand sides in one pass over the factor.
  Eigen::Matrix<double, Eigen::Dynamic, 2> solve2(const VecX& b0, const VecX& b1) {
    Eigen::Matrix<double, Eigen::Dynamic, 2> B(b0.size(), 2);
    B.col(0) = b0;
    B.col(1) = b1;
    if (!use_llt) return ldlt.solve(B);
    Eigen::Matrix<double, Eigen::Dynamic, 2> X(b0.size(), 2);
    llt.solve(B.data(), 2, X.data());
    return X;
  }
  double last_potential_J = NAN;  // backward Euler: potential energy at the accepted state
  // Factorises A: CHOLMOD's LLᵀ of the free block when allowed and positive definite, else
  // Eigen's LDLᵀ of the whole matrix (attached dofs as identity rows).
  bool factorise(bool supernodal, bool cholmod_simplicial) {
    use_llt = false;
    if (supernodal) {
      if (!llt.is_analysed()) llt.analyse(A, fixed_dof, cholmod_simplicial);
      if (llt.factorise(A.valuePtr())) {
        use_llt = true;
        return true;
      }
    }
    if (!analysed) {
      ldlt.analyzePattern(A);
      analysed = true;
    }
    ldlt.factorize(A);
    return ldlt.info() == Eigen::Success;
  }
  double size_m = 1.0;
  double max_lumped_mass = 0.0;  // largest row sum of the mass matrix (kg)
  VecX prev_v;                   // velocities at the start of the last accepted step
  double prev_h = 0.0;           // its length (0: none, e.g. after set_state)
  VecX extrapolation;            // h² (v_n − v_{n−1})/h_{n−1} of the current step
  bool extrapolation_wins = true;  // the last step's solution was closer to the extrapolated start
  double last_lambda = 0.0;  // multiplier of the exact volume constraint (warm start)
  double omega_max = 0.0;    // symplectic Euler: cached largest frequency (rad/s)
  int omega_age = -1;
};

namespace {

// y = M x for interleaved x (M: #P x #P node matrix).
VecX apply_mass(const Eigen::SparseMatrix<double>& M, const VecX& x) {
  // y_J = Σ_I M_IJ x_I per coordinate (M symmetric, column-major).
  const Eigen::Index n = M.rows();
  VecX y = VecX::Zero(3 * n);
  const int* outer = M.outerIndexPtr();
  const int* inner = M.innerIndexPtr();
  const double* val = M.valuePtr();
  const double* xp = x.data();
  double* yp = y.data();
  for (Eigen::Index J = 0; J < n; ++J) {
    double y0 = 0.0, y1 = 0.0, y2 = 0.0;
    for (int p = outer[J]; p < outer[J + 1]; ++p) {
      const double v = val[p];
      const double* xi = xp + 3 * inner[p];
      y0 += v * xi[0];
      y1 += v * xi[1];
      y2 += v * xi[2];
    }
    yp[3 * J] = y0;
    yp[3 * J + 1] = y1;
    yp[3 * J + 2] = y2;
  }
  return y;
}

// y = M x for interleaved x that is zero on most nodes (e.g. only the attached ones): a scatter
// over the columns of the nodes where x is non-zero (M symmetric).
VecX apply_mass_sparse_input(const Eigen::SparseMatrix<double>& M, const VecX& x) {
  const Eigen::Index n = M.rows();
  VecX y = VecX::Zero(3 * n);
  const int* outer = M.outerIndexPtr();
  const int* inner = M.innerIndexPtr();
  const double* val = M.valuePtr();
  for (Eigen::Index I = 0; I < n; ++I) {
    const double x0 = x[3 * I], x1 = x[3 * I + 1], x2 = x[3 * I + 2];
    if (x0 == 0.0 && x1 == 0.0 && x2 == 0.0) continue;
    for (int p = outer[I]; p < outer[I + 1]; ++p) {
      const double v = val[p];
      double* yj = y.data() + 3 * inner[p];
      yj[0] += v * x0;
      yj[1] += v * x1;
      yj[2] += v * x2;
    }
  }
  return y;
}

VecX apply_lower(const Eigen::SparseMatrix<double>& A, const VecX& x) {
  return A.selfadjointView<Eigen::Lower>() * x;
}

}  // namespace

SolidDynamicsSolver::SolidDynamicsSolver(std::shared_ptr<const SolidDynamicsModel> model,
                                         SolverOptions options)
    : model_(std::move(model)), options_(options), ws_(std::make_unique<Workspace>()) {
  if (!model_) throw_internal("SolidDynamicsSolver: null model");
  const SolidDynamicsModel& m = *model_;
  const int n = m.rest.num_control_points();
  state_.P = m.rest.P;
  state_.V = Points3::Zero(n, 3);
  Workspace& w = *ws_;
  w.A = dynamics_detail::make_pattern_matrix(m);
  w.inertia_values = VecX::Zero(w.A.nonZeros());
  for (int J = 0; J < n; ++J)
    for (Eigen::SparseMatrix<double>::InnerIterator it(m.mass_matrix, J); it; ++it) {
      const int I = static_cast<int>(it.row());
      if (I < J) continue;
      const int blk = find_block(m, I, J);
      for (int r = 0; r < 3; ++r) w.inertia_values[find_value_position(m, J, blk, r, r)] += it.value();
    }
  // Fixed dofs: rows and columns of the system become identity.
  w.fixed_dof.assign(3 * n, 0);
  w.inv_mass = VecX::Zero(3 * n);
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) {
      w.fixed_dof[3 * i + c] = m.fixed[i];
      w.inv_mass[3 * i + c] = m.fixed[i] ? 0.0 : 1.0 / m.lumped_mass[i];
    }
  for (int col = 0; col < w.A.outerSize(); ++col)
    for (int p = w.A.outerIndexPtr()[col]; p < w.A.outerIndexPtr()[col + 1]; ++p) {
      const int row = w.A.innerIndexPtr()[p];
      if (!w.fixed_dof[row] && !w.fixed_dof[col]) continue;
      (row == col ? w.diag_positions : w.zero_positions).push_back(p);
    }
  // Rayleigh damping D = α M + β K(rest).
  if (m.spec.rayleigh_alpha_1_s > 0.0 || m.spec.rayleigh_beta_s > 0.0) {
    w.D = w.A;
    VecX vals = m.spec.rayleigh_alpha_1_s * w.inertia_values;
    if (m.spec.rayleigh_beta_s > 0.0) {
      // K(rest) of the material alone: contacts (which may be active in the rest pose of the
      // bones) must not become damping.
      SolidDynamicsModel material = m;
      material.contact_samples.clear();
      material.bone_queries.clear();
      material.bone_rest_depth.clear();
      material.spec.contact_planes.clear();
      material.spec.contact_bones.clear();
      ForceEvaluation k0;
      calc_forces_into(material, m.rest.P, {}, 0.0, true, {}, k0);
      const VecX kvals =
          m.spec.rayleigh_beta_s * Eigen::Map<const VecX>(k0.stiffness.valuePtr(), vals.size());
      vals += kvals;
      w.D_stiff = w.A;
      Eigen::Map<VecX>(w.D_stiff.valuePtr(), kvals.size()) = kvals;
    }
    Eigen::Map<VecX>(w.D.valuePtr(), vals.size()) = vals;
  }
  const Vec3 lo = m.rest.P.colwise().minCoeff(), hi = m.rest.P.colwise().maxCoeff();
  w.size_m = std::max(1e-6, (hi - lo).norm());
  w.max_lumped_mass = m.lumped_mass.size() > 0 ? m.lumped_mass.maxCoeff() : 0.0;
}

SolidDynamicsSolver::~SolidDynamicsSolver() = default;
SolidDynamicsSolver::SolidDynamicsSolver(SolidDynamicsSolver&&) noexcept = default;
SolidDynamicsSolver& SolidDynamicsSolver::operator=(SolidDynamicsSolver&&) noexcept = default;

void SolidDynamicsSolver::set_state(SolidState s) {
  const int n = model_->rest.num_control_points();
  if (s.P.rows() != n || s.V.rows() != n)
    throw_bad_input(fmt::format("solid state has {} points, the model {}", s.P.rows(), n));
  state_ = std::move(s);
  initial_energy_ = NAN;
  ws_->omega_age = -1;
  ws_->factor_age = -1;
  ws_->prev_h = 0.0;
  ws_->extrapolation_wins = true;
}

void SolidDynamicsSolver::correct_state(const Points3& P, const Points3& V) {
  const int n = model_->rest.num_control_points();
  if (P.rows() != n || V.rows() != n)
    throw_bad_input(fmt::format("solid state correction has {} positions and {} velocities, the model {} points",
                                P.rows(), V.rows(), n));
  // The correction's velocity change is no acceleration to extrapolate: shift the previous
  // velocities by it too.
  if (ws_->prev_h > 0.0) ws_->prev_v += flatten_points(V) - flatten_points(state_.V);
  state_.P = P;
  state_.V = V;
}

void SolidDynamicsSolver::project_volume(SolidState& s, double dt, StepReport& r) const {
  const SolidDynamicsModel& m = *model_;
  if (m.spec.volume != VolumeMethod::exact) return;
  VecX x = flatten_points(s.P);
  const VecX x0 = x;
  VecX g;
  for (int it = 0; it < 30; ++it) {
    const double V = calc_volume_and_flat_gradient(m, unflatten_points(x), &g);
    const double err = V - m.rest_volume_m3;
    if (std::abs(err) <= m.spec.volume_tolerance * m.rest_volume_m3) break;
    const VecX Wg = ws_->inv_mass.cwiseProduct(g);
    const double denom = g.dot(Wg);
    if (!(denom > 0.0)) break;
    x -= (err / denom) * Wg;
    r.volume_projection_m3 += std::abs(err);
  }
  s.P = unflatten_points(x);
  // The projection is part of the step: velocities follow the corrected positions.
  if (dt > 0.0 && options_.integrator != Integrator::quasi_static)
    s.V += unflatten_points((x - x0) / dt);
}

StepReport SolidDynamicsSolver::step(double dt, const StepInputs& in) {
  const SolidDynamicsModel& m = *model_;
  if (!(dt > 0.0) || !std::isfinite(dt))
    throw_bad_input(fmt::format("solid dynamics: time step {} s is not positive", dt));
  const int n = m.rest.num_control_points();
  if (in.external_forces.rows() != 0 && in.external_forces.rows() != n)
    throw_bad_input(fmt::format("external forces have {} rows, the solid {} control points",
                                in.external_forces.rows(), n));
  if (std::isnan(initial_energy_)) initial_energy_ = calc_energies(m, state_, in.X_now_rest).total();

  StepReport total;
  double remaining = dt, h = dt;
  int halvings = 0;
  while (remaining > 1e-12 * dt) {
    h = std::min(h, remaining);
    SolidState trial = state_;
    StepReport r;
    ws_->last_potential_J = NAN;
    try {
      // Attachment targets are interpolated linearly in time across sub-intervals.
      r = try_step(h, in, trial);
    } catch (const Error& e) {
      ws_->factor_age = -1;  // a failed step never leaves a lagged factorisation behind
      ws_->omega_age = -1;
      if (e.kind() == ErrorKind::numerical && halvings < options_.max_step_halvings) {
        h *= 0.5;
        ++halvings;
        continue;
      }
      throw_numerical(fmt::format("solid '{}' at t = {:.6g} s: {} (after {} step halvings; the "
                                  "last good state is kept)",
                                  m.rest.name, state_.time_s, e.message(), halvings),
                      e.context());
    }
    // Divergence checks: NaN, energy blow-up.
    if (!trial.P.allFinite() || !trial.V.allFinite()) {
      if (halvings < options_.max_step_halvings) {
        h *= 0.5;
        ++halvings;
        continue;
      }
      throw_numerical(fmt::format("solid '{}' diverged (NaN) at t = {:.6g} s; the last good state "
                                  "is kept", m.rest.name, state_.time_s),
                      {.object = m.rest.name, .suggestion = "reduce the time step or use backward Euler"});
    }
    double E = NAN;
    try {
      // Backward Euler and quasi-static: the potential of the accepted Newton iterate (before
      // the volume projection's rounding-level correction) plus the kinetic energy.
      if (options_.integrator != Integrator::symplectic_euler && std::isfinite(ws_->last_potential_J)) {
        // The kinetic energy is bounded by ½ max_I(Σ_J |M_IJ|) |v|² (Gershgorin; the entries of
        // M are non-negative, so the row sums are the lumped masses); the exact ½ vᵀMv (a mass
        // product) is needed only when that bound could cross the blow-up limit.
        const VecX v = flatten_points(trial.V);
        E = ws_->last_potential_J + 0.5 * ws_->max_lumped_mass * v.squaredNorm();
        const double limit = initial_energy_ + options_.energy_blowup_factor *
                                                   (std::abs(initial_energy_) + m.mass_kg * 1.0);
        if (!(E <= limit)) E = ws_->last_potential_J + 0.5 * v.dot(apply_mass(m.mass_matrix, v));
      } else {
        E = calc_energies(m, trial, in.X_now_rest).total();
      }
    } catch (const Error& e) {
      if (e.kind() != ErrorKind::numerical) throw;
      throw_numerical(fmt::format("solid '{}' at t = {:.6g} s: {}; the last good state is kept",
                                  m.rest.name, state_.time_s, e.message()),
                      e.context());
    }
    const double bound = initial_energy_ + options_.energy_blowup_factor *
                                               (std::abs(initial_energy_) + m.mass_kg * 1.0);
    if (!std::isfinite(E) || E > bound) {
      throw_numerical(
          fmt::format("solid '{}': energy blow-up at t = {:.6g} s ({:.4g} J, started at {:.4g} J); "
                      "the last good state is kept", m.rest.name, state_.time_s + h, E, initial_energy_),
          {.object = m.rest.name,
           .suggestion = "reduce the time step (explicit integration is only stable below 2/w_max) "
                         "or use backward Euler"});
    }
    ws_->prev_v = flatten_points(state_.V);
    ws_->prev_h = h;
    state_ = std::move(trial);
    remaining -= h;
    total.substeps += r.substeps;
    total.newton_iterations += r.newton_iterations;
    total.factorisations += r.factorisations;
    total.residual = r.residual;
    total.volume_projection_m3 += r.volume_projection_m3;
  }
  total.halvings = halvings;
  return total;
}

StepReport SolidDynamicsSolver::try_step(double h, const StepInputs& in, SolidState& s) {
  const SolidDynamicsModel& m = *model_;
  const SolidDynamicsSpec& sp = m.spec;
  Workspace& w = *ws_;
  const int n = m.rest.num_control_points();
  StepReport rep;

  // Activation dynamics (OpenSim first-order model), sub-stepped at <= 1 ms.
  const double u = std::clamp(in.excitation, 0.0, 1.0);
  double a = s.activation;
  const int na = std::max(1, static_cast<int>(std::ceil(h / 1e-3)));
  for (int i = 0; i < na; ++i)
    a = std::clamp(a + (h / na) * calc_activation_rate_opensim(sp.activation, a, u), 0.0, 1.0);

  // Attachment targets at the end of this sub-interval.
  const VecX x_n = flatten_points(s.P), v_n = flatten_points(s.V);
  VecX target = x_n;
  for (const auto& att : sp.attachments) {
    const Transform X = get_body_pose(in.X_now_rest, att.body);
    for (int i : att.control_points) target.segment<3>(3 * i) = X * m.rest.P.row(i).transpose();
  }
  const VecX f_ext = in.external_forces.rows() == n ? flatten_points(in.external_forces)
                                                     : VecX::Zero(3 * n);
  const double V0 = m.rest_volume_m3;
  const bool has_D = w.D.nonZeros() > 0;

  if (options_.integrator == Integrator::symplectic_euler) {
    // ω_max is re-estimated every 20 steps (a full tangent assembly), with a 10 % margin.
    if (w.omega_age < 0 || w.omega_age >= 20) {
      w.omega_max = 1.1 * calc_max_frequency(m, s.P, a);
      w.omega_age = 0;
    }
    ++w.omega_age;
    const double wmax = w.omega_max;
    const double hmax = options_.explicit_safety * 2.0 / std::max(wmax, 1e-12);
    const int ns = std::max(1, static_cast<int>(std::ceil(h / hmax)));
    const double hs = h / ns;
    VecX x = x_n, v = v_n;
    for (int k = 0; k < ns; ++k) {
      const Points3 P = unflatten_points(x), V = unflatten_points(v);
      calc_forces_into(m, P, V, a, false, in.X_now_rest, w.fe, 0.0, nullptr, 0.0, &w.scratch);
      VecX f = w.fe.force + f_ext;
      if (has_D) f -= apply_lower(w.D, v);
      if (sp.volume == VolumeMethod::penalty && sp.volume_damping_Pa_s > 0.0)
        f -= (sp.volume_damping_Pa_s * w.fe.volume_gradient.dot(v) / V0) * w.fe.volume_gradient;
      v += hs * w.inv_mass.cwiseProduct(f);
      const double frac = static_cast<double>(k + 1) / ns;
      for (int i = 0; i < 3 * n; ++i) {
        if (!w.fixed_dof[i]) continue;
        const double xt = x_n[i] + frac * (target[i] - x_n[i]);
        v[i] = (xt - x[i]) / hs;
      }
      x += hs * v;
      s.P = unflatten_points(x);
      s.V = unflatten_points(v);
      project_volume(s, hs, rep);
      x = flatten_points(s.P);
      v = flatten_points(s.V);
    }
    s.activation = a;
    s.time_s += h;
    rep.substeps = ns;
    return rep;
  }

  // Backward Euler / quasi-static: Newton on r(x) = M(x − x̃)/h² + D(x − x_n)/h − f(x) − f_ext.
  const bool quasi = options_.integrator == Integrator::quasi_static;
  const double inertia = quasi ? 1e-6 : 1.0;  // quasi-static: a tiny mass regularises free modes
  const VecX x_tilde = quasi ? x_n : VecX(x_n + h * v_n);
  VecX x = x_tilde;
  // The extrapolated start is used while it predicts better than x̃ (checked after each step):
  // it helps on smooth motions and overshoots oscillations at large steps.
  const bool can_extrapolate = options_.extrapolate_start && !quasi && w.prev_h > 0.0 &&
                               w.prev_v.size() == x.size();
  const bool extrapolated = can_extrapolate && w.extrapolation_wins;
  if (can_extrapolate) w.extrapolation = (h * h / w.prev_h) * (v_n - w.prev_v);
  if (extrapolated) x += w.extrapolation;
  for (int i = 0; i < 3 * n; ++i)
    if (w.fixed_dof[i]) x[i] = target[i];
  const Points3 V_start = s.V;
  // Force–velocity from the step's stretch rate (implicit): fibre stretches at the step's start.
  const std::vector<double> lambda_start =
      quasi ? std::vector<double>() : dynamics_detail::calc_fibre_stretches(m, s.P);
  const std::vector<double>* fv_from = quasi ? nullptr : &lambda_start;
  // Volume: the penalty enters with its Gauss–Newton rank-one Hessian c g gᵀ (Sherman–Morrison);
  // its damping acts on (V − V_n)/h so that it has the potential d/(2 V0 h) (V − V_n)². The exact
  // constraint enters Newton as a Lagrange multiplier λ on the linearised constraint
  // g·Δx = −(V − V0) (the projection after the step only removes the last rounding).
  const bool penalty = sp.volume == VolumeMethod::penalty;
  const bool exact = sp.volume == VolumeMethod::exact;
  const double d_vol = (penalty && !quasi) ? sp.volume_damping_Pa_s / (V0 * h) : 0.0;
  const double c_rank = penalty ? sp.volume_stiffness_Pa / V0 + d_vol : 0.0;
  const double V_n = (d_vol > 0.0) ? calc_volume_and_flat_gradient(m, s.P, nullptr) : 0.0;
  double lambda = exact ? w.last_lambda : 0.0;
  // Pressure times the volume Hessian, for the stiffness (full Newton instead of Gauss–Newton).
  auto volume_curvature = [&]() {
    if (exact) return lambda;
    if (penalty) return sp.volume_stiffness_Pa * (w.fe.volume_m3 - V0) / V0 +
                        d_vol * (w.fe.volume_m3 - V_n);
    return 0.0;
  };
  // Rayleigh damping D (x − x_n) = α M (x − x̃ + h v_n) + β K(rest) (x − x_n): the mass part
  // from M (x − x̃) (which the merit and residual share) and M v_n (once per step).
  const bool damped = has_D && !quasi;
  const double alpha_D = sp.rayleigh_alpha_1_s;
  const VecX Mvn = damped && alpha_D > 0.0 ? apply_mass(m.mass_matrix, v_n) : VecX();
  auto damping_force = [&](const VecX& xx, const VecX& Mdx) {
    VecX out = alpha_D > 0.0 ? VecX(alpha_D * (Mdx + h * Mvn)) : VecX::Zero(xx.size());
    if (w.D_stiff.nonZeros() > 0) out += apply_lower(w.D_stiff, xx - x_n);
    return out;
  };
  // M (x − x̃) is shared by the merit and the residual of the same point (Mdx below).
  auto merit = [&](const VecX& xx, const ForceEvaluation& fe, const VecX& Mdx) {
    const VecX dx = xx - x_tilde;
    double phi = 0.5 * inertia / (h * h) * dx.dot(Mdx) + fe.energy_J +
                 fe.active_energy_J - f_ext.dot(xx);
    if (damped) phi += 0.5 / h * (xx - x_n).dot(damping_force(xx, Mdx));
    if (d_vol > 0.0) phi += 0.5 * d_vol * (fe.volume_m3 - V_n) * (fe.volume_m3 - V_n);
    if (exact) phi += lambda * (fe.volume_m3 - V0);  // the Lagrangian at the current multiplier
    return phi;
  };
  // Residual of the step equations without the multiplier term; g receives the masked ∇V.
  auto residual = [&](const VecX& xx, const ForceEvaluation& fe, const VecX& Mdx, VecX& g) {
    VecX r = inertia / (h * h) * Mdx - fe.force - f_ext;
    if (damped) r += damping_force(xx, Mdx) / h;
    if (penalty || exact) {
      g = fe.volume_gradient;
      for (int i = 0; i < 3 * n; ++i)
        if (w.fixed_dof[i]) g[i] = 0.0;  // masked: the attachments hold those points
      if (d_vol > 0.0) r += (d_vol * (fe.volume_m3 - V_n)) * g;
    }
    for (int i = 0; i < 3 * n; ++i)
      if (w.fixed_dof[i]) r[i] = 0.0;
    return r;
  };
  const double tol = options_.newton_tolerance * w.size_m;
  calc_forces_into(m, unflatten_points(x), V_start, a, false, in.X_now_rest, w.fe, 0.0, fv_from, h,
                   &w.scratch);
  // x − x̃ is non-zero only on the attached dofs here.
  VecX Mdx = extrapolated ? apply_mass(m.mass_matrix, x - x_tilde)
                          : apply_mass_sparse_input(m.mass_matrix, x - x_tilde);
  VecX My;  // M y of the Newton direction: trial points' M (x + α y − x̃) = Mdx + α My
  bool factored = false;
  bool converged = false;
  int nonmonotone_left = 3;
  bool shift_changed = false;
  double shift = 0.0;  // Levenberg–Marquardt shift: A + shift·M/h² when Newton's direction fails
  double last_step_norm = 0.0, last_rate = 0.0;  // |Δx| of the last iteration and the contraction
  int since_factor = 0;  // Newton directions of this step from the current factorisation
  for (int it = 0; it < options_.max_newton_iterations; ++it) {
    ++rep.newton_iterations;
    const VecX d = x - x_n;
    VecX g;
    VecX r = residual(x, w.fe, Mdx, g);
    // A lagged factorisation from an earlier step is kept while Newton converges quickly.
    const bool reuse = options_.reuse_factorisation_steps > 0 && it == 0 && w.factor_age >= 0 &&
                       w.factor_age < options_.reuse_factorisation_steps && w.factor_h == h;
    const bool modified = !options_.refresh_stiffness || options_.reuse_factorisation_steps > 0;
    // Newton slows down: refresh after 4 directions from one factorisation, or (with a rate) as
    // soon as two of them contract by less than the rate (again after a refresh: a hard step
    // falls back to full Newton).
    const bool slow = factored && modified &&
                      (since_factor >= 4 || (options_.refresh_contraction_rate > 0.0 && since_factor >= 2 &&
                                             last_rate > options_.refresh_contraction_rate));
    if (reuse) {
      factored = true;
    } else if (!factored || !modified || slow || shift_changed) {
      shift_changed = false;
      calc_forces_into(m, unflatten_points(x), V_start, a, true, in.X_now_rest, w.fe,
                       volume_curvature(), fv_from, h, &w.scratch);
      Eigen::Map<VecX> Av(w.A.valuePtr(), w.A.nonZeros());
      Av = Eigen::Map<const VecX>(w.fe.stiffness.valuePtr(), Av.size()) +
           ((inertia + shift) / (h * h)) * w.inertia_values;
      if (has_D && !quasi) Av += Eigen::Map<const VecX>(w.D.valuePtr(), Av.size()) / h;
      for (int p : w.zero_positions) Av[p] = 0.0;
      for (int p : w.diag_positions) Av[p] = 1.0;
      ++rep.factorisations;
      if (!w.factorise(options_.supernodal, options_.cholmod_simplicial)) {
        w.factor_age = -1;
        throw_numerical("the backward-Euler system could not be factorised");
      }
      w.factor_age = 0;
      w.factor_h = h;
      factored = true;
      since_factor = 0;
      last_step_norm = 0.0;  // the contraction rate is measured with one factorisation
    }
    ++since_factor;
    VecX y, z;
    if (penalty || exact) {
      const Eigen::Matrix<double, Eigen::Dynamic, 2> yz = w.solve2(-r, g);
      y = yz.col(0);
      z = yz.col(1);
    } else {
      y = w.solve(-r);
    }
    if (penalty) {
      y -= (c_rank * g.dot(y) / (1.0 + c_rank * g.dot(z))) * z;
    } else if (exact) {
      const double gz = g.dot(z);
      if (gz > 0.0) {
        lambda = (g.dot(y) + (w.fe.volume_m3 - V0)) / gz;
        y -= lambda * z;
      }
      r += lambda * g;
    }
    rep.residual = r.lpNorm<Eigen::Infinity>();
    if (!y.allFinite()) throw_numerical("the Newton step is not finite");
    {
      const double yn = y.lpNorm<Eigen::Infinity>();
      last_rate = last_step_norm > 0.0 ? yn / last_step_norm : 0.0;
      last_step_norm = yn;
      // A full step below the tolerance is accepted without the line search (which would accept
      // it whatever the merit says): its force evaluation would only confirm it. The state is the
      // same bits; the blow-up guard then uses the potential at the previous iterate.
      if (yn < tol) {
        x += y;
        spdlog::trace("solid '{}' Newton {}: |r| {:.3e} N, |dx| {:.3e} m, converged, lambda {:.4g} Pa",
                      m.rest.name, it, rep.residual, yn, lambda);
        converged = true;
        break;
      }
    }
    // Backtracking line search on the incremental potential (the Lagrangian for the exact
    // constraint); inverted trials are rejected.
    double phi = merit(x, w.fe, Mdx);
    double alpha = 1.0;
    bool accepted = false;
    ForceEvaluation& trial_fe = w.trial_fe;
    ForceEvaluation& full_fe = w.full_fe;
    bool full_ok = false;  // the full step is not inverted (kept for a non-monotone step)
    My = apply_mass(m.mass_matrix, y);
    auto accept = [&](const VecX& xt, ForceEvaluation& fe, VecX* Mdx_t) {
      x = xt;
      if (Mdx_t) std::swap(Mdx, *Mdx_t);
      else Mdx += My;
      std::swap(w.fe.force, fe.force);
      w.fe.energy_J = fe.energy_J;
      w.fe.active_energy_J = fe.active_energy_J;
      w.fe.volume_m3 = fe.volume_m3;
      std::swap(w.fe.volume_gradient, fe.volume_gradient);
      accepted = true;
    };
    for (int ls = 0; ls < 10; ++ls, alpha *= 0.5) {
      const VecX xt = x + alpha * y;
      try {
        calc_forces_into(m, unflatten_points(xt), V_start, a, false, in.X_now_rest, trial_fe, 0.0,
                         fv_from, h, &w.scratch);
      } catch (const Error& e) {
        if (e.kind() == ErrorKind::numerical) continue;
        throw;
      }
      if (ls == 0) {
        full_ok = true;
        full_fe = trial_fe;
      }
      VecX Mdx_t = Mdx + alpha * My;
      const double phi_t = merit(xt, trial_fe, Mdx_t);
      // The implicit force–velocity term has no potential: a clear drop of the residual is
      // accepted too.
      VecX gt;
      VecX rt = residual(xt, trial_fe, Mdx_t, gt);
      if (exact) rt += lambda * gt;
      if (phi_t <= phi + 1e-10 * std::abs(phi) + 1e-14 ||
          rt.lpNorm<Eigen::Infinity>() < 0.5 * rep.residual ||
          alpha * y.lpNorm<Eigen::Infinity>() < tol) {
        accept(xt, trial_fe, &Mdx_t);
        break;
      }
    }
    // An indefinite tangent (isochoric ground substance, λ ∂²V) can give a direction without
    // decrease: retry from the same point with a growing shift towards M/h² (shorter, more
    // gradient-like steps).
    if (!accepted && shift < 1e4) {
      shift = shift == 0.0 ? 1.0 : 10.0 * shift;
      shift_changed = true;
      continue;
    }
    if (accepted && shift > 0.0) {
      shift = shift < 1e-3 ? 0.0 : 0.1 * shift;
      shift_changed = true;
    }
    // Kinks of the fibre laws (at λ = λopt) can make Newton cycle with no decrease along its
    // direction: a few non-monotone full steps get it past them.
    if (!accepted && full_ok && nonmonotone_left > 0) {
      --nonmonotone_left;
      alpha = 1.0;
      accept(VecX(x + y), full_fe, nullptr);
    }
    if (!accepted) {
      // Already at the solution within rounding: the merit cannot decrease any more.
      if (y.lpNorm<Eigen::Infinity>() < 100.0 * tol) {
        converged = true;
        break;
      }
      auto inv = find_inverted_point(m, unflatten_points(x + y));
      throw_numerical(inv ? fmt::format("Newton step inverts the solid at material point ({:.4f}, "
                                        "{:.4f}, {:.4f})", (*inv)[0], (*inv)[1], (*inv)[2])
                          : std::string("Newton line search failed"));
    }
    spdlog::trace("solid '{}' Newton {}: |r| {:.3e} N, |dx| {:.3e} m, alpha {}, lambda {:.4g} Pa",
                  m.rest.name, it, rep.residual, y.lpNorm<Eigen::Infinity>(), alpha, lambda);
    if (alpha * y.lpNorm<Eigen::Infinity>() < tol) {
      converged = true;
      break;
    }
  }
  if (!converged)
    throw_numerical(fmt::format("Newton did not converge in {} iterations (|r| = {:.3e} N)",
                                options_.max_newton_iterations, rep.residual));
  if (can_extrapolate) {
    double e_plain = 0.0, e_extra = 0.0;
    for (int i = 0; i < 3 * n; ++i) {
      if (w.fixed_dof[i]) continue;
      e_plain = std::max(e_plain, std::abs(x[i] - x_tilde[i]));
      e_extra = std::max(e_extra, std::abs(x[i] - x_tilde[i] - w.extrapolation[i]));
    }
    w.extrapolation_wins = e_extra < e_plain;
  }
  s.P = unflatten_points(x);
  s.V = quasi ? Points3::Zero(n, 3) : unflatten_points((x - x_n) / h);
  w.last_potential_J = w.fe.energy_J;
  project_volume(s, h, rep);
  w.last_lambda = lambda;
  if (w.factor_age >= 0) ++w.factor_age;
  s.activation = a;
  s.time_s += h;
  rep.substeps = 1;
  return rep;
}

SolidMetrics SolidDynamicsSolver::calc_metrics(const StepInputs& in) const {
  return fascicle::calc_metrics(*model_, state_, in.X_now_rest);
}

double calc_max_frequency(const SolidDynamicsModel& m, const Points3& P, double activation) {
  ForceEvaluation fe;
  calc_forces_into(m, P, {}, activation, true, {}, fe);
  const int n = static_cast<int>(P.rows());
  VecX s(3 * n);  // M^{-1/2}, zero on fixed dofs
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) s[3 * i + c] = m.fixed[i] ? 0.0 : 1.0 / std::sqrt(m.lumped_mass[i]);
  double cr = 0.0;
  VecX g;
  if (m.spec.volume == VolumeMethod::penalty) {
    cr = m.spec.volume_stiffness_Pa / m.rest_volume_m3;
    g = fe.volume_gradient;
  }
  VecX x = VecX::Ones(3 * n).cwiseProduct(s);
  for (int i = 0; i < 3 * n; i += 2) x[i] *= -1.0;  // break symmetry
  double lambda = 0.0;
  for (int it = 0; it < 60; ++it) {
    const double nx = x.norm();
    if (!(nx > 0.0)) break;
    x /= nx;
    VecX y = s.cwiseProduct(x);
    VecX z = fe.stiffness.selfadjointView<Eigen::Lower>() * y;
    if (cr > 0.0) z += cr * g.dot(y) * g;
    z = s.cwiseProduct(z);
    lambda = x.dot(z);
    x = z;
  }
  // Also the springs' and contacts' contributions are in fe.stiffness.
  return std::sqrt(std::max(lambda, 0.0));
}

}  // namespace fascicle
