// "solid_dynamics" muscles of one scene are stepped together and push each other apart
// (src/scene/representation_solid_dynamics.cpp, SolidDynamicsGroup; seed 000 §4.7): two ellipsoidal
// bellies side by side, fixed at both ends, overlapping by 3 mm at rest, separate; bellies 2 mm
// apart are not pulled together (identical to a run without muscle contact); results are the same
// for 1 and 2 threads.
#include "fascicle/core/parallel.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/mesh_io.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/scene_json.hpp"
#include "fascicle/scene/state.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <fmt/format.h>

#include <fstream>

using namespace fascicle;
namespace fs = std::filesystem;

namespace {

// Two bellies (radii 12 × 60 × 12 mm) with centres ±(half_distance, 0, 0), between a fixed upper
// and lower box; no bone contact, so only the muscles act on each other.
// right_representation / right_options: the right muscle's spelling of the representation and
// extra options (JSON members, with a leading comma).
Model make_pair_scene(const std::string& name, double half_distance_m, bool muscle_contact,
                      const std::string& right_representation = "solid_dynamics", const std::string& right_options = "") {
  const fs::path dir = test::scratch_dir("solid_dynamics_group_" + name);
  const auto box_at = [](const Vec3& centre, const Vec3& half) {
    TriMesh m = make_box(half);
    m.V.rowwise() += centre.transpose();
    return m;
  };
  write_mesh(dir / "upper.obj", box_at(Vec3(0.0, 0.10, 0.0), Vec3(0.04, 0.04, 0.02)));
  write_mesh(dir / "lower.obj", box_at(Vec3(0.0, -0.10, 0.0), Vec3(0.04, 0.04, 0.02)));
  for (int side = 0; side < 2; ++side) {
    TriMesh belly = make_ellipsoid(Vec3(0.012, 0.06, 0.012), 3);
    belly.V.col(0).array() += side == 0 ? -half_distance_m : half_distance_m;
    write_mesh(dir / (side == 0 ? "left.obj" : "right.obj"), belly);
  }
  const auto muscle = [&](const std::string& n, double x) {
    const bool right = n == "right";
    return fmt::format(R"({{"name": "{}", "representation": "{}", "mesh": "{}.obj",
     "options": {{"contact": 0, "muscle_contact": {}, "muscle_contact_stiffness": 200{}}},
     "origin": {{"body": "upper", "points": [[{}, 0.06, 0]], "radius": 0.004}},
     "insertion": {{"body": "lower", "points": [[{}, -0.06, 0]], "radius": 0.004}},
     "actuator": {{"type": "none"}}, "activation": 0}})",
                       n, right ? right_representation : "solid_dynamics", n, muscle_contact ? 1 : 0,
                       right ? right_options : "", x, x);
  };
  std::ofstream(dir / "scene.json") << R"({
  "fascicle_scene": 1, "name": "pair", "units": "m", "geometry_frame": "ground",
  "bodies": [{"name": "upper", "mesh": "upper.obj"}, {"name": "lower", "mesh": "lower.obj"}],
  "joints": [{"name": "upper_fixed", "type": "weld", "parent": "ground", "child": "upper"},
             {"name": "lower_fixed", "type": "weld", "parent": "ground", "child": "lower"}],
  "muscles": [)" << muscle("left", -half_distance_m)
                                    << ",\n" << muscle("right", half_distance_m) << "]\n}\n";
  const Registry registry = make_default_registry();
  return compile(load_scene(dir / "scene.json", registry), registry);
}

struct PairRun {
  std::vector<Points3> left, right;  // surfaces per frame
  std::vector<double> overlap;       // max muscle overlap of the left belly per frame (m)
};

PairRun run_pair(const Model& model, int frames) {
  State state = make_state(model);
  PairRun r;
  for (int f = 0; f < frames; ++f) {
    state.time_s = 0.02 * f;
    forward(model, state);
    r.left.push_back(state.muscles[0].surface);
    r.right.push_back(state.muscles[1].surface);
    r.overlap.push_back(state.muscles[0].max_muscle_overlap_m);
  }
  return r;
}

double mean_x(const Points3& S) { return S.col(0).mean(); }

}  // namespace

