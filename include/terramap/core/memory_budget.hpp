#pragma once
/// \file
/// The memory budget: the most memory one structure built from a file or a configuration may
/// take (a map, a point cloud, a DEM, a snapshot's layers, an episode's datasets). Every count,
/// size or dimension read from outside is checked against what the file can hold and against
/// this budget *before* anything is allocated, so a bogus header gives an error that names the
/// file and the field, never std::bad_alloc (or, on a machine without a memory limit, a host
/// brought down by swapping).
///
/// Default: half of the machine's physical memory, at most 16 GiB (docs/reliability.md). The
/// environment variable TERRAMAP_MEMORY_BUDGET (bytes, or with a K/M/G/T suffix, powers of 1024)
/// overrides it at start-up; setMemoryBudget() overrides both (the CLI's --memory-budget).
/// Thread-safe (an atomic value).
#include <terramap/core/export.hpp>

#include <cstdint>
#include <initializer_list>
#include <string>

namespace terramap {

/// The budget in bytes (> 0).
TERRAMAP_API std::uint64_t memoryBudget();
/// Sets the budget (bytes, > 0). \throws ConfigError on 0.
TERRAMAP_API void setMemoryBudget(std::uint64_t bytes);
/// "1.5 GiB"-style text of a byte count, for messages.
TERRAMAP_API std::string formatBytes(std::uint64_t bytes);
/// Parses "4G", "512M", "1048576", "2.5G" (powers of 1024). \throws ConfigError naming `what`
/// and the text when it is not a positive size.
TERRAMAP_API std::uint64_t parseByteSize(const std::string& text, const std::string& what);

/// The product of `factors`, or UINT64_MAX when it overflows (which no budget admits).
TERRAMAP_API std::uint64_t saturatingProduct(std::initializer_list<std::uint64_t> factors);

/// Throws InputError "<context>: needs <bytes> (<detail>), more than the memory budget ..." when
/// `bytes` exceeds the budget. `context` names the file and the field; `detail` the sizes that
/// gave the bytes (e.g. "100000 x 100000 cells x 4 bytes").
TERRAMAP_API void requireInputBudget(std::uint64_t bytes, const std::string& context, const std::string& detail);
/// The same for a configuration (map size, scenario terrain): throws ConfigError.
TERRAMAP_API void requireConfigBudget(std::uint64_t bytes, const std::string& context, const std::string& detail);

}  // namespace terramap
