// Activation dynamics, static equilibrium, dynamics energy balance, parameter validation.
#include "fascicle/core/error.hpp"
#include "fascicle/musculotendon/activation.hpp"
#include "fascicle/musculotendon/experiments.hpp"
#include "fascicle/musculotendon/muscle.hpp"
#include "fascicle/musculotendon/ode.hpp"
#include "fascicle/musculotendon/params_json.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace fascicle;

namespace {
MuscleParameters test_muscle(MuscleModel model, double pennation = 0.2) {
  MuscleParameters p = default_muscle_parameters(model);
  p.name = std::string("test_") + to_string(model);
  p.max_isometric_force_N = 1200.0;
  p.optimal_fiber_length_m = 0.09;
  p.tendon_slack_length_m = 0.25;
  p.pennation_at_optimal_rad = pennation;
  return p;
}

// Time for activation to go between two levels under a constant excitation (explicit RK45).
double activation_crossing_time(const ActivationParameters& ap, double a0, double u, double level) {
  VecX y(1);
  y << a0;
  double h = 1e-6, t = 0.0;
  const double dt = 1e-5;
  double prev = a0;
  for (int i = 0; i < 200000; ++i) {
    integrate_dopri5([&](double, const VecX& x, VecX& dx) {
      dx.resize(1);
      dx[0] = calc_activation_rate_opensim(ap, x[0], u);
    }, t, t + dt, y, h, {.rtol = 1e-10, .atol = 1e-12});
    t += dt;
    if ((prev - level) * (y[0] - level) <= 0.0) {
      return t - dt + (level - prev) / (y[0] - prev) * dt;
    }
    prev = y[0];
  }
  return NAN;
}
}  // namespace

TEST(Activation, OpenSimRiseAndFallTimes) {
  // OpenSim's activation-dynamics check: 10-90 % rise ≈ 3 τa, 90-10 % fall ≈ 2.17 τd.
  const ActivationParameters ap{0.015, 0.050, 0.0, 10.0};
  const double rise = activation_crossing_time(ap, 0.0, 1.0, 0.9) -
                      activation_crossing_time(ap, 0.0, 1.0, 0.1);
  const double fall = activation_crossing_time(ap, 1.0, 0.0, 0.1) -
                      activation_crossing_time(ap, 1.0, 0.0, 0.9);
  EXPECT_NEAR(rise / ap.activation_time_constant_s, 3.0, 0.3);
  EXPECT_NEAR(fall / ap.deactivation_time_constant_s, 2.17, 0.2);
}

TEST(Activation, FormsAgreeOnFixedPointsAndSigns) {
  const ActivationParameters ap{0.015, 0.050, 0.0, 10.0};
  for (double a : {0.0, 0.3, 1.0}) {
    EXPECT_NEAR(calc_activation_rate_opensim(ap, a, a), 0.0, 1e-12);
    EXPECT_NEAR(calc_activation_rate_degroote(ap, a, a), 0.0, 1e-12);
  }
  // Zajac's form at u = 1: ȧ = (1 − a)/τa; at u = 0: ȧ = −a/τd.
  EXPECT_NEAR(calc_activation_rate_zajac(ap, 0.4, 1.0), 0.6 / 0.015, 1e-9);
  EXPECT_NEAR(calc_activation_rate_zajac(ap, 0.4, 0.0), -0.4 / 0.050, 1e-9);
  // DeGroote with a sharp switch approaches OpenSim's form away from u = a.
  EXPECT_NEAR(calc_activation_rate_degroote(ap, 0.2, 1.0), calc_activation_rate_opensim(ap, 0.2, 1.0),
              1e-3 * std::abs(calc_activation_rate_opensim(ap, 0.2, 1.0)));
}

class EquilibriumGrid : public ::testing::TestWithParam<std::tuple<MuscleModel, double>> {};

