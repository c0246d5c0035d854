// Spatial queries on the Visible Human Female right tibia (binary STL in mm, ~60k triangles), one
// core: closest point, inside test, signed distance, ray casts and BVH build.
// Query points (fixed seeds): "Box" = uniform in the mesh's bounding box enlarged by 10% (mean
// distance to the bone 21 mm); "Near" = what fascicle's contact and fibre code issues: area-uniform
// surface points moved along the face normal by +-(0.5 ... 5) mm (uniform magnitude, random sign).
// Run: build/bin/bench_geometry_queries   (FASCICLE_DATA_DIR overrides the data folder)
#include "fascicle/core/parallel.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/io/mesh_io.hpp"

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <vector>

namespace {

using namespace fascicle;

std::filesystem::path data_dir() {
  if (const char* env = std::getenv("FASCICLE_DATA_DIR"); env != nullptr && *env != '\0') return env;
  return FASCICLE_DEFAULT_DATA_DIR;
}

const TriMesh& tibia() {
  static const TriMesh mesh = read_mesh(
      data_dir() / "visible_human_female/right/VHF_Right_Bone_Tibia_smooth.stl", LengthUnit::millimetre);
  return mesh;
}

const MeshQuery& tibia_query() {
  static const MeshQuery query(tibia());
  return query;
}

// The two closest-point trees side by side (the "...Tree" benchmarks; argument tree: 0 = Embree
// scene of Morton clusters, 1 = compact tree from Embree's SAH builder). The benchmarks without
// "Tree" measure the default MeshQuery.
MeshQueryOptions tree_options(std::int64_t tree) {
  MeshQueryOptions o;
  o.closest_point_tree = tree == 0 ? MeshQueryOptions::ClosestPointTree::embree_clusters
                                   : MeshQueryOptions::ClosestPointTree::compact;
  return o;
}

const MeshQuery& tibia_query(std::int64_t tree) {
  static const MeshQuery clusters(tibia(), tree_options(0));
  static const MeshQuery compact(tibia(), tree_options(1));
  return tree == 0 ? clusters : compact;
}

// n points uniform in the bounding box enlarged by 10% (half extents x 1.1).
Points3 box_points(const TriMesh& m, Eigen::Index n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Vec3 lo = m.V.colwise().minCoeff().transpose(), hi = m.V.colwise().maxCoeff().transpose();
  const Vec3 c = 0.5 * (lo + hi), h = 0.55 * (hi - lo);
  Points3 P(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) P(i, k) = c[k] + u(rng) * h[k];
  }
  return P;
}

// n points near the surface: area-uniform random surface points offset along the face normal by
// s * u, s = +-1 at random, u uniform in [0.5, 5] mm.
Points3 near_points(const TriMesh& m, Eigen::Index n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> cumulative(static_cast<std::size_t>(m.F.rows()));
  double total = 0.0;
  for (Eigen::Index f = 0; f < m.F.rows(); ++f) {
    const Vec3 a = m.V.row(m.F(f, 0)).transpose(), b = m.V.row(m.F(f, 1)).transpose(),
               c = m.V.row(m.F(f, 2)).transpose();
    total += 0.5 * (b - a).cross(c - a).norm();
    cumulative[static_cast<std::size_t>(f)] = total;
  }
  Points3 P(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) {
    const auto it = std::lower_bound(cumulative.begin(), cumulative.end(), u(rng) * total);
    const Eigen::Index f = std::min<Eigen::Index>(it - cumulative.begin(), m.F.rows() - 1);
    const Vec3 a = m.V.row(m.F(f, 0)).transpose(), b = m.V.row(m.F(f, 1)).transpose(),
               c = m.V.row(m.F(f, 2)).transpose();
    double s = u(rng), t = u(rng);
    if (s + t > 1.0) {
      s = 1.0 - s;
      t = 1.0 - t;
    }
    const Vec3 n_f = (b - a).cross(c - a).normalized();
    const double offset = (u(rng) < 0.5 ? -1.0 : 1.0) * (0.5e-3 + 4.5e-3 * u(rng));
    P.row(i) = (a + s * (b - a) + t * (c - a) + offset * n_f).transpose();
  }
  return P;
}

void BM_Build(benchmark::State& state) {
  const ThreadLimit one(1);
  for (auto _ : state) {
    MeshQuery q(tibia());
    benchmark::DoNotOptimize(q);
  }
  state.counters["triangles"] = static_cast<double>(tibia().F.rows());
}
BENCHMARK(BM_Build)->Unit(benchmark::kMillisecond);

const TriMesh& soleus() {
  static const TriMesh mesh = read_mesh(
      data_dir() / "visible_human_female/right/VHF_Right_Muscle_Soleus_smooth.stl", LengthUnit::millimetre);
  return mesh;
}

