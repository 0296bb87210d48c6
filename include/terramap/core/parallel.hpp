#pragma once
/// \file
/// Tile-parallel loops on an engine-owned TBB arena, with a serial twin.
/// Kernels must write only inside the tile they are given (or into per-tile buffers), so the
/// result is bit-identical for any thread count: there is no reduction order to vary.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <atomic>
#include <exception>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#if defined(__SANITIZE_THREAD__)
#define TERRAMAP_THREAD_SANITIZER 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define TERRAMAP_THREAD_SANITIZER 1
#endif
#endif
#ifndef TERRAMAP_THREAD_SANITIZER
#define TERRAMAP_THREAD_SANITIZER 0
#endif

namespace terramap {

/// Runs tile-parallel loops with a fixed concurrency. Never touches global TBB limits.
///
/// Two backends, the same tasks and the same results (each index is one task whatever runs it):
/// - `Backend::kTbb` (the default): a tbb::task_arena of `threads` slots.
/// - `Backend::kThreads`: every parallel call starts threads() - 1 plain std::threads that take
///   indices from a shared counter next to the calling thread, and joins them. Slower to start
///   (tens of microseconds per call); meant for ThreadSanitizer builds, where it is the default:
///   Debian's TBB is not instrumented, so TSan cannot see the synchronisation inside it and
///   reports races on data handed between TBB's workers that are not there. With std::thread,
///   atomics and joins in our own instrumented code, every happens-before edge is visible.
///
/// Threading: forEach() may be called from several threads at once on one Executor (each call
/// is independent); an exception thrown by f is rethrown on the calling thread after every
/// task of the call has finished or been skipped.
class Executor {
 public:
  enum class Backend { kTbb, kThreads };
  static constexpr Backend kDefaultBackend = TERRAMAP_THREAD_SANITIZER ? Backend::kThreads : Backend::kTbb;

  /// \param threads >= 1 (1 runs everything inline, with no TBB involvement).
  explicit Executor(int threads = 1, Backend backend = kDefaultBackend)
      : threads_(threads < 1 ? 1 : threads), backend_(backend) {
    if (backend_ == Backend::kTbb) arena_ = std::make_unique<tbb::task_arena>(threads_);
  }
  int threads() const { return threads_; }
  Backend backend() const { return backend_; }
  /// The TBB arena. \throws std::logic_error for the kThreads backend, which has none.
  tbb::task_arena& arena() const;

  /// Calls f(i) for i in [0, n): in parallel (each index one task) or serially when
  /// threads() == 1.
  template <class F>
  void forEach(int n, F&& f) const {
    if (threads_ == 1 || n <= 1) {
      for (int i = 0; i < n; ++i) f(i);
      return;
    }
    if (backend_ == Backend::kThreads) {
      forEachOnThreads(n, f);
      return;
    }
    arena_->execute([&] {
      tbb::parallel_for(tbb::blocked_range<int>(0, n, 1), [&](const tbb::blocked_range<int>& r) {
        for (int i = r.begin(); i != r.end(); ++i) f(i);
      });
    });
  }

  /// Inside a task of forEach(): the slot of the thread running it, in [0, threads()), distinct
  /// among the threads running tasks of one call at the same time (per-slot scratch buffers).
  /// Outside any task: 0 for the kThreads backend's callers; TBB's index otherwise (-1 outside
  /// an arena, as tbb::this_task_arena::current_thread_index()).
  static int currentSlot() {
    const int s = threadSlot();
    return s >= 0 ? s : tbb::this_task_arena::current_thread_index();
  }

 private:
  // The slot of a thread running kThreads tasks, -1 on any other thread.
  static int& threadSlot() {
    static thread_local int slot = -1;
    return slot;
  }
  struct SlotScope {
    int saved;
    explicit SlotScope(int s) : saved(threadSlot()) { threadSlot() = s; }
    ~SlotScope() { threadSlot() = saved; }
  };

  template <class F>
  void forEachOnThreads(int n, F& f) const {
    std::atomic<int> next{0};
    std::atomic<bool> failed{false};
    std::exception_ptr error;
    std::mutex error_mu;
    auto work = [&](int slot) {
      SlotScope scope(slot);
      for (int i = next.fetch_add(1); i < n && !failed.load(); i = next.fetch_add(1)) {
        try {
          f(i);
        } catch (...) {
          std::lock_guard<std::mutex> lk(error_mu);
          if (!error) error = std::current_exception();
          failed = true;
        }
      }
    };
    const int helpers = (threads_ < n ? threads_ : n) - 1;
    std::vector<std::thread> pool;
    pool.reserve(static_cast<std::size_t>(helpers));
    for (int k = 1; k <= helpers; ++k) pool.emplace_back(work, k);
    work(0);
    for (auto& t : pool) t.join();
    if (error) std::rethrow_exception(error);
  }

  int threads_;
  Backend backend_;
  std::unique_ptr<tbb::task_arena> arena_;
};

inline tbb::task_arena& Executor::arena() const {
  if (!arena_) throw std::logic_error("Executor::arena(): the kThreads backend has no TBB arena");
  return *arena_;
}

/// Serial twin of Executor::forEach: the reference the tests compare against.
template <class F>
void serialForEach(int n, F&& f) {
  for (int i = 0; i < n; ++i) f(i);
}

}  // namespace terramap
