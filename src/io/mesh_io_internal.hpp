// Format-specific mesh readers and writers behind read_mesh / write_mesh (not a public header).
#pragma once

#include "fascicle/io/mesh_io.hpp"

#include <string>
#include <string_view>
#include <vector>

namespace fascicle::mesh_io_detail {

// Polygons collected by a reader before they become triangles.
struct PolygonSoup {
  std::vector<Vec3> vertices;
  std::vector<int> corners;     // vertex indices of all polygons, concatenated
  std::vector<int> sizes;       // corner count per polygon
};

// Fan-triangulates every polygon (>= 3 corners) around its first corner; polygons with fewer than
// three corners are counted in `skipped`. Throws bad_input if no triangle results.
TriMesh triangulate_soup(const PolygonSoup& soup, const std::string& file, long* skipped);

// Readers of a whole file's bytes; `file` names it in error messages.
TriMesh read_obj(std::string_view bytes, const std::string& file);
TriMesh read_stl(std::string_view bytes, const std::string& file);  // Assimp, size pre-check
TriMesh read_ply(std::string_view bytes, const std::string& file);  // Assimp, header pre-check
TriMesh read_vtp(std::string_view bytes, const std::string& file);  // VTK

// `mesh` is already in the file's unit.
void write_obj(const std::filesystem::path& path, const TriMesh& mesh);
void write_stl(const std::filesystem::path& path, const TriMesh& mesh, bool ascii);
void write_ply(const std::filesystem::path& path, const TriMesh& mesh, bool ascii);
void write_vtp(const std::filesystem::path& path, const TriMesh& mesh, MeshEncoding encoding,
               bool compress);

}  // namespace fascicle::mesh_io_detail
