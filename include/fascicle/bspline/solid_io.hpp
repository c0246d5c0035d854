// JSON file format of B-spline solids and VTK export (boundary and fibres .vtp, volume .vtu).
//
// {
//   "format": "fascicle.bspline_solid", "version": 1, "name": "soleus_r", "units": "m",
//   "fibre_direction": "w",
//   "bases": [ {"degree": 3, "periodic": false, "control_points": 5, "knots": [...]}, x3 (u,v,w) ],
//   "control_points": [[x, y, z], ...]      // i fastest, then j, then k
// }
// "units" may be "m", "cm" or "mm": coordinates are scaled to metres on read; files are written
// in metres.
#pragma once

#include "fascicle/bspline/solid.hpp"

#include <filesystem>
#include <string>
#include <vector>

namespace fascicle {

// Throws fascicle::Error (bad_input, naming the file and JSON path) for malformed files.
BSplineSolid read_solid(const std::filesystem::path& path);
BSplineSolid parse_solid(const std::string& json_text, const std::string& source = "<string>");
std::string format_solid(const BSplineSolid& solid);  // JSON text
void write_solid(const std::filesystem::path& path, const BSplineSolid& solid);  // atomic

// Polylines (each #n x 3, metres) written as VTK PolyData lines, atomically.
void write_polylines_vtp(const std::filesystem::path& path, const std::vector<Points3>& lines);
// Hexahedral mesh as a VTK unstructured grid; optional per-node vectors (e.g. fibre directions).
void write_hexahedra_vtu(const std::filesystem::path& path, const Points3& V,
                         const Eigen::Matrix<int, Eigen::Dynamic, 8>& hexes,
                         const Points3* node_vectors = nullptr,
                         const std::string& vector_name = "fibre_direction");

}  // namespace fascicle
