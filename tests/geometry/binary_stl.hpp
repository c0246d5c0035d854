// A minimal binary-STL reader (millimetres -> metres) for the geometry tests: test_geometry links
// the geometry module alone, and fascicle::read_mesh lives in the io module, a layer above.
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

namespace fascicle::test {

inline TriMesh read_binary_stl_mm(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  char header[80];
  std::uint32_t n = 0;
  in.read(header, 80);
  in.read(reinterpret_cast<char*>(&n), 4);
  TriMesh m;
  m.V.resize(3 * n, 3);
  m.F.resize(n, 3);
  for (std::uint32_t t = 0; t < n && in; ++t) {
    float rec[12];
    std::uint16_t attr = 0;
    in.read(reinterpret_cast<char*>(rec), sizeof rec);
    in.read(reinterpret_cast<char*>(&attr), 2);
    for (int k = 0; k < 3; ++k) {
      for (int j = 0; j < 3; ++j) m.V(3 * t + k, j) = 1e-3 * static_cast<double>(rec[3 + 3 * k + j]);
      m.F(t, k) = static_cast<int>(3 * t + k);
    }
  }
  if (!in) throw std::runtime_error("truncated STL " + path.string());
  return m;
}

}  // namespace fascicle::test
