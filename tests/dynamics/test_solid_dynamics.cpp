// Tests of the solid-muscle dynamics: analytic motions, invariants, finite differences.
#include "fascicle/bspline/lattice.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/dynamics/solid_dynamics.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <memory>

namespace fascicle {
namespace {

// A 2 x 2 x 4 cm box, quadratic, 4 x 4 x 6 control points, fibres along z.
BSplineSolid make_box(std::array<int, 3> count = {4, 4, 6}) {
  LatticeDesign d = make_cubical_lattice(Vec3(0, 0, 0), Vec3(0.02, 0.02, 0.04), {2, 2, 2}, count);
  d.solid.name = "box";
  return d.solid;
}

SolidDynamicsSpec make_free_spec() {
  SolidDynamicsSpec s;
  s.volume = VolumeMethod::none;
  s.ground.c1_Pa = 5e3;
  s.ground.c2_Pa = 0.0;
  return s;
}

TEST(SolidModel, MassAndVolumeFromDensity) {
  const BSplineSolid box = make_box();
  SolidDynamicsSpec spec = make_free_spec();
  const SolidDynamicsModel m = compile_solid_dynamics(box, spec);
  EXPECT_NEAR(m.rest_volume_m3, 0.02 * 0.02 * 0.04, 1e-15);
  EXPECT_NEAR(m.mass_kg, 1060.0 * 1.6e-5, 1e-12);
  // Consistent mass reproduces the first moment: Σ_IJ M_IJ P_J = m × centre.
  const Points3 MP = m.mass_matrix * box.P;
  EXPECT_NEAR(MP.col(2).sum() / m.mass_kg, 0.02, 1e-14);
}

TEST(SolidModel, ForcesAreMinusEnergyGradient) {
  const BSplineSolid box = make_box({3, 3, 4});
  SolidDynamicsSpec spec = make_free_spec();
  spec.ground.c2_Pa = 2e3;
  spec.spring_modulus_Pa = 1e3;
  spec.volume = VolumeMethod::penalty;
  spec.volume_stiffness_Pa = 1e5;
  spec.pennation_rad = 0.3;
  const SolidDynamicsModel m = compile_solid_dynamics(box, spec);
  Points3 P = box.P;
  // A smooth non-affine deformation with fibre stretch in the exponential range.
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const double z = P(i, 2);
    P(i, 0) += 0.1 * P(i, 0) + 0.05 * z * z / 0.04;
    P(i, 2) *= 1.15;
    P(i, 1) += 0.02 * std::sin(40 * z) * 0.01;
  }
  const ForceEvaluation fe = calc_forces(m, P, {}, 0.0, true);
  const VecX x = flatten_points(P);
  const double h = 1e-8;
  double max_err = 0.0, max_f = 0.0;
  for (int k = 0; k < x.size(); k += 5) {
    VecX xp = x, xm = x;
    xp[k] += h;
    xm[k] -= h;
    const double ep = calc_forces(m, unflatten_points(xp), {}, 0.0, false).energy_J;
    const double em = calc_forces(m, unflatten_points(xm), {}, 0.0, false).energy_J;
    max_err = std::max(max_err, std::abs(-(ep - em) / (2 * h) - fe.force[k]));
    max_f = std::max(max_f, std::abs(fe.force[k]));
  }
  EXPECT_LT(max_err, 1e-5 * max_f) << "max |f| " << max_f;
  // Stiffness = −∂f/∂x by central differences. The volume penalty's Hessian is not in K (the
  // solver adds its rank-one Gauss–Newton part), so this check uses a model without it.
  spec.volume = VolumeMethod::none;
  const SolidDynamicsModel m2 = compile_solid_dynamics(box, spec);
  const ForceEvaluation fe2 = calc_forces(m2, P, {}, 0.0, true);
  Eigen::SparseMatrix<double> Ks;
  Ks = fe2.stiffness.selfadjointView<Eigen::Lower>();
  const Eigen::MatrixXd K = Eigen::MatrixXd(Ks);
  EXPECT_LT((K - K.transpose()).lpNorm<Eigen::Infinity>(), 1e-9 * K.lpNorm<Eigen::Infinity>());
  for (int k : {0, 7, 20, 41}) {
    VecX xp = x, xm = x;
    xp[k] += 1e-7;
    xm[k] -= 1e-7;
    const VecX col = -(calc_forces(m2, unflatten_points(xp), {}, 0.0, false).force -
                       calc_forces(m2, unflatten_points(xm), {}, 0.0, false).force) / 2e-7;
    EXPECT_LT((col - K.col(k)).lpNorm<Eigen::Infinity>(), 1e-5 * K.col(k).lpNorm<Eigen::Infinity>())
        << "column " << k;
  }
}

TEST(SolidModel, InternalForcesSumToZero) {
  const BSplineSolid box = make_box();
  SolidDynamicsSpec spec = make_free_spec();
  spec.pennation_rad = 0.4;
  spec.tendon_fraction_start = 0.2;
  const SolidDynamicsModel m = compile_solid_dynamics(box, spec);
  Points3 P = box.P;
  P.col(2) *= 0.9;
  P.col(0) += 0.3 * P.col(2);
  const VecX f = calc_internal_forces(m, P, 1.0);
  Vec3 sum = Vec3::Zero();
  Vec3 torque = Vec3::Zero();
  double scale = 0.0;
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    sum += f.segment<3>(3 * i);
    torque += P.row(i).transpose().cross(f.segment<3>(3 * i));
    scale += f.segment<3>(3 * i).norm();
  }
  EXPECT_GT(scale, 1.0);  // the fibres do pull
  EXPECT_LT(sum.norm(), 1e-12 * scale);
  // Objectivity: internal forces carry no net torque either.
  EXPECT_LT(torque.norm(), 1e-12 * scale * 0.05);
}

