// The scene's muscle-muscle overlap measure: equal to deformation's calc_surface_overlap on real
// (Visible Human) muscles, and unchanged by the per-State cache and by the thread count.
#include "fascicle/core/parallel.hpp"
#include "fascicle/deformation/surface_first.hpp"
#include "fascicle/geometry/obb.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/mesh_io.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/driver.hpp"
#include "fascicle/scene/overlap.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace fascicle;

namespace {

TriMesh read_vh_muscle(const std::string& name) {
  return read_mesh(test::data_path("visible_human_female/right/VHF_Right_Muscle_" + name + "_smooth.stl"),
                   LengthUnit::millimetre);
}

// Every ordered pair of four neighbouring shank muscles, at rest and with a moved 4 mm towards b
// (deeper overlaps, more vertices in b's box): the restricted propagation gives exactly
// calc_surface_overlap's count and depth.
TEST(MuscleOverlap, EqualsCalcSurfaceOverlapOnVisibleHumanMuscles) {
  std::vector<TriMesh> meshes;
  for (const char* name : {"Soleus", "GastrocnemiusMedial", "GastrocnemiusLateral", "TibialisPosterior"})
    meshes.push_back(read_vh_muscle(name));
  std::vector<std::unique_ptr<MeshQuery>> query;
  for (const TriMesh& m : meshes) query.push_back(std::make_unique<MeshQuery>(m));
  // Oriented bounds along each mesh's oriented-box axes: they hold every vertex, and for these long
  // oblique muscles they enclose much less than the axis-aligned box.
  std::vector<OrientedBounds> bounds;
  for (const TriMesh& m : meshes) {
    bounds.push_back(calc_padded_oriented_bounds(m.V, compute_oriented_box(m).axes));
    for (Eigen::Index i = 0; i < m.V.rows(); ++i) ASSERT_TRUE(bounds.back().contains(m.V.row(i).transpose()));
    const Eigen::AlignedBox3d box = calc_padded_bounding_box(m.V);
    const double ratio = (bounds.back().hi - bounds.back().lo).prod() / box.volume();
    std::printf("oriented bounds / axis-aligned box volume: %.2f\n", ratio);
    EXPECT_LT(ratio, 0.8);
  }
  int pairs_with_overlap = 0;
  long inside_total = 0;
  for (size_t a = 0; a < meshes.size(); ++a) {
    const SurfaceGraph graph = make_surface_graph(meshes[a].F, meshes[a].V.rows());
    for (size_t b = 0; b < meshes.size(); ++b) {
      if (a == b) continue;
      const Eigen::AlignedBox3d box = calc_padded_bounding_box(meshes[b].V);
      const Vec3 towards = (meshes[b].V.colwise().mean() - meshes[a].V.colwise().mean()).transpose().normalized();
      for (double shift_m : {0.0, 0.004}) {
        const Points3 V = (meshes[a].V.rowwise() + shift_m * towards.transpose()).eval();
        const OverlapInfo expected = calc_surface_overlap(V, meshes[a].F, *query[b]);
        const MuscleOverlap got = calc_muscle_overlap(V, graph, *query[b], box);
        EXPECT_EQ(got.vertices_inside, expected.vertices_inside) << a << " in " << b << " shift " << shift_m;
        EXPECT_EQ(got.max_depth_m, expected.max_depth_m) << a << " in " << b << " shift " << shift_m;
        // Seeding also from the vertices outside b's oriented bounds changes nothing either.
        const MuscleOverlap oriented = calc_muscle_overlap(V, graph, *query[b], box, &bounds[b]);
        EXPECT_EQ(oriented.vertices_inside, expected.vertices_inside) << a << " in " << b << " shift " << shift_m;
        EXPECT_EQ(oriented.max_depth_m, expected.max_depth_m) << a << " in " << b << " shift " << shift_m;
        pairs_with_overlap += expected.vertices_inside > 0;
        inside_total += expected.vertices_inside;
      }
    }
  }
  // The comparison is not vacuous: real overlaps were measured.
  EXPECT_GE(pairs_with_overlap, 6);
  EXPECT_GT(inside_total, 100);
}

TEST(MuscleOverlap, NoVertexInTheBoxMeansNoOverlap) {
  const TriMesh a = make_icosphere(0.01, 2);
  TriMesh b = a;
  b.V.col(0).array() += 0.05;
  const MeshQuery qb(b);
  const MuscleOverlap r = calc_muscle_overlap(a.V, make_surface_graph(a.F, a.V.rows()), qb,
                                              calc_padded_bounding_box(b.V));
  EXPECT_EQ(r.vertices_inside, 0);
  EXPECT_EQ(r.max_depth_m, 0.0);
}

// Analytic case: a sphere of radius 1 cm whose centre lies 1.5 cm from another's: the deepest vertex
// of one inside the other is its vertex nearest the other centre, 1 cm − |0.5 cm| deep (to the
// icosphere's chord error).
TEST(MuscleOverlap, TwoSpheresOverlapByTheirLensDepth) {
  const TriMesh a = make_icosphere(0.01, 4);
  TriMesh b = a;
  b.V.col(0).array() += 0.015;
  const MeshQuery qb(b);
  const MuscleOverlap r = calc_muscle_overlap(a.V, make_surface_graph(a.F, a.V.rows()), qb,
                                              calc_padded_bounding_box(b.V));
  EXPECT_GT(r.vertices_inside, 0);
  EXPECT_NEAR(r.max_depth_m, 0.005, 1e-4);
}

// Two ellipsoid muscles side by side across a hinge (they overlap by a few millimetres and the
// overlap changes with the angle).
SceneSpec make_overlapping_scene() {
  SceneSpec s;
  s.name = "overlap";
  SceneBodySpec upper{.name = "upper"};
  upper.mesh = make_box(Vec3(0.02, 0.1, 0.02));
  upper.mesh->V.col(1).array() += 0.1;
  SceneBodySpec lower{.name = "lower"};
  lower.mesh = make_box(Vec3(0.02, 0.1, 0.02));
  lower.mesh->V.col(1).array() -= 0.1;
  s.bodies = {upper, lower};
  SceneJointSpec weld{.name = "fix", .type = "weld", .parent = "ground", .child = "upper"};
  SceneJointSpec pin{.name = "hinge", .type = "pin", .parent = "upper", .child = "lower"};
  pin.axis = Vec3::UnitZ();
  pin.coordinates = {{"angle", 0.0, -M_PI, M_PI}};
  s.joints = {weld, pin};
  for (int k = 0; k < 2; ++k) {
    MuscleSpec m;
    m.name = k == 0 ? "front" : "side";
    const double x = 0.03, z = k == 0 ? 0.0 : 0.02;
    m.origin = {"upper", {Vec3(x, 0.1, z)}, 0.0};
    m.insertion = {"lower", {Vec3(x, -0.1 + 0.03 * k, z)}, 0.0};
    m.mesh = make_ellipsoid(Vec3(0.015, 0.09, 0.015), 2);
    m.mesh->V.col(0).array() += x;
    m.mesh->V.col(2).array() += z;
    s.muscles.push_back(m);
  }
  return s;
}

// Reused State (queries refitted frame after frame) vs a fresh State per frame, 1 vs 2 threads:
// the same overlap numbers, bit for bit.
TEST(MuscleOverlap, CacheAndThreadCountDoNotChangeResults) {
  const Model model = compile(make_overlapping_scene(), make_default_registry());
  std::vector<std::vector<double>> runs;
  for (int threads : {1, 2}) {
    ThreadLimit limit(threads);
    State state = make_state(model);
    std::vector<double> values;
    for (int f = 0; f < 8; ++f) {
      state.q = VecX::Constant(1, -0.15 * f);
      forward(model, state);
      State fresh = make_state(model);
      fresh.muscles = state.muscles;
      for (MuscleFrame& mf : fresh.muscles) mf.max_muscle_overlap_m = mf.max_muscle_overlap_growth_m = MuscleFrame::nan;
      calc_muscle_overlaps(model, fresh);
      // The bounds carried through the moving frames (widened by both surfaces' motion) stay true
      // upper bounds on the current surfaces, through a point of their named triangle.
      const MuscleOverlapCache& cache = state.overlap_cache;
      const size_t n = model.muscles.size();
      int checked = 0;
      for (size_t a = 0; a < n; ++a)
        for (size_t b = 0; b < n; ++b) {
          if (a == b || a * n + b >= cache.depth_bound.size()) continue;
          const std::vector<DepthBound>& ub = cache.depth_bound[a * n + b];
          if (ub.empty()) continue;
          const Points3& Va = cache.previous[a];
          const TriMesh Sb{cache.previous[b], model.muscles[b].rest_mesh.F};
          const MeshQuery qb(Sb);
          for (Eigen::Index i = 0; i < Va.rows(); ++i) {
            const DepthBound& d = ub[static_cast<size_t>(i)];
            if (!std::isfinite(d.bound)) continue;
            ++checked;
            const Vec3 x = Va.row(i).transpose();
            EXPECT_GE(d.bound * (1.0 + 1e-12), qb.calc_closest_point(x).distance) << "frame " << f << " vertex " << i;
            ASSERT_GE(d.triangle, 0);
            const TrianglePoint on = closest_point_on_triangle(x, Sb.V.row(Sb.F(d.triangle, 0)).transpose(),
                                                               Sb.V.row(Sb.F(d.triangle, 1)).transpose(),
                                                               Sb.V.row(Sb.F(d.triangle, 2)).transpose());
            EXPECT_GE(d.bound * (1.0 + 1e-12), (x - on.point).norm()) << "frame " << f << " vertex " << i;
          }
        }
      if (f > 0) {
        EXPECT_GT(checked, 0) << "frame " << f;
      }
      for (size_t m = 0; m < model.muscles.size(); ++m) {
        EXPECT_EQ(fresh.muscles[m].max_muscle_overlap_m, state.muscles[m].max_muscle_overlap_m)
            << "frame " << f << " muscle " << m;
        EXPECT_EQ(fresh.muscles[m].max_muscle_overlap_growth_m, state.muscles[m].max_muscle_overlap_growth_m)
            << "frame " << f << " muscle " << m;
        values.push_back(state.muscles[m].max_muscle_overlap_m);
        values.push_back(state.muscles[m].max_muscle_overlap_growth_m);
      }
    }
    runs.push_back(values);
  }
  EXPECT_EQ(runs[0], runs[1]);
  EXPECT_GT(*std::max_element(runs[0].begin(), runs[0].end()), 1e-3);  // the muscles do overlap
}

}  // namespace

