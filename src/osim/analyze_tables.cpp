// MuscleAnalysis over a motion, its .sto tables, and pose parsing.
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>
#include <system_error>

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/core/progress.hpp"
#include "fascicle/osim/analyze.hpp"

namespace fascicle {
namespace {

// Column of the activation table for a muscle: its name, or `/forceset/<muscle>/activation`.
long find_activation_column(const Table& table, const std::string& muscle) {
  const long c = find_column(table, muscle);
  if (c >= 0) return c;
  return find_column(table, "/forceset/" + muscle + "/activation");
}

// Coordinate speeds (#coordinates, rad/s or m/s) for one row from `/jointset/<j>/<c>/speed`
// columns; returns false when the motion has none.
struct SpeedColumns {
  std::vector<int> column_of_coordinate;
  std::vector<double> scale;
  bool any = false;
};

SpeedColumns match_speed_columns(const Skeleton& skeleton, const Table& motion) {
  SpeedColumns sc;
  sc.column_of_coordinate.assign(skeleton.num_coordinates(), -1);
  sc.scale.assign(skeleton.num_coordinates(), 1.0);
  for (long c = 0; c < motion.columns(); ++c) {
    const std::string& label = motion.labels[c];
    const std::string suffix = "/speed";
    if (label.size() <= suffix.size() || label.compare(label.size() - suffix.size(), suffix.size(), suffix) != 0)
      continue;
    const std::string stem = label.substr(0, label.size() - suffix.size());
    const std::string name = stem.substr(stem.find_last_of('/') + 1);
    const int i = skeleton.find_coordinate(name);
    if (i < 0) continue;
    sc.column_of_coordinate[i] = static_cast<int>(c);
    if (motion.in_degrees && skeleton.get_coordinate(i).spec.motion_type == MotionType::rotational)
      sc.scale[i] = M_PI / 180.0;
    sc.any = true;
  }
  return sc;
}

bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

}  // namespace

MuscleAnalysis calc_muscle_analysis(const OsimAnalysisModel& model, const Table& motion,
                                    const MuscleAnalysisOptions& options) {
  const Skeleton& sk = model.skeleton;
  const int nm = model.num_muscles();
  const long nf = motion.rows();
  if (nf == 0) throw_bad_input("the motion has no rows", {.file = options.motion_file});
  if (nm == 0)
    throw_bad_input("the model has no muscles to analyse",
                    {.file = model.osim.file.string(),
                     .suggestion = "use a model with Thelen2003Muscle, Millard2012EquilibriumMuscle "
                                   "or DeGrooteFregly2016Muscle elements"});
  const MotionColumns columns = match_motion_columns(sk, motion, options.motion_file, true);
  const SpeedColumns speeds = match_speed_columns(sk, motion);
  // Moment-arm coordinates.
  std::vector<int> coords;
  if (options.coordinates.empty()) {
    coords = find_spanned_coordinates(model);
  } else {
    for (const std::string& name : options.coordinates) {
      const int c = sk.find_coordinate(name);
      if (c < 0)
        throw_usage("unknown coordinate '" + name + "' in --coordinates",
                    {.file = model.osim.file.string(), .object = name,
                     .suggestion = "give coordinate names of the model, separated by commas"});
      coords.push_back(c);
    }
  }
  // Activation columns.
  std::vector<long> act_col(nm, -1);
  if (options.activations) {
    const Table& a = *options.activations;
    int matched = 0;
    for (int m = 0; m < nm; ++m) {
      act_col[m] = find_activation_column(a, model.get_muscle_name(m));
      matched += act_col[m] >= 0;
    }
    if (matched == 0)
      throw_bad_input("no column of the activation table names a muscle of the model",
                      {.file = options.activations_file,
                       .suggestion = "name the columns by muscle (e.g. 'soleus_r' or "
                                     "'/forceset/soleus_r/activation')"});
    std::vector<std::string> unmatched;
    for (const std::string& label : a.labels) {
      bool used = false;
      for (int m = 0; m < nm && !used; ++m)
        used = act_col[m] >= 0 && a.labels[act_col[m]] == label;
      if (!used) unmatched.push_back(label);
    }
    if (!unmatched.empty())
      spdlog::warn("{}: {} activation column(s) name no muscle and are ignored: {}",
                   options.activations_file, unmatched.size(), fmt::join(unmatched, ", "));
  }

  MuscleAnalysis out;
  out.model_name = model.osim.name;
  out.time = motion.time;
  out.has_speeds = speeds.any;
  for (int m = 0; m < nm; ++m) out.muscles.push_back(model.get_muscle_name(m));
  for (MatX* M : {&out.length, &out.lengthening_speed, &out.fiber_length, &out.pennation,
                  &out.tendon_length, &out.normalized_fiber_length, &out.tendon_force,
                  &out.active_fiber_force, &out.passive_fiber_force, &out.activation})
    M->setConstant(nf, nm, std::numeric_limits<double>::quiet_NaN());
  for (const int c : coords) {
    out.moment_arm_coordinates.push_back(sk.get_coordinate(c).spec.name);
    out.moment_arms.emplace_back(MatX::Zero(nf, nm));
  }

  OsimFrame frame(model);
  std::vector<PathResult> results(nm);
  ProgressBar bar("analyze " + model.osim.name, static_cast<std::size_t>(nf));
  for (long row = 0; row < nf; ++row) {
    const double t = motion.time[row];
    const VecX q = get_motion_pose(sk, motion, columns, row);
    VecX qdot = VecX::Zero(sk.num_coordinates());
    if (speeds.any)
      for (int c = 0; c < sk.num_coordinates(); ++c)
        if (speeds.column_of_coordinate[c] >= 0)
          qdot[c] = motion.data(row, speeds.column_of_coordinate[c]) * speeds.scale[c];
    try {
      calc_frame(model, q, frame, true);
    } catch (const Error& e) {
      throw Error(e.kind(), fmt::format("frame at t = {} s: {}", t, e.message()), e.context())
          .with_file(options.motion_file);
    }
    VecX activation_row;
    if (options.activations) activation_row = calc_row_at(*options.activations, t);
    parallel_for(static_cast<std::size_t>(nm), [&](std::size_t mi) {
      const int m = static_cast<int>(mi);
      const int path = model.muscle_path[m];
      PathResult& pr = results[m];
      const std::string& name = model.get_muscle_name(m);
      try {
        const double L = calc_path_length(model, frame, path, pr);
        const VecX r = calc_path_moment_arms(model, frame, path, pr);
        // Independent speeds only: the coupling is in r (dependent entries are zero).
        const double v = speeds.any ? calc_lengthening_speed(r, qdot) : 0.0;
        double a = model.osim.actuators[model.muscles[m]].default_activation;
        if (act_col[m] >= 0) a = activation_row[act_col[m]];
        if (!std::isfinite(a))
          throw_bad_input("activation is not finite",
                          {.file = options.activations_file, .object = name});
        const MuscleOutputs o = calc_static_equilibrium(model.musculotendons[m], a, L, v);
        out.length(row, m) = L;
        out.lengthening_speed(row, m) = v;
        out.fiber_length(row, m) = o.fiber_length_m;
        out.pennation(row, m) = o.pennation_rad;
        out.tendon_length(row, m) = o.tendon_length_m;
        out.normalized_fiber_length(row, m) = o.norm_fiber_length;
        out.tendon_force(row, m) = o.tendon_force_N;
        out.active_fiber_force(row, m) = o.active_fiber_force_N;
        out.passive_fiber_force(row, m) = o.passive_fiber_force_N;
        out.activation(row, m) = o.activation;
        for (std::size_t k = 0; k < coords.size(); ++k) out.moment_arms[k](row, m) = r[coords[k]];
      } catch (const Error& e) {
        throw Error(e.kind(), fmt::format("muscle {} at t = {} s: {}", name, t, e.message()),
                    e.context());
      }
    });
    if (options.progress) bar.advance();
  }
  bar.finish();
  return out;
}

std::vector<std::filesystem::path> write_muscle_analysis(const std::filesystem::path& folder,
                                                         const MuscleAnalysis& a) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (ec || !fs::is_directory(folder))
    throw_bad_input("cannot create the output folder: " + ec.message(),
                    {.file = folder.string(), .suggestion = "choose a writable --out folder"});
  struct Item {
    std::string quantity;
    const MatX* values;
  };
  std::vector<Item> items{{"Length", &a.length},
                          {"FiberLength", &a.fiber_length},
                          {"PennationAngle", &a.pennation},
                          {"TendonLength", &a.tendon_length},
                          {"NormalizedFiberLength", &a.normalized_fiber_length},
                          {"TendonForce", &a.tendon_force},
                          {"ActiveFiberForce", &a.active_fiber_force},
                          {"PassiveFiberForce", &a.passive_fiber_force}};
  for (std::size_t k = 0; k < a.moment_arm_coordinates.size(); ++k)
    items.push_back({"MomentArm_" + a.moment_arm_coordinates[k], &a.moment_arms[k]});
  // Stage every table under a temporary name, then rename them all into place.
  const std::string stage_suffix = ".partial";
  std::vector<fs::path> finals, staged;
  try {
    for (const Item& it : items) {
      Table t;
      t.name = a.model_name + "_MuscleAnalysis_" + it.quantity;
      t.labels = a.muscles;
      t.time = a.time;
      t.data = *it.values;
      t.in_degrees = false;
      t.header.emplace_back("DataType", "double");
      const fs::path final_path = folder / (t.name + ".sto");
      const fs::path tmp = folder / (t.name + ".sto" + stage_suffix);
      write_sto(tmp, t);
      finals.push_back(final_path);
      staged.push_back(tmp);
    }
    for (std::size_t i = 0; i < staged.size(); ++i) {
      fs::rename(staged[i], finals[i], ec);
      if (ec)
        throw_bad_input("cannot move the table into place: " + ec.message(),
                        {.file = finals[i].string()});
    }
  } catch (...) {
    for (const fs::path& p : staged) fs::remove(p, ec);
    throw;
  }
  return finals;
}