TEST(SolidDynamicsGroup, OverlappingBelliesSeparateAndDoNotPull) {
  const int frames = 12;
  const PairRun with = run_pair(make_pair_scene("touching", 0.0105, true), frames);
  const PairRun without = run_pair(make_pair_scene("touching_free", 0.0105, false), frames);
  ASSERT_EQ(with.overlap.size(), static_cast<size_t>(frames));
  // At rest the surfaces overlap by about 3 mm (a little less: the ellipsoid is a polyhedron).
  EXPECT_GT(with.overlap.front(), 2.0e-3);
  EXPECT_NEAR(without.overlap.back(), without.overlap.front(), 2e-4);  // nothing pushes them apart
  EXPECT_LT(with.overlap.back(), 0.5 * with.overlap.front());
  for (int f = 1; f < frames; ++f) {
    // Pushed apart, never pulled together: the left belly moves to −x and the right to +x relative
    // to the free run.
    EXPECT_LE(mean_x(with.left[f]) - mean_x(without.left[f]), 1e-9) << "frame " << f;
    EXPECT_GE(mean_x(with.right[f]) - mean_x(without.right[f]), -1e-9) << "frame " << f;
  }
  EXPECT_LT(mean_x(with.left.back()) - mean_x(without.left.back()), -1e-4);
  EXPECT_GT(mean_x(with.right.back()) - mean_x(without.right.back()), 1e-4);
  RecordProperty("overlap_start_mm", std::to_string(with.overlap.front() * 1e3));
  RecordProperty("overlap_end_mm", std::to_string(with.overlap.back() * 1e3));
}

TEST(SolidDynamicsGroup, ApartBelliesAreNotPulledTogether) {
  // 2 mm apart (within the 5 mm adjacency margin, so the pair is checked every sub-step).
  const PairRun with = run_pair(make_pair_scene("apart", 0.013, true), 4);
  const PairRun without = run_pair(make_pair_scene("apart_free", 0.013, false), 4);
  for (size_t f = 0; f < with.left.size(); ++f) {
    EXPECT_EQ((with.left[f] - without.left[f]).cwiseAbs().maxCoeff(), 0.0) << "frame " << f;
    EXPECT_EQ((with.right[f] - without.right[f]).cwiseAbs().maxCoeff(), 0.0) << "frame " << f;
  }
}

TEST(SolidDynamicsGroup, SameResultsForOneAndTwoThreads) {
  const Model model = make_pair_scene("threads", 0.0105, true);
  PairRun one, two;
  {
    ThreadLimit limit(1);
    one = run_pair(model, 4);
  }
  {
    ThreadLimit limit(2);
    two = run_pair(model, 4);
  }
  for (size_t f = 0; f < one.left.size(); ++f) {
    EXPECT_EQ((one.left[f] - two.left[f]).cwiseAbs().maxCoeff(), 0.0) << "frame " << f;
    EXPECT_EQ((one.right[f] - two.right[f]).cwiseAbs().maxCoeff(), 0.0) << "frame " << f;
  }
}

// "solid_dynamics" and "solid-dynamics" are one group: the muscles still push each other apart,
// with the same results as when both are spelled alike.
TEST(SolidDynamicsGroup, BothSpellingsAreOneGroup) {
  const Model mixed = make_pair_scene("spellings", 0.0105, true, "solid-dynamics");
  ASSERT_EQ(mixed.muscle_groups.size(), 1u);
  EXPECT_EQ(mixed.muscle_groups[0].muscles.size(), 2u);
  EXPECT_EQ(mixed.muscle_groups[0].representation, "solid_dynamics");
  const PairRun a = run_pair(mixed, 3);
  const PairRun b = run_pair(make_pair_scene("spellings_same", 0.0105, true), 3);
  for (size_t f = 0; f < a.left.size(); ++f) {
    EXPECT_EQ((a.left[f] - b.left[f]).cwiseAbs().maxCoeff(), 0.0) << "frame " << f;
    EXPECT_EQ((a.right[f] - b.right[f]).cwiseAbs().maxCoeff(), 0.0) << "frame " << f;
  }
}

// The muscle-contact options act on pairs: members giving different values are bad input naming
// both muscles; the same value given twice (or the default written out) is accepted.
TEST(SolidDynamicsGroup, ConflictingContactOptionsAreRejected) {
  for (const std::string& extra : {std::string(R"(, "muscle_margin": 0.01)"), std::string(R"(, "muscle_contact_samples": 3)"),
                                   std::string(R"(, "muscle_contact": 2, "muscle_contact_stiffness": 100)")}) {
    SCOPED_TRACE(extra);
    try {
      make_pair_scene("conflict", 0.0105, true, "solid_dynamics", extra);
      ADD_FAILURE() << "conflicting options accepted";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::bad_input);
      const std::string msg = e.what();
      EXPECT_NE(msg.find("'left'"), std::string::npos) << msg;
      EXPECT_NE(msg.find("'right'"), std::string::npos) << msg;
    }
  }
  // muscle_contact 2 means on, as 1 does; the default margin written out is no conflict.
  EXPECT_NO_THROW(make_pair_scene("no_conflict", 0.0105, true, "solid_dynamics",
                                  R"(, "muscle_contact": 2, "muscle_margin": 0.005)"));
}