// Carried depth bounds (calc_muscle_overlap's depth_bound): the same result as without them, the
// returned bounds are true upper bounds of every inside vertex's depth (equal where measured), and
// with the bounds of a first call a second call on the same surfaces measures fewer vertices.
TEST(MuscleOverlap, CarriedDepthBoundsPruneMeasurementsOnly) {
  const Model model = compile(make_overlapping_scene(), make_default_registry());
  const TriMesh& A = model.muscles[0].rest_mesh;
  const TriMesh& B = model.muscles[1].rest_mesh;
  const MeshQuery qb(B);
  const SurfaceGraph graph = make_surface_graph(A.F, A.V.rows());
  const Eigen::AlignedBox3d box = calc_padded_bounding_box(B.V);
  const MuscleOverlap plain = calc_muscle_overlap(A.V, graph, qb, box);
  ASSERT_GT(plain.vertices_inside, 10);
  std::vector<DepthBound> bound;
  const MuscleOverlap first = calc_muscle_overlap(A.V, graph, qb, box, nullptr, &bound);
  EXPECT_EQ(first.max_depth_m, plain.max_depth_m);
  EXPECT_EQ(first.vertices_inside, plain.vertices_inside);
  ASSERT_EQ(bound.size(), static_cast<size_t>(A.V.rows()));
  const auto check_bounds = [&](const std::vector<DepthBound>& ub) {
    int finite = 0, loose = 0;
    for (Eigen::Index i = 0; i < A.V.rows(); ++i) {
      const DepthBound& d = ub[static_cast<size_t>(i)];
      if (!std::isfinite(d.bound)) continue;
      ++finite;
      const Vec3 x = A.V.row(i).transpose();
      const double depth = qb.calc_closest_point(x).distance;
      EXPECT_GE(d.bound, depth) << i;
      // the bound is realised through a point of the named triangle
      EXPECT_GE(d.triangle, 0) << i;
      if (d.triangle < 0) continue;
      const TrianglePoint on = closest_point_on_triangle(x, B.V.row(B.F(d.triangle, 0)).transpose(),
                                                         B.V.row(B.F(d.triangle, 1)).transpose(),
                                                         B.V.row(B.F(d.triangle, 2)).transpose());
      EXPECT_GE(d.bound * (1.0 + 1e-12), (x - on.point).norm()) << i;
      loose += d.bound > depth;
    }
    EXPECT_EQ(finite, plain.vertices_inside);  // a bound for every inside vertex, none elsewhere
    return loose;
  };
  check_bounds(bound);
  // Same surfaces again, the bounds widened by 0.1 um (still valid: as after a tiny motion): the
  // call skips vertices; the ones it measures get their exact depth back, the others keep a
  // widened bound.
  std::vector<DepthBound> again = bound;
  for (DepthBound& b : again) b.bound += 1e-7;
  const MuscleOverlap second = calc_muscle_overlap(A.V, graph, qb, box, nullptr, &again);
  EXPECT_EQ(second.max_depth_m, plain.max_depth_m);
  EXPECT_EQ(second.vertices_inside, plain.vertices_inside);
  int measured_first = 0, measured_second = 0;
  for (Eigen::Index i = 0; i < A.V.rows(); ++i) {
    if (!std::isfinite(bound[static_cast<size_t>(i)].bound)) continue;
    const double depth = qb.calc_closest_point(Vec3(A.V.row(i).transpose())).distance;
    measured_first += bound[static_cast<size_t>(i)].bound == depth;
    measured_second += again[static_cast<size_t>(i)].bound == depth;
  }
  check_bounds(again);
  EXPECT_LT(measured_second, measured_first);
  EXPECT_GE(measured_second, 1);  // the deepest vertex is always measured
}

