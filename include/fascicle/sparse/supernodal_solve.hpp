#pragma once
// Triangular solves with a CHOLMOD supernodal LLᵀ factor, applied by our own small kernels rather
// than CHOLMOD's solve: for a few right-hand sides on small supernodes the BLAS calls CHOLMOD makes
// per supernode cost more than the arithmetic. The factor stays CHOLMOD's (computed by it); only
// its application is here. This header does not include cholmod.h: the factor is passed as an
// opaque pointer.
#include <vector>

namespace fascicle {

// Which clone of the kernels runs. Both do the same operations in the same order without FMA, so
// they give identical bits; `automatic` picks AVX2 when the CPU has it.
enum class SupernodalKernel { automatic, generic, avx2 };

// Scratch space of solve_supernodal_llt, reused across calls (it only grows: no allocation once
// it has met the largest factor and column count). One per thread of use.
struct SupernodalSolveWorkspace {
  SupernodalKernel kernel = SupernodalKernel::automatic;
  std::vector<double> gathered;  // one supernode's rows of up to eight right-hand sides
  std::vector<double> permuted;  // P b for up to eight right-hand sides (permuted factors only)
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

}  // namespace fascicle