TEST_P(EquilibriumGrid, ResidualVanishesOverActivationAndLength) {
  const auto [model, pennation] = GetParam();
  const Musculotendon m = compile_musculotendon(test_muscle(model, pennation));
  const double l0 = m.params.optimal_fiber_length_m, lTs = m.params.tendon_slack_length_m;
  const double F0 = m.params.max_isometric_force_N;
  int solved = 0;
  for (double a : {0.0, 0.01, 0.05, 0.3, 0.7, 1.0}) {
    for (int i = 0; i <= 40; ++i) {
      const double lMT = lTs + (0.2 + 1.8 * i / 40.0) * l0;
      for (double vMT : {0.0, -0.3, 0.2}) {
        const MuscleOutputs o = calc_static_equilibrium(m, a, lMT, vMT);
        ASSERT_TRUE(std::isfinite(o.fiber_length_m));
        ASSERT_TRUE(std::isfinite(o.tendon_force_N));
        EXPECT_NEAR(o.fiber_length_m * std::cos(o.pennation_rad) + o.tendon_length_m, lMT, 1e-12);
        if (o.tendon_force_N == 0.0 && o.fiber_force_along_tendon_N < 0.0) {
          // Fast shortening at low activation: the fibre force is compressive at every length,
          // which a slack tendon cannot balance; the solver returns the slack-tendon state.
          EXPECT_NEAR(o.tendon_length_m, lTs, 1e-12);
        } else if (!o.fiber_at_lower_bound) {
          EXPECT_NEAR(o.fiber_force_along_tendon_N, o.tendon_force_N, 1e-9 * F0)
              << to_string(model) << " a=" << a << " lMT=" << lMT << " v=" << vMT;
          ++solved;
        } else {
          EXPECT_NEAR(o.fiber_length_m, m.min_fiber_length_m, 1e-15);
        }
      }
    }
  }
  EXPECT_GT(solved, 500);
}

INSTANTIATE_TEST_SUITE_P(Models, EquilibriumGrid,
                         ::testing::Combine(::testing::Values(MuscleModel::thelen2003,
                                                              MuscleModel::millard2012,
                                                              MuscleModel::degroote2016),
                                            ::testing::Values(0.0, 0.35)));

TEST(Equilibrium, RigidTendonIsClosedForm) {
  MuscleParameters p = test_muscle(MuscleModel::millard2012, 0.3);
  p.rigid_tendon = true;
  const Musculotendon m = compile_musculotendon(p);
  const double lMT = p.tendon_slack_length_m + 0.08;
  const MuscleOutputs o = calc_static_equilibrium(m, 1.0, lMT);
  const double h = p.optimal_fiber_length_m * std::sin(0.3);
  EXPECT_NEAR(o.fiber_length_m, std::sqrt(0.08 * 0.08 + h * h), 1e-15);
  EXPECT_NEAR(o.tendon_force_N, o.fiber_force_along_tendon_N, 1e-12);
}

TEST(Equilibrium, SlackTendonAndShortPath) {
  const Musculotendon m = compile_musculotendon(test_muscle(MuscleModel::thelen2003, 0.2));
  // Path shorter than the tendon: fibre at its lower bound, no tendon force, no NaN.
  const MuscleOutputs o = calc_static_equilibrium(m, 0.5, 0.2);
  EXPECT_TRUE(o.fiber_at_lower_bound);
  EXPECT_EQ(o.tendon_force_N, 0.0);
  EXPECT_NEAR(o.pennation_rad, std::acos(0.1), 1e-12);
}

TEST(Equilibrium, BadInputNamesTheMuscle) {
  const Musculotendon m = compile_musculotendon(test_muscle(MuscleModel::millard2012));
  try {
    calc_static_equilibrium(m, 1.5, 0.3);
    FAIL() << "activation 1.5 accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("test_millard"), std::string::npos);
  }
  EXPECT_THROW(calc_static_equilibrium(m, 0.5, std::nan("")), Error);
}

