// JSON reading/writing of B-spline solids and VTK export.
#include "fascicle/bspline/solid_io.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/core/units.hpp"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <vtkCellArray.h>
#include <vtkDoubleArray.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkUnstructuredGrid.h>
#include <vtkXMLPolyDataWriter.h>
#include <vtkXMLUnstructuredGridWriter.h>
#include <vtkCellType.h>

#include <fstream>
#include <sstream>

namespace fascicle {

namespace {

using nlohmann::json;

[[noreturn]] void fail(const std::string& source, const std::string& path, const std::string& msg) {
  throw_bad_input(msg, ErrorContext{.file = source, .json_path = path,
                                    .suggestion = "see docs/bspline-solids.md for the format"});
}

const json& require(const json& j, const char* key, const std::string& source,
                    const std::string& path) {
  if (!j.is_object() || !j.contains(key)) fail(source, path, fmt::format("missing \"{}\"", key));
  return j.at(key);
}

}  // namespace

BSplineSolid parse_solid(const std::string& text, const std::string& source) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::parse_error& e) {
    fail(source, "", fmt::format("not valid JSON: {}", e.what()));
  }
  try {
    if (j.value("format", std::string()) != "fascicle.bspline_solid") {
      fail(source, "/format", "\"format\" must be \"fascicle.bspline_solid\"");
    }
    const double scale = metres_per(parse_length_unit(j.value("units", std::string("m"))));
    BSplineSolid s;
    s.name = j.value("name", std::string());
    const std::string fd = j.value("fibre_direction", std::string("w"));
    if (fd == "u") s.fibre_direction = FibreDirection::u;
    else if (fd == "v") s.fibre_direction = FibreDirection::v;
    else if (fd == "w") s.fibre_direction = FibreDirection::w;
    else fail(source, "/fibre_direction", "fibre_direction must be \"u\", \"v\" or \"w\"");
    const json& bases = require(j, "bases", source, "");
    if (!bases.is_array() || bases.size() != 3) fail(source, "/bases", "needs three bases (u, v, w)");
    for (int d = 0; d < 3; ++d) {
      const std::string path = fmt::format("/bases/{}", d);
      const json& b = bases[d];
      BSplineBasis basis;
      basis.degree = require(b, "degree", source, path).get<int>();
      basis.num_control = require(b, "control_points", source, path).get<int>();
      basis.periodic = b.value("periodic", false);
      basis.knots = require(b, "knots", source, path).get<std::vector<double>>();
      try {
        validate_basis(basis, "knot vector");
      } catch (const Error& e) {
        fail(source, path, e.message());
      }
      s.basis[d] = std::move(basis);
    }
    const json& cp = require(j, "control_points", source, "");
    if (!cp.is_array()) fail(source, "/control_points", "must be an array of [x, y, z]");
    s.P.resize(static_cast<Eigen::Index>(cp.size()), 3);
    for (std::size_t r = 0; r < cp.size(); ++r) {
      if (!cp[r].is_array() || cp[r].size() != 3) {
        fail(source, fmt::format("/control_points/{}", r), "a control point is [x, y, z]");
      }
      for (int c = 0; c < 3; ++c) {
        // JSON has no NaN: null stands for a missing value
        s.P(r, c) = cp[r][c].is_number() ? cp[r][c].get<double>() * scale
                                         : std::numeric_limits<double>::quiet_NaN();
      }
    }
    try {
      validate_solid(s);
    } catch (const Error& e) {
      fail(source, "/control_points", e.message());
    }
    return s;
  } catch (const json::exception& e) {
    fail(source, "", fmt::format("wrong JSON type: {}", e.what()));
  }
}

BSplineSolid read_solid(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) {
    throw_bad_input("cannot open the B-spline solid file",
                    ErrorContext{.file = path.string(), .suggestion = "check the path"});
  }
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_solid(ss.str(), path.string());
}

std::string format_solid(const BSplineSolid& s) {
  json j;
  j["format"] = "fascicle.bspline_solid";
  j["version"] = 1;
  j["name"] = s.name;
  j["units"] = "m";
  j["fibre_direction"] = std::string(1, "uvw"[static_cast<int>(s.fibre_direction)]);
  j["bases"] = json::array();
  for (int d = 0; d < 3; ++d) {
    j["bases"].push_back({{"degree", s.basis[d].degree},
                          {"periodic", s.basis[d].periodic},
                          {"control_points", s.basis[d].num_control},
                          {"knots", s.basis[d].knots}});
  }
  json cp = json::array();
  for (Eigen::Index r = 0; r < s.P.rows(); ++r) cp.push_back({s.P(r, 0), s.P(r, 1), s.P(r, 2)});
  j["control_points"] = cp;
  return j.dump(1);
}

void write_solid(const std::filesystem::path& path, const BSplineSolid& s) {
  validate_solid(s);
  const std::string text = format_solid(s);
  write_file_atomically(path, [&](std::ostream& out) { out << text << '\n'; });
}

void write_polylines_vtp(const std::filesystem::path& path, const std::vector<Points3>& lines) {
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  vtkNew<vtkCellArray> cells;
  for (const Points3& l : lines) {
    if (l.rows() < 2) continue;
    cells->InsertNextCell(static_cast<vtkIdType>(l.rows()));
    for (Eigen::Index r = 0; r < l.rows(); ++r) {
      cells->InsertCellPoint(points->InsertNextPoint(l(r, 0), l(r, 1), l(r, 2)));
    }
  }
  vtkNew<vtkPolyData> poly;
  poly->SetPoints(points);
  poly->SetLines(cells);
  write_via_temporary(path, [&](const std::filesystem::path& tmp) {
    vtkNew<vtkXMLPolyDataWriter> w;
    w->SetFileName(tmp.string().c_str());
    w->SetInputData(poly);
    w->SetDataModeToBinary();
    if (w->Write() != 1) throw_bad_input("VTK could not write the file", ErrorContext{.file = path.string()});
  });
}

void write_hexahedra_vtu(const std::filesystem::path& path, const Points3& V,
                         const Eigen::Matrix<int, Eigen::Dynamic, 8>& hexes,
                         const Points3* node_vectors, const std::string& vector_name) {
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  for (Eigen::Index r = 0; r < V.rows(); ++r) points->InsertNextPoint(V(r, 0), V(r, 1), V(r, 2));
  vtkNew<vtkUnstructuredGrid> grid;
  grid->SetPoints(points);
  grid->Allocate(hexes.rows());
  for (Eigen::Index h = 0; h < hexes.rows(); ++h) {
    vtkIdType ids[8];
    for (int c = 0; c < 8; ++c) ids[c] = hexes(h, c);
    grid->InsertNextCell(VTK_HEXAHEDRON, 8, ids);
  }
  if (node_vectors) {
    vtkNew<vtkDoubleArray> a;
    a->SetName(vector_name.c_str());
    a->SetNumberOfComponents(3);
    for (Eigen::Index r = 0; r < node_vectors->rows(); ++r) {
      a->InsertNextTuple3((*node_vectors)(r, 0), (*node_vectors)(r, 1), (*node_vectors)(r, 2));
    }
    grid->GetPointData()->SetVectors(a);
  }
  write_via_temporary(path, [&](const std::filesystem::path& tmp) {
    vtkNew<vtkXMLUnstructuredGridWriter> w;
    w->SetFileName(tmp.string().c_str());
    w->SetInputData(grid);
    w->SetDataModeToBinary();
    if (w->Write() != 1) throw_bad_input("VTK could not write the file", ErrorContext{.file = path.string()});
  });
}

}  // namespace fascicle
