// The one-pass simplicial LDLᵀ solve against CHOLMOD's own solve (cholmod_solve2), on factors
// that CHOLMOD ordered, factorised and modified by rank-one updates and downdates.
#include "fascicle/sparse/simplicial_solve.hpp"
#include "fascicle/sparse/cholmod_view.hpp"
#include "lower_csc.hpp"

#include <gtest/gtest.h>
#include <suitesparse/cholmod.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>
#include <vector>

namespace fascicle {
namespace {

// A spring lattice like the fibres-first systems: `fibres` chains of `length` particles, each
// particle joined to the next along its chain and to the same index on two other chains, with
// random stiffnesses and a small diagonal term (the fixed ends), rows shuffled. Lower triangle.
using Lattice = test::LowerCsc;

Lattice make_lattice(int fibres, int length, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> k(100.0, 400.0);
  const int n = fibres * length;
  std::vector<int> shuffle(n);
  for (int a = 0; a < n; ++a) shuffle[a] = a;
  std::shuffle(shuffle.begin(), shuffle.end(), rng);
  std::vector<std::vector<std::pair<int, double>>> cols(n);
  std::vector<double> diag(n, 1.0);
  auto spring = [&](int a, int b) {
    a = shuffle[a];
    b = shuffle[b];
    const double w = k(rng);
    cols[std::min(a, b)].push_back({std::max(a, b), -w});
    diag[a] += w;
    diag[b] += w;
  };
  std::uniform_int_distribution<int> other(0, fibres - 1);
  for (int f = 0; f < fibres; ++f)
    for (int s = 0; s < length; ++s) {
      if (s + 1 < length) spring(f * length + s, f * length + s + 1);
      for (int e = 0; e < 2; ++e) {
        const int g = other(rng);
        if (g != f) spring(f * length + s, g * length + s);
      }
    }
  return test::assemble_lower_csc(std::move(cols), diag);
}

class SimplicialSolve : public ::testing::Test {
 protected:
  void SetUp() override { set_up(40, 15, 7u); }
  // Factorises make_lattice(fibres, length, seed) as a simplicial LDL^T.
  void set_up(int fibres, int length, unsigned seed) {
    cholmod_start(&c_);
    c_.print = 0;
    c_.supernodal = CHOLMOD_SIMPLICIAL;
    c_.final_ll = 0;
    A_ = make_lattice(fibres, length, seed);
    view_ = view_symmetric_lower(static_cast<std::size_t>(A_.n), A_.x.size(), A_.p.data(), A_.i.data(), A_.x.data());
    L_ = cholmod_analyze(&view_, &c_);
    ASSERT_NE(L_, nullptr);
    ASSERT_TRUE(cholmod_factorize(&view_, L_, &c_));
  }
  void TearDown() override {
    if (L_) cholmod_free_factor(&L_, &c_);
    cholmod_finish(&c_);
  }
  // Adds (update) or removes (downdate) weights w on the diagonal rows `rows` (original order)
  // by cholmod_updown, as the fibres-first solver does for contacts; A_ follows.
  void modify(bool update, const std::vector<int>& rows, double w) {
    const int* perm = static_cast<const int*>(L_->Perm);
    std::vector<int> position(A_.n);
    for (int k = 0; k < A_.n; ++k) position[perm[k]] = k;
    const std::size_t m = rows.size();
    cholmod_sparse* C = cholmod_allocate_sparse(L_->n, m, m, 1, 1, 0, CHOLMOD_REAL, &c_);
    for (std::size_t j = 0; j < m; ++j) {
      static_cast<int*>(C->p)[j] = static_cast<int>(j);
      static_cast<int*>(C->i)[j] = position[rows[j]];
      static_cast<double*>(C->x)[j] = std::sqrt(w);
      for (int q = A_.p[rows[j]]; q < A_.p[rows[j] + 1]; ++q)
        if (A_.i[q] == rows[j]) A_.x[q] += update ? w : -w;
    }
    static_cast<int*>(C->p)[m] = static_cast<int>(m);
    ASSERT_TRUE(cholmod_updown(update ? 1 : 0, C, L_, &c_));
    cholmod_free_sparse(&C, &c_);
  }
  std::vector<double> make_rhs(int ncols, unsigned seed) const {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    std::vector<double> B(static_cast<std::size_t>(A_.n) * ncols);
    for (double& b : B) b = u(rng);
    return B;
  }
  std::vector<double> cholmod_solution(const std::vector<double>& B, int ncols) {
    cholmod_dense b{};
    b.nrow = static_cast<std::size_t>(A_.n);
    b.ncol = static_cast<std::size_t>(ncols);
    b.nzmax = b.nrow * b.ncol;
    b.d = b.nrow;
    b.x = const_cast<double*>(B.data());
    b.xtype = CHOLMOD_REAL;
    b.dtype = CHOLMOD_DOUBLE;
    cholmod_dense* X = cholmod_solve(CHOLMOD_A, L_, &b, &c_);
    std::vector<double> x(static_cast<const double*>(X->x), static_cast<const double*>(X->x) + B.size());
    cholmod_free_dense(&X, &c_);
    return x;
  }
  // max |A x - b| / max |b| over all columns (A from its lower triangle)
  double relative_residual(const std::vector<double>& X, const std::vector<double>& B, int ncols) const {
    double worst = 0.0, scale = 0.0;
    for (int c = 0; c < ncols; ++c) {
      const double* x = X.data() + static_cast<std::size_t>(c) * A_.n;
      const double* b = B.data() + static_cast<std::size_t>(c) * A_.n;
      std::vector<double> r(b, b + A_.n);
      for (int col = 0; col < A_.n; ++col)
        for (int q = A_.p[col]; q < A_.p[col + 1]; ++q) {
          const int row = A_.i[q];
          r[row] -= A_.x[q] * x[col];
          if (row != col) r[col] -= A_.x[q] * x[row];
        }
      for (int k = 0; k < A_.n; ++k) {
        worst = std::max(worst, std::abs(r[k]));
        scale = std::max(scale, std::abs(b[k]));
      }
    }
    return worst / scale;
  }
  cholmod_common c_;
  Lattice A_;
  cholmod_sparse view_{};
  cholmod_factor* L_ = nullptr;
};

TEST_F(SimplicialSolve, FactorIsAPermutedSimplicialLdlt) {
  EXPECT_TRUE(is_simplicial_ldlt(L_));
  const int* perm = static_cast<const int*>(L_->Perm);
  int moved = 0;
  for (int k = 0; k < A_.n; ++k) moved += perm[k] != k;
  EXPECT_GT(moved, A_.n / 2);
}

// Same bits as cholmod_solve for 1 to 8 columns (CHOLMOD: four per pass, with chains of columns
// whose length depends on the count), before and after rank-one updates and downdates, and a
// solution of A x = b.
TEST_F(SimplicialSolve, EqualsCholmodSolveBitForBitForOneToEightColumns) {
  for (int stage = 0; stage < 3; ++stage) {
    if (stage == 1) modify(true, {3, 50, 51, 52, 300, 599}, 4e4);
    if (stage == 2) modify(false, {50, 52}, 4e4);
    SimplicialSolveWorkspace ws;
    for (int ncols = 1; ncols <= 8; ++ncols) {
      const std::vector<double> B = make_rhs(ncols, 11u + ncols);
      std::vector<double> X = B;
      ASSERT_TRUE(solve_simplicial_ldlt(L_, X.data(), ncols, A_.n, ws));
      const std::vector<double> expected = cholmod_solution(B, ncols);
      EXPECT_EQ(std::memcmp(X.data(), expected.data(), X.size() * sizeof(double)), 0)
          << "stage " << stage << ", " << ncols << " columns";
      EXPECT_LT(relative_residual(X, B, ncols), 1e-12) << "stage " << stage << ", " << ncols << " columns";
    }
  }
}

// More rows than 16-bit indices can hold (a shuffled chain of 70 000 unknowns, which AMD orders
// without fill): the solve reads L's own 32-bit row indices, keeps no 16-bit copy, and still gives
// CHOLMOD's bits.
class SimplicialSolveLarge : public SimplicialSolve {
 protected:
  void SetUp() override { set_up(1, 70000, 5u); }
};

TEST_F(SimplicialSolveLarge, MoreRowsThanSixteenBitIndicesKeepCholmodBits) {
  ASSERT_GT(A_.n, 65536);
  SimplicialSolveWorkspace ws;
  for (int ncols : {1, 3, 8}) {
    const std::vector<double> B = make_rhs(ncols, 21u + ncols);
    std::vector<double> X = B;
    ASSERT_TRUE(solve_simplicial_ldlt(L_, X.data(), ncols, A_.n, ws));
    const std::vector<double> expected = cholmod_solution(B, ncols);
    EXPECT_EQ(std::memcmp(X.data(), expected.data(), X.size() * sizeof(double)), 0) << ncols << " columns";
    EXPECT_LT(relative_residual(X, B, ncols), 1e-12) << ncols << " columns";
  }
  EXPECT_TRUE(ws.row_index16.empty());
}

// One workspace across modifications that change L's pattern (a rank-one update coupling the
// first and the last unknown adds fill; the downdate keeps it): the solve's 16-bit copy of L's
// row indices follows, and every solve keeps CHOLMOD's bits.
TEST_F(SimplicialSolve, ReusedWorkspaceFollowsPatternChanges) {
  SimplicialSolveWorkspace ws;
  auto expect_cholmod_bits = [&](const char* stage) {
    for (int ncols : {3, 6}) {
      const std::vector<double> B = make_rhs(ncols, 70u + ncols);
      std::vector<double> X = B;
      ASSERT_TRUE(solve_simplicial_ldlt(L_, X.data(), ncols, A_.n, ws));
      const std::vector<double> expected = cholmod_solution(B, ncols);
      EXPECT_EQ(std::memcmp(X.data(), expected.data(), X.size() * sizeof(double)), 0) << stage << ", " << ncols;
    }
  };
  expect_cholmod_bits("before");
  std::size_t entries_before = 0;
  for (std::size_t j = 0; j < L_->n; ++j) entries_before += static_cast<const int*>(L_->nz)[j];
  cholmod_sparse* C = cholmod_allocate_sparse(L_->n, 1, 2, 1, 1, 0, CHOLMOD_REAL, &c_);
  static_cast<int*>(C->p)[0] = 0;
  static_cast<int*>(C->p)[1] = 2;
  static_cast<int*>(C->i)[0] = 0;
  static_cast<int*>(C->i)[1] = static_cast<int>(L_->n) - 1;
  static_cast<double*>(C->x)[0] = static_cast<double*>(C->x)[1] = 30.0;
  ASSERT_TRUE(cholmod_updown(1, C, L_, &c_));
  std::size_t entries_after = 0;
  for (std::size_t j = 0; j < L_->n; ++j) entries_after += static_cast<const int*>(L_->nz)[j];
  EXPECT_GT(entries_after, entries_before);  // the update added fill
  expect_cholmod_bits("after the update");
  ASSERT_TRUE(cholmod_updown(0, C, L_, &c_));
  expect_cholmod_bits("after the downdate");
  cholmod_free_sparse(&C, &c_);
}

// Right-hand sides stored by rows (4 or 8 doubles per unknown, the unused lanes left alone): the
// same bits as the column solve, and so as CHOLMOD's, for 1 to 8 columns; rows already in the
// factor's order too; wrong widths refused.
TEST_F(SimplicialSolve, RowStorageGivesTheColumnSolvesBits) {
  SimplicialSolveWorkspace rows_ws, columns_ws;
  for (int ncols = 1; ncols <= 8; ++ncols) {
    const int width = ncols <= 4 ? 4 : 8;
    const std::vector<double> B = make_rhs(ncols, 90u + ncols);
    std::vector<double> columns = B;
    ASSERT_TRUE(solve_simplicial_ldlt(L_, columns.data(), ncols, A_.n, columns_ws));
    std::vector<double> rows(static_cast<std::size_t>(A_.n) * width, -3.0);
    for (int k = 0; k < A_.n; ++k)
      for (int c = 0; c < ncols; ++c) rows[static_cast<std::size_t>(k) * width + c] = B[static_cast<std::size_t>(c) * A_.n + k];
    ASSERT_TRUE(solve_simplicial_ldlt_rows(L_, rows.data(), ncols, width, rows_ws));
    for (int k = 0; k < A_.n; ++k) {
      for (int c = 0; c < ncols; ++c) {
        const double a = rows[static_cast<std::size_t>(k) * width + c], b = columns[static_cast<std::size_t>(c) * A_.n + k];
        ASSERT_EQ(std::memcmp(&a, &b, sizeof(double)), 0) << ncols << " columns, row " << k << ", column " << c;
      }
      for (int c = ncols; c < width; ++c) ASSERT_EQ(rows[static_cast<std::size_t>(k) * width + c], -3.0);
    }
  }
  // rows already in the factor's order (row k: unknown Perm[k]), solved in place: the same bits
  const int* perm = static_cast<const int*>(L_->Perm);
  for (int ncols : {3, 6}) {
    const int width = ncols <= 4 ? 4 : 8;
    const std::vector<double> B = make_rhs(ncols, 120u + ncols);
    std::vector<double> natural(static_cast<std::size_t>(A_.n) * width, 0.0), permuted = natural;
    for (int k = 0; k < A_.n; ++k)
      for (int c = 0; c < ncols; ++c) {
        natural[static_cast<std::size_t>(k) * width + c] = B[static_cast<std::size_t>(c) * A_.n + k];
        permuted[static_cast<std::size_t>(k) * width + c] = B[static_cast<std::size_t>(c) * A_.n + perm[k]];
      }
    ASSERT_TRUE(solve_simplicial_ldlt_rows(L_, natural.data(), ncols, width, rows_ws));
    ASSERT_TRUE(solve_simplicial_ldlt_in_factor_order(L_, permuted.data(), ncols, width, columns_ws));
    for (int k = 0; k < A_.n; ++k)
      for (int c = 0; c < ncols; ++c)
        ASSERT_EQ(std::memcmp(&permuted[static_cast<std::size_t>(k) * width + c],
                              &natural[static_cast<std::size_t>(perm[k]) * width + c], sizeof(double)), 0)
            << ncols << " columns, row " << k;
  }
  std::vector<double> rows(static_cast<std::size_t>(A_.n) * 8, 1.0);
  EXPECT_FALSE(solve_simplicial_ldlt_in_factor_order(L_, rows.data(), 6, 4, rows_ws));
  EXPECT_FALSE(solve_simplicial_ldlt_rows(L_, rows.data(), 3, 8, rows_ws));  // 3 columns need width 4
  EXPECT_FALSE(solve_simplicial_ldlt_rows(L_, rows.data(), 6, 4, rows_ws));
  EXPECT_FALSE(solve_simplicial_ldlt_rows(nullptr, rows.data(), 3, 4, rows_ws));
}

TEST_F(SimplicialSolve, LeadingDimensionLeavesTheGapUntouched) {
  const int ld = A_.n + 5, ncols = 3;
  const std::vector<double> packed = make_rhs(ncols, 5u);
  std::vector<double> padded(static_cast<std::size_t>(ld) * ncols, -7.0);
  for (int c = 0; c < ncols; ++c)
    std::copy_n(packed.data() + static_cast<std::size_t>(c) * A_.n, A_.n, padded.data() + static_cast<std::size_t>(c) * ld);
  SimplicialSolveWorkspace ws;
  ASSERT_TRUE(solve_simplicial_ldlt(L_, padded.data(), ncols, ld, ws));
  const std::vector<double> expected = cholmod_solution(packed, ncols);
  for (int c = 0; c < ncols; ++c) {
    EXPECT_EQ(std::memcmp(padded.data() + static_cast<std::size_t>(c) * ld,
                          expected.data() + static_cast<std::size_t>(c) * A_.n, A_.n * sizeof(double)), 0);
    for (int k = A_.n; k < ld; ++k) EXPECT_EQ(padded[static_cast<std::size_t>(c) * ld + k], -7.0);
  }
}

// One workspace for solves of alternating widths (as the fibres-first solver's three- and
// six-column solves): every solve equals a fresh workspace's.
TEST_F(SimplicialSolve, ReusedWorkspaceGivesTheSameBitsAsAFreshOne) {
  SimplicialSolveWorkspace reused;
  for (int ncols : {3, 6, 3, 3, 6, 6, 1, 3}) {
    std::vector<double> a = make_rhs(ncols, 20u + ncols), b = a;
    SimplicialSolveWorkspace fresh;
    ASSERT_TRUE(solve_simplicial_ldlt(L_, a.data(), ncols, A_.n, reused));
    ASSERT_TRUE(solve_simplicial_ldlt(L_, b.data(), ncols, A_.n, fresh));
    EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(double)), 0) << ncols;
  }
}

