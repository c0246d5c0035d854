// The clones of fascicle/sparse's supernodal kernels (AVX-512, AVX2 + FMA, generic) on a real
// factor: CHOLMOD's supernodal LLᵀ of the surface-first system of the Visible Human soleus (14k
// unknowns, ~2 M factor entries, supernodes up to several hundred columns wide). Every clone this
// CPU runs must give the generic clone's bits, whole solves, halves and unit columns alike, so
// results do not depend on the machine.
#include "fascicle/deformation/surface_first.hpp"
#include "fascicle/io/mesh_io.hpp"
#include "fascicle/sparse/supernodal_solve.hpp"
#include "fascicle/sparse/cholmod_view.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>
#include <suitesparse/cholmod.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>
#include <vector>

namespace fascicle {
namespace {

class SupernodalClonesOnSoleus : public ::testing::Test {
 protected:
  void SetUp() override {
    const TriMesh soleus = read_mesh(
        test::data_path("visible_human_female/right/VHF_Right_Muscle_Soleus_smooth.stl"), LengthUnit::millimetre);
    // Action line along the mesh's z extent, no attachment areas: all vertices free.
    const Vec3 centre = soleus.V.colwise().mean().transpose();
    Points3 line(2, 3);
    line << centre.x(), centre.y(), soleus.V.col(2).maxCoeff(), centre.x(), centre.y(), soleus.V.col(2).minCoeff();
    K_ = bind_surface(soleus, line, {}, {}, {}, "soleus_r").system;
    cholmod_start(&c_);
    c_.print = 0;
    c_.supernodal = CHOLMOD_SUPERNODAL;
    cholmod_sparse S = view_symmetric_lower(static_cast<std::size_t>(K_.rows()), static_cast<std::size_t>(K_.nonZeros()),
                                            K_.outerIndexPtr(), K_.innerIndexPtr(), K_.valuePtr());
    L_ = cholmod_analyze(&S, &c_);
    ASSERT_NE(L_, nullptr);
    ASSERT_TRUE(cholmod_factorize(&S, L_, &c_));
    ASSERT_EQ(L_->minor, L_->n);
    n_ = static_cast<int>(L_->n);
  }
  void TearDown() override {
    if (L_) cholmod_free_factor(&L_, &c_);
    cholmod_finish(&c_);
  }
  std::vector<double> random_rhs(int ncols, unsigned seed) const {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    std::vector<double> B(static_cast<std::size_t>(n_) * ncols);
    for (double& b : B) b = u(rng);
    return B;
  }
  // max |K x − b| / max |b| of one column (K stored whole; CHOLMOD reads its lower triangle).
  double relative_residual(const double* x, const double* b) const {
    std::vector<double> r(b, b + n_);
    for (int j = 0; j < K_.outerSize(); ++j)
      for (SparseMatrix::InnerIterator it(K_, j); it; ++it) r[it.row()] -= it.value() * x[j];
    double rmax = 0.0, bmax = 0.0;
    for (int k = 0; k < n_; ++k) {
      rmax = std::max(rmax, std::abs(r[k]));
      bmax = std::max(bmax, std::abs(b[k]));
    }
    return rmax / bmax;
  }
  static bool same_bits(const std::vector<double>& a, const std::vector<double>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0;
  }

  SparseMatrix K_;
  cholmod_common c_{};
  cholmod_factor* L_ = nullptr;
  int n_ = 0;
};

TEST_F(SupernodalClonesOnSoleus, FactorHasWideSupernodes) {
  ASSERT_TRUE(is_supernodal_llt(L_));
  EXPECT_GT(n_, 14000);
  EXPECT_GT(L_->xsize, 1'500'000u);
  const int* super = static_cast<const int*>(L_->super);
  int widest = 0;
  for (std::size_t s = 0; s < L_->nsuper; ++s) widest = std::max(widest, super[s + 1] - super[s]);
  EXPECT_GE(widest, 100);
}

TEST_F(SupernodalClonesOnSoleus, EveryCloneGivesTheGenericBits) {
  std::vector<SupernodalKernel> clones;
  for (SupernodalKernel k : {SupernodalKernel::avx2, SupernodalKernel::avx512})
    if (has_supernodal_kernel(k)) clones.push_back(k);
  if (clones.empty()) GTEST_SKIP() << "only the generic clone runs on this CPU";
  const SupernodalTree tree = make_supernodal_tree(L_);
  const std::vector<int> rows = {0, 7, 1000, 5000, 9000, 12345, n_ - 1, 42, 4242};  // nine: two passes
  SupernodalSolveWorkspace generic;
  generic.kernel = SupernodalKernel::generic;
  for (int ncols : {1, 2, 3, 4, 5, 6, 7, 8, 11}) {
    const std::vector<double> B = random_rhs(ncols, 900u + ncols);
    std::vector<double> Xg = B, Yg(B.size());
    ASSERT_TRUE(solve_supernodal_llt(L_, Xg.data(), ncols, n_, generic));
    ASSERT_TRUE(solve_supernodal_forward(L_, B.data(), ncols, n_, Yg.data(), generic));
    // The common result is a solution of K x = b (all clones could otherwise agree on nonsense).
    for (int c = 0; c < ncols; ++c) {
      const std::size_t q = static_cast<std::size_t>(c) * n_;
      EXPECT_LT(relative_residual(Xg.data() + q, B.data() + q), 1e-10) << ncols << " columns, column " << c;
    }
    for (SupernodalKernel kernel : clones) {
      SupernodalSolveWorkspace ws;
      ws.kernel = kernel;
      std::vector<double> X = B, Y(B.size());
      ASSERT_TRUE(solve_supernodal_llt(L_, X.data(), ncols, n_, ws));
      EXPECT_TRUE(same_bits(X, Xg)) << "clone " << static_cast<int>(kernel) << ", " << ncols << " columns";
      ASSERT_TRUE(solve_supernodal_forward(L_, B.data(), ncols, n_, Y.data(), ws));
      EXPECT_TRUE(same_bits(Y, Yg)) << "clone " << static_cast<int>(kernel) << ", forward, " << ncols << " columns";
    }
  }
  std::vector<UnitForwardColumn> Fg(rows.size());
  ASSERT_TRUE(solve_supernodal_unit_forward(L_, tree, rows.data(), static_cast<int>(rows.size()), Fg.data(), generic));
  for (SupernodalKernel kernel : clones) {
    SupernodalSolveWorkspace ws;
    ws.kernel = kernel;
    std::vector<UnitForwardColumn> F(rows.size());
    ASSERT_TRUE(solve_supernodal_unit_forward(L_, tree, rows.data(), static_cast<int>(rows.size()), F.data(), ws));
    for (std::size_t k = 0; k < rows.size(); ++k) {
      EXPECT_EQ(F[k].chain, Fg[k].chain);
      EXPECT_TRUE(same_bits(F[k].values, Fg[k].values)) << "clone " << static_cast<int>(kernel) << ", row " << rows[k];
    }
  }
}

}  // namespace
}  // namespace fascicle
