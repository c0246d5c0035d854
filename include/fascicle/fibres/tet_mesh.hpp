// TetMesh: a tetrahedral mesh of a closed surface, built with TetGen (Si 2015, ACM TOMS 41(2)).
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"

namespace fascicle {

using Tetrahedra = Eigen::Matrix<int, Eigen::Dynamic, 4>;

struct TetMesh {
  Points3 V;     // #V x 3 positions (metres); the first rows are the surface mesh's vertices
  Tetrahedra T;  // #T x 4 vertex indices, positively oriented (det[b-a, c-a, d-a] > 0)
  Tetrahedra neighbours;  // #T x 4: tet across the face opposite corner k, or -1 on the boundary

  Eigen::Index num_vertices() const { return V.rows(); }
  Eigen::Index num_tets() const { return T.rows(); }
};

struct TetOptions {
  // Upper bound of a tet's volume (m^3); <= 0: (mean surface edge length)^3 * volume_scale.
  double max_volume = 0.0;
  double volume_scale = 2.0;
  // TetGen's radius-edge ratio bound (switch -q); <= 0 disables quality refinement.
  double max_radius_edge_ratio = 2.0;
};

// Tetrahedralises the interior of a closed, consistently oriented, non-self-intersecting surface.
// The boundary is kept exactly (TetGen -Y), so surface vertex i is TetMesh vertex i and every tet
// lies inside the surface. Throws bad_input (with TetGen's reason) when the surface cannot be
// meshed (open, self-intersecting).
TetMesh calc_tet_mesh(const TriMesh& surface, const TetOptions& options = {});

// Sum of tet volumes (m^3).
double calc_tet_volume(const TetMesh& mesh);

}  // namespace fascicle
