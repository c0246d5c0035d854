// Model compile, stages, driver order and determinism, writers, the procedural demo.
#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/polydata.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/io/vtk_series.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/demo.hpp"
#include "fascicle/scene/driver.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <fstream>

namespace fs = std::filesystem;
using namespace fascicle;

namespace {

constexpr double kDeg = M_PI / 180.0;

// Two boxes joined by a pin about z at the origin; a muscle from the upper box to the lower one.
SceneSpec make_two_link_scene() {
  SceneSpec s;
  s.name = "two_link";
  SceneBodySpec upper{.name = "upper"};
  upper.mesh = make_box(Vec3(0.02, 0.1, 0.02));
  upper.mesh->V.col(1).array() += 0.1;
  SceneBodySpec lower{.name = "lower"};
  lower.mesh = make_box(Vec3(0.02, 0.1, 0.02));
  lower.mesh->V.col(1).array() -= 0.1;
  lower.density_kg_per_m3 = 1000.0;
  s.bodies = {upper, lower};
  SceneJointSpec weld{.name = "fix", .type = "weld", .parent = "ground", .child = "upper"};
  SceneJointSpec pin{.name = "hinge", .type = "pin", .parent = "upper", .child = "lower"};
  pin.axis = Vec3::UnitZ();
  pin.coordinates = {{"angle", 0.0, -M_PI, M_PI}};
  s.joints = {weld, pin};
  MuscleSpec m;
  m.name = "flexor";
  m.origin = {"upper", {Vec3(0.03, 0.1, 0.0)}, 0.0};
  m.insertion = {"lower", {Vec3(0.03, -0.1, 0.0)}, 0.0};
  m.mesh = make_ellipsoid(Vec3(0.015, 0.09, 0.015), 2);
  m.mesh->V.col(0).array() += 0.03;
  m.actuator.max_isometric_force_N = 500;
  m.actuator.optimal_fiber_length_m = 0.08;
  m.actuator.tendon_slack_length_m = 0.12;
  s.muscles = {m};
  return s;
}

Table make_angle_motion(int n, double max_deg) {
  Table t;
  t.labels = {"angle"};
  t.in_degrees = true;
  t.time = VecX::LinSpaced(n, 0.0, 1.0);
  t.data = (max_deg * t.time).eval();
  return t;
}

}  // namespace

TEST(SceneModel, CompileComputesMassPropertiesFromMeshes) {
  const Model model = compile(make_two_link_scene(), make_default_registry());
  ASSERT_EQ(model.num_bodies(), 3);
  const Body& lower = model.get_body(model.find_body("lower"));
  EXPECT_NEAR(lower.mesh_volume_m3, 0.04 * 0.2 * 0.04, 1e-15);
  EXPECT_NEAR(lower.mass_kg, 1000.0 * 0.04 * 0.2 * 0.04, 1e-12);
  EXPECT_NEAR(lower.center_of_mass.y(), -0.1, 1e-14);
  // Box inertia about its centre: m/12 (b² + c²).
  EXPECT_NEAR(lower.inertia(0, 0), lower.mass_kg / 12.0 * (0.2 * 0.2 + 0.04 * 0.04), 1e-12);
  EXPECT_EQ(model.coordinates.size(), 1u);
  EXPECT_TRUE(model.coordinates[0].rotational);
}

TEST(SceneModel, PoseAndActionLineMatchClosedForm) {
  const Model model = compile(make_two_link_scene(), make_default_registry());
  State state = make_state(model);
  state.q[0] = 90.0 * kDeg;
  forward(model, state);
  const Transform& X = state.X_ground_body[model.find_body("lower").v];
  // Insertion (0.03, −0.1) rotated by +90° about z: (0.1, 0.03).
  const Vec3 p = X * Vec3(0.03, -0.1, 0.0);
  EXPECT_NEAR((p - Vec3(0.1, 0.03, 0.0)).norm(), 0.0, 1e-15);
  const double expected = (Vec3(0.1, 0.03, 0) - Vec3(0.03, 0.1, 0)).norm();
  EXPECT_NEAR(state.muscles[0].musculotendon_length_m, expected, 1e-15);
  // Hill equilibrium: fibre force along the tendon equals tendon force.
  const auto& h = state.muscles[0].hill;
  EXPECT_NEAR(h.fiber_force_along_tendon_N, h.tendon_force_N, 1e-6 * std::max(1.0, h.tendon_force_N));
  EXPECT_NEAR(h.fiber_length_m * std::cos(h.pennation_rad) + h.tendon_length_m, expected, 1e-9);
}

