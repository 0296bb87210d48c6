#include <terramap/core/memory_budget.hpp>

#include <terramap/core/error.hpp>

#include <unistd.h>

#include <atomic>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

namespace terramap {

namespace {

constexpr std::uint64_t kGiB = 1024ull * 1024ull * 1024ull;

std::uint64_t defaultBudget() {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  std::uint64_t half = 16 * kGiB;
  if (pages > 0 && page > 0) half = static_cast<std::uint64_t>(pages) / 2 * static_cast<std::uint64_t>(page);
  return std::max<std::uint64_t>(std::min<std::uint64_t>(half, 16 * kGiB), 64ull * 1024 * 1024);
}

std::uint64_t initialBudget() {
  if (const char* env = std::getenv("TERRAMAP_MEMORY_BUDGET"); env && *env)
    return parseByteSize(env, "environment variable TERRAMAP_MEMORY_BUDGET");
  return defaultBudget();
}

std::atomic<std::uint64_t>& budget() {
  static std::atomic<std::uint64_t> b{initialBudget()};
  return b;
}

std::string message(std::uint64_t bytes, const std::string& context, const std::string& detail) {
  return context + ": needs " + formatBytes(bytes) + (detail.empty() ? "" : " (" + detail + ")") +
         ", more than the memory budget of " + formatBytes(memoryBudget()) +
         " (raise it with --memory-budget or TERRAMAP_MEMORY_BUDGET if this is really meant)";
}

}  // namespace

std::uint64_t memoryBudget() { return budget().load(std::memory_order_relaxed); }

void setMemoryBudget(std::uint64_t bytes) {
  if (bytes == 0) throw ConfigError("memory budget: must be > 0 bytes");
  budget().store(bytes, std::memory_order_relaxed);
}

std::string formatBytes(std::uint64_t bytes) {
  if (bytes == std::numeric_limits<std::uint64_t>::max()) return "more than 16 EiB (the size overflows)";
  static const char* units[] = {"bytes", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
  double v = static_cast<double>(bytes);
  int u = 0;
  while (v >= 1024.0 && u < 6) {
    v /= 1024.0;
    ++u;
  }
  char buf[64];
  if (u == 0) std::snprintf(buf, sizeof buf, "%llu bytes", static_cast<unsigned long long>(bytes));
  else std::snprintf(buf, sizeof buf, "%.1f %s", v, units[u]);
  return buf;
}

std::uint64_t parseByteSize(const std::string& text, const std::string& what) {
  auto bad = [&]() -> ConfigError {
    return ConfigError(what + ": '" + text + "' is not a memory size (bytes, or a number with K, M, G or T: '4G')");
  };
  std::size_t pos = 0;
  double v = 0;
  try {
    v = std::stod(text, &pos);
  } catch (const std::exception&) {
    throw bad();
  }
  std::string suffix = text.substr(pos);
  while (!suffix.empty() && std::isspace(static_cast<unsigned char>(suffix.back()))) suffix.pop_back();
  if (!suffix.empty() && (suffix.back() == 'B' || suffix.back() == 'b')) suffix.pop_back();
  if (suffix.size() == 2 && (suffix[1] == 'i' || suffix[1] == 'I')) suffix.pop_back();  // "GiB"
  double scale = 1;
  if (suffix.size() == 1) {
    switch (std::toupper(static_cast<unsigned char>(suffix[0]))) {
      case 'K': scale = 1024.0; break;
      case 'M': scale = 1024.0 * 1024; break;
      case 'G': scale = 1024.0 * 1024 * 1024; break;
      case 'T': scale = 1024.0 * 1024 * 1024 * 1024; break;
      default: throw bad();
    }
  } else if (!suffix.empty()) {
    throw bad();
  }
  const double bytes = v * scale;
  if (!std::isfinite(bytes) || !(bytes >= 1.0) || bytes > 9.0e18) throw bad();
  return static_cast<std::uint64_t>(bytes);
}

std::uint64_t saturatingProduct(std::initializer_list<std::uint64_t> factors) {
  std::uint64_t p = 1;
  for (std::uint64_t f : factors) {
    if (f == 0) return 0;
    if (p > std::numeric_limits<std::uint64_t>::max() / f) return std::numeric_limits<std::uint64_t>::max();
    p *= f;
  }
  return p;
}

void requireInputBudget(std::uint64_t bytes, const std::string& context, const std::string& detail) {
  if (bytes > memoryBudget()) throw InputError(message(bytes, context, detail));
}

void requireConfigBudget(std::uint64_t bytes, const std::string& context, const std::string& detail) {
  if (bytes > memoryBudget()) throw ConfigError(message(bytes, context, detail));
}

}  // namespace terramap
