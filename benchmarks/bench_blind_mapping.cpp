// Blind mapping benchmarks: the blade_sweep and soil_erosion plugins as deployed (loaded from
// their shared libraries through the plugin ABI, driven through ProcessContext).
//
//   BM_BladeSweep/<res_mm>/<threads>   one swept-volume update of a 1.85 m x 0.76 m blade
//                                      (0.21 m of travel, 10 cm deep, rolled and yawed) on a
//                                      20 m map; items = sweep updates.
//   BM_SoilErosion/<res_mm>/<threads>  one 20-sub-step erosion pass over the ROI around the blade
//                                      (±3 m x ±1.925 m) holding a fresh deposit pile;
//                                      items = ROI cells, plus a passes/s counter.
// Map resets happen with the timer paused. Build the plugins first (ninja blade_sweep soil_erosion).
#include <benchmark/benchmark.h>

#include <terramap/plugin/abi.hpp>
#include <terramap/plugin/records/sweep_record.hpp>

#include <dlfcn.h>

#include <cmath>
#include <memory>
#include <stdexcept>
#include <string>

using namespace terramap;

namespace {

// Loads a plugin library once and keeps it loaded for the program's lifetime.
struct PluginLib {
  void* handle = nullptr;
  Plugin* (*create)() = nullptr;
  void (*destroy)(Plugin*) = nullptr;
  explicit PluginLib(const std::string& name) {
    const std::string path = std::string(TERRAMAP_PLUGIN_DIR) + "/" + name + ".so";
    handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!handle) throw std::runtime_error("cannot load " + path + ": " + dlerror());
    create = reinterpret_cast<Plugin* (*)()>(dlsym(handle, kPluginCreateSymbol));
    destroy = reinterpret_cast<void (*)(Plugin*)>(dlsym(handle, kPluginDestroySymbol));
    if (!create || !destroy) throw std::runtime_error(path + " lacks the plugin symbols");
  }
  std::unique_ptr<Plugin, void (*)(Plugin*)> make(const std::string& instance,
                                                  const std::map<std::string, ParamValue>& params = {}) const {
    std::unique_ptr<Plugin, void (*)(Plugin*)> p(create(), destroy);
    p->configure(makeParams(instance, p->schema(), params));
    return p;
  }
};

const PluginLib& bladeLib() {
  static PluginLib lib("blade_sweep");
  return lib;
}
const PluginLib& erosionLib() {
  static PluginLib lib("soil_erosion");
  return lib;
}

LayeredMap makeMap(double res) {
  const int n = static_cast<int>(std::lround(20.0 / res));
  LayeredMap map(Geometry(res, Size(n, n)), MapOptions{64, false});
  const LayerId h = map.addLayer("elevation", "m");
  map.addLayer("loose", "m", 0.0f);
  map.addLayer("height_sigma", "m");
  Eigen::MatrixXf m(n, n);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const Position p = map.geometry().positionOf(Index(i, j));
      m(i, j) = static_cast<float>(0.04 * std::sin(0.8 * p.x()) + 0.03 * std::cos(1.1 * p.y()));
    }
  map.fromMatrix(h, m);
  return map;
}

BladePose pose(double stamp, double x, double y) {
  BladePose p;
  p.stamp = stamp;
  p.machine_id = "ctl";
  p.T_map_blade.linear() = (Eigen::AngleAxisd(0.15, Eigen::Vector3d::UnitZ()) *
                            Eigen::AngleAxisd(0.03, Eigen::Vector3d::UnitX()) *
                            Eigen::AngleAxisd(-0.17, Eigen::Vector3d::UnitY()))
                               .toRotationMatrix();
  p.T_map_blade.translation() = Eigen::Vector3d(x, y, -0.1);
  return p;
}

// Dirty every tile so copy-on-write costs stay out of the timed region.
void unshare(LayeredMap& map) {
  for (LayerId id = 0; id < map.layerCount(); ++id)
    for (int t = 0; t < map.tileCount(); ++t) map.mutableTileData(id, t);
}

