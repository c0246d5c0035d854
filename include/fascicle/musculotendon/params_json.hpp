// Muscle parameters from a JSON file (format in docs/musculotendon.md, "Parameter files").
#pragma once

#include "fascicle/musculotendon/parameters.hpp"

#include <filesystem>
#include <string>

namespace fascicle {

// Parses the JSON text; `file` names the source in error messages. Unknown keys are errors
// (with their JSON path), absent keys take the model's OpenSim defaults. F0 may instead be given
// by "volume_m3" (and optional "specific_tension_Pa", default 25 N/cm²) as F0 = σ V cos α0 / l0.
MuscleParameters parse_muscle_parameters_json(const std::string& text, const std::string& file);
MuscleParameters read_muscle_parameters_json(const std::filesystem::path& path);

}  // namespace fascicle
