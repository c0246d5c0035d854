// Posed paths and bones as VTK PolyData for viewing.
#include <spdlog/spdlog.h>

#include <filesystem>
#include <system_error>

#include "fascicle/core/error.hpp"
#include "fascicle/io/mesh_io.hpp"
#include "fascicle/io/polydata.hpp"
#include "fascicle/osim/analyze.hpp"

namespace fascicle {

std::vector<std::filesystem::path> write_path_geometry(const std::filesystem::path& folder,
                                                       const OsimAnalysisModel& model,
                                                       const VecX& q, double arc_step_m) {
  namespace fs = std::filesystem;
  if (!(arc_step_m > 0)) throw_usage("the arc sampling step must be positive");
  OsimFrame frame(model);
  calc_frame(model, q, frame, false);
  // Paths.
  PolyData paths;
  std::vector<Vec3> points;
  const int np = static_cast<int>(model.paths.paths.size());
  MatX path_index(np, 1), length(np, 1);
  PathResult result;
  for (int p = 0; p < np; ++p) {
    try {
      calc_path_length(model, frame, p, result);
    } catch (const Error& e) {
      throw e.with_file(model.osim.file.string());
    }
    const Points3 line = calc_path_polyline(result, arc_step_m);
    std::vector<int> cell;
    for (Eigen::Index i = 0; i < line.rows(); ++i) {
      cell.push_back(static_cast<int>(points.size()));
      points.emplace_back(line.row(i).transpose());
    }
    paths.lines.push_back(std::move(cell));
    path_index(p, 0) = p;
    length(p, 0) = result.length_m;
  }
  paths.points.resize(static_cast<Eigen::Index>(points.size()), 3);
  for (std::size_t i = 0; i < points.size(); ++i) paths.points.row(i) = points[i].transpose();
  paths.cell_fields.push_back({"path", path_index});
  paths.cell_fields.push_back({"length_m", length});
  // Bones.
  PolyData bones;
  std::vector<double> body_of_triangle;
  std::vector<Vec3> bone_points;
  std::vector<Eigen::Vector3i> triangles;
  const Skeleton& sk = model.skeleton;
  for (int b = 0; b < sk.num_bodies(); ++b) {
    const Transform& X_ground_body = frame.skeleton.get_body_transform(b);
    for (const MeshReference& ref : sk.get_body(b).meshes) {
      if (!fs::path(ref.file).is_absolute() || !fs::exists(ref.file)) continue;  // warned at import
      TriMesh mesh;
      try {
        mesh = read_mesh(ref.file);
      } catch (const Error& e) {
        spdlog::warn("bone mesh skipped: {}", e.what());
        continue;
      }
      const int offset = static_cast<int>(bone_points.size());
      const Transform X = X_ground_body * ref.X_body_mesh;
      for (Eigen::Index i = 0; i < mesh.V.rows(); ++i)
        bone_points.push_back(X * Vec3(mesh.V.row(i).transpose().cwiseProduct(ref.scale)));
      for (Eigen::Index i = 0; i < mesh.F.rows(); ++i) {
        triangles.emplace_back(mesh.F.row(i).transpose().array() + offset);
        body_of_triangle.push_back(b);
      }
    }
  }
  bones.points.resize(static_cast<Eigen::Index>(bone_points.size()), 3);
  for (std::size_t i = 0; i < bone_points.size(); ++i) bones.points.row(i) = bone_points[i].transpose();
  bones.triangles.resize(static_cast<Eigen::Index>(triangles.size()), 3);
  for (std::size_t i = 0; i < triangles.size(); ++i) bones.triangles.row(i) = triangles[i].transpose();
  bones.cell_fields.push_back(
      {"body", Eigen::Map<const VecX>(body_of_triangle.data(),
                                      static_cast<Eigen::Index>(body_of_triangle.size()))});
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (ec || !fs::is_directory(folder))
    throw_bad_input("cannot create the output folder: " + ec.message(),
                    {.file = folder.string(), .suggestion = "choose a writable --out folder"});
  const std::string stem = model.osim.name.empty() ? model.osim.file.stem().string() : model.osim.name;
  const fs::path paths_file = folder / (stem + "_paths.vtp");
  const fs::path bones_file = folder / (stem + "_bones.vtp");
  write_polydata(paths_file, paths);
  write_polydata(bones_file, bones);
  return {paths_file, bones_file};
}

}  // namespace fascicle
