// Forward and backward substitution with CHOLMOD's supernodal LLᵀ factor (the factor is the
// library's; only its application is ours). For the few right-hand sides of the deformation and
// dynamics solves, CHOLMOD's per-supernode dtrsm/dgemm calls cost more than their arithmetic on the
// small supernodes of these meshes.
#include "fascicle/sparse/supernodal_solve.hpp"

#include <suitesparse/cholmod.h>

#include <algorithm>
#include <cstddef>
#include <cstring>

namespace fascicle {

namespace {

// Right-hand sides solved together in one pass over the factor (which may not fit in the cache).
constexpr int kMaxBlock = 8;

// A supernode holds columns k1 .. k1 + nscol of L as a dense nsrow x nscol column-major block
// whose row indices are rows[0 .. nsrow), the first nscol of them k1 .. k1 + nscol. t[0 .. NR):
// the right-hand sides gathered at those rows.
// Forward (L y = b): y_j = t_j / L_jj, then t_i −= L_ij y_j below it, in column order for every
// t_i whatever the vector width. Backward (Lᵀ x = y): row j's dot product over i > j with four
// partial sums combined as (s0 + s1) + (s2 + s3), then the tail in order. No FMA anywhere, so the
// generic and the AVX2 clones give the same bits; every right-hand side has its own operations,
// so NR does not change any result either.
// Forward solve of one supernode: columns are taken four at a time (the small triangle first,
// then every row below updated by the four columns in column order): each t_i still sums in
// column order, but is loaded and stored once per four columns.
// Four doubles (GCC's vector extension: the same element-wise operations on SSE2 and AVX2).
typedef double V4d __attribute__((vector_size(32)));

template <int NR>
[[gnu::always_inline]] inline void supernode_forward_nr(const double* Lx, int nsrow, int nscol,
                                                        double* const* t) {
  int j = 0;
  for (; j + 4 <= nscol; j += 4) {
    const double* __restrict c0 = Lx + static_cast<std::ptrdiff_t>(j) * nsrow;
    const double* __restrict c1 = c0 + nsrow;
    const double* __restrict c2 = c1 + nsrow;
    const double* __restrict c3 = c2 + nsrow;
    double y[NR][4];
    for (int r = 0; r < NR; ++r) {
      double* tr = t[r];
      const double y0 = tr[j] / c0[j];
      tr[j] = y0;
      tr[j + 1] -= c0[j + 1] * y0;
      tr[j + 2] -= c0[j + 2] * y0;
      tr[j + 3] -= c0[j + 3] * y0;
      const double y1 = tr[j + 1] / c1[j + 1];
      tr[j + 1] = y1;
      tr[j + 2] -= c1[j + 2] * y1;
      tr[j + 3] -= c1[j + 3] * y1;
      const double y2 = tr[j + 2] / c2[j + 2];
      tr[j + 2] = y2;
      tr[j + 3] -= c2[j + 3] * y2;
      const double y3 = tr[j + 3] / c3[j + 3];
      tr[j + 3] = y3;
      y[r][0] = y0;
      y[r][1] = y1;
      y[r][2] = y2;
      y[r][3] = y3;
    }
    // Rows below: the four columns are read once for all NR right-hand sides (a supernode's
    // block may be larger than the cache), four rows at a time; each t_i has the same operations
    // as the scalar tail.
    int i = j + 4;
    for (; i + 4 <= nsrow; i += 4) {
      V4d l0, l1, l2, l3;
      std::memcpy(&l0, c0 + i, sizeof l0);
      std::memcpy(&l1, c1 + i, sizeof l1);
      std::memcpy(&l2, c2 + i, sizeof l2);
      std::memcpy(&l3, c3 + i, sizeof l3);
      for (int r = 0; r < NR; ++r) {
        V4d tv;
        std::memcpy(&tv, t[r] + i, sizeof tv);
        tv = (((tv - l0 * y[r][0]) - l1 * y[r][1]) - l2 * y[r][2]) - l3 * y[r][3];
        std::memcpy(t[r] + i, &tv, sizeof tv);
      }
    }
    for (; i < nsrow; ++i)
      for (int r = 0; r < NR; ++r) {
        double* tr = t[r];
        tr[i] = (((tr[i] - c0[i] * y[r][0]) - c1[i] * y[r][1]) - c2[i] * y[r][2]) - c3[i] * y[r][3];
      }
  }
  for (; j < nscol; ++j) {
    const double* __restrict col = Lx + static_cast<std::ptrdiff_t>(j) * nsrow;
    for (int r = 0; r < NR; ++r) {
      double* __restrict tr = t[r];
      const double yj = tr[j] / col[j];
      tr[j] = yj;
      for (int i = j + 1; i < nsrow; ++i) tr[i] -= col[i] * yj;
    }
  }
}

// Four-lane partial sums (lane k: i ≡ begin + k mod 4) combined as (s0 + s1) + (s2 + s3), then
// the tail in order: GCC's vector extension gives the same lanes on SSE2 and AVX2.
template <int NR>
[[gnu::always_inline]] inline void dot4_nr(const double* __restrict a, double* const* b, int begin,
                                           int end, double* out) {
  V4d s[NR];
  for (int r = 0; r < NR; ++r) s[r] = V4d{0.0, 0.0, 0.0, 0.0};
  int i = begin;
  for (; i + 4 <= end; i += 4) {
    V4d av, bv;
    std::memcpy(&av, a + i, sizeof av);
    for (int r = 0; r < NR; ++r) {
      std::memcpy(&bv, b[r] + i, sizeof bv);
      s[r] += av * bv;
    }
  }
  for (int r = 0; r < NR; ++r) {
    double sum = (s[r][0] + s[r][1]) + (s[r][2] + s[r][3]);
    for (int k = i; k < end; ++k) sum += a[k] * b[r][k];
    out[r] = sum;
  }
}
template <int NR>
[[gnu::always_inline]] inline void supernode_backward_nr(const double* Lx, int nsrow, int nscol,
                                                         double* const* t) {
  for (int j = nscol - 1; j >= 0; --j) {
    const double* __restrict col = Lx + static_cast<std::ptrdiff_t>(j) * nsrow;
    double d[NR];
    dot4_nr<NR>(col, t, j + 1, nsrow, d);
    for (int r = 0; r < NR; ++r) t[r][j] = (t[r][j] - d[r]) / col[j];
  }
}

[[gnu::always_inline]] inline void supernode_forward_body(const double* Lx, int nsrow, int nscol,
                                                          double* const* t, int nr) {
  switch (nr) {
    case 1: supernode_forward_nr<1>(Lx, nsrow, nscol, t); break;
    case 2: supernode_forward_nr<2>(Lx, nsrow, nscol, t); break;
    case 3: supernode_forward_nr<3>(Lx, nsrow, nscol, t); break;
    case 4: supernode_forward_nr<4>(Lx, nsrow, nscol, t); break;
    case 5: supernode_forward_nr<5>(Lx, nsrow, nscol, t); break;
    case 6: supernode_forward_nr<6>(Lx, nsrow, nscol, t); break;
    case 7: supernode_forward_nr<7>(Lx, nsrow, nscol, t); break;
    default: supernode_forward_nr<8>(Lx, nsrow, nscol, t); break;
  }
}
[[gnu::always_inline]] inline void supernode_backward_body(const double* Lx, int nsrow, int nscol,
                                                           double* const* t, int nr) {
  switch (nr) {
    case 1: supernode_backward_nr<1>(Lx, nsrow, nscol, t); break;
    case 2: supernode_backward_nr<2>(Lx, nsrow, nscol, t); break;
    case 3: supernode_backward_nr<3>(Lx, nsrow, nscol, t); break;
    case 4: supernode_backward_nr<4>(Lx, nsrow, nscol, t); break;
    case 5: supernode_backward_nr<5>(Lx, nsrow, nscol, t); break;
    case 6: supernode_backward_nr<6>(Lx, nsrow, nscol, t); break;
    case 7: supernode_backward_nr<7>(Lx, nsrow, nscol, t); break;
    default: supernode_backward_nr<8>(Lx, nsrow, nscol, t); break;
  }
}
__attribute__((target("avx2"))) void supernode_forward_avx2(const double* Lx, int nsrow, int nscol,
                                                            double* const* t, int nr) {
  supernode_forward_body(Lx, nsrow, nscol, t, nr);
}
void supernode_forward_generic(const double* Lx, int nsrow, int nscol, double* const* t, int nr) {
  supernode_forward_body(Lx, nsrow, nscol, t, nr);
}
__attribute__((target("avx2"))) void supernode_backward_avx2(const double* Lx, int nsrow,
                                                             int nscol, double* const* t, int nr) {
  supernode_backward_body(Lx, nsrow, nscol, t, nr);
}
void supernode_backward_generic(const double* Lx, int nsrow, int nscol, double* const* t, int nr) {
  supernode_backward_body(Lx, nsrow, nscol, t, nr);
}

bool has_avx2() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2");
}

// Forward substitution L y = b of one supernode for nr (1 .. kMaxBlock) columns b[r] (permuted
// system): gather its rows, solve, scatter back.
inline void forward_supernode(const cholmod_factor& L, int sn, double* const* b, int nr, bool avx2,
                              std::vector<double>& gathered) {
  const int* super = static_cast<const int*>(L.super);
  const int* pi = static_cast<const int*>(L.pi);
  const int* px = static_cast<const int*>(L.px);
  const int* ls = static_cast<const int*>(L.s);
  const double* lx = static_cast<const double*>(L.x);
  const int nscol = super[sn + 1] - super[sn], nsrow = pi[sn + 1] - pi[sn];
  const int* rows = ls + pi[sn];
  double* t[kMaxBlock];
  for (int r = 0; r < nr; ++r) {
    t[r] = gathered.data() + static_cast<std::ptrdiff_t>(r) * nsrow;
    for (int i = 0; i < nsrow; ++i) t[r][i] = b[r][rows[i]];
  }
  (avx2 ? supernode_forward_avx2 : supernode_forward_generic)(lx + px[sn], nsrow, nscol, t, nr);
  for (int r = 0; r < nr; ++r)
    for (int i = 0; i < nsrow; ++i) b[r][rows[i]] = t[r][i];
}

void forward_columns(const cholmod_factor& L, double* const* b, int nr, bool avx2,
                     std::vector<double>& gathered) {
  const int ns = static_cast<int>(L.nsuper);
  for (int sn = 0; sn < ns; ++sn) forward_supernode(L, sn, b, nr, avx2, gathered);
}

// Lᵀ x = y in place for nr (1 .. kMaxBlock) columns (permuted system), supernode by supernode.
void backward_columns(const cholmod_factor& L, double* const* b, int nr, bool avx2,
                      std::vector<double>& gathered) {
  const int* super = static_cast<const int*>(L.super);
  const int* pi = static_cast<const int*>(L.pi);
  const int* px = static_cast<const int*>(L.px);
  const int* ls = static_cast<const int*>(L.s);
  const double* lx = static_cast<const double*>(L.x);
  const int ns = static_cast<int>(L.nsuper);
  auto backward = avx2 ? supernode_backward_avx2 : supernode_backward_generic;
  double* t[kMaxBlock];
  for (int sn = ns - 1; sn >= 0; --sn) {
    const int nscol = super[sn + 1] - super[sn], nsrow = pi[sn + 1] - pi[sn];
    const int* rows = ls + pi[sn];
    for (int r = 0; r < nr; ++r) {
      t[r] = gathered.data() + static_cast<std::ptrdiff_t>(r) * nsrow;
      for (int i = 0; i < nsrow; ++i) t[r][i] = b[r][rows[i]];
    }
    backward(lx + px[sn], nsrow, nscol, t, nr);
    for (int r = 0; r < nr; ++r)
      for (int i = 0; i < nscol; ++i) b[r][rows[i]] = t[r][i];
  }
}

// L Lᵀ x = b in place for nr (1 .. kMaxBlock) columns b[r] (permuted system).
void solve_columns(const cholmod_factor& L, double* const* b, int nr, bool avx2,
                   std::vector<double>& gathered) {
  forward_columns(L, b, nr, avx2, gathered);
  backward_columns(L, b, nr, avx2, gathered);
}

bool use_avx2(SupernodalSolveWorkspace& workspace) {
  if (workspace.kernel == SupernodalKernel::automatic)
    workspace.kernel = has_avx2() ? SupernodalKernel::avx2 : SupernodalKernel::generic;
  return workspace.kernel == SupernodalKernel::avx2;
}

// What every solve entry point needs of the factor: its size, the kernel, the fill-reducing
// permutation, and a gather buffer for `chunk` columns of at most n rows of a supernode.
struct FactorPass {
  const cholmod_factor& L;
  int n;
  bool avx2;
  const int* perm;
  bool permuted;
};
FactorPass begin_factor_pass(const void* factor, std::size_t chunk, SupernodalSolveWorkspace& workspace) {
  const cholmod_factor& L = *static_cast<const cholmod_factor*>(factor);
  const int n = static_cast<int>(L.n);
  if (workspace.gathered.size() < chunk * n) workspace.gathered.resize(chunk * n);
  const int* perm = static_cast<const int*>(L.Perm);
  return {L, n, use_avx2(workspace), perm, perm && L.ordering != CHOLMOD_NATURAL};
}

}  // namespace

