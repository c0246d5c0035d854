// Adaptive explicit Runge-Kutta integration (Dormand-Prince 5(4), FSAL) with per-component error
// control |e_i| ≤ atol + rtol·|y_i|, used for musculotendon dynamics. Stiff tendons make the
// fibre-length equation stiff; the controller then shrinks the step until the embedded error
// estimate is met, so accuracy is guaranteed at the cost of more steps (docs/musculotendon.md).
#pragma once

#include "fascicle/core/types.hpp"

#include <functional>

namespace fascicle {

struct OdeOptions {
  double rtol = 1e-7;
  double atol = 1e-10;
  double initial_step_s = 1e-5;
  double max_step_s = 1e-3;
  long max_steps = 2'000'000;
};

struct OdeStats {
  long accepted = 0;
  long rejected = 0;
  double last_step_s = 0.0;
};

// dy/dt = f(t, y). Throws fascicle::Error (numerical) if the step size underflows, the step
// budget is exhausted or the right-hand side is not finite.
using OdeRhs = std::function<void(double t, const VecX& y, VecX& dydt)>;

// Integrates y from t0 to t1 in place; `step_s` carries the step size between calls.
OdeStats integrate_dopri5(const OdeRhs& f, double t0, double t1, VecX& y, double& step_s,
                          const OdeOptions& options = {});

}  // namespace fascicle
