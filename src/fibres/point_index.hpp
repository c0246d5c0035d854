// Private: a k-d tree over points (nanoflann), kept out of the public headers.
#pragma once

#include "fascicle/core/types.hpp"

#include <nanoflann.hpp>

#include <memory>
#include <utility>
#include <vector>

namespace fascicle::detail {

class PointIndex {
 public:
  explicit PointIndex(Points3 points) : data_{std::move(points)} {
    tree_ = std::make_unique<Tree>(3, data_, nanoflann::KDTreeSingleIndexAdaptorParams(12));
    tree_->buildIndex();
  }
  PointIndex(const PointIndex&) = delete;
  PointIndex& operator=(const PointIndex&) = delete;

  const Points3& get_points() const { return data_.P; }

  // Index of the nearest point and its squared distance; -1 for an empty set.
  std::pair<int, double> find_nearest(const Vec3& q) const {
    if (data_.P.rows() == 0) return {-1, 0.0};
    std::size_t index = 0;
    double d2 = 0.0;
    tree_->knnSearch(q.data(), 1, &index, &d2);
    return {static_cast<int>(index), d2};
  }

  // Indices of the points within `radius` of q.
  std::vector<int> find_within(const Vec3& q, double radius) const {
    std::vector<std::pair<std::size_t, double>> hits;
    nanoflann::SearchParams params;
    params.sorted = false;
    tree_->radiusSearch(q.data(), radius * radius, hits, params);
    std::vector<int> out;
    out.reserve(hits.size());
    for (const auto& h : hits) out.push_back(static_cast<int>(h.first));
    return out;
  }

 private:
  struct Data {
    Points3 P;
    std::size_t kdtree_get_point_count() const { return static_cast<std::size_t>(P.rows()); }
    double kdtree_get_pt(std::size_t i, std::size_t d) const { return P(i, d); }
    template <class Box>
    bool kdtree_get_bbox(Box&) const { return false; }
  };
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Data>, Data,
                                                   3, std::size_t>;
  Data data_;
  std::unique_ptr<Tree> tree_;
};

}  // namespace fascicle::detail
