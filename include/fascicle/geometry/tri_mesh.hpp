// TriMesh: a triangle surface mesh as plain arrays (libigl layout). Positions are in metres;
// triangles are counter-clockwise seen from outside (outward normals) for closed meshes.
#pragma once

#include "fascicle/core/types.hpp"

namespace fascicle {

struct TriMesh {
  Points3 V;    // #V x 3 vertex positions
  Triangles F;  // #F x 3 vertex indices (0-based)

  Eigen::Index num_vertices() const { return V.rows(); }
  Eigen::Index num_faces() const { return F.rows(); }
};

}  // namespace fascicle
