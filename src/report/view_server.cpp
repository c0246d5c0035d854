// `fascicle view`'s HTTP server (cpp-httplib; this is the only file that includes it).
#include "fascicle/report/view_server.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/report/report.hpp"

#include <httplib.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <condition_variable>
#include <fstream>
#include <mutex>
#include <sstream>
#include <thread>

namespace fascicle {
namespace {

namespace fs = std::filesystem;

std::string read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

const char* content_type(const fs::path& file) {
  const std::string ext = file.extension().string();
  if (ext == ".json") return "application/json";
  if (ext == ".html") return "text/html; charset=utf-8";
  if (ext == ".csv" || ext == ".sto" || ext == ".mot" || ext == ".txt") return "text/plain; charset=utf-8";
  if (ext == ".svg") return "image/svg+xml";
  if (ext == ".png") return "image/png";
  if (ext == ".js") return "text/javascript";
  if (ext == ".css") return "text/css";
  return "application/octet-stream";
}

bool is_below(const fs::path& root, const fs::path& p) {
  auto r = root.begin(), q = p.begin();
  for (; r != root.end(); ++r, ++q)
    if (q == p.end() || *r != *q) return false;
  return true;
}

}  // namespace

ResolvedPath resolve_run_path(const fs::path& run_dir, const std::string& request_path) {
  static constexpr std::string_view prefix = "/run/";
  if (request_path.rfind(prefix, 0) != 0) return {404, {}};
  const std::string rel = request_path.substr(prefix.size());
  if (rel.empty()) return {404, {}};
  // Segment by segment: nothing that could climb out or alias.
  fs::path joined = run_dir;
  size_t start = 0;
  while (start <= rel.size()) {
    const size_t end = std::min(rel.find('/', start), rel.size());
    const std::string seg = rel.substr(start, end - start);
    if (seg.empty() || seg == "." || seg == ".." || seg.find('\\') != std::string::npos ||
        seg.find('\0') != std::string::npos)
      return {403, {}};
    joined /= seg;
    start = end + 1;
  }
  std::error_code ec;
  const fs::path root = fs::canonical(run_dir, ec);
  if (ec) return {404, {}};
  const fs::path real = fs::canonical(joined, ec);
  if (ec) return {404, {}};
  if (!is_below(root, real)) return {403, {}};
  if (!fs::is_regular_file(real, ec)) return {404, {}};
  return {200, real};
}

struct ViewServer::Impl {
  ViewServerOptions options;
  httplib::Server server;
  int port = 0;
  std::string page;
  std::mutex mutex;
  std::condition_variable stopped;
  bool stopping = false;
};

ViewServer::ViewServer(const ViewServerOptions& options) : impl_(std::make_unique<Impl>()) {
  impl_->options = options;
  std::error_code ec;
  if (!fs::is_directory(options.run_dir, ec))
    throw_bad_input("'" + options.run_dir.string() + "' is not a folder",
                    {.file = options.run_dir.string(),
                     .suggestion = "give the output folder of `fascicle run` or `fascicle demo`"});
  if (!fs::is_regular_file(options.run_dir / "viewer" / "manifest.json", ec))
    spdlog::warn("'{}' has no viewer/manifest.json: it is not a fascicle run written with the report "
                 "writer; the page will say so",
                 options.run_dir.string());

  // The page: the built viewer inlined, loading the run from /run/viewer/.
  const fs::path assets = options.viewer_dir.empty() ? find_viewer_assets() : options.viewer_dir;
  std::string css, js;
  if (!assets.empty() && fs::is_regular_file(assets / "viewer.js", ec)) {
    css = read_file(assets / "viewer.css");
    js = read_file(assets / "viewer.js");
  } else {
    spdlog::warn("the viewer assets were not found (build them with `make`, or set FASCICLE_VIEWER_DIR)");
  }
  impl_->page = make_viewer_page("fascicle view — " + options.run_dir.filename().string(), css, js, "");

  Impl* impl = impl_.get();
  impl->server.Get(R"(/(index\.html)?)", [impl](const httplib::Request&, httplib::Response& res) {
    res.set_content(impl->page, "text/html; charset=utf-8");
  });
  impl->server.Get(R"(/run/.*)", [impl](const httplib::Request& req, httplib::Response& res) {
    const ResolvedPath r = resolve_run_path(impl->options.run_dir, req.path);
    res.status = r.status;
    if (r.status == 200) {
      res.set_content(read_file(r.file), content_type(r.file));
      res.set_header("Cache-Control", "no-store");
    } else {
      res.set_content(r.status == 403 ? "forbidden\n" : "not found\n", "text/plain");
    }
  });
  impl->server.set_error_handler([](const httplib::Request&, httplib::Response& res) {
    if (res.body.empty()) res.set_content(std::to_string(res.status) + "\n", "text/plain");
  });

  // httplib's default socket options include SO_REUSEPORT, which would let a second server share a
  // busy port silently; keep SO_REUSEADDR only (a restart may reuse a port in TIME_WAIT).
  impl->server.set_socket_options([](socket_t sock) {
    int yes = 1;
    ::setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, reinterpret_cast<const char*>(&yes), sizeof yes);
  });
  // 127.0.0.1 only: never another interface.
  if (options.port == 0) {
    impl->port = impl->server.bind_to_any_port("127.0.0.1");
    if (impl->port < 0) throw_bad_input("could not bind any port on 127.0.0.1");
  } else {
    if (!impl->server.bind_to_port("127.0.0.1", options.port))
      throw_bad_input("port " + std::to_string(options.port) + " on 127.0.0.1 is in use (or not allowed)",
                      {.suggestion = "choose another with --port N, or --port 0 for any free port"});
    impl->port = options.port;
  }
}

ViewServer::~ViewServer() { stop(); }

int ViewServer::get_port() const { return impl_->port; }

std::string ViewServer::get_url() const { return "http://127.0.0.1:" + std::to_string(impl_->port) + "/"; }

void ViewServer::serve(double max_seconds) {
  std::thread timer;
  if (max_seconds > 0) {
    timer = std::thread([this, max_seconds] {
      std::unique_lock lock(impl_->mutex);
      impl_->stopped.wait_for(lock, std::chrono::duration<double>(max_seconds), [&] { return impl_->stopping; });
      lock.unlock();
      impl_->server.stop();
    });
  }
  impl_->server.listen_after_bind();
  {
    std::lock_guard lock(impl_->mutex);
    impl_->stopping = true;
  }
  impl_->stopped.notify_all();
  if (timer.joinable()) timer.join();
}

void ViewServer::stop() {
  {
    std::lock_guard lock(impl_->mutex);
    impl_->stopping = true;
  }
  impl_->stopped.notify_all();
  impl_->server.stop();
}

}  // namespace fascicle
