// The simulator's depth camera (SensorSpec::Type::DepthCamera, docs/sim.md "Depth cameras"):
// pixels look where the pinhole says and the points are in the optical frame with depth = z,
// the depth range is on z, the noise grows with depth squared, the machine hides the ground and
// is seen, scans are the same bits at any thread count, the simulator delivers and records the
// clouds, and bad keys are named.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/core/parallel.hpp>
#include <terramap/sim/episode.hpp>
#include <terramap/sim/excavator.hpp>
#include <terramap/sim/lidar.hpp>
#include <terramap/sim/machine_shape.hpp>
#include <terramap/sim/simulator.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/world.hpp>

#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include "sim_test_terrain.hpp"

using namespace terramap;
using namespace terramap::sim;

namespace {

std::string scenarioYaml(const std::string& camera, double duration = 0.5) {
  return "version: 1\nseed: 5\nduration_s: " + std::to_string(duration) +
         "\nthreads: 1\n"
         "terrain: {size_m: [16, 10], origin_m: [-4, -5], resolution_m: 0.02}\n"
         "machines:\n  - id: ctl1\n"
         "    controller: {type: route, start_m: [0, 0], length_m: 4, passes: 1, depth_m: 0.05}\n"
         "    sensors:\n      - {id: cam, type: depth_camera, " +
         camera + "}\n";
}

SensorSpec cameraOf(const std::string& keys) {
  const Scenario sc = parseScenario(scenarioYaml(keys), "s.yaml");
  return sc.machines.at(0).sensors.at(0);
}

}  // namespace

TEST(DepthCamera, PixelsLookWhereThePinholeSaysAndDepthIsTheOpticalZ) {
  // Mast at 2 m, pitched 30 deg down; 64 x 48 pixels, 60 deg field of view, depth 0.3-6 m.
  const SensorSpec ss = cameraOf(
      "width: 64, height: 48, horizontal_fov_deg: 60, depth_range_m: [0.3, 6], noise_abs_m: 0, noise_k_per_m: 0, "
      "keep_dropouts: true, offset_m: [0, 0, 2], rotation_deg: [0, 30, 0]");
  ASSERT_EQ(ss.type, SensorSpec::Type::DepthCamera);
  EXPECT_NEAR(ss.fx, 32.0 / std::tan(30.0 * M_PI / 180), 1e-9);
  EXPECT_EQ(ss.fy, ss.fx);
  EXPECT_EQ(ss.cx, 31.5);
  // The optical frame's z is the body's x (pitched 30 deg down), its x the body's -y, its y the body's -z.
  const Eigen::Matrix3d R = ss.T_base_sensor.linear();
  EXPECT_NEAR(R(0, 2), std::cos(M_PI / 6), 1e-12);
  EXPECT_NEAR(R(2, 2), -std::sin(M_PI / 6), 1e-12);
  EXPECT_NEAR(R(1, 0), -1.0, 1e-12);
  const LidarModel L(ss);
  ASSERT_EQ(L.raysPerScan(), 64u * 48u);
  const TruthTerrain t = test::flatTerrain40m();
  std::vector<PointXYZI> pts;
  L.scan(t, ss.T_base_sensor, 1, nullptr, pts);
  ASSERT_EQ(pts.size(), 64u * 48u);  // organised: one point (or NaN) per pixel, row-major
  int seen = 0, beyond = 0;
  for (int v = 0; v < 48; ++v)
    for (int u = 0; u < 64; ++u) {
      const PointXYZI& p = pts[static_cast<std::size_t>(v) * 64 + u];
      // Where the pixel's ray meets the ground z = 0, analytically.
      const Eigen::Vector3d d_opt((u - ss.cx) / ss.fx, (v - ss.cy) / ss.fy, 1.0);
      const Eigen::Vector3d d_map = R * d_opt;
      const double s = d_map.z() < 0 ? -2.0 / d_map.z() : std::numeric_limits<double>::infinity();  // ground at optical depth s
      if (!(s <= 6.0)) {
        EXPECT_TRUE(std::isnan(p.x)) << u << " " << v;  // farther than the depth range: none
        ++beyond;
        continue;
      }
      ASSERT_FALSE(std::isnan(p.x)) << u << " " << v;
      EXPECT_NEAR(p.z, s, 1e-5 * s) << u << " " << v;  // depth = the optical z
      EXPECT_NEAR(p.x / p.z, d_opt.x(), 1e-5);
      EXPECT_NEAR(p.y / p.z, d_opt.y(), 1e-5);
      const Eigen::Vector3d m = ss.T_base_sensor * Eigen::Vector3d(p.x, p.y, p.z);
      EXPECT_NEAR(m.z(), 0.0, 1e-5);
      ++seen;
    }
  // The vertical field is 2 atan(24 / fy) = 47 deg: the top row looks 6.6 deg down and meets
  // the ground 17 m away, past the 6 m range; the bottom rows see it within range.
  EXPECT_GT(seen, 1000);
  EXPECT_GT(beyond, 100);
}

