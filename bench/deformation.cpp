// Surface-first deformation: per-frame time and volume error for a 10k-vertex cylinder muscle bent
// at a hinge (without and with a bone pressing on it) and for the Visible Human soleus under an
// ankle rotation, on one thread. Run with OPENBLAS_NUM_THREADS=1 for one-core figures.
#include "fascicle/core/parallel.hpp"
#include "fascicle/deformation/surface_first.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/mesh_io.hpp"

#include <benchmark/benchmark.h>

#include <cmath>
#include <filesystem>

namespace fascicle {
namespace {

Transform rotation_about_x(double angle, const Vec3& centre) {
  Transform T = Transform::Identity();
  T.translate(centre).rotate(Eigen::AngleAxisd(angle, Vec3::UnitX())).translate(-centre);
  return T;
}

struct Cylinder {
  TriMesh mesh = make_cylinder(0.02, 0.2, 100, 99);  // 10,002 vertices
  std::vector<SurfaceAttachment> areas{{"origin", {}}, {"insertion", {}}};
  Cylinder() {
    for (int i = 0; i < mesh.V.rows(); ++i) {
      if (mesh.V(i, 2) < -0.09) areas[0].vertices.push_back(i);
      if (mesh.V(i, 2) > 0.09) areas[1].vertices.push_back(i);
    }
  }
  static Points3 line() {
    Points3 L(11, 3);
    for (int k = 0; k < 11; ++k) L.row(k) << 0.0, 0.0, -0.1 + 0.02 * k;
    return L;
  }
  static SurfaceFrameInput frame(double angle, int bones) {
    SurfaceFrameInput in;
    const Transform T = rotation_about_x(angle, Vec3::Zero());
    in.action_line = line();
    for (int k = 6; k < 11; ++k) in.action_line.row(k) = (T * Vec3(in.action_line.row(k).transpose())).transpose();
    in.attachment_motions = {Transform::Identity(), T};
    if (bones > 0) {
      Transform B = Transform::Identity();
      B.translate(Vec3(-0.01, 0.0, 0.0));  // the bone pressed 5 mm into the belly
      in.bone_motions = {B};
    }
    return in;
  }
};

// A frame sequence: 30 deg +- 20 deg, about 1 deg per frame.
double angle_of(std::int64_t k) { return (30.0 + 20.0 * std::sin(0.05 * k)) * M_PI / 180.0; }

void run_cylinder(benchmark::State& state, SparseSolverKind kind, bool with_bone) {
  ThreadLimit one(1);
  const Cylinder c;
  TriMesh box = make_box(Vec3(0.02, 0.03, 0.03));
  box.V.col(0).array() += 0.025 + 0.02;
  const MeshQuery bone(box);
  const BoneQueries bones = with_bone ? BoneQueries{&bone} : BoneQueries{};
  SurfaceFirstOptions o;
  o.sparse_solver = kind;
  const SurfaceBinding b = bind_surface(c.mesh, Cylinder::line(), c.areas, bones, o);
  SurfaceFirstSolver solver(b, bones);
  std::int64_t k = 0;
  double max_error = 0.0, solves = 0.0, contacts = 0.0, depth = 0.0;
  for (auto _ : state) {
    solver.calc_frame(Cylinder::frame(angle_of(k++), static_cast<int>(bones.size())));
    const SurfaceFrameInfo& info = solver.get_info();
    max_error = std::max(max_error, info.relative_volume_error);
    depth = std::max(depth, info.max_penetration_beyond_rest_m);
    solves += info.volume_iterations;
    contacts += info.active_contacts;
  }
  state.counters["vertices"] = static_cast<double>(c.mesh.V.rows());
  state.counters["max_rel_vol_err"] = max_error;
  state.counters["solves_per_frame"] = solves / k;
  state.counters["contacts_per_frame"] = contacts / k;
  state.counters["max_depth_mm"] = depth * 1e3;
}

void BM_Cylinder10k_Cholmod(benchmark::State& s) { run_cylinder(s, SparseSolverKind::cholmod_supernodal, false); }
void BM_Cylinder10k_SimplicialLDLT(benchmark::State& s) { run_cylinder(s, SparseSolverKind::eigen_simplicial_ldlt, false); }
void BM_Cylinder10k_BoxBone(benchmark::State& s) { run_cylinder(s, SparseSolverKind::cholmod_supernodal, true); }
BENCHMARK(BM_Cylinder10k_Cholmod)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Cylinder10k_SimplicialLDLT)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Cylinder10k_BoxBone)->Unit(benchmark::kMillisecond);

