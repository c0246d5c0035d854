// fascicle: the command-line tool over libfascicle. Exit codes are documented in docs/cli.md.
#include "commands.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/log.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/io/polydata.hpp"

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <optional>

#if defined(__GLIBC__)
#include <malloc.h>
#endif

int main(int argc, char** argv) {
  using fascicle::ExitCode;
#if defined(__GLIBC__)
  // A frame allocates and frees many buffers of a few MB (sparse factors, meshes, writer
  // strings). glibc's defaults map such blocks with mmap and return freed heap tops to the kernel,
  // so every frame pays for fresh zeroed pages (the VH scene: about 280 k page faults; the same
  // settings as tunables cut a 40-frame run from 167 k to 67 k faults and 0.73 to 0.43 s of system
  // time). Keep blocks up to 32 MiB (the largest threshold every 64-bit glibc accepts) on the heap
  // and trim only above 256 MiB. Setting the trim threshold also freezes glibc's dynamic mmap
  // threshold, so it is set only if the first setting was accepted.
  if (mallopt(M_MMAP_THRESHOLD, 32 << 20) == 1) mallopt(M_TRIM_THRESHOLD, 256 << 20);
#endif
  CLI::App app{"fascicle — anatomically based skeletal-muscle modelling.\n"
               "Exit codes: 0 ok, 1 internal error, 2 usage, 3 bad input, 4 numerical failure."};
  app.set_version_flag("--version", std::string("fascicle ") + FASCICLE_VERSION);
  app.require_subcommand(1);
  int verbose = 0;
  bool quiet_flag = false;
  int threads = 0;
  app.add_flag("-v,--verbose", verbose, "More log output (-vv for trace)");
  app.add_flag("-q,--quiet", quiet_flag, "Errors only; no progress bars");
  app.add_option("--threads", threads, "Worker threads (default: all cores)")
      ->check(CLI::NonNegativeNumber);

  fascicle::cli::Invocation run;
  fascicle::cli::add_mesh_commands(app, run);
  fascicle::cli::add_demo_commands(app, run);
  fascicle::cli::add_run_commands(app, run);
  fascicle::cli::add_muscle_commands(app, run);
  fascicle::cli::add_solid_commands(app, run);
  fascicle::cli::add_fibres_commands(app, run);
  fascicle::cli::add_analyze_commands(app, run);
  fascicle::cli::add_paths_commands(app, run);
  fascicle::cli::add_view_commands(app, run);
  fascicle::cli::add_export_commands(app, run);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : static_cast<int>(ExitCode::usage);
  }

  try {
    fascicle::init_logging(quiet_flag ? -1 : verbose);
    const fascicle::ThreadLimit limit(threads);
    fascicle::use_single_threaded_blas();
    if (!fascicle::use_sequential_vtk_loops())
      spdlog::debug("VTK's parallel loops keep the backend '{}' (VTK_SMP_BACKEND_IN_USE)",
                    std::getenv("VTK_SMP_BACKEND_IN_USE") ? std::getenv("VTK_SMP_BACKEND_IN_USE") : "?");
    if (run.action) run.action();
    return static_cast<int>(ExitCode::ok);
  } catch (const fascicle::Error& e) {
    spdlog::error("{}", e.what());
    return static_cast<int>(e.exit_code());
  } catch (const std::bad_alloc&) {
    spdlog::error("out of memory");
    return static_cast<int>(ExitCode::internal);
  } catch (const std::exception& e) {
    spdlog::error("internal error: {} (please report this with the command line)", e.what());
    return static_cast<int>(ExitCode::internal);
  }
}
