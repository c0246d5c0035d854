// Benchmarks of the solid-muscle dynamics (docs/solid-dynamics.md, docs/benchmarks.md):
// one backward-Euler step of a 6 x 6 x 10 solid (360 control points), force evaluation,
// factorisation, and the explicit integrator.
#include "fascicle/bspline/fitting.hpp"
#include "fascicle/bspline/lattice.hpp"
#include "fascicle/bspline/tessellation.hpp"
#include "fascicle/dynamics/solid_dynamics.hpp"
#include "fascicle/io/mesh_io.hpp"

#include <Eigen/Dense>
#include <Eigen/SparseCholesky>
#include <benchmark/benchmark.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <vector>

using namespace fascicle;

namespace {

std::shared_ptr<const SolidDynamicsModel> make_model(int degree, int qpts, VolumeMethod vol) {
  LatticeDesign d = make_cubical_lattice(Vec3(0, 0, 0), Vec3(0.03, 0.03, 0.10),
                                         {degree, degree, degree}, {6, 6, 10});
  SolidDynamicsSpec s;
  s.volume = vol;
  s.quadrature_points_per_span = qpts;
  s.attachments.push_back({"origin", -1, find_end_layer(d.solid, 0)});
  s.attachments.push_back({"insertion", -1, find_end_layer(d.solid, 1)});
  return std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(d.solid, s));
}

// args: degree, quadrature points per span, Newton (1: full, 0: modified within a step,
// 2: factorisation kept over up to 20 steps, >= 10: over up to that many steps; these rows keep
// the settings they were measured with before the defaults changed: Newton from x_n + h v_n, no
// contraction-rate refresh), 3: the solver's defaults (SolverOptions{}) at this benchmark's
// tolerance 1e-6, 4: the defaults including their tolerance 1e-7; supernodal CHOLMOD (1),
// simplicial CHOLMOD (2) or Eigen LDLT (0)
void BM_BackwardEulerStep(benchmark::State& state) {
  const int degree = static_cast<int>(state.range(0));
  const int q = static_cast<int>(state.range(1));
  auto m = make_model(degree, q, VolumeMethod::exact);
  SolverOptions o;
  const int mode = static_cast<int>(state.range(2));
  if (mode != 3 && mode != 4) {
    o.refresh_stiffness = mode != 0;
    o.reuse_factorisation_steps = mode == 2 ? 20 : mode >= 10 ? mode : 0;
    o.extrapolate_start = false;
    o.refresh_contraction_rate = 0.0;
  }
  o.supernodal = state.range(3) != 0;
  o.cholmod_simplicial = state.range(3) == 2;
  if (mode != 4) o.newton_tolerance = 1e-6;
  SolidDynamicsSolver solver(m, o);
  StepInputs in;
  in.excitation = 1.0;
  int iterations = 0, factorisations = 0, steps = 0;
  for (auto _ : state) {
    const StepReport r = solver.step(1e-3, in);
    iterations += r.newton_iterations;
    factorisations += r.factorisations;
    ++steps;
    if (solver.get_state().time_s > 0.2) {
      state.PauseTiming();
      solver.set_state({0.0, m->rest.P, Points3::Zero(m->rest.P.rows(), 3), 0.0});
      state.ResumeTiming();
    }
  }
  state.counters["newton_per_step"] = static_cast<double>(iterations) / steps;
  state.counters["factor_per_step"] = static_cast<double>(factorisations) / steps;
  state.counters["quad_points"] = static_cast<double>(m->quadrature.size());
}
BENCHMARK(BM_BackwardEulerStep)
    ->Args({2, 3, 1, 1})->Args({2, 2, 1, 1})->Args({2, 2, 1, 0})->Args({2, 2, 0, 1})
    ->Args({2, 2, 2, 1})->Args({3, 4, 1, 1})->Args({3, 2, 2, 1})->Args({3, 2, 1, 1})
    ->Args({3, 2, 50, 1})->Args({3, 2, 200, 1})->Args({3, 2, 2, 2})->Args({3, 2, 1, 2})
    ->Args({3, 2, 3, 1})->Args({3, 2, 4, 1})->Args({2, 2, 3, 1})
    ->Unit(benchmark::kMillisecond);
