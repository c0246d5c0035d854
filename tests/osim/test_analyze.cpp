// The analysis glue: body Jacobians against finite differences of poses, exact moment arms against
// central differences of path length on real models (coupled coordinates, moving and conditional
// points, cylinder and ellipsoid wraps), spanned coordinates, MuscleAnalysis tables, bad input.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <algorithm>
#include <string>

#include "fascicle/core/error.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/osim/analyze.hpp"
#include "test_support.hpp"

namespace fascicle {
namespace {

OsimAnalysisModel load(const std::string& rel, std::optional<PathOptions> po = std::nullopt) {
  OsimImportOptions import;
  import.warn = false;
  import.geometry_dirs = {test::data_path("opensim/Geometry")};
  return load_osim_model(test::data_path(rel), import, po);
}

// Poses: some rows of a motion (unknown columns ignored).
std::vector<VecX> motion_poses(const OsimAnalysisModel& model, const std::string& rel,
                               std::vector<long> rows) {
  const Table motion = read_table(test::data_path(rel));
  const MotionColumns mc = match_motion_columns(model.skeleton, motion, rel, false);
  std::vector<VecX> out;
  for (long r : rows) out.push_back(get_motion_pose(model.skeleton, motion, mc, std::min(r, motion.rows() - 1)));
  return out;
}

Mat3 rotation_of(const Transform& X) { return X.linear(); }

TEST(BodyJacobians, MatchFiniteDifferencesOfBodyPosesWithCouplers) {
  const OsimAnalysisModel model = load("opensim/models/Rajagopal/Rajagopal2016.osim");
  const auto poses = motion_poses(model, "opensim/motions/subject_walk_armless_coordinates.mot", {40});
  const Skeleton& sk = model.skeleton;
  OsimFrame frame(model), plus(model), minus(model);
  calc_frame(model, poses[0], frame, true);
  const double h = 1e-6;
  double max_err = 0;
  int checked = 0;
  for (int c = 0; c < sk.num_coordinates(); ++c) {
    const CoordinateInfo& info = sk.get_coordinate(c);
    if (info.dependent_on >= 0 || info.spec.locked) continue;
    VecX qp = frame.skeleton.get_q(), qm = qp;
    qp[c] += h;
    qm[c] -= h;
    calc_frame(model, qp, plus, false);
    calc_frame(model, qm, minus, false);
    for (int b = 1; b < sk.num_bodies(); ++b) {
      const Transform& Xp = plus.skeleton.get_body_transform(b);
      const Transform& Xm = minus.skeleton.get_body_transform(b);
      // Angular velocity from dR/dq Rᵀ (skew part); velocity of the body point at the origin.
      const Mat3 W = (rotation_of(Xp) - rotation_of(Xm)) / (2 * h) *
                     frame.skeleton.get_body_transform(b).linear().transpose();
      const Vec3 w(0.5 * (W(2, 1) - W(1, 2)), 0.5 * (W(0, 2) - W(2, 0)), 0.5 * (W(1, 0) - W(0, 1)));
      // The station fixed on the body that is at the origin now.
      const Vec3 s = frame.skeleton.get_body_transform(b).inverse() * Vec3::Zero();
      const Vec3 v_fd = (Xp * s - Xm * s) / (2 * h);
      const auto& J = frame.jacobians.J[b];
      max_err = std::max(max_err, (J.col(c).head<3>() - w).norm());
      max_err = std::max(max_err, (J.col(c).tail<3>() - v_fd).norm());
      ++checked;
    }
  }
  EXPECT_GT(checked, 200);
  EXPECT_LT(max_err, 1e-7);
  // Columns of dependent coordinates are zero; the patella moves with knee_angle_r.
  const int beta = sk.find_coordinate("knee_angle_r_beta");
  const int knee = sk.find_coordinate("knee_angle_r");
  const int patella = sk.find_body("patella_r");
  ASSERT_GE(beta, 0);
  ASSERT_GE(patella, 0);
  EXPECT_EQ(frame.jacobians.J[patella].col(beta).norm(), 0.0);
  EXPECT_GT(frame.jacobians.J[patella].col(knee).norm(), 0.1);
}

struct MomentArmCase {
  const char* model;
  const char* motion;
  std::vector<long> rows;
  int min_checks;
};

class MomentArms : public ::testing::TestWithParam<MomentArmCase> {};

// r_j = −dL/dq_j by central differences (h = 1e-6), dependent coordinates assembled at each
// perturbed pose. Poses where the set of active points or wraps changes within ±h are skipped.
TEST_P(MomentArms, EqualCentralDifferencesOfLength) {
  const MomentArmCase& mc = GetParam();
  PathOptions po;
  po.tolerance_m = 1e-13;  // converge multi-wrap paths fully (OpenSim stops at 0.5 mm)
  po.max_iterations = 100;
  const OsimAnalysisModel model = load(mc.model, po);
  const Skeleton& sk = model.skeleton;
  const auto poses = motion_poses(model, mc.motion, mc.rows);
  OsimFrame frame(model), plus(model), minus(model);
  PathResult r0, rp, rm;
  int current_path = 0;
  const double h = 1e-6;
  double max_err = 0;
  std::string worst;
  int checks = 0, skipped = 0, non_geodesic = 0;
  double non_geodesic_err = 0;
  // Wraps over non-spherical ellipsoids (and tori) are not shortest paths: counted apart.
  auto is_geodesic = [&](const PathResult& pr) {
    const CompiledPath& cp = model.paths.paths[current_path];
    for (std::size_t w = 0; w < pr.wraps.size(); ++w) {
      if (!pr.wraps[w].wrapping) continue;
      const WrapObjectSpec& o = model.paths.wrap_objects[cp.wraps[w].object].spec;
      if (o.shape == WrapShape::torus) return false;
      if (o.shape == WrapShape::ellipsoid &&
          (o.radii.maxCoeff() - o.radii.minCoeff()) > 1e-12 * o.radii.maxCoeff())
        return false;
    }
    return true;
  };
  auto same_topology = [](const PathResult& a, const PathResult& b) {
    if (a.vertices.size() != b.vertices.size()) return false;
    for (std::size_t i = 0; i < a.vertices.size(); ++i)
      if (a.vertices[i].point != b.vertices[i].point || a.vertices[i].wrap != b.vertices[i].wrap)
        return false;
    return true;
  };
  for (const VecX& q : poses) {
    calc_frame(model, q, frame, true);
    for (int m = 0; m < model.num_muscles(); ++m) {
      const int p = model.muscle_path[m];
      current_path = p;
      calc_path_length(model, frame, p, r0);
      const VecX r = calc_path_moment_arms(model, frame, p, r0);
      for (int c = 0; c < sk.num_coordinates(); ++c) {
        const CoordinateInfo& info = sk.get_coordinate(c);
        if (info.dependent_on >= 0 || info.spec.locked) continue;
        VecX qp = frame.skeleton.get_q(), qm = qp;
        qp[c] += h;
        qm[c] -= h;
        calc_frame(model, qp, plus, false);
        calc_frame(model, qm, minus, false);
        const double Lp = calc_path_length(model, plus, p, rp);
        const double Lm = calc_path_length(model, minus, p, rm);
        if (!same_topology(rp, r0) || !same_topology(rm, r0)) {
          ++skipped;
          continue;
        }
        const double fd = -(Lp - Lm) / (2 * h);
        const double e = std::abs(fd - r[c]);
        if (!is_geodesic(r0)) {
          non_geodesic_err = std::max(non_geodesic_err, e);
          ++non_geodesic;
          continue;
        }
        ++checks;
        if (e > max_err) {
          max_err = e;
          worst = model.get_muscle_name(m) + " / " + info.spec.name;
        }
      }
    }
  }
  std::printf("[moment arms] %s: %d checks (%d skipped at switches), max |r - FD| = %.3g m (%s)\n",
              mc.model, checks, skipped, max_err, worst.c_str());
  if (non_geodesic > 0)
    std::printf("[moment arms]   over non-spherical ellipsoids: %d checks, max |r - FD| = %.3g m\n",
                non_geodesic, non_geodesic_err);
  EXPECT_GE(checks, mc.min_checks);
  EXPECT_LT(max_err, 1e-6) << worst;
  // Over non-spherical ellipsoids the wrap piece is differentiated as the central-section length
  // it is (path module), so r = −dL/dq there too (was 5.5e-4 m on arm26 before).
  EXPECT_LT(non_geodesic_err, 1e-6);
}

INSTANTIATE_TEST_SUITE_P(
    SharedModels, MomentArms,
    ::testing::Values(
        MomentArmCase{"opensim/models/gait2392_thelen2003muscle.osim",
                      "opensim/motions/subject01_walk1_ik.mot", {0, 60, 120}, 3 * 92 * 10},
        MomentArmCase{"opensim/models/Rajagopal/Rajagopal2016.osim",
                      "opensim/motions/subject_walk_armless_coordinates.mot", {0, 100}, 2 * 80 * 10},
        MomentArmCase{"opensim/models/arm26.osim", "opensim/motions/arm26_InverseKinematics.mot",
                      {0, 40, 80, 120}, 20}),
    [](const auto& info) { return test::make_test_name(info.param.model, info.index); });

TEST(SpannedCoordinates, Arm26AndGait2392) {
  const OsimAnalysisModel arm = load("opensim/models/arm26.osim");
  std::vector<std::string> names;
  for (int c : find_spanned_coordinates(arm)) names.push_back(arm.skeleton.get_coordinate(c).spec.name);
  EXPECT_EQ(names, (std::vector<std::string>{"r_shoulder_elev", "r_elbow_flex"}));

  const OsimAnalysisModel gait = load("opensim/models/gait2392_thelen2003muscle.osim");
  names.clear();
  for (int c : find_spanned_coordinates(gait)) names.push_back(gait.skeleton.get_coordinate(c).spec.name);
  auto has = [&](const std::string& n) { return std::find(names.begin(), names.end(), n) != names.end(); };
  EXPECT_FALSE(has("pelvis_tx"));
  EXPECT_FALSE(has("pelvis_tilt"));
  for (const char* n : {"hip_flexion_r", "hip_adduction_l", "knee_angle_r", "ankle_angle_l",
                        "lumbar_extension"})
    EXPECT_TRUE(has(n)) << n;
  // Rajagopal: the patella's coupled coordinate counts for knee_angle_r, and is not listed itself.
  const OsimAnalysisModel raj = load("opensim/models/Rajagopal/Rajagopal2016.osim");
  names.clear();
  for (int c : find_spanned_coordinates(raj)) names.push_back(raj.skeleton.get_coordinate(c).spec.name);
  EXPECT_TRUE(std::find(names.begin(), names.end(), "knee_angle_r") != names.end());
  EXPECT_TRUE(std::find(names.begin(), names.end(), "knee_angle_r_beta") == names.end());
}

TEST(MuscleAnalysisTables, Arm26StaticEquilibriumIdentitiesAndFiles) {
  const OsimAnalysisModel model = load("opensim/models/arm26.osim");
  Table motion = read_table(test::data_path("opensim/motions/arm26_InverseKinematics.mot"));
  MuscleAnalysisOptions opt;
  opt.motion_file = "arm26_InverseKinematics.mot";
  opt.progress = false;
  const MuscleAnalysis a = calc_muscle_analysis(model, motion, opt);
  ASSERT_EQ(a.length.rows(), motion.rows());
  ASSERT_EQ(a.length.cols(), 6);
  EXPECT_EQ(a.moment_arm_coordinates, (std::vector<std::string>{"r_shoulder_elev", "r_elbow_flex"}));
  OsimFrame frame(model);
  PathResult pr;
  const MotionColumns mc = match_motion_columns(model.skeleton, motion, "", true);
  for (long row = 0; row < motion.rows(); row += 30) {
    calc_frame(model, get_motion_pose(model.skeleton, motion, mc, row), frame, true);
    for (int m = 0; m < 6; ++m) {
      const double L = calc_path_length(model, frame, model.muscle_path[m], pr);
      const VecX r = calc_path_moment_arms(model, frame, model.muscle_path[m], pr);
      EXPECT_DOUBLE_EQ(a.length(row, m), L);
      EXPECT_DOUBLE_EQ(a.moment_arms[1](row, m), r[model.skeleton.find_coordinate("r_elbow_flex")]);
      // Geometry: L = lT + lM cos α; equilibrium at zero speed: F_T = (F_active + F_passive) cos α.
      const double ca = std::cos(a.pennation(row, m));
      EXPECT_NEAR(a.tendon_length(row, m) + a.fiber_length(row, m) * ca, L, 1e-9);
      EXPECT_NEAR(a.tendon_force(row, m),
                  (a.active_fiber_force(row, m) + a.passive_fiber_force(row, m)) * ca,
                  1e-6 * model.musculotendons[m].params.max_isometric_force_N);
      EXPECT_NEAR(a.normalized_fiber_length(row, m),
                  a.fiber_length(row, m) / model.musculotendons[m].params.optimal_fiber_length_m, 1e-12);
    }
  }
  // The elbow flexors have positive elbow moment arms, the triceps negative.
  const int elbow = 1;
  EXPECT_GT(a.moment_arms[elbow](60, model.find_muscle("BIClong")), 0.005);
  EXPECT_LT(a.moment_arms[elbow](60, model.find_muscle("TRIlong")), -0.005);
  // Activations from a table change the active force.
  Table act;
  act.time = motion.time;
  act.labels = {"BIClong"};
  act.data = MatX::Constant(motion.rows(), 1, 1.0);
  opt.activations = &act;
  opt.activations_file = "act.sto";
  const MuscleAnalysis full = calc_muscle_analysis(model, motion, opt);
  const int bic = model.find_muscle("BIClong");
  EXPECT_GT(full.active_fiber_force(60, bic), 5 * a.active_fiber_force(60, bic));
  EXPECT_EQ(full.active_fiber_force(60, 0 == bic ? 1 : 0), a.active_fiber_force(60, 0 == bic ? 1 : 0));

  const auto dir = test::scratch_dir("analyze_tables");
  const auto files = write_muscle_analysis(dir, a);
  ASSERT_EQ(files.size(), 10u);
  const Table back = read_table(dir / "arm26_MuscleAnalysis_MomentArm_r_elbow_flex.sto");
  EXPECT_EQ(back.labels, a.muscles);
  EXPECT_DOUBLE_EQ(back.data(60, bic), a.moment_arms[elbow](60, bic));
  for (const auto& f : std::filesystem::directory_iterator(dir))
    EXPECT_EQ(f.path().extension(), ".sto") << f.path();
}

TEST(AnalyzeBadInput, UnknownCoordinateColumnNamesFileAndColumn) {
  const OsimAnalysisModel model = load("opensim/models/arm26.osim");
  Table motion = read_table(test::data_path("opensim/motions/arm26_InverseKinematics.mot"));
  motion.labels[1] = "r_wrist_dev";
  MuscleAnalysisOptions opt;
  opt.motion_file = "bad.mot";
  opt.progress = false;
  try {
    calc_muscle_analysis(model, motion, opt);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("bad.mot"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("r_wrist_dev"), std::string::npos) << e.what();
  }
  opt.coordinates = {"nope"};
  motion.labels[1] = "r_elbow_flex";
  EXPECT_THROW(calc_muscle_analysis(model, motion, opt), Error);
}

TEST(ParsePose, ValuesDegreesAndErrors) {
  const OsimAnalysisModel model = load("opensim/models/Rajagopal/Rajagopal2016.osim");
  const Skeleton& sk = model.skeleton;
  const VecX q = parse_pose(sk, {"knee_angle_r=-1.2", "hip_flexion_r=30deg", "pelvis_tx=0.5"});
  EXPECT_DOUBLE_EQ(q[sk.find_coordinate("knee_angle_r")], -1.2);
  EXPECT_NEAR(q[sk.find_coordinate("hip_flexion_r")], M_PI / 6, 1e-15);
  EXPECT_DOUBLE_EQ(q[sk.find_coordinate("pelvis_tx")], 0.5);
  EXPECT_THROW(parse_pose(sk, {"no_such=1"}), Error);
  EXPECT_THROW(parse_pose(sk, {"knee_angle_r_beta=1"}), Error);
  EXPECT_THROW(parse_pose(sk, {"knee_angle_r=abc"}), Error);
  EXPECT_THROW(parse_pose(sk, {"pelvis_tx=3deg"}), Error);
  EXPECT_THROW(parse_pose(sk, {"knee_angle_r"}), Error);
}

TEST(PathGeometry, WritesPathsAndBones) {
  const OsimAnalysisModel model = load("opensim/models/arm26.osim");
  const VecX q = parse_pose(model.skeleton, {"r_elbow_flex=90deg"});
  const auto dir = test::scratch_dir("path_geometry");
  const auto files = write_path_geometry(dir, model, q);
  ASSERT_EQ(files.size(), 2u);
  for (const auto& f : files) EXPECT_GT(std::filesystem::file_size(f), 100u) << f;
}

}  // namespace
}  // namespace fascicle
