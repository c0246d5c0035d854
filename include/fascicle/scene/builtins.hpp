// The built-in kinds registered by register_builtins(), for direct use and for tests.
#pragma once

#include "fascicle/scene/registry.hpp"
#include "fascicle/scene/state.hpp"

namespace fascicle {

// Joint types, as skeleton joints. pin: rotation by q about `axis` (unit, in F = M); slider:
// translation by q along `axis`; weld: no coordinates; free: 3 rotations (body-fixed x-y-z) then
// 3 translations along F's axes. The skeleton's pin turns about z of F and its slider moves along
// x of F, so F and M are rotated to put that axis on `axis`.
JointSpec make_weld_joint(const SceneJointSpec& spec);
JointSpec make_pin_joint(const SceneJointSpec& spec);
JointSpec make_slider_joint(const SceneJointSpec& spec);
JointSpec make_free_joint(const SceneJointSpec& spec);

// "hill": the musculotendon module's static equilibrium (calc_static_equilibrium) at zero
// lengthening speed, for the spec's model and parameters.
std::unique_ptr<const Actuator> make_hill_actuator(const MuscleSpec& spec);

// "surface_first": the volume-preserving deformation of seed 002 §4 (deformation/surface_first.hpp):
// the rest surface bound to the rest action line, attachment areas (vertices within the radius of
// their landmarks) moving with their bodies, the volume held exactly, vertices kept out of every
// body mesh near the muscle (beyond their rest-pose contact). Fibres: the muscle's rest fibres, or
// the fibres module's template decomposition of the rest surface, carried by the deformation.
// Options (scene "options"): line_weight, contact_weight, contact_margin (m), line_samples,
// max_volume_error, max_contact_rounds, bone_margin (m, default 0.02), fibres (0: none),
// fibre_count (60), fibre_resolution (15), fibre_weights (64).
std::unique_ptr<const MuscleRepresentation> make_surface_first(const Model& model, MuscleIndex m);
// "fibres_first" (group): seed 002 §5's particle/spring fibre bundles (deformation/fibres_first.hpp)
// for all the scene's muscles that name it, solved together so they stay apart; particles fixed
// to the origin and insertion bodies, volume held, kept out of the bones. Its display surface
// (from the boundary fibres) replaces the muscle's mesh as the rest mesh. Options (taken from the
// group's first muscle): particles_per_fibre (15), along_stiffness (N/m), across_stiffness,
// bending_stiffness, muscle_margin (m), bone_margin (m), dynamic (0/1), damping (1/s), iterations
// (20; 3 for interactive rates), contact_rounds (4; 1), fibre_count.
std::unique_ptr<const MuscleGroupRepresentation> make_fibres_first(const Model& model,
                                                                   const std::vector<MuscleIndex>& muscles);
// "blended_surface": the interim deformation (docs/scene-format.md). Each rest vertex is bound to
// the nearest segment of the rest action line; its motion is the blend (1−w)·T_a + w·T_b of the
// rigid motions of the bodies at the segment's ends with w = smoothstep(s) of its position s along
// the segment; vertices inside an attachment area follow that body rigidly. Volume is not
// preserved: the change is reported per frame.
std::unique_ptr<const MuscleRepresentation> make_blended_surface(const Model& model, MuscleIndex m);
// "action_line": no surface; the muscle is its action line only.
std::unique_ptr<const MuscleRepresentation> make_action_line_only(const Model& model, MuscleIndex m);

// Writers: "paraview" (OUT/<basename>.pvd + OUT/<basename>_frames/*.vtp), "sto" and "csv"
// (OUT/<basename>_muscles.sto/.csv: per-muscle metrics per frame), "summary" (OUT/summary.json).
std::unique_ptr<FrameWriter> make_paraview_writer();
std::unique_ptr<FrameWriter> make_sto_writer();
std::unique_ptr<FrameWriter> make_csv_writer();
std::unique_ptr<FrameWriter> make_summary_writer();
// "sketch": OUT/<basename>_sketch.svg, a side view (x horizontal; y or z up) of the first frame:
// bone vertices, each muscle's fibres and action line.
std::unique_ptr<FrameWriter> make_sketch_writer();

}  // namespace fascicle

namespace fascicle {

// Per-muscle scalar metrics of a frame, in the order of get_muscle_metric_names():
// activation, musculotendon_length_m, fiber_length_m, norm_fiber_length, pennation_rad,
// tendon_length_m, tendon_force_N, active_fiber_force_N, passive_fiber_force_N, volume_m3,
// relative_volume_change, max_bone_penetration_m, max_muscle_overlap_m, mean_fibre_length_m,
// mean_pennation_rad, max_muscle_overlap_growth_m. NaN where not computed.
const std::vector<std::string>& get_muscle_metric_names();
std::vector<double> get_muscle_metrics(const Muscle& muscle, const MuscleFrame& frame);

}  // namespace fascicle