TEST(DepthCamera, NoiseGrowsWithDepthSquared) {
  // The same scan with and without noise: the rays stop at the same t, so the depth difference
  // of a pixel is its noise. Its spread, binned by depth, follows sigma = a + k z^2.
  const std::string keys = "width: 320, height: 240, horizontal_fov_deg: 80, depth_range_m: [0.3, 10], "
                           "keep_dropouts: true, offset_m: [0, 0, 1.5], rotation_deg: [0, 25, 0], ";
  const SensorSpec noisy = cameraOf(keys + "noise_abs_m: 0.002, noise_k_per_m: 0.004");
  const SensorSpec clean = cameraOf(keys + "noise_abs_m: 0, noise_k_per_m: 0");
  const TruthTerrain t = test::flatTerrain40m();
  std::vector<PointXYZI> a, b;
  LidarModel(noisy).scan(t, noisy.T_base_sensor, 11, nullptr, a);
  LidarModel(clean).scan(t, clean.T_base_sensor, 11, nullptr, b);
  ASSERT_EQ(a.size(), b.size());
  struct Bin { double lo, hi, sum2 = 0; long n = 0; double sigma2 = 0; };
  std::vector<Bin> bins{{1.5, 2.5}, {3.0, 4.0}, {6.0, 8.0}};
  for (std::size_t k = 0; k < a.size(); ++k) {
    if (std::isnan(a[k].z) || std::isnan(b[k].z)) continue;
    const double z = b[k].z, e = static_cast<double>(a[k].z) - z;
    for (Bin& bin : bins)
      if (z >= bin.lo && z < bin.hi) {
        const double s = 0.002 + 0.004 * z * z;
        bin.sum2 += e * e;
        bin.sigma2 += s * s;
        ++bin.n;
      }
  }
  for (const Bin& bin : bins) {
    ASSERT_GT(bin.n, 2000) << bin.lo;
    // Measured RMS over the modelled RMS of the bin: 1 within sampling error (n >= 2000: < 5 %).
    EXPECT_NEAR(std::sqrt(bin.sum2 / bin.sigma2), 1.0, 0.06) << bin.lo;
  }
  // Far points are several times noisier than near ones (a constant sigma would give 1).
  EXPECT_GT(std::sqrt(bins[2].sum2 / bins[2].n) / std::sqrt(bins[0].sum2 / bins[0].n), 5.0);
}

