#pragma once
// Shared by the libFuzzer targets of fuzz/ (docs/reliability.md, "Fuzzing").
//
// The contract every target checks: whatever the bytes, a reader either returns or throws
// terramap::InputError / terramap::ConfigError. Any other exception escapes the target and
// libFuzzer reports it (uncaught exception -> abort) together with the input; so do crashes,
// sanitizer reports, hangs (-timeout) and large allocations (-malloc_limit_mb).
#include <terramap/core/error.hpp>
#include <terramap/core/memory_budget.hpp>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <unistd.h>

namespace terramap::fuzz {

/// The memory budget every target runs under. Small, so that a reader which forgets to check a
/// size against it allocates past libFuzzer's -malloc_limit_mb (512 MiB in scripts/fuzz.sh)
/// and is caught, while the budget check itself is exercised by every oversized header.
inline constexpr std::uint64_t kBudgetBytes = 256ull << 20;

inline void setUp() { setMemoryBudget(kBudgetBytes); }

/// The DEM loaders get less: filling the holes of a grid is linear in its cells (~0.35 s per
/// million in a Release build) but much slower under the sanitizers: a 7.5-million-cell grid,
/// within the full budget, took 16 s, past libFuzzer's -timeout of 10 s. 32 MiB still reaches
/// every path, the budget refusals included.
inline constexpr std::uint64_t kDemBudgetBytes = 32ull << 20;

/// Sets the budget for a scope and restores the previous one.
class BudgetScope {
 public:
  explicit BudgetScope(std::uint64_t bytes) : saved_(memoryBudget()) { setMemoryBudget(bytes); }
  ~BudgetScope() { setMemoryBudget(saved_); }
  BudgetScope(const BudgetScope&) = delete;
  BudgetScope& operator=(const BudgetScope&) = delete;

 private:
  std::uint64_t saved_;
};

/// Most readers take only a path: each input is written to one file per process, reused for
/// every input (a new name per input would litter the file system with millions of files and
/// cost a directory operation per run). /dev/shm when there is one, so no disk is touched.
class ScratchFile {
 public:
  /// `tag` keeps the targets' files apart; `ext` matters to readers that look at it (GDAL).
  ScratchFile(const char* tag, const char* ext) {
    const char* dir = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : std::getenv("TMPDIR");
    path_ = std::string(dir && *dir ? dir : "/tmp") + "/terramap-fuzz-" + tag + "-" + std::to_string(getpid()) + ext;
  }
  ~ScratchFile() { std::remove(path_.c_str()); }
  ScratchFile(const ScratchFile&) = delete;
  ScratchFile& operator=(const ScratchFile&) = delete;

  /// Replaces the file's content. Failing to write is the harness's fault, not the reader's:
  /// abort rather than let the reader see a stale file.
  const std::string& write(const std::uint8_t* data, std::size_t size) {
    std::FILE* f = std::fopen(path_.c_str(), "wb");
    if (!f || (size && std::fwrite(data, 1, size, f) != size) || std::fclose(f) != 0) {
      std::perror(path_.c_str());
      std::abort();
    }
    return path_;
  }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

/// TERRAMAP_FUZZ_VERBOSE=1 prints why each input was refused: to check that seeds load, or
/// what a reproduced input runs into.
inline void noteRefusal(const Error& e) {
  static const bool verbose = std::getenv("TERRAMAP_FUZZ_VERBOSE") != nullptr;
  if (verbose) std::fprintf(stderr, "refused (%s): %s\n", e.kind(), e.what());
}

/// Runs `f`, swallowing only the errors a reader is documented to throw for bad input.
template <class F>
void expectInputErrorsOnly(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    noteRefusal(e);
  } catch (const ConfigError& e) {
    noteRefusal(e);
  }
}

}  // namespace terramap::fuzz
