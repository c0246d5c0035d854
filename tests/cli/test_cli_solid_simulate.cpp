// End-to-end tests of `fascicle solid simulate` (docs/solid-dynamics.md).
#include "test_support.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;

// The repository: $FASCICLE_SOURCE_DIR, else the first folder above the CLI binary that holds
// examples/solid.
fs::path repo_root() {
  if (const char* env = std::getenv("FASCICLE_SOURCE_DIR"); env != nullptr && *env != '\0')
    return fs::path(env);
  for (fs::path p = fs::absolute(FASCICLE_CLI_PATH).parent_path(); !p.empty() && p != p.root_path();
       p = p.parent_path())
    if (fs::exists(p / "examples" / "solid")) return p;
  throw std::runtime_error("cannot find the repository above " + std::string(FASCICLE_CLI_PATH) +
                           " (set FASCICLE_SOURCE_DIR to it)");
}

const std::string kExample = (repo_root() / "examples" / "solid" / "block_muscle.json").string();

std::vector<std::string> read_lines(const std::filesystem::path& p) {
  std::ifstream in(p);
  std::vector<std::string> out;
  for (std::string line; std::getline(in, line);) out.push_back(line);
  return out;
}

int run(const std::string& args) {
  return fascicle::test::run_command(std::string(FASCICLE_CLI_PATH) + " -q solid simulate " + args +
                                     " > /dev/null 2>&1").exit_code;
}

TEST(CliSolidSimulate, IsometricContractionWritesSeriesAndMetrics) {
  const auto dir = fascicle::test::scratch_dir("solid_simulate");
  ASSERT_EQ(run(kExample + " --activation 1 --duration 0.02 --tendon 0.2 --out " + dir.string()), 0);
  EXPECT_TRUE(std::filesystem::exists(dir / "solid.pvd"));
  EXPECT_TRUE(std::filesystem::exists(dir / "boundary_00002.vtp"));
  EXPECT_TRUE(std::filesystem::exists(dir / "fibres_00002.vtp"));
  EXPECT_TRUE(std::filesystem::exists(dir / "volume_00002.vtu"));
  const auto lines = read_lines(dir / "metrics.csv");
  ASSERT_EQ(lines.size(), 4u);  // header + t = 0, 0.01, 0.02
  // Last row: volume error (column 3) within the exact constraint's tolerance, stretch < 1.
  std::vector<double> v;
  std::stringstream ss(lines.back());
  for (std::string c; std::getline(ss, c, ',');) v.push_back(std::stod(c));
  EXPECT_NEAR(v[0], 0.02, 1e-9);
  EXPECT_LT(std::abs(v[2]), 1e-6);
  EXPECT_LT(v[4], 0.99);
}

std::vector<double> last_metrics(const fs::path& dir) {
  const auto lines = read_lines(dir / "metrics.csv");
  std::vector<double> v;
  if (lines.size() < 2) return v;
  std::stringstream ss(lines.back());
  for (std::string c; std::getline(ss, c, ',');) v.push_back(std::stod(c));
  return v;
}

// --extrapolate-start changes only where Newton starts: the contraction ends in the same state
// (to the Newton tolerance), and it is refused where it has no meaning.
TEST(CliSolidSimulate, ExtrapolatedStartGivesTheSameContraction) {
  const auto plain = fascicle::test::scratch_dir("solid_simulate_plain");
  const auto extra = fascicle::test::scratch_dir("solid_simulate_extrapolated");
  const std::string common = kExample + " --activation 1 --duration 0.03 --tendon 0.2 --dt 0.002 ";
  ASSERT_EQ(run(common + "--no-extrapolate-start --out " + plain.string()), 0);
  ASSERT_EQ(run(common + "--extrapolate-start --out " + extra.string()), 0);
  const std::vector<double> a = last_metrics(plain), b = last_metrics(extra);
  ASSERT_EQ(a.size(), b.size());
  ASSERT_GE(a.size(), 5u);
  EXPECT_NEAR(a[0], 0.03, 1e-9);
  EXPECT_NEAR(b[0], a[0], 1e-12);
  EXPECT_LT(std::abs(b[2]), 1e-6);           // volume error
  EXPECT_LT(a[4], 0.99);                      // the fibres shortened
  EXPECT_NEAR(b[4], a[4], 1e-4 * std::abs(a[4]));  // mean fibre stretch, same state
  EXPECT_EQ(run(kExample + " --integrator symplectic-euler --extrapolate-start --out " +
                extra.string()),
            2);
}

TEST(CliSolidSimulate, BadInputAndUsage) {
  const auto dir = fascicle::test::scratch_dir("solid_simulate_bad");
  EXPECT_EQ(run("/nonexistent/solid.json --out " + dir.string()), 3);
  EXPECT_EQ(run(kExample + " --activation 2 --out " + dir.string()), 2);
  EXPECT_EQ(run(kExample + " --fix elbow --out " + dir.string()), 2);
}

TEST(CliSolidSimulate, DivergenceIsANumericalErrorWithTheLastGoodFrameWritten) {
  const auto dir = fascicle::test::scratch_dir("solid_simulate_blowup");
  // Explicit integration at 40x its stability limit.
  const int code = run(kExample + " --integrator symplectic-euler --explicit-safety 40 --c1 1e6 "
                       "--activation 1 --duration 0.05 --out " + dir.string());
  EXPECT_EQ(code, 4);
  const auto lines = read_lines(dir / "metrics.csv");
  ASSERT_GE(lines.size(), 2u);
  EXPECT_EQ(lines.back().find("nan"), std::string::npos);
  EXPECT_TRUE(std::filesystem::exists(dir / "solid.pvd"));
}

}  // namespace