TEST(SolidModel, InvertedSolidReportedWithMaterialLocation) {
  BSplineSolid box = make_box();
  // Push one interior layer of control points past the next: det J < 0 there.
  for (int j = 0; j < 4; ++j)
    for (int i = 0; i < 4; ++i) box.P(box.index(i, j, 2), 2) = 0.035;
  try {
    compile_solid_dynamics(box, make_free_spec());
    FAIL() << "inverted solid accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("material point"), std::string::npos) << e.what();
  }
  const SolidDynamicsModel m = compile_solid_dynamics(make_box(), make_free_spec());
  Points3 P = m.rest.P;
  P.row(m.rest.index(1, 1, 1)) = Vec3(0.03, 0.03, 0.03);
  P.row(m.rest.index(2, 2, 1)) = Vec3(-0.01, -0.01, -0.01);
  const auto loc = find_inverted_point(m, P);
  ASSERT_TRUE(loc.has_value());
  EXPECT_THROW(calc_forces(m, P, {}, 0.0, false), Error);
}

// Free fall: every integrator reproduces x = x0 + g t²/2 up to its order; with no internal
// forces acting on a rigid translation, the discrete update is exact for symplectic Euler's
// Σ h² k form and for backward Euler's.
TEST(SolidIntegrators, FreeFall) {
  const BSplineSolid box = make_box({3, 3, 4});
  SolidDynamicsSpec spec = make_free_spec();
  spec.volume = VolumeMethod::exact;
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  for (Integrator integ : {Integrator::symplectic_euler, Integrator::backward_euler}) {
    SolverOptions o;
    o.integrator = integ;
    SolidDynamicsSolver solver(m, o);
    const int steps = 50;
    const double h = 0.002;
    int substeps = 0;  // symplectic Euler sub-steps below its stability limit
    for (int k = 0; k < steps; ++k) substeps += solver.step(h, {}).substeps;
    const double t = steps * h;
    const Vec3 com0 = (m->lumped_mass.transpose() * box.P).transpose() / m->mass_kg;
    const Vec3 com = solver.calc_metrics({}).centre_of_mass_m;
    SCOPED_TRACE(static_cast<int>(integ));
    const double drop = com0.z() - com.z();
    // Discrete solutions after M steps of size hs: both integrators give g hs² M(M+1)/2
    // (v_{k+1} = v_k + hs g, x_{k+1} = x_k + hs v_{k+1}); exact g t²/2 differs by g hs t / 2.
    const double hs = t / substeps;
    const double discrete = 9.81 * hs * hs * substeps * (substeps + 1) / 2.0;
    EXPECT_NEAR(drop, discrete, 1e-9 * discrete);
    EXPECT_NEAR(drop, 0.5 * 9.81 * t * t, 0.5 * 9.81 * h * t + 1e-12);
    EXPECT_LT(solver.get_state().P.col(0).cwiseAbs().maxCoeff(), 0.02 + 1e-9);
  }
}

}  // namespace
}  // namespace fascicle
