// The classical muscle experiments of seed 000 §4.6 on one compiled musculotendon: isometric
// force-length sweep, rise to tetanus, quick release and isotonic contractions. Each returns a
// table (columns with units in their names) and a few summary numbers.
#pragma once

#include "fascicle/musculotendon/muscle.hpp"

#include <string>
#include <utility>
#include <vector>

namespace fascicle {

struct ExperimentTable {
  std::vector<std::string> columns;
  std::vector<std::vector<double>> rows;
  std::vector<double> column(const std::string& name) const;  // throws internal if absent
};

struct ExperimentResult {
  ExperimentTable table;
  std::vector<std::pair<std::string, double>> summary;  // name (with unit) → value
  double summary_value(const std::string& name) const;
};

// Path length at which the fully activated, isometric muscle has its fibre at l0.
double calc_optimal_musculotendon_length(const Musculotendon& m);

// Force-length sweep lM/l0 ∈ [0.4, 1.9] at full activation and zero velocity: active, passive and
// total fibre force, tendon force and the musculotendon length that holds that state.
ExperimentResult run_isometric_experiment(const Musculotendon& m, int samples = 151);

// Rise to tetanus: path held at the optimal length, initial static equilibrium at the minimum
// activation, excitation 1 from t = 0. Summary: 10-90 % rise time of the tendon force.
ExperimentResult run_tetanus_experiment(const Musculotendon& m, double duration_s = 0.4,
                                        double sample_s = 5e-4);

// Quick release: fully active isometric muscle at the optimal length; at t = 0 its end (a mass
// load_mass_kg) is released to a constant load of load_fraction × the isometric tendon force.
ExperimentResult run_quick_release_experiment(const Musculotendon& m, double load_fraction = 0.5,
                                              double load_mass_kg = 1.0, double duration_s = 0.1,
                                              double sample_s = 2e-4);

// Isotonic contractions at loads F/F_iso ∈ load_fractions (massless load, full activation),
// starting with the fibre at l0; each is integrated for duration_s. The initial fibre velocities
// recover the force-velocity curve: the table also holds the model's fv at those velocities.
ExperimentResult run_isotonic_experiment(const Musculotendon& m,
                                         const std::vector<double>& load_fractions = {},
                                         double duration_s = 0.02);

}  // namespace fascicle
