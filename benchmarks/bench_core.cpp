// Core engine benchmarks: tile-parallel loops and ring-buffer moves.
//   build/bin/bench_core --benchmark_counters_tabular=true
// Thread count is the last argument of each benchmark; items_per_second = cells/s.
#include <terramap/core/layered_map.hpp>
#include <terramap/core/parallel.hpp>

#include <benchmark/benchmark.h>

#include <cmath>
#include <random>

using namespace terramap;

namespace {

LayeredMap makeMap(int n, int layers) {
  LayeredMap m(Geometry(0.05, Size(n, n)), MapOptions{64, false});
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (int l = 0; l < layers; ++l) {
    const LayerId id = m.addLayer("l" + std::to_string(l), "m");
    for (int t = 0; t < m.tileCount(); ++t) {
      float* d = m.mutableTileData(id, t);
      for (int k = 0; k < 64 * 64; ++k) d[k] = u(rng);
    }
  }
  return m;
}

// A light per-cell update (what variance growth or a mask costs): b = 0.5 b + a^2, NaN-aware.
void BM_CoreTileLoop(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int threads = static_cast<int>(state.range(1));
  LayeredMap m = makeMap(n, 2);
  const LayerId a = 0, b = 1;
  Executor ex(threads);
  const int T = m.tileSize();
  for (auto _ : state) {
    ex.forEach(m.tileCount(), [&](int t) {
      const CellRect r = m.tileRect(t);
      const float* s = m.tileData(a, t);
      float* d = m.mutableTileData(b, t);
      for (int i = 0; i < r.rows; ++i)
        for (int j = 0; j < r.cols; ++j) {
          const float v = s[i * T + j];
          d[i * T + j] = std::isnan(v) ? d[i * T + j] : 0.5f * d[i * T + j] + v * v;
        }
    });
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(n) * n);
  state.counters["threads"] = threads;
}
BENCHMARK(BM_CoreTileLoop)->Args({2000, 1})->Args({2000, 2})->Unit(benchmark::kMillisecond)->UseRealTime();

// A heavier per-cell kernel (transcendentals), where memory bandwidth matters less.
void BM_CoreTileLoopHeavy(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int threads = static_cast<int>(state.range(1));
  LayeredMap m = makeMap(n, 2);
  Executor ex(threads);
  const int T = m.tileSize();
  for (auto _ : state) {
    ex.forEach(m.tileCount(), [&](int t) {
      const CellRect r = m.tileRect(t);
      const float* s = m.tileData(0, t);
      float* d = m.mutableTileData(1, t);
      for (int i = 0; i < r.rows; ++i)
        for (int j = 0; j < r.cols; ++j) d[i * T + j] = std::exp(-s[i * T + j] * s[i * T + j]) * std::sin(s[i * T + j]);
    });
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(n) * n);
  state.counters["threads"] = threads;
}
BENCHMARK(BM_CoreTileLoopHeavy)->Args({2000, 1})->Args({2000, 2})->Unit(benchmark::kMillisecond)->UseRealTime();

// Ring-buffer move of a 2000x2000 map with 7 layers (lidar_fusion's) by k cells diagonally:
// cost is proportional to the cells that come in, not to the map.
void BM_CoreMove(benchmark::State& state) {
  const int k = static_cast<int>(state.range(0));
  LayeredMap m = makeMap(2000, 7);
  double x = 0;
  for (auto _ : state) {
    x += k * 0.05;
    const MoveResult r = m.move(Position(x, x));
    benchmark::DoNotOptimize(r);
  }
  const int64_t per = static_cast<int64_t>(2000) * 2000 - static_cast<int64_t>(2000 - k) * (2000 - k);
  state.SetItemsProcessed(state.iterations() * per);  // cells reset per move
  state.counters["cells_in_per_move"] = static_cast<double>(per);
}
BENCHMARK(BM_CoreMove)->Arg(1)->Arg(10)->Arg(100)->Unit(benchmark::kMicrosecond);

// Snapshot cost (copy-on-write pointers) of the same map.
void BM_CoreSnapshot(benchmark::State& state) {
  LayeredMap m = makeMap(2000, 7);
  for (auto _ : state) {
    LayeredMap s = m.snapshot();
    benchmark::DoNotOptimize(s);
  }
}
BENCHMARK(BM_CoreSnapshot)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
