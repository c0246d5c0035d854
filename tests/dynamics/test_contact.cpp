// Contact tests: sliding on a bone plane, muscles pushing apart.
#include "fascicle/bspline/lattice.hpp"
#include "fascicle/dynamics/contact.hpp"
#include "fascicle/geometry/primitives.hpp"

#include <gtest/gtest.h>

#include <memory>

namespace fascicle {
namespace {

BSplineSolid make_small_box(const Vec3& lo, const Vec3& hi) {
  LatticeDesign d = make_cubical_lattice(lo, hi, {2, 2, 2}, {3, 3, 4});
  d.solid.name = "box";
  return d.solid;
}

// A box dropped on an inclined-gravity floor: it lands, slides freely along the plane (point-on-
// plane contact is frictionless: x = a t²/2) and never crosses it; the reaction carries its weight.
TEST(SolidContact, PressedOnBonePlaneSlidesWithoutCrossing) {
  const BSplineSolid box = make_small_box(Vec3(0, 0, 0.0005), Vec3(0.02, 0.02, 0.0405));
  SolidDynamicsSpec spec;
  spec.gravity_m_s2 = Vec3(2.0, 0.0, -9.81);
  spec.ground.c1_Pa = 5e3;
  spec.rayleigh_beta_s = 0.005;  // stiffness-proportional: does not damp rigid motion
  ContactPlaneSpec floor;
  floor.name = "tibia";
  floor.body = 0;
  floor.point_rest = Vec3(0, 0, 0);
  floor.normal_rest = Vec3::UnitZ();
  spec.contact_planes.push_back(floor);
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  SolidDynamicsSolver solver(m);
  StepInputs in;
  in.X_now_rest = {Transform::Identity()};
  const double h = 0.002;
  double worst_gap = 0.0;
  for (int k = 0; k < 100; ++k) {
    solver.step(h, in);
    const Points3& P = solver.get_state().P;
    for (const auto& cs : m->contact_samples) {
      double z = 0.0;
      for (std::size_t a = 0; a < cs.index.size(); ++a) z += cs.N[a] * P(cs.index[a], 2);
      worst_gap = std::min(worst_gap, z);
    }
  }
  const SolidMetrics mm = solver.calc_metrics(in);
  const double t = solver.get_state().time_s;
  const Vec3 com0 = (m->lumped_mass.transpose() * box.P).transpose() / m->mass_kg;
  // Frictionless sliding: the tangential motion is free fall along x.
  EXPECT_NEAR(mm.centre_of_mass_m.x() - com0.x(), 0.5 * 2.0 * t * t, 0.03 * 0.5 * 2.0 * t * t);
  EXPECT_GT(worst_gap, -2e-4) << "penetration (m)";
  // At rest on the floor the reaction (force of the solid on the plane) carries the weight.
  EXPECT_NEAR(mm.contact_reaction_N.z(), -m->mass_kg * 9.81, 0.15 * m->mass_kg * 9.81);
  EXPECT_NEAR(mm.contact_reaction_N.x(), 0.0, 1e-9);
  EXPECT_NEAR(mm.volume_error, 0.0, 1e-6);
}

// The same on a bone mesh (a slab posed by its body transform): the contact is the tangent plane at
// the closest surface point.
TEST(SolidContact, SlidesOnBoneMeshWithoutCrossing) {
  const BSplineSolid box = make_small_box(Vec3(0, 0, 0.0005), Vec3(0.02, 0.02, 0.0405));
  SolidDynamicsSpec spec;
  spec.gravity_m_s2 = Vec3(2.0, 0.0, -9.81);
  spec.ground.c1_Pa = 5e3;
  spec.rayleigh_beta_s = 0.005;
  BoneContactSpec bone;
  bone.name = "slab";
  bone.body = 0;
  bone.mesh_rest = make_box(Vec3(0.06, 0.06, 0.01));  // centred at the origin in its rest frame
  spec.contact_bones.push_back(bone);
  auto m = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(box, spec));
  SolidDynamicsSolver solver(m);
  StepInputs in;
  Transform X = Transform::Identity();
  X.translate(Vec3(0.01, 0.01, -0.01));  // slab top at z = 0
  in.X_now_rest = {X};
  double worst = 0.0;
  for (int k = 0; k < 100; ++k) {
    solver.step(0.002, in);
    const Points3& P = solver.get_state().P;
    for (const auto& cs : m->contact_samples) {
      double z = 0.0;
      for (std::size_t a = 0; a < cs.index.size(); ++a) z += cs.N[a] * P(cs.index[a], 2);
      worst = std::min(worst, z);
    }
  }
  const SolidMetrics mm = solver.calc_metrics(in);
  const double t = solver.get_state().time_s;
  const Vec3 com0 = (m->lumped_mass.transpose() * box.P).transpose() / m->mass_kg;
  EXPECT_NEAR(mm.centre_of_mass_m.x() - com0.x(), 0.5 * 2.0 * t * t, 0.03 * 0.5 * 2.0 * t * t);
  EXPECT_GT(worst, -2e-4) << "penetration into the bone (m)";
  EXPECT_NEAR(mm.contact_reaction_N.z(), -m->mass_kg * 9.81, 0.15 * m->mass_kg * 9.81)
      << "worst " << worst << " min z now " << solver.get_state().P.col(2).minCoeff();
}

TEST(SolidContact, TwoSolidsPushedTogetherSeparateAndDoNotPull) {
  const BSplineSolid left = make_small_box(Vec3(0, 0, 0), Vec3(0.02, 0.02, 0.04));
  const BSplineSolid right = make_small_box(Vec3(0.017, 0.0, 0.0), Vec3(0.037, 0.02, 0.04));
  SolidDynamicsSpec spec;
  spec.gravity_m_s2.setZero();
  spec.ground.c1_Pa = 5e3;
  spec.rayleigh_alpha_1_s = 5.0;
  auto ma = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(left, spec));
  auto mb = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(right, spec));
  SolidDynamicsSolver a(ma), b(mb);
  const double k = 200.0;
  int contacts_first = -1;
  for (int step = 0; step < 60; ++step) {
    const auto pairs = find_contact_pairs({a.get_state().P, b.get_state().P}, {{0, 1}});
    MuscleContactResult c;
    c.forces_a = Points3::Zero(a.get_state().P.rows(), 3);
    c.forces_b = Points3::Zero(b.get_state().P.rows(), 3);
    if (!pairs.empty()) c = calc_muscle_contact(*ma, a.get_state().P, *mb, b.get_state().P, k);
    if (contacts_first < 0) contacts_first = c.num_contacts;
    // Push only: the left solid is pushed to −x, never pulled to +x.
    EXPECT_LE(c.force_on_a_N.x(), 1e-12) << "step " << step;
    EXPECT_NEAR((c.forces_a.colwise().sum() + c.forces_b.colwise().sum()).norm(), 0.0, 1e-9);
    StepInputs ia, ib;
    ia.external_forces = c.forces_a;
    ib.external_forces = c.forces_b;
    a.step(0.002, ia);
    b.step(0.002, ib);
  }
  EXPECT_GT(contacts_first, 0);
  const MuscleContactResult end = calc_muscle_contact(*ma, a.get_state().P, *mb, b.get_state().P, k);
  EXPECT_EQ(end.num_contacts, 0);
  const double right_face = a.get_state().P.col(0).maxCoeff();
  const double left_face = b.get_state().P.col(0).minCoeff();
  EXPECT_GT(left_face, right_face - 1e-4);  // apart (control hulls no longer overlap in x)
  const Vec3 va = (ma->lumped_mass.transpose() * a.get_state().V).transpose();
  EXPECT_LT(va.x(), 0.0);  // moving apart
}

}  // namespace
}  // namespace fascicle
