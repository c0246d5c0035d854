// Lagrangian dynamics of B-spline solid muscles (seed 000 ch. 4).
//
// Generalised coordinates are the control points P (#P x 3, m): x(U) = Σ N_I(U) P_I, so the
// kinetic energy ½ ∫ ρ |ẋ|² dX gives the mass matrix M_IJ = ∫ ρ N_I N_J dX (consistent) or its
// row sums (lumped; B-spline bases are non-negative, so lumped masses are positive). The
// deformation gradient at a material point is F = Σ P_I ⊗ g_I with g_I = J_rest^{-T} ∇_U N_I, and
// every potential W(F) integrated by Gauss quadrature in the rest solid gives generalised forces
// f_I = −∫ P(F) g_I dX. Because Σ_I N_I = 1, Σ_I g_I = 0: stress-based forces (elastic, fibre
// contraction) are internal, they sum to zero and do not move the centre of mass.
//
// Flow: SolidDynamicsSpec (plain options) → compile_solid_dynamics(rest solid, spec) →
// SolidDynamicsModel (immutable, shareable) → SolidDynamicsSolver (owns the per-muscle state and
// scratch, stepped per frame with the bones' rigid motions X_now_rest as input).
#pragma once

#include "fascicle/bspline/solid.hpp"
#include "fascicle/core/types.hpp"
#include "fascicle/dynamics/materials.hpp"
#include "fascicle/geometry/tri_mesh.hpp"
#include "fascicle/musculotendon/activation.hpp"

#include <Eigen/SparseCore>

#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace fascicle {

class BoundaryVolumeIntegrator;
class MeshQuery;

enum class MassLumping { lumped, consistent };
enum class VolumeMethod {
  none,
  penalty,  // E = k/2 (V − V0)²/V0 with damping −d (dV/dt)/V0 ∇V (seed 000 §4.4)
  exact,    // projection per step: P ← P + μ M⁻¹ ∇V with μ solving V(P) = V0 (Newton on μ)
};
enum class Integrator { symplectic_euler, backward_euler, quasi_static };

// Control points moved rigidly with one bone: P_I = X_now_rest[body] P_rest_I.
struct SolidAttachmentSpec {
  std::string name;
  int body = 0;                  // index into StepInputs::X_now_rest (−1: fixed in the world)
  std::vector<int> control_points;
};

// A bone surface locally approximated by a plane (seed 000 §4.7: the contact point slides on it).
// The solid's boundary sample points may not cross to the side opposite the normal.
struct ContactPlaneSpec {
  std::string name;
  int body = -1;                   // moves with X_now_rest[body]; −1: fixed
  Vec3 point_rest = Vec3::Zero();  // a point of the plane (rest frame, m)
  Vec3 normal_rest = Vec3::UnitZ();  // outward (into the free side)
  double stiffness_N_m = 0.0;      // per contact sample; 0: automatic (see docs)
};

// A bone mesh (closed, rest frame of its body, m). Boundary samples of the solid found inside it
// are pushed out along the direction to the closest surface point: the locally planar contact of
// seed 000 §4.7 (point on the tangent plane, free to slide), with the plane stiffness.
struct BoneContactSpec {
  std::string name;
  int body = -1;  // moves with X_now_rest[body]; −1: fixed
  TriMesh mesh_rest;
  // true: samples already inside this mesh in the rest configuration are pushed only beyond their
  // rest depth (a muscle bound in a pose where it touches or overlaps the bone, e.g. at an
  // attachment): the contact acts on the penetration beyond the rest contact.
  bool exempt_rest_contact = false;
};

struct SolidDynamicsSpec {
  double density_kg_m3 = 1060.0;
  Vec3 gravity_m_s2 = Vec3(0.0, 0.0, -9.81);
  MassLumping mass = MassLumping::consistent;
  double rayleigh_alpha_1_s = 0.0;  // D = α M + β K(rest)
  double rayleigh_beta_s = 0.0;

  VolumeMethod volume = VolumeMethod::exact;
  double volume_stiffness_Pa = 1.0e6;
  double volume_damping_Pa_s = 0.0;
  double volume_tolerance = 1.0e-6;  // relative, exact projection

