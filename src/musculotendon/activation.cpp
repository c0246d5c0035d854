#include "fascicle/musculotendon/activation.hpp"

#include <algorithm>
#include <cmath>

namespace fascicle {

double calc_activation_rate_opensim(const ActivationParameters& p, double a, double u) {
  a = std::clamp(a, p.minimum_activation, 1.0);
  const double tau = (u > a) ? p.activation_time_constant_s * (0.5 + 1.5 * a)
                             : p.deactivation_time_constant_s / (0.5 + 1.5 * a);
  return (u - a) / tau;
}

double calc_activation_rate_zajac(const ActivationParameters& p, double a, double u) {
  const double beta = p.activation_time_constant_s / p.deactivation_time_constant_s;
  return (u - (beta + (1.0 - beta) * u) * a) / p.activation_time_constant_s;
}

double calc_activation_rate_degroote(const ActivationParameters& p, double a, double u) {
  const double k = 0.5 + 1.5 * a;
  const double f = 0.5 * std::tanh(p.smoothing * (u - a));
  const double rate = (f + 0.5) / (p.activation_time_constant_s * k) +
                      (0.5 - f) * k / p.deactivation_time_constant_s;
  return rate * (u - a);
}

}  // namespace fascicle
