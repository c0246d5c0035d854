// Tests of the solid-muscle dynamics: analytic motions, invariants, finite differences.
#include "fascicle/bspline/lattice.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/dynamics/solid_dynamics.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
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

// The closed-form tangents against central differences of the analytic stresses, at a general
// (non-symmetric, J ≠ 1) F: Mooney–Rivlin with a bulk term, Blemker in each passive branch with
// activation, the tendon law.
TEST(SolidMaterials, AnalyticTangentsMatchFiniteDifferences) {
  Mat3 F;
  F << 1.12, 0.07, -0.05, 0.03, 0.93, 0.11, -0.08, 0.04, 1.21;
  const double h = 1e-6;
  auto fd = [&](auto&& stress, const Mat3& F0) {
    Mat9 D;
    for (int l = 0; l < 3; ++l)
      for (int k = 0; k < 3; ++k) {
        Mat3 Fp = F0, Fm = F0;
        Fp(k, l) += h;
        Fm(k, l) -= h;
        const Mat3 d = (stress(Fp) - stress(Fm)) / (2.0 * h);
        D.col(k + 3 * l) = Eigen::Map<const Eigen::Matrix<double, 9, 1>>(d.data());
      }
    return D;
  };
  MooneyRivlinParameters mr{.c1_Pa = 2e3, .c2_Pa = 1e3, .bulk_modulus_Pa = 5e4};
  const Mat9 Dmr = calc_mooney_rivlin_tangent(mr, F);
  const Mat9 Dmr_fd = fd([&](const Mat3& G) { return calc_mooney_rivlin(mr, G).P; }, F);
  EXPECT_LT((Dmr - Dmr_fd).cwiseAbs().maxCoeff(), 1e-6 * Dmr.cwiseAbs().maxCoeff());
  EXPECT_LT((Dmr - Dmr.transpose()).cwiseAbs().maxCoeff(), 1e-9 * Dmr.cwiseAbs().maxCoeff());

  const BlemkerFibreParameters bf;
  const Vec3 a0 = Vec3(0.2, -0.1, 1.0).normalized();
  // Stretches below λopt (active only), in the exponential branch and in the linear branch.
  for (double s : {0.8, 1.2, 1.5}) {
    const Mat3 Fs = F * (s / (F * a0).norm());
    const double lambda = (Fs * a0).norm();
    ASSERT_NEAR(lambda, s, 1e-12);
    const double a = 0.7;
    const double scale = bf.sigma_max_Pa / bf.lambda_opt;
    const double phi = scale * (calc_blemker_passive(bf, lambda) + a * calc_blemker_active(bf, lambda));
    const double dphi = scale * (calc_blemker_passive_slope(bf, lambda) +
                                 a * calc_blemker_active_slope(bf, lambda));
    Mat9 D = Mat9::Zero();
    add_fibre_tangent(Fs, a0, phi, dphi, D);
    const Mat9 D_fd = fd([&](const Mat3& G) { return calc_blemker_fibre(bf, G, a0, a, 1.0).P; }, Fs);
    EXPECT_LT((D - D_fd).cwiseAbs().maxCoeff(), 1e-6 * D.cwiseAbs().maxCoeff()) << "stretch " << s;
  }
  const Mat3 Ft = F * (1.05 / (F * a0).norm());
  Mat9 Dt = Mat9::Zero();
  add_fibre_tangent(Ft, a0, 2e6 * 0.05, 2e6, Dt);
  const Mat9 Dt_fd = fd([&](const Mat3& G) { return calc_tendon_fibre(2e6, G, a0).P; }, Ft);
  EXPECT_LT((Dt - Dt_fd).cwiseAbs().maxCoeff(), 1e-6 * Dt.cwiseAbs().maxCoeff());
}