  // Shape: a spring network between lattice neighbours (rest lengths from the rest control
  // points, stiffness spring_modulus_Pa × rest length) and/or the hyperelastic potential.
  double spring_modulus_Pa = 0.0;
  bool hyperelastic = true;
  MooneyRivlinParameters ground;
  BlemkerFibreParameters fibre;
  // Rest fibre direction: the tangent of the solid's fibre parameter, tilted in space by
  // `pennation_rad` towards the tangent of parametric direction `pennation_towards` (its part
  // orthogonal to the fibre tangent). On a fitted cylindrical lattice (u radial) this gives a
  // conical, bipennate-like arrangement about the muscle axis.
  double pennation_rad = 0.0;
  int pennation_towards = 0;

  // Tendon/aponeurosis: these fractions of the fibre-parameter range at the start and end of the
  // solid are passive, their ground substance stiffer by tendon_stiffness_factor and their fibres
  // follow calc_tendon_fibre with tendon_modulus_Pa.
  double tendon_fraction_start = 0.0;
  double tendon_fraction_end = 0.0;
  double tendon_stiffness_factor = 20.0;
  double tendon_modulus_Pa = 2.0e6;

  ActivationParameters activation;
  double max_fibre_strain_rate_1_s = 10.0;  // v_max in optimal lengths per second

  int quadrature_points_per_span = 0;  // 0: degree + 1 per direction
  std::vector<SolidAttachmentSpec> attachments;
  std::vector<ContactPlaneSpec> contact_planes;
  std::vector<BoneContactSpec> contact_bones;
  int contact_samples_per_span = 2;  // boundary sample density for plane contact
  // Further contact samples at these material points (u, v, w), e.g. the vertices of a surface
  // embedded in the solid, so that the contact acts where that surface is.
  std::vector<Vec3> contact_material_points;
  // Optional, one per contact material point: the sample is x(U) + J(U) dU (to first order the
  // point at U + dU, e.g. a surface vertex just outside the solid), weights N_I + ∇_U N_I · dU.
  std::vector<Vec3> contact_material_offsets;
  double contact_stiffness_N_m = 0.0;  // per sample; 0: the planes' stiffness, else automatic
};

// One quadrature point of the rest solid.
struct QuadraturePoint {
  Vec3 material = Vec3::Zero();
  double weight_m3 = 0.0;            // Gauss weight × det J_rest
  int first = 0;                     // offset into SolidDynamicsModel::support arrays
  int count = 0;                     // number of control points with N_I ≠ 0 here
  Vec3 fibre_rest = Vec3::UnitZ();   // unit rest fibre direction a0
  bool tendon = false;
};

// Compiled, immutable. Build with compile_solid_dynamics.
struct SolidDynamicsModel {
  BSplineSolid rest;           // the rest solid (its control points are the rest configuration)
  SolidDynamicsSpec spec;
  double rest_volume_m3 = 0.0;
  double mass_kg = 0.0;
  std::vector<QuadraturePoint> quadrature;
  std::vector<int> support_index;   // control-point indices, per quadrature point
  std::vector<double> support_N;    // N_I at the quadrature point
  std::vector<Vec3> support_g;      // g_I = J_rest^{-T} ∇_U N_I (1/m)
  Eigen::SparseMatrix<double> mass_matrix;  // #P x #P (kg), consistent or lumped (diagonal)
  VecX lumped_mass;                 // #P row sums (kg)
  // Node-level sparsity: for control point J, the sorted control points coupled to it.
  std::vector<int> block_ptr, block_row;
  struct Spring {
    int a = 0, b = 0;
    double rest_length_m = 0.0, stiffness_N_m = 0.0;
  };
  std::vector<Spring> springs;
  std::vector<char> fixed;          // per control point: attached
  // Contact samples on the boundary: material point and its support.
  struct ContactSample {
    Vec3 material = Vec3::Zero();
    std::vector<int> index;
    std::vector<double> N;
  };
  std::vector<ContactSample> contact_samples;
  double contact_stiffness_N_m = 0.0;  // per sample, resolved from the spec
  std::vector<std::shared_ptr<const MeshQuery>> bone_queries;  // per contact bone (rest frame)
  std::vector<std::vector<double>> bone_rest_depth;  // per contact bone: per sample, depth inside at
                                                    // rest (m; 0 unless exempt_rest_contact)
  // Lower-triangle block pairs (I >= J) of each quadrature point: local support indices and the
  // block's position in block_row; pairs of quadrature point q start at pair_first[q].
  struct BlockPair {
    int a = 0, b = 0, block = 0;
  };
  std::vector<BlockPair> pairs;
  std::vector<int> pair_first;
  // Quadrature points grouped by identical support (one group per knot span), for the per-span
  // kernels of calc_forces: group k holds the points group_points[group_ptr[k] .. group_ptr[k+1]),
  // whose support (and block pairs) are those of its first point. group_g[k] is count x 3m
  // (column-major): column 3 i + j holds component j of g_I at the group's i-th point, over the
  // support I. group_ascending[k]: the support's control-point indices increase (then the lower
  // pairs I >= J are the local pairs a >= b).
  std::vector<int> group_ptr, group_points;
  std::vector<Eigen::MatrixXd> group_g;
  std::vector<Eigen::MatrixXd> group_gt;  // the transposes (3m x count), for F
  std::vector<char> group_ascending;
  std::shared_ptr<const BoundaryVolumeIntegrator> volume_integrator;  // null: volume form
  int size_of_pattern() const { return static_cast<int>(block_row.size()); }
};

