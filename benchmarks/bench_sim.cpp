// Simulator throughput: simulated seconds per wall second (one CTL, 64-beam LiDAR at 10 Hz,
// observations at 60 Hz, 2 threads), over the first 2 s and over 16 s, and LiDAR rays per second.
// BM_SimRealtime/2 is the figure (goal 30x; `terramap sim` on the same file with its
// HDF5 writer within 20 % of it). BM_SimRealtimeDepthCameraImus adds a depth camera and two IMUs;
// BM_SimExcavator is the excavator's dig-and-dump cycle with its depth camera.
#include <benchmark/benchmark.h>

#include <terramap/sim/lidar.hpp>
#include <terramap/sim/excavator.hpp>
#include <terramap/sim/simulator.hpp>

#include <algorithm>
#include <string>

using namespace terramap;
using namespace terramap::sim;

namespace {

// The workload is configs/scenarios/bench_ctl_os1_64.yaml, the file `terramap sim` runs for the
// with-HDF5 comparison; only the duration, the thread count and the overlap are overridden.
Scenario benchScenario(int threads, double duration_s = 2, bool overlap = true) {
  Scenario sc = loadScenario(std::string(TERRAMAP_CONFIG_DIR) + "/scenarios/bench_ctl_os1_64.yaml");
  sc.duration_s = duration_s;
  sc.threads = threads;
  sc.overlap_scans = overlap;
  return sc;
}

// Runs the scenario to its end per iteration (terrain construction is not part of the measured
// loop). Counters: realtime_factor and rays_per_second (the rays of every scan, cast or kept);
// kept_share, the share of them that took the hit kept from their sensor's last scan
// (SensorSpec::reuse_casts); physics_share, the physics' part of
// (physics + LiDAR) wall seconds as Simulator::stats() counts them (with the overlap the two run
// at the same time, so it is not a share of the run); with the overlap only, wait_s (seconds
// next() waited for or computed the physics) and patch_nodes (mean nodes per terrain patch).
void runScenario(benchmark::State& state, const Scenario& sc) {
  double simulated = 0, physics = 0, lidar = 0, wait = 0;
  std::uint64_t rays = 0, rays_kept = 0, patches = 0, patch_nodes = 0;
  for (auto _ : state) {
    state.PauseTiming();
    Simulator sim(sc);
    std::vector<Event> ev;
    state.ResumeTiming();
    while (sim.next(ev)) ev.clear();
    const Simulator::Stats& st = sim.stats();
    simulated += sim.time();
    rays += st.rays;
    rays_kept += st.rays_kept;
    physics += st.physics_wall_s;
    lidar += st.lidar_wall_s;
    wait += st.wait_wall_s;
    patches += st.patches;
    patch_nodes += st.patch_nodes;
  }
  state.counters["realtime_factor"] = benchmark::Counter(simulated, benchmark::Counter::kIsRate);
  state.counters["rays_per_second"] = benchmark::Counter(static_cast<double>(rays), benchmark::Counter::kIsRate);
  state.counters["kept_share"] = rays ? static_cast<double>(rays_kept) / static_cast<double>(rays) : 0.0;
  state.counters["physics_share"] = physics / (physics + lidar);
  state.counters["wait_s"] = wait;
  state.counters["patch_nodes"] = patches ? static_cast<double>(patch_nodes) / static_cast<double>(patches) : 0.0;
}

void BM_SimRealtime(benchmark::State& state) { runScenario(state, benchScenario(static_cast<int>(state.range(0)))); }
BENCHMARK(BM_SimRealtime)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(2);

// The same with `overlap_scans: false`: physics and scans alternate (the order before the
// overlap), for comparisons run back to back on a machine whose speed drifts.
void BM_SimRealtimeSerialOrder(benchmark::State& state) {
  runScenario(state, benchScenario(static_cast<int>(state.range(0)), 2, false));
}
BENCHMARK(BM_SimRealtimeSerialOrder)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(2);

// The same machine over 16 s: past the first seconds it cuts and pushes spoil most of the
// time, so the soil physics weighs about twice as much as in BM_SimRealtime's window.
void BM_SimRealtimeSustained(benchmark::State& state) {
  runScenario(state, benchScenario(static_cast<int>(state.range(0)), 16));
}
BENCHMARK(BM_SimRealtimeSustained)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);
void BM_SimRealtimeSustainedSerialOrder(benchmark::State& state) {
  runScenario(state, benchScenario(static_cast<int>(state.range(0)), 16, false));
}
BENCHMARK(BM_SimRealtimeSustainedSerialOrder)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);

