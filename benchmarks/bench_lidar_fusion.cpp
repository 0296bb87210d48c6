// Throughput of lidar_fusion (points/s = input points per second), side by side with
// OctoMap's insertPointCloud and a naive single-threaded per-point loop on the same clouds.
//
//   BM_LidarFusion_<cloud>_<map>_<Cleanup|NoCleanup>/<threads>
//     cloud: Kitti (000000.bin of /work/shared/data/kitti_hdl64, 124,668 points; KITTI data
//            CC BY-NC-SA 3.0) or Synthetic (128 x 1024 spinning LiDAR, seeded);
//     map:   400x400_5cm (20 m) or 2000x2000_4cm (80 m), tiles of 64 cells;
//   BM_LidarFusion_<cloud>_400x400_5cm_NoCleanup_ScalarGates/<threads>: the same with the
//     portable scalar gate loop instead of the AVX2 kernel (LidarFusion::forceScalarGates);
//   BM_LidarFusion_TimeUpdate_<map>/<threads>: the per-event time/variance pass alone;
//   BM_OctoMapInsert_<cloud>_<map>/1: octomap::OcTree::insertPointCloud at the map's
//     resolution, rays clipped at the map's half width (maxrange), single-threaded;
//   BM_NaiveFusion_<cloud>_<map>/1: a plain per-point loop on a row-major array.
// Each LidarFusion iteration fuses the whole cloud into a map that already holds it (steady
// state, as on a vehicle), without advancing time (measured separately by TimeUpdate).
//
// The plugin is a MODULE library (not linkable): this program links its kernel library,
// lidar_fusion_kernels, built with the module's flags.
#include "lidar_fusion.hpp"

#include <terramap/io/readers.hpp>

#include <benchmark/benchmark.h>

#include <octomap/octomap.h>

#include <cmath>
#include <random>

using namespace terramap;
using namespace terramap::plugins;

namespace {

const std::vector<PointXYZI>& kittiCloud() {
  static const std::vector<PointXYZI> pts =
      io::readKittiBin(std::string(TERRAMAP_DATA_DIR) + "/kitti_hdl64/000000.bin");
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
  state.SetItemsProcessed(state.iterations() * static_cast<long>(m.cells) * m.cells);  // cells/s
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
      if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) continue;
      const Eigen::Vector3d ps(p.x, p.y, p.z);
      const double r = ps.norm();
      if (r < c.min_range_m || r > c.max_range_m) continue;
      const Eigen::Vector3d pm = T * ps;
      if (pm.z() - T.translation().z() > c.max_height_above_sensor_m) continue;
      const auto idx = g.indexAt(pm.head<2>());
      if (!idx) continue;
      const size_t k = static_cast<size_t>(idx->x()) * static_cast<size_t>(m.cells) + static_cast<size_t>(idx->y());
      const double sigma = c.range_noise_a_m + c.range_noise_b * r;
      const float vp = float(sigma * sigma), z = float(pm.z());
      if (std::isnan(h[k])) {
        h[k] = z;
        v[k] = vp;
      } else if ((z - h[k]) * (z - h[k]) > k2 * (v[k] + vp)) {
        v[k] += float(c.outlier_variance_m2);
      } else {
        const float s = v[k] + vp;
        h[k] = (h[k] * vp + z * v[k]) / s;
        v[k] = v[k] * vp / s;
      }
      ++fused;
    }
    return fused;
  };
  once();
  for (auto _ : state) benchmark::DoNotOptimize(once());
  state.SetItemsProcessed(state.iterations() * static_cast<long>(pts.size()));
}

void registerAll() {
  for (bool kitti : {true, false}) {
    const std::string cloud = kitti ? "Kitti" : "Synthetic";
    for (const MapSpec& m : kMaps) {
      for (bool cleanup : {false, true}) {
        const std::string name =
            "BM_LidarFusion_" + cloud + "_" + m.name + (cleanup ? "_Cleanup" : "_NoCleanup");
        benchmark::RegisterBenchmark(name.c_str(), [=](benchmark::State& s) { runLidarFusion(s, kitti, m, cleanup); })
            ->Arg(1)
            ->Arg(2)
            ->Unit(benchmark::kMillisecond)
            ->UseRealTime();
      }
      if (m.cells == 400)
        benchmark::RegisterBenchmark(
            ("BM_LidarFusion_" + cloud + "_" + m.name + "_NoCleanup_ScalarGates").c_str(),
            [=](benchmark::State& s) { runLidarFusion(s, kitti, m, false, true); })
            ->Arg(1)
            ->Arg(2)
            ->Unit(benchmark::kMillisecond)
            ->UseRealTime();
      benchmark::RegisterBenchmark(("BM_OctoMapInsert_" + cloud + "_" + m.name).c_str(),
                                   [=](benchmark::State& s) { runOctoMap(s, kitti, m); })
          ->Arg(1)
          ->Unit(benchmark::kMillisecond)
          ->Iterations(m.cells > 1000 ? 1 : 3)
          ->UseRealTime();
      benchmark::RegisterBenchmark(("BM_NaiveFusion_" + cloud + "_" + m.name).c_str(),
                                   [=](benchmark::State& s) { runNaive(s, kitti, m); })
          ->Arg(1)
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime();
    }
  }
  for (const MapSpec& m : kMaps)
    benchmark::RegisterBenchmark((std::string("BM_LidarFusion_TimeUpdate_") + m.name).c_str(),
                                 [=](benchmark::State& s) { runTimeUpdate(s, m); })
        ->Arg(1)
        ->Arg(2)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
}

}  // namespace

int main(int argc, char** argv) {
  registerAll();
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
