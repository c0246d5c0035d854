// Bases, solids, exact volume and lattices (seed 000 ch. 3, §3.0.1, §3.1.1).
#include "fascicle/bspline/basis.hpp"
#include "fascicle/bspline/lattice.hpp"
#include "fascicle/bspline/solid.hpp"
#include "fascicle/bspline/volume.hpp"
#include "fascicle/core/error.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

namespace fascicle {
namespace {

std::vector<BSplineBasis> sample_bases() {
  return {make_clamped_uniform_basis(3, 6), make_clamped_uniform_basis(2, 5, -1.0, 2.0),
          make_unclamped_uniform_basis(3, 7), make_periodic_uniform_basis(3, 8),
          make_periodic_uniform_basis(2, 5, 0.0, 2.0),
          make_clamped_basis(3, 8, {0.1, 0.15, 0.5, 0.5}), make_clamped_uniform_basis(1, 4),
          make_clamped_uniform_basis(5, 9)};
}

TEST(Basis, PartitionOfUnityAndNonNegativity) {
  for (const auto& b : sample_bases()) {
    for (int s = 0; s <= 200; ++s) {
      const double t = b.get_lower() + (b.get_upper() - b.get_lower()) * s / 200.0;
      const auto v = calc_all_basis_values(b, t);
      double sum = 0.0;
      for (double x : v) {
        EXPECT_GE(x, -1e-15);
        sum += x;
      }
      EXPECT_NEAR(sum, 1.0, 1e-14) << "degree " << b.degree << " t " << t;
      // derivatives of a partition of unity sum to zero
      double d1 = 0.0;
      for (double x : calc_all_basis_values(b, t, 1)) d1 += x;
      EXPECT_NEAR(d1, 0.0, 1e-11);
    }
  }
}

TEST(Basis, DerivativesMatchFiniteDifferences) {
  for (const auto& b : sample_bases()) {
    const double h = 1e-6 * (b.get_upper() - b.get_lower());
    for (int s = 1; s < 50; ++s) {
      const double t = b.get_lower() + (b.get_upper() - b.get_lower()) * (s + 0.37) / 51.0;
      const auto vp = calc_all_basis_values(b, t + h), vm = calc_all_basis_values(b, t - h);
      const auto d1 = calc_all_basis_values(b, t, 1);
      const auto d1p = calc_all_basis_values(b, t + h, 1), d1m = calc_all_basis_values(b, t - h, 1);
      const auto d2 = calc_all_basis_values(b, t, 2);
      // skip points whose stencil crosses a knot (derivatives may jump there)
      if (find_span(b, t - h) != find_span(b, t + h)) continue;
      for (int i = 0; i < b.num_control; ++i) {
        EXPECT_NEAR(d1[i], (vp[i] - vm[i]) / (2 * h), 1e-7 * (1 + std::abs(d1[i])));
        if (b.degree >= 2) {
          EXPECT_NEAR(d2[i], (d1p[i] - d1m[i]) / (2 * h), 1e-5 * (1 + std::abs(d2[i])));
        }
      }
    }
  }
}

TEST(Basis, KnownCubicValues) {
  // clamped cubic with 4 control points = Bernstein polynomials
  const auto b = make_clamped_uniform_basis(3, 4);
  const double t = 0.3;
  const auto v = calc_all_basis_values(b, t);
  EXPECT_NEAR(v[0], std::pow(1 - t, 3), 1e-15);
  EXPECT_NEAR(v[1], 3 * t * (1 - t) * (1 - t), 1e-15);
  EXPECT_NEAR(v[2], 3 * t * t * (1 - t), 1e-15);
  EXPECT_NEAR(v[3], t * t * t, 1e-15);
  // periodic uniform cubic: interior value 1/6, 2/3, 1/6 at a knot
  const auto pb = make_periodic_uniform_basis(3, 6);
  const auto pv = calc_all_basis_values(pb, 0.0);
  EXPECT_NEAR(pv[0], 1.0 / 6, 1e-15);
  EXPECT_NEAR(pv[1], 2.0 / 3, 1e-15);
  EXPECT_NEAR(pv[2], 1.0 / 6, 1e-15);
  EXPECT_EQ(pv[5], 0.0);
  // periodicity
  const auto a = calc_all_basis_values(pb, 0.123), c = calc_all_basis_values(pb, 1.123);
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(a[i], c[i], 1e-14);
}

TEST(Basis, BadKnotVectorsAreRejected) {
  EXPECT_THROW(make_basis(3, 4, {0, 0, 0, 0, 1, 1, 1}, false), Error);            // short
  EXPECT_THROW(make_basis(3, 4, {0, 0, 0, 0.5, 0.2, 1, 1, 1}, false), Error);     // decreasing
  EXPECT_THROW(make_basis(3, 3, {0, 0, 0, 0, 1, 1, 1}, false), Error);            // degree >= n
  EXPECT_THROW(make_basis(2, 3, {0, 0, 0, NAN, 1, 1}, false), Error);             // NaN
  EXPECT_THROW(make_clamped_uniform_basis(9, 12), Error);                         // degree > max
  try {
    make_basis(3, 4, {0, 0, 0, 0.5, 0.2, 1, 1, 1}, false);
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("non-decreasing"), std::string::npos) << e.what();
  }
  try {
    make_clamped_uniform_basis(4, 3);
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("smaller than the number of control points"),
              std::string::npos) << e.what();
  }
}