bool is_supernodal_llt(const void* factor) {
  const auto* L = static_cast<const cholmod_factor*>(factor);
  return L && L->is_super && L->is_ll && L->itype == CHOLMOD_INT && L->xtype == CHOLMOD_REAL &&
         L->dtype == CHOLMOD_DOUBLE && L->x && L->super && L->pi && L->px && L->s;
}

bool solve_supernodal_llt(const void* factor, double* B, int ncols, int ld,
                          SupernodalSolveWorkspace& workspace) {
  if (!is_supernodal_llt(factor)) return false;
  const std::size_t chunk = static_cast<std::size_t>(std::min(ncols, kMaxBlock));
  const auto [L, n, avx2, perm, permuted] = begin_factor_pass(factor, chunk, workspace);
  if (permuted && workspace.permuted.size() < chunk * n) workspace.permuted.resize(chunk * n);
  double* b[kMaxBlock];
  for (int c0 = 0; c0 < ncols; c0 += kMaxBlock) {
    const int nr = std::min(kMaxBlock, ncols - c0);
    for (int r = 0; r < nr; ++r) {
      double* col = B + static_cast<std::ptrdiff_t>(c0 + r) * ld;
      if (permuted) {
        // (P b)_k = b_{Perm[k]}
        b[r] = workspace.permuted.data() + static_cast<std::ptrdiff_t>(r) * n;
        for (int k = 0; k < n; ++k) b[r][k] = col[perm[k]];
      } else {
        b[r] = col;
      }
    }
    solve_columns(L, b, nr, avx2, workspace.gathered);
    if (permuted)
      for (int r = 0; r < nr; ++r) {
        double* col = B + static_cast<std::ptrdiff_t>(c0 + r) * ld;
        for (int k = 0; k < n; ++k) col[perm[k]] = b[r][k];
      }
  }
  return true;
}

