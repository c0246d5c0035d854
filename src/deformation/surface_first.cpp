// Surface-first deformation: binding, per-frame Laplacian editing with the exact volume constraint,
// and bone contacts (see surface_first.hpp and docs/deformation.md).
#include "fascicle/deformation/surface_first.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/sparse/supernodal_solve.hpp"

#include <omp.h>

#include <Eigen/CholmodSupport>
#include <Eigen/LU>
#include <Eigen/SparseCholesky>

#include <algorithm>
#include <array>
#include <cmath>
#include <initializer_list>
#include <iterator>
#include <fmt/format.h>

namespace fascicle {

namespace {

ErrorContext muscle_context(const std::string& name, std::string suggestion = {}) {
  return {.object = name, .suggestion = std::move(suggestion)};
}

double bbox_diagonal(const Points3& V) {
  return (V.colwise().maxCoeff() - V.colwise().minCoeff()).norm();
}

// Scatters free-vertex rows and fixed-vertex rows into a full #V x 3 array.
Points3 assemble(const SurfaceBinding& b, const Points3& free_rows, const Points3& fixed_rows) {
  Points3 X(b.rest.V.rows(), 3);
  for (std::size_t k = 0; k < b.free_vertices.size(); ++k) X.row(b.free_vertices[k]) = free_rows.row(k);
  for (std::size_t k = 0; k < b.fixed_vertices.size(); ++k)
    X.row(b.fixed_vertices[k]) = fixed_rows.row(k);
  return X;
}

Points3 gather_free(const SurfaceBinding& b, const Points3& X) {
  Points3 out(b.free_vertices.size(), 3);
  for (std::size_t k = 0; k < b.free_vertices.size(); ++k) out.row(k) = X.row(b.free_vertices[k]);
  return out;
}

// start + sign * (row k of A X) for a matrix A stored by rows (sign = +1 or -1): the row's terms
// added to `start` one at a time in column order. These are the sums, in the order, of Eigen's
// column-major sparse products (which scatter column by column; `D - A X` is evaluated as D, then
// each term subtracted), so the result has their bits; a gather runs without their
// read-modify-write chains through the result.
template <int Sign>
inline Eigen::Matrix<double, 1, 3> calc_row_product(const RowSparseMatrix& A, Eigen::Index k, const Points3& X,
                                                    Eigen::Matrix<double, 1, 3> start) {
  double s0 = start[0], s1 = start[1], s2 = start[2];
  const int* inner = A.innerIndexPtr();
  const double* value = A.valuePtr();
  const Eigen::Index rows = X.rows();
  const double* x = X.data();
  for (int q = A.outerIndexPtr()[k]; q < A.outerIndexPtr()[k + 1]; ++q) {
    const double v = value[q];
    const Eigen::Index j = inner[q];
    if constexpr (Sign > 0) {
      s0 += v * x[j];
      s1 += v * x[j + rows];
      s2 += v * x[j + 2 * rows];
    } else {
      s0 -= v * x[j];
      s1 -= v * x[j + rows];
      s2 -= v * x[j + 2 * rows];
    }
  }
  return {s0, s1, s2};
}

// The per-frame right-hand side without contacts: Lf^T (D - Lx X_fixed) + w_line S_free.
Points3 calc_base_rhs(const SurfaceBinding& b, const Points3& D, const Points3& S, const Points3& fixed,
                      double line_weight) {
  Points3 M(D.rows(), 3);
  for (Eigen::Index i = 0; i < D.rows(); ++i) M.row(i) = calc_row_product<-1>(b.L_fixed, i, fixed, D.row(i));
  Points3 rhs(static_cast<Eigen::Index>(b.free_vertices.size()), 3);
  for (Eigen::Index k = 0; k < rhs.rows(); ++k)
    rhs.row(k) = calc_row_product<1>(b.Lf_transpose, k, M, Eigen::Matrix<double, 1, 3>::Zero()) +
                 line_weight * S.row(b.free_vertices[static_cast<std::size_t>(k)]);
  return rhs;
}

Eigen::AlignedBox3d calc_padded_box(const Points3& B) {
  Eigen::AlignedBox3d box(B.colwise().minCoeff().transpose(), B.colwise().maxCoeff().transpose());
  const double pad = 1e-9 * box.diagonal().norm();
  box.min().array() -= pad;
  box.max().array() += pad;
  return box;
}

// Winding number of `surface` at p by one ray's signed crossings (exact for closed surfaces, also
// nested or overlapping shells); the ray vote's yes/no (0 or 1) when every ray grazes an edge.
int calc_winding_by_ray(const MeshQuery& surface, const Vec3& p) {
  static constexpr double kDirections[3][3] = {{0.3015113445777636, 0.4522670168666454, 0.8392497325522977},
                                               {-0.6837634587578276, 0.5318160234783104, -0.4999999999999999},
                                               {0.5773502691896258, -0.8017837257372732, 0.1543033499620919}};
  for (const auto& d : kDirections)
    if (const std::optional<int> w = surface.calc_crossing_number(p, Vec3(d[0], d[1], d[2]))) return *w;
  return surface.calc_is_inside(p) ? 1 : 0;
}

}  // namespace

VertexAdjacency make_vertex_adjacency(const Triangles& F, Eigen::Index num_vertices) {
  VertexAdjacency g;
  g.start.assign(static_cast<std::size_t>(num_vertices) + 1, 0);
  g.neighbours.resize(static_cast<std::size_t>(F.rows()) * 6);
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    for (int k = 0; k < 3; ++k) g.start[F(f, k) + 1] += 2;
  for (Eigen::Index i = 0; i < num_vertices; ++i) g.start[i + 1] += g.start[i];
  std::vector<int> fill(g.start.begin(), g.start.end() - 1);
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    for (int k = 0; k < 3; ++k) {
      const int a = F(f, k);
      g.neighbours[fill[a]++] = F(f, (k + 1) % 3);
      g.neighbours[fill[a]++] = F(f, (k + 2) % 3);
    }
  // Each edge of a closed surface lies in two triangles, so every neighbour came twice: keep its
  // first occurrence only (in place, rows compacted). A walk over the rows then meets the
  // neighbours in the same order as over the doubled rows, and does half the work.
  int out = 0;
  for (Eigen::Index i = 0; i < num_vertices; ++i) {
    const int begin = g.start[i], end = g.start[i + 1];
    g.start[i] = out;
    for (int k = begin; k < end; ++k) {
      const int q = g.neighbours[k];
      if (std::find(g.neighbours.begin() + g.start[i], g.neighbours.begin() + out, q) == g.neighbours.begin() + out)
        g.neighbours[out++] = q;
    }
  }
  g.start[num_vertices] = out;
  g.neighbours.resize(static_cast<std::size_t>(out));
  return g;
}

bool propagate_winding(const Points3& P, const VertexAdjacency& graph, const MeshQuery& surface,
                       std::vector<int>& winding, int max_whole_rays) {
  int whole_rays = 0;
  const auto whole_ray = [&](int i) {
    ++whole_rays;
    return calc_winding_by_ray(surface, Vec3(P.row(i).transpose()));
  };
  const Eigen::Index n = P.rows();
  std::vector<int> queue;
  queue.reserve(static_cast<std::size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i)
    if (winding[i] >= 0) queue.push_back(static_cast<int>(i));
  std::size_t head = 0;
  Eigen::Index next_seed = 0;
  for (;;) {
    while (head < queue.size()) {
      const int p = queue[head++];
      const Vec3 xp = P.row(p).transpose();
      for (int k = graph.start[p]; k < graph.start[p + 1]; ++k) {
        const int q = graph.neighbours[k];
        if (winding[q] >= 0) continue;
        const Vec3 d = Vec3(P.row(q).transpose()) - xp;
        int w = winding[p];
        bool grazed = d.squaredNorm() == 0.0;
        if (!grazed) {
          for (const RayHit& h : surface.cast_ray_all(xp, d, 0.0, 1.0)) {
            if (!(h.barycentric.minCoeff() > 1e-12) || std::abs(h.normal.dot(d)) <= 1e-12 * d.norm()) grazed = true;
            w += h.front_facing ? 1 : -1;  // entering through a face raises the winding number
          }
        }
        winding[q] = (grazed || w < 0) ? whole_ray(q) : w;
        queue.push_back(q);
        if (max_whole_rays >= 0 && whole_rays > max_whole_rays) return false;
      }
    }
    while (next_seed < n && winding[next_seed] >= 0) ++next_seed;
    if (next_seed >= n) break;
    winding[next_seed] = whole_ray(static_cast<int>(next_seed));
    queue.push_back(static_cast<int>(next_seed));
    if (max_whole_rays >= 0 && whole_rays > max_whole_rays) return false;
  }
  return true;
}

// ---------------------------------------------------------------------------------------------
// Binding

SurfaceBinding bind_surface(const TriMesh& rest_surface, const Points3& rest_action_line,
                            std::vector<SurfaceAttachment> attachments, const BoneQueries& bones,
                            const SurfaceFirstOptions& options, std::string name) {
  SurfaceBinding b;
  b.name = std::move(name);
  b.options = options;
  b.rest = rest_surface;
  const Eigen::Index n = rest_surface.V.rows();
  if (!(options.line_weight > 0.0) || !(options.contact_weight > 0.0) || options.line_samples < 2 ||
      options.max_contact_rounds < 1 || options.max_volume_iterations < 1)
    throw_usage("invalid surface-first options (weights must be > 0, samples >= 2, rounds >= 1)",
                muscle_context(b.name));
  if (n < 4 || rest_surface.F.rows() < 4 || !rest_surface.V.allFinite())
    throw_bad_input("muscle surface is empty or has non-finite coordinates", muscle_context(b.name));

  // operators and volume
  b.laplacian = calc_laplacian(rest_surface, options.laplacian);
  b.size_m = bbox_diagonal(rest_surface.V);
  const Vec3 centre = rest_surface.V.colwise().mean().transpose();
  b.rest_volume_m3 = calc_enclosed_volume(rest_surface.V, rest_surface.F, centre);
  if (!(b.rest_volume_m3 > 1e-12 * std::pow(b.size_m, 3)))
    throw_bad_input(fmt::format("muscle surface encloses no positive volume ({:.3g} m^3)",
                                b.rest_volume_m3),
                    muscle_context(b.name, "the surface must be closed with outward normals; "
                                           "repair it (fascicle mesh repair) first"));

  // action line frames and per-vertex binding
  b.rest_line = calc_framed_line(rest_action_line, options.line_samples,
                                 calc_default_start_frame(rest_action_line));
  const Points3 delta = b.laplacian * rest_surface.V;
  b.vertex_s.resize(n);
  b.offset_local.resize(n, 3);
  b.delta_local.resize(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) {
    const Vec3 v = rest_surface.V.row(i);
    b.vertex_s[i] = find_closest_line_parameter(b.rest_line, v).s;
    const LinePoint lp = calc_line_point(b.rest_line, b.vertex_s[i]);
    const Mat3 Rt = lp.frame.toRotationMatrix().transpose();
    b.offset_local.row(i) = (Rt * (v - lp.point)).transpose();
    b.delta_local.row(i) = (Rt * delta.row(i).transpose()).transpose();
  }

  // attachment areas -> fixed and free vertex sets
  std::vector<int> area_of(n, -1);
  for (std::size_t a = 0; a < attachments.size(); ++a) {
    if (attachments[a].vertices.empty())
      throw_bad_input(fmt::format("attachment area '{}' has no vertices", attachments[a].name),
                      muscle_context(b.name, "check that the area lies on the muscle surface"));
    for (int v : attachments[a].vertices) {
      if (v < 0 || v >= n)
        throw_bad_input(fmt::format("attachment area '{}' has vertex {} out of range [0, {})",
                                    attachments[a].name, v, n),
                        muscle_context(b.name));
      if (area_of[v] >= 0 && area_of[v] != static_cast<int>(a))
        throw_bad_input(fmt::format("vertex {} belongs to attachment areas '{}' and '{}'", v,
                                    attachments[area_of[v]].name, attachments[a].name),
                        muscle_context(b.name, "attachment areas must not overlap"));
      area_of[v] = static_cast<int>(a);
    }
  }
  b.attachments = std::move(attachments);
  b.free_index.assign(n, -1);
  std::vector<int> fixed_index(n, -1);
  for (int i = 0; i < n; ++i) {
    if (area_of[i] >= 0) {
      fixed_index[i] = static_cast<int>(b.fixed_vertices.size());
      b.fixed_vertices.push_back(i);
      b.fixed_area.push_back(area_of[i]);
    } else {
      b.free_index[i] = static_cast<int>(b.free_vertices.size());
      b.free_vertices.push_back(i);
    }
  }
  if (b.free_vertices.empty())
    throw_bad_input("every vertex is in an attachment area; nothing to deform",
                    muscle_context(b.name));

  // split L by columns: L = Lf Pf + Lx Px
  const int nf = static_cast<int>(b.free_vertices.size());
  const int nx = static_cast<int>(b.fixed_vertices.size());
  std::vector<Eigen::Triplet<double>> tf, tx;
  for (int j = 0; j < b.laplacian.outerSize(); ++j)
    for (SparseMatrix::InnerIterator it(b.laplacian, j); it; ++it) {
      if (b.free_index[j] >= 0) tf.emplace_back(b.free_index[j], it.row(), it.value());
      else tx.emplace_back(it.row(), fixed_index[j], it.value());
    }
  SparseMatrix Lf_transpose(nf, n), L_fixed(n, nx);
  Lf_transpose.setFromTriplets(tf.begin(), tf.end());
  L_fixed.setFromTriplets(tx.begin(), tx.end());
  b.Lf_transpose = Lf_transpose;  // the same entries, stored by rows
  b.L_fixed = L_fixed;

  // normal-equation matrix Lf^T Lf + w_line I (the identity also puts every diagonal entry in the
  // pattern, so contact weights never change the sparsity pattern)
  // (Eigen's conservative product, then its exact zeros dropped: the entries and values of
  // .pruned() on the product, without the slower pruning product)
  SparseMatrix LtL = Lf_transpose * SparseMatrix(Lf_transpose.transpose());
  LtL.prune(0.0, 0.0);
  b.diagonal_scale = LtL.diagonal().mean();
  SparseMatrix I(nf, nf);
  I.setIdentity();
  b.system = LtL + (options.line_weight * b.diagonal_scale) * I;
  b.system.makeCompressed();

  b.adjacency = make_vertex_adjacency(rest_surface.F, n);

  // rest-pose depth inside every bone
  for (const MeshQuery* bone : bones) {
    if (!bone) throw_usage("null bone query", muscle_context(b.name));
    VecX depth = VecX::Zero(n);
    VecX clearance = bone->calc_distances(rest_surface.V);
    // only vertices inside the bone's (padded) bounding box can be inside the bone (the rule of
    // SurfaceFirstSolver::update_contacts); the ray votes run on those alone
    const Eigen::AlignedBox3d box = calc_padded_box(bone->get_mesh().V);
    std::vector<Eigen::Index> in_box;
    for (Eigen::Index i = 0; i < n; ++i)
      if (box.contains(rest_surface.V.row(i).transpose())) in_box.push_back(i);
    Points3 P(static_cast<Eigen::Index>(in_box.size()), 3);
    for (std::size_t k = 0; k < in_box.size(); ++k) P.row(static_cast<Eigen::Index>(k)) = rest_surface.V.row(in_box[k]);
    const InsideFlags inside = bone->calc_is_inside(P);
    for (std::size_t k = 0; k < in_box.size(); ++k) {
      if (!inside[static_cast<Eigen::Index>(k)]) continue;
      const Eigen::Index i = in_box[k];
      depth[i] = clearance[i];
      clearance[i] = 0.0;
    }
    b.rest_bone_depth.push_back(std::move(depth));
    b.rest_bone_clearance.push_back(std::move(clearance));
  }
  return b;
}

// ---------------------------------------------------------------------------------------------
// Solver

// Debian's CHOLMOD is built with OpenMP and opens a thread team in its supernodal kernels. Our
// parallelism is over muscles (TBB); nested OpenMP teams on top of it only wake sleeping threads
// (measured: 25 % of a frame in futex wake-ups on two cores). Limit the calling thread's OpenMP
// team to itself before each CHOLMOD call (the ICV is per thread, so this is cheap and local).
// CHOLMOD 3's supernodal numeric factorisation also asks for a fixed team (num_threads(4) on its
// copy loops), which overrides that ICV: those teams spun on the two cores for ≈ 8 % of the VH
// shank run's CPU. With no active parallel level allowed, every OpenMP region runs on the thread
// that meets it (same arithmetic, so the same results). In libgomp that limit may be one value for
// the whole process rather than per thread: harmless here, as fascicle parallelises with TBB and
// wants no OpenMP teams anywhere; each caller writes the same value.
void use_single_threaded_cholmod() {
  omp_set_num_threads(1);
  if (omp_get_max_active_levels() != 0) omp_set_max_active_levels(0);
  use_single_threaded_blas();
}

// Eigen's CHOLMOD supernodal LL^T with its factor reachable (Eigen keeps it as a protected
// member), so the solves can apply it with fascicle/sparse's kernels.
struct CholmodLLT : Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> {
  const void* get_factor() const { return m_cholmodFactor; }
  const int* get_permutation() const {
    return m_cholmodFactor ? static_cast<const int*>(m_cholmodFactor->Perm) : nullptr;
  }
  // Symbolic analysis with the fill-reducing ordering `methods` (CHOLMOD's default strategy when
  // empty; else it tries each and keeps the best), or with the given permutation `perm`.
  void analyse(const SparseMatrix& K, std::initializer_list<int> methods, const int* perm = nullptr) {
    cholmod_common& c = cholmod();
    if (m_cholmodFactor) cholmod_free_factor(&m_cholmodFactor, &c);
    cholmod_sparse A = Eigen::viewAsCholmod(K.selfadjointView<Eigen::Lower>());
    // The method table is restored below, with nmethods = 0 (CHOLMOD's default strategy).
    std::array<cholmod_common::cholmod_method_struct, CHOLMOD_MAXMETHODS + 1> saved;
    std::copy(std::begin(c.method), std::end(c.method), saved.begin());
    c.nmethods = 0;
    if (perm) {
      c.nmethods = 1;
      c.method[0].ordering = CHOLMOD_GIVEN;
    }
    for (int m : methods) c.method[c.nmethods++].ordering = m;
    m_cholmodFactor = cholmod_analyze_p(&A, const_cast<int*>(perm), nullptr, 0, &c);
    c.nmethods = 0;
    std::copy(saved.begin(), saved.end(), std::begin(c.method));
    m_isInitialized = true;
    m_info = m_cholmodFactor ? Eigen::Success : Eigen::NumericalIssue;
    m_analysisIsOk = m_cholmodFactor != nullptr;
    m_factorizationIsOk = false;
  }
  // Flops of a simplicial factorisation per entry of L for the selected ordering (after analyse).
  double get_flops_per_entry() {
    const cholmod_common& c = cholmod();
    return c.lnz > 0.0 ? c.fl / c.lnz : 0.0;
  }
};

// One sparse Cholesky factorisation (CHOLMOD supernodal LL^T or Eigen's simplicial LDL^T).
struct SparseCholesky {
  CholmodLLT cholmod;
  Eigen::SimplicialLDLT<SparseMatrix, Eigen::Lower> ldlt;
  SparseSolverKind kind = SparseSolverKind::cholmod_supernodal;