TEST(SceneModel, BlendedSurfaceIsRigidWhenNothingMovesAndFollowsRigidMotion) {
  const Model model = compile(make_two_link_scene(), make_default_registry());
  State state = make_state(model);
  forward(model, state);
  // T = X·X⁻¹ is the identity up to rounding.
  EXPECT_LT((state.muscles[0].surface - model.muscles[0].rest_mesh.V).cwiseAbs().maxCoeff(), 1e-16);
  EXPECT_NEAR(state.muscles[0].relative_volume_change, 0.0, 1e-14);
  // Stages must be computed in order.
  State fresh = make_state(model);
  EXPECT_THROW(calc_forces(model, fresh), Error);
}

TEST(SceneModel, StructuralErrorsNameTheObject) {
  const Registry registry = make_default_registry();
  SceneSpec s = make_two_link_scene();
  s.muscles[0].origin.body = "uper";
  try {
    compile(s, registry);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_EQ(e.context().object, "flexor");
    EXPECT_NE(e.context().suggestion.find("did you mean 'upper'"), std::string::npos);
  }
  s = make_two_link_scene();
  s.joints[1].type = "pinn";
  EXPECT_THROW(compile(s, registry), Error);
  s = make_two_link_scene();
  s.joints[0].parent = "lower";  // cycle: upper ↔ lower, nothing on ground
  EXPECT_THROW(compile(s, registry), Error);
  s = make_two_link_scene();
  s.bodies[0].mesh->F.col(0).swap(s.bodies[0].mesh->F.col(1));  // inside-out mesh
  EXPECT_THROW(compile(s, registry), Error);
  // An attachment area must lie on its bone: the upper box's surface is at x = 0.02; a landmark
  // at x = 0.03 (10 mm away) with a 10 mm area is on it, one at x = 0.05 (30 mm) is not.
  s = make_two_link_scene();
  s.muscles[0].origin.radius_m = 0.01;
  EXPECT_NO_THROW(compile(s, registry));
  s.muscles[0].origin.points = {Vec3(0.05, 0.1, 0.0)};
  try {
    compile(s, registry);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_EQ(e.context().object, "flexor");
    EXPECT_NE(std::string(e.what()).find("lies on no bone: its landmarks are 30 mm from body 'upper'"),
              std::string::npos) << e.what();
  }
}

namespace {

// Records the stage of the state it is handed and the frame order.
struct RecordingWriter final : FrameWriter {
  std::vector<int> frames;
  std::vector<Stage> stages;
  std::vector<double> lengths;
  bool began = false, finished = false;
  void begin(const Model&, const RunInfo&) override { began = true; }
  void write_frame(const Model&, const State& s, int frame) override {
    frames.push_back(frame);
    stages.push_back(s.stage);
    lengths.push_back(s.muscles[0].musculotendon_length_m);
  }
  void finish(const Model&) override { finished = true; }
  std::vector<fs::path> get_outputs() const override { return {}; }
};

}  // namespace

