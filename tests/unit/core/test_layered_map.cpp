#include <terramap/core/error.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/core/parallel.hpp>

#include "memory_budget_scope.hpp"

#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <chrono>
#include <stdexcept>
#include <thread>
#include <vector>
#include <dlfcn.h>
#include <cmath>
#include <cstring>
#include <random>
#include <set>

using namespace terramap;

namespace {
// Bitwise equality, NaN-aware (NaN payloads compared as bits).
bool sameBits(const Eigen::MatrixXf& a, const Eigen::MatrixXf& b) {
  return a.rows() == b.rows() && a.cols() == b.cols() &&
         std::memcmp(a.data(), b.data(), sizeof(float) * static_cast<size_t>(a.size())) == 0;
}
float valueFor(int i, int j) { return static_cast<float>(i * 1000 + j); }
}  // namespace

TEST(LayeredMap, LayersHaveNamesUnitsAndFill) {
  LayeredMap m(Geometry(0.1, Size(10, 20)), MapOptions{8, false});
  const LayerId e = m.addLayer("elevation", "m");
  const LayerId h = m.addLayer("hits", "count", 0.0f);
  EXPECT_TRUE(std::isnan(m.at(e, Index(3, 4))));
  EXPECT_EQ(m.at(h, Index(3, 4)), 0.0f);
  EXPECT_EQ(m.layerInfo(h).unit, "count");
  EXPECT_THROW(m.addLayer("elevation", "m"), LayerError);
  try {
    m.layerId("elevaton");
    FAIL();
  } catch (const LayerError& err) {
    EXPECT_NE(std::string(err.what()).find("did you mean 'elevation'"), std::string::npos) << err.what();
  }
  EXPECT_THROW(m.at(e, Index(10, 0)), std::out_of_range);
}

TEST(LayeredMap, TilesCoverTheMapExactlyOnce) {
  LayeredMap m(Geometry(0.1, Size(70, 33)), MapOptions{16, false});
  EXPECT_EQ(m.tileRows(), 5);
  EXPECT_EQ(m.tileCols(), 3);
  std::vector<int> covered(70 * 33, 0);
  for (int t = 0; t < m.tileCount(); ++t) {
    const CellRect r = m.tileRect(t);
    for (int i = r.r0; i < r.r0 + r.rows; ++i)
      for (int j = r.c0; j < r.c0 + r.cols; ++j) {
        covered[static_cast<size_t>(i * 33 + j)]++;
        EXPECT_EQ(m.tileOfBuffer(i, j), t);
      }
  }
  for (int c : covered) EXPECT_EQ(c, 1);
}

TEST(LayeredMap, MatrixRoundTripInLogicalOrder) {
  LayeredMap m(Geometry(0.1, Size(19, 23)), MapOptions{8, false});
  const LayerId id = m.addLayer("a", "m");
  Eigen::MatrixXf in(19, 23);
  for (int i = 0; i < 19; ++i)
    for (int j = 0; j < 23; ++j) in(i, j) = valueFor(i, j);
  m.fromMatrix(id, in);
  EXPECT_TRUE(sameBits(m.toMatrix(id), in));
  EXPECT_EQ(m.at(id, Index(5, 7)), valueFor(5, 7));
  EXPECT_THROW(m.fromMatrix(id, Eigen::MatrixXf(3, 3)), LayerError);
}

TEST(LayeredMap, ReadsAndWritesCallerOwnedBuffersOfTheGeometrysSizeOnly) {
  LayeredMap m(Geometry(0.1, Size(9, 5)), MapOptions{8, true});
  const LayerId id = m.addLayer("a", "m", 2.5f);
  std::vector<float> buf(9 * 5, -1.0f);
  m.readLayer(id, buf.data(), 9, 5);  // sparse: nothing allocated, every cell reads the fill
  for (float v : buf) ASSERT_EQ(v, 2.5f);
  for (int i = 0; i < 9; ++i)
    for (int j = 0; j < 5; ++j) buf[static_cast<size_t>(i + j * 9)] = valueFor(i, j);
  m.writeLayer(id, buf.data(), 9, 5);
  EXPECT_EQ(m.at(id, Index(7, 3)), valueFor(7, 3));  // column-major: dst[i + j * rows]
  EXPECT_THROW(m.readLayer(id, buf.data(), 5, 9), LayerError);
  EXPECT_THROW(m.writeLayer(id, buf.data(), 9, 4), LayerError);
  EXPECT_THROW(m.readLayer(7, buf.data(), 9, 5), LayerError);
}

long terramapTestMatrixUser(const LayeredMap& map, LayerId id);  // tests/plugins/matrix_user.cpp

