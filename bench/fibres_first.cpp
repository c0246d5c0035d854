// Fibres-first deformation: per-frame time on one thread for
//   - the Visible Human female right shank: 7 muscles decomposed into 100 fibres x 15 particles
//     by the fibres module (template method), tibia+fibula as the origin bone and talus+calcaneus
//     as the insertion bone, the foot rotating about an ankle axis by 10 +- 15 deg (about 1 deg a
//     frame), quasi-static and dynamic;
//   - a synthetic set of 43 bundles (100 fibres x 15 particles each, irregular cross-sections)
//     between two slabs, the distal slab flexing by 20 +- 20 deg.
// Counters report the worst volume error, bone penetration and muscle overlap over the frames.
#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/deformation/fibres_first.hpp"
#include "fascicle/fibres/decompose.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/mesh_io.hpp"

#include <benchmark/benchmark.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <string>

namespace fascicle {
namespace {

const std::filesystem::path data_dir = FASCICLE_DEFAULT_DATA_DIR;

TriMesh read_vh(const std::string& part) {
  return read_mesh(data_dir / ("visible_human_female/right/VHF_Right_" + part + "_smooth.stl"),
                   LengthUnit::millimetre);
}

TriMesh merge(const TriMesh& a, const TriMesh& b) {
  TriMesh m;
  m.V.resize(a.V.rows() + b.V.rows(), 3);
  m.V << a.V, b.V;
  m.F.resize(a.F.rows() + b.F.rows(), 3);
  m.F << a.F, (b.F.array() + static_cast<int>(a.V.rows())).matrix();
  return m;
}

Transform rotation_about(const Vec3& axis, double angle, const Vec3& centre) {
  Transform T = Transform::Identity();
  T.translate(centre).rotate(Eigen::AngleAxisd(angle, axis.normalized())).translate(-centre);
  return T;
}

// The shank scene: bones, their queries and the muscles' fibre specifications (set up once).
struct Shank {
  std::vector<std::unique_ptr<MeshQuery>> bones;
  std::vector<FibreBundleSpec> muscles;       // display surface: the hull tube
  std::vector<FibreBundleSpec> loft_muscles;  // the same fibres with the segmented rest surface
  Vec3 ankle = Vec3::Zero();
  double setup_s = 0.0;

