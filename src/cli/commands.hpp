// The CLI's subcommands. Each cmd_*.cpp adds its subcommands to the app; the chosen one stores
// its work in `action`, which main() runs after logging and threads are set up.
#pragma once

#include <CLI/CLI.hpp>

#include <functional>
#include <string>
#include <vector>

namespace fascicle {
struct Registry;
}

namespace fascicle::cli {

struct Invocation {
  std::function<void()> action;  // the work of the chosen subcommand; throws fascicle::Error
};

void add_mesh_commands(CLI::App& app, Invocation& run);  // cmd_mesh.cpp
void add_demo_commands(CLI::App& app, Invocation& run);  // cmd_demo.cpp
void add_run_commands(CLI::App& app, Invocation& run);   // cmd_run.cpp
void add_muscle_commands(CLI::App& app, Invocation& run);  // cmd_muscle.cpp
void add_solid_commands(CLI::App& app, Invocation& run);  // cmd_solid.cpp
void add_fibres_commands(CLI::App& app, Invocation& run);  // cmd_fibres.cpp
void add_analyze_commands(CLI::App& app, Invocation& run);  // cmd_analyze.cpp
void add_paths_commands(CLI::App& app, Invocation& run);  // cmd_paths.cpp
void add_view_commands(CLI::App& app, Invocation& run);  // cmd_view.cpp
void add_export_commands(CLI::App& app, Invocation& run);  // cmd_export.cpp

// The registry of `fascicle run` and `fascicle demo` (cli_registry.cpp): the library's built-ins
// plus the kinds of the modules above the scene (e.g. the report writer), and the writers a run
// uses when the scene names none.
Registry make_cli_registry();
std::vector<std::string> get_default_writer_names();


}  // namespace fascicle::cli
