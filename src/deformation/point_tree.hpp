// Private to the deformation module: a nanoflann k-d tree over the rows of a #P x 3 array.
#pragma once

#include "fascicle/core/types.hpp"

#include <nanoflann.hpp>

#include <cstddef>

namespace fascicle::detail {

// nanoflann's dataset adaptor: the rows of P (not copied; P must outlive the tree).
struct PointCloud {
  const Points3& P;
  std::size_t kdtree_get_point_count() const { return static_cast<std::size_t>(P.rows()); }
  double kdtree_get_pt(std::size_t i, std::size_t d) const { return P(i, d); }
  template <class Box>
  bool kdtree_get_bbox(Box&) const { return false; }
};
using PointTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, PointCloud>,
                                                      PointCloud, 3, std::size_t>;

}  // namespace fascicle::detail
