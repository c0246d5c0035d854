// "solid_dynamics" in a scene (src/scene/representation_solid_dynamics.cpp): the procedural leg's
// soleus as a B-spline solid driven by the knee and ankle motion. Volume held every frame, the
// origin end following the tibia rigidly, the insertion end keeping its distances to the Achilles
// insertion (inextensible tendon), the same rows as the rest mesh, finite and deterministic.
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/demo.hpp"
#include "fascicle/scene/driver.hpp"
#include "fascicle/scene/state.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace fascicle;

namespace {

struct LegRun {
  std::vector<MuscleFrame> frames;  // the soleus, per frame
  std::vector<std::vector<Transform>> X_ground_body;
  std::vector<double> time;
};

// The demo leg at 50 Hz with the soleus as a solid and the other muscles as action lines.
Model make_leg_model(const std::map<std::string, double>& options = {}) {
  DemoScene demo = make_demo_leg(50.0);
  for (auto& m : demo.spec.muscles) {
    m.representation = m.name == "soleus" ? "solid_dynamics" : "action_line";
    if (m.name == "soleus")
      for (const auto& [k, v] : options) m.options[k] = v;
  }
  return compile(demo.spec, make_default_registry());
}

LegRun run_leg(const Model& model, int frames, int first_frame = 0) {
  const DemoScene demo = make_demo_leg(50.0);
  const CoordinateTrajectory traj = make_trajectory(model, demo.motion, 50.0);
  const int soleus = model.find_muscle("soleus").v;
  State state = make_state(model);
  LegRun r;
  for (int f = first_frame; f < first_frame + frames; ++f) {
    state.time_s = traj.time[f];
    state.q = traj.q.row(f).transpose();
    forward(model, state);
    r.frames.push_back(state.muscles[soleus]);
    r.X_ground_body.push_back(state.X_ground_body);
    r.time.push_back(state.time_s);
  }
  return r;
}

}  // namespace

TEST(SolidDynamicsRepresentation, HoldsVolumeAndFollowsTheBones) {
  const Model model = make_leg_model();
  const Muscle& soleus = model.get_muscle(model.find_muscle("soleus"));
  // Frames 0–12 (0.24 s at 50 Hz): knee 0 → 8°, ankle −20° → −13°.
  const LegRun r = run_leg(model, 13);
  ASSERT_EQ(r.frames.size(), 13u);
  const BodyIndex tibia = model.find_body("tibia"), calcaneus = model.find_body("calcaneus");
  const auto motion = [&](int f, BodyIndex b) {
    return Transform(r.X_ground_body[f][b.v] * model.X_ground_body_default[b.v].inverse());
  };
  const MuscleFrame& first = r.frames.front();
  ASSERT_FALSE(first.fibres.empty());
  const Vec3 achilles0 = r.X_ground_body[0][calcaneus.v] * soleus.insertion.p_body_centroid;
  // The fibre end nearer the tibial origin, per fibre (first or last sample).
  const Vec3 origin0 = r.X_ground_body[0][tibia.v] * soleus.origin.p_body_centroid;
  const bool origin_first =
      (first.fibres[0].row(0).transpose() - origin0).norm() < (first.fibres[0].bottomRows(1).transpose() - origin0).norm();
  double max_volume_error = 0.0, max_origin_error = 0.0, max_insertion_error = 0.0, max_motion = 0.0;
  for (size_t f = 0; f < r.frames.size(); ++f) {
    const MuscleFrame& mf = r.frames[f];
    ASSERT_EQ(mf.surface.rows(), soleus.rest_mesh.V.rows());
    ASSERT_TRUE(mf.surface.allFinite()) << "frame " << f;
    ASSERT_TRUE(std::isfinite(mf.volume_m3));
    max_volume_error = std::max(max_volume_error, std::abs(mf.relative_volume_change));
    EXPECT_TRUE(std::isfinite(mf.max_bone_penetration_m));
    EXPECT_TRUE(std::isfinite(mf.mean_fibre_length_m));
    // Origin end: rigid with the tibia (relative to frame 0, where the knee is at 0).
    const Transform X_t = motion(static_cast<int>(f), tibia) * motion(0, tibia).inverse();
    const Vec3 achilles = r.X_ground_body[f][calcaneus.v] * soleus.insertion.p_body_centroid;
    for (size_t k = 0; k < mf.fibres.size(); ++k) {
      const Points3& c0 = first.fibres[k];
      const Points3& c = mf.fibres[k];
      const Eigen::Index o = origin_first ? 0 : c.rows() - 1, i = origin_first ? c.rows() - 1 : 0;
      max_motion = std::max(max_motion, (c.row(o) - c0.row(o)).norm());
      max_origin_error = std::max(max_origin_error, (c.row(o).transpose() - X_t * c0.row(o).transpose()).norm());
      // Insertion end: its distance to the insertion landmark is kept (inextensible tendon).
      max_insertion_error = std::max(max_insertion_error, std::abs((c.row(i).transpose() - achilles).norm() -
                                                                   (c0.row(i).transpose() - achilles0).norm()));
    }
  }
  EXPECT_LE(max_volume_error, 1e-3);
  EXPECT_GT(max_motion, 1e-3);  // the knee moves the origin end by millimetres
  EXPECT_LE(max_origin_error, 1e-6 * std::max(1.0, max_motion / 1e-3));
  EXPECT_LE(max_insertion_error, 1e-6);
  RecordProperty("max_volume_error", std::to_string(max_volume_error));
  RecordProperty("max_origin_error_m", std::to_string(max_origin_error));
}

