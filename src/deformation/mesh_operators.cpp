// Laplacians, enclosed volume, its gradient and the volume cubic (see mesh_operators.hpp).
#include "fascicle/deformation/mesh_operators.hpp"

#include "fascicle/core/error.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace fascicle {

namespace {

void check_indices(const TriMesh& mesh) {
  if (mesh.F.size() > 0 && (mesh.F.minCoeff() < 0 || mesh.F.maxCoeff() >= mesh.V.rows()))
    throw_bad_input("triangle index out of range in muscle surface");
}

// cot of the angle at a between (b - a) and (c - a); 0 for a degenerate corner
double cot_at(const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 u = b - a, v = c - a;
  const double s = u.cross(v).norm();
  return s > 0.0 ? u.dot(v) / s : 0.0;
}

}  // namespace

SparseMatrix calc_laplacian(const TriMesh& mesh, LaplacianKind kind) {
  check_indices(mesh);
  const Eigen::Index n = mesh.V.rows();
  std::vector<Eigen::Triplet<double>> t;
  t.reserve(mesh.F.rows() * 12);
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int e = 0; e < 3; ++e) {
      // edge (i, j) opposite corner k
      const int i = mesh.F(f, (e + 1) % 3), j = mesh.F(f, (e + 2) % 3), k = mesh.F(f, e);
      double w;
      if (kind == LaplacianKind::cotangent) {
        w = 0.5 * cot_at(mesh.V.row(k), mesh.V.row(i), mesh.V.row(j));
      } else {
        w = 0.5;  // each interior edge is seen by two faces
      }
      t.emplace_back(i, j, -w);
      t.emplace_back(j, i, -w);
      t.emplace_back(i, i, w);
      t.emplace_back(j, j, w);
    }
  }
  SparseMatrix L(n, n);
  L.setFromTriplets(t.begin(), t.end());
  return L;
}

namespace {

// The rows of P (#V x 3, column-major) as one interleaved array x0 y0 z0 x1 ..., so a triangle's
// corners are read as three contiguous triples instead of nine strided values.
std::vector<double> interleave(const Points3& P) {
  std::vector<double> out(static_cast<std::size_t>(P.rows()) * 3);
  for (Eigen::Index i = 0; i < P.rows(); ++i)
    for (int k = 0; k < 3; ++k) out[static_cast<std::size_t>(3 * i + k)] = P(i, k);
  return out;
}

}  // namespace

void add_volume_gradient_times_six(const double* X, const Triangles& F, double* G) {
  const auto row = [&](int i) {
    const double* p = X + 3 * static_cast<std::size_t>(i);
    return Vec3(p[0], p[1], p[2]);
  };
  const auto add = [&](int i, const Vec3& v) {
    double* g = G + 3 * static_cast<std::size_t>(i);
    g[0] += v[0];
    g[1] += v[1];
    g[2] += v[2];
  };
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const int i0 = F(f, 0), i1 = F(f, 1), i2 = F(f, 2);
    const Vec3 a = row(i0), b = row(i1), c = row(i2);
    // d/da [a.(b x c)] = b x c, and cyclically; translation-invariant form (b-a) x (c-a) summed
    // gives the same total but this one is exact for the sum
    add(i0, b.cross(c));
    add(i1, c.cross(a));
    add(i2, a.cross(b));
  }
}

Points3 calc_volume_gradient(const Points3& V, const Triangles& F) {
  // Same sums in the same (face) order as a direct loop over G's rows, on interleaved copies.
  const std::vector<double> X = interleave(V);
  std::vector<double> G(X.size(), 0.0);
  add_volume_gradient_times_six(X.data(), F, G.data());
  Points3 out(V.rows(), 3);
  for (Eigen::Index i = 0; i < V.rows(); ++i)
    for (int k = 0; k < 3; ++k) out(i, k) = G[static_cast<std::size_t>(3 * i + k)] / 6.0;
  return out;
}

std::array<double, 4> calc_volume_cubic(const Points3& X, const Points3& Y, const Triangles& F,
                                        const Vec3& origin) {
  return calc_volume_cubic(interleave(X).data(), interleave(Y).data(), F, origin);
}

