// B-spline solid kernels on a 6x6x8 cubic solid: point evaluation, exact volume + gradient,
// point membership and cached tessellation update (seed 000 §3.1.1, §3.1.3, §3.1.4).
#include "fascicle/bspline/lattice.hpp"
#include "fascicle/bspline/membership.hpp"
#include "fascicle/bspline/tessellation.hpp"
#include "fascicle/bspline/volume.hpp"

#include <benchmark/benchmark.h>

#include <random>

namespace {

using namespace fascicle;

BSplineSolid make_bench_solid() {
  auto s = make_cubical_lattice(Vec3(0, 0, 0), Vec3(0.03, 0.03, 0.12), {3, 3, 3}, {6, 6, 8}).solid;
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> U(-1e-3, 1e-3);
  for (int r = 0; r < s.P.rows(); ++r) {
    s.P(r, 0) += U(rng) + 0.1 * s.P(r, 2) * s.P(r, 2);
    s.P(r, 1) += U(rng);
    s.P(r, 2) += U(rng);
  }
  return s;
}

std::vector<Vec3> make_material_points(int n) {
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> U(0, 1);
  std::vector<Vec3> out(n);
  for (auto& u : out) u = Vec3(U(rng), U(rng), U(rng));
  return out;
}

void BM_EvaluatePoint(benchmark::State& state) {
  const auto s = make_bench_solid();
  const auto pts = make_material_points(1024);
  std::size_t i = 0;
  for (auto _ : state) benchmark::DoNotOptimize(calc_point(s, pts[i++ & 1023]));
}
BENCHMARK(BM_EvaluatePoint);

void BM_EvaluatePointAndJacobian(benchmark::State& state) {
  const auto s = make_bench_solid();
  const auto pts = make_material_points(1024);
  std::size_t i = 0;
  for (auto _ : state) benchmark::DoNotOptimize(calc_point_and_jacobian(s, pts[i++ & 1023]));
}
BENCHMARK(BM_EvaluatePointAndJacobian);

void BM_BoundaryVolumeAndGradient(benchmark::State& state) {
  const auto s = make_bench_solid();
  const BoundaryVolumeIntegrator integrator(s);
  for (auto _ : state) benchmark::DoNotOptimize(integrator.calc(s.P));
}
BENCHMARK(BM_BoundaryVolumeAndGradient)->Unit(benchmark::kMicrosecond);

void BM_BoundaryVolumeOnly(benchmark::State& state) {
  const auto s = make_bench_solid();
  const BoundaryVolumeIntegrator integrator(s);
  for (auto _ : state) benchmark::DoNotOptimize(integrator.calc_volume(s.P));
}
BENCHMARK(BM_BoundaryVolumeOnly)->Unit(benchmark::kMicrosecond);

void BM_QuadratureVolumeAndGradient(benchmark::State& state) {
  const auto s = make_bench_solid();
  for (auto _ : state) benchmark::DoNotOptimize(calc_volume_and_gradient(s));
}
BENCHMARK(BM_QuadratureVolumeAndGradient)->Unit(benchmark::kMicrosecond);

// Membership of points inside the solid (x(U) at random U).
void BM_LocateInside(benchmark::State& state) {
  const auto s = make_bench_solid();
  const SolidLocator loc(s);
  std::vector<Vec3> pts;
  for (const Vec3& u : make_material_points(1024)) pts.push_back(calc_point(s, u));
  std::size_t i = 0;
  for (auto _ : state) benchmark::DoNotOptimize(loc.locate(pts[i++ & 1023]));
}
BENCHMARK(BM_LocateInside);

// Closest point for points up to 5 mm outside.
void BM_LocateOutside(benchmark::State& state) {
  const auto s = make_bench_solid();
  const SolidLocator loc(s);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> X(-0.005, 0.04), Z(-0.005, 0.125);
  std::vector<Vec3> pts;
  while (pts.size() < 1024) {
    const Vec3 p(X(rng), X(rng), Z(rng));
    if (!loc.locate(p).inside) pts.push_back(p);
  }
  std::size_t i = 0;
  for (auto _ : state) benchmark::DoNotOptimize(loc.locate(pts[i++ & 1023]));
}
BENCHMARK(BM_LocateOutside);

// Tessellation update for about 10k boundary vertices (positions and normals).
void BM_TessellationUpdate10k(benchmark::State& state) {
  const auto s = make_bench_solid();
  auto t = make_boundary_tessellation(s, 12);  // 12 samples per span: ≈ 11k vertices
  state.counters["vertices"] = static_cast<double>(t.mesh.V.rows());
  Points3 P = s.P;
  for (auto _ : state) {
    P(0, 0) += 1e-9;
    update_tessellation(t, P);
    benchmark::DoNotOptimize(t.mesh.V.data());
  }
}
BENCHMARK(BM_TessellationUpdate10k)->Unit(benchmark::kMicrosecond);

void BM_VolumeTessellationUpdate10k(benchmark::State& state) {
  const auto s = make_bench_solid();
  auto t = make_volume_tessellation(s, 6);  // 6 per span: 19 × 19 × 31 ≈ 11k nodes
  state.counters["nodes"] = static_cast<double>(t.V.rows());
  for (auto _ : state) {
    update_tessellation(t, s.P);
    benchmark::DoNotOptimize(t.V.data());
  }
}
BENCHMARK(BM_VolumeTessellationUpdate10k)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
