#pragma once
/// \file
/// Tile-parallel loops on an engine-owned TBB arena, with a serial twin.
/// Kernels must write only inside the tile they are given (or into per-tile buffers), so the
/// result is bit-identical for any thread count: there is no reduction order to vary.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <memory>

namespace terramap {

/// Owns a tbb::task_arena of a fixed concurrency. Never touches global TBB limits.
class Executor {
 public:
  /// \param threads >= 1 (1 runs everything inline, with no TBB involvement).
  explicit Executor(int threads = 1)
      : threads_(threads < 1 ? 1 : threads), arena_(std::make_unique<tbb::task_arena>(threads_)) {}
  int threads() const { return threads_; }
  tbb::task_arena& arena() const { return *arena_; }

  /// Calls f(i) for i in [0, n): in parallel inside the arena (grain 1, each index one task)
  /// or serially when threads() == 1.
  template <class F>
  void forEach(int n, F&& f) const {
    if (threads_ == 1 || n <= 1) {
      for (int i = 0; i < n; ++i) f(i);
      return;
    }
    arena_->execute([&] {
      tbb::parallel_for(tbb::blocked_range<int>(0, n, 1), [&](const tbb::blocked_range<int>& r) {
        for (int i = r.begin(); i != r.end(); ++i) f(i);
      });
    });
  }

 private:
  int threads_;
  std::unique_ptr<tbb::task_arena> arena_;
};

/// Serial twin of Executor::forEach: the reference the tests compare against.
template <class F>
void serialForEach(int n, F&& f) {
  for (int i = 0; i < n; ++i) f(i);
}

}  // namespace terramap