std::array<double, 4> calc_volume_cubic(const double* XI, const double* YI, const Triangles& F, const Vec3& origin) {
  const auto get_row = [](const double* P, int i) {
    const double* p = P + 3 * static_cast<std::size_t>(i);
    return Vec3(p[0], p[1], p[2]);
  };
  std::array<double, 4> c{0.0, 0.0, 0.0, 0.0};
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const int i0 = F(f, 0), i1 = F(f, 1), i2 = F(f, 2);
    const Vec3 a = get_row(XI, i0) - origin, da = get_row(YI, i0);
    const Vec3 b = get_row(XI, i1) - origin, db = get_row(YI, i1);
    const Vec3 cc = get_row(XI, i2) - origin, dc = get_row(YI, i2);
    const Vec3 bc = b.cross(cc), bdc = b.cross(dc), dbc = db.cross(cc), dbdc = db.cross(dc);
    c[0] += a.dot(bc);
    c[1] += da.dot(bc) + a.dot(dbc + bdc);
    c[2] += da.dot(dbc + bdc) + a.dot(dbdc);
    c[3] += da.dot(dbdc);
  }
  for (double& x : c) x /= 6.0;
  return c;
}

namespace {

// The real root of smallest |t| of a0 + a1 t + a2 t^2 + a3 t^3 (NaN when none): the real line is
// cut at the critical points into monotone pieces, bounded by Cauchy's bound; a piece whose ends
// differ in sign holds exactly one root, found by bisection to the last bit.
double find_smallest_real_root(const std::array<double, 4>& a) {
  int degree = 3;
  while (degree > 0 && a[degree] == 0.0) --degree;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (degree == 0) return a[0] == 0.0 ? 0.0 : nan;
  double bound = 0.0;
  for (int k = 0; k < degree; ++k) bound = std::max(bound, std::abs(a[k] / a[degree]));
  bound += 1.0;
  const auto p = [&](double t) { return a[0] + t * (a[1] + t * (a[2] + t * a[3])); };
  std::vector<double> cuts = {-bound, bound};
  // critical points: a1 + 2 a2 t + 3 a3 t^2 = 0
  const double q2 = 3.0 * a[3], q1 = 2.0 * a[2], q0 = a[1];
  if (q2 != 0.0) {
    const double disc = q1 * q1 - 4.0 * q2 * q0;
    if (disc >= 0.0) {
      const double s = std::sqrt(disc);
      cuts.push_back((-q1 - s) / (2.0 * q2));
      cuts.push_back((-q1 + s) / (2.0 * q2));
    }
  } else if (q1 != 0.0) {
    cuts.push_back(-q0 / q1);
  }
  std::sort(cuts.begin(), cuts.end());
  double best = nan;
  for (std::size_t k = 0; k + 1 < cuts.size(); ++k) {
    double lo = std::clamp(cuts[k], -bound, bound), hi = std::clamp(cuts[k + 1], -bound, bound);
    double plo = p(lo);
    const double phi = p(hi);
    double root = nan;
    if (plo == 0.0) root = lo;
    else if (phi == 0.0) root = hi;
    else if ((plo < 0.0) != (phi < 0.0)) {
      for (int it = 0; it < 200 && hi - lo > 0.0; ++it) {
        const double mid = 0.5 * (lo + hi);
        if (mid <= lo || mid >= hi) break;
        const double pm = p(mid);
        if ((pm < 0.0) == (plo < 0.0)) {
          lo = mid;
          plo = pm;
        } else {
          hi = mid;
        }
      }
      root = 0.5 * (lo + hi);
    }
    if (std::isfinite(root) && !(std::abs(root) >= std::abs(best))) best = root;
  }
  return best;
}

}  // namespace

double solve_volume_cubic(const std::array<double, 4>& c, double target) {
  if (std::abs(c[1]) > 0.0) {
    double t = (target - c[0]) / c[1];
    for (int it = 0; it < 50; ++it) {
      const double r = c[0] + t * (c[1] + t * (c[2] + t * c[3])) - target;
      const double d = c[1] + t * (2.0 * c[2] + 3.0 * t * c[3]);
      if (!(std::abs(d) > 0.0)) break;
      const double step = r / d;
      t -= step;
      if (!std::isfinite(t)) break;
      if (std::abs(step) <= 1e-15 * (1.0 + std::abs(t))) return t;
    }
    const double r = c[0] + t * (c[1] + t * (c[2] + t * c[3])) - target;
    if (std::isfinite(t) && std::abs(r) <= 1e-12 * std::abs(target)) return t;
  }
  return find_smallest_real_root({c[0] - target, c[1], c[2], c[3]});
}

}  // namespace fascicle
