// Fibres-first solver: per frame, projective dynamics (local/global) on the particle springs with
// the volume held by a Lagrange multiplier, bone and muscle contacts as stiff targets, and optional
// backward-Euler dynamics (see fibres_first.hpp and docs/representations.md).
#include "fascicle/deformation/fibres_first.hpp"
#include "point_tree.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/deformation/mesh_operators.hpp"
#include "fascicle/sparse/cholmod_view.hpp"
#include "fascicle/sparse/simplicial_solve.hpp"

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <cholmod.h>

#include <algorithm>
#include <unordered_map>
#include <cmath>
#include <fmt/format.h>
#include <array>
#include <unordered_set>

namespace fascicle {

namespace {

ErrorContext frame_context(const std::string& name, std::string suggestion = {}) {
  return {.object = name, .suggestion = std::move(suggestion)};
}

using detail::PointCloud;
using detail::PointTree;

using SurfaceMap = Eigen::SparseMatrix<double, Eigen::RowMajor>;

// The display surface's vertex weights of muscle m as a #vertices x #particles-of-m matrix W:
// surface vertices = W x_m (muscle-local particle rows).
SurfaceMap make_surface_map(const FibreBundle& m) {
  std::vector<Eigen::Triplet<double>> t;
  for (int v = 0; v < m.num_surface_vertices(); ++v)
    for (int k = m.surface_weight_start[v]; k < m.surface_weight_start[v + 1]; ++k)
      t.emplace_back(v, m.surface_weight_particle[k] - m.first_particle, m.surface_weight[k]);
  SurfaceMap W(std::max(0, m.num_surface_vertices()), m.num_particles);
  W.setFromTriplets(t.begin(), t.end());
  return W;
}

double surface_volume(const FibreBundle& m, const Points3& S) {
  return calc_enclosed_volume(S, m.surface_triangles, S.colwise().mean().transpose());
}

// dV/dx per particle of muscle m (xm, gradient: muscle-local rows): the surface gradient carried
// back through the vertex weights, W^T dV/dS.
Points3 calc_particle_volume_gradient(const FibreBundle& m, const SurfaceMap& W, const Points3& xm) {
  const Points3 S = W * xm;
  return W.transpose() * calc_volume_gradient(S, m.surface_triangles);
}

// Moves the muscle's particles xm (muscle-local rows) to xm + t Y with t the root of the cubic
// V(t) = V0 nearest to the linearised one (the exact volume along the line). Returns t (NaN: none).
// Sy = W Y: the direction's surface image (kept with Y, which changes once per contact round).
double hold_volume_along(const FibreBundle& m, const SurfaceMap& W, Points3& xm, const Points3& Y,
                         const Points3& Sy) {
  const Points3 Sx = W * xm;
  const Vec3 centre = Sx.colwise().mean().transpose();
  const double t = solve_volume_cubic(calc_volume_cubic(Sx, Sy, m.surface_triangles, centre),
                                      m.rest_volume_m3);
  if (std::isfinite(t)) xm += t * Y;
  return t;
}

}  // namespace

// Right-hand sides of the global step stored by rows: per free particle its x, y, z (and the
// volume gradient's three components on a round's first iteration) side by side, padded to 4 or
// 8 doubles, the layout of the simplicial solve's rows (sparse/simplicial_solve.hpp).
using RowRhs = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// A sparse LDL^T factor (CHOLMOD simplicial, AMD ordering) that can be modified by rank-k
// updates/downdates (Davis and Hager 1999, cholmod_updown): adding or removing contact weights on
// the diagonal costs a small fraction of a new factorisation. One CHOLMOD workspace per factor,
// so factors of different muscles can be used from different threads.
class LdlFactor {
 public:
  LdlFactor() {
    cholmod_start(&c_);
    c_.supernodal = CHOLMOD_SIMPLICIAL;
    c_.final_ll = 0;
    // the fill-reducing ordering with the fewest flops among AMD and METIS nested dissection
    // (a particle lattice is a fibre chain times a cross-section graph: nested dissection often
    // wins there)
    c_.nmethods = 2;
    c_.method[0].ordering = CHOLMOD_AMD;
    c_.method[1].ordering = CHOLMOD_METIS;
    c_.print = 0;
  }
  ~LdlFactor() {
    if (X_) cholmod_free_dense(&X_, &c_);
    if (Y_) cholmod_free_dense(&Y_, &c_);
    if (E_) cholmod_free_dense(&E_, &c_);
    if (L_) cholmod_free_factor(&L_, &c_);
    cholmod_finish(&c_);
  }
  LdlFactor(const LdlFactor&) = delete;
  LdlFactor& operator=(const LdlFactor&) = delete;

  bool is_analysed() const { return L_ != nullptr; }

  // K: symmetric, lower triangle stored, compressed. False when not positive definite.
  bool factorise(SparseMatrix& K) {
    cholmod_sparse A = view_symmetric_lower(static_cast<std::size_t>(K.rows()), static_cast<std::size_t>(K.nonZeros()),
                                            K.outerIndexPtr(), K.innerIndexPtr(), K.valuePtr());
    if (!L_) {
      {
        const std::lock_guard lock(get_ordering_mutex());  // AMD or METIS (shared GKlib state)
        L_ = cholmod_analyze(&A, &c_);
      }
      if (!L_) return false;
      const int* perm = static_cast<const int*>(L_->Perm);
      position_.resize(K.rows());
      for (Eigen::Index r = 0; r < K.rows(); ++r) position_[perm[r]] = static_cast<int>(r);
    }
    const bool ok = cholmod_factorize(&A, L_, &c_) && c_.status == CHOLMOD_OK && L_->minor == L_->n;
    own_solve_.forget_pattern();  // the solve's copy of L's row indices is made again
    return ok;
  }

  // K += sum_j delta_j e_j e_j^T (update when all deltas > 0, downdate when all < 0).
  bool modify_diagonal(bool update, const std::vector<std::pair<int, double>>& changes) {
    if (changes.empty()) return true;
    const std::size_t k = changes.size();
    cholmod_sparse* C = cholmod_allocate_sparse(L_->n, k, k, 1, 1, 0, CHOLMOD_REAL, &c_);
    if (!C) return false;
    auto* cp = static_cast<int*>(C->p);
    auto* ci = static_cast<int*>(C->i);
    auto* cx = static_cast<double*>(C->x);
    for (std::size_t j = 0; j < k; ++j) {
      cp[j] = static_cast<int>(j);
      ci[j] = position_[changes[j].first];  // rows of C in the factor's permuted order
      cx[j] = std::sqrt(std::abs(changes[j].second));
    }
    cp[k] = static_cast<int>(k);
    const bool ok = cholmod_updown(update ? 1 : 0, C, L_, &c_) && c_.status == CHOLMOD_OK;
    cholmod_free_sparse(&C, &c_);
    return ok;
  }

  // Solves K X = B in place for B stored by rows (RowRhs: n rows of 4 doubles for up to four
  // columns, 8 for up to eight; `ncols` of them used): through the simplicial kernel, or CHOLMOD's
  // solve on a column copy when the kernel cannot apply it. The same bits as solve() on the
  // columns.
  void solve_rows(RowRhs& B, int ncols) {
    if (solve_simplicial_ldlt_rows(L_, B.data(), ncols, static_cast<int>(B.cols()), own_solve_)) return;
    Eigen::MatrixXd columns = B.leftCols(ncols);
    solve(columns);
    B.leftCols(ncols) = columns;
  }

  // Per unknown: its row in the factor's order (valid once analysed).
  const std::vector<int>& get_positions() const { return position_; }

  // solve_rows for B whose row get_positions()[j] holds unknown j (the factor's order), in place.
  void solve_factor_rows(RowRhs& B, int ncols) {
    if (solve_simplicial_ldlt_in_factor_order(L_, B.data(), ncols, static_cast<int>(B.cols()), own_solve_)) return;
    RowRhs natural(B.rows(), B.cols());
    for (Eigen::Index j = 0; j < B.rows(); ++j) natural.row(j) = B.row(position_[j]);
    solve_rows(natural, ncols);
    for (Eigen::Index j = 0; j < B.rows(); ++j) B.row(position_[j]) = natural.row(j);
  }

  // Solves K X = B in place (B: n x any columns). Up to eight columns go through
  // fascicle/sparse's simplicial kernel in one pass over the factor (the same bits as CHOLMOD's
  // solve, which takes four columns per pass); more through cholmod_solve2, whose solution and
  // workspaces are kept between calls. Either way a solve allocates nothing once warm.
  void solve(Eigen::MatrixXd& B) {
    if (solve_simplicial_ldlt(L_, B.data(), static_cast<int>(B.cols()), static_cast<int>(B.rows()),
                              own_solve_))
      return;
    cholmod_dense b{};
    b.nrow = static_cast<std::size_t>(B.rows());
    b.ncol = static_cast<std::size_t>(B.cols());
    b.nzmax = b.nrow * b.ncol;
    b.d = b.nrow;
    b.x = B.data();
    b.xtype = CHOLMOD_REAL;
    b.dtype = CHOLMOD_DOUBLE;
    if (!cholmod_solve2(CHOLMOD_A, L_, &b, nullptr, &X_, nullptr, &Y_, &E_, &c_) || !X_) {
      B.setConstant(std::numeric_limits<double>::quiet_NaN());
      return;
    }
    B = Eigen::Map<const Eigen::MatrixXd>(static_cast<const double*>(X_->x), B.rows(), B.cols());
  }