// The mesh's vertices moved by a smooth deformation (a few mm of twist and bulge), as a muscle
// deforms between frames.
Points3 deformed_vertices(const TriMesh& m) {
  const Vec3 lo = m.V.colwise().minCoeff().transpose(), hi = m.V.colwise().maxCoeff().transpose();
  const Vec3 c = 0.5 * (lo + hi);
  const double size = (hi - lo).norm();
  Points3 W = m.V;
  for (Eigen::Index i = 0; i < W.rows(); ++i) {
    const Vec3 x = m.V.row(i).transpose() - c;
    const double angle = 0.1 * x.z() / size;
    W(i, 0) = c.x() + (std::cos(angle) * x.x() - std::sin(angle) * x.y()) * (1.0 + 0.05 * std::sin(x.z() / size));
    W(i, 1) = c.y() + std::sin(angle) * x.x() + std::cos(angle) * x.y();
    W(i, 2) = c.z() + x.z() * 1.02;
  }
  return W;
}

// Build vs refit (MeshQuery::update_vertices) for the tibia (0) and the VH soleus (1). Refit
// alternates between the rest and the deformed vertices so every iteration moves every vertex.
const TriMesh& mesh_of(std::int64_t which) { return which == 0 ? tibia() : soleus(); }

void BM_BuildMesh(benchmark::State& state) {
  const ThreadLimit one(1);
  const TriMesh& m = mesh_of(state.range(0));
  for (auto _ : state) {
    MeshQuery q(m);
    benchmark::DoNotOptimize(q);
  }
  state.counters["vertices"] = static_cast<double>(m.V.rows());
  state.counters["triangles"] = static_cast<double>(m.F.rows());
}
BENCHMARK(BM_BuildMesh)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_RefitMesh(benchmark::State& state) {
  const ThreadLimit one(1);
  const TriMesh& m = mesh_of(state.range(0));
  const Points3 W = deformed_vertices(m);
  MeshQuery q(m);
  q.update_vertices(W);  // the first update builds the refittable (two-level) tree; later ones refit
  bool toggle = true;
  for (auto _ : state) {
    q.update_vertices(toggle ? m.V : W);
    toggle = !toggle;
    benchmark::ClobberMemory();
  }
  state.counters["vertices"] = static_cast<double>(m.V.rows());
  state.counters["triangles"] = static_cast<double>(m.F.rows());
}
BENCHMARK(BM_RefitMesh)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// Independent single queries in random order (no coherence between consecutive points).
void BM_ClosestPointSingle(benchmark::State& state) {
  const MeshQuery& q = tibia_query();
  const Points3 P = box_points(tibia(), 100000, 1);
  Eigen::Index i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(q.calc_closest_point(P.row(i).transpose()));
    if (++i == P.rows()) i = 0;
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_ClosestPointSingle);

// The batched API on one thread: Morton-ordered blocks, each query hinted by the previous one.
void BM_ClosestPointBatch(benchmark::State& state) {
  const ThreadLimit one(1);
  const MeshQuery& q = tibia_query();
  const Points3 P = box_points(tibia(), state.range(0), 2);
  for (auto _ : state) benchmark::DoNotOptimize(q.calc_closest_points(P));
  state.SetItemsProcessed(state.iterations() * P.rows());
}
BENCHMARK(BM_ClosestPointBatch)->Arg(10000)->Arg(1000000)->Unit(benchmark::kMillisecond);

// Near-surface points (0.5-5 mm off the bone), single queries in random order.
void BM_ClosestPointNearSingle(benchmark::State& state) {
  const MeshQuery& q = tibia_query();
  const Points3 P = near_points(tibia(), 100000, 8);
  Eigen::Index i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(q.calc_closest_point(P.row(i).transpose()));
    if (++i == P.rows()) i = 0;
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_ClosestPointNearSingle);

// Near-surface points, batched API on one thread.
void BM_ClosestPointNearBatch(benchmark::State& state) {
  const ThreadLimit one(1);
  const MeshQuery& q = tibia_query();
  const Points3 P = near_points(tibia(), state.range(0), 9);
  for (auto _ : state) benchmark::DoNotOptimize(q.calc_closest_points(P));
  state.SetItemsProcessed(state.iterations() * P.rows());
}
BENCHMARK(BM_ClosestPointNearBatch)->Arg(10000)->Arg(1000000)->Unit(benchmark::kMillisecond);

void BM_InsideNearSingle(benchmark::State& state) {
  const MeshQuery& q = tibia_query();
  const Points3 P = near_points(tibia(), 100000, 10);
  Eigen::Index i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(q.calc_is_inside(Vec3(P.row(i).transpose())));
    if (++i == P.rows()) i = 0;
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_InsideNearSingle);

void BM_InsideSingle(benchmark::State& state) {
  const MeshQuery& q = tibia_query();
  const Points3 P = box_points(tibia(), 100000, 3);
  Eigen::Index i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(q.calc_is_inside(Vec3(P.row(i).transpose())));
    if (++i == P.rows()) i = 0;
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_InsideSingle);

