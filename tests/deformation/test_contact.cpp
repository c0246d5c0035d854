// Bone contacts: a box bone pressed into a cylinder muscle, with and without rest-pose intersection.
#include "fascicle/deformation/surface_first.hpp"
#include "fascicle/geometry/primitives.hpp"

#include <gtest/gtest.h>

namespace fascicle {
namespace {

struct PressScene {
  TriMesh muscle = make_cylinder(0.02, 0.2, 48, 60);
  std::vector<SurfaceAttachment> areas{{"origin", {}}, {"insertion", {}}};
  Points3 line;
  PressScene() {
    for (int i = 0; i < muscle.V.rows(); ++i) {
      if (muscle.V(i, 2) < -0.09) areas[0].vertices.push_back(i);
      if (muscle.V(i, 2) > 0.09) areas[1].vertices.push_back(i);
    }
    line.resize(2, 3);
    line << 0, 0, -0.1, 0, 0, 0.1;
  }
  SurfaceFrameInput frame(const Transform& bone_motion) const {
    SurfaceFrameInput in;
    in.action_line = line;
    in.attachment_motions = {Transform::Identity(), Transform::Identity()};
    in.bone_motions = {bone_motion};
    return in;
  }
};

// A box bone with its -x face at x = face_x, 40 mm deep in x and 60 mm tall, centred at z = 0.
TriMesh make_box_bone(double face_x) {
  TriMesh box = make_box(Vec3(0.02, 0.03, 0.03));
  box.V.col(0).array() += face_x + 0.02;
  return box;
}

Transform translate_x(double dx) {
  Transform T = Transform::Identity();
  T.translate(Vec3(dx, 0, 0));
  return T;
}

TEST(SurfaceFirstContact, BoxPressedIntoMuscleEndsOutside) {
  const PressScene s;
  const MeshQuery bone(make_box_bone(0.025));  // 5 mm gap at rest
  const SurfaceBinding b = bind_surface(s.muscle, s.line, s.areas, {&bone});
  EXPECT_EQ(b.rest_bone_depth[0].maxCoeff(), 0.0);
  SurfaceFirstSolver solver(b, {&bone});
  // the bone moves 15 mm towards the muscle in 5 frames: 10 mm into the 20 mm radius at the end
  for (int frame = 1; frame <= 5; ++frame) {
    const Transform T = translate_x(-0.003 * frame);
    const Points3& X = solver.calc_frame(s.frame(T));
    const SurfaceFrameInfo& info = solver.get_info();
    const PenetrationInfo p = calc_bone_penetration(X, bone, T, {}, b.fixed_vertices);
    EXPECT_LE(p.max_depth_m, 0.5e-3) << "frame " << frame;
    EXPECT_NEAR(info.max_penetration_beyond_rest_m, p.max_depth_beyond_rest_m, 1e-12);
    EXPECT_LT(info.relative_volume_error, 1e-10) << "frame " << frame;
    if (frame >= 3) {
      EXPECT_GT(info.active_contacts, 0);
    }
  }
  // the muscle was pushed: some vertices now lie at x < -radius (bulging away from the bone)
  const PenetrationInfo p = calc_bone_penetration(solver.get_vertices(), bone, translate_x(-0.015));
  EXPECT_EQ(p.vertices_beyond_rest, 0);
  // without contacts the same frame leaves many vertices deep inside the bone
  const SurfaceBinding free_b = bind_surface(s.muscle, s.line, s.areas, {});
  SurfaceFrameInput in = s.frame(translate_x(-0.015));
  in.bone_motions.clear();
  const Points3 Xfree = deform_surface(free_b, {}, in);
  EXPECT_GT(calc_bone_penetration(Xfree, bone, translate_x(-0.015)).max_depth_m, 5e-3);
}

TEST(SurfaceFirstContact, IntersectingAtRestKeepsRestDepthOnly) {
  const PressScene s;
  const MeshQuery bone(make_box_bone(0.015));  // 5 mm into the muscle at rest
  const SurfaceBinding b = bind_surface(s.muscle, s.line, s.areas, {&bone});
  EXPECT_NEAR(b.rest_bone_depth[0].maxCoeff(), 0.005, 1e-12);
  SurfaceFirstSolver solver(b, {&bone});
  // the rest pose is a solution: nothing moves, no contact is made
  const Points3& X0 = solver.calc_frame(s.frame(Transform::Identity()));
  EXPECT_LT((X0 - s.muscle.V).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_EQ(solver.get_info().active_contacts, 0);
  // pressing 8 mm further: nothing deeper than at rest (beyond 0.5 mm), volume held
  for (int frame = 1; frame <= 4; ++frame) {
    const Transform T = translate_x(-0.002 * frame);
    const Points3& X = solver.calc_frame(s.frame(T));
    const PenetrationInfo p = calc_bone_penetration(X, bone, T, b.rest_bone_depth[0], b.fixed_vertices);
    EXPECT_LE(p.max_depth_beyond_rest_m, 0.5e-3) << "frame " << frame;
    EXPECT_GT(p.vertices_inside, 0);  // the rest contact region stays inside, as at rest
    EXPECT_LT(solver.get_info().relative_volume_error, 1e-10);
  }
  // moving the bone back releases the contacts and restores the rest shape
  solver.calc_frame(s.frame(Transform::Identity()));
  EXPECT_EQ(solver.get_info().active_contacts, 0);
  EXPECT_LT((solver.get_vertices() - s.muscle.V).cwiseAbs().maxCoeff(), 1e-9);
}

TEST(SurfaceFirstContact, OverlapOfTwoMuscles) {
  const TriMesh a = make_icosphere(0.02, 3);
  TriMesh b = make_icosphere(0.02, 3);
  b.V.col(0).array() += 0.035;  // 5 mm overlap along x
  const MeshQuery qb(b);
  const OverlapInfo o = calc_surface_overlap(a.V, qb);
  EXPECT_GT(o.vertices_inside, 0);
  // deepest vertex of a inside b: a's vertex at (0.02, 0, 0) is at distance 0.02 - 0.015 = 5 mm
  // from b's surface (b's sphere centre at 0.035, radius 0.02), up to the tessellation error
  EXPECT_NEAR(o.max_depth_m, 0.005, 2e-4);
  EXPECT_LE(o.max_depth_m, 0.005 + 1e-12);
  const OverlapInfo none = calc_surface_overlap(a.V, MeshQuery(make_icosphere(0.01, 2)));
  EXPECT_EQ(none.vertices_inside, 0);
}

}  // namespace
}  // namespace fascicle
