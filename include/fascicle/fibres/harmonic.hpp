// Harmonic fibre fields (Choi & Blemker 2013, PLoS ONE 8(10):e77576; Modenese & Kohout 2020,
// Ann Biomed Eng 48:1793-1804): the potential u solving Laplace's equation in the muscle volume,
// u = 0 on the origin area, u = 1 on the insertion area, zero flux elsewhere; fibres are the
// streamlines of grad u, from the origin area to the insertion area.
#pragma once

#include "fascicle/fibres/attachment.hpp"
#include "fascicle/fibres/fibre_set.hpp"
#include "fascicle/fibres/tet_mesh.hpp"

#include <Eigen/SparseCore>

#include <string_view>
#include <vector>

namespace fascicle {

// Linear-FEM (cotangent) stiffness of a tet mesh, #V x #V, symmetric positive semi-definite,
// rows summing to 0: K_ij = sum over tets of vol * grad(phi_i) . grad(phi_j).
Eigen::SparseMatrix<double> calc_stiffness_matrix(const TetMesh& mesh);

// Solves K u = 0 with u = 0 on `zero_vertices` and u = 1 on `one_vertices` by sparse Cholesky
// (CHOLMOD) on the free vertices. Throws bad_input when a set is empty or the sets share a vertex
// (the messages name the sets by `zero_name` / `one_name`) and numerical when the factorisation
// fails (a part of the mesh without any Dirichlet vertex).
VecX solve_laplace(const TetMesh& mesh, const std::vector<int>& zero_vertices,
                   const std::vector<int>& one_vertices,
                   std::string_view zero_name = "the origin area",
                   std::string_view one_name = "the insertion area");

// A solved field, immutable, reusable for any number of fibre tracings.
struct HarmonicField {
  TriMesh surface;         // the muscle surface (its vertices are the first tet vertices)
  TetMesh tets;
  VecX u;                  // #V potential
  Points3 vertex_gradient;  // #V x 3 volume-weighted mean of the adjacent tets' gradients (1/m)
  Points3 tet_gradient;     // #T x 3 (1/m)
  // Pennate fields only (HarmonicOptions::pennation_rad > 0): the end-to-end potential, and
  // vertex_gradient / tet_gradient then hold the unit fibre directions instead of grad u.
  VecX u_along;
};

struct HarmonicOptions {
  TetOptions tets;
  // > 0: pennate field (docs/fibres.md, "Pennate harmonic field"): fibres run at this angle to the
  // end-to-end direction grad(u_along) (u_along: 0 / 1 on the end regions of `end_fraction`),
  // turned towards grad(u) of the aponeurosis areas (Laplace-Dirichlet rule-based directions,
  // Bayer et al. 2012). 0: fibres follow grad(u) (the plain harmonic method).
  double pennation_rad = 0.0;
  double end_fraction = 0.08;
  // What the pennation angle of the pennate field is measured against. line_of_action (default):
  // d = cos(a) e_l + sin(a) e_t with e_l the end-to-end direction grad(u_along) and e_t the part of
  // grad(u) normal to it. aponeurosis: the angle between the fibre and the local level set of u
  // (the surfaces parallel to the aponeuroses; ultrasound measures pennation against the
  // aponeurosis): d = cos(a) e_a + sin(a) e_n with e_n = grad(u) / |grad(u)| and e_a the part of
  // grad(u_along) normal to e_n.
  enum class PennationReference { line_of_action, aponeurosis };
  PennationReference pennation_reference = PennationReference::line_of_action;
  // > 0 (with pennation_rad > 0): the angle varies through the muscle as a planimetric model with
  // one fibre length L predicts, sin(a) = t / L, t the local distance the fibre crosses = 1 /
  // |grad| of the crossing potential (the faces' potential of unipennate aponeurosis areas, else
  // u: 0 on the faces, 1 on a central sheet); pennation_rad is then only the fallback where that
  // gradient vanishes. 0: one angle everywhere.
  double fibre_length_m = 0.0;
  // Nonzero (pennate fields): the plane in which the fibres turn away from the line of action.
  // The transverse direction (e_t of the line-of-action reference, e_n of the aponeurosis
  // reference) is this direction made normal to e_l (resp. e_a): as given when the areas carry
  // both faces (unipennate aponeurosis areas; give it towards the insertion face), else signed
  // the way grad(u) points (towards a central sheet from either side). Typically the muscle's
  // thickness direction (find_aponeurosis_attachments' box x, Attachments::thickness_direction):
  // the DTI tracts of the medial gastrocnemius and tibialis anterior turn within that plane,
  // while grad(u) also turns sideways near the areas' edges (docs/fibres.md, "Session 9").
  // With PennationReference::aponeurosis and both faces known, e_n is then this fixed direction,
  // not the faces' level sets (the angle is measured against the box's plane); the CLI keeps the
  // gradient there unless asked. Zero: grad(u) (or the faces' potential), as before.
  Vec3 transverse_direction = Vec3::Zero();
  // Non-empty (pennate fields; metres, #N x 3): points the fibres turn towards, e.g. the tendon-side
  // border of an interior aponeurosis (find_aponeurosis_border). The transverse direction at a point
  // is then the direction to the nearest of these points, made normal to e_l; it replaces
  // transverse_direction. With PennationReference::aponeurosis that direction is used as e_n itself
  // (Bolsterlee TA 18.1 deg from the tracts, against 12.8: the CLI refuses the combination). For the tibialis anterior the DTI tracts approach the central
  // aponeurosis and drift towards the side where it becomes the tendon, about equally
  // (docs/fibres.md, "Session 10").
  Points3 transverse_targets = Points3(0, 3);
};

// Tetrahedralises `muscle` and solves the field for the given attachment areas. An interior
// insertion aponeurosis (areas.insertion_interior) adds the tet vertices within 0.6 mean tet
// edges of its points to the u = 1 set.
HarmonicField calc_harmonic_field(const TriMesh& muscle, const Attachments& areas,
                                  const HarmonicOptions& options = {});

struct TraceOptions {
  int count = 100;        // fibres
  int resolution = 15;    // points per fibre
  double step_scale = 0.5;  // RK4 step as a fraction of the mean tet edge length
  // A fibre ends where u reaches this value (1 - 1e-9: on the insertion area; with an interior
  // aponeurosis, streamlines approach its vertex layer and a value such as 0.99 ends them there).
  double stop_potential = 1.0 - 1e-9;
  // true: a fibre ends where it first reaches the surface with u >= 1/2 (pennate fields: it has
  // crossed to the insertion side); false: away from the insertion area it slides along the
  // surface.
  bool end_on_boundary = false;
  // Where fibres start. origin_area: on the origin area (area-weighted, stratified), traced to the
  // insertion. level_set: on the level set u = seed_level inside the muscle (stratified by area, or
  // by flux |grad u| dA with seed_by_flux), each traced backwards to the origin area and forwards
  // to the insertion area, so the fibres follow the volume rather than the origin area's flux.
  // level_set needs grad u (plain fields; pennate fields hold directions).
  // volume: seeds spread over the muscle volume (volume-weighted, stratified), traced both ways.
  enum class Seeding { origin_area, level_set, volume };
  Seeding seeding = Seeding::origin_area;
  double seed_level = 0.5;
  bool seed_by_flux = false;
  // volume seeding with the insertion area given: this share of the fibres starts on the areas
  // instead (half on each, stratified by area), traced into the muscle to the other area.
  double area_seed_fraction = 0.0;
  // volume seeding: > 1 traces this many times `count` seeds and keeps `count` fibres chosen by
  // farthest-point order of their shapes (five points along each fibre, origin end to insertion
  // end; fibres with both ends on their areas first; area_seed_fraction is then not used).
  // 1: the seeds themselves.
  int candidate_factor = 1;
  // With candidate_factor > 1 and the insertion area given: this many times `count` seeds on
  // each area's surface (stratified by area), traced to the other area, join the candidates (so
  // the ends can reach the parts of the areas the flux hardly feeds, e.g. thin tips).
  int area_candidate_factor = 0;
};

// Traces `count` fibres: seeds spread over the origin area's triangles (area-weighted R2
// sequence), streamlines of the interpolated gradient by RK4 with tet walking until u reaches 1 or
// the boundary, resampled to `resolution` points. Every point lies in the tet mesh (inside the
// surface). Fibres are traced in parallel; results are deterministic.
// `insertion` is needed only for TraceOptions::area_seed_fraction > 0.
FibreSet trace_harmonic_fibres(const HarmonicField& field, const AttachmentArea& origin,
                               const TraceOptions& options = {},
                               const AttachmentArea* insertion = nullptr);

}  // namespace fascicle