// Binding and the first factorisation (done once per muscle).
void BM_Cylinder10k_BindAndFactorise(benchmark::State& state) {
  ThreadLimit one(1);
  const Cylinder c;
  for (auto _ : state) {
    const SurfaceBinding b = bind_surface(c.mesh, Cylinder::line(), c.areas, {});
    SurfaceFirstSolver solver(b, {});
    benchmark::DoNotOptimize(solver.get_vertices().data());
  }
}
BENCHMARK(BM_Cylinder10k_BindAndFactorise)->Unit(benchmark::kMillisecond);

// The VH soleus (14k vertices) with tibia and fibula, ankle -20 -> +15 deg.
void BM_Soleus_AnkleRotation(benchmark::State& state) {
  ThreadLimit one(1);
  const std::filesystem::path dir =
      std::filesystem::path(FASCICLE_DEFAULT_DATA_DIR) / "visible_human_female/right";
  const TriMesh soleus = read_mesh(dir / "VHF_Right_Muscle_Soleus_smooth.stl", LengthUnit::millimetre);
  const MeshQuery tibia(read_mesh(dir / "VHF_Right_Bone_Tibia_smooth.stl", LengthUnit::millimetre));
  const MeshQuery fibula(read_mesh(dir / "VHF_Right_Bone_Fibula_smooth.stl", LengthUnit::millimetre));
  const double z0 = soleus.V.col(2).minCoeff(), z1 = soleus.V.col(2).maxCoeff();
  std::vector<SurfaceAttachment> areas{{"origin", {}}, {"insertion", {}}};
  Vec3 po = Vec3::Zero(), pi = Vec3::Zero();
  for (int i = 0; i < soleus.V.rows(); ++i) {
    const double t = (soleus.V(i, 2) - z0) / (z1 - z0);
    if (t > 0.96) { areas[0].vertices.push_back(i); po += soleus.V.row(i).transpose(); }
    if (t < 0.04) { areas[1].vertices.push_back(i); pi += soleus.V.row(i).transpose(); }
  }
  po /= areas[0].vertices.size();
  pi /= areas[1].vertices.size();
  Points3 line(2, 3);
  line << po.transpose(), pi.transpose();
  const BoneQueries bones{&tibia, &fibula};
  const SurfaceBinding b = bind_surface(soleus, line, areas, bones, {}, "soleus_r");
  SurfaceFirstSolver solver(b, bones);
  const Vec3 ankle(0.588, 0.412, 0.135);
  std::int64_t k = 0;
  double max_error = 0.0, depth = 0.0, solves = 0.0;
  for (auto _ : state) {
    const double deg = -2.5 + 17.5 * std::sin(0.1 * k++);
    const Transform foot = rotation_about_x(deg * M_PI / 180.0, ankle);
    SurfaceFrameInput in;
    in.action_line = line;
    in.action_line.row(1) = (foot * pi).transpose();
    in.attachment_motions = {Transform::Identity(), foot};
    solver.calc_frame(in);
    const SurfaceFrameInfo& info = solver.get_info();
    max_error = std::max(max_error, info.relative_volume_error);
    depth = std::max(depth, info.max_penetration_beyond_rest_m);
    solves += info.volume_iterations;
  }
  state.counters["vertices"] = static_cast<double>(soleus.V.rows());
  state.counters["max_rel_vol_err"] = max_error;
  state.counters["max_depth_mm"] = depth * 1e3;
  state.counters["solves_per_frame"] = solves / k;
}
BENCHMARK(BM_Soleus_AnkleRotation)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace fascicle

BENCHMARK_MAIN();
