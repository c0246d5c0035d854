// The frame driver: steps a motion (a Table of coordinate values over time, resampled to a frame
// rate), runs forward() on each frame (pose → action lines → forces → muscle geometry; parallel
// over muscles) and hands the State to the writers. A failure names the muscle and the frame; the
// writers are finished first, so the frames already written stay valid.
#pragma once

#include "fascicle/io/table.hpp"
#include "fascicle/scene/model.hpp"
#include "fascicle/scene/registry.hpp"
#include "fascicle/scene/state.hpp"

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace fascicle {

// Coordinate values per frame, #frames × #coordinates, in SI (rad, m).
struct CoordinateTrajectory {
  VecX time;
  MatX q;
  MatX activation;  // #frames × #muscles, or empty; NaN: the muscle's constant activation
};

// Resamples `motion` at `frame_rate_hz` and maps its columns to the Model's coordinates (labels
// equal to coordinate names, or OpenSim paths ending in /<coordinate>/value). Rotational columns
// are converted from degrees when the table says `inDegrees=yes`. Coordinates without a column
// keep their default. Values outside a coordinate's range are clamped when the coordinate says so
// (Coordinate::clamped), else kept; either way with a warning naming the coordinate. Throws
// bad_input when no column matches any coordinate.
CoordinateTrajectory make_trajectory(const Model& model, const Table& motion, double frame_rate_hz);

// Activations over time (e.g. an OpenSim states or controls .sto), interpolated linearly at the
// trajectory's times (held constant outside the table's time range). A column belongs to a muscle
// when its label is the muscle's name, `<name>.activation`, or an OpenSim path ending in
// `/<name>/activation`. Muscles without a column keep their constant activation. Values are
// clamped to [0, 1]. Throws bad_input naming the file when no column matches any muscle.
void add_activations(const Model& model, const Table& activations, const std::string& file,
                     CoordinateTrajectory& trajectory);

struct DriverOptions {
  std::filesystem::path out_dir = ".";
  std::string basename = "scene";
  double frame_rate_hz = 50.0;
  bool progress = true;      // a progress bar on a terminal
};

struct DriverResult {
  int frames_written = 0;
  double seconds = 0.0;     // wall time of the loop
  std::vector<std::filesystem::path> outputs;
};

// Runs every frame through forward() and the writers (in order: writers[0] first).
DriverResult run_frames(const Model& model, const CoordinateTrajectory& trajectory,
                        const DriverOptions& options, const std::vector<FrameWriter*>& writers);

// Convenience: writers by their registered names (empty: paraview, sto, csv, summary).
std::vector<std::unique_ptr<FrameWriter>> make_writers(const Registry& registry,
                                                       const std::vector<std::string>& names);

}  // namespace fascicle
