#include "fascicle/core/progress.hpp"

#include "fascicle/core/log.hpp"

#include <cstdio>
#include <unistd.h>

namespace fascicle {

ProgressBar::ProgressBar(std::string label, std::size_t total)
    : label_(std::move(label)),
      total_(total),
      enabled_(!quiet() && total > 0 && ::isatty(STDERR_FILENO) == 1),
      start_(std::chrono::steady_clock::now()),
      last_draw_(start_) {}

ProgressBar::~ProgressBar() { finish(); }

void ProgressBar::advance(std::size_t steps) {
  const std::size_t done = done_.fetch_add(steps) + steps;
  if (!enabled_) return;
  const auto now = std::chrono::steady_clock::now();
  // redraw at most 20 times a second, and always at the end
  if (done < total_ && now - last_draw_ < std::chrono::milliseconds(50)) return;
  std::unique_lock lock(draw_mutex_, std::try_to_lock);
  if (!lock.owns_lock()) return;
  last_draw_ = now;
  draw(done);
}

void ProgressBar::draw(std::size_t done) {
  constexpr int width = 30;
  const double fraction = total_ == 0 ? 1.0 : std::min(1.0, double(done) / double(total_));
  const int filled = static_cast<int>(fraction * width);
  const double elapsed =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  const double eta = fraction > 0 ? elapsed * (1.0 - fraction) / fraction : 0.0;
  std::string bar(filled, '#');
  bar.resize(width, '-');
  std::fprintf(stderr, "\r%s [%s] %zu/%zu  %.1fs elapsed, %.1fs left ", label_.c_str(),
               bar.c_str(), done, total_, elapsed, eta);
  std::fflush(stderr);
}

void ProgressBar::finish() {
  if (!enabled_ || finished_) return;
  finished_ = true;
  std::lock_guard lock(draw_mutex_);
  draw(done_.load());
  std::fputc('\n', stderr);
}

}  // namespace fascicle
