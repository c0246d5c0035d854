// Fibres-first deformation on small procedural bundles: rest invariance, analytic spring
// equilibria (static and dynamic), bone non-penetration, muscle-muscle separation, volume under
// stretch, and input errors.
#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/deformation/fibres_first.hpp"
#include "fascicle/geometry/mesh_validation.hpp"
#include "fascicle/geometry/primitives.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <gtest/gtest.h>

#include <cmath>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <functional>
#include <set>

namespace fascicle {
namespace {

TriMesh moved(TriMesh m, const Vec3& by) {
  m.V.rowwise() += by.transpose();
  return m;
}

Transform translation(const Vec3& v) {
  Transform T = Transform::Identity();
  T.translate(v);
  return T;
}

// A bundle of nx x ny straight fibres along `axis` from `start` (length L), spaced `gap` apart in
// the two directions u, v normal to the axis, centred on the line through `start`.
std::vector<Points3> make_bundle(const Vec3& start, const Vec3& axis, const Vec3& u, double L,
                                 int nx, int ny, double gap, int points = 5) {
  const Vec3 v = axis.cross(u);
  std::vector<Points3> fibres;
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j) {
      const Vec3 offset = (i - 0.5 * (nx - 1)) * gap * u + (j - 0.5 * (ny - 1)) * gap * v;
      Points3 f(points, 3);
      for (int k = 0; k < points; ++k)
        f.row(k) = (start + offset + axis * (L * k / (points - 1))).transpose();
      fibres.push_back(f);
    }
  return fibres;
}

// Two slabs (bones) below z = 0 and above z = L that the bundle's ends touch.
struct EndBones {
  double L;
  MeshQuery bottom, top;
  explicit EndBones(double length)
      : L(length),
        bottom(moved(make_box(Vec3(0.02, 0.02, 0.005)), Vec3(0, 0, -0.005))),
        top(moved(make_box(Vec3(0.02, 0.02, 0.005)), Vec3(0, 0, length + 0.005))) {}
  std::vector<const MeshQuery*> list() const { return {&bottom, &top}; }
};

// Two bundles along z between the end bones, with box surfaces for the surface particles:
// "pushed" (3 x 3 fibres, 11 mm square) on the axis and "aside" (2 x 2, 7 mm) 12 mm away along −x.
std::pair<FibreBundleSpec, FibreBundleSpec> make_pushed_and_aside(double L) {
  FibreBundleSpec a{"pushed", make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), L, 3, 3, 0.004), 0, 1};
  a.rest_surface = moved(make_box(Vec3(0.0055, 0.0055, L / 2)), Vec3(0, 0, L / 2));
  FibreBundleSpec b{"aside", make_bundle(Vec3(-0.012, 0, 0), Vec3::UnitZ(), Vec3::UnitX(), L, 2, 2, 0.004), 0, 1};
  b.rest_surface = moved(make_box(Vec3(0.0035, 0.0035, L / 2)), Vec3(-0.012, 0, L / 2));
  return {a, b};
}

FibresFirstOptions tight_options() {
  FibresFirstOptions o;
  o.max_iterations = 400;
  o.step_tolerance = 1e-10;
  return o;
}

TEST(FibresFirst, BundleAtRestStaysAtRest) {
  const EndBones bones(0.08);
  const FibreBundleSpec spec{"rest", make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), 0.08, 4, 3, 0.004), 0, 1};
  const FibresFirstModel model = build_fibres_first_model({spec}, bones.list(), tight_options());
  EXPECT_EQ(model.num_particles(), 12 * 15);
  EXPECT_EQ(model.muscles[0].boundary_fibres.size(), 10u);  // the sides of the 4 x 3 grid
  FibresFirstSolver solver(model);
  solver.calc_frame({});
  EXPECT_LT((solver.get_particles() - model.rest).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT(solver.get_muscles()[0].relative_volume_error, 1e-12);
  EXPECT_EQ(solver.get_muscles()[0].max_bone_penetration_m, 0.0);
  EXPECT_LE(solver.get_info().iterations, 2);
  // rest volume: the tube through the 3 x 4 hull is a 12 mm x 8 mm x 80 mm box
  EXPECT_NEAR(model.muscles[0].rest_volume_m3, 0.012 * 0.008 * 0.08, 1e-12);
}

// Contact fibres of a 5 x 5 grid: the 16 on the hull, plus the next ring of 8 (one spacing from
// the hull's edges) with muscle_contact_band = 1.
TEST(FibresFirst, ContactFibresAreTheHullAndTheBandAroundIt) {
  const EndBones bones(0.08);
  const FibreBundleSpec spec{"grid", make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), 0.08, 5, 5, 0.004), 0, 1};
  for (double band : {0.0, 1.0}) {
    FibresFirstOptions o;
    o.muscle_contact_band = band;
    const FibresFirstModel model = build_fibres_first_model({spec}, bones.list(), o);
    EXPECT_EQ(model.muscles[0].boundary_fibres.size(), 16u);
    EXPECT_EQ(model.muscles[0].contact_particles.size(), (band > 0.0 ? 24u : 16u) * 15u) << band;
  }
}

TEST(FibresFirst, RigidMotionOfAllBonesMovesTheBundleRigidly) {
  const EndBones bones(0.08);
  const FibreBundleSpec spec{"rigid", make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), 0.08, 3, 3, 0.004), 0, 1};
  const FibresFirstModel model = build_fibres_first_model({spec}, bones.list(), tight_options());
  FibresFirstSolver solver(model);
  Transform T = Transform::Identity();
  T.translate(Vec3(0.01, -0.02, 0.03)).rotate(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()));
  solver.calc_frame({{T, T}});
  const Points3 expected = (model.rest * T.linear().transpose()).rowwise() + T.translation().transpose();
  EXPECT_LT((solver.get_particles() - expected).cwiseAbs().maxCoeff(), 1e-9);
}

// A block whose face lies 1 mm inside the bundle's outer fibres at rest (overlapping segmentations)
// and then moves 4 mm further in: particles inside it at rest may stay at their rest depth but go
// no deeper (depth beyond rest <= 1e-9 m, measured independently), and the bundle is pushed.
TEST(FibresFirst, ParticlesInsideABoneAtRestGoNoDeeper) {
  const double L = 0.1;
  const EndBones ends(L);
  const MeshQuery block(moved(make_box(Vec3(0.01, 0.03, 0.01)), Vec3(0.013, 0.0, L / 2)));
  const FibreBundleSpec spec{"overlapping", make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), L, 3, 3, 0.004), 0, 1};
  const FibresFirstOptions o;
  const FibresFirstModel model = build_fibres_first_model({spec}, {&ends.bottom, &ends.top, &block}, o);
  int inside_at_rest = 0;
  for (int p = 0; p < model.num_particles(); ++p) inside_at_rest += model.rest_bone_depth[2][p] > 0.0;
  EXPECT_EQ(inside_at_rest, 3 * 3);  // the x = 4 mm fibres' particles within the block's 20 mm
  FibresFirstSolver solver(model);
  for (int k = 1; k <= 4; ++k) {
    const Transform B = translation(Vec3(-0.001 * k, 0, 0));
    solver.calc_frame({{Transform::Identity(), Transform::Identity(), B}});
    const FibreBundleFrame& fr = solver.get_muscles()[0];
    EXPECT_LE(fr.max_bone_penetration_m, 1e-9) << "frame " << k;
    EXPECT_LT(fr.relative_volume_error, o.volume_tolerance);
    const Points3& x = solver.get_particles();
    for (int p = 0; p < x.rows(); ++p) {
      const Vec3 local = B.inverse() * Vec3(x.row(p).transpose());
      if (model.role[p] != ParticleRole::free || !block.calc_is_inside(local)) continue;
      EXPECT_LE(block.calc_closest_point(local).distance, model.rest_bone_depth[2][p] + 1e-9)
          << "particle " << p << " frame " << k;
    }
  }
  EXPECT_LT(solver.get_particles().col(0).minCoeff(), -0.006);
}