TEST(DepthCamera, TheMachineHidesTheGroundAndIsSeen) {
  // A blade-sized box 2.5 m ahead of a camera looking forward and down: the pixels whose ground
  // point lies in the box's shadow stop on the box; every other pixel is unchanged.
  const SensorSpec ss = cameraOf("width: 160, height: 120, noise_abs_m: 0, noise_k_per_m: 0, keep_dropouts: true, "
                                 "offset_m: [0, 0, 2], rotation_deg: [0, 30, 0]");
  std::vector<PlacedBox> wall;
  Eigen::Isometry3d Tw = Eigen::Isometry3d::Identity();
  Tw.translation() = Eigen::Vector3d(2.6, 0, 0.4);
  const Eigen::Vector3d half(0.1, 0.9, 0.4);
  placeShape({ShapeBox{"blade", ShapeBox::Frame::Base, -half, half}}, Tw, Tw, wall);
  const LidarModel L(ss);
  const TruthTerrain t = test::flatTerrain40m();
  std::vector<PointXYZI> bare, seen;
  L.scan(t, ss.T_base_sensor, 2, nullptr, bare);
  L.scan(t, ss.T_base_sensor, 2, nullptr, seen, &wall);
  ASSERT_EQ(bare.size(), seen.size());
  long on_box = 0, changed = 0;
  for (std::size_t k = 0; k < seen.size(); ++k) {
    if (std::isnan(bare[k].x) && std::isnan(seen[k].x)) continue;
    const Eigen::Vector3d s = ss.T_base_sensor * Eigen::Vector3d(seen[k].x, seen[k].y, seen[k].z);
    const bool box = std::abs(s.x() - 2.6) <= 0.1 + 1e-6 && std::abs(s.y()) <= 0.9 + 1e-6 && s.z() >= -1e-6 &&
                     s.z() <= 0.8 + 1e-6;
    if (box) {
      ++on_box;
      // The ray would have reached the ground beyond the box's front face.
      const Eigen::Vector3d b = ss.T_base_sensor * Eigen::Vector3d(bare[k].x, bare[k].y, bare[k].z);
      EXPECT_TRUE(std::isnan(bare[k].x) || b.x() > 2.5) << k;
      ++changed;
    } else {
      ASSERT_EQ(0, std::memcmp(&bare[k], &seen[k], sizeof(PointXYZI))) << k;
    }
  }
  EXPECT_GT(on_box, 1000);
  EXPECT_EQ(changed, on_box);
}

TEST(DepthCamera, CulledBoxTestsFindTheHitsEveryBoxWouldGive) {
  // The scan tests a pixel's ray only against the boxes whose clipped projection holds the pixel
  // (and whose sphere meets the row's plane). Against a brute force over every box, for a camera
  // on the cab of a CTL whose boxes reach behind and beside it, at several poses: the same hits.
  const TruthTerrain t = test::flatTerrain40m();
  std::vector<PlacedBox> boxes;
  Eigen::Isometry3d base = Eigen::Isometry3d::Identity();
  base.translation() = Eigen::Vector3d(0, 0, 0.0);
  Eigen::Isometry3d blade = Eigen::Isometry3d::Identity();
  blade.translation() = Eigen::Vector3d(1.9, 0, 0.3);
  placeShape(defaultCtlShape(1.6, 1.9, 1.85, 0.76), base, blade, boxes);
  long on_box = 0;
  for (const char* mount : {"offset_m: [0.6, 0, 2.1], rotation_deg: [0, 35, 0]", "offset_m: [0.2, 0.4, 2.2], rotation_deg: [5, 60, 40]",
                            "offset_m: [-0.5, 0, 1.6], rotation_deg: [0, 10, 180]"}) {
    const SensorSpec ss = cameraOf(std::string("width: 96, height: 64, noise_abs_m: 0, noise_k_per_m: 0, keep_dropouts: true, ") + mount);
    const LidarModel L(ss);
    std::vector<PointXYZI> bare, seen;
    L.scan(t, ss.T_base_sensor, 4, nullptr, bare);
    L.scan(t, ss.T_base_sensor, 4, nullptr, seen, &boxes);
    ASSERT_EQ(seen.size(), L.raysPerScan());
    const Eigen::Vector3d o = ss.T_base_sensor.translation();
    for (std::size_t k = 0; k < seen.size(); ++k) {
      const Eigen::Vector3d ds = L.directions()[k];
      const Eigen::Vector3d dm = ss.T_base_sensor.linear() * ds;
      const double t_ground = std::isnan(bare[k].x) ? L.maxRayLength() : Eigen::Vector3d(bare[k].x, bare[k].y, bare[k].z).norm();
      const double t_box = firstBoxHit(boxes, o, dm, ss.min_range_m, t_ground, nullptr);
      if (std::isinf(t_box)) {
        ASSERT_EQ(0, std::memcmp(&bare[k], &seen[k], sizeof(PointXYZI))) << mount << " pixel " << k;
        continue;
      }
      ++on_box;
      const double z = ds.z() * t_box;
      if (z < ss.min_range_m || z > ss.max_range_m) {
        ASSERT_TRUE(std::isnan(seen[k].x)) << mount << " pixel " << k;
      } else {
        ASSERT_NEAR(seen[k].x, ds.x() * t_box, 1e-5) << mount << " pixel " << k;
        ASSERT_NEAR(seen[k].z, ds.z() * t_box, 1e-5) << mount << " pixel " << k;
      }
    }
  }
  EXPECT_GT(on_box, 1000);
}