// A solid with random interior perturbations of a cubical lattice.
BSplineSolid make_wobbly_solid(unsigned seed, double interior_amp = 0.05, double boundary_amp = 0.05) {
  auto s = make_cubical_lattice(Vec3(0, 0, 0), Vec3(0.02, 0.03, 0.08), {3, 2, 3}, {5, 4, 7}).solid;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> U(-1, 1);
  for (int k = 0; k < 7; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 5; ++i) {
        const bool boundary = i == 0 || i == 4 || j == 0 || j == 3 || k == 0 || k == 6;
        const double amp = (boundary ? boundary_amp : interior_amp) * 0.02;
        s.P.row(s.index(i, j, k)) += amp * Eigen::RowVector3d(U(rng), U(rng), U(rng));
      }
  return s;
}

TEST(Solid, AffineReproduction) {
  auto s = make_cubical_lattice(Vec3(0, 0, 0), Vec3(1, 1, 1), {3, 2, 4}, {6, 5, 7}).solid;
  Mat3 A;
  A << 0.02, 0.003, -0.001, 0.001, 0.03, 0.002, 0.004, -0.002, 0.05;
  const Vec3 b(0.1, -0.2, 0.3);
  for (int r = 0; r < s.P.rows(); ++r) s.P.row(r) = (A * s.P.row(r).transpose() + b).transpose();
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> U(0, 1);
  for (int n = 0; n < 100; ++n) {
    const Vec3 uvw(U(rng), U(rng), U(rng));
    const SolidPoint sp = calc_point_and_jacobian(s, uvw);
    EXPECT_LT((sp.x - (A * uvw + b)).norm(), 1e-15);
    EXPECT_LT((sp.J - A).norm(), 1e-14);  // sums of 60 rounded products of size ~0.05
    EXPECT_LT((calc_point(s, uvw) - sp.x).norm(), 1e-16);
  }
  EXPECT_NEAR(calc_volume(s), A.determinant(), 1e-15);
  EXPECT_NEAR(calc_boundary_volume(s), A.determinant(), 1e-15);
}

// Reference evaluation from dense basis values (calc_all_basis_values): no specialised kernel.
SolidPoint evaluate_densely(const BSplineSolid& s, const Vec3& uvw) {
  std::array<std::array<std::vector<double>, 2>, 3> N;
  for (int d = 0; d < 3; ++d)
    for (int k = 0; k < 2; ++k) N[d][k] = calc_all_basis_values(s.basis[d], uvw[d], k);
  SolidPoint out;
  for (int k = 0; k < s.num_control(2); ++k)
    for (int j = 0; j < s.num_control(1); ++j)
      for (int i = 0; i < s.num_control(0); ++i) {
        const Vec3 p = s.P.row(s.index(i, j, k)).transpose();
        out.x += N[0][0][i] * N[1][0][j] * N[2][0][k] * p;
        out.J.col(0) += N[0][1][i] * N[1][0][j] * N[2][0][k] * p;
        out.J.col(1) += N[0][0][i] * N[1][1][j] * N[2][0][k] * p;
        out.J.col(2) += N[0][0][i] * N[1][0][j] * N[2][1][k] * p;
      }
  return out;
}