// A single fibre (no volume) stretched along its axis by moving its insertion bone. Along the
// axis the springs act as linear springs of the coordinate z, so the equilibrium is the solution
// of a small linear system: with springs only, uniform spacing (L + d) / (P - 1); with bending
// springs (i, i+2), the one-sided bending springs next to the ends make the spacing non-uniform.
TEST(FibresFirst, StretchedFibreSettlesToTheAnalyticEquilibrium) {
  const double L = 0.1, d = 0.02;
  const int P = 11;
  const EndBones bones(L);
  Points3 fibre(3, 3);  // unevenly spaced input points: resampling makes the particles uniform
  fibre << 0, 0, 0, 0, 0, 0.07, 0, 0, L;
  for (double kb : {0.0, 40.0}) {
    FibresFirstOptions o = tight_options();
    o.hold_volume = false;
    o.particles_per_fibre = P;
    o.bending_stiffness = kb;
    const FibresFirstModel model = build_fibres_first_model({{"single", {fibre}, 0, 1}}, bones.list(), o);
    FibresFirstSolver solver(model);
    solver.calc_frame({{Transform::Identity(), translation(Vec3(0, 0, d))}});
    const Points3& x = solver.get_particles();
    // reference: minimise sum k/2 (z_j - z_i - l0)^2 over z_1..z_{P-2}, z_0 = 0, z_{P-1} = L + d
    const double l0 = L / (P - 1);
    Eigen::MatrixXd K = Eigen::MatrixXd::Zero(P, P);
    VecX f = VecX::Zero(P);
    auto spring = [&](int i, int j, double k, double rest) {
      K(i, i) += k, K(j, j) += k, K(i, j) -= k, K(j, i) -= k;
      f[i] -= k * rest, f[j] += k * rest;
    };
    for (int i = 0; i + 1 < P; ++i) spring(i, i + 1, o.along_stiffness, l0);
    for (int i = 0; kb > 0.0 && i + 2 < P; ++i) spring(i, i + 2, kb, 2 * l0);
    VecX z = VecX::Zero(P);
    z[P - 1] = L + d;
    const VecX rhs = f.segment(1, P - 2) - K.block(1, 0, P - 2, 1) * z[0] - K.block(1, P - 1, P - 2, 1) * z[P - 1];
    z.segment(1, P - 2) = K.block(1, 1, P - 2, P - 2).ldlt().solve(rhs);
    for (int i = 0; i < P; ++i) {
      EXPECT_NEAR(x(i, 2), z[i], 1e-9) << "particle " << i << " bending " << kb;
      EXPECT_NEAR(x(i, 0), 0.0, 1e-12);
      if (kb == 0.0) {
        EXPECT_NEAR(x(i, 2), (L + d) * i / (P - 1), 1e-9);
      }
    }
    if (kb > 0.0) {
      EXPECT_GT(std::abs(x(1, 2) - (L + d) / (P - 1)), 1e-5);  // really non-uniform
    }
    EXPECT_LT(solver.get_info().residual, 1e-10);
  }
}

// A belly from the bottom slab to 30 mm short of the top one: its distal ends are too far from
// the top slab to be fixed to it, so they are carried along the action line (a tendon), not
// rigidly with the slab: by default at their rest arc-length fraction 0.05 / 0.08, or, with
// carry_inextensible_tendon, at their rest arc length from the nearer (top) end, 30 mm.
TEST(FibresFirst, FarEndsAreCarriedAlongTheActionLine) {
  const EndBones bones(0.08);
  FibreBundleSpec spec{"belly", make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), 0.05, 3, 3, 0.004), 0, 1};
  Points3 line(2, 3);
  line << 0, 0, 0, 0, 0, 0.08;
  spec.action_line = line;
  FibresFirstOptions o = tight_options();
  o.end_attachment_distance_m = 0.005;
  const FibresFirstModel model = build_fibres_first_model({spec}, bones.list(), o);
  const int P = o.particles_per_fibre;
  for (int f = 0; f < 9; ++f) {
    EXPECT_EQ(model.role[f * P], ParticleRole::fixed);
    EXPECT_EQ(model.fixed_bone[f * P], 0);
    EXPECT_EQ(model.role[f * P + P - 1], ParticleRole::carried);
    EXPECT_NEAR(model.line_fraction[f * P + P - 1], 0.625, 1e-12);
  }
  // the top slab moves 20 mm up: with the tendon rule the ends keep their 30 mm to the top and
  // move 20 mm; with the fraction rule the line's point at 0.625 moves 12.5 mm; given or derived
  Points3 longer(2, 3);
  longer << 0, 0, 0, 0, 0, 0.10;
  EXPECT_FALSE(FibresFirstOptions{}.carry_inextensible_tendon);
  for (bool tendon : {true, false}) {
    FibresFirstOptions ot = o;
    ot.carry_inextensible_tendon = tendon;
    const FibresFirstModel mt = build_fibres_first_model({spec}, bones.list(), ot);
    for (bool given : {true, false}) {
      FibresFirstSolver solver(mt);
      FibresFirstInput input{{Transform::Identity(), translation(Vec3(0, 0, 0.02))}};
      if (given) input.action_lines = {longer};
      solver.calc_frame(input);
      const Points3& x = solver.get_particles();
      for (int f = 0; f < 9; ++f) {
        const Vec3 expected = mt.rest.row(f * P + P - 1).transpose() + Vec3(0, 0, tendon ? 0.02 : 0.0125);
        EXPECT_LT((x.row(f * P + P - 1).transpose() - expected).norm(), 1e-12) << given << tendon;
        EXPECT_EQ(x.row(f * P), mt.rest.row(f * P));
      }
      EXPECT_LT(solver.get_muscles()[0].relative_volume_error, 1e-3);
    }
  }
  // the tendon rule from the origin side: a belly whose proximal ends are carried (fraction 0.25
  // of a 80 mm line, 20 mm from the bottom) keeps them 20 mm from the line's start when the line
  // shortens by 10 mm
  {
    const EndBones far(0.08);
    FibreBundleSpec upper{"upper", make_bundle(Vec3(0, 0, 0.02), Vec3::UnitZ(), Vec3::UnitX(), 0.06, 3, 3, 0.004), 0, 1};
    upper.action_line = line;
    FibresFirstOptions ot = o;
    ot.carry_inextensible_tendon = true;
    const FibresFirstModel mu = build_fibres_first_model({upper}, far.list(), ot);
    EXPECT_EQ(mu.role[0], ParticleRole::carried);
    EXPECT_NEAR(mu.line_fraction[0], 0.25, 1e-12);
    Points3 shorter(2, 3);
    shorter << 0, 0, 0, 0, 0, 0.07;
    FibresFirstSolver solver(mu);
    FibresFirstInput input{{Transform::Identity(), translation(Vec3(0, 0, -0.01))}};
    input.action_lines = {shorter};
    solver.calc_frame(input);
    for (int f = 0; f < 9; ++f)
      EXPECT_LT((solver.get_particles().row(f * P).transpose() - mu.rest.row(f * P).transpose()).norm(), 1e-12);
  }
  // the line turned by 90 deg about x through the origin: the end layer turns with it
  Points3 turned(2, 3);
  turned << 0, 0, 0, 0, -0.08, 0;
  FibresFirstSolver solver(model);
  FibresFirstInput input{{Transform::Identity(), Transform::Identity()}};
  input.action_lines = {turned};
  solver.calc_frame(input);
  const Mat3 R = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitX()).toRotationMatrix();
  for (int f = 0; f < 9; ++f)
    EXPECT_LT((solver.get_particles().row(f * P + P - 1).transpose() -
               R * model.rest.row(f * P + P - 1).transpose()).norm(), 1e-12);
  // bad input: a wrong number of lines, a non-finite line, a degenerate rest line
  EXPECT_THROW(solver.calc_frame({{Transform::Identity(), Transform::Identity()}, 0.0, {longer, longer}}), Error);
  Points3 broken = longer;
  broken(1, 2) = std::nan("");
  EXPECT_THROW(solver.calc_frame({{Transform::Identity(), Transform::Identity()}, 0.0, {broken}}), Error);
  spec.action_line = Points3::Zero(2, 3);
  EXPECT_THROW(build_fibres_first_model({spec}, bones.list(), o), Error);
}

// Longitudinal oscillation of one particle between two fixed ones: omega = sqrt(2 k / m).
TEST(FibresFirst, DynamicParticleOscillatesAtTheSpringFrequency) {
  const double L = 0.02;
  const EndBones bones(L);
  FibresFirstOptions o = tight_options();
  o.hold_volume = false;
  o.particles_per_fibre = 3;
  o.bending_stiffness = 0.0;
  o.dynamic = true;
  o.damping_per_s = 0.0;
  Points3 fibre(2, 3);
  fibre << 0, 0, 0, 0, 0, L;
  FibreBundleSpec spec{"oscillator", {fibre}, 0, 1};
  spec.volume_m3 = 3e-6;  // 3 particles: m = 1060 kg/m^3 x 1e-6 m^3
  const FibresFirstModel model = build_fibres_first_model({spec}, bones.list(), o);
  const double m = 1060.0 * 1e-6, omega = std::sqrt(2.0 * o.along_stiffness / m);
  const double period = 2.0 * M_PI / omega, h = period / 400.0;
  FibresFirstSolver solver(model);
  const double d = 0.002;  // insertion jumps by d: new equilibrium of the middle at L/2 + d/2
  std::vector<double> crossings;
  double previous = -d / 2;  // displacement from the new equilibrium at t = 0
  double late_amplitude = 0.0;
  for (int k = 1; k <= 1200; ++k) {
    solver.calc_frame({{Transform::Identity(), translation(Vec3(0, 0, d))}, h});
    const double u = solver.get_particles()(1, 2) - (L + d) / 2;
    if ((previous < 0.0) != (u < 0.0)) crossings.push_back((k - 1 + previous / (previous - u)) * h);
    if (k > 800) late_amplitude = std::max(late_amplitude, std::abs(u));
    previous = u;
  }
  ASSERT_GE(crossings.size(), 4u);
  const double measured = (crossings[crossings.size() - 1] - crossings[crossings.size() - 3]);
  // backward Euler lengthens the period by about (omega h)^2 / 2 relative: 0.012 % here
  EXPECT_NEAR(measured / period, 1.0, 2e-3);
  // backward Euler's numerical damping: amplitude factor (1 + (omega h)^2)^(-1/2) per step
  const double decay = std::pow(1.0 + omega * omega * h * h, -800 / 2.0);
  EXPECT_NEAR(late_amplitude / (d / 2), decay, 0.02);
}

