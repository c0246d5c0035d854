#include "fascicle/scene/driver.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/log.hpp"
#include "fascicle/core/progress.hpp"
#include "muscle_setup.hpp"

#include <tbb/task_group.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <utility>

namespace fascicle {

CoordinateTrajectory make_trajectory(const Model& model, const Table& motion, double frame_rate_hz) {
  const Table t = resample_linear(motion, frame_rate_hz);
  CoordinateTrajectory traj;
  traj.time = t.time;
  traj.q = model.default_q.transpose().replicate(t.rows(), 1);
  int matched = 0;
  for (long c = 0; c < t.columns(); ++c) {
    const std::string name = find_coordinate_of_label(t.labels[c]);
    const CoordinateIndex ci = name.empty() ? CoordinateIndex{} : model.find_coordinate(name);
    if (!ci.valid()) {
      spdlog::debug("motion column '{}' matches no coordinate; ignored", t.labels[c]);
      continue;
    }
    ++matched;
    const Coordinate& coord = model.coordinates[ci.v];
    const double scale = (t.in_degrees && coord.rotational) ? M_PI / 180.0 : 1.0;
    bool outside = false;
    for (long r = 0; r < t.rows(); ++r) {
      const double v = scale * t.data(r, c);
      const double cv = std::clamp(v, coord.range_min, coord.range_max);
      outside |= cv != v;
      traj.q(r, ci.v) = coord.clamped ? cv : v;
    }
    if (outside && coord.clamped)
      spdlog::warn("motion takes coordinate '{}' outside its range [{}, {}]; values clamped", coord.name,
                   coord.range_min, coord.range_max);
    else if (outside)
      spdlog::warn("motion takes coordinate '{}' outside its range [{}, {}]; kept (the coordinate is not clamped)",
                   coord.name, coord.range_min, coord.range_max);
  }
  if (matched == 0 && model.num_coordinates() > 0)
    throw_bad_input("no motion column matches a coordinate of the scene",
                    {.suggestion = "name the columns after the coordinates (e.g. '" +
                                   model.coordinates[0].name + "')"});
  return traj;
}

void add_activations(const Model& model, const Table& t, const std::string& file, CoordinateTrajectory& traj) {
  const long frames = traj.time.size();
  traj.activation = MatX::Constant(frames, model.num_muscles(), std::numeric_limits<double>::quiet_NaN());
  int matched = 0;
  for (long c = 0; c < t.columns(); ++c) {
    const std::string& label = t.labels[c];
    for (int m = 0; m < model.num_muscles(); ++m) {
      const std::string& name = model.muscles[m].name;
      const std::string path_suffix = "/" + name + "/activation";
      const bool match = label == name || label == name + ".activation" ||
                         (label.size() > path_suffix.size() &&
                          label.compare(label.size() - path_suffix.size(), path_suffix.size(), path_suffix) == 0);
      if (!match) continue;
      ++matched;
      for (long r = 0; r < frames; ++r) {
        const double time = traj.time[r];
        // Linear interpolation in the table's (increasing) times, constant outside.
        const auto it = std::lower_bound(t.time.data(), t.time.data() + t.rows(), time);
        const long k = it - t.time.data();
        double v;
        if (k <= 0) v = t.data(0, c);
        else if (k >= t.rows()) v = t.data(t.rows() - 1, c);
        else {
          const double w = (time - t.time[k - 1]) / (t.time[k] - t.time[k - 1]);
          v = (1.0 - w) * t.data(k - 1, c) + w * t.data(k, c);
        }
        if (!std::isfinite(v))
          throw_bad_input("activation is not a number at t = " + std::to_string(time) + " s",
                          {.file = file, .object = label});
        traj.activation(r, m) = std::clamp(v, 0.0, 1.0);
      }
    }
  }
  if (matched == 0)
    throw_bad_input("no activation column matches a muscle of the scene",
                    {.file = file, .suggestion = "name columns after muscles, e.g. '" +
                                                 (model.muscles.empty() ? std::string("soleus_r") : model.muscles[0].name) +
                                                 "' or '/forceset/<muscle>/activation'"});
}

// Frames are pipelined: while the muscles of frame k+1 are solved, frame k's muscle-overlap
// measure and writers run as one task beside them (the solves of a frame depend on the previous
// frame's solver states only, never on its overlaps or outputs). The writers see a State of their
// own holding a copy of the frame's pose and muscles, so the files and metrics are the same as in
// the sequential order, for any number of threads; frames are written in order.
DriverResult run_frames(const Model& model, const CoordinateTrajectory& traj, const DriverOptions& options,
                        const std::vector<FrameWriter*>& writers) {
  const int frames = static_cast<int>(traj.time.size());
  if (traj.q.rows() != frames || traj.q.cols() != model.num_coordinates())
    throw_internal("run_frames: trajectory has the wrong shape");
  RunInfo info{options.out_dir, options.basename, frames, options.frame_rate_hz};
  for (FrameWriter* w : writers) w->begin(model, info);

  DriverResult result;
  const auto start = std::chrono::steady_clock::now();
  std::unique_ptr<ProgressBar> bar;
  if (options.progress) bar = std::make_unique<ProgressBar>("frames", static_cast<size_t>(frames));
  State state = make_state(model);
  State written;  // the frame handed to the writers (pose, muscles, overlaps; no solver state)

  // The writing task of one frame; its error (if any) is kept with its frame and rethrown by
  // wait_writing() on the calling thread.
  tbb::task_group writing;
  bool pending = false;
  int writing_frame = -1;
  std::exception_ptr writing_error;
  const auto wait_writing = [&] {
    if (!pending) return;
    writing.wait();
    pending = false;
    if (writing_error) std::rethrow_exception(std::exchange(writing_error, nullptr));
    ++result.frames_written;
    if (bar) bar->advance();
  };
  // Never leave this scope (also by an exception other than fascicle::Error) with a task running.
  struct JoinOnExit {
    tbb::task_group& group;
    ~JoinOnExit() {
      try {
        group.wait();
      } catch (...) {
      }
    }
  } join_on_exit{writing};

  int frame = 0;
  double failed_time = 0.0;
  try {
    for (; frame < frames; ++frame) {
      state.time_s = traj.time[frame];
      state.q = traj.q.row(frame).transpose();
      if (traj.activation.rows() == frames) state.activation = traj.activation.row(frame).transpose();
      state.stage = Stage::none;
      failed_time = state.time_s;
      calc_pose(model, state);
      calc_action_lines(model, state);
      calc_forces(model, state);
      scene_detail::calc_muscle_shapes(model, state);
      const int solved = frame;
      frame = writing_frame;  // an error while waiting belongs to the frame being written
      if (pending) failed_time = written.time_s;
      wait_writing();
      frame = solved;
      written.time_s = state.time_s;
      written.q = state.q;
      written.activation = state.activation;
      written.X_ground_body = state.X_ground_body;
      written.muscles = state.muscles;
      written.stage = Stage::forces;
      writing_frame = frame;
      pending = true;
      writing.run([&model, &writers, &written, &writing_error, frame] {
        try {
          calc_muscle_overlaps(model, written);
          written.stage = Stage::geometry;
          for (FrameWriter* w : writers) w->write_frame(model, written, frame);
        } catch (...) {
          writing_error = std::current_exception();
        }
      });
    }
    frame = writing_frame;
    failed_time = written.time_s;
    wait_writing();
  } catch (const Error& e) {
    // the frame that failed (a solve, or the writing of the frame before it); the frame being
    // written when a solve failed is completed first, so every frame before the failure is on disk
    try {
      wait_writing();
    } catch (...) {
      // a second failure (of any kind) while finishing the frame before: the first is reported
    }
    if (bar) bar->finish();
    for (FrameWriter* w : writers) w->finish(model);
    ErrorContext ctx = e.context();
    const std::string where = "frame " + std::to_string(frame) + " (t = " + std::to_string(failed_time) + " s)";
    if (ctx.suggestion.empty())
      ctx.suggestion = std::to_string(result.frames_written) + " frames before it were written and stay valid";
    throw Error(e.kind(), e.message() + " at " + where, ctx);
  }
  if (bar) bar->finish();
  for (FrameWriter* w : writers) w->finish(model);
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  for (FrameWriter* w : writers)
    for (auto& p : w->get_outputs()) result.outputs.push_back(p);
  return result;
}

std::vector<std::unique_ptr<FrameWriter>> make_writers(const Registry& registry,
                                                       const std::vector<std::string>& names) {
  std::vector<std::string> use = names;
  if (use.empty()) use = {"paraview", "sto", "csv", "summary"};
  std::vector<std::unique_ptr<FrameWriter>> writers;
  for (const auto& n : use) writers.push_back(registry.writers.get(n)());
  return writers;
}

}  // namespace fascicle
