#pragma once
/// \file
/// Error types for everything a user can cause (bad YAML, bad files, bad plugins, bad layers).
/// Internal invariants use TERRAMAP_CHECK, which is always on (not an assert).
#include <stdexcept>
#include <string>

namespace terramap {

/// Base of every error terramap throws for user-caused conditions.
/// `kind()` names the class for the CLI's exit-code mapping.
class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(what) {}
  virtual const char* kind() const noexcept { return "error"; }
};

/// Bad configuration: YAML syntax, unknown/mistyped/out-of-range keys, pipeline inconsistencies.
/// The message carries file:line:col and the key path where known.
class ConfigError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "config"; }
};

/// Bad input data: a malformed point-cloud file, trajectory, snapshot or episode.
/// The message names the file and the byte offset or line.
class InputError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "input"; }
};

/// A plugin library that cannot be loaded, has the wrong ABI, or threw while running.
class PluginError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "plugin"; }
};

/// A layer that does not exist, exists twice, or is used against its declaration.
class LayerError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "layer"; }
};

/// Writing an output failed (disk full, permissions, GDAL driver error).
class OutputError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "output"; }
};

/// Thrown by TERRAMAP_CHECK: a bug in terramap or a plugin, not a user error.
class InternalError : public std::logic_error {
 public:
  using std::logic_error::logic_error;
};

namespace detail {
[[noreturn]] void checkFailed(const char* expr, const char* file, int line, const std::string& msg);
}  // namespace detail

}  // namespace terramap

/// Always-on invariant check (stays in Release builds). Throws terramap::InternalError.
#define TERRAMAP_CHECK(cond, msg)                                                  \
  do {                                                                             \
    if (!(cond)) ::terramap::detail::checkFailed(#cond, __FILE__, __LINE__, (msg)); \
  } while (0)
