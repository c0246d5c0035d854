#pragma once
// Triangular solves with a CHOLMOD simplicial LDLᵀ factor (the kind cholmod_updown modifies),
// applied by our own kernel: all right-hand sides (up to eight) in one pass over the factor, where
// CHOLMOD's own simplicial solve takes them four at a time (six columns: two passes), with the
// columns of one row side by side so a vector unit updates them together.
//
// Same bits as cholmod_solve2(CHOLMOD_A, ...): every column goes through the same arithmetic in
// the same order as in CHOLMOD's simplicial kernels (forward solve with the unit-diagonal L, then
// D⁻¹ and Lᵀ, both with CHOLMOD's chains of up to three consecutive columns that share their
// pattern), whatever the number of columns; no fused multiply-add. This header does not include
// cholmod.h: the factor is passed as an opaque pointer.
#include <cstdint>
#include <vector>

namespace fascicle {

// Which clone of the kernel runs. Both do the same operations in the same order without FMA, so
// they give identical bits; `automatic` picks AVX2 when the CPU has it.
enum class SimplicialKernel { automatic, generic, avx2 };

// Scratch space of solve_simplicial_ldlt, reused across calls (no allocation once warm). One per
// thread of use.
struct SimplicialSolveWorkspace {
  SimplicialKernel kernel = SimplicialKernel::automatic;
  std::vector<double> rows;  // P b, one row of up to eight columns per unknown
  int row_width = 0, used_columns = 0;  // layout of `rows` at the last solve (its unused lanes are 0)
  // L's row indices in 16 bits (n <= 65536), made from L's index array `row_index_source` with
  // these column starts and counts; made again when any of them differs at a solve. A factor
  // re-analysed for another matrix inside the same CHOLMOD object with the same column layout is
  // not detected: call forget_pattern() after any new analysis or factorisation.
  std::vector<std::uint16_t> row_index16;
  std::vector<int> column_start, column_count;
  const void* row_index_source = nullptr;
  void forget_pattern() { row_index_source = nullptr; }
};

// True when `factor` (a `const cholmod_factor*`) is one solve_simplicial_ldlt can apply: numeric,
// simplicial LDLᵀ (not LLᵀ), real double values, int indices.
bool is_simplicial_ldlt(const void* factor);

// Solves A x = b in place for ncols ≤ 8 right-hand sides stored column-major in B (leading
// dimension ld ≥ n), where CHOLMOD factorised P A Pᵀ = L D Lᵀ: x = Pᵀ L⁻ᵀ D⁻¹ L⁻¹ P b. Returns
// false (B untouched) when !is_simplicial_ldlt(factor), ncols is not in 1..8 or ld < n; the caller then
// uses CHOLMOD's own solve.
bool solve_simplicial_ldlt(const void* factor, double* B, int ncols, int ld,
                           SimplicialSolveWorkspace& workspace);

// The same solve with the right-hand sides stored by rows: B holds n rows of `width` doubles
// (width 4 for ncols <= 4, 8 for ncols <= 8), row i = the ncols values of unknown i followed by
// unused lanes, which are left as they are. The same bits as solve_simplicial_ldlt; saves its
// column-to-row copies when the caller assembles rows anyway. False (B untouched) when the factor
// or the sizes do not fit, as there.
bool solve_simplicial_ldlt_rows(const void* factor, double* B, int ncols, int width,
                                SimplicialSolveWorkspace& workspace);

// The same solve on rows already in the factor's order (row k: unknown Perm[k]; width and
// columns as in solve_simplicial_ldlt_rows), in place and without copies: x in the factor's
// order, P x. Every lane is solved on its own, so the unused lanes do not touch the used ones.
bool solve_simplicial_ldlt_in_factor_order(const void* factor, double* X, int ncols, int width,
                                           SimplicialSolveWorkspace& workspace);

}  // namespace fascicle
