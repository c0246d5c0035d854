// End-to-end tests of `fascicle solid fit|info|export`.
#include "test_support.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

namespace {

struct SolidCliRun {
  int code;
  std::string out;
};

SolidCliRun run_solid_cli(const std::string& args) {
  const auto r = fascicle::test::run_command(std::string(FASCICLE_CLI_PATH) + " " + args + " 2>&1");
  return {r.exit_code, r.output};
}

TEST(CliSolid, FitInfoExportTibialisAnterior) {
  const auto mesh = fascicle::test::data_path(
      "visible_human_female/right/VHF_Right_Muscle_TibialisAnterior_smooth.stl");
  const auto dir = fascicle::test::scratch_dir("cli_solid");
  const auto json = (dir / "ta.json").string();
  const SolidCliRun fit = run_solid_cli("solid fit --mesh " + mesh.string() + " --units mm --axis auto --lattice 4x16x14 "
                      "--degree 3 --out " + json);
  ASSERT_EQ(fit.code, 0) << fit.out;
  EXPECT_NE(fit.out.find("mean"), std::string::npos) << fit.out;
  EXPECT_NE(fit.out.find("cm^3"), std::string::npos) << fit.out;
  const SolidCliRun info = run_solid_cli("solid info " + json);
  ASSERT_EQ(info.code, 0) << info.out;
  EXPECT_NE(info.out.find("boundary formula"), std::string::npos) << info.out;
  const SolidCliRun exp = run_solid_cli("solid export " + json + " --out " + (dir / "vtk").string());
  ASSERT_EQ(exp.code, 0) << exp.out;
  for (const char* f : {"boundary.vtp", "fibres.vtp", "volume.vtu"}) {
    EXPECT_GT(std::filesystem::file_size(dir / "vtk" / f), 1000u) << f;
  }
}

// examples/solid/README.md: the coarse soleus fit, then a short maximal contraction. The
// parameter correction would invert this lattice; the fit backs off (and says so) and the solid
// simulates.
TEST(CliSolid, ReadmeSoleusFitBacksOffAndSimulates) {
  const auto mesh = fascicle::test::data_path(
      "visible_human_female/right/VHF_Right_Muscle_Soleus_smooth.stl");
  const auto dir = fascicle::test::scratch_dir("cli_solid_readme");
  const auto json = (dir / "soleus.json").string();
  const SolidCliRun fit = run_solid_cli("solid fit --mesh " + mesh.string() +
                                        " --units mm --axis auto --lattice 3x8x6 --degree 2 --out " + json);
  ASSERT_EQ(fit.code, 0) << fit.out;
  EXPECT_NE(fit.out.find("backed off"), std::string::npos) << fit.out;
  EXPECT_EQ(fit.out.find("inverted at material point"), std::string::npos) << fit.out;
  const SolidCliRun sim = run_solid_cli("solid simulate " + json +
                                        " --activation 1 --duration 0.05 --frame-dt 0.05 --tendon 0.1 "
                                        "--tendon-modulus 1e8 --c1 5e4 --damping 10 --pennation 0.436 --out " +
                                        (dir / "sim").string());
  EXPECT_EQ(sim.code, 0) << sim.out;
  EXPECT_NE(sim.out.find("simulated 0.050 s"), std::string::npos) << sim.out;
}

TEST(CliSolid, BadInputAndUsageExitCodes) {
  const auto dir = fascicle::test::scratch_dir("cli_solid_bad");
  {
    std::ofstream(dir / "bad.json") << R"({"format": "fascicle.bspline_solid", "bases": []})";
  }
  EXPECT_EQ(run_solid_cli("solid info " + (dir / "bad.json").string()).code, 3);
  EXPECT_EQ(run_solid_cli("solid info " + (dir / "missing.json").string()).code, 3);
  EXPECT_EQ(run_solid_cli("solid fit --mesh x.stl --out y.json").code, 2);  // no axis choice
  EXPECT_EQ(run_solid_cli("solid fit --mesh x.stl --axis auto --lattice 4x4 --out y.json").code, 2);
}

}  // namespace
