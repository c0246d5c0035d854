// Benchmarks of the solid-muscle dynamics (docs/solid-dynamics.md, docs/benchmarks.md):
// one backward-Euler step of a 6 x 6 x 10 solid (360 control points), force evaluation,
// factorisation, and the explicit integrator.
#include "fascicle/bspline/lattice.hpp"
#include "fascicle/dynamics/solid_dynamics.hpp"

#include <Eigen/SparseCholesky>
#include <benchmark/benchmark.h>

#include <memory>

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
// 2: factorisation kept over up to 20 steps), supernodal CHOLMOD (1) or Eigen LDLT (0)
void BM_BackwardEulerStep(benchmark::State& state) {
  const int degree = static_cast<int>(state.range(0));
  const int q = static_cast<int>(state.range(1));
  auto m = make_model(degree, q, VolumeMethod::exact);
  SolverOptions o;
  o.refresh_stiffness = state.range(2) != 0;
  o.reuse_factorisation_steps = state.range(2) == 2 ? 20 : 0;
  o.supernodal = state.range(3) != 0;
  o.newton_tolerance = 1e-6;
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
    ->Args({2, 2, 2, 1})->Args({3, 4, 1, 1})->Args({3, 2, 2, 1})
    ->Unit(benchmark::kMillisecond);

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

}  // namespace

BENCHMARK_MAIN();
