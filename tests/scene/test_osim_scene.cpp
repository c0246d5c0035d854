// OpenSim models as scenes: generated bellies (shape rule, exact volume, fibres inside), the
// path-driven action lines, per-frame activations, and the surface-first invariants on gait2392.
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/geometry/mesh_validation.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/osim/osim_model.hpp"
#include "fascicle/scene/driver.hpp"
#include "fascicle/scene/osim_scene.hpp"
#include "fascicle/scene/state.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace fascicle {
namespace {

double calc_volume(const TriMesh& m) {
  double six_v = 0.0;
  for (Eigen::Index t = 0; t < m.F.rows(); ++t)
    six_v += m.V.row(m.F(t, 0)).dot(m.V.row(m.F(t, 1)).cross(m.V.row(m.F(t, 2))));
  return six_v / 6.0;
}

// A quarter circle of radius `bend` (curved) or a straight segment, 0.2 m long.
Points3 make_centreline(double bend) {
  const int n = 41;
  Points3 P(n, 3);
  for (int i = 0; i < n; ++i) {
    const double s = 0.2 * i / (n - 1);
    if (bend <= 0.0)
      P.row(i) << 0.0, 0.0, s;
    else
      P.row(i) << bend * (1.0 - std::cos(s / bend)), 0.0, bend * std::sin(s / bend);
  }
  return P;
}

void expect_closed_belly_with_inner_fibres(const GeneratedBelly& belly, double volume) {
  ValidationOptions vo;
  const MeshReport report = validate_mesh(belly.mesh, vo);
  EXPECT_TRUE(report.is_solid());
  EXPECT_NEAR(calc_volume(belly.mesh), volume, 1e-9 * volume);
  const MeshQuery query(belly.mesh);
  int outside = 0, points = 0;
  for (const Points3& f : belly.fibres)
    for (Eigen::Index i = 0; i < f.rows(); ++i, ++points)
      {
        const Vec3 x = f.row(i).transpose();
        if (!query.calc_is_inside(x) && query.calc_closest_point(x).distance > 1e-9) ++outside;
      }
  EXPECT_EQ(outside, 0) << "of " << points << " fibre points";
}

TEST(GeneratedBelly, StraightAndCurvedBelliesAreClosedWithExactVolume) {
  for (double bend : {0.0, 0.3}) {
    const double volume = 2.5e-4;
    const GeneratedBelly belly = make_fusiform_belly(make_centreline(bend), volume);
    EXPECT_EQ(belly.mesh.V.rows(), 16 * 24 + 2);
    ASSERT_EQ(belly.fibres.size(), 30u);
    expect_closed_belly_with_inner_fibres(belly, volume);
  }
}

TEST(GeneratedBelly, StraightBellyFollowsTheProfileVolumeFormula) {
  // V = ∫ π R² sin(πu) l du = 2 R² l for the continuous profile; the polygonal sections hold a
  // factor (s/2π) sin(2π/s) of the circle area, and the rings sample the profile, so R from the
  // formula is within a few per cent of the fitted one.
  const double volume = 2.5e-4, length = 0.2;
  const GeneratedBelly belly = make_fusiform_belly(make_centreline(0.0), volume);
  const double R = belly.mesh.V.col(0).maxCoeff();
  EXPECT_NEAR(R, std::sqrt(volume / (2.0 * length)), 0.05 * R);
  // Parallel fibres run tip to tip along the axis.
  for (const Points3& f : belly.fibres) {
    EXPECT_NEAR(f(0, 2), 0.0, 1e-12);
    EXPECT_NEAR(f(f.rows() - 1, 2), length, 1e-9);
  }
}

TEST(GeneratedBelly, PennateFibresLeaveTheAxisAtThePennationAngle) {
  const double alpha = 20.0 * M_PI / 180.0, volume = 2.5e-4;
  const GeneratedBelly belly = make_fusiform_belly(make_centreline(0.0), volume, {}, alpha);
  expect_closed_belly_with_inner_fibres(belly, volume);
  for (const Points3& f : belly.fibres) {
    const Vec3 d = (f.row(f.rows() - 1) - f.row(0)).transpose();
    EXPECT_NEAR(std::hypot(f(0, 0), f(0, 1)), 0.0, 1e-12);  // starts on the axis
    EXPECT_LT(d.z(), 0.0);                                  // towards the origin tip (z = 0)
    EXPECT_NEAR(std::atan2(std::hypot(d.x(), d.y()), -d.z()), alpha, 1e-9);
  }
}

TEST(GeneratedBelly, SpanRule) {
  MuscleParameters p;
  p.optimal_fiber_length_m = 0.05;
  p.pennation_at_optimal_rad = 0.0;
  const double k = 1.0 / 6.0, volume = 3e-4;
  const double l = std::cbrt(volume / (2.0 * k * k));  // 0.1754 m
  BellySpan s = calc_belly_span(0.5, volume, p, k);
  EXPECT_NEAR(s.end_m - s.start_m, l, 1e-12);
  EXPECT_NEAR(s.start_m, 0.5 * (0.5 - l), 1e-12);
  s = calc_belly_span(0.15, volume, p, k);  // a short path: at most 90 % of it
  EXPECT_NEAR(s.end_m - s.start_m, 0.135, 1e-12);
  s = calc_belly_span(0.5, 1e-7, p, k);    // a tiny volume: never shorter than the fibres
  EXPECT_NEAR(s.end_m - s.start_m, 0.05, 1e-12);
}

TEST(GeneratedBelly, BadInput) {
  EXPECT_THROW(make_fusiform_belly(make_centreline(0.0), -1.0), Error);
  EXPECT_THROW(make_fusiform_belly(make_centreline(0.0), std::nan("")), Error);
  Points3 point(2, 3);
  point.setZero();
  EXPECT_THROW(make_fusiform_belly(point, 1e-4), Error);
}

class Gait2392Scene : public ::testing::Test {
 protected:
  static OsimModel read_model() {
    OsimImportOptions o;
    o.geometry_dirs.push_back(test::data_path("opensim/Geometry"));
    o.warn = false;
    return read_osim(test::data_path("opensim/models/gait2392_thelen2003muscle.osim"), o);
  }
};

TEST_F(Gait2392Scene, UnknownMuscleSuggestsTheNearestName) {
  OsimSceneOptions o;
  o.muscles = {"soleus_rr"};
  try {
    make_scene_from_osim(read_model(), o);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("soleus_r"), std::string::npos) << e.what();
  }
}

