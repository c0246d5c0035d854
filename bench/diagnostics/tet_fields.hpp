// Small helpers shared by the DTI diagnostics (dti_error_map.cpp, dti_sheet_fields.cpp): the angle
// between two undirected lines and per-tet quantities of a linear field on a tet mesh.
#pragma once

#include "fascicle/core/types.hpp"
#include "fascicle/fibres/tet_mesh.hpp"

#include <algorithm>
#include <cmath>

namespace fascicle::diagnostics {

// Angle in [0, pi/2] between the lines along a and b (the sign of either is ignored).
inline double calc_line_angle(const Vec3& a, const Vec3& b) {
  return std::acos(std::min(1.0, std::abs(a.normalized().dot(b.normalized()))));
}

// Per-tet gradient of the piecewise-linear field with vertex values u.
inline Points3 calc_tet_gradients(const TetMesh& m, const VecX& u) {
  Points3 G(m.num_tets(), 3);
  for (Eigen::Index t = 0; t < m.num_tets(); ++t) {
    const Vec3 x0 = m.V.row(m.T(t, 0));
    Mat3 D;
    Vec3 du;
    for (int k = 0; k < 3; ++k) {
      D.row(k) = m.V.row(m.T(t, k + 1)) - x0.transpose();
      du(k) = u(m.T(t, k + 1)) - u(m.T(t, 0));
    }
    G.row(t) = D.partialPivLu().solve(du).transpose();
  }
  return G;
}

inline Points3 calc_tet_centroids(const TetMesh& m) {
  Points3 C = Points3::Zero(m.num_tets(), 3);
  for (Eigen::Index t = 0; t < m.num_tets(); ++t)
    for (int k = 0; k < 4; ++k) C.row(t) += 0.25 * m.V.row(m.T(t, k));
  return C;
}

}  // namespace fascicle::diagnostics