// A box bone pushed 6 mm into the side of a bundle: no particle ends inside it.
TEST(FibresFirst, NoParticleEndsInsideABone) {
  const double L = 0.1;
  const EndBones ends(L);
  const MeshQuery block(moved(make_box(Vec3(0.01, 0.03, 0.01)), Vec3(0.016, 0.0, L / 2)));
  const FibreBundleSpec spec{"pushed", make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), L, 3, 3, 0.004), 0, 1};
  FibresFirstOptions o;
  const FibresFirstModel model = build_fibres_first_model({spec}, {&ends.bottom, &ends.top, &block}, o);
  FibresFirstSolver solver(model);
  for (int k = 1; k <= 6; ++k) {
    const Transform B = translation(Vec3(-0.001 * k, 0, 0));
    solver.calc_frame({{Transform::Identity(), Transform::Identity(), B}});
    const FibreBundleFrame& fr = solver.get_muscles()[0];
    EXPECT_LE(fr.max_bone_penetration_m, 1e-9) << "frame " << k;
    EXPECT_LT(fr.relative_volume_error, o.volume_tolerance);
    const Points3& x = solver.get_particles();
    for (int p = 0; p < x.rows(); ++p) {
      const Vec3 local = B.inverse() * Vec3(x.row(p).transpose());
      EXPECT_FALSE(block.calc_is_inside(local)) << "particle " << p << " frame " << k;
    }
  }
  EXPECT_GT(solver.get_muscles()[0].bone_contacts, 0);
  // the bundle was really pushed: its boundary fibres facing the block moved by several mm
  EXPECT_LT(solver.get_particles().col(0).minCoeff(), -0.006);
}

// Two 3 x 3 bundles of length L = 60 mm crossing at right angles: A along z between the bones 0
// (below) and 1 (above), B along y with its axis at x = x0, between the bones 2 and 3; with
// `surfaces`, each gets a box rest surface 1.5 mm outside its outer particles.
struct CrossingBundles {
  static constexpr double L = 0.06, gap = 0.003, half = 0.0045;
  MeshQuery a0, a1, b0, b1;
  FibreBundleSpec A, B;
  CrossingBundles(double x0, bool surfaces)
      : a0(moved(make_box(Vec3(0.01, 0.01, 0.005)), Vec3(0, 0, -0.005))),
        a1(moved(make_box(Vec3(0.01, 0.01, 0.005)), Vec3(0, 0, L + 0.005))),
        b0(moved(make_box(Vec3(0.01, 0.005, 0.01)), Vec3(x0, -L / 2 - 0.005, L / 2))),
        b1(moved(make_box(Vec3(0.01, 0.005, 0.01)), Vec3(x0, L / 2 + 0.005, L / 2))),
        A{"A", make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), L, 3, 3, gap), 0, 1},
        B{"B", make_bundle(Vec3(x0, -L / 2, L / 2), Vec3::UnitY(), Vec3::UnitX(), L, 3, 3, gap), 2, 3} {
    if (!surfaces) return;
    A.rest_surface = moved(make_box(Vec3(half, half, L / 2)), Vec3(0, 0, L / 2));
    B.rest_surface = moved(make_box(Vec3(half, L / 2, half)), Vec3(x0, 0, L / 2));
  }
  FibresFirstModel build(const FibresFirstOptions& o) const {
    return build_fibres_first_model({A, B}, {&a0, &a1, &b0, &b1}, o);
  }
};

// Two bundles crossing at right angles, the second pulled across the first by 8 mm: no particle
// of one ends inside the other's surface, and pairs keep their minimum distance.
TEST(FibresFirst, BundlesPressedTogetherDoNotInterpenetrate) {
  const CrossingBundles bundles(0.008, false);  // B's axis beside A (half widths 3 mm each)
  FibresFirstOptions o;
  o.particles_per_fibre = 21;  // 3 mm along the fibres, as across
  o.muscle_margin_m = 0.0025;
  const FibresFirstModel model = bundles.build(o);
  FibresFirstSolver solver(model);
  for (int k = 1; k <= 8; ++k) {
    const Transform T = translation(Vec3(-0.001 * k, 0, 0));
    solver.calc_frame({{Transform::Identity(), Transform::Identity(), T, T}});
    const auto& fr = solver.get_muscles();
    EXPECT_LE(fr[0].max_muscle_overlap_m, 5e-4) << "frame " << k;
    EXPECT_LE(fr[1].max_muscle_overlap_m, 5e-4) << "frame " << k;
  }
  const auto& fr = solver.get_muscles();
  EXPECT_GT(fr[0].muscle_contacts, 0);
  for (int m = 0; m < 2; ++m) {
    const MeshQuery other(TriMesh{fr[1 - m].surface_vertices, model.muscles[1 - m].surface_triangles});
    for (int p = 0; p < fr[m].particles.rows(); ++p)
      EXPECT_FALSE(other.calc_is_inside(Vec3(fr[m].particles.row(p).transpose())))
          << "particle " << p << " of " << model.muscles[m].name;
  }
  // without contact handling the same motion interpenetrates (the test can fail)
  FibresFirstOptions off = o;
  off.muscle_margin_m = 0.0;
  const FibresFirstModel loose = bundles.build(off);
  FibresFirstSolver free_solver(loose);
  for (int k = 1; k <= 8; ++k) {
    const Transform T = translation(Vec3(-0.001 * k, 0, 0));
    free_solver.calc_frame({{Transform::Identity(), Transform::Identity(), T, T}});
  }
  const auto& lf = free_solver.get_muscles();
  const MeshQuery surface_a(TriMesh{lf[0].surface_vertices, loose.muscles[0].surface_triangles});
  int inside = 0;
  for (int p = 0; p < lf[1].particles.rows(); ++p)
    inside += surface_a.calc_is_inside(Vec3(lf[1].particles.row(p).transpose()));
  EXPECT_GT(inside, 0);
}

// Deepest vertex of `mesh` inside the closed surface `other` (0: none inside), measured
// independently of the solver (ray-vote inside test, exact closest point).
double calc_deepest_vertex_inside(const Points3& vertices, const MeshQuery& other) {
  double deepest = 0.0;
  for (Eigen::Index v = 0; v < vertices.rows(); ++v) {
    const Vec3 p = vertices.row(v).transpose();
    if (other.calc_is_inside(p)) deepest = std::max(deepest, other.calc_closest_point(p).distance);
  }
  return deepest;
}

