// Throughput of lidar_fusion, side by side with OctoMap and a naive per-point loop.
//
// Moving sequences (the workload a vehicle has; one iteration = one scan: time advanced, map
// moved with follow_robot, cloud fused; one full pass of the sequence before timing):
//   BM_LidarFusionSeq_<seq>_<map>_<cleanup>/<threads>
//     seq: Kitti (the six KITTI HDL-64E frames at $TERRAMAP_KITTI_DIR, data/README.md; skipped
//          without them) with their ICP poses, played 0..5, 4..1, 0..5, ...; KITTI data CC BY-NC-SA 3.0) or Sim64 (120 scans of
//          a simulated OS1-64 on a CTL driving a random walk over hills, generated at start-up);
//     map: 400x400_5cm (20 m) or 2000x2000_4cm (80 m), tiles of 64 cells;
//     cleanup: NoCleanup, Cleanup4th (every 4th ray, exact walk: the default until 2026-11-28),
//              CleanupAll (every ray, exact walk), CleanupAllCellByCell (every ray, exact walk
//              without its block skipping; 400x400 only), CleanupAllFan (every ray, fan walk:
//              each azimuth bin's rays walked together along its centre line, within half a
//              cell of every ray at 10 m; the default);
//     counters (per second): points_in, points_fused, cells_fused, rays, ray_cells,
//              ray_cells_read (seqCounters below).
//   BM_OctoMapSeq_<seq>_400x400_5cm/1: the same scans into one persistent octomap::OcTree at
//     5 cm, every ray carved up to 10 m (lidar_fusion's max_ray_length_m, the map's half width).
//   BM_NaiveSeq_<seq>_<map>/1: a grid_map-style per-point loop into a scrolling row-major array.
//
// Steady state (one cloud re-fused from the same pose into a map that already holds it: no
// stale cells, warm caches; items = input points):
//   BM_LidarFusionSteady_<cloud>_<map>_<Cleanup|NoCleanup>[_ScalarGates]/<threads>
//     (Cleanup: every 4th ray, exact walk, as when these figures were first taken);
//     cloud: Kitti (000000.bin, 124,668 points) or Synthetic (128 x 1024 spinning LiDAR);
//   BM_LidarFusion_TimeUpdate_<map>/<threads>: the per-event time/variance pass alone after one
//     KITTI cloud (items = cells of the tiles holding known cells, the ones the pass touches);
//   BM_OctoMapFreshTree_<cloud>_<map>/1: insertPointCloud into a new tree per iteration;
//   BM_NaiveSteady_<cloud>_<map>/1: the per-point loop on a fixed array.
//
// The plugin is a MODULE library (not linkable): this program links its kernel library,
// lidar_fusion_kernels, built with the module's flags.
#include "lidar_fusion.hpp"

#include <terramap/io/readers.hpp>
#include <terramap/io/trajectory.hpp>
#include <terramap/sim/simulator.hpp>

#include <benchmark/benchmark.h>

#include <octomap/octomap.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <variant>

using namespace terramap;
using namespace terramap::plugins;

