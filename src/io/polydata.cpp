// .vtp output (our own appended LZ4 encoder, VTK's block layout) and input (VTK's XML reader).
#include "fascicle/io/polydata.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"

#include <vtkCallbackCommand.h>
#include <vtkCellArray.h>
#include <vtkCellData.h>
#include <vtkCommand.h>
#include <vtkDataArray.h>
#include <vtkIdList.h>
#include <vtkLZ4DataCompressor.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkXMLPolyDataReader.h>

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstring>
#include <limits>
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

static_assert(std::endian::native == std::endian::little, "the .vtp writer writes little-endian bytes");

// The appended-data section of a .vtp: every array's bytes, LZ4-compressed in 32 KiB blocks with
// VTK's block header (UInt32: #blocks, block size, last block size, each block's compressed size),
// as vtkXMLWriter lays it out, so VTK's readers (and ParaView >= 5.5) read it.
class AppendedData {
 public:
  // Appends one array; returns its offset in the section (the DataArray's `offset`).
  std::size_t add(const void* data, std::size_t bytes) {
    const std::size_t offset = buffer_.size();
    const auto* in = static_cast<const unsigned char*>(data);
    const std::size_t blocks = (bytes + kBlock - 1) / kBlock;
    const std::size_t header_at = buffer_.size();
    buffer_.resize(header_at + (3 + blocks) * sizeof(std::uint32_t));
    put(header_at, 0, blocks);
    put(header_at, 1, kBlock);
    put(header_at, 2, bytes % kBlock);  // 0: the last block is full (or there is none)
    for (std::size_t b = 0; b < blocks; ++b) {
      const std::size_t n = std::min(kBlock, bytes - b * kBlock);
      const std::size_t at = buffer_.size();
      const std::size_t space = compressor_->GetMaximumCompressionSpace(n);
      buffer_.resize(at + space);
      const std::size_t packed = compressor_->Compress(in + b * kBlock, n, buffer_.data() + at, space);
      if (packed == 0) throw_internal("LZ4 compression of a .vtp array failed");
      buffer_.resize(at + packed);
      put(header_at, 3 + b, packed);
    }
    return offset;
  }
  const std::vector<unsigned char>& get_bytes() const { return buffer_; }

 private:
  static constexpr std::size_t kBlock = 32768;
  void put(std::size_t header_at, std::size_t k, std::size_t value) {
    if (value > 0xffffffffu) throw_internal(".vtp array block too large for a UInt32 header");
    const auto v = static_cast<std::uint32_t>(value);
    std::memcpy(buffer_.data() + header_at + k * sizeof v, &v, sizeof v);
  }
  vtkNew<vtkLZ4DataCompressor> compressor_;
  std::vector<unsigned char> buffer_;
};

// One <DataArray> line (format="appended") and its data, #rows x cols doubles read row by row.
std::string add_double_array(AppendedData& app, const std::string& name, const MatX& values) {
  std::vector<double> rows(static_cast<std::size_t>(values.size()));
  Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(rows.data(), values.rows(),
                                                                                     values.cols()) = values;
  const std::size_t offset = app.add(rows.data(), rows.size() * sizeof(double));
  return fmt::format("<DataArray type=\"Float64\" Name=\"{}\" NumberOfComponents=\"{}\" format=\"appended\" "
                     "offset=\"{}\"/>\n",
                     name, values.cols(), offset);
}

std::string add_int_array(AppendedData& app, const char* name, const std::vector<std::int32_t>& values) {
  const std::size_t offset = app.add(values.data(), values.size() * sizeof(std::int32_t));
  return fmt::format("<DataArray type=\"Int32\" Name=\"{}\" format=\"appended\" offset=\"{}\"/>\n", name, offset);
}

std::string escape_xml(const std::string& text) {
  std::string out;
  for (char c : text) {
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

}  // namespace

void write_polydata(const std::filesystem::path& path, const PolyData& data) {
  check_polydata(data);
  if (data.points.rows() > std::numeric_limits<std::int32_t>::max())
    throw_internal("polydata: more than 2^31 points");
  // Arrays in the order VTK's reader expects nothing about (each has its own offset).
  AppendedData app;
  std::string point_xml, cell_xml;
  for (const auto& f : data.point_fields) point_xml += "        " + add_double_array(app, escape_xml(f.name), f.values);
  for (const auto& f : data.cell_fields) cell_xml += "        " + add_double_array(app, escape_xml(f.name), f.values);
  const std::string points_xml = "        " + add_double_array(app, "Points", data.points);
  std::string lines_xml, polys_xml;
  if (!data.lines.empty()) {
    std::vector<std::int32_t> connectivity, offsets;
    for (const auto& line : data.lines) {
      connectivity.insert(connectivity.end(), line.begin(), line.end());
      offsets.push_back(static_cast<std::int32_t>(connectivity.size()));
    }
    lines_xml = "        " + add_int_array(app, "connectivity", connectivity) + "        " +
                add_int_array(app, "offsets", offsets);
  }
  if (data.triangles.rows() > 0) {
    std::vector<std::int32_t> connectivity(static_cast<std::size_t>(data.triangles.size()));
    Eigen::Map<Eigen::Matrix<std::int32_t, Eigen::Dynamic, 3, Eigen::RowMajor>>(connectivity.data(),
                                                                                data.triangles.rows(), 3) = data.triangles;
    std::vector<std::int32_t> offsets(static_cast<std::size_t>(data.triangles.rows()));
    for (std::size_t t = 0; t < offsets.size(); ++t) offsets[t] = static_cast<std::int32_t>(3 * (t + 1));
    polys_xml = "        " + add_int_array(app, "connectivity", connectivity) + "        " +
                add_int_array(app, "offsets", offsets);
  }
  std::string xml = fmt::format(
      "<?xml version=\"1.0\"?>\n"
      "<VTKFile type=\"PolyData\" version=\"0.1\" byte_order=\"LittleEndian\" header_type=\"UInt32\" "
      "compressor=\"vtkLZ4DataCompressor\">\n"
      "  <PolyData>\n"
      "    <Piece NumberOfPoints=\"{}\" NumberOfVerts=\"0\" NumberOfLines=\"{}\" NumberOfStrips=\"0\" "
      "NumberOfPolys=\"{}\">\n",
      data.points.rows(), data.lines.size(), data.triangles.rows());
  xml += "      <PointData>\n" + point_xml + "      </PointData>\n";
  xml += "      <CellData>\n" + cell_xml + "      </CellData>\n";
  xml += "      <Points>\n" + points_xml + "      </Points>\n";
  if (!lines_xml.empty()) xml += "      <Lines>\n" + lines_xml + "      </Lines>\n";
  if (!polys_xml.empty()) xml += "      <Polys>\n" + polys_xml + "      </Polys>\n";
  xml += "    </Piece>\n  </PolyData>\n  <AppendedData encoding=\"raw\">\n   _";
  const std::string tail = "\n  </AppendedData>\n</VTKFile>\n";
  write_file_atomically(path, [&](std::ostream& out) {
    out.write(xml.data(), static_cast<std::streamsize>(xml.size()));
    const auto& bytes = app.get_bytes();
    out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
    out.write(tail.data(), static_cast<std::streamsize>(tail.size()));
  });
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