// Two crossing bundles whose display surfaces (boxes 1.5 mm outside their outer particles) are
// pressed 5 mm into each other over 6 frames. Returns muscle A's surface contacts at the end;
// `deepest`: per muscle, its deepest vertex inside the other's surface (independent MeshQuery) at
// the last frame. With separate_surfaces it asserts <= 0.5 mm at every frame; with
// surface_particles also that every fibre particle stays inside its own surface (<= 0.1 mm out).
int press_crossing_bundles(const FibresFirstOptions& o, std::vector<double>& deepest, int* iterations = nullptr) {
  const CrossingBundles bundles(0.010, true);  // surfaces 1 mm apart at rest
  const FibresFirstModel model = bundles.build(o);
  EXPECT_TRUE(model.muscles[0].surface_from_rest_mesh && model.muscles[1].surface_from_rest_mesh);
  FibresFirstSolver solver(model);
  const int fibre_particles = 9 * o.particles_per_fibre;
  // how far each fibre particle lies outside its own surface (0: inside); at rest the fibre ends
  // lie beyond the loft's end rings (3 % of the length): the particles inside at rest must stay
  // inside (within 0.1 mm)
  auto calc_outside = [&](const Points3& particles, const Points3& surface, int m) {
    const MeshQuery own(TriMesh{surface, model.muscles[m].surface_triangles});
    VecX out = VecX::Zero(fibre_particles);
    for (int p = 0; p < fibre_particles; ++p) {
      const Vec3 x = particles.row(p).transpose();
      if (!own.calc_is_inside(x)) out[p] = own.calc_closest_point(x).distance;
    }
    return out;
  };
  std::vector<VecX> rest_outside(2);
  for (int m = 0; m < 2 && o.surface_particles; ++m) {
    const FibreBundle& b = model.muscles[m];
    rest_outside[m] = calc_outside(model.rest.middleRows(b.first_particle, b.num_particles),
                                   model.rest.middleRows(b.first_particle + fibre_particles, b.num_surface_particles), m);
  }
  for (int k = 1; k <= 6; ++k) {
    const Transform T = translation(Vec3(-0.001 * k, 0, 0));
    solver.calc_frame({{Transform::Identity(), Transform::Identity(), T, T}});
    if (iterations) *iterations += solver.get_info().iterations;
    const auto& fr = solver.get_muscles();
    deepest.assign(2, 0.0);
    for (int m = 0; m < 2; ++m) {
      const MeshQuery other(TriMesh{fr[1 - m].surface_vertices, model.muscles[1 - m].surface_triangles});
      deepest[m] = calc_deepest_vertex_inside(fr[m].surface_vertices, other);
      EXPECT_LT(fr[m].relative_volume_error, o.volume_tolerance) << "frame " << k;
      if (o.separate_surfaces) {
        EXPECT_LE(deepest[m], 5e-4) << model.muscles[m].name << ", frame " << k;
        EXPECT_LE(fr[m].max_surface_overlap_m, 5e-4) << model.muscles[m].name << ", frame " << k;
      }
      if (o.surface_particles) {
        const VecX out = calc_outside(fr[m].particles, fr[m].surface_vertices, m);
        for (int p = 0; p < fibre_particles; ++p)
          if (rest_outside[m][p] == 0.0) {
            EXPECT_LE(out[p], 1e-4) << model.muscles[m].name << " particle " << p << ", frame " << k;
          }
      }
    }
  }
  const Points3 pressed = solver.get_muscles()[0].particles;
  if (o.surface_particles && o.separate_surfaces) {
    // reset() forgets every frame (kept contacts, culling bounds, warm starts): the same frames
    // again give the same particles, bit for bit, and so does one thread (the muscles are solved
    // in parallel, each writing only its own rows)
    for (const int threads : {0, 1}) {
      const ThreadLimit limit(threads);
      solver.reset();
      for (int k = 1; k <= 6; ++k) {
        const Transform T = translation(Vec3(-0.001 * k, 0, 0));
        solver.calc_frame({{Transform::Identity(), Transform::Identity(), T, T}});
      }
      EXPECT_EQ((solver.get_muscles()[0].particles - pressed).cwiseAbs().maxCoeff(), 0.0)
          << "threads " << threads;
    }
    // the same pose again: the contacts of the last frame are kept (they still touch), so the
    // first round already holds them and no second round is needed (without keeping them, the
    // first round relaxes the surfaces back into each other and a second round separates them)
    const Transform T = translation(Vec3(-0.006, 0, 0));
    solver.calc_frame({{Transform::Identity(), Transform::Identity(), T, T}});
    EXPECT_EQ(solver.get_info().contact_rounds, 1);
    EXPECT_GT(solver.get_muscles()[0].surface_contacts, 0);
    for (int m = 0; m < 2; ++m) EXPECT_LE(solver.get_muscles()[m].max_surface_overlap_m, 5e-4);
  }
  return solver.get_muscles()[0].surface_contacts;
}

// Presses the crossing bundles with `on` (separate_surfaces set) and again with surface separation
// off: with it some surface contacts act (the bound of 0.5 mm is asserted inside
// press_crossing_bundles), without it none do and the surfaces overlap by more than 1 mm.
void expect_surface_separation_matters(const FibresFirstOptions& on) {
  std::vector<double> deepest_on, deepest_off;
  EXPECT_GT(press_crossing_bundles(on, deepest_on), 0);
  FibresFirstOptions off = on;
  off.separate_surfaces = false;
  EXPECT_EQ(press_crossing_bundles(off, deepest_off), 0);
  EXPECT_GT(std::max(deepest_off[0], deepest_off[1]), 1e-3);
}

// Display-surface separation with the surface carried by the particles (loft weights): no vertex
// ends more than 0.5 mm inside the other surface; with particle separation only, more than 1 mm.
TEST(FibresFirst, DisplaySurfacesPressedTogetherDoNotOverlap) {
  FibresFirstOptions on;
  on.particles_per_fibre = 21;
  on.separate_surfaces = true;
  expect_surface_separation_matters(on);
}

// The same with surface particles (the surface's vertices are particles, contacts are targets of
// the global step): separated to <= 0.5 mm, fibres inside their surfaces; without separation the
// surfaces overlap by more than 1 mm.
TEST(FibresFirst, SurfaceParticlesPressedTogetherDoNotOverlap) {
  FibresFirstOptions on;
  on.surface_particles = true;
  on.separate_surfaces = true;
  expect_surface_separation_matters(on);
}

// The stall rule (a muscle whose step stops falling rests) at its most eager setting (one
// iteration without a 10 % decrease) and off, with a step tolerance the iterations do not reach
// (1e-5): off, every round runs its 60 iterations; on, the rule ends the rounds after a few. The
// crossing bundles stay separated to <= 0.5 mm with the volume held and the fibres inside their
// surfaces either way (asserted inside press_crossing_bundles), with surface contacts acting.
TEST(FibresFirst, StallRuleKeepsSurfaceParticlesSeparated) {
  int iterations[2] = {0, 0};
  for (int stall : {0, 1}) {
    FibresFirstOptions o;
    o.surface_particles = true;
    o.separate_surfaces = true;
    o.stall_iterations = stall;
    o.step_tolerance = 1e-5;  // a tail of slow steps for the rule to cut
    o.max_iterations = 60;
    std::vector<double> deepest;
    EXPECT_GT(press_crossing_bundles(o, deepest, &iterations[stall]), 0) << "stall_iterations " << stall;
    EXPECT_LE(std::max(deepest[0], deepest[1]), 5e-4) << "stall_iterations " << stall;
  }
  EXPECT_EQ(iterations[0], 6 * 60);  // 6 frames, one round each at the iteration limit
  EXPECT_LT(iterations[1], 6 * 20);
}

// The final projection of the separation path never ends a frame with a worse volume than it
// started with (its alternating passes need not converge: gait2392's walk failed the volume hold
// at frame 42 after passes that took a muscle from 0.22 % to 0.66 %). A bundle with surface
// particles squeezed by a block moving 10 mm into it towards a second bundle that lies against a
// fixed wall, with the iterations cut short (3 per round, one round) and a volume tolerance of
// 1e-300, so every frame runs the three passes. At every frame the error at the end is not above
// the error after the first bone projection, the reported volumes agree with it, and the frames
// end in an earlier state whenever the last pass is worse than it (here: the state before the
// passes, exact to round-off, against round-off a few times larger after them).
TEST(FibresFirst, FinalProjectionNeverEndsWorseThanItStarted) {
  const double L = 0.1;
  const EndBones ends(L);
  const MeshQuery block(moved(make_box(Vec3(0.01, 0.03, 0.01)), Vec3(0.016, 0.0, L / 2)));
  const MeshQuery wall(moved(make_box(Vec3(0.005, 0.03, 0.03)), Vec3(-0.021, 0.0, L / 2)));
  const auto [a, b] = make_pushed_and_aside(L);
  FibresFirstOptions o;
  o.surface_particles = true;
  o.separate_surfaces = true;
  o.max_iterations = 3;
  o.max_contact_rounds = 1;
  o.volume_tolerance = 1e-300;
  const FibresFirstModel model = build_fibres_first_model({a, b}, {&ends.bottom, &ends.top, &block, &wall}, o);
  FibresFirstSolver solver(model);
  const Transform I = Transform::Identity();
  int restored = 0, passes = 0;
  for (int k = 1; k <= 10; ++k) {
    solver.calc_frame({{I, I, translation(Vec3(-0.001 * k, 0, 0)), I}});
    const FibresFirstInfo& info = solver.get_info();
    ASSERT_TRUE(std::isfinite(info.final_volume_error_start) && std::isfinite(info.final_volume_error));
    EXPECT_LE(info.final_volume_error, std::max(info.final_volume_error_start, o.volume_tolerance)) << "frame " << k;
    restored += info.final_state_restored > 0;
    passes += info.final_passes;
    // final_volume_error is taken before the last bone check; here that check finds nothing
    // left inside (the block's contacts were projected before it), so the muscles' reported
    // errors, from the returned positions, must not exceed it
    for (const FibreBundleFrame& fr : solver.get_muscles())
      EXPECT_LE(fr.relative_volume_error, info.final_volume_error) << "frame " << k;
  }
  EXPECT_EQ(passes, 30);
  EXPECT_GT(restored, 0);
  EXPECT_GT(solver.get_muscles()[0].bone_contacts, 0);
}