namespace {

/// The KITTI frames' folder: $TERRAMAP_KITTI_DIR, else beside the checkout (data/README.md).
std::string kittiDir() {
  const char* env = std::getenv("TERRAMAP_KITTI_DIR");
  return env && *env ? std::string(env) : std::string(TERRAMAP_KITTI_DIR_DEFAULT);
}

/// True (and the benchmark marked skipped, naming the path) when the KITTI frames are absent.
bool kittiMissing(benchmark::State& state) {
  const std::string probe = kittiDir() + "/000005.bin";
  if (std::filesystem::is_regular_file(probe)) return false;
  state.SkipWithError(("KITTI frames not found: " + probe + " is missing (set TERRAMAP_KITTI_DIR)").c_str());
  return true;
}

const std::vector<PointXYZI>& kittiCloud() {
  static const std::vector<PointXYZI> pts = io::readKittiBin(kittiDir() + "/000000.bin");
  return pts;
}

/// 128 rings x 1024 azimuths, elevation -25..+3 deg, sensor 1.8 m above a gently rolling
/// ground with a few boxes; rays above the horizon that hit nothing are NaN (no return).
const std::vector<PointXYZI>& syntheticCloud() {
  static const std::vector<PointXYZI> pts = [] {
    std::mt19937 rng(1234);
    std::normal_distribution<float> noise(0.0f, 0.02f);
    std::vector<PointXYZI> out;
    out.reserve(128 * 1024);
    for (int r = 0; r < 128; ++r) {
      const double el = (-25.0 + 28.0 * r / 127.0) * M_PI / 180.0;
      for (int c = 0; c < 1024; ++c) {
        const double az = 2.0 * M_PI * c / 1024.0;
        const double dx = std::cos(el) * std::cos(az), dy = std::cos(el) * std::sin(az), dz = std::sin(el);
        double range = 80.0;
        if (dz < -1e-3) range = std::min(range, 1.8 / -dz);
        // Boxes: 2 m tall walls at x = 6 m (|y| < 2) and y = -8 m (|x| < 3).
        if (dx > 1e-6) {
          const double t = 6.0 / dx;
          if (t < range && std::abs(t * dy) < 2.0 && 1.8 + t * dz < 2.0) range = t;
        }
        if (dy < -1e-6) {
          const double t = -8.0 / dy;
          if (t < range && std::abs(t * dx) < 3.0 && 1.8 + t * dz < 2.0) range = t;
        }
        if (range >= 80.0) {
          const float nan = std::numeric_limits<float>::quiet_NaN();
          out.push_back({nan, nan, nan, 0.0f});
          continue;
        }
        const double x = dx * range, y = dy * range;
        const double z = dz * range + 0.05 * std::sin(0.3 * x) * std::cos(0.2 * y);
        out.push_back({float(x) + noise(rng), float(y) + noise(rng), float(z) + noise(rng), 1.0f});
      }
    }
    return out;
  }();
  return pts;
}

struct MapSpec {
  const char* name;
  int cells;
  double res;
};
const MapSpec kMaps[] = {{"400x400_5cm", 400, 0.05}, {"2000x2000_4cm", 2000, 0.04}};

Eigen::Isometry3d sensorPose(bool kitti) {
  // KITTI's HDL-64E is 1.73 m above the road; the synthetic sensor 1.8 m.
  return Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, kitti ? 1.73 : 1.8));
}

void runLidarFusion(benchmark::State& state, bool kitti, MapSpec m, bool cleanup, bool scalar_gates = false) {
  const int threads = static_cast<int>(state.range(0));
  LayeredMap map(Geometry(m.res, Size(m.cells, m.cells)), MapOptions{64, false});
  LidarFusion f;
  LidarFusionConfig c;
  c.enable_visibility_cleanup = cleanup;
  // The cleanup these figures were first taken with (the default until 2026-11-28), so that
  // they stay comparable with the older reference runs (`git log -p BENCHMARKS.md`).
  c.cleanup_walk = CleanupWalk::Exact;
  c.cleanup_ray_stride = 4;
  f.configure(c);
  f.forceScalarGates(scalar_gates);
  f.attach(map);
  Executor ex(threads);
  PointCloud pc;
  pc.T_map_sensor = sensorPose(kitti);
  pc.points = kitti ? kittiCloud() : syntheticCloud();
  FusionStats s = f.fuse(map, ex, pc);  // warm: the map holds the cloud already
  for (auto _ : state) {
    s = f.fuse(map, ex, pc);
    benchmark::DoNotOptimize(s.points_fused);
  }
  state.SetItemsProcessed(state.iterations() * static_cast<long>(pc.points.size()));
  state.counters["points"] = static_cast<double>(pc.points.size());
  state.counters["fused"] = static_cast<double>(s.points_fused);
  state.counters["rays"] = static_cast<double>(s.rays);
  state.counters["ray_cells"] = static_cast<double>(s.ray_cells);
}