TEST(SceneDriver, StepsFramesInOrderWithAllStagesDone) {
  const Model model = compile(make_two_link_scene(), make_default_registry());
  const CoordinateTrajectory traj = make_trajectory(model, make_angle_motion(11, 90.0), 20.0);
  ASSERT_EQ(traj.time.size(), 21);
  EXPECT_NEAR(traj.q(20, 0), 90.0 * kDeg, 1e-15);  // degrees converted
  RecordingWriter w;
  DriverOptions o;
  o.progress = false;
  const DriverResult r = run_frames(model, traj, o, {&w});
  EXPECT_EQ(r.frames_written, 21);
  EXPECT_TRUE(w.began && w.finished);
  for (int f = 0; f < 21; ++f) {
    EXPECT_EQ(w.frames[f], f);
    EXPECT_EQ(w.stages[f], Stage::geometry);
  }
  // The muscle is anterior (+x) of a +z hinge: flexing shortens it at first.
  EXPECT_LT(w.lengths[5], w.lengths[0]);
}

// A writer that fails at one frame: frames are written one step behind the solves (pipelined), so
// the error must still name the frame being written, the writers must be finished, and the frames
// before it must have been handed over in order.
TEST(SceneDriver, WriterFailureNamesItsFrameAndFinishesTheWriters) {
  struct FailingWriter final : FrameWriter {
    int fail_at = 7;
    std::vector<int> frames;
    bool finished = false;
    void begin(const Model&, const RunInfo&) override {}
    void write_frame(const Model&, const State& s, int frame) override {
      EXPECT_EQ(s.stage, Stage::geometry);
      if (frame == fail_at) throw_bad_input("test writer cannot write this frame");
      frames.push_back(frame);
    }
    void finish(const Model&) override { finished = true; }
    std::vector<fs::path> get_outputs() const override { return {}; }
  };
  const Model model = compile(make_two_link_scene(), make_default_registry());
  const CoordinateTrajectory traj = make_trajectory(model, make_angle_motion(11, 90.0), 20.0);
  FailingWriter w;
  RecordingWriter other;
  DriverOptions o;
  o.progress = false;
  try {
    run_frames(model, traj, o, {&other, &w});
    ADD_FAILURE() << "the writer's error was not reported";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    const std::string what = e.what();
    EXPECT_NE(what.find("at frame 7 (t = " + std::to_string(traj.time[7]) + " s)"), std::string::npos) << what;
    EXPECT_NE(what.find("7 frames before it were written"), std::string::npos) << what;
  }
  EXPECT_TRUE(w.finished && other.finished);
  ASSERT_EQ(w.frames.size(), 7u);
  for (int f = 0; f < 7; ++f) EXPECT_EQ(w.frames[f], f);
  // the other writer got frame 7 too (it comes first), and nothing after it
  ASSERT_EQ(other.frames.size(), 8u);
  EXPECT_EQ(other.frames.back(), 7);
}

TEST(SceneDriver, MotionValuesOutsideRangeAreClampedAndUnknownColumnsIgnored) {
  SceneSpec s = make_two_link_scene();
  s.joints[1].coordinates[0].range_max = 45.0 * kDeg;
  const Model model = compile(s, make_default_registry());
  Table t = make_angle_motion(3, 90.0);
  t.labels = {"/jointset/hinge/angle/value"};
  t.labels.push_back("unrelated");
  t.data.conservativeResize(3, 2);
  t.data.col(1).setConstant(7.0);
  const CoordinateTrajectory traj = make_trajectory(model, t, 2.0);
  EXPECT_NEAR(traj.q.maxCoeff(), 45.0 * kDeg, 1e-15);
  Table none = t;
  none.labels = {"a", "b"};
  EXPECT_THROW(make_trajectory(model, none, 2.0), Error);
}

namespace {

// An actuator that fails at a given length, to test the failure path.
struct FailingActuator final : Actuator {
  double fail_below;
  explicit FailingActuator(double f) : fail_below(f) {}
  MuscleOutputs calc_outputs(double a, double l) const override {
    if (l < fail_below) throw_numerical("test actuator refuses this length");
    MuscleOutputs o;
    o.activation = a;
    o.musculotendon_length_m = l;
    o.tendon_force_N = 1.0;
    return o;
  }
};

}  // namespace

