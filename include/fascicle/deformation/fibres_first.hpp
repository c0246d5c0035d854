// Fibres-first muscle deformation (Kohout et al., seed 002 section 5): every muscle is a bundle of
// rest-pose fibres sampled by particles joined by springs (stiffer along the fibres than across),
// its fibre ends fixed to bones; per frame the particles settle to the equilibrium of the springs
// with each muscle's volume held, particles kept out of bones and away from other muscles.
//
// Three pieces (fascicle style, like surface_first.hpp):
//   - FibresFirstModel: built once from the rest pose of all muscles of a scene by
//     build_fibres_first_model(); immutable ("model"). One model per scene, because muscle-muscle
//     separation couples the muscles.
//   - FibresFirstSolver: prefactorised per-muscle systems, warm start, active contacts ("state").
//   - calc_fibres_first_frame(): one-off solve of a single frame.
// Method, equations, stopping criterion and measured performance: docs/representations.md.
// Units: metres, kilograms, seconds, newtons. Positions are in the world (ground) frame.
#pragma once

#include "fascicle/geometry/mesh_query.hpp"

#include <limits>
#include <memory>
#include <string>
#include <vector>

namespace fascicle {

// One muscle's rest pose: fibre polylines (world, metres) ordered from origin to insertion, each
// with >= 2 points (e.g. fascicle::FibreSet::fibres from the fibres module), and its bones.
struct FibreBundleSpec {
  std::string name;             // used in messages
  std::vector<Points3> fibres;  // rest fibres, #points x 3 each
  int origin_bone = -1;         // index into the model's bones; first particles follow it
  int insertion_bone = -1;      // index into the model's bones; last particles follow it
  // Rest volume used for the particle masses (m^3); <= 0: the volume of the reconstructed surface.
  double volume_m3 = 0.0;
  // Optional rest action line (origin -> via points -> insertion, world, >= 2 points). When given,
  // a fibre end farther than end_attachment_distance_m from its bone is carried along the action
  // line (a tendon) instead of being left free; see ParticleRole::carried.
  Points3 action_line;
  // Optional closed rest surface of the muscle (world, outward triangles, e.g. the segmented
  // mesh). When given, the display surface is this surface resampled as a loft of
  // FibresFirstOptions::surface_rings contours x surface_ring_points points, each vertex carried
  // by nearby particles with fixed affine weights (concave sections stay concave); when empty, or
  // when a slice has no closed contour, it is the tube through the section's convex-hull fibres
  // (docs/representations.md, "Display surface and volume").
  TriMesh rest_surface;
};

struct FibresFirstOptions {
  int particles_per_fibre = 15;  // uniform in arc length along every fibre (>= 2)
  int cross_neighbours = 4;      // k nearest fibres in the rest cross-section (symmetrised)
  // Spring constants (N/m) of one spring along a fibre, across fibres, and of the bending spring
  // joining particles i-1 and i+1 of a fibre (0: none). Along > across gives the anisotropy.
  double along_stiffness = 400.0;
  double across_stiffness = 100.0;
  double bending_stiffness = 40.0;
  double density_kg_per_m3 = 1060.0;  // muscle density (Mendez and Keys 1960)
  // Hold each muscle's enclosed volume (of its reconstructed surface) at its rest value by a
  // Lagrange multiplier. Needs >= 3 fibres not all in one plane.
  bool hold_volume = true;
  double volume_tolerance = 1e-3;    // |V - V0| / V0 reached by the final volume iterations
  double max_volume_error = 5e-3;    // a frame above this throws fascicle::Error (numerical)
  int max_volume_iterations = 8;     // final Gauss-Newton steps on the volume constraint
  // Fixing particles to bones. A fibre's first (last) particle is fixed to the origin (insertion)
  // bone when it lies within end_attachment_distance_m of that bone's surface (infinity: always,
  // a rigid-tendon model for bellies without tendons). A farther end is carried along the
  // muscle's action line when its spec has one (a tendon), else free. Any other particle within
  // bone_attachment_distance_m of its muscle's origin or insertion bone is fixed to the nearer one
  // (seed 002's rule; 0: off).
  double end_attachment_distance_m = std::numeric_limits<double>::infinity();
  // How a carried end moves along the action line: true keeps its rest arc length from the
  // nearer end of the line (an inextensible tendon between the belly end and that end's bone);
  // false keeps its rest arc-length fraction (the tendon stretches with the whole line). Not the
  // default: with carried ends on gait2392 it misses the first frame's volume hold by more than
  // the fraction rule (docs/representations.md).
  bool carry_inextensible_tendon = false;
  double bone_attachment_distance_m = 0.0;
  // Initial guess: free particles move by a blend of the origin and insertion bones' motions
  // since the last frame, weight w(t) = a t^2 - (a+1) t + 1 of the origin bone at normalised fibre
  // position t (Modenese and Kohout 2020); a in [-1, 1] keeps w monotone.
  double blend_a = 0.0;
  // Warm start: add to that guess the previous frame's correction (its converged minus its guessed
  // free positions), a first-order extrapolation of what the iterations will do for smooth motion.
  // Off by default: it can carry particles through a neighbour before its contacts are detected
  // (the two-bundle test fails with it), and its effect on the iteration count is not measured.
  bool extrapolate_correction = false;
  // Contacts. A particle that enters a bone (deeper than it was at rest) is held at the bone
  // surface plus bone_margin_m; particles of different muscles are kept at least
  // min(muscle_margin_m, their rest distance) apart.
  double bone_margin_m = 2e-4;
  double muscle_margin_m = 2e-3;
  // Fibres taking part in muscle-muscle separation: the cross-section's convex hull (0), or also
  // those within this many mean fibre spacings of the hull's edges (1: about one more layer;
  // on the VH shank 5x the pairs and about 1.5x the time per frame). Tube display surfaces only:
  // with a loft surface the contact particles are those nearest to its vertices.
  double muscle_contact_band = 0.0;
  // Loft display surface (muscles whose spec gives a rest surface): contours along the rest
  // surface's principal axis and points per contour.
  int surface_rings = 12;
  int surface_ring_points = 20;
  // Skin of the muscle-pair candidate list (a Verlet list): candidates are the contact-particle
  // pairs closer than muscle_margin_m + this when the list is built, and the list is rebuilt
  // only once a contact particle has moved more than half of it. Larger: fewer rebuilds, more
  // candidates to scan; the pairs found are the same for any value >= 0.
  double pair_list_skin_m = 2e-3;
  // Display-surface separation (muscles with a display surface, loft or tube), in the final
  // projection: a surface vertex of one muscle that comes closer than surface_margin_m to another
  // muscle's display surface, or enters it, is pushed out along that surface's normal, half by
  // its own muscle's particles and half by the other's, each side by a smooth bump of particle
  // displacements (the vertex and the opposite face point are fixed linear combinations of
  // particles; docs/representations.md, "Display-surface separation"). Pairs of muscles whose
  // surfaces overlap at rest by at most surface_rest_overlap_resolved_m are separated fully from
  // the first frame; deeper pairs (generated volumes) keep every vertex's rest depth and only
  // growth beyond it is held. Contacts that still touch at the end of a frame stay active in the
  // next one, and bone contacts are released on the converged iterate (docs/representations.md).
  // EXPERIMENTAL, off by default: with the loft carried by weights it separates two bundles
  // (test) and the VH shank's rest pose (3.9 -> 0.4 mm), but on the posed VH frames the
  // projection does not converge (overlaps of 3-4 mm remain where carried belly ends converge at
  // the ankle) and the volume hold then fails (> 0.5 %) within a few frames; use it with
  // surface_particles.
  bool separate_surfaces = false;
  double surface_margin_m = 2e-4;
  // Surface particles (muscles with a loft display surface): the loft's vertices become particles
  // of the system, appended after the muscle's fibre particles and tied by springs at their rest
  // lengths (stiffness surface_stiffness, N/m) to their surface_anchor_count nearest fibre
  // particles and to their loft neighbours (the loft's triangle edges). The display surface is
  // then these particles themselves (weights 1): its volume is held directly, and with
  // separate_surfaces its contacts are particle targets of the global step, like bone contacts (a
  // vertex against the opposite face's three particles with their barycentric weights); see
  // docs/representations.md, "Surface particles". Off by default: with separate_surfaces it
  // brings the VH shank's scene overlap from 8.3 mm to 0 at every frame (volume <= 3e-4,
  // penetration 0) but costs about 1.8x the default path's CPU time per frame (idle, end of
  // session 10, alternated runs: 14.0-14.1 ms against 7.3-8.0 ms; docs/benchmarks.md), and on
  // gait2392's generated bellies the whole walk runs with volume <= 0.17 % and no bone
  // penetration, but overlaps beyond 0.5 mm remain in 116 of its 211 frames (session 13, with the
  // ring frames, surface_frame_stiffness; 175 before; the synthetic leg of scene/demo.hpp, which
  // failed at frame 39 at 25 Hz in session 9, was not re-measured).
  bool surface_particles = false;
  int surface_anchor_count = 6;
  double surface_stiffness = 400.0;
  // Surface particles only: also a spring (surface_stiffness) across every surface edge, between
  // the two vertices opposite it, so the loft resists folding (docs/representations.md, "Session
  // 12"). Off by default: on gait2392 with separation it took the overlap growth's median over
  // the walk from 1.24 to 0.84 mm (measured before the push cap of session 12), but it costs the
  // VH shank 27 % more CPU per frame.
  bool surface_bending = false;
  // Surface particles only (0: off): ring frames. Each loft ring is pulled, with this stiffness
  // (N/m) per vertex, towards its rest ring moved by the best-fit rigid motion of the fibre
  // particles anchoring it (a shape-matching target in the local step; a constant diagonal term
  // in the global step, so no fill). The loft then follows the rotation of the muscle's interior
  // instead of twisting about its fibres or folding between its anchors (docs/representations.md,
  // "Session 13"). Default 100 since session 13: on gait2392 with separation the overlap growth's
  // median over the walk fell from 2.67 to 0.54 mm at 60 Hz (1.43 to 0.75 mm at 50 Hz); 200 and
  // 400 failed one of the two walks; the VH shank keeps overlap 0 at -1 % instructions per frame.
  double surface_frame_stiffness = 100.0;
  double surface_rest_overlap_resolved_m = 5e-3;
  double contact_weight = 100.0;  // contact spring = this x along_stiffness
  int max_contact_rounds = 4;     // solve -> detect new contacts -> solve rounds per frame
  // Local/global iterations (projective dynamics) per contact round; stop when the largest
  // particle displacement of an iteration is below step_tolerance x the mean rest spring length.
  // A muscle stops iterating once its step is below the tolerance and no muscle it is in contact
  // with still moves.
  int max_iterations = 20;
  double step_tolerance = 3e-3;
  // With separate_surfaces only (0: off): a muscle whose step has not fallen below 0.9 x its
  // smallest step of the round for this many iterations stops (as if converged; it iterates again
  // when a neighbour wakes it). Default 4 since session 10: it ends the creeping rounds of the VH
  // shank (40 instead of 46 solves per frame), and with far bone contacts re-evaluated and the
  // final projection's volume passes (docs/representations.md, "Session 10") gait2392 with
  // separation runs to frame 42 with it and to frame 38 without it (before: 12 with, 21 without).
  // See docs/representations.md, "Stall rule".
  int stall_iterations = 4;
  // Anderson acceleration of the local/global iterations: number of previous iterates mixed
  // (0: plain projective dynamics).
  int anderson_window = 5;
  // Dynamics (off: quasi-static equilibrium). Backward-Euler time integration of the particles
  // with velocity damping (1/s); the time step comes with each frame (default_time_step_s if 0).
  bool dynamic = false;
  double damping_per_s = 5.0;
  double default_time_step_s = 1.0 / 60.0;
};

// Where a particle is held: free (solved for), fixed to a bone (moves rigidly with it), or carried
// along its muscle's action line (a fibre end away from the bones: it keeps its rest arc-length
// fraction s on the line and its rest offset from the line, turned by the minimal rotation of the
// line's tangent there; a tendon between the belly end and the bone).
enum class ParticleRole : unsigned char { free, fixed, carried };

// One muscle of the model: particles (rows of the model's particle arrays) and its springs.
struct FibreBundle {
  std::string name;
  int origin_bone = -1, insertion_bone = -1;
  int first_particle = 0;   // particles [first_particle, first_particle + num_particles)
  int num_particles = 0;
  int num_fibres = 0;       // particle (f, i) = first_particle + f * particles_per_fibre + i
  // surface particles (options.surface_particles, loft only): rows
  // [first_particle + num_fibres * particles_per_fibre, first_particle + num_particles), one per
  // display-surface vertex in vertex order
  int num_surface_particles = 0;
  Points3 rest_action_line; // the spec's action line (empty: none)
  std::vector<int> free;    // model particle indices of its free particles (sorted)
  std::vector<int> free_index;  // per muscle particle: index into `free`, or -1
  // Boundary fibres (muscle-local fibre indices). Tube surface: the rest cross-section's convex
  // hull, counter-clockwise about the mean fibre direction. Loft surface: the fibres holding the
  // particle nearest to some surface vertex (ascending).
  std::vector<int> boundary_fibres;
  bool surface_from_rest_mesh = false;  // true: loft of the spec's rest surface; false: tube
  // Display surface: vertex v = sum_k surface_weight[k] x[surface_weight_particle[k]] over
  // k in [surface_weight_start[v], surface_weight_start[v + 1]) (model particle indices; weights
  // sum to 1 and reproduce the vertex's rest position). Tube: the boundary fibres' particles
  // (weight 1) then two cap centres (means of the first and last ring). Loft: each vertex carried
  // by the particles of its nearest fibre and that fibre's cross neighbours at three positions
  // along them, with the minimum-norm affine-reproducing weights. Triangles fixed, outward.
  std::vector<int> surface_weight_start;
  std::vector<int> surface_weight_particle;
  std::vector<double> surface_weight;
  // Particles kept apart from other muscles. Tube surface: those of the boundary fibres and of
  // the fibres within options.muscle_contact_band x the mean nearest-fibre spacing of the hull's
  // edges, measured in the rest mid-section. Loft surface: the particles nearest to the surface
  // vertices (muscle_contact_band is not used)
  std::vector<int> contact_particles;
  // Surface particles only: per loft ring r (options.surface_rings rings of
  // options.surface_ring_points vertices), the fibre particles anchoring its vertices (model
  // indices, ascending, without repeats) in [ring_frame_start[r], ring_frame_start[r + 1]) of
  // ring_frame_particle; empty without surface particles.
  std::vector<int> ring_frame_start;
  std::vector<int> ring_frame_particle;
  Triangles surface_triangles;
  int num_surface_vertices() const { return static_cast<int>(surface_weight_start.size()) - 1; }
  double rest_volume_m3 = 0.0;    // enclosed by the rest display surface
  double particle_mass_kg = 0.0;
  double mean_spring_length_m = 0.0;
};

// A spring between particles a and b (model indices) of one muscle.
struct Spring {
  int a = -1, b = -1;
  double rest_length_m = 0.0;
  double stiffness = 0.0;  // N/m
};

struct FibresFirstModel {
  FibresFirstOptions options;
  std::vector<const MeshQuery*> bones;  // rest pose, world frame; not owned
  std::vector<FibreBundle> muscles;
  Points3 rest;                          // all particles, #N x 3
  std::vector<int> muscle_of;            // per particle
  std::vector<double> fibre_t;           // per particle: normalised position along its fibre
  std::vector<ParticleRole> role;        // per particle
  std::vector<int> fixed_bone;           // per particle: bone it follows (fixed), or -1
  std::vector<double> line_fraction;     // per particle: arc-length fraction on the rest action
                                         // line (carried), or NaN
  // per particle: for a surface particle (options.surface_particles) its nearest fibre particle
  // at rest (the initial guess moves it with that particle's fibre), else -1
  std::vector<int> surface_anchor;
  std::vector<Spring> springs;           // grouped by muscle
  std::vector<int> first_spring;         // per muscle, plus one past the end
  // Per bone, per particle: distance to the bone surface at rest when outside it (culls contact
  // tests exactly), and depth inside it at rest (0 outside; only penetration beyond it counts).
  std::vector<VecX> rest_bone_clearance;
  std::vector<VecX> rest_bone_depth;

