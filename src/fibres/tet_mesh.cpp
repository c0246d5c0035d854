// Tetrahedralisation with TetGen (Si 2015), boundary-preserving.
#include "fascicle/fibres/tet_mesh.hpp"

#include "fascicle/core/error.hpp"

#include <tetgen.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <vector>

namespace fascicle {

namespace {

double calc_mean_edge(const TriMesh& m) {
  double sum = 0.0;
  for (Eigen::Index f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) sum += (m.V.row(m.F(f, k)) - m.V.row(m.F(f, (k + 1) % 3))).norm();
  return sum / (3.0 * std::max<Eigen::Index>(1, m.num_faces()));
}

// Face adjacency: the tet across the face opposite each corner.
Tetrahedra calc_neighbours(const Tetrahedra& T) {
  struct FaceRef {
    std::array<int, 3> key;
    int tet;
    int corner;
  };
  std::vector<FaceRef> faces;
  faces.reserve(4 * T.rows());
  for (Eigen::Index t = 0; t < T.rows(); ++t)
    for (int c = 0; c < 4; ++c) {
      std::array<int, 3> k{T(t, (c + 1) % 4), T(t, (c + 2) % 4), T(t, (c + 3) % 4)};
      std::sort(k.begin(), k.end());
      faces.push_back({k, static_cast<int>(t), c});
    }
  std::sort(faces.begin(), faces.end(), [](const FaceRef& a, const FaceRef& b) {
    return a.key != b.key ? a.key < b.key : a.tet < b.tet;
  });
  Tetrahedra N = Tetrahedra::Constant(T.rows(), 4, -1);
  for (std::size_t i = 0; i + 1 < faces.size(); ++i)
    if (faces[i].key == faces[i + 1].key) {
      N(faces[i].tet, faces[i].corner) = faces[i + 1].tet;
      N(faces[i + 1].tet, faces[i + 1].corner) = faces[i].tet;
      ++i;
    }
  return N;
}

}  // namespace

TetMesh calc_tet_mesh(const TriMesh& surface, const TetOptions& options) {
  if (surface.num_faces() < 4 || surface.num_vertices() < 4)
    throw_bad_input("the surface has too few triangles to enclose a volume");
  tetgenio in, out;
  in.firstnumber = 0;
  in.numberofpoints = static_cast<int>(surface.num_vertices());
  in.pointlist = new REAL[3 * in.numberofpoints];
  for (int v = 0; v < in.numberofpoints; ++v)
    for (int d = 0; d < 3; ++d) in.pointlist[3 * v + d] = surface.V(v, d);
  in.numberoffacets = static_cast<int>(surface.num_faces());
  in.facetlist = new tetgenio::facet[in.numberoffacets];
  for (int f = 0; f < in.numberoffacets; ++f) {
    tetgenio::facet& fa = in.facetlist[f];
    tetgenio::init(&fa);
    fa.numberofpolygons = 1;
    fa.polygonlist = new tetgenio::polygon[1];
    tetgenio::init(&fa.polygonlist[0]);
    fa.polygonlist[0].numberofvertices = 3;
    fa.polygonlist[0].vertexlist = new int[3];
    for (int k = 0; k < 3; ++k) fa.polygonlist[0].vertexlist[k] = surface.F(f, k);
  }
  const double edge = calc_mean_edge(surface);
  const double max_volume =
      options.max_volume > 0.0 ? options.max_volume : options.volume_scale * edge * edge * edge;
  // Work in a scaled frame (unit mean edge) so TetGen's tolerances see well-sized numbers.
  const double scale = 1.0 / edge;
  for (int i = 0; i < 3 * in.numberofpoints; ++i) in.pointlist[i] *= scale;
  std::string switches = "pzQY";
  if (options.max_radius_edge_ratio > 0.0) switches += "q" + std::to_string(options.max_radius_edge_ratio);
  switches += "a" + std::to_string(max_volume * scale * scale * scale);
  try {
    tetrahedralize(switches.data(), &in, &out);
  } catch (int code) {
    throw_bad_input("TetGen could not tetrahedralise the muscle surface (TetGen error " +
                        std::to_string(code) +
                        (code == 3 ? ": the surface self-intersects" : "") + ")",
                    {.suggestion = "repair the mesh (closed, manifold, no self-intersections) "
                                   "before the fibre decomposition"});
  }
  if (out.numberoftetrahedra <= 0 || out.numberofpoints < surface.num_vertices())
    throw_bad_input("TetGen produced no tetrahedra for the muscle surface",
                    {.suggestion = "check the surface is closed and encloses a volume"});
  TetMesh mesh;
  mesh.V.resize(out.numberofpoints, 3);
  for (int v = 0; v < out.numberofpoints; ++v)
    for (int d = 0; d < 3; ++d) mesh.V(v, d) = out.pointlist[3 * v + d] / scale;
  // -Y keeps the input points first and unmoved: restore them bit-exactly.
  mesh.V.topRows(surface.num_vertices()) = surface.V;
  mesh.T.resize(out.numberoftetrahedra, 4);
  for (int t = 0; t < out.numberoftetrahedra; ++t) {
    for (int k = 0; k < 4; ++k) mesh.T(t, k) = out.tetrahedronlist[out.numberofcorners * t + k];
    const Vec3 a = mesh.V.row(mesh.T(t, 0));
    const double det = (Vec3(mesh.V.row(mesh.T(t, 1))) - a)
                           .cross(Vec3(mesh.V.row(mesh.T(t, 2))) - a)
                           .dot(Vec3(mesh.V.row(mesh.T(t, 3))) - a);
    if (det < 0.0) std::swap(mesh.T(t, 2), mesh.T(t, 3));
  }
  mesh.neighbours = calc_neighbours(mesh.T);
  return mesh;
}

double calc_tet_volume(const TetMesh& mesh) {
  double vol = 0.0;
  for (Eigen::Index t = 0; t < mesh.num_tets(); ++t) {
    const Vec3 a = mesh.V.row(mesh.T(t, 0));
    vol += (Vec3(mesh.V.row(mesh.T(t, 1))) - a)
               .cross(Vec3(mesh.V.row(mesh.T(t, 2))) - a)
               .dot(Vec3(mesh.V.row(mesh.T(t, 3))) - a) /
           6.0;
  }
  return vol;
}

}  // namespace fascicle
