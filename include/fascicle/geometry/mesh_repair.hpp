// Safe, conservative repairs of triangle meshes, and the gate later modules use to require a solid.
// Only repairs that cannot change the shape are made; everything else is an error that says what
// is wrong and what to do (see docs/geometry.md).
#pragma once

#include "fascicle/geometry/mesh_validation.hpp"
#include "fascicle/geometry/tri_mesh.hpp"

#include <string>
#include <vector>

namespace fascicle {

struct RepairOptions {
  // Vertices closer than this (metres) are merged; 0 merges only identical positions.
  double merge_tolerance = 0.0;
};

struct RepairResult {
  TriMesh mesh;
  std::vector<std::string> actions;  // what was done, one line each (empty: nothing to do)
  MeshReport report;                 // validation of the repaired mesh
};

// In order: merge duplicate vertices (within the tolerance; the first vertex of a cluster stays),
// drop degenerate faces (repeated index or zero area), drop unreferenced vertices, orient every
// connected component consistently (breadth-first over manifold edges) and then outward (flip a
// component whose signed volume is negative). Throws fascicle::Error (bad_input) naming the
// counts when the mesh cannot be repaired safely: NaN/Inf coordinates, out-of-range indices,
// boundary edges (holes), non-manifold edges, non-orientable components, self-intersections, or
// nothing left.
RepairResult repair_mesh(const TriMesh& mesh, const RepairOptions& options = {});

// Throws fascicle::Error (bad_input, object = name) unless the mesh is a solid: finite, all
// indices in range, no degenerate faces, closed, manifold, consistently and outward oriented and
// (when check_self_intersections) free of self-intersections. The message lists the problems and
// suggests `fascicle mesh repair`.
void require_closed_manifold(const TriMesh& mesh, const std::string& name,
                             bool check_self_intersections = true);

}  // namespace fascicle