void runTimeUpdate(benchmark::State& state, MapSpec m) {
  const int threads = static_cast<int>(state.range(0));
  LayeredMap map(Geometry(m.res, Size(m.cells, m.cells)), MapOptions{64, false});
  LidarFusion f;
  f.configure(LidarFusionConfig{});
  f.attach(map);
  Executor ex(threads);
  PointCloud pc;
  pc.T_map_sensor = sensorPose(true);
  pc.points = kittiCloud();
  f.fuse(map, ex, pc);
  double stamp = 0.0;
  f.advanceTime(map, ex, stamp);
  for (auto _ : state) {
    stamp += 0.1;
    f.advanceTime(map, ex, stamp);
  }
  // The pass touches the tiles that hold known cells (whole tiles), not the map: count those.
  const LayerId time = map.layerId(LidarFusionLayers::kTimeSinceUpdate);
  const int tile_cells = map.tileSize() * map.tileSize();
  long touched = 0;
  for (int t = 0; t < map.tileCount(); ++t) {
    const float* d = map.tileData(time, t);
    if (d && std::any_of(d, d + tile_cells, [](float v) { return !std::isnan(v); })) touched += tile_cells;
  }
  state.SetItemsProcessed(state.iterations() * touched);  // cells of the touched tiles per second
  state.counters["map_cells"] = static_cast<double>(m.cells) * m.cells;
  state.counters["touched_cells"] = static_cast<double>(touched);
}

void runOctoMap(benchmark::State& state, bool kitti, MapSpec m) {
  const std::vector<PointXYZI>& pts = kitti ? kittiCloud() : syntheticCloud();
  octomap::Pointcloud cloud;
  for (const PointXYZI& p : pts)
    if (std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z)) cloud.push_back(p.x, p.y, p.z);
  const Eigen::Vector3d t = sensorPose(kitti).translation();
  const double maxrange = 0.5 * m.cells * m.res;
  for (auto _ : state) {
    octomap::OcTree tree(m.res);
    tree.insertPointCloud(cloud, octomap::point3d(0, 0, 0),
                          octomap::pose6d(float(t.x()), float(t.y()), float(t.z()), 0, 0, 0), maxrange);
    benchmark::DoNotOptimize(tree.size());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<long>(pts.size()));
}

/// The naive loops' gates: finite, range, height above the sensor; the map-frame point and
/// its range when it passes.
inline bool naiveGate(const PointXYZI& p, const Eigen::Isometry3d& T, const LidarFusionConfig& c, Eigen::Vector3d& pm,
                      double& r) {
  if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) return false;
  const Eigen::Vector3d ps(p.x, p.y, p.z);
  r = ps.norm();
  if (r < c.min_range_m || r > c.max_range_m) return false;
  pm = T * ps;
  return pm.z() - T.translation().z() <= c.max_height_above_sensor_m;
}

/// The naive loops' update of one cell (h, v) by one point (z, vp): the plugin's arithmetic
/// without its floor, forgetting or bookkeeping.
inline void naiveFuse(float& h, float& v, float z, float vp, float k2, float outlier_var) {
  if (std::isnan(h)) {
    h = z;
    v = vp;
  } else if ((z - h) * (z - h) > k2 * (v + vp)) {
    v += outlier_var;
  } else {
    const float s = v + vp;
    h = (h * vp + z * v) / s;
    v = v * vp / s;
  }
}

/// The obvious serial implementation: per point, transform, gate, index, fuse into a
/// row-major array. No binning, no tiles, no rays.
void runNaive(benchmark::State& state, bool kitti, MapSpec m) {
  const std::vector<PointXYZI>& pts = kitti ? kittiCloud() : syntheticCloud();
  const Geometry g(m.res, Size(m.cells, m.cells));
  const LidarFusionConfig c;
  const Eigen::Isometry3d T = sensorPose(kitti);
  std::vector<float> h(static_cast<size_t>(g.cellCount()), std::numeric_limits<float>::quiet_NaN());
  std::vector<float> v(h.size(), std::numeric_limits<float>::quiet_NaN());
  const float k2 = float(c.mahalanobis_thresh * c.mahalanobis_thresh);
  auto once = [&] {
    long fused = 0;
    for (const PointXYZI& p : pts) {
      Eigen::Vector3d pm;
      double r;
      if (!naiveGate(p, T, c, pm, r)) continue;
      const auto idx = g.indexAt(pm.head<2>());
      if (!idx) continue;
      const size_t k = static_cast<size_t>(idx->x()) * static_cast<size_t>(m.cells) + static_cast<size_t>(idx->y());
      const double sigma = c.range_noise_a_m + c.range_noise_b * r;
      naiveFuse(h[k], v[k], float(pm.z()), float(sigma * sigma), k2, float(c.outlier_variance_m2));
      ++fused;
    }
    return fused;
  };
  once();
  for (auto _ : state) benchmark::DoNotOptimize(once());
  state.SetItemsProcessed(state.iterations() * static_cast<long>(pts.size()));
}