TEST(Parameters, ValidationNamesMuscleAndParameter) {
  const auto expect_bad = [](MuscleParameters p, const std::string& parameter) {
    try {
      validate(p);
      FAIL() << parameter << " accepted";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::bad_input);
      const std::string w = e.what();
      EXPECT_NE(w.find(p.name), std::string::npos) << w;
      EXPECT_NE(w.find(parameter), std::string::npos) << w;
    }
  };
  MuscleParameters p = test_muscle(MuscleModel::thelen2003);
  p.name = "soleus_r";
  auto q = p; q.optimal_fiber_length_m = 0.0; expect_bad(q, "optimal_fiber_length");
  q = p; q.tendon_slack_length_m = -0.1; expect_bad(q, "tendon_slack_length");
  q = p; q.pennation_at_optimal_rad = 1.6; expect_bad(q, "pennation_angle_at_optimal");
  q = p; q.activation_time_constant_s = 0.0; expect_bad(q, "activation_time_constant");
  q = p; q.minimum_activation = 1.2; expect_bad(q, "minimum_activation");
  q = p; q.max_isometric_force_N = -5; expect_bad(q, "max_isometric_force");
  q = p; q.thelen.Flen = 0.9; expect_bad(q, "Flen");
  MuscleParameters mm = test_muscle(MuscleModel::millard2012);
  mm.name = "gmax";
  mm.millard.fiber_damping = -1; expect_bad(mm, "fiber_damping");
}

TEST(Parameters, PcsaAndMaxIsometricForce) {
  // 300 cm³, l0 = 10 cm, α0 = 0: PCSA = 30 cm², F0 = 25 N/cm² · 30 cm² = 750 N.
  const double pcsa = calc_pcsa(300e-6, 0.1, 0.0);
  EXPECT_NEAR(pcsa, 30e-4, 1e-15);
  EXPECT_NEAR(calc_max_isometric_force(pcsa), 750.0, 1e-9);
  EXPECT_NEAR(calc_max_isometric_force(calc_pcsa(300e-6, 0.1, std::acos(0.5)), 60e4), 900.0, 1e-9);
  EXPECT_THROW(calc_pcsa(-1.0, 0.1, 0.0), Error);
}

TEST(Parameters, JsonFileRoundTripAndErrors) {
  const MuscleParameters p = parse_muscle_parameters_json(
      R"({"name": "vastus", "model": "thelen", "optimal_fiber_length_m": 0.087,
          "tendon_slack_length_m": 0.19, "pennation_at_optimal_deg": 5, "volume_m3": 4.0e-4,
          "thelen": {"FmaxTendonStrain": 0.033}})", "p.json");
  EXPECT_EQ(p.model, MuscleModel::thelen2003);
  EXPECT_NEAR(p.pennation_at_optimal_rad, 5 * M_PI / 180, 1e-15);
  EXPECT_NEAR(p.max_isometric_force_N, 25e4 * 4e-4 * std::cos(5 * M_PI / 180) / 0.087, 1e-9);
  EXPECT_EQ(p.thelen.FmaxTendonStrain, 0.033);
  try {
    parse_muscle_parameters_json(R"({"name": "x", "optimal_fibre_length": 0.1})", "p.json");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.context().json_path, "/optimal_fibre_length");
    EXPECT_EQ(e.context().file, "p.json");
  }
  EXPECT_THROW(parse_muscle_parameters_json(R"({"tendon_slack_length_m": 0})", "p.json"), Error);
  EXPECT_THROW(parse_muscle_parameters_json("{", "p.json"), Error);
}

// A muscle pulling a free block: KE + tendon + passive energy − active work + damping loss = const.
class EnergyBalance : public ::testing::TestWithParam<MuscleModel> {};

