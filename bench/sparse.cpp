// The supernodal LLᵀ solve of fascicle/sparse against CHOLMOD's own (cholmod_solve2 with reused
// workspaces, BLAS per supernode) on the VH soleus surface-first system (14k vertices, CHOLMOD's
// fill-reducing ordering, ~2 M factor entries), for the column counts the surface-first solver
// uses (3: the three coordinates; 6 and more: Woodbury columns). Run with OPENBLAS_NUM_THREADS=1
// OMP_NUM_THREADS=1 (as the surface-first solver runs CHOLMOD).
#include "fascicle/deformation/surface_first.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/io/mesh_io.hpp"
#include "fascicle/sparse/cholmod_view.hpp"
#include "fascicle/sparse/supernodal_solve.hpp"

#include <benchmark/benchmark.h>
#include <suitesparse/cholmod.h>

#include <filesystem>
#include <memory>
#include <random>

namespace fascicle {
namespace {

// The VH soleus surface-first system, factorised by CHOLMOD.
struct SoleusFactor {
  SparseMatrix K;
  cholmod_common c{};
  cholmod_factor* L = nullptr;
  SoleusFactor() {
    const std::filesystem::path dir =
        std::filesystem::path(FASCICLE_DEFAULT_DATA_DIR) / "visible_human_female/right";
    const TriMesh soleus = read_mesh(dir / "VHF_Right_Muscle_Soleus_smooth.stl", LengthUnit::millimetre);
    // Action line along the mesh's z extent through its centroid, no attachment areas (the line
    // weight makes the system definite): all 14,282 vertices free.
    const Vec3 centre = soleus.V.colwise().mean().transpose();
    Points3 line(2, 3);
    line << centre.x(), centre.y(), soleus.V.col(2).maxCoeff(), centre.x(), centre.y(),
        soleus.V.col(2).minCoeff();
    K = bind_surface(soleus, line, {}, {}, {}, "soleus_r").system;
    cholmod_start(&c);
    c.print = 0;
    c.supernodal = CHOLMOD_SUPERNODAL;
    cholmod_sparse S = view_symmetric_lower(static_cast<std::size_t>(K.rows()), static_cast<std::size_t>(K.nonZeros()),
                                            K.outerIndexPtr(), K.innerIndexPtr(), K.valuePtr());
    L = cholmod_analyze(&S, &c);
    cholmod_factorize(&S, L, &c);
  }
  ~SoleusFactor() {
    cholmod_free_factor(&L, &c);
    cholmod_finish(&c);
  }
};

SoleusFactor& get_soleus() {
  static SoleusFactor f;  // built once per benchmark process (read-only afterwards)
  return f;
}

std::vector<double> random_rhs(int n, int ncols) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<double> b(static_cast<std::size_t>(n) * ncols);
  for (double& v : b) v = u(rng);
  return b;
}

void BM_SoleusSolve_Supernodal(benchmark::State& state) {
  SoleusFactor& f = get_soleus();
  const int n = static_cast<int>(f.L->n), ncols = static_cast<int>(state.range(0));
  const std::vector<double> b = random_rhs(n, ncols);
  std::vector<double> x = b;
  SupernodalSolveWorkspace ws;
  for (auto _ : state) {
    std::copy(b.begin(), b.end(), x.begin());
    solve_supernodal_llt(f.L, x.data(), ncols, n, ws);
    benchmark::DoNotOptimize(x.data());
  }
  state.counters["factor_entries"] = static_cast<double>(f.L->xsize);
}
BENCHMARK(BM_SoleusSolve_Supernodal)->Arg(1)->Arg(3)->Arg(6)->Arg(12)->Unit(benchmark::kMillisecond);

void BM_SoleusSolve_Cholmod(benchmark::State& state) {
  SoleusFactor& f = get_soleus();
  const int n = static_cast<int>(f.L->n), ncols = static_cast<int>(state.range(0));
  std::vector<double> b = random_rhs(n, ncols);
  cholmod_dense B{};
  B.nrow = static_cast<std::size_t>(n);
  B.ncol = static_cast<std::size_t>(ncols);
  B.nzmax = b.size();
  B.d = static_cast<std::size_t>(n);
  B.x = b.data();
  B.xtype = CHOLMOD_REAL;
  B.dtype = CHOLMOD_DOUBLE;
  cholmod_dense *X = nullptr, *Y = nullptr, *E = nullptr;
  for (auto _ : state) {
    cholmod_solve2(CHOLMOD_A, f.L, &B, nullptr, &X, nullptr, &Y, &E, &f.c);
    benchmark::DoNotOptimize(X->x);
  }
  cholmod_free_dense(&X, &f.c);
  cholmod_free_dense(&Y, &f.c);
  cholmod_free_dense(&E, &f.c);
}
BENCHMARK(BM_SoleusSolve_Cholmod)->Arg(1)->Arg(3)->Arg(6)->Arg(12)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace fascicle

BENCHMARK_MAIN();