// The growth figure: per ordered pair, the depth now minus the pair's depth between the rest meshes
// (never below 0), the largest over the other muscles. Two muscles, so each one's overlap is its one
// pair's depth; the rest depths are measured here directly from the rest meshes.
TEST(MuscleOverlap, GrowthIsTheDepthBeyondTheRestPosePerPair) {
  const Model model = compile(make_overlapping_scene(), make_default_registry());
  ASSERT_EQ(model.muscles.size(), 2u);
  double rest_depth[2];
  for (int a = 0; a < 2; ++a) {
    const TriMesh& A = model.muscles[a].rest_mesh;
    const TriMesh& B = model.muscles[1 - a].rest_mesh;
    const MeshQuery qb(B);
    rest_depth[a] = calc_muscle_overlap(A.V, make_surface_graph(A.F, A.V.rows()), qb,
                                        calc_padded_bounding_box(B.V)).max_depth_m;
  }
  EXPECT_GT(rest_depth[0] + rest_depth[1], 1e-3);  // the rest meshes overlap
  // The rest pose (q = 0) reproduces the rest meshes: no growth.
  State state = make_state(model);
  state.q = VecX::Zero(1);
  forward(model, state);
  for (int m = 0; m < 2; ++m) EXPECT_LE(state.muscles[m].max_muscle_overlap_growth_m, 1e-9) << m;
  // Surfaces moved by hand towards (and away from) the other muscle by 3 mm.
  double largest_growth = 0.0;
  for (double shift_m : {-0.003, 0.003}) {
    for (int m = 0; m < 2; ++m) {
      const TriMesh& A = model.muscles[m].rest_mesh;
      const Vec3 towards =
          (model.muscles[1 - m].rest_mesh.V.colwise().mean() - A.V.colwise().mean()).transpose().normalized();
      state.muscles[m].surface = (A.V.rowwise() + shift_m * towards.transpose()).eval();
      state.muscles[1 - m].surface = model.muscles[1 - m].rest_mesh.V;
      calc_muscle_overlaps(model, state);
      const MuscleFrame& mf = state.muscles[m];
      EXPECT_EQ(mf.max_muscle_overlap_growth_m, std::max(0.0, mf.max_muscle_overlap_m - rest_depth[m]))
          << "shift " << shift_m << " muscle " << m;
      if (shift_m < 0.0) {
        EXPECT_EQ(mf.max_muscle_overlap_growth_m, 0.0) << m;
      }
      largest_growth = std::max(largest_growth, mf.max_muscle_overlap_growth_m);
    }
  }
  EXPECT_GT(largest_growth, 1e-3);  // moving 3 mm closer deepens the overlap by millimetres
}
