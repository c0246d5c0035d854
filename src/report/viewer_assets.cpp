// Where the built viewer (viewer.js, viewer.css) is found at run time.
#include "fascicle/report/report.hpp"

#include <cstdlib>
#include <system_error>
#include <vector>

namespace fascicle {

std::filesystem::path find_viewer_assets() {
  namespace fs = std::filesystem;
  std::vector<fs::path> candidates;
  if (const char* env = std::getenv("FASCICLE_VIEWER_DIR"); env && *env) candidates.emplace_back(env);
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    candidates.push_back(exe.parent_path() / "viewer");
    candidates.push_back(exe.parent_path().parent_path() / "share" / "fascicle" / "viewer");
  }
#ifdef FASCICLE_VIEWER_BUILD_DIR
  candidates.emplace_back(FASCICLE_VIEWER_BUILD_DIR);
#endif
  for (const fs::path& dir : candidates)
    if (fs::is_regular_file(dir / "viewer.js", ec) && fs::is_regular_file(dir / "viewer.css", ec)) return dir;
  return {};
}

}  // namespace fascicle
