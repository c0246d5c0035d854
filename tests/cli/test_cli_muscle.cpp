// End-to-end runs of `fascicle muscle ...`.
#include "test_support.hpp"

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace {
int run(const std::string& args) {
  const std::string cmd = std::string(FASCICLE_CLI_PATH) + " -q " + args + " > /dev/null 2>&1";
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}
std::string slurp(const std::filesystem::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}
}  // namespace

TEST(CliMuscle, ExperimentsWriteCsvAndSvg) {
  const auto dir = fascicle::test::scratch_dir("cli_muscle");
  for (const char* kind : {"isometric", "tetanus", "quick-release", "isotonic"}) {
    ASSERT_EQ(run(std::string("muscle experiment ") + kind + " --model thelen --out " + dir.string()), 0)
        << kind;
    EXPECT_NE(slurp(dir / (std::string(kind) + ".svg")).find("</svg>"), std::string::npos);
    EXPECT_GT(slurp(dir / (std::string(kind) + ".csv")).size(), 100u);
  }
  const std::string summary = slurp(dir / "tetanus_summary.csv");
  EXPECT_NE(summary.find("rise_time_10_90_s"), std::string::npos);
}

TEST(CliMuscle, CurvesFromOsimAndParams) {
  const auto dir = fascicle::test::scratch_dir("cli_muscle_curves");
  const auto osim = fascicle::test::data_path("opensim/models/gait2392_millard2012muscle.osim");
  ASSERT_EQ(run("muscle curves --osim " + osim.string() + " --muscle soleus_r --out " + dir.string()), 0);
  EXPECT_NE(slurp(dir / "force_length.svg").find("soleus_r"), std::string::npos);
  std::ofstream(dir / "p.json") << R"({"name": "tiny", "model": "degroote", "max_isometric_force_N": 300,
      "optimal_fiber_length_m": 0.05, "tendon_slack_length_m": 0.1})";
  ASSERT_EQ(run("muscle experiment isometric --params " + (dir / "p.json").string() + " --out " +
                (dir / "exp").string()), 0);
}

TEST(CliMuscle, BadInputAndUsageExitCodes) {
  const auto dir = fascicle::test::scratch_dir("cli_muscle_bad");
  std::ofstream(dir / "bad.json") << R"({"name": "neg", "tendon_slack_length_m": -1})";
  EXPECT_EQ(run("muscle experiment isometric --params " + (dir / "bad.json").string() + " --out " +
                dir.string()), 3);
  const auto osim = fascicle::test::data_path("opensim/models/gait2392_thelen2003muscle.osim");
  EXPECT_EQ(run("muscle curves --osim " + osim.string() + " --muscle nope --out " + dir.string()), 3);
  EXPECT_EQ(run("muscle experiment sprint --out " + dir.string()), 2);
  EXPECT_EQ(run("muscle curves --model hill --out " + dir.string()), 2);
}
