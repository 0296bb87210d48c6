// Point-cloud reader throughput on the real recordings of ../shared/data (read in place).
//   build/bin/bench_readers --benchmark_counters_tabular=true
// items_per_second = points decoded per second; bytes_per_second = file bytes per second.
// The first read of each file warms the page cache, so the figures are decoding, not disk;
// wall-clock time (UseRealTime), since a read may wait on the kernel.
#include <terramap/io/readers.hpp>

#include <benchmark/benchmark.h>

#include <filesystem>
#include <string>

using namespace terramap;

namespace {

const std::string kData = TERRAMAP_DATA_DIR;

template <class Read>
void readLoop(benchmark::State& state, const std::string& path, Read read) {
  if (!std::filesystem::exists(path)) {
    state.SkipWithError(("missing " + path).c_str());
    return;
  }
  const auto bytes = static_cast<std::int64_t>(std::filesystem::file_size(path));
  std::size_t points = read(path);  // warm the page cache
  for (auto _ : state) {
    points = read(path);
    benchmark::DoNotOptimize(points);
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(points) * state.iterations());
  state.SetBytesProcessed(bytes * state.iterations());
  state.counters["points_per_read"] = static_cast<double>(points);
}

void BM_ReadKittiBin(benchmark::State& state) {
  readLoop(state, kData + "/kitti_hdl64/000000.bin", [](const std::string& p) { return io::readKittiBin(p).size(); });
}
BENCHMARK(BM_ReadKittiBin)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_ReadLas(benchmark::State& state) {
  readLoop(state, kData + "/las_hexbin/hexbin-crop.las", [](const std::string& p) { return io::readLas(p).size(); });
}
BENCHMARK(BM_ReadLas)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_ReadPlyPcl(benchmark::State& state) {
  readLoop(state, kData + "/gicp_pair/source.ply", [](const std::string& p) { return io::readPly(p).size(); });
}
BENCHMARK(BM_ReadPlyPcl)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