TEST_P(EnergyBalance, BlockPulledByMuscle) {
  const MuscleModel model = GetParam();
  const Musculotendon m = compile_musculotendon(test_muscle(model, 0.25));
  const double mass = 2.0;
  const double lMT0 = calc_optimal_musculotendon_length(m) + 0.2 * m.params.optimal_fiber_length_m;
  const MuscleState s0 = calc_equilibrium_state(m, 0.3, lMT0);
  const bool degroote = model == MuscleModel::degroote2016;
  // y = [a, elastic state, x = lMT, v = vMT, W_active, W_damping]
  VecX y(6);
  y << s0.activation, degroote ? s0.norm_tendon_force : s0.fiber_length_m, lMT0, 0.0, 0.0, 0.0;
  const auto state = [&](const VecX& x) {
    MuscleState s;
    s.activation = x[0];
    (degroote ? s.norm_tendon_force : s.fiber_length_m) = x[1];
    return s;
  };
  const auto rhs = [&](double, const VecX& x, VecX& dx) {
    MuscleOutputs o;
    const MuscleStateRate r = calc_state_rate(m, state(x), 0.8, x[2], x[3], &o);
    dx.resize(6);
    dx << r.activation, degroote ? r.norm_tendon_force : r.fiber_length, x[3],
        -o.tendon_force_N / mass, o.fiber_active_power_W,
        o.damping_fiber_force_N * o.fiber_velocity_m_per_s;
  };
  const auto energy = [&](const VecX& x) {
    MuscleOutputs o;
    calc_state_rate(m, state(x), 0.8, x[2], x[3], &o);
    EXPECT_FALSE(o.fiber_at_lower_bound);
    return 0.5 * mass * x[3] * x[3] + o.tendon_energy_J + o.fiber_passive_energy_J - x[4] + x[5];
  };
  const double e0 = energy(y);
  double h = 1e-6, kinetic_max = 0.0, work_max = 0.0;
  for (int i = 1; i <= 40; ++i) {
    integrate_dopri5(rhs, (i - 1) * 1e-3, i * 1e-3, y, h, {.rtol = 1e-10, .atol = 1e-13});
    kinetic_max = std::max(kinetic_max, 0.5 * mass * y[3] * y[3]);
    work_max = std::max(work_max, std::abs(y[4]));
    EXPECT_NEAR(energy(y), e0, 1e-6 * std::max(1.0, work_max)) << "t = " << i << " ms";
  }
  EXPECT_GT(kinetic_max, 1e-3);  // the block really moved
  EXPECT_GT(work_max, 1e-2);
}

INSTANTIATE_TEST_SUITE_P(Models, EnergyBalance,
                         ::testing::Values(MuscleModel::thelen2003, MuscleModel::millard2012,
                                           MuscleModel::degroote2016));

TEST(Experiments, TetanusRiseAndIsotonicForceVelocity) {
  for (MuscleModel model : {MuscleModel::thelen2003, MuscleModel::millard2012, MuscleModel::degroote2016}) {
    const Musculotendon m = compile_musculotendon(test_muscle(model, 0.1));
    const ExperimentResult t = run_tetanus_experiment(m, 0.6, 1e-3);
    const double fiso = calc_static_equilibrium(m, 1.0, calc_optimal_musculotendon_length(m)).tendon_force_N;
    EXPECT_NEAR(t.summary_value("final_tendon_force_N"), fiso, 2e-3 * fiso) << to_string(model)
        << " initial " << t.summary_value("initial_tendon_force_N");
    const double rise = t.summary_value("rise_time_10_90_s");
    EXPECT_GT(rise, 1.0 * m.params.activation_time_constant_s);
    EXPECT_LT(rise, 0.2);
    const ExperimentResult iso = run_isotonic_experiment(m, {0.1, 0.5, 0.9, 1.2}, 0.01);
    const auto v = iso.table.column("initial_norm_fiber_velocity");
    const auto fv = iso.table.column("force_velocity_multiplier");
    // Shortening below the isometric load, lengthening above; velocity increases with load.
    EXPECT_LT(v[0], v[1]);
    EXPECT_LT(v[1], v[2]);
    EXPECT_LT(v[2], 0.0);
    EXPECT_GT(v[3], 0.0);
    EXPECT_LT(fv[0], fv[1]);
  }
}
