// PolyData: points with triangles and/or polylines plus named point and cell fields, written as a
// VTK XML PolyData file (.vtp) by VTK's own vtkXMLPolyDataWriter (appended raw binary, LZ4 or
// uncompressed, UInt32 block headers, Int32 connectivity and offsets), as ParaView reads it. Used
// for the per-frame outputs: bones, muscle surfaces, fibres, action lines.
#pragma once

#include "fascicle/core/types.hpp"
#include "fascicle/geometry/tri_mesh.hpp"

#include <filesystem>
#include <string>
#include <vector>

namespace fascicle {

// A named array: one row per point (or cell), `values.cols()` components (1 scalar, 3 vector).
struct DataField {
  std::string name;
  MatX values;
};

// Cells are ordered as VTK orders them: all polylines first, then all triangles. Cell fields have
// #lines + #triangles rows in that order; point fields have #points rows.
struct PolyData {
  Points3 points;                       // #P×3, metres
  std::vector<std::vector<int>> lines;  // polylines: point indices, each ≥ 2 points
  Triangles triangles;                  // #T×3 point indices
  std::vector<DataField> point_fields;
  std::vector<DataField> cell_fields;

  long num_cells() const { return static_cast<long>(lines.size()) + triangles.rows(); }
};

// A PolyData holding a triangle mesh without fields.
PolyData make_polydata(const TriMesh& mesh);

// Throws fascicle::Error (internal) when indices are out of range or field sizes do not match,
// naming the field.
void check_polydata(const PolyData& data);

// How the arrays of a .vtp are stored. LZ4 pays where an array repeats itself (a field constant
// over the cells); coordinates, displacements and triangle ids of segmented meshes hardly compress
// (VH bones 1.9 %; regular procedural meshes do, the demo's bones by 20 %), and LZ4 costs system
// time (a buffer per 32 KiB block). VTK's readers and ParaView read both.
enum class VtpCompression { lz4, none };

// Writes a .vtp: VTK encodes it into a buffer in memory (one per thread, reused from file to file),
// then it goes into a temporary file that is renamed over `path` on success (an error never leaves
// a partial file; the same input gives the same bytes).
// Throws fascicle::Error (bad_input naming the path) when the folder is not writable or VTK
// reports an error.
void write_polydata(const std::filesystem::path& path, const PolyData& data,
                    VtpCompression compression = VtpCompression::lz4);

// Makes VTK's own parallel loops (vtkSMPTools) run sequentially in this process and returns
// whether they now do. The .vtp writer's only parallel work there is each array's value range (a
// few thousand values), while fascicle already writes a frame's files in parallel, so VTK's TBB
// backend only adds a nested split and a thread-local set-up per array; minimum and maximum do not
// depend on the order, so the files are the same either way. The setting is process-wide and VTK
// does not guard it: call this once at start-up, before other threads use VTK (the fascicle CLI
// does). An explicit VTK_SMP_BACKEND_IN_USE in the environment is left alone.
bool use_sequential_vtk_loops();

// Reads a .vtp with vtkXMLPolyDataReader: points, polylines, triangles (polygons with more than
// three points are kept as fans) and all double/float/int point and cell arrays as doubles.
// Throws fascicle::Error (bad_input naming the file) when it cannot be read.
PolyData read_polydata(const std::filesystem::path& path);

}  // namespace fascicle
