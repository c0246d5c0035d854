// Validation of triangle meshes: what a solid (closed, manifold, outward, non-self-intersecting)
// surface needs, reported without ever indexing out of range. Topology follows libigl/CGAL usage:
// an undirected edge used by one triangle is a boundary edge, by more than two a non-manifold edge;
// an edge of two triangles is consistently oriented when they traverse it in opposite directions.
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"

#include <nlohmann/json_fwd.hpp>

#include <array>
#include <string>
#include <vector>

namespace fascicle {

using EdgeList = std::vector<std::array<int, 2>>;  // vertex pairs, smaller index first
using FacePairs = std::vector<std::array<int, 2>>;  // face pairs, smaller index first

enum class SurfaceOrientation { outward, inward, undefined };
std::string to_string(SurfaceOrientation orientation);

struct MeshReport {
  long num_vertices = 0;
  long num_faces = 0;
  long num_edges = 0;                     // undirected edges of the valid faces
  long num_unreferenced_vertices = 0;     // vertices no valid face uses
  std::vector<int> nonfinite_vertices;    // rows of V holding NaN or Inf
  std::vector<int> out_of_range_faces;    // faces with an index outside [0, #V)
  std::vector<int> degenerate_faces;      // a repeated index, or zero area (collinear corners)
  EdgeList boundary_edges;                // used by one face
  EdgeList nonmanifold_edges;             // used by three or more faces
  EdgeList inconsistent_edges;            // two faces traversing the edge the same way
  int num_components = 0;                 // of the valid faces, connected through shared vertices
  long euler_characteristic = 0;          // V - E + F over the valid faces and their vertices
  double signed_volume = 0.0;             // m^3, divergence theorem; > 0 for outward normals
  SurfaceOrientation orientation = SurfaceOrientation::undefined;  // only when closed + oriented
  bool self_intersections_checked = false;
  FacePairs self_intersections;           // intersecting face pairs that share no vertex

  // Closed: every edge has exactly two faces; manifold: no edge has more; valid: no NaN,
  // out-of-range or degenerate faces.
  bool is_closed() const;
  bool is_manifold() const;
  bool is_consistently_oriented() const;
  // A usable solid: valid, closed, manifold, consistently and outward oriented, no (checked)
  // self-intersections.
  bool is_solid() const;
  // One line per problem found (empty for a clean solid).
  std::vector<std::string> list_problems() const;
};

struct ValidationOptions {
  bool check_self_intersections = true;  // Embree collision of triangle boxes + exact-in-double test
};

// Validates a mesh (cost O(F log F) plus the self-intersection search). Never throws for bad data:
// everything is reported.
MeshReport validate_mesh(const TriMesh& mesh, const ValidationOptions& options = {});

// Pairs of faces that intersect and share no vertex index. Faces with out-of-range indices,
// non-finite or repeated corners are skipped. Candidate pairs come from Embree's rtcCollide on the
// faces' bounding boxes; each is decided by triangles_intersect. Sorted, deterministic.
FacePairs calc_self_intersections(const TriMesh& mesh);

// Whether two triangles (a0,a1,a2) and (b0,b1,b2) share at least one point (touching counts).
// Non-coplanar case: the intervals the triangles cut on the line of their planes' intersection
// (Moeller 1997, "A fast triangle-triangle intersection test"); coplanar case: 2D edge/containment
// tests in the plane. Signed distances within 1e-12 of the triangle size count as zero.
bool triangles_intersect(const Vec3& a0, const Vec3& a1, const Vec3& a2, const Vec3& b0,
                         const Vec3& b1, const Vec3& b2);

// The report as JSON: counts, flags, and the first `max_listed` items of each list.
nlohmann::json to_json(const MeshReport& report, std::size_t max_listed = 50);

// A human-readable multi-line summary.
std::string format_report(const MeshReport& report);

}  // namespace fascicle