  // Fill-reducing ordering: CHOLMOD's default (AMD here). When AMD's factor is expensive for its
  // size (a simplicial factorisation would take >= kNestedDissectionFlopsPerEntry flops per entry of
  // L; CHOLMOD's own default only looks further at 500), METIS nested dissection is tried as well
  // and CHOLMOD keeps the better of the two: these factors are refactorised and applied hundreds
  // of times, so METIS's dearer analysis (VH soleus: ~85 ms against ~13 ms) pays. VH soleus (14k unknowns, 248 flops per entry with
  // AMD): factor 2.14 M -> 1.90 M stored entries, 4.2e8 -> 2.9e8 flops; the other VH muscles
  // (84-190 flops per entry) keep AMD, where METIS gains <= 6 % or loses. `same_as` (optional):
  // a factor of a matrix with the same pattern whose final ordering is reused (the contact factor
  // takes the contact-free one's: no second METIS run, the same permutation).
  static constexpr double kNestedDissectionFlopsPerEntry = 200.0;
  void analyse(const SparseMatrix& K, const SparseCholesky* same_as = nullptr) {
    use_single_threaded_cholmod();
    cholmod.cholmod().print = 0;  // failures are reported by the caller, not printed by CHOLMOD
    if (kind == SparseSolverKind::cholmod_supernodal) {
      const std::lock_guard lock(get_ordering_mutex());  // CHOLMOD may order with METIS
      const int* perm = same_as && same_as->kind == kind ? same_as->cholmod.get_permutation() : nullptr;
      if (perm) {
        cholmod.analyse(K, {}, perm);
        return;
      }
      cholmod.analyse(K, {});
      if (cholmod.info() == Eigen::Success && cholmod.get_flops_per_entry() >= kNestedDissectionFlopsPerEntry)
        cholmod.analyse(K, {CHOLMOD_AMD, CHOLMOD_METIS});
    }
    else ldlt.analyzePattern(K);
  }
  bool factorise(const SparseMatrix& K) {
    use_single_threaded_cholmod();
    if (kind == SparseSolverKind::cholmod_supernodal) {
      cholmod.factorize(K);
      if (cholmod.info() != Eigen::Success) return false;
      if (tree.parent.empty()) tree = make_supernodal_tree(cholmod.get_factor());
      return true;
    }
    ldlt.factorize(K);
    return ldlt.info() == Eigen::Success;
  }
  bool kind_is_ldlt() const { return kind == SparseSolverKind::eigen_simplicial_ldlt; }
  // Up to eight columns (the three coordinates, most Woodbury column batches), the CHOLMOD factor
  // is applied by fascicle/sparse's supernodal kernels in one pass over it (VH soleus factor,
  // 3 columns: 1.5 ms against CHOLMOD's 2.6 ms; bench_sparse, session 11); wider batches go to
  // CHOLMOD (chosen when its BLAS blocks won at 12 columns; since the AVX-512 kernels of session
  // 11 ours take 4.5 ms there against 6.1 ms, but no surface-first path solves more than eight).
  Eigen::MatrixXd solve(const Eigen::MatrixXd& rhs) const {
    use_single_threaded_cholmod();
    if (kind == SparseSolverKind::cholmod_supernodal) {
      if (rhs.cols() <= 8) {
        Eigen::MatrixXd x = rhs;
        if (solve_supernodal_llt(cholmod.get_factor(), x.data(), static_cast<int>(x.cols()),
                                 static_cast<int>(x.rows()), workspace))
          return x;
      }
      return cholmod.solve(rhs);
    }
    return ldlt.solve(rhs);
  }
  // First column of each supernode (the factor's `super` array; supernodal factors only).
  const int* tree_super() const {
    return static_cast<const int*>(static_cast<const cholmod_factor*>(cholmod.get_factor())->super);
  }
  // True when the factor is a supernodal LL^T that fascicle/sparse's kernels apply: then the
  // forward and backward halves and the unit-column solves of the low-rank corrections serve it.
  bool is_own_supernodal() const {
    return kind == SparseSolverKind::cholmod_supernodal && !tree.parent.empty() &&
           is_supernodal_llt(cholmod.get_factor());
  }
  // Scratch of the supernodal solves (the solver is used by one thread at a time).
  mutable SupernodalSolveWorkspace workspace;
  // Elimination tree of the supernodal factor (after the first numeric factorisation; the
  // pattern and permutation never change afterwards).
  SupernodalTree tree;
};

// The base factor (no contacts; computed once) and the factor with the current contacts' weights
// added to the diagonal (same pattern: numeric refactorisation only).
struct SurfaceFirstSolver::Factor {
  SparseMatrix K;                  // system + contact weights on the diagonal
  std::vector<Eigen::Index> diag;  // position of K(j, j) in K.valuePtr()
  SparseCholesky base, with_contacts;

