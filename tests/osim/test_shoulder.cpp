// The two shoulder models (ScapulothoracicJoint, EllipsoidJoint): they load, every path's length
// is finite and continuous over a sweep of each scapula coordinate, moment arms equal central
// differences of length at a few poses, and a synthetic sweep runs through the MuscleAnalysis.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "fascicle/core/error.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/osim/analyze.hpp"
#include "test_support.hpp"

namespace fascicle {
namespace {

struct ShoulderCase {
  const char* model;
  JointType joint;
  std::vector<std::string> unsupported;  // entries expected in the single warning's list
  int paths;
};

OsimAnalysisModel load(const std::string& rel, std::optional<PathOptions> po = std::nullopt) {
  OsimImportOptions import;
  import.warn = false;
  import.geometry_dirs = {test::data_path("opensim/Geometry")};
  return load_osim_model(test::data_path(rel), import, po);
}

std::vector<int> scapula_coordinates(const OsimAnalysisModel& m, JointType type) {
  std::vector<int> out;
  for (int c = 0; c < m.skeleton.num_coordinates(); ++c)
    if (m.skeleton.get_joints()[m.skeleton.get_coordinate(c).joint].type == type) out.push_back(c);
  return out;
}

// 0: only spheres, cylinders and no wrap; 1: one wrap over a non-spherical ellipsoid; 2: a torus,
// or a non-spherical ellipsoid together with other wraps (iterated wraps: no exact envelope).
int wrap_kind(const OsimAnalysisModel& model, int path, const PathResult& pr) {
  const CompiledPath& cp = model.paths.paths[path];
  int wrapping = 0, ellipsoids = 0;
  bool torus = false;
  for (std::size_t w = 0; w < pr.wraps.size(); ++w) {
    if (!pr.wraps[w].wrapping) continue;
    ++wrapping;
    const WrapObjectSpec& o = model.paths.wrap_objects[cp.wraps[w].object].spec;
    torus = torus || o.shape == WrapShape::torus;
    ellipsoids += o.shape == WrapShape::ellipsoid &&
                  o.radii.maxCoeff() - o.radii.minCoeff() > 1e-12 * o.radii.maxCoeff();
  }
  if (torus || (ellipsoids > 0 && wrapping > 1)) return 2;
  return ellipsoids > 0 ? 1 : 0;
}

bool same_topology(const PathResult& a, const PathResult& b) {
  if (a.vertices.size() != b.vertices.size()) return false;
  for (std::size_t i = 0; i < a.vertices.size(); ++i)
    if (a.vertices[i].point != b.vertices[i].point || a.vertices[i].wrap != b.vertices[i].wrap) return false;
  return true;
}

class Shoulder : public ::testing::TestWithParam<ShoulderCase> {};

TEST_P(Shoulder, LoadsWithTheJointAndListsWhatIsUnsupported) {
  const ShoulderCase& sc = GetParam();
  const OsimAnalysisModel model = load(sc.model);
  EXPECT_EQ(static_cast<int>(model.paths.paths.size()), sc.paths);
  const std::vector<int> coords = scapula_coordinates(model, sc.joint);
  EXPECT_EQ(coords.size(), sc.joint == JointType::scapulothoracic ? 4u : 3u);
  for (const std::string& u : sc.unsupported)
    EXPECT_TRUE(std::any_of(model.osim.unsupported.begin(), model.osim.unsupported.end(),
                            [&](const std::string& s) { return s.find(u) != std::string::npos; }))
        << u;
  for (const std::string& s : model.osim.unsupported)  // the joints themselves are supported now
    EXPECT_EQ(s.find("Joint"), std::string::npos) << s;
}

// Sweep each scapula coordinate over ±0.4 rad about its default in 0.005 rad steps: every path
// length is finite, and continuous: no step changes the length by more than 0.1 mm beyond the
// larger change of its two neighbouring steps (a smooth length, even one through a sharp minimum
// where origin and insertion nearly meet, changes its steps gradually; a wrap that jumps changes
// one step by millimetres) — except at OpenSim's two discontinuities by design,
// which are counted and reported: a path point entering or leaving a wrap object (the wrap is
// dropped), and a wrap whose range spans several segments moving from one segment to another
// (OpenSim wraps the first segment that crosses the object; when that segment stops crossing,
// the next one that does takes the wrap, with its whole arc at once).
TEST_P(Shoulder, PathLengthsFiniteAndContinuousOverScapulaSweeps) {
  const ShoulderCase& sc = GetParam();
  PathOptions po;  // multi-wrap paths converged fully: OpenSim's 0.5 mm stop makes steps of that size
  po.tolerance_m = 1e-12;
  po.max_iterations = 100;
  const OsimAnalysisModel model = load(sc.model, po);
  OsimFrame frame(model);
  PathResult pr;
  const double dq = 0.005;
  const int np = static_cast<int>(model.paths.paths.size());
  double worst_jump = 0.0;
  std::string worst;
  int inside_steps = 0, segment_steps = 0, steps = 0;
  for (const int c : scapula_coordinates(model, sc.joint)) {
    VecX q = model.skeleton.get_default_q();
    const double q0 = q[c];
    const int n = 161;
    MatX L(n, np);
    Eigen::Matrix<bool, Eigen::Dynamic, Eigen::Dynamic> inside(n, np);
    std::vector<std::vector<std::vector<int>>> segment(n, std::vector<std::vector<int>>(np));
    for (int k = 0; k < n; ++k) {
      q[c] = q0 + (k - n / 2) * dq;
      calc_frame(model, q, frame, false);
      for (int p = 0; p < np; ++p) {
        L(k, p) = calc_path_length(model, frame, p, pr);
        ASSERT_TRUE(std::isfinite(L(k, p)) && L(k, p) > 0.0) << model.osim.paths.paths[p].name;
        bool in = false;
        for (const auto& w : pr.wraps) in = in || w.status == WrapStatus::inside;
        inside(k, p) = in;
        // Per wrap: the path point before its first tangent point (−1 when not wrapping).
        segment[k][p].assign(pr.wraps.size(), -1);
        for (std::size_t v = 1; v < pr.vertices.size(); ++v)
          if (pr.vertices[v].wrap >= 0 && pr.vertices[v - 1].wrap != pr.vertices[v].wrap)
            segment[k][p][pr.vertices[v].wrap] = pr.vertices[v - 1].point;
      }
    }
    for (int p = 0; p < np; ++p)
      for (int k = 1; k + 2 < n; ++k) {  // the step k → k+1 and its neighbours
        if (inside(k - 1, p) != inside(k, p) || inside(k, p) != inside(k + 1, p) ||
            inside(k + 1, p) != inside(k + 2, p)) {
          ++inside_steps;
          continue;
        }
        bool moved = false;
        for (int a = k - 1; a < k + 2; ++a)
          for (std::size_t w = 0; w < segment[a][p].size(); ++w)
            moved = moved || (segment[a][p][w] >= 0 && segment[a + 1][p][w] >= 0 &&
                              segment[a][p][w] != segment[a + 1][p][w]);
        if (moved) {
          ++segment_steps;
          continue;
        }
        ++steps;
        const double jump = std::abs(L(k + 1, p) - L(k, p)) -
                            std::max(std::abs(L(k, p) - L(k - 1, p)), std::abs(L(k + 2, p) - L(k + 1, p)));
        if (jump > worst_jump) {
          worst_jump = jump;
          worst = model.osim.paths.paths[p].name + " / " + model.skeleton.get_coordinate(c).spec.name +
                  " at " + std::to_string(q0 + (k - n / 2) * dq);
        }
      }
  }
  std::printf("[shoulder] %s: %d sweep steps, largest step excess over its neighbours %.3g m (%s); "
              "skipped: %d steps next to a point entering or leaving a wrap object, %d next to a "
              "wrap moving to another segment\n",
              sc.model, steps, worst_jump, worst.c_str(), inside_steps, segment_steps);
  EXPECT_LT(worst_jump, 1e-4) << worst;
}

// r_j = −dL/dq_j by central differences (h = 1e-6) at the default pose and two others, for every
// unlocked coordinate, single ellipsoid wraps included; paths over a torus, or over a
// non-spherical ellipsoid together with other wraps, are counted apart (not shortest paths, and
// the iterated wraps have no exact envelope: docs/paths.md).
TEST_P(Shoulder, MomentArmsEqualCentralDifferences) {
  const ShoulderCase& sc = GetParam();
  PathOptions po;
  po.tolerance_m = 1e-13;
  po.max_iterations = 100;
  const OsimAnalysisModel model = load(sc.model, po);
  const Skeleton& sk = model.skeleton;
  OsimFrame frame(model), plus(model), minus(model);
  PathResult r0, rp, rm;
  const double h = 1e-6;
  double max_err = 0.0, other_err = 0.0;
  int checks = 0, others = 0, scapula_checks = 0;
  std::string worst;
  const std::vector<int> scap = scapula_coordinates(model, sc.joint);
  for (int pose = 0; pose < 3; ++pose) {
    VecX q = sk.get_default_q();
    for (int c = 0; c < sk.num_coordinates(); ++c)
      if (pose > 0 && sk.get_coordinate(c).dependent_on < 0 && !sk.get_coordinate(c).spec.locked)
        q[c] += 0.15 * std::sin(1.3 * c + 2.1 * pose);
    calc_frame(model, q, frame, true);
    for (int p = 0; p < static_cast<int>(model.paths.paths.size()); ++p) {
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
        const double fd = -(calc_path_length(model, plus, p, rp) - calc_path_length(model, minus, p, rm)) / (2 * h);
        if (!same_topology(rp, r0) || !same_topology(rm, r0)) continue;
        const double e = std::abs(fd - r[c]);
        const int kind = wrap_kind(model, p, r0);
        if (kind == 2) {
          other_err = std::max(other_err, e);
          ++others;
          continue;
        }
        ++checks;
        if (std::find(scap.begin(), scap.end(), c) != scap.end() && std::abs(r[c]) > 1e-4) ++scapula_checks;
        if (e > max_err) {
          max_err = e;
          worst = model.osim.paths.paths[p].name + " / " + info.spec.name;
        }
      }
    }
  }
  std::printf("[shoulder] %s: %d moment-arm checks (%d non-zero on scapula coordinates), max |r - FD| = "
              "%.3g m (%s); %d over tori or an ellipsoid among several wraps, max %.3g m\n",
              sc.model, checks, scapula_checks, max_err, worst.c_str(), others, other_err);
  EXPECT_GE(scapula_checks, 10);
  EXPECT_LT(max_err, 1e-6) << worst;
}

// A synthetic 1-s sweep of the scapula coordinates through the MuscleAnalysis and its tables.
TEST_P(Shoulder, SyntheticSweepRunsThroughMuscleAnalysis) {
  const ShoulderCase& sc = GetParam();
  const OsimAnalysisModel model = load(sc.model);
  const std::vector<int> scap = scapula_coordinates(model, sc.joint);
  Table motion;
  motion.name = "synthetic scapula sweep";
  const int rows = 21;
  motion.time = VecX::LinSpaced(rows, 0.0, 1.0);
  motion.data.resize(rows, static_cast<long>(scap.size()));
  const VecX q0 = model.skeleton.get_default_q();
  for (std::size_t k = 0; k < scap.size(); ++k) {
    motion.labels.push_back(model.skeleton.get_coordinate(scap[k]).spec.name);
    for (int r = 0; r < rows; ++r)
      motion.data(r, static_cast<long>(k)) = q0[scap[k]] + 0.3 * std::sin(2 * M_PI * motion.time[r] + k);
  }
  MuscleAnalysisOptions options;
  options.progress = false;
  options.motion_file = "synthetic";
  if (model.num_muscles() == 0) {  // PathSprings only: nothing for a MuscleAnalysis, said clearly
    try {
      calc_muscle_analysis(model, motion, options);
      FAIL() << "expected a bad-input error";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("no muscles"), std::string::npos) << e.what();
    }
    return;
  }
  const MuscleAnalysis a = calc_muscle_analysis(model, motion, options);
  ASSERT_EQ(a.length.rows(), rows);
  EXPECT_EQ(a.length.cols(), model.num_muscles());
  EXPECT_TRUE(a.length.allFinite());
  for (const MatX& r : a.moment_arms) EXPECT_TRUE(r.allFinite());
  // The scapula coordinates are spanned by some muscle of each model.
  int spanned = 0;
  for (const std::string& c : a.moment_arm_coordinates)
    for (const int s : scap) spanned += c == model.skeleton.get_coordinate(s).spec.name;
  EXPECT_GT(spanned, 0);
  const auto files = write_muscle_analysis(test::scratch_dir("shoulder_analysis"), a);
  EXPECT_GE(files.size(), 9u);
}

INSTANTIATE_TEST_SUITE_P(
    SharedModels, Shoulder,
    ::testing::Values(
        ShoulderCase{"opensim/models/ThoracoscapularShoulderModel.osim", JointType::scapulothoracic,
                     {"PointConstraint 'AC'", "SerratusAnterior_I"}, 33},
        ShoulderCase{"opensim/models/testGeometryPathWrapping_ShoulderWrappingWithPathSprings.osim",
                     JointType::ellipsoid, {}, 103}),
    [](const auto& info) { return test::make_test_name(info.param.model, info.index); });

}  // namespace
}  // namespace fascicle
