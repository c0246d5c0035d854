// Muscle parameters from OpenSim .osim model files (format versions 30000-40600).
#pragma once

#include "fascicle/musculotendon/parameters.hpp"

#include <filesystem>
#include <string>

namespace pugi {
class xml_node;
}

namespace fascicle {

// True for <Thelen2003Muscle>, <Millard2012EquilibriumMuscle>, <DeGrooteFregly2016Muscle>, also
// when written with a namespace prefix such as <OpenSim::Thelen2003Muscle>.
bool is_osim_muscle_element(const pugi::xml_node& element);

// Parameters of one muscle element. Properties absent from the file take OpenSim 4.5's C++
// defaults; present ones win (gait2392 sets its own Thelen values). Millard curve sub-objects
// (ActiveForceLengthCurve, ForceVelocityCurve, FiberForceLengthCurve, TendonForceLengthCurve)
// are read with OpenSim's rules for optional stiffness/curviness. Throws bad_input naming the
// file, the muscle and the property for unknown element types or malformed numbers, and
// validates the result.
MuscleParameters parse_osim_muscle(const pugi::xml_node& muscle_element, const std::string& file);

// Finds the muscle called `muscle_name` anywhere in the .osim file; throws bad_input if the file
// cannot be read or has no such muscle.
MuscleParameters read_osim_muscle(const std::filesystem::path& path, const std::string& muscle_name);

}  // namespace fascicle