// The solver's own surface-overlap measure (vertex tests culled by distance bounds from earlier
// tests) equals an independent one (every vertex, ray-vote inside test, exact closest point) at
// every frame. The two box surfaces overlap by 1.5 mm at rest, more than
// surface_rest_overlap_resolved_m, so the pair keeps its rest depths and the overlap stays
// measurable while B is pressed 3 mm further into A; what grows beyond the rest depth is held
// within 0.5 mm.
TEST(FibresFirst, SurfaceOverlapMeasureMatchesAnIndependentOne) {
  const CrossingBundles bundles(0.0075, true);
  FibresFirstOptions o;
  o.surface_particles = true;
  o.separate_surfaces = true;
  o.surface_rest_overlap_resolved_m = 1e-3;
  const FibresFirstModel model = bundles.build(o);
  FibresFirstSolver solver(model);
  double largest = 0.0;
  for (int k = 0; k <= 6; ++k) {
    const Transform T = translation(Vec3(-0.0005 * k, 0, 0));
    solver.calc_frame({{Transform::Identity(), Transform::Identity(), T, T}});
    const auto& fr = solver.get_muscles();
    for (int m = 0; m < 2; ++m) {
      const MeshQuery other(TriMesh{fr[1 - m].surface_vertices, model.muscles[1 - m].surface_triangles});
      const double independent = calc_deepest_vertex_inside(fr[m].surface_vertices, other);
      EXPECT_NEAR(fr[m].max_surface_overlap_m, independent, 1e-9) << model.muscles[m].name << ", frame " << k;
      EXPECT_LE(fr[m].max_surface_overlap_beyond_rest_m, 5e-4) << model.muscles[m].name << ", frame " << k;
      EXPECT_LT(fr[m].relative_volume_error, o.volume_tolerance) << "frame " << k;
      largest = std::max(largest, independent);
    }
  }
  EXPECT_GT(largest, 1e-3);  // the measures compared a real overlap
}

// A 4 x 4 bundle of length L along z between the end bones, with a box rest surface around it.
FibreBundleSpec make_boxed_bundle_spec(double L) {
  FibreBundleSpec spec{"surface", make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), L, 4, 4, 0.004), 0, 1};
  spec.rest_surface = moved(make_box(Vec3(0.0075, 0.0075, L / 2)), Vec3(0, 0, L / 2));
  return spec;
}

// Surface particles: the loft's vertices are particles after the fibre particles, with weight 1;
// a rigid motion of both bones moves the surface rigidly (1e-9 m), and a 25 % stretch keeps the
// volume of the surface within 1e-3.
TEST(FibresFirst, SurfaceParticlesMoveRigidlyAndHoldVolume) {
  const double L = 0.08;
  const EndBones bones(L);
  const FibreBundleSpec spec = make_boxed_bundle_spec(L);
  FibresFirstOptions o = tight_options();
  o.surface_particles = true;
  const FibresFirstModel model = build_fibres_first_model({spec}, bones.list(), o);
  const FibreBundle& m = model.muscles[0];
  ASSERT_TRUE(m.surface_from_rest_mesh);
  EXPECT_EQ(m.num_surface_particles, o.surface_rings * o.surface_ring_points);
  EXPECT_EQ(m.num_particles, 16 * o.particles_per_fibre + m.num_surface_particles);
  EXPECT_EQ(m.surface_weight_particle.front(), m.first_particle + 16 * o.particles_per_fibre);
  {
    FibresFirstSolver solver(model);
    Transform T = Transform::Identity();
    T.translate(Vec3(0.01, -0.02, 0.03)).rotate(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()));
    solver.calc_frame({{T, T}});
    const Points3 rest_surface = model.rest.bottomRows(m.num_surface_particles);
    const Points3 expected = (rest_surface * T.linear().transpose()).rowwise() + T.translation().transpose();
    EXPECT_LT((solver.get_muscles()[0].surface_vertices - expected).cwiseAbs().maxCoeff(), 1e-9);
    EXPECT_LT(solver.get_muscles()[0].relative_volume_error, 1e-12);
  }
  FibresFirstOptions d;  // the solver's defaults otherwise
  d.surface_particles = true;
  const FibresFirstModel stretched = build_fibres_first_model({spec}, bones.list(), d);
  FibresFirstSolver solver(stretched);
  for (int k = 1; k <= 5; ++k) {
    solver.calc_frame({{Transform::Identity(), translation(Vec3(0, 0, 0.004 * k))}});
    EXPECT_LT(solver.get_muscles()[0].relative_volume_error, 1e-3) << "frame " << k;
  }
  // the surface really stretched with the fibres (its top ring follows the moved bone)
  EXPECT_GT(solver.get_muscles()[0].surface_vertices.col(2).maxCoeff(), model.rest.col(2).maxCoeff() + 0.01);
}

// A bundle squeezed between two neighbours while all three lie on a bone (a floor): three
// 3 x 3 bundles (box surfaces 11 mm wide, 1 mm apart) side by side, 0.1 mm above the floor. From
// the first frame on the floor is raised by 1 mm (0.9 mm into them), and the outer two, each between its own
// pair of end bones, move 1 mm per frame towards the middle one (4 frames: the middle bundle
// loses 3 mm of width on each side). Its room is upwards: at every frame each bundle keeps its
// volume (<= 0.5 %), the middle surface and its neighbours' stay apart (<= 0.5 mm, measured
// independently), and no particle is in the floor (<= 0.5 mm), while the bundles' bottom
// particles are held by the floor; the middle bundle's top rises by more than 1 mm. (Measured:
// volume <= 1.6e-3, deepest vertex 0.25 mm, penetration 0, top +3.0 mm. The same bounds hold
// with the bone contacts pinned to their points as before session 12 — the final projection
// separates these simple boxes either way — so this guards the invariants; the gait2392 scene
// test guards the change.)
TEST(FibresFirst, BundleSqueezedBetweenNeighboursOnABoneKeepsVolumeAndSeparation) {
  const double L = 0.06, w = 0.0055, spacing = 0.012, floor_top = -w - 1e-4;
  std::vector<MeshQuery> bones;
  bones.reserve(7);
  std::vector<FibreBundleSpec> specs;
  for (int k = 0; k < 3; ++k) {
    const double x0 = (k - 1) * spacing;
    bones.emplace_back(moved(make_box(Vec3(w, w, 0.005)), Vec3(x0, 0, -0.005)));
    bones.emplace_back(moved(make_box(Vec3(w, w, 0.005)), Vec3(x0, 0, L + 0.005)));
    FibreBundleSpec spec{fmt::format("bundle{}", k),
                         make_bundle(Vec3(x0, 0, 0), Vec3::UnitZ(), Vec3::UnitX(), L, 3, 3, 0.004), 2 * k, 2 * k + 1};
    spec.rest_surface = moved(make_box(Vec3(w, w, L / 2)), Vec3(x0, 0, L / 2));
    specs.push_back(spec);
  }
  bones.emplace_back(moved(make_box(Vec3(0.04, 0.005, L / 2)), Vec3(0, floor_top - 0.005, L / 2)));
  std::vector<const MeshQuery*> list;
  for (const MeshQuery& b : bones) list.push_back(&b);
  FibresFirstOptions o;
  o.surface_particles = true;
  o.separate_surfaces = true;
  const FibresFirstModel model = build_fibres_first_model(specs, list, o);
  FibresFirstSolver solver(model);
  const FibreBundle& middle_bundle = model.muscles[1];
  const double rest_top = model.rest.middleRows(middle_bundle.first_particle, middle_bundle.num_particles).col(1).maxCoeff();
  int floor_contacts = 0;
  for (int f = 1; f <= 4; ++f) {
    const Transform I = Transform::Identity(), lift = translation(Vec3(0, 0.001, 0));
    const Transform left = translation(Vec3(0.001 * f, 0, 0)), right = translation(Vec3(-0.001 * f, 0, 0));
    solver.calc_frame({{left, left, I, I, right, right, lift}});
    const auto& fr = solver.get_muscles();
    for (int m = 0; m < 3; ++m) {
      EXPECT_LE(fr[m].relative_volume_error, 5e-3) << "bundle " << m << ", frame " << f;
      EXPECT_LE(fr[m].max_bone_penetration_m, 5e-4) << "bundle " << m << ", frame " << f;
    }
    for (int m : {0, 2}) {
      const MeshQuery middle(TriMesh{fr[1].surface_vertices, model.muscles[1].surface_triangles});
      const MeshQuery side(TriMesh{fr[m].surface_vertices, model.muscles[m].surface_triangles});
      EXPECT_LE(calc_deepest_vertex_inside(fr[m].surface_vertices, middle), 5e-4) << "bundle " << m << ", frame " << f;
      EXPECT_LE(calc_deepest_vertex_inside(fr[1].surface_vertices, side), 5e-4) << "bundle " << m << ", frame " << f;
    }
    floor_contacts = fr[1].bone_contacts;
  }
  EXPECT_GT(floor_contacts, 0);  // the middle bundle lies on the floor
  // it made its room upwards
  EXPECT_GT(solver.get_muscles()[1].particles.col(1).maxCoeff(), rest_top + 1e-3);
}