// The degree-specialised kernels (degrees 2 and 3, adjacent or periodic neighbours) equal the
// dense reference at random points, on knots and on the domain ends, and calc_point equals the
// position calc_point_and_jacobian returns bit for bit.
TEST(Solid, SpecialisedEvaluationMatchesDenseReference) {
  std::vector<BSplineSolid> solids;
  solids.push_back(make_wobbly_solid(11, 0.3, 0.3));  // degrees (3, 2, 3)
  {
    auto s = make_cubical_lattice(Vec3(0, 0, 0), Vec3(0.03, 0.03, 0.12), {3, 3, 3}, {6, 6, 8}).solid;
    s.basis[1] = make_clamped_basis(3, 6, {0.1, 0.7});  // non-uniform knots
    solids.push_back(s);
  }
  for (const auto& degree : {std::array<int, 3>{2, 3, 3}, std::array<int, 3>{3, 3, 3}}) {
    auto cyl = make_cylindrical_lattice(0.01, 0.1, degree, {4, 9, 7}).solid;  // v periodic
    std::swap(cyl.basis[0], cyl.basis[1]);  // a periodic u direction too (neighbours wrap)
    auto P = cyl.P;
    for (int k = 0; k < 7; ++k)
      for (int j = 0; j < 4; ++j)
        for (int i = 0; i < 9; ++i) P.row(i + 9 * (j + 4 * k)) = cyl.P.row(j + 4 * (i + 9 * k));
    cyl.P = P;
    solids.push_back(make_solid(cyl.basis, cyl.P));
    solids.push_back(make_cylindrical_lattice(0.01, 0.1, degree, {4, 9, 7}).solid);
  }
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> U(-0.1, 1.1);
  for (const auto& s : solids) {
    const double scale = s.P.cwiseAbs().maxCoeff();
    for (int n = 0; n < 300; ++n) {
      Vec3 uvw(U(rng), U(rng), U(rng));
      if (n % 3 == 0) uvw[n % 9 / 3] = std::round(uvw[n % 9 / 3] * 4) / 4;  // ends and knots
      const Vec3 w = wrap_material_point(s, uvw);
      const SolidPoint ref = evaluate_densely(s, w);
      const SolidPoint sp = calc_point_and_jacobian(s, uvw);
      EXPECT_LT((sp.x - ref.x).norm(), 1e-15 * scale) << uvw.transpose();
      EXPECT_LT((sp.J - ref.J).norm(), 1e-13 * scale) << uvw.transpose();
      EXPECT_EQ(calc_point(s, uvw), sp.x);
    }
  }
}

TEST(Solid, JacobianMatchesFiniteDifferencesAndDeformationGradient) {
  const auto s = make_wobbly_solid(7, 0.3, 0.3);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> U(0.01, 0.99);
  const double h = 1e-6;
  for (int n = 0; n < 50; ++n) {
    const Vec3 uvw(U(rng), U(rng), U(rng));
    const Mat3 J = calc_point_and_jacobian(s, uvw).J;
    for (int d = 0; d < 3; ++d) {
      Vec3 e = Vec3::Zero();
      e[d] = h;
      const Vec3 fd = (calc_point(s, uvw + e) - calc_point(s, uvw - e)) / (2 * h);
      EXPECT_LT((fd - J.col(d)).norm(), 1e-8) << d;
    }
  }
  // an affine deformation x -> M x + c of the control points has F = M everywhere
  Mat3 M;
  M << 1.1, 0.2, 0.0, -0.1, 0.9, 0.3, 0.05, 0.0, 1.2;
  Points3 cur = s.P;
  for (int r = 0; r < cur.rows(); ++r) cur.row(r) = (M * s.P.row(r).transpose()).transpose() + Eigen::RowVector3d(1, 2, 3);
  for (int n = 0; n < 20; ++n) {
    const Vec3 uvw(U(rng), U(rng), U(rng));
    EXPECT_LT((calc_deformation_gradient(s, s.P, cur, uvw) - M).norm(), 1e-12);
  }
}

TEST(Solid, NanControlPointNamed) {
  auto s = make_wobbly_solid(1);
  s.P(s.index(2, 1, 3), 1) = NAN;
  try {
    validate_solid(s);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("(2,1,3)"), std::string::npos) << e.what();
  }
}

