// STL and PLY readers through Assimp, with no post-processing: what the file holds reaches the
// caller (only STL's unshared facet corners are joined, by exact coordinates).
#include "mesh_io_internal.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/log.hpp"

#include <assimp/Importer.hpp>
#include <assimp/scene.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <string_view>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <unordered_map>

namespace fascicle::mesh_io_detail {
namespace {

bool starts_with_word(std::string_view bytes, const char* word) {
  std::size_t i = 0;
  while (i < bytes.size() && std::isspace(static_cast<unsigned char>(bytes[i]))) ++i;
  const std::size_t n = std::strlen(word);
  if (bytes.size() < i + n) return false;
  for (std::size_t k = 0; k < n; ++k) {
    if (std::tolower(static_cast<unsigned char>(bytes[i + k])) != word[k]) return false;
  }
  return true;
}

// Binary STL: 80-byte header, uint32 triangle count, 50 bytes per triangle. A file that does not
// start with "solid" must be binary, and its size must match its count; Assimp would only say that
// it cannot tell the storage kind, so the check is made here with a clearer message.
void check_stl_size(std::string_view bytes, const std::string& file) {
  if (bytes.empty()) {
    throw_bad_input("the file is empty", {.file = file,
                                          .suggestion = "re-export the mesh"});
  }
  const bool ascii_like = starts_with_word(bytes, "solid");
  if (bytes.size() < 84) {
    if (ascii_like) return;
    throw_bad_input("too short for a binary STL (" + std::to_string(bytes.size()) +
                        " bytes, the header alone needs 84)",
                    {.file = file, .suggestion = "the file is truncated; re-export it"});
  }
  std::uint32_t count = 0;
  std::memcpy(&count, bytes.data() + 80, 4);
  const std::uint64_t expected = 84 + 50 * static_cast<std::uint64_t>(count);
  if (expected == bytes.size() || ascii_like) return;
  throw_bad_input("binary STL header declares " + std::to_string(count) + " triangles (" +
                      std::to_string(expected) + " bytes) but the file has " +
                      std::to_string(bytes.size()) + " bytes",
                  {.file = file,
                   .suggestion = expected > bytes.size() ? "the file is truncated; re-export it"
                                                         : "the file has trailing data or a "
                                                           "wrong triangle count"});
}

// Each declared PLY element takes at least one byte, so a header declaring more elements than the
// file has bytes is corrupt; checking it first keeps a damaged header from requesting gigabytes.
void check_ply_header(std::string_view bytes, const std::string& file) {
  const std::string_view text = bytes.substr(0, 65536);
  const std::size_t end = text.find("end_header");
  if (end == std::string_view::npos) {
    throw_bad_input("PLY header has no end_header line", {.file = file,
                    .suggestion = "the file is truncated or not a PLY file"});
  }
  const std::size_t after = end + 10;
  if (after >= bytes.size() || (bytes[after] != '\n' && bytes.substr(after, 2) != "\r\n") ||
      (end > 0 && bytes[end - 1] != '\n')) {
    throw_bad_input("PLY end_header must be a line of its own", {.file = file,
                    .suggestion = "the file is corrupt or not a PLY file"});
  }
  // every header line must be well formed: Assimp loops on some damaged headers
  {
    long number = 0;
    std::size_t start = 0;
    const std::string_view header = text.substr(0, end + 10);
    while (start < header.size()) {
      const std::size_t eol = std::min(header.find('\n', start), header.size());
      std::string_view ln = header.substr(start, eol - start);
      start = eol + 1;
      ++number;
      if (!ln.empty() && ln.back() == '\r') ln.remove_suffix(1);
      std::vector<std::string_view> tok;
      for (std::size_t i = 0; i < ln.size();) {
        while (i < ln.size() && ln[i] == ' ') ++i;
        const std::size_t b = i;
        while (i < ln.size() && ln[i] != ' ') ++i;
        if (i > b) tok.push_back(ln.substr(b, i - b));
      }
      const bool printable = std::all_of(ln.begin(), ln.end(), [](char c) {
        return c == '\t' || (c >= 32 && c < 127);
      });
      const std::string_view key = tok.empty() ? std::string_view() : tok[0];
      const bool ok = printable && !tok.empty() &&
                      ((key == "ply" && tok.size() == 1) || (key == "format" && tok.size() == 3) ||
                       key == "comment" || key == "obj_info" ||
                       (key == "element" && tok.size() == 3) ||
                       (key == "property" && tok.size() == 3 && tok[1] != "list") ||
                       (key == "property" && tok.size() == 5 && tok[1] == "list") ||
                       (key == "end_header" && tok.size() == 1));
      if (!ok) {
        throw_bad_input("malformed PLY header line", {.file = file, .line = number,
                        .suggestion = "the file is corrupt or not a PLY file"});
      }
    }
  }
  unsigned long long declared = 0;
  std::size_t at = 0;
  long line = 1;
  while ((at = text.find("element", at)) != std::string_view::npos && at < end) {
    line = 1 + static_cast<long>(std::count(text.begin(), text.begin() + static_cast<long>(at), '\n'));
    std::size_t p = text.find_first_of(" \t", at);
    p = text.find_first_not_of(" \t", p);                // element name
    p = p == std::string_view::npos ? p : text.find_first_of(" \t", p);
    p = p == std::string_view::npos ? p : text.find_first_not_of(" \t", p);  // count
    unsigned long long n = 0;
    if (p == std::string_view::npos ||
        std::from_chars(text.data() + p, text.data() + end, n).ec != std::errc()) {
      throw_bad_input("PLY element line without a count", {.file = file, .line = line});
    }
    declared += n;
    if (declared > bytes.size()) {
      throw_bad_input("PLY header declares " + std::to_string(n) + " elements, more than the " +
                          std::to_string(bytes.size()) + " bytes of the file can hold",
                      {.file = file, .line = line,
                       .suggestion = "the file is truncated or its header is corrupt"});
    }
    at += 7;
  }
  // ASCII bodies: an integer token (list count or index) larger than the file is corrupt; Assimp
  // would try to read or copy that many list entries
  if (text.substr(0, end).find("format ascii") == std::string_view::npos) return;
  const std::size_t body = bytes.find('\n', end);
  for (std::size_t p = body; p != std::string_view::npos && p < bytes.size();) {
    p = bytes.find_first_of("0123456789", p);
    if (p == std::string_view::npos) break;
    const bool starts_token = p == 0 || std::isspace(static_cast<unsigned char>(bytes[p - 1]));
    std::size_t q = p;
    while (q < bytes.size() && std::isdigit(static_cast<unsigned char>(bytes[q]))) ++q;
    const bool ends_token = q == bytes.size() || std::isspace(static_cast<unsigned char>(bytes[q]));
    if (starts_token && ends_token && (q - p > 19 || std::stoull(std::string(bytes.substr(p, q - p))) > bytes.size())) {
      throw_bad_input("PLY body holds the integer " + std::string(bytes.substr(p, std::min<std::size_t>(q - p, 24))) +
                          ", larger than any count or index a " + std::to_string(bytes.size()) +
                          "-byte file can hold",
                      {.file = file, .suggestion = "the file is corrupt; re-export it"});
    }
    p = q;
  }
}

const aiScene* import(Assimp::Importer& importer, std::string_view bytes,
                      const std::string& file, const char* hint) {
  // no post-processing flags: Assimp must not drop, merge or fix anything
  const aiScene* scene = importer.ReadFileFromMemory(bytes.data(), bytes.size(), 0, hint);
  if (!scene) {
    throw_bad_input(std::string("cannot read the file: ") + importer.GetErrorString(),
                    {.file = file, .suggestion = "check that it is a valid " +
                                                          std::string(hint) + " file"});
  }
  return scene;
}

// Exact coordinate key of a vertex (-0 and +0 are the same point).
struct Key {
  std::uint64_t x, y, z;
  bool operator==(const Key&) const = default;
};
struct KeyHash {
  std::size_t operator()(const Key& k) const {
    std::uint64_t h = k.x * 0x9E3779B97F4A7C15ull;
    h ^= k.y + 0x7F4A7C159E3779B9ull + (h << 6) + (h >> 2);
    h ^= k.z + 0x94D049BB133111EBull + (h << 6) + (h >> 2);
    return static_cast<std::size_t>(h);
  }
};
std::uint64_t bits(double v) {
  if (v == 0.0) v = 0.0;
  std::uint64_t b;
  std::memcpy(&b, &v, 8);
  return b;
}

// Collects every mesh of the scene (root-level meshes of STL/PLY have identity transforms).
// Every corner index takes at least one byte of the file: `max_corners` bounds what a damaged
// file can make us allocate.
PolygonSoup collect(const aiScene* scene, bool join_identical, std::size_t max_corners,
                    const std::string& file) {
  PolygonSoup soup;
  std::unordered_map<Key, int, KeyHash> seen;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh* mesh = scene->mMeshes[m];
    if (!mesh || !mesh->mVertices) continue;
    const int base = static_cast<int>(soup.vertices.size());
    std::vector<int> remap(mesh->mNumVertices);
    for (unsigned i = 0; i < mesh->mNumVertices; ++i) {
      const aiVector3D& p = mesh->mVertices[i];
      const Vec3 q(p.x, p.y, p.z);
      if (join_identical) {
        const Key key{bits(q.x()), bits(q.y()), bits(q.z())};
        const auto [it, inserted] = seen.try_emplace(key, static_cast<int>(soup.vertices.size()));
        if (inserted) soup.vertices.push_back(q);
        remap[i] = it->second;
      } else {
        soup.vertices.push_back(q);
        remap[i] = base + static_cast<int>(i);
      }
    }
    if (!mesh->mFaces) continue;
    for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
      const aiFace& face = mesh->mFaces[f];
      if (face.mNumIndices > 0 && !face.mIndices) continue;
      if (soup.corners.size() + face.mNumIndices > max_corners) {
        throw_bad_input("the faces declare more vertex indices than the file can hold",
                        {.file = file, .suggestion = "the file is corrupt; re-export it"});
      }
      for (unsigned k = 0; k < face.mNumIndices; ++k) {
        const unsigned i = face.mIndices[k];
        // indices outside this mesh stay out of range for validate_mesh to report
        soup.corners.push_back(i < mesh->mNumVertices ? remap[i] : -1);
      }
      soup.sizes.push_back(static_cast<int>(face.mNumIndices));
    }
  }
  return soup;
}

}  // namespace

TriMesh read_stl(std::string_view bytes, const std::string& file) {
  check_stl_size(bytes, file);
  Assimp::Importer importer;
  const aiScene* scene = import(importer, bytes, file, "stl");
  long skipped = 0;
  TriMesh mesh = triangulate_soup(collect(scene, true, bytes.size(), file), file, &skipped);
  if (skipped > 0) spdlog::warn("{}: skipped {} facets with fewer than 3 corners", file, skipped);
  return mesh;
}

TriMesh read_ply(std::string_view bytes, const std::string& file) {
  if (!starts_with_word(bytes, "ply")) {
    throw_bad_input("not a PLY file (it does not start with 'ply')", {.file = file});
  }
  check_ply_header(bytes, file);
  Assimp::Importer importer;
  const aiScene* scene = import(importer, bytes, file, "ply");
  long skipped = 0;
  TriMesh mesh = triangulate_soup(collect(scene, false, bytes.size(), file), file, &skipped);
  if (skipped > 0) {
    spdlog::warn("{}: skipped {} points/lines (faces with fewer than 3 vertices)", file,
                 skipped);
  }
  return mesh;
}

}  // namespace fascicle::mesh_io_detail
