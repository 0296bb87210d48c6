// Point-cloud reader throughput on the real recordings: data/ (LAS, PLY) and the KITTI frames at
// $TERRAMAP_KITTI_DIR (data/README.md; skipped without them).
//   build/bin/bench_readers --benchmark_counters_tabular=true
// items_per_second = points decoded per second; bytes_per_second = file bytes per second.
// The first read of each file warms the page cache, so the figures are decoding, not disk;
// wall-clock time (UseRealTime), since a read may wait on the kernel.
// BM_Crc64/piece_kb:0 is the checksum every sealed episode is written and opened through (one
// call over 64 MB: four interleaved streams); piece_kb:32 feeds the same bytes in 32 kB calls,
// each below the streams' threshold: the one-stream rate, in the same run.
#include <terramap/io/readers.hpp>
#include <terramap/io/snapshot.hpp>

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

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

std::string kittiDir() {
  const char* env = std::getenv("TERRAMAP_KITTI_DIR");
  return env && *env ? std::string(env) : std::string(TERRAMAP_KITTI_DIR_DEFAULT);
}

void BM_ReadKittiBin(benchmark::State& state) {
  readLoop(state, kittiDir() + "/000000.bin", [](const std::string& p) { return io::readKittiBin(p).size(); });
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

void BM_Crc64(benchmark::State& state) {
  std::vector<unsigned char> buf(std::size_t{64} << 20);
  std::uint64_t x = 0x9e3779b97f4a7c15ULL;
  for (unsigned char& c : buf) {
    x ^= x << 13, x ^= x >> 7, x ^= x << 17;
    c = static_cast<unsigned char>(x);
  }
  const std::size_t piece = static_cast<std::size_t>(state.range(0)) << 10;
  for (auto _ : state) {
    std::uint64_t crc = 0;
    if (piece == 0) crc = io::crc64(buf.data(), buf.size());
    else
      for (std::size_t at = 0; at < buf.size(); at += piece)
        crc = io::crc64(buf.data() + at, std::min(piece, buf.size() - at), crc);
    benchmark::DoNotOptimize(crc);
  }
  state.SetBytesProcessed(static_cast<std::int64_t>(buf.size()) * state.iterations());
}
BENCHMARK(BM_Crc64)->ArgName("piece_kb")->Arg(0)->Arg(32)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
