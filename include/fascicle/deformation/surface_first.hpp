// Surface-first muscle deformation (Kohout et al., seed 002 section 4): a muscle's closed surface is
// bound to its action line in the rest pose; per frame, the differential (Laplacian) coordinates are
// rotated by the action line's frames and the surface is solved for by Laplacian surface editing
// (Sorkine et al. 2004) with the attachment areas following their bones, the enclosed volume held
// exactly at its rest value, and vertices kept out of bones (beyond their rest-pose contact).
//
// Three pieces (geometry-central / fascicle style):
//   - SurfaceBinding: built once in the rest pose by bind_surface(); immutable ("model").
//   - SurfaceFirstSolver: per muscle; prefactorises the sparse system and keeps warm-start data
//     (previous solution, active bone contacts) from frame to frame ("state").
//   - deform_surface(): one-off solve of a single frame.
// Method, equations and measured performance: docs/deformation.md. Units: metres, radians.
#pragma once

#include "fascicle/deformation/framed_line.hpp"
#include "fascicle/deformation/mesh_operators.hpp"
#include "fascicle/geometry/mesh_query.hpp"

#include <limits>
#include <memory>
#include <string>
#include <vector>

namespace fascicle {

using RowSparseMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor>;

// A set of surface vertices that moves rigidly with a bone (an origin or insertion area).
struct SurfaceAttachment {
  std::string name;           // e.g. "origin", "insertion" (for messages)
  std::vector<int> vertices;  // rows of the rest surface's V
};

enum class SparseSolverKind { cholmod_supernodal, eigen_simplicial_ldlt };

struct SurfaceFirstOptions {
  LaplacianKind laplacian = LaplacianKind::cotangent;
  SparseSolverKind sparse_solver = SparseSolverKind::cholmod_supernodal;
  int line_samples = 64;  // samples of the action line (normalised arc length)
  // Weight of the soft pull of every vertex towards its position carried rigidly by the action-line
  // frame ("skinned" position), relative to the mean diagonal of L^T L. Keeps the belly following
  // a wrapping line and makes the system definite without attachments. Must be > 0.
  double line_weight = 1e-3;
  // Weight of a bone-contact constraint relative to the mean diagonal of L^T L.
  double contact_weight = 1e4;
  double contact_margin_m = 1e-4;     // a contact vertex is held this far outside the bone
  double contact_tolerance_m = 1e-5;  // depth beyond the rest depth that triggers a contact
  int max_contact_rounds = 8;         // solve -> detect -> add/release rounds per frame
  // When the wanted contact set differs from a factorised one (the contact-free factor or the
  // last contact factor) by at most this many vertices, the factor is corrected by a low-rank
  // (Woodbury) update instead of a numeric refactorisation; 0 always refactorises. (32 until
  // session 10, when the supernodal correction moved between the triangular solves and its
  // columns became sparse: docs/deformation.md. The simplicial fallback, whose columns are dense
  // full solves, stays at 32 whatever this says.)
  int max_low_rank = 128;
  int max_volume_iterations = 10;     // Gauss-Newton iterations on the volume constraint
  // Stop when the relative change of the volume gradient between iterations (the relative KKT
  // residual of the constrained problem) is below this. The volume is exact at every iterate; this
  // only bounds the shape error, to about this fraction of the volume-correction displacement.
  double stationarity_tolerance = 1e-3;
  // A frame whose relative volume error exceeds this throws fascicle::Error (numerical).
  double max_volume_error = 1e-4;
};

// Vertex neighbours of a triangle mesh (compressed rows; each neighbour once, in the order of its
// first appearance in the triangles).
struct VertexAdjacency {
  std::vector<int> start;       // neighbours of i: neighbours[start[i] .. start[i+1])
  std::vector<int> neighbours;
};

// Rest-pose binding of one muscle surface. Plain data built by bind_surface(); treat as immutable.
struct SurfaceBinding {
  std::string name;  // muscle name, used in error messages
  SurfaceFirstOptions options;
  TriMesh rest;                 // rest surface (closed, outward normals)
  FramedLine rest_line;         // rest action line, resampled and framed
  VecX vertex_s;                // per vertex: normalised arc length of the closest line point
  Points3 offset_local;         // per vertex: (v - line point) in the line frame at s
  Points3 delta_local;          // per vertex: differential coordinate (L V)_i in the line frame
  std::vector<SurfaceAttachment> attachments;
  std::vector<int> fixed_vertices;  // all attachment vertices (sorted)
  std::vector<int> fixed_area;      // attachment area of each fixed vertex
  std::vector<int> free_vertices;   // the other vertices (sorted)
  std::vector<int> free_index;      // per vertex: index into free_vertices, or -1
  SparseMatrix laplacian;           // #V x #V
  // (L restricted to free columns)^T: #free x #V, and L restricted to fixed columns: #V x #fixed,
  // both stored by rows (the per-frame right-hand side is gathered row by row)
  RowSparseMatrix Lf_transpose;
  RowSparseMatrix L_fixed;
  SparseMatrix system;              // Lf^T Lf + line weight I (#free x #free, lower+upper)
  double diagonal_scale = 0.0;      // mean diagonal of Lf^T Lf
  double rest_volume_m3 = 0.0;
  double size_m = 0.0;              // bounding-box diagonal of the rest surface
  std::vector<VecX> rest_bone_depth;  // per bone, per vertex: depth inside the bone at rest (>= 0)
  // per bone, per vertex: distance to the bone at rest for vertices outside it (0 inside). A vertex
  // that has moved less than this relative to the bone cannot be inside it (exact culling).
  std::vector<VecX> rest_bone_clearance;
  VertexAdjacency adjacency;  // of the rest surface (for inside tests by winding propagation)

