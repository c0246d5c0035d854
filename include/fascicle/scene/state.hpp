// Per-frame State of a scene and the stage functions that fill it, in dependency order:
// pose (q → body transforms) → action lines (origin → via points → insertion) → forces
// (musculotendon state) → muscle geometry. Each stage requires the previous one; forward() runs
// them all. Shape f(const Model&, State&); the Model is never modified.
#pragma once

#include "fascicle/core/types.hpp"
#include "fascicle/musculotendon/muscle.hpp"
#include "fascicle/scene/model.hpp"
#include "fascicle/scene/overlap.hpp"

#include <limits>
#include <memory>
#include <optional>
#include <vector>

namespace fascicle {

enum class Stage { none = 0, pose = 1, action_lines = 2, forces = 3, geometry = 4 };

struct MuscleFrame {
  static constexpr double nan = std::numeric_limits<double>::quiet_NaN();
  Points3 action_line;                // origin centroid, via points, insertion centroid (ground)
  std::vector<BodyIndex> action_line_bodies;  // the body each action-line point moves with
  double musculotendon_length_m = nan;
  MuscleOutputs hill;                 // NaN when the muscle has no actuator
  Points3 surface;                    // ground frame; rows match the Model's rest mesh
  std::vector<Points3> fibres;        // polylines in ground (optional)
  VecX fibre_length_m;                // per fibre (empty without fibres)
  VecX fibre_strain;                  // per fibre: length / rest length − 1
  VecX fibre_pennation_rad;           // per fibre: angle to the action line (length-weighted)
  double mean_fibre_length_m = nan;
  double mean_pennation_rad = nan;
  double volume_m3 = nan;
  double relative_volume_change = nan;  // volume / rest volume − 1
  double max_bone_penetration_m = nan;  // deepest surface point inside a bone, beyond rest contact
  double max_muscle_overlap_m = nan;    // deepest surface point inside another muscle
  // Over the other muscles B: max(0, depth of this muscle's vertices inside B now − the same at
  // the rest pose (the rest meshes)): the overlap a pair gained beyond the input's own.
  double max_muscle_overlap_growth_m = nan;
};

struct State {
  double time_s = 0.0;
  VecX q;                                  // #coordinates
  VecX activation;                         // #muscles or empty; NaN: the muscle's constant activation
  std::vector<Transform> X_ground_body;    // #bodies (valid from Stage::pose)
  std::vector<MuscleFrame> muscles;        // #muscles
  // Per muscle: its representation's frame-to-frame data (null when it keeps none); made by
  // make_state() from this Model, so a State is moved, not copied.
  std::vector<std::unique_ptr<RepresentationState>> representation_states;
  std::vector<std::unique_ptr<RepresentationState>> group_states;  // per Model::muscle_groups
  Stage stage = Stage::none;
  std::optional<SkeletonState> skeleton;   // the skeleton module's per-frame state
  // The overlap measure's per-muscle edge graphs and surface queries, kept across frames so a
  // query is refitted, not rebuilt (scene/overlap.hpp). Empty from make_state(); never changes a
  // result.
  MuscleOverlapCache overlap_cache;
};

// A state at the default coordinates, nothing computed; each muscle's representation state made.
State make_state(const Model& model);

// Requires nothing; sets X_ground_body from q. Stage → pose.
void calc_pose(const Model& model, State& state);
// Requires Stage::pose. Action lines and musculotendon lengths, in parallel over muscles.
void calc_action_lines(const Model& model, State& state);
// Requires Stage::action_lines. Hill outputs at each muscle's activation, in parallel.
void calc_forces(const Model& model, State& state);
// Requires Stage::forces. Muscle surfaces by each muscle's representation, in parallel; then
// the muscle-muscle overlap of every pair of surfaces whose bounding boxes meet
// (MuscleFrame::max_muscle_overlap_m, 0 for a muscle that overlaps none) and its growth per ordered
// pair beyond the pair's depth at the rest pose (MuscleFrame::max_muscle_overlap_growth_m).
void calc_muscle_geometry(const Model& model, State& state);
// The overlap part of calc_muscle_geometry (surfaces must be computed).
void calc_muscle_overlaps(const Model& model, State& state);
// All stages in order. A failure throws fascicle::Error naming the muscle.
void forward(const Model& model, State& state);

}  // namespace fascicle