VecX parse_pose(const Skeleton& skeleton, const std::vector<std::string>& assignments) {
  VecX q = skeleton.get_default_q();
  for (const std::string& item : assignments) {
    const auto eq = item.find('=');
    if (eq == std::string::npos || eq == 0)
      throw_usage("pose entry '" + item + "' is not name=value",
                  {.suggestion = "write e.g. --pose knee_angle_r=-1.2,hip_flexion_r=30deg"});
    const std::string name = item.substr(0, eq);
    std::string text = item.substr(eq + 1);
    const int c = skeleton.find_coordinate(name);
    if (c < 0)
      throw_usage("unknown coordinate '" + name + "' in --pose",
                  {.object = name, .suggestion = "use coordinate names of the model"});
    const CoordinateInfo& info = skeleton.get_coordinate(c);
    if (info.dependent_on >= 0)
      throw_usage("coordinate '" + name + "' is set by a coupler constraint",
                  {.object = name, .suggestion = "set its independent coordinate instead"});
    double scale = 1.0;
    if (ends_with(text, "deg")) {
      if (info.spec.motion_type != MotionType::rotational)
        throw_usage("'" + name + "' is not rotational: its value cannot be in degrees",
                    {.object = name});
      text.resize(text.size() - 3);
      scale = M_PI / 180.0;
    }
    std::size_t used = 0;
    double v = 0;
    try {
      v = std::stod(text, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || used != text.size() || !std::isfinite(v))
      throw_usage("value of '" + name + "' in --pose is not a finite number", {.object = name});
    q[c] = v * scale;
  }
  return q;
}

}  // namespace fascicle
