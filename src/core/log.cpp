#include "fascicle/core/log.hpp"

#include <spdlog/sinks/stdout_color_sinks.h>

#include <atomic>

namespace fascicle {
namespace {
std::atomic<bool> g_quiet{false};  // set once at start-up by the CLI
}

void init_logging(int verbosity) {
  auto logger = spdlog::stderr_color_mt("fascicle");
  logger->set_pattern("%^%l%$: %v");
  spdlog::level::level_enum level = spdlog::level::info;
  if (verbosity < 0) level = spdlog::level::err;
  if (verbosity == 1) level = spdlog::level::debug;
  if (verbosity >= 2) level = spdlog::level::trace;
  logger->set_level(level);
  spdlog::set_default_logger(logger);
  g_quiet = verbosity < 0;
}

bool quiet() { return g_quiet; }

}  // namespace fascicle