SupernodalTree make_supernodal_tree(const void* factor) {
  SupernodalTree tree;
  if (!is_supernodal_llt(factor)) return tree;
  const cholmod_factor& L = *static_cast<const cholmod_factor*>(factor);
  const int n = static_cast<int>(L.n), ns = static_cast<int>(L.nsuper);
  const int* super = static_cast<const int*>(L.super);
  const int* pi = static_cast<const int*>(L.pi);
  const int* ls = static_cast<const int*>(L.s);
  tree.supernode_of.resize(static_cast<std::size_t>(n));
  for (int sn = 0; sn < ns; ++sn)
    for (int k = super[sn]; k < super[sn + 1]; ++k) tree.supernode_of[static_cast<std::size_t>(k)] = sn;
  // A supernode's parent holds its first row below the diagonal block (CHOLMOD orders supernodes
  // so that a parent comes after its children).
  tree.parent.assign(static_cast<std::size_t>(ns), -1);
  for (int sn = 0; sn < ns; ++sn) {
    const int nscol = super[sn + 1] - super[sn], nsrow = pi[sn + 1] - pi[sn];
    if (nsrow > nscol) tree.parent[static_cast<std::size_t>(sn)] = tree.supernode_of[static_cast<std::size_t>(ls[pi[sn] + nscol])];
  }
  tree.position.resize(static_cast<std::size_t>(n));
  const int* perm = static_cast<const int*>(L.Perm);
  const bool permuted = perm && L.ordering != CHOLMOD_NATURAL;
  for (int k = 0; k < n; ++k) tree.position[static_cast<std::size_t>(permuted ? perm[k] : k)] = k;
  return tree;
}

