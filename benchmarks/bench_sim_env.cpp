// The environment API (sim/env.hpp): building an environment against resetting it, and N
// environments stepped together on the TBB pool.
//   BM_SimEnvBuild/scenario   an Env built and reset (the terrain sampled), per iteration
//   BM_SimEnvReset/scenario   reset() of an Env that ran an episode (the kept terrain copied)
//     scenario 0: configs/scenarios/env_loader_cut.yaml (12 x 8 m at 2 cm);
//     scenario 1: excavator_dig_dump.yaml (16 x 12 m at 2 cm) with the excavator made external.
//   BM_SimVectorEnv/N/lidar/frame_skip   N environments of env_loader_cut, random levers, 2 TBB
//     threads; lidar 0: physics only (no ray cast), 1: the loader's 64-beam LiDAR cast and
//     returned; frame_skip 1: a step is one 1/60 s period (60 Hz control), 6: six (10 Hz).
//     Counters: env_steps_per_s and sim_s_per_wall_s (aggregate over the N environments),
//     MiB_per_env (heap the batch took, divided by N).
// Goal (docs/sim.md): aggregate env_steps_per_s at N = 8 physics-only >= 1.8x that at N = 1
// on 2 cores.
#include <benchmark/benchmark.h>

#include <terramap/sim/env.hpp>

#include <malloc.h>

#include <random>
#include <string>

using namespace terramap;
using namespace terramap::sim;

namespace {

Scenario scenarioOf(int which) {
  if (which == 0) return loadScenario(std::string(TERRAMAP_CONFIG_DIR) + "/scenarios/env_loader_cut.yaml");
  Scenario sc = loadScenario(std::string(TERRAMAP_CONFIG_DIR) + "/scenarios/excavator_dig_dump.yaml");
  sc.machines[0].controller.type = ControllerSpec::Type::External;
  return sc;
}

// Heap in use (small blocks and mmapped ones), MiB: resident memory would miss what the batch
// took from pages an earlier benchmark freed but the process kept.
double heapMiB() {
  const struct mallinfo2 m = mallinfo2();
  return static_cast<double>(m.uordblks + m.hblkhd) / (1024.0 * 1024.0);
}

std::vector<double> randomLevers(std::mt19937_64& rng, std::size_t n) {
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  std::vector<double> a(n);
  for (double& v : a) v = U(rng);
  return a;
}

void BM_SimEnvBuild(benchmark::State& state) {
  const Scenario sc = scenarioOf(static_cast<int>(state.range(0)));
  for (auto _ : state) {
    Env env(sc);
    benchmark::DoNotOptimize(env.reset(1));
  }
}
BENCHMARK(BM_SimEnvBuild)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

void BM_SimEnvReset(benchmark::State& state) {
  const Scenario sc = scenarioOf(static_cast<int>(state.range(0)));
  Env env(sc);
  env.reset(1);
  std::mt19937_64 rng(3);
  for (auto _ : state) {
    state.PauseTiming();
    // An episode's worth of changes to undo: 60 steps of random levers.
    for (int k = 0; k < 60; ++k) {
      const std::vector<double> a = randomLevers(rng, env.actionSize(0));
      env.step(a.data(), a.size());
    }
    state.ResumeTiming();
    benchmark::DoNotOptimize(env.reset(1));
  }
}
BENCHMARK(BM_SimEnvReset)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

void BM_SimVectorEnv(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  VectorEnvOptions o;
  o.env.clouds = state.range(1) != 0;
  o.env.frame_skip = static_cast<int>(state.range(2));
  o.threads = 2;
  const Scenario sc = scenarioOf(0);
  const double before = heapMiB();
  VectorEnv v(sc, n, o);
  v.reset(1);
  // Environment k draws its levers from its own stream: its workload does not depend on N.
  std::vector<std::mt19937_64> rng;
  for (int k = 0; k < n; ++k) rng.emplace_back(7 + k);
  const std::size_t w = v.actionWidth();
  std::vector<double> a(static_cast<std::size_t>(n) * w);
  auto fill = [&] {
    for (int k = 0; k < n; ++k) {
      const auto l = randomLevers(rng[static_cast<std::size_t>(k)], w);
      std::copy(l.begin(), l.end(), a.begin() + static_cast<std::ptrdiff_t>(k * w));
    }
  };
  fill();
  v.step(a.data(), a.size());  // the lazily allocated state (track nodes) counted in the memory
  const double mib_per_env = (heapMiB() - before) / n;
  const int steps = 60 / o.env.frame_skip;  // 1 s of simulated time per environment and iteration
  for (auto _ : state) {
    for (int s = 0; s < steps; ++s) {
      fill();  // a few hundred draws: nothing against a step
      v.step(a.data(), a.size());
    }
  }
  const double env_steps = static_cast<double>(state.iterations()) * steps * n;
  state.counters["env_steps_per_s"] = benchmark::Counter(env_steps, benchmark::Counter::kIsRate);
  state.counters["sim_s_per_wall_s"] =
      benchmark::Counter(env_steps * o.env.frame_skip / sc.observation_hz, benchmark::Counter::kIsRate);
  state.counters["MiB_per_env"] = mib_per_env;
}
BENCHMARK(BM_SimVectorEnv)
    ->ArgsProduct({{1, 2, 8, 32}, {0, 1}, {1}})
    ->Args({1, 0, 6})
    ->Args({8, 0, 6})
    ->ArgNames({"N", "lidar", "frame_skip"})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()  // CPU column: every thread's, so idle or stolen cores show as CPU < 2 x real
    ->UseRealTime()
    ->MinTime(3.0);

}  // namespace

BENCHMARK_MAIN();