  // The factor solve() uses, and a low-rank correction of it (Woodbury identity): with U the unit
  // columns e_j of the vertices in `low_rank` and W = diag(low_rank_weight) (+w_c for a contact
  // the factor lacks, -w_c for one it has but is not wanted),
  //   (K + U W U^T)^-1 r = y - Z C^-1 U^T y,  y = K^-1 r,  Z = K^-1 U,  C = W^-1 + U^T Z.
  // With a supernodal LL^T factor K = L L^T (P omitted) the same correction is applied between
  // the two triangular solves: (K + U W U^T)^-1 r = L^-T (z - F C^-1 F^T z), z = L^-1 r,
  // F = L^-1 U, C = W^-1 + F^T F. A column of F is non-zero only on the elimination-tree path of
  // its vertex (about 6 % of the rows for the VH soleus), so it costs a fraction of a solve, and
  // F^T z, F c and C are short sums (sparse/supernodal_solve.hpp, solve_supernodal_unit_forward).
  bool use_contacts = false;
  std::vector<int> low_rank;
  VecX low_rank_weight;
  Eigen::MatrixXd Z;  // dense K^-1 U (simplicial LDL^T factor)
  // Columns of L^-1 U (supernodal factor): point into unit_columns, valid until the next
  // prepare_factor() or reset() (which clear F first).
  std::vector<const UnitForwardColumn*> F;
  Eigen::PartialPivLU<Eigen::MatrixXd> capacitance;
  // Columns already computed, per factor (0: base, 1: with_contacts): free index -> column
  // (K^-1 e_j for a simplicial factor, L^-1 P e_j for a supernodal one). Cleared when that factor
  // changes or grows past a bound.
  std::vector<int> column_of[2];
  std::vector<VecX> columns[2];
  std::vector<UnitForwardColumn> unit_columns[2];

