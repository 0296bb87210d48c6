// What a Foxglove subscriber costs `terramap serve`'s pipeline thread: building one
// foxglove.Grid (cells gathered in Grid order, base64 by GDAL, JSON) and one foxglove.PointCloud
// message, as cmd_serve.cpp does once per frame while a client is subscribed.
//   build/bin/bench_foxglove --benchmark_counters_tabular=true
// Grid arguments: map side (cells), layers; the side is sampled to at most 1024 cells as
// --foxglove-max-grid's default does (5000: a map too big to copy, read at the sampled cells).
// items_per_second = Grid cells (or points) per second.
#include "foxglove_ws.hpp"

#include <benchmark/benchmark.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

using namespace terramap;

namespace {

constexpr int kMaxGrid = 1024;  // --foxglove-max-grid's default

LayeredMap makeMap(int n, int layers) {
  LayeredMap m(Geometry(0.05, Size(n, n)), MapOptions{64, false});
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (int l = 0; l < layers; ++l) {
    const LayerId id = m.addLayer("l" + std::to_string(l), "m");
    for (int t = 0; t < m.tileCount(); ++t) {
      float* d = m.mutableTileData(id, t);
      for (int k = 0; k < 64 * 64; ++k) d[k] = (k % 17 == 0) ? NAN : u(rng);  // some unknown cells
    }
  }
  return m;
}

void BM_FoxgloveGridMessage(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0)), layers = static_cast<int>(state.range(1));
  const LayeredMap m = makeMap(n, layers);
  std::vector<std::string> names;
  for (int l = 0; l < layers; ++l) names.push_back("l" + std::to_string(l));
  const int stride = std::max(1, (n + kMaxGrid - 1) / kMaxGrid);
  const long cells = static_cast<long>((n + stride - 1) / stride) * ((n + stride - 1) / stride);
  std::size_t bytes = 0;
  for (auto _ : state) {
    const std::string msg = cli::foxglove::gridMessage(m, names, stride, 12.5, "map");
    bytes = msg.size();
    benchmark::DoNotOptimize(msg.data());
  }
  state.SetItemsProcessed(state.iterations() * cells);
  state.counters["grid_cells"] = static_cast<double>(cells);
  state.counters["message_MB"] = static_cast<double>(bytes) / 1e6;
}
BENCHMARK(BM_FoxgloveGridMessage)->Args({400, 1})->Args({400, 3})->Args({2000, 1})->Args({2000, 3})->Args({5000, 1})
    ->Unit(benchmark::kMillisecond);

void BM_FoxglovePointCloudMessage(benchmark::State& state) {
  PointCloud c;
  c.stamp = 12.5;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-50.f, 50.f);
  c.points.resize(static_cast<std::size_t>(state.range(0)));
  for (auto& p : c.points) p = {u(rng), u(rng), u(rng) * 0.05f, 0.5f};
  std::size_t bytes = 0;
  for (auto _ : state) {
    const std::string msg = cli::foxglove::pointCloudMessage(c, "map");
    bytes = msg.size();
    benchmark::DoNotOptimize(msg.data());
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
  state.counters["message_MB"] = static_cast<double>(bytes) / 1e6;
}
// About one KITTI HDL-64E frame (120 k points).
BENCHMARK(BM_FoxglovePointCloudMessage)->Arg(120000)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
