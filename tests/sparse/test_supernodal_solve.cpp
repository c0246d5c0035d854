// The supernodal LLᵀ solve against CHOLMOD's own solve on a permuted factor.
#include "fascicle/sparse/supernodal_solve.hpp"
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

// A random sparse SPD matrix (lower triangle stored): a 3-D grid Laplacian-like pattern with
// random off-diagonal weights and random extra couplings, diagonally dominant. Rows are shuffled
// so the fill-reducing ordering CHOLMOD picks is far from the identity, and the 3-D grid gives
// supernodes of many sizes (wide ones near the root of the elimination tree).
using TestMatrix = test::LowerCsc;

TestMatrix make_matrix(int side, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> w(0.1, 1.0);
  const int n = side * side * side;
  std::vector<int> shuffle(n);
  for (int k = 0; k < n; ++k) shuffle[k] = k;
  std::shuffle(shuffle.begin(), shuffle.end(), rng);
  std::vector<std::vector<std::pair<int, double>>> cols(n);  // lower part, by column
  std::vector<double> diag(n, 0.5);
  auto couple = [&](int a, int b, double v) {
    a = shuffle[a];
    b = shuffle[b];
    if (a == b) return;
    cols[std::min(a, b)].push_back({std::max(a, b), -v});
    diag[a] += v;
    diag[b] += v;
  };
  auto id = [&](int u, int v, int z) { return u + side * (v + side * z); };
  for (int z = 0; z < side; ++z)
    for (int v = 0; v < side; ++v)
      for (int u = 0; u < side; ++u) {
        if (u + 1 < side) couple(id(u, v, z), id(u + 1, v, z), w(rng));
        if (v + 1 < side) couple(id(u, v, z), id(u, v + 1, z), w(rng));
        if (z + 1 < side) couple(id(u, v, z), id(u, v, z + 1), w(rng));
      }
  std::uniform_int_distribution<int> any(0, n - 1);
  for (int e = 0; e < n / 10; ++e) couple(any(rng), any(rng), w(rng));
  return test::assemble_lower_csc(std::move(cols), diag);
}

class SupernodalSolve : public ::testing::Test {
 protected:
  void SetUp() override {
    cholmod_start(&c_);
    c_.print = 0;
    c_.supernodal = CHOLMOD_SUPERNODAL;
    A_ = make_matrix(12, 7u);
    S_ = view_symmetric_lower(static_cast<std::size_t>(A_.n), A_.x.size(), A_.p.data(), A_.i.data(), A_.x.data());
    L_ = cholmod_analyze(&S_, &c_);
    ASSERT_NE(L_, nullptr);
    ASSERT_TRUE(cholmod_factorize(&S_, L_, &c_));
    ASSERT_EQ(L_->minor, L_->n);
  }
  void TearDown() override {
    if (L_) cholmod_free_factor(&L_, &c_);
    cholmod_finish(&c_);
  }
  // CHOLMOD's own solve of A X = B (column-major, n x ncols).
  std::vector<double> cholmod_reference(const std::vector<double>& B, int ncols) {
    cholmod_dense* Bd = cholmod_allocate_dense(A_.n, ncols, A_.n, CHOLMOD_REAL, &c_);
    std::memcpy(Bd->x, B.data(), B.size() * sizeof(double));
    cholmod_dense* X = cholmod_solve(CHOLMOD_A, L_, Bd, &c_);
    std::vector<double> out(static_cast<const double*>(X->x),
                            static_cast<const double*>(X->x) + B.size());
    cholmod_free_dense(&X, &c_);
    cholmod_free_dense(&Bd, &c_);
    return out;
  }
  std::vector<double> random_rhs(int ncols, int ld, unsigned seed) const {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    std::vector<double> B(static_cast<std::size_t>(ld) * ncols);
    for (double& b : B) b = u(rng);
    return B;
  }
  cholmod_common c_{};
  TestMatrix A_;
  cholmod_sparse S_{};
  cholmod_factor* L_ = nullptr;
};

