#include "fascicle/musculotendon/experiments.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/musculotendon/ode.hpp"

#include <algorithm>
#include <cmath>

namespace fascicle {

std::vector<double> ExperimentTable::column(const std::string& name) const {
  const auto it = std::find(columns.begin(), columns.end(), name);
  if (it == columns.end()) throw_internal("experiment table has no column '" + name + "'");
  const size_t j = static_cast<size_t>(it - columns.begin());
  std::vector<double> out;
  out.reserve(rows.size());
  for (const auto& r : rows) out.push_back(r[j]);
  return out;
}

double ExperimentResult::summary_value(const std::string& name) const {
  for (const auto& [k, v] : summary) {
    if (k == name) return v;
  }
  throw_internal("experiment summary has no entry '" + name + "'");
}

namespace {
double cos_pennation(const Musculotendon& m, double lM) {
  const double s = m.parallelogram_height_m / lM;
  return std::sqrt(std::max(0.0, 1.0 - s * s));
}

// Elastic-state component of the ODE vector (fibre length or normalised tendon force).
double elastic_state(const Musculotendon& m, const MuscleState& s) {
  return m.params.model == MuscleModel::degroote2016 ? s.norm_tendon_force : s.fiber_length_m;
}
MuscleState to_state(const Musculotendon& m, double a, double e) {
  MuscleState s;
  s.activation = a;
  if (m.params.model == MuscleModel::degroote2016) s.norm_tendon_force = e;
  else s.fiber_length_m = e;
  return s;
}
double elastic_rate(const Musculotendon& m, const MuscleStateRate& r) {
  return m.params.model == MuscleModel::degroote2016 ? r.norm_tendon_force : r.fiber_length;
}

// Time at which the series crosses `level` (linear interpolation), or NaN.
double crossing_time(const std::vector<double>& t, const std::vector<double>& y, double level) {
  for (size_t i = 1; i < y.size(); ++i) {
    if ((y[i - 1] - level) * (y[i] - level) <= 0.0 && y[i] != y[i - 1]) {
      return t[i - 1] + (level - y[i - 1]) / (y[i] - y[i - 1]) * (t[i] - t[i - 1]);
    }
  }
  return std::numeric_limits<double>::quiet_NaN();
}
}  // namespace

double calc_optimal_musculotendon_length(const Musculotendon& m) {
  const double l0 = m.params.optimal_fiber_length_m;
  const double c = cos_pennation(m, l0);
  const double f = (calc_active_force_length(m, 1.0).value + calc_passive_force_length(m, 1.0).value) * c;
  const double lT = m.params.rigid_tendon ? m.params.tendon_slack_length_m
                                          : calc_tendon_length_for_force(m, f);
  return l0 * c + lT;
}

ExperimentResult run_isometric_experiment(const Musculotendon& m, int samples) {
  ExperimentResult r;
  r.table.columns = {"norm_fiber_length", "fiber_length_m", "musculotendon_length_m",
                     "active_fiber_force_N", "passive_fiber_force_N", "total_fiber_force_N",
                     "tendon_force_N"};
  const double F0 = m.params.max_isometric_force_N, l0 = m.params.optimal_fiber_length_m;
  double peak = 0.0, peak_l = 0.0;
  for (int i = 0; i < samples; ++i) {
    const double l = 0.4 + 1.5 * i / (samples - 1);
    const double lM = l * l0;
    if (lM <= m.parallelogram_height_m * 1.0000001) continue;
    const double c = cos_pennation(m, lM);
    const double fa = F0 * calc_active_force_length(m, l).value;
    const double fp = F0 * calc_passive_force_length(m, l).value;
    const double ft = (fa + fp) * c;
    const double lT = m.params.rigid_tendon ? m.params.tendon_slack_length_m
                                            : calc_tendon_length_for_force(m, ft / F0);
    r.table.rows.push_back({l, lM, lM * c + lT, fa, fp, fa + fp, ft});
    if (fa > peak) peak = fa, peak_l = l;
  }
  r.summary = {{"peak_active_force_N", peak}, {"norm_fiber_length_at_peak", peak_l}};
  return r;
}

ExperimentResult run_tetanus_experiment(const Musculotendon& m, double duration_s, double dt) {
  const double lMT = calc_optimal_musculotendon_length(m);
  const double a0 = m.minimum_activation;
  const MuscleState s0 = calc_equilibrium_state(m, a0, lMT);
  VecX y(2);
  y << s0.activation, elastic_state(m, s0);
  const auto rhs = [&](double, const VecX& x, VecX& dx) {
    const MuscleStateRate r = calc_state_rate(m, to_state(m, x[0], x[1]), 1.0, lMT, 0.0, nullptr);
    dx.resize(2);
    dx << r.activation, elastic_rate(m, r);
  };
  ExperimentResult res;
  res.table.columns = {"time_s", "excitation", "activation", "fiber_length_m", "norm_fiber_length",
                       "fiber_velocity_m_per_s", "tendon_force_N"};
  double h = 1e-5;
  std::vector<double> ts, fs;
  const int n = static_cast<int>(std::round(duration_s / dt));
  for (int i = 0; i <= n; ++i) {
    const double t = i * dt;
    if (i > 0) integrate_dopri5(rhs, (i - 1) * dt, t, y, h);
    MuscleOutputs o;
    calc_state_rate(m, to_state(m, y[0], y[1]), 1.0, lMT, 0.0, &o);
    res.table.rows.push_back({t, 1.0, y[0], o.fiber_length_m, o.norm_fiber_length,
                              o.fiber_velocity_m_per_s, o.tendon_force_N});
    ts.push_back(t);
    fs.push_back(o.tendon_force_N);
  }
  const double f0 = fs.front(), f1 = fs.back();
  const double t10 = crossing_time(ts, fs, f0 + 0.1 * (f1 - f0));
  const double t90 = crossing_time(ts, fs, f0 + 0.9 * (f1 - f0));
  res.summary = {{"musculotendon_length_m", lMT},
                 {"initial_tendon_force_N", f0},
                 {"final_tendon_force_N", f1},
                 {"rise_time_10_90_s", t90 - t10}};
  return res;
}

ExperimentResult run_quick_release_experiment(const Musculotendon& m, double load_fraction,
                                              double mass, double duration_s, double dt) {
  const double lMT0 = calc_optimal_musculotendon_length(m);
  const MuscleState s0 = calc_equilibrium_state(m, 1.0, lMT0);
  const MuscleOutputs iso = calc_static_equilibrium(m, 1.0, lMT0);
  const double load = load_fraction * iso.tendon_force_N;
  // y = [a, elastic state, lMT, vMT]; the load pulls the free end (lengthening), the muscle pulls back.
  VecX y(4);
  y << s0.activation, elastic_state(m, s0), lMT0, 0.0;
  const auto rhs = [&](double, const VecX& x, VecX& dx) {
    MuscleOutputs o;
    const MuscleStateRate r = calc_state_rate(m, to_state(m, x[0], x[1]), 1.0, x[2], x[3], &o);
    dx.resize(4);
    dx << r.activation, elastic_rate(m, r), x[3], (load - o.tendon_force_N) / mass;
  };
  ExperimentResult res;
  res.table.columns = {"time_s", "musculotendon_length_m", "musculotendon_velocity_m_per_s",
                       "fiber_length_m", "fiber_velocity_m_per_s", "tendon_length_m",
                       "tendon_force_N", "load_N"};
  double h = 1e-6;
  const int n = static_cast<int>(std::round(duration_s / dt));
  double v_fiber_end = 0.0;
  for (int i = 0; i <= n; ++i) {
    const double t = i * dt;
    if (i > 0) integrate_dopri5(rhs, (i - 1) * dt, t, y, h);
    MuscleOutputs o;
    calc_state_rate(m, to_state(m, y[0], y[1]), 1.0, y[2], y[3], &o);
    res.table.rows.push_back({t, y[2], y[3], o.fiber_length_m, o.fiber_velocity_m_per_s,
                              o.tendon_length_m, o.tendon_force_N, load});
    v_fiber_end = o.fiber_velocity_m_per_s;
  }
  res.summary = {{"isometric_force_N", iso.tendon_force_N},
                 {"load_N", load},
                 {"initial_musculotendon_length_m", lMT0},
                 {"final_fiber_velocity_m_per_s", v_fiber_end}};
  return res;
}

ExperimentResult run_isotonic_experiment(const Musculotendon& m, const std::vector<double>& loads_in,
                                         double duration_s) {
  std::vector<double> loads = loads_in;
  if (loads.empty()) loads = {0.02, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3};
  const auto& p = m.params;
  const double F0 = p.max_isometric_force_N, l0 = p.optimal_fiber_length_m;
  const double vscale = l0 * p.max_contraction_velocity;
  const double c0 = cos_pennation(m, l0);
  const double f_iso = (calc_active_force_length(m, 1.0).value + calc_passive_force_length(m, 1.0).value) * c0;
  ExperimentResult res;
  res.table.columns = {"load_fraction", "load_N", "initial_fiber_velocity_m_per_s",
                       "initial_norm_fiber_velocity", "force_velocity_multiplier",
                       "mean_fiber_velocity_m_per_s", "fiber_length_end_m"};
  for (double q : loads) {
    const double load_norm = q * f_iso;  // tendon force / F0, held constant
    // Fibre-length ODE with the tendon force fixed by the load.
    const auto velocity = [&](double lM) {
      const double c = cos_pennation(m, lM);
      return calc_norm_fiber_velocity(m, 1.0, lM / l0, load_norm / c) * vscale;
    };
    VecX y(1);
    y << l0;
    const auto rhs = [&](double, const VecX& x, VecX& dx) {
      dx.resize(1);
      dx[0] = velocity(std::max(x[0], m.min_fiber_length_m));
    };
    const double v0 = velocity(l0);
    double h = 1e-5;
    integrate_dopri5(rhs, 0.0, duration_s, y, h);
    const double a = 1.0;
    const double fv = calc_force_velocity(m, a, v0 / vscale).value;
    res.table.rows.push_back({q, load_norm * F0, v0, v0 / vscale, fv, (y[0] - l0) / duration_s, y[0]});
  }
  res.summary = {{"isometric_tendon_force_N", f_iso * F0}};
  return res;
}

}  // namespace fascicle
