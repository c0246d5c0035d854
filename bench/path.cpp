// Muscle-path throughput on a synthetic leg-like model (until the OpenSim importer lands): 40
// paths on a 3-body chain, each with 3-5 points (one conditional, one moving), half of them over a
// cylinder with a quadrant, some over a second cylinder or an ellipsoid. Reports time per
// muscle-frame for lengths, and for lengths + moment arms (generalized-force method).
#include <benchmark/benchmark.h>

#include <cmath>
#include <random>

#include "fascicle/path/path_model.hpp"

using namespace fascicle;

namespace {

Transform rot_z(double q, const Vec3& o = Vec3::Zero()) {
  Transform X = Transform::Identity();
  X.linear() = Eigen::AngleAxisd(q, Vec3::UnitZ()).toRotationMatrix();
  X.translation() = o;
  return X;
}

struct Synthetic {
  PathSetModel model;
  std::vector<std::vector<Transform>> X;  // per frame
  std::vector<VecX> q;
  std::vector<BodyJacobians> J;
};

Synthetic make_synthetic(int paths, int frames) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> U(-1, 1);
  PathSetSpec spec;
  const char* bodies[] = {"pelvis", "femur", "tibia"};
  for (int b = 0; b < 3; ++b) {
    WrapObjectSpec c;
    c.name = std::string("cyl_") + bodies[b];
    c.body = bodies[b];
    c.shape = WrapShape::cylinder;
    c.radius = 0.03;
    c.length = 0.2;
    c.quadrant = WrapQuadrant::pos_y;
    c.X_body_wrap.translation() = Vec3(0.4, 0, 0);
    spec.wrap_objects.push_back(c);
  }
  WrapObjectSpec e;
  e.name = "ell";
  e.body = "femur";
  e.shape = WrapShape::ellipsoid;
  e.radii = Vec3(0.05, 0.03, 0.04);
  e.X_body_wrap.translation() = Vec3(0.4, 0, 0);
  spec.wrap_objects.push_back(e);
  for (int m = 0; m < paths; ++m) {
    GeometryPathSpec p;
    p.name = "m" + std::to_string(m);
    const int b0 = m % 2, b1 = b0 + 1;
    PathPointSpec o{.name = "o", .body = bodies[b0], .p_body = Vec3(0.1 + 0.05 * U(rng), 0.06 + 0.02 * U(rng), 0.02 * U(rng))};
    PathPointSpec v{.name = "v", .body = bodies[b0], .p_body = Vec3(0.3, 0.05 + 0.01 * U(rng), 0.01 * U(rng))};
    PathPointSpec c{.name = "c", .body = bodies[b1], .kind = PathPointKind::conditional,
                    .p_body = Vec3(0.05, 0.05, 0), .coordinate = "q1", .range_min = -0.5, .range_max = 0.5};
    PathPointSpec mv{.name = "mv", .body = bodies[b1], .kind = PathPointKind::moving};
    mv.location[0] = {"q1", [](double x) { return 0.1 + 0.02 * std::sin(x); },
                      [](double x) { return 0.02 * std::cos(x); }};
    mv.location[1] = constant_function(0.04);
    mv.location[2] = constant_function(0.0);
    PathPointSpec i{.name = "i", .body = bodies[b1], .p_body = Vec3(0.25, 0.04 * U(rng), 0.01)};
    p.points = {o, v, c, mv, i};
    if (m % 2 == 0) p.wraps.push_back({.wrap_object = std::string("cyl_") + bodies[b1]});
    if (m % 8 == 0) p.wraps.push_back({.wrap_object = "ell"});
    spec.paths.push_back(p);
  }
  Synthetic s;
  s.model = compile_paths(spec, {{"pelvis", "femur", "tibia"}, {"q0", "q1"}});
  for (int f = 0; f < frames; ++f) {
    const double q0 = 0.3 * std::sin(0.05 * f), q1 = 0.8 * std::sin(0.07 * f + 1);
    const Transform Xf = rot_z(q0, Vec3(0.4, 0, 0));
    const Transform Xt = Xf * rot_z(q1, Vec3(0.4, 0, 0));
    s.X.push_back({Transform::Identity(), Xf, Xt});
    s.q.push_back((VecX(2) << q0, q1).finished());
    BodyJacobians J;
    J.J.assign(3, Eigen::Matrix<double, 6, Eigen::Dynamic>::Zero(6, 2));
    J.J[1](2, 0) = 1;
    J.J[1].bottomRows<3>().col(0) = -Vec3::UnitZ().cross(Xf.translation());
    J.J[2](2, 0) = 1;
    J.J[2](2, 1) = 1;
    J.J[2].bottomRows<3>().col(0) = -Vec3::UnitZ().cross(Xf.translation());
    J.J[2].bottomRows<3>().col(1) = -Vec3::UnitZ().cross(Xt.translation());
    J.dq_du = MatX::Identity(2, 2);
    s.J.push_back(J);
  }
  return s;
}

void BM_PathLengths(benchmark::State& state) {
  const Synthetic s = make_synthetic(40, 200);
  PathResult res;
  double sink = 0;
  for (auto _ : state) {
    for (size_t f = 0; f < s.X.size(); ++f) {
      for (int p = 0; p < static_cast<int>(s.model.paths.size()); ++p) {
        calc_path(s.model, p, s.X[f], s.q[f], res);
        sink += res.length_m;
      }
    }
  }
  benchmark::DoNotOptimize(sink);
  state.counters["seconds_per_muscle_frame"] = benchmark::Counter(
      double(state.iterations()) * s.X.size() * s.model.paths.size(),
      benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_PathLengths)->Unit(benchmark::kMillisecond);

void BM_PathLengthsAndMomentArms(benchmark::State& state) {
  const Synthetic s = make_synthetic(40, 200);
  PathResult res;
  double sink = 0;
  for (auto _ : state) {
    for (size_t f = 0; f < s.X.size(); ++f) {
      for (int p = 0; p < static_cast<int>(s.model.paths.size()); ++p) {
        calc_path(s.model, p, s.X[f], s.q[f], res);
        sink += calc_moment_arms(s.model, p, res, s.X[f], s.q[f], s.J[f])[0];
      }
    }
  }
  benchmark::DoNotOptimize(sink);
  state.counters["seconds_per_muscle_frame"] = benchmark::Counter(
      double(state.iterations()) * s.X.size() * s.model.paths.size(),
      benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_PathLengthsAndMomentArms)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
