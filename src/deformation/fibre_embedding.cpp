// Mean-value coordinates and fibre embedding (see fibre_embedding.hpp).
#include "fascicle/deformation/fibre_embedding.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"

#include <Eigen/Dense>
#include <nanoflann.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <mutex>
#include <numeric>

namespace fascicle {

namespace {

// Undirected edges of a triangle mesh and, per triangle corner i, the edge opposite it with its
// orientation (stored as (F(t,i+1), F(t,i+2)), or reversed). Kept as plain arrays (edge ends, and
// per corner the edge index and a sign) so the per-point loops below read them contiguously.
struct EdgeTable {
  std::vector<int> edge_a, edge_b;   // ends of edge e
  std::vector<int> opposite;         // per triangle t, corner i: [3 t + i] = edge index
  std::vector<double> sign;          // [3 t + i] = +1 (stored as (F(t,i+1), F(t,i+2))) or -1
};

EdgeTable make_edge_table(const Triangles& F) {
  EdgeTable t;
  std::vector<std::array<int, 3>> half;  // (min vertex, max vertex, triangle * 3 + corner)
  half.reserve(static_cast<std::size_t>(F.rows()) * 3);
  for (int f = 0; f < F.rows(); ++f)
    for (int i = 0; i < 3; ++i) {
      const int a = F(f, (i + 1) % 3), b = F(f, (i + 2) % 3);
      half.push_back({std::min(a, b), std::max(a, b), f * 3 + i});
    }
  std::sort(half.begin(), half.end());
  t.opposite.resize(static_cast<std::size_t>(F.rows()) * 3);
  t.sign.resize(static_cast<std::size_t>(F.rows()) * 3);
  for (std::size_t k = 0; k < half.size(); ++k) {
    if (k == 0 || half[k][0] != half[k - 1][0] || half[k][1] != half[k - 1][1]) {
      t.edge_a.push_back(half[k][0]);
      t.edge_b.push_back(half[k][1]);
    }
    const int f = half[k][2] / 3, i = half[k][2] % 3;
    const bool reversed = F(f, (i + 1) % 3) != half[k][0];
    t.opposite[static_cast<std::size_t>(half[k][2])] = static_cast<int>(t.edge_a.size() - 1);
    t.sign[static_cast<std::size_t>(half[k][2])] = reversed ? -1.0 : 1.0;
  }
  return t;
}

// Makes v hold at least n elements; never shrinks (so the per-cluster calls on meshes of varying
// size neither reallocate nor zero-fill: every element a call reads it has written first).
template <class T>
void grow(std::vector<T>& v, std::size_t n) {
  if (v.size() < n) v.resize(n);
}

// Per-point work arrays of calc_mean_value_coordinates (one set per call; no shared state).
struct MvcScratch {
  std::vector<double> d, ux, uy, uz;           // per vertex: distance and unit direction from x
  std::vector<double> theta, nx, ny, nz;       // per edge: arc and unit plane normal
  std::vector<double> contribution;            // per face corner: closed-form weight
  std::vector<unsigned char> robust;           // per face: needs the per-triangle formula
};

// 2 asin(l / 2) for a chord 0 <= l <= 2 between unit vectors, for short chords (every edge of a
// triangle far from x): the Maclaurin series of asin through y^15 (y = l/2 < 1/8: the first omitted
// term is below 5e-17 y, i.e. round-off). Branch-free, so the edge loop vectorises; longer chords
// are redone with std::asin in a second, scalar pass.
constexpr double kSeriesChord = 0.25;
inline double calc_short_chord_angle(double l) {
  const double y = 0.5 * l;
  const double y2 = y * y;
  // asin(y) = sum_k (2k)! / (4^k (k!)^2 (2k+1)) y^(2k+1)
  const double p = 1.0 + y2 * (1.0 / 6.0 + y2 * (3.0 / 40.0 + y2 * (15.0 / 336.0 + y2 * (105.0 / 3456.0 +
                   y2 * (945.0 / 42240.0 + y2 * (10395.0 / 599040.0 + y2 * (135135.0 / 9676800.0)))))));
  return 2.0 * y * p;
}

// The contribution of triangle f to the (unnormalised) mean-value weights w of the point x, with
// d_j = |v_j - x| and u_j = (v_j - x) / d_j: the robust per-triangle formula of Ju, Schaefer and
// Warren (2005, section 3.3). Returns true when x lies on the triangle (w then holds its
// barycentric coordinates, normalised, and nothing else).
bool add_triangle_weights(const Triangles& F, Eigen::Index f, const MvcScratch& s, Eigen::Ref<VecX> w) {
  const int id[3] = {F(f, 0), F(f, 1), F(f, 2)};
  const auto u = [&](int j) { return Vec3(s.ux[j], s.uy[j], s.uz[j]); };
  // θ_i = 2 asin(l_i / 2) for the chord l_i between the unit vectors; then exactly
  // sin θ_i = l_i sqrt(1 - l_i²/4) and cos θ_i = 1 - l_i²/2.
  double theta[3], sin_theta[3], cos_theta[3], c[3], sv[3];
  for (int i = 0; i < 3; ++i) {
    const double l = std::min((u(id[(i + 1) % 3]) - u(id[(i + 2) % 3])).norm(), 2.0);
    theta[i] = 2.0 * std::asin(0.5 * l);
    sin_theta[i] = l * std::sqrt(std::max(0.0, 1.0 - 0.25 * l * l));
    cos_theta[i] = 1.0 - 0.5 * l * l;
  }
  const double h = 0.5 * (theta[0] + theta[1] + theta[2]);
  if (M_PI - h < 1e-10) {
    // x lies on this triangle: barycentric coordinates from the angles
    w.setZero();
    for (int i = 0; i < 3; ++i) w[id[i]] = sin_theta[i] * s.d[id[(i + 2) % 3]] * s.d[id[(i + 1) % 3]];
    w /= w.sum();
    return true;
  }
  const double sin_h = std::sin(h), cos_h = std::cos(h);
  Mat3 U;
  U << u(id[0]).transpose(), u(id[1]).transpose(), u(id[2]).transpose();
  const double sign = U.determinant() < 0.0 ? -1.0 : 1.0;
  for (int i = 0; i < 3; ++i) {
    const double sin_h_minus = sin_h * cos_theta[i] - cos_h * sin_theta[i];  // sin(h - θ_i)
    c[i] = 2.0 * sin_h * sin_h_minus / (sin_theta[(i + 1) % 3] * sin_theta[(i + 2) % 3]) - 1.0;
    sv[i] = sign * std::sqrt(std::max(0.0, 1.0 - c[i] * c[i]));
    if (std::abs(sv[i]) <= 1e-10) return false;  // x in the triangle's plane, outside it: no contribution
  }
  for (int i = 0; i < 3; ++i) {
    const int a = (i + 1) % 3, b = (i + 2) % 3;
    w[id[i]] += (theta[i] - c[a] * theta[b] - c[b] * theta[a]) / (s.d[id[i]] * sin_theta[a] * sv[b]);
  }
  return false;
}

// Adds the unnormalised mean-value weights of x over the triangles of `mesh` to w (#V, zero on
// entry). Returns true when x lies on a vertex or triangle (within eps): w then holds the final,
// normalised coordinates (that vertex, or the triangle's barycentric coordinates) and nothing else.
// Most triangles use the closed form of Ju, Schaefer and
// Warren (2005, section 3.2): with unit directions u_i from x to the corners, the mean vector of
// the triangle's spherical image is m = 1/2 sum_i theta_i n_i (theta_i the arc opposite corner i,
// n_i the unit normal u_{i+1} x u_{i+2} / |.| of the plane through x and the opposite edge) and the
// corner weights are w_i = (n_i . m) / (d_i n_i . u_i). Arc and plane normal depend on the edge
// only, so they are computed once per edge: half the asin of the per-triangle formula and no
// sin/cos. Triangles seen nearly edge-on (|n_i . u_i| <= 1e-6) or nearly containing x use the
// per-triangle formula (add_triangle_weights), which handles the in-plane and on-triangle cases.
// The vertex and edge passes run over plain arrays (structure of arrays) so they vectorise.
// With GCC on x86-64 it is compiled for AVX-512, AVX2 and the baseline, and the loader picks the
// best the CPU has (function multiversioning). The loops are element-wise (no reassociated sums);
// the AVX2 and baseline versions give the same bits, while GCC's avx512f target implies FMA and
// contracts some multiply-adds, so the AVX-512 version differs at round-off (docs/deformation.md);
// elsewhere, and under AddressSanitizer (whose instrumentation does not mix with ifunc resolvers),
// only the baseline is built.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(__SANITIZE_ADDRESS__)
__attribute__((target_clones("avx512f", "avx2", "default")))
#endif
bool accumulate_mean_value_weights(const TriMesh& mesh, const EdgeTable& table, const Vec3& x, double eps,
                                   MvcScratch& s, Eigen::Ref<VecX> w) {
  const Eigen::Index n = mesh.V.rows();
  const auto nu = static_cast<std::size_t>(n);
  grow(s.d, nu);
  grow(s.ux, nu);
  grow(s.uy, nu);
  grow(s.uz, nu);
  const double* vx = mesh.V.col(0).data();
  const double* vy = mesh.V.col(1).data();
  const double* vz = mesh.V.col(2).data();
  double* __restrict d = s.d.data();
  double* __restrict ux = s.ux.data();
  double* __restrict uy = s.uy.data();
  double* __restrict uz = s.uz.data();
  const double x0 = x[0], x1 = x[1], x2 = x[2];
  for (std::size_t j = 0; j < nu; ++j) {
    const double ex = vx[j] - x0, ey = vy[j] - x1, ez = vz[j] - x2;
    d[j] = std::sqrt(ex * ex + ey * ey + ez * ez);
    ux[j] = ex;
    uy[j] = ey;
    uz[j] = ez;
  }
  for (std::size_t j = 0; j < nu; ++j)
    if (d[j] < eps) {  // x is a vertex
      w.setZero();
      w[static_cast<Eigen::Index>(j)] = 1.0;
      return true;
    }
  for (std::size_t j = 0; j < nu; ++j) {
    ux[j] /= d[j];
    uy[j] /= d[j];
    uz[j] /= d[j];
  }
  const std::size_t ne = table.edge_a.size();
  grow(s.theta, ne);
  grow(s.nx, ne);
  grow(s.ny, ne);
  grow(s.nz, ne);
  const int* ea = table.edge_a.data();
  const int* eb = table.edge_b.data();
  double* __restrict theta = s.theta.data();
  double* __restrict nx = s.nx.data();
  double* __restrict ny = s.ny.data();
  double* __restrict nz = s.nz.data();
  double longest = 0.0;
  for (std::size_t e = 0; e < ne; ++e) {
    const int a = ea[e], b = eb[e];
    const double ax = ux[a], ay = uy[a], az = uz[a], bx = ux[b], by = uy[b], bz = uz[b];
    const double lx = ax - bx, ly = ay - by, lz = az - bz;
    const double l = std::sqrt(lx * lx + ly * ly + lz * lz);
    theta[e] = calc_short_chord_angle(l);
    longest = std::max(longest, l);
    const double cx = ay * bz - az * by, cy = az * bx - ax * bz, cz = ax * by - ay * bx;
    const double cn = std::sqrt(cx * cx + cy * cy + cz * cz);
    const double inv = 1.0 / std::max(cn, std::numeric_limits<double>::min());  // n = 0 when cn = 0
    nx[e] = cx * inv;
    ny[e] = cy * inv;
    nz[e] = cz * inv;
  }
  if (longest >= kSeriesChord) {
    for (std::size_t e = 0; e < ne; ++e) {
      const int a = ea[e], b = eb[e];
      const double lx = ux[a] - ux[b], ly = uy[a] - uy[b], lz = uz[a] - uz[b];
      const double l = std::sqrt(lx * lx + ly * ly + lz * lz);
      if (l >= kSeriesChord) theta[e] = 2.0 * std::asin(0.5 * std::min(l, 2.0));
    }
  }
  // face pass in two parts: the closed-form corner contributions of every face into per-face
  // arrays (no branches or scatter, so it vectorises with gathers), with a flag for faces that
  // need the per-triangle formula; then the scatter into w, in face order, with flagged faces
  // handled in place (same sums in the same order as a single loop)
  const std::size_t nfaces = static_cast<std::size_t>(mesh.F.rows());
  grow(s.contribution, 3 * nfaces);
  grow(s.robust, nfaces);
  const int* F0 = mesh.F.col(0).data();
  const int* F1 = mesh.F.col(1).data();
  const int* F2 = mesh.F.col(2).data();
  const int* opposite = table.opposite.data();
  const double* edge_sign = table.sign.data();
  double* contribution = s.contribution.data();
  unsigned char* robust = s.robust.data();
  for (std::size_t f = 0; f < nfaces; ++f) {
    const int corner[3] = {F0[f], F1[f], F2[f]};
    double th[3], nuv[3], nix[3], niy[3], niz[3];
    bool flag = false;
    for (int i = 0; i < 3; ++i) {
      const int e = opposite[3 * f + i];
      const double sg = edge_sign[3 * f + i];
      th[i] = theta[e];
      nix[i] = sg * nx[e];
      niy[i] = sg * ny[e];
      niz[i] = sg * nz[e];
      nuv[i] = nix[i] * ux[corner[i]] + niy[i] * uy[corner[i]] + niz[i] * uz[corner[i]];
      flag |= !(std::abs(nuv[i]) > 1e-6);
    }
    flag |= M_PI - 0.5 * (th[0] + th[1] + th[2]) < 1e-6;
    robust[f] = flag ? 1 : 0;
    const double mx = 0.5 * (th[0] * nix[0] + th[1] * nix[1] + th[2] * nix[2]);
    const double my = 0.5 * (th[0] * niy[0] + th[1] * niy[1] + th[2] * niy[2]);
    const double mz = 0.5 * (th[0] * niz[0] + th[1] * niz[1] + th[2] * niz[2]);
    for (int i = 0; i < 3; ++i)
      contribution[3 * f + i] = (nix[i] * mx + niy[i] * my + niz[i] * mz) / (d[corner[i]] * nuv[i]);
  }
  for (std::size_t f = 0; f < nfaces; ++f) {
    if (robust[f]) {
      if (add_triangle_weights(mesh.F, static_cast<Eigen::Index>(f), s, w)) return true;  // x on this triangle
      continue;
    }
    w[F0[f]] += contribution[3 * f];
    w[F1[f]] += contribution[3 * f + 1];
    w[F2[f]] += contribution[3 * f + 2];
  }
  return false;
}

// Mean-value coordinates of x with respect to the whole mesh (normalised).
VecX calc_mean_value_coordinates(const TriMesh& mesh, const EdgeTable& table, const Vec3& x, MvcScratch& s) {
  const double scale = (mesh.V.colwise().maxCoeff() - mesh.V.colwise().minCoeff()).norm();
  VecX w = VecX::Zero(mesh.V.rows());
  if (accumulate_mean_value_weights(mesh, table, x, 1e-12 * scale, s, w)) return w;
  const double sum = w.sum();
  if (!(std::abs(sum) > 0.0) || !std::isfinite(sum))
    throw_numerical("mean-value coordinates undefined (point far outside or degenerate surface)");
  return w / sum;
}

// Keeps the k largest |w| and corrects them (minimum norm) so that sum w = 1 and sum w_j v_j = x.
std::vector<std::pair<int, double>> truncate_affine(const TriMesh& mesh, const Vec3& x,
                                                    const VecX& w, int k) {
  std::vector<int> idx(w.size());
  std::iota(idx.begin(), idx.end(), 0);
  if (k > 0 && k < w.size()) {
    std::nth_element(idx.begin(), idx.begin() + k, idx.end(),
                     [&](int a, int b) { return std::abs(w[a]) > std::abs(w[b]); });
    idx.resize(k);
    std::sort(idx.begin(), idx.end());
  }
  const int m = static_cast<int>(idx.size());
  VecX wk(m);
  Eigen::MatrixXd A(4, m);
  double scale = 0.0;
  for (int j = 0; j < m; ++j) scale = std::max(scale, (mesh.V.row(idx[j]).transpose() - x).norm());
  for (int j = 0; j < m; ++j) {
    wk[j] = w[idx[j]];
    A.block<3, 1>(0, j) = (mesh.V.row(idx[j]).transpose() - x) / scale;
    A(3, j) = 1.0;
  }
  if (m < w.size()) {
    // minimum-norm correction: A dw = r (rank-revealing, exact when the kept vertices span 3-D)
    const Vec4 r = Vec4(0, 0, 0, 1) - A * wk;
    wk += A.completeOrthogonalDecomposition().solve(r);
  }
  std::vector<std::pair<int, double>> out;
  for (int j = 0; j < m; ++j)
    if (wk[j] != 0.0) out.emplace_back(idx[j], wk[j]);
  return out;
}

// The triangles of a surface in spatially compact clusters, for far-field sums.
//
// The mean-value normaliser is an integral over the surface: for a closed triangle mesh the
// weights of the corners of triangle T add up to
//     sum_i w_i,T = integral over T of n . (p - x) / |p - x|^4 dA(p)
// (the continuous coordinates of Ju et al. 2005 weight a surface point by 1/|p - x| per unit solid
// angle, and dw = n . (p - x) / |p - x|^3 dA). For a cluster C of triangles whose centre c is far
// from x compared with its radius, the integral of the vector kernel g(y) = y / |y|^4 over C is
// expanded about y0 = c - x to second order:
//     sum_T a_T . g(y0) + sum_T a_T^T J(y0) dc_T + 1/2 sum_T H(y0)[a_T, S_T],
// with a_T = area_T n_T, dc_T = centroid_T - c, S_T = (1/area_T) integral over T of (p - c)(p - c)^T
// dA, J and H the first and second derivatives of g. The moments N = sum a_T, M = sum a_T dc_T^T and
// Q_ikl = sum_T a_T,i S_T,kl are exact sums per cluster (computed once), so the remainder is the
// third-order term of the expansion, O((radius / |y0|)^3) relative to the cluster's contribution.
struct FarField {
  Vec3 centre = Vec3::Zero();
  double radius = 0.0;        // largest distance from the centre to a corner
  Vec3 N = Vec3::Zero();
  Mat3 M = Mat3::Zero();
  std::array<Mat3, 3> Q{Mat3::Zero(), Mat3::Zero(), Mat3::Zero()};  // Q[i](k, l)
  Vec3 P = Vec3::Zero();      // P_l = sum_i Q_iil
  Vec3 T = Vec3::Zero();      // T_i = sum_k Q_ikk
};

struct FaceCluster {
  TriMesh local;              // the cluster's triangles over its own vertices
  EdgeTable table;            // of `local`
  std::vector<int> vertex;    // local vertex -> surface vertex
  std::vector<int> faces_at;  // per local vertex: the cluster's triangles that use it
  FarField far;
};

// Consecutive clusters [first, last) with the far field of all their triangles: a group far from
// the point is expanded once instead of cluster by cluster.
struct ClusterGroup {
  int first = 0, last = 0;
  FarField far;
};

// nanoflann's view of a surface's vertices (not copied).
struct VertexCloud {
  const Points3* V = nullptr;
  std::size_t kdtree_get_point_count() const { return static_cast<std::size_t>(V->rows()); }
  double kdtree_get_pt(std::size_t i, std::size_t d) const { return (*V)(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(d)); }
  template <class Box>
  bool kdtree_get_bbox(Box&) const { return false; }
};
using VertexTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, VertexCloud>,
                                                       VertexCloud, 3, std::size_t>;

struct ClusteredSurface {
  std::vector<FaceCluster> clusters;
  std::vector<ClusterGroup> groups;
  std::vector<int> valence;  // per surface vertex: triangles that use it
  std::unique_ptr<VertexCloud> cloud;  // (on the heap: the tree refers to it)
  std::unique_ptr<VertexTree> tree;    // k nearest vertices of a point
};

// The moments of the far-field expansion of the triangles `faces` of mesh (about their
// area-weighted centroid).
FarField make_far_field(const TriMesh& mesh, const std::vector<int>& faces) {
  FarField c;
  double area = 0.0;
  Vec3 weighted = Vec3::Zero();
  const auto corner = [&](int f, int i) -> Vec3 { return mesh.V.row(mesh.F(f, i)).transpose(); };
  for (int f : faces) {
    const Vec3 a = corner(f, 0), b = corner(f, 1), d = corner(f, 2);
    const double A = 0.5 * (b - a).cross(d - a).norm();
    area += A;
    weighted += A * (a + b + d) / 3.0;
  }
  Vec3 mean = Vec3::Zero();
  for (int f : faces) mean += (corner(f, 0) + corner(f, 1) + corner(f, 2)) / (3.0 * static_cast<double>(faces.size()));
  c.centre = area > 0.0 ? Vec3(weighted / area) : mean;
  for (int f : faces) {
    const Vec3 d0 = corner(f, 0) - c.centre, d1 = corner(f, 1) - c.centre, d2 = corner(f, 2) - c.centre;
    c.radius = std::max({c.radius, d0.norm(), d1.norm(), d2.norm()});
    const Vec3 a = 0.5 * (d1 - d0).cross(d2 - d0);  // area times outward normal
    const Vec3 sum = d0 + d1 + d2;
    // (1/area) integral over the triangle of (p - c)(p - c)^T = (sum_i d_i d_i^T + s s^T) / 12
    const Mat3 S = (d0 * d0.transpose() + d1 * d1.transpose() + d2 * d2.transpose() + sum * sum.transpose()) / 12.0;
    c.N += a;
    c.M += a * (sum / 3.0).transpose();
    for (int i = 0; i < 3; ++i) c.Q[static_cast<std::size_t>(i)] += a[i] * S;
  }
  for (int i = 0; i < 3; ++i) {
    c.P += c.Q[static_cast<std::size_t>(i)].row(i).transpose();
    c.T[i] = c.Q[static_cast<std::size_t>(i)].trace();
  }
  return c;
}

// Clusters of about `size` consecutive triangles in Morton order of their centroids.
ClusteredSurface make_clustered_surface(const TriMesh& mesh, int size) {
  ClusteredSurface out;
  const Eigen::Index nf = mesh.F.rows();
  out.valence.assign(static_cast<std::size_t>(mesh.V.rows()), 0);
  for (Eigen::Index f = 0; f < nf; ++f)
    for (int i = 0; i < 3; ++i) ++out.valence[static_cast<std::size_t>(mesh.F(f, i))];
  const Vec3 lo = mesh.V.colwise().minCoeff().transpose();
  const Vec3 extent = (mesh.V.colwise().maxCoeff().transpose() - lo).cwiseMax(1e-300);
  const auto spread = [](std::uint64_t v) {  // 21 bits -> every third bit
    v &= 0x1fffff;
    v = (v | v << 32) & 0x1f00000000ffffULL;
    v = (v | v << 16) & 0x1f0000ff0000ffULL;
    v = (v | v << 8) & 0x100f00f00f00f00fULL;
    v = (v | v << 4) & 0x10c30c30c30c30c3ULL;
    v = (v | v << 2) & 0x1249249249249249ULL;
    return v;
  };
  std::vector<std::pair<std::uint64_t, int>> order(static_cast<std::size_t>(nf));
  for (Eigen::Index f = 0; f < nf; ++f) {
    const Vec3 c = (mesh.V.row(mesh.F(f, 0)) + mesh.V.row(mesh.F(f, 1)) + mesh.V.row(mesh.F(f, 2))).transpose() / 3.0;
    std::uint64_t code = 0;
    for (int k = 0; k < 3; ++k) {
      const double t = std::clamp((c[k] - lo[k]) / extent[k], 0.0, 1.0);
      code |= spread(static_cast<std::uint64_t>(t * 2097151.0)) << k;
    }
    order[static_cast<std::size_t>(f)] = {code, static_cast<int>(f)};
  }
  std::sort(order.begin(), order.end());
  std::vector<int> local_of(static_cast<std::size_t>(mesh.V.rows()), -1);
  for (std::size_t start = 0; start < order.size(); start += static_cast<std::size_t>(size)) {
    const std::size_t end = std::min(order.size(), start + static_cast<std::size_t>(size));
    FaceCluster c;
    c.local.F.resize(static_cast<Eigen::Index>(end - start), 3);
    for (std::size_t k = start; k < end; ++k)
      for (int i = 0; i < 3; ++i) {
        const int g = mesh.F(order[k].second, i);
        if (local_of[static_cast<std::size_t>(g)] < 0) {
          local_of[static_cast<std::size_t>(g)] = static_cast<int>(c.vertex.size());
          c.vertex.push_back(g);
          c.faces_at.push_back(0);
        }
        const int l = local_of[static_cast<std::size_t>(g)];
        c.local.F(static_cast<Eigen::Index>(k - start), i) = l;
        ++c.faces_at[static_cast<std::size_t>(l)];
      }
    c.local.V.resize(static_cast<Eigen::Index>(c.vertex.size()), 3);
    for (std::size_t l = 0; l < c.vertex.size(); ++l) {
      c.local.V.row(static_cast<Eigen::Index>(l)) = mesh.V.row(c.vertex[l]);
      local_of[static_cast<std::size_t>(c.vertex[l])] = -1;
    }
    c.table = make_edge_table(c.local.F);
    std::vector<int> faces;
    for (std::size_t k = start; k < end; ++k) faces.push_back(order[k].second);
    c.far = make_far_field(mesh, faces);
    out.clusters.push_back(std::move(c));
  }
  out.cloud = std::make_unique<VertexCloud>(VertexCloud{&mesh.V});
  out.tree = std::make_unique<VertexTree>(3, *out.cloud, nanoflann::KDTreeSingleIndexAdaptorParams(10));
  constexpr int kGroup = 16;  // clusters per group
  const int nc = static_cast<int>(out.clusters.size());
  for (int first = 0; first < nc; first += kGroup) {
    ClusterGroup g;
    g.first = first;
    g.last = std::min(nc, first + kGroup);
    std::vector<int> faces;
    for (std::size_t k = static_cast<std::size_t>(first) * static_cast<std::size_t>(size);
         k < std::min(order.size(), static_cast<std::size_t>(g.last) * static_cast<std::size_t>(size)); ++k)
      faces.push_back(order[k].second);
    g.far = make_far_field(mesh, faces);
    out.groups.push_back(std::move(g));
  }
  return out;
}

// The cluster's share of the mean-value normaliser at x, by the expansion above (y = centre - x).
double calc_far_field_sum(const FarField& c, const Vec3& y) {
  const double s = y.squaredNorm();
  const double inv2 = 1.0 / (s * s), inv3 = inv2 / s, inv4 = inv3 / s;
  const double zeroth = c.N.dot(y) * inv2;
  const double first = c.M.trace() * inv2 - 4.0 * y.dot(c.M * y) * inv3;
  const double cubic = y[0] * y.dot(c.Q[0] * y) + y[1] * y.dot(c.Q[1] * y) + y[2] * y.dot(c.Q[2] * y);
  const double second = -2.0 * (2.0 * c.P + c.T).dot(y) * inv3 + 12.0 * cubic * inv4;
  return zeroth + first + second;
}

// Work arrays of one thread for calc_clustered_weights.
struct ClusterScratch {
  MvcScratch mvc;
  VecX local_w;
  VecX w;                     // per surface vertex (zero between calls)
  std::vector<int> covered;   // per surface vertex: near triangles that use it (zero between calls)
  std::vector<int> touched;
  std::vector<double> distance2;     // squared distances of x's k nearest vertices
  std::vector<std::size_t> nearest;  // and their indices
};

// The k largest mean-value coordinates of x (then made affine by truncate_affine's correction):
// clusters within `ratio` radii of x, or with a corner within twice the distance of x's k-th nearest
// vertex, are summed exactly (closed form); the others enter only the normaliser, by their
// far-field expansion. Only vertices all of whose triangles are near are candidates. Returns false when fewer than k vertices are candidates (the caller then uses the
// exact coordinates). x on a vertex or triangle gives that vertex or the barycentric coordinates.
bool calc_clustered_weights(const TriMesh& mesh, const ClusteredSurface& cs, const Vec3& x, double eps,
                            double ratio, int k, ClusterScratch& s,
                            std::vector<std::pair<int, double>>& out) {
  s.w.resize(mesh.V.rows());
  if (s.covered.size() != static_cast<std::size_t>(mesh.V.rows())) {
    s.w.setZero();
    s.covered.assign(static_cast<std::size_t>(mesh.V.rows()), 0);
  }
  s.touched.clear();
  out.clear();
  // d_k: the distance of x's k-th nearest vertex. Every cluster with a corner within 2 d_k of x is
  // near (so x's k nearest vertices, and any vertex up to 2 d_k away, have all their triangles
  // summed exactly and are candidates).
  s.distance2.resize(static_cast<std::size_t>(k));
  s.nearest.resize(static_cast<std::size_t>(k));
  const std::size_t found = cs.tree->knnSearch(x.data(), static_cast<std::size_t>(k), s.nearest.data(), s.distance2.data());
  if (found < static_cast<std::size_t>(k)) return false;
  const double near_m = 2.0 * std::sqrt(*std::max_element(s.distance2.begin(), s.distance2.end()));
  double far = 0.0;
  bool on_surface = false;
  const auto is_far = [&](const FarField& f, Vec3& y) {
    y = f.centre - x;
    const double reach = std::max(ratio * f.radius, f.radius + near_m);
    return y.squaredNorm() > reach * reach;
  };
  for (const ClusterGroup& group : cs.groups) {
    Vec3 y;
    if (is_far(group.far, y)) {
      far += calc_far_field_sum(group.far, y);
      continue;
    }
    for (int ci = group.first; ci < group.last && !on_surface; ++ci) {
      const FaceCluster& c = cs.clusters[static_cast<std::size_t>(ci)];
      if (is_far(c.far, y)) {
        far += calc_far_field_sum(c.far, y);
        continue;
      }
      const Eigen::Index nl = c.local.V.rows();
      if (s.local_w.size() < nl) s.local_w.resize(std::max(nl, 2 * s.local_w.size()));
      s.local_w.head(nl).setZero();
      if (accumulate_mean_value_weights(c.local, c.table, x, eps, s.mvc, s.local_w.head(nl))) {
        // x on a vertex or triangle of this cluster: those coordinates are the answer
        for (int g : s.touched) {
          s.w[g] = 0.0;
          s.covered[static_cast<std::size_t>(g)] = 0;
        }
        s.touched.clear();
        for (Eigen::Index l = 0; l < nl; ++l)
          if (s.local_w[l] != 0.0) out.emplace_back(c.vertex[static_cast<std::size_t>(l)], s.local_w[l]);
        std::sort(out.begin(), out.end());
        on_surface = true;
        break;
      }
      for (std::size_t l = 0; l < c.vertex.size(); ++l) {
        const int g = c.vertex[l];
        if (s.covered[static_cast<std::size_t>(g)] == 0) s.touched.push_back(g);
        s.covered[static_cast<std::size_t>(g)] += c.faces_at[l];
        s.w[g] += s.local_w[static_cast<Eigen::Index>(l)];
      }
    }
    if (on_surface) break;
  }
  if (on_surface) return true;
  double sum = far;
  for (int g : s.touched) sum += s.w[g];
  for (int g : s.touched) {
    if (s.covered[static_cast<std::size_t>(g)] == cs.valence[static_cast<std::size_t>(g)])
      out.emplace_back(g, s.w[g]);
    s.w[g] = 0.0;
    s.covered[static_cast<std::size_t>(g)] = 0;
  }
  if (!(std::abs(sum) > 0.0) || !std::isfinite(sum))
    throw_numerical("mean-value coordinates undefined (point far outside or degenerate surface)");
  if (static_cast<int>(out.size()) < k) return false;
  // the k largest |w| (ties: the lower vertex), in vertex order, normalised
  std::nth_element(out.begin(), out.begin() + (k - 1), out.end(), [](const auto& a, const auto& b) {
    return std::abs(a.second) > std::abs(b.second) || (std::abs(a.second) == std::abs(b.second) && a.first < b.first);
  });
  out.resize(static_cast<std::size_t>(k));
  std::sort(out.begin(), out.end());
  for (auto& [g, v] : out) v /= sum;
  return true;
}

// Corrects the coordinates `kept` (vertex, weight) of x with the minimum-norm change so that
// sum w = 1 and sum w_j v_j = x (as truncate_affine does after its selection).
std::vector<std::pair<int, double>> correct_affine(const TriMesh& mesh, const Vec3& x,
                                                   const std::vector<std::pair<int, double>>& kept) {
  const int m = static_cast<int>(kept.size());
  VecX wk(m);
  Eigen::MatrixXd A(4, m);
  double scale = 0.0;
  for (int j = 0; j < m; ++j) scale = std::max(scale, (mesh.V.row(kept[j].first).transpose() - x).norm());
  if (!(scale > 0.0)) return kept;  // x is the one kept vertex
  for (int j = 0; j < m; ++j) {
    wk[j] = kept[j].second;
    A.block<3, 1>(0, j) = (mesh.V.row(kept[j].first).transpose() - x) / scale;
    A(3, j) = 1.0;
  }
  const Vec4 r = Vec4(0, 0, 0, 1) - A * wk;
  wk += A.completeOrthogonalDecomposition().solve(r);
  std::vector<std::pair<int, double>> out;
  for (int j = 0; j < m; ++j)
    if (wk[j] != 0.0) out.emplace_back(kept[j].first, wk[j]);
  return out;
}

}  // namespace

VecX calc_mean_value_coordinates(const TriMesh& mesh, const Vec3& x) {
  MvcScratch scratch;
  return calc_mean_value_coordinates(mesh, make_edge_table(mesh.F), x, scratch);
}

FibreEmbedding embed_fibres(const SurfaceBinding& binding, const std::vector<Points3>& fibres,
                            const FibreEmbeddingOptions& options) {
  const TriMesh& rest_surface = binding.rest;
  FibreEmbedding e;
  std::vector<Vec3> points;
  e.fibre_start.push_back(0);
  for (const Points3& f : fibres) {
    if (!f.allFinite()) throw_bad_input("fibre has non-finite points");
    for (Eigen::Index i = 0; i < f.rows(); ++i) points.push_back(f.row(i).transpose());
    e.fibre_start.push_back(static_cast<int>(points.size()));
  }
  std::vector<std::vector<std::pair<int, double>>> rows(points.size());
  // The whole surface's edge table is needed only for points summed over every triangle (all of
  // them without the far-field sums, else the rare point with too few candidates).
  std::once_flag table_once;
  EdgeTable table;
  const auto get_table = [&]() -> const EdgeTable& {
    std::call_once(table_once, [&] { table = make_edge_table(rest_surface.F); });
    return table;
  };
  // The far-field sums pay off only with truncation and enough clusters.
  const int k = options.max_weights;
  const bool clustered = options.far_field_ratio > 0.0 && k > 0 && options.cluster_size > 0 &&
                         rest_surface.F.rows() >= 16 * static_cast<Eigen::Index>(options.cluster_size) &&
                         k < rest_surface.V.rows();
  const ClusteredSurface clusters =
      clustered ? make_clustered_surface(rest_surface, options.cluster_size) : ClusteredSurface{};
  const double eps = 1e-12 * (rest_surface.V.colwise().maxCoeff() - rest_surface.V.colwise().minCoeff()).norm();
  // in blocks of points, each with its own work arrays (results do not depend on the blocking)
  constexpr std::size_t kBlock = 16;
  parallel_for((points.size() + kBlock - 1) / kBlock, [&](std::size_t block) {
    MvcScratch scratch;
    ClusterScratch cluster_scratch;
    std::vector<std::pair<int, double>> kept;
    for (std::size_t p = block * kBlock; p < std::min(points.size(), (block + 1) * kBlock); ++p) {
      if (clustered && calc_clustered_weights(rest_surface, clusters, points[p], eps, options.far_field_ratio, k,
                                              cluster_scratch, kept)) {
        rows[p] = correct_affine(rest_surface, points[p], kept);
        continue;
      }
      const VecX w = calc_mean_value_coordinates(rest_surface, get_table(), points[p], scratch);
      rows[p] = truncate_affine(rest_surface, points[p], w, options.max_weights);
    }
  });
  std::vector<Eigen::Triplet<double>> t;
  for (std::size_t p = 0; p < rows.size(); ++p)
    for (const auto& [j, v] : rows[p]) t.emplace_back(static_cast<int>(p), j, v);
  e.weights.resize(static_cast<Eigen::Index>(points.size()), rest_surface.V.rows());
  e.weights.setFromTriplets(t.begin(), t.end());

  // binding to the rest action line, as for the surface vertices
  const Eigen::Index np = static_cast<Eigen::Index>(points.size());
  e.point_s.resize(np);
  e.point_offset_local.resize(np, 3);
  for (Eigen::Index p = 0; p < np; ++p) {
    e.point_s[p] = find_closest_line_parameter(binding.rest_line, points[p]).s;
    const LinePoint lp = calc_line_point(binding.rest_line, e.point_s[p]);
    e.point_offset_local.row(p) = (lp.frame.conjugate() * (points[p] - lp.point)).transpose();
  }
  return e;
}

namespace {

std::vector<Points3> split_fibres(const FibreEmbedding& embedding, const Points3& P) {
  std::vector<Points3> out;
  for (std::size_t f = 0; f + 1 < embedding.fibre_start.size(); ++f)
    out.emplace_back(P.middleRows(embedding.fibre_start[f],
                                  embedding.fibre_start[f + 1] - embedding.fibre_start[f]));
  return out;
}

}  // namespace

std::vector<Points3> calc_embedded_fibres_mvc(const FibreEmbedding& embedding, const Points3& V) {
  return split_fibres(embedding, embedding.weights * V);
}

std::vector<Points3> calc_embedded_fibres(const FibreEmbedding& embedding,
                                          const SurfaceFirstSolver& solver) {
  const FramedLine& line = solver.get_line();
  if (line.num_samples() < 2 || solver.get_skinned_vertices().rows() != embedding.weights.cols())
    throw_usage("calc_embedded_fibres needs a solver that has solved a frame of this muscle");
  // P = weights * (X - S): row p sums w_pj (x_j - s_j) over the row's entries in column order,
  // as Eigen's row-major product on the evaluated difference does, in one pass for x, y and z
  // over the difference stored interleaved (one cache line per vertex instead of six)
  const Points3& X = solver.get_vertices();
  const Points3& S = solver.get_skinned_vertices();
  const Eigen::Index n = X.rows();
  std::vector<double> residual(static_cast<std::size_t>(3 * n));
  for (Eigen::Index i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) residual[static_cast<std::size_t>(3 * i + c)] = X(i, c) - S(i, c);
  Points3 P(embedding.weights.rows(), 3);
  for (Eigen::Index p = 0; p < P.rows(); ++p) {
    double s0 = 0.0, s1 = 0.0, s2 = 0.0;
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(embedding.weights, p); it; ++it) {
      const double w = it.value();
      const double* d = residual.data() + 3 * static_cast<std::size_t>(it.index());
      s0 += w * d[0];
      s1 += w * d[1];
      s2 += w * d[2];
    }
    P(p, 0) = s0;
    P(p, 1) = s1;
    P(p, 2) = s2;
  }
  const LinePointInterpolator line_point(line);
  for (Eigen::Index p = 0; p < P.rows(); ++p) {
    const LinePoint lp = line_point(embedding.point_s[p]);
    P.row(p) += (lp.point + lp.frame * Vec3(embedding.point_offset_local.row(p).transpose())).transpose();
  }
  return split_fibres(embedding, P);
}

