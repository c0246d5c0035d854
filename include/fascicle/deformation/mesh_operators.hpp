// Discrete operators on closed triangle surfaces used by the surface-first deformation:
// Laplacians (differential coordinates), the enclosed volume with its exact gradient, and the exact
// volume along a straight line in configuration space (a cubic polynomial).
#pragma once

#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/geometry/tri_mesh.hpp"

#include <Eigen/SparseCore>

#include <array>

namespace fascicle {

using SparseMatrix = Eigen::SparseMatrix<double>;

enum class LaplacianKind {
  // (L x)_i = sum_j (cot a_ij + cot b_ij)/2 (x_i - x_j): the Dirichlet-energy Laplacian (Pinkall and
  // Polthier 1993; Meyer et al. 2003). Its differential coordinates are area-weighted mean-curvature
  // normals, which are invariant to tangential re-parametrisation and independent of mesh valence.
  cotangent,
  // (L x)_i = sum_j (x_i - x_j) over the one-ring (graph Laplacian): robust to degenerate triangles,
  // but its differential coordinates carry tangential components that depend on the sampling.
  uniform,
};

// #V x #V symmetric Laplacian, positive semidefinite, L * ones = 0. Throws fascicle::Error
// (bad input) for out-of-range indices.
SparseMatrix calc_laplacian(const TriMesh& mesh, LaplacianKind kind);

// calc_enclosed_volume(V, F, origin): geometry/mass_properties.hpp.

// dV/dx_i = 1/6 sum over faces (i, j, k) containing i, in their cyclic order, of x_j x x_k
// (#V x 3); equal to one third of the area-weighted outward normals.
Points3 calc_volume_gradient(const Points3& V, const Triangles& F);

// Coefficients c0..c3 with V(X + t Y) = c0 + c1 t + c2 t^2 + c3 t^3 (exact for a triangle mesh).
std::array<double, 4> calc_volume_cubic(const Points3& X, const Points3& Y, const Triangles& F,
                                        const Vec3& origin);

// The same two on points stored interleaved (x0 y0 z0 x1 y1 z1 ...: 3 #V values), for callers that
// keep them so; the functions above interleave copies and call these (same arithmetic, same bits).
// add_volume_gradient_times_six adds 6 dV/dx to G (3 #V values; calc_volume_gradient divides by 6).
std::array<double, 4> calc_volume_cubic(const double* X, const double* Y, const Triangles& F, const Vec3& origin);
void add_volume_gradient_times_six(const double* X, const Triangles& F, double* G);

// A real root of c0 + c1 t + c2 t^2 + c3 t^3 = target: Newton's iteration from the linearised root
// when it converges, otherwise the real root of smallest |t|, bracketed between the critical points
// and Cauchy's bound and found by bisection. Returns NaN only when there is no real root (a
// polynomial of even degree that does not reach the target, or all coefficients zero).
double solve_volume_cubic(const std::array<double, 4>& c, double target);

}  // namespace fascicle
