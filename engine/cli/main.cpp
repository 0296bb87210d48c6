// terramap: command-line front end. Each subcommand is in cmd_<name>.cpp.
#include "command.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/eval/sim_source.hpp>
#include <terramap/pipeline/plugin_loader.hpp>

#include <algorithm>
#include <iostream>
#include <new>


int main(int argc, char** argv) {
  using namespace terramap;
  using namespace terramap::cli;
  sim::registerSimSource();  // `source: {type: sim}` (the pipeline library does not know the simulator)
  CLI::App app{"terramap: parallel layered grid maps for machines that move soil.\n"
               "Exit codes: 0 ok, 1 internal error, 2 usage, 3 config, 4 input, 5 plugin, 6 layer,\n"
               "7 output, 8 validation failed / invalid result."};
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("terramap ") + "0.1.0");
  std::string budget;
  std::vector<std::string> plugin_dirs;
  bool allow_config_plugin_paths = false;
  app.add_option("--plugin-path", plugin_dirs,
                 "folder of plugins to search (repeatable), after a pipeline's own and before TERRAMAP_PLUGIN_PATH");
  app.add_flag("--allow-config-plugin-paths", allow_config_plugin_paths,
               "let a pipeline file's plugin_paths name folders whose libraries are loaded (their code runs: only for "
               "files you trust; docs/reliability.md)");
  app.add_option("--memory-budget", budget,
                 "most memory one map, cloud, DEM or snapshot built from the input may take (e.g. 4G; default: half "
                 "the physical memory, at most 16G, or TERRAMAP_MEMORY_BUDGET)");
  app.fallthrough();  // the option may also follow the subcommand
  return runApp(app, argc, argv, "terramap", [&] {
    if (!budget.empty()) setMemoryBudget(parseByteSize(budget, "--memory-budget"));
    PluginRegistry::addTrustedPaths(plugin_dirs);
    PluginRegistry::allowConfigPluginPaths(allow_config_plugin_paths);
  });
}
