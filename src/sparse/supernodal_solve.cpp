// Forward and backward substitution with CHOLMOD's supernodal LLᵀ factor (the factor is the
// library's; only its application is ours). For the few right-hand sides of the deformation and
// dynamics solves, CHOLMOD's per-supernode dtrsm/dgemm calls cost more than their arithmetic on the
// small supernodes of these meshes.
#include "fascicle/sparse/supernodal_solve.hpp"

#include <suitesparse/cholmod.h>

#include <algorithm>
#include <cstddef>
#include <cstring>

#include <immintrin.h>

namespace fascicle {

namespace {

// Right-hand sides solved together in one pass over the factor (which may not fit in the cache).
constexpr int kMaxBlock = 8;
// Columns per block of the backward kernel (fixes the order of its sums: supernodal_kernels.inc).
constexpr int kBackwardBlock = 4;
// Columns per block of the forward kernel (any width gives the same bits).
// Eight (tried) is slower: the broadcast values no longer fit in the registers.
constexpr int kForwardBlock = 4;

// A supernode holds columns k1 .. k1 + nscol of L as a dense nsrow x nscol column-major block
// whose row indices are rows[0 .. nsrow), the first nscol of them k1 .. k1 + nscol. t[0 .. nr):
// the right-hand sides gathered at those rows. The kernels `forward` and `backward` solve with
// that block; they exist in three clones (AVX-512, AVX2 + FMA, generic) that give identical bits
// (the rules are at the top of supernodal_kernels.inc).

}  // namespace

namespace sn_generic {
namespace {
#define FASCICLE_SN_GENERIC
#include "supernodal_kernels.inc"
#undef FASCICLE_SN_GENERIC
}  // namespace
}  // namespace sn_generic

#pragma GCC push_options
#pragma GCC target("avx2,fma")
namespace sn_avx2 {
namespace {
#define FASCICLE_SN_AVX2
#include "supernodal_kernels.inc"
#undef FASCICLE_SN_AVX2
}  // namespace
}  // namespace sn_avx2
#pragma GCC pop_options

#pragma GCC push_options
#pragma GCC target("avx512f,avx2,fma")
#pragma GCC diagnostic push
// GCC 12's _mm512_extractf64x4_pd initialises an unused operand from itself.
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
namespace sn_avx512 {
namespace {
#define FASCICLE_SN_AVX512
#include "supernodal_kernels.inc"
#undef FASCICLE_SN_AVX512
}  // namespace
}  // namespace sn_avx512
#pragma GCC diagnostic pop
#pragma GCC pop_options

namespace {

// One supernode sn of the factor for nr right-hand sides b[r] (whole vectors, permuted order);
// `scratch`: (nsrow − nscol) nr doubles.
using SupernodeKernel = void (*)(const double* Lx, int nsrow, int nscol, const int* rows, double* const* b,
                                 int nr, double* scratch);
struct Kernels {
  SupernodeKernel forward, backward;
};

Kernels get_kernels(SupernodalKernel which) {
  switch (which) {
    case SupernodalKernel::avx512: return {sn_avx512::forward, sn_avx512::backward};
    case SupernodalKernel::avx2: return {sn_avx2::forward, sn_avx2::backward};
    default: return {sn_generic::forward, sn_generic::backward};
  }
}

// L y = b (forward) or Lᵀ x = y (backward) of supernode sn for nr (1 .. kMaxBlock) columns b[r]
// (permuted system), in place.
inline void apply_supernode(SupernodeKernel kernel, const cholmod_factor& L, int sn, double* const* b, int nr,
                            std::vector<double>& scratch) {
  const int* super = static_cast<const int*>(L.super);
  const int* pi = static_cast<const int*>(L.pi);
  const int* px = static_cast<const int*>(L.px);
  const int* ls = static_cast<const int*>(L.s);
  const double* lx = static_cast<const double*>(L.x);
  const int nscol = super[sn + 1] - super[sn], nsrow = pi[sn + 1] - pi[sn];
  kernel(lx + px[sn], nsrow, nscol, ls + pi[sn], b, nr, scratch.data());
}

void forward_columns(const cholmod_factor& L, double* const* b, int nr, const Kernels& kernels,
                     std::vector<double>& scratch) {
  const int ns = static_cast<int>(L.nsuper);
  for (int sn = 0; sn < ns; ++sn) apply_supernode(kernels.forward, L, sn, b, nr, scratch);
}

void backward_columns(const cholmod_factor& L, double* const* b, int nr, const Kernels& kernels,
                      std::vector<double>& scratch) {
  for (int sn = static_cast<int>(L.nsuper) - 1; sn >= 0; --sn) apply_supernode(kernels.backward, L, sn, b, nr, scratch);
}

// L Lᵀ x = b in place for nr (1 .. kMaxBlock) columns b[r] (permuted system).
void solve_columns(const cholmod_factor& L, double* const* b, int nr, const Kernels& kernels,
                   std::vector<double>& scratch) {
  forward_columns(L, b, nr, kernels, scratch);
  backward_columns(L, b, nr, kernels, scratch);
}

// The fastest clone this CPU runs (they all give the same bits).
SupernodalKernel best_kernel() {
  for (SupernodalKernel k : {SupernodalKernel::avx512, SupernodalKernel::avx2})
    if (has_supernodal_kernel(k)) return k;
  return SupernodalKernel::generic;
}
Kernels select_kernels(SupernodalSolveWorkspace& workspace) {
  if (workspace.kernel == SupernodalKernel::automatic) workspace.kernel = best_kernel();
  return get_kernels(workspace.kernel);
}

// What every solve entry point needs of the factor: its size, the kernel, the fill-reducing
// permutation, and a gather buffer for `chunk` columns of at most n rows of a supernode.
struct FactorPass {
  const cholmod_factor& L;
  int n;
  Kernels kernels;
  const int* perm;
  bool permuted;
};
FactorPass begin_factor_pass(const void* factor, std::size_t chunk, SupernodalSolveWorkspace& workspace) {
  const cholmod_factor& L = *static_cast<const cholmod_factor*>(factor);
  const int n = static_cast<int>(L.n);
  if (workspace.gathered.size() < chunk * n) workspace.gathered.resize(chunk * n);
  const int* perm = static_cast<const int*>(L.Perm);
  return {L, n, select_kernels(workspace), perm, perm && L.ordering != CHOLMOD_NATURAL};
}

}  // namespace

bool has_supernodal_kernel(SupernodalKernel kernel) {
  __builtin_cpu_init();
  switch (kernel) {
    case SupernodalKernel::avx512: return __builtin_cpu_supports("avx512f");
    case SupernodalKernel::avx2: return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    default: return true;
  }
}

bool is_supernodal_llt(const void* factor) {
  const auto* L = static_cast<const cholmod_factor*>(factor);
  return L && L->is_super && L->is_ll && L->itype == CHOLMOD_INT && L->xtype == CHOLMOD_REAL &&
         L->dtype == CHOLMOD_DOUBLE && L->x && L->super && L->pi && L->px && L->s;
}

bool solve_supernodal_llt(const void* factor, double* B, int ncols, int ld,
                          SupernodalSolveWorkspace& workspace) {
  if (!is_supernodal_llt(factor)) return false;
  const std::size_t chunk = static_cast<std::size_t>(std::min(ncols, kMaxBlock));
  const auto [L, n, kernels, perm, permuted] = begin_factor_pass(factor, chunk, workspace);
  if (permuted && workspace.permuted.size() < chunk * n) workspace.permuted.resize(chunk * n);
  double* b[kMaxBlock];
  double* cols[kMaxBlock];
  for (int c0 = 0; c0 < ncols; c0 += kMaxBlock) {
    const int nr = std::min(kMaxBlock, ncols - c0);
    for (int r = 0; r < nr; ++r) {
      cols[r] = B + static_cast<std::ptrdiff_t>(c0 + r) * ld;
      // the permuted copy of the right-hand side (P b), or the column itself
      b[r] = permuted ? workspace.permuted.data() + static_cast<std::ptrdiff_t>(r) * n : cols[r];
    }
    // the permutation read once for all the block's columns
    if (permuted)
      for (int k = 0; k < n; ++k) {
        const int from = perm[k];
        for (int r = 0; r < nr; ++r) b[r][k] = cols[r][from];
      }
    solve_columns(L, b, nr, kernels, workspace.gathered);
    if (permuted)
      for (int k = 0; k < n; ++k) {
        const int to = perm[k];
        for (int r = 0; r < nr; ++r) cols[r][to] = b[r][k];
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
  const auto [L, n, kernels, perm, permuted] =
      begin_factor_pass(factor, static_cast<std::size_t>(std::min(ncols, kMaxBlock)), workspace);
  double* y[kMaxBlock];
  for (int c0 = 0; c0 < ncols; c0 += kMaxBlock) {
    const int nr = std::min(kMaxBlock, ncols - c0);
    const double* cols[kMaxBlock];
    for (int r = 0; r < nr; ++r) {
      cols[r] = B + static_cast<std::ptrdiff_t>(c0 + r) * ldb;
      y[r] = Y + static_cast<std::ptrdiff_t>(c0 + r) * n;
    }
    for (int k = 0; k < n; ++k) {  // the permutation read once for all the block's columns
      const int from = permuted ? perm[k] : k;
      for (int r = 0; r < nr; ++r) y[r][k] = cols[r][from];
    }
    forward_columns(L, y, nr, kernels, workspace.gathered);
  }
  return true;
}

bool solve_supernodal_backward(const void* factor, double* Y, int ncols, double* X, int ldx,
                               SupernodalSolveWorkspace& workspace) {
  if (!is_supernodal_llt(factor)) return false;
  const auto [L, n, kernels, perm, permuted] =
      begin_factor_pass(factor, static_cast<std::size_t>(std::min(ncols, kMaxBlock)), workspace);
  double* y[kMaxBlock];
  for (int c0 = 0; c0 < ncols; c0 += kMaxBlock) {
    const int nr = std::min(kMaxBlock, ncols - c0);
    for (int r = 0; r < nr; ++r) y[r] = Y + static_cast<std::ptrdiff_t>(c0 + r) * n;
    backward_columns(L, y, nr, kernels, workspace.gathered);
    double* cols[kMaxBlock];
    for (int r = 0; r < nr; ++r) cols[r] = X + static_cast<std::ptrdiff_t>(c0 + r) * ldx;
    for (int k = 0; k < n; ++k) {
      const int to = permuted ? perm[k] : k;
      for (int r = 0; r < nr; ++r) cols[r][to] = y[r][k];
    }
  }
  return true;
}

bool solve_supernodal_unit_forward(const void* factor, const SupernodalTree& tree, const int* rows,
                                   int count, UnitForwardColumn* out,
                                   SupernodalSolveWorkspace& workspace) {
  if (!is_supernodal_llt(factor)) return false;
  const auto [L, n, kernels, perm, permuted] = begin_factor_pass(factor, kMaxBlock, workspace);
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
    for (int sn : chain_union) apply_supernode(kernels.forward, L, sn, b, nr, workspace.gathered);
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
