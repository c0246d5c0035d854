// Exact volume of a B-spline solid and its gradient (seed 000 §3.1.1).
//
// V = ∫∫∫ det J(u,v,w) du dv dw, J = dx/d(u,v,w). det J is a polynomial of degree 3p-1 in each
// parameter on every knot span, so Gauss–Legendre quadrature with ceil(3p/2) points per span and
// direction is exact (up to rounding). For solids whose non-periodic directions have clamped knots,
// the divergence theorem (∇·x = 3) turns V into an integral over the six boundary faces,
//   V = 1/3 ∮ x·n dA = 1/3 Σ_faces ± ∫∫ x·(x_a × x_b) da db,
// and each face is the B-spline surface of the boundary layer of control points, so interior
// control points do not enter. The first variation of V is ∮ δx·n dA, hence
//   dV/dP_I = ∫∫ N_I n dA over the faces that contain P_I (boundary form), or
//   dV/dP_I = ∫∫∫ (∂_u N_I x_v×x_w + ∂_v N_I x_w×x_u + ∂_w N_I x_u×x_v) du dv dw (volume form).
// Both are exact polynomial integrals with the same quadrature. V is signed: a left-handed
// parametrisation (reversed orientation) gives exactly -V.
#pragma once

#include "fascicle/bspline/solid.hpp"

#include <vector>

namespace fascicle {

struct VolumeAndGradient {
  double volume_m3 = 0.0;
  Points3 gradient;  // #P x 3, dV/dP in m^2 (rows follow the control-point order of the solid)
};

// Gauss–Legendre nodes on [-1, 1] (ascending) and weights, n >= 1.
void calc_gauss_legendre(int n, std::vector<double>& nodes, std::vector<double>& weights);

// Points per knot span that integrate det J exactly for a direction of this degree.
int find_volume_quadrature_order(int degree);

// Gauss–Legendre points of every non-empty knot span of a direction: parameter t and weight
// (the span's half-length times the rule's weight), `points_per_span` per span.
struct SpanPoint {
  double t = 0.0;
  double weight = 0.0;
};
std::vector<SpanPoint> calc_span_quadrature(const BSplineBasis& basis, int points_per_span);

// Smallest det J, J = dx/d(u,v,w) (m^3 per unit parameter volume), over the Gauss–Legendre points
// of every knot span (`points_per_span` per direction; 0: degree + 1, the rule solid dynamics
// integrates with), and the material point where it occurs (the first one on ties). A solid whose
// minimum is not positive is inverted or degenerate there (solid dynamics rejects it). Meaningful
// for trivariate solids (degree >= 1 in every direction; a collapsed direction gives det J = 0).
struct JacobianMinimum {
  double det_J = 0.0;
  Vec3 material = Vec3::Zero();
};
JacobianMinimum find_min_jacobian_determinant(const BSplineSolid& solid, int points_per_span = 0);

// Volume by quadrature of det J over the parametric box (any knots).
double calc_volume(const BSplineSolid& solid);
VolumeAndGradient calc_volume_and_gradient(const BSplineSolid& solid);

// Volume from the boundary faces only. Throws bad_input if a non-periodic direction is not clamped.
double calc_boundary_volume(const BSplineSolid& solid);
VolumeAndGradient calc_boundary_volume_and_gradient(const BSplineSolid& solid);

// The reusable form of calc_boundary_volume_and_gradient: basis values at the quadrature points
// are computed once for a lattice; calc() then only touches control points. Each face is a
// tensor-product sum factorisation: the face's control points are contracted along one direction
// onto its quadrature points, then the other direction is swept with the first one's quadrature
// points as the contiguous (SIMD) index. Thread-safe (const; scratch memory is per call).
// On CPUs with AVX2 the sweep runs four points per instruction instead of two (allow_avx2 =
// false forces the SSE2 kernel); both round every point identically, but each lane accumulates a
// different subset of points (stride 4 vs 2), so volume and gradient differ by a few ulps between
// an AVX2 and a non-AVX2 machine (each is deterministic on its machine).
class BoundaryVolumeIntegrator {
 public:
  explicit BoundaryVolumeIntegrator(const BSplineSolid& lattice, bool allow_avx2 = true);
  // P: control points of a solid with the lattice given to the constructor.
  VolumeAndGradient calc(const Points3& P) const;
  double calc_volume(const Points3& P) const;

 private:
  // Quadrature of one parametric direction: per point, its weight and the degree + 1 non-zero
  // basis values, derivatives and control indices (periodic indices already wrapped).
  struct Direction {
    int num_control = 0, num_points = 0, width = 0;  // width = degree + 1
    std::vector<double> weight;       // num_points
    std::vector<double> N0, N1;       // num_points x width
    std::vector<int> index;           // num_points x width
    // The same values densely, control point major, points padded to whole SIMD vectors (zeros):
    // dense0/dense1/dense_w[i * padded_points + q] = N_i(t_q), N_i'(t_q), w_q N_i(t_q); and the
    // vector-aligned range [band_lo[i], band_hi[i]) of points where N_i is non-zero.
    int padded_points = 0;
    std::vector<double> dense0, dense1, dense_w;
    std::vector<int> band_lo, band_hi;
  };
  template <bool kGradient>
  double integrate(const Points3& P, Points3* gradient) const;
  std::array<BSplineBasis, 3> basis_;
  int lanes_ = 2;  // points per SIMD vector of the sweep: 2 (SSE2) or 4 (AVX2)
  std::array<Direction, 3> dir_;
};

// Gradient with respect to spatial points x_s = x(U_s) instead of control points: when the
// control points are the least-squares solution P = A^+ X of A P = X (A_si = N_i(U_s), A of full
// column rank), dV/dX = A^{+T} dV/dP. material: #S x 3 material points. Returns #S x 3 (m^2).
Points3 calc_volume_gradient_wrt_spatial_points(const BSplineSolid& solid, const Points3& material);

}  // namespace fascicle
