// Mooney–Rivlin ground substance and Blemker et al. 2005 fibre law (see materials.hpp).
#include "fascicle/dynamics/materials.hpp"

#include <cmath>

namespace fascicle {

StressAndEnergy calc_mooney_rivlin(const MooneyRivlinParameters& p, const Mat3& F) {
  const double J = F.determinant();
  const Mat3 FinvT = F.inverse().transpose();
  const Mat3 C = F.transpose() * F;
  const double I1 = C.trace();
  const double I2 = 0.5 * (I1 * I1 - (C * C).trace());
  const double cbrt_J = std::cbrt(J);  // J^{-2/3} through cbrt: cheaper than pow
  const double J23 = 1.0 / (cbrt_J * cbrt_J);
  const double J43 = J23 * J23;
  const double lnJ = p.bulk_modulus_Pa != 0.0 ? std::log(J) : 0.0;
  StressAndEnergy out;
  out.energy_density_Pa = p.c1_Pa * (J23 * I1 - 3.0) + p.c2_Pa * (J43 * I2 - 3.0) +
                          0.5 * p.bulk_modulus_Pa * lnJ * lnJ;
  // dĪ1/dF = J^{-2/3} (2F − 2/3 I1 F^{-T});  dĪ2/dF = J^{-4/3} (2 (I1 F − F C) − 4/3 I2 F^{-T}).
  out.P = p.c1_Pa * J23 * (2.0 * F - (2.0 / 3.0) * I1 * FinvT) +
          p.c2_Pa * J43 * (2.0 * (I1 * F - F * C) - (4.0 / 3.0) * I2 * FinvT) +
          p.bulk_modulus_Pa * lnJ * FinvT;
  return out;
}

namespace {
// Slope and offset of the linear passive branch (C¹ at λ̂*).
void passive_linear_branch(const BlemkerFibreParameters& p, double& p3, double& p4) {
  const double s = p.lambda_star / p.lambda_opt;
  p3 = p.p1 * p.p2 * std::exp(p.p2 * (s - 1.0));
  p4 = p.p1 * (std::exp(p.p2 * (s - 1.0)) - 1.0) - p3 * s;
}
}  // namespace

double calc_blemker_passive(const BlemkerFibreParameters& p, double lambda) {
  const double l = lambda / p.lambda_opt;
  const double s = p.lambda_star / p.lambda_opt;
  if (l <= 1.0) return 0.0;
  if (l < s) return p.p1 * (std::exp(p.p2 * (l - 1.0)) - 1.0);
  double p3, p4;
  passive_linear_branch(p, p3, p4);
  return p3 * l + p4;
}

// ∫_1^λ̂ f_passive dλ̂' (dimensionless; energy density = σmax × this).
double calc_blemker_passive_energy(const BlemkerFibreParameters& p, double lambda) {
  const double l = lambda / p.lambda_opt;
  const double s = p.lambda_star / p.lambda_opt;
  auto exp_part = [&](double x) {
    return p.p1 * ((std::exp(p.p2 * (x - 1.0)) - 1.0) / p.p2 - (x - 1.0));
  };
  if (l <= 1.0) return 0.0;
  if (l < s) return exp_part(l);
  double p3, p4;
  passive_linear_branch(p, p3, p4);
  return exp_part(s) + 0.5 * p3 * (l * l - s * s) + p4 * (l - s);
}

double calc_blemker_active(const BlemkerFibreParameters& p, double lambda) {
  const double l = lambda / p.lambda_opt;
  if (l <= 0.4 || l >= 1.6) return 0.0;
  if (l < 0.6) return 9.0 * (l - 0.4) * (l - 0.4);
  if (l <= 1.4) return 1.0 - 4.0 * (1.0 - l) * (1.0 - l);
  return 9.0 * (l - 1.6) * (l - 1.6);
}

double calc_blemker_active_integral(const BlemkerFibreParameters& p, double lambda) {
  const double l = lambda / p.lambda_opt;
  if (l <= 0.4) return 0.0;
  if (l < 0.6) return 3.0 * (l - 0.4) * (l - 0.4) * (l - 0.4);
  const double at06 = 0.024;
  if (l <= 1.4) return at06 + (l - 0.6) - (4.0 / 3.0) * ((l - 1.0) * (l - 1.0) * (l - 1.0) + 0.064);
  const double at14 = at06 + 0.8 - (4.0 / 3.0) * 0.128;
  if (l < 1.6) return at14 + 3.0 * ((l - 1.6) * (l - 1.6) * (l - 1.6) + 0.008);
  return at14 + 0.024;
}

StressAndEnergy calc_blemker_fibre(const BlemkerFibreParameters& p, const Mat3& F, const Vec3& a0,
                                   double activation, double fv) {
  const Vec3 Fa = F * a0;
  const double lambda = Fa.norm();
  StressAndEnergy out;
  out.energy_density_Pa = p.sigma_max_Pa * calc_blemker_passive_energy(p, lambda);
  out.active_density_Pa = p.sigma_max_Pa * activation * fv * calc_blemker_active_integral(p, lambda);
  const double dWdl = p.sigma_max_Pa / p.lambda_opt *
                      (calc_blemker_passive(p, lambda) +
                       activation * calc_blemker_active(p, lambda) * fv);
  // dλ/dF = (F a0 ⊗ a0)/λ
  if (lambda > 0.0) out.P = (dWdl / lambda) * Fa * a0.transpose();
  return out;
}

StressAndEnergy calc_tendon_fibre(double modulus_Pa, const Mat3& F, const Vec3& a0) {
  const Vec3 Fa = F * a0;
  const double lambda = Fa.norm();
  StressAndEnergy out;
  if (lambda <= 1.0) return out;
  out.energy_density_Pa = 0.5 * modulus_Pa * (lambda - 1.0) * (lambda - 1.0);
  out.P = (modulus_Pa * (lambda - 1.0) / lambda) * Fa * a0.transpose();
  return out;
}

// Directional derivative of the stress of calc_mooney_rivlin along dF = e_k e_lᵀ, per column:
//   d(J^{-2/3}) = −2/3 J^{-2/3} F^{-T}:dF,  dI1 = 2 F:dF,  dI2 = 2 (I1 F − F C):dF,
//   d(F^{-T}) = −F^{-T} dFᵀ F^{-T},  d(F C) = dF C + F dFᵀ F + F Fᵀ dF.
Mat9 calc_mooney_rivlin_tangent(const MooneyRivlinParameters& p, const Mat3& F) {
  const double J = F.determinant();
  const Mat3 FinvT = F.inverse().transpose();
  const Mat3 C = F.transpose() * F;
  const Mat3 FC = F * C;
  const Mat3 FFt = F * F.transpose();
  const double I1 = C.trace();
  const double I2 = 0.5 * (I1 * I1 - (C * C).trace());
  const double cbrt_J = std::cbrt(J);  // J^{-2/3} through cbrt: cheaper than pow
  const double J23 = 1.0 / (cbrt_J * cbrt_J);
  const double J43 = J23 * J23;
  const double lnJ = p.bulk_modulus_Pa != 0.0 ? std::log(J) : 0.0;
  const Mat3 P1 = 2.0 * F - (2.0 / 3.0) * I1 * FinvT;
  const Mat3 P2 = 2.0 * (I1 * F - FC) - (4.0 / 3.0) * I2 * FinvT;
  const double c1 = p.c1_Pa, c2 = p.c2_Pa, kappa = p.bulk_modulus_Pa;
  Mat9 D;
  for (int l = 0; l < 3; ++l)
    for (int k = 0; k < 3; ++k) {
      const double tr = FinvT(k, l);  // F^{-T} : dF
      const double dI1 = 2.0 * F(k, l);
      const double dI2 = 2.0 * (I1 * F(k, l) - FC(k, l));
      const Mat3 dFinvT = -FinvT.col(l) * FinvT.row(k);
      Mat3 dF = Mat3::Zero();
      dF(k, l) = 1.0;
      Mat3 dFC = F.col(l) * F.row(k) + FFt.col(k) * Mat3::Identity().row(l);
      dFC.row(k) += C.row(l);
      const Mat3 dP1 = 2.0 * dF - (2.0 / 3.0) * (dI1 * FinvT + I1 * dFinvT);
      const Mat3 dP2 = 2.0 * (dI1 * F + I1 * dF - dFC) - (4.0 / 3.0) * (dI2 * FinvT + I2 * dFinvT);
      Mat3 dP = c1 * J23 * (dP1 - (2.0 / 3.0) * tr * P1) + c2 * J43 * (dP2 - (4.0 / 3.0) * tr * P2);
      if (kappa != 0.0) dP += kappa * (tr * FinvT + lnJ * dFinvT);
      D.col(k + 3 * l) = Eigen::Map<const Eigen::Matrix<double, 9, 1>>(dP.data());
    }
  return D;
}

double calc_blemker_passive_slope(const BlemkerFibreParameters& p, double lambda) {
  const double l = lambda / p.lambda_opt;
  const double s = p.lambda_star / p.lambda_opt;
  if (l <= 1.0) return 0.0;
  if (l < s) return p.p1 * p.p2 * std::exp(p.p2 * (l - 1.0)) / p.lambda_opt;
  double p3, p4;
  passive_linear_branch(p, p3, p4);
  return p3 / p.lambda_opt;
}

double calc_blemker_active_slope(const BlemkerFibreParameters& p, double lambda) {
  const double l = lambda / p.lambda_opt;
  double d = 0.0;
  if (l <= 0.4 || l >= 1.6) d = 0.0;
  else if (l < 0.6) d = 18.0 * (l - 0.4);
  else if (l <= 1.4) d = 8.0 * (1.0 - l);
  else d = 18.0 * (l - 1.6);
  return d / p.lambda_opt;
}

void add_fibre_tangent(const Mat3& F, const Vec3& a0, double phi, double dphi, Mat9& D) {
  const Vec3 Fa = F * a0;
  const double lambda = Fa.norm();
  if (!(lambda > 0.0)) return;
  const double psi = phi / lambda;
  const double c = (dphi / lambda - phi / (lambda * lambda)) / lambda;
  Mat3 B = Fa * a0.transpose();
  const Eigen::Map<const Eigen::Matrix<double, 9, 1>> b(B.data());
  D.noalias() += c * b * b.transpose();
  // ψ δ_ik a0_j a0_l: rows i + 3 j, columns k + 3 l.
  for (int l = 0; l < 3; ++l)
    for (int j = 0; j < 3; ++j) {
      const double v = psi * a0[j] * a0[l];
      for (int i = 0; i < 3; ++i) D(i + 3 * j, i + 3 * l) += v;
    }
}

}  // namespace fascicle