TEST(Volume, GaussLegendreIntegratesPolynomialsExactly) {
  for (int n = 1; n <= 8; ++n) {
    std::vector<double> x, w;
    calc_gauss_legendre(n, x, w);
    for (int k = 0; k <= 2 * n - 1; ++k) {
      double q = 0.0;
      for (int i = 0; i < n; ++i) q += w[i] * std::pow(x[i], k);
      EXPECT_NEAR(q, k % 2 ? 0.0 : 2.0 / (k + 1), 1e-14) << n << " " << k;
    }
  }
}

TEST(Volume, QuadratureAndBoundaryAgreeAndIgnoreInterior) {
  for (unsigned seed : {1u, 2u, 3u}) {
    const auto s = make_wobbly_solid(seed, 0.4, 0.3);
    const double vq = calc_volume(s), vb = calc_boundary_volume(s);
    EXPECT_NEAR(vq, vb, 1e-12 * std::abs(vb));
    EXPECT_GT(vb, 0.0);
    // moving interior control points changes neither
    auto t = s;
    for (int k = 1; k < 6; ++k)
      for (int j = 1; j < 3; ++j)
        for (int i = 1; i < 4; ++i) t.P.row(t.index(i, j, k)) += Eigen::RowVector3d(0.003, -0.002, 0.004);
    EXPECT_EQ(calc_boundary_volume(t), vb);
    EXPECT_NEAR(calc_volume(t), vb, 1e-12 * std::abs(vb));
    // reversed orientation (u mirrored): exactly the negative
    auto r = s;
    for (int k = 0; k < 7; ++k)
      for (int j = 0; j < 4; ++j)
        for (int i = 0; i < 5; ++i) r.P.row(r.index(i, j, k)) = s.P.row(s.index(4 - i, j, k));
    EXPECT_NEAR(calc_boundary_volume(r), -vb, 1e-14 * std::abs(vb));
    EXPECT_NEAR(calc_volume(r), -vb, 1e-13 * std::abs(vb));
  }
}

// The AVX2 sweep (four points per vector, used when the CPU has it) and the SSE2 one (pairs)
// round every quadrature point identically; only the final sums over lanes differ. Degrees 1..4
// in the b direction of the faces, including a periodic direction.
TEST(Volume, SimdKernelsAgree) {
  std::vector<BSplineSolid> solids = {make_wobbly_solid(5, 0.4, 0.3)};
  const auto b1 = make_clamped_uniform_basis(1, 3), b2 = make_clamped_uniform_basis(2, 5);
  const auto b4 = make_clamped_uniform_basis(4, 7);
  Points3 P(3 * 5 * 7, 3);
  for (int k = 0; k < 7; ++k)
    for (int j = 0; j < 5; ++j)
      for (int i = 0; i < 3; ++i)
        P.row(i + 3 * (j + 5 * k)) << i + 0.1 * std::sin(j + k), j + 0.05 * k * k, k + 0.02 * i * j;
  solids.push_back(make_solid({b1, b2, b4}, P));
  solids.push_back(make_cylindrical_lattice(0.01, 0.1, {2, 3, 3}, {4, 9, 7}).solid);  // v periodic
  for (const BSplineSolid& s : solids) {
    const VolumeAndGradient a = BoundaryVolumeIntegrator(s).calc(s.P);
    const VolumeAndGradient b = BoundaryVolumeIntegrator(s, false).calc(s.P);
    EXPECT_NEAR(a.volume_m3, b.volume_m3, 1e-14 * std::abs(b.volume_m3));
    EXPECT_NEAR(BoundaryVolumeIntegrator(s, false).calc_volume(s.P), b.volume_m3,
                1e-14 * std::abs(b.volume_m3));
    const double scale = b.gradient.cwiseAbs().maxCoeff();
    EXPECT_LT((a.gradient - b.gradient).cwiseAbs().maxCoeff(), 1e-14 * scale);
    EXPECT_NEAR(b.volume_m3, calc_volume(s), 1e-12 * std::abs(b.volume_m3));
  }
}

