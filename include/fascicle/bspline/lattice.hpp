// Lattice designs of seed 000 §3.0.1: cubical, cylindrical, spherical and toroidal control-point
// lattices, with the equality constraints on control points that collapsed axes and poles need,
// and the boundary faces of clamped solids as B-spline surfaces.
#pragma once

#include "fascicle/bspline/solid.hpp"

#include <Eigen/SparseCore>

#include <array>
#include <vector>

namespace fascicle {

// Groups of control points that must stay equal (a collapsed axis, centre or pole).
// representative[I] is the smallest index of I's group (I itself when unconstrained).
struct LatticeConstraints {
  std::vector<int> representative;
};

// A solid together with the constraints its lattice needs.
struct LatticeDesign {
  BSplineSolid solid;
  LatticeConstraints constraints;
};

// Axis-aligned box [lower, upper] with control points at the Greville abscissae, so the solid is
// exactly the affine map of the parametric unit box (fibres along w). No constraints.
LatticeDesign make_cubical_lattice(const Vec3& lower, const Vec3& upper,
                                   const std::array<int, 3>& degree,
                                   const std::array<int, 3>& count);

// Cylinder around the z axis, z in [0, length]. u is radial (clamped; u = 0 is the axis, where all
// control points of a ring coincide: constrained), v goes around (periodic), w along z (clamped).
// Control rings have radius radius * greville(u).
LatticeDesign make_cylindrical_lattice(double radius, double length,
                                       const std::array<int, 3>& degree,
                                       const std::array<int, 3>& count);

// Ball about the origin. u radial (u = 0: the centre, constrained), v azimuth (periodic), w polar
// angle from the south pole (w = 0) to the north pole (w = 1); each pole layer is constrained to
// one point per radius.
LatticeDesign make_spherical_lattice(double radius, const std::array<int, 3>& degree,
                                     const std::array<int, 3>& count);

// Solid torus about the z axis. u radial in the tube (u = 0: the core circle, constrained),
// v around the tube (periodic), w around the z axis (periodic).
LatticeDesign make_toroidal_lattice(double major_radius, double minor_radius,
                                    const std::array<int, 3>& degree,
                                    const std::array<int, 3>& count);

// No constraints for a lattice of n control points.
LatticeConstraints make_free_constraints(int n);

// Projects control points onto the constraints: every group is replaced by its mean.
Points3 enforce_lattice_constraints(const LatticeConstraints& c, const Points3& P);

// Largest distance (m) of a control point from its group's representative.
double calc_constraint_violation(const LatticeConstraints& c, const Points3& P);

// The matrix E (#P x #free) with P = E P_free: columns are the groups in order of representative.
Eigen::SparseMatrix<double> make_constraint_expansion(const LatticeConstraints& c);

// Boundary face of a solid: direction d in {0,1,2}, side 0 (lower) or 1 (upper). With clamped
// knots in d it is the B-spline surface (collapsed d) of that boundary layer of control points:
// the returned solid has the other two bases, in cyclic order (d+1, d+2), so that its
// x_a × x_b points outwards on the upper side. Throws bad_input if d is periodic or not clamped.
BSplineSolid extract_boundary_surface(const BSplineSolid& solid, int d, int side);

}  // namespace fascicle