// The matrix-returning convenience must be compiled into each caller (TERRAMAP_LOCAL), never
// exported: a plugin that called an exported copy would free, with its own Eigen allocator, a
// matrix the library allocated with another (the -march=native crash). Nothing in the process
// may export it, not even a library built with default visibility that emits a copy.
TEST(LayeredMap, MatrixConvenienceIsNotExportedByAnyLibrary) {
  LayeredMap m(Geometry(0.1, Size(4, 3)), MapOptions{8, false});
  ASSERT_EQ(terramapTestMatrixUser(m, m.addLayer("a", "m")), 12);  // the library is loaded
  for (const char* sym : {"_ZNK8terramap10LayeredMap8toMatrixEi",
                          "_ZN8terramap10LayeredMap10fromMatrixEiRKN5Eigen6MatrixIfLin1ELin1ELi0ELin1ELin1EEE"})
    EXPECT_EQ(dlsym(RTLD_DEFAULT, sym), nullptr) << sym << " is exported";
  // ... while the buffer functions are (the check above looks in the right place).
  EXPECT_NE(dlsym(RTLD_DEFAULT, "_ZNK8terramap10LayeredMap9readLayerEiPfll"), nullptr);
}

TEST(LayeredMap, MoveKeepsDataUnderTheSamePositionAndResetsNewCells) {
  const Geometry g(1.0, Size(10, 12), Position(0, 0));
  LayeredMap m(g, MapOptions{8, false});
  const LayerId id = m.addLayer("a", "m");
  const LayerId z = m.addLayer("z", "count", 0.0f);
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 12; ++j) {
      m.set(id, Index(i, j), valueFor(i, j));
      m.set(z, Index(i, j), 7.0f);
    }
  // Move by +3 cells in x and -2 in y.
  const MoveResult r = m.move(Position(3.0, -2.0));
  EXPECT_EQ(r.shift_cells.x(), 3);
  EXPECT_EQ(r.shift_cells.y(), -2);
  EXPECT_DOUBLE_EQ(m.geometry().center().x(), 3.0);
  EXPECT_DOUBLE_EQ(m.geometry().center().y(), -2.0);
  // Hand-computed: a physical cell at old index (i, j) now has index (i + 3, j - 2).
  std::set<std::pair<int, int>> fresh;
  for (const CellRect& rect : r.new_regions)
    for (int i = rect.r0; i < rect.r0 + rect.rows; ++i)
      for (int j = rect.c0; j < rect.c0 + rect.cols; ++j) EXPECT_TRUE(fresh.insert({i, j}).second) << "twice";
  int n_new = 0;
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 12; ++j) {
      const int oi = i - 3, oj = j + 2;
      const bool came_in = oi < 0 || oi >= 10 || oj < 0 || oj >= 12;
      EXPECT_EQ(came_in, fresh.count({i, j}) == 1) << i << "," << j;
      if (came_in) {
        ++n_new;
        EXPECT_TRUE(std::isnan(m.at(id, Index(i, j))));
        EXPECT_EQ(m.at(z, Index(i, j)), 0.0f);
      } else {
        EXPECT_EQ(m.at(id, Index(i, j)), valueFor(oi, oj));
        EXPECT_EQ(m.at(z, Index(i, j)), 7.0f);
      }
    }
  EXPECT_EQ(n_new, 10 * 12 - 7 * 10);  // 3 rows x 12 + 7 rows x 2
  // Positions: the value that was at position p before is still at p.
  const auto idx = m.geometry().indexAt(Position(0.5, 0.5));
  ASSERT_TRUE(idx);
  const auto old_idx = g.indexAt(Position(0.5, 0.5));
  ASSERT_TRUE(old_idx);
  EXPECT_EQ(m.at(id, *idx), valueFor(old_idx->x(), old_idx->y()));
}

TEST(LayeredMap, MoveFartherThanTheMapResetsEverything) {
  LayeredMap m(Geometry(1.0, Size(4, 4)), MapOptions{8, false});
  const LayerId id = m.addLayer("a", "m");
  m.fill(id, 1.0f);
  const MoveResult r = m.move(Position(100, 0));
  ASSERT_EQ(r.new_regions.size(), 1u);
  EXPECT_EQ(r.new_regions[0].cells(), 16);
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) EXPECT_TRUE(std::isnan(m.at(id, Index(i, j))));
}

