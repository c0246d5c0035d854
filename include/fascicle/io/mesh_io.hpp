// Reading and writing triangle surface meshes: OBJ, STL (ASCII/binary), PLY (ASCII/binary) and
// VTK XML PolyData (.vtp: ASCII, binary, appended; zlib-compressed or not). The format follows the
// file extension (case-insensitive). Readers hand the raw data to the caller without repairing it
// (run validate_mesh / repair_mesh on the result); see docs/geometry.md for details per format.
#pragma once

#include "fascicle/core/units.hpp"
#include "fascicle/geometry/tri_mesh.hpp"

#include <filesystem>
#include <string>
#include <string_view>

namespace fascicle {

enum class MeshFormat { obj, stl, ply, vtp };

// The format of a path by its extension; throws a usage error for unknown extensions.
MeshFormat find_mesh_format(const std::filesystem::path& path);
std::string to_string(MeshFormat format);

// Reads a triangle mesh. Positions are scaled from `unit` to metres. Polygons with more than three
// vertices are split into a fan of triangles around their first vertex (correct for convex
// polygons). STL vertices are joined when their coordinates are bitwise identical. Out-of-range
// indices (OBJ, PLY, VTP) and NaN/Inf coordinates are kept as read, for validate_mesh to report.
// Throws fascicle::Error (bad_input, naming the file and, where known, the line) when the file is
// missing, unreadable, malformed or holds no triangles.
TriMesh read_mesh(const std::filesystem::path& path, LengthUnit unit = LengthUnit::metre);

// The same from the bytes of a file already in memory; `name` is used in error messages.
TriMesh read_mesh_from_memory(std::string_view bytes, MeshFormat format,
                              LengthUnit unit = LengthUnit::metre,
                              const std::string& name = "<memory>");

enum class MeshEncoding {
  binary,    // STL/PLY binary little-endian; VTP inline base64 binary
  ascii,     // text
  appended,  // VTP only: raw appended data block (as ParaView writes); other formats: binary
};

struct MeshWriteOptions {
  MeshEncoding encoding = MeshEncoding::binary;
  bool compress = true;                  // VTP binary/appended: zlib compression
  LengthUnit unit = LengthUnit::metre;   // the file's length unit (positions are divided by it)
};

// Writes a mesh atomically (temporary file + rename). OBJ is always text (17 significant digits,
// exact for doubles); STL stores float32; PLY and VTP store float64. Throws fascicle::Error
// (bad_input) if the folder is not writable, or usage for an unknown extension.
void write_mesh(const std::filesystem::path& path, const TriMesh& mesh,
                MeshWriteOptions options = {});

}  // namespace fascicle