TEST(SceneDriver, FailureNamesMuscleAndFrameAndKeepsWrittenFrames) {
  Registry registry = make_default_registry();
  registry.actuators.add("fragile", [](const MuscleSpec&) {
    return std::unique_ptr<const Actuator>(std::make_unique<FailingActuator>(0.15));
  });
  SceneSpec s = make_two_link_scene();
  s.muscles[0].actuator.type = "fragile";
  const Model model = compile(s, registry);
  const CoordinateTrajectory traj = make_trajectory(model, make_angle_motion(11, 150.0), 10.0);
  const fs::path dir = test::scratch_dir("driver_failure");
  auto writers = make_writers(registry, {});
  std::vector<FrameWriter*> use;
  for (auto& w : writers) use.push_back(w.get());
  DriverOptions o;
  o.out_dir = dir;
  o.progress = false;
  int failed_frame = -1;
  try {
    run_frames(model, traj, o, use);
    FAIL() << "expected a failure";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::numerical);
    EXPECT_EQ(e.context().object, "flexor");
    const std::string what = e.what();
    const auto at = what.find("at frame ");
    ASSERT_NE(at, std::string::npos) << what;
    failed_frame = std::stoi(what.substr(at + 9));
  }
  ASSERT_GT(failed_frame, 0);
  // The frames before the failure are complete and readable.
  const auto pvd = read_pvd(dir / "scene.pvd");
  EXPECT_EQ(static_cast<int>(pvd.size()), failed_frame * 4);  // 2 bones, muscle, action line (no fibres)
  for (const auto& d : pvd) EXPECT_NO_THROW(read_polydata(dir / d.file));
  const Table sto = read_table(dir / "scene_muscles.sto");
  EXPECT_EQ(sto.rows(), failed_frame);
  EXPECT_GE(find_column(sto, "flexor.tendon_force_N"), 0);
  EXPECT_EQ(find_column(sto, "flexor.fiber_length_m"), -1);  // never computed: left out
  EXPECT_TRUE(fs::exists(dir / "summary.json"));
}

TEST(SceneDriver, SameResultsWithOneAndTwoThreads) {
  const DemoScene demo = make_demo_leg(50.0);
  const Model model = compile(demo.spec, make_default_registry());
  const CoordinateTrajectory traj = make_trajectory(model, demo.motion, 10.0);
  std::vector<std::vector<MuscleFrame>> runs;
  for (int threads : {1, 2}) {
    ThreadLimit limit(threads);
    State state = make_state(model);
    std::vector<MuscleFrame> frames;
    for (int f = 0; f < traj.time.size(); ++f) {
      state.q = traj.q.row(f).transpose();
      forward(model, state);
      frames.insert(frames.end(), state.muscles.begin(), state.muscles.end());
    }
    runs.push_back(std::move(frames));
  }
  ASSERT_EQ(runs[0].size(), runs[1].size());
  for (size_t i = 0; i < runs[0].size(); ++i) {
    EXPECT_EQ(runs[0][i].surface, runs[1][i].surface)
        << "max difference " << (runs[0][i].surface - runs[1][i].surface).cwiseAbs().maxCoeff();
    EXPECT_EQ(runs[0][i].hill.tendon_force_N, runs[1][i].hill.tendon_force_N);
    EXPECT_EQ(runs[0][i].volume_m3, runs[1][i].volume_m3);
  }
}

namespace {

// A per-muscle representation whose calc_geometry throws fascicle::Error for the muscles named in
// `fail`, after some work so that two threads are inside it at once.
struct ThrowingRepresentation final : MuscleRepresentation {
  bool fail;
  explicit ThrowingRepresentation(bool f) : fail(f) {}
  void calc_geometry(const Model&, MuscleIndex, const State&, RepresentationState*, MuscleFrame& out) const override {
    double s = 0.0;
    for (int i = 1; i < 20000; ++i) s += std::sqrt(static_cast<double>(i));
    out.volume_m3 = s;
    if (fail) throw_numerical("test representation refuses this frame");
  }
};

}  // namespace