  Shank() {
    const auto t0 = std::chrono::steady_clock::now();
    const TriMesh shank = merge(read_vh("Bone_Tibia"), read_vh("Bone_Fibula"));
    const TriMesh talus = read_vh("Bone_Talus");
    const TriMesh foot = merge(talus, read_vh("Bone_Calcaneous"));
    ankle = talus.V.colwise().mean().transpose();
    bones.push_back(std::make_unique<MeshQuery>(shank));
    bones.push_back(std::make_unique<MeshQuery>(foot));
    const char* names[] = {"Soleus", "GastrocnemiusMedial", "GastrocnemiusLateral",
                           "TibialisAnterior", "TibialisPosterior", "PeroneusLongus",
                           "ExtensorDigitorumLongus"};
    DecomposeOptions options;
    options.count = 100;
    options.resolution = 15;
    for (const char* name : names) {
      const TriMesh mesh = read_vh(std::string("Muscle_") + name);
      const Decomposition d = decompose_muscle(mesh, find_end_attachments(mesh), options);
      muscles.push_back({name, d.fibres.fibres, 0, 1});
      loft_muscles.push_back(muscles.back());
      loft_muscles.back().rest_surface = mesh;
    }
    setup_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
  std::vector<const MeshQuery*> bone_list() const { return {bones[0].get(), bones[1].get()}; }
};

const Shank& shank() {
  static const Shank s;  // benchmark fixture data, built on first use
  return s;
}

struct Worst {
  double volume = 0.0, penetration = 0.0, overlap = 0.0, iterations = 0.0, factorisations = 0.0,
         updates = 0.0, residual = 0.0,
         bone_contacts = 0.0, muscle_contacts = 0.0;
  std::int64_t frames = 0;
  void add(const FibresFirstSolver& solver) {
    ++frames;
    iterations += solver.get_info().iterations;
    factorisations += solver.get_info().factorisations;
    updates += solver.get_info().factor_updates;
    residual = std::max(residual, solver.get_info().residual);
    for (const FibreBundleFrame& f : solver.get_muscles()) {
      volume = std::max(volume, f.relative_volume_error);
      penetration = std::max(penetration, f.max_bone_penetration_m);
      overlap = std::max(overlap, f.max_muscle_overlap_m);
      bone_contacts += f.bone_contacts;
      muscle_contacts += f.muscle_contacts / 2.0;
    }
  }
  void report(benchmark::State& state, int particles) const {
    state.counters["particles"] = particles;
    state.counters["max_rel_vol_err"] = volume;
    state.counters["max_bone_pen_mm"] = penetration * 1e3;
    state.counters["max_overlap_mm"] = overlap * 1e3;
    state.counters["iters_per_frame"] = iterations / frames;
    state.counters["refactors_per_frame"] = factorisations / frames;
    state.counters["updates_per_frame"] = updates / frames;
    state.counters["max_residual"] = residual;
    state.counters["bone_contacts"] = bone_contacts / frames;
    state.counters["muscle_pairs"] = muscle_contacts / frames;
  }
};

// One quasi-static (or dynamic) frame per iteration while the foot swings; `loft`: the display
// (and volume) surface is the segmented rest surface carried by the particles, as in scenes.
// `surface_particles`: the loft's vertices are particles of the system and the display surfaces
// are separated (FibresFirstOptions::surface_particles + separate_surfaces).
void run_shank_frames(benchmark::State& state, bool loft, bool surface_particles = false) {
  ThreadLimit one(1);
  const Shank& s = shank();
  FibresFirstOptions o;
  o.dynamic = state.range(0) != 0;
  o.max_iterations = static_cast<int>(state.range(1));
  o.max_contact_rounds = static_cast<int>(state.range(2));
  o.anderson_window = static_cast<int>(state.range(3));
  o.step_tolerance = 1e-4 * static_cast<double>(state.range(4));
  o.surface_particles = surface_particles;
  o.separate_surfaces = surface_particles;
  const FibresFirstModel model =
      build_fibres_first_model(loft ? s.loft_muscles : s.muscles, s.bone_list(), o);
  FibresFirstSolver solver(model);
  const Vec3 axis = Vec3::UnitX();  // medio-lateral in the Visible Human frame (x across the body)
  std::int64_t k = 0;
  Worst worst;
  for (auto _ : state) {
    const double angle = (10.0 + 15.0 * std::sin(0.07 * static_cast<double>(k++))) * M_PI / 180.0;
    try {
      solver.calc_frame({{Transform::Identity(), rotation_about(axis, angle, s.ankle)}, 1.0 / 60.0});
    } catch (const Error& e) {  // a failed frame (e.g. the volume hold) is reported, not timed
      state.SkipWithError(e.what());
      break;
    }
    worst.add(solver);
  }
  if (worst.frames == 0) return;
  worst.report(state, model.num_particles());
  state.counters["setup_s"] = s.setup_s;
  state.SetLabel(std::string(o.dynamic ? "VH shank, dynamic" : "VH shank, quasi-static") +
                 (loft ? (surface_particles ? ", surface particles, separated" : ", loft surface")
                       : ", hull tube"));
}

void BM_ShankFrame(benchmark::State& state) { run_shank_frames(state, false); }
void BM_ShankFrameLoft(benchmark::State& state) { run_shank_frames(state, true); }
void BM_ShankFrameSurfaceParticles(benchmark::State& state) { run_shank_frames(state, true, true); }
// Args: dynamic, iterations per round, contact rounds, Anderson window (0: plain projective
// dynamics), step tolerance in units of 1e-4
BENCHMARK(BM_ShankFrame)
    ->Args({0, 20, 4, 5, 30})  // the defaults
    ->Args({0, 20, 4, 5, 10})
    ->Args({0, 20, 4, 0, 10})
    ->Args({0, 10, 2, 5, 30})
    ->Args({0, 10, 1, 5, 30})
    ->Args({0, 3, 1, 5, 30})
    ->Args({1, 10, 2, 5, 30})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(120);  // the same 120 frames (about 1.3 periods of the foot's motion) every run
// The scenes' display surface, same arguments: the converged defaults and the real-time setting.
BENCHMARK(BM_ShankFrameLoft)
    ->Args({0, 20, 4, 5, 30})
    ->Args({0, 3, 1, 5, 30})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(120);

// The loft's vertices as particles with display-surface separation (option, off by default).
BENCHMARK(BM_ShankFrameSurfaceParticles)
    ->Args({0, 20, 4, 5, 30})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(120);
// 43 bundles with irregular (R2-sampled) elliptic cross-sections on a 7 x 7 grid, touching.
struct Synthetic {
  std::vector<std::unique_ptr<MeshQuery>> bones;
  std::vector<FibreBundleSpec> muscles;
  double length = 0.25;
  Synthetic() {
    const double ry = 0.009, rx = 0.007, pitch_x = 2 * rx + 0.001, pitch_y = 2 * ry + 0.001;
    bones.push_back(std::make_unique<MeshQuery>([&] {
      TriMesh top = make_box(Vec3(0.1, 0.1, 0.01));
      top.V.col(2).array() += length + 0.01;
      return top;
    }()));
    bones.push_back(std::make_unique<MeshQuery>([&] {
      TriMesh bottom = make_box(Vec3(0.1, 0.1, 0.01));
      bottom.V.col(2).array() -= 0.01;
      return bottom;
    }()));
    for (int m = 0; m < 43; ++m) {
      const Vec3 centre((m % 7 - 3) * pitch_x, (m / 7 - 3) * pitch_y, 0.0);
      FibreBundleSpec spec{"bundle_" + std::to_string(m), {}, 0, 1};
      for (int f = 0; f < 100; ++f) {
        const Vec2 u = get_r2_point(f + 17 * m);
        const double r = std::sqrt(u.x()), phi = 2 * M_PI * u.y();
        Points3 fibre(2, 3);
        fibre.row(0) = (centre + Vec3(rx * r * std::cos(phi), ry * r * std::sin(phi), length)).transpose();
        fibre.row(1) = fibre.row(0);
        fibre(1, 2) = 0.0;
        spec.fibres.push_back(fibre);
      }
      muscles.push_back(std::move(spec));
    }
  }
};

void BM_Synthetic43(benchmark::State& state) {
  ThreadLimit one(1);
  static const Synthetic s;  // benchmark fixture data
  FibresFirstOptions o;
  o.max_iterations = static_cast<int>(state.range(0));
  o.max_contact_rounds = static_cast<int>(state.range(1));
  const FibresFirstModel model =
      build_fibres_first_model(s.muscles, {s.bones[0].get(), s.bones[1].get()}, o);
  FibresFirstSolver solver(model);
  std::int64_t k = 0;
  Worst worst;
  for (auto _ : state) {
    const double angle = (20.0 + 20.0 * std::sin(0.05 * static_cast<double>(k++))) * M_PI / 180.0;
    solver.calc_frame({{Transform::Identity(), rotation_about(Vec3::UnitX(), angle, Vec3(0, -0.07, 0))}});
    worst.add(solver);
  }
  worst.report(state, model.num_particles());
  state.SetLabel("43 synthetic bundles x 100 fibres x 15 particles");
}
BENCHMARK(BM_Synthetic43)->Args({20, 4})->Args({3, 1})->Unit(benchmark::kMillisecond)->MinTime(3.0);

}  // namespace
}  // namespace fascicle

BENCHMARK_MAIN();