TEST_F(Gait2392Scene, WalkingKeepsVolumesAndFollowsThePathsAndActivations) {
  OsimSceneOptions o;
  o.muscles = {"soleus_r", "tib_ant_r", "med_gas_r"};
  const SceneSpec spec = make_scene_from_osim(read_model(), o);
  ASSERT_EQ(spec.muscles.size(), 3u);
  // The Thelen curve parameters of the model travel with the actuator.
  ASSERT_TRUE(spec.muscles[0].actuator.parameters.has_value());
  EXPECT_EQ(spec.muscles[0].actuator.model, "thelen");
  EXPECT_EQ(spec.muscles[0].fibre_template, "pennate");  // med_gas_r: 17° at optimal length
  // Generated volume = F0 / σ · l0 (σ = 25 N/cm²).
  const MuscleParameters& p = *spec.muscles[0].actuator.parameters;
  EXPECT_NEAR(calc_volume(*spec.muscles[0].mesh), p.max_isometric_force_N / 25e4 * p.optimal_fiber_length_m, 1e-12);

  const Model model = compile(spec, make_default_registry());
  const Table motion = read_table(test::data_path("opensim/motions/subject01_walk1_ik.mot"));
  CoordinateTrajectory traj = make_trajectory(model, motion, 20.0);
  traj.time.conservativeResize(4);
  traj.q.conservativeResize(4, Eigen::NoChange);
  Table act;
  act.labels = {"/forceset/soleus_r/activation", "tib_ant_r"};
  act.time = (VecX(2) << 0.0, 10.0).finished();
  act.data = (MatX(2, 2) << 0.3, 0.3, 0.3, 0.3).finished();
  add_activations(model, act, "test", traj);

  State state = make_state(model);
  for (long f = 0; f < traj.time.size(); ++f) {
    state.q = traj.q.row(f).transpose();
    state.activation = traj.activation.row(f).transpose();
    forward(model, state);
    for (int m = 0; m < model.num_muscles(); ++m) {
      const MuscleFrame& mf = state.muscles[m];
      EXPECT_LT(std::abs(mf.relative_volume_change), 1e-9) << model.muscles[m].name;
      EXPECT_LE(mf.max_bone_penetration_m, 5e-4) << model.muscles[m].name;
      // The action line is the wrapping path: its polyline length equals the path length (arcs
      // sampled every 5 mm: within 1 mm).
      double polyline = 0.0;
      for (Eigen::Index i = 1; i < mf.action_line.rows(); ++i)
        polyline += (mf.action_line.row(i) - mf.action_line.row(i - 1)).norm();
      EXPECT_NEAR(polyline, mf.musculotendon_length_m, 1e-3);
      EXPECT_GT(mf.mean_fibre_length_m, 0.03);
      EXPECT_EQ(mf.fibres.size(), 30u);
    }
    const auto activation = [&](const char* name) { return state.muscles[model.find_muscle(name).v].hill.activation; };
    EXPECT_DOUBLE_EQ(activation("soleus_r"), 0.3);   // from the table, by OpenSim path
    EXPECT_DOUBLE_EQ(activation("tib_ant_r"), 0.3);  // by name
    EXPECT_DOUBLE_EQ(activation("med_gas_r"), model.muscles[model.find_muscle("med_gas_r").v].activation);
  }
  // Tibia and fibula are closed meshes: obstacles; the pelvis mesh is open: drawn only.
  EXPECT_TRUE(model.get_body(model.find_body("tibia_r")).mesh_is_obstacle);
  EXPECT_TRUE(model.get_body(model.find_body("tibia_r")).rest_query != nullptr);
  EXPECT_FALSE(model.get_body(model.find_body("pelvis")).mesh_is_obstacle);
  EXPECT_EQ(model.get_body(model.find_body("pelvis")).rest_query, nullptr);  // not an obstacle
}

TEST_F(Gait2392Scene, ActivationTableWithoutMatchingColumnIsBadInput) {
  OsimSceneOptions o;
  o.muscles = {"soleus_r"};
  const Model model = compile(make_scene_from_osim(read_model(), o), make_default_registry());
  CoordinateTrajectory traj;
  traj.time = VecX::LinSpaced(3, 0.0, 1.0);
  Table act;
  act.labels = {"nothing"};
  act.time = traj.time;
  act.data = MatX::Zero(3, 1);
  EXPECT_THROW(add_activations(model, act, "a.sto", traj), Error);
}

}  // namespace
}  // namespace fascicle
