#include "fascicle/core/parallel.hpp"

#include <dlfcn.h>

#include <mutex>
#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>

namespace fascicle {

struct ThreadLimit::Impl {
  explicit Impl(int n) : control(tbb::global_control::max_allowed_parallelism, n) {}
  tbb::global_control control;
};

ThreadLimit::ThreadLimit(int n)
    : impl_(std::make_unique<Impl>(n > 0 ? n : tbb::info::default_concurrency())),
      threads_(n > 0 ? n : tbb::info::default_concurrency()) {}

ThreadLimit::~ThreadLimit() = default;

void parallel_for(std::size_t n, const std::function<void(std::size_t)>& body) {
  tbb::parallel_for(std::size_t{0}, n, [&](std::size_t i) { body(i); });
}

void use_single_threaded_blas() {
  static std::once_flag once;  // a process-wide library setting, made once
  std::call_once(once, [] {
    using SetThreads = void (*)(int);
    if (auto set = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"))) set(1);
  });
}

int max_threads() {
  return static_cast<int>(
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
}

std::mutex& get_ordering_mutex() {
  static std::mutex mutex;
  return mutex;
}

}  // namespace fascicle