// The same workload plus the depth camera and IMUs: a RealSense D435-class depth camera (424 x 240
// at 15 Hz, the docs/sim.md defaults) on the cab roof looking 35 deg down, and IMUs on the base
// and the blade at 120 Hz. Read against BM_SimRealtime of the same run: the cost of the camera's
// 1.5 M rays/s beside the LiDAR's 6.6 M and of the IMUs.
void BM_SimRealtimeDepthCameraImus(benchmark::State& state) {
  Scenario sc = benchScenario(static_cast<int>(state.range(0)));
  // Parsed from YAML so the camera gets its optical frame as a scenario's camera does.
  const Scenario extra = parseScenario(
      "version: 1\nterrain: {size_m: [4, 4], origin_m: [-2, -2]}\nmachines:\n  - id: x\n    sensors:\n"
      "      - {id: cam, type: depth_camera, offset_m: [0.6, 0, 2.1], rotation_deg: [0, 35, 0]}\n"
      "      - {id: imu_base, type: imu, rate_hz: 120}\n"
      "      - {id: imu_blade, type: imu, link: blade, rate_hz: 120}\n",
      "bench_extra_sensors.yaml");
  for (const SensorSpec& s : extra.machines.front().sensors) sc.machines.front().sensors.push_back(s);
  runScenario(state, sc);
}
BENCHMARK(BM_SimRealtimeDepthCameraImus)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(2);

// The excavator's real-time factor (goal 20x): configs/scenarios/excavator_dig_dump.yaml's excavator alone
// (its 15 Hz depth camera at the D435-class defaults and IMUs on chassis, boom, arm and bucket) over 16 s, one whole
// dig-and-dump cycle; /camera:0 drops the camera (the arm, bucket and soil physics alone).
// /reuse:1 is the default (SensorSpec::reuse_casts: the camera, on the standing excavator's
// undercarriage, re-casts only the rays over terrain that changed since its last frame;
// kept_share counts the rays that did not); /reuse:0 casts every ray of every frame, the cost
// of a camera that moves every frame. /camera:2 mounts the camera on the cab (`link: slew`,
// docs/sim.md "Sensors on links"), whose pose changes from frame to frame while the arm works.
void BM_SimExcavator(benchmark::State& state) {
  Scenario sc = loadScenario(std::string(TERRAMAP_CONFIG_DIR) + "/scenarios/excavator_dig_dump.yaml");
  sc.machines.resize(1);
  sc.duration_s = 16;
  sc.threads = static_cast<int>(state.range(0));
  auto& ss = sc.machines.front().sensors;
  if (state.range(1) == 0)
    ss.erase(std::remove_if(ss.begin(), ss.end(), [](const SensorSpec& s) { return s.castsRays(); }), ss.end());
  if (state.range(1) == 2) {
    // The camera on the cab (`link: slew`, where TERA's sits), at the same place at the start.
    const ExcavatorArm arm(*sc.machines.front().arm);
    for (SensorSpec& s : ss)
      if (s.castsRays()) {
        s.T_base_sensor = arm.T_base_slew(arm.q()).inverse() * s.T_base_sensor;
        s.link = SensorSpec::Link::Slew;
      }
  }
  for (SensorSpec& s : ss) s.reuse_casts = state.range(2) != 0;
  runScenario(state, sc);
}
BENCHMARK(BM_SimExcavator)
    ->Args({1, 1, 1})
    ->Args({2, 1, 1})
    ->Args({1, 1, 0})
    ->Args({2, 1, 0})
    ->Args({1, 0, 1})
    ->Args({2, 0, 1})
    ->Args({2, 2, 1})
    ->ArgNames({"threads", "camera", "reuse"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(1);

// One OS1-64 scanning the same hills from the same pose, scan after scan: /reuse:0 casts every
// ray (the ray caster's speed); /reuse:1 is a parked sensor (SensorSpec::reuse_casts: from the
// third scan on every ray takes its kept hit, so this measures the noise, dropouts and the
// cloud's assembly around the cast). items_per_second counts the rays of the scans.
void BM_SimLidarRays(benchmark::State& state) {
  TerrainSpec ts;
  ts.size_x_m = 30; ts.size_y_m = 30; ts.origin_x_m = -15; ts.origin_y_m = -15; ts.resolution_m = 0.02;
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<double> U(0, 1);
  for (int k = 0; k < 20; ++k) ts.bumps.push_back({-15 + 30 * U(rng), -15 + 30 * U(rng), -0.25 + 0.55 * U(rng), 1 + 3 * U(rng)});
  const TruthTerrain t = buildTerrain(ts);
  SensorSpec ss;
  applyLidarPreset("os1_64", ss);
  ss.reuse_casts = state.range(1) != 0;
  const LidarModel L(ss);
  Executor ex(static_cast<int>(state.range(0)));
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(0, 0, 2.4);
  std::vector<PointXYZI> pts;
  std::uint64_t key = 0;
  for (auto _ : state) {
    L.scan(t, T, ++key, &ex, pts);
    benchmark::DoNotOptimize(pts.data());
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * L.raysPerScan()));
}
BENCHMARK(BM_SimLidarRays)
    ->ArgsProduct({{1, 2}, {0, 1}})
    ->ArgNames({"threads", "reuse"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
