// .vtp output and input of PolyData through VTK's XML writer and reader.
#include "fascicle/io/polydata.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"

#include <vtkCallbackCommand.h>
#include <vtkCellArray.h>
#include <vtkCellData.h>
#include <vtkCommand.h>
#include <vtkDataArray.h>
#include <vtkDoubleArray.h>
#include <vtkIdList.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkXMLPolyDataReader.h>
#include <vtkXMLPolyDataWriter.h>

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

vtkNew<vtkDoubleArray> to_vtk_array(const DataField& field) {
  vtkNew<vtkDoubleArray> array;
  array->SetName(field.name.c_str());
  array->SetNumberOfComponents(static_cast<int>(field.values.cols()));
  array->SetNumberOfTuples(field.values.rows());
  for (Eigen::Index r = 0; r < field.values.rows(); ++r)
    for (Eigen::Index c = 0; c < field.values.cols(); ++c)
      array->SetComponent(r, static_cast<int>(c), field.values(r, c));
  return array;
}

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

void write_polydata(const std::filesystem::path& path, const PolyData& data) {
  check_polydata(data);
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(data.points.rows());
  for (Eigen::Index i = 0; i < data.points.rows(); ++i)
    points->SetPoint(i, data.points(i, 0), data.points(i, 1), data.points(i, 2));
  vtkNew<vtkPolyData> poly;
  poly->SetPoints(points);
  if (!data.lines.empty()) {
    vtkNew<vtkCellArray> lines;
    for (const auto& line : data.lines) {
      lines->InsertNextCell(static_cast<vtkIdType>(line.size()));
      for (int i : line) lines->InsertCellPoint(i);
    }
    poly->SetLines(lines);
  }
  if (data.triangles.rows() > 0) {
    vtkNew<vtkCellArray> polys;
    for (Eigen::Index t = 0; t < data.triangles.rows(); ++t) {
      const vtkIdType ids[3] = {data.triangles(t, 0), data.triangles(t, 1), data.triangles(t, 2)};
      polys->InsertNextCell(3, ids);
    }
    poly->SetPolys(polys);
  }
  for (const auto& f : data.point_fields) poly->GetPointData()->AddArray(to_vtk_array(f));
  for (const auto& f : data.cell_fields) poly->GetCellData()->AddArray(to_vtk_array(f));

  write_via_temporary(path, [&](const std::filesystem::path& tmp) {
    vtkNew<vtkXMLPolyDataWriter> writer;
    VtkErrorLog log;
    log.observe(writer);
    writer->SetFileName(tmp.string().c_str());
    writer->SetInputData(poly);
    writer->SetDataModeToAppended();
    writer->EncodeAppendedDataOff();
    // LZ4, not zlib: per-frame outputs are written every frame, and on a 60k-triangle bone VTK's
    // zlib takes ~13x longer than LZ4 for files ~1.6x smaller (ParaView >= 5.5 reads both).
    writer->SetCompressorTypeToLZ4();
    if (writer->Write() != 1 || !log.text.empty()) {
      throw_bad_input("VTK could not write the file: " + (log.text.empty() ? "unknown error" : log.text),
                      {.file = path.string(), .suggestion = "check the output folder and free space"});
    }
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
