// An OpenSim model compiled for analysis — skeleton on Simbody, compiled muscle paths, compiled
// Hill-type musculotendons — and its per-frame evaluation: body poses and Jacobians, path lengths,
// lengthening speeds, exact moment arms, and the static-equilibrium fibre quantities of OpenSim's
// MuscleAnalysis. This is the library behind `fascicle analyze` and `fascicle paths`.
//
// Conventions (docs/analyze.md): SI units and radians; coordinate speeds are q̇ (u = q̇ for every
// joint, see docs/skeleton.md); moment arms r_j = −∂L/∂q_j along the coupler constraints (the
// columns of dependent coordinates are zero: their effect is in the independent coordinate's).
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "fascicle/core/types.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/musculotendon/muscle.hpp"
#include "fascicle/osim/osim_model.hpp"
#include "fascicle/path/path_model.hpp"
#include "fascicle/skeleton/skeleton.hpp"

namespace fascicle {

// Immutable after construction; shared by all threads.
struct OsimAnalysisModel {
  OsimModel osim;                           // the imported specs
  Skeleton skeleton;
  PathSetModel paths;                       // one compiled path per osim.paths.paths entry
  std::vector<int> muscles;                 // indices into osim.actuators of the muscles
  std::vector<Musculotendon> musculotendons;  // one per entry of `muscles`
  std::vector<int> muscle_path;             // index into paths.paths, one per entry of `muscles`

  int num_muscles() const { return static_cast<int>(muscles.size()); }
  const std::string& get_muscle_name(int m) const { return osim.actuators[muscles[m]].name; }
  int find_muscle(const std::string& name) const;  // -1 if absent
};

// Compiles an imported model. `path_options` replaces the model's path options when given
// (OpenSim's defaults are kept otherwise). Throws fascicle::Error (bad_input) naming the model file
// and the element for unknown bodies/coordinates/wrap objects and non-physical muscle parameters.
OsimAnalysisModel compile_osim_model(OsimModel osim,
                                     const std::optional<PathOptions>& path_options = std::nullopt);

// read_osim + compile_osim_model.
OsimAnalysisModel load_osim_model(const std::filesystem::path& file,
                                  const OsimImportOptions& import = {},
                                  const std::optional<PathOptions>& path_options = std::nullopt);

// Per-thread, per-frame workspace: the skeleton state and the body Jacobians of the last pose.
struct OsimFrame {
  explicit OsimFrame(const OsimAnalysisModel& model);
  SkeletonState skeleton;
  BodyJacobians jacobians;  // J per body and dq_du = coupling (u = q̇ of every coordinate)
  bool has_jacobians = false;
};

// Poses the skeleton at q (#coordinates; dependent coordinates are assembled from their
// couplers, locked ones held at their default) and, when `jacobians`, fills the body Jacobians.
void calc_frame(const OsimAnalysisModel& model, const VecX& q, OsimFrame& frame,
                bool jacobians = true);

// Length (m) of path `path` in the posed frame; `out` keeps the vertices and wraps.
double calc_path_length(const OsimAnalysisModel& model, const OsimFrame& frame, int path,
                        PathResult& out);

// Moment arms (#coordinates, m or dimensionless for translational coordinates) of an evaluated
// path: r_j = −∂L/∂q_j. Needs calc_frame(..., jacobians = true).
VecX calc_path_moment_arms(const OsimAnalysisModel& model, const OsimFrame& frame, int path,
                           const PathResult& result);

// Independent, unlocked coordinates that at least one muscle spans: a joint lies between two of
// the bodies its path points and wrap objects ride on, or a moving point depends on it (a
// dependent coordinate counts for its independent one). In the skeleton's coordinate order.
std::vector<int> find_spanned_coordinates(const OsimAnalysisModel& model);

// ----------------------------------------------------------------------------------------------
// MuscleAnalysis over a motion
// ----------------------------------------------------------------------------------------------

struct MuscleAnalysisOptions {
  // Coordinates for moment arms by name; empty: find_spanned_coordinates.
  std::vector<std::string> coordinates;
  // Activations by muscle (columns named by muscle, or `/forceset/<muscle>/activation`),
  // interpolated linearly at the motion's times; muscles without a column use their default.
  const Table* activations = nullptr;
  std::string activations_file;  // for error messages
  std::string motion_file;       // for error messages
  bool progress = true;          // a progress bar on a terminal
};

// Every matrix is #frames × #muscles, SI units and radians.
struct MuscleAnalysis {
  std::string model_name;
  VecX time;
  std::vector<std::string> muscles;
  bool has_speeds = false;  // the motion gave coordinate speeds (else speeds are zero)
  MatX length, lengthening_speed, fiber_length, pennation, tendon_length, normalized_fiber_length,
      tendon_force, active_fiber_force, passive_fiber_force, activation;
  std::vector<std::string> moment_arm_coordinates;
  std::vector<MatX> moment_arms;  // one per moment_arm_coordinates entry
};

// Runs the analysis over every row of `motion` (columns matched to coordinates by name or by
// absolute path; unknown coordinate columns are an error naming the file and column; columns
// `/jointset/<j>/<c>/speed` give coordinate speeds). Parallel over muscles, deterministic.
MuscleAnalysis calc_muscle_analysis(const OsimAnalysisModel& model, const Table& motion,
                                    const MuscleAnalysisOptions& options = {});

// Writes `<model>_MuscleAnalysis_<Quantity>.sto` (Length, FiberLength, PennationAngle,
// TendonLength, NormalizedFiberLength, TendonForce, ActiveFiberForce, PassiveFiberForce and
// MomentArm_<coordinate>) into `folder` (created if needed). All tables are written to temporary
// files first and renamed into place only when every one has been written. Returns the paths.
std::vector<std::filesystem::path> write_muscle_analysis(const std::filesystem::path& folder,
                                                         const MuscleAnalysis& analysis);

// ----------------------------------------------------------------------------------------------
// Path geometry for viewing
// ----------------------------------------------------------------------------------------------

// Coordinate values from `name=value` assignments (rad or m; a value may end in "deg" for a
// rotational coordinate) on top of the default pose. Throws a usage error naming an unknown
// coordinate, a dependent one, or a value that does not parse.
VecX parse_pose(const Skeleton& skeleton, const std::vector<std::string>& assignments);

// Writes the posed model for viewing in ParaView: `<model>_paths.vtp` (one polyline per path,
// origin to insertion through the active points, wrap arcs sampled every `arc_step_m`; cell
// fields `path` (index into model.paths.paths) and `length_m`) and `<model>_bones.vtp` (every
// attached mesh found, in ground; cell field `body`). Bone meshes that cannot be read are skipped
// with a warning. Each file is written atomically. Returns the paths written.
std::vector<std::filesystem::path> write_path_geometry(const std::filesystem::path& folder,
                                                       const OsimAnalysisModel& model,
                                                       const VecX& q, double arc_step_m = 0.002);

}  // namespace fascicle