TEST(DepthCamera, ScansAreTheSameBitsAtAnyThreadCount) {
  const SensorSpec ss = cameraOf("dropout: 0.05, offset_m: [0.2, 0, 2.2], rotation_deg: [3, 25, 10]");
  const LidarModel L(ss);
  const TruthTerrain t = test::flatTerrain40m();
  std::vector<PlacedBox> boxes;
  Eigen::Isometry3d blade = Eigen::Isometry3d::Identity();
  blade.translation() = Eigen::Vector3d(1.9, 0, -0.05);
  placeShape(defaultCtlShape(1.6, 1.9, 1.85, 0.76), Eigen::Isometry3d::Identity(), blade, boxes);
  std::vector<PointXYZI> a, b;
  L.scan(t, ss.T_base_sensor, 3, nullptr, a, &boxes);
  Executor ex(2);
  L.scan(t, ss.T_base_sensor, 3, &ex, b, &boxes);
  ASSERT_EQ(a.size(), b.size());
  ASSERT_GT(a.size(), 50000u);
  for (std::size_t k = 0; k < a.size(); ++k) ASSERT_EQ(0, std::memcmp(&a[k], &b[k], sizeof(PointXYZI))) << k;
}

namespace {

/// Raises (dz > 0) or digs (dz < 0) a round patch of radius r around (x, y) and refreshes the
/// pyramid over it, as the simulator does after its physics.
void reshape(TruthTerrain& t, double x, double y, double r, double dz) {
  const int i0 = static_cast<int>((x - r - t.originX()) / t.resolution()), i1 = static_cast<int>((x + r - t.originX()) / t.resolution()) + 1;
  const int j0 = static_cast<int>((y - r - t.originY()) / t.resolution()), j1 = static_cast<int>((y + r - t.originY()) / t.resolution()) + 1;
  for (int j = j0; j <= j1; ++j)
    for (int i = i0; i <= i1; ++i) {
      const Eigen::Vector2d p = t.nodePosition(i, j);
      const double q = (p - Eigen::Vector2d(x, y)).norm() / r;
      if (q < 1) t.setUndisturbed(i, j, t.height(i, j) + dz * (1 - q * q));
    }
  t.refreshPyramid(i0, j0, i1, j1);
}

bool sameBits(const std::vector<PointXYZI>& a, const std::vector<PointXYZI>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(PointXYZI)) == 0;
}

}  // namespace