TEST_F(SimplicialSolve, GenericAndAvx2KernelsGiveIdenticalBits) {
  __builtin_cpu_init();
  if (!__builtin_cpu_supports("avx2")) GTEST_SKIP() << "no AVX2 on this CPU";
  for (int ncols : {3, 6}) {
    std::vector<double> generic = make_rhs(ncols, 3u), avx2 = generic;
    SimplicialSolveWorkspace g, a;
    g.kernel = SimplicialKernel::generic;
    a.kernel = SimplicialKernel::avx2;
    ASSERT_TRUE(solve_simplicial_ldlt(L_, generic.data(), ncols, A_.n, g));
    ASSERT_TRUE(solve_simplicial_ldlt(L_, avx2.data(), ncols, A_.n, a));
    EXPECT_EQ(std::memcmp(generic.data(), avx2.data(), generic.size() * sizeof(double)), 0) << ncols;
  }
}

TEST_F(SimplicialSolve, RefusesWhatItCannotApply) {
  SimplicialSolveWorkspace ws;
  std::vector<double> B = make_rhs(9, 1u);
  const std::vector<double> before = B;
  EXPECT_FALSE(solve_simplicial_ldlt(L_, B.data(), 9, A_.n, ws));  // more than eight columns
  EXPECT_FALSE(solve_simplicial_ldlt(L_, B.data(), 0, A_.n, ws));
  EXPECT_FALSE(solve_simplicial_ldlt(nullptr, B.data(), 3, A_.n, ws));
  // an LLᵀ factor
  cholmod_factor* LL = cholmod_copy_factor(L_, &c_);
  ASSERT_TRUE(cholmod_change_factor(CHOLMOD_REAL, 1, 0, 1, 1, LL, &c_));
  EXPECT_FALSE(is_simplicial_ldlt(LL));
  EXPECT_FALSE(solve_simplicial_ldlt(LL, B.data(), 3, A_.n, ws));
  cholmod_free_factor(&LL, &c_);
  EXPECT_EQ(B, before);
}

}  // namespace
}  // namespace fascicle
