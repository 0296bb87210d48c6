#pragma once
// Subcommands register themselves here so each lives in its own file (cmd_<name>.cpp).
#include <CLI/CLI.hpp>

#include <functional>
#include <string>
#include <vector>

namespace terramap::cli {

/// Documented exit codes, one per error class (README "Exit codes").
enum ExitCode : int {
  kOk = 0,
  kInternal = 1,   ///< a bug: InternalError or an unexpected exception
  kUsage = 2,      ///< bad command line
  kConfig = 3,     ///< ConfigError: bad YAML / pipeline / parameters
  kInput = 4,      ///< InputError: malformed input file
  kPlugin = 5,     ///< PluginError: plugin refused or failed
  kLayer = 6,      ///< LayerError
  kOutput = 7,     ///< OutputError: could not write results
  kInvalid = 8,    ///< `validate` found errors / `fee` result invalid
};

/// A subcommand: `setup` adds it to the app and stores a callback in `run`, which returns
/// the exit code. Exceptions escaping `run` are mapped to exit codes by main().
struct Command {
  std::string name;
  std::function<void(CLI::App& app, std::function<int()>& run)> setup;
};

std::vector<Command>& registry();
struct Registrar {
  explicit Registrar(Command c) { registry().push_back(std::move(c)); }
};

}  // namespace terramap::cli
