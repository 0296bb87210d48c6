#pragma once
// Subcommands register themselves here so each lives in its own file (cmd_<name>.cpp).
#include <terramap/core/error.hpp>

#include <CLI/CLI.hpp>

#include <algorithm>
#include <iostream>
#include <new>

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

/// The program's commands (each program that includes this header has its own list).
inline std::vector<Command>& registry() {
  static std::vector<Command> r;
  return r;
}
struct Registrar {
  explicit Registrar(Command c) { registry().push_back(std::move(c)); }
};

/// Runs `body` and maps what escapes it to the documented exit code, with one line on stderr
/// prefixed by `prog` (shared by `terramap` and `terramap-soil`).
template <class Body>
int runMapped(const char* prog, Body&& body) {
  const std::string p(prog);
  try {
    return body();
  } catch (const ConfigError& e) {
    std::cerr << p << ": configuration error: " << e.what() << "\n";
    return kConfig;
  } catch (const InputError& e) {
    std::cerr << p << ": input error: " << e.what() << "\n";
    return kInput;
  } catch (const PluginError& e) {
    std::cerr << p << ": plugin error: " << e.what() << "\n";
    return kPlugin;
  } catch (const LayerError& e) {
    std::cerr << p << ": layer error: " << e.what() << "\n";
    return kLayer;
  } catch (const OutputError& e) {
    std::cerr << p << ": output error: " << e.what() << "\n";
    return kOutput;
  } catch (const Error& e) {
    std::cerr << p << ": error: " << e.what() << "\n";
    return kInternal;
  } catch (const std::bad_alloc&) {
    std::cerr << p << ": internal error: out of memory: a size in the input or the configuration passed every "
                      "check (docs/reliability.md) yet could not be allocated; please report it with the input\n";
    return kInternal;
  } catch (const std::exception& e) {
    std::cerr << p << ": internal error: " << e.what() << "\n";
    return kInternal;
  }
}

/// Sets up every registered command (in name order) on `app`, parses argv and runs the chosen
/// command through runMapped(); `before()` runs first inside the mapping (global options).
template <class Before>
int runApp(CLI::App& app, int argc, char** argv, const char* prog, Before&& before) {
  std::function<int()> run;
  auto& cmds = registry();
  std::sort(cmds.begin(), cmds.end(), [](const Command& a, const Command& b) { return a.name < b.name; });
  for (auto& c : cmds) c.setup(app, run);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? kOk : kUsage;
  }
  return runMapped(prog, [&] {
    before();
    return run ? run() : kUsage;
  });
}

}  // namespace terramap::cli
