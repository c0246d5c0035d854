#include "fascicle/core/atomic_file.hpp"

#include "fascicle/core/error.hpp"

#include <atomic>
#include <fstream>
#include <system_error>
#include <unistd.h>

namespace fascicle {
namespace {

std::filesystem::path temporary_name(const std::filesystem::path& path) {
  static std::atomic<unsigned> counter{0};
  return path.parent_path() / ("." + path.filename().string() + ".tmp" +
                               std::to_string(::getpid()) + "." + std::to_string(counter++));
}

}  // namespace

void write_via_temporary(const std::filesystem::path& path,
                         const std::function<void(const std::filesystem::path& tmp)>& write) {
  const std::filesystem::path parent =
      path.parent_path().empty() ? std::filesystem::path(".") : path.parent_path();
  std::error_code ec;
  std::filesystem::create_directories(parent, ec);
  if (ec) {
    throw_bad_input("cannot create output folder: " + ec.message(),
                    {.file = parent.string(), .suggestion = "choose a writable --out folder"});
  }
  const std::filesystem::path tmp = temporary_name(path);
  try {
    write(tmp);
  } catch (...) {
    std::filesystem::remove(tmp, ec);
    throw;
  }
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    throw_bad_input("cannot write output file: " + ec.message(), {.file = path.string()});
  }
}

void write_file_atomically(const std::filesystem::path& path,
                           const std::function<void(std::ostream&)>& write) {
  write_via_temporary(path, [&](const std::filesystem::path& tmp) {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) {
      throw_bad_input("cannot open output file for writing",
                      {.file = path.string(), .suggestion = "check the folder's permissions"});
    }
    write(out);
    out.flush();
    if (!out) throw_bad_input("writing failed (disk full?)", {.file = path.string()});
  });
}

}  // namespace fascicle
