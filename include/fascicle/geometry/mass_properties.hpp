// Mass properties of a closed, consistently oriented triangle surface by surface integrals:
// the divergence theorem turns the volume integrals of 1, x, y, z, x^2, y^2, z^2, xy, yz, zx into
// sums over the triangles (D. Eberly, "Polyhedral Mass Properties (Revisited)", Geometric Tools,
// 2002; same result as B. Mirtich, "Fast and accurate computation of polyhedral mass properties",
// J. Graphics Tools 1(2), 1996). Seed 000 §5.1 uses these for bone inertia from surface meshes.
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"

namespace fascicle {

struct MassProperties {
  double volume_m3 = 0.0;         // signed: negative when the normals point inward
  double area_m2 = 0.0;           // surface area
  double mass_kg = 0.0;           // density * volume
  Vec3 centroid = Vec3::Zero();   // centre of mass (uniform density), same frame as the mesh
  Mat3 inertia = Mat3::Zero();    // kg m^2 about the centroid, axes of the mesh frame;
                                  // off-diagonal terms are -∫ρ x y dV (products of inertia)
  Vec3 principal_moments = Vec3::Zero();  // kg m^2, ascending
  Mat3 principal_axes = Mat3::Identity(); // columns: the principal axes in the mesh frame, a
                                          // right-handed rotation (R_mesh_principal)
};

// Computes the mass properties for a uniform density (kg/m^3; default 1, so mass = volume).
// Meaningful for closed, consistently oriented surfaces (check with validate_mesh). Integration is
// done about the centre of the bounding box, so results do not lose digits far from the origin.
// Throws fascicle::Error (bad_input) for out-of-range indices, NaN/Inf coordinates used by a face,
// an empty mesh or zero volume.
MassProperties calc_mass_properties(const TriMesh& mesh, double density_kg_per_m3 = 1.0);

// Signed enclosed volume (positive for outward normals) by the divergence theorem:
// V = 1/6 sum_f a . (b x c), coordinates relative to `origin` (any point; one near the mesh keeps
// digits far from the coordinate origin). No checks: the fast form for per-frame use.
double calc_enclosed_volume(const Points3& V, const Triangles& F, const Vec3& origin);
// The same about the mesh's vertex mean.
double calc_enclosed_volume(const TriMesh& mesh);

}  // namespace fascicle