TEST(Volume, RuledHeightFieldSolidHasAnalyticVolume) {
  // x = u, y = v, z = w f(u,v) with f a bicubic B-spline function: V = sum c_ij I_i I_j where
  // I_i = ∫ N_i = (t_{i+p+1} - t_i)/(p+1).
  const auto bu = make_clamped_basis(3, 6, {0.2, 0.45}, 0.0, 1.0);
  const auto bv = make_clamped_uniform_basis(2, 5, 0.0, 1.0);
  const auto bw = make_clamped_uniform_basis(1, 2);
  const auto gu = calc_greville_abscissae(bu), gv = calc_greville_abscissae(bv);
  Points3 P(6 * 5 * 2, 3);
  double exact = 0.0;
  for (int j = 0; j < 5; ++j)
    for (int i = 0; i < 6; ++i) {
      const double c = 0.5 + 0.1 * i - 0.07 * j + 0.03 * i * j;
      P.row(i + 6 * j) << gu[i], gv[j], 0.0;
      P.row(i + 6 * (j + 5)) << gu[i], gv[j], c;
      exact += c * (bu.knots[i + 4] - bu.knots[i]) / 4 * (bv.knots[j + 3] - bv.knots[j]) / 3;
    }
  const auto s = make_solid({bu, bv, bw}, P);
  EXPECT_NEAR(calc_volume(s), exact, 1e-12 * exact);
  EXPECT_NEAR(calc_boundary_volume(s), exact, 1e-12 * exact);
}

TEST(Volume, GradientsMatchFiniteDifferences) {
  const auto s = make_wobbly_solid(11, 0.3, 0.3);
  const auto gb = calc_boundary_volume_and_gradient(s);
  const auto gq = calc_volume_and_gradient(s);
  EXPECT_NEAR(gb.volume_m3, gq.volume_m3, 1e-12 * gb.volume_m3);
  const double scale = gb.gradient.cwiseAbs().maxCoeff();
  EXPECT_LT((gb.gradient - gq.gradient).cwiseAbs().maxCoeff(), 1e-11 * scale);
  // V is a cubic polynomial in each coordinate: central differences have error h^2 V'''/6
  const double h = 1e-6;
  for (int r = 0; r < s.P.rows(); r += 3) {
    for (int c = 0; c < 3; ++c) {
      auto sp = s, sm = s;
      sp.P(r, c) += h;
      sm.P(r, c) -= h;
      const double fd = (calc_boundary_volume(sp) - calc_boundary_volume(sm)) / (2 * h);
      EXPECT_NEAR(gb.gradient(r, c), fd, 1e-7 * scale) << r << "," << c;
    }
  }
  // interior control points: zero gradient
  EXPECT_LT(gq.gradient.row(s.index(2, 1, 3)).norm(), 1e-13 * scale);
  EXPECT_EQ(gb.gradient.row(s.index(2, 1, 3)).norm(), 0.0);
}

TEST(Volume, SpatialPointGradientMatchesFiniteDifferences) {
  // control points interpolate spatial points at the Greville grid (square system)
  auto s = make_cubical_lattice(Vec3(0, 0, 0), Vec3(1, 1, 2), {2, 2, 2}, {3, 3, 4}).solid;
  std::array<std::vector<double>, 3> g;
  for (int d = 0; d < 3; ++d) g[d] = calc_greville_abscissae(s.basis[d]);
  Points3 U(s.num_control_points(), 3), X(s.num_control_points(), 3);
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 3; ++j)
      for (int i = 0; i < 3; ++i) U.row(s.index(i, j, k)) << g[0][i], g[1][j], g[2][k];
  for (int r = 0; r < U.rows(); ++r) X.row(r) = calc_point(s, U.row(r).transpose()).transpose();
  X(5, 0) += 0.1;
  X(17, 2) -= 0.2;
  // control points from spatial points by solving A P = X
  MatX A(U.rows(), U.rows());
  for (int r = 0; r < U.rows(); ++r)
    for (int c = 0; c < U.rows(); ++c) {
      const Vec3 uvw = U.row(r).transpose();
      A(r, c) = calc_all_basis_values(s.basis[0], uvw[0])[c % 3] *
                calc_all_basis_values(s.basis[1], uvw[1])[(c / 3) % 3] *
                calc_all_basis_values(s.basis[2], uvw[2])[c / 9];
    }
  const auto volume_of = [&](const Points3& Xs) {
    auto t = s;
    t.P = A.lu().solve(MatX(Xs));
    return calc_volume(t);
  };
  s.P = A.lu().solve(MatX(X));
  const Points3 G = calc_volume_gradient_wrt_spatial_points(s, U);
  const double h = 1e-6;
  for (int r = 0; r < X.rows(); ++r)
    for (int c = 0; c < 3; ++c) {
      Points3 Xp = X, Xm = X;
      Xp(r, c) += h;
      Xm(r, c) -= h;
      EXPECT_NEAR(G(r, c), (volume_of(Xp) - volume_of(Xm)) / (2 * h), 1e-7);
    }
}

