// Parallel loops on TBB with a user-chosen thread count. Work is split by index and every index
// writes only its own outputs, so results do not depend on scheduling: the same inputs and thread
// count give identical results (and, for independent items, identical for any thread count).
#pragma once

#include <cstddef>
#include <functional>
#include <memory>
#include <mutex>

namespace fascicle {

// Limits TBB to n threads for the lifetime of the returned guard (n <= 0: all cores).
class ThreadLimit {
 public:
  explicit ThreadLimit(int n);
  ~ThreadLimit();
  ThreadLimit(const ThreadLimit&) = delete;
  ThreadLimit& operator=(const ThreadLimit&) = delete;
  int threads() const { return threads_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int threads_;
};

// Calls body(i) for i in [0, n), in parallel. Exceptions thrown by body propagate (the first one).
void parallel_for(std::size_t n, const std::function<void(std::size_t)>& body);

// The number of threads TBB will use now.
int max_threads();

// fascicle parallelises over muscles, bodies and points with TBB; the BLAS under the sparse
// Cholesky factorisations must not start thread teams of its own inside those loops. When the
// process's BLAS is OpenBLAS (Debian's libopenblas0-pthread provides libblas.so.3), this limits it
// to one thread per call, once per process; with another BLAS it does nothing. Cheap after the
// first call. (OpenBLAS's *serial* build is not safe to call from several threads at once: results
// then differ run to run — use the pthread build.)
void use_single_threaded_blas();

// Held around every sparse symbolic analysis that may choose a METIS ordering (cholmod_analyze,
// Eigen's Cholmod*::analyzePattern): METIS draws from a random-number state that GKlib shares
// between all threads, so two analyses at once race on it and their orderings (and every result
// after them) depend on timing. The one process-wide lock guards that library state; the
// numeric factorisations and solves stay parallel.
std::mutex& get_ordering_mutex();

}  // namespace fascicle
