#pragma once
// Test matrices for the sparse-solve tests: a symmetric matrix assembled from its strictly lower
// entries by column (duplicates summed) and its diagonal, stored as the lower triangle in
// compressed sparse columns with sorted rows (view it with view_symmetric_lower).
#include <algorithm>
#include <utility>
#include <vector>

namespace fascicle::test {

struct LowerCsc {
  int n = 0;
  std::vector<int> p, i;
  std::vector<double> x;
};

// below[c]: (row > c, value) pairs of column c, in any order, repeats allowed.
inline LowerCsc assemble_lower_csc(std::vector<std::vector<std::pair<int, double>>> below,
                                   const std::vector<double>& diag) {
  LowerCsc A;
  A.n = static_cast<int>(diag.size());
  A.p.push_back(0);
  for (int c = 0; c < A.n; ++c) {
    std::vector<std::pair<int, double>>& entries = below[c];
    entries.push_back({c, diag[c]});
    std::sort(entries.begin(), entries.end());
    for (std::size_t k = 0; k < entries.size(); ++k) {
      if (k > 0 && entries[k].first == entries[k - 1].first) {
        A.x.back() += entries[k].second;
        continue;
      }
      A.i.push_back(entries[k].first);
      A.x.push_back(entries[k].second);
    }
    A.p.push_back(static_cast<int>(A.i.size()));
  }
  return A;
}

}  // namespace fascicle::test