// ---- moving sequences -------------------------------------------------------------------------
//
// The workload a vehicle has: consecutive scans from a moving sensor into one persistent map
// that follows it, so every cloud meets stale cells, cells it never saw and cells seen from
// elsewhere. One benchmark iteration = one scan (time advanced, map moved, cloud fused).

/// A recorded sequence: clouds with their sensor poses (the benchmarks stamp them 0.1 s apart).
struct Sequence {
  std::vector<PointCloud> clouds;
};

/// The six KITTI frames with their ICP poses (frame 0's sensor frame lifted 1.73 m, so the road
/// is near z = 0), played forward and back (0..5, 4..1, 0..5, ...): real motion, 0.68-0.75 m per
/// frame, over a scene that stays consistent when the sequence turns round.
const Sequence& kittiSequence() {
  static const Sequence seq = [] {
    const std::string dir = kittiDir() + "/";
    const std::vector<Eigen::Isometry3d> T0 =
        io::chainRelativePoses(io::readRelativePoses(dir + "DERIVED_icp_relative_poses.txt"));
    Sequence s;
    for (size_t k = 0; k < T0.size(); ++k) {
      PointCloud pc;
      pc.T_map_sensor = Eigen::Translation3d(0.0, 0.0, 1.73) * T0[k];
      char name[32];
      std::snprintf(name, sizeof name, "%06zu.bin", k);
      pc.points = io::readKittiBin(dir + name);
      s.clouds.push_back(std::move(pc));
    }
    return s;
  }();
  return seq;
}

/// A simulator recording: one CTL under the random-walk controller (its default set-points) over
/// 40 m x 40 m of hills, its 64-beam OS1 LiDAR at 10 Hz on the cab (2.1 m), 120 scans (12 s).
/// Generated once per process (seeded: the same clouds every run), before any benchmark is timed.
const Sequence& simSequence() {
  static const Sequence seq = [] {
    const std::string y = R"(version: 1
seed: 7
duration_s: 12
physics_hz: 240
observation_hz: 60
threads: 2
terrain:
  size_m: [40, 40]
  resolution_m: 0.02
  hills: {count: 30, amplitude_m: [-0.3, 0.4], sigma_m: [1.0, 4.0], seed: 4}
soil: {default: {family: loam, relative_density: 0.5}}
machines:
  - id: ctl1
    pose: {x_m: -8, y_m: 0}
    controller: {type: random_walk}
    sensors:
      - {id: top, type: lidar, preset: os1_64, rate_hz: 10, offset_m: [0.3, 0, 2.1]}
)";
    sim::Simulator sim(sim::parseScenario(y, "bench_lidar_fusion sequence"));
    Sequence s;
    std::vector<Event> ev;
    while (sim.next(ev)) {
      for (Event& e : ev)
        if (auto* pc = std::get_if<PointCloud>(&e)) s.clouds.push_back(std::move(*pc));
      ev.clear();
    }
    return s;
  }();
  return seq;
}

const Sequence& sequence(bool kitti) { return kitti ? kittiSequence() : simSequence(); }

/// Frame k of the ping-pong order 0..n-1, n-2..1, 0..n-1, ...
size_t pingPong(long k, size_t n) {
  if (n < 2) return 0;
  const long period = 2 * static_cast<long>(n) - 2;
  const long r = k % period;
  return static_cast<size_t>(r < static_cast<long>(n) ? r : period - r);
}

enum class Cleanup { None, Every4th, EveryRay, EveryRayCellByCell, EveryRayFan };

