// Logging through spdlog. Messages go to stderr; results go to files or stdout.
#pragma once

#include <spdlog/spdlog.h>

namespace fascicle {

// verbosity: -1 quiet (errors only), 0 normal (info), 1 verbose (debug), 2+ trace.
void init_logging(int verbosity);

// True when --quiet was given: progress bars and informational output are suppressed.
bool quiet();

}  // namespace fascicle
