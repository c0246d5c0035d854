// Static equilibrium per muscle-state and one dynamics step of the 92 gait2392 muscles.
#include "fascicle/musculotendon/muscle.hpp"
#include "fascicle/musculotendon/osim_parameters.hpp"

#include <benchmark/benchmark.h>
#include <pugixml.hpp>

#include <string>
#include <vector>

using namespace fascicle;

namespace {
Musculotendon bench_muscle(MuscleModel model) {
  MuscleParameters p = default_muscle_parameters(model);
  p.name = "bench";
  p.max_isometric_force_N = 1500;
  p.optimal_fiber_length_m = 0.09;
  p.tendon_slack_length_m = 0.25;
  p.pennation_at_optimal_rad = 0.2;
  return compile_musculotendon(p);
}

// Static equilibrium (with all outputs and curve derivatives) over a sweep of path lengths;
// "_no_energies" skips the two elastic-energy integrals.
void BM_StaticEquilibrium(benchmark::State& state, MuscleModel model, bool energies) {
  const Musculotendon m = bench_muscle(model);
  double lMT = 0.30;
  for (auto _ : state) {
    lMT = (lMT > 0.40) ? 0.30 : lMT + 1e-4;
    const MuscleOutputs o = calc_static_equilibrium(m, 0.6, lMT, 0.0, {.energies = energies});
    benchmark::DoNotOptimize(o.fiber_length_m);
  }
}
BENCHMARK_CAPTURE(BM_StaticEquilibrium, thelen, MuscleModel::thelen2003, true);
BENCHMARK_CAPTURE(BM_StaticEquilibrium, millard, MuscleModel::millard2012, true);
BENCHMARK_CAPTURE(BM_StaticEquilibrium, degroote, MuscleModel::degroote2016, true);
BENCHMARK_CAPTURE(BM_StaticEquilibrium, thelen_no_energies, MuscleModel::thelen2003, false);
BENCHMARK_CAPTURE(BM_StaticEquilibrium, millard_no_energies, MuscleModel::millard2012, false);

std::vector<Musculotendon> gait2392(const char* file) {
  const std::string path = std::string(FASCICLE_DEFAULT_DATA_DIR) + "/opensim/models/" + file;
  pugi::xml_document doc;
  doc.load_file(path.c_str());
  std::vector<Musculotendon> out;
  for (const pugi::xpath_node& x : doc.select_nodes("//*[@name]")) {
    if (is_osim_muscle_element(x.node())) out.push_back(compile_musculotendon(parse_osim_muscle(x.node(), path)));
  }
  return out;
}

// State derivative (activation and fibre-length rates, all outputs) of the 92 muscles.
void BM_DynamicsStep92(benchmark::State& state, const char* file) {
  const std::vector<Musculotendon> muscles = gait2392(file);
  if (muscles.size() != 92) {
    state.SkipWithError("gait2392 model not found in the shared data folder");
    return;
  }
  std::vector<MuscleState> s;
  std::vector<double> lMT;
  for (const Musculotendon& m : muscles) {
    lMT.push_back(m.params.tendon_slack_length_m * 1.02 + m.params.optimal_fiber_length_m);
    s.push_back(calc_equilibrium_state(m, 0.3, lMT.back()));
  }
  for (auto _ : state) {
    double acc = 0.0;
    for (size_t i = 0; i < muscles.size(); ++i) {
      MuscleOutputs o;
      const MuscleStateRate r = calc_state_rate(muscles[i], s[i], 0.5, lMT[i], 0.01, &o);
      acc += r.fiber_length + o.tendon_force_N;
    }
    benchmark::DoNotOptimize(acc);
  }
}
BENCHMARK_CAPTURE(BM_DynamicsStep92, thelen, "gait2392_thelen2003muscle.osim");
BENCHMARK_CAPTURE(BM_DynamicsStep92, millard, "gait2392_millard2012muscle.osim");
}  // namespace

BENCHMARK_MAIN();