TEST_F(SupernodalSolve, FactorIsPermutedAndSupernodal) {
  ASSERT_TRUE(is_supernodal_llt(L_));
  const int* P = static_cast<const int*>(L_->Perm);
  int moved = 0;
  for (int k = 0; k < A_.n; ++k) moved += P[k] != k;
  EXPECT_GT(moved, A_.n / 2);  // the test exercises the permutation
  int widest = 0;
  const int* super = static_cast<const int*>(L_->super);
  for (std::size_t s = 0; s < L_->nsuper; ++s) widest = std::max(widest, super[s + 1] - super[s]);
  EXPECT_GE(widest, 8);  // and the four-column blocks of the kernels
}

// 1 .. 10 columns: every block width of the kernels (up to eight) and a second pass.
TEST_F(SupernodalSolve, EqualsCholmodSolveForOneToTenColumns) {
  SupernodalSolveWorkspace ws;
  for (int ncols = 1; ncols <= 10; ++ncols) {
    const std::vector<double> B = random_rhs(ncols, A_.n, 100u + ncols);
    const std::vector<double> ref = cholmod_reference(B, ncols);
    std::vector<double> X = B;
    ASSERT_TRUE(solve_supernodal_llt(L_, X.data(), ncols, A_.n, ws));
    for (int c = 0; c < ncols; ++c) {
      double diff = 0.0, norm = 0.0;
      for (int k = 0; k < A_.n; ++k) {
        const std::size_t q = static_cast<std::size_t>(c) * A_.n + k;
        diff = std::max(diff, std::abs(X[q] - ref[q]));
        norm = std::max(norm, std::abs(ref[q]));
      }
      EXPECT_LE(diff, 1e-12 * norm) << ncols << " columns, column " << c;
      EXPECT_GT(norm, 0.0);
    }
    // The residual of the original (unpermuted) system, independent of CHOLMOD's solve.
    for (int c = 0; c < ncols; ++c) {
      const double* x = X.data() + static_cast<std::size_t>(c) * A_.n;
      const double* b = B.data() + static_cast<std::size_t>(c) * A_.n;
      std::vector<double> r(b, b + A_.n);
      for (int j = 0; j < A_.n; ++j)
        for (int q = A_.p[j]; q < A_.p[j + 1]; ++q) {
          const int i = A_.i[q];
          r[i] -= A_.x[q] * x[j];
          if (i != j) r[j] -= A_.x[q] * x[i];
        }
      double rmax = 0.0;
      for (double v : r) rmax = std::max(rmax, std::abs(v));
      EXPECT_LE(rmax, 1e-12) << ncols << " columns, column " << c;
    }
  }
}

TEST_F(SupernodalSolve, ColumnsAreIndependentOfTheirCountAndLeadingDimension) {
  // Each column gives the same bits alone as within a block of eleven (eight, then three) with a
  // padded ld.
  const int ncols = 11, ld = A_.n + 5;
  const std::vector<double> B = random_rhs(ncols, ld, 31u);
  std::vector<double> X = B;
  SupernodalSolveWorkspace ws;
  ASSERT_TRUE(solve_supernodal_llt(L_, X.data(), ncols, ld, ws));
  for (int c = 0; c < ncols; ++c) {
    std::vector<double> one(B.begin() + static_cast<std::ptrdiff_t>(c) * ld,
                            B.begin() + static_cast<std::ptrdiff_t>(c) * ld + A_.n);
    ASSERT_TRUE(solve_supernodal_llt(L_, one.data(), 1, A_.n, ws));
    for (int k = 0; k < A_.n; ++k)
      ASSERT_EQ(one[k], X[static_cast<std::size_t>(c) * ld + k]) << "column " << c << " row " << k;
    for (int k = A_.n; k < ld; ++k)  // padding untouched
      ASSERT_EQ(X[static_cast<std::size_t>(c) * ld + k], B[static_cast<std::size_t>(c) * ld + k]);
  }
}