TEST(DepthCamera, KeptHitsAreTheHitsOfANewCast) {
  // A camera that keeps its hits (reuse_casts) against one that casts every ray, scan after
  // scan from the same pose while the terrain in and out of view changes: the same clouds, bit
  // for bit, and most rays served from the kept hits once the view holds still.
  SensorSpec ss = cameraOf("dropout: 0.02, offset_m: [0.2, 0, 2.2], rotation_deg: [2, 30, 5]");
  ASSERT_TRUE(ss.reuse_casts);  // the default
  const LidarModel keep(ss);
  ss.reuse_casts = false;
  const LidarModel fresh(ss);
  TerrainSpec ts;
  ts.size_x_m = 24, ts.size_y_m = 20, ts.origin_x_m = -8, ts.origin_y_m = -10, ts.resolution_m = 0.02;
  ts.bumps = {{4, 1, 0.3, 1.5}, {7, -2, -0.2, 2.0}, {2, -1.5, 0.15, 0.7}};
  TruthTerrain t = buildTerrain(ts);
  std::vector<PlacedBox> boxes;
  Eigen::Isometry3d blade = Eigen::Isometry3d::Identity();
  blade.translation() = Eigen::Vector3d(1.9, 0, -0.05);
  placeShape(defaultCtlShape(1.6, 1.9, 1.85, 0.76), Eigen::Isometry3d::Identity(), blade, boxes);
  Executor ex(2);
  Eigen::Isometry3d pose = ss.T_base_sensor;
  std::vector<PointXYZI> a, b, before;
  auto scanBoth = [&](std::uint64_t key) {
    keep.scan(t, pose, key, &ex, a, &boxes);
    fresh.scan(t, pose, key, nullptr, b, &boxes);
    return sameBits(a, b);
  };
  ASSERT_TRUE(scanBoth(7));
  EXPECT_EQ(keep.keptLastScan(), 0u);
  ASSERT_GT(a.size(), 50000u);
  before = b;
  // The second scan from the same pose keeps its hits (the first keeps none: a sensor that
  // moves every scan should not pay for keeping them).
  ASSERT_TRUE(scanBoth(7));
  EXPECT_EQ(keep.keptLastScan(), 0u);
  // Still terrain: every ray that may hit takes its kept hit.
  ASSERT_TRUE(scanBoth(7));
  EXPECT_TRUE(sameBits(b, before));
  const std::size_t all = keep.keptLastScan();
  EXPECT_GT(all, keep.raysPerScan() * 9 / 10);
  // A mound rises in view (it hides ground behind it), a trench is dug in view, a small bump
  // near the camera: the rays over them are cast again, the rest kept.
  for (const auto& [x, y, r, dz] : std::vector<std::array<double, 4>>{
           {3.5, 0.3, 0.4, 0.35}, {6.0, 1.5, 0.6, -0.3}, {2.6, -0.8, 0.15, 0.05}}) {
    reshape(t, x, y, r, dz);
    ASSERT_TRUE(scanBoth(7)) << "after the change at (" << x << ", " << y << ")";
    EXPECT_FALSE(sameBits(b, before)) << "the change at (" << x << ", " << y << ") is not seen";
    EXPECT_LT(keep.keptLastScan(), all) << x << ", " << y;
    EXPECT_GT(keep.keptLastScan(), all / 2) << x << ", " << y;
    before = b;
  }
  // A change behind the camera (out of view): the same cloud, nearly every hit kept.
  reshape(t, -6, 4, 1.0, 0.5);
  ASSERT_TRUE(scanBoth(7));
  EXPECT_TRUE(sameBits(b, before));
  EXPECT_GT(keep.keptLastScan(), all * 95 / 100);
  // A new noise key draws new noise over the kept hits, as a cast does.
  ASSERT_TRUE(scanBoth(8));
  // The sensor moves by a hair: nothing is kept, then kept again once it holds still.
  pose.translation().x() += 1e-9;
  ASSERT_TRUE(scanBoth(8));
  EXPECT_EQ(keep.keptLastScan(), 0u);
  ASSERT_TRUE(scanBoth(8));
  EXPECT_EQ(keep.keptLastScan(), 0u);
  ASSERT_TRUE(scanBoth(8));
  EXPECT_GT(keep.keptLastScan(), all * 95 / 100);
  // Another terrain object with the same contents (a copy): cast anew, the same cloud.
  const TruthTerrain copy = t;
  keep.scan(copy, pose, 8, &ex, a, &boxes);
  EXPECT_EQ(keep.keptLastScan(), 0u);
  EXPECT_TRUE(sameBits(a, b));
}

