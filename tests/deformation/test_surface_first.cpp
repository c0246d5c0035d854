// Surface-first deformation on procedural muscles: volume under bending, exact rigid motion,
// bone contact (also when intersecting at rest), input errors.
#include "fascicle/core/error.hpp"
#include "fascicle/deformation/surface_first.hpp"
#include "fascicle/geometry/primitives.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <string>

namespace fascicle {
namespace {

constexpr double kRadius = 0.02, kHeight = 0.2;

// A cylinder muscle along z in [-0.1, 0.1] m with the end caps (|z| > 0.09) as attachment areas.
struct CylinderMuscle {
  TriMesh mesh = make_cylinder(kRadius, kHeight, 32, 40);
  std::vector<SurfaceAttachment> areas;
  CylinderMuscle() {
    areas = {{"origin", {}}, {"insertion", {}}};
    for (int i = 0; i < mesh.V.rows(); ++i) {
      if (mesh.V(i, 2) < -0.09) areas[0].vertices.push_back(i);
      if (mesh.V(i, 2) > 0.09) areas[1].vertices.push_back(i);
    }
  }
};

Points3 straight_line(int points) {
  Points3 L(points, 3);
  for (int k = 0; k < points; ++k) L.row(k) << 0.0, 0.0, -0.1 + 0.2 * k / (points - 1);
  return L;
}

Transform rotation_about_x(double angle, const Vec3& centre) {
  Transform T = Transform::Identity();
  T.translate(centre).rotate(Eigen::AngleAxisd(angle, Vec3::UnitX())).translate(-centre);
  return T;
}

// A hinge at the origin, axis x: the upper half of the line and the insertion turn by `angle`.
SurfaceFrameInput hinge_frame(double angle) {
  SurfaceFrameInput in;
  const Transform T = rotation_about_x(angle, Vec3::Zero());
  in.action_line = straight_line(11);
  for (int k = 6; k < 11; ++k) in.action_line.row(k) = (T * Vec3(in.action_line.row(k).transpose())).transpose();
  in.attachment_motions = {Transform::Identity(), T};
  return in;
}

// The per-segment slerp parts computed once give calc_line_point's bits, on a bent line whose
// frames turn by small and large angles (and stay put on its straight parts: the linear blend).
TEST(FramedLine, InterpolatorGivesTheBitsOfCalcLinePoint) {
  Points3 polyline(40, 3);
  for (int k = 0; k < 40; ++k) {
    const double t = k / 39.0;
    polyline.row(k) << 0.05 * std::sin(6.0 * t) * (t > 0.5 ? 1.0 : 0.0), 0.02 * t * t, 0.3 * t;
  }
  const FramedLine line = calc_framed_line(polyline, 64, calc_default_start_frame(polyline));
  const LinePointInterpolator interpolate(line);
  int curved = 0;
  for (int i = 0; i <= 2000; ++i) {
    const double s = -0.01 + 1.02 * i / 2000.0;  // also outside [0, 1] (clamped)
    const LinePoint a = calc_line_point(line, s), b = interpolate(s);
    ASSERT_EQ(a.point, b.point) << s;
    ASSERT_EQ(a.frame.coeffs(), b.frame.coeffs()) << s;
    curved += a.frame.coeffs() != line.frames[std::min(63, static_cast<int>(std::clamp(s, 0.0, 1.0) * 63))].coeffs();
  }
  EXPECT_GT(curved, 1000);  // most points lie between two different frames
}

TEST(SurfaceFirst, RestPoseIsReproducedExactly) {
  const CylinderMuscle m;
  const SurfaceBinding b = bind_surface(m.mesh, straight_line(2), m.areas, {});
  SurfaceFirstSolver solver(b, {});
  const Points3& X = solver.calc_frame(hinge_frame(0.0));
  EXPECT_LT((X - m.mesh.V).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT(solver.get_info().relative_volume_error, 1e-13);
}

TEST(SurfaceFirst, HingeBendKeepsVolume) {
  const CylinderMuscle m;
  SurfaceFirstOptions tight;
  tight.stationarity_tolerance = 1e-8;  // converge the Gauss-Newton iteration fully
  tight.max_volume_iterations = 12;
  const SurfaceBinding b = bind_surface(m.mesh, straight_line(2), m.areas, {}, tight);
  SurfaceFirstSolver solver(b, {});
  double max_error = 0.0, max_lambda = 0.0;
  for (int frame = 0; frame <= 12; ++frame) {
    const double angle = (M_PI / 2.0) * frame / 12.0;  // 0 -> 90 degrees
    const SurfaceFrameInput in = hinge_frame(angle);
    const Points3& X = solver.calc_frame(in);
    const SurfaceFrameInfo& info = solver.get_info();
    max_error = std::max(max_error, info.relative_volume_error);
    max_lambda = std::max(max_lambda, std::abs(info.volume_multiplier));
    EXPECT_LE(info.stationarity, 1e-8) << "frame " << frame;
    EXPECT_LT(info.volume_iterations, 12) << "frame " << frame;
    // the volume computed independently of the solver
    const double V = calc_enclosed_volume(X, m.mesh.F, Vec3::Zero());
    EXPECT_NEAR(V / b.rest_volume_m3, 1.0, 1e-4) << "frame " << frame;
    // attachment vertices follow their bones exactly
    for (int i : m.areas[1].vertices)
      EXPECT_LT((X.row(i).transpose() - in.attachment_motions[1] * Vec3(m.mesh.V.row(i).transpose())).norm(), 1e-12);
    for (int i : m.areas[0].vertices) EXPECT_LT((X.row(i) - m.mesh.V.row(i)).norm(), 1e-12);
  }
  EXPECT_LT(max_error, 1e-10);
  // the constraint is active: without it a bend loses volume, so the multiplier is not zero
  EXPECT_GT(max_lambda, 0.0);
  // the bend itself: the middle of the muscle at 90 degrees lies around the hinge, not straight
  const Points3& X = solver.get_vertices();
  const double top_y = X.col(1).minCoeff();
  EXPECT_LT(top_y, -0.08);  // the insertion end turned towards -y (rotation +90 deg about x)
  // the default (looser) stationarity tolerance changes the shape by little: the volume is exact at
  // every iterate, only the KKT residual differs
  const SurfaceBinding b_default = bind_surface(m.mesh, straight_line(2), m.areas, {});
  const Points3 X_default = deform_surface(b_default, {}, hinge_frame(M_PI / 2.0));
  const double shape_difference = (X_default - X).rowwise().norm().maxCoeff();
  std::printf("90 deg hinge: default vs converged KKT solution differ by %.3g mm\n", shape_difference * 1e3);
  EXPECT_LT(shape_difference, 1e-6);
}

TEST(SurfaceFirst, RigidMotionOfAllHandlesIsExact) {
  const CylinderMuscle m;
  const SurfaceBinding b = bind_surface(m.mesh, straight_line(5), m.areas, {});
  SurfaceFirstSolver solver(b, {});
  // first a bent frame (so the warm start is not the answer), then a rigid motion
  solver.calc_frame(hinge_frame(0.7));
  Transform T = Transform::Identity();
  T.translate(Vec3(0.31, -0.12, 0.05)).rotate(Eigen::AngleAxisd(1.1, Vec3(0.3, -0.5, 0.8).normalized()));
  SurfaceFrameInput in;
  in.action_line = straight_line(7);
  for (int k = 0; k < 7; ++k) in.action_line.row(k) = (T * Vec3(in.action_line.row(k).transpose())).transpose();
  in.attachment_motions = {T, T};
  const Points3& X = solver.calc_frame(in);
  double err = 0.0;
  for (int i = 0; i < X.rows(); ++i)
    err = std::max(err, (X.row(i).transpose() - T * Vec3(m.mesh.V.row(i).transpose())).norm());
  EXPECT_LT(err, 1e-9);
  EXPECT_LT(solver.get_info().relative_volume_error, 1e-12);
}

TEST(SurfaceFirst, UniformLaplacianAndLdltAgreeOnVolume) {
  const CylinderMuscle m;
  SurfaceFirstOptions o;
  o.laplacian = LaplacianKind::uniform;
  o.sparse_solver = SparseSolverKind::eigen_simplicial_ldlt;
  const SurfaceBinding b = bind_surface(m.mesh, straight_line(2), m.areas, {}, o);
  SurfaceFrameInfo info;
  const Points3 X = deform_surface(b, {}, hinge_frame(1.0), &info);
  EXPECT_LT(info.relative_volume_error, 1e-10);
  EXPECT_NEAR(calc_enclosed_volume(X, m.mesh.F, Vec3::Zero()) / b.rest_volume_m3, 1.0, 1e-10);
}

TEST(SurfaceFirst, CotangentLaplacianAnnihilatesLinearFunctions) {
  const TriMesh mesh = make_icosphere(0.03, 3);
  for (LaplacianKind kind : {LaplacianKind::cotangent, LaplacianKind::uniform}) {
    const SparseMatrix L = calc_laplacian(mesh, kind);
    EXPECT_LT((L * VecX::Ones(mesh.V.rows())).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_LT((SparseMatrix(L.transpose()) - L).norm(), 1e-12);
  }
  // cotangent: sum_i x_i . (L x)_i = 2 * Dirichlet energy of the coordinate functions = 2 * area
  // (for a closed surface, sum over coordinates of |grad x|^2 integrated is 2 A)
  const SparseMatrix L = calc_laplacian(mesh, LaplacianKind::cotangent);
  double e = 0.0;
  for (int c = 0; c < 3; ++c) e += mesh.V.col(c).dot(L * mesh.V.col(c));
  double area = 0.0;
  for (int f = 0; f < mesh.F.rows(); ++f)
    area += 0.5 * (mesh.V.row(mesh.F(f, 1)) - mesh.V.row(mesh.F(f, 0)))
                      .cross(mesh.V.row(mesh.F(f, 2)) - mesh.V.row(mesh.F(f, 0)))
                      .norm();
  EXPECT_NEAR(e, 2.0 * area, 1e-12 * area);
}

TEST(SurfaceFirst, VolumeGradientMatchesFiniteDifferences) {
  TriMesh mesh = make_ellipsoid(Vec3(0.02, 0.03, 0.05), 2);
  const Points3 G = calc_volume_gradient(mesh.V, mesh.F);
  // V is linear in each single coordinate, so central differences are exact up to rounding
  // (about eps * V / h): a large step is the accurate choice.
  const double h = 1e-4;
  for (int i : {0, 7, 41, 100}) {
    for (int c = 0; c < 3; ++c) {
      Points3 Vp = mesh.V, Vm = mesh.V;
      Vp(i, c) += h;
      Vm(i, c) -= h;
      const double fd = (calc_enclosed_volume(Vp, mesh.F, Vec3::Zero()) -
                         calc_enclosed_volume(Vm, mesh.F, Vec3::Zero())) / (2 * h);
      EXPECT_NEAR(G(i, c), fd, 1e-9 * G.cwiseAbs().maxCoeff());
    }
  }
  // the cubic along a direction equals the volume there
  Points3 Y = Points3::Random(mesh.V.rows(), 3) * 0.01;
  const auto c = calc_volume_cubic(mesh.V, Y, mesh.F, Vec3(0.001, 0.0, 0.0));
  for (double t : {-1.3, 0.4, 2.0}) {
    const double V = calc_enclosed_volume(mesh.V + t * Y, mesh.F, Vec3::Zero());
    EXPECT_NEAR(c[0] + t * (c[1] + t * (c[2] + t * c[3])), V, 1e-15);
  }
}

}  // namespace
}  // namespace fascicle

namespace fascicle {
namespace {

ErrorKind kind_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    EXPECT_FALSE(e.message().empty());
    return e.kind();
  }
  ADD_FAILURE() << "no fascicle::Error thrown";
  return ErrorKind::internal;
}

TEST(SurfaceFirstBadInput, ClearErrors) {
  const CylinderMuscle m;
  // attachment index out of range
  std::vector<SurfaceAttachment> bad = m.areas;
  bad[1].vertices.push_back(1000000);
  EXPECT_EQ(kind_of([&] { bind_surface(m.mesh, straight_line(2), bad, {}); }), ErrorKind::bad_input);
  // overlapping areas
  bad = m.areas;
  bad[1].vertices.push_back(m.areas[0].vertices[0]);
  EXPECT_EQ(kind_of([&] { bind_surface(m.mesh, straight_line(2), bad, {}); }), ErrorKind::bad_input);
  // inward-facing surface
  TriMesh flipped = m.mesh;
  flipped.F.col(1).swap(flipped.F.col(2));
  EXPECT_EQ(kind_of([&] { bind_surface(flipped, straight_line(2), m.areas, {}); }), ErrorKind::bad_input);
  // degenerate action line
  Points3 point(2, 3);
  point.setZero();
  EXPECT_EQ(kind_of([&] { bind_surface(m.mesh, point, m.areas, {}); }), ErrorKind::bad_input);
  // wrong number of attachment motions, NaN action line
  const SurfaceBinding b = bind_surface(m.mesh, straight_line(2), m.areas, {}, {}, "test_muscle");
  SurfaceFirstSolver solver(b, {});
  SurfaceFrameInput in = hinge_frame(0.3);
  in.attachment_motions.pop_back();
  EXPECT_EQ(kind_of([&] { solver.calc_frame(in); }), ErrorKind::bad_input);
  in = hinge_frame(0.3);
  in.action_line(1, 0) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(kind_of([&] { solver.calc_frame(in); }), ErrorKind::bad_input);
  // the solver still works after rejected input
  EXPECT_LT((solver.calc_frame(hinge_frame(0.0)) - m.mesh.V).cwiseAbs().maxCoeff(), 1e-12);
}

// Contact-set changes handled by a low-rank (Woodbury) correction of a factor give the same frames
// as numeric refactorisations: a spherical bone pressed into a cylinder muscle 0.25 mm per frame and
// back (the contact patch grows and shrinks by a few vertices per frame).
TEST(SurfaceFirstContact, LowRankContactUpdatesMatchRefactorisation) {
  TriMesh muscle = make_cylinder(kRadius, kHeight, 48, 60);
  std::vector<SurfaceAttachment> areas{{"origin", {}}, {"insertion", {}}};
  for (int i = 0; i < muscle.V.rows(); ++i) {
    if (muscle.V(i, 2) < -0.09) areas[0].vertices.push_back(i);
    if (muscle.V(i, 2) > 0.09) areas[1].vertices.push_back(i);
  }
  Points3 line(2, 3);
  line << 0, 0, -0.1, 0, 0, 0.1;
  TriMesh ball = make_icosphere(0.01, 3);
  ball.V.col(0).array() += kRadius + 0.01 + 0.001;  // 1 mm outside the muscle at rest
  const MeshQuery bone(ball);
  // Both factor kinds: the supernodal one corrects between its triangular solves (sparse columns
  // of L^-1 U), the simplicial LDL^T one after its solve (dense columns of K^-1 U).
  // Rank limits: the default (every correction relative to the contact-free factor here; the
  // simplicial kind caps it at 32) and 4 (the limit is hit: refactorisations with contacts, then
  // corrections relative to that factor, adding and removing contacts).
  for (const int limit : {SurfaceFirstOptions{}.max_low_rank, 4})
  for (const SparseSolverKind kind : {SparseSolverKind::cholmod_supernodal, SparseSolverKind::eigen_simplicial_ldlt}) {
    SCOPED_TRACE(kind == SparseSolverKind::cholmod_supernodal ? "supernodal" : "simplicial LDLT");
    SCOPED_TRACE("max_low_rank " + std::to_string(limit));
    SurfaceFirstOptions refactorise, low_rank;
    refactorise.sparse_solver = low_rank.sparse_solver = kind;
    refactorise.max_low_rank = 0;
    low_rank.max_low_rank = limit;
    const SurfaceBinding b0 = bind_surface(muscle, line, areas, {&bone}, refactorise);
    const SurfaceBinding b1 = bind_surface(muscle, line, areas, {&bone}, low_rank);
    SurfaceFirstSolver s0(b0, {&bone}), s1(b1, {&bone});
    double worst_difference = 0.0;
    int frames_with_contacts = 0;
    for (int k = 0; k <= 40; ++k) {
      const double press = 0.25e-3 * (k <= 20 ? k : 40 - k);  // 0 -> 5 mm -> 0
      SurfaceFrameInput in;
      in.action_line = line;
      in.attachment_motions = {Transform::Identity(), Transform::Identity()};
      Transform T = Transform::Identity();
      T.translate(Vec3(-press, 0, 0));
      in.bone_motions = {T};
      const Points3& X0 = s0.calc_frame(in);
      const Points3& X1 = s1.calc_frame(in);
      ASSERT_EQ(s0.get_info().active_contacts, s1.get_info().active_contacts) << "frame " << k;
      frames_with_contacts += s1.get_info().active_contacts > 0;
      // Each contact round after the first starts from the previous round's solution with the
      // direction K^-1 grad V there (solved with the minimiser as six right-hand sides), and the
      // press changes the shape little: one step and one check. (A defect once kept only three of
      // the six solved columns, so the first step went along the minimiser itself: 4 solves.)
      const SurfaceFrameInfo& info = s1.get_info();
      if (info.contact_rounds > 1) {
        EXPECT_LE(info.volume_iterations, 1 + 2 * (info.contact_rounds - 1)) << "frame " << k;
      }
      worst_difference = std::max(worst_difference, (X1 - X0).cwiseAbs().maxCoeff());
      EXPECT_LE(s1.get_info().relative_volume_error, 1e-12);
      EXPECT_LE(s1.get_info().max_penetration_beyond_rest_m, 0.5e-3);
      EXPECT_LE(calc_bone_penetration(X1, bone, T, b1.rest_bone_depth[0], b1.fixed_vertices).max_depth_beyond_rest_m,
                0.5e-3);
    }
    EXPECT_GT(frames_with_contacts, 20);
    EXPECT_LT(worst_difference, 1e-9);  // metres: round-off of the two factorisations
    EXPECT_EQ(s0.get_info().low_rank_updates, 0);
    EXPECT_GT(s1.get_info().low_rank_updates, 10);
    EXPECT_LT(s1.get_info().factorisations, s0.get_info().factorisations);
    if (limit == 4) {
      EXPECT_GE(s1.get_info().factorisations, 3);  // the base and >= 2 with contacts
    }
    std::printf("ball pressed 0 -> 5 -> 0 mm in 41 frames: %d refactorisations, or %d with %d low-rank updates; "
                "max vertex difference %.2g m\n",
                s0.get_info().factorisations, s1.get_info().factorisations, s1.get_info().low_rank_updates,
                worst_difference);
  }
}

}  // namespace
}  // namespace fascicle
