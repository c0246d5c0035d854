// Simplicial LDLᵀ solves for up to eight right-hand sides in one pass (see simplicial_solve.hpp).
#include "fascicle/sparse/simplicial_solve.hpp"

#include <suitesparse/cholmod.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>

namespace fascicle {

namespace {

// Four doubles (GCC's vector extension: two SSE2 registers in the generic clone, one AVX register
// in the AVX2 clone; the same lane-wise IEEE operations either way). A row of the solution holds
// W of them: its columns side by side, the unused ones zero. Loads and stores are unaligned
// vector moves (the type's alignment is that of a double).
using V4d = double __attribute__((vector_size(32), aligned(8), may_alias));

template <int W>
struct Row {
  V4d v[W];
};
template <int W>
[[gnu::always_inline]] inline Row<W> load(const double* x) {
  Row<W> r;
  for (int w = 0; w < W; ++w) r.v[w] = *reinterpret_cast<const V4d*>(x + 4 * w);
  return r;
}
template <int W>
[[gnu::always_inline]] inline void store(double* x, const Row<W>& r) {
  for (int w = 0; w < W; ++w) *reinterpret_cast<V4d*>(x + 4 * w) = r.v[w];
}

// L y = b with L's unit diagonal, X: n rows of 4W doubles. Column j of L alone, or a chain of two
// or three consecutive columns when each is the previous one without its first entry (the test
// and the order of the operations are those of CHOLMOD's ldl_lsolve kernels, so every column of X
// gets the same bits as there: x_i - (l0 y0 + l1 y1 + l2 y2), summed left to right).
template <int W, class I>
[[gnu::always_inline]] inline void forward_unit(const int* Lp, const I* Li, const int* Lnz,
                                                const double* Lx, int n, double* X) {
  constexpr int S = 4 * W;
  for (int j = 0; j < n;) {
    int p = Lp[j];
    const int lnz = Lnz[j], pend = p + lnz;
    if (lnz < 4 || lnz != Lnz[j + 1] + 1 || Li[p + 1] != j + 1) {
      const Row<W> y = load<W>(X + static_cast<std::ptrdiff_t>(j) * S);
      #pragma GCC unroll 4
      for (++p; p < pend; ++p) {
        double* xi = X + static_cast<std::ptrdiff_t>(Li[p]) * S;
        Row<W> x = load<W>(xi);
        for (int w = 0; w < W; ++w) x.v[w] = x.v[w] - Lx[p] * y.v[w];
        store<W>(xi, x);
      }
      j += 1;
    } else if (lnz != Lnz[j + 2] + 2 || Li[p + 2] != j + 2) {
      int q = Lp[j + 1];
      const Row<W> y0 = load<W>(X + static_cast<std::ptrdiff_t>(j) * S);
      Row<W> y1 = load<W>(X + static_cast<std::ptrdiff_t>(j + 1) * S);
      for (int w = 0; w < W; ++w) y1.v[w] = y1.v[w] - Lx[p + 1] * y0.v[w];
      store<W>(X + static_cast<std::ptrdiff_t>(j + 1) * S, y1);
      #pragma GCC unroll 4
      for (p += 2, ++q; p < pend; ++p, ++q) {
        double* xi = X + static_cast<std::ptrdiff_t>(Li[p]) * S;
        Row<W> x = load<W>(xi);
        for (int w = 0; w < W; ++w) x.v[w] = x.v[w] - (Lx[p] * y0.v[w] + Lx[q] * y1.v[w]);
        store<W>(xi, x);
      }
      j += 2;
    } else {
      int q = Lp[j + 1], r = Lp[j + 2];
      const Row<W> y0 = load<W>(X + static_cast<std::ptrdiff_t>(j) * S);
      Row<W> y1 = load<W>(X + static_cast<std::ptrdiff_t>(j + 1) * S);
      Row<W> y2 = load<W>(X + static_cast<std::ptrdiff_t>(j + 2) * S);
      for (int w = 0; w < W; ++w) {
        y1.v[w] = y1.v[w] - Lx[p + 1] * y0.v[w];
        y2.v[w] = (y2.v[w] - Lx[p + 2] * y0.v[w]) - Lx[q + 1] * y1.v[w];
      }
      store<W>(X + static_cast<std::ptrdiff_t>(j + 1) * S, y1);
      store<W>(X + static_cast<std::ptrdiff_t>(j + 2) * S, y2);
      #pragma GCC unroll 4
      for (p += 3, q += 2, ++r; p < pend; ++p, ++q, ++r) {
        double* xi = X + static_cast<std::ptrdiff_t>(Li[p]) * S;
        Row<W> x = load<W>(xi);
        for (int w = 0; w < W; ++w)
          x.v[w] = x.v[w] - ((Lx[p] * y0.v[w] + Lx[q] * y1.v[w]) + Lx[r] * y2.v[w]);
        store<W>(xi, x);
      }
      j += 3;
    }
  }
}

// D Lᵀ x = y for four columns of X (rows of `stride` doubles): one group of columns from column j
// back, alone or the chain of two or three columns that ends at j (forward_unit's chains seen
// from their last column), at most MaxChain long; returns the next column. CHOLMOD's
// ldl_dltsolve kernels chain up to three columns for one to three right-hand sides and up to two
// for four, and the grouping decides the order of the operations, so a column gets CHOLMOD's bits
// only with the chain length of the group CHOLMOD solves it in (solve_simplicial_ldlt). Per
// column: y_j / d_j minus the dot product with the rows below, then the chain's own columns. A
// group reads only rows below its columns, so groups of different columns of X may interleave.
template <int MaxChain, class I>
[[gnu::always_inline]] inline int backward_group(const int* Lp, const I* Li, const int* Lnz,
                                                 const double* Lx, int j, double* X, int stride) {
  auto row = [X, stride](int k) { return X + static_cast<std::ptrdiff_t>(k) * stride; };
  int p = Lp[j];
  const int lnz = Lnz[j], pend = p + lnz;
  if (j < 4 || lnz != Lnz[j - 1] - 1 || Li[Lp[j - 1] + 1] != j) {
    V4d y = load<1>(row(j)).v[0] / Lx[p];
    #pragma GCC unroll 4
    for (++p; p < pend; ++p) y = y - Lx[p] * load<1>(row(Li[p])).v[0];
    store<1>(row(j), Row<1>{{y}});
    return j - 1;
  }
  if (MaxChain == 2 || lnz != Lnz[j - 2] - 2 || Li[Lp[j - 2] + 2] != j) {
    int q = Lp[j - 1];
    const double t = Lx[q + 1];
    V4d y0 = load<1>(row(j)).v[0] / Lx[p];
    V4d y1 = load<1>(row(j - 1)).v[0] / Lx[q];
    #pragma GCC unroll 4
    for (++p, q += 2; p < pend; ++p, ++q) {
      const V4d x = load<1>(row(Li[p])).v[0];
      y0 = y0 - Lx[p] * x;
      y1 = y1 - Lx[q] * x;
    }
    y1 = y1 - t * y0;
    store<1>(row(j), Row<1>{{y0}});
    store<1>(row(j - 1), Row<1>{{y1}});
    return j - 2;
  }
  int q = Lp[j - 1], r = Lp[j - 2];
  const double t0 = Lx[q + 1], t1 = Lx[r + 1], t2 = Lx[r + 2];
  V4d y0 = load<1>(row(j)).v[0] / Lx[p];
  V4d y1 = load<1>(row(j - 1)).v[0] / Lx[q];
  V4d y2 = load<1>(row(j - 2)).v[0] / Lx[r];
  #pragma GCC unroll 4
  for (++p, q += 2, r += 3; p < pend; ++p, ++q, ++r) {
    const V4d x = load<1>(row(Li[p])).v[0];
    y0 = y0 - Lx[p] * x;
    y1 = y1 - Lx[q] * x;
    y2 = y2 - Lx[r] * x;
  }
  y1 = y1 - t0 * y0;
  y2 = y2 - (t2 * y0 + t1 * y1);
  store<1>(row(j), Row<1>{{y0}});
  store<1>(row(j - 1), Row<1>{{y1}});
  store<1>(row(j - 2), Row<1>{{y2}});
  return j - 3;
}

// All columns of one four-wide half of X, the last column first.
template <int MaxChain, class I>
[[gnu::always_inline]] inline void backward_diagonal(const int* Lp, const I* Li, const int* Lnz,
                                                     const double* Lx, int n, double* X, int stride) {
  for (int j = n - 1; j >= 0;) j = backward_group<MaxChain>(Lp, Li, Lnz, Lx, j, X, stride);
}

// Both halves of an eight-wide X, the first with chains of at most two columns and the second
// with chains of MaxChainB, in one sweep: the group with the higher last column goes first, so
// the two halves read the same columns of L while they are in cache.
template <int MaxChainB, class I>
[[gnu::always_inline]] inline void backward_diagonal_pair(const int* Lp, const I* Li, const int* Lnz,
                                                          const double* Lx, int n, double* X) {
  int ja = n - 1, jb = n - 1;
  while (ja >= 0 || jb >= 0) {
    if (ja >= jb) ja = backward_group<2>(Lp, Li, Lnz, Lx, ja, X, 8);
    else jb = backward_group<MaxChainB>(Lp, Li, Lnz, Lx, jb, X + 4, 8);
  }
}

// Columns 0-3 of a pass over more than four go through CHOLMOD's four-column kernels and the
// others through those of their own count; the forward kernels chain alike for every count.
// Li: the factor's row indices, or their 16-bit copy (SimplicialSolveWorkspace::row_index16).
template <class I>
[[gnu::always_inline]] inline void solve_body(const cholmod_factor& L, const I* Li, double* X, int ncols) {
  const auto* Lp = static_cast<const int*>(L.p);
  const auto* Lnz = static_cast<const int*>(L.nz);
  const auto* Lx = static_cast<const double*>(L.x);
  const int n = static_cast<int>(L.n);
  if (ncols <= 4) {
    forward_unit<1>(Lp, Li, Lnz, Lx, n, X);
    if (ncols == 4) backward_diagonal<2>(Lp, Li, Lnz, Lx, n, X, 4);
    else backward_diagonal<3>(Lp, Li, Lnz, Lx, n, X, 4);
    return;
  }
  forward_unit<2>(Lp, Li, Lnz, Lx, n, X);
  if (ncols == 8) backward_diagonal_pair<2>(Lp, Li, Lnz, Lx, n, X);
  else backward_diagonal_pair<3>(Lp, Li, Lnz, Lx, n, X);
}
__attribute__((target("avx2"))) void solve_avx2(const cholmod_factor& L, const int* Li, double* X, int ncols) {
  solve_body(L, Li, X, ncols);
}
__attribute__((target("avx2"))) void solve_avx2(const cholmod_factor& L, const std::uint16_t* Li, double* X,
                                                int ncols) {
  solve_body(L, Li, X, ncols);
}
void solve_generic(const cholmod_factor& L, const int* Li, double* X, int ncols) { solve_body(L, Li, X, ncols); }
void solve_generic(const cholmod_factor& L, const std::uint16_t* Li, double* X, int ncols) {
  solve_body(L, Li, X, ncols);
}

// Brings the workspace's 16-bit copy of L's row indices up to date (n <= 65536 only): kept while
// L's index array, its size and every column's start and count are those it was made from (a
// rank-one update or downdate that adds entries changes a count; one that does not leaves the
// pattern as it was). Returns the copy, or null when n is too large for 16 bits.
const std::uint16_t* get_row_index16(const cholmod_factor& L, SimplicialSolveWorkspace& ws) {
  const int n = static_cast<int>(L.n);
  if (n > 65536) return nullptr;
  const auto* Lp = static_cast<const int*>(L.p);
  const auto* Lnz = static_cast<const int*>(L.nz);
  const auto* Li = static_cast<const int*>(L.i);
  const bool same = ws.row_index_source == L.i && ws.row_index16.size() == L.nzmax &&
                    ws.column_start.size() == static_cast<std::size_t>(n) &&
                    std::equal(Lp, Lp + n, ws.column_start.begin()) &&
                    std::equal(Lnz, Lnz + n, ws.column_count.begin());
  if (!same) {
    ws.row_index16.assign(L.nzmax, 0);
    for (int j = 0; j < n; ++j)
      for (int p = Lp[j]; p < Lp[j] + Lnz[j]; ++p) ws.row_index16[static_cast<std::size_t>(p)] = static_cast<std::uint16_t>(Li[p]);
    ws.column_start.assign(Lp, Lp + n);
    ws.column_count.assign(Lnz, Lnz + n);
    ws.row_index_source = L.i;
  }
  return ws.row_index16.data();
}

bool has_avx2() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2");
}

// Solves L D L^T x = b in place on rows in the factor's order (X: n rows of 4 or 8 lanes, ncols
// used), with the workspace's kernel (chosen on first use) and, for n <= 65536, the 16-bit copy of
// the row indices: the solve streams L twice, and its 4-byte indices are a third of each entry's
// bytes; the same entries in the same order, so the same bits.
void solve_rows_in_place(const cholmod_factor& L, SimplicialSolveWorkspace& workspace, double* X, int ncols) {
  if (workspace.kernel == SimplicialKernel::automatic)
    workspace.kernel = has_avx2() ? SimplicialKernel::avx2 : SimplicialKernel::generic;
  const bool avx2 = workspace.kernel == SimplicialKernel::avx2;
  if (const std::uint16_t* Li16 = get_row_index16(L, workspace))
    avx2 ? solve_avx2(L, Li16, X, ncols) : solve_generic(L, Li16, X, ncols);
  else
    avx2 ? solve_avx2(L, static_cast<const int*>(L.i), X, ncols) : solve_generic(L, static_cast<const int*>(L.i), X, ncols);
}

}  // namespace