TEST_F(SupernodalSolve, EveryKernelCloneGivesIdenticalBits) {
  // The AVX-512 and AVX2 clones (those this CPU runs) against the generic one, whole solves and
  // forward halves, for every block width and a second pass.
  if (!has_supernodal_kernel(SupernodalKernel::avx2) && !has_supernodal_kernel(SupernodalKernel::avx512))
    GTEST_SKIP() << "this CPU runs only the generic clone";
  for (SupernodalKernel kernel : {SupernodalKernel::avx2, SupernodalKernel::avx512}) {
    if (!has_supernodal_kernel(kernel)) continue;
    for (int ncols = 1; ncols <= 9; ++ncols) {
      const std::vector<double> B = random_rhs(ncols, A_.n, 500u + ncols);
      std::vector<double> Xg = B, Xv = B, Yg(B.size()), Yv(B.size());
      SupernodalSolveWorkspace wg, wv;
      wg.kernel = SupernodalKernel::generic;
      wv.kernel = kernel;
      ASSERT_TRUE(solve_supernodal_llt(L_, Xg.data(), ncols, A_.n, wg));
      ASSERT_TRUE(solve_supernodal_llt(L_, Xv.data(), ncols, A_.n, wv));
      EXPECT_EQ(0, std::memcmp(Xg.data(), Xv.data(), Xg.size() * sizeof(double))) << ncols;
      ASSERT_TRUE(solve_supernodal_forward(L_, B.data(), ncols, A_.n, Yg.data(), wg));
      ASSERT_TRUE(solve_supernodal_forward(L_, B.data(), ncols, A_.n, Yv.data(), wv));
      EXPECT_EQ(0, std::memcmp(Yg.data(), Yv.data(), Yg.size() * sizeof(double))) << ncols;
    }
  }
}

TEST_F(SupernodalSolve, ForwardThenBackwardEqualsTheWholeSolve) {
  // The two halves (with the permuted intermediate in between) give the whole solve's bits, for
  // every block width and a padded leading dimension.
  for (int ncols = 1; ncols <= 10; ++ncols) {
    const int ld = A_.n + 3;
    const std::vector<double> B = random_rhs(ncols, ld, 700u + ncols);
    std::vector<double> whole = B, Y(static_cast<std::size_t>(A_.n) * ncols), X(B.size(), -7.0);
    SupernodalSolveWorkspace ws;
    ASSERT_TRUE(solve_supernodal_llt(L_, whole.data(), ncols, ld, ws));
    ASSERT_TRUE(solve_supernodal_forward(L_, B.data(), ncols, ld, Y.data(), ws));
    ASSERT_TRUE(solve_supernodal_backward(L_, Y.data(), ncols, X.data(), ld, ws));
    for (int c = 0; c < ncols; ++c)
      for (int k = 0; k < A_.n; ++k) {
        const std::size_t q = static_cast<std::size_t>(c) * ld + k;
        ASSERT_EQ(X[q], whole[q]) << ncols << " columns, column " << c << " row " << k;
      }
  }
}

