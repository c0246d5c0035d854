// .vtp output and input of PolyData through VTK's XML writer and reader.
#include "fascicle/io/polydata.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"
#include "vtk_smp.hpp"

#include <vtkCallbackCommand.h>
#include <vtkCellArray.h>
#include <vtkCellData.h>
#include <vtkCellType.h>
#include <vtkCellTypes.h>
#include <vtkCommand.h>
#include <vtkDataArray.h>
#include <vtkIdList.h>
#include <vtkDoubleArray.h>
#include <vtkNew.h>
#include <vtkObjectFactory.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkSmartPointer.h>
#include <vtkTypeInt32Array.h>
#include <vtkXMLPolyDataReader.h>
#include <vtkXMLPolyDataWriter.h>

#include <algorithm>
#include <cstdint>
#include <functional>
#include <limits>
#include <sstream>
#include <string>

namespace fascicle {
namespace {

// Gathers VTK error events of one object so they become a fascicle::Error, not console noise.
struct VtkErrorLog {
  std::string text;
  static void on_event(vtkObject*, unsigned long event, void* client, void* call) {
    auto* self = static_cast<VtkErrorLog*>(client);
    if (event != vtkCommand::ErrorEvent || call == nullptr) return;
    std::string t(static_cast<const char*>(call));
    while (!t.empty() && (t.back() == '\n' || t.back() == ' ')) t.pop_back();
    if (!self->text.empty()) self->text += "; ";
    self->text += t.substr(0, 300);
  }
  void observe(vtkObject* object) {
    vtkNew<vtkCallbackCommand> cb;
    cb->SetCallback(&VtkErrorLog::on_event);
    cb->SetClientData(this);
    object->AddObserver(vtkCommand::ErrorEvent, cb);
    object->AddObserver(vtkCommand::WarningEvent, cb);
  }
};

std::vector<DataField> from_vtk_fields(vtkFieldData* data) {
  std::vector<DataField> fields;
  for (int i = 0; i < data->GetNumberOfArrays(); ++i) {
    vtkDataArray* array = vtkDataArray::SafeDownCast(data->GetAbstractArray(i));
    if (array == nullptr) continue;
    DataField field;
    field.name = array->GetName() ? array->GetName() : "";
    field.values.resize(array->GetNumberOfTuples(), array->GetNumberOfComponents());
    for (vtkIdType r = 0; r < array->GetNumberOfTuples(); ++r)
      for (int c = 0; c < array->GetNumberOfComponents(); ++c)
        field.values(r, c) = array->GetComponent(r, c);
    fields.push_back(std::move(field));
  }
  return fields;
}

}  // namespace

PolyData make_polydata(const TriMesh& mesh) {
  PolyData data;
  data.points = mesh.V;
  data.triangles = mesh.F;
  return data;
}

void check_polydata(const PolyData& data) {
  const long n = data.points.rows();
  for (const auto& line : data.lines) {
    if (line.size() < 2) throw_internal("polydata: a polyline has fewer than 2 points");
    for (int i : line)
      if (i < 0 || i >= n) throw_internal("polydata: polyline index out of range");
  }
  if (data.triangles.size() > 0 && (data.triangles.minCoeff() < 0 || data.triangles.maxCoeff() >= n))
    throw_internal("polydata: triangle index out of range");
  for (const auto& f : data.point_fields)
    if (f.values.rows() != n)
      throw_internal("polydata: point field has " + std::to_string(f.values.rows()) + " rows, expected " +
                     std::to_string(n), {.object = f.name});
  for (const auto& f : data.cell_fields)
    if (f.values.rows() != data.num_cells())
      throw_internal("polydata: cell field has " + std::to_string(f.values.rows()) + " rows, expected " +
                     std::to_string(data.num_cells()), {.object = f.name});
}

namespace {

// VTK's XML writer puts array names into attributes verbatim; escaped here, they read back as
// given (the reader's XML parser decodes the entities).
std::string escape_xml(const std::string& text) {
  std::string out;
  for (const char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

// A VTK array holding `values` (#rows x cols, row by row), filled in one pass.
vtkSmartPointer<vtkDoubleArray> to_vtk_array(const std::string& name, const MatX& values) {
  auto array = vtkSmartPointer<vtkDoubleArray>::New();
  array->SetName(escape_xml(name).c_str());
  array->SetNumberOfComponents(static_cast<int>(values.cols()));
  array->SetNumberOfTuples(values.rows());
  Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
      array->GetPointer(0), values.rows(), values.cols()) = values;
  return array;
}

// Cells from VTK 9's offsets + connectivity arrays, stored as 32-bit ids (smaller files; the
// readers take either width), filled in place.
vtkNew<vtkCellArray> make_cells(vtkIdType num_cells, vtkIdType num_ids,
                                const std::function<void(std::int32_t* offsets, std::int32_t* connectivity)>& fill) {
  vtkNew<vtkTypeInt32Array> off, conn;
  off->SetNumberOfValues(num_cells + 1);
  conn->SetNumberOfValues(num_ids);
  fill(off->GetPointer(0), conn->GetPointer(0));
  vtkNew<vtkCellArray> cells;
  cells->SetData(off, conn);
  return cells;
}

// A vtkPolyData that lists its cell types from the cell sizes write_polydata knows instead of
// asking every cell: VTK 9.1's XML writer calls GetCellTypes once per file, and vtkDataSet's
// version builds the poly data's per-cell type map (BuildCells) and reads it cell by cell (about
// a third of VTK's encoding work on the VH shank's 100k-triangle foot). The list is the one
// vtkDataSet::GetCellTypes makes: each type once, in the order of first appearance in cell order
// (vertices, lines, polygons, strips), with vtkPolyData's types (a 2-point line VTK_LINE, a longer
// one VTK_POLY_LINE, a 3-point polygon VTK_TRIANGLE).
class KnownTypesPolyData : public vtkPolyData {
 public:
  static KnownTypesPolyData* New();
  vtkTypeMacro(KnownTypesPolyData, vtkPolyData)
  void GetCellTypes(vtkCellTypes* types) override {
    types->Reset();
    for (const unsigned char t : cell_types) types->InsertNextType(t);
  }
  std::vector<unsigned char> cell_types;  // distinct, in order of first appearance
};
vtkStandardNewMacro(KnownTypesPolyData)

// vtkXMLPolyDataWriter writing into a stream given by the caller (vtkXMLWriter keeps its output
// stream in the protected member `Stream`, takes a stream already set as its output and rewinds
// it; the writer releases it after each Write()).
class StreamPolyDataWriter : public vtkXMLPolyDataWriter {
 public:
  static StreamPolyDataWriter* New();
  vtkTypeMacro(StreamPolyDataWriter, vtkXMLPolyDataWriter)
  void set_stream(std::ostream* stream) { this->Stream = stream; }
};
vtkStandardNewMacro(StreamPolyDataWriter)

// One encoding buffer per thread, kept between files: VTK's many small writes (and its seeks back
// to fill in offsets) go into memory whose capacity is reused, instead of a fresh string stream
// per file that grows by doubling and is then copied out twice (str(), GetOutputString()).
// Re-entrance: unless use_sequential_vtk_loops() was called (the CLI does), VTK's range
// computations run vtkSMPTools on TBB, so a thread waiting inside
// Write() may start another write_polydata() of the same parallel loop on the same thread. The
// buffer is therefore only borrowed: moved into the call's own stream before encoding and given
// back after the file is written, never used in place across a call that can wait on TBB.
std::string& get_encoding_buffer() {
  thread_local std::string buffer;
  return buffer;
}

}  // namespace

bool use_sequential_vtk_loops() { return io_detail::use_sequential_vtk_smp(); }

void write_polydata(const std::filesystem::path& path, const PolyData& data, VtpCompression compression) {
  check_polydata(data);
  if (data.points.rows() > std::numeric_limits<std::int32_t>::max() ||
      data.triangles.size() > std::numeric_limits<std::int32_t>::max())
    throw_internal("polydata: more than 2^31 points or cell ids");
  vtkNew<vtkPoints> points;
  points->SetData(to_vtk_array("Points", data.points));
  vtkNew<KnownTypesPolyData> poly;
  poly->SetPoints(points);
  const auto add_type = [&](unsigned char t) {
    if (std::find(poly->cell_types.begin(), poly->cell_types.end(), t) == poly->cell_types.end())
      poly->cell_types.push_back(t);
  };
  for (const auto& line : data.lines) add_type(line.size() == 2 ? VTK_LINE : VTK_POLY_LINE);
  if (data.triangles.rows() > 0) add_type(VTK_TRIANGLE);
  if (!data.lines.empty()) {
    vtkIdType ids = 0;
    for (const auto& line : data.lines) ids += static_cast<vtkIdType>(line.size());
    poly->SetLines(make_cells(static_cast<vtkIdType>(data.lines.size()), ids, [&](std::int32_t* offsets, std::int32_t* connectivity) {
      std::int32_t at = 0;
      offsets[0] = 0;
      for (std::size_t l = 0; l < data.lines.size(); ++l) {
        for (const int i : data.lines[l]) connectivity[at++] = i;
        offsets[l + 1] = at;
      }
    }));
  }
  if (data.triangles.rows() > 0) {
    const Eigen::Index nt = data.triangles.rows();
    poly->SetPolys(make_cells(nt, 3 * nt, [&](std::int32_t* offsets, std::int32_t* connectivity) {
      Eigen::Map<Eigen::Matrix<std::int32_t, Eigen::Dynamic, 3, Eigen::RowMajor>>(connectivity, nt, 3) = data.triangles;
      for (Eigen::Index t = 0; t <= nt; ++t) offsets[t] = static_cast<std::int32_t>(3 * t);
    }));
  }
  for (const auto& f : data.point_fields) poly->GetPointData()->AddArray(to_vtk_array(f.name, f.values));
  for (const auto& f : data.cell_fields) poly->GetCellData()->AddArray(to_vtk_array(f.name, f.values));

  // VTK's XML writer encodes into memory (appended raw binary, LZ4 or none); the file is then
  // written in one piece through a temporary and a rename, so no half-written file is ever left.
  std::string& buffer = get_encoding_buffer();
  buffer.clear();
  std::ostringstream stream(std::move(buffer), std::ios::out | std::ios::binary);
  vtkNew<StreamPolyDataWriter> writer;
  VtkErrorLog log;
  log.observe(writer);
  writer->SetInputData(poly);
  writer->set_stream(&stream);
  writer->SetDataModeToAppended();
  writer->EncodeAppendedDataOff();
  writer->SetHeaderTypeToUInt32();
  writer->SetIdTypeToInt32();
  // LZ4, not zlib: per-frame outputs are written every frame, and on a 60k-triangle bone VTK's
  // zlib takes ~13x longer than LZ4 for files ~1.6x smaller (ParaView >= 5.5 reads both).
  if (compression == VtpCompression::lz4)
    writer->SetCompressorTypeToLZ4();
  else
    writer->SetCompressorTypeToNone();
  if (writer->Write() != 1 || !log.text.empty())
    throw_bad_input("VTK could not encode the file: " + (log.text.empty() ? "unknown error" : log.text),
                    {.file = path.string(), .suggestion = "report this with the scene that produced it"});
  std::string bytes = std::move(stream).str();
  write_file_atomically(path, [&](std::ostream& out) { out.write(bytes.data(), static_cast<std::streamsize>(bytes.size())); });
  if (bytes.capacity() <= (std::size_t{64} << 20)) buffer = std::move(bytes);  // not kept for a rare huge file
}

PolyData read_polydata(const std::filesystem::path& path) {
  const std::string file = path.string();
  vtkNew<vtkXMLPolyDataReader> reader;
  VtkErrorLog log;
  log.observe(reader);
  if (!std::filesystem::exists(path) || !reader->CanReadFile(file.c_str()))
    throw_bad_input("not a readable VTK XML PolyData file", {.file = file});
  reader->SetFileName(file.c_str());
  reader->Update();
  vtkPolyData* poly = reader->GetOutput();
  if (!log.text.empty() || poly == nullptr)
    throw_bad_input("VTK could not read the file: " + log.text, {.file = file});

  PolyData data;
  data.points.resize(poly->GetNumberOfPoints(), 3);
  for (vtkIdType i = 0; i < poly->GetNumberOfPoints(); ++i) {
    double p[3];
    poly->GetPoint(i, p);
    data.points.row(i) << p[0], p[1], p[2];
  }
  vtkNew<vtkIdList> ids;
  for (poly->GetLines()->InitTraversal(); poly->GetLines()->GetNextCell(ids);) {
    std::vector<int> line(ids->GetNumberOfIds());
    for (vtkIdType k = 0; k < ids->GetNumberOfIds(); ++k) line[k] = static_cast<int>(ids->GetId(k));
    data.lines.push_back(std::move(line));
  }
  std::vector<Eigen::Vector3i> tris;
  for (poly->GetPolys()->InitTraversal(); poly->GetPolys()->GetNextCell(ids);) {
    for (vtkIdType k = 1; k + 1 < ids->GetNumberOfIds(); ++k)
      tris.emplace_back(ids->GetId(0), ids->GetId(k), ids->GetId(k + 1));
  }
  data.triangles.resize(static_cast<Eigen::Index>(tris.size()), 3);
  for (size_t t = 0; t < tris.size(); ++t) data.triangles.row(t) = tris[t].transpose();
  data.point_fields = from_vtk_fields(poly->GetPointData());
  data.cell_fields = from_vtk_fields(poly->GetCellData());
  return data;
}

}  // namespace fascicle
