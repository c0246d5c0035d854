// Private: stratified low-discrepancy sampling of weighted triangle sets (attachment areas,
// level sets of the harmonic potential).
#pragma once

#include "fascicle/core/types.hpp"

#include <array>
#include <cstddef>
#include <vector>

namespace fascicle::detail {

// Inverse-CDF pick: the interval k of the running sums `cumulative` (non-decreasing, not empty)
// that holds `target`, and where in it target lies (a fraction in [0, 1]).
struct CumulativePick {
  std::size_t index = 0;
  double fraction = 0.0;
};
CumulativePick pick_cumulative(const std::vector<double>& cumulative, double target);

struct WeightedTriangle {
  std::array<Vec3, 3> corner;
  double weight = 0.0;  // sampling density x area (>= 0)
  int tag = -1;         // caller's index (a surface face, a tet)
};

// The triangles `faces` of `mesh` weighted by their areas, tagged with their face indices.
std::vector<WeightedTriangle> make_area_weighted(const Points3& V, const Triangles& F,
                                                 const std::vector<int>& faces);

struct TriangleSample {
  Vec3 point;
  int piece = -1;  // index into the input triangles
};

// `count` points distributed over the triangles in proportion to their weights. The triangles are
// put in a boustrophedon order over their two principal directions (strips about as wide as the
// spacing of `count` points) and the first coordinate of the R2 sequence picks the position along
// the cumulative weight, so consecutive weight intervals are spatial neighbours and the samples are
// stratified in 2-D (no clusters or holes larger than about one spacing); the second coordinate
// places the point inside its triangle. Deterministic. Empty when the total weight is zero.
std::vector<TriangleSample> sample_triangles(const std::vector<WeightedTriangle>& tris, int count);

struct TetSample {
  Vec3 point;
  int tet = -1;
};

// `count` points spread over the tets of `m` (vertices V, tets T) in proportion to their volume:
// the tets are ordered along a serpentine path through cells about (volume / count)^(1/3) wide
// over the three principal directions, and the first coordinate of the R2 sequence picks the
// position along the cumulative volume (3-D stratification); the point inside its tet follows
// from the remainder and the second coordinate (Rocchini & Cignoni 2000's cube-to-tet folding).
std::vector<TetSample> sample_tets(const Points3& V, const Eigen::Matrix<int, Eigen::Dynamic, 4>& T,
                                   int count);

}  // namespace fascicle::detail
