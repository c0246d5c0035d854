// `fascicle demo --out DIR` end to end: exit code, outputs readable by VTK and the table reader,
// closed bones with positive volume, the specified motion ranges.
#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/geometry/mesh_validation.hpp"
#include "fascicle/io/polydata.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/io/vtk_series.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdlib>
#include <fstream>
#include <set>

namespace fs = std::filesystem;
using namespace fascicle;

namespace {

int run_cli(const std::string& args) {
  return test::run_command(std::string(FASCICLE_CLI_PATH) + " " + args + " > /dev/null 2>&1").exit_code;
}

}  // namespace

TEST(CliDemo, WritesAReadableParaViewSeriesTablesAndSummary) {
  const fs::path out = test::scratch_dir("cli_demo") / "demo";
  ASSERT_EQ(run_cli("--quiet --threads 2 demo --out " + out.string() + " --fps 10"), 0);
  const auto series = read_pvd(out / "demo.pvd");
  std::set<std::string> parts;
  std::set<double> times;
  for (const auto& d : series) {
    parts.insert(d.name);
    times.insert(d.time_s);
  }
  EXPECT_EQ(times.size(), 21u);  // 2 s at 10 Hz, both ends
  EXPECT_DOUBLE_EQ(*times.rbegin(), 2.0);
  for (const char* bone : {"femur", "tibia", "fibula", "talus", "calcaneus", "foot"})
    EXPECT_TRUE(parts.count(std::string("bone_") + bone)) << bone;
  for (const char* muscle : {"soleus", "medial_gastrocnemius", "lateral_gastrocnemius", "tibialis_anterior"}) {
    EXPECT_TRUE(parts.count(std::string("muscle_") + muscle)) << muscle;
    EXPECT_TRUE(parts.count(std::string("action_line_") + muscle)) << muscle;
    EXPECT_TRUE(parts.count(std::string("fibres_") + muscle)) << muscle;
  }
  // Bones of the last frame: closed, outward, positive volume, read back through VTK.
  for (const auto& d : series) {
    if (d.time_s != 2.0 || d.name.rfind("bone_", 0) != 0) continue;
    const PolyData p = read_polydata(out / d.file);
    const TriMesh mesh{p.points, p.triangles};
    const MeshReport r = validate_mesh(mesh, {.check_self_intersections = false});
    EXPECT_TRUE(r.is_closed() && r.is_consistently_oriented()) << d.name;
    EXPECT_GT(calc_mass_properties(mesh).volume_m3, 1e-6) << d.name;
  }
  const Table sto = read_table(out / "demo_muscles.sto");
  EXPECT_EQ(sto.rows(), 21);
  const long force = find_column(sto, "soleus.tendon_force_N");
  ASSERT_GE(force, 0);
  EXPECT_GT(sto.data.col(force).maxCoeff(), 0.0);
  EXPECT_TRUE(fs::exists(out / "demo_muscles.csv"));

  std::ifstream in(out / "summary.json");
  const auto summary = nlohmann::json::parse(in);
  EXPECT_EQ(summary["frames"], 21);
  EXPECT_TRUE(summary["complete"].get<bool>());
  const auto& soleus = summary["muscles"]["soleus"]["range"];
  EXPECT_GT(soleus["musculotendon_length_m"][1].get<double>(), soleus["musculotendon_length_m"][0].get<double>());
}

TEST(CliDemo, UnwritableOutputFolderIsBadInput) {
  const fs::path dir = test::scratch_dir("cli_demo_bad");
  std::ofstream(dir / "file") << "x";
  EXPECT_EQ(run_cli("--quiet demo --out " + (dir / "file" / "sub").string()), 3);
  EXPECT_EQ(run_cli("demo --fps -1"), 2);
}
