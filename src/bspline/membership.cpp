// Point membership / closest point by bound-constrained Levenberg–Marquardt (seed 000 §3.1.3).
#include "fascicle/bspline/membership.hpp"

#include "fascicle/core/error.hpp"

#include <Eigen/Cholesky>
#include <nanoflann.hpp>

#include <algorithm>
#include <cmath>

namespace fascicle {

// Sample grid: positions and material points; nanoflann adaptor over the positions.
struct SolidLocator::SampleTree {
  Points3 X;
  Points3 U;
  size_t kdtree_get_point_count() const { return static_cast<size_t>(X.rows()); }
  double kdtree_get_pt(size_t i, size_t d) const { return X(static_cast<Eigen::Index>(i), d); }
  template <class Box>
  bool kdtree_get_bbox(Box&) const { return false; }
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<
      nanoflann::L2_Simple_Adaptor<double, SampleTree>, SampleTree, 3>;
  std::unique_ptr<Tree> tree;
};

namespace {

// Parameter samples per direction: samples_per_span points inside every non-empty span, plus the
// ends when `ends` (volume samples leave them out: collapsed axes and poles make poor starts).
std::vector<double> make_samples(const BSplineBasis& b, int per_span, bool ends) {
  std::vector<double> t;
  for (int s = b.degree; s < b.num_functions(); ++s) {
    const double a = b.knots[s], c = b.knots[s + 1];
    if (!(c > a)) continue;
    for (int q = 0; q < per_span; ++q) t.push_back(a + (c - a) * (q + 0.5) / per_span);
  }
  if (!b.periodic && ends) {
    t.push_back(b.get_lower());
    t.push_back(b.get_upper());
  }
  std::sort(t.begin(), t.end());
  return t;
}

}  // namespace

SolidLocator::SolidLocator(BSplineSolid solid, LocateOptions options)
    : solid_(std::move(solid)), options_(options), tree_(std::make_unique<SampleTree>()),
      boundary_tree_(std::make_unique<SampleTree>()) {
  validate_solid(solid_);
  const Vec3 lo = solid_.P.colwise().minCoeff().transpose();
  const Vec3 hi = solid_.P.colwise().maxCoeff().transpose();
  tolerance_ = options_.inside_tolerance * std::max((hi - lo).norm(), 1e-300);
  const int per_span = std::max(1, options_.samples_per_span);
  std::array<std::vector<double>, 3> t;
  for (int d = 0; d < 3; ++d) t[d] = make_samples(solid_.basis[d], per_span, false);
  std::vector<Vec3> all, boundary;
  for (double w : t[2])
    for (double v : t[1])
      for (double u : t[0]) all.emplace_back(u, v, w);
  // boundary faces, twice as dense in-plane
  for (int d = 0; d < 3; ++d) {
    if (solid_.basis[d].periodic) continue;
    const int a = (d + 1) % 3, b = (d + 2) % 3;
    const auto ta = make_samples(solid_.basis[a], 2 * per_span, true);
    const auto tb = make_samples(solid_.basis[b], 2 * per_span, true);
    for (double end : {solid_.basis[d].get_lower(), solid_.basis[d].get_upper()})
      for (double y : tb)
        for (double x : ta) {
          Vec3 uvw;
          uvw[d] = end;
          uvw[a] = x;
          uvw[b] = y;
          boundary.push_back(uvw);
        }
  }
  if (boundary.empty()) boundary = all;  // fully periodic: no boundary
  const auto fill = [&](SampleTree& st, const std::vector<Vec3>& U) {
    st.X.resize(static_cast<Eigen::Index>(U.size()), 3);
    st.U.resize(static_cast<Eigen::Index>(U.size()), 3);
    for (std::size_t r = 0; r < U.size(); ++r) {
      st.U.row(r) = U[r].transpose();
      st.X.row(r) = calc_point(solid_, U[r]).transpose();
    }
    st.tree = std::make_unique<SampleTree::Tree>(3, st, nanoflann::KDTreeSingleIndexAdaptorParams(16));
    st.tree->buildIndex();
  };
  fill(*tree_, all);
  fill(*boundary_tree_, boundary);
}

SolidLocator::~SolidLocator() = default;
SolidLocator::SolidLocator(SolidLocator&&) noexcept = default;
SolidLocator& SolidLocator::operator=(SolidLocator&&) noexcept = default;

PointLocation SolidLocator::locate_from(const Vec3& p, const Vec3& start) const {
  const Vec3 lo = solid_.get_lower(), hi = solid_.get_upper();
  bool periodic[3];
  for (int d = 0; d < 3; ++d) periodic[d] = solid_.basis[d].periodic;
  const auto project = [&](Vec3 u) {
    for (int d = 0; d < 3; ++d) u[d] = wrap_parameter(solid_.basis[d], u[d]);
    return u;
  };
  Vec3 u = project(start);
  SolidPoint sp = calc_point_and_jacobian(solid_, u);
  Vec3 r = sp.x - p;
  double f = r.squaredNorm();
  double lambda = 1e-3;
  // iterate well below the inside tolerance: Gauss–Newton converges quadratically there
  const double tol2 = 1e-6 * tolerance_ * tolerance_;
  PointLocation out;
  int it = 0;
  bool stalled = false;
  while (it < options_.max_iterations && f > tol2 && !stalled) {
    ++it;
    const Vec3 g = sp.J.transpose() * r;
    Mat3 H = sp.J.transpose() * sp.J;
    // active set: coordinates on a bound with the descent direction pointing out of the box
    bool active[3];
    for (int d = 0; d < 3; ++d) {
      const double span = hi[d] - lo[d];
      active[d] = !periodic[d] && ((u[d] <= lo[d] + 1e-14 * span && g[d] > 0) ||
                                   (u[d] >= hi[d] - 1e-14 * span && g[d] < 0));
      if (solid_.basis[d].degree == 0) active[d] = true;  // collapsed direction
    }
    bool accepted = false;
    while (!accepted && lambda < 1e16) {
      Mat3 A = H;
      Vec3 b = -g;
      const double scale = std::max(H.diagonal().maxCoeff(), 1e-300);
      for (int d = 0; d < 3; ++d) {
        A(d, d) += lambda * std::max(H(d, d), 1e-12 * scale);
        if (active[d]) {
          A.row(d).setZero();
          A.col(d).setZero();
          A(d, d) = 1.0;
          b[d] = 0.0;
        }
      }
      const Vec3 step = A.ldlt().solve(b);
      const Vec3 un = project(u + step);
      const SolidPoint spn = calc_point_and_jacobian(solid_, un);
      const Vec3 rn = spn.x - p;
      const double fn = rn.squaredNorm();
      if (fn < f) {
        const double moved = (un - u).cwiseAbs().maxCoeff();
        const double gain = f - fn;
        u = un;
        sp = spn;
        r = rn;
        f = fn;
        lambda = std::max(lambda * 0.2, 1e-12);
        accepted = true;
        // converged (outside): the parameter step or the relative decrease is at rounding level
        stalled = moved < 1e-15 || gain <= 1e-14 * f;
      } else {
        lambda *= 8.0;
      }
    }
    if (!accepted) break;  // no descent possible: a stationary point
  }
  out.iterations = it;
  out.starts = 1;
  out.material = u;
  out.closest = sp.x;
  out.distance = std::sqrt(f);
  out.inside = out.distance <= tolerance_;
  return out;
}

PointLocation SolidLocator::locate(const Vec3& p) const {
  if (!p.allFinite()) throw_bad_input("point membership: the query point is not finite");
  // first start: the nearest sample of the volume grid
  unsigned int idx[16];
  double d2[16];
  tree_->tree->knnSearch(p.data(), 1, idx, d2);
  PointLocation best = locate_from(p, tree_->U.row(idx[0]).transpose());
  int iterations = best.iterations, starts = 1;
  if (!best.inside) {
    // outside (or a local minimum): restart from the nearest boundary samples
    const int k = std::clamp(options_.restarts, 1, 16);
    const size_t found = boundary_tree_->tree->knnSearch(p.data(), k, idx, d2);
    for (size_t s = 0; s < found; ++s) {
      const PointLocation loc = locate_from(p, boundary_tree_->U.row(idx[s]).transpose());
      iterations += loc.iterations;
      ++starts;
      if (loc.distance < best.distance) best = loc;
      if (best.inside) break;
    }
  }
  best.iterations = iterations;
  best.starts = starts;
  return best;
}

PointLocation locate_point(const BSplineSolid& solid, const Vec3& p, LocateOptions options) {
  return SolidLocator(solid, options).locate(p);
}

}  // namespace fascicle