// The target row (issue 10: a cubic 6 x 6 x 10 solid) with a fixed number of steps, for a
// load-independent instruction count: valgrind --tool=callgrind --toggle-collect='*::step*'.
BENCHMARK(BM_BackwardEulerStep)->Name("BM_CubicStepFixedCount")->Args({3, 2, 2, 1})->Args({3, 2, 3, 1})
    ->Iterations(200)->Unit(benchmark::kMillisecond);

void BM_ForceEvaluation(benchmark::State& state) {
  auto m = make_model(static_cast<int>(state.range(0)), static_cast<int>(state.range(1)),
                      VolumeMethod::exact);
  const bool stiffness = state.range(2) != 0;
  for (auto _ : state) {
    ForceEvaluation fe = calc_forces(*m, m->rest.P, {}, 0.5, stiffness);
    benchmark::DoNotOptimize(fe.force.data());
  }
}
BENCHMARK(BM_ForceEvaluation)->Args({2, 2, 0})->Args({2, 2, 1})->Args({2, 3, 1})->Args({3, 4, 1})
    ->Args({3, 2, 0})->Args({3, 2, 1})
    ->Unit(benchmark::kMillisecond);

// Passive sag under gravity between fixed ends (the benign case: no activation).
void BM_BackwardEulerStepPassive(benchmark::State& state) {
  auto m = make_model(2, 2, VolumeMethod::exact);
  SolverOptions o;
  o.reuse_factorisation_steps = static_cast<int>(state.range(0));
  SolidDynamicsSolver solver(m, o);
  int iterations = 0, factorisations = 0, steps = 0;
  for (auto _ : state) {
    const StepReport r = solver.step(1e-3, {});
    iterations += r.newton_iterations;
    factorisations += r.factorisations;
    ++steps;
  }
  state.counters["newton_per_step"] = static_cast<double>(iterations) / steps;
  state.counters["factor_per_step"] = static_cast<double>(factorisations) / steps;
}
BENCHMARK(BM_BackwardEulerStepPassive)->Arg(0)->Arg(50)->Unit(benchmark::kMillisecond);

// Eigen's simplicial LDLᵀ of the backward-Euler matrix at rest (1080 unknowns); the solver's
// supernodal CHOLMOD path is measured through BM_BackwardEulerStep.
void BM_Factorisation(benchmark::State& state) {
  auto m = make_model(2, 2, VolumeMethod::exact);
  const ForceEvaluation fe = calc_forces(*m, m->rest.P, {}, 0.0, true);
  Eigen::SparseMatrix<double> A = fe.stiffness;
  // + M/h² on the diagonal blocks (lumped here; enough for timing)
  for (int i = 0; i < A.cols(); ++i) A.coeffRef(i, i) += m->lumped_mass[i / 3] / 1e-6;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>, Eigen::Lower> ldlt;
  ldlt.analyzePattern(A);
  for (auto _ : state) ldlt.factorize(A);
  state.counters["nnz_A"] = static_cast<double>(A.nonZeros());
}
BENCHMARK(BM_Factorisation)->Unit(benchmark::kMillisecond);

