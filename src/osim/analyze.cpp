// OsimAnalysisModel: compilation, per-frame kinematics, lengths, moment arms, spanned coordinates.
#include "fascicle/osim/analyze.hpp"

#include <algorithm>
#include <cmath>
#include <set>

#include "fascicle/core/error.hpp"

namespace fascicle {

int OsimAnalysisModel::find_muscle(const std::string& name) const {
  for (int m = 0; m < num_muscles(); ++m)
    if (get_muscle_name(m) == name) return m;
  return -1;
}

OsimAnalysisModel compile_osim_model(OsimModel osim, const std::optional<PathOptions>& path_options) {
  const std::string file = osim.file.string();
  try {
    Skeleton skeleton = compile(osim.skeleton);
    PathNames names;
    for (int b = 0; b < skeleton.num_bodies(); ++b) names.bodies.push_back(skeleton.get_body_name(b));
    for (int c = 0; c < skeleton.num_coordinates(); ++c)
      names.coordinates.push_back(skeleton.get_coordinate(c).spec.name);
    if (path_options) osim.paths.options = *path_options;
    PathSetModel paths = compile_paths(osim.paths, names);
    std::vector<int> muscles, muscle_path;
    std::vector<Musculotendon> mts;
    for (int a = 0; a < static_cast<int>(osim.actuators.size()); ++a) {
      const OsimPathActuator& act = osim.actuators[a];
      if (!act.muscle || act.path < 0) continue;
      try {
        mts.push_back(compile_musculotendon(*act.muscle));
      } catch (const Error& e) {
        throw e.with_object(act.type + " " + act.name);
      }
      muscles.push_back(a);
      muscle_path.push_back(act.path);
    }
    return OsimAnalysisModel{std::move(osim), std::move(skeleton), std::move(paths),
                             std::move(muscles), std::move(mts), std::move(muscle_path)};
  } catch (const Error& e) {
    throw e.with_file(file);
  }
}

OsimAnalysisModel load_osim_model(const std::filesystem::path& file, const OsimImportOptions& import,
                                  const std::optional<PathOptions>& path_options) {
  return compile_osim_model(read_osim(file, import), path_options);
}

OsimFrame::OsimFrame(const OsimAnalysisModel& model) : skeleton(model.skeleton) {}

void calc_frame(const OsimAnalysisModel& model, const VecX& q, OsimFrame& frame, bool jacobians) {
  calc_pose(model.skeleton, q, frame.skeleton);
  frame.has_jacobians = jacobians;
  if (!jacobians) return;
  calc_body_jacobians(model.skeleton, frame.skeleton, frame.jacobians.J);
  frame.jacobians.dq_du = frame.skeleton.get_coupling();
}

double calc_path_length(const OsimAnalysisModel& model, const OsimFrame& frame, int path,
                        PathResult& out) {
  calc_path(model.paths, path, frame.skeleton.get_body_transforms(), frame.skeleton.get_q(), out);
  return out.length_m;
}

VecX calc_path_moment_arms(const OsimAnalysisModel& model, const OsimFrame& frame, int path,
                           const PathResult& result) {
  if (!frame.has_jacobians)
    throw_usage("moment arms need the body Jacobians: call calc_frame with jacobians = true");
  return calc_moment_arms(model.paths, path, result, frame.skeleton.get_body_transforms(),
                          frame.skeleton.get_q(), frame.jacobians);
}

std::vector<int> find_spanned_coordinates(const OsimAnalysisModel& model) {
  const Skeleton& sk = model.skeleton;
  const int nb = sk.num_bodies();
  const int nc = sk.num_coordinates();
  // Joint (and so coordinates) of each body: the coordinates whose joint's child is the body.
  std::vector<std::vector<int>> coords_of_body(nb);
  for (int c = 0; c < nc; ++c) {
    const JointSpec& j = sk.get_joints()[sk.get_coordinate(c).joint];
    coords_of_body[sk.find_body(j.child)].push_back(c);
  }
  std::vector<bool> spanned(nc, false);
  for (int m = 0; m < model.num_muscles(); ++m) {
    const CompiledPath& p = model.paths.paths[model.muscle_path[m]];
    std::set<int> bodies;
    for (const CompiledPathPoint& pt : p.points) {
      bodies.insert(pt.body);
      for (const int32_t c : pt.location_coordinate)
        if (c >= 0) spanned[c] = true;
    }
    for (const CompiledPathWrap& w : p.wraps) bodies.insert(model.paths.wrap_objects[w.object].body);
    // A joint spans the muscle when its child's subtree holds some but not all of the bodies.
    std::vector<int> count(nb, 0);
    for (const int b : bodies)
      for (int a = b; a > 0; a = sk.get_parent_body(a)) ++count[a];
    for (int b = 1; b < nb; ++b)
      if (count[b] > 0 && count[b] < static_cast<int>(bodies.size()))
        for (const int c : coords_of_body[b]) spanned[c] = true;
  }
  // A dependent coordinate counts for its independent one (through chains of couplers).
  const auto& couplers = sk.get_spec().couplers;
  for (int pass = 0; pass < nc; ++pass) {
    bool changed = false;
    for (int c = 0; c < nc; ++c) {
      const int k = sk.get_coordinate(c).dependent_on;
      if (k < 0 || !spanned[c]) continue;
      const int ind = sk.find_coordinate(couplers[k].independent);
      if (ind >= 0 && !spanned[ind]) spanned[ind] = changed = true;
    }
    if (!changed) break;
  }
  std::vector<int> out;
  for (int c = 0; c < nc; ++c) {
    const CoordinateInfo& info = sk.get_coordinate(c);
    if (spanned[c] && info.dependent_on < 0 && !info.spec.locked) out.push_back(c);
  }
  return out;
}

}  // namespace fascicle
