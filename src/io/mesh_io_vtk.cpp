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

#include <charconv>
#include <cctype>
#include <climits>
#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>

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

// Decodes base64 text into `out` (stops at the first non-alphabet character).
void decode_base64(std::string_view text, std::size_t max_bytes, std::string& out) {
  static constexpr std::string_view alphabet =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  unsigned buffer = 0;
  int bits = 0;
  for (const char c : text) {
    const std::size_t v = alphabet.find(c);
    if (v == std::string_view::npos || out.size() >= max_bytes) break;
    buffer = (buffer << 6) | static_cast<unsigned>(v);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out.push_back(static_cast<char>((buffer >> bits) & 0xFF));
    }
  }
}

// zlib-compressed VTK arrays start with a header (block count, block size, last block size,
// compressed sizes). VTK allocates from it before checking it, so a damaged header could request
// gigabytes: every header must describe at most ~1100x the file's size (zlib expands <= 1032x).
void check_compression_headers(std::string_view bytes, const std::string& file) {
  const std::string_view head = bytes.substr(0, 4096);
  if (head.find("compressor=\"") == std::string_view::npos) return;
  const bool wide = head.find("header_type=\"UInt64\"") != std::string_view::npos;
  const std::size_t word = wide ? 8 : 4;
  const auto check_header = [&](const std::string& raw) {
    if (raw.size() < 2 * word) return;  // too short: VTK reports it
    std::uint64_t blocks = 0, block_size = 0;
    std::memcpy(&blocks, raw.data(), word);
    std::memcpy(&block_size, raw.data() + word, word);
    const double expanded = static_cast<double>(blocks) * static_cast<double>(block_size);
    if (blocks > bytes.size() || expanded > 1100.0 * static_cast<double>(bytes.size()) + 65536.0) {
      throw_bad_input("a compressed data array declares " + std::to_string(blocks) +
                          " blocks of " + std::to_string(block_size) + " bytes, more than a " +
                          std::to_string(bytes.size()) + "-byte file can hold",
                      {.file = file, .suggestion = "the file is corrupt; re-export it"});
    }
  };
  const std::size_t appended = bytes.find("<AppendedData");
  const std::size_t marker = appended == std::string_view::npos ? appended
                                                                : bytes.find('_', appended);
  const bool appended_base64 =
      appended != std::string_view::npos &&
      bytes.substr(appended, 64).find("encoding=\"base64\"") != std::string_view::npos;
  const std::size_t header_bytes = 3 * word;
  for (std::size_t at = bytes.find("<DataArray"); at != std::string_view::npos &&
                                                  (appended == std::string_view::npos || at < appended);
       at = bytes.find("<DataArray", at + 1)) {
    const std::size_t close = bytes.find('>', at);
    if (close == std::string_view::npos) return;
    const std::string_view tag = bytes.substr(at, close - at);
    std::string raw;
    if (tag.find("format=\"binary\"") != std::string_view::npos) {
      std::size_t p = close + 1;
      while (p < bytes.size() && std::isspace(static_cast<unsigned char>(bytes[p]))) ++p;
      decode_base64(bytes.substr(p, 64), header_bytes, raw);
    } else if (tag.find("format=\"appended\"") != std::string_view::npos &&
               marker != std::string_view::npos) {
      const std::size_t o = tag.find("offset=\"");
      unsigned long long offset = 0;
      if (o == std::string_view::npos) continue;
      std::from_chars(tag.data() + o + 8, tag.data() + tag.size(), offset);
      if (offset >= bytes.size() - marker - 1) continue;  // VTK reports the bad offset
      const std::string_view data = bytes.substr(marker + 1 + offset);
      if (appended_base64) decode_base64(data.substr(0, 64), header_bytes, raw);
      else raw = std::string(data.substr(0, header_bytes));
    }
    check_header(raw);
  }
}

}  // namespace

TriMesh read_vtp(std::string_view bytes, const std::string& file) {
  // VTK's CanReadFile needs a file; the same test on the bytes: an XML VTKFile of type PolyData
  const std::string_view head = bytes.substr(0, 4096);
  const std::size_t root = head.find("<VTKFile");
  if (root == std::string_view::npos ||
      head.find("type=\"PolyData\"", root) == std::string_view::npos) {
    throw_bad_input("not a VTK XML PolyData file",
                    {.file = file, .suggestion = "check that it is a .vtp written by VTK, "
                                                 "ParaView or OpenSim"});
  }
  // a damaged count must not make VTK allocate gigabytes: zlib expands at most ~1032:1
  for (const char* what : {"NumberOfPoints=\"", "NumberOfPolys=\"", "NumberOfStrips=\"",
                           "NumberOfVerts=\"", "NumberOfLines=\""}) {
    for (std::size_t at = head.find(what); at != std::string_view::npos;
         at = head.find(what, at + 1)) {
      const std::size_t p = at + std::char_traits<char>::length(what);
      unsigned long long n = 0;
      std::from_chars(head.data() + p, head.data() + head.size(), n);
      if (n > 1100ull * bytes.size()) {
        throw_bad_input(std::string(what).substr(0, std::string(what).size() - 2) + " = " +
                            std::to_string(n) + " cannot fit in a file of " +
                            std::to_string(bytes.size()) + " bytes",
                        {.file = file, .suggestion = "the file is corrupt; re-export it"});
      }
    }
  }
  check_compression_headers(bytes, file);
  vtkNew<vtkXMLPolyDataReader> reader;
  VtkMessages messages;
  messages.observe(reader);
  reader->ReadFromInputStringOn();
  reader->SetInputString(std::string(bytes));
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
