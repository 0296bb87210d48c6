#pragma once
/// \file
/// Error types for everything a user can cause (bad YAML, bad files, bad plugins, bad layers).
/// Internal invariants use TERRAMAP_CHECK, which is always on (not an assert).
#include <terramap/core/export.hpp>

#include <stdexcept>
#include <string>

namespace terramap {

/// Base of every error terramap throws for user-caused conditions.
/// `kind()` names the class for the CLI's exit-code mapping.
class TERRAMAP_API Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(what) {}
  ~Error() override;
  virtual const char* kind() const noexcept;
};

/// Bad configuration: YAML syntax, unknown/mistyped/out-of-range keys, pipeline inconsistencies.
/// The message carries file:line:col and the key path where known.
class TERRAMAP_API ConfigError : public Error {
 public:
  using Error::Error;
  ~ConfigError() override;
  const char* kind() const noexcept override;
};

/// Bad input data: a malformed point-cloud file, trajectory, snapshot or episode.
/// The message names the file and the byte offset or line.
class TERRAMAP_API InputError : public Error {
 public:
  using Error::Error;
  ~InputError() override;
  const char* kind() const noexcept override;
};

/// A sparse map was asked for a tile it cannot allocate within the memory budget
/// (LayeredMap::mutableTileData): the data arriving needs more of the map than the budget holds.
/// An InputError (exit code 4); kernels that can drop data ask LayeredMap::tryAllocateTile
/// first and count the refusal instead (docs/reliability.md, "Sparse maps' tiles").
class TERRAMAP_API TileBudgetError : public InputError {
 public:
  using InputError::InputError;
  ~TileBudgetError() override;
};

/// A plugin library that cannot be loaded, has the wrong ABI, or threw while running.
class TERRAMAP_API PluginError : public Error {
 public:
  using Error::Error;
  ~PluginError() override;
  const char* kind() const noexcept override;
};

/// A layer that does not exist, exists twice, or is used against its declaration.
class TERRAMAP_API LayerError : public Error {
 public:
  using Error::Error;
  ~LayerError() override;
  const char* kind() const noexcept override;
};

/// Writing an output failed (disk full, permissions, GDAL driver error).
class TERRAMAP_API OutputError : public Error {
 public:
  using Error::Error;
  ~OutputError() override;
  const char* kind() const noexcept override;
};

/// Thrown by TERRAMAP_CHECK: a bug in terramap or a plugin, not a user error.
class TERRAMAP_API InternalError : public std::logic_error {
 public:
  using std::logic_error::logic_error;
  ~InternalError() override;
};

namespace detail {
[[noreturn]] TERRAMAP_API void checkFailed(const char* expr, const char* file, int line, const std::string& msg);
}  // namespace detail

}  // namespace terramap

/// Always-on invariant check (stays in Release builds). Throws terramap::InternalError.
#define TERRAMAP_CHECK(cond, msg)                                                  \
  do {                                                                             \
    if (!(cond)) ::terramap::detail::checkFailed(#cond, __FILE__, __LINE__, (msg)); \
  } while (0)
