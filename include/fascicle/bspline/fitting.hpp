// Data fitting of B-spline solids (seed 000 §3.1.2).
//
// Control points from samples with known material coordinates: minimise
//   sum_s w_s |x(U_s) - X_s|^2 + lambda |D P|^2
// over the free control points (lattice constraints eliminated, P = E P_free), where D holds the
// second differences of the control lattice along each direction (periodic ones wrap): linear least
// squares, solved from the sparse normal equations by Eigen's SimplicialLDLT. lambda is
// `smoothing` times trace(A^T A) / trace(D^T D), so it does not depend on units or sample count.
//
// From a closed muscle surface mesh: the mesh is sliced by planes normal to the muscle axis
// (origin -> insertion, or the longest axis of its oriented box), each slice must be one closed
// contour (tiny extra contours are ignored); contours are parametrised by arc length from a seam
// where they cross a fixed reference direction (consistent seams), giving boundary samples
// (u = 1, v = arc fraction, w = slice level) and interior samples on the segments from the contour
// centroid (u < 1). A few rounds of parameter correction then move each boundary sample's (v, w)
// to its closest point on the fitted boundary surface and fit again (the slice/arc-length
// parametrisation is only a first guess of correspondence); a correction step that would invert
// the solid (det J <= 0 at a Gauss point, find_min_jacobian_determinant) is dropped (the
// last non-inverted fit is kept, at worst the uncorrected one). The lattice is cylindrical: u radial (axis at u = 0, constrained), v around
// (periodic), w along the axis (clamped).
#pragma once

#include "fascicle/bspline/lattice.hpp"
#include "fascicle/geometry/tri_mesh.hpp"

#include <optional>
#include <string>
#include <vector>

namespace fascicle {

// material, X: #S x 3; weights: #S (empty: all 1). Returns the fitted control points (#P x 3).
// Throws bad_input if the samples do not determine the control points.
Points3 fit_control_points(const BSplineSolid& lattice, const LatticeConstraints& constraints,
                           const Points3& material, const Points3& X, const VecX& weights = {},
                           double smoothing = 1e-6);

struct MeshFitOptions {
  std::array<int, 3> count{4, 16, 14};  // control points u (radial), v (around), w (along)
  std::array<int, 3> degree{2, 3, 3};
  int num_slices = 48;
  int contour_samples = 96;             // boundary samples per slice
  int radial_samples = 4;               // interior rings per slice (u < 1)
  double end_inset = 0.0015;            // first/last slice: this fraction of the length inside
  double smoothing = 1e-7;
  // Parameter correction (closest-point re-parametrisation): after each fit, every boundary
  // sample's material coordinates (v, w) move to the foot of its perpendicular on the fitted
  // boundary surface u = 1, then the control points are fitted again. 0 keeps the slice and
  // arc-length parametrisation.
  int reparametrise_iterations = 3;
  // Also fit the mesh vertices themselves as boundary samples (material coordinates: their
  // closest points on the first fitted boundary, then corrected like the slice samples). Slices
  // sample surfaces that run across the axis (shelves, steps) poorly; vertices sample them.
  bool mesh_vertex_samples = true;
  // Lattice choice: when not empty, these control-point counts are fitted as well as `count` and
  // the fit with the smallest max boundary distance is returned (its counts are in the solid).
  std::vector<std::array<int, 3>> lattice_candidates;
  std::optional<Vec3> origin;           // attachment centres (m); both or neither
  std::optional<Vec3> insertion;
  std::string name;
};

struct MeshFitResult {
  BSplineSolid solid;
  LatticeConstraints constraints;
  Vec3 axis_start = Vec3::Zero(), axis_end = Vec3::Zero();  // w = 0 and w = 1 slice centres
  int num_samples = 0;
  double mean_distance_m = 0.0;  // fitted boundary (tessellation vertices) to mesh
  double max_distance_m = 0.0;
  double mesh_volume_m3 = 0.0;
  double solid_volume_m3 = 0.0;  // exact (boundary formula)
  double volume_difference = 0.0;  // (solid - mesh) / mesh
  // Parameter correction as applied: a step that would turn a non-inverted fit into an inverted
  // one is dropped (vertex samples: the rounds then run on the slice samples alone; a
  // closest-point round: the rounds end), so the last non-inverted fit is returned (at worst the
  // uncorrected slice fit).
  bool mesh_vertex_samples_used = false;  // the vertex samples are in the returned fit
  int reparametrise_rounds = 0;           // closest-point rounds in the returned fit
  bool correction_backed_off = false;     // a correction step was dropped because it inverted
  // Smallest det J (m^3 per unit parameter volume) at the Gauss points solid dynamics uses
  // (degree + 1 per span) and at degree + 2 per span, and where. <= 0: the returned solid is
  // inverted (only when even the uncorrected fit is; solid dynamics then rejects it).
  double min_jacobian_det = 0.0;
  Vec3 min_jacobian_material = Vec3::Zero();
};

// Never returns an inverted solid when the uncorrected slice fit is not inverted (see
// MeshFitResult::correction_backed_off). Throws bad_input naming the slice (index and axial position) when a slice is not a single
// closed contour, or when the mesh is open or empty.
MeshFitResult fit_solid_to_mesh(const TriMesh& mesh, const MeshFitOptions& options = {});

}  // namespace fascicle