bool solve_supernodal_forward(const void* factor, const double* B, int ncols, int ldb, double* Y,
                              SupernodalSolveWorkspace& workspace) {
  if (!is_supernodal_llt(factor)) return false;
  const auto [L, n, avx2, perm, permuted] =
      begin_factor_pass(factor, static_cast<std::size_t>(std::min(ncols, kMaxBlock)), workspace);
  double* y[kMaxBlock];
  for (int c0 = 0; c0 < ncols; c0 += kMaxBlock) {
    const int nr = std::min(kMaxBlock, ncols - c0);
    for (int r = 0; r < nr; ++r) {
      const double* col = B + static_cast<std::ptrdiff_t>(c0 + r) * ldb;
      y[r] = Y + static_cast<std::ptrdiff_t>(c0 + r) * n;
      for (int k = 0; k < n; ++k) y[r][k] = col[permuted ? perm[k] : k];
    }
    forward_columns(L, y, nr, avx2, workspace.gathered);
  }
  return true;
}

bool solve_supernodal_backward(const void* factor, double* Y, int ncols, double* X, int ldx,
                               SupernodalSolveWorkspace& workspace) {
  if (!is_supernodal_llt(factor)) return false;
  const auto [L, n, avx2, perm, permuted] =
      begin_factor_pass(factor, static_cast<std::size_t>(std::min(ncols, kMaxBlock)), workspace);
  double* y[kMaxBlock];
  for (int c0 = 0; c0 < ncols; c0 += kMaxBlock) {
    const int nr = std::min(kMaxBlock, ncols - c0);
    for (int r = 0; r < nr; ++r) y[r] = Y + static_cast<std::ptrdiff_t>(c0 + r) * n;
    backward_columns(L, y, nr, avx2, workspace.gathered);
    for (int r = 0; r < nr; ++r) {
      double* col = X + static_cast<std::ptrdiff_t>(c0 + r) * ldx;
      for (int k = 0; k < n; ++k) col[permuted ? perm[k] : k] = y[r][k];
    }
  }
  return true;
}

