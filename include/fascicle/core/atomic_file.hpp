// Atomic file output: write to a temporary file in the destination folder, then rename it over the
// destination. A failure (exception, crash) never leaves a half-written destination behind.
#pragma once

#include <filesystem>
#include <functional>
#include <ostream>
#include <string>

namespace fascicle {

// Writes text or binary data through the stream the callback receives; throws fascicle::Error
// (bad_input, naming the path) if the folder is not writable or the stream fails.
void write_file_atomically(const std::filesystem::path& path,
                           const std::function<void(std::ostream&)>& write);

// For writers that need a file name (e.g. VTK's): the callback writes to the temporary path it is
// given; on success the temporary file is renamed to `path`, on failure it is removed.
void write_via_temporary(const std::filesystem::path& path,
                         const std::function<void(const std::filesystem::path& tmp)>& write);

}  // namespace fascicle