void BM_InsideBatch(benchmark::State& state) {
  const ThreadLimit one(1);
  const MeshQuery& q = tibia_query();
  const Points3 P = box_points(tibia(), 100000, 4);
  for (auto _ : state) benchmark::DoNotOptimize(q.calc_is_inside(P));
  state.SetItemsProcessed(state.iterations() * P.rows());
}
BENCHMARK(BM_InsideBatch)->Unit(benchmark::kMillisecond);

void BM_SignedDistanceBatch(benchmark::State& state) {
  const ThreadLimit one(1);
  const MeshQuery& q = tibia_query();
  const Points3 P = box_points(tibia(), 100000, 5);
  for (auto _ : state) benchmark::DoNotOptimize(q.calc_signed_distances(P));
  state.SetItemsProcessed(state.iterations() * P.rows());
}
BENCHMARK(BM_SignedDistanceBatch)->Unit(benchmark::kMillisecond);

// First hits of rays from box points in random directions.
void run_ray_first_hit(benchmark::State& state, const MeshQuery& q) {
  const Points3 P = box_points(tibia(), 100000, 6);
  std::mt19937_64 rng(7);
  std::normal_distribution<double> g(0.0, 1.0);
  Points3 D(P.rows(), 3);
  for (Eigen::Index i = 0; i < D.rows(); ++i) D.row(i) = Eigen::RowVector3d(g(rng), g(rng), g(rng));
  Eigen::Index i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(q.cast_ray(P.row(i).transpose(), D.row(i).transpose()));
    if (++i == P.rows()) i = 0;
  }
  state.SetItemsProcessed(state.iterations());
}

void BM_RayFirstHit(benchmark::State& state) { run_ray_first_hit(state, tibia_query()); }
BENCHMARK(BM_RayFirstHit);

// ----- Both trees side by side -----

void BM_BuildTree(benchmark::State& state) {
  const ThreadLimit one(1);
  const TriMesh& m = mesh_of(state.range(1));
  for (auto _ : state) {
    MeshQuery q(m, tree_options(state.range(0)));
    benchmark::DoNotOptimize(q);
  }
}
BENCHMARK(BM_BuildTree)->ArgNames({"tree", "mesh"})->ArgsProduct({{0, 1}, {0, 1}})->Unit(benchmark::kMillisecond);

void BM_RefitTree(benchmark::State& state) {
  const ThreadLimit one(1);
  const TriMesh& m = mesh_of(state.range(1));
  const Points3 W = deformed_vertices(m);
  MeshQuery q(m, tree_options(state.range(0)));
  q.update_vertices(W);
  bool toggle = true;
  for (auto _ : state) {
    q.update_vertices(toggle ? m.V : W);
    toggle = !toggle;
    benchmark::ClobberMemory();
  }
}
BENCHMARK(BM_RefitTree)->ArgNames({"tree", "mesh"})->ArgsProduct({{0, 1}, {0, 1}})->Unit(benchmark::kMillisecond);

// Single closest-point queries in random order: box points (which = 0) or near points (1).
void BM_ClosestPointSingleTree(benchmark::State& state) {
  const MeshQuery& q = tibia_query(state.range(0));
  const Points3 P = state.range(1) == 0 ? box_points(tibia(), 100000, 1) : near_points(tibia(), 100000, 8);
  Eigen::Index i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(q.calc_closest_point(P.row(i).transpose()));
    if (++i == P.rows()) i = 0;
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_ClosestPointSingleTree)->ArgNames({"tree", "near"})->ArgsProduct({{0, 1}, {0, 1}});

// Batched closest points (1 M points, one thread): box or near points.
void BM_ClosestPointBatchTree(benchmark::State& state) {
  const ThreadLimit one(1);
  const MeshQuery& q = tibia_query(state.range(0));
  const Points3 P = state.range(1) == 0 ? box_points(tibia(), 1000000, 2) : near_points(tibia(), 1000000, 9);
  for (auto _ : state) benchmark::DoNotOptimize(q.calc_closest_points(P));
  state.SetItemsProcessed(state.iterations() * P.rows());
}
BENCHMARK(BM_ClosestPointBatchTree)->ArgNames({"tree", "near"})->ArgsProduct({{0, 1}, {0, 1}})->Unit(benchmark::kMillisecond);

// Inside tests (box or near points) and first ray hits: Embree scenes over either tree's clusters.
void BM_InsideSingleTree(benchmark::State& state) {
  const MeshQuery& q = tibia_query(state.range(0));
  const Points3 P = state.range(1) == 0 ? box_points(tibia(), 100000, 3) : near_points(tibia(), 100000, 10);
  Eigen::Index i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(q.calc_is_inside(Vec3(P.row(i).transpose())));
    if (++i == P.rows()) i = 0;
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_InsideSingleTree)->ArgNames({"tree", "near"})->ArgsProduct({{0, 1}, {0, 1}});

void BM_RayFirstHitTree(benchmark::State& state) {
  run_ray_first_hit(state, tibia_query(state.range(0)));
}
BENCHMARK(BM_RayFirstHitTree)->ArgNames({"tree"})->Arg(0)->Arg(1);

}  // namespace

BENCHMARK_MAIN();