// Option surface_bending: one spring per surface edge between the two vertices opposite it. On
// the 12 x 20 loft of a box bundle (a closed surface: E = 3F/2 edges) that adds one spring for
// almost every edge (none where the opposite vertices already share an edge, as in the end caps'
// fans), and springs at rest length keep a rigid motion rigid (1e-9 m) with the volume exact.
TEST(FibresFirst, SurfaceBendingSpringsKeepARigidMotionRigid) {
  const double L = 0.08;
  const EndBones bones(L);
  const FibreBundleSpec spec = make_boxed_bundle_spec(L);
  FibresFirstOptions o = tight_options();
  o.surface_particles = true;
  const FibresFirstModel plain = build_fibres_first_model({spec}, bones.list(), o);
  o.surface_bending = true;
  const FibresFirstModel model = build_fibres_first_model({spec}, bones.list(), o);
  const long edges = 3 * model.muscles[0].surface_triangles.rows() / 2;
  const long added = static_cast<long>(model.springs.size()) - static_cast<long>(plain.springs.size());
  EXPECT_GT(added, 9 * edges / 10);
  EXPECT_LE(added, edges);
  FibresFirstSolver solver(model);
  Transform T = Transform::Identity();
  T.translate(Vec3(0.01, -0.02, 0.03)).rotate(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()));
  solver.calc_frame({{T, T}});
  const FibreBundle& m = model.muscles[0];
  const Points3 rest_surface = model.rest.bottomRows(m.num_surface_particles);
  const Points3 expected = (rest_surface * T.linear().transpose()).rowwise() + T.translation().transpose();
  EXPECT_LT((solver.get_muscles()[0].surface_vertices - expected).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_LT(solver.get_muscles()[0].relative_volume_error, 1e-12);
}

// Ring frames (option surface_frame_stiffness): each loft ring is pulled towards its rest ring
// moved by the best-fit rigid motion of its anchoring fibre particles. Measured independently
// here (Procrustes by an SVD): a rigid motion stays rigid with the term on; with the top bone
// twisted by 2.8 rad about the bundle's axis, a stiff term keeps every ring within 1.5 mm of its
// anchors' rigid copy of the rest ring, where the loft without it strays more than four times as
// far (at 0.6 rad the two differ by less than 2x: a mild twist is followed by the anchor springs
// alone), and the volume holds.
double calc_ring_frame_deviation(const FibresFirstModel& model, const Points3& x) {
  const FibreBundle& m = model.muscles[0];
  const int K = model.options.surface_ring_points;
  const int s0 = m.first_particle + m.num_fibres * model.options.particles_per_fibre;
  double worst = 0.0;
  for (std::size_t r = 0; r + 1 < m.ring_frame_start.size(); ++r) {
    Points3 a(m.ring_frame_start[r + 1] - m.ring_frame_start[r], 3), b(a.rows(), 3);
    for (Eigen::Index k = 0; k < a.rows(); ++k) {
      a.row(k) = model.rest.row(m.ring_frame_particle[m.ring_frame_start[r] + k]);
      b.row(k) = x.row(m.ring_frame_particle[m.ring_frame_start[r] + k]);
    }
    const Vec3 ca = a.colwise().mean().transpose(), cb = b.colwise().mean().transpose();
    const Mat3 H = (b.rowwise() - cb.transpose()).transpose() * (a.rowwise() - ca.transpose());
    const Eigen::JacobiSVD<Mat3> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Mat3 D = Mat3::Identity();
    D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0 ? -1.0 : 1.0;
    const Mat3 R = svd.matrixU() * D * svd.matrixV().transpose();
    for (int v = static_cast<int>(r) * K; v < (static_cast<int>(r) + 1) * K; ++v) {
      const Vec3 target = cb + R * (model.rest.row(s0 + v).transpose() - ca);
      worst = std::max(worst, (x.row(s0 + v).transpose() - target).norm());
    }
  }
  return worst;
}

TEST(FibresFirst, RingFramesHoldTheLoftToItsInteriorsRotation) {
  const double L = 0.08;
  const EndBones bones(L);
  const FibreBundleSpec spec = make_boxed_bundle_spec(L);
  FibresFirstOptions o = tight_options();
  o.surface_particles = true;
  o.surface_frame_stiffness = 0.0;
  const FibresFirstModel plain = build_fibres_first_model({spec}, bones.list(), o);
  o.surface_frame_stiffness = 4e4;
  const FibresFirstModel model = build_fibres_first_model({spec}, bones.list(), o);
  const FibreBundle& m = model.muscles[0];
  ASSERT_EQ(static_cast<int>(m.ring_frame_start.size()), o.surface_rings + 1);
  for (int r = 0; r < o.surface_rings; ++r) EXPECT_GE(m.ring_frame_start[r + 1] - m.ring_frame_start[r], 6);
  {
    FibresFirstSolver solver(model);
    Transform T = Transform::Identity();
    T.translate(Vec3(0.01, -0.02, 0.03)).rotate(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()));
    solver.calc_frame({{T, T}});
    const Points3 expected = (model.rest * T.linear().transpose()).rowwise() + T.translation().transpose();
    EXPECT_LT((solver.get_particles() - expected).cwiseAbs().maxCoeff(), 1e-9);
  }
  Transform twist = Transform::Identity();
  twist.rotate(Eigen::AngleAxisd(2.8, Vec3::UnitZ()));
  FibresFirstSolver with(model), without(plain);
  with.calc_frame({{Transform::Identity(), twist}});
  without.calc_frame({{Transform::Identity(), twist}});
  const double dev_with = calc_ring_frame_deviation(model, with.get_particles());
  const double dev_without = calc_ring_frame_deviation(plain, without.get_particles());
  // measured: 0.73 mm with the term, 6.0 mm without (the loft's rings turn against the interior)
  EXPECT_LT(dev_with, 1.5e-3);
  EXPECT_GT(dev_without, 4.0 * dev_with);
  EXPECT_LT(with.get_muscles()[0].relative_volume_error, o.volume_tolerance);
}

// Ring frames of a belly whose fibres converge to a point at its origin (as gait2392's generated
// bellies at their tendons): the end ring's vertices all find their anchors in that cluster,
// whose rotation is undetermined, so the ring takes its neighbours' anchors as well, until its
// set spreads across at least a fifth of the ring's RMS radius (or holds every anchor). Checked
// against the anchors read from the model's springs; then a twisted and stretched frame solves
// with the volume held (fitting the cluster alone diverged on gait2392).
TEST(FibresFirst, RingFramesOfAConvergingBellyReachPastItsTendonCluster) {
  const double L = 0.08;
  const EndBones bones(L);
  FibreBundleSpec spec = make_boxed_bundle_spec(L);
  for (Points3& f : spec.fibres)
    for (Eigen::Index k = 0; k < f.rows(); ++k) {
      const double t = f(k, 2) / L;
      f(k, 0) *= 0.02 + 0.98 * t;
      f(k, 1) *= 0.02 + 0.98 * t;
    }
  FibresFirstOptions o = tight_options();
  o.surface_particles = true;
  const FibresFirstModel model = build_fibres_first_model({spec}, bones.list(), o);
  const FibreBundle& m = model.muscles[0];
  const int K = o.surface_ring_points, R = o.surface_rings;
  const int s0 = m.first_particle + m.num_fibres * o.particles_per_fibre;
  ASSERT_EQ(static_cast<int>(m.ring_frame_start.size()), R + 1);
  std::vector<std::set<int>> own(R);
  std::set<int> all;
  for (int sp = model.first_spring[0]; sp < model.first_spring[1]; ++sp) {
    const Spring& s = model.springs[sp];
    if (s.a >= s0 && s.b < s0) {
      own[(s.a - s0) / K].insert(s.b);
      all.insert(s.b);
    }
  }
  auto second_spread = [&](const std::set<int>& set) {
    Vec3 c = Vec3::Zero();
    for (int p : set) c += model.rest.row(p).transpose();
    c /= static_cast<double>(set.size());
    Mat3 H = Mat3::Zero();
    for (int p : set) H += (model.rest.row(p).transpose() - c) * (model.rest.row(p) - c.transpose());
    const Vec3 e = Eigen::SelfAdjointEigenSolver<Mat3>(H / static_cast<double>(set.size())).eigenvalues();
    return std::sqrt(std::max(0.0, e[1]));
  };
  for (int r = 0; r < R; ++r) {
    SCOPED_TRACE(r);
    const std::set<int> set(m.ring_frame_particle.begin() + m.ring_frame_start[r],
                            m.ring_frame_particle.begin() + m.ring_frame_start[r + 1]);
    EXPECT_TRUE(std::includes(set.begin(), set.end(), own[r].begin(), own[r].end()));
    const auto ring = model.rest.middleRows(s0 + r * K, K);
    const double radius = std::sqrt((ring.rowwise() - ring.colwise().mean()).squaredNorm() / K);
    EXPECT_TRUE(second_spread(set) >= 0.2 * radius || set == all) << second_spread(set) << " " << radius;
  }
  // the end ring's own anchors are the cluster: its set had to grow
  EXPECT_LT(second_spread(own[0]), 0.2 * std::sqrt((model.rest.middleRows(s0, K).rowwise() -
                                                    model.rest.middleRows(s0, K).colwise().mean()).squaredNorm() / K));
  EXPECT_GT(m.ring_frame_start[1] - m.ring_frame_start[0], static_cast<int>(own[0].size()));
  Transform T = Transform::Identity();
  T.translate(Vec3(0.0, 0.0, 0.01)).rotate(Eigen::AngleAxisd(0.6, Vec3::UnitZ()));
  FibresFirstSolver solver(model);
  solver.calc_frame({{Transform::Identity(), T}});
  EXPECT_TRUE(solver.get_particles().allFinite());
  EXPECT_LT(solver.get_muscles()[0].relative_volume_error, o.volume_tolerance);
}

