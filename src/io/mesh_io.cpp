// read_mesh / write_mesh dispatch, the OBJ reader and the OBJ/STL/PLY writers.
#include "mesh_io_internal.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/core/log.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <charconv>
#include <climits>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <new>
#include <stdexcept>
#include <sstream>
#include <string_view>

namespace fascicle {
namespace mesh_io_detail {
namespace {

static_assert(std::endian::native == std::endian::little,
              "binary mesh writers assume a little-endian host");

std::string_view trim(std::string_view s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
  return s;
}

// Splits at whitespace.
std::vector<std::string_view> split(std::string_view s) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    const std::size_t start = i;
    while (i < s.size() && !std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    if (i > start) out.push_back(s.substr(start, i - start));
  }
  return out;
}

// A double from an OBJ token; "nan", "inf" are accepted (validate_mesh reports them).
bool parse_double(std::string_view token, double& value) {
  if (!token.empty() && token.front() == '+') token.remove_prefix(1);
  const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
  return ec == std::errc() && end == token.data() + token.size();
}

// The vertex index of an OBJ face corner "v", "v/t", "v//n" or "v/t/n" (1-based, or negative
// relative to the vertices read so far). Returns false if the token is not a number; indices that
// cannot refer to any vertex become -1 (reported as out of range by validate_mesh).
bool parse_obj_corner(std::string_view token, long long num_vertices, int& index) {
  const std::size_t slash = token.find('/');
  const std::string_view head = token.substr(0, slash);
  long long i = 0;
  const auto [end, ec] = std::from_chars(head.data(), head.data() + head.size(), i);
  if (ec == std::errc::result_out_of_range) {
    index = -1;
    return end == head.data() + head.size();
  }
  if (ec != std::errc() || end != head.data() + head.size()) return false;
  const long long zero_based = i > 0 ? i - 1 : (i < 0 ? num_vertices + i : -1);
  index = (zero_based < 0 || zero_based > INT_MAX) ? -1 : static_cast<int>(zero_based);
  return true;
}

template <typename T>
void put(std::ostream& out, T value) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  out.write(bytes, sizeof(T));
}

Vec3 face_normal(const TriMesh& m, Eigen::Index f) {
  const Vec3 a = m.V.row(m.F(f, 0)), b = m.V.row(m.F(f, 1)), c = m.V.row(m.F(f, 2));
  const Vec3 n = (b - a).cross(c - a);
  const double len = n.norm();
  return len > 0.0 && std::isfinite(len) ? Vec3(n / len) : Vec3::Zero();
}

}  // namespace

TriMesh triangulate_soup(const PolygonSoup& soup, const std::string& file, long* skipped) {
  long num_triangles = 0;
  long small = 0;
  for (const int n : soup.sizes) {
    if (n >= 3) num_triangles += n - 2;
    else ++small;
  }
  if (skipped) *skipped = small;
  if (num_triangles == 0) {
    throw_bad_input(soup.vertices.empty() ? "the file holds no vertices and no triangles"
                                          : "the file holds no triangles (no polygon has 3 or more "
                                            "vertices)",
                    {.file = file, .suggestion = "check that this is a surface mesh file"});
  }
  TriMesh mesh;
  mesh.V.resize(static_cast<Eigen::Index>(soup.vertices.size()), 3);
  for (std::size_t i = 0; i < soup.vertices.size(); ++i) {
    mesh.V.row(static_cast<Eigen::Index>(i)) = soup.vertices[i];
  }
  mesh.F.resize(num_triangles, 3);
  Eigen::Index row = 0;
  std::size_t offset = 0;
  for (const int n : soup.sizes) {
    // fan around the first corner: (c0, ci, ci+1)
    for (int k = 1; k + 1 < n; ++k) {
      mesh.F.row(row++) << soup.corners[offset], soup.corners[offset + k],
          soup.corners[offset + k + 1];
    }
    offset += static_cast<std::size_t>(n);
  }
  return mesh;
}