// The assembled stiffness with activation, tendon ends and a bulk term (all analytic tangents)
// against central differences of the forces.
TEST(SolidModel, ActiveStiffnessMatchesForceDifferences) {
  const BSplineSolid box = make_box({3, 3, 5});
  SolidDynamicsSpec spec = make_free_spec();
  spec.ground.c2_Pa = 1e3;
  spec.ground.bulk_modulus_Pa = 2e4;
  spec.pennation_rad = 0.25;
  spec.tendon_fraction_start = 0.2;
  spec.tendon_fraction_end = 0.2;
  const SolidDynamicsModel m = compile_solid_dynamics(box, spec);
  Points3 P = box.P;
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const double z = P(i, 2);
    P(i, 0) += 0.08 * P(i, 0) + 0.03 * z * z / 0.04;
    P(i, 2) *= 0.9 + 3.0 * z;  // belly shortened, ends stretched (tendon in tension)
  }
  const double a = 0.8;
  const ForceEvaluation fe = calc_forces(m, P, {}, a, true);
  Eigen::SparseMatrix<double> Ks;
  Ks = fe.stiffness.selfadjointView<Eigen::Lower>();
  const Eigen::MatrixXd K = Eigen::MatrixXd(Ks);
  const VecX x = flatten_points(P);
  for (int k : {1, 9, 26, 40, 70}) {
    VecX xp = x, xm = x;
    xp[k] += 1e-7;
    xm[k] -= 1e-7;
    const VecX col = -(calc_forces(m, unflatten_points(xp), {}, a, false).force -
                       calc_forces(m, unflatten_points(xm), {}, a, false).force) / 2e-7;
    EXPECT_LT((col - K.col(k)).lpNorm<Eigen::Infinity>(), 1e-5 * K.col(k).lpNorm<Eigen::Infinity>())
        << "column " << k;
  }
}

