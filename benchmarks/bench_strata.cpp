// octomap_strata: the plugin's work per blade sweep (tree update when the sweep's record
// arrives, voxels re-assigned when its estimate arrives, the strata_next_* layers recomputed on
// the tiles touched, the change layers every change_interval_s of event time and at the end)
// while a machine covers a square site in lanes, and the memory the model
// holds once the site is covered, against the site's area (100 m², 1000 m², 1 ha at 5 cm
// voxels and 5 cm map cells) at 1 and 2 threads.
//
// Workload: lanes 1.6 m apart, blade 1.85 m wide, one sweep per 0.2 m of travel cutting 5 cm of
// bank (the default min_translation_m of blade_sweep), the estimate of each sweep published
// right after it (as soil_pinn does within a few events), events stamped as a machine at
// 0.8 m/s makes them (0.25 s a sweep), then finish(). One benchmark iteration covers the whole
// site once; counters:
//   sweeps_per_s  sweeps processed per second (record + estimate + layers)
//   voxels_per_s  voxels removed (and re-assigned) per second
//   memory_bytes  the model's tree + columns after covering the site (Strata::memoryBytes)
//   tree_nodes    OctoMap nodes after pruning
//   columns       voxel columns cut
#include <benchmark/benchmark.h>

#include <terramap/core/parallel.hpp>

#include <cmath>

#include "octomap_strata.hpp"

using namespace terramap;
using namespace terramap::plugins;

namespace {

struct Site {
  LayeredMap map;
  Executor ex;
  RecordBus bus;
  PluginStats stats;
  ChangeTracker tracker;  // as the engine: the plugin tracks the elevation's tiles
  ProcessContext ctx;
  OctomapStrata plugin;
  Site(double side_m, int threads)
      : map(Geometry(0.05, Size(static_cast<int>(std::lround(side_m / 0.05)) + 40, static_cast<int>(std::lround(side_m / 0.05)) + 40),
                     Position(0.5 * side_m, 0.5 * side_m)),
            MapOptions{}),
        ex(threads),
        ctx(map, ex, bus, stats, "strata") {
    std::map<std::string, ParamValue> p{{"extent_min_m", ParamValue{std::vector<double>{-2, -2, -5}}},
                                         {"extent_max_m", ParamValue{std::vector<double>{side_m + 2, side_m + 2, 5}}}};
    plugin.configure(makeParams("strata", plugin.schema(), p));
    for (const LayerSpec& l : plugin.layers())
      if (l.access == LayerAccess::Create) map.addLayer(l.name, l.unit, l.fill);
    map.addLayer("elevation", "m", 0.0f);
    ctx.setTracker(&tracker);
    plugin.start(ctx);
  }
  void process(double stamp) {
    ctx.setStamp(stamp);
    plugin.process(ctx, Tick{});
    tracker.mark(map);
  }
};

// The sweep at travel distance s along lane `lane` of a site `side` metres wide.
SweepRecord sweepAt(long index, int lane, double s, double side) {
  SweepRecord r;
  r.sweep_index = index;
  r.resolution_m = 0.05;
  const double y0 = 0.8 + 1.6 * lane;
  for (double x = s; x < s + 0.2 - 1e-9; x += 0.05)
    for (double y = y0 - 0.925; y < y0 + 0.925; y += 0.05) {
      if (y < 0 || y > side) continue;
      SweepMaskCell m;
      m.position = {x + 0.025, y + 0.025};
      m.cut = true;
      m.sv_bottom_m = -0.05f;
      r.mask.push_back(m);
      SweepSlice sl;
      sl.valid = true;
      sl.surface_z_m = 0.0;
      r.slices.push_back(sl);
    }
  return r;
}

void BM_StrataCoverSite(benchmark::State& state) {
  const double side = std::sqrt(static_cast<double>(state.range(0)));
  const int threads = static_cast<int>(state.range(1));
  long sweeps = 0;
  double voxels = 0, memory = 0, nodes = 0, columns = 0;
  for (auto _ : state) {
    state.PauseTiming();
    auto site = std::make_unique<Site>(side, threads);
    state.ResumeTiming();
    long index = 0;
    const int lanes = static_cast<int>(std::ceil(side / 1.6));
    for (int lane = 0; lane < lanes; ++lane)
      for (double s = 0; s + 0.2 <= side + 1e-9; s += 0.2) {
        ++index;
        const double t = 0.25 * static_cast<double>(index);  // 0.2 m of travel at 0.8 m/s
        site->bus.publish<SweepRecord>(SweepRecord::kType, t, std::make_shared<const SweepRecord>(sweepAt(index, lane, s, side)));
        site->process(t);
        SoilEstimateRecord e;
        e.sweep_index = index;
        e.T_map_blade1.translation() = Eigen::Vector3d(s + 0.2, 0.8 + 1.6 * lane, 0.0);
        e.w_m = 1.85;
        e.mean = {10e3 + 100.0 * (index % 50), 0.5, 4e3, 0.35, 16e3};
        e.var_total = {4e6, 0.01, 1e6, 0.004, 1e6};
        e.valid = true;
        site->bus.publish<SoilEstimateRecord>(SoilEstimateRecord::kType, t, std::make_shared<const SoilEstimateRecord>(e));
        site->process(t);
      }
    site->plugin.finish(site->ctx);
    sweeps += index;
    state.PauseTiming();
    voxels += site->stats.counters["voxels_removed"];
    memory = static_cast<double>(site->plugin.model().memoryBytes());
    nodes = static_cast<double>(site->plugin.model().nodes());
    columns = static_cast<double>(site->plugin.model().columns());
    site.reset();
    state.ResumeTiming();
  }
  state.counters["sweeps_per_s"] = benchmark::Counter(static_cast<double>(sweeps), benchmark::Counter::kIsRate);
  state.counters["voxels_per_s"] = benchmark::Counter(voxels, benchmark::Counter::kIsRate);
  state.counters["memory_bytes"] = memory;
  state.counters["tree_nodes"] = nodes;
  state.counters["columns"] = columns;
}
BENCHMARK(BM_StrataCoverSite)
    ->ArgNames({"area_m2", "threads"})
    ->Args({100, 1})
    ->Args({100, 2})
    ->Args({1000, 1})
    ->Args({1000, 2})
    ->Args({10000, 1})
    ->Args({10000, 2})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