TEST(LayeredMap, SparseAllocatesOnFirstWriteOnly) {
  LayeredMap m(Geometry(0.05, Size(2000, 2000)), MapOptions{64, true});
  const LayerId id = m.addLayer("a", "m");
  EXPECT_EQ(m.allocatedTiles(), 0);
  EXPECT_TRUE(std::isnan(m.at(id, Index(1500, 20))));
  m.set(id, Index(1500, 20), 2.0f);
  EXPECT_EQ(m.allocatedTiles(), 1);
  EXPECT_EQ(m.at(id, Index(1500, 20)), 2.0f);
  // Moving does not allocate the regions that come in.
  m.move(Position(1.0, 0.0));
  EXPECT_LE(m.allocatedTiles(), 1);
}

using BudgetGuard = terramap::test::MemoryBudgetScope;

TEST(LayeredMap, SparseTilesStayWithinTheMemoryBudget) {
  // 160 x 160 cells in tiles of 16: 100 tiles per layer, two layers, 1 KiB a tile; the budget
  // holds 10 tiles. Writes over more tiles than that: the first 10 tiles are allocated, the
  // next write is refused with a TileBudgetError (an InputError) that leaves the map as it was,
  // never std::bad_alloc or a map past its budget.
  LayeredMap m(Geometry(0.1, Size(160, 160)), MapOptions{16, true});
  const LayerId a = m.addLayer("a", "m");
  const LayerId b = m.addLayer("b", "m");
  ASSERT_EQ(m.tileBytes(), 1024u);
  BudgetGuard budget(10 * 1024);
  for (int k = 0; k < 10; ++k) m.set(a, Index(16 * k, 3), static_cast<float>(k));
  EXPECT_EQ(m.allocatedTiles(), 10);
  try {
    m.set(a, Index(5, 40), 1.0f);
    FAIL() << "an 11th tile was allocated";
  } catch (const TileBudgetError& e) {
    EXPECT_NE(std::string(e.what()).find("memory budget"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("layer 'a'"), std::string::npos) << e.what();
  }
  EXPECT_EQ(m.allocatedTiles(), 10);
  EXPECT_TRUE(std::isnan(m.at(a, Index(5, 40))));
  EXPECT_THROW(m.mutableTileData(b, 0), InputError);  // the same budget for every layer
  // Writing into tiles it holds needs nothing more.
  m.set(a, Index(16 * 3 + 2, 7), 9.0f);
  EXPECT_EQ(m.at(a, Index(16 * 3 + 2, 7)), 9.0f);
  EXPECT_EQ(m.at(a, Index(16 * 3, 3)), 3.0f);

  // tryAllocateTile: all or none, and true without allocating when the tiles exist.
  m.fill(a, std::numeric_limits<float>::quiet_NaN());  // frees a's tiles (they read NaN again)
  EXPECT_EQ(m.allocatedTiles(), 0);
  for (int t = 0; t < 9; ++t) ASSERT_TRUE(m.tryAllocateTile(t, {a}));
  EXPECT_EQ(m.allocatedTiles(), 9);
  EXPECT_FALSE(m.tryAllocateTile(50, {a, b}));  // needs 2, 1 left: nothing allocated
  EXPECT_EQ(m.allocatedTiles(), 9);
  EXPECT_FALSE(m.tileAllocated(a, 50));
  EXPECT_TRUE(m.tryAllocateTile(50, {a, a, -1}));  // one tile: a layer named twice, -1 skipped
  EXPECT_EQ(m.allocatedTiles(), 10);
  EXPECT_TRUE(m.tryAllocateTile(3, {a}));  // exists already
  EXPECT_FALSE(m.tryAllocateTile(51, {a}));
  EXPECT_TRUE(std::isnan(m.at(a, Index(16 * 5, 16 * 0))));  // allocated tiles hold the fill
  // A dense map was checked when its layers were added; its tiles are all there.
  LayeredMap dense(Geometry(0.1, Size(32, 32)), MapOptions{16, false});
  const LayerId d = dense.addLayer("d", "m");
  EXPECT_EQ(dense.allocatedTiles(), 4);
  EXPECT_TRUE(dense.tryAllocateTile(3, {d}));
  dense.set(d, Index(31, 31), 1.0f);
}

TEST(LayeredMap, SparseMapMovingAwayFromItsDataFreesTheTilesItLeaves) {
  // A sparse map that moves with a machine frees a tile once move() has reset all of it with
  // no write since: memory follows the data, and the tile budget is not used up by the
  // tiles a long drive once touched. Moves of one cell at a time (a map following a machine)
  // reset one row per move; the tile goes when its 16th row does.
  LayeredMap m(Geometry(0.1, Size(64, 64)), MapOptions{16, true});
  const LayerId a = m.addLayer("a", "m");
  m.set(a, Index(3, 5), 1.0f);  // tile row 0 (logical rows 0..15 are buffer rows 0..15 now)
  ASSERT_EQ(m.allocatedTiles(), 1);
  // Towards -x: logical row 0 (the +x edge) leaves first.
  auto step = [&] { m.move(m.geometry().center() - Position(0.1, 0.0)); };
  for (int k = 0; k < 15; ++k) step();
  EXPECT_EQ(m.allocatedTiles(), 1) << "rows of the tile are still unreset";
  step();
  EXPECT_EQ(m.allocatedTiles(), 0);
  for (int i = 0; i < 64; ++i)
    for (int j = 0; j < 64; ++j) ASSERT_TRUE(std::isnan(m.at(a, Index(i, j))));

  // A write between the resets keeps the tile, and its value.
  LayeredMap w(Geometry(0.1, Size(64, 64)), MapOptions{16, true});
  const LayerId wa = w.addLayer("a", "m");
  w.set(wa, Index(3, 5), 1.0f);  // buffer row 3: tile row 0
  auto stepW = [&] { w.move(w.geometry().center() - Position(0.1, 0.0)); };
  for (int k = 0; k < 8; ++k) stepW();  // buffer rows 0..7 reset (the 1.0 left the map)
  w.set(wa, Index(58, 5), 5.0f);        // logical 58 = buffer row (58 + 8) % 64 = 2, reset before
  for (int k = 0; k < 8; ++k) stepW();  // buffer rows 8..15: every row of the tile reset once
  EXPECT_EQ(w.allocatedTiles(), 1);
  EXPECT_EQ(w.at(wa, Index(50, 5)), 5.0f);  // the same cell, 8 rows on
  // A dense map never frees a tile.
  LayeredMap dense(Geometry(0.1, Size(64, 64)), MapOptions{16, false});
  dense.addLayer("a", "m");
  for (int k = 0; k < 40; ++k) dense.move(dense.geometry().center() - Position(0.1, 0.0));
  EXPECT_EQ(dense.allocatedTiles(), 16);
}

TEST(LayeredMap, SnapshotIsCopyOnWrite) {
  LayeredMap m(Geometry(0.1, Size(64, 64)), MapOptions{16, false});
  const LayerId id = m.addLayer("a", "m");
  m.fill(id, 1.0f);
  const LayeredMap snap = m.snapshot();
  EXPECT_EQ(snap.tileData(id, 3), m.tileData(id, 3));  // shared, not copied
  m.set(id, Index(0, 0), 5.0f);
  EXPECT_EQ(m.at(id, Index(0, 0)), 5.0f);
  EXPECT_EQ(snap.at(id, Index(0, 0)), 1.0f);
  EXPECT_NE(snap.tileData(id, 0), m.tileData(id, 0));  // tile 0 was copied on write
  EXPECT_EQ(snap.tileData(id, 3), m.tileData(id, 3));  // others still shared
}

TEST(LayeredMap, TileKernelIsBitIdenticalAtOneAndTwoThreads) {
  // A kernel with real floating-point work per cell; each tile writes only its own cells.
  auto runKernel = [](int threads, Executor::Backend backend = Executor::kDefaultBackend) {
    LayeredMap m(Geometry(0.04, Size(300, 257), Position(1.3, -0.7)), MapOptions{64, false});
    const LayerId a = m.addLayer("a", "m");
    const LayerId b = m.addLayer("b", "m");
    std::mt19937 rng(42);
    std::normal_distribution<float> n(0.f, 1.f);
    Eigen::MatrixXf in(300, 257);
    for (int i = 0; i < in.rows(); ++i)
      for (int j = 0; j < in.cols(); ++j) in(i, j) = n(rng);
    m.fromMatrix(a, in);
    m.move(Position(2.0, 0.3));  // exercise the ring buffer too
    Executor ex(threads, backend);
    const int T = m.tileSize();
    for (int pass = 0; pass < 3; ++pass)
      ex.forEach(m.tileCount(), [&](int t) {
        const CellRect r = m.tileRect(t);
        const float* s = m.tileData(a, t);
        float* d = m.mutableTileData(b, t);
        for (int i = 0; i < r.rows; ++i)
          for (int j = 0; j < r.cols; ++j) {
            const float v = s[i * T + j];
            d[i * T + j] = std::isnan(v) ? 0.f : d[i * T + j] * 0.5f + std::sin(v) * std::exp(-v * v);
          }
      });
    return m.toMatrix(b);
  };
  const Eigen::MatrixXf one = runKernel(1);
  const Eigen::MatrixXf two = runKernel(2);
  EXPECT_TRUE(sameBits(one, two));
  // And the serial twin gives the same as well.
  EXPECT_TRUE(sameBits(one, runKernel(4)));
  EXPECT_TRUE(sameBits(one, runKernel(2, Executor::Backend::kThreads)));
}

namespace {
// Debian's TBB is not instrumented: under ThreadSanitizer only the std::thread backend means
// anything (parallel.hpp), so the TBB runs are left out there.
std::vector<Executor::Backend> testedBackends() {
  if (TERRAMAP_THREAD_SANITIZER) return {Executor::Backend::kThreads};
  return {Executor::Backend::kTbb, Executor::Backend::kThreads};
}
}  // namespace

TEST(Executor, ForEachVisitsEveryIndexOnce) {
  for (auto backend : testedBackends()) {
    Executor ex(2, backend);
    std::vector<std::atomic<int>> hits(1000);
    ex.forEach(1000, [&](int i) { hits[static_cast<size_t>(i)]++; });
    for (auto& h : hits) EXPECT_EQ(h.load(), 1);
  }
  int n = 0;
  serialForEach(17, [&](int) { ++n; });
  EXPECT_EQ(n, 17);
}

TEST(Executor, SlotsAreDistinctAmongConcurrentTasksOnBothBackends) {
  // Per-slot scratch buffers (lidar_fusion's ray minima) rely on it: two tasks running at once
  // never share a slot, and every slot is in [0, threads). Each task holds its slot until a
  // task on another slot has started too, so both threads take part whatever the scheduling.
  for (auto backend : testedBackends()) {
    Executor ex(2, backend);
    std::array<std::atomic<int>, 2> busy{};
    std::atomic<int> bad{0}, started{0};
    ex.forEach(2, [&](int) {
      const int s = Executor::currentSlot();
      if (s < 0 || s >= 2) {
        ++bad;
        return;
      }
      if (busy[static_cast<size_t>(s)].fetch_add(1) != 0) ++bad;
      ++started;
      const auto t0 = std::chrono::steady_clock::now();
      while (started.load() < 2 && std::chrono::steady_clock::now() - t0 < std::chrono::seconds(5))
        std::this_thread::yield();
      busy[static_cast<size_t>(s)].fetch_sub(1);
    });
    EXPECT_EQ(bad.load(), 0);
    EXPECT_EQ(started.load(), 2);
  }
}

TEST(Executor, ThreadsBackendRethrowsATasksExceptionAfterTheOthersFinish) {
  Executor ex(2, Executor::Backend::kThreads);
  std::atomic<int> finished{0};
  EXPECT_THROW(ex.forEach(64,
                          [&](int i) {
                            if (i == 5) throw std::runtime_error("task 5");
                            ++finished;
                          }),
               std::runtime_error);
  // Still usable, and the thrown call left nothing running behind it.
  const int after = finished.load();
  ex.forEach(8, [&](int) { ++finished; });
  EXPECT_EQ(finished.load(), after + 8);
  EXPECT_THROW(ex.arena(), std::logic_error);
}

TEST(LayeredMap, ManyMovesMatchAPlainShiftedMatrix) {
  // Reference: a plain logical-order matrix shifted by copying; the ring buffer must agree
  // after every move, for moves that wrap the buffer seam in both directions.
  const int R = 45, C = 38;
  LayeredMap m(Geometry(0.5, Size(R, C)), MapOptions{16, false});
  const LayerId id = m.addLayer("a", "m");
  Eigen::MatrixXf ref(R, C);
  for (int i = 0; i < R; ++i)
    for (int j = 0; j < C; ++j) ref(i, j) = valueFor(i, j);
  m.fromMatrix(id, ref);
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> step(-20, 20);
  Position c = m.geometry().center();
  for (int k = 0; k < 60; ++k) {
    const Index s(step(rng), step(rng));
    c += s.cast<double>().matrix() * 0.5;
    m.move(c);
    Eigen::MatrixXf next = Eigen::MatrixXf::Constant(R, C, NAN);
    for (int i = 0; i < R; ++i)
      for (int j = 0; j < C; ++j) {
        const int oi = i - s.x(), oj = j - s.y();
        if (oi >= 0 && oj >= 0 && oi < R && oj < C) next(i, j) = ref(oi, oj);
      }
    ref = next;
    // Write something new into the cells that came in, as a mapper would.
    for (int i = 0; i < R; ++i)
      for (int j = 0; j < C; ++j)
        if (std::isnan(ref(i, j)) && (i + j + k) % 3 == 0) {
          ref(i, j) = static_cast<float>(k * 100000 + i * 100 + j);
          m.set(id, Index(i, j), ref(i, j));
        }
    ASSERT_TRUE(sameBits(m.toMatrix(id), ref)) << "after move " << k;
  }
}