  int num_bones() const { return static_cast<int>(rest_bone_depth.size()); }
};

// Bones a muscle must stay out of: meshes in their rest pose, in the same (world) frame as the
// muscle's rest surface. Not owned; they must outlive bindings and solvers that use them.
using BoneQueries = std::vector<const MeshQuery*>;

// Binds a closed muscle surface to its rest action line (polyline, >= 2 points) and records the
// attachment areas and the rest-pose depth of every vertex inside each bone. Throws fascicle::Error
// (bad input) for an open or inward surface, bad or overlapping attachment indices, a degenerate
// action line; (usage) for invalid options.
SurfaceBinding bind_surface(const TriMesh& rest_surface, const Points3& rest_action_line,
                            std::vector<SurfaceAttachment> attachments, const BoneQueries& bones,
                            const SurfaceFirstOptions& options = {}, std::string name = {});

// One frame's input.
struct SurfaceFrameInput {
  Points3 action_line;  // the action line this frame (world), any number (>= 2) of points
  // Per attachment area, X_now_rest: the bone's motion from the rest pose (maps rest positions to
  // this frame; X_world_bone(now) * X_world_bone(rest)^-1). Area 0's rotation also fixes the twist
  // of the line frames about the line (identity when absent).
  std::vector<Transform> attachment_motions;
  // Alternative to attachment_motions: target positions of binding.fixed_vertices, in that order.
  Points3 attachment_targets;
  // Per bone, X_now_rest (empty: all bones at rest).
  std::vector<Transform> bone_motions;
};

// What happened in a frame (NaN until solved).
struct SurfaceFrameInfo {
  double volume_m3 = std::numeric_limits<double>::quiet_NaN();
  double relative_volume_error = std::numeric_limits<double>::quiet_NaN();  // |V - V0| / V0
  double stationarity = std::numeric_limits<double>::quiet_NaN();  // final relative KKT residual
  double volume_multiplier = std::numeric_limits<double>::quiet_NaN();      // lambda
  double max_penetration_beyond_rest_m = 0.0;  // over bones and non-attachment vertices
  int volume_iterations = 0;                   // linear solves for the volume constraint
  int contact_rounds = 0;
  int active_contacts = 0;
  int factorisations = 0;
  int low_rank_updates = 0;  // contact-set changes handled by a low-rank correction (so far)
};

// Per-muscle solver: prefactorises the system once and refactorises (numerically only, same
// pattern, into a second factor) when the set of bone contacts changes within a frame; warm-starts
// the volume iteration from the previous frame's solution. Contacts are re-detected every frame.
class SurfaceFirstSolver {
 public:
  // `binding` and `bones` must outlive the solver; bones.size() == binding.num_bones().
  SurfaceFirstSolver(const SurfaceBinding& binding, BoneQueries bones);
  ~SurfaceFirstSolver();
  SurfaceFirstSolver(SurfaceFirstSolver&&) noexcept;
  SurfaceFirstSolver& operator=(SurfaceFirstSolver&&) = delete;
  SurfaceFirstSolver(const SurfaceFirstSolver&) = delete;
  SurfaceFirstSolver& operator=(const SurfaceFirstSolver&) = delete;

  // Solves one frame; returns the deformed vertices (#V x 3, world). Throws fascicle::Error
  // (bad input) for inconsistent input sizes, (numerical) when the volume cannot be held.
  const Points3& calc_frame(const SurfaceFrameInput& input);

  const Points3& get_vertices() const { return vertices_; }
  // This frame's framed action line and the vertices carried rigidly by its frames ("skinned").
  const FramedLine& get_line() const { return line_; }
  const Points3& get_skinned_vertices() const { return skinned_; }
  const SurfaceFrameInfo& get_info() const { return info_; }
  const SurfaceBinding& get_binding() const { return binding_; }
  // Forget the warm start (previous solution and contacts).
  void reset();