// A bone contact kept across frames must not outlive its bone's neighbourhood: with display
// surface separation (surface particles), a block pushed 4 mm into a bundle's side holds its
// surface particles by bone contacts (kept from frame to frame); then the block jumps 40 mm along
// its face, clear of the bundle. The contacts' target points moved with the block, 40 mm from
// their particles: they are re-evaluated exactly, found outside the block and released. (Before,
// the iterations pulled those particles toward the far targets, 100 x stiffer than the springs,
// and the bundle was dragged 40 mm along with the block; on gait2392 such a stale contact's plane
// made the final projection move a particle by 49 mm.)
TEST(FibresFirst, BoneContactsFarFromTheirBoneAreReleased) {
  const double L = 0.1;
  const EndBones ends(L);
  const MeshQuery block(moved(make_box(Vec3(0.01, 0.03, 0.01)), Vec3(0.016, 0.0, L / 2)));
  const auto [a, b] = make_pushed_and_aside(L);
  FibresFirstOptions o;
  o.surface_particles = true;
  o.separate_surfaces = true;
  const FibresFirstModel model = build_fibres_first_model({a, b}, {&ends.bottom, &ends.top, &block}, o);
  FibresFirstSolver solver(model);
  const Transform I = Transform::Identity();
  for (int k = 1; k <= 4; ++k) solver.calc_frame({{I, I, translation(Vec3(-0.001 * k, 0, 0))}});
  ASSERT_GT(solver.get_muscles()[0].bone_contacts, 0);
  // the surface was really pushed in where the block is (its face at x = 2 mm, the rest surface
  // at 5.5 mm)
  {
    const Points3& S = solver.get_muscles()[0].surface_vertices;
    double facing = -1.0;
    for (Eigen::Index v = 0; v < S.rows(); ++v)
      if (std::abs(S(v, 2) - L / 2) < 0.008 && std::abs(S(v, 1)) < 0.003) facing = std::max(facing, S(v, 0));
    EXPECT_GT(facing, 0.0);
    EXPECT_LT(facing, 0.0025);
  }
  const Transform away = translation(Vec3(-0.004, 0.04, 0));
  for (int k = 0; k < 2; ++k) solver.calc_frame({{I, I, away}});
  const FibreBundleFrame& fr = solver.get_muscles()[0];
  EXPECT_EQ(fr.bone_contacts, 0);
  EXPECT_LT(fr.relative_volume_error, o.volume_tolerance);
  // not dragged along: no particle moved more than 1 mm along the block's 40 mm jump (with the
  // contacts kept, all of the held particles followed it by 40 mm)
  const FibreBundle& m = model.muscles[0];
  const Points3 rest = model.rest.middleRows(m.first_particle, m.num_particles);
  EXPECT_LT((fr.particles - rest).col(1).cwiseAbs().maxCoeff(), 1e-3);
}

// A corner of a bundle pressed by two blocks at once (one moving in -x, one in -y): the corner
// particles need two bone contacts; none ends inside either block.
TEST(FibresFirst, ParticleNearTwoBonesStaysOutOfBoth) {
  const double L = 0.1;
  const EndBones ends(L);
  const MeshQuery bx(moved(make_box(Vec3(0.005, 0.005, 0.01)), Vec3(0.0095, 0.0, L / 2)));
  const MeshQuery by(moved(make_box(Vec3(0.005, 0.005, 0.01)), Vec3(0.0, 0.0095, L / 2)));
  const FibreBundleSpec spec{"cornered", make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), L, 3, 3, 0.004), 0, 1};
  FibresFirstOptions o;
  const FibresFirstModel model = build_fibres_first_model({spec}, {&ends.bottom, &ends.top, &bx, &by}, o);
  FibresFirstSolver solver(model);
  for (int k = 1; k <= 4; ++k) {  // faces from 4.5 mm (0.5 mm clear of the corner) to 2.5 mm
    const Transform Tx = translation(Vec3(-0.0005 * k, 0, 0)), Ty = translation(Vec3(0, -0.0005 * k, 0));
    solver.calc_frame({{Transform::Identity(), Transform::Identity(), Tx, Ty}});
    const FibreBundleFrame& fr = solver.get_muscles()[0];
    EXPECT_LE(fr.max_bone_penetration_m, 1e-9) << "frame " << k;
    const Points3& x = solver.get_particles();
    for (int p = 0; p < x.rows(); ++p) {
      const Vec3 xp = x.row(p).transpose();
      EXPECT_FALSE(bx.calc_is_inside(Tx.inverse() * xp)) << "particle " << p << " frame " << k;
      EXPECT_FALSE(by.calc_is_inside(Ty.inverse() * xp)) << "particle " << p << " frame " << k;
    }
  }
  // the middle particle of the corner fibre (x = y = +4 mm at rest) was pushed past both faces,
  // which end at x = 2.5 mm and y = 2.5 mm
  const int P = o.particles_per_fibre;
  const Vec3 corner = solver.get_particles().row(8 * P + P / 2).transpose();
  EXPECT_LT(corner.x(), 0.0025);
  EXPECT_LT(corner.y(), 0.0025);
}

// Stretching a bundle by 25 %: the volume stays within the tolerance with the volume term and
// drops by several per cent without it.
TEST(FibresFirst, VolumeHoldsUnderStretch) {
  const double L = 0.08;
  const EndBones bones(L);
  const FibreBundleSpec spec{"stretched", make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), L, 4, 4, 0.004), 0, 1};
  double error_with = 0.0, error_without = 0.0;
  for (bool hold : {true, false}) {
    FibresFirstOptions o;
    o.hold_volume = hold;
    const FibresFirstModel model = build_fibres_first_model({spec}, bones.list(), o);
    FibresFirstSolver solver(model);
    for (int k = 1; k <= 5; ++k)
      solver.calc_frame({{Transform::Identity(), translation(Vec3(0, 0, 0.004 * k))}});
    const FibreBundleFrame& fr = solver.get_muscles()[0];
    (hold ? error_with : error_without) = fr.relative_volume_error;
    if (hold) {
      EXPECT_LT(fr.relative_volume_error, 5e-3);
      EXPECT_LT(fr.relative_volume_error, o.volume_tolerance);
    }
  }
  EXPECT_LT(error_with, 1e-3);
  EXPECT_GT(error_without, 0.02);
}

template <class F>
Error catch_error(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e;
  }
  ADD_FAILURE() << "no fascicle::Error thrown";
  return Error(ErrorKind::internal, "none");
}

// A crescent (annulus sector: radii 9-17 mm, 210 degrees, opening towards -x) extruded along z
// over [0, L], as a closed outward mesh; and straight fibres along z on a 3 x 9 polar grid inside.
TriMesh make_crescent_prism(double L, int n) {
  const double r0 = 0.009, r1 = 0.017, half = 105.0 * M_PI / 180.0;
  Points3 V(4 * (n + 1), 3);
  for (int j = 0; j <= n; ++j) {
    const double a = -half + 2.0 * half * j / n;
    V.row(j) << r1 * std::cos(a), r1 * std::sin(a), 0.0;              // outer, bottom
    V.row(n + 1 + j) << r0 * std::cos(a), r0 * std::sin(a), 0.0;      // inner, bottom
    V.row(2 * (n + 1) + j) << r1 * std::cos(a), r1 * std::sin(a), L;  // outer, top
    V.row(3 * (n + 1) + j) << r0 * std::cos(a), r0 * std::sin(a), L;  // inner, top
  }
  std::vector<Eigen::Vector3i> t;
  auto quad = [&](int a, int b, int c, int d) { t.emplace_back(a, b, c); t.emplace_back(a, c, d); };
  const int ob = 0, ib = n + 1, ot = 2 * (n + 1), it = 3 * (n + 1);
  for (int j = 0; j < n; ++j) {
    quad(ob + j, ob + j + 1, ot + j + 1, ot + j);      // outer wall
    quad(ib + j + 1, ib + j, it + j, it + j + 1);      // inner wall
    quad(ob + j + 1, ob + j, ib + j, ib + j + 1);      // bottom
    quad(ot + j, ot + j + 1, it + j + 1, it + j);      // top
  }
  quad(ob, ot, it, ib);  // end walls
  quad(ob + n, ib + n, it + n, ot + n);
  TriMesh m{V, Triangles(static_cast<Eigen::Index>(t.size()), 3)};
  for (std::size_t k = 0; k < t.size(); ++k) m.F.row(static_cast<Eigen::Index>(k)) = t[k].transpose();
  return m;
}

