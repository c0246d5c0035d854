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
  const double J23 = std::pow(J, -2.0 / 3.0);
  const double J43 = J23 * J23;
  const double lnJ = std::log(J);
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
  if (l < 0.6) return 3.0 * std::pow(l - 0.4, 3);
  const double at06 = 0.024;
  if (l <= 1.4) return at06 + (l - 0.6) - (4.0 / 3.0) * (std::pow(l - 1.0, 3) + 0.064);
  const double at14 = at06 + 0.8 - (4.0 / 3.0) * 0.128;
  if (l < 1.6) return at14 + 3.0 * (std::pow(l - 1.6, 3) + 0.008);
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

}  // namespace fascicle