/// Counters of a sequence benchmark, all rates (per wall second): points_in (every point of
/// every scan, NaN returns included), points_fused (points that updated a cell), cells_fused
/// (distinct cells those points updated, per scan), rays (rays walked), ray_cells (cells the
/// cleanup's walks span) and ray_cells_read (of those, the cells read: the rest lay in blocks
/// skipped whole); fused_share = points_fused / points_in. items_per_second = points_in.
void seqCounters(benchmark::State& state, const FusionStats& sum) {
  auto rate = [&](const char* name, long v) {
    state.counters[name] = benchmark::Counter(static_cast<double>(v), benchmark::Counter::kIsRate);
  };
  rate("points_in", sum.points_in);
  rate("points_fused", sum.points_fused);
  rate("cells_fused", sum.cells_fused);
  rate("ray_cells", sum.ray_cells);
  rate("ray_cells_read", sum.ray_cells_read);
  rate("rays", sum.rays);
  state.counters["fused_share"] = sum.points_in ? double(sum.points_fused) / double(sum.points_in) : 0.0;
  state.SetItemsProcessed(sum.points_in);
}

void runLidarFusionSeq(benchmark::State& state, bool kitti, MapSpec m, Cleanup cleanup) {
  const Sequence& seq = sequence(kitti);
  const int threads = static_cast<int>(state.range(0));
  const Eigen::Vector3d start = seq.clouds.front().T_map_sensor.translation();
  LayeredMap map(Geometry(m.res, Size(m.cells, m.cells), Position(start.x(), start.y())), MapOptions{64, false});
  LidarFusion f;
  LidarFusionConfig c;
  c.follow_robot = true;
  c.enable_visibility_cleanup = cleanup != Cleanup::None;
  c.cleanup_ray_stride = cleanup == Cleanup::Every4th ? 4 : 1;
  c.cleanup_walk = cleanup == Cleanup::EveryRayFan ? CleanupWalk::Fan : CleanupWalk::Exact;
  f.configure(c);
  f.forceCellByCellWalk(cleanup == Cleanup::EveryRayCellByCell);
  f.attach(map);
  Executor ex(threads);
  long k = 0;
  auto step = [&] {
    const PointCloud& pc = seq.clouds[pingPong(k, seq.clouds.size())];
    f.advanceTime(map, ex, 0.1 * static_cast<double>(k));
    ++k;
    f.followTo(map, pc.T_map_sensor.translation());
    return f.fuse(map, ex, pc);
  };
  // One full pass first: the map holds the scene, as it does a few seconds into a drive.
  for (size_t w = 0; w < seq.clouds.size(); ++w) step();
  FusionStats sum;
  for (auto _ : state) {
    const FusionStats s = step();
    sum.points_in += s.points_in;
    sum.points_fused += s.points_fused;
    sum.cells_fused += s.cells_fused;
    sum.ray_cells += s.ray_cells;
    sum.ray_cells_read += s.ray_cells_read;
    sum.rays += s.rays;
  }
  seqCounters(state, sum);
}

/// OctoMap with the same sequence in one persistent tree at the map's resolution, every ray
/// carved up to the same range limit as lidar_fusion's cleanup walk (max_ray_length_m 10 m;
/// for the 400 x 400 map also its half width). Single-threaded (insertPointCloud is serial).
void runOctoMapSeq(benchmark::State& state, bool kitti, MapSpec m) {
  const Sequence& seq = sequence(kitti);
  // Points in the map frame (OctoMap takes them so with the sensor origin); transformed once,
  // outside the timed loop, which favours OctoMap slightly.
  std::vector<octomap::Pointcloud> clouds(seq.clouds.size());
  for (size_t k = 0; k < seq.clouds.size(); ++k) {
    const Eigen::Isometry3d& T = seq.clouds[k].T_map_sensor;
    for (const PointXYZI& p : seq.clouds[k].points)
      if (std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z)) {
        const Eigen::Vector3d q = T * Eigen::Vector3d(p.x, p.y, p.z);
        clouds[k].push_back(float(q.x()), float(q.y()), float(q.z()));
      }
  }
  const double maxrange = LidarFusionConfig{}.max_ray_length_m;
  octomap::OcTree tree(m.res);
  long k = 0;
  auto step = [&] {
    const size_t i = pingPong(k++, seq.clouds.size());
    const Eigen::Vector3d t = seq.clouds[i].T_map_sensor.translation();
    tree.insertPointCloud(clouds[i], octomap::point3d(float(t.x()), float(t.y()), float(t.z())), maxrange);
    return static_cast<long>(seq.clouds[i].points.size());
  };
  step();  // the tree holds the first scan
  long points = 0;
  for (auto _ : state) points += step();
  state.counters["points_in"] = benchmark::Counter(static_cast<double>(points), benchmark::Counter::kIsRate);
  state.counters["tree_nodes"] = static_cast<double>(tree.size());
  state.SetItemsProcessed(points);
}