bool is_simplicial_ldlt(const void* factor) {
  const auto* L = static_cast<const cholmod_factor*>(factor);
  return L && !L->is_super && !L->is_ll && L->minor == L->n && L->itype == CHOLMOD_INT &&
         L->xtype == CHOLMOD_REAL && L->dtype == CHOLMOD_DOUBLE && L->x && L->p && L->i && L->nz;
}

bool solve_simplicial_ldlt_in_factor_order(const void* factor, double* X, int ncols, int width,
                                           SimplicialSolveWorkspace& workspace) {
  if (!is_simplicial_ldlt(factor) || ncols < 1 || ncols > 8 || width != (ncols <= 4 ? 4 : 8)) return false;
  const cholmod_factor& L = *static_cast<const cholmod_factor*>(factor);
  solve_rows_in_place(L, workspace, X, ncols);
  return true;
}

bool solve_simplicial_ldlt_rows(const void* factor, double* B, int ncols, int width,
                                SimplicialSolveWorkspace& workspace) {
  if (!is_simplicial_ldlt(factor) || ncols < 1 || ncols > 8 || width != (ncols <= 4 ? 4 : 8)) return false;
  const cholmod_factor& L = *static_cast<const cholmod_factor*>(factor);
  const int n = static_cast<int>(L.n);
  const std::size_t size = static_cast<std::size_t>(n) * width;
  if (workspace.rows.size() < size) workspace.rows.resize(size);
  // the layout of `rows` changes (solve_simplicial_ldlt clears its unused lanes again)
  workspace.row_width = 0;
  workspace.used_columns = 0;
  double* X = workspace.rows.data();
  // (P b)_k = b_{Perm[k]}: whole rows, the lanes past ncols cleared
  const int* perm = L.ordering != CHOLMOD_NATURAL ? static_cast<const int*>(L.Perm) : nullptr;
  for (int k = 0; k < n; ++k) {
    const double* from = B + static_cast<std::ptrdiff_t>(perm ? perm[k] : k) * width;
    double* to = X + static_cast<std::ptrdiff_t>(k) * width;
    for (int c = 0; c < width; ++c) to[c] = c < ncols ? from[c] : 0.0;
  }
  solve_rows_in_place(L, workspace, X, ncols);
  for (int k = 0; k < n; ++k) {
    const double* from = X + static_cast<std::ptrdiff_t>(k) * width;
    double* to = B + static_cast<std::ptrdiff_t>(perm ? perm[k] : k) * width;
    for (int c = 0; c < ncols; ++c) to[c] = from[c];
  }
  return true;
}