namespace {

// The framed line's segments, for find_closest_line_parameter's result found with pruning.
struct LineSegments {
  std::vector<Vec3> start, direction, centre;
  std::vector<double> squared_length, radius;
  // Runs of kGroup consecutive segments with a sphere holding all of their spheres.
  static constexpr int kGroup = 8;
  std::vector<Vec3> group_centre;
  std::vector<double> group_radius;
  explicit LineSegments(const FramedLine& line) {
    for (int k = 0; k + 1 < line.num_samples(); ++k) {
      const Vec3 a = line.points.row(k).transpose();
      const Vec3 d = line.points.row(k + 1).transpose() - a;
      start.push_back(a);
      direction.push_back(d);
      centre.push_back(a + 0.5 * d);
      squared_length.push_back(d.squaredNorm());
      radius.push_back(0.5 * d.norm());
    }
    for (int g = 0; g < size(); g += kGroup) {
      const int end = std::min(size(), g + kGroup);
      const Vec3 c = 0.5 * (start[g] + start[end - 1] + direction[end - 1]);
      double r = 0.0;
      for (int k = g; k < end; ++k) r = std::max(r, (centre[k] - c).norm() + radius[k]);
      group_centre.push_back(c);
      group_radius.push_back(r * (1.0 + 1e-12));
    }
  }
  int size() const { return static_cast<int>(start.size()); }
  // squared distance from p to segment k and its parameter u (the same arithmetic as
  // find_closest_line_parameter)
  double calc_squared_distance(int k, const Vec3& p, double& u) const {
    const double dd = squared_length[k];
    u = dd > 0.0 ? std::clamp((p - start[k]).dot(direction[k]) / dd, 0.0, 1.0) : 0.0;
    return (start[k] + u * direction[k] - p).squaredNorm();
  }
};

// find_closest_line_parameter(line, p).s with the same result (the first segment, in order, of
// the smallest squared distance): segment `hint` is tried first, and a segment is skipped when
// its bounding sphere is farther than the best distance so far (it cannot be closer or equal).
// Runs of segments whose common sphere is that far are skipped as a whole (the same test).
double find_closest_line_fraction(const LineSegments& segments, const Vec3& p, int& hint) {
  const int n = segments.size();
  double best_u = 0.0;
  int best_k = std::clamp(hint, 0, n - 1);
  double best_d2 = segments.calc_squared_distance(best_k, p, best_u);
  for (int k = 0; k < n; ++k) {
    if (k % LineSegments::kGroup == 0) {
      const int g = k / LineSegments::kGroup;
      const double reach = std::sqrt(best_d2) + segments.group_radius[g];
      if ((segments.group_centre[g] - p).squaredNorm() > reach * reach * (1.0 + 1e-9)) {
        k += LineSegments::kGroup - 1;
        continue;
      }
    }
    if (k == hint) continue;
    const double reach = std::sqrt(best_d2) + segments.radius[k];
    // (1 + 1e-9): the bound is not decided by round-off
    if ((segments.centre[k] - p).squaredNorm() > reach * reach * (1.0 + 1e-9)) continue;
    double u = 0.0;
    const double d2 = segments.calc_squared_distance(k, p, u);
    if (d2 < best_d2 || (d2 == best_d2 && k < best_k)) {
      best_d2 = d2;
      best_k = k;
      best_u = u;
    }
  }
  hint = best_k;
  return (best_k + best_u) / n;
}

}  // namespace

