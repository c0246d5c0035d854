// OpenSim import on the shared models: counts, poses from motions, couplers, bad input.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "fascicle/core/error.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/osim/osim_model.hpp"
#include "test_support.hpp"

namespace fascicle {
namespace {

struct Counts {
  const char* file;
  int bodies;  // without the ground
  int joints;
  int coordinates;
  int muscles;
  int paths;
  int couplers;
  int wrap_objects;
  bool all_meshes = true;  // the shared Geometry/ holds every mesh the model names
};

class OsimCounts : public ::testing::TestWithParam<Counts> {};

TEST_P(OsimCounts, LoadWithTheRightCounts) {
  const Counts& e = GetParam();
  OsimImportOptions opt;
  opt.geometry_dirs = {test::data_path("opensim/Geometry")};
  const OsimModel m = read_osim(test::data_path(e.file), opt);
  int muscles = 0;
  for (const auto& a : m.actuators) muscles += a.muscle.has_value();
  EXPECT_EQ(static_cast<int>(m.skeleton.bodies.size()), e.bodies);
  EXPECT_EQ(static_cast<int>(m.skeleton.joints.size()), e.joints);
  EXPECT_EQ(muscles, e.muscles);
  EXPECT_EQ(static_cast<int>(m.paths.paths.size()), e.paths);
  EXPECT_EQ(static_cast<int>(m.skeleton.couplers.size()), e.couplers);
  EXPECT_EQ(static_cast<int>(m.paths.wrap_objects.size()), e.wrap_objects);
  const Skeleton sk = compile(m.skeleton);
  EXPECT_EQ(sk.num_coordinates(), e.coordinates);
  EXPECT_EQ(sk.num_bodies(), e.bodies + 1);
  if (e.all_meshes) EXPECT_TRUE(m.missing_meshes.empty()) << m.missing_meshes.front();
}

INSTANTIATE_TEST_SUITE_P(
    SharedModels, OsimCounts,
    ::testing::Values(
        Counts{"opensim/models/gait2392_thelen2003muscle.osim", 12, 12, 23, 92, 92, 0, 0},
        Counts{"opensim/models/gait2392_millard2012muscle.osim", 12, 12, 23, 92, 92, 0, 0},
        Counts{"opensim/models/Rajagopal/Rajagopal2016.osim", 22, 22, 39, 80, 80, 2, 40},
        Counts{"opensim/models/arm26.osim", 3, 3, 2, 6, 6, 0, 4},
        Counts{"opensim/models/subject_walk_armless_18musc.osim", 14, 14, 25, 18, 18, 2, 40, false},
        Counts{"opensim/models/walk_gait1018_subject01.osim", 12, 12, 10, 18, 18, 0, 0, false},
        Counts{"opensim/models/test_wrapAllVis.osim", 4, 4, 5, 1, 1, 0, 6}),
    [](const auto& info) { return test::make_test_name(info.param.file, info.index); });

// Poses of the walking motion give bone transforms that move continuously from frame to frame.
TEST(Osim, Gait2392WalkingPosesAreContinuous) {
  OsimImportOptions opt;
  opt.warn = false;
  const OsimModel m = read_osim(test::data_path("opensim/models/gait2392_thelen2003muscle.osim"), opt);
  const Skeleton sk = compile(m.skeleton);
  const auto motion_file = test::data_path("opensim/motions/subject01_walk1_ik.mot");
  const Table motion = read_table(motion_file);
  const MotionColumns mc = match_motion_columns(sk, motion, motion_file.string());
  SkeletonState st(sk);
  std::vector<Transform> previous;
  double largest_step = 0.0;
  std::string worst;
  for (long r = 0; r < motion.rows(); ++r) {
    calc_pose(sk, get_motion_pose(sk, motion, mc, r), st);
    const auto& X = st.get_body_transforms();
    for (const Transform& x : X) ASSERT_TRUE(x.matrix().allFinite());
    if (!previous.empty())
      for (std::size_t b = 1; b < X.size(); ++b)
        if ((X[b].translation() - previous[b].translation()).norm() > largest_step) {
          largest_step = (X[b].translation() - previous[b].translation()).norm();
          worst = sk.get_body_name(static_cast<int>(b)) + " at row " + std::to_string(r);
        }
    previous = X;
  }
  // 60 Hz walking at ~1.3 m/s: no body origin moves more than 5 cm between frames.
  EXPECT_LT(largest_step, 0.05) << worst;
  EXPECT_GT(largest_step, 0.005);
  // The pelvis follows pelvis_tx/ty/tz of the last frame exactly.
  const int pelvis = sk.find_body("pelvis");
  const long last = motion.rows() - 1;
  EXPECT_NEAR(st.get_body_transform(pelvis).translation().x(),
              motion.data(last, find_column(motion, "pelvis_tx")), 1e-12);
}

// Rajagopal's patella coordinates are coupled to the knee angle: after assembly they equal the
// coupler function of the knee angle, and Simbody's constraint residual vanishes.
TEST(Osim, RajagopalCoupledKneeFollowsItsCoupler) {
  OsimImportOptions opt;
  opt.warn = false;
  const OsimModel m = read_osim(test::data_path("opensim/models/Rajagopal/Rajagopal2016.osim"), opt);
  const Skeleton sk = compile(m.skeleton);
  const auto motion_file = test::data_path("opensim/motions/subject_walk_armless_coordinates.mot");
  const Table motion = read_table(motion_file);
  const MotionColumns mc = match_motion_columns(sk, motion, motion_file.string(), false);
  SkeletonState st(sk);
  const int knee = sk.find_coordinate("knee_angle_r");
  const int beta = sk.find_coordinate("knee_angle_r_beta");
  ASSERT_GE(knee, 0);
  ASSERT_GE(beta, 0);
  for (long r = 0; r < motion.rows(); r += 17) {
    calc_pose(sk, get_motion_pose(sk, motion, mc, r), st);
    EXPECT_NEAR(st.get_q()[beta], st.get_q()[knee], 1e-15);  // Rajagopal: beta = knee (linear 1 0)
    EXPECT_LT(calc_constraint_error(sk, st), 1e-14);
  }
}

TEST(Osim, BadInputNamesFileAndLine) {
  const auto dir = test::scratch_dir("osim_bad");
  const auto write = [&](const char* name, const std::string& s) {
    std::ofstream(dir / name) << s;
    return dir / name;
  };
  const auto broken = write("broken.osim", "<OpenSimDocument Version=\"40000\">\n<Model name=\"m\">\n</Mod>\n");
  try {
    read_osim(broken);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.context().file, broken.string());
    EXPECT_TRUE(e.context().line.has_value());
  }
  const auto joint = write("joint.osim",
                           "<OpenSimDocument Version=\"40000\">\n<Model name=\"m\">\n<JointSet><objects>\n"
                           "<ConstantCurvatureJoint name=\"p\"/>\n</objects></JointSet></Model></OpenSimDocument>\n");
  try {
    read_osim(joint);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(*e.context().line, 4);
    EXPECT_EQ(e.context().object, "p");
    EXPECT_NE(std::string(e.what()).find("ConstantCurvatureJoint"), std::string::npos);
  }
  const auto motion = write("m.mot", "x\ninDegrees=no\nendheader\ntime\tnot_a_coordinate\n0\t1\n");
  const OsimModel arm = read_osim(test::data_path("opensim/models/arm26.osim"));
  const Skeleton sk = compile(arm.skeleton);
  EXPECT_THROW(match_motion_columns(sk, read_table(motion), motion.string()), Error);
}

}  // namespace
}  // namespace fascicle
