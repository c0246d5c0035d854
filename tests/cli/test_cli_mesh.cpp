// End-to-end tests of `fascicle mesh info | convert | repair`: exit codes and outputs.
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/mesh_io.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <array>
#include <cstdio>
#include <string>
#include <sys/wait.h>

namespace fascicle {
namespace {

struct CliResult {
  int code;
  std::string out;
};

// Runs the CLI with arguments; stdout captured, stderr discarded.
CliResult run_cli(const std::string& args) {
  const auto r = test::run_command(std::string(FASCICLE_CLI_PATH) + " " + args + " 2>/dev/null");
  return {r.exit_code, r.output};
}

std::string quoted(const std::filesystem::path& p) { return "'" + p.string() + "'"; }

TEST(CliMesh, InfoJsonOnABox) {
  const auto dir = test::scratch_dir("cli_mesh_info");
  write_mesh(dir / "box.stl", make_box(Vec3(50, 10, 20)));  // mm
  const CliResult r = run_cli("mesh info " + quoted(dir / "box.stl") + " --units mm --json --density 1000");
  ASSERT_EQ(r.code, 0) << r.out;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_TRUE(j["validation"]["solid"].get<bool>());
  EXPECT_EQ(j["validation"]["faces"], 12);
  EXPECT_EQ(j["validation"]["vertices"], 8);
  const double v = 0.1 * 0.02 * 0.04;
  EXPECT_NEAR(j["mass_properties"]["volume_m3"].get<double>(), v, 1e-12 * v * 1e3);
  EXPECT_NEAR(j["mass_properties"]["mass_kg"].get<double>(), 1000 * v, 1e-9);
  EXPECT_EQ(j["units"], "mm");
}

TEST(CliMesh, ProblemsAreReportedWithExitZeroUnlessStrict) {
  const auto open = test::data_path("negative/open_cube.obj");
  const CliResult r = run_cli("mesh info " + quoted(open) + " --json");
  ASSERT_EQ(r.code, 0);
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["validation"]["boundary_edges"]["count"], 4);
  EXPECT_TRUE(j["mass_properties"].is_null());
  EXPECT_EQ(run_cli("mesh info " + quoted(open) + " --strict").code, 3);
  const CliResult text = run_cli("mesh info " + quoted(test::data_path("negative/nan_vertex.obj")));
  EXPECT_EQ(text.code, 0);
  EXPECT_NE(text.out.find("NaN/Inf"), std::string::npos) << text.out;
}

TEST(CliMesh, ExitCodes) {
  EXPECT_EQ(run_cli("mesh info " + quoted(test::data_path("negative/garbage.vtp"))).code, 3);
  EXPECT_EQ(run_cli("mesh info " + quoted(test::data_path("negative/truncated.stl"))).code, 3);
  EXPECT_EQ(run_cli("mesh info /nonexistent/file.stl").code, 3);
  EXPECT_EQ(run_cli("mesh info").code, 2);                     // missing FILE
  EXPECT_EQ(run_cli("mesh info x.stl --units furlong").code, 2);  // bad unit
  EXPECT_EQ(run_cli("mesh convert a.stl b.xyz").code, 2);       // unknown output format
  EXPECT_EQ(run_cli("mesh frobnicate").code, 2);
}

TEST(CliMesh, ConvertAndRepair) {
  const auto dir = test::scratch_dir("cli_mesh_convert");
  write_mesh(dir / "ball.obj", make_icosphere(0.05, 2));
  ASSERT_EQ(run_cli("mesh convert " + quoted(dir / "ball.obj") + " " + quoted(dir / "ball.vtp") +
                    " --appended")
                .code,
            0);
  const TriMesh back = read_mesh(dir / "ball.vtp");
  EXPECT_EQ(back.V, make_icosphere(0.05, 2).V);

  const CliResult fixed = run_cli("mesh repair " + quoted(test::data_path("negative/flipped_face_cube.obj")) +
                            " " + quoted(dir / "cube.stl"));
  ASSERT_EQ(fixed.code, 0) << fixed.out;
  EXPECT_NE(fixed.out.find("flipped 1 faces"), std::string::npos) << fixed.out;
  EXPECT_EQ(read_mesh(dir / "cube.stl").F.rows(), 12);

  const CliResult refused = run_cli("mesh repair " +
                              quoted(test::data_path("negative/nonmanifold_edge.obj")) + " " +
                              quoted(dir / "nm.obj"));
  EXPECT_EQ(refused.code, 3);
  EXPECT_NE(refused.out.find("non-manifold"), std::string::npos) << refused.out;
  EXPECT_FALSE(std::filesystem::exists(dir / "nm.obj"));
}

}  // namespace
}  // namespace fascicle