// The dense alternative to CHOLMOD for the cubic 6 x 6 x 10 system (docs/solid-dynamics.md,
// Performance): Eigen's blocked dense LLᵀ of the free block (864 unknowns; both end layers
// attached) at rest, range(0) = 0, and its two-column triangular solves, range(0) = 1.
void BM_DenseFreeBlockLLT(benchmark::State& state) {
  auto m = make_model(3, 2, VolumeMethod::exact);
  const ForceEvaluation fe = calc_forces(*m, m->rest.P, {}, 1.0, true);
  const Eigen::MatrixXd K = Eigen::MatrixXd(Eigen::SparseMatrix<double>(
      fe.stiffness.selfadjointView<Eigen::Lower>()));
  std::vector<int> free;
  for (int i = 0; i < static_cast<int>(K.rows()); ++i)
    if (!m->fixed[i / 3]) free.push_back(i);
  const int nf = static_cast<int>(free.size());
  Eigen::MatrixXd A(nf, nf);
  const Eigen::MatrixXd Mfull = Eigen::MatrixXd(m->mass_matrix);
  for (int b = 0; b < nf; ++b)
    for (int a = 0; a < nf; ++a)
      A(a, b) = K(free[a], free[b]) +
                (free[a] % 3 == free[b] % 3 ? Mfull(free[a] / 3, free[b] / 3) / 1e-6 : 0.0);
  Eigen::LLT<Eigen::MatrixXd> llt(A);
  Eigen::MatrixXd B = Eigen::MatrixXd::Random(nf, 2);
  for (auto _ : state) {
    if (state.range(0) == 0) {
      llt.compute(A);
      benchmark::DoNotOptimize(llt.matrixLLT().data());
    } else {
      Eigen::MatrixXd X = B;
      llt.solveInPlace(X);
      benchmark::DoNotOptimize(X.data());
    }
  }
  state.counters["free_unknowns"] = nf;
}
BENCHMARK(BM_DenseFreeBlockLLT)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_SymplecticEulerStep(benchmark::State& state) {
  auto m = make_model(2, 2, VolumeMethod::exact);
  SolverOptions o;
  o.integrator = Integrator::symplectic_euler;
  SolidDynamicsSolver solver(m, o);
  int sub = 0, steps = 0;
  for (auto _ : state) {
    sub += solver.step(1e-3, {}).substeps;
    ++steps;
  }
  state.counters["substeps"] = static_cast<double>(sub) / steps;
}
BENCHMARK(BM_SymplecticEulerStep)->Unit(benchmark::kMillisecond);

// Stability study (docs/solid-dynamics.md): for ground-substance stiffness c1 (range(0), Pa), the
// explicit limit 2/ω_max and the largest backward-Euler step (of 1, 2, 5, ... 100 ms) that takes a
// stretched 2 x 2 x 6 cm block (origin fixed) through 0.1 s without failing or halving (counters,
// in ms). The passive Blemker fibre term (σmax P1 P2 ≈ 100 kPa for stretch) is always present.
void BM_StabilityStudy(benchmark::State& state) {
  const double c1 = static_cast<double>(state.range(0));
  LatticeDesign d = make_cubical_lattice(Vec3(0, 0, 0), Vec3(0.02, 0.02, 0.06), {2, 2, 2}, {4, 4, 6});
  SolidDynamicsSpec s;
  s.ground.c1_Pa = c1;
  s.ground.c2_Pa = 0.0;
  s.gravity_m_s2.setZero();
  s.attachments.push_back({"origin", -1, find_end_layer(d.solid, 0)});
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(d.solid, s));
  SolidState start;
  start.P = d.solid.P;
  start.P.col(2) *= 1.2;  // volume-preserving stretch
  start.P.col(0) /= std::sqrt(1.2);
  start.P.col(1) /= std::sqrt(1.2);
  start.V = Points3::Zero(start.P.rows(), 3);
  double explicit_ms = 0.0, implicit_ms = 0.0;
  for (auto _ : state) {
    explicit_ms = 2.0 / calc_max_frequency(*m, d.solid.P, 0.0) * 1e3;
    for (double dt_ms : {1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0}) {
      SolverOptions o;
      o.max_step_halvings = 0;
      SolidDynamicsSolver solver(m, o);
      solver.set_state(start);
      try {
        for (double t = 0.0; t < 0.1 - 1e-9; t += dt_ms * 1e-3) solver.step(dt_ms * 1e-3, {});
        implicit_ms = dt_ms;
      } catch (const std::exception& e) {
        if (std::getenv("FASCICLE_DEBUG_DYN")) std::fprintf(stderr, "%g ms: %s\n", dt_ms, e.what());
        break;
      }
    }
  }
  state.counters["explicit_limit_ms"] = explicit_ms;
  state.counters["implicit_largest_ms"] = implicit_ms;
}
BENCHMARK(BM_StabilityStudy)->Arg(1000)->Arg(10000)->Arg(100000)->Arg(1000000)->Arg(10000000)
    ->Iterations(1)->Unit(benchmark::kMillisecond);

