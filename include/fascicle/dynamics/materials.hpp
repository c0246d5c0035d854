// Constitutive kernels of the solid-muscle dynamics: pure functions of the deformation gradient F
// (dimensionless, F = dx/dX) returning an energy density (J/m^3 = Pa) and the first Piola–Kirchhoff
// stress P = dW/dF (Pa). No model, no state.
//
// Ground substance: isochoric Mooney–Rivlin,
//   W = c1 (Ī1 − 3) + c2 (Ī2 − 3) + κ/2 (ln J)^2,  Ī1 = J^{-2/3} I1, Ī2 = J^{-4/3} I2,
// (κ = 0 by default: volume is kept by the solid-level volume term, seed 000 §4.4).
// Along-fibre law of Blemker, Pinsky & Delp 2005 (Ann. Biomed. Eng. 33:661), with the fibre
// stretch λ = |F a0| (a0: unit fibre direction in the rest configuration):
//   λ ∂W/∂λ = σmax (f_passive(λ) + a f_active(λ) f_v) λ/λopt,
//   f_passive = 0 (λ ≤ λopt), P1 (exp(P2 (λ/λopt − 1)) − 1) (λopt < λ < λ*), P3 λ/λopt + P4 beyond,
//   f_active  = 9 (λ̂ − 0.4)^2 on [0.4, 0.6], 1 − 4 (1 − λ̂)^2 on [0.6, 1.4], 9 (λ̂ − 1.6)^2 on
//   [1.4, 1.6], 0 elsewhere (λ̂ = λ/λopt).
// The active term is not conservative (it depends on activation and velocity); the passive one has
// the closed-form energy returned below. Blemker uses the deviatoric stretch; here λ is the full
// stretch, which differs by J^{1/3} ≈ 1 because volume is constrained (docs/solid-dynamics.md).
#pragma once

#include "fascicle/core/types.hpp"

namespace fascicle {

struct MooneyRivlinParameters {
  double c1_Pa = 2.0e3;
  double c2_Pa = 1.0e3;
  double bulk_modulus_Pa = 0.0;  // κ; 0: volume handled by the solid-level volume term
};

struct BlemkerFibreParameters {
  double sigma_max_Pa = 3.0e5;  // maximum isometric stress
  double lambda_opt = 1.0;      // optimal fibre stretch
  double lambda_star = 1.4;     // stretch where the passive curve turns linear (λmax)
  double p1 = 0.05;
  double p2 = 6.6;
};

struct StressAndEnergy {
  double energy_density_Pa = 0.0;  // J/m^3 (stored elastic energy)
  double active_density_Pa = 0.0;  // J/m^3, potential of the active stress at fixed a and fv
  Mat3 P = Mat3::Zero();           // first Piola–Kirchhoff stress, Pa
};

// Mooney–Rivlin energy and stress. Precondition: det F > 0 (callers check inversion first).
StressAndEnergy calc_mooney_rivlin(const MooneyRivlinParameters& p, const Mat3& F);

// Blemker's normalised passive and active curves (dimensionless) of the fibre stretch.
double calc_blemker_passive(const BlemkerFibreParameters& p, double lambda);
double calc_blemker_passive_energy(const BlemkerFibreParameters& p, double lambda);  // ∫ f dλ
double calc_blemker_active(const BlemkerFibreParameters& p, double lambda);
// ∫_0^λ̂ f_active dλ̂' (dimensionless): for a fixed activation and fv the active stress derives from
// the potential σmax a fv × this, which the implicit solver's line search uses.
double calc_blemker_active_integral(const BlemkerFibreParameters& p, double lambda);

// Fibre stress for activation a ∈ [0, 1] and force–velocity factor fv (1 = isometric):
// P = σmax/λopt (f_passive + a f_active fv) (F a0 ⊗ a0)/λ. The energy is the passive part only.
// a0: unit rest fibre direction.
StressAndEnergy calc_blemker_fibre(const BlemkerFibreParameters& p, const Mat3& F, const Vec3& a0,
                                   double activation, double fv);

// Tension-only linear fibre (tendon, aponeurosis): W = E/2 (λ − 1)^2 for λ > 1, else 0.
StressAndEnergy calc_tendon_fibre(double modulus_Pa, const Mat3& F, const Vec3& a0);

// ---- Analytic tangents (Newton's stiffness). Mat9 column k + 3 l holds vec(∂P/∂F_kl), with vec
// column-major (row i + 3 j = P_ij), the layout of Eigen's Mat3 storage.
using Mat9 = Eigen::Matrix<double, 9, 9>;

// ∂P/∂F of calc_mooney_rivlin, closed form (directional derivatives of the stress above).
Mat9 calc_mooney_rivlin_tangent(const MooneyRivlinParameters& p, const Mat3& F);

// ∂/∂λ of the normalised Blemker curves (per unit of λ, not λ̂; one-sided at the kinks).
double calc_blemker_passive_slope(const BlemkerFibreParameters& p, double lambda);
double calc_blemker_active_slope(const BlemkerFibreParameters& p, double lambda);

// Adds ∂P/∂F of any fibre stress P = φ(λ)/λ (F a0 ⊗ a0), λ = |F a0|, to D:
//   ∂P_ij/∂F_kl = (φ'/λ − φ/λ²)/λ (F a0)_i a0_j (F a0)_k a0_l + φ/λ δ_ik a0_j a0_l.
// phi = ∂W/∂λ (Pa), dphi = its derivative in λ (Pa).
void add_fibre_tangent(const Mat3& F, const Vec3& a0, double phi, double dphi, Mat9& D);

}  // namespace fascicle