// The per-span kernels on a cylinder (periodic v: supports that wrap around are not increasing,
// so the span tangent is formed for all local pairs): the spans partition the quadrature points,
// the forces equal the per-point sum of calc_internal_forces, and the stiffness matches central
// differences of the forces.
TEST(SolidModel, SpanKernelsOnAPeriodicSolid) {
  const LatticeDesign d = make_cylindrical_lattice(0.01, 0.05, {2, 2, 2}, {3, 8, 5});
  SolidDynamicsSpec spec = make_free_spec();
  spec.gravity_m_s2.setZero();
  spec.ground.c2_Pa = 1e3;
  spec.pennation_rad = 0.3;
  spec.pennation_towards = 0;
  const SolidDynamicsModel m = compile_solid_dynamics(d.solid, spec);
  std::vector<int> seen(m.quadrature.size(), 0);
  for (int q : m.group_points) ++seen[q];
  EXPECT_EQ(std::count(seen.begin(), seen.end(), 1), static_cast<long>(seen.size()));
  EXPECT_NE(std::count(m.group_ascending.begin(), m.group_ascending.end(), 0), 0);
  Points3 P = d.solid.P;
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    const double z = P(i, 2);
    P(i, 0) += 0.1 * P(i, 0) + 0.2 * z * z;
    P(i, 2) *= 0.9 + 2.0 * z;
  }
  const double a = 0.7;
  const ForceEvaluation fe = calc_forces(m, P, {}, a, true);
  const VecX f_ref = calc_internal_forces(m, P, a);
  EXPECT_LT((fe.force - f_ref).lpNorm<Eigen::Infinity>(), 1e-10 * f_ref.lpNorm<Eigen::Infinity>());
  Eigen::SparseMatrix<double> Ks;
  Ks = fe.stiffness.selfadjointView<Eigen::Lower>();
  const Eigen::MatrixXd K = Eigen::MatrixXd(Ks);
  const VecX x = flatten_points(P);
  for (int k : {4, 31, 50, 77, 100}) {
    VecX xp = x, xm = x;
    xp[k] += 1e-7;
    xm[k] -= 1e-7;
    const VecX col = -(calc_forces(m, unflatten_points(xp), {}, a, false).force -
                       calc_forces(m, unflatten_points(xm), {}, a, false).force) / 2e-7;
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

namespace fascicle {
namespace {

// Spinning free solid: symplectic Euler keeps the energy to O(h) (bounded oscillation), backward
// Euler dissipates O(h); halving h halves both errors.
TEST(SolidIntegrators, RigidRotationEnergyWithinOrder) {
  const BSplineSolid box = make_box({3, 3, 4});
  SolidDynamicsSpec spec = make_free_spec();
  spec.gravity_m_s2.setZero();
  spec.mass = MassLumping::lumped;  // the explicit integrator's mass (energies use the model's)
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  const Vec3 c(0.01, 0.01, 0.02);
  const Vec3 omega(0.0, 0.0, 3.0);  // rad/s about the long axis
  SolidState s0;
  s0.P = box.P;
  s0.V = Points3(box.P.rows(), 3);
  for (Eigen::Index i = 0; i < box.P.rows(); ++i)
    s0.V.row(i) = omega.cross(box.P.row(i).transpose() - c).transpose();
  auto drift = [&](Integrator integ, double h) {
    SolverOptions o;
    o.integrator = integ;
    o.explicit_safety = 1e9;  // fixed step h (below the stability limit here)
    SolidDynamicsSolver solver(m, o);
    solver.set_state(s0);
    const double E0 = calc_energies(*m, s0).total();
    double worst = 0.0;
    const int steps = static_cast<int>(std::round(0.06 / h));
    for (int k = 0; k < steps; ++k) {
      solver.step(h, {});
      const double E = calc_energies(*m, solver.get_state()).total();
      worst = std::max(worst, std::abs(E - E0) / E0);
    }
    return worst;
  };
  const double wmax = calc_max_frequency(*m, box.P, 0.0);
  const double h = 0.2 / wmax;  // 10% of the stability limit 2/ω_max
  const double se1 = drift(Integrator::symplectic_euler, h);
  const double se2 = drift(Integrator::symplectic_euler, h / 2);
  const double be1 = drift(Integrator::backward_euler, 20 * h);
  const double be2 = drift(Integrator::backward_euler, 10 * h);
  EXPECT_LT(se1, 0.05);
  EXPECT_GT(se1 / se2, 1.6);
  EXPECT_LT(se1 / se2, 2.5);
  EXPECT_GT(be1 / be2, 1.6);
  EXPECT_LT(be1 / be2, 2.5);
  std::printf("energy drift: symplectic %.3e / %.3e, backward %.3e / %.3e (h = %.3e s)\n", se1, se2,
              be1, be2, h);
}

TEST(SolidIntegrators, StretchedSolidReturnsToRest) {
  const BSplineSolid box = make_box({3, 3, 5});
  SolidDynamicsSpec spec = make_free_spec();
  spec.gravity_m_s2.setZero();
  spec.rayleigh_alpha_1_s = 30.0;
  spec.volume = VolumeMethod::exact;
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  SolidDynamicsSolver solver(m);
  SolidState s;
  s.P = box.P;
  s.P.col(2) *= 1.25;
  s.P.col(0) *= 0.9;
  s.P.col(1) *= 0.9;  // ~1% volume change: the projection restores it on the first step
  s.V = Points3::Zero(box.P.rows(), 3);
  solver.set_state(s);
  const Vec3 com_shift = ((m->lumped_mass.transpose() * (s.P - box.P)) / m->mass_kg).transpose();
  for (int k = 0; k < 150; ++k) solver.step(0.005, {});
  // Rest shape up to a rigid motion: compare after removing the (zero) mean drift.
  const Points3& P = solver.get_state().P;
  const Vec3 shift = ((m->lumped_mass.transpose() * (P - box.P)) / m->mass_kg).transpose();
  double err = 0.0;
  for (Eigen::Index i = 0; i < P.rows(); ++i)
    err = std::max(err, (P.row(i) - box.P.row(i) - shift.transpose()).norm());
  EXPECT_LT(err, 1e-5) << "max deviation from the rest shape (m)";
  EXPECT_LT((shift - com_shift).norm(), 1e-9);  // internal forces keep the centre of mass
  EXPECT_NEAR(solver.calc_metrics({}).volume_error, 0.0, 1e-6);
}

// Shape memory from the spring network alone (no hyperelastic potential).
TEST(SolidIntegrators, SpringNetworkReturnsToRest) {
  const BSplineSolid box = make_box({3, 3, 4});
  SolidDynamicsSpec spec = make_free_spec();
  spec.hyperelastic = false;
  spec.spring_modulus_Pa = 2e4;
  spec.gravity_m_s2.setZero();
  spec.rayleigh_alpha_1_s = 40.0;
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  SolidDynamicsSolver solver(m);
  SolidState s;
  s.P = box.P;
  s.P.col(0) += 0.3 * (s.P.col(2).array() - 0.02).matrix();  // 17° shear
  s.V = Points3::Zero(box.P.rows(), 3);
  solver.set_state(s);
  for (int k = 0; k < 60; ++k) solver.step(0.01, {});
  // Back to the rest shape up to a rigid motion: pairwise distances are restored.
  const Points3& P = solver.get_state().P;
  double err = 0.0;
  for (Eigen::Index i = 0; i < P.rows(); ++i)
    for (Eigen::Index j = i + 1; j < P.rows(); ++j)
      err = std::max(err, std::abs((P.row(i) - P.row(j)).norm() - (box.P.row(i) - box.P.row(j)).norm()));
  EXPECT_LT(err, 1e-5);
}

struct ImposedResult {
  double worst_volume_error = 0.0;
  double final_stretch = 0.0;
};

ImposedResult run_imposed(VolumeMethod method, double k) {
  const BSplineSolid box = make_box({3, 3, 5});
  SolidDynamicsSpec spec = make_free_spec();
  spec.volume = method;
  spec.volume_stiffness_Pa = k;
  spec.volume_damping_Pa_s = 0.01 * k;
  spec.rayleigh_alpha_1_s = 10.0;
  spec.attachments.push_back({"origin", -1, find_end_layer(box, 0)});
  spec.attachments.push_back({"insertion", 0, find_end_layer(box, 1)});
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  SolidDynamicsSolver solver(m);
  ImposedResult out;
  const int steps = 60;
  for (int k2 = 1; k2 <= steps; ++k2) {
    const double s = static_cast<double>(std::min(k2, 40)) / 40.0;
    StepInputs in;
    Transform X = Transform::Identity();
    // Insertion: pulled 40% along the axis, sheared 1 cm and twisted 40 degrees.
    X.translate(Vec3(0.01 * s, 0.0, 0.016 * s));
    X.translate(Vec3(0.01, 0.01, 0.04));
    X.rotate(Eigen::AngleAxisd(0.7 * s, Vec3::UnitZ()));
    X.translate(-Vec3(0.01, 0.01, 0.04));
    in.X_now_rest = {X};
    solver.step(0.005, in);
    const SolidMetrics mm = solver.calc_metrics(in);
    out.worst_volume_error = std::max(out.worst_volume_error, std::abs(mm.volume_error));
    out.final_stretch = mm.mean_fibre_stretch;
  }
  return out;
}

TEST(SolidVolume, ExactConstraintUnderLargeImposedDeformation) {
  const ImposedResult r = run_imposed(VolumeMethod::exact, 0.0);
  EXPECT_GT(r.final_stretch, 1.3);
  EXPECT_LT(r.worst_volume_error, 1e-5);
}

TEST(SolidVolume, PenaltyWithinOnePercent) {
  const ImposedResult r = run_imposed(VolumeMethod::penalty, 2e6);
  const ImposedResult none = run_imposed(VolumeMethod::none, 0.0);
  EXPECT_LT(r.worst_volume_error, 0.01);
  EXPECT_GT(none.worst_volume_error, 5 * r.worst_volume_error);  // the penalty does the work
  std::printf("volume error: penalty %.3e, none %.3e\n", r.worst_volume_error,
              none.worst_volume_error);
}

TEST(SolidIntegrators, BlowUpIsANumericalErrorAndKeepsTheLastGoodState) {
  const BSplineSolid box = make_box({3, 3, 4});
  SolidDynamicsSpec spec = make_free_spec();
  spec.ground.c1_Pa = 1e6;
  spec.gravity_m_s2.setZero();
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  SolverOptions o;
  o.integrator = Integrator::symplectic_euler;
  o.explicit_safety = 1e9;  // fixed steps, 5 x past the stability limit 2/ω_max
  o.max_step_halvings = 0;
  const double h = 10.0 / calc_max_frequency(*m, box.P, 0.0);
  SolidDynamicsSolver solver(m, o);
  SolidState s;
  s.P = box.P;
  s.P(5, 0) += 1e-4;  // a small perturbation grows exponentially
  s.V = Points3::Zero(box.P.rows(), 3);
  solver.set_state(s);
  double last_good_time = 0.0;
  try {
    for (int k = 0; k < 1000; ++k) {
      solver.step(h, {});
      last_good_time = solver.get_state().time_s;
    }
    FAIL() << "no error from a diverging explicit integration";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::numerical);
    const std::string msg = e.what();
    EXPECT_TRUE(msg.find("blow-up") != std::string::npos || msg.find("NaN") != std::string::npos ||
                msg.find("inverted") != std::string::npos) << msg;
    EXPECT_NE(msg.find("last good state"), std::string::npos) << msg;
  }
  EXPECT_EQ(solver.get_state().time_s, last_good_time);
  EXPECT_TRUE(solver.get_state().P.allFinite());
}

TEST(SolidIntegrators, QuasiStaticContractionIsAnEquilibrium) {
  const BSplineSolid box = make_box();
  SolidDynamicsSpec spec = make_free_spec();
  spec.gravity_m_s2.setZero();
  spec.attachments.push_back({"origin", -1, find_end_layer(box, 0)});
  spec.attachments.push_back({"insertion", -1, find_end_layer(box, 1)});
  spec.tendon_fraction_start = spec.tendon_fraction_end = 0.2;
  spec.volume = VolumeMethod::exact;
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  SolverOptions o;
  o.integrator = Integrator::quasi_static;
  SolidDynamicsSolver solver(m, o);
  StepInputs in;
  in.excitation = 1.0;
  for (int k = 0; k < 20; ++k) solver.step(0.01, in);
  const SolidState& s = solver.get_state();
  EXPECT_GT(s.activation, 0.99);
  // Free forces vanish (equilibrium) up to the volume constraint force along ∇V.
  const ForceEvaluation fe = calc_forces(*m, s.P, {}, s.activation, false);
  VecX f = fe.force, g = fe.volume_gradient;
  for (int i = 0; i < f.size(); ++i)
    if (m->fixed[i / 3]) f[i] = g[i] = 0.0;
  const double mu = f.dot(g) / g.dot(g);
  const double peak = calc_internal_forces(*m, s.P, s.activation).lpNorm<Eigen::Infinity>();
  EXPECT_GT(peak, 1.0);
  EXPECT_LT((f - mu * g).lpNorm<Eigen::Infinity>(), 1e-5 * peak);
  // The belly shortens, the (passive, stiffer) tendons stretch, the volume is kept.
  const SolidMetrics mm = solver.calc_metrics(in);
  EXPECT_LT(mm.mean_fibre_stretch, 0.97);
  double tendon_stretch = 0.0, tendon_w = 0.0;
  for (const QuadraturePoint& q : m->quadrature) {
    if (!q.tendon) continue;
    Mat3 F = Mat3::Zero();
    for (int a = 0; a < q.count; ++a)
      F += s.P.row(m->support_index[q.first + a]).transpose() *
           m->support_g[q.first + a].transpose();
    tendon_stretch += q.weight_m3 * (F * q.fibre_rest).norm();
    tendon_w += q.weight_m3;
  }
  EXPECT_GT(tendon_stretch / tendon_w, 1.0);
  // Force balance along the fibres: the tendon's stress E (λ − 1) cannot exceed σmax.
  EXPECT_LT(tendon_stretch / tendon_w - 1.0, spec.fibre.sigma_max_Pa / spec.tendon_modulus_Pa);
  EXPECT_NEAR(mm.volume_error, 0.0, 1e-6);
}

}  // namespace
}  // namespace fascicle

