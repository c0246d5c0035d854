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
  // the edge-propagated version gives the same numbers
  const OverlapInfo o2 = calc_surface_overlap(a.V, a.F, qb);
  EXPECT_EQ(o2.vertices_inside, o.vertices_inside);
  EXPECT_EQ(o2.max_depth_m, o.max_depth_m);
  EXPECT_EQ(calc_surface_overlap(a.V, a.F, MeshQuery(make_icosphere(0.01, 2))).vertices_inside, 0);
}

// Winding propagation along edges against the per-vertex ray vote: a torus threaded through an
// ellipsoid (two separate inside regions, non-convex), a surface entirely inside the other's box
// (no seed outside it), one inside the other, and a sphere against a coarser, rotated one of almost
// the same radius (many thin inside regions).
TEST(SurfaceFirstContact, OverlapByPropagationEqualsRayVote) {
  const TriMesh torus = make_torus(0.03, 0.008, 48, 16);
  std::vector<std::pair<TriMesh, TriMesh>> cases;
  cases.emplace_back(torus, make_ellipsoid(Vec3(0.012, 0.05, 0.02), 3));
  cases.emplace_back(make_ellipsoid(Vec3(0.012, 0.05, 0.02), 3), torus);
  cases.emplace_back(make_icosphere(0.005, 2), make_icosphere(0.02, 3));
  TriMesh shifted = make_icosphere(0.02, 3);
  shifted.V.col(0).array() += 0.01;
  cases.emplace_back(make_icosphere(0.02, 3), shifted);
  TriMesh coarse = make_icosphere(0.0201, 2);  // crosses the finer sphere many times, close by
  coarse.V = (coarse.V * Eigen::AngleAxisd(0.3, Vec3(1, 2, 3).normalized()).toRotationMatrix()).eval();
  cases.emplace_back(make_icosphere(0.02, 4), coarse);
  for (std::size_t c = 0; c < cases.size(); ++c) {
    const auto& [a, b] = cases[c];
    const MeshQuery qb(b);
    const OverlapInfo vote = calc_surface_overlap(a.V, qb);
    const OverlapInfo walk = calc_surface_overlap(a.V, a.F, qb);
    EXPECT_EQ(walk.vertices_inside, vote.vertices_inside) << "case " << c;
    EXPECT_EQ(walk.max_depth_m, vote.max_depth_m) << "case " << c;
  }
  EXPECT_GT(calc_surface_overlap(cases[0].first.V, cases[0].first.F, MeshQuery(cases[0].second)).vertices_inside, 0);
  EXPECT_EQ(calc_surface_overlap(cases[2].first.V, cases[2].first.F, MeshQuery(cases[2].second)).vertices_inside,
            cases[2].first.V.rows());
  const OverlapInfo thin = calc_surface_overlap(cases[4].first.V, cases[4].first.F, MeshQuery(cases[4].second));
  EXPECT_GT(thin.vertices_inside, 100);
  EXPECT_LT(thin.vertices_inside, cases[4].first.V.rows() - 100);
}

// An inside-out `other` makes every crossing count negative: the walk gives up after its budget
// of whole rays and the overlap falls back to the per-vertex vote (same answer, bounded cost).
TEST(SurfaceFirstContact, OverlapAgainstInsideOutSurfaceFallsBackToTheVote) {
  const TriMesh a = make_icosphere(0.02, 4);
  TriMesh b = make_icosphere(0.02, 3);
  b.V.col(0).array() += 0.01;
  b.F.col(1).swap(b.F.col(2));  // inward normals
  const MeshQuery qb(b);
  std::vector<int> winding(static_cast<std::size_t>(a.V.rows()), -1);
  for (Eigen::Index i = 0; i < a.V.rows(); ++i)
    if (a.V(i, 0) < -0.015) winding[i] = 0;  // left of b's box
  EXPECT_FALSE(propagate_winding(a.V, make_vertex_adjacency(a.F, a.V.rows()), qb, winding, 64));
  const OverlapInfo vote = calc_surface_overlap(a.V, qb);
  const OverlapInfo walk = calc_surface_overlap(a.V, a.F, qb);
  EXPECT_EQ(walk.vertices_inside, vote.vertices_inside);
  EXPECT_EQ(walk.max_depth_m, vote.max_depth_m);
  // The same surface the right way out needs no fallback.
  b.F.col(1).swap(b.F.col(2));
  std::fill(winding.begin(), winding.end(), -1);
  for (Eigen::Index i = 0; i < a.V.rows(); ++i)
    if (a.V(i, 0) < -0.015) winding[i] = 0;
  EXPECT_TRUE(propagate_winding(a.V, make_vertex_adjacency(a.F, a.V.rows()), MeshQuery(b), winding, 64));
}

}  // namespace
}  // namespace fascicle