std::vector<Points3> make_crescent_fibres(double L) {
  std::vector<Points3> fibres;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 9; ++j) {
      const double r = 0.010 + 0.003 * i, a = (-95.0 + 190.0 * j / 8) * M_PI / 180.0;
      Points3 f(5, 3);
      for (int k = 0; k < 5; ++k) f.row(k) << r * std::cos(a), r * std::sin(a), L * k / 4;
      fibres.push_back(f);
    }
  return fibres;
}

// With a rest surface the display surface is its loft carried by the particles: concave where the
// surface is (the crescent's hollow is outside it, which the convex-hull tube covers), outward,
// closed, without self-intersections; the vertex weights reproduce the rest pose and rigid
// motions; the volume it encloses is held under stretch.
TEST(FibresFirst, LoftSurfaceFollowsAConcaveRestSurface) {
  const double L = 0.08;
  const EndBones bones(L);
  FibreBundleSpec spec{"crescent", make_crescent_fibres(L), 0, 1};
  const FibresFirstModel hull_model = build_fibres_first_model({spec}, bones.list(), tight_options());
  spec.rest_surface = make_crescent_prism(L, 40);
  const MeshReport report = validate_mesh(spec.rest_surface);
  ASSERT_TRUE(report.is_solid()) << fmt::format("{}", fmt::join(report.list_problems(), "; "));
  const FibresFirstModel model = build_fibres_first_model({spec}, bones.list(), tight_options());
  const FibreBundle& m = model.muscles[0];
  ASSERT_TRUE(m.surface_from_rest_mesh);
  EXPECT_FALSE(hull_model.muscles[0].surface_from_rest_mesh);
  FibresFirstSolver solver(model);
  solver.calc_frame({});
  const TriMesh rest_surface{solver.get_muscles()[0].surface_vertices, m.surface_triangles};
  EXPECT_EQ(rest_surface.V.rows(), model.options.surface_rings * model.options.surface_ring_points);
  EXPECT_TRUE(calc_self_intersections(rest_surface).empty());
  // vertices at rest lie on the crescent's surface
  const MeshQuery crescent(spec.rest_surface);
  for (Eigen::Index v = 0; v < rest_surface.V.rows(); ++v)
    EXPECT_LT(std::abs(crescent.calc_signed_distance(Vec3(rest_surface.V.row(v).transpose()))), 1e-12) << v;
  // outward and concave: the hollow's centre is outside, the crescent's middle inside; the hull
  // tube covers the hollow
  const MeshQuery loft(rest_surface);
  EXPECT_FALSE(loft.calc_is_inside(Vec3(0.0, 0.0, L / 2)));
  EXPECT_TRUE(loft.calc_is_inside(Vec3(0.013, 0.0, L / 2)));
  EXPECT_TRUE(loft.calc_is_inside(Vec3(-0.003, 0.012, L / 2)));
  FibresFirstSolver hull_solver(hull_model);
  hull_solver.calc_frame({});
  const MeshQuery hull(TriMesh{hull_solver.get_muscles()[0].surface_vertices, hull_model.muscles[0].surface_triangles});
  EXPECT_TRUE(hull.calc_is_inside(Vec3(0.0, 0.0, L / 2)));
  // volume: the 24-gon section (area between that of the inscribed polygon and the crescent's
  // 381 mm^2) over 94 % of the length
  const double crescent_area = 0.5 * (0.017 * 0.017 - 0.009 * 0.009) * 210.0 * M_PI / 180.0;
  EXPECT_NEAR(m.rest_volume_m3 / (crescent_area * 0.94 * L), 1.0, 0.05);
  // a rigid motion of both bones moves the surface rigidly
  Transform T = Transform::Identity();
  T.translate(Vec3(0.01, -0.02, 0.03)).rotate(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()));
  FibresFirstSolver moved_solver(model);
  moved_solver.calc_frame({{T, T}});
  const Points3 expected = (rest_surface.V * T.linear().transpose()).rowwise() + T.translation().transpose();
  EXPECT_LT((moved_solver.get_muscles()[0].surface_vertices - expected).cwiseAbs().maxCoeff(), 1e-9);
  // stretch by 20 %: the loft's volume is held
  for (int k = 1; k <= 4; ++k) {
    solver.calc_frame({{Transform::Identity(), translation(Vec3(0, 0, 0.004 * k))}});
    EXPECT_LT(solver.get_muscles()[0].relative_volume_error, 1e-6) << k;
    EXPECT_EQ(solver.get_muscles()[0].max_bone_penetration_m, 0.0);
  }
}

TEST(FibresFirst, BadInput) {
  const EndBones bones(0.08);
  const auto fibres = make_bundle(Vec3::Zero(), Vec3::UnitZ(), Vec3::UnitX(), 0.08, 3, 3, 0.004);
  // a muscle whose fibres reach no bone
  Error e = catch_error([&] { build_fibres_first_model({{"floating", fibres, -1, -1}}, bones.list()); });
  EXPECT_EQ(e.kind(), ErrorKind::bad_input);
  EXPECT_NE(std::string(e.what()).find("floating"), std::string::npos) << e.what();
  // no bone at all, even with an action line to carry the ends along: nothing to move them with
  FibreBundleSpec boneless{"boneless", fibres, -1, -1};
  boneless.action_line = Points3(2, 3);
  boneless.action_line << 0, 0, 0, 0, 0, 0.08;
  e = catch_error([&] { build_fibres_first_model({boneless}, bones.list()); });
  EXPECT_EQ(e.kind(), ErrorKind::bad_input);
  EXPECT_NE(std::string(e.what()).find("boneless"), std::string::npos) << e.what();
  FibresFirstOptions near;
  near.end_attachment_distance_m = 0.001;
  const auto far = make_bundle(Vec3(0, 0, 0.01), Vec3::UnitZ(), Vec3::UnitX(), 0.05, 3, 3, 0.004);
  e = catch_error([&] { build_fibres_first_model({{"short", far, 0, 1}}, bones.list(), near); });
  EXPECT_EQ(e.kind(), ErrorKind::bad_input);
  EXPECT_NE(std::string(e.what()).find("short"), std::string::npos) << e.what();
  // stiffness <= 0
  for (double k : {0.0, -1.0, std::nan("")}) {
    FibresFirstOptions o;
    o.across_stiffness = k;
    e = catch_error([&] { build_fibres_first_model({{"m", fibres, 0, 1}}, bones.list(), o); });
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("stiffness"), std::string::npos) << e.what();
  }
  // bone index out of range, empty muscle, degenerate fibre
  e = catch_error([&] { build_fibres_first_model({{"m", fibres, 0, 5}}, bones.list()); });
  EXPECT_EQ(e.kind(), ErrorKind::bad_input);
  e = catch_error([&] { build_fibres_first_model({{"empty", {}, 0, 1}}, bones.list()); });
  EXPECT_NE(std::string(e.what()).find("empty"), std::string::npos);
  // wrong number of bone motions, non-finite motion
  const FibresFirstModel model = build_fibres_first_model({{"m", fibres, 0, 1}}, bones.list());
  FibresFirstSolver solver(model);
  e = catch_error([&] { solver.calc_frame({{Transform::Identity()}}); });
  EXPECT_EQ(e.kind(), ErrorKind::bad_input);
  Transform nan = Transform::Identity();
  nan.translation().x() = std::nan("");
  e = catch_error([&] { solver.calc_frame({{Transform::Identity(), nan}}); });
  EXPECT_EQ(e.kind(), ErrorKind::bad_input);
  // divergence: springs so stiff that the system overflows -> numerical error naming muscle and frame
  FibresFirstOptions huge;
  huge.along_stiffness = 1e308;
  huge.across_stiffness = 1e308;
  const FibresFirstModel bad = build_fibres_first_model({{"overflowing", fibres, 0, 1}}, bones.list(), huge);
  FibresFirstSolver diverging(bad);
  e = catch_error([&] { diverging.calc_frame({{Transform::Identity(), translation(Vec3(0, 0, 0.01))}}); });
  EXPECT_EQ(e.kind(), ErrorKind::numerical);
  EXPECT_NE(std::string(e.what()).find("overflowing"), std::string::npos) << e.what();
  EXPECT_NE(std::string(e.what()).find("frame 0"), std::string::npos) << e.what();
  // the failed frame left the previous (rest) state in place
  EXPECT_EQ(diverging.get_particles(), bad.rest);
}

}  // namespace
}  // namespace fascicle