/// The grid_map-style CPU floor: per point, transform, gate, index into a row-major array that
/// scrolls with the sensor (a circular buffer as grid_map's move(); cells that scroll in are
/// cleared), fuse. No tiles, no binning, no rays, no time, serial.
void runNaiveSeq(benchmark::State& state, bool kitti, MapSpec m) {
  const Sequence& seq = sequence(kitti);
  const LidarFusionConfig c;
  const int N = m.cells;
  const double res = m.res;
  std::vector<float> h(static_cast<size_t>(N) * N, std::numeric_limits<float>::quiet_NaN());
  std::vector<float> v(h.size(), std::numeric_limits<float>::quiet_NaN());
  const float k2 = float(c.mahalanobis_thresh * c.mahalanobis_thresh);
  // Global integer cell of the map's lower corner; buffer cell of global (gx, gy) =
  // (gx mod N, gy mod N).
  long x0 = 0, y0 = 0;
  bool placed = false;
  auto wrap = [N](long g) { return static_cast<size_t>(((g % N) + N) % N); };
  auto clearRow = [&](long gx) {
    for (int j = 0; j < N; ++j) h[wrap(gx) * N + j] = v[wrap(gx) * N + j] = std::numeric_limits<float>::quiet_NaN();
  };
  auto clearCol = [&](long gy) {
    for (int i = 0; i < N; ++i) h[i * size_t(N) + wrap(gy)] = v[i * size_t(N) + wrap(gy)] = std::numeric_limits<float>::quiet_NaN();
  };
  auto moveTo = [&](double x, double y) {
    const long nx0 = std::lround(x / res) - N / 2, ny0 = std::lround(y / res) - N / 2;
    if (placed) {
      for (long g = x0; g < nx0 && g < x0 + N; ++g) clearRow(g);           // left behind at -x
      for (long g = std::max(nx0 + N, x0); g < x0 + N; ++g) clearRow(g);   // left behind at +x
      for (long g = y0; g < ny0 && g < y0 + N; ++g) clearCol(g);
      for (long g = std::max(ny0 + N, y0); g < y0 + N; ++g) clearCol(g);
    }
    x0 = nx0;
    y0 = ny0;
    placed = true;
  };
  long k = 0;
  auto once = [&] {
    const PointCloud& pc = seq.clouds[pingPong(k++, seq.clouds.size())];
    const Eigen::Isometry3d& T = pc.T_map_sensor;
    moveTo(T.translation().x(), T.translation().y());
    long fused = 0;
    for (const PointXYZI& p : pc.points) {
      Eigen::Vector3d pm;
      double r;
      if (!naiveGate(p, T, c, pm, r)) continue;
      const long gx = static_cast<long>(std::floor(pm.x() / res)), gy = static_cast<long>(std::floor(pm.y() / res));
      if (gx < x0 || gx >= x0 + N || gy < y0 || gy >= y0 + N) continue;
      const size_t q = wrap(gx) * static_cast<size_t>(N) + wrap(gy);
      const double sigma = c.range_noise_a_m + c.range_noise_b * r;
      naiveFuse(h[q], v[q], float(pm.z()), float(sigma * sigma), k2, float(c.outlier_variance_m2));
      ++fused;
    }
    return std::pair<long, long>(static_cast<long>(pc.points.size()), fused);
  };
  for (size_t w = 0; w < seq.clouds.size(); ++w) once();
  FusionStats sum;
  for (auto _ : state) {
    const auto [in, fused] = once();
    sum.points_in += in;
    sum.points_fused += fused;
  }
  state.counters["points_in"] = benchmark::Counter(static_cast<double>(sum.points_in), benchmark::Counter::kIsRate);
  state.counters["points_fused"] = benchmark::Counter(static_cast<double>(sum.points_fused), benchmark::Counter::kIsRate);
  state.SetItemsProcessed(sum.points_in);
}

