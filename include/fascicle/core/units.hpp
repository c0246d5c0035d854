// Length units of input files. fascicle computes in SI; inputs in millimetres (Visible Human,
// MRI segmentations) are scaled to metres on load.
#pragma once

#include <string>
#include <string_view>

namespace fascicle {

enum class LengthUnit { metre, centimetre, millimetre };

// Metres per unit (millimetre -> 1e-3).
double metres_per(LengthUnit unit);

// Parses "m", "cm", "mm" (case-insensitive); throws a usage error naming the accepted values.
LengthUnit parse_length_unit(std::string_view text);

// Parses a length with an optional unit suffix ("2mm", "0.002", "0.5 cm") into metres.
double parse_length(std::string_view text);

std::string to_string(LengthUnit unit);

}  // namespace fascicle