// Throws bad_input for non-physical options, attachments naming missing control points, or an
// inverted rest solid (naming the material location), numerical if the mass matrix is singular.
SolidDynamicsModel compile_solid_dynamics(const BSplineSolid& rest, const SolidDynamicsSpec& spec);

// The control points of one end layer of the fibre direction (side 0: start, 1: end).
std::vector<int> find_end_layer(const BSplineSolid& solid, int side);

// Per-muscle state: every number that changes over time.
struct SolidState {
  double time_s = 0.0;
  Points3 P;  // #P x 3, m
  Points3 V;  // #P x 3, m/s
  double activation = 0.0;
};

// Energies (J) and forces of one configuration.
struct SolidEnergies {
  double kinetic_J = NAN;
  double elastic_J = NAN;      // ground substance + passive fibres + springs + volume penalty
  double gravity_J = NAN;      // −Σ m_I g·P_I
  double contact_J = NAN;
  double total() const { return kinetic_J + elastic_J + gravity_J + contact_J; }
};

struct SolidMetrics {
  double time_s = NAN;
  double volume_m3 = NAN;
  double volume_error = NAN;            // (V − V0)/V0
  double mean_fibre_stretch = NAN;      // mass-weighted |F a0| over the belly
  double mean_fibre_length_m = NAN;     // mean length of iso-parametric fibre curves
  double mean_pennation_rad = NAN;      // angle of fibres to the line of action (belly mean)
  double min_jacobian_ratio = NAN;      // min det F over quadrature points
  Vec3 centre_of_mass_m = Vec3::Constant(NAN);
  SolidEnergies energies;
  Vec3 contact_reaction_N = Vec3::Constant(NAN);  // total force of the solid on the contact planes
  double activation = NAN;
};

// Inputs of one step.
struct StepInputs {
  double excitation = 0.0;                 // u ∈ [0, 1]
  std::vector<Transform> X_now_rest;       // per body: current pose relative to the rest pose
  Points3 external_forces;                 // optional #P x 3 generalised forces (N); empty: none
};

// SolverOptions::reuse_factorisation_steps with no practical cap (10⁶ steps): the factorisation
// is kept until Newton slows down, the step size changes or a step fails.
inline constexpr int kReuseFactorisationNoCap = 1000000;

struct SolverOptions {
  Integrator integrator = Integrator::backward_euler;
  int max_newton_iterations = 25;
  double newton_tolerance = 1e-7;       // on |Δx|∞ relative to the solid's size
  bool refresh_stiffness = true;        // false: keep the factorisation of the first iteration
                                        //   of the step while Newton converges (modified Newton)
  // Backward Euler and quasi-static: 0 is full Newton (a factorisation per iteration); > 0 keeps
  // a factorisation over up to this many steps (lagged Jacobian, modified Newton), refreshed
  // earlier when Newton slows down (refresh_contraction_rate, or 4 slow iterations), when the
  // step size changes or after a failed step. Default: no step cap (docs/solid-dynamics.md,
  // "Refactorisation policy").
  int reuse_factorisation_steps = kReuseFactorisationNoCap;
  bool supernodal = true;               // CHOLMOD supernodal LLᵀ (falls back to Eigen's LDLᵀ
                                        //   when the matrix is not positive definite)
  bool cholmod_simplicial = false;      // with supernodal: CHOLMOD's simplicial LLᵀ instead of
                                        //   its supernodal one (docs/solid-dynamics.md, Performance)
  int max_step_halvings = 6;            // step-size control: failed steps are retried at dt/2
  double explicit_safety = 0.5;         // symplectic Euler: sub-step = safety × 2/ω_max
  double energy_blowup_factor = 1e3;    // error if the energy grows by this factor plus 1 J/kg
  // Backward Euler: start Newton from x̃ + h² (v_n − v_{n−1})/h_{n−1} (constant acceleration
  // from the last two steps) instead of x̃ = x_n + h v_n. Only the starting point changes.
  bool extrapolate_start = true;
  // With a kept factorisation (modified Newton): refresh it as soon as the observed contraction
  // |Δx_k|/|Δx_{k−1}| of a step exceeds this rate (0: only after 4 slow iterations).
  double refresh_contraction_rate = 0.5;
};