/// Registers a benchmark in ms of wall time at 1 thread, and at 2 when `two_threads`; one that
/// reads the KITTI frames is skipped without them.
template <class F>
benchmark::internal::Benchmark* reg(const std::string& name, F f, bool two_threads, bool kitti) {
  auto run = [f, kitti](benchmark::State& s) {
    if (kitti && kittiMissing(s)) return;
    f(s);
  };
  benchmark::internal::Benchmark* b = benchmark::RegisterBenchmark(name.c_str(), run)->Arg(1);
  if (two_threads) b->Arg(2);
  return b->Unit(benchmark::kMillisecond)->UseRealTime();
}

void registerSequences() {
  for (bool kitti : {true, false}) {
    const std::string cloud = kitti ? "Kitti" : "Sim64";
    for (const MapSpec& m : kMaps) {
      for (Cleanup cl : {Cleanup::None, Cleanup::Every4th, Cleanup::EveryRay, Cleanup::EveryRayCellByCell,
                         Cleanup::EveryRayFan}) {
        if (cl == Cleanup::EveryRayCellByCell && m.cells != 400) continue;
        const char* suffix = cl == Cleanup::None        ? "_NoCleanup"
                             : cl == Cleanup::Every4th  ? "_Cleanup4th"
                             : cl == Cleanup::EveryRay ? "_CleanupAll"
                             : cl == Cleanup::EveryRayFan ? "_CleanupAllFan"
                                                        : "_CleanupAllCellByCell";
        reg("BM_LidarFusionSeq_" + cloud + "_" + m.name + suffix,
            [=](benchmark::State& s) { runLidarFusionSeq(s, kitti, m, cl); }, true, kitti);
      }
      reg("BM_NaiveSeq_" + cloud + "_" + m.name, [=](benchmark::State& s) { runNaiveSeq(s, kitti, m); }, false, kitti);
      // OctoMap only where its range limit equals the map's half width (10 m): like for like.
      if (m.cells == 400)
        reg("BM_OctoMapSeq_" + cloud + "_" + m.name, [=](benchmark::State& s) { runOctoMapSeq(s, kitti, m); }, false, kitti)
            ->Iterations(10);
    }
  }
}

void registerAll() {
  for (bool kitti : {true, false}) {
    const std::string cloud = kitti ? "Kitti" : "Synthetic";
    for (const MapSpec& m : kMaps) {
      for (bool cleanup : {false, true})
        reg("BM_LidarFusionSteady_" + cloud + "_" + m.name + (cleanup ? "_Cleanup" : "_NoCleanup"),
            [=](benchmark::State& s) { runLidarFusion(s, kitti, m, cleanup); }, true, kitti);
      if (m.cells == 400)
        reg("BM_LidarFusionSteady_" + cloud + "_" + m.name + "_NoCleanup_ScalarGates",
            [=](benchmark::State& s) { runLidarFusion(s, kitti, m, false, true); }, true, kitti);
      reg("BM_OctoMapFreshTree_" + cloud + "_" + m.name, [=](benchmark::State& s) { runOctoMap(s, kitti, m); }, false, kitti)
          ->Iterations(m.cells > 1000 ? 1 : 3);
      reg("BM_NaiveSteady_" + cloud + "_" + m.name, [=](benchmark::State& s) { runNaive(s, kitti, m); }, false, kitti);
    }
  }
  for (const MapSpec& m : kMaps)
    reg(std::string("BM_LidarFusion_TimeUpdate_") + m.name, [=](benchmark::State& s) { runTimeUpdate(s, m); }, true, true);
}

}  // namespace

int main(int argc, char** argv) {
  registerSequences();
  registerAll();
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
