#pragma once
// Triangular solves with a CHOLMOD supernodal LLᵀ factor, applied by our own small kernels rather
// than CHOLMOD's solve: for a few right-hand sides on small supernodes the BLAS calls CHOLMOD makes
// per supernode cost more than the arithmetic. The factor stays CHOLMOD's (computed by it); only
// its application is here. This header does not include cholmod.h: the factor is passed as an
// opaque pointer.
#include <vector>

namespace fascicle {

// Which clone of the kernels runs. All do the same operations in the same order (eight-lane
// partial sums, fused multiply-adds; exact library fma() in the generic clone), so they give
// identical bits on every machine; `automatic` picks the fastest this CPU runs (AVX-512, then
// AVX2 with FMA, then generic). Choosing a clone the CPU lacks is undefined behaviour: check
// has_supernodal_kernel first.
enum class SupernodalKernel { automatic, generic, avx2, avx512 };
bool has_supernodal_kernel(SupernodalKernel kernel);

// Scratch space of solve_supernodal_llt, reused across calls (it only grows: no allocation once
// it has met the largest factor and column count). One per thread of use.
struct SupernodalSolveWorkspace {
  SupernodalKernel kernel = SupernodalKernel::automatic;
  std::vector<double> gathered;  // one supernode's rows of up to eight right-hand sides
  std::vector<double> permuted;  // P b for up to eight right-hand sides (permuted factors only)
  std::vector<double> unit;      // unit right-hand sides (solve_supernodal_unit_forward; kept zero)
  std::vector<char> marked;      // per supernode (solve_supernodal_unit_forward; kept zero)
};

// True when `factor` (a `const cholmod_factor*`) is one solve_supernodal_llt can apply: numeric,
// supernodal LLᵀ, real double values, int indices.
bool is_supernodal_llt(const void* factor);

// Solves A x = b in place for ncols right-hand sides stored column-major in B (leading dimension
// ld ≥ n), where CHOLMOD factorised P A Pᵀ = L Lᵀ (P from the factor's Perm; skipped when the
// ordering is natural): x = Pᵀ L⁻ᵀ L⁻¹ P b. Up to eight columns are solved in one pass over the
// factor; columns are independent and each gives the same bits whatever ncols is. `factor` is a
// `const cholmod_factor*`. Returns false (B untouched) when !is_supernodal_llt(factor); the caller
// then uses CHOLMOD's own solve.
bool solve_supernodal_llt(const void* factor, double* B, int ncols, int ld,
                          SupernodalSolveWorkspace& workspace);

// The two halves of solve_supernodal_llt, for a correction between them (a low-rank update of the
// factorised matrix, deformation/surface_first.cpp): Y = L⁻¹ P B (Y: n x ncols, column-major,
// leading dimension n, in the factor's permuted order), then X = Pᵀ L⁻ᵀ Y (Y is overwritten).
// Forward then backward give the same bits as solve_supernodal_llt. False when
// !is_supernodal_llt(factor).
bool solve_supernodal_forward(const void* factor, const double* B, int ncols, int ldb, double* Y,
                              SupernodalSolveWorkspace& workspace);
bool solve_supernodal_backward(const void* factor, double* Y, int ncols, double* X, int ldx,
                               SupernodalSolveWorkspace& workspace);

// The supernodal elimination tree of a factor: parent[s] (−1 at a root; parents come after their
// children), supernode_of[k] for each permuted row k, and position[j]: where the factor's
// permutation puts original row j (P e_j = e_position[j]). Empty when !is_supernodal_llt(factor).
struct SupernodalTree {
  std::vector<int> parent;
  std::vector<int> supernode_of;
  std::vector<int> position;
};
SupernodalTree make_supernodal_tree(const void* factor);

// f = L⁻¹ P e_j for a unit vector: non-zero only in the pivot rows of the supernodes on the path
// from position[j]'s supernode to the root (Gilbert's reach in the elimination tree). Stored along
// that chain, root first: the values of supernode chain[c] (its pivot rows, in order) are
// values[offset[c] .. offset[c + 1]).
struct UnitForwardColumn {
  std::vector<int> chain;
  std::vector<int> offset;
  std::vector<double> values;
};
// out[k] = L⁻¹ P e_rows[k] for k < count (original row indices), only the supernodes on the
// chains visited (up to eight columns per pass). The values equal those of a full forward solve.
bool solve_supernodal_unit_forward(const void* factor, const SupernodalTree& tree, const int* rows,
                                   int count, UnitForwardColumn* out,
                                   SupernodalSolveWorkspace& workspace);
// aᵀ b of two such columns (of one factor): (L⁻¹ P e_i)ᵀ (L⁻¹ P e_j) = (A⁻¹)_ij. Summed in row order
// over the shared part of the two chains.
double dot_unit_forward(const UnitForwardColumn& a, const UnitForwardColumn& b);

}  // namespace fascicle