FibreMetrics calc_fibre_metrics(const std::vector<Points3>& fibres, const Points3& action_line) {
  const FramedLine line = calc_framed_line(action_line, 64, calc_default_start_frame(action_line));
  const LineSegments segments(line);
  const LinePointInterpolator line_point(line);
  FibreMetrics m;
  const Eigen::Index n = static_cast<Eigen::Index>(fibres.size());
  m.length_m = VecX::Zero(n);
  m.pennation_rad = VecX::Zero(n);
  int hint = 0;  // the closest segment of the previous fibre segment's midpoint
  for (Eigen::Index f = 0; f < n; ++f) {
    const Points3& P = fibres[f];
    double length = 0.0, angle_sum = 0.0;
    for (Eigen::Index i = 0; i + 1 < P.rows(); ++i) {
      const Vec3 seg = (P.row(i + 1) - P.row(i)).transpose();
      const double l = seg.norm();
      if (!(l > 0.0)) continue;
      const Vec3 mid = 0.5 * (P.row(i) + P.row(i + 1)).transpose();
      const Vec3 t = line_point(find_closest_line_fraction(segments, mid, hint)).frame * Vec3::UnitX();
      angle_sum += l * std::acos(std::min(1.0, std::abs(t.dot(seg) / l)));
      length += l;
    }
    m.length_m[f] = length;
    m.pennation_rad[f] = length > 0.0 ? angle_sum / length : 0.0;
  }
  if (n > 0) {
    m.mean_length_m = m.length_m.mean();
    m.mean_pennation_rad = m.pennation_rad.mean();
  }
  return m;
}

}  // namespace fascicle