TEST(Lattice, CylinderSphereTorusConstraintsAndVolumes) {
  const auto cyl = make_cylindrical_lattice(0.01, 0.1, {3, 3, 3}, {4, 8, 6});
  EXPECT_EQ(calc_constraint_violation(cyl.constraints, cyl.solid.P), 0.0);
  const double vc = calc_volume(cyl.solid);
  EXPECT_NEAR(calc_boundary_volume(cyl.solid), vc, 1e-12 * vc);
  // a periodic uniform cubic over a regular octagon of circumradius r is close to a circle of
  // radius ~0.92 r; the volume is between the inscribed polygon-ish bounds
  EXPECT_GT(vc, 0.7 * std::numbers::pi * 1e-4 * 0.1);
  EXPECT_LT(vc, std::numbers::pi * 1e-4 * 0.1);
  const auto E = make_constraint_expansion(cyl.constraints);
  EXPECT_EQ(E.cols(), cyl.solid.num_control_points() - 6 * 7);

  const auto sph = make_spherical_lattice(0.02, {2, 3, 3}, {3, 8, 6});
  EXPECT_EQ(calc_constraint_violation(sph.constraints, sph.solid.P), 0.0);
  const double vs = calc_volume(sph.solid);
  EXPECT_NEAR(calc_boundary_volume(sph.solid), vs, 1e-12 * vs);
  EXPECT_GT(vs, 0.0);

  const auto tor = make_toroidal_lattice(0.05, 0.01, {2, 3, 3}, {3, 8, 12});
  EXPECT_EQ(calc_constraint_violation(tor.constraints, tor.solid.P), 0.0);
  const double vt = calc_volume(tor.solid);
  EXPECT_NEAR(calc_boundary_volume(tor.solid), vt, 1e-12 * vt);
  EXPECT_LT(vt, 2 * std::numbers::pi * std::numbers::pi * 0.05 * 1e-4);
  EXPECT_GT(vt, 0.5 * 2 * std::numbers::pi * std::numbers::pi * 0.05 * 1e-4);

  // enforcing constraints projects perturbed points back onto them
  Points3 P = cyl.solid.P;
  P(0, 0) += 1e-3;
  EXPECT_GT(calc_constraint_violation(cyl.constraints, P), 0.0);
  EXPECT_LT(calc_constraint_violation(cyl.constraints, enforce_lattice_constraints(cyl.constraints, P)), 1e-18);
}

TEST(Lattice, BoundaryFaceIsTheSurfaceOfBoundaryControlPoints) {
  const auto s = make_wobbly_solid(4, 0.3, 0.3);
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> U(0, 1);
  for (int d = 0; d < 3; ++d)
    for (int side = 0; side < 2; ++side) {
      const auto face = extract_boundary_surface(s, d, side);
      for (int n = 0; n < 20; ++n) {
        const double a = U(rng), b = U(rng);
        Vec3 uvw;
        uvw[d] = side;
        uvw[(d + 1) % 3] = a;
        uvw[(d + 2) % 3] = b;
        EXPECT_LT((calc_point(face, Vec3(a, b, 0)) - calc_point(s, uvw)).norm(), 1e-15);
      }
      EXPECT_EQ(calc_volume(face), 0.0);  // a surface is a degenerate solid
    }
  // a curve as a degenerate solid
  Points3 C(4, 3);
  C << 0, 0, 0, 1, 1, 0, 2, 1, 0, 3, 0, 0;
  const auto curve = make_curve_solid(make_clamped_uniform_basis(3, 4), C);
  EXPECT_LT((calc_point(curve, Vec3(0.5, 0, 0)) - Vec3(1.5, 0.75, 0)).norm(), 1e-15);
}

}  // namespace
}  // namespace fascicle
