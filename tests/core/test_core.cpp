#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/core/units.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <numeric>
#include <vector>

namespace fascicle {
namespace {

TEST(Error, MessageCarriesContextAndExitCode) {
  const Error e(ErrorKind::bad_input, "vertex 4 is NaN",
                {.file = "leg.obj", .line = 7, .object = "soleus", .suggestion = "fix the mesh"});
  EXPECT_EQ(std::string(e.what()), "leg.obj:7: 'soleus': vertex 4 is NaN (fix the mesh)");
  EXPECT_EQ(e.exit_code(), ExitCode::bad_input);
  EXPECT_EQ(Error(ErrorKind::numerical, "x").exit_code(), ExitCode::numerical);
  EXPECT_EQ(Error(ErrorKind::usage, "x").exit_code(), ExitCode::usage);
  const Error j(ErrorKind::bad_input, "expected a number", {.json_path = "/muscles/0/f0"});
  EXPECT_EQ(std::string(j.with_file("s.json").what()), "s.json: at /muscles/0/f0: expected a number");
}

TEST(Units, ParsesLengthsWithSuffixes) {
  EXPECT_DOUBLE_EQ(parse_length("2mm"), 0.002);
  EXPECT_DOUBLE_EQ(parse_length("0.5 cm"), 0.005);
  EXPECT_DOUBLE_EQ(parse_length("0.25"), 0.25);
  EXPECT_DOUBLE_EQ(metres_per(parse_length_unit("MM")), 1e-3);
  EXPECT_THROW(parse_length("two"), Error);
  EXPECT_THROW(parse_length("2 furlongs"), Error);
}

TEST(AtomicFile, WritesWholeFileOrNothing) {
  const auto dir = test::scratch_dir("atomic");
  const auto path = dir / "table.csv";
  write_file_atomically(path, [](std::ostream& os) { os << "a,b\n1,2\n"; });
  std::ifstream in(path);
  std::string all((std::istreambuf_iterator<char>(in)), {});
  EXPECT_EQ(all, "a,b\n1,2\n");
  // a failing writer leaves the previous content and no temporary files
  EXPECT_THROW(write_file_atomically(path,
                                     [](std::ostream& os) {
                                       os << "partial";
                                       throw_numerical("solver diverged");
                                     }),
               Error);
  std::ifstream again(path);
  std::string kept((std::istreambuf_iterator<char>(again)), {});
  EXPECT_EQ(kept, "a,b\n1,2\n");
  int files = 0;
  for ([[maybe_unused]] const auto& entry : std::filesystem::directory_iterator(dir)) ++files;
  EXPECT_EQ(files, 1);
}

TEST(Parallel, SameResultForAnyThreadCount) {
  auto run = [](int threads) {
    const ThreadLimit limit(threads);
    std::vector<double> out(1000);
    parallel_for(out.size(), [&](std::size_t i) { out[i] = std::sin(double(i)) * double(i); });
    return out;
  };
  EXPECT_EQ(run(1), run(2));
  const ThreadLimit one(1);
  EXPECT_EQ(max_threads(), 1);
}

TEST(Parallel, PropagatesExceptions) {
  EXPECT_THROW(parallel_for(100, [](std::size_t i) { if (i == 42) throw_numerical("bad"); }), Error);
}

}  // namespace
}  // namespace fascicle