TriMesh read_obj(std::string_view bytes, const std::string& file) {
  PolygonSoup soup;
  long line_number = 0;
  std::size_t next = 0;
  while (next < bytes.size()) {
    const std::size_t eol = std::min(bytes.find('\n', next), bytes.size());
    const std::string_view line = bytes.substr(next, eol - next);
    next = eol + 1;
    ++line_number;
    const std::string_view text = trim(line);
    if (text.empty() || text.front() == '#') continue;
    const std::vector<std::string_view> tok = split(text);
    const ErrorContext where{.file = file, .line = line_number};
    if (tok[0] == "v") {
      Vec3 p;
      if (tok.size() < 4 || !parse_double(tok[1], p.x()) || !parse_double(tok[2], p.y()) ||
          !parse_double(tok[3], p.z())) {
        throw_bad_input("a vertex line needs three numbers: '" + std::string(text.substr(0, 80)) +
                            "'",
                        where);
      }
      soup.vertices.push_back(p);
    } else if (tok[0] == "f") {
      if (tok.size() < 4) {
        throw_bad_input("a face needs at least three vertex indices", where);
      }
      for (std::size_t k = 1; k < tok.size(); ++k) {
        int index = -1;
        if (!parse_obj_corner(tok[k], static_cast<long long>(soup.vertices.size()), index)) {
          throw_bad_input("bad face index '" + std::string(tok[k].substr(0, 40)) + "'", where);
        }
        soup.corners.push_back(index);
      }
      soup.sizes.push_back(static_cast<int>(tok.size() - 1));
    } else {
      // texture/normal coordinates, groups, materials, smoothing, lines, free-form geometry and
      // vendor extensions carry nothing a triangle surface needs
      const bool printable = std::all_of(tok[0].begin(), tok[0].end(), [](char c) {
        return std::isalnum(static_cast<unsigned char>(c)) || c == '_';
      });
      if (!printable) {
        throw_bad_input("not an OBJ text line", {.file = file, .line = line_number,
                                                 .suggestion = "is this a binary file?"});
      }
    }
  }
  return triangulate_soup(soup, file, nullptr);
}

void write_obj(const std::filesystem::path& path, const TriMesh& mesh) {
  write_file_atomically(path, [&](std::ostream& out) {
    out << "# written by fascicle: " << mesh.V.rows() << " vertices, " << mesh.F.rows()
        << " triangles\n";
    out.precision(17);
    for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
      out << "v " << mesh.V(i, 0) << ' ' << mesh.V(i, 1) << ' ' << mesh.V(i, 2) << '\n';
    }
    for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
      out << "f " << mesh.F(f, 0) + 1 << ' ' << mesh.F(f, 1) + 1 << ' ' << mesh.F(f, 2) + 1 << '\n';
    }
  });
}

void write_stl(const std::filesystem::path& path, const TriMesh& mesh, bool ascii) {
  write_file_atomically(path, [&](std::ostream& out) {
    if (ascii) {
      out << "solid fascicle\n";
      out.precision(9);  // float32 round-trips through 9 significant digits
      for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
        const Vec3 n = face_normal(mesh, f);
        out << " facet normal " << n.x() << ' ' << n.y() << ' ' << n.z() << "\n  outer loop\n";
        for (int k = 0; k < 3; ++k) {
          const auto p = mesh.V.row(mesh.F(f, k)).cast<float>();
          out << "   vertex " << p.x() << ' ' << p.y() << ' ' << p.z() << '\n';
        }
        out << "  endloop\n endfacet\n";
      }
      out << "endsolid fascicle\n";
      return;
    }
    std::array<char, 80> header{};
    const std::string title = "binary STL written by fascicle";
    std::copy(title.begin(), title.end(), header.begin());
    out.write(header.data(), header.size());
    put<std::uint32_t>(out, static_cast<std::uint32_t>(mesh.F.rows()));
    for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
      const Vec3 n = face_normal(mesh, f);
      for (int j = 0; j < 3; ++j) put<float>(out, static_cast<float>(n[j]));
      for (int k = 0; k < 3; ++k) {
        for (int j = 0; j < 3; ++j) put<float>(out, static_cast<float>(mesh.V(mesh.F(f, k), j)));
      }
      put<std::uint16_t>(out, 0);
    }
  });
}