namespace fascicle {
namespace {

// correct_state (small corrections such as contact projections) keeps the energy reference: the
// energy that repeated corrections inject still trips the blow-up guard, whereas set_state
// re-bases the guard at every call and never notices it.
TEST(SolidCorrections, EnergyInjectedByCorrectionsTripsTheBlowUpGuard) {
  const BSplineSolid box = make_box({3, 3, 4});
  SolidDynamicsSpec spec = make_free_spec();
  spec.gravity_m_s2.setZero();
  spec.rayleigh_alpha_1_s = 0.0;
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  SolidState s0;
  s0.P = box.P;
  s0.V = Points3::Zero(box.P.rows(), 3);
  s0.V.col(0).setConstant(0.1);  // rigid translation: E0 = ½ m v², stable under any step
  const auto run = [&](bool additive) -> int {
    SolidDynamicsSolver solver(m);
    solver.set_state(s0);
    for (int k = 0; k < 40; ++k) {
      solver.step(0.001, {});
      SolidState s = solver.get_state();
      s.V *= 1.5;  // each correction multiplies the kinetic energy by 2.25
      if (additive)
        solver.correct_state(s.P, s.V);
      else
        solver.set_state(s);
    }
    return 40;
  };
  // Bound: E0 + 1e3 (E0 + m·1 J/kg) with E0 = 0.005 m: E grows past it after ~13 corrections.
  try {
    run(true);
    FAIL() << "energy grew by 1.5^80 through corrections without an error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::numerical);
    EXPECT_NE(std::string(e.what()).find("blow-up"), std::string::npos) << e.what();
  }
  // The same growth through set_state goes unnoticed (the guard is re-based each step).
  EXPECT_EQ(run(false), 40);
}

// An identity correction between steps changes nothing: same bits, same factorisations (the kept
// factorisation survives it); set_state drops the factorisation every time.
TEST(SolidCorrections, IdentityCorrectionKeepsResultsAndFactorisation) {
  const BSplineSolid box = make_box({3, 3, 5});
  SolidDynamicsSpec spec = make_free_spec();
  spec.gravity_m_s2.setZero();
  spec.rayleigh_alpha_1_s = 30.0;
  spec.volume = VolumeMethod::exact;
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  SolverOptions o;
  o.reuse_factorisation_steps = 20;
  SolidState s0;
  s0.P = box.P;
  s0.P.col(2) *= 1.2;
  s0.V = Points3::Zero(box.P.rows(), 3);
  const auto run = [&](int mode, int& factorisations) {
    SolidDynamicsSolver solver(m, o);
    solver.set_state(s0);
    factorisations = 0;
    for (int k = 0; k < 30; ++k) {
      factorisations += solver.step(0.005, {}).factorisations;
      const SolidState s = solver.get_state();
      if (mode == 1) solver.correct_state(s.P, s.V);
      if (mode == 2) solver.set_state(s);
    }
    return solver.get_state();
  };
  int f_plain = 0, f_corrected = 0, f_reset = 0;
  const SolidState plain = run(0, f_plain);
  const SolidState corrected = run(1, f_corrected);
  run(2, f_reset);
  EXPECT_EQ(plain.P, corrected.P);
  EXPECT_EQ(plain.V, corrected.V);
  EXPECT_EQ(plain.time_s, corrected.time_s);
  EXPECT_EQ(f_plain, f_corrected);
  EXPECT_LT(f_plain, f_reset) << "the factorisation is reused across steps without corrections";
  // Wrong sizes are bad input.
  SolidDynamicsSolver solver(m, o);
  try {
    solver.correct_state(Points3::Zero(3, 3), Points3::Zero(3, 3));
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
  }
}

}  // namespace
}  // namespace fascicle

