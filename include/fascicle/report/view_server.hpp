// The HTTP server of `fascicle view`: the viewer page at "/", the run's files under "/run/".
// Bound to 127.0.0.1 only. Only regular files below the run folder are served: a request path with
// "..", "." or empty segments, a backslash or a NUL is refused (403), and a file whose real path
// (symbolic links resolved) leaves the run folder too (403); anything else missing is 404.
#pragma once

#include <filesystem>
#include <memory>
#include <string>

namespace fascicle {

struct ViewServerOptions {
  std::filesystem::path run_dir;     // the run's output folder
  std::filesystem::path viewer_dir;  // built viewer assets; empty: find_viewer_assets()
  int port = 8080;                   // 0: any free port
};

// Result of mapping a request path onto the run folder.
struct ResolvedPath {
  int status = 404;            // 200, 403 or 404
  std::filesystem::path file;  // when 200
};
// Maps "/run/<relative>" onto a regular file below `run_dir` (see the header comment). Pure apart
// from reading the file system; used by the server and by its tests.
ResolvedPath resolve_run_path(const std::filesystem::path& run_dir, const std::string& request_path);

class ViewServer {
 public:
  // Binds 127.0.0.1:port; throws fascicle::Error (bad input) when the port is in use or the run
  // folder does not exist.
  explicit ViewServer(const ViewServerOptions& options);
  ~ViewServer();
  ViewServer(const ViewServer&) = delete;
  ViewServer& operator=(const ViewServer&) = delete;

  int get_port() const;
  std::string get_url() const;  // http://127.0.0.1:PORT/
  // Serves until stop() is called from another thread (or the process ends). `max_seconds` > 0:
  // stops by itself after that long.
  void serve(double max_seconds = 0.0);
  void stop();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace fascicle
