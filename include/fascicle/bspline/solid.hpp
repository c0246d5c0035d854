// Trivariate B-spline solids (seed 000 ch. 3): x(u,v,w) = sum_ijk N_i(u) N_j(v) N_k(w) P_ijk.
// (u,v,w) are material coordinates (dimensionless, in the box of the three knot domains); x is
// the spatial position (m). Curves and surfaces are solids with collapsed directions (degree 0,
// one control point).
#pragma once

#include "fascicle/bspline/basis.hpp"
#include "fascicle/core/types.hpp"

#include <array>
#include <string>

namespace fascicle {

// Which parametric direction runs along the muscle fibres.
enum class FibreDirection { u = 0, v = 1, w = 2 };

struct BSplineSolid {
  std::array<BSplineBasis, 3> basis;  // u, v, w
  // (n_u n_v n_w) x 3 control points in metres; point (i,j,k) is row i + n_u (j + n_v k).
  Points3 P;
  FibreDirection fibre_direction = FibreDirection::w;
  std::string name;

  int num_control(int d) const { return basis[d].num_control; }
  int num_control_points() const {
    return basis[0].num_control * basis[1].num_control * basis[2].num_control;
  }
  int index(int i, int j, int k) const {
    return i + basis[0].num_control * (j + basis[1].num_control * k);
  }
  Vec3 get_lower() const { return {basis[0].get_lower(), basis[1].get_lower(), basis[2].get_lower()}; }
  Vec3 get_upper() const { return {basis[0].get_upper(), basis[1].get_upper(), basis[2].get_upper()}; }
};

// Builds a solid and validates it (see validate_solid).
BSplineSolid make_solid(std::array<BSplineBasis, 3> basis, Points3 P,
                        FibreDirection fibre = FibreDirection::w, std::string name = {});
// A B-spline surface (u,v) as a solid with a collapsed w direction.
BSplineSolid make_surface_solid(BSplineBasis u, BSplineBasis v, Points3 P);
// A B-spline curve (u) as a solid with collapsed v and w directions.
BSplineSolid make_curve_solid(BSplineBasis u, Points3 P);

// Throws fascicle::Error (bad_input, naming the solid) for invalid knot vectors, a control-point
// array of the wrong size, or NaN/Inf control points (naming the first one as (i,j,k)).
void validate_solid(const BSplineSolid& solid);

// Maps material coordinates into the parametric box (clamp, or wrap on periodic directions).
Vec3 wrap_material_point(const BSplineSolid& solid, const Vec3& uvw);

// x(u,v,w) in metres.
Vec3 calc_point(const BSplineSolid& solid, const Vec3& uvw);

// Position and Jacobian J = [dx/du dx/dv dx/dw] (columns, m per unit parameter).
struct SolidPoint {
  Vec3 x = Vec3::Zero();
  Mat3 J = Mat3::Zero();
};
SolidPoint calc_point_and_jacobian(const BSplineSolid& solid, const Vec3& uvw);

// Same, for the given control points (same lattice as `solid`): lets callers evaluate a deformed
// configuration without copying the solid.
SolidPoint calc_point_and_jacobian(const BSplineSolid& solid, const Points3& P, const Vec3& uvw);

// Deformation gradient F = dx/dX = J_current J_rest^{-1} at a material point, between the rest
// control points `rest` and the current ones `current`. Throws numerical if J_rest is singular.
Mat3 calc_deformation_gradient(const BSplineSolid& solid, const Points3& rest,
                               const Points3& current, const Vec3& uvw);

}  // namespace fascicle