// Generalised coordinates: control points P versus spatial points X = A P sampled at the Greville
// material points (seed 000 §4.2; A square and invertible, P = A⁻¹ X). Reports the fill of the mass
// and stiffness matrices in X (M_X = A⁻ᵀ M A⁻¹), the explicit stability limit 2/ω_max with
// lumped masses in each set of coordinates, and times the dense factorisation the X system needs.
void BM_SpatialPointCoordinates(benchmark::State& state) {
  LatticeDesign d = make_cubical_lattice(Vec3(0, 0, 0), Vec3(0.03, 0.03, 0.10), {2, 2, 2}, {6, 6, 10});
  SolidDynamicsSpec s;
  s.gravity_m_s2.setZero();
  s.volume = VolumeMethod::none;
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(d.solid, s));
  const int n = d.solid.num_control_points();
  // A: rows = basis values at the Greville points (the same lattice order as P).
  std::array<std::vector<double>, 3> gr;
  for (int k = 0; k < 3; ++k) gr[k] = calc_greville_abscissae(d.solid.basis[k]);
  std::vector<Eigen::Triplet<double>> t;
  for (int k = 0; k < d.solid.num_control(2); ++k)
    for (int j = 0; j < d.solid.num_control(1); ++j)
      for (int i = 0; i < d.solid.num_control(0); ++i)
        append_basis_row(d.solid, Vec3(gr[0][i], gr[1][j], gr[2][k]), {0, 0, 0}, d.solid.index(i, j, k), t);
  Eigen::SparseMatrix<double> A(n, n);
  A.setFromTriplets(t.begin(), t.end());
  const Eigen::MatrixXd Ainv = Eigen::MatrixXd(A).inverse();
  const Eigen::MatrixXd MX = Ainv.transpose() * Eigen::MatrixXd(m->mass_matrix) * Ainv;
  const double tiny = 1e-9 * MX.cwiseAbs().maxCoeff();
  const double fill = static_cast<double>((MX.cwiseAbs().array() > tiny).count()) / (double(n) * n);
  // Explicit limits with lumped masses: control points (model) versus points (row sums of M_X,
  // i.e. each point's share of the mass; positive here).
  const ForceEvaluation fe = calc_forces(*m, d.solid.P, {}, 0.0, true);
  Eigen::SparseMatrix<double> Kf;
  Kf = fe.stiffness.selfadjointView<Eigen::Lower>();
  const Eigen::MatrixXd K = Eigen::MatrixXd(Kf);
  Eigen::MatrixXd T = Eigen::MatrixXd::Zero(3 * n, 3 * n);  // A⁻¹ per coordinate
  for (int a = 0; a < n; ++a)
    for (int b = 0; b < n; ++b)
      for (int c = 0; c < 3; ++c) T(3 * a + c, 3 * b + c) = Ainv(a, b);
  const Eigen::MatrixXd KX = T.transpose() * K * T;
  const VecX mX = MX.rowwise().sum();
  auto omega = [&](const Eigen::MatrixXd& Kd, const VecX& masses) {
    VecX sc(3 * n);
    for (int i = 0; i < 3 * n; ++i) sc[i] = 1.0 / std::sqrt(masses[i / 3]);
    const Eigen::MatrixXd S = sc.asDiagonal() * Kd * sc.asDiagonal();
    return std::sqrt(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(S, Eigen::EigenvaluesOnly)
                         .eigenvalues().maxCoeff());
  };
  const double wP = omega(K, m->lumped_mass), wX = omega(KX, mX);
  Eigen::MatrixXd sys = KX;
  for (int i = 0; i < 3 * n; ++i) sys(i, i) += mX[i / 3] / 1e-6;
  for (auto _ : state) {
    Eigen::LLT<Eigen::MatrixXd> llt(sys);
    benchmark::DoNotOptimize(llt.matrixLLT().data());
  }
  state.counters["fill_MX"] = fill;
  state.counters["fill_MP"] = static_cast<double>(m->mass_matrix.nonZeros()) / (double(n) * n);
  state.counters["explicit_limit_P_ms"] = 2e3 / wP;
  state.counters["explicit_limit_X_ms"] = 2e3 / wX;
  state.counters["min_point_mass_g"] = mX.minCoeff() * 1e3;
}
BENCHMARK(BM_SpatialPointCoordinates)->Unit(benchmark::kMillisecond);

