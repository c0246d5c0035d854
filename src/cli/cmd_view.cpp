// fascicle view OUT_DIR [--port N]: serves the browser viewer and the run on 127.0.0.1.
#include "commands.hpp"

#include "fascicle/core/log.hpp"
#include "fascicle/report/view_server.hpp"

#include <cstdio>
#include <memory>

namespace fascicle::cli {
namespace {

struct ViewArgs {
  std::string run_dir;
  int port = 8080;
  double max_seconds = 0.0;
};

void run_view(const ViewArgs& args) {
  ViewServer server({.run_dir = args.run_dir, .viewer_dir = {}, .port = args.port});
  // The URL goes to standard output even with --quiet: it is the command's result.
  std::printf("fascicle view: serving %s at %s (127.0.0.1 only; Ctrl-C stops)\n", args.run_dir.c_str(),
              server.get_url().c_str());
  std::fflush(stdout);
  server.serve(args.max_seconds);
}

}  // namespace

void add_view_commands(CLI::App& app, Invocation& run) {
  auto args = std::make_shared<ViewArgs>();
  CLI::App* cmd = app.add_subcommand("view", "Serve a run's results to a browser (127.0.0.1 only)");
  cmd->add_option("OUT_DIR", args->run_dir, "Output folder of `fascicle run` or `fascicle demo`")->required();
  cmd->add_option("--port", args->port, "TCP port on 127.0.0.1 (0: any free port)")
      ->check(CLI::Range(0, 65535))->capture_default_str();
  cmd->add_option("--max-seconds", args->max_seconds, "Stop serving after this many seconds (0: until Ctrl-C)")
      ->check(CLI::NonNegativeNumber);
  cmd->callback([&run, args] { run.action = [args] { run_view(*args); }; });
}

}  // namespace fascicle::cli
