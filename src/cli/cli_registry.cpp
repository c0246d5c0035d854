// The registry the run commands use: scene built-ins plus the kinds of higher modules.
#include "commands.hpp"

#include "fascicle/scene/registry.hpp"

namespace fascicle::cli {

Registry make_cli_registry() {
  Registry registry = make_default_registry();
  return registry;
}

std::vector<std::string> get_default_writer_names() { return {"paraview", "sto", "csv", "summary"}; }

}  // namespace fascicle::cli
