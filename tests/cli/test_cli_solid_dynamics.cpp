// `fascicle run SCENE --representation solid-dynamics` end to end on a small knee scene: exit
// code, a ParaView series whose muscle surface keeps the rest mesh's topology, and per-muscle
// metrics (volume held, finite penetration and fibre lengths) in the .sto table.
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/mesh_io.hpp"
#include "fascicle/io/polydata.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/io/vtk_series.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <set>

namespace fs = std::filesystem;
using namespace fascicle;

namespace {

int run_cli(const std::string& args) {
  return test::run_command(std::string(FASCICLE_CLI_PATH) + " " + args + " > /dev/null 2>&1").exit_code;
}

// A knee of two box bones and an ellipsoidal posterior belly spanning it (metres), with a flexion
// of 0 → 25° over 0.1 s, written to `dir`.
fs::path write_knee_scene(const fs::path& dir) {
  const auto box_at = [](const Vec3& centre, const Vec3& half) {
    TriMesh m = make_box(half);
    m.V.rowwise() += centre.transpose();
    return m;
  };
  write_mesh(dir / "thigh.obj", box_at(Vec3(0.0, 0.17, 0.0), Vec3(0.02, 0.15, 0.02)));
  write_mesh(dir / "shank.obj", box_at(Vec3(0.0, -0.17, 0.0), Vec3(0.02, 0.15, 0.02)));
  TriMesh belly = make_ellipsoid(Vec3(0.014, 0.08, 0.012), 3);
  belly.V.col(0).array() -= 0.036;
  write_mesh(dir / "belly.obj", belly);
  std::ofstream(dir / "motion.mot") << "knee\nversion=1\nnRows=6\nnColumns=2\ninDegrees=yes\nendheader\n"
                                       "time\tknee_flexion\n0\t0\n0.02\t5\n0.04\t10\n0.06\t15\n0.08\t20\n0.1\t25\n";
  std::ofstream(dir / "scene.json") << R"({
  "fascicle_scene": 1, "name": "knee", "units": "m", "geometry_frame": "ground",
  "bodies": [{"name": "thigh", "mesh": "thigh.obj"}, {"name": "shank", "mesh": "shank.obj"}],
  "joints": [
    {"name": "hip_fixed", "type": "weld", "parent": "ground", "child": "thigh"},
    {"name": "knee", "type": "pin", "parent": "thigh", "child": "shank", "axis": [0, 0, -1],
     "coordinates": [{"name": "knee_flexion", "default": 0, "range": [0, 2.1]}]}],
  "muscles": [
    {"name": "flexor", "representation": "blended_surface", "mesh": "belly.obj",
     "origin": {"body": "thigh", "points": [[-0.03, 0.07, 0]], "radius": 0.015},
     "insertion": {"body": "shank", "points": [[-0.03, -0.07, 0]], "radius": 0.015},
     "actuator": {"type": "hill", "model": "millard", "max_isometric_force": 800,
                  "optimal_fiber_length": 0.06, "tendon_slack_length": 0.09, "pennation_angle": 0.1},
     "activation": 0.3}],
  "motion": {"file": "motion.mot", "frame_rate": 50}
})";
  return dir / "scene.json";
}

}  // namespace

TEST(CliSolidDynamicsRun, WritesSeriesAndMetricsWithVolumeHeld) {
  const fs::path dir = test::scratch_dir("cli_solid_dynamics");
  const fs::path scene = write_knee_scene(dir), out = dir / "out";
  ASSERT_EQ(run_cli("--quiet --threads 2 run " + scene.string() + " --representation solid-dynamics --frames 6 "
                    "--outputs paraview,sto --out " + out.string()),
            0);
  const auto series = read_pvd(out / "knee.pvd");
  std::set<double> times;
  std::vector<PolyData> surfaces;
  for (const auto& d : series) {
    times.insert(d.time_s);
    if (d.name == "muscle_flexor") surfaces.push_back(read_polydata(out / d.file));
  }
  EXPECT_EQ(times.size(), 6u);
  ASSERT_EQ(surfaces.size(), 6u);
  for (const PolyData& p : surfaces) {
    EXPECT_EQ(p.points.rows(), surfaces[0].points.rows());
    EXPECT_EQ(p.triangles, surfaces[0].triangles);  // constant topology across frames
    EXPECT_TRUE(p.points.allFinite());
  }
  // The knee flexes: the surface moves.
  EXPECT_GT((surfaces.back().points - surfaces.front().points).cwiseAbs().maxCoeff(), 1e-3);

  const Table sto = read_table(out / "knee_muscles.sto");
  ASSERT_EQ(sto.rows(), 6);
  const auto column = [&](const std::string& name) {
    for (size_t c = 0; c < sto.labels.size(); ++c)
      if (sto.labels[c] == name) return VecX(sto.data.col(static_cast<Eigen::Index>(c)));
    ADD_FAILURE() << "no column " << name;
    return VecX(VecX::Zero(sto.rows()));
  };
  EXPECT_LE(column("flexor.relative_volume_change").cwiseAbs().maxCoeff(), 1e-3);
  EXPECT_TRUE(column("flexor.max_bone_penetration_m").allFinite());
  EXPECT_TRUE((column("flexor.mean_fibre_length_m").array() > 0.0).all());
}

TEST(CliSolidDynamicsRun, UnknownRepresentationNameIsBadInput) {
  const fs::path dir = test::scratch_dir("cli_solid_dynamics");
  const fs::path scene = write_knee_scene(dir), out = dir / "out";
  EXPECT_EQ(run_cli("--quiet run " + scene.string() + " --representation solid-dynamic --frames 2 --out " +
                    out.string()),
            3);
}
