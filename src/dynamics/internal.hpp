// Internal helpers of the dynamics module (not installed).
#pragma once

#include "fascicle/dynamics/solid_dynamics.hpp"

namespace fascicle::dynamics_detail {

// The 3#P x 3#P matrix with the model's lower block pattern (diagonal blocks full), values zero.
Eigen::SparseMatrix<double> make_pattern_matrix(const SolidDynamicsModel& m);

// Position in valuePtr() of entry (3 I + r, 3 J + c) for block index `block` (of column J).
inline int find_value_position(const SolidDynamicsModel& m, int J, int block, int r, int c) {
  const int deg = m.block_ptr[J + 1] - m.block_ptr[J];
  return 9 * m.block_ptr[J] + 3 * c * deg + 3 * (block - m.block_ptr[J]) + r;
}
int find_block(const SolidDynamicsModel& m, int I, int J);  // I >= J

// Pose of body b (identity for b < 0); throws bad_input when b is out of range of a non-empty X.
Transform get_body_pose(const std::vector<Transform>& X_now_rest, int b);

// F = Σ_a P_a g_aᵀ over a quadrature point's support.
Mat3 calc_deformation_gradient(const Points3& P, const int* idx, const Vec3* g, int count);
// Fibre stretch |F a0| at every quadrature point.
std::vector<double> calc_fibre_stretches(const SolidDynamicsModel& m, const Points3& P);

// Scratch of the per-span kernels of calc_forces_into: the span's gathered control points, F of
// its points, their weighted stresses, the span forces and the dense span tangent.
struct SpanScratch {
  std::vector<double> p0, p1, p2, Fs, S, f0, f1, f2, Kl;
  std::vector<double> gp;  // one point's g columns padded to a multiple of 4 (tangent kernel)
};
// Kept by the solver so that force evaluations inside a step allocate nothing.
struct ForceScratch {
  SpanScratch span, velocity;
};

// calc_forces reusing `out` (its stiffness keeps the pattern between calls) and, when given,
// `scratch`.
void calc_forces_into(const SolidDynamicsModel& model, const Points3& P, const Points3& V,
                      double activation, bool with_stiffness,
                      const std::vector<Transform>& X_now_rest, ForceEvaluation& out,
                      double volume_hessian_scale = 0.0,
                      const std::vector<double>* lambda_start = nullptr, double step_h = 0.0,
                      ForceScratch* scratch = nullptr);
// lambda_start (per quadrature point, calc_fibre_stretches at the step's start), step_h (backward
// Euler): the force–velocity factor uses the fibre stretch rate (λ − λ_start)/h of the step
// instead of the velocities V.
// volume_hessian_scale: adds that multiple of the Hessian of V (by the model's quadrature) to the
// stiffness only (the Lagrange multiplier or penalty pressure times ∂²V).

// Contacts of the boundary samples with planes and bone meshes at P: for each active contact the
// sample, the unit push direction n (world) and the depth (> 0).
struct ActiveContact {
  int sample = 0;
  Vec3 normal = Vec3::Zero();
  double depth = 0.0;
};
std::vector<ActiveContact> find_active_contacts(const SolidDynamicsModel& m, const Points3& P,
                                                const std::vector<Transform>& X_now_rest);

// Volume and gradient (3#P interleaved).
double calc_volume_and_flat_gradient(const SolidDynamicsModel& m, const Points3& P, VecX* grad);

}  // namespace fascicle::dynamics_detail
