// Packing of generated muscle bellies at the rest pose: each belly's sections become star-shaped
// (radius varying with angle) so that no belly vertex lies inside another belly or a bone, while
// every belly keeps its exact volume and its fibres stay inside. Shape rule: docs/opensim-volumes.md.
#pragma once

#include "fascicle/core/types.hpp"
#include "fascicle/deformation/framed_line.hpp"
#include "fascicle/geometry/tri_mesh.hpp"

#include <string>
#include <vector>

namespace fascicle {

// A generated belly in its own parametrisation: vertex v = centres.row(v) + scale(v) · offsets.row(v),
// where offsets are the unit-radius profile offsets (|offset| = √sin(πu) of the vertex's ring,
// perpendicular to the centreline in the ring's rotation-minimising frame; zero at the two tips).
// The unpacked belly has scale(v) = R for every vertex (R fitted to the volume).
struct BellyShape {
  std::string name;
  FramedLine line;   // rings + 2 samples: sample k is ring k (0 and rings + 1 are the tips)
  int rings = 0;
  int segments = 0;
  Points3 centres;   // #V x 3: the ring's path point (tips: the tip), plus the ring's packing shift
  Points3 offsets;   // #V x 3
  VecX scale;        // #V, metres per unit offset
  Triangles F;       // outward
  double volume_m3 = 0.0;
  double R = 0.0;    // the fitted radius of the unpacked belly
  double pennation_rad = 0.0;
  int fibres = 30;

  Points3 calc_vertices() const;  // centres + scale ∘ offsets
  Vec3 calc_vertex(Eigen::Index v) const;
};

// The circular belly (the shape rule's steps 2–4): offsets from the centreline and R fitted by Newton
// so the mesh encloses volume_m3 to 1e-9 relative. Throws fascicle::Error as make_fusiform_belly.
BellyShape make_belly_shape(const Points3& centreline, double volume_m3, int rings, int segments, int fibres,
                            double pennation_rad);

// Fibres of a belly whose sections may be star-shaped: the fusiform rules of make_fusiform_belly
// (parallel for α ≤ 5°, multipennate above) with the section radius taken, in each fibre's direction
// φ, from the polygonal section itself (the ray from the centre at angle φ meets the edge between the
// two vertices around φ), linear in arc length between rings. Fibre points then lie at fraction ρ
// ≤ 0.9 (parallel) or at most 0.95 (pennate ends) of the local section radius.
std::vector<Points3> calc_belly_fibres(const BellyShape& shape);

struct BellyPackingOptions {
  bool enabled = true;
  double tolerance_m = 1.0e-4;       // deepest allowed vertex depth inside another belly or a bone
  double margin_m = 5.0e-5;          // pushed vertices end this far beyond the contact
  int max_iterations = 100;
  double min_scale_fraction = 0.15;  // a vertex is never pulled below this fraction of R
  double max_growth = 2.0;           // no vertex grows beyond this multiple of R (no spikes)
  int hold_iterations = 8;           // a pushed vertex is held (not regrown) for this many iterations
  bool shift_rings = true;           // sections may also move off the path (in their plane)
  double max_shift_fraction = 1.0;   // ... by at most this fraction of R
  double max_shift_slope = 0.5;      // ... changing by at most this much per unit length along the belly
  // Cap each section vertex's radius so that it stays behind the next ring's plane and ahead of the
  // previous ring's (neighbouring sections cannot cross in a bend). Off by default; pack_bellies
  // turns it on when it re-packs a belly that the first packing made self-intersect.
  bool keep_sections_apart = false;
};

// An obstacle at the rest pose, in the bellies' frame (ground).
struct PackingObstacle {
  std::string name;
  TriMesh mesh;  // closed, outward
};

struct PackingContact {
  std::string a, b;      // belly names (b: a belly or a bone)
  double depth_m = 0.0;  // deepest vertex of a inside b (closest-point distance)
};

// A belly whose surface, clean (no self-intersecting faces) before packing, had crossing faces after
// it: re-packed alone against its fixed neighbours with gentler settings, else kept unpacked.
struct PackingFold {
  std::string name;
  int crossing_pairs = 0;        // self-intersecting face pairs after the first packing
  std::string remedy;            // the re-packing settings that cleared it (empty: none did)
  bool kept_unpacked = false;    // no re-packing cleared it: the belly keeps its unpacked shape
  double overlap_m = 0.0;        // its deepest remaining overlap (either way) with any other solid
};

struct PackingReport {
  int iterations = 0;
  bool converged = true;
  std::vector<PackingContact> before;  // per ordered pair, deepest vertex depth at the start, > 0 only
  std::vector<PackingContact> after;   // the same after packing
  std::vector<double> max_radial_change_m;   // per belly: max |Δ radius| over its vertices
  std::vector<double> mean_radial_change_m;  // per belly: mean |Δ radius| over its vertices
  std::vector<bool> changed;                 // per belly: any vertex moved
  std::vector<PackingFold> folds;            // bellies packing made self-intersecting (see pack_bellies)
};

// Deepest vertex of every belly inside every other belly and every obstacle (pairs with depth > 0).
std::vector<PackingContact> calc_packing_contacts(const std::vector<BellyShape>& bellies,
                                                  const std::vector<PackingObstacle>& obstacles);

// Packs the bellies in place (their `scale` and `centres` change; volumes stay exact to 1e-9).
// Iterates (docs/opensim-volumes.md, step 6): a vertex inside another belly moves radially by half
// its radial depth and the face it is in by half the closest-point depth (the face all of it when
// the vertex is at its minimum radius); a vertex inside an obstacle takes all of it; pushed rings
// also shift off the path in their plane (smoothed, slope-limited, at most max_shift_fraction R);
// pushed vertices are held for hold_iterations; the others are scaled by one factor per belly (no
// vertex beyond max_growth R; Newton safeguarded by bisection) to restore the volume; free vertices
// bordering a contact are tapered (lowering only). Stops when the deepest overlap is <= tolerance or
// after max_iterations, then warns naming the pairs left, their depths and why (tip inside another
// solid, squeezed, in contact all round). Never throws for lack of space. Deterministic: Jacobi
// updates from one snapshot per iteration, the same result for any thread count.
// Afterwards every changed belly whose unpacked surface has no self-intersecting faces
// (calc_self_intersections) is checked again; one that now has some is packed again, alone, from
// its unpacked shape against the other bellies (fixed) and the obstacles, first with a quarter of
// the shift slope, then without ring shifts, then both again with keep_sections_apart; the first clean
// result is kept, else the belly keeps its unpacked shape and a warning names it, why and its
// remaining overlap. Such bellies are listed in PackingReport::folds.
PackingReport pack_bellies(std::vector<BellyShape>& bellies, const std::vector<PackingObstacle>& obstacles,
                           const BellyPackingOptions& options = {});

}  // namespace fascicle
