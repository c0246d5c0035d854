// The "report" frame writer: what the browser viewer needs from a run (docs/viewer.md).
// Per frame it writes OUT/viewer/frames/NNNNN.bin (full resolution, float32); at begin() and
// finish() OUT/viewer/manifest.json and OUT/viewer/mesh.bin; at finish() the self-contained
// OUT/report.html (viewer JS/CSS inlined, the run embedded with positions quantised to 16 bits and
// frames subsampled above a size budget). After a failed run the report says it is incomplete.
#pragma once

#include <cstddef>
#include <filesystem>
#include <memory>
#include <string>

namespace fascicle {

struct Registry;
class FrameWriter;

struct ReportOptions {
  // Budget of the embedded frame data in report.html (bytes before base64); frames are
  // subsampled evenly (first and last kept) when the run needs more.
  std::size_t html_frame_budget_bytes = 12u << 20;
  // Folder with the built viewer (viewer.js, viewer.css); empty: find_viewer_assets().
  std::filesystem::path viewer_dir;
};

std::unique_ptr<FrameWriter> make_report_writer(const ReportOptions& options = {});

// Adds the writer "report" to the registry.
void register_report_writers(Registry& registry);

// The folder of the built viewer assets (viewer.js and viewer.css), searched in order:
// $FASCICLE_VIEWER_DIR, <folder of the running program>/viewer, <that folder>/../share/fascicle/viewer,
// the source tree's viewer/dist (as configured at build time). Empty path when none has them.
std::filesystem::path find_viewer_assets();

// The viewer page: inline CSS and JS, and, when `embedded_data` is not empty, the run's data
// elements (report.html); without them the page loads the run from `run/viewer/` over HTTP.
// `css`/`js` empty: a page that explains the viewer assets were not found.
std::string make_viewer_page(const std::string& title, const std::string& css, const std::string& js,
                             const std::string& embedded_data);

}  // namespace fascicle