struct StepReport {
  int substeps = 0;
  int newton_iterations = 0;
  int halvings = 0;
  int factorisations = 0;
  double residual = 0.0;
  double volume_projection_m3 = 0.0;   // |volume correction| applied by the exact projection
};

// Values, forces and stiffness of the potential part (no inertia, no damping) at P.
struct ForceEvaluation {
  double energy_J = 0.0;               // stored energy (elastic, gravity, penalty, contact)
  double active_energy_J = 0.0;        // potential of the active fibre stress at fixed a, fv
  VecX force;                          // 3#P, interleaved (3 I + c), N
  Eigen::SparseMatrix<double> stiffness;  // −∂f/∂x (only when requested), 3#P square
  double volume_m3 = 0.0;
  VecX volume_gradient;                // 3#P, m² (when the model keeps volume)
};

// Location of the first quadrature point whose Jacobian is not positive, if any.
std::optional<Vec3> find_inverted_point(const SolidDynamicsModel& model, const Points3& P);

// The potential forces (elastic, fibre at activation a and fv from velocities V, springs, gravity,
// volume penalty, contact). Throws numerical naming the material point if the solid is inverted.
ForceEvaluation calc_forces(const SolidDynamicsModel& model, const Points3& P, const Points3& V,
                            double activation, bool with_stiffness,
                            const std::vector<Transform>& X_now_rest = {});

// Sum of stress-based internal forces only (elastic + fibre), 3#P: used to check Σ f = 0.
VecX calc_internal_forces(const SolidDynamicsModel& model, const Points3& P, double activation);

SolidEnergies calc_energies(const SolidDynamicsModel& model, const SolidState& s,
                            const std::vector<Transform>& X_now_rest = {});
SolidMetrics calc_metrics(const SolidDynamicsModel& model, const SolidState& s,
                          const std::vector<Transform>& X_now_rest = {});

// Largest circular frequency of M⁻¹K at P (rad/s), by power iteration: explicit stability needs
// dt < 2/ω_max.
double calc_max_frequency(const SolidDynamicsModel& model, const Points3& P, double activation);

// The per-muscle solver object. Not thread-safe per object; one object per muscle.
class SolidDynamicsSolver {
 public:
  SolidDynamicsSolver(std::shared_ptr<const SolidDynamicsModel> model, SolverOptions options = {});
  ~SolidDynamicsSolver();
  SolidDynamicsSolver(SolidDynamicsSolver&&) noexcept;
  SolidDynamicsSolver& operator=(SolidDynamicsSolver&&) noexcept;

  const SolidDynamicsModel& get_model() const { return *model_; }
  const SolidState& get_state() const { return state_; }
  // Replaces the whole state and starts afresh: the energy blow-up reference is re-taken at the
  // next step and any kept factorisation is dropped.
  void set_state(SolidState s);
  // Replaces positions P and velocities V (#P × 3, m and m/s) and keeps everything else: the time,
  // activation, the energy blow-up reference and the kept factorisation (which stays valid for
  // the remaining reuse steps). For small corrections between steps, such as contact projections;
  // the energy that such corrections add still counts against the blow-up guard.
  void correct_state(const Points3& P, const Points3& V);
  const SolverOptions& get_options() const { return options_; }

  // Advances the state by dt (s). On failure (NaN, energy blow-up, inversion that step halving
  // cannot cure) throws fascicle::Error (numerical) and leaves the last good state in place.
  StepReport step(double dt, const StepInputs& inputs);

  SolidMetrics calc_metrics(const StepInputs& inputs) const;

 private:
  struct Workspace;
  StepReport try_step(double dt, const StepInputs& inputs, SolidState& s);
  void project_volume(SolidState& s, double dt, StepReport& r) const;
  std::shared_ptr<const SolidDynamicsModel> model_;
  SolverOptions options_;
  SolidState state_;
  double initial_energy_ = NAN;
  std::unique_ptr<Workspace> ws_;
};

// Interleaved coordinate helpers (3 I + c).
VecX flatten_points(const Points3& P);
Points3 unflatten_points(const VecX& x);

}  // namespace fascicle
