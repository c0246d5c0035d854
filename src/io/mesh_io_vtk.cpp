// VTK XML PolyData (.vtp) through VTK's own vtkXMLPolyDataReader / vtkXMLPolyDataWriter.
#include "mesh_io_internal.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/core/log.hpp"

#include <vtkCallbackCommand.h>
#include <vtkCellArray.h>
#include <vtkCellArrayIterator.h>
#include <vtkCommand.h>
#include <vtkDoubleArray.h>
#include <vtkIdTypeArray.h>
#include <vtkNew.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkSmartPointer.h>
#include <vtkXMLPolyDataReader.h>
#include <vtkXMLPolyDataWriter.h>

#include <climits>
#include <string>

namespace fascicle::mesh_io_detail {
namespace {

// Collects the error and warning events of a VTK object instead of printing them.
struct VtkMessages {
  std::string errors;
  static void on_event(vtkObject*, unsigned long event, void* client, void* call) {
    auto* self = static_cast<VtkMessages*>(client);
    const char* text = static_cast<const char*>(call);
    if (event == vtkCommand::ErrorEvent && text) {
      if (!self->errors.empty()) self->errors += "; ";
      std::string t(text);
      while (!t.empty() && (t.back() == '\n' || t.back() == ' ')) t.pop_back();
      self->errors += t.substr(0, 300);
    }
  }
  void observe(vtkObject* object) {
    vtkNew<vtkCallbackCommand> cb;
    cb->SetCallback(&VtkMessages::on_event);
    cb->SetClientData(this);
    object->AddObserver(vtkCommand::ErrorEvent, cb);
    object->AddObserver(vtkCommand::WarningEvent, cb);
  }
};

int to_index(vtkIdType id, vtkIdType num_points) {
  return (id < 0 || id >= num_points || id > INT_MAX) ? -1 : static_cast<int>(id);
}

}  // namespace

TriMesh read_vtp(const std::filesystem::path& path) {
  const std::string file = path.string();
  vtkNew<vtkXMLPolyDataReader> reader;
  VtkMessages messages;
  messages.observe(reader);
  if (!reader->CanReadFile(file.c_str())) {
    throw_bad_input("not a VTK XML PolyData file",
                    {.file = file, .suggestion = "check that it is a .vtp written by VTK, "
                                                 "ParaView or OpenSim"});
  }
  reader->SetFileName(file.c_str());
  reader->Update();
  vtkPolyData* data = reader->GetOutput();
  if (!messages.errors.empty() || reader->GetErrorCode() != 0 || !data) {
    throw_bad_input("VTK cannot read the file: " +
                        (messages.errors.empty() ? std::string("unknown error") : messages.errors),
                    {.file = file, .suggestion = "the file is corrupt or truncated; re-export it"});
  }
  PolygonSoup soup;
  const vtkIdType num_points = data->GetNumberOfPoints();
  soup.vertices.resize(static_cast<std::size_t>(num_points));
  for (vtkIdType i = 0; i < num_points; ++i) {
    double p[3];
    data->GetPoint(i, p);
    soup.vertices[static_cast<std::size_t>(i)] = Vec3(p[0], p[1], p[2]);
  }
  // polygons (triangles pass through; n-gons become fans in triangulate_soup)
  if (vtkCellArray* polys = data->GetPolys()) {
    auto it = vtk::TakeSmartPointer(polys->NewIterator());
    for (it->GoToFirstCell(); !it->IsDoneWithTraversal(); it->GoToNextCell()) {
      vtkIdType n = 0;
      const vtkIdType* ids = nullptr;
      it->GetCurrentCell(n, ids);
      for (vtkIdType k = 0; k < n; ++k) soup.corners.push_back(to_index(ids[k], num_points));
      soup.sizes.push_back(static_cast<int>(n));
    }
  }
  // triangle strips: triangle k is (k, k+1, k+2), every other one reversed to keep the winding
  if (vtkCellArray* strips = data->GetStrips()) {
    auto it = vtk::TakeSmartPointer(strips->NewIterator());
    for (it->GoToFirstCell(); !it->IsDoneWithTraversal(); it->GoToNextCell()) {
      vtkIdType n = 0;
      const vtkIdType* ids = nullptr;
      it->GetCurrentCell(n, ids);
      for (vtkIdType k = 0; k + 2 < n; ++k) {
        const bool odd = (k % 2) == 1;
        soup.corners.push_back(to_index(ids[k], num_points));
        soup.corners.push_back(to_index(ids[odd ? k + 2 : k + 1], num_points));
        soup.corners.push_back(to_index(ids[odd ? k + 1 : k + 2], num_points));
        soup.sizes.push_back(3);
      }
    }
  }
  long skipped = 0;
  TriMesh mesh = triangulate_soup(soup, file, &skipped);
  const vtkIdType other = data->GetNumberOfVerts() + data->GetNumberOfLines();
  if (skipped + other > 0) {
    spdlog::warn("{}: ignored {} vertex/line cells and {} polygons with fewer than 3 points", file,
                 other, skipped);
  }
  return mesh;
}

void write_vtp(const std::filesystem::path& path, const TriMesh& mesh, MeshEncoding encoding,
               bool compress) {
  vtkNew<vtkDoubleArray> coords;
  coords->SetNumberOfComponents(3);
  coords->SetNumberOfTuples(mesh.V.rows());
  for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
    coords->SetTypedTuple(i, mesh.V.row(i).eval().data());
  }
  vtkNew<vtkPoints> points;
  points->SetData(coords);
  vtkNew<vtkIdTypeArray> offsets, connectivity;
  offsets->SetNumberOfValues(mesh.F.rows() + 1);
  connectivity->SetNumberOfValues(3 * mesh.F.rows());
  for (Eigen::Index f = 0; f <= mesh.F.rows(); ++f) offsets->SetValue(f, 3 * f);
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) connectivity->SetValue(3 * f + k, mesh.F(f, k));
  }
  vtkNew<vtkCellArray> polys;
  polys->SetData(offsets, connectivity);
  vtkNew<vtkPolyData> data;
  data->SetPoints(points);
  data->SetPolys(polys);

  write_via_temporary(path, [&](const std::filesystem::path& tmp) {
    vtkNew<vtkXMLPolyDataWriter> writer;
    VtkMessages messages;
    messages.observe(writer);
    writer->SetInputData(data);
    writer->SetFileName(tmp.string().c_str());
    switch (encoding) {
      case MeshEncoding::ascii: writer->SetDataModeToAscii(); break;
      case MeshEncoding::binary: writer->SetDataModeToBinary(); break;
      case MeshEncoding::appended:
        writer->SetDataModeToAppended();
        writer->EncodeAppendedDataOff();  // raw bytes, as ParaView writes
        break;
    }
    if (compress) writer->SetCompressorTypeToZLib();
    else writer->SetCompressorTypeToNone();
    if (writer->Write() != 1 || !messages.errors.empty()) {
      throw_bad_input("VTK could not write the file: " + messages.errors,
                      {.file = path.string(), .suggestion = "check the folder and free space"});
    }
  });
}

}  // namespace fascicle::mesh_io_detail
