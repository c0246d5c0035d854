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