  const SparseCholesky& get_active() const { return use_contacts ? with_contacts : base; }
};

SurfaceFirstSolver::SurfaceFirstSolver(const SurfaceBinding& binding, BoneQueries bones)
    : binding_(binding), bones_(std::move(bones)), factor_(std::make_unique<Factor>()) {
  if (static_cast<int>(bones_.size()) != binding_.num_bones())
    throw_usage(fmt::format("solver given {} bones but the binding was made with {}", bones_.size(),
                            binding_.num_bones()),
                muscle_context(binding_.name));
  for (const MeshQuery* bone : bones_) {
    const Points3& V = bone->get_mesh().V;
    bone_boxes_.push_back(calc_padded_box(V));
  }
  Factor& f = *factor_;
  f.base.kind = f.with_contacts.kind = binding_.options.sparse_solver;
  f.K = binding_.system;
  f.diag.resize(f.K.cols());
  for (int j = 0; j < f.K.outerSize(); ++j)
    for (SparseMatrix::InnerIterator it(f.K, j); it; ++it)
      if (it.row() == j) f.diag[j] = &it.valueRef() - f.K.valuePtr();
  f.base.analyse(f.K);
  if (!f.base.factorise(f.K))
    throw_numerical("sparse Cholesky factorisation of the Laplacian system failed",
                    muscle_context(binding_.name, "check the surface for degenerate triangles or "
                                                  "use the uniform Laplacian"));
  ++info_.factorisations;
  vertices_ = binding_.rest.V;
}

SurfaceFirstSolver::~SurfaceFirstSolver() = default;
SurfaceFirstSolver::SurfaceFirstSolver(SurfaceFirstSolver&&) noexcept = default;

void SurfaceFirstSolver::reset() {
  contacts_.clear();
  last_direction_.clear();
  last_gradient_.resize(0, 3);
  vertices_ = binding_.rest.V;
  has_previous_ = false;
  info_ = {};
  // Back to a fresh solver's factor state, so frames after a reset equal a new solver's to the
  // bit: the contact factor is treated as holding no contacts (it is refactorised before it is
  // used again) and the low-rank correction and its cached columns are dropped.
  Factor& f = *factor_;
  factorised_contacts_.clear();
  f.use_contacts = false;
  f.low_rank.clear();
  f.F.clear();
  for (int k = 0; k < 2; ++k) {
    f.column_of[k].clear();
    f.columns[k].clear();
    f.unit_columns[k].clear();
  }
}

// Numeric factorisation of K = system + w_c sum over contacts e_i e_i^T (pattern unchanged).
void SurfaceFirstSolver::factorise() {
  Factor& f = *factor_;
  const double* base = binding_.system.valuePtr();
  for (std::size_t j = 0; j < f.diag.size(); ++j) f.K.valuePtr()[f.diag[j]] = base[f.diag[j]];
  const double wc = binding_.options.contact_weight * binding_.diagonal_scale;
  factorised_contacts_.clear();
  for (const Contact& c : contacts_) {
    const int j = binding_.free_index[c.vertex];
    f.K.valuePtr()[f.diag[j]] += wc;
    factorised_contacts_.push_back(j);
  }
  std::sort(factorised_contacts_.begin(), factorised_contacts_.end());
  if (!analysed_contacts_) {
    f.with_contacts.analyse(f.K, &f.base);
    analysed_contacts_ = true;
  }
  if (!f.with_contacts.factorise(f.K)) {
    // The contact weights are large next to the cotangent weights of a poorly shaped mesh, and
    // the supernodal LL^T can then meet a pivot that rounding made non-positive. Eigen's
    // simplicial LDL^T (no square roots) factorises the same matrix; keep it for this solver.
    if (f.with_contacts.kind == SparseSolverKind::cholmod_supernodal) {
      f.with_contacts.kind = SparseSolverKind::eigen_simplicial_ldlt;
      f.with_contacts.analyse(f.K);
    }
    if (!f.with_contacts.kind_is_ldlt() || !f.with_contacts.factorise(f.K))
      throw_numerical(fmt::format("sparse factorisation of the Laplacian system with {} bone contacts failed",
                                  contacts_.size()),
                      muscle_context(binding_.name, "check the surface for degenerate triangles, lower the "
                                                    "contact weight or use the uniform Laplacian"));
  }
  ++info_.factorisations;
}

Eigen::MatrixXd SurfaceFirstSolver::solve(const Eigen::MatrixXd& rhs) const {
  const Factor& f = *factor_;
  const SparseCholesky& active = f.get_active();
  if (!f.low_rank.empty() && !f.F.empty()) {
    // Woodbury between the halves: z = L^-1 P r; z -= F C^-1 F^T z; x = P^T L^-T z.
    const auto n = rhs.rows(), nc = rhs.cols();
    Eigen::MatrixXd z(n, nc), x(n, nc);
    const void* L = active.cholmod.get_factor();
    // F is filled only for the own supernodal LL^T (prepare_factor), whose halves cannot refuse.
    if (!solve_supernodal_forward(L, rhs.data(), static_cast<int>(nc), static_cast<int>(n), z.data(), active.workspace))
      throw_internal("surface-first: sparse low-rank columns without a supernodal LL^T factor");
    const auto r = static_cast<Eigen::Index>(f.F.size());
    const int* super = active.tree_super();
    // t = F^T z and z -= F u, each column of F read once for all right-hand sides (every entry
    // the same sum, in the same order, as column by column)
    constexpr int kMaxColumns = 8;
    double acc[kMaxColumns];
    const auto columns_at_once = static_cast<int>(std::min<Eigen::Index>(nc, kMaxColumns));
    Eigen::MatrixXd t(r, nc);
    for (Eigen::Index k = 0; k < r; ++k) {
      const UnitForwardColumn& col = *f.F[static_cast<std::size_t>(k)];
      for (Eigen::Index c0 = 0; c0 < nc; c0 += columns_at_once) {
        const int m = static_cast<int>(std::min<Eigen::Index>(columns_at_once, nc - c0));
        std::fill(acc, acc + m, 0.0);
        for (std::size_t q = 0; q < col.chain.size(); ++q) {
          const double* v = col.values.data() + col.offset[q];
          const int k0 = super[col.chain[q]], len = col.offset[q + 1] - col.offset[q];
          for (int c = 0; c < m; ++c) {
            const double* zc = z.data() + (c0 + c) * n + k0;
            double sum = acc[c];
            for (int i = 0; i < len; ++i) sum += v[i] * zc[i];
            acc[c] = sum;
          }
        }
        for (int c = 0; c < m; ++c) t(k, c0 + c) = acc[c];
      }
    }
    const Eigen::MatrixXd u = f.capacitance.solve(t);
    for (Eigen::Index k = 0; k < r; ++k) {
      const UnitForwardColumn& col = *f.F[static_cast<std::size_t>(k)];
      for (std::size_t q = 0; q < col.chain.size(); ++q) {
        const double* v = col.values.data() + col.offset[q];
        const int k0 = super[col.chain[q]], len = col.offset[q + 1] - col.offset[q];
        for (Eigen::Index c = 0; c < nc; ++c) {
          double* zc = z.data() + c * n + k0;
          const double uk = u(k, c);
          for (int i = 0; i < len; ++i) zc[i] -= v[i] * uk;
        }
      }
    }
    if (!solve_supernodal_backward(L, z.data(), static_cast<int>(nc), x.data(), static_cast<int>(n), active.workspace))
      throw_internal("surface-first: sparse low-rank columns without a supernodal LL^T factor");
    return x;
  }
  Eigen::MatrixXd y = active.solve(rhs);
  if (!f.low_rank.empty()) {
    Eigen::MatrixXd t(static_cast<Eigen::Index>(f.low_rank.size()), y.cols());
    for (std::size_t k = 0; k < f.low_rank.size(); ++k) t.row(static_cast<Eigen::Index>(k)) = y.row(f.low_rank[k]);
    y.noalias() -= f.Z * f.capacitance.solve(t);
  }
  return y;
}

void SurfaceFirstSolver::prepare_factor(const std::vector<int>& wanted) {
  Factor& f = *factor_;
  const SurfaceBinding& b = binding_;
  const double wc = b.options.contact_weight * b.diagonal_scale;
  f.low_rank.clear();
  f.F.clear();
  // differences from the contact-free factor (= wanted) and from the contact factor
  std::vector<int> added, removed;
  const auto diff_from = [&](const std::vector<int>& have) {
    added.clear();
    removed.clear();
    std::set_difference(wanted.begin(), wanted.end(), have.begin(), have.end(), std::back_inserter(added));
    std::set_difference(have.begin(), have.end(), wanted.begin(), wanted.end(), std::back_inserter(removed));
    return added.size() + removed.size();
  };
  const std::size_t to_base = wanted.size();
  const std::size_t to_contacts = analysed_contacts_ ? diff_from(factorised_contacts_) : to_base + 1;
  // The supernodal path corrects with sparse columns L^-1 e_j (cheap, session 10); the simplicial
  // fallback keeps dense columns K^-1 e_j (one full solve each, up to 8 x limit of n doubles cached),
  // so it keeps the rank bound of before (32) whatever the option says. The bound is per factor:
  // the fallback may hold only for the factor with contacts (factorise()).
  constexpr std::size_t kDenseLowRankLimit = 32;
  const auto option_limit = static_cast<std::size_t>(std::max(0, b.options.max_low_rank));
  const auto limit_of = [&](const SparseCholesky& s) {
    return s.is_own_supernodal() ? option_limit : std::min(option_limit, kDenseLowRankLimit);
  };
  const bool base_ok = to_base <= limit_of(f.base);
  const bool contacts_ok = analysed_contacts_ && to_contacts <= limit_of(f.with_contacts);
  if (!base_ok && !contacts_ok) {
    factorise();
    f.use_contacts = true;
    f.column_of[1].clear();
    f.columns[1].clear();
    f.unit_columns[1].clear();
    return;
  }
  f.use_contacts = contacts_ok && (!base_ok || to_contacts < to_base);
  const std::size_t limit = limit_of(f.use_contacts ? f.with_contacts : f.base);
  if (!f.use_contacts) diff_from({});
  if (added.empty() && removed.empty()) return;

  // the low-rank set, its weights and the columns K^-1 e_j (new ones in one multi-column solve)
  const int which = f.use_contacts ? 1 : 0;
  const auto nf = static_cast<Eigen::Index>(b.free_vertices.size());
  std::vector<int>& column_of = f.column_of[which];
  std::vector<VecX>& columns = f.columns[which];
  std::vector<UnitForwardColumn>& unit_columns = f.unit_columns[which];
  const SparseCholesky& active = f.get_active();
  const bool own = active.is_own_supernodal();
  if (columns.size() > 8 * limit || unit_columns.size() > 8 * limit || (own ? !columns.empty() : !unit_columns.empty())) {
    column_of.clear();
    columns.clear();
    unit_columns.clear();
  }
  if (column_of.empty()) column_of.assign(static_cast<std::size_t>(nf), -1);
  f.low_rank = added;
  f.low_rank.insert(f.low_rank.end(), removed.begin(), removed.end());
  const auto r = static_cast<Eigen::Index>(f.low_rank.size());
  f.low_rank_weight.resize(r);
  for (Eigen::Index k = 0; k < r; ++k) f.low_rank_weight[k] = k < static_cast<Eigen::Index>(added.size()) ? wc : -wc;
  std::vector<int> missing;
  for (int j : f.low_rank)
    if (column_of[j] < 0) missing.push_back(j);
  if (own) {
    if (!missing.empty()) {
      const std::size_t first = unit_columns.size();
      unit_columns.resize(first + missing.size());
      solve_supernodal_unit_forward(active.cholmod.get_factor(), active.tree, missing.data(),
                                    static_cast<int>(missing.size()), unit_columns.data() + first,
                                    active.workspace);
      for (std::size_t k = 0; k < missing.size(); ++k) column_of[missing[k]] = static_cast<int>(first + k);
    }
    f.Z.resize(0, 0);
    f.F.resize(static_cast<std::size_t>(r));
    for (Eigen::Index k = 0; k < r; ++k) f.F[static_cast<std::size_t>(k)] = &unit_columns[column_of[f.low_rank[k]]];
    Eigen::MatrixXd C(r, r);
    for (Eigen::Index k = 0; k < r; ++k)
      for (Eigen::Index l = 0; l <= k; ++l)
        C(k, l) = C(l, k) = dot_unit_forward(*f.F[static_cast<std::size_t>(k)], *f.F[static_cast<std::size_t>(l)]);
    C.diagonal() += f.low_rank_weight.cwiseInverse();
    f.capacitance.compute(C);
    ++info_.low_rank_updates;
    return;
  }
  f.F.clear();
  if (!missing.empty()) {
    Eigen::MatrixXd E = Eigen::MatrixXd::Zero(nf, static_cast<Eigen::Index>(missing.size()));
    for (std::size_t k = 0; k < missing.size(); ++k) E(missing[k], static_cast<Eigen::Index>(k)) = 1.0;
    const Eigen::MatrixXd solved = f.get_active().solve(E);
    for (std::size_t k = 0; k < missing.size(); ++k) {
      column_of[missing[k]] = static_cast<int>(columns.size());
      columns.push_back(solved.col(static_cast<Eigen::Index>(k)));
    }
  }
  f.Z.resize(nf, r);
  for (Eigen::Index k = 0; k < r; ++k) f.Z.col(k) = columns[column_of[f.low_rank[k]]];
  Eigen::MatrixXd C(r, r);
  for (Eigen::Index k = 0; k < r; ++k) C.row(k) = f.Z.row(f.low_rank[k]);
  C.diagonal() += f.low_rank_weight.cwiseInverse();
  f.capacitance.compute(C);
  ++info_.low_rank_updates;
}

// Minimises the quadratic energy E(x) = 1/2 x^T K x - b^T x subject to V(x) = V0 (docs: "volume
// step"). With X0 = K^-1 b and Y = K^-1 g(X_k), the iterate X_{k+1} = X0 + lambda Y lies on the
// constraint exactly (lambda: root of the cubic V(X0 + lambda Y) = V0); at a fixed point
// K x - b = lambda grad V(x), the KKT conditions. Returns the number of linear solves.
// X0, Y and the iterate are kept interleaved (x0 y0 z0 x1 ...) for the volume cubic and gradient,
// which read a triangle's corners as three contiguous triples; the arithmetic is that of
// X0 + lambda * Y, calc_volume_cubic and calc_volume_gradient on #V x 3 matrices (same bits).
int SurfaceFirstSolver::solve_volume(const Points3& rhs_free, const Points3& fixed, Points3& X) {
  const SurfaceBinding& b = binding_;
  const Triangles& F = b.rest.F;
  const int nf = static_cast<int>(b.free_vertices.size());
  const Eigen::Index n = X.rows();
  const auto n3 = static_cast<std::size_t>(3 * n);
  const Vec3 centre = X.colwise().mean().transpose();

  // free rows of a #free x 3 block into an interleaved #V array
  const auto put_free = [&](const auto& M, std::vector<double>& out) {
    for (int k = 0; k < nf; ++k) {
      double* o = out.data() + 3 * static_cast<std::size_t>(b.free_vertices[static_cast<std::size_t>(k)]);
      o[0] = M(k, 0);
      o[1] = M(k, 1);
      o[2] = M(k, 2);
    }
  };
  // the volume gradient's free rows at the interleaved points P (calc_volume_gradient's bits)
  std::vector<double>& G = gradient_scratch_;
  G.resize(n3);
  const auto free_gradient = [&](const std::vector<double>& P) {
    std::fill(G.begin(), G.end(), 0.0);
    add_volume_gradient_times_six(P.data(), F, G.data());
    Points3 out(nf, 3);
    for (int k = 0; k < nf; ++k) {
      const double* g = G.data() + 3 * static_cast<std::size_t>(b.free_vertices[static_cast<std::size_t>(k)]);
      out(k, 0) = g[0] / 6.0;
      out(k, 1) = g[1] / 6.0;
      out(k, 2) = g[2] / 6.0;
    }
    return out;
  };

  // first solve: the unconstrained minimiser, and a direction: the previous frame's (contact-free
  // factor only) or K^-1 g at the warm-start point
  std::vector<double>& X0 = start_scratch_;
  std::vector<double>& P = iterate_scratch_;
  X0.resize(n3);
  P.resize(n3);
  std::vector<double> Y;
  for (std::size_t k = 0; k < b.fixed_vertices.size(); ++k)
    for (int c = 0; c < 3; ++c)
      X0[3 * static_cast<std::size_t>(b.fixed_vertices[k]) + c] = fixed(static_cast<Eigen::Index>(k), c);
  Points3 g;
  const bool reuse = contacts_.empty() && last_direction_.size() == n3;
  if (reuse) {
    g = last_gradient_;
    put_free(solve(rhs_free), X0);
    Y = last_direction_;
  } else {
    for (Eigen::Index i = 0; i < n; ++i)
      for (int c = 0; c < 3; ++c) P[static_cast<std::size_t>(3 * i + c)] = X(i, c);
    g = free_gradient(P);
    Eigen::MatrixXd B(nf, 6);
    B << rhs_free, g;
    const Eigen::MatrixXd Z = solve(B);
    put_free(Z.leftCols(3), X0);
    Y.assign(n3, 0.0);
    put_free(Z.rightCols(3), Y);
  }
  int solves = 1;
  for (;;) {
    const double lambda = solve_volume_cubic(calc_volume_cubic(X0.data(), Y.data(), F, centre), b.rest_volume_m3);
    if (!std::isfinite(lambda))
      throw_numerical("the volume constraint has no solution along the Gauss-Newton direction",
                      muscle_context(b.name, "the frame's deformation is too large; check the "
                                             "action line and attachment motions"));
    for (std::size_t q = 0; q < n3; ++q) P[q] = X0[q] + lambda * Y[q];
    info_.volume_multiplier = lambda;
    const Points3 g_new = free_gradient(P);
    info_.stationarity = (g_new - g).norm() / g.norm();
    if (info_.stationarity <= b.options.stationarity_tolerance ||
        solves >= b.options.max_volume_iterations)
      break;
    g = g_new;
    put_free(solve(g), Y);  // (the fixed rows of Y stay zero)
    ++solves;
  }
  for (Eigen::Index i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) X(i, c) = P[static_cast<std::size_t>(3 * i + c)];
  if (contacts_.empty()) {
    last_direction_ = std::move(Y);
    last_gradient_ = std::move(g);
  }
  return solves;
}

// Adds contacts for vertices deeper inside a bone than at rest and releases contacts the rest of
// the surface pulls away from the bone. Updates the penetration measure. Returns true on change.
bool SurfaceFirstSolver::update_contacts(const Points3& X, const std::vector<Transform>& bone_motions) {
  const SurfaceBinding& b = binding_;
  const SurfaceFirstOptions& o = b.options;
  bool changed = false;
  std::vector<char> in_contact(X.rows(), 0);

  // release
  std::vector<Contact> kept;
  for (const Contact& c : contacts_) {
    const Transform T = bone_motions.empty() ? Transform::Identity() : bone_motions[c.bone];
    const Vec3 t = T * c.target_rest;
    const Vec3 nrm = T.linear() * c.normal_rest;
    const Vec3 x = X.row(c.vertex);
    if ((x - t).dot(nrm) > o.contact_tolerance_m) {
      changed = true;
    } else {
      kept.push_back(c);
      in_contact[c.vertex] = 1;
    }
  }
  contacts_ = std::move(kept);

  // detect: the winding number of each bone at every vertex, propagated along the muscle's edges
  // from the vertices that are certainly outside (moved less than their rest clearance relative
  // to the bone, or outside its box)
  double worst = 0.0;
  const Eigen::Index n = X.rows();
  std::vector<int> winding(static_cast<std::size_t>(n));
  for (std::size_t k = 0; k < bones_.size(); ++k) {
    const Transform T = bone_motions.empty() ? Transform::Identity() : bone_motions[k];
    const Transform Tinv = T.inverse();
    const Points3 P = ((X * Tinv.linear().transpose()).rowwise() + Tinv.translation().transpose()).eval();
    const Eigen::AlignedBox3d& box = bone_boxes_[k];
    bool any_unknown = false;
    for (Eigen::Index i = 0; i < n; ++i) {
      const Vec3 p = P.row(i).transpose();
      const double clearance = b.rest_bone_clearance[k][i];
      const bool outside = (clearance > 0.0 && (p - b.rest.V.row(i).transpose()).squaredNorm() < clearance * clearance) ||
                           !box.contains(p);
      winding[i] = outside ? 0 : -1;
      any_unknown |= !outside;
    }
    if (!any_unknown) continue;
    propagate_winding(P, b.adjacency, *bones_[k], winding);
    for (int i : b.free_vertices) {
      if (winding[i] <= 0) continue;
      const Vec3 p = P.row(i).transpose();
      const ClosestPoint cp = bones_[k]->calc_closest_point(p);
      const double allowed = b.rest_bone_depth[k][i];
      const double beyond = cp.distance - allowed;
      worst = std::max(worst, beyond);
      if (in_contact[i] || beyond <= o.contact_tolerance_m) continue;
      const Vec3 nrm = cp.distance > 0.0 ? Vec3((cp.point - p) / cp.distance) : Vec3::UnitZ();
      contacts_.push_back({i, static_cast<int>(k), cp.point + nrm * (o.contact_margin_m - allowed), nrm});
      in_contact[i] = 1;
      changed = true;
    }
  }
  info_.max_penetration_beyond_rest_m = worst;
  return changed;
}

const Points3& SurfaceFirstSolver::calc_frame(const SurfaceFrameInput& input) {
  const SurfaceBinding& b = binding_;
  const Eigen::Index n = b.rest.V.rows();
  const int nx = static_cast<int>(b.fixed_vertices.size());
  const int nf = static_cast<int>(b.free_vertices.size());
  const int factorisations_before = info_.factorisations;
  const int low_rank_before = info_.low_rank_updates;
  info_ = {};
  info_.factorisations = factorisations_before;
  info_.low_rank_updates = low_rank_before;

  // check input sizes
  const bool by_targets = input.attachment_targets.rows() > 0;
  if (by_targets && input.attachment_targets.rows() != nx)
    throw_bad_input(fmt::format("{} attachment targets given for {} attachment vertices",
                                input.attachment_targets.rows(), nx),
                    muscle_context(b.name));
  if (!by_targets && input.attachment_motions.size() != b.attachments.size())
    throw_bad_input(fmt::format("{} attachment motions given for {} attachment areas",
                                input.attachment_motions.size(), b.attachments.size()),
                    muscle_context(b.name));
  if (!input.bone_motions.empty() && input.bone_motions.size() != bones_.size())
    throw_bad_input(fmt::format("{} bone motions given for {} bones", input.bone_motions.size(),
                                bones_.size()),
                    muscle_context(b.name));

  // the action line now, its twist fixed by the origin area's rotation
  const Quat R_ref = input.attachment_motions.empty() ? Quat::Identity()
                                                      : Quat(input.attachment_motions[0].linear());
  const FramedLine line =
      calc_framed_line(input.action_line, b.options.line_samples, R_ref * b.rest_line.frames[0]);

  // skinned positions S and rotated differential coordinates D
  Points3 S(n, 3), D(n, 3);
  const LinePointInterpolator line_point(line);
  for (Eigen::Index i = 0; i < n; ++i) {
    const LinePoint lp = line_point(b.vertex_s[i]);
    const Mat3 R = lp.frame.toRotationMatrix();
    S.row(i) = (lp.point + R * b.offset_local.row(i).transpose()).transpose();
    D.row(i) = (R * b.delta_local.row(i).transpose()).transpose();
  }

  // attachment positions
  Points3 fixed(nx, 3);
  if (by_targets) {
    fixed = input.attachment_targets;
  } else {
    for (int k = 0; k < nx; ++k)
      fixed.row(k) = (input.attachment_motions[b.fixed_area[k]] *
                      Vec3(b.rest.V.row(b.fixed_vertices[k]).transpose()))
                         .transpose();
  }
  if (!fixed.allFinite() || !S.allFinite())
    throw_bad_input("non-finite action line or attachment positions", muscle_context(b.name));

  // right-hand side without contacts: Lf^T (D - Lx X_fixed) + w_line S_free
  const double wl = b.options.line_weight * b.diagonal_scale;
  const double wc = b.options.contact_weight * b.diagonal_scale;
  const Points3 rhs_base = calc_base_rhs(b, D, S, fixed, wl);

  // warm start: the previous solution (or the skinned shape) gives the first volume gradient.
  // Contacts are found afresh every frame (targets from this frame's geometry), so the solution
  // depends on this frame's input only.
  Points3 X = has_previous_ ? vertices_ : assemble(b, gather_free(b, S), fixed);
  contacts_.clear();
  for (int round = 0; round < b.options.max_contact_rounds; ++round) {
    std::vector<int> wanted;
    for (const Contact& c : contacts_) wanted.push_back(b.free_index[c.vertex]);
    std::sort(wanted.begin(), wanted.end());
    prepare_factor(wanted);

    Points3 rhs = rhs_base;
    for (const Contact& c : contacts_) {
      const Transform T = input.bone_motions.empty() ? Transform::Identity()
                                                     : input.bone_motions[c.bone];
      rhs.row(b.free_index[c.vertex]) += wc * (T * c.target_rest).transpose();
    }
    info_.volume_iterations += solve_volume(rhs, fixed, X);
    ++info_.contact_rounds;
    if (bones_.empty() || !update_contacts(X, input.bone_motions)) break;
  }
  info_.active_contacts = static_cast<int>(contacts_.size());
  (void)nf;

  // report and check the volume
  info_.volume_m3 = calc_enclosed_volume(X, b.rest.F, X.colwise().mean().transpose());
  info_.relative_volume_error = std::abs(info_.volume_m3 - b.rest_volume_m3) / b.rest_volume_m3;
  if (!X.allFinite() || !(info_.relative_volume_error <= b.options.max_volume_error))
    throw_numerical(fmt::format("volume not held: relative error {:.3g} (limit {:.3g})",
                                info_.relative_volume_error, b.options.max_volume_error),
                    muscle_context(b.name, "the frame's deformation is too large; check the "
                                           "action line and attachment motions"));
  vertices_ = std::move(X);
  skinned_ = std::move(S);
  line_ = line;
  has_previous_ = true;
  return vertices_;
}

Points3 deform_surface(const SurfaceBinding& binding, const BoneQueries& bones,
                       const SurfaceFrameInput& input, SurfaceFrameInfo* info) {
  SurfaceFirstSolver solver(binding, bones);
  Points3 X = solver.calc_frame(input);
  if (info) *info = solver.get_info();
  return X;
}

// ---------------------------------------------------------------------------------------------
// Measures

PenetrationInfo calc_bone_penetration(const Points3& V, const MeshQuery& bone,
                                      const Transform& X_now_rest, const VecX& rest_depth,
                                      const std::vector<int>& skip_vertices) {
  std::vector<char> skip(V.rows(), 0);
  for (int i : skip_vertices)
    if (i >= 0 && i < V.rows()) skip[i] = 1;
  const Points3& B = bone.get_mesh().V;
  const Eigen::AlignedBox3d box(B.colwise().minCoeff().transpose(), B.colwise().maxCoeff().transpose());
  const Transform Tinv = X_now_rest.inverse();
  PenetrationInfo out;
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    if (skip[i]) continue;
    const Vec3 p = Tinv * Vec3(V.row(i).transpose());
    if (!box.contains(p) || !bone.calc_is_inside(p)) continue;
    const double depth = bone.calc_closest_point(p).distance;
    const double beyond = depth - (rest_depth.size() ? rest_depth[i] : 0.0);
    ++out.vertices_inside;
    out.max_depth_m = std::max(out.max_depth_m, depth);
    if (beyond > 1e-9) ++out.vertices_beyond_rest;
    out.max_depth_beyond_rest_m = std::max(out.max_depth_beyond_rest_m, beyond);
  }
  return out;
}