TEST(DepthCamera, AStandingExcavatorsCameraKeepsMostHitsAndGivesTheSameClouds) {
  // configs/scenarios/excavator_dig_dump.yaml (the excavator's camera, the loader's LiDAR, the
  // physics ahead of the scans on two threads), every sensor keeping hits or casting every ray,
  // over the first seconds of the excavator's cycle (the bucket digs in view): the same clouds.
  auto run = [](bool reuse, Simulator::Stats& st) {
    Scenario sc = loadScenario(std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/excavator_dig_dump.yaml");
    sc.duration_s = 6;
    for (MachineSpec& m : sc.machines)
      for (SensorSpec& s : m.sensors) s.reuse_casts = reuse;
    Simulator sim(sc);
    std::vector<Event> ev;
    std::vector<PointCloud> clouds;
    while (sim.next(ev)) {
      for (auto& e : ev)
        if (auto* p = std::get_if<PointCloud>(&e)) clouds.push_back(std::move(*p));
      ev.clear();
    }
    st = sim.stats();
    return clouds;
  };
  Simulator::Stats on, off;
  const std::vector<PointCloud> a = run(true, on), b = run(false, off);
  ASSERT_EQ(a.size(), b.size());
  ASSERT_GE(a.size(), 90u + 60u);
  for (std::size_t k = 0; k < a.size(); ++k) ASSERT_TRUE(sameBits(a[k].points, b[k].points)) << "scan " << k;
  EXPECT_EQ(off.rays_kept, 0u);
  EXPECT_GT(on.rays_kept, on.rays / 3);  // the camera's (the moving loader's LiDAR keeps none)
  EXPECT_LT(on.rays_kept, on.rays * 99 / 100);  // the dig is re-cast
}

TEST(DepthCamera, TheSimulatorDeliversAndRecordsItsClouds) {
  // 15 Hz camera, 1 s: scans at the first physics step (1/240 s), then at 1/15, ..., 15/15 s, frame
  // "ctl1/cam", points in the optical frame (positive depth), the machine's own blade in view.
  const Scenario sc = parseScenario(
      scenarioYaml("offset_m: [0.5, 0, 2.0], rotation_deg: [0, 35, 0]", 1.0), "s.yaml");
  Simulator sim(sc);
  std::vector<Event> ev;
  std::vector<PointCloud> clouds;
  while (sim.next(ev)) {
    for (auto& e : ev)
      if (auto* p = std::get_if<PointCloud>(&e)) clouds.push_back(*p);
    ev.clear();
  }
  ASSERT_EQ(clouds.size(), 16u);
  std::size_t points = 0;
  for (std::size_t k = 0; k < clouds.size(); ++k) {
    EXPECT_EQ(clouds[k].frame, "ctl1/cam");
    EXPECT_NEAR(clouds[k].stamp, k == 0 ? 1 / 240.0 : k / 15.0, 1e-9);
    points += clouds[k].points.size();
    for (const PointXYZI& p : clouds[k].points) ASSERT_GT(p.z, 0.25f);
  }
  EXPECT_GT(points, 16u * 50000u);
  const std::string dir = std::string(TERRAMAP_BINARY_DIR) + "/sim_test_depth_camera";
  std::filesystem::remove_all(dir);
  const std::string path = runEpisode(sc, dir);
  std::vector<std::uint64_t> dims;
  readEpisodeDataset(path, "/machines/ctl1/clouds/cam/points", dims);
  ASSERT_EQ(dims.size(), 2u);
  EXPECT_EQ(dims[0], points);
  readEpisodeDataset(path, "/machines/ctl1/clouds/cam/count", dims);
  EXPECT_EQ(dims[0], 16u);
}

TEST(DepthCamera, BadKeysAreNamed) {
  auto message = [](const std::string& keys) {
    try {
      parseScenario(scenarioYaml(keys), "s.yaml");
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const std::string both = message("fx: 200, horizontal_fov_deg: 80");
  EXPECT_NE(both.find("sensors[0].fx"), std::string::npos) << both;
  const std::string beams = message("beams: 64");
  EXPECT_NE(beams.find("sensors[0].beams"), std::string::npos) << beams;
  const std::string range = message("depth_range_m: [2, 1]");
  EXPECT_NE(range.find("depth_range_m"), std::string::npos) << range;
  const std::string width = message("width: 1");
  EXPECT_NE(width.find("sensors[0].width"), std::string::npos) << width;
}

TEST(SensorOnLink, ACameraOnTheCabTurnsWithTheCabAndItsCloudsCarryTheEstimatedCabPose) {
  // configs/scenarios/excavator_dig_dump.yaml's excavator alone over a dig and its swing to the
  // dump: its camera moved to the cab (`link: slew`), mounted where the undercarriage's camera is
  // at the start. Each cloud must be cast from the cab's true pose (its points, placed with the
  // cab's true pose, lie on the terrain while the cab has turned away from the undercarriage) and
  // carry the machine's estimate of it (the localisation's errors and the slew encoder's:
  // centimetres and ~0.01 rad from the truth).
  Scenario sc = loadScenario(std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/excavator_dig_dump.yaml");
  sc.machines.resize(1);
  sc.duration_s = 12;
  // Mounds and a dip beside the machine, so that a cloud cast from another heading than the one
  // its points are placed with leaves the ground (on a plane a turn about the slew axis, the
  // plane's normal, would not show).
  for (const GaussianBump& b : {GaussianBump{1.4, 1.4, 0.5, 0.4}, GaussianBump{-0.6, 2.0, -0.4, 0.5},
                                GaussianBump{1.9, -1.1, 0.5, 0.4}, GaussianBump{0.8, 2.7, 0.5, 0.35}})
    sc.terrain.bumps.push_back(b);
  sc.lidar_sees_machines = false;  // every point on the terrain (the cab's camera sees the boom)
  MachineSpec& m = sc.machines.front();
  ASSERT_TRUE(m.arm.has_value());
  const ExcavatorArm arm(*m.arm);
  SensorSpec* cam = nullptr;
  for (SensorSpec& s : m.sensors)
    if (s.type == SensorSpec::Type::DepthCamera) cam = &s;
  ASSERT_NE(cam, nullptr);
  const Eigen::Isometry3d T_slew_cam = arm.T_base_slew(arm.q()).inverse() * cam->T_base_sensor;
  cam->link = SensorSpec::Link::Slew;
  cam->T_base_sensor = T_slew_cam;
  const std::string frame = m.id + "/" + cam->id;
  Simulator sim(sc);
  std::vector<Event> ev;
  double slew_lo = 1e9, slew_hi = -1e9, worst_t = 0, worst_r = 0, worst_dz = 0;
  int checked = 0, turned = 0;
  while (sim.next(ev)) {
    const MachineTruth& tr = sim.machineTruth(0);
    for (const Event& e : ev) {
      const auto* pc = std::get_if<PointCloud>(&e);
      if (!pc || pc->frame != frame || std::abs(pc->stamp - sim.time()) > 1e-9) continue;
      const Eigen::Isometry3d T_true = tr.T_map_base * arm.linkFrames(tr.arm_q)[0] * T_slew_cam;
      worst_t = std::max(worst_t, (pc->T_map_sensor.translation() - T_true.translation()).norm());
      worst_r = std::max(worst_r, Eigen::AngleAxisd(pc->T_map_sensor.linear() * T_true.linear().transpose()).angle());
      slew_lo = std::min(slew_lo, tr.arm_q[0]);
      slew_hi = std::max(slew_hi, tr.arm_q[0]);
      ++checked;
      if (std::abs(tr.arm_q[0] - arm.q()[0]) < 0.5) continue;
      // Turned by more than 0.5 rad: the median height error of the near points (optical depth
      // < 3 m, noise sigma < 5 cm along the ray) placed with the cab's true pose; the arm in view
      // is a minority.
      ++turned;
      std::vector<double> dz;
      for (const PointXYZI& p : pc->points) {
        if (!(p.z < 3.0f)) continue;
        const Eigen::Vector3d q = T_true * Eigen::Vector3d(p.x, p.y, p.z);
        dz.push_back(std::abs(q.z() - sim.truth().heightAt(q.x(), q.y())));
      }
      ASSERT_GT(dz.size(), 1000u);
      std::nth_element(dz.begin(), dz.begin() + dz.size() / 2, dz.end());
      worst_dz = std::max(worst_dz, dz[dz.size() / 2]);
    }
    ev.clear();
  }
  EXPECT_GE(checked, 170);     // every 4th period end (15 Hz camera, 60 Hz observations) over 12 s
  EXPECT_GT(turned, 10);       // the cab swung away from where the camera was mounted
  EXPECT_GT(slew_hi - slew_lo, 1.0);
  // The localisation's errors (rtk_imu: centimetres, attitude ~0.5 deg) and the encoder's 0.1 deg;
  // an estimate that missed the cab's turn would be off by > 0.5 rad.
  EXPECT_LT(worst_t, 0.1);
  EXPECT_LT(worst_r, 0.02);
  EXPECT_LT(worst_dz, 0.035);  // 0.02 here; 0.66 m when cast from the undercarriage's pose
  // While the cab holds its heading (the swing lever within its deadband, the joint's Eq. 1
  // transient settled) the camera stands still to the bit and keeps its hits: 44 % of the rays
  // here; without the deadband none, without the settling 21 %.
  EXPECT_GT(sim.stats().rays_kept, sim.stats().rays / 3);
}

TEST(SensorOnLink, ALoadersCameraCannotHangOnAnExcavatorsLink) {
  try {
    (void)parseScenario(scenarioYaml("offset_m: [0.5, 0, 2.0], link: slew", 1.0), "s.yaml");
    FAIL() << "a loader's camera on 'slew' was accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("unknown link 'slew' (known: base, blade)"), std::string::npos) << e.what();
  }
}

TEST(SensorOnLink, ALidarOnTheBladeIsPosedByTheBladeAndTheMeasuredCylinders) {
  // A single-line scanner on a loader's blade over a cut (the blade lifts, tilts and angles):
  // each scan carries the estimate of the blade's pose (the localisation and the cylinder
  // sensors, as the Observation's T_map_blade), close to the blade's true pose and far from
  // where the same mount on the base would put it.
  const Scenario sc = parseScenario(
      "version: 1\nseed: 3\nduration_s: 3\nthreads: 1\n"
      "terrain: {size_m: [16, 10], origin_m: [-4, -5], resolution_m: 0.02}\n"
      "machines:\n  - id: ctl1\n"
      "    controller: {type: route, start_m: [0, 0], length_m: 4, passes: 1, depth_m: 0.1}\n"
      "    sensors:\n      - {id: edge, type: lidar, preset: single_line, link: blade, rate_hz: 20,"
      " offset_m: [0.2, 0, 0.6], rotation_deg: [0, 20, 0]}\n",
      "s.yaml");
  ASSERT_EQ(sc.machines.at(0).sensors.at(0).link, SensorSpec::Link::Blade);
  const Eigen::Isometry3d T_blade_lidar = sc.machines.at(0).sensors.at(0).T_base_sensor;
  Simulator sim(sc);
  std::vector<Event> ev;
  int checked = 0;
  double worst = 0, off_base = 1e9;
  while (sim.next(ev)) {
    const MachineTruth& tr = sim.machineTruth(0);
    for (const Event& e : ev) {
      const auto* pc = std::get_if<PointCloud>(&e);
      if (!pc || std::abs(pc->stamp - sim.time()) > 1e-9) continue;
      ++checked;
      worst = std::max(worst, (pc->T_map_sensor.translation() - (tr.T_map_blade * T_blade_lidar).translation()).norm());
      off_base = std::min(off_base, (pc->T_map_sensor.translation() - (tr.T_map_base * T_blade_lidar).translation()).norm());
    }
    ev.clear();
  }
  EXPECT_GE(checked, 59);  // 20 Hz for 3 s, at every third period end
  EXPECT_LT(worst, 0.05);  // localisation (cm) and the cylinder sensors' noise
  EXPECT_GT(off_base, 1.0);  // the blade hangs ~2 m ahead of the base
}
