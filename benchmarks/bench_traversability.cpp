// traversability: one whole-map pass (slope, roughness, step height, traversability) with the
// plugin's default windows (plane 0.3 m, step 0.15 m) on the 400 x 400 map at 5 cm and the
// 2000 x 2000 map at 4 cm of the lidar_fusion benchmarks.
//   build/bin/bench_traversability --benchmark_counters_tabular=true
// Arguments: map cells per side, threads. items_per_second = cells/s.
// Terrain: rolling hills, 2 cm of noise, a 25 cm kerb every 4 m and 5 % unknown cells in
// blobs, the same every run (fixed seed).
#include "traversability.hpp"

#include <terramap/core/layered_map.hpp>
#include <terramap/core/parallel.hpp>

#include <benchmark/benchmark.h>

#include <cmath>
#include <random>

using namespace terramap;
using terramap::plugins::Traversability;
using terramap::plugins::TraversabilityLayers;

namespace {

struct Bench {
  LayeredMap map;
  TraversabilityLayers l;
  Bench(int n, double res) : map(Geometry(res, Size(n, n)), MapOptions{64, false}) {
    l.elevation = map.addLayer("elevation", "m");
    l.slope = map.addLayer("slope", "rad");
    l.roughness = map.addLayer("roughness", "m");
    l.step = map.addLayer("step_height", "m");
    l.traversability = map.addLayer("traversability", "1");
    std::mt19937 rng(17);
    std::normal_distribution<float> noise(0.f, 0.02f);
    std::uniform_real_distribution<float> u(0.f, 1.f);
    Eigen::MatrixXf z(n, n);
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const double x = i * res, y = j * res;
        const double hills = 0.8 * std::sin(0.35 * x) * std::cos(0.25 * y) + 0.05 * x;
        const double kerb = std::fmod(y, 4.0) > 2.0 ? 0.25 : 0.0;
        z(i, j) = static_cast<float>(100.0 + hills + kerb) + noise(rng);
      }
    // Unknown blobs (shadows behind obstacles): 5 % of the cells.
    const int blobs = n * n / 400;
    for (int b = 0; b < blobs; ++b) {
      const int ci = static_cast<int>(u(rng) * n), cj = static_cast<int>(u(rng) * n);
      for (int di = -2; di <= 2; ++di)
        for (int dj = -2; dj <= 2; ++dj) {
          const int i = ci + di, j = cj + dj;
          if (i >= 0 && j >= 0 && i < n && j < n && di * di + dj * dj <= 4) z(i, j) = NAN;
        }
    }
    map.fromMatrix(l.elevation, z);
  }
};

void BM_Traversability(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int threads = static_cast<int>(state.range(1));
  const double res = n <= 400 ? 0.05 : 0.04;
  Bench b(n, res);
  Traversability t;  // the defaults of the plugin's params
  Executor ex(threads);
  Traversability::PassStats st = t.run(b.map, ex, b.l);  // warm the scratch buffers
  for (auto _ : state) {
    st = t.run(b.map, ex, b.l);
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(n) * n);
  state.counters["cells"] = static_cast<double>(n) * n;
  state.counters["cells_fitted"] = static_cast<double>(st.cells_fitted);
  state.counters["plane_window"] = 2 * t.planeHalfWidth(res) + 1;
  state.counters["step_window"] = 2 * t.stepHalfWidth(res) + 1;
  state.counters["threads"] = threads;
}
BENCHMARK(BM_Traversability)
    ->Args({400, 1})
    ->Args({400, 2})
    ->Args({2000, 1})
    ->Args({2000, 2})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