 private:
  cholmod_common c_;
  cholmod_factor* L_ = nullptr;
  cholmod_dense *X_ = nullptr, *Y_ = nullptr, *E_ = nullptr;  // cholmod_solve2 workspaces
  SimplicialSolveWorkspace own_solve_;
  std::vector<int> position_;  // per unknown: its row in the permuted factor
};

// A spring as the local step reads it: its ends as free-particle indices of the muscle (-1: fixed)
// and as model particle indices.
struct LocalSpring {
  int a = -1, b = -1;    // free index or -1
  int pa = -1, pb = -1;  // model particle index
  double k = 0.0, rest_length = 0.0;
};

// The local step's spring vectors, d = L0 (x_a - x_b) / |x_a - x_b| (the rest vector x_a - x_b
// at rest for a degenerate spring, |x_a - x_b| <= 1e-15), of `count` springs from positions
// (sx, sy, sz), into d (x, y, z per spring). Four springs at a time: the square roots and
// divisions, which bound the scalar loop, run on vector lanes; each lane is the same IEEE
// operation as the scalar code, so d has the same bits ((dx dx + dy dy) + dz dz, then the root,
// then L0 / len, then the products).
namespace spring_vectors {
using V4d = double __attribute__((vector_size(32), aligned(8)));
using V4l = long long __attribute__((vector_size(32)));

// Lane-wise square roots in place: one AVX instruction, or four scalar ones (same results).
struct SqrtAvx {
  __attribute__((target("avx2"))) static inline void apply(V4d& v) {
    v = __builtin_ia32_sqrtpd256(v);
  }
};
struct SqrtScalar {
  [[gnu::always_inline]] static inline void apply(V4d& v) {
    for (int l = 0; l < 4; ++l) v[l] = std::sqrt(v[l]);
  }
};

template <class Sqrt>
[[gnu::always_inline]] inline void calc_body(const LocalSpring* sp, int count, const double* sx,
                                             const double* sy, const double* sz, const Points3& rest,
                                             double* d) {
  int s = 0;
  for (; s + 4 <= count; s += 4) {
    V4d dx, dy, dz, L0;
    for (int l = 0; l < 4; ++l) {
      const LocalSpring& q = sp[s + l];
      dx[l] = sx[q.pa] - sx[q.pb];
      dy[l] = sy[q.pa] - sy[q.pb];
      dz[l] = sz[q.pa] - sz[q.pb];
      L0[l] = q.rest_length;
    }
    V4d len = (dx * dx + dy * dy) + dz * dz;
    Sqrt::apply(len);
    const V4d scale = L0 / len;
    const V4l ok = len > 1e-15;
    dx = dx * scale;
    dy = dy * scale;
    dz = dz * scale;
    for (int l = 0; l < 4; ++l) {
      double* out = d + 3 * (s + l);
      if (ok[l]) {
        out[0] = dx[l];
        out[1] = dy[l];
        out[2] = dz[l];
      } else {
        const LocalSpring& q = sp[s + l];
        for (int c = 0; c < 3; ++c) out[c] = rest(q.pa, c) - rest(q.pb, c);
      }
    }
  }
  for (; s < count; ++s) {
    const LocalSpring& q = sp[s];
    double dx = sx[q.pa] - sx[q.pb], dy = sy[q.pa] - sy[q.pb], dz = sz[q.pa] - sz[q.pb];
    const double len = std::sqrt(dx * dx + dy * dy + dz * dz);
    double* out = d + 3 * s;
    if (len > 1e-15) {
      const double scale = q.rest_length / len;
      out[0] = dx * scale;
      out[1] = dy * scale;
      out[2] = dz * scale;
    } else {
      for (int c = 0; c < 3; ++c) out[c] = rest(q.pa, c) - rest(q.pb, c);
    }
  }
}

__attribute__((target("avx2"))) void calc_avx2(const LocalSpring* sp, int count, const double* sx,
                                               const double* sy, const double* sz,
                                               const Points3& rest, double* d) {
  calc_body<SqrtAvx>(sp, count, sx, sy, sz, rest, d);
}
void calc_generic(const LocalSpring* sp, int count, const double* sx, const double* sy,
                  const double* sz, const Points3& rest, double* d) {
  calc_body<SqrtScalar>(sp, count, sx, sy, sz, rest, d);
}
// Adds k d (a spring's term of the right-hand side) to its ends' rows of B (rows of `width`
// doubles, x y z in lanes 0-2; free particle j in row position[j]): +k d to a's row, -k d to b's; a fixed end's position moves to
// the other end's term (a's row gets k (d + x_b), b's row k (x_a - d)). Per lane these are the
// scalar code's operations (d + x, then the product, then the sum; -d is an exact negation), so
// the rows get the bits of three separate columns; lane 3 gets +0.
template <class Sqrt>
[[gnu::always_inline]] inline void add_to_rows_body(const LocalSpring* sp, int count, const double* d,
                                                    const double* sx, const double* sy, const double* sz,
                                                    const int* position, double* rows, int width) {
  using V4u = double __attribute__((vector_size(32), aligned(8), may_alias));
  auto row = [rows, width, position](int j) {
    return reinterpret_cast<V4u*>(rows + static_cast<std::ptrdiff_t>(position[j]) * width);
  };
  for (int s = 0; s < count; ++s) {
    const LocalSpring& q = sp[s];
    const V4d v = {d[3 * s], d[3 * s + 1], d[3 * s + 2], 0.0};
    const double k = q.k;
    if (q.a >= 0) {
      const V4d t = q.b >= 0 ? v : v + V4d{sx[q.pb], sy[q.pb], sz[q.pb], 0.0};
      *row(q.a) = *row(q.a) + k * t;
    }
    if (q.b >= 0) {
      const V4d t = q.a >= 0 ? -v : V4d{sx[q.pa], sy[q.pa], sz[q.pa], 0.0} - v;
      *row(q.b) = *row(q.b) + k * t;
    }
  }
}
__attribute__((target("avx2"))) void add_to_rows_avx2(const LocalSpring* sp, int count, const double* d,
                                                      const double* sx, const double* sy, const double* sz,
                                                      const int* position, double* rows, int width) {
  add_to_rows_body<SqrtAvx>(sp, count, d, sx, sy, sz, position, rows, width);
}
void add_to_rows_generic(const LocalSpring* sp, int count, const double* d, const double* sx,
                         const double* sy, const double* sz, const int* position, double* rows, int width) {
  add_to_rows_body<SqrtScalar>(sp, count, d, sx, sy, sz, position, rows, width);
}

void calc(const LocalSpring* sp, int count, const double* sx, const double* sy, const double* sz,
          const Points3& rest, double* d) {
  static const bool avx2 = [] {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") != 0;
  }();
  (avx2 ? calc_avx2 : calc_generic)(sp, count, sx, sy, sz, rest, d);
}
void add_to_rows(const LocalSpring* sp, int count, const double* d, const double* sx, const double* sy,
                 const double* sz, const int* position, double* rows, int width) {
  static const bool avx2 = [] {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") != 0;
  }();
  (avx2 ? add_to_rows_avx2 : add_to_rows_generic)(sp, count, d, sx, sy, sz, position, rows, width);
}
}  // namespace spring_vectors

// Anderson acceleration of a fixed-point map x -> G(x) (Walker and Ni 2011; used for projective
// dynamics by Peng et al. 2018): the next iterate is G(x_k) - dG gamma, with gamma minimising
// |f_k - dF gamma| over the last `window` differences of the residuals f = G(x) - x (dF) and of
// the map's values (dG). Restarted when the residual grows (the safeguard) and at every contact
// round (the map changes with the contacts).
struct Anderson {
  Eigen::MatrixXd dF, dG;  // n x window, used as a ring
  VecX f_previous, g_previous;
  int count = 0, next = 0;
  bool has_previous = false;
  double best_step = std::numeric_limits<double>::infinity();
  void restart() {
    count = next = 0;
    has_previous = false;
    best_step = std::numeric_limits<double>::infinity();
  }
  // x: the iterate the map was applied to, g = G(x) (both n); `step` its stopping measure.
  // Returns the next iterate.
  VecX calc_next(const VecX& x, const VecX& g, double step, int window) {
    if (window <= 0) return g;
    if (step > 2.0 * best_step) restart();  // safeguard: the mixed iterate made things worse
    best_step = std::min(best_step, step);
    const VecX f = g - x;
    if (dF.rows() != f.size() || dF.cols() != window) {
      dF.resize(f.size(), window);
      dG.resize(f.size(), window);
      count = next = 0;
    }
    if (has_previous) {
      dF.col(next) = f - f_previous;
      dG.col(next) = g - g_previous;
      next = (next + 1) % window;
      count = std::min(count + 1, window);
    }
    f_previous = f;
    g_previous = g;
    has_previous = true;
    if (count == 0) return g;
    const auto F = dF.leftCols(count);
    Eigen::MatrixXd normal = F.transpose() * F;
    normal.diagonal().array() += 1e-12 * std::max(normal.trace(), 1e-300);
    const VecX gamma = normal.ldlt().solve(F.transpose() * f);
    if (!gamma.allFinite()) {
      restart();
      return g;
    }
    return g - dG.leftCols(count) * gamma;
  }
};

// Ring frames (FibresFirstOptions::surface_frame_stiffness): per loft ring, the rest centre of
// the fibre particles anchoring it and its last fitted rotation (the next fit's warm start).
struct RingFrames {
  std::vector<Vec3> rest_centre;
  std::vector<Quat> rotation;
};

// One muscle's linear system: K = sum_springs k A^T A (free rows) + m/h^2 I (dynamic) + contact
// weights on the diagonal (+ the ring frames' constant diagonal); factorised numerically again
// only when the contact or mass terms change.
struct MuscleSystem {
  RingFrames rings;
  std::vector<LocalSpring> springs;
  Anderson anderson;
  Eigen::MatrixXd plain;  // G(x) of the last iteration, free rows (nf x 3)
  SparseMatrix K_springs;
  SparseMatrix K;
  std::vector<Eigen::Index> diag;  // position of K(j, j) in K.valuePtr()
  LdlFactor factor;
  bool valid = false;
  int modifications = 0;  // rank-one modifications since the last full factorisation
  std::vector<double> factored_weight;  // per free particle
  double factored_mass_term = 0.0;
  std::vector<double> weight;  // per free particle: contact weight wanted this iteration
  // -K^-1 dV/dx (muscle-local rows, zero on fixed particles): the volume-correction direction,
  // refreshed on the first iteration of every contact round
  Points3 volume_direction;
  // display-surface vertices = surface_map * (the muscle's particle rows)
  SurfaceMap surface_map;
  Points3 volume_direction_surface;  // surface_map * volume_direction
};

struct MusclePair {
  int p = -1, q = -1;
  double allowed_m = 0.0;
};

// Candidate pairs of contact particles of different muscles (a Verlet list, Verlet 1967): every
// pair closer than muscle_margin_m + skin when the list was built. The list is rebuilt only once
// some contact particle has moved more than skin/2 since then, so every pair closer than the
// margin now is in it; between rebuilds a detection is one pass over the list instead of a k-d
// tree build and one radius query per particle.
//
// Partial rebuilds (since session 13): each contact particle has its own reference position
// (built_at), and the list holds every pair of different muscles whose reference positions are
// within margin + skin. When only a few particles (the movers) have moved more than skin/2 from
// theirs, only the movers get new references and new pairs: their old pairs are dropped, and
// each mover's new partners are found in the k-d tree of the last full build (the particles
// whose reference has not changed since) and in a small k-d tree of the particles whose
// reference has. Pairs between other particles keep their references and stay right, so the
// list still holds every pair closer than the margin now, and a detection (which reads the list
// in (p, q) order) finds the same pairs as after a full rebuild. A full rebuild once more than
// an eighth of the particles have new references.
struct PairCandidates {
  std::vector<int> ids;          // contact particles of all muscles (model indices)
  Points3 built_at;              // their reference positions (#ids x 3)
  std::vector<MusclePair> list;  // p < q, allowed = min(margin, rest distance), sorted by (p, q)
  bool valid = false;
  int builds = 0;                // full rebuilds since the solver was made (diagnostics)
  int partial_builds = 0;        // partial rebuilds (diagnostics)
  // the last full build: its reference positions, their k-d tree, and the particles (positions
  // in ids) whose reference has changed since
  Points3 full_at;
  std::unique_ptr<PointCloud> full_cloud;
  std::unique_ptr<PointTree> full_tree;
  std::vector<Eigen::Index> rereferenced;
  std::vector<char> is_rereferenced;  // per position in ids
};

// A display-surface contact: vertex v of muscle a against the point of triangle `triangle` of
// muscle b's display surface with barycentric coordinates `barycentric` (the closest point when
// detected). Its gap is (s_v - c) . n, n the triangle's current outward unit normal; it must stay
// >= min_gap.
struct SurfaceContact {
  int a = -1, v = -1, b = -1, triangle = -1;
  Vec3 barycentric = Vec3::Zero();
  double min_gap = 0.0;
  // The contact's direction n (the way out of b's surface) in the frame of its face
  // (calc_face_frame): (0, 0, 1) is the face's normal. Set at detection from the closest-point
  // direction, so it stays right where the closest point is on an edge or vertex of a folded
  // face (see calc_contact_direction), and turns with the face between detections.
  Vec3 direction = Vec3::UnitZ();
};

// A push's smooth displacement field around one display vertex: (particle, phi) pairs.
struct PushKernel {
  bool built = false;
  std::vector<std::pair<int, double>> entries;
};

// Display-surface separation state (see FibresFirstOptions::separate_surfaces).
struct SurfaceSeparation {
  bool enabled = false;
  std::vector<std::unique_ptr<MeshQuery>> query;  // per muscle: its current surface (null: none)
  std::vector<Points3> surface;                   // per muscle: the vertices the query holds
  // Per ordered muscle pair a * nm + b: per vertex of a, its signed gap to b's surface at rest
  // (positive outside; empty when a's vertices are all farther than the margin from b at rest),
  // and whether the pair is separated fully (its rest overlap is small) or keeps rest depths.
  std::vector<VecX> rest_gap;
  std::vector<char> resolved;
  // Culling of the vertex tests (like the bones' clearances): the distance of a surface to a
  // point changes by at most the point's displacement plus the largest displacement of the
  // surface's vertices (every point of a triangle is a convex combination of its corners). The
  // bound is exact for the distance; the sign (face side, ray vote beyond 1 mm) can flip on a
  // folded face without the distance passing through 0, which the bound does not see.
  // travel[b]: the sum over the surface updates of b's largest vertex displacement in that
  // update, so travel[b] now - then bounds every displacement of b's surface in between.
  // Per ordered pair a * nm + b, per vertex of a (empty until a is first near b): its gap at its
  // last exact test (-inf: none yet), its position then and travel[b] then.
  std::vector<double> travel;
  std::vector<VecX> tested_gap, tested_travel;
  std::vector<Points3> tested_at;
  // The same bound in b's body frame (the gap does not change when one rigid motion moves both
  // the point and the surface): to_body[b] is the inverse of the rigid motion best fitting b's
  // rest surface to its surface at the last fit (Umeyama 1991), and body_travel[b] the sum over
  // the updates of the largest vertex displacement in that frame (at a refit: the new frame's
  // vertices against the old frame's previous ones), so a muscle that moves rigidly adds
  // nothing. b is refitted only once its world travel since the last fit exceeds
  // body_refit_after_m (in between, the body displacements equal the world ones). Per ordered
  // pair, per vertex of a: its position in b's body frame and body_travel[b] at its last test.
  // A vertex is skipped when either bound keeps it beyond the margin (gait2392: the frame's bone
  // motion, ~20 mm, made the world bound retest nearly every vertex at each frame's start).
  static constexpr double body_refit_after_m = 1e-3;
  std::vector<Points3> rest_surface;
  std::vector<Transform> to_body;
  std::vector<double> body_travel, fitted_travel;
  std::vector<VecX> tested_body_travel;
  std::vector<Points3> tested_body_at;
  std::vector<SurfaceContact> contacts;
  std::unordered_map<long long, int> keys;  // (a, b, v) -> index into contacts
  std::vector<std::vector<PushKernel>> kernels;  // per muscle, per display vertex
};

// Bone contacts, per particle: up to two (a particle where two bone surfaces come closer than
// about twice the margin is held against both; slot 0 is filled first). Targets and normals are
// fixed in the bone's rest frame.
struct BoneContacts {
  static constexpr int slots = 2;
  std::vector<int> bone[slots];  // per particle: the bone, or -1
  std::vector<Vec3> target_rest[slots], normal_rest[slots];
  void clear(int n) {
    for (int s = 0; s < slots; ++s) {
      bone[s].assign(n, -1);
      target_rest[s].assign(n, Vec3::Zero());
      normal_rest[s].assign(n, Vec3::Zero());
    }
  }
  bool has(int p) const { return bone[0][p] >= 0; }
  // The target a particle is pulled to in the global step: its contact's, or the mean of both.
  Vec3 calc_target(int p, const std::vector<Transform>& motions) const {
    Vec3 t = motions[bone[0][p]] * target_rest[0][p];
    if (bone[1][p] >= 0) t = 0.5 * (t + motions[bone[1][p]] * target_rest[1][p]);
    return t;
  }
};

// Whole muscles skipped by the bone detection (since session 13). For muscle m and bone b, after
// a pass over m's free particles, slack = min over them of (clearance - distance moved since the
// last exact test): each particle is culled while it moves less than its clearance, so all of m
// are culled while every particle has moved less than slack since that pass. In b's frame a
// particle moves by at most its world displacement since then (travel: the sum over the
// detections of m's largest displacement) plus what the change of b's motion does to it:
// |X_now^-1 x - X_then^-1 x| <= |E y_c - y_c| + |R_E - I| r for E = X_now^-1 X_then, y_c the
// pass's centre of m's particles in b's frame and r their radius around it. When that bound is
// below slack the pass would cull every particle: it is skipped, with the same results.
struct BoneCull {
  std::vector<double> travel;  // per muscle
  Points3 last_x;              // positions at the last detection (empty: none yet)
  // per muscle * bones + bone, at the last pass
  std::vector<double> slack, travel_then, radius;
  std::vector<Vec3> centre;  // world
  std::vector<Transform> motion;
};

struct FibresFirstSolver::Workspace {
  std::vector<std::unique_ptr<MuscleSystem>> systems;  // per muscle
  BoneContacts bone_contacts;
  std::vector<Points3> checked_at;  // per bone: last exactly tested position (bone rest frame)
  std::vector<VecX> clearance;      // per bone: its distance to the bone then (inside: -depth)
  BoneCull bone_cull;
  std::vector<MusclePair> pairs;
  std::unordered_set<long long> pair_keys;
  PairCandidates candidates;
  SurfaceSeparation surfaces;
  Points3 pair_target;           // per particle: mean pair target this iteration
  std::vector<int> pair_count;   // per particle
  std::vector<int> target_rows;  // the particles whose pair_target and pair_count are non-zero
  Points3 previous, velocity;
  Points3 correction;  // last frame's converged minus guessed positions (0 on non-free rows)
  std::vector<Transform> previous_motions;
  bool has_previous = false;
  int frames = 0;
};

namespace {
void init_surface_separation(const FibresFirstModel& model,
                             const std::vector<std::unique_ptr<MuscleSystem>>& systems,
                             SurfaceSeparation& ss);

// The culling distances at rest (per bone, per particle): the clearance outside, minus the depth
// inside (a particle inside at rest is tested at every detection, and its bounded closest-point
// query must reach the surface at its rest depth).
std::vector<VecX> calc_start_clearance(const FibresFirstModel& model) {
  std::vector<VecX> clearance = model.rest_bone_clearance;
  for (std::size_t b = 0; b < clearance.size(); ++b)
    for (Eigen::Index p = 0; p < clearance[b].size(); ++p)
      if (model.rest_bone_depth[b][p] > 0.0) clearance[b][p] = -model.rest_bone_depth[b][p];
  return clearance;
}
}  // namespace

// A workspace as before the first frame: per-muscle systems with their spring matrices (no factor,
// no contact weights, no acceleration history), no contacts, the surfaces' queries at rest.
std::unique_ptr<FibresFirstSolver::Workspace> make_workspace(const FibresFirstModel& model_) {
  auto ws_ = std::make_unique<FibresFirstSolver::Workspace>();
  FibresFirstSolver::Workspace& ws = *ws_;
  const int N = model_.num_particles();
  for (std::size_t mi = 0; mi < model_.muscles.size(); ++mi) {
    const FibreBundle& m = model_.muscles[mi];
    MuscleSystem& sys = *ws.systems.emplace_back(std::make_unique<MuscleSystem>());
    const int nf = static_cast<int>(m.free.size());
    std::vector<Eigen::Triplet<double>> t;
    for (int j = 0; j < nf; ++j) t.emplace_back(j, j, 0.0);  // every diagonal entry in the pattern
    for (int s = model_.first_spring[mi]; s < model_.first_spring[mi + 1]; ++s) {
      const Spring& sp = model_.springs[s];
      const int a = m.free_index[sp.a - m.first_particle], b = m.free_index[sp.b - m.first_particle];
      if (a >= 0) t.emplace_back(a, a, sp.stiffness);
      if (b >= 0) t.emplace_back(b, b, sp.stiffness);
      if (a >= 0 && b >= 0) {
        t.emplace_back(std::max(a, b), std::min(a, b), -sp.stiffness);
      }
    }
    for (int s = model_.first_spring[mi]; s < model_.first_spring[mi + 1]; ++s) {
      const Spring& sp = model_.springs[s];
      const int a = m.free_index[sp.a - m.first_particle], b = m.free_index[sp.b - m.first_particle];
      if (a < 0 && b < 0) continue;  // between two prescribed particles: adds nothing to any row
      sys.springs.push_back({a, b, sp.a, sp.b, sp.stiffness, sp.rest_length_m});
    }
    // ring frames: the constant diagonal term of each ring vertex (add_ring_frame_targets)
    const double ring_w = model_.options.surface_frame_stiffness;
    if (ring_w > 0.0 && m.num_surface_particles > 0 && m.ring_frame_start.size() > 1) {
      const int s0 = m.first_particle + m.num_fibres * model_.options.particles_per_fibre;
      for (int v = 0; v < m.num_surface_particles; ++v) {
        const int j = m.free_index[s0 + v - m.first_particle];
        t.emplace_back(j, j, ring_w);
      }
      for (std::size_t r = 0; r + 1 < m.ring_frame_start.size(); ++r) {
        Vec3 C = Vec3::Zero();
        for (int k = m.ring_frame_start[r]; k < m.ring_frame_start[r + 1]; ++k)
          C += model_.rest.row(m.ring_frame_particle[k]).transpose();
        sys.rings.rest_centre.push_back(C / (m.ring_frame_start[r + 1] - m.ring_frame_start[r]));
        sys.rings.rotation.push_back(Quat::Identity());
      }
    }
    sys.K_springs.resize(nf, nf);
    sys.K_springs.setFromTriplets(t.begin(), t.end());  // lower triangle only
    sys.K_springs.makeCompressed();
    sys.K = sys.K_springs;
    sys.diag.resize(nf);
    for (int j = 0; j < sys.K.outerSize(); ++j)
      for (SparseMatrix::InnerIterator it(sys.K, j); it; ++it)
        if (it.row() == j) sys.diag[j] = &it.valueRef() - sys.K.valuePtr();
    sys.factored_weight.assign(nf, 0.0);
    sys.surface_map = make_surface_map(m);
    sys.weight.assign(nf, 0.0);
  }
  ws.checked_at.assign(model_.num_bones(), model_.rest);
  ws.clearance = calc_start_clearance(model_);
  {
    const std::size_t nmb = model_.muscles.size() * static_cast<std::size_t>(model_.num_bones());
    ws.bone_cull.travel.assign(model_.muscles.size(), 0.0);
    ws.bone_cull.slack.assign(nmb, -std::numeric_limits<double>::infinity());
    ws.bone_cull.travel_then.assign(nmb, 0.0);
    ws.bone_cull.radius.assign(nmb, 0.0);
    ws.bone_cull.centre.assign(nmb, Vec3::Zero());
    ws.bone_cull.motion.assign(nmb, Transform::Identity());
  }
  ws.bone_contacts.clear(N);
  init_surface_separation(model_, ws.systems, ws.surfaces);
  ws.pair_target = Points3::Zero(N, 3);
  ws.pair_count.assign(N, 0);
  return ws_;
}

FibresFirstSolver::FibresFirstSolver(const FibresFirstModel& model)
    : model_(model), ws_(make_workspace(model)) {
  x_ = model_.rest;
  frames_.resize(model_.muscles.size());
}

FibresFirstSolver::~FibresFirstSolver() = default;
FibresFirstSolver::FibresFirstSolver(FibresFirstSolver&&) noexcept = default;

void FibresFirstSolver::reset() {
  ws_ = make_workspace(model_);
  x_ = model_.rest;
  frames_.assign(model_.muscles.size(), {});
  info_ = {};
}

std::vector<Points3> FibresFirstSolver::calc_fibres(int m) const {
  const FibreBundle& b = model_.muscles.at(m);
  const int P = model_.options.particles_per_fibre;
  std::vector<Points3> out;
  for (int f = 0; f < b.num_fibres; ++f) out.push_back(x_.middleRows(b.first_particle + f * P, P));
  return out;
}

namespace {

// Everything one frame needs, shared read-only by the per-muscle steps.
struct FrameContext {
  const FibresFirstModel& model;
  const std::vector<Transform>& motions;  // per bone, X_now_rest
  const Points3* inertial = nullptr;      // dynamic: x_n + h v (free rows)
  double mass_scale = 0.0;                // 1/h^2 (dynamic) or 0
  double contact_weight = 0.0;
};

// The outward direction of a bone contact set for a particle at `local` (bone rest frame) inside
// the bone, with closest point cp and closest face normal `face_normal` (not unit): the face's
// normal; with display-surface separation, where the closest point lies on an edge or a vertex,
// the direction from the particle to its closest point (the way out by the shortest path). The
// face's normal there can point along or against the way out (a concave crease, or a face of a
// coarse bone mesh seen past its edge): gait2392 frame 29, a lateral gastrocnemius surface
// particle 1.37 mm inside the femur stayed there through the four final bone projections, whose
// plane (of one face at the crease) had it above. The default path keeps the face normal (its
// answers unchanged).
Vec3 calc_bone_contact_normal(const FibresFirstModel& model, const Vec3& local, const ClosestPoint& cp,
                              const Vec3& face_normal) {
  const Vec3 out = cp.point - local;
  if (model.options.separate_surfaces && cp.barycentric.minCoeff() <= 1e-9 && out.norm() > 1e-9)
    return out.normalized();
  return face_normal.norm() > 0.0 ? Vec3(face_normal.normalized()) : Vec3(out.normalized());
}

// Adds particles that entered a bone (beyond their rest depth) as contacts; returns the number
// added and reports the deepest penetration beyond rest over all particles.
// `checked_at` / `clearance` (per bone, per particle) cache the last exact test (clearance: the
// distance then, minus the depth when inside): a particle that
// was outside at distance c (bone frame) and has moved less than c since cannot be inside. A
// muscle whose particles are all culled that way for a bone is skipped as a whole (BoneCull).
int detect_bone_contacts(const FrameContext& c, const Points3& x, BoneContacts& contacts,
                         std::vector<Points3>& checked_at, std::vector<VecX>& clearance,
                         BoneCull& cull, bool add, std::vector<double>* max_depth_per_muscle,
                         std::vector<char>* added_muscle = nullptr,
                         std::vector<char>* inside_muscle = nullptr) {
  const FibresFirstModel& model = c.model;
  const double margin = model.options.bone_margin_m;
  const int nm = static_cast<int>(model.muscles.size()), nb = model.num_bones();
  // each muscle's largest displacement since the last detection, and its free particles' centre
  // (middle of their box) and radius about it
  std::vector<Vec3> centre(nm, Vec3::Zero());
  std::vector<double> radius_now(nm, 0.0);
  for (int mi = 0; mi < nm; ++mi) {
    const FibreBundle& m = model.muscles[mi];
    double largest2 = 0.0;
    Eigen::AlignedBox3d box;
    for (int p = m.first_particle; p < m.first_particle + m.num_particles; ++p) {
      if (model.role[p] != ParticleRole::free) continue;
      if (cull.last_x.rows() == x.rows()) largest2 = std::max(largest2, (x.row(p) - cull.last_x.row(p)).squaredNorm());
      box.extend(Vec3(x.row(p).transpose()));
    }
    cull.travel[mi] += std::sqrt(largest2);
    if (box.isEmpty()) continue;
    centre[mi] = box.center();
    for (int p = m.first_particle; p < m.first_particle + m.num_particles; ++p)
      if (model.role[p] == ParticleRole::free)
        radius_now[mi] = std::max(radius_now[mi], (Vec3(x.row(p).transpose()) - centre[mi]).norm());
  }
  cull.last_x = x;
  int added = 0;
  for (int b = 0; b < model.num_bones(); ++b) {
    const MeshQuery& bone = *model.bones[b];
    const Transform X_rest_now = c.motions[b].inverse();
    for (int mi = 0; mi < nm; ++mi) {
      const std::size_t mb = static_cast<std::size_t>(mi) * nb + b;
      if (cull.slack[mb] > 0.0) {
        double bound = cull.travel[mi] - cull.travel_then[mb];
        if (c.motions[b].matrix() != cull.motion[mb].matrix()) {  // b moved since the pass
          const Transform E = X_rest_now * cull.motion[mb];
          const Vec3 yc = cull.motion[mb].inverse() * cull.centre[mb];
          const double turn = std::sqrt(std::max(0.0, 3.0 - E.linear().trace()));  // |R - I|
          bound += (E * yc - yc).norm() + (turn + 1e-12) * cull.radius[mb];
        }
        if (bound < cull.slack[mb] * (1.0 - 1e-9) - 1e-12) continue;  // every particle culled
      }
      double slack = std::numeric_limits<double>::infinity();
      const FibreBundle& m = model.muscles[mi];
      for (int p = m.first_particle; p < m.first_particle + m.num_particles; ++p) {
        // fixed particles follow their bone and cannot be moved: neither contacts nor measured.
        // A particle inside the bone at rest (depth d0) may stay as deep: only depth beyond d0
        // counts, and its contact plane lies at depth d0 - margin (its clearance is 0: never culled)
        if (model.role[p] != ParticleRole::free) continue;
        const double rest_depth = model.rest_bone_depth[b][p];
        const Vec3 local = X_rest_now * Vec3(x.row(p).transpose());
        const double moved = (local - checked_at[b].row(p).transpose()).norm();
        if (moved < clearance[b][p]) {  // cannot have reached the bone
          slack = std::min(slack, clearance[b][p] - moved);
          continue;
        }
        // the surface lies within |last distance| + moved of the particle: a bounded query, and
        // nothing within it means outside by at least that much
        const double radius = std::abs(clearance[b][p]) + moved + 1e-9;
        const ClosestPoint cp = bone.calc_closest_point(local, radius);
        checked_at[b].row(p) = local.transpose();
        if (cp.triangle < 0) {
          clearance[b][p] = radius;
          slack = std::min(slack, radius);
          continue;
        }
        clearance[b][p] = cp.distance;
        slack = std::min(slack, cp.distance);
        Vec3 face_normal;
        if (!detail::calc_is_behind_bone(bone, local, cp, &face_normal)) continue;
        clearance[b][p] = -cp.distance;  // inside: minus the depth (never culls)
        slack = 0.0;
        if (cp.distance <= rest_depth) continue;  // not deeper than at rest
        // flagged whether or not a contact slot is free (a third bone finds both slots taken)
        if (inside_muscle) (*inside_muscle)[model.muscle_of[p]] = 1;
        if (max_depth_per_muscle) {
          double& d = (*max_depth_per_muscle)[model.muscle_of[p]];
          d = std::max(d, cp.distance - rest_depth);
        }
        if (!add) continue;
        // a free slot, and not a second contact with the same bone
        int slot = -1;
        bool held_by_b = false;
        for (int s = 0; s < BoneContacts::slots; ++s) {
          held_by_b = held_by_b || contacts.bone[s][p] == b;
          if (slot < 0 && contacts.bone[s][p] < 0) slot = s;
        }
        const Vec3 n = calc_bone_contact_normal(model, local, cp, face_normal);
        if (held_by_b) {
          // inside a bone it is already held against: the contact's plane (set where the particle
          // entered) no longer fits where it is now; move the plane to the current closest point
          for (int s = 0; s < BoneContacts::slots; ++s)
            if (contacts.bone[s][p] == b) {
              contacts.target_rest[s][p] = cp.point + (margin - rest_depth) * n;
              contacts.normal_rest[s][p] = n;
            }
          if (added_muscle) (*added_muscle)[model.muscle_of[p]] = 1;
          continue;
        }
        if (slot < 0) continue;
        contacts.bone[slot][p] = b;
        contacts.target_rest[slot][p] = cp.point + (margin - rest_depth) * n;
        contacts.normal_rest[slot][p] = n;
        if (added_muscle) (*added_muscle)[model.muscle_of[p]] = 1;
        ++added;
      }
      cull.slack[mb] = slack;
      cull.travel_then[mb] = cull.travel[mi];
      cull.centre[mb] = centre[mi];
      cull.radius[mb] = radius_now[mi];
      cull.motion[mb] = c.motions[b];
    }
  }
  return added;
}

// Re-evaluates the bone contacts whose particle lies farther than its muscle's mean rest spring
// length from the contact's target point (separation only; docs/representations.md, "Session
// 10"). A contact's plane describes the bone only near the point where it was set, and a
// contact kept across frames can end far from it when bones move much relative to each other
// within a frame (gait2392 at 60 Hz: a medial gastrocnemius surface particle 84 mm from its
// target and 14 mm outside the bone was projected 49 mm onto the stale plane by the final
// projection, which broke the volume hold). Such a contact is tested exactly: when the particle
// is inside the bone beyond its rest depth the plane moves to its current closest point (as
// detection does for held particles), otherwise the contact is released (a remaining second
// contact moves to the first slot). Returns the number released.
int revalidate_far_bone_contacts(const FrameContext& c, const Points3& x, BoneContacts& contacts) {
  const FibresFirstModel& model = c.model;
  const double margin = model.options.bone_margin_m;
  int released = 0;
  for (int p = 0; p < model.num_particles(); ++p) {
    if (!contacts.has(p)) continue;
    const double reach = model.muscles[model.muscle_of[p]].mean_spring_length_m;
    const Vec3 xp = x.row(p).transpose();
    for (int s = 0; s < BoneContacts::slots; ++s) {
      const int b = contacts.bone[s][p];
      if (b < 0 || (c.motions[b] * contacts.target_rest[s][p] - xp).norm() <= reach) continue;
      const MeshQuery& bone = *model.bones[b];
      const Vec3 local = c.motions[b].inverse() * xp;
      const ClosestPoint cp = bone.calc_closest_point(local);
      const double rest_depth = model.rest_bone_depth[b][p];
      Vec3 face_normal;
      if (cp.triangle >= 0 && detail::calc_is_behind_bone(bone, local, cp, &face_normal) &&
          cp.distance > rest_depth) {
        const Vec3 n = calc_bone_contact_normal(model, local, cp, face_normal);
        contacts.target_rest[s][p] = cp.point + (margin - rest_depth) * n;
        contacts.normal_rest[s][p] = n;
        continue;
      }
      contacts.bone[s][p] = -1;
      ++released;
    }
    if (contacts.bone[0][p] < 0 && contacts.bone[1][p] >= 0) {
      contacts.bone[0][p] = contacts.bone[1][p];
      contacts.target_rest[0][p] = contacts.target_rest[1][p];
      contacts.normal_rest[0][p] = contacts.normal_rest[1][p];
      contacts.bone[1][p] = -1;
    }
  }
  return released;
}

// Brings the candidate list up to date for positions x (see PairCandidates).
void refresh_pair_candidates(const FibresFirstModel& model, const Points3& x, PairCandidates& c) {
  const double margin = model.options.muscle_margin_m, skin = model.options.pair_list_skin_m;
  if (c.ids.empty())
    for (const FibreBundle& m : model.muscles)
      c.ids.insert(c.ids.end(), m.contact_particles.begin(), m.contact_particles.end());
  const Eigen::Index n = static_cast<Eigen::Index>(c.ids.size());
  const double radius = margin + skin;
  if (c.valid) {
    const double limit2 = 0.25 * skin * skin;
    std::vector<Eigen::Index> movers;
    for (Eigen::Index j = 0; j < n; ++j)
      if ((x.row(c.ids[j]) - c.built_at.row(j)).squaredNorm() > limit2) movers.push_back(j);
    if (movers.empty()) return;
    std::size_t rereferenced = c.rereferenced.size();
    for (Eigen::Index j : movers) rereferenced += c.is_rereferenced[j] ? 0 : 1;
    if (static_cast<Eigen::Index>(rereferenced) * 8 < n) {  // a few movers: partial rebuild
      std::vector<char> is_mover(model.num_particles(), 0);
      for (Eigen::Index j : movers) {
        c.built_at.row(j) = x.row(c.ids[j]);
        is_mover[c.ids[j]] = 1;
        if (!c.is_rereferenced[j]) c.rereferenced.push_back(j);
        c.is_rereferenced[j] = 1;
      }
      c.list.erase(std::remove_if(c.list.begin(), c.list.end(),
                                  [&](const MusclePair& pr) { return is_mover[pr.p] || is_mover[pr.q]; }),
                   c.list.end());
      Points3 moved_at(static_cast<Eigen::Index>(c.rereferenced.size()), 3);
      for (std::size_t i = 0; i < c.rereferenced.size(); ++i)
        moved_at.row(static_cast<Eigen::Index>(i)) = c.built_at.row(c.rereferenced[i]);
      const PointCloud moved_cloud{moved_at};
      PointTree moved_tree(3, moved_cloud, nanoflann::KDTreeSingleIndexAdaptorParams(12));
      moved_tree.buildIndex();
      std::vector<std::pair<std::size_t, double>> hits;
      nanoflann::SearchParams params;
      params.sorted = false;
      auto add = [&](int a, int b) {
        if (model.muscle_of[b] == model.muscle_of[a]) return;
        const int p = std::min(a, b), q = std::max(a, b);
        const double allowed = std::min(margin, (model.rest.row(p) - model.rest.row(q)).norm());
        if (allowed > 1e-12) c.list.push_back({p, q, allowed});
      };
      for (Eigen::Index j : movers) {
        const int a = c.ids[j];
        const Vec3 xa = c.built_at.row(j);
        hits.clear();
        c.full_tree->radiusSearch(xa.data(), radius * radius, hits, params);
        for (const auto& [k, d2] : hits)
          if (!c.is_rereferenced[static_cast<Eigen::Index>(k)]) add(a, c.ids[k]);
        hits.clear();
        moved_tree.radiusSearch(xa.data(), radius * radius, hits, params);
        for (const auto& [i, d2] : hits) {
          const int b = c.ids[c.rereferenced[i]];
          if (!(is_mover[b] && b < a)) add(a, b);  // both movers: added once, from the larger index
        }
      }
      std::sort(c.list.begin(), c.list.end(),
                [](const MusclePair& a, const MusclePair& b) { return a.p != b.p ? a.p < b.p : a.q < b.q; });
      ++c.partial_builds;
      return;
    }
  }
  c.built_at.resize(n, 3);
  for (Eigen::Index j = 0; j < n; ++j) c.built_at.row(j) = x.row(c.ids[j]);
  c.full_at = c.built_at;
  c.full_cloud = std::make_unique<PointCloud>(PointCloud{c.full_at});
  c.full_tree = std::make_unique<PointTree>(3, *c.full_cloud, nanoflann::KDTreeSingleIndexAdaptorParams(12));
  PointTree& tree = *c.full_tree;
  tree.buildIndex();
  c.rereferenced.clear();
  c.is_rereferenced.assign(static_cast<std::size_t>(n), 0);
  c.list.clear();
  std::vector<std::pair<std::size_t, double>> hits;
  nanoflann::SearchParams params;
  params.sorted = false;
  for (Eigen::Index j = 0; j < n; ++j) {
    const int p = c.ids[j];
    const Vec3 xp = c.built_at.row(j);
    hits.clear();
    tree.radiusSearch(xp.data(), radius * radius, hits, params);
    for (const auto& [k, d2] : hits) {
      const int q = c.ids[k];
      if (q <= p || model.muscle_of[q] == model.muscle_of[p]) continue;
      const double allowed = std::min(margin, (model.rest.row(p) - model.rest.row(q)).norm());
      if (allowed > 1e-12) c.list.push_back({p, q, allowed});
    }
  }
  std::sort(c.list.begin(), c.list.end(),
            [](const MusclePair& a, const MusclePair& b) { return a.p != b.p ? a.p < b.p : a.q < b.q; });
  c.valid = true;
  ++c.builds;
}

// Finds contact particles of different muscles closer than min(muscle margin, rest distance)
// (from the candidate list, refreshed when needed); adds new pairs when `add`; returns the number
// added and the largest shortfall per muscle.
int detect_muscle_pairs(const FibresFirstModel& model, const Points3& x, PairCandidates& candidates,
                        std::vector<MusclePair>& pairs, std::unordered_set<long long>& keys,
                        bool add, std::vector<double>* max_overlap_per_muscle) {
  const double margin = model.options.muscle_margin_m;
  if (model.muscles.size() < 2 || margin <= 0.0) return 0;
  refresh_pair_candidates(model, x, candidates);
  int added = 0;
  const long long N = model.num_particles();
  for (const MusclePair& c : candidates.list) {
    const double d2 = (x.row(c.p) - x.row(c.q)).squaredNorm();
    if (d2 >= c.allowed_m * c.allowed_m) continue;
    const double shortfall = c.allowed_m - std::sqrt(d2);
    if (shortfall <= 1e-12) continue;
    if (max_overlap_per_muscle)
      for (int mm : {model.muscle_of[c.p], model.muscle_of[c.q]})
        (*max_overlap_per_muscle)[mm] = std::max((*max_overlap_per_muscle)[mm], shortfall);
    if (add && keys.insert(c.p * N + c.q).second) {
      pairs.push_back(c);
      ++added;
    }
  }
  return added;
}

// ---- Display-surface separation (docs/representations.md, "Display-surface separation") ----

// Display vertex v of muscle m at positions x (all particles): sum_k w_k x_k.
Vec3 calc_surface_vertex(const FibreBundle& m, int v, const Points3& x) {
  Vec3 s = Vec3::Zero();
  for (int k = m.surface_weight_start[v]; k < m.surface_weight_start[v + 1]; ++k)
    s += m.surface_weight[k] * x.row(m.surface_weight_particle[k]).transpose();
  return s;
}

// The frame of a triangle with corners c: columns e1 (along its first edge), e2 = n x e1, and n
// its unit normal. False for a degenerate triangle.
bool calc_face_frame(const Vec3 (&c)[3], Mat3& frame) {
  const Vec3 e1 = c[1] - c[0];
  Vec3 n = e1.cross(c[2] - c[0]);
  if (!(n.norm() > 0.0) || !(e1.norm() > 0.0)) return false;
  n.normalize();
  frame.col(0) = e1.normalized();
  frame.col(2) = n;
  frame.col(1) = n.cross(frame.col(0));
  return true;
}

// The direction of a surface contact found with vertex position p, closest point cp on the other
// surface's face with corners `corner`, and signed gap `gap` (negative inside), in the face's
// frame (SurfaceContact::direction): the unit vector from the closest point to p, negated inside,
// i.e. the gradient of the signed distance, along which the vertex leaves the other surface by
// the shortest way. (Before, the face's own normal was used. Where the closest point lies on an
// edge between a face and a folded neighbour, that normal can point into the other muscle:
// gait2392 frame 7, a semimem_r vertex 6.3 mm inside semiten_r, whose closest face had turned by
// 105 degrees from its rest orientation, met its contact on that face's plane and was never
// pushed out.) Within 1 um of the surface the face normal is used.
Vec3 calc_contact_direction(const Vec3 (&corner)[3], const Vec3& p, const ClosestPoint& cp, double gap) {
  Mat3 frame;
  const Vec3 d = p - cp.point;
  if (!calc_face_frame(corner, frame) || !(d.norm() > 1e-6) || !std::isfinite(gap)) return Vec3::UnitZ();
  return frame.transpose() * (gap < 0.0 ? Vec3(-d.normalized()) : Vec3(d.normalized()));
}

// The face of surface contact c at positions x: its corners, current unit normal n and the
// contact's point c on it (its barycentric blend of the corners). False for a degenerate face.
struct ContactFace {
  Vec3 corner[3];
  Vec3 n;
  Vec3 point;
};
bool calc_contact_face(const FibreBundle& mb, const SurfaceContact& c, const Points3& x, ContactFace& f) {
  for (int i = 0; i < 3; ++i) f.corner[i] = calc_surface_vertex(mb, mb.surface_triangles(c.triangle, i), x);
  Mat3 frame;
  if (!calc_face_frame(f.corner, frame)) return false;
  f.n = frame * c.direction;
  f.point = c.barycentric[0] * f.corner[0] + c.barycentric[1] * f.corner[1] + c.barycentric[2] * f.corner[2];
  return true;
}

// Key of the contact of vertex v of muscle a with muscle b's surface (SurfaceSeparation::keys).
long long get_contact_key(int a, int v, int b, int nm) {
  return (static_cast<long long>(a) * nm + b) * (1LL << 31) + v;
}

// Signed gap of p from a closed, outward surface (positive outside): the closest point, and the
// side of its face (MeshQuery's ray vote on an edge or a vertex), the bones' rule. An "inside"
// answer deeper than 1 mm is confirmed by the ray vote (the winding number; the scene's overlap
// measure uses winding numbers too): on a folded surface the closest face can face the wrong
// way, and the face rule then called vertices inside up to 124 mm away from the VH medial
// gastrocnemius; such a vertex became a contact with a push of that size (gait2392 sar_r lost
// 111 % of its volume in one push at frame 1; with the confirmation gait2392 runs to frame 21 and
// the demo leg at 25 Hz to frame 39, instead of frames 1 and 4). Shallower answers keep the face
// rule (soleus at VH frames 84-87: 0.14-0.17 mm inside by the face rule, outside by the winding
// number), so contacts at the margin cost no ray votes; confirming every inside answer gave the
// same VH results but made gait2392 fail at frame 16. (The sign of the closest feature's
// angle-weighted pseudonormal, Baerentzen and Aanaes 2005, was tried in place of the ray vote
// with surface particles: on the VH shank the solve then broke down at frame 61, a vertex 24 mm
// inside another surface, and the volume hold failed at frame 65.)
double calc_signed_gap(const MeshQuery& surface, const Vec3& p, ClosestPoint& cp) {
  constexpr double confirm_beyond_m = 1e-3;
  cp = surface.calc_closest_point(p);
  if (cp.triangle < 0) return std::numeric_limits<double>::infinity();
  if (!detail::calc_is_behind_bone(surface, p, cp)) return cp.distance;
  if (cp.distance > confirm_beyond_m && !surface.calc_is_inside(p)) return cp.distance;
  return -cp.distance;
}

// Whether surface contact c still holds at positions x, to be kept for the next frame (the
// surfaces' queries brought to x): its gap (s_v - c) . n to its face's plane is below the minimum
// plus the margin, and so is its gap to the other surface itself. The second test releases a
// vertex that slid past its face: held against that face's plane it would float off a convex
// partner by about s^2 / 2R after a slide s over radius R, and detection, which refreshes a known
// contact's face only while the vertex is below its minimum gap, would not notice; if the vertex
// is still near, the next detection finds it again with its current closest face.
bool calc_contact_holds(const FibresFirstModel& model, const SurfaceSeparation& ss,
                        const SurfaceContact& c, const Points3& x, double margin) {
  ContactFace f;
  if (!calc_contact_face(model.muscles[c.b], c, x, f)) return false;
  const Vec3 s = calc_surface_vertex(model.muscles[c.a], c.v, x);
  if (!((s - f.point).dot(f.n) <= c.min_gap + margin)) return false;
  ClosestPoint cp;
  return calc_signed_gap(*ss.query[c.b], s, cp) <= c.min_gap + margin;
}

Eigen::AlignedBox3d calc_box(const Points3& V, double pad) {
  Eigen::AlignedBox3d box(V.colwise().minCoeff().transpose(), V.colwise().maxCoeff().transpose());
  box.min().array() -= pad;
  box.max().array() += pad;
  return box;
}

// The smallest gap vertex v of muscle a may have to muscle b's surface: the margin, or for a pair
// that keeps its rest depths, min(margin, rest gap).
double get_min_gap(const SurfaceSeparation& ss, const FibresFirstOptions& o, int nm, int a, int v,
                   int b) {
  const VecX& rest = ss.rest_gap[a * nm + b];
  if (ss.resolved[a * nm + b] || rest.size() == 0) return o.surface_margin_m;
  return std::min(o.surface_margin_m, rest[v]);
}

// One query per display surface (rest pose), the rest gaps of every vertex near another muscle's
// surface, and which pairs are separated fully (rest overlap <= surface_rest_overlap_resolved_m
// both ways) or keep their rest depths.
void init_surface_separation(const FibresFirstModel& model,
                             const std::vector<std::unique_ptr<MuscleSystem>>& systems,
                             SurfaceSeparation& ss) {
  const FibresFirstOptions& o = model.options;
  const int nm = static_cast<int>(model.muscles.size());
  ss = SurfaceSeparation{};
  ss.enabled = o.separate_surfaces && nm >= 2;
  if (!ss.enabled) return;
  ss.query.resize(nm);
  ss.surface.resize(nm);
  ss.kernels.resize(nm);
  for (int mi = 0; mi < nm; ++mi)
    ss.kernels[mi].resize(std::max(0, model.muscles[mi].num_surface_vertices()));
  for (int mi = 0; mi < nm; ++mi) {
    const FibreBundle& m = model.muscles[mi];
    if (m.surface_triangles.rows() < 4) continue;
    ss.surface[mi] = systems[mi]->surface_map * model.rest.middleRows(m.first_particle, m.num_particles);
    ss.query[mi] = std::make_unique<MeshQuery>(TriMesh{ss.surface[mi], m.surface_triangles});
  }
  ss.travel.assign(nm, 0.0);
  ss.tested_gap.assign(static_cast<std::size_t>(nm) * nm, VecX());
  ss.tested_travel.assign(static_cast<std::size_t>(nm) * nm, VecX());
  ss.tested_at.assign(static_cast<std::size_t>(nm) * nm, Points3());
  ss.rest_surface = ss.surface;
  ss.to_body.assign(nm, Transform::Identity());
  ss.body_travel.assign(nm, 0.0);
  ss.fitted_travel.assign(nm, 0.0);
  ss.tested_body_travel.assign(static_cast<std::size_t>(nm) * nm, VecX());
  ss.tested_body_at.assign(static_cast<std::size_t>(nm) * nm, Points3());
  ss.rest_gap.assign(static_cast<std::size_t>(nm) * nm, VecX());
  ss.resolved.assign(static_cast<std::size_t>(nm) * nm, 1);
  std::vector<Eigen::AlignedBox3d> box(nm);
  for (int mi = 0; mi < nm; ++mi)
    if (ss.query[mi]) box[mi] = calc_box(ss.surface[mi], o.surface_margin_m);
  std::vector<double> rest_depth(static_cast<std::size_t>(nm) * nm, 0.0);
  parallel_for(static_cast<std::size_t>(nm), [&](std::size_t a) {
    if (!ss.query[a]) return;
    for (int b = 0; b < nm; ++b) {
      if (b == static_cast<int>(a) || !ss.query[b] || !box[a].intersects(box[b])) continue;
      const Points3& S = ss.surface[a];
      VecX gap = VecX::Constant(S.rows(), std::numeric_limits<double>::infinity());
      bool near = false;
      for (Eigen::Index v = 0; v < S.rows(); ++v) {
        const Vec3 p = S.row(v).transpose();
        if (!box[b].contains(p)) continue;
        ClosestPoint cp;
        gap[v] = calc_signed_gap(*ss.query[b], p, cp);
        near = near || gap[v] < o.surface_margin_m;
        rest_depth[a * nm + b] = std::max(rest_depth[a * nm + b], -gap[v]);
      }
      if (near) ss.rest_gap[a * nm + b] = std::move(gap);
    }
  });
  for (int a = 0; a < nm; ++a)
    for (int b = 0; b < nm; ++b)
      ss.resolved[a * nm + b] = std::max(rest_depth[a * nm + b], rest_depth[b * nm + a]) <=
                                o.surface_rest_overlap_resolved_m;
}

// Brings every display surface (and its query) to positions x.
void update_surfaces(const FibresFirstModel& model,
                     const std::vector<std::unique_ptr<MuscleSystem>>& systems, const Points3& x,
                     SurfaceSeparation& ss) {
  parallel_for(model.muscles.size(), [&](std::size_t mi) {
    if (!ss.query[mi]) return;
    const FibreBundle& m = model.muscles[mi];
    Points3 now = systems[mi]->surface_map * x.middleRows(m.first_particle, m.num_particles);
    if (now == ss.surface[mi]) return;  // unchanged: the query already holds these vertices
    const double moved = std::sqrt((now - ss.surface[mi]).rowwise().squaredNorm().maxCoeff());
    ss.travel[mi] += moved;
    if (!(ss.travel[mi] - ss.fitted_travel[mi] > SurfaceSeparation::body_refit_after_m)) {
      ss.body_travel[mi] += moved;  // the same body frame: rigid, so the world displacements
    } else {
      Transform to_body;
      to_body.matrix() = Eigen::umeyama(now.transpose(), ss.rest_surface[mi].transpose(), false);
      double largest2 = 0.0;
      for (Eigen::Index v = 0; v < now.rows(); ++v)
        largest2 = std::max(largest2, (to_body * Vec3(now.row(v).transpose()) -
                                       ss.to_body[mi] * Vec3(ss.surface[mi].row(v).transpose())).squaredNorm());
      ss.body_travel[mi] += std::sqrt(largest2);
      ss.to_body[mi] = to_body;
      ss.fitted_travel[mi] = ss.travel[mi];
    }
    ss.surface[mi] = std::move(now);
    ss.query[mi]->update_vertices(ss.surface[mi]);
  });
}

// Finds the display vertices closer to another muscle's surface than their minimum gap (the
// surfaces brought to x first); adds new contacts when `add`; returns the number added. Metrics
// per muscle of the vertex: the deepest vertex inside another surface (absolute, and beyond its
// rest depth). A vertex of a is tested against b's surface (closest point and side) only when it
// lies in b's box padded by the margin and the bound from its last test (see SurfaceSeparation)
// does not keep it beyond the margin; the vertices found, their gaps and the contacts added are
// those of testing every vertex, in the order a, v, b, except where the sign rule flips on a
// folded face without the distance passing through 0 (see SurfaceSeparation). (Before, a Verlet list of the vertices
// within margin + 2 mm, rebuilt 2-3 times per frame on the VH shank, chose the tested vertices:
// its rebuilds were about 19 % of the solver's time.)
int detect_surface_contacts(const FibresFirstModel& model,
                            const std::vector<std::unique_ptr<MuscleSystem>>& systems,
                            const Points3& x, SurfaceSeparation& ss, bool add,
                            std::vector<double>* depth, std::vector<double>* beyond_rest,
                            std::vector<char>* touched = nullptr) {
  if (!ss.enabled) return 0;
  const FibresFirstOptions& o = model.options;
  const int nm = static_cast<int>(model.muscles.size());
  update_surfaces(model, systems, x, ss);
  std::vector<Eigen::AlignedBox3d> box(nm);
  for (int mi = 0; mi < nm; ++mi)
    if (ss.query[mi]) box[mi] = calc_box(ss.surface[mi], o.surface_margin_m);
  struct Found {
    int v = -1, b = -1;
    double gap = 0.0;
    ClosestPoint cp;
  };
  std::vector<std::vector<Found>> found(nm);
  parallel_for(static_cast<std::size_t>(nm), [&](std::size_t ai) {
    const int a = static_cast<int>(ai);
    if (!ss.query[a]) return;
    std::vector<int> near;
    for (int b = 0; b < nm; ++b)
      if (b != a && ss.query[b] && box[a].intersects(box[b])) near.push_back(b);
    if (near.empty()) return;
    const Points3& S = ss.surface[a];
    for (int b : near) {
      const std::size_t ab = static_cast<std::size_t>(a) * nm + b;
      if (ss.tested_gap[ab].size() != S.rows()) {
        ss.tested_gap[ab] = VecX::Constant(S.rows(), -std::numeric_limits<double>::infinity());
        ss.tested_travel[ab] = VecX::Zero(S.rows());
        ss.tested_at[ab] = S;
        ss.tested_body_travel[ab] = VecX::Zero(S.rows());
        ss.tested_body_at[ab] = S;
      }
    }
    for (int v = 0; v < static_cast<int>(S.rows()); ++v) {
      const Vec3 p = S.row(v).transpose();
      for (int b : near) {
        if (!box[b].contains(p)) continue;
        const std::size_t ab = static_cast<std::size_t>(a) * nm + b;
        const double bound = ss.tested_gap[ab][v] - (p - Vec3(ss.tested_at[ab].row(v).transpose())).norm() -
                             (ss.travel[b] - ss.tested_travel[ab][v]);
        const double beyond = o.surface_margin_m * (1.0 + 1e-9) + 1e-12;
        if (bound > beyond) continue;  // cannot be within the margin
        const Vec3 z = ss.to_body[b] * p;
        const double body_bound = ss.tested_gap[ab][v] - (z - Vec3(ss.tested_body_at[ab].row(v).transpose())).norm() -
                                  (ss.body_travel[b] - ss.tested_body_travel[ab][v]);
        if (body_bound > beyond) continue;
        ClosestPoint cp;
        const double gap = calc_signed_gap(*ss.query[b], p, cp);
        ss.tested_gap[ab][v] = gap;
        ss.tested_travel[ab][v] = ss.travel[b];
        ss.tested_at[ab].row(v) = p.transpose();
        ss.tested_body_travel[ab][v] = ss.body_travel[b];
        ss.tested_body_at[ab].row(v) = z.transpose();
        if (gap < o.surface_margin_m) found[a].push_back({v, b, gap, cp});
      }
    }
  });
  int added = 0;
  for (int a = 0; a < nm; ++a) {
    for (const Found& f : found[a]) {
      const int v = f.v, b = f.b;
      if (f.gap < 0.0) {
        if (depth) (*depth)[a] = std::max((*depth)[a], -f.gap);
        if (beyond_rest) {
          const VecX& rest = ss.rest_gap[a * nm + b];
          const double rest_depth = rest.size() > 0 ? std::max(0.0, -rest[v]) : 0.0;
          (*beyond_rest)[a] = std::max((*beyond_rest)[a], -f.gap - rest_depth);
        }
      }
      if (!add || !(f.gap < get_min_gap(ss, o, nm, a, v, b))) continue;
      const long long key = get_contact_key(a, v, b, nm);
      Vec3 corner[3];
      for (int i = 0; i < 3; ++i) corner[i] = ss.surface[b].row(model.muscles[b].surface_triangles(f.cp.triangle, i)).transpose();
      const Vec3 direction = calc_contact_direction(corner, ss.surface[a].row(v).transpose(), f.cp, f.gap);
      const auto [it, fresh] = ss.keys.emplace(key, static_cast<int>(ss.contacts.size()));
      if (!fresh) {
        // a known contact: it pushes against the current closest face (the surfaces slide)
        ss.contacts[it->second].triangle = f.cp.triangle;
        ss.contacts[it->second].barycentric = f.cp.barycentric;
        ss.contacts[it->second].direction = direction;
        continue;
      }
      ss.contacts.push_back({a, v, b, f.cp.triangle, f.cp.barycentric, get_min_gap(ss, o, nm, a, v, b), direction});
      if (touched) (*touched)[a] = (*touched)[b] = 1;
      ++added;
    }
  }
  return added;
}

// The smooth displacement field a push applies around display vertex v of muscle m: per particle
// of m (ascending), phi = exp(-|r|^2 / R^2), r its rest distance to the vertex's rest position,
// R = 2 x the muscle's mean spring length, kept where phi >= 1e-3. Built on first use.
const PushKernel& get_push_kernel(const FibresFirstModel& model, SurfaceSeparation& ss, int mi, int v) {
  PushKernel& k = ss.kernels[mi][v];
  if (k.built) return k;
  const FibreBundle& m = model.muscles[mi];
  const Vec3 centre = calc_surface_vertex(m, v, model.rest);
  const double R = 2.0 * m.mean_spring_length_m, cut2 = R * R * std::log(1e3);
  for (int p = m.first_particle; p < m.first_particle + m.num_particles; ++p) {
    const double r2 = (model.rest.row(p).transpose() - centre).squaredNorm();
    if (r2 <= cut2) k.entries.emplace_back(p, std::exp(-r2 / (R * R)));
  }
  k.built = true;
  return k;
}

// Pushes contact c to its minimum gap at positions x: the vertex along n by its muscle's
// particles, the face point against n by the other muscle's, half each (all of it by one side
// when the other cannot move). A side moves its movable particles by a smooth bump, phi_k d / c,
// with phi the push kernel around the point (get_push_kernel; for the face point the barycentric
// blend of its corners' kernels) and c = sum_k w_k phi_k over the point's weights w, so the point
// moves by exactly d and the surface around it follows smoothly; a side with c < 1/2 (mostly
// carried by particles that cannot move) counts as immovable. (Moving only the point's own
// particles, by the minimum-norm w_k d / sum w^2 or by a common translation, was tried first: the
// loft's weights extrapolate, reaching |w| = 6, so a partial move of a vertex's particles moved
// its neighbours by several times d, and the Gauss-Seidel passes diverged on the VH shank.)
// Returns the deficit found (<= 0: the gap was met). `bump`: scratch.
template <class Movable>
double push_surface_contact(const FibresFirstModel& model, SurfaceSeparation& ss,
                            const SurfaceContact& c, Points3& x, const Movable& movable,
                            std::vector<std::pair<int, double>>& bump) {
  const FibreBundle& ma = model.muscles[c.a];
  const FibreBundle& mb = model.muscles[c.b];
  const Vec3 s = calc_surface_vertex(ma, c.v, x);
  ContactFace face;
  if (!calc_contact_face(mb, c, x, face)) return 0.0;
  const Vec3& n = face.n;
  const double deficit = c.min_gap - (s - face.point).dot(n);
  if (!(deficit > 0.0)) return deficit;
  // a side: its bump (movable particles only, ascending) and c = sum_k w_k phi_k
  auto phi_of = [&](int p) {
    const auto it = std::lower_bound(bump.begin(), bump.end(), std::make_pair(p, -1.0));
    return it != bump.end() && it->first == p ? it->second : 0.0;
  };
  auto make_side = [&](const FibreBundle& m, int mi, const int* vertices, const double* blend, int count) {
    bump.clear();
    for (int i = 0; i < count; ++i)
      for (const auto& [p, phi] : get_push_kernel(model, ss, mi, vertices[i]).entries)
        if (movable(p)) bump.emplace_back(p, blend[i] * phi);
    std::sort(bump.begin(), bump.end());
    std::size_t kept = 0;
    for (std::size_t j = 0; j < bump.size(); ++j) {
      if (kept > 0 && bump[kept - 1].first == bump[j].first) bump[kept - 1].second += bump[j].second;
      else bump[kept++] = bump[j];
    }
    bump.resize(kept);
    double weight = 0.0;
    for (int i = 0; i < count; ++i)
      for (int k = m.surface_weight_start[vertices[i]]; k < m.surface_weight_start[vertices[i] + 1]; ++k)
        weight += blend[i] * m.surface_weight[k] * phi_of(m.surface_weight_particle[k]);
    return weight;
  };
  const int va[1] = {c.v};
  const double one[1] = {1.0};
  const int vb[3] = {mb.surface_triangles(c.triangle, 0), mb.surface_triangles(c.triangle, 1),
                     mb.surface_triangles(c.triangle, 2)};
  const double beta[3] = {c.barycentric[0], c.barycentric[1], c.barycentric[2]};
  const double wa = make_side(ma, c.a, va, one, 1);
  const bool a_moves = wa >= 0.5;
  std::vector<std::pair<int, double>> bump_a;
  if (a_moves) bump_a = bump;
  const double wb = make_side(mb, c.b, vb, beta, 3);
  const bool b_moves = wb >= 0.5;
  if (!a_moves && !b_moves) return deficit;
  const double share_a = a_moves ? (b_moves ? 0.5 : 1.0) : 0.0;
  if (share_a > 0.0) {
    const Vec3 d = (share_a * deficit / wa) * n;
    for (const auto& [p, phi] : bump_a) x.row(p) += phi * d.transpose();
  }
  if (share_a < 1.0) {
    const Vec3 d = ((1.0 - share_a) * deficit / wb) * n;
    for (const auto& [p, phi] : bump) x.row(p) -= phi * d.transpose();
  }
  return deficit;
}

// Surface particles (FibresFirstOptions::surface_particles): a contact between two particle
// surfaces is the constraint C = (x_v - sum_i beta_i x_i) . n - min_gap >= 0 on the vertex
// particle v and the face's three particles i (n the contact's direction, which turns with the
// face: SurfaceContact::direction). Its
// projection with equal masses moves v by lambda n and particle i by -beta_i lambda n, with
// lambda = -C / (1 + sum beta_i^2) (the barycentric weights are convex, so the step is bounded
// by the deficit). Returns false when the contact is not between two particle surfaces or its
// face is degenerate; `lambda` is 0 when the gap is met.
bool calc_particle_contact_step(const FibresFirstModel& model, const SurfaceContact& c,
                                const Points3& x, int& pv, int (&pf)[3], Vec3& n, double& lambda) {
  const FibreBundle& ma = model.muscles[c.a];
  const FibreBundle& mb = model.muscles[c.b];
  if (ma.num_surface_particles == 0 || mb.num_surface_particles == 0) return false;
  pv = ma.surface_weight_particle[c.v];
  Vec3 corner[3];
  for (int i = 0; i < 3; ++i) {
    pf[i] = mb.surface_weight_particle[mb.surface_triangles(c.triangle, i)];
    corner[i] = x.row(pf[i]).transpose();
  }
  Mat3 frame;
  if (!calc_face_frame(corner, frame)) return false;
  n = frame * c.direction;
  const Vec3 point = c.barycentric[0] * corner[0] + c.barycentric[1] * corner[1] + c.barycentric[2] * corner[2];
  const double C = (Vec3(x.row(pv).transpose()) - point).dot(n) - c.min_gap;
  lambda = C < 0.0 ? -C / (1.0 + c.barycentric.squaredNorm()) : 0.0;
  return true;
}

// Surface-particle contact targets of this iteration (Jacobi, like the pairs): each contact's
// projection (calc_particle_contact_step) from the snapshot, accumulated into the per-particle
// mean targets. `active` (optional, per muscle): only the contacts of an active muscle are needed
// (the others' rows are read by no solve this iteration); a particle's sum takes the same terms in
// the same order either way.
void add_surface_particle_targets(const FibresFirstModel& model, FibresFirstSolver::Workspace& ws,
                                  const Points3& snapshot, const std::vector<char>* active = nullptr) {
  if (!ws.surfaces.enabled) return;
  for (const SurfaceContact& c : ws.surfaces.contacts) {
    if (active && !(*active)[c.a] && !(*active)[c.b]) continue;
    int pv = -1, pf[3];
    Vec3 n;
    double lambda = 0.0;
    if (!calc_particle_contact_step(model, c, snapshot, pv, pf, n, lambda)) continue;
    // at most one mean spring length of the deficit per iteration (the smaller muscle's): a
    // vertex found deep inside a large neighbour asked for its whole depth at once, and on
    // gait2392 at 50 Hz a gemellus pushed 46 mm in one iteration diverged (positions of
    // kilometres, frame 105); the iterations then separate such a contact over several steps
    const double reach = std::min(model.muscles[c.a].mean_spring_length_m, model.muscles[c.b].mean_spring_length_m);
    lambda = std::min(lambda, reach / (1.0 + c.barycentric.squaredNorm()));
    ws.pair_target.row(pv) += snapshot.row(pv) + lambda * n.transpose();
    if (ws.pair_count[pv]++ == 0) ws.target_rows.push_back(pv);
    for (int i = 0; i < 3; ++i) {
      ws.pair_target.row(pf[i]) += snapshot.row(pf[i]) - (c.barycentric[i] * lambda) * n.transpose();
      if (ws.pair_count[pf[i]]++ == 0) ws.target_rows.push_back(pf[i]);
    }
  }
}

}  // namespace

namespace {

// Sets each muscle's contact weights wanted this round and brings its factor up to date: rank-one
// updates/downdates when only contact weights changed, a new factorisation otherwise (and after
// 4n modifications, to bound round-off). Throws fascicle::Error (numerical) when one fails.
// `changed` (optional, per muscle): set to 1 for the muscles whose factor changed.
void update_factors(const FrameContext& ctx, FibresFirstSolver::Workspace& ws, int frame,
                    FibresFirstInfo& info, std::vector<char>* changed = nullptr) {
  const FibresFirstModel& model = ctx.model;
  const int nm = static_cast<int>(model.muscles.size());
  // contact weights wanted per free particle; refactorise the muscles whose weights changed
  for (int mi = 0; mi < nm; ++mi) {
    const FibreBundle& m = model.muscles[mi];
    MuscleSystem& sys = *ws.systems[mi];
    std::fill(sys.weight.begin(), sys.weight.end(), 0.0);
    for (std::size_t j = 0; j < m.free.size(); ++j)
      if (ws.bone_contacts.has(m.free[j])) sys.weight[j] = ctx.contact_weight;
  }
  for (const MusclePair& pr : ws.pairs)
    for (int p : {pr.p, pr.q}) {
      const FibreBundle& m = model.muscles[model.muscle_of[p]];
      const int j = m.free_index[p - m.first_particle];
      if (j >= 0) ws.systems[model.muscle_of[p]]->weight[j] = ctx.contact_weight;
    }
  if (ws.surfaces.enabled)
    for (const SurfaceContact& c : ws.surfaces.contacts) {
      const FibreBundle& ma = model.muscles[c.a];
      const FibreBundle& mb = model.muscles[c.b];
      if (ma.num_surface_particles == 0 || mb.num_surface_particles == 0) continue;
      auto set = [&](const FibreBundle& m, int mi, int p) {
        const int j = m.free_index[p - m.first_particle];
        if (j >= 0) ws.systems[mi]->weight[j] = ctx.contact_weight;
      };
      set(ma, c.a, ma.surface_weight_particle[c.v]);
      for (int i = 0; i < 3; ++i) set(mb, c.b, mb.surface_weight_particle[mb.surface_triangles(c.triangle, i)]);
    }
  std::vector<int> refactor;
  for (int mi = 0; mi < nm; ++mi) {
    const MuscleSystem& sys = *ws.systems[mi];
    const double mass_term = model.muscles[mi].particle_mass_kg * ctx.mass_scale;
    if (!sys.valid || sys.weight != sys.factored_weight || mass_term != sys.factored_mass_term)
      refactor.push_back(mi);
  }
  if (changed)
    for (int mi : refactor) (*changed)[mi] = 1;
  std::vector<char> failed(nm, 0);
  std::vector<char> refactorised(nm, 0);
  // The first factorisation of a muscle also computes its fill-reducing ordering; METIS draws
  // from a random-number state shared by all threads (GKlib), so concurrent orderings depend on
  // timing. Those muscles are factorised one after another, the others in parallel.
  auto refactorise = [&](std::size_t r) {
    const int mi = refactor[r];
    MuscleSystem& sys = *ws.systems[mi];
    const double mass_term = model.muscles[mi].particle_mass_kg * ctx.mass_scale;
    // contact weights changed only: update/downdate the factor (refactorise now and then to
    // bound round-off); otherwise factorise anew
    if (sys.valid && mass_term == sys.factored_mass_term && sys.modifications < 4 * static_cast<int>(sys.diag.size())) {
      std::vector<std::pair<int, double>> up, down;
      for (std::size_t j = 0; j < sys.diag.size(); ++j) {
        const double delta = sys.weight[j] - sys.factored_weight[j];
        if (delta > 0.0) up.emplace_back(static_cast<int>(j), delta);
        if (delta < 0.0) down.emplace_back(static_cast<int>(j), delta);
      }
      if (sys.factor.modify_diagonal(true, up) && sys.factor.modify_diagonal(false, down)) {
        sys.modifications += static_cast<int>(up.size() + down.size());
        sys.factored_weight = sys.weight;
        return;
      }
    }
    const double* base = sys.K_springs.valuePtr();
    for (std::size_t j = 0; j < sys.diag.size(); ++j)
      sys.K.valuePtr()[sys.diag[j]] = base[sys.diag[j]] + mass_term + sys.weight[j];
    sys.valid = sys.factor.factorise(sys.K);
    failed[mi] = !sys.valid;
    refactorised[mi] = 1;
    sys.modifications = 0;
    sys.factored_weight = sys.weight;
    sys.factored_mass_term = mass_term;
  };
  for (std::size_t r = 0; r < refactor.size(); ++r)
    if (!ws.systems[refactor[r]]->factor.is_analysed()) refactorise(r);
  std::vector<std::size_t> analysed;
  for (std::size_t r = 0; r < refactor.size(); ++r)
    if (refactorised[refactor[r]] == 0) analysed.push_back(r);
  parallel_for(analysed.size(), [&](std::size_t k) { refactorise(analysed[k]); });
  for (int mi = 0; mi < nm; ++mi) info.factorisations += refactorised[mi];
  info.factor_updates += static_cast<int>(refactor.size()) - static_cast<int>(
      std::count(refactorised.begin(), refactorised.end(), 1));
  for (int mi = 0; mi < nm; ++mi)
    if (failed[mi])
      throw_numerical(fmt::format("frame {}: factorisation of the spring system of muscle '{}' "
                                  "failed", frame, model.muscles[mi].name),
                      frame_context(model.muscles[mi].name));
}

// Muscle-muscle targets of this iteration (Jacobi): each pair pushed apart symmetrically to its
// allowed distance (all of the way by the free one when the other is fixed); per particle, the
// mean over its pairs. `active` (optional, per muscle): only the pairs of an active muscle are set
// (see add_surface_particle_targets).
void set_pair_targets(const FibresFirstModel& model, FibresFirstSolver::Workspace& ws,
                      const Points3& snapshot, const std::vector<char>* active = nullptr) {
  // only the rows written in the last iteration are non-zero
  for (int p : ws.target_rows) {
    ws.pair_target.row(p).setZero();
    ws.pair_count[p] = 0;
  }
  ws.target_rows.clear();
  for (const MusclePair& pr : ws.pairs) {
    if (active && !(*active)[model.muscle_of[pr.p]] && !(*active)[model.muscle_of[pr.q]]) continue;
    const Vec3 d = snapshot.row(pr.p) - snapshot.row(pr.q);
    const double dist = d.norm();
    Vec3 tp = snapshot.row(pr.p), tq = snapshot.row(pr.q);
    if (dist < pr.allowed_m) {
      const Vec3 rest_d = model.rest.row(pr.p) - model.rest.row(pr.q);
      const Vec3 n = dist > 1e-12 ? Vec3(d / dist) : Vec3(rest_d.normalized());
      const bool p_fixed = model.role[pr.p] != ParticleRole::free;
      const bool q_fixed = model.role[pr.q] != ParticleRole::free;
      const double share_p = p_fixed ? 0.0 : (q_fixed ? 1.0 : 0.5);
      tp += share_p * (pr.allowed_m - dist) * n;
      tq -= (1.0 - share_p) * (pr.allowed_m - dist) * n;
    }
    ws.pair_target.row(pr.p) += tp.transpose();
    ws.pair_target.row(pr.q) += tq.transpose();
    if (ws.pair_count[pr.p]++ == 0) ws.target_rows.push_back(pr.p);
    if (ws.pair_count[pr.q]++ == 0) ws.target_rows.push_back(pr.q);
  }
}

// The target of a particle held by a bone that is also in a muscle contact (separation only):
// its muscle-contact target (the mean over its pairs and surface contacts) projected onto the
// half-space of each of its bone contacts (the plane through the contact's target point), so it
// slides along the bone instead of being pinned to the point where it met it.
Vec3 calc_sliding_target(const FibresFirstSolver::Workspace& ws, int p, const std::vector<Transform>& motions) {
  const BoneContacts& bc = ws.bone_contacts;
  Vec3 t = ws.pair_target.row(p).transpose() / ws.pair_count[p];
  const int passes = bc.bone[1][p] >= 0 ? 4 : 1;
  for (int pass = 0; pass < passes; ++pass)
    for (int s = 0; s < BoneContacts::slots; ++s) {
      const int b = bc.bone[s][p];
      if (b < 0) continue;
      const Vec3 n = motions[b].linear() * bc.normal_rest[s][p];
      const double below = (motions[b] * bc.target_rest[s][p] - t).dot(n);
      if (below > 0.0) t += below * n;
    }
  return t;
}

// The rotation R maximising tr(R^T A) (the rotation of the polar decomposition of A when
// det A > 0), by the fixed-point iteration of Mueller, Bender, Chentanez and Macklin 2016 ("A
// robust method to extract the rotational part of deformations", eq. 9), warm-started from q and
// written back to it. Each step turns q by the axis-angle vector sum_i r_i x a_i / |sum_i r_i . a_i|
// (r_i, a_i the columns of R and A); the fixed points are the stationary rotations, and the
// maximum is the attracting one.
Mat3 fit_rotation(const Mat3& A, Quat& q) {
  for (int iteration = 0; iteration < 20; ++iteration) {
    const Mat3 R = q.toRotationMatrix();
    const Vec3 omega = (R.col(0).cross(A.col(0)) + R.col(1).cross(A.col(1)) + R.col(2).cross(A.col(2))) /
                       (std::abs(R.col(0).dot(A.col(0)) + R.col(1).dot(A.col(1)) + R.col(2).dot(A.col(2))) + 1e-300);
    const double angle = omega.norm();
    if (!(angle > 1e-12)) break;
    q = Quat(Eigen::AngleAxisd(angle, omega / angle)) * q;
    q.normalize();
  }
  return q.toRotationMatrix();
}

// Ring frames (FibresFirstOptions::surface_frame_stiffness), local step of muscle m: per loft ring,
// the best-fit rigid motion (rest -> snapshot) of the fibre particles anchoring the ring (their
// centre c and rotation R, Procrustes), and for each ring vertex v the target c + R (X_v - C), the
// rest ring moved with its anchors; w times the target is added to the vertex's row of B (its
// diagonal term w is in the constant part of K). A shape-matching constraint in the projective
// dynamics sense (Bouaziz et al. 2014) that acts on the ring only: the ring keeps its rest shape
// and its orientation about the fibres relative to the muscle's interior, and the anchors are not
// pulled by it.
void add_ring_frame_targets(const FibresFirstModel& model, const FibreBundle& m, RingFrames& rings,
                            const Points3& snapshot, double w, const int* position, RowRhs& B) {
  const int K = model.options.surface_ring_points;
  const int s0 = m.first_particle + m.num_fibres * model.options.particles_per_fibre;
  const int num_rings = static_cast<int>(m.ring_frame_start.size()) - 1;
  for (int r = 0; r < num_rings; ++r) {
    const int begin = m.ring_frame_start[r], end = m.ring_frame_start[r + 1];
    Vec3 c = Vec3::Zero();
    for (int k = begin; k < end; ++k) c += snapshot.row(m.ring_frame_particle[k]).transpose();
    c /= end - begin;
    const Vec3& C = rings.rest_centre[r];
    Mat3 A = Mat3::Zero();
    for (int k = begin; k < end; ++k) {
      const int p = m.ring_frame_particle[k];
      A.noalias() += (snapshot.row(p).transpose() - c) * (model.rest.row(p).transpose() - C).transpose();
    }
    const Mat3 R = fit_rotation(A, rings.rotation[r]);
    for (int v = r * K; v < (r + 1) * K; ++v) {
      const int p = s0 + v;
      const Vec3 target = c + R * (model.rest.row(p).transpose() - C);
      B.row(position[m.free_index[p - m.first_particle]]).head<3>() += w * target.transpose();
    }
  }
}

// One local/global iteration of muscle mi from `snapshot` (all particles): spring and contact
// targets (local), the prefactorised solve (global), then the volume step along
// Y = -K^-1 dV/dx (Y refreshed on the first iteration of a round). This is the map G; its value is
// kept in sys.plain. Writes the next iterate into the muscle's rows of x: G's value when the step
// is below the tolerance (converged), else the Anderson-accelerated iterate. Returns the step: the
// largest particle displacement |G(x) - x| over the mean rest spring length.
double relax_muscle(const FrameContext& ctx, FibresFirstSolver::Workspace& ws, int mi,
                    bool first_iteration, const Points3& snapshot, Points3& x, char& volume_failed) {
  const FibresFirstModel& model = ctx.model;
  const FibresFirstOptions& o = model.options;
  const std::vector<Transform>& motions = ctx.motions;
  const FibreBundle& m = model.muscles[mi];
  MuscleSystem& sys = *ws.systems[mi];
  const int nf = static_cast<int>(m.free.size());
  const int base = m.first_particle;
  const bool volume = o.hold_volume && m.surface_triangles.rows() > 0;
  const bool fresh = volume && (first_iteration || sys.volume_direction.rows() != m.num_particles);
  if (first_iteration) sys.anderson.restart();
  // B by rows (RowRhs): lanes 0-2 the spring and contact terms, lanes 3-5 the volume gradient,
  const int ncols = fresh ? 6 : 3, width = fresh ? 8 : 4;
  // row position[j] holds free particle j: the factor's order, so the solve needs no copies
  const int* position = sys.factor.get_positions().data();
  RowRhs B = RowRhs::Zero(nf, width);
  const double* sx = snapshot.col(0).data();
  const double* sy = snapshot.col(1).data();
  const double* sz = snapshot.col(2).data();
  // local step: every spring's rest-length vector along its current direction (in blocks of 256
  // springs, so the vectors stay in cache between the two loops), added to both ends' rows of B
  // four lanes at a time (lane 3 adds k * 0 = +0 to +0, and is overwritten by the volume
  // gradient on a round's first iteration; per lane the same products and sums, in the same
  // spring order, as three scalar columns)
  constexpr int block = 256;
  double d[3 * block];
  const int num_springs = static_cast<int>(sys.springs.size());
  double* rows = B.data();
  for (int s0 = 0; s0 < num_springs; s0 += block) {
    const int count = std::min(block, num_springs - s0);
    spring_vectors::calc(sys.springs.data() + s0, count, sx, sy, sz, model.rest, d);
    spring_vectors::add_to_rows(sys.springs.data() + s0, count, d, sx, sy, sz, position, rows, width);
  }
  if (!sys.rings.rest_centre.empty())
    add_ring_frame_targets(model, m, sys.rings, snapshot, o.surface_frame_stiffness, position, B);
  const double mass_term = m.particle_mass_kg * ctx.mass_scale;
  for (int j = 0; j < nf; ++j) {
    const int p = m.free[j];
    if (ctx.inertial) B.row(position[j]).head<3>() += mass_term * ctx.inertial->row(p);
    if (sys.factored_weight[j] == 0.0) continue;
    const Vec3 target = !ws.bone_contacts.has(p)
                            ? Vec3(ws.pair_target.row(p).transpose() / ws.pair_count[p])
                            : (ws.surfaces.enabled && ws.pair_count[p] > 0
                                   ? calc_sliding_target(ws, p, motions)
                                   : ws.bone_contacts.calc_target(p, motions));
    B.row(position[j]).head<3>() += sys.factored_weight[j] * target.transpose();
  }
  // volume gradient at the current iterate (first iteration of a round only)
  if (fresh) {
    const Points3 g = calc_particle_volume_gradient(m, sys.surface_map, snapshot.middleRows(base, m.num_particles));
    for (int j = 0; j < nf; ++j) B.row(position[j]).segment<3>(3) = g.row(m.free[j] - base);
  }
  // global step, then the volume: x = x_u + t Y with Y = -K^-1 g, t the root of V(t) = V0
  sys.factor.solve_factor_rows(B, ncols);
  Points3 xm = snapshot.middleRows(base, m.num_particles);
  for (int j = 0; j < nf; ++j) xm.row(m.free[j] - base) = B.row(position[j]).head<3>();
  if (fresh) {
    sys.volume_direction = Points3::Zero(m.num_particles, 3);
    for (int j = 0; j < nf; ++j) sys.volume_direction.row(m.free[j] - base) = -B.row(position[j]).segment<3>(3);
    sys.volume_direction_surface = sys.surface_map * sys.volume_direction;
  }
  if (volume) volume_failed = !std::isfinite(hold_volume_along(m, sys.surface_map, xm, sys.volume_direction, sys.volume_direction_surface));
  double largest2 = 0.0;
  sys.plain.resize(nf, 3);
  Eigen::MatrixXd current(nf, 3);
  for (int j = 0; j < nf; ++j) {
    const int p = m.free[j];
    sys.plain.row(j) = xm.row(p - base);
    current.row(j) = snapshot.row(p);
    largest2 = std::max(largest2, (sys.plain.row(j) - current.row(j)).squaredNorm());
  }
  const double step = std::sqrt(largest2) / std::max(m.mean_spring_length_m, 1e-12);
  if (step < o.step_tolerance || o.anderson_window <= 0 || !std::isfinite(step)) {
    sys.anderson.restart();
    x.middleRows(base, m.num_particles) = xm;
    return step;
  }
  const VecX next = sys.anderson.calc_next(Eigen::Map<const VecX>(current.data(), 3 * nf),
                                           Eigen::Map<const VecX>(sys.plain.data(), 3 * nf), step,
                                           o.anderson_window);
  const Eigen::Map<const Eigen::MatrixXd> next_rows(next.data(), nf, 3);
  for (int j = 0; j < nf; ++j) x.row(m.free[j]) = next_rows.row(j);
  return step;
}

// The final projection of a frame (see the comment inside).
void project_final(const FrameContext& ctx, FibresFirstSolver::Workspace& ws, Points3& x,
                   FibresFirstInfo& info) {
  const FibresFirstModel& model = ctx.model;
  const FibresFirstOptions& o = model.options;
  const int N = model.num_particles();
  const int nm = static_cast<int>(model.muscles.size());
  const std::vector<Transform>& motions = ctx.motions;
  // final projection (seed 002's rule, applied to the constraints the iterations left unmet):
  // particles below their bone contact's target plane onto it, pairs of muscles still too close
  // pushed apart, each muscle's volume restored along its correction direction with those
  // particles held; then once more the pairs and bones (the volume step moves the other particles)
  std::vector<char> held(N, 0);
  // onto each contact's target plane; a particle with two contacts alternates between the planes
  // (a few passes: the projections converge to the intersection of the half-spaces)
  const BoneContacts& bc = ws.bone_contacts;
  // snap: a particle with one contact that is below its plane goes to the contact's target point
  // (the closest bone point, moved out by the margin) instead of onto the plane along its normal
  auto project_onto_bones = [&](bool snap = false) {
    for (int p = 0; p < N; ++p) {
      if (!bc.has(p)) continue;
      if (snap && bc.bone[1][p] < 0) {
        const int b = bc.bone[0][p];
        const Vec3 target = motions[b] * bc.target_rest[0][p];
        if ((target - Vec3(x.row(p).transpose())).dot(motions[b].linear() * bc.normal_rest[0][p]) > 0.0) {
          x.row(p) = target.transpose();
          held[p] = 1;
        }
        continue;
      }
      const int passes = bc.bone[1][p] >= 0 ? 4 : 1;
      for (int pass = 0; pass < passes; ++pass)
        for (int s = 0; s < BoneContacts::slots; ++s) {
          const int b = bc.bone[s][p];
          if (b < 0) continue;
          const Vec3 target = motions[b] * bc.target_rest[s][p];
          const Vec3 n = motions[b].linear() * bc.normal_rest[s][p];
          const double below = (target - Vec3(x.row(p).transpose())).dot(n);
          if (below > 0.0) {
            x.row(p) += below * n.transpose();
            held[p] = 1;
          }
        }
    }
  };
  auto push_pairs_apart = [&] {
    for (int pass = 0; pass < 3; ++pass) {  // Gauss-Seidel passes over the pairs
      detect_muscle_pairs(model, x, ws.candidates, ws.pairs, ws.pair_keys, true, nullptr);
      bool moved = false;
      for (const MusclePair& pr : ws.pairs) {
        const Vec3 d = x.row(pr.p) - x.row(pr.q);
        const double dist = d.norm();
        if (dist >= pr.allowed_m) continue;
        const Vec3 n = dist > 1e-12 ? Vec3(d / dist)
                                    : Vec3((model.rest.row(pr.p) - model.rest.row(pr.q)).normalized());
        const bool p_fixed = model.role[pr.p] != ParticleRole::free || held[pr.p] == 1;
        const bool q_fixed = model.role[pr.q] != ParticleRole::free || held[pr.q] == 1;
        if (p_fixed && q_fixed) continue;
        const double share_p = p_fixed ? 0.0 : (q_fixed ? 1.0 : 0.5);
        x.row(pr.p) += (share_p * (pr.allowed_m - dist) * n).transpose();
        x.row(pr.q) -= ((1.0 - share_p) * (pr.allowed_m - dist) * n).transpose();
        moved = true;
      }
      if (!moved) break;
    }
    for (const MusclePair& pr : ws.pairs) {  // held by the volume step (2: movable by pairs)
      held[pr.p] = std::max<char>(held[pr.p], 2);
      held[pr.q] = std::max<char>(held[pr.q], 2);
    }
  };
  // display surfaces: new contacts at x, then Gauss-Seidel passes over all of them; their
  // particles are held by the volume step (2: movable by pairs and surfaces)
  std::vector<std::pair<int, double>> face;
  SurfaceSeparation& ss = ws.surfaces;
  auto push_surfaces_apart = [&] {
    if (!ss.enabled) return;
    detect_surface_contacts(model, ws.systems, x, ss, true, nullptr, nullptr);
    auto movable = [&](int p) { return model.role[p] != ParticleRole::fixed && held[p] != 1; };
    for (int pass = 0; pass < 3; ++pass) {
      bool moved = false;
      for (const SurfaceContact& c : ss.contacts) {
        int pv = -1, pf[3];
        Vec3 n;
        double lambda = 0.0;
        if (calc_particle_contact_step(model, c, x, pv, pf, n, lambda)) {
          // particle surfaces: the contact's own projection (surface particles are never fixed;
          // one held against a bone does not move)
          if (!(lambda > 0.0)) continue;
          const bool v_moves = movable(pv);
          double face_mass = 0.0;
          for (int i = 0; i < 3; ++i) face_mass += movable(pf[i]) ? c.barycentric[i] * c.barycentric[i] : 0.0;
          const double denominator = (v_moves ? 1.0 : 0.0) + face_mass;
          if (!(denominator > 0.0)) continue;
          const double l = lambda * (1.0 + c.barycentric.squaredNorm()) / denominator;
          if (v_moves) x.row(pv) += l * n.transpose();
          for (int i = 0; i < 3; ++i)
            if (movable(pf[i])) x.row(pf[i]) -= (c.barycentric[i] * l) * n.transpose();
          moved = true;
          continue;
        }
        moved = push_surface_contact(model, ss, c, x, movable, face) > 0.0 || moved;
      }
      if (!moved) break;
    }
    for (const SurfaceContact& c : ss.contacts) {  // held by the volume step (particle surfaces)
      const FibreBundle& ma = model.muscles[c.a];
      const FibreBundle& mb = model.muscles[c.b];
      if (ma.num_surface_particles == 0 || mb.num_surface_particles == 0) continue;
      auto hold = [&](int p) { held[p] = std::max<char>(held[p], 2); };
      hold(ma.surface_weight_particle[c.v]);
      for (int i = 0; i < 3; ++i) hold(mb.surface_weight_particle[mb.surface_triangles(c.triangle, i)]);
    }
  };
  auto worst_volume_error = [&] {
    double worst = 0.0;
    for (int mi = 0; mi < nm; ++mi) {
      const FibreBundle& m = model.muscles[mi];
      if (m.surface_triangles.rows() == 0) continue;
      const double V = surface_volume(m, ws.systems[mi]->surface_map * x.middleRows(m.first_particle, m.num_particles));
      worst = std::max(worst, std::abs(V - m.rest_volume_m3) / m.rest_volume_m3);
    }
    return worst;
  };
  // The state with the smallest worst volume error so far among those after a bone projection
  // (see the end): stage 1 after the first, 2 before the passes, 2 + k after pass k
  struct State {
    int stage = 0;
    double error = std::numeric_limits<double>::infinity();
    Points3 x;
    BoneContacts contacts;
  } best;
  int current_stage = 0;  // the stage of the current positions
  const bool keep_best = ss.enabled && o.hold_volume;
  auto consider = [&](int stage, double e) {
    current_stage = stage;
    if (stage == 1) info.final_volume_error_start = e;
    info.final_volume_error = e;
    // a state within volume_tolerance after stage 1 ends the frame: no copy needed
    if (!keep_best || !(e < best.error) || (stage > 1 && e <= o.volume_tolerance)) return;
    best.stage = stage;
    best.error = e;
    best.x = x;
    best.contacts = ws.bone_contacts;
  };
  detect_bone_contacts(ctx, x, ws.bone_contacts, ws.checked_at, ws.clearance, ws.bone_cull, true, nullptr);
  if (ss.enabled) revalidate_far_bone_contacts(ctx, x, ws.bone_contacts);
  project_onto_bones();
  push_pairs_apart();
  if (keep_best) consider(1, worst_volume_error());
  push_surfaces_apart();
  auto restore_volumes = [&] {
    if (!o.hold_volume) return;
    for (int mi = 0; mi < nm; ++mi) {
      const FibreBundle& m = model.muscles[mi];
      const MuscleSystem& sys = *ws.systems[mi];
      if (m.surface_triangles.rows() == 0 || sys.volume_direction.rows() != m.num_particles) continue;
      Points3 Y = sys.volume_direction;
      for (int q = 0; q < m.num_particles; ++q)
        if (held[m.first_particle + q]) Y.row(q).setZero();
      Points3 xm = x.middleRows(m.first_particle, m.num_particles);
      const Points3 SY = sys.surface_map * Y;
      for (int k = 0; k < std::max(1, o.max_volume_iterations); ++k) {
        const double V = surface_volume(m, sys.surface_map * xm);
        if (std::abs(V - m.rest_volume_m3) <= 1e-12 * m.rest_volume_m3) break;
        ++info.volume_iterations;
        if (!std::isfinite(hold_volume_along(m, sys.surface_map, xm, Y, SY))) break;
        x.middleRows(m.first_particle, m.num_particles) = xm;
      }
    }
  };
  restore_volumes();
  push_pairs_apart();
  if (ss.enabled) {
    // the volume step moves the surfaces: separate them again and restore the volumes once more
    // (the surface pushes' particles are not held, so this last volume step can bring back a
    // small overlap; docs/representations.md)
    push_surfaces_apart();
    restore_volumes();
    // the pushes may have moved particles into bones: detect those too (a second contact slot
    // when the particle already holds one)
    detect_bone_contacts(ctx, x, ws.bone_contacts, ws.checked_at, ws.clearance, ws.bone_cull, true, nullptr);
    revalidate_far_bone_contacts(ctx, x, ws.bone_contacts);
  }
  project_onto_bones();
  if (!ss.enabled || !o.hold_volume) return;
  // The last bone projection moves the particles that the volume step or the surface pushes
  // moved into a bone back out; on a coarse loft a millimetre there is a few tenths of a percent
  // of a muscle's volume (gait2392 frame 14 with the stall rule: 6 tibialis posterior surface
  // particles by up to 1.2 mm, 0.52 %, and the frame failed). While some muscle is off by more
  // than volume_tolerance: restore the volumes with those particles held, separate the surfaces
  // again and project onto the bones again (alternating projections, at most 3 passes). On the
  // VH shank no frame needs a pass (volume error <= 3e-4), so its results are unchanged.
  // The passes are alternating projections, which need not converge (gait2392 frame 41 of the
  // walk: 0.22 % before them, 1.5 % and 0.66 % after the first two), and on a muscle squeezed
  // between its neighbours and a bone the surface pushes themselves can take several percent of
  // its volume, which the restore then puts back by bulging the free part of its surface into
  // the next muscle (frame 47: semimem_r -15 % after the first pushes, +4.4 % after the last
  // bone projection). So the final projection never ends worse than it started: when its last
  // state is still off by more than volume_tolerance, the frame ends in the state with the
  // smallest worst volume error among those after a bone projection: the first one, before any
  // surface push (stage 1); the one before the passes (2); the one after each pass (2 + k). The
  // bone contacts are part of a state (detection adds contacts and moves or releases planes for
  // positions the frame then leaves); the caches of the culled tests (bones' clearances,
  // surfaces' tested gaps and travel) are bounds from each particle's last exact test and stay
  // valid for any positions, and surface contacts found on the way are revalidated at the end of
  // the frame.
  double error = worst_volume_error();
  consider(2, error);
  for (int pass = 0; pass < 3 && !(error <= o.volume_tolerance); ++pass) {  // NaN: go on
    ++info.final_passes;
    restore_volumes();
    push_surfaces_apart();
    detect_bone_contacts(ctx, x, ws.bone_contacts, ws.checked_at, ws.clearance, ws.bone_cull, true, nullptr);
    revalidate_far_bone_contacts(ctx, x, ws.bone_contacts);
    project_onto_bones();
    error = worst_volume_error();
    consider(3 + pass, error);
  }
  if (!(error <= o.volume_tolerance) && best.stage > 0 && best.stage != current_stage) {
    x = std::move(best.x);
    ws.bone_contacts = std::move(best.contacts);
    info.final_state_restored = best.stage;
    info.final_volume_error = best.error;
  }
  // The last bone projection moves a particle out along its contact plane's normal; where the
  // bone is concave (or the plane was set a few millimetres away, closer than the revalidation's
  // reach) that can leave it inside another part of the bone (gait2392 frame 49: a lateral
  // gastrocnemius surface particle 3.4 mm inside the femur, on a plane set 3.9 mm away). And a
  // restored stage-1 state has had particle pushes after its bone projection. So the bones are
  // detected again (planes moved to the current closest points) and projected again while that
  // finds a particle inside, at most four times; from the second time on, a particle with one
  // contact is put on its target point (the closest bone point plus the margin) instead of
  // being moved along the plane's normal, which in a crease can go on alternating between the
  // two faces (another frame of the same walk: 0.6 mm inside after four plane projections).
  // Returns whether it projected anything.
  auto check_bones = [&] {
    bool projected = false;
    for (int k = 0; k < 4; ++k) {
      std::vector<char> inside(nm, 0);
      detect_bone_contacts(ctx, x, ws.bone_contacts, ws.checked_at, ws.clearance, ws.bone_cull, true, nullptr, nullptr,
                           &inside);
      if (std::find(inside.begin(), inside.end(), 1) == inside.end()) break;
      revalidate_far_bone_contacts(ctx, x, ws.bone_contacts);
      project_onto_bones(k > 0);
      projected = true;
    }
    return projected;
  };
  // Since the bone contacts' directions on edges and vertices come from the closest point
  // (calc_bone_contact_normal), the check really moves such particles out, and that can cost a
  // muscle its volume: gait2392 frame 151 ended its final projection at 0.14 % in its stage-1
  // state and the check took vas_int_r to 0.54 % (> max_volume_error). So when the check moved
  // particles and some muscle is then off by more than volume_tolerance, the volumes are
  // restored once more with every projected or contact particle held, and the check runs again.
  if (check_bones() && !(worst_volume_error() <= o.volume_tolerance)) {
    restore_volumes();
    check_bones();
  }
}

}  // namespace

void FibresFirstSolver::calc_frame(const FibresFirstInput& input) {
  Workspace& ws = *ws_;
  const FibresFirstModel& model = model_;
  const FibresFirstOptions& o = model.options;
  const int P = o.particles_per_fibre;
  const int N = model.num_particles();
  const int frame = ws.frames++;
  info_ = {};
  info_.frame = frame;

  // bone motions
  std::vector<Transform> motions = input.bone_motions;
  if (motions.empty()) motions.assign(model.num_bones(), Transform::Identity());
  if (static_cast<int>(motions.size()) != model.num_bones())
    throw_bad_input(fmt::format("frame {}: {} bone motions given for {} bones", frame,
                                motions.size(), model.num_bones()));
  for (int b = 0; b < model.num_bones(); ++b)
    if (!motions[b].matrix().allFinite())
      throw_bad_input(fmt::format("frame {}: the motion of bone {} is not finite", frame, b));
  const int nm_in = static_cast<int>(model.muscles.size());
  if (!input.action_lines.empty() && static_cast<int>(input.action_lines.size()) != nm_in)
    throw_bad_input(fmt::format("frame {}: {} action lines given for {} muscles", frame,
                                input.action_lines.size(), nm_in));
  for (std::size_t mi = 0; mi < input.action_lines.size(); ++mi)
    if (input.action_lines[mi].rows() < 2 || !input.action_lines[mi].allFinite())
      throw_bad_input(fmt::format("frame {}: the action line of muscle '{}' has fewer than 2 points "
                                  "or a non-finite one", frame, model.muscles[mi].name),
                      frame_context(model.muscles[mi].name));
  const double h = o.dynamic ? (input.time_step_s > 0.0 ? input.time_step_s : o.default_time_step_s)
                             : 0.0;
  if (o.dynamic && !std::isfinite(h))
    throw_bad_input(fmt::format("frame {}: time step {} s is not finite", frame, input.time_step_s));

  // initial guess: fixed particles follow their bones; free ones move by the blend of their
  // origin and insertion bones' motions since the previous frame (Modenese and Kohout 2020)
  const Points3& before = ws.has_previous ? ws.previous : model.rest;
  std::vector<Transform> step(model.num_bones());
  for (int b = 0; b < model.num_bones(); ++b)
    step[b] = ws.has_previous ? motions[b] * ws.previous_motions[b].inverse() : motions[b];
  Points3 x(N, 3);
  for (std::size_t mi = 0; mi < model.muscles.size(); ++mi) {
    const FibreBundle& m = model.muscles[mi];
    const int ob = m.origin_bone >= 0 ? m.origin_bone : m.insertion_bone;
    const int ib = m.insertion_bone >= 0 ? m.insertion_bone : m.origin_bone;
    // the current action line (carried particles): given, or the rest line moved by the blend
    Points3 line;
    if (m.rest_action_line.rows() >= 2) {
      if (!input.action_lines.empty()) {
        line = input.action_lines[mi];
      } else {
        line = m.rest_action_line;
        for (Eigen::Index k = 0; k < line.rows(); ++k) {
          const double t = detail::calc_line_fraction(m.rest_action_line, line.row(k).transpose());
          const double w = o.blend_a * t * t - (o.blend_a + 1.0) * t + 1.0;
          const Vec3 r = m.rest_action_line.row(k).transpose();
          line.row(k) = (w * (motions[ob] * r) + (1.0 - w) * (motions[ib] * r)).transpose();
        }
      }
    }
    const double rest_line_length = line.rows() >= 2 ? detail::calc_line_length(m.rest_action_line) : 0.0;
    const double line_length = line.rows() >= 2 ? detail::calc_line_length(line) : 0.0;
    for (int p = m.first_particle; p < m.first_particle + m.num_particles; ++p) {
      if (model.role[p] == ParticleRole::fixed) {
        x.row(p) = (motions[model.fixed_bone[p]] * Vec3(model.rest.row(p).transpose())).transpose();
        continue;
      }
      if (model.role[p] == ParticleRole::carried) {
        // the rest offset from the line, turned by the minimal rotation of the line's tangent
        // the point of the current line: the same arc length from the nearer end (tendon) or
        // the same fraction
        const double s0 = model.line_fraction[p];
        const double s = o.carry_inextensible_tendon ? detail::calc_tendon_fraction(s0, rest_line_length, line_length)
                                                     : s0;
        Vec3 c0, t0, c, t;
        detail::calc_line_point(m.rest_action_line, s0, c0, t0);
        detail::calc_line_point(line, s, c, t);
        const Eigen::Quaterniond turn = t.squaredNorm() > 0.0 && t0.squaredNorm() > 0.0
                                            ? Eigen::Quaterniond::FromTwoVectors(t0, t)
                                            : Eigen::Quaterniond::Identity();
        x.row(p) = (c + turn * (Vec3(model.rest.row(p).transpose()) - c0)).transpose();
        continue;
      }
      const double t = model.fibre_t[p];
      const double w = o.blend_a * t * t - (o.blend_a + 1.0) * t + 1.0;
      const Vec3 xb = before.row(p);
      x.row(p) = (w * (step[ob] * xb) + (1.0 - w) * (step[ib] * xb)).transpose();
    }
    // a fibre with a carried end: its free particles move by the interpolation (in fibre
    // position t) of its two ends' displacements, not with the far bone's rigid motion
    for (int f = 0; f < m.num_fibres; ++f) {
      const int p0 = m.first_particle + f * P, p1 = p0 + P - 1;
      if (model.role[p0] != ParticleRole::carried && model.role[p1] != ParticleRole::carried) continue;
      const Vec3 d0 = (x.row(p0) - before.row(p0)).transpose(), d1 = (x.row(p1) - before.row(p1)).transpose();
      for (int p = p0 + 1; p < p1; ++p)
        if (model.role[p] == ParticleRole::free)
          x.row(p) = before.row(p) + ((1.0 - model.fibre_t[p]) * d0 + model.fibre_t[p] * d1).transpose();
    }
    // surface particles whose nearest fibre has a carried end: the same interpolation, at that
    // particle's position t along its fibre
    for (int p = m.first_particle + m.num_fibres * P; p < m.first_particle + m.num_particles; ++p) {
      const int a = model.surface_anchor[p];
      if (a < 0) continue;
      const int p0 = m.first_particle + (a - m.first_particle) / P * P, p1 = p0 + P - 1;
      if (model.role[p0] != ParticleRole::carried && model.role[p1] != ParticleRole::carried) continue;
      const Vec3 d0 = (x.row(p0) - before.row(p0)).transpose(), d1 = (x.row(p1) - before.row(p1)).transpose();
      x.row(p) = before.row(p) + ((1.0 - model.fibre_t[p]) * d0 + model.fibre_t[p] * d1).transpose();
    }
  }
  const Points3 guess = x;  // before the extrapolation: the correction is measured from it
  if (o.extrapolate_correction && ws.has_previous && ws.correction.rows() == N) x += ws.correction;
  Points3 inertial;
  if (o.dynamic) {
    // y = x_n + h v_n / (1 + c h): the inertial position with implicit velocity damping
    inertial = before;
    if (ws.has_previous)
      inertial += h / (1.0 + o.damping_per_s * h) * ws.velocity;
  }
  const FrameContext ctx{model, motions, o.dynamic ? &inertial : nullptr,
                         o.dynamic ? 1.0 / (h * h) : 0.0, o.contact_weight * o.along_stiffness};

  // contacts at the start: previous bone contacts (kept unless released last frame), new ones
  ws.pairs.clear();
  ws.pair_keys.clear();
  // surface contacts kept from the previous frame (see the end of calc_frame) stay active; with
  // separation, kept bone contacts far from their particle are re-evaluated first
  if (ws.surfaces.enabled) revalidate_far_bone_contacts(ctx, x, ws.bone_contacts);
  detect_bone_contacts(ctx, x, ws.bone_contacts, ws.checked_at, ws.clearance, ws.bone_cull, true, nullptr);
  detect_muscle_pairs(model, x, ws.candidates, ws.pairs, ws.pair_keys, true, nullptr);
  detect_surface_contacts(model, ws.systems, x, ws.surfaces, true, nullptr, nullptr);
  const int nm = static_cast<int>(model.muscles.size());
  std::vector<double> steps(nm, 0.0);
  std::vector<char> volume_failed(nm, 0);
  Points3 snapshot;
  // Round-start wake rule (separation only): in a later round, only the muscles that had not
  // converged, whose factor changed, or that take part in a contact the last detection added (or
  // a bone contact whose plane it moved) iterate from its start; the others rest (at the fixed point of an unchanged map)
  // until a neighbour wakes them. Before, every muscle iterated at least once per round (a
  // six-column solve: the volume direction is refreshed on a muscle's first iteration of a round).
  const bool round_wake = ws.surfaces.enabled;
  std::vector<char> touched(nm, 1);
  for (int round = 0; round < o.max_contact_rounds; ++round) {
    ++info_.contact_rounds;
    update_factors(ctx, ws, frame, info_, &touched);

    // local/global iterations; a muscle whose step is below the tolerance rests until a muscle it
    // touches (an active pair) moves again
    std::vector<std::vector<int>> partners(nm);
    for (const MusclePair& pr : ws.pairs) {
      const int a = model.muscle_of[pr.p], b = model.muscle_of[pr.q];
      partners[a].push_back(b);
      partners[b].push_back(a);
    }
    for (auto& list : partners) {
      std::sort(list.begin(), list.end());
      list.erase(std::unique(list.begin(), list.end()), list.end());
    }
    std::vector<char> active(nm, 1), first(nm, 1);
    if (round_wake) active = touched;
    // stall rule (separation only): per muscle, the smallest step of this round and the
    // iterations since the step last fell below 0.9 x that smallest step
    const bool stall_rule = ws.surfaces.enabled && o.stall_iterations > 0;
    std::vector<double> best_step(nm, std::numeric_limits<double>::infinity());
    std::vector<int> since_best(nm, 0);
    // the muscles whose rows of x the last iteration wrote: the snapshot copies and the finiteness
    // check cover all rows at a round's first iteration and only those rows after it (the other
    // rows are unchanged since)
    std::vector<char> ran(nm, 1);
    auto rows_of = [&](Points3& m, int mi) {
      return m.middleRows(model.muscles[mi].first_particle, model.muscles[mi].num_particles);
    };
    for (int it = 0; it < o.max_iterations; ++it) {
      ++info_.iterations;
      if (it == 0 || snapshot.rows() != x.rows()) {
        snapshot = x;
      } else {
        for (int mi = 0; mi < nm; ++mi)
          if (ran[mi]) rows_of(snapshot, mi) = rows_of(x, mi);
      }
      set_pair_targets(model, ws, snapshot, &active);
      add_surface_particle_targets(model, ws, snapshot, &active);
      // every other iteration in reverse muscle order, so the muscle relaxed last in one
      // iteration is relaxed first in the next, while its factor, springs and rows are still in
      // the core's cache (the muscles of an iteration are independent: any order gives the same
      // bits, as any thread count does)
      parallel_for(static_cast<std::size_t>(nm), [&](std::size_t k) {
        const std::size_t mi = it % 2 == 0 ? k : static_cast<std::size_t>(nm) - 1 - k;
        if (!active[mi]) return;
        steps[mi] = relax_muscle(ctx, ws, static_cast<int>(mi), first[mi] != 0, snapshot, x,
                                 volume_failed[mi]);
      });
      for (int mi = 0; mi < nm; ++mi) {
        info_.solves += active[mi];
        // a muscle's first iteration of the round is the first one it takes part in
        if (active[mi] || !round_wake) first[mi] = 0;
      }
      info_.residual = *std::max_element(steps.begin(), steps.end());
      ran = active;
      bool finite = true;
      if (it == 0) {
        finite = x.allFinite();
      } else {
        for (int mi = 0; mi < nm && finite; ++mi) finite = !active[mi] || rows_of(x, mi).allFinite();
      }
      if (!finite || !std::isfinite(info_.residual)) {
        int bad = 0;
        for (int mi = 0; mi < nm; ++mi)
          if (!std::isfinite(steps[mi]) ||
              !x.middleRows(model.muscles[mi].first_particle, model.muscles[mi].num_particles).allFinite()) {
            bad = mi;
            break;
          }
        throw_numerical(fmt::format("frame {}: the fibres-first solve of muscle '{}' diverged "
                                    "(non-finite particle positions)", frame, model.muscles[bad].name),
                        frame_context(model.muscles[bad].name,
                                      "check the bone motions of this frame and the stiffness options"));
      }
      std::vector<char> moving(nm, 0);
      for (int mi = 0; mi < nm; ++mi) moving[mi] = active[mi] && steps[mi] >= o.step_tolerance;
      // a muscle whose step has not fallen by 10 % in stall_iterations iterations counts as not
      // moving: it rests, and it no longer wakes its neighbours (it iterates again when woken)
      if (stall_rule)
        for (int mi = 0; mi < nm; ++mi) {
          if (!active[mi]) continue;
          if (steps[mi] < 0.9 * best_step[mi]) {
            best_step[mi] = steps[mi];
            since_best[mi] = 0;
          } else if (++since_best[mi] >= o.stall_iterations) {
            moving[mi] = 0;
          }
        }
      // surface contacts: a muscle rests on unless the other side's particles of one of its
      // contacts moved by the tolerance in this iteration (its contact targets changed); a
      // moving partner elsewhere on its surface does not wake it (the particle pairs keep the
      // coarser rule: any moving partner)
      std::vector<char> pushed(nm, 0);
      if (ws.surfaces.enabled) {
        auto moved = [&](int p, int mi) {
          return (x.row(p) - snapshot.row(p)).norm() >= o.step_tolerance * model.muscles[mi].mean_spring_length_m;
        };
        for (const SurfaceContact& c : ws.surfaces.contacts) {
          const FibreBundle& ma = model.muscles[c.a];
          const FibreBundle& mb = model.muscles[c.b];
          if (ma.num_surface_particles == 0 || mb.num_surface_particles == 0) continue;
          if (!pushed[c.b] && moving[c.a] && moved(ma.surface_weight_particle[c.v], c.b)) pushed[c.b] = 1;
          if (!pushed[c.a] && moving[c.b])
            for (int i = 0; i < 3; ++i)
              if (moved(mb.surface_weight_particle[mb.surface_triangles(c.triangle, i)], c.a)) pushed[c.a] = 1;
        }
      }
      bool any = false;
      for (int mi = 0; mi < nm; ++mi) {
        active[mi] = moving[mi] || pushed[mi];
        for (int other : partners[mi]) active[mi] = active[mi] || moving[other];
        any = any || active[mi];
      }
      if (!any) break;
    }
    // muscles stopped by max_iterations end on the map's value (volume held), not a mixed iterate
    for (int mi = 0; mi < nm; ++mi) {
      const FibreBundle& m = model.muscles[mi];
      const MuscleSystem& sys = *ws.systems[mi];
      if (steps[mi] < o.step_tolerance || sys.plain.rows() != static_cast<Eigen::Index>(m.free.size())) continue;
      for (std::size_t j = 0; j < m.free.size(); ++j) x.row(m.free[j]) = sys.plain.row(j);
    }
    // new contacts? (after the last round, the final projection below detects them)
    if (round + 1 == o.max_contact_rounds) break;
    for (int mi = 0; mi < nm; ++mi) touched[mi] = steps[mi] >= o.step_tolerance;
    const std::size_t pairs_before = ws.pairs.size();
    const int added_bone = detect_bone_contacts(ctx, x, ws.bone_contacts, ws.checked_at, ws.clearance, ws.bone_cull,
                                                true, nullptr, &touched);
    const int added_pairs = detect_muscle_pairs(model, x, ws.candidates, ws.pairs, ws.pair_keys, true, nullptr);
    const int added_surf = detect_surface_contacts(model, ws.systems, x, ws.surfaces, true, nullptr,
                                                   nullptr, &touched);
    for (std::size_t k = pairs_before; k < ws.pairs.size(); ++k)
      touched[model.muscle_of[ws.pairs[k].p]] = touched[model.muscle_of[ws.pairs[k].q]] = 1;
    const int added = added_bone + added_pairs + added_surf;
    if (added == 0) break;
  }

  // before the final projection: decides which bone contacts stay (separation only, see below)
  const Points3 converged = ws.surfaces.enabled ? x : Points3();
  project_final(ctx, ws, x, info_);

  // results and checks
  std::vector<FibreBundleFrame> frames(nm);
  std::vector<double> depth(nm, 0.0), overlap(nm, 0.0);
  detect_bone_contacts(ctx, x, ws.bone_contacts, ws.checked_at, ws.clearance, ws.bone_cull, false, &depth);
  std::vector<MusclePair> no_pairs;
  std::unordered_set<long long> no_keys;
  detect_muscle_pairs(model, x, ws.candidates, no_pairs, no_keys, false, &overlap);
  std::vector<double> surface_depth(nm, 0.0), surface_beyond(nm, 0.0);
  detect_surface_contacts(model, ws.systems, x, ws.surfaces, false, &surface_depth, &surface_beyond);
  for (int mi = 0; mi < nm; ++mi) {
    const FibreBundle& m = model.muscles[mi];
    FibreBundleFrame& fr = frames[mi];
    fr.particles = x.middleRows(m.first_particle, m.num_particles);
    if (m.surface_triangles.rows() > 0) {
      fr.surface_vertices = ws_->systems[mi]->surface_map * x.middleRows(m.first_particle, m.num_particles);
      fr.volume_m3 = surface_volume(m, fr.surface_vertices);
      fr.relative_volume_error = std::abs(fr.volume_m3 - m.rest_volume_m3) / m.rest_volume_m3;
    }
    fr.max_bone_penetration_m = depth[mi];
    fr.max_muscle_overlap_m = overlap[mi];
    fr.max_surface_overlap_m = surface_depth[mi];
    fr.max_surface_overlap_beyond_rest_m = surface_beyond[mi];
    if (o.hold_volume && !(fr.relative_volume_error <= o.max_volume_error))
      throw_numerical(fmt::format("frame {}: the volume of muscle '{}' could not be held (relative "
                                  "error {:.3g} > {:.3g}{})", frame, m.name, fr.relative_volume_error,
                                  o.max_volume_error, volume_failed[mi] ? "; no volume root" : ""),
                      frame_context(m.name, "the deformation is too large for one frame; use "
                                            "smaller steps between frames or more iterations"));
  }
  for (int p = 0; p < N; ++p)
    for (int s = 0; s < BoneContacts::slots; ++s)
      if (ws.bone_contacts.bone[s][p] >= 0) ++frames[model.muscle_of[p]].bone_contacts;
  for (const MusclePair& pr : ws.pairs) {
    ++frames[model.muscle_of[pr.p]].muscle_contacts;
    ++frames[model.muscle_of[pr.q]].muscle_contacts;
  }
  for (const SurfaceContact& c : ws.surfaces.contacts) {
    ++frames[c.a].surface_contacts;
    ++frames[c.b].surface_contacts;
  }

  // release bone contacts whose particle the springs pull away from the bone
  // (each contact on its own; a remaining second contact moves to the first slot). With display
  // surface separation this is decided on the converged iterate, before the final projection: the
  // projection puts a particle held below its plane onto the plane, where the test reads about 0
  // and released contacts that the springs still press into the bone, so they were found again
  // after the next frame's first round, up to 6 mm deep, and cost a second round (VH shank:
  // 20.4 -> 16.8 iterations and 2.7 -> 1.9 rounds per frame). The default path keeps the test
  // after the projection, so its results stay as they were (there: 14.2 -> 13.0 iterations).
  BoneContacts& bc = ws.bone_contacts;
  for (int p = 0; p < N; ++p) {
    if (!bc.has(p)) continue;
    for (int s = 0; s < BoneContacts::slots; ++s) {
      const int b = bc.bone[s][p];
      if (b < 0) continue;
      const Vec3 target = motions[b] * bc.target_rest[s][p];
      const Vec3 n = motions[b].linear() * bc.normal_rest[s][p];
      const Points3& at = ws.surfaces.enabled ? converged : x;
      if ((target - Vec3(at.row(p).transpose())).dot(n) < 0.0) bc.bone[s][p] = -1;
    }
    if (bc.bone[0][p] < 0 && bc.bone[1][p] >= 0) {
      bc.bone[0][p] = bc.bone[1][p];
      bc.target_rest[0][p] = bc.target_rest[1][p];
      bc.normal_rest[0][p] = bc.normal_rest[1][p];
      bc.bone[1][p] = -1;
    }
  }

  // surface contacts: those still holding (calc_contact_holds: gap below the minimum plus the
  // margin, vertex over its face) stay active in the next frame, so its first round already holds
  // them; the others are released
  if (ws.surfaces.enabled) {
    SurfaceSeparation& ss = ws.surfaces;
    update_surfaces(model, ws.systems, x, ss);
    std::vector<SurfaceContact> kept;
    ss.keys.clear();
    for (const SurfaceContact& c : ss.contacts) {
      if (!calc_contact_holds(model, ss, c, x, o.surface_margin_m)) continue;
      ss.keys.emplace(get_contact_key(c.a, c.v, c.b, nm), static_cast<int>(kept.size()));
      kept.push_back(c);
    }
    ss.contacts = std::move(kept);
  }

  // commit
  if (o.dynamic) {
    ws.velocity = ws.has_previous ? Points3((x - ws.previous) / h) : Points3(Points3::Zero(N, 3));
  }
  ws.correction = x - guess;
  ws.previous = x;
  ws.previous_motions = motions;
  ws.has_previous = true;
  x_ = std::move(x);
  frames_ = std::move(frames);
}

std::vector<FibreBundleFrame> calc_fibres_first_frame(const FibresFirstModel& model,
                                                      const FibresFirstInput& input) {
  FibresFirstSolver solver(model);
  solver.calc_frame(input);
  return solver.get_muscles();
}

}  // namespace fascicle
