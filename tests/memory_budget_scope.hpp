#pragma once
// Sets the process's memory budget (terramap/core/memory_budget.hpp) for one test and puts the
// old one back, so a test that shrinks it cannot leak the small budget into the next test.
#include <terramap/core/memory_budget.hpp>

#include <cstdint>

namespace terramap::test {

class MemoryBudgetScope {
 public:
  explicit MemoryBudgetScope(std::uint64_t bytes) : old_(memoryBudget()) { setMemoryBudget(bytes); }
  ~MemoryBudgetScope() { setMemoryBudget(old_); }
  MemoryBudgetScope(const MemoryBudgetScope&) = delete;
  MemoryBudgetScope& operator=(const MemoryBudgetScope&) = delete;

 private:
  std::uint64_t old_;
};

}  // namespace terramap::test
