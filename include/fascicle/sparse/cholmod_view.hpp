#pragma once
// A CHOLMOD view (no copy) of a symmetric matrix stored as its lower triangle in compressed sparse
// columns with int indices and sorted rows, for the .cpp files, tests and benchmarks that call
// CHOLMOD themselves (the solver headers of this module keep cholmod.h out).
#include <suitesparse/cholmod.h>

#include <cstddef>

namespace fascicle {

inline cholmod_sparse view_symmetric_lower(std::size_t n, std::size_t nnz, int* p, int* i, double* x) {
  cholmod_sparse s{};
  s.nrow = s.ncol = n;
  s.nzmax = nnz;
  s.p = p;
  s.i = i;
  s.x = x;
  s.stype = -1;  // lower triangle stored
  s.itype = CHOLMOD_INT;
  s.xtype = CHOLMOD_REAL;
  s.dtype = CHOLMOD_DOUBLE;
  s.sorted = 1;
  s.packed = 1;
  return s;
}

}  // namespace fascicle
