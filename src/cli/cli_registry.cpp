// The registry the run commands use: scene built-ins plus the kinds of higher modules.
#include "commands.hpp"

#include "fascicle/report/report.hpp"
#include "fascicle/scene/registry.hpp"

namespace fascicle::cli {

Registry make_cli_registry() {
  Registry registry = make_default_registry();
  register_report_writers(registry);
  return registry;
}

std::vector<std::string> get_default_writer_names() { return {"paraview", "sto", "csv", "summary", "report"}; }

}  // namespace fascicle::cli