void write_ply(const std::filesystem::path& path, const TriMesh& mesh, bool ascii) {
  write_file_atomically(path, [&](std::ostream& out) {
    out << "ply\nformat " << (ascii ? "ascii" : "binary_little_endian") << " 1.0\n"
        << "comment written by fascicle\n"
        << "element vertex " << mesh.V.rows() << "\n"
        << "property double x\nproperty double y\nproperty double z\n"
        << "element face " << mesh.F.rows() << "\n"
        << "property list uchar int vertex_indices\nend_header\n";
    if (ascii) {
      out.precision(17);
      for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
        out << mesh.V(i, 0) << ' ' << mesh.V(i, 1) << ' ' << mesh.V(i, 2) << '\n';
      }
      for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
        out << "3 " << mesh.F(f, 0) << ' ' << mesh.F(f, 1) << ' ' << mesh.F(f, 2) << '\n';
      }
      return;
    }
    for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
      for (int j = 0; j < 3; ++j) put<double>(out, mesh.V(i, j));
    }
    for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
      put<std::uint8_t>(out, 3);
      for (int k = 0; k < 3; ++k) put<std::int32_t>(out, mesh.F(f, k));
    }
  });
}

}  // namespace mesh_io_detail

MeshFormat find_mesh_format(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == ".obj") return MeshFormat::obj;
  if (ext == ".stl") return MeshFormat::stl;
  if (ext == ".ply") return MeshFormat::ply;
  if (ext == ".vtp") return MeshFormat::vtp;
  throw_usage("unknown mesh file extension '" + ext + "'",
              {.file = path.string(), .suggestion = "use .obj, .stl, .ply or .vtp"});
}

std::string to_string(MeshFormat format) {
  switch (format) {
    case MeshFormat::obj: return "OBJ";
    case MeshFormat::stl: return "STL";
    case MeshFormat::ply: return "PLY";
    case MeshFormat::vtp: return "VTK XML PolyData";
  }
  return "?";
}

TriMesh read_mesh_from_memory(std::string_view bytes, MeshFormat format, LengthUnit unit,
                              const std::string& name) {
  using namespace mesh_io_detail;
  TriMesh mesh;
  try {
    switch (format) {
      case MeshFormat::obj: mesh = read_obj(bytes, name); break;
      case MeshFormat::stl: mesh = read_stl(bytes, name); break;
      case MeshFormat::ply: mesh = read_ply(bytes, name); break;
      case MeshFormat::vtp: mesh = read_vtp(bytes, name); break;
    }
  } catch (const Error&) {
    throw;
  } catch (const std::bad_alloc&) {
    throw_bad_input("the file declares more data than fits in memory",
                    {.file = name, .suggestion = "the file is probably corrupt"});
  } catch (const std::exception& e) {
    // Assimp and VTK report problems with their own exception types
    throw_bad_input(std::string("cannot read the file: ") + e.what(), {.file = name});
  }
  const double scale = metres_per(unit);
  if (scale != 1.0) mesh.V *= scale;
  spdlog::debug("read {}: {} vertices, {} triangles ({})", name, mesh.V.rows(), mesh.F.rows(),
                to_string(format));
  return mesh;
}

TriMesh read_mesh(const std::filesystem::path& path, LengthUnit unit) {
  const MeshFormat format = find_mesh_format(path);
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw_bad_input("no such mesh file", {.file = path.string(),
                                          .suggestion = "check the path and its spelling"});
  }
  std::ifstream in(path, std::ios::binary);
  std::string bytes(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>{});
  if (!in && !in.eof()) throw_bad_input("cannot read the file", {.file = path.string()});
  return read_mesh_from_memory(bytes, format, unit, path.string());
}

void write_mesh(const std::filesystem::path& path, const TriMesh& mesh, MeshWriteOptions options) {
  using namespace mesh_io_detail;
  const MeshFormat format = find_mesh_format(path);
  const Eigen::Index n = mesh.V.rows();
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      if (mesh.F(f, k) < 0 || mesh.F(f, k) >= n) {
        throw_bad_input("cannot write a mesh whose triangle " + std::to_string(f) +
                            " refers to vertex " + std::to_string(mesh.F(f, k)) + " of " +
                            std::to_string(n),
                        {.file = path.string(), .suggestion = "validate the mesh first"});
      }
    }
  }
  const double scale = metres_per(options.unit);
  TriMesh scaled;
  const TriMesh* out = &mesh;
  if (scale != 1.0) {
    scaled.V = mesh.V / scale;
    scaled.F = mesh.F;
    out = &scaled;
  }
  const bool ascii = options.encoding == MeshEncoding::ascii;
  switch (format) {
    case MeshFormat::obj: write_obj(path, *out); break;
    case MeshFormat::stl: write_stl(path, *out, ascii); break;
    case MeshFormat::ply: write_ply(path, *out, ascii); break;
    case MeshFormat::vtp: write_vtp(path, *out, options.encoding, options.compress); break;
  }
}

}  // namespace fascicle
