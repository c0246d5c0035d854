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

// L Lᵀ x = b in place for nr (1 .. kMaxBlock) columns b[r] (unpermuted system), supernode by
// supernode.
void solve_columns(const cholmod_factor& L, double* const* b, int nr, bool avx2,
                   std::vector<double>& gathered) {
  const int* super = static_cast<const int*>(L.super);
  const int* pi = static_cast<const int*>(L.pi);
  const int* px = static_cast<const int*>(L.px);
  const int* ls = static_cast<const int*>(L.s);
  const double* lx = static_cast<const double*>(L.x);
  const int ns = static_cast<int>(L.nsuper);
  auto forward = avx2 ? supernode_forward_avx2 : supernode_forward_generic;
  auto backward = avx2 ? supernode_backward_avx2 : supernode_backward_generic;
  double* t[kMaxBlock];
  for (int sn = 0; sn < ns; ++sn) {
    const int nscol = super[sn + 1] - super[sn], nsrow = pi[sn + 1] - pi[sn];
    const int* rows = ls + pi[sn];
    for (int r = 0; r < nr; ++r) {
      t[r] = gathered.data() + static_cast<std::ptrdiff_t>(r) * nsrow;
      for (int i = 0; i < nsrow; ++i) t[r][i] = b[r][rows[i]];
    }
    forward(lx + px[sn], nsrow, nscol, t, nr);
    for (int r = 0; r < nr; ++r)
      for (int i = 0; i < nsrow; ++i) b[r][rows[i]] = t[r][i];
  }
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

}  // namespace

bool is_supernodal_llt(const void* factor) {
  const auto* L = static_cast<const cholmod_factor*>(factor);
  return L && L->is_super && L->is_ll && L->itype == CHOLMOD_INT && L->xtype == CHOLMOD_REAL &&
         L->dtype == CHOLMOD_DOUBLE && L->x && L->super && L->pi && L->px && L->s;
}

bool solve_supernodal_llt(const void* factor, double* B, int ncols, int ld,
                          SupernodalSolveWorkspace& workspace) {
  if (!is_supernodal_llt(factor)) return false;
  const cholmod_factor& L = *static_cast<const cholmod_factor*>(factor);
  const int n = static_cast<int>(L.n);
  if (workspace.kernel == SupernodalKernel::automatic)
    workspace.kernel = has_avx2() ? SupernodalKernel::avx2 : SupernodalKernel::generic;
  const bool avx2 = workspace.kernel == SupernodalKernel::avx2;
  const std::size_t chunk = static_cast<std::size_t>(std::min(ncols, kMaxBlock));
  // At most kMaxBlock columns of at most n rows of a supernode.
  if (workspace.gathered.size() < chunk * n) workspace.gathered.resize(chunk * n);
  const int* perm = static_cast<const int*>(L.Perm);
  const bool permuted = perm && L.ordering != CHOLMOD_NATURAL;
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

}  // namespace fascicle