  int num_particles() const { return static_cast<int>(rest.rows()); }
  int num_bones() const { return static_cast<int>(bones.size()); }
};

// Builds the model. `bones` are rest-pose meshes in the world frame; they must outlive the model
// and its solvers. Throws fascicle::Error (bad input, naming the muscle) for a muscle without
// fibres, a fibre with < 2 points or non-finite or zero length, a bone index out of range, a
// muscle with no particle fixed to a bone or a part of it connected to none, fewer than 3 fibres
// spanning an area when hold_volume is set; (bad input) for non-physical options (stiffness <= 0,
// particles_per_fibre < 2, ...); (usage) for a null bone query. Cost: one closest-point and one
// inside query per particle and bone, plus small k-d tree and hull computations.
FibresFirstModel build_fibres_first_model(const std::vector<FibreBundleSpec>& muscles,
                                          const std::vector<const MeshQuery*>& bones,
                                          const FibresFirstOptions& options = {});

// One frame's input.
struct FibresFirstInput {
  std::vector<Transform> bone_motions;  // per bone, X_now_rest (empty: all bones at rest)
  double time_step_s = 0.0;             // dynamic mode only (0: options.default_time_step_s)
  // Per muscle, its current action line (any number of points >= 2; used for carried particles).
  // Empty: every muscle's rest action line with each point moved by the blend (blend_a) of its
  // origin and insertion bones' motions at the point's arc-length fraction.
  std::vector<Points3> action_lines;
};

// Per muscle results of a frame (NaN until solved). Penetration counts free particles only,
// beyond their rest depth; overlap is over boundary-fibre particles of different muscles, against
// min(muscle_margin_m, rest distance).
struct FibreBundleFrame {
  Points3 particles;  // #particles x 3 (fibre-major: fibre f, particle i at row f * P + i; then
                      // the surface particles, if any)
  Points3 surface_vertices;  // display surface vertices; triangles: bundle.surface_triangles
  double volume_m3 = std::numeric_limits<double>::quiet_NaN();
  double relative_volume_error = std::numeric_limits<double>::quiet_NaN();  // |V - V0| / V0
  double max_bone_penetration_m = 0.0;   // deepest particle inside a bone beyond its rest depth
  double max_muscle_overlap_m = 0.0;     // largest shortfall of a pair distance below its minimum
  // Display surfaces (when separate_surfaces): the deepest vertex of this muscle's surface inside
  // another muscle's surface (face-side rule), absolute and beyond that vertex's rest depth.
  double max_surface_overlap_m = 0.0;
  double max_surface_overlap_beyond_rest_m = 0.0;
  int surface_contacts = 0;              // vertex contacts of this muscle's surface (both sides)
  int bone_contacts = 0, muscle_contacts = 0;
};

struct FibresFirstInfo {
  int frame = -1;                 // frames solved so far - 1
  int iterations = 0;             // local/global iterations (all rounds)
  int solves = 0;                 // muscle global steps (one per awake muscle and iteration)
  int contact_rounds = 0;
  int factorisations = 0;         // muscle systems factorised anew this frame
  int factor_updates = 0;         // muscle factors modified by low-rank updates this frame
  int volume_iterations = 0;      // final volume steps
  // separate_surfaces: passes of the final projection's volume / surface / bone loop beyond the
  // first (taken while some muscle's volume is off by more than volume_tolerance)
  int final_passes = 0;
  // separate_surfaces: 0 when the final projection ended in its last state; otherwise that state
  // was off by more than volume_tolerance and the frame went back to the state with the smallest
  // worst volume error: 1 the state before the surface pushes, 2 the state before the passes,
  // 2 + k the state after pass k
  int final_state_restored = 0;
  // separate_surfaces with the volume held: the worst relative volume error over the muscles
  // after the final projection's first bone projection (before any surface push) and at its end
  // (before the last bone check; NaN when not computed). The second is never larger than the
  // larger of the first and volume_tolerance.
  double final_volume_error_start = std::numeric_limits<double>::quiet_NaN();
  double final_volume_error = std::numeric_limits<double>::quiet_NaN();
  // Stopping measure of the last local/global iteration: the largest particle displacement of
  // that iteration divided by the muscle's mean rest spring length (max over muscles; a muscle
  // resting in that iteration — converged, stalled, or not woken this round — counts with the step
  // of its last iteration).
  double residual = std::numeric_limits<double>::quiet_NaN();
};

// The per-scene solver. Holds one prefactorised sparse system per muscle (refactorised only for
// muscles whose contact set changed), the previous frame (warm start, velocities) and contacts.
class FibresFirstSolver {
 public:
  explicit FibresFirstSolver(const FibresFirstModel& model);  // model must outlive the solver
  ~FibresFirstSolver();
  FibresFirstSolver(FibresFirstSolver&&) noexcept;
  FibresFirstSolver& operator=(FibresFirstSolver&&) = delete;
  FibresFirstSolver(const FibresFirstSolver&) = delete;
  FibresFirstSolver& operator=(const FibresFirstSolver&) = delete;

