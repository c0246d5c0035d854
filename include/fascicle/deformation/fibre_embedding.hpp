// Fibres carried by the surface deformation. A rest-pose fibre point p is bound like a surface
// vertex to the action line (arc length s_p, offset in the line frame) and written as an affine
// combination of the surface vertices by mean-value coordinates w (Ju, Schaefer and Warren 2005,
// "Mean value coordinates for closed triangular meshes", ACM TOG 24(3)). Per frame
//     p' = c(s_p) + R(s_p) o_p + sum_j w_j (x_j - skin_j),
// the point carried by the line frame plus the mean-value interpolation of the surface's residual
// displacement from its own line-frame ("skinned") position. The residual is small and smooth, so
// each point keeps only its `max_weights` largest coordinates (corrected with the minimum-norm
// change so they still sum to 1 and reproduce the point). Rigid motions are carried exactly.
// calc_embedded_fibres_mvc is plain mean-value transport W X (the reference in docs/deformation.md).
#pragma once

#include "fascicle/deformation/framed_line.hpp"
#include "fascicle/deformation/mesh_operators.hpp"
#include "fascicle/deformation/surface_first.hpp"

#include <vector>

namespace fascicle {

struct FibreEmbeddingOptions {
  int max_weights = 256;  // kept coordinates per fibre point; 0 keeps all (dense)
  // With truncation (max_weights > 0), triangle clusters whose centre lies farther from the point
  // than far_field_ratio times their radius enter only the normalising sum of the coordinates, by
  // a second-order far-field expansion (their vertices are never among the kept ones); the nearer
  // ones are summed exactly. 0: every triangle exactly (O(#F) per point). docs/deformation.md.
  double far_field_ratio = 4.0;
  int cluster_size = 16;  // triangles per cluster (Morton order of the centroids)
};

struct FibreEmbedding {
  std::vector<int> fibre_start;  // fibre f is rows [fibre_start[f], fibre_start[f+1]) of weights
  Eigen::SparseMatrix<double, Eigen::RowMajor> weights;  // #points x #V
  VecX point_s;                  // per point: normalised arc length on the rest action line
  Points3 point_offset_local;    // per point: offset from the line in the line frame
};

// Mean-value coordinates of point x with respect to a closed triangle mesh (dense, sum 1; for x on
// a triangle, its barycentric coordinates; for x on a vertex, that vertex).
VecX calc_mean_value_coordinates(const TriMesh& mesh, const Vec3& x);

// Embeds fibre polylines (rest pose, metres) in the binding's rest surface and action line. Cost
// O(#points * #F), in parallel over points. Throws fascicle::Error (bad input) for non-finite
// fibre points.
FibreEmbedding embed_fibres(const SurfaceBinding& binding, const std::vector<Points3>& fibres,
                            const FibreEmbeddingOptions& options = {});

// The fibres in the solver's current frame (after calc_frame): line-frame transport plus
// interpolated residual. Cost O(#points * max_weights).
std::vector<Points3> calc_embedded_fibres(const FibreEmbedding& embedding,
                                          const SurfaceFirstSolver& solver);

// Plain mean-value transport: the fibres for deformed vertices V (#V x 3) as W V.
std::vector<Points3> calc_embedded_fibres_mvc(const FibreEmbedding& embedding, const Points3& V);

// Per-fibre length and pennation: the length-weighted mean over segments of the acute angle
// between a segment and the action-line tangent at the line point closest to its midpoint.
struct FibreMetrics {
  VecX length_m;
  VecX pennation_rad;
  double mean_length_m = 0.0;
  double mean_pennation_rad = 0.0;
};
FibreMetrics calc_fibre_metrics(const std::vector<Points3>& fibres, const Points3& action_line);

}  // namespace fascicle