void BM_BladeSweep(benchmark::State& state) {
  const double res = state.range(0) / 1000.0;
  const int threads = static_cast<int>(state.range(1));
  LayeredMap initial = makeMap(res);
  LayeredMap map = initial.snapshot();
  unshare(map);
  Executor ex(threads);
  RecordBus bus;
  PluginStats stats;
  ProcessContext ctx(map, ex, bus, stats, "blade");
  auto blade = bladeLib().make("blade");
  blade->start(ctx);
  const double step = 0.21 / 4;  // four poses per update, the fourth crosses 0.2 m
  double x = -8.0, t = 0.0;
  blade->process(ctx, Event(pose(t, x, 0.0)));
  long updates = 0;
  for (auto _ : state) {
    for (int k = 0; k < 4; ++k) {
      x += step;
      t += 0.02;
      blade->process(ctx, Event(pose(t, x, 0.0)));
    }
    ++updates;
    if (x > 7.0) {  // back to the start on a fresh map (teleport: no sweep)
      state.PauseTiming();
      map = initial.snapshot();
      unshare(map);
      x = -8.0;
      t += 1.0;
      blade->process(ctx, Event(pose(t, x, 0.0)));
      state.ResumeTiming();
    }
  }
  const double sweeps = stats.counters["sweeps"];
  if (std::abs(sweeps - static_cast<double>(updates)) > 0.5)
    state.SkipWithError("pose stream did not produce one sweep per iteration");
  state.SetItemsProcessed(updates);
  state.counters["cells_cut_per_update"] = stats.counters["cells_cut"] / std::max(1.0, sweeps);
  state.counters["map_cells"] = static_cast<double>(map.geometry().cellCount());
}

void BM_SoilErosion(benchmark::State& state) {
  const double res = state.range(0) / 1000.0;
  const int threads = static_cast<int>(state.range(1));
  // A realistic state: push 2 m of soil with the blade, then erode around its last pose.
  LayeredMap map = makeMap(res);
  Executor ex(threads);
  RecordBus bus;
  PluginStats blade_stats, stats;
  ProcessContext bctx(map, ex, bus, blade_stats, "blade");
  ProcessContext ctx(map, ex, bus, stats, "erode");
  auto blade = bladeLib().make("blade");
  blade->start(bctx);
  for (int k = 0; k <= 40; ++k) blade->process(bctx, Event(pose(0.05 * k, -2.0 + 0.05 * k, 0.0)));
  const Record* r = bus.latest(SweepRecord::kType);
  if (!r) {
    state.SkipWithError("no sweep record");
    return;
  }
  const auto rec = std::static_pointer_cast<const SweepRecord>(r->payload);
  const LayeredMap initial = map.snapshot();
  auto erosion = erosionLib().make("erode");  // defaults: 20 sub-steps of 0.1 s, 1 pass
  erosion->start(ctx);
  const Event ev(pose(10.0, 0.0, 0.0));
  long passes = 0;
  for (auto _ : state) {
    state.PauseTiming();
    map = initial.snapshot();
    unshare(map);
    bus.publish<SweepRecord>(SweepRecord::kType, 10.0, rec);  // a new sequence: erosion runs
    state.ResumeTiming();
    erosion->process(ctx, ev);
    ++passes;
  }
  const double roi = stats.counters["roi_cells"] / std::max(1L, passes);
  state.SetItemsProcessed(static_cast<long>(roi * static_cast<double>(passes)));
  state.counters["roi_cells"] = roi;
  state.counters["passes_per_s"] = benchmark::Counter(static_cast<double>(passes), benchmark::Counter::kIsRate);
  state.counters["eroded_m3_per_pass"] = stats.counters["eroded_volume_m3"] / std::max(1L, passes);
}

}  // namespace

BENCHMARK(BM_BladeSweep)->ArgNames({"res_mm", "threads"})->Args({50, 1})->Args({50, 2})->Args({20, 1})->Args({20, 2})->Unit(benchmark::kMicrosecond)->UseRealTime();
BENCHMARK(BM_SoilErosion)->ArgNames({"res_mm", "threads"})->Args({50, 1})->Args({50, 2})->Args({20, 1})->Args({20, 2})->Unit(benchmark::kMicrosecond)->UseRealTime();

BENCHMARK_MAIN();
