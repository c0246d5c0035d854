#include "fascicle/musculotendon/ode.hpp"

#include "fascicle/core/error.hpp"

#include <algorithm>
#include <cmath>

namespace fascicle {

OdeStats integrate_dopri5(const OdeRhs& f, double t0, double t1, VecX& y, double& h,
                          const OdeOptions& opt) {
  // Dormand & Prince (1980) coefficients.
  constexpr double c2 = 1.0 / 5, c3 = 3.0 / 10, c4 = 4.0 / 5, c5 = 8.0 / 9;
  constexpr double a21 = 1.0 / 5;
  constexpr double a31 = 3.0 / 40, a32 = 9.0 / 40;
  constexpr double a41 = 44.0 / 45, a42 = -56.0 / 15, a43 = 32.0 / 9;
  constexpr double a51 = 19372.0 / 6561, a52 = -25360.0 / 2187, a53 = 64448.0 / 6561,
                   a54 = -212.0 / 729;
  constexpr double a61 = 9017.0 / 3168, a62 = -355.0 / 33, a63 = 46732.0 / 5247, a64 = 49.0 / 176,
                   a65 = -5103.0 / 18656;
  constexpr double b1 = 35.0 / 384, b3 = 500.0 / 1113, b4 = 125.0 / 192, b5 = -2187.0 / 6784,
                   b6 = 11.0 / 84;
  constexpr double e1 = 71.0 / 57600, e3 = -71.0 / 16695, e4 = 71.0 / 1920,
                   e5 = -17253.0 / 339200, e6 = 22.0 / 525, e7 = -1.0 / 40;
  OdeStats stats;
  const long n = y.size();
  VecX k1(n), k2(n), k3(n), k4(n), k5(n), k6(n), k7(n), ytmp(n), ynew(n), err(n);
  if (!(h > 0.0)) h = opt.initial_step_s;
  double t = t0;
  f(t, y, k1);
  while (t < t1) {
    if (stats.accepted + stats.rejected > opt.max_steps) {
      throw_numerical("ODE integration exceeded its step budget at t = " + std::to_string(t) + " s");
    }
    h = std::min({h, opt.max_step_s, t1 - t});
    ytmp = y + h * a21 * k1;
    f(t + c2 * h, ytmp, k2);
    ytmp = y + h * (a31 * k1 + a32 * k2);
    f(t + c3 * h, ytmp, k3);
    ytmp = y + h * (a41 * k1 + a42 * k2 + a43 * k3);
    f(t + c4 * h, ytmp, k4);
    ytmp = y + h * (a51 * k1 + a52 * k2 + a53 * k3 + a54 * k4);
    f(t + c5 * h, ytmp, k5);
    ytmp = y + h * (a61 * k1 + a62 * k2 + a63 * k3 + a64 * k4 + a65 * k5);
    f(t + h, ytmp, k6);
    ynew = y + h * (b1 * k1 + b3 * k3 + b4 * k4 + b5 * k5 + b6 * k6);
    f(t + h, ynew, k7);
    err = h * (e1 * k1 + e3 * k3 + e4 * k4 + e5 * k5 + e6 * k6 + e7 * k7);
    double norm = 0.0;
    for (long i = 0; i < n; ++i) {
      const double sc = opt.atol + opt.rtol * std::max(std::abs(y[i]), std::abs(ynew[i]));
      norm = std::max(norm, std::abs(err[i]) / sc);
    }
    if (!std::isfinite(norm)) {
      if (h < 1e-14) throw_numerical("non-finite state derivative at t = " + std::to_string(t) + " s");
      h *= 0.25;
      ++stats.rejected;
      continue;
    }
    if (norm <= 1.0) {
      t += h;
      y = ynew;
      k1 = k7;
      ++stats.accepted;
      stats.last_step_s = h;
      h *= std::min(5.0, std::max(0.2, 0.9 * std::pow(std::max(norm, 1e-10), -0.2)));
    } else {
      h *= std::max(0.1, 0.9 * std::pow(norm, -0.2));
      ++stats.rejected;
      if (h < 1e-14) throw_numerical("ODE step size underflow at t = " + std::to_string(t) + " s");
    }
  }
  return stats;
}

}  // namespace fascicle
