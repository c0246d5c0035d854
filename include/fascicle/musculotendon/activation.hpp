// Activation dynamics: excitation u(t) ∈ [0, 1] → activation a(t). Rates in 1/s.
#pragma once

namespace fascicle {

struct ActivationParameters {
  double activation_time_constant_s = 0.015;    // τa
  double deactivation_time_constant_s = 0.050;  // τd
  double minimum_activation = 0.0;              // a_min (OpenSim clamps a to [a_min, 1])
  double smoothing = 0.1;                       // b of the tanh switch (DeGroote form only;
                                                // OpenSim's default 0.1)
};

// OpenSim MuscleFirstOrderActivationDynamicModel (Thelen 2003 / Millard 2012):
//   ȧ = (u − a)/τ,  τ = τa (0.5 + 1.5 a) if u > a, else τd / (0.5 + 1.5 a); a clamped to [a_min, 1].
double calc_activation_rate_opensim(const ActivationParameters& p, double activation,
                                    double excitation);

// Seed 001 (Zajac 1989):  τa ȧ + (τa/τd + (1 − τa/τd) u) a = u.
double calc_activation_rate_zajac(const ActivationParameters& p, double activation,
                                  double excitation);

// De Groote et al. 2016, eq. 1-2 (tanh-smoothed switch between activation and deactivation):
//   f = 0.5 tanh(b (u − a)),  ȧ = [(f + 0.5)/(τa (0.5 + 1.5a)) + (0.5 − f)(0.5 + 1.5a)/τd] (u − a).
double calc_activation_rate_degroote(const ActivationParameters& p, double activation,
                                     double excitation);

}  // namespace fascicle
