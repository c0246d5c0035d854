// OpenSim model import (.osim, format versions 30000–40600): the skeleton (bodies, joints,
// coordinates, coordinate couplers, attached meshes), wrap objects, and the force elements that
// have a GeometryPath (muscles, PathActuator, PathSpring, Ligament) as plain specs of the skeleton,
// path and musculotendon modules. Element names written with a namespace (`OpenSim::Body`) are
// read like plain ones. See docs/opensim-import.md.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "fascicle/io/table.hpp"
#include "fascicle/musculotendon/parameters.hpp"
#include "fascicle/path/path_spec.hpp"
#include "fascicle/skeleton/skeleton.hpp"

namespace fascicle {

// A force element with a path, in the order of the model's ForceSet.
struct OsimPathActuator {
  std::string name;
  std::string type;                             // element type, e.g. "Thelen2003Muscle"
  int path = -1;                                // index into OsimModel::paths.paths
  std::optional<MuscleParameters> muscle;       // for the three supported muscle models
  double default_activation = 0.05;             // from <default_activation> when present
};

struct OsimModel {
  std::filesystem::path file;
  std::string name;
  int version = 0;                    // the file's Version attribute (e.g. 30000, 40000)
  SkeletonSpec skeleton;              // mesh files resolved to absolute paths where found
  PathSetSpec paths;
  std::vector<OsimPathActuator> actuators;
  std::vector<std::string> unsupported;    // "Type 'name'" of every element that was skipped
  std::vector<std::string> missing_meshes; // mesh files found in no search folder
};

struct OsimImportOptions {
  // Searched for mesh files after the model's folder and its Geometry/ (OpenSim's order).
  std::vector<std::filesystem::path> geometry_dirs;
  bool warn = true;  // log one warning listing unsupported elements, one per missing mesh
};

// Reads a model. Throws fascicle::Error (bad_input) naming the file, the element and its line
// for malformed XML, unsupported joint or function types, unknown bodies/coordinates, and paths
// with fewer than two points.
OsimModel read_osim(const std::filesystem::path& path, const OsimImportOptions& options = {});

// OpenSim's search for a mesh file: absolute path, the model folder, its Geometry/ subfolder, then
// each of `geometry_dirs`. Returns an empty path when not found.
std::filesystem::path find_mesh_file(const std::string& mesh_file,
                                     const std::filesystem::path& model_file,
                                     const std::vector<std::filesystem::path>& geometry_dirs);

// Coordinate values (#coordinates of `skeleton`, radians/metres) for row `row` of a motion table:
// columns are matched by coordinate name or absolute path (`/jointset/j/c/value`); rotational
// columns are converted from degrees when the table says inDegrees=yes; coordinates absent from
// the table keep their default; dependent (coupled) coordinates are left to assembly. Unknown
// coordinate columns raise a bad-input error naming the column when `strict`.
struct MotionColumns {
  std::vector<int> column_of_coordinate;  // -1 when the coordinate is not in the table
  std::vector<double> scale;              // π/180 for rotational columns in degrees, else 1
};
MotionColumns match_motion_columns(const Skeleton& skeleton, const Table& motion,
                                   const std::string& motion_file, bool strict = true);
VecX get_motion_pose(const Skeleton& skeleton, const Table& motion, const MotionColumns& columns,
                     long row);

}  // namespace fascicle