  // A bone contact: vertex held at a point fixed in the bone's rest frame.
  struct Contact {
    int vertex = -1;
    int bone = -1;
    Vec3 target_rest = Vec3::Zero();  // in the bone's rest pose (world rest frame)
    Vec3 normal_rest = Vec3::Zero();  // outward bone normal there
  };
  const std::vector<Contact>& get_contacts() const { return contacts_; }

  struct Factor;  // the sparse Cholesky factor (defined in the .cpp; keeps CHOLMOD out of here)

 private:
  void factorise();
  // Makes solve() use K + w_c sum_{j in wanted} e_j e_j^T (wanted: sorted free indices): the
  // nearer factorised set plus a low-rank correction, or a numeric refactorisation.
  void prepare_factor(const std::vector<int>& wanted);
  // K^-1 rhs for any number of columns (the active factor and its low-rank correction).
  Eigen::MatrixXd solve(const Eigen::MatrixXd& rhs) const;
  int solve_volume(const Points3& rhs_free, const Points3& fixed, Points3& X);
  bool update_contacts(const Points3& X, const std::vector<Transform>& bone_motions);

  const SurfaceBinding& binding_;
  BoneQueries bones_;
  std::vector<Eigen::AlignedBox3d> bone_boxes_;
  std::unique_ptr<Factor> factor_;
  std::vector<Contact> contacts_;
  std::vector<int> factorised_contacts_;  // free indices with a contact in the current factor
  bool analysed_contacts_ = false;        // symbolic analysis of the contact factor done
  Points3 vertices_;
  Points3 skinned_;
  FramedLine line_;
  // warm start of the volume iteration: the last direction Y = K^-1 g (contact-free factor;
  // interleaved, 3 #V values) and g
  std::vector<double> last_direction_;
  // scratch of solve_volume (interleaved, 3 #V values; every entry written before it is read)
  std::vector<double> start_scratch_, iterate_scratch_, gradient_scratch_;
  Points3 last_gradient_;
  bool has_previous_ = false;
  SurfaceFrameInfo info_;
};

// One-off: binds nothing new, builds a solver and solves a single frame.
Points3 deform_surface(const SurfaceBinding& binding, const BoneQueries& bones,
                       const SurfaceFrameInput& input, SurfaceFrameInfo* info = nullptr);

// Depth of vertices inside a bone (moved by X_now_rest) beyond their rest depth.
struct PenetrationInfo {
  int vertices_inside = 0;
  int vertices_beyond_rest = 0;  // deeper than at rest by more than 1e-9 m
  double max_depth_m = 0.0;
  double max_depth_beyond_rest_m = 0.0;
};
// `rest_depth` (per vertex, may be empty = all zero) and `skip` (per vertex, may be empty) as in
// the binding. Checks every vertex exactly (no culling beyond the bone's bounding box).
PenetrationInfo calc_bone_penetration(const Points3& V, const MeshQuery& bone,
                                      const Transform& X_now_rest, const VecX& rest_depth = {},
                                      const std::vector<int>& skip_vertices = {});

// Muscle-muscle overlap: vertices of one surface inside another closed surface.
struct OverlapInfo {
  int vertices_inside = 0;
  double max_depth_m = 0.0;
};
OverlapInfo calc_surface_overlap(const Points3& V, const MeshQuery& other);
// Same result for the closed surface (V, F), much cheaper: the winding number of `other` is
// propagated along the edges of (V, F) from vertices outside other's bounding box (winding 0), one
// short segment crossing count per vertex (propagate_winding). When more than 1/16 of the vertices
// need a whole ray (a crumpled or inside-out surface), it falls back to the per-vertex vote.
OverlapInfo calc_surface_overlap(const Points3& V, const Triangles& F, const MeshQuery& other);

VertexAdjacency make_vertex_adjacency(const Triangles& F, Eigen::Index num_vertices);

// Winding numbers of the closed surface behind `surface` at the points P (vertices of a mesh with
// adjacency `graph`). `winding` holds one entry per point: a known winding number (>= 0) or -1;
// every -1 is replaced. Breadth-first from the known points, each new point gets its neighbour's
// winding number plus the signed crossings of the segment between them (one short segment query);
// a point reached through a segment that grazes an edge, or a component with no known point, gets
// the crossings of a whole ray. The order depends on the input only (deterministic).
// max_whole_rays >= 0 bounds the number of whole-ray fallbacks: past it the function stops and
// returns false (winding is then incomplete). Crumpled or inside-out surfaces make most points
// fall back, and then a per-point vote (MeshQuery::calc_is_inside) is cheaper.
bool propagate_winding(const Points3& P, const VertexAdjacency& graph, const MeshQuery& surface,
                       std::vector<int>& winding, int max_whole_rays = -1);

}  // namespace fascicle