  // Solves one frame. Throws fascicle::Error (bad input) for a wrong number of bone motions or a
  // non-finite one; (numerical, naming the muscle and frame) when the solve produces non-finite
  // positions or a volume error above options.max_volume_error. A failed frame leaves the
  // previous frame's results in place.
  void calc_frame(const FibresFirstInput& input);

  const FibresFirstModel& get_model() const { return model_; }
  const Points3& get_particles() const { return x_; }  // all particles, #N x 3
  const std::vector<FibreBundleFrame>& get_muscles() const { return frames_; }
  const FibresFirstInfo& get_info() const { return info_; }
  // The fibres of muscle m as polylines (#particles_per_fibre x 3 each).
  std::vector<Points3> calc_fibres(int m) const;
  // Forget every frame: the solver is as new (warm start, velocities, contacts, factors).
  void reset();

  struct Workspace;  // factors, contacts, scratch (defined in the .cpp)

 private:
  const FibresFirstModel& model_;
  std::unique_ptr<Workspace> ws_;
  Points3 x_;
  std::vector<FibreBundleFrame> frames_;
  FibresFirstInfo info_;
};

// One-off: builds a solver and solves a single frame from the rest pose.
std::vector<FibreBundleFrame> calc_fibres_first_frame(const FibresFirstModel& model,
                                                      const FibresFirstInput& input);

}  // namespace fascicle