// The contracting VH soleus (examples/solid/README.md settings: 3 x 8 x 6 degree-2 fit, both ends
// fixed, 25° rest pennation, 10 % tendon at each end of 100 MPa, c1 50 kPa, α 10/s, excitation 1,
// backward Euler 1 ms with exact volume) over 0.5 s simulated: CPU time against real time, and the
// pennation change and largest volume error. range(0): reuse_factorisation_steps (0: full
// Newton). The fit keeps the slice parametrisation (no closest-point correction, no vertex
// samples), as the scene's fallback does: the corrected 3 x 8 x 6 fit is inverted.
// flags (BM_SoleusContractionVariant's second argument): bit 0 extrapolated Newton start, bit 1
// refresh at contraction rate 0.5, bit 2 at 0.25,
// bits 8.. the time step in ms (0: 1 ms).
void run_soleus(benchmark::State& state, int reuse, int flags) {
  const auto mesh_path = std::filesystem::path(FASCICLE_DEFAULT_DATA_DIR) /
                         "visible_human_female/right/VHF_Right_Muscle_Soleus_smooth.stl";
  MeshFitOptions fo;
  fo.count = {3, 8, 6};
  fo.degree = {2, 2, 2};
  fo.reparametrise_iterations = 0;
  fo.mesh_vertex_samples = false;
  fo.name = "soleus";
  const BSplineSolid rest = fit_solid_to_mesh(read_mesh(mesh_path, LengthUnit::millimetre), fo).solid;
  SolidDynamicsSpec spec;
  spec.ground.c1_Pa = 5e4;
  spec.ground.c2_Pa = 2.5e4;
  spec.rayleigh_alpha_1_s = 10.0;
  spec.tendon_fraction_start = spec.tendon_fraction_end = 0.1;
  spec.tendon_modulus_Pa = 1e8;
  spec.pennation_rad = 0.436;
  spec.gravity_m_s2.setZero();
  spec.attachments.push_back({"origin", -1, find_end_layer(rest, 0)});
  spec.attachments.push_back({"insertion", -1, find_end_layer(rest, 1)});
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(rest, spec));
  SolverOptions o;  // reuse < 0: the solver's defaults (SolverOptions{})
  if (reuse >= 0) {
    o.reuse_factorisation_steps = reuse;
    o.extrapolate_start = (flags & 1) != 0;
    o.refresh_contraction_rate = 0.0;
  }
  if (flags & 2) o.refresh_contraction_rate = 0.5;
  if (flags & 4) o.refresh_contraction_rate = 0.25;
  const int dt_ms = std::max(1, flags >> 8);
  std::vector<double> pennation_track;  // every 10 ms, for comparisons between runs
  const int nsteps = 500 / dt_ms;
  if (std::getenv("FASCICLE_DEBUG_DYN")) spdlog::set_level(spdlog::level::trace);
  double pennation0 = 0.0, pennation1 = 0.0, max_err = 0.0, stretch = 0.0;
  int iterations = 0, factorisations = 0;
  for (auto _ : state) {
    SolidDynamicsSolver solver(m, o);
    StepInputs in;
    in.excitation = 1.0;
    pennation0 = solver.calc_metrics(in).mean_pennation_rad;
    for (int k = 0; k < nsteps; ++k) {
      const StepReport r = solver.step(dt_ms * 1e-3, in);
      iterations += r.newton_iterations;
      factorisations += r.factorisations;
      if (std::getenv("FASCICLE_DEBUG_DYN"))
        std::fprintf(stderr, "step %d t %.4f a %.4f newton %d factor %d\n", k,
                     solver.get_state().time_s, solver.get_state().activation, r.newton_iterations,
                     r.factorisations);
      if ((k + 1) % std::max(1, 10 / dt_ms) == 0) {
        const SolidMetrics mk = solver.calc_metrics(in);
        max_err = std::max(max_err, std::abs(mk.volume_error));
        pennation_track.push_back(mk.mean_pennation_rad);
      }
    }
    const SolidMetrics end = solver.calc_metrics(in);
    pennation1 = end.mean_pennation_rad;
    stretch = end.mean_fibre_stretch;
    // FASCICLE_SOLEUS_TRACE=FILE: the end state and the pennation every 10 ms, full precision.
    if (const char* path = std::getenv("FASCICLE_SOLEUS_TRACE")) {
      if (std::FILE* f = std::fopen(path, "a")) {
        std::fprintf(f, "reuse %d flags %d end_pennation_rad %.12g end_stretch %.12g max_volume_error %.3g max_pennation_rad %.12g",
                     reuse, flags, pennation1, stretch, max_err,
                     *std::max_element(pennation_track.begin(), pennation_track.end()));
        for (double p : pennation_track) std::fprintf(f, " %.12g", p);
        std::fprintf(f, "\n");
        std::fclose(f);
      }
    }
  }
  state.counters["simulated_s"] = 0.5;
  state.counters["pennation_rest_deg"] = pennation0 * 180.0 / M_PI;
  state.counters["pennation_end_deg"] = pennation1 * 180.0 / M_PI;
  state.counters["fibre_stretch_end"] = stretch;
  state.counters["max_volume_error"] = max_err;
  state.counters["newton_per_step"] = iterations / (double(nsteps) * state.iterations());
  state.counters["factor_per_step"] = factorisations / (double(nsteps) * state.iterations());
}
void BM_SoleusContraction(benchmark::State& state) {
  run_soleus(state, static_cast<int>(state.range(0)), 0);
}
BENCHMARK(BM_SoleusContraction)->Arg(0)->Arg(20)->Iterations(1)->Unit(benchmark::kSecond);
// The solver's defaults (SolverOptions{}, what `fascicle solid simulate` and the scene use) at the
// CLI's default step (1 ms, range(0) = 1) and the scene's (5 ms, range(0) = 5).
void BM_SoleusContractionDefaults(benchmark::State& state) {
  run_soleus(state, -1, static_cast<int>(state.range(0)) << 8);
}
BENCHMARK(BM_SoleusContractionDefaults)->Arg(1)->Arg(5)->Iterations(1)->Unit(benchmark::kSecond);
// range(0): reuse_factorisation_steps; range(1): flags of run_soleus (1: extrapolated start;
// 256 k: steps of k ms).
void BM_SoleusContractionVariant(benchmark::State& state) {
  run_soleus(state, static_cast<int>(state.range(0)), static_cast<int>(state.range(1)));
}
BENCHMARK(BM_SoleusContractionVariant)->Args({20, 1})->Args({20, 3})->Args({20, 5})->Args({20, 2})
    ->Args({20, 512})->Args({20, 513})->Args({20, 1280})->Args({20, 1281})
    // refactorisation policy: kept over up to 200 steps, or with no step cap (refreshed only when
    // Newton slows, the step size changes or a step fails)
    ->Args({200, 0})->Args({200, 1})->Args({1000000, 0})->Args({1000000, 1})->Args({1000000, 2})
    ->Args({1000000, 3})->Args({1000000, 5})->Args({1000000, 1280})->Args({1000000, 1281})
    ->Iterations(1)->Unit(benchmark::kSecond);

}  // namespace

BENCHMARK_MAIN();