TEST_F(SupernodalSolve, UnitForwardColumnsEqualFullForwardSolves) {
  // L^-1 P e_j restricted to the elimination-tree path of j: the same values as the full forward
  // solve, exact zeros elsewhere; their dot products are the entries of A^-1.
  const SupernodalTree tree = make_supernodal_tree(L_);
  ASSERT_EQ(static_cast<int>(tree.position.size()), A_.n);
  ASSERT_EQ(tree.parent.size(), L_->nsuper);
  for (std::size_t s = 0; s < tree.parent.size(); ++s)
    if (tree.parent[s] >= 0) {
      ASSERT_GT(tree.parent[s], static_cast<int>(s));
    }
  const std::vector<int> rows = {0, 5, 17, 17, 100, 333, 901, 1200, 1500, A_.n - 1, 42};  // 11: two passes
  std::vector<UnitForwardColumn> F(rows.size());
  SupernodalSolveWorkspace ws;
  ASSERT_TRUE(solve_supernodal_unit_forward(L_, tree, rows.data(), static_cast<int>(rows.size()), F.data(), ws));
  const int* super = static_cast<const int*>(L_->super);
  std::vector<double> Ainv(rows.size() * A_.n);  // columns A^-1 e_j (whole solves)
  std::size_t touched = 0;
  for (std::size_t k = 0; k < rows.size(); ++k) {
    std::vector<double> e(static_cast<std::size_t>(A_.n), 0.0), y(static_cast<std::size_t>(A_.n));
    e[static_cast<std::size_t>(rows[k])] = 1.0;
    ASSERT_TRUE(solve_supernodal_forward(L_, e.data(), 1, A_.n, y.data(), ws));
    std::vector<double> from_path(static_cast<std::size_t>(A_.n), 0.0);
    for (std::size_t c = 0; c < F[k].chain.size(); ++c) {
      const int sn = F[k].chain[c];
      ASSERT_EQ(F[k].offset[c + 1] - F[k].offset[c], super[sn + 1] - super[sn]);
      for (int i = 0; i < super[sn + 1] - super[sn]; ++i) from_path[static_cast<std::size_t>(super[sn] + i)] = F[k].values[static_cast<std::size_t>(F[k].offset[c] + i)];
    }
    for (int i = 0; i < A_.n; ++i) ASSERT_EQ(from_path[static_cast<std::size_t>(i)], y[static_cast<std::size_t>(i)]) << "column " << k << " row " << i;
    touched += F[k].values.size();
    std::vector<double> x(static_cast<std::size_t>(A_.n));
    ASSERT_TRUE(solve_supernodal_backward(L_, y.data(), 1, x.data(), A_.n, ws));
    std::copy(x.begin(), x.end(), Ainv.begin() + static_cast<std::ptrdiff_t>(k * A_.n));
  }
  EXPECT_LT(touched, rows.size() * static_cast<std::size_t>(A_.n) / 2);  // the paths are short
  for (std::size_t a = 0; a < rows.size(); ++a)
    for (std::size_t b = 0; b < rows.size(); ++b) {
      const double ref = Ainv[b * A_.n + static_cast<std::size_t>(rows[a])];
      EXPECT_NEAR(dot_unit_forward(F[a], F[b]), ref, 1e-13 * std::abs(Ainv[a * A_.n + static_cast<std::size_t>(rows[a])]))
          << rows[a] << ", " << rows[b];
    }
  // The workspace's unit columns are left zero: a second call gives the same bits.
  std::vector<UnitForwardColumn> again(rows.size());
  ASSERT_TRUE(solve_supernodal_unit_forward(L_, tree, rows.data(), static_cast<int>(rows.size()), again.data(), ws));
  for (std::size_t k = 0; k < rows.size(); ++k) EXPECT_EQ(again[k].values, F[k].values);
}

TEST_F(SupernodalSolve, RefusesASimplicialFactor) {
  cholmod_factor* Ls = cholmod_copy_factor(L_, &c_);
  ASSERT_TRUE(cholmod_change_factor(CHOLMOD_REAL, 1, 0, 1, 1, Ls, &c_));  // simplicial LLᵀ
  EXPECT_FALSE(is_supernodal_llt(Ls));
  std::vector<double> B = random_rhs(2, A_.n, 9u), X = B;
  SupernodalSolveWorkspace ws;
  EXPECT_FALSE(solve_supernodal_llt(Ls, X.data(), 2, A_.n, ws));
  EXPECT_EQ(X, B);
  EXPECT_FALSE(is_supernodal_llt(nullptr));
  cholmod_free_factor(&Ls, &c_);
}

}  // namespace
}  // namespace fascicle