bool solve_supernodal_unit_forward(const void* factor, const SupernodalTree& tree, const int* rows,
                                   int count, UnitForwardColumn* out,
                                   SupernodalSolveWorkspace& workspace) {
  if (!is_supernodal_llt(factor)) return false;
  const auto [L, n, avx2, perm, permuted] = begin_factor_pass(factor, kMaxBlock, workspace);
  const int ns = static_cast<int>(L.nsuper);
  const int* super = static_cast<const int*>(L.super);
  // Zero columns (kept zero between calls) and the union of the columns' supernode chains.
  if (workspace.unit.size() < static_cast<std::size_t>(kMaxBlock) * n)
    workspace.unit.assign(static_cast<std::size_t>(kMaxBlock) * n, 0.0);
  if (workspace.marked.size() < static_cast<std::size_t>(ns)) workspace.marked.assign(static_cast<std::size_t>(ns), 0);
  std::vector<int> chain_union;
  double* b[kMaxBlock];
  for (int c0 = 0; c0 < count; c0 += kMaxBlock) {
    const int nr = std::min(kMaxBlock, count - c0);
    chain_union.clear();
    for (int r = 0; r < nr; ++r) {
      b[r] = workspace.unit.data() + static_cast<std::ptrdiff_t>(r) * n;
      const int k = tree.position[static_cast<std::size_t>(rows[c0 + r])];
      b[r][k] = 1.0;
      UnitForwardColumn& col = out[c0 + r];
      col.chain.clear();
      for (int sn = tree.supernode_of[static_cast<std::size_t>(k)]; sn >= 0; sn = tree.parent[static_cast<std::size_t>(sn)]) {
        col.chain.push_back(sn);
        if (!workspace.marked[static_cast<std::size_t>(sn)]) {
          workspace.marked[static_cast<std::size_t>(sn)] = 1;
          chain_union.push_back(sn);
        }
      }
      std::reverse(col.chain.begin(), col.chain.end());  // root first
    }
    // Supernodes off a column's chain see only zeros of that column and leave them zero, so the
    // union gives every column the values of its own full forward solve.
    std::sort(chain_union.begin(), chain_union.end());
    for (int sn : chain_union) forward_supernode(L, sn, b, nr, avx2, workspace.gathered);
    for (int r = 0; r < nr; ++r) {
      UnitForwardColumn& col = out[c0 + r];
      col.offset.assign(1, 0);
      col.values.clear();
      for (int sn : col.chain) {
        col.values.insert(col.values.end(), b[r] + super[sn], b[r] + super[sn + 1]);
        col.offset.push_back(static_cast<int>(col.values.size()));
      }
    }
    for (int sn : chain_union) {
      workspace.marked[static_cast<std::size_t>(sn)] = 0;
      for (int r = 0; r < nr; ++r) std::fill(b[r] + super[sn], b[r] + super[sn + 1], 0.0);
    }
  }
  return true;
}

double dot_unit_forward(const UnitForwardColumn& a, const UnitForwardColumn& b) {
  // Both chains run from the root down: they share a prefix and then part for good.
  std::size_t m = 0;
  while (m < a.chain.size() && m < b.chain.size() && a.chain[m] == b.chain[m]) ++m;
  const int len = m == 0 ? 0 : a.offset[m];
  double sum = 0.0;
  for (int i = 0; i < len; ++i) sum += a.values[static_cast<std::size_t>(i)] * b.values[static_cast<std::size_t>(i)];
  return sum;
}

}  // namespace fascicle