TEST(SolidDynamicsRepresentation, StartsFromAnyPoseAndIsDeterministic) {
  const Model model = make_leg_model();
  const LegRun a = run_leg(model, 3, 40), b = run_leg(model, 3, 40);
  for (size_t f = 0; f < a.frames.size(); ++f) {
    ASSERT_TRUE(a.frames[f].surface.allFinite());
    EXPECT_LE(std::abs(a.frames[f].relative_volume_change), 1e-3) << "frame " << f;
    EXPECT_EQ((a.frames[f].surface - b.frames[f].surface).cwiseAbs().maxCoeff(), 0.0) << "frame " << f;
    // Frames 40–42 (knee ≈ 54°, ankle ≈ 25°), started there from rest: far from the rest mesh.
    EXPECT_GT((a.frames[f].surface - model.get_muscle(model.find_muscle("soleus")).rest_mesh.V).cwiseAbs().maxCoeff(),
              0.01);
  }
}

TEST(SolidDynamicsRepresentation, RejectsBadOptions) {
  try {
    make_leg_model({{"lattice_u", 1.0}});
    FAIL() << "lattice_u = 1 accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("soleus"), std::string::npos) << e.what();
  }
}

// Integer options are checked before the conversion to int (NaN or 1e20 cast to int is undefined
// behaviour): bad input naming the muscle and the option.
TEST(SolidDynamicsRepresentation, RejectsNonFiniteAndHugeIntegerOptions) {
  for (const char* key : {"lattice_u", "lattice_v", "lattice_w", "degree", "reuse_factorisation", "settle_steps",
                          "slices", "fibre_rings", "fibre_count_around", "fibre_samples", "muscle_contact_samples"})
    for (const double v : {std::nan(""), 1e20, -1e20, 2.5}) {
      SCOPED_TRACE(std::string(key) + " = " + std::to_string(v));
      try {
        make_leg_model({{key, v}});
        ADD_FAILURE() << "accepted";
      } catch (const Error& e) {
        EXPECT_EQ(e.kind(), ErrorKind::bad_input);
        const std::string msg = e.what();
        EXPECT_NE(msg.find("soleus"), std::string::npos) << msg;
        EXPECT_NE(msg.find(key), std::string::npos) << msg;
      }
    }
  for (const char* key : {"time_step", "settle_step"})
    for (const double v : {std::nan(""), double(INFINITY), 0.0}) {
      SCOPED_TRACE(std::string(key) + " = " + std::to_string(v));
      EXPECT_THROW(make_leg_model({{key, v}}), Error);
    }
}

// A frame interval that needs more sub-steps than an int holds (0.02 s / 1e-12 s) is bad input
// naming the muscle, not an undefined cast.
TEST(SolidDynamicsRepresentation, RejectsTooManySubsteps) {
  const Model model = make_leg_model({{"time_step", 1e-12}});
  try {
    run_leg(model, 2);
    FAIL() << "2e10 sub-steps accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    const std::string msg = e.what();
    EXPECT_NE(msg.find("soleus"), std::string::npos) << msg;
    EXPECT_NE(msg.find("time_step"), std::string::npos) << msg;
  }
}
