// Edge topology shared by mesh validation and repair (not a public header).
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"

#include <array>
#include <vector>

namespace fascicle::mesh_detail {

// Faces that take part in the topology: all three indices in range and distinct.
std::vector<char> find_topological_faces(const TriMesh& mesh);

// One use of an undirected edge (a < b) by a face; `forward` when the face runs a -> b.
struct EdgeUse {
  int a, b, face;
  bool forward;
};
// All edge uses of the selected faces, sorted by (a, b, face): uses of one edge are adjacent.
std::vector<EdgeUse> collect_edge_uses(const TriMesh& mesh, const std::vector<char>& use);

// Component label per face (-1 for unselected faces), connected through shared vertices;
// labels are 0..count-1 in order of their smallest face.
std::vector<int> label_face_components(const TriMesh& mesh, const std::vector<char>& use,
                                       int& count);

// Signed volume (m^3) of the selected faces about the centre of their bounding box.
double calc_signed_volume(const TriMesh& mesh, const std::vector<char>& use);

// Zero area: finite corners with |cross| <= 16 eps * (longest edge)^2 (collinear/coincident).
bool has_zero_area(const Vec3& a, const Vec3& b, const Vec3& c);

}  // namespace fascicle::mesh_detail
