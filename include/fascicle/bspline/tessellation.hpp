// Tessellation with cached basis products (seed 000 §3.1.4). The basis-function products at the
// sample points are computed once into sparse matrices W (#samples x #control points); when control
// points move, positions are W P and tangents W_a P, W_b P: a sparse matrix–vector product, no
// basis evaluation. Level of detail = tessellating again at another density.
#pragma once

#include "fascicle/bspline/solid.hpp"
#include "fascicle/geometry/tri_mesh.hpp"

#include <Eigen/SparseCore>

namespace fascicle {

using SparseRowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor>;

// Boundary surface of a solid as a closed triangle mesh (outward normals for a positively
// oriented solid). Faces of periodic directions are skipped and faces collapsed to a line or a
// point (axes, poles) are dropped; coincident vertices along collapsed edges are merged.
struct BoundaryTessellation {
  TriMesh mesh;             // at the control points it was built (or last updated) with
  Points3 material;         // #V x 3 material points of the vertices
  SparseRowMatrix weights;  // #V x #P: V = weights * P
  SparseRowMatrix tangent_a, tangent_b;  // #V x #P: in-face tangents; normal = a x b
  Points3 normals;          // #V x 3 unit outward normals
};

// samples_per_span: vertices per knot span along each direction (>= 1).
BoundaryTessellation make_boundary_tessellation(const BSplineSolid& solid, int samples_per_span);

// Recomputes positions and normals for new control points (same lattice): sparse products only.
void update_tessellation(BoundaryTessellation& t, const Points3& P);

// Hexahedral volume mesh on a material grid.
struct VolumeTessellation {
  Points3 V;                              // #V x 3 node positions (m)
  Points3 material;                       // #V x 3 material points
  Eigen::Matrix<int, Eigen::Dynamic, 8> hexes;  // VTK_HEXAHEDRON node order
  SparseRowMatrix weights;                // #V x #P
};

VolumeTessellation make_volume_tessellation(const BSplineSolid& solid, int samples_per_span);
void update_tessellation(VolumeTessellation& t, const Points3& P);

// Parameter values of a grid: samples_per_span per non-empty span, ends included (periodic:
// the upper end is omitted, it equals the lower one).
std::vector<double> make_parameter_grid(const BSplineBasis& basis, int samples_per_span);

// Sparse row of basis products at material point U (derivative orders per direction).
void append_basis_row(const BSplineSolid& solid, const Vec3& uvw, const std::array<int, 3>& order,
                      int row, std::vector<Eigen::Triplet<double>>& triplets);

}  // namespace fascicle