bool solve_simplicial_ldlt(const void* factor, double* B, int ncols, int ld,
                           SimplicialSolveWorkspace& workspace) {
  if (!is_simplicial_ldlt(factor) || ncols < 1 || ncols > 8) return false;
  const cholmod_factor& L = *static_cast<const cholmod_factor*>(factor);
  const int n = static_cast<int>(L.n);
  if (ld < n) return false;  // B's columns must hold n rows
  const int W = ncols <= 4 ? 1 : 2, S = 4 * W;
  // Unused lanes hold 0, which the solve keeps (0 - l 0, 0 / d): they are cleared only when the
  // layout changes.
  const std::size_t size = static_cast<std::size_t>(n) * S;
  if (workspace.rows.size() < size || workspace.row_width != S || workspace.used_columns != ncols) {
    if (workspace.rows.size() < size) workspace.rows.resize(size);
    std::fill_n(workspace.rows.begin(), size, 0.0);
    workspace.row_width = S;
    workspace.used_columns = ncols;
  }
  double* X = workspace.rows.data();
  // (P b)_k = b_{Perm[k]} (natural order when the factor has no permutation)
  const int* perm = L.ordering != CHOLMOD_NATURAL ? static_cast<const int*>(L.Perm) : nullptr;
  for (int k = 0; k < n; ++k) {
    double* row = X + static_cast<std::ptrdiff_t>(k) * S;
    const std::ptrdiff_t from = perm ? perm[k] : k;
    for (int c = 0; c < ncols; ++c) row[c] = B[static_cast<std::ptrdiff_t>(c) * ld + from];
  }
  solve_rows_in_place(L, workspace, X, ncols);
  for (int c = 0; c < ncols; ++c) {
    double* col = B + static_cast<std::ptrdiff_t>(c) * ld;
    for (int k = 0; k < n; ++k) col[perm ? perm[k] : k] = X[static_cast<std::ptrdiff_t>(k) * S + c];
  }
  return true;
}

}  // namespace fascicle