namespace fascicle {
namespace {

// The extrapolated Newton start and the contraction-rate refresh change only how Newton gets to
// the step's solution: a contraction between fixed ends ends at the same state within the Newton
// tolerance, with fewer iterations in the smooth phase.
TEST(SolidIntegrators, ExtrapolatedStartReachesTheSameSteps) {
  const BSplineSolid box = make_box();
  SolidDynamicsSpec spec = make_free_spec();
  spec.gravity_m_s2.setZero();
  spec.attachments.push_back({"origin", -1, find_end_layer(box, 0)});
  spec.attachments.push_back({"insertion", -1, find_end_layer(box, 1)});
  spec.rayleigh_alpha_1_s = 10.0;
  spec.tendon_fraction_start = spec.tendon_fraction_end = 0.2;  // compliant ends: the belly moves
  spec.volume = VolumeMethod::exact;
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  const auto run = [&](bool extrapolate, double rate, int& iterations) {
    SolverOptions o;
    o.reuse_factorisation_steps = 20;
    o.extrapolate_start = extrapolate;
    o.refresh_contraction_rate = rate;
    SolidDynamicsSolver solver(m, o);
    StepInputs in;
    in.excitation = 1.0;
    iterations = 0;
    for (int k = 0; k < 60; ++k) iterations += solver.step(1e-3, in).newton_iterations;
    return solver.get_state();
  };
  int it_plain = 0, it_extra = 0, it_rate = 0;
  const SolidState plain = run(false, 0.0, it_plain);
  const SolidState extra = run(true, 0.0, it_extra);
  const SolidState rate = run(true, 0.25, it_rate);
  const double size = (box.P.colwise().maxCoeff() - box.P.colwise().minCoeff()).norm();
  const double moved = (plain.P - box.P).cwiseAbs().maxCoeff();
  EXPECT_GT(moved, 1e-4 * size) << "the block contracts";
  // Each step stops within 1e-7 × size of its solution; over 60 steps the two runs stay close.
  EXPECT_LT((extra.P - plain.P).cwiseAbs().maxCoeff(), 1e-5 * size);
  EXPECT_LT((rate.P - plain.P).cwiseAbs().maxCoeff(), 1e-5 * size);
  EXPECT_LE(it_extra, it_plain);
  EXPECT_LT(std::abs(calc_metrics(*m, extra).volume_error), 1e-6);
}

}  // namespace
}  // namespace fascicle
