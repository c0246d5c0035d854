// Random bytes and mutated valid files never crash a reader: each either reads or throws
// fascicle::Error. Seeds are fixed, so a failure is reproducible.
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mesh_validation.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/mesh_io.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <spdlog/spdlog.h>
#include <vtkObject.h>

#include <fstream>
#include <cstdlib>
#include <random>

namespace fascicle {
namespace {

std::string read_bytes(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// One of: flip random bytes, truncate, duplicate a chunk, overwrite with digits/keywords.
std::string mutate(const std::string& valid, std::mt19937& rng) {
  std::string s = valid;
  std::uniform_int_distribution<int> kind(0, 4);
  const auto pos = [&] {
    return std::uniform_int_distribution<std::size_t>(0, s.empty() ? 0 : s.size() - 1)(rng);
  };
  switch (kind(rng)) {
    case 0: {  // flip a few bytes
      const int n = std::uniform_int_distribution<int>(1, 8)(rng);
      for (int i = 0; i < n && !s.empty(); ++i) s[pos()] = static_cast<char>(rng());
      break;
    }
    case 1: s.resize(pos()); break;  // truncate
    case 2: {                        // duplicate a chunk somewhere else
      const std::size_t a = pos(), len = std::min<std::size_t>(64, s.size() - a);
      s.insert(pos(), s.substr(a, len));
      break;
    }
    case 3: {  // large or negative numbers where digits were
      const char* tokens[] = {"4294967295", "-1", "999999999", "nan", "1e308", "0", "-2147483648"};
      const std::size_t p = pos();
      s.replace(p, std::min<std::size_t>(3, s.size() - p), tokens[rng() % 7]);
      break;
    }
    default: {  // zero a run of bytes
      const std::size_t p = pos();
      for (std::size_t i = p; i < std::min(s.size(), p + 16); ++i) s[i] = '\0';
    }
  }
  return s;
}

struct FuzzCase {
  std::string name;
  MeshEncoding encoding;
  bool compress;
};

class MeshReaderFuzz : public ::testing::TestWithParam<FuzzCase> {};

TEST_P(MeshReaderFuzz, NeverCrashes) {
  // this test process only: VTK's parse errors and the readers' warnings are expected here
  vtkObject::GlobalWarningDisplayOff();
  spdlog::set_level(spdlog::level::err);
  const FuzzCase& c = GetParam();
  const auto dir = test::scratch_dir("mesh_fuzz_" + std::to_string(std::hash<std::string>()(c.name)));
  const auto valid_path = dir / ("valid_" + c.name);
  write_mesh(valid_path, make_icosphere(0.5, 1), {.encoding = c.encoding, .compress = c.compress});
  const std::string valid = read_bytes(valid_path);
  const auto path = dir / ("case_" + c.name);
  std::mt19937 rng(12345);
  int read_ok = 0, rejected = 0;
  const int mutated = 700, random = 300;
  for (int n = 0; n < mutated + random; ++n) {
    std::string bytes;
    if (n < mutated) {
      bytes = mutate(valid, rng);
      if (n % 3 == 0) bytes = mutate(bytes, rng);
    } else {
      bytes.resize(std::uniform_int_distribution<std::size_t>(0, 2000)(rng));
      for (char& b : bytes) b = static_cast<char>(rng());
      // sometimes behind a valid-looking start
      if (n % 2 == 0) bytes = valid.substr(0, std::min<std::size_t>(valid.size(), 120)) + bytes;
    }
    if (std::getenv("FASCICLE_FUZZ_DUMP")) {  // debugging aid: keep the case that misbehaves
      std::ofstream(dir / ("dump_" + c.name), std::ios::binary) << bytes;
      std::fprintf(stderr, "case %d\n", n);
    }
    try {
      // from memory: the same readers as read_mesh without the cost of a file per case
      const TriMesh m = read_mesh_from_memory(bytes, find_mesh_format(path), LengthUnit::metre,
                                              "case " + std::to_string(n));
      validate_mesh(m);  // must cope with whatever was read
      ++read_ok;
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::bad_input) << "case " << n << ": " << e.what();
      ++rejected;
    }
    // any other exception type or a crash fails the test
  }
  EXPECT_EQ(read_ok + rejected, mutated + random);
  EXPECT_GT(rejected, 0);
  std::printf("%s: %d read, %d rejected\n", c.name.c_str(), read_ok, rejected);
}

INSTANTIATE_TEST_SUITE_P(
    Readers, MeshReaderFuzz,
    ::testing::Values(FuzzCase{"m.obj", MeshEncoding::ascii, false},
                      FuzzCase{"a.stl", MeshEncoding::ascii, false},
                      FuzzCase{"b.stl", MeshEncoding::binary, false},
                      FuzzCase{"a.ply", MeshEncoding::ascii, false},
                      FuzzCase{"b.ply", MeshEncoding::binary, false},
                      FuzzCase{"a.vtp", MeshEncoding::ascii, false},
                      FuzzCase{"b.vtp", MeshEncoding::binary, true},
                      FuzzCase{"p.vtp", MeshEncoding::appended, false}),
    [](const auto& info) {
      std::string n = info.param.name;
      for (char& ch : n) {
        if (ch == '.') ch = '_';
      }
      return n;
    });

}  // namespace
}  // namespace fascicle