// An error thrown inside parallel_for by a muscle's representation (calc_muscle_geometry) comes
// out of forward() on the calling thread as a fascicle::Error naming the muscle, with 2 threads,
// whether one or both muscles throw (reported crash: a segfault inside TBB; not reproduced).
TEST(SceneDriver, RepresentationErrorsInParallelPropagateNamingTheMuscle) {
  Registry registry = make_default_registry();
  registry.muscle_representations.add("throwing", [](const Model& model, MuscleIndex m) {
    const std::string& name = model.get_muscle(m).name;
    return std::unique_ptr<const MuscleRepresentation>(std::make_unique<ThrowingRepresentation>(name != "flexor"));
  });
  registry.muscle_representations.add("throwing_all", [](const Model&, MuscleIndex) {
    return std::unique_ptr<const MuscleRepresentation>(std::make_unique<ThrowingRepresentation>(true));
  });
  for (const std::string rep : {"throwing", "throwing_all"}) {
    SCOPED_TRACE(rep);
    SceneSpec s = make_two_link_scene();
    s.muscles.push_back(s.muscles[0]);
    s.muscles[1].name = "extensor";
    for (auto& m : s.muscles) m.representation = rep;
    const Model model = compile(s, registry);
    ThreadLimit limit(2);
    for (int trial = 0; trial < 50; ++trial) {
      State state = make_state(model);
      try {
        forward(model, state);
        FAIL() << "no error";
      } catch (const Error& e) {
        EXPECT_EQ(e.kind(), ErrorKind::numerical);
        const std::string object = e.context().object;
        if (rep == "throwing")
          EXPECT_EQ(object, "extensor");
        else
          EXPECT_TRUE(object == "flexor" || object == "extensor") << object;
        EXPECT_NE(std::string(e.what()).find("test representation refuses"), std::string::npos) << e.what();
      }
    }
  }
}

namespace {

// A group representation that only records how many muscles it was given.
struct CountingGroup final : MuscleGroupRepresentation {
  void calc_geometry(const Model&, const std::vector<MuscleIndex>&, const State&, RepresentationState*,
                     const std::vector<MuscleFrame*>&) const override {}
};

}  // namespace

// Group names that differ only in '-' versus '_' (the built-in aliases solid_dynamics /
// solid-dynamics and fibres_first / fibres-first) are one group: a scene mixing the spellings gets
// one group holding all its muscles, built by the '_' spelling's factory.
TEST(SceneModel, GroupSpellingsWithDashOrUnderscoreAreOneGroup) {
  Registry registry = make_default_registry();
  std::vector<std::string> built;
  const auto factory = [&](const std::string& tag) {
    return [&built, tag](const Model&, const std::vector<MuscleIndex>& muscles) {
      built.push_back(tag + ":" + std::to_string(muscles.size()));
      return std::unique_ptr<const MuscleGroupRepresentation>(std::make_unique<CountingGroup>());
    };
  };
  registry.muscle_groups.add("probe-group", factory("dash"));
  registry.muscle_groups.add("probe_group", factory("underscore"));
  SceneSpec s = make_two_link_scene();
  s.muscles.push_back(s.muscles[0]);
  s.muscles.push_back(s.muscles[0]);
  s.muscles[1].name = "extensor";
  s.muscles[2].name = "third";
  s.muscles[0].representation = "probe-group";
  s.muscles[1].representation = "probe_group";
  s.muscles[2].representation = "action_line";
  const Model model = compile(s, registry);
  ASSERT_EQ(model.muscle_groups.size(), 1u);
  EXPECT_EQ(model.muscle_groups[0].representation, "probe_group");
  ASSERT_EQ(model.muscle_groups[0].muscles.size(), 2u);
  EXPECT_EQ(model.muscle_groups[0].muscles[0].v, 0);
  EXPECT_EQ(model.muscle_groups[0].muscles[1].v, 1);
  EXPECT_EQ(built, std::vector<std::string>{"underscore:2"});
  // The built-in aliases are registered in both spellings.
  for (const char* name : {"solid_dynamics", "solid-dynamics", "fibres_first", "fibres-first"})
    EXPECT_NE(registry.muscle_groups.find(name), nullptr) << name;
}