OverlapInfo calc_surface_overlap(const Points3& V, const MeshQuery& other) {
  OverlapInfo out;
  const InsideFlags inside = other.calc_is_inside(V);
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    if (!inside[i]) continue;
    ++out.vertices_inside;
    out.max_depth_m = std::max(out.max_depth_m, other.calc_closest_point(V.row(i)).distance);
  }
  return out;
}

OverlapInfo calc_surface_overlap(const Points3& V, const Triangles& F, const MeshQuery& other) {
  OverlapInfo out;
  const Eigen::Index n = V.rows();
  if (n == 0) return out;
  std::vector<int> winding(static_cast<std::size_t>(n), -1);
  const Eigen::AlignedBox3d box = calc_padded_box(other.get_mesh().V);
  for (Eigen::Index i = 0; i < n; ++i)
    if (!box.contains(Vec3(V.row(i).transpose()))) winding[i] = 0;
  const int max_whole_rays = std::max(64, static_cast<int>(n / 16));
  if (!propagate_winding(V, make_vertex_adjacency(F, n), other, winding, max_whole_rays))
    return calc_surface_overlap(V, other);
  for (Eigen::Index i = 0; i < n; ++i) {
    if (winding[i] <= 0) continue;
    ++out.vertices_inside;
    out.max_depth_m = std::max(out.max_depth_m, other.calc_closest_point(V.row(i)).distance);
  }
  return out;
}

}  // namespace fascicle
