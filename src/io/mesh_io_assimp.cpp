// STL and PLY readers through Assimp, with no post-processing: what the file holds reaches the
// caller (only STL's unshared facet corners are joined, by exact coordinates).
#include "mesh_io_internal.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/log.hpp"

#include <assimp/Importer.hpp>
#include <assimp/scene.h>

#include <cctype>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <unordered_map>

namespace fascicle::mesh_io_detail {
namespace {

std::vector<char> read_bytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw_bad_input("cannot open the file", {.file = path.string()});
  return std::vector<char>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

bool starts_with_word(const std::vector<char>& bytes, const char* word) {
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
void check_stl_size(const std::vector<char>& bytes, const std::filesystem::path& path) {
  if (bytes.empty()) {
    throw_bad_input("the file is empty", {.file = path.string(),
                                          .suggestion = "re-export the mesh"});
  }
  const bool ascii_like = starts_with_word(bytes, "solid");
  if (bytes.size() < 84) {
    if (ascii_like) return;
    throw_bad_input("too short for a binary STL (" + std::to_string(bytes.size()) +
                        " bytes, the header alone needs 84)",
                    {.file = path.string(), .suggestion = "the file is truncated; re-export it"});
  }
  std::uint32_t count = 0;
  std::memcpy(&count, bytes.data() + 80, 4);
  const std::uint64_t expected = 84 + 50 * static_cast<std::uint64_t>(count);
  if (expected == bytes.size() || ascii_like) return;
  throw_bad_input("binary STL header declares " + std::to_string(count) + " triangles (" +
                      std::to_string(expected) + " bytes) but the file has " +
                      std::to_string(bytes.size()) + " bytes",
                  {.file = path.string(),
                   .suggestion = expected > bytes.size() ? "the file is truncated; re-export it"
                                                         : "the file has trailing data or a "
                                                           "wrong triangle count"});
}

const aiScene* import(Assimp::Importer& importer, const std::vector<char>& bytes,
                      const std::filesystem::path& path, const char* hint) {
  // no post-processing flags: Assimp must not drop, merge or fix anything
  const aiScene* scene = importer.ReadFileFromMemory(bytes.data(), bytes.size(), 0, hint);
  if (!scene) {
    throw_bad_input(std::string("cannot read the file: ") + importer.GetErrorString(),
                    {.file = path.string(), .suggestion = "check that it is a valid " +
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
PolygonSoup collect(const aiScene* scene, bool join_identical) {
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

TriMesh read_stl(const std::filesystem::path& path) {
  const std::vector<char> bytes = read_bytes(path);
  check_stl_size(bytes, path);
  Assimp::Importer importer;
  const aiScene* scene = import(importer, bytes, path, "stl");
  long skipped = 0;
  TriMesh mesh = triangulate_soup(collect(scene, true), path.string(), &skipped);
  if (skipped > 0) spdlog::warn("{}: skipped {} facets with fewer than 3 corners", path.string(), skipped);
  return mesh;
}

TriMesh read_ply(const std::filesystem::path& path) {
  const std::vector<char> bytes = read_bytes(path);
  if (!starts_with_word(bytes, "ply")) {
    throw_bad_input("not a PLY file (it does not start with 'ply')", {.file = path.string()});
  }
  Assimp::Importer importer;
  const aiScene* scene = import(importer, bytes, path, "ply");
  long skipped = 0;
  TriMesh mesh = triangulate_soup(collect(scene, false), path.string(), &skipped);
  if (skipped > 0) {
    spdlog::warn("{}: skipped {} points/lines (faces with fewer than 3 vertices)", path.string(),
                 skipped);
  }
  return mesh;
}

}  // namespace fascicle::mesh_io_detail
