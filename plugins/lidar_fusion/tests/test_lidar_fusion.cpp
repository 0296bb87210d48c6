// Unit tests of lidar_fusion with hand-computed expectations (see the comments at each
// expectation for the arithmetic).
#include "lidar_fusion.hpp"
#include "memory_budget_scope.hpp"

#include <terramap/core/memory_budget.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <map>
#include <random>

using namespace terramap;
using namespace terramap::plugins;
using L = LidarFusionLayers;

namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

/// A 40 x 40 map at 0.1 m centred on the origin (x, y in [-2, 2)), tiles of 8 cells so that
/// the tile machinery (25 tiles, ring-buffer wrap) is exercised.
LayeredMap makeMap(int tile = 8, bool sparse = false, int cells = 40, double res = 0.1) {
  return LayeredMap(Geometry(res, Size(cells, cells)), MapOptions{tile, sparse});
}

/// A config with the heuristics that would obscure hand arithmetic switched off.
LidarFusionConfig plainConfig() {
  LidarFusionConfig c;
  c.enable_visibility_cleanup = false;
  c.enable_ramped_height_range = false;
  c.time_variance_m2_per_s = 0.0;
  return c;
}

PointCloud cloudAt(const Eigen::Vector3d& sensor, std::vector<PointXYZI> pts, double stamp = 0.0) {
  PointCloud pc;
  pc.stamp = stamp;
  pc.T_map_sensor = Eigen::Isometry3d::Identity();
  pc.T_map_sensor.translation() = sensor;
  pc.points = std::move(pts);
  return pc;
}

float layerAt(const LayeredMap& m, const char* layer, const Index& idx) { return m.at(m.layerId(layer), idx); }

Index cellOf(const LayeredMap& m, double x, double y) {
  auto idx = m.geometry().indexAt(Position(x, y));
  EXPECT_TRUE(idx.has_value());
  return idx.value_or(Index(0, 0));
}

/// The message of the ConfigError fn throws, or "(no ConfigError)" (which names no key, so a
/// check for the key fails).
std::string configErrorOf(const std::function<void()>& fn) {
  try {
    fn();
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "(no ConfigError)";
}

bool sameBits(const Eigen::MatrixXf& a, const Eigen::MatrixXf& b) {
  return a.rows() == b.rows() && a.cols() == b.cols() &&
         std::memcmp(a.data(), b.data(), sizeof(float) * static_cast<size_t>(a.size())) == 0;
}

}  // namespace

TEST(LidarFusion, OnePoint) {
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();  // range_based a = 0.02 m, b = 0.001
  f.configure(c);
  f.attach(map);
  Executor ex(1);
  // Sensor at the origin, point (1.23, -0.47, -0.5).
  const FusionStats s = f.fuse(map, ex, cloudAt({0, 0, 0}, {{1.23f, -0.47f, -0.5f, 0}}));
  EXPECT_EQ(s.points_fused, 1);
  // xmax = ymax = 2.0: i = ceil((2 - 1.23)/0.1) - 1 = 7, j = ceil((2 + 0.47)/0.1) - 1 = 24.
  const Index idx(7, 24);
  EXPECT_TRUE((cellOf(map, 1.23f, -0.47f) == idx).all());
  const double r = std::sqrt(1.23 * 1.23 + 0.47 * 0.47 + 0.25);  // 1.4103 m
  const double sigma = 0.02 + 0.001 * r;
  EXPECT_FLOAT_EQ(layerAt(map, L::kElevation, idx), -0.5f);
  EXPECT_NEAR(layerAt(map, L::kVariance, idx), sigma * sigma, 1e-9);
  EXPECT_EQ(layerAt(map, L::kIsValid, idx), 1.0f);
  EXPECT_EQ(layerAt(map, L::kTimeSinceUpdate, idx), 0.0f);
  EXPECT_EQ(layerAt(map, L::kHits, idx), 1.0f);
  EXPECT_EQ(layerAt(map, L::kUpperBound, idx), -0.5f);
  EXPECT_EQ(layerAt(map, L::kIsUpperBound, idx), 0.0f);
  // Every other cell is still unknown.
  const Eigen::MatrixXf e = map.toMatrix(map.layerId(L::kElevation));
  EXPECT_EQ((e.array() == e.array()).count(), 1);
}

TEST(LidarFusion, DepthSquaredNoise) {
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.noise_model = NoiseModel::DepthSquared;
  c.sensor_noise_factor = 0.05;
  f.configure(c);
  f.attach(map);
  Executor ex(1);
  f.fuse(map, ex, cloudAt({0, 0, 0.5}, {{1.0f, 0.3f, -0.8f, 0}}));
  // v = k z_s^2 = 0.05 * 0.64 = 0.032 (sensor-frame z, not range).
  const Index idx = cellOf(map, 1.0, 0.3);
  EXPECT_NEAR(layerAt(map, L::kVariance, idx), 0.032, 1e-8);
  EXPECT_FLOAT_EQ(layerAt(map, L::kElevation, idx), -0.3f);
}

TEST(LidarFusion, DepthSquaredFramesTakeTheCameraModelBesideALiDAR) {
  // One fusion, range_based for the LiDAR; clouds of frames matching "*/cam" (a depth camera,
  // points in its optical frame) take v = k z_s^2 instead. Without the pattern the camera's
  // point would get the LiDAR's (a + b r)^2.
  for (bool with_pattern : {true, false}) {
    LayeredMap map = makeMap();
    LidarFusion f;
    LidarFusionConfig c = plainConfig();
    c.range_noise_a_m = 0.02;
    c.range_noise_b = 0.0;
    c.sensor_noise_factor = 0.01;
    if (with_pattern) c.depth_squared_frames = {"*/cam"};
    f.configure(c);
    f.attach(map);
    Executor ex(1);
    PointCloud cam = cloudAt({0, 0, 0.5}, {{1.0f, 0.3f, -0.8f, 0}});
    cam.frame = "ctl1/cam";
    EXPECT_EQ(f.fuse(map, ex, cam).points_fused, 1);
    PointCloud lidar = cloudAt({0, 0, 0.5}, {{-1.04f, -0.63f, -0.8f, 0}}, 0.1);
    lidar.frame = "ctl1/top";
    EXPECT_EQ(f.fuse(map, ex, lidar).points_fused, 1);
    const double v_cam = layerAt(map, L::kVariance, cellOf(map, 1.0, 0.3));
    const double v_lidar = layerAt(map, L::kVariance, cellOf(map, -1.04, -0.63));
    EXPECT_NEAR(v_cam, with_pattern ? 0.01 * 0.64 : 0.02 * 0.02, 1e-8) << with_pattern;  // z_s = -0.8
    EXPECT_NEAR(v_lidar, 0.02 * 0.02, 1e-8);
  }
  // A pattern with sensor_noise_factor = 0 would make the camera's points noise-free: refused.
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.depth_squared_frames = {"*/cam"};
  c.sensor_noise_factor = 0.0;
  const std::string why = configErrorOf([&] { f.configure(c); });
  EXPECT_NE(why.find("sensor_noise_factor"), std::string::npos) << why;
}

TEST(LidarFusion, NPointsInOneCellShrinkVariance) {
  // b = 0: every point has variance a^2 = 0.0025, so sequential precision-weighted fusion of
  // n points is the plain mean with variance a^2 / n.
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.range_noise_a_m = 0.05;
  c.range_noise_b = 0.0;
  f.configure(c);
  f.attach(map);
  Executor ex(1);
  const std::vector<float> zs{0.10f, 0.12f, 0.08f, 0.11f, 0.09f};
  std::vector<PointXYZI> pts;
  for (float z : zs) pts.push_back({1.04f, 0.52f, z, 0});
  // A point in another cell in between must not disturb the sequence.
  pts.insert(pts.begin() + 2, PointXYZI{-1.0f, -1.0f, 0.3f, 0});
  const FusionStats s = f.fuse(map, ex, cloudAt({0, 0, 0}, pts));
  EXPECT_EQ(s.points_fused, 6);
  EXPECT_EQ(s.outliers, 0);
  const Index idx = cellOf(map, 1.04, 0.52);
  EXPECT_NEAR(layerAt(map, L::kElevation, idx), 0.1, 1e-6);  // (0.10+0.12+0.08+0.11+0.09)/5
  EXPECT_NEAR(layerAt(map, L::kVariance, idx), 0.0025 / 5, 1e-9);
  EXPECT_EQ(layerAt(map, L::kHits, idx), 5.0f);
  // A second cloud keeps shrinking it (hits count only the latest cloud).
  f.fuse(map, ex, cloudAt({0, 0, 0}, {{1.04f, 0.52f, 0.1f, 0}}));
  EXPECT_NEAR(layerAt(map, L::kVariance, idx), 0.0025 / 6, 1e-9);
  EXPECT_EQ(layerAt(map, L::kHits, idx), 1.0f);
}

TEST(LidarFusion, MahalanobisOutlierAddsVariance) {
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.range_noise_a_m = 0.05;
  c.range_noise_b = 0.0;  // v_p = 0.0025
  f.configure(c);
  f.attach(map);
  Executor ex(1);
  const Index idx = cellOf(map, 1.0, 0.0);
  // 0.0 initialises; 0.05 is inside the true gate k sqrt(v + v_p) = 2 sqrt(0.005) = 0.1414
  // (elevation_mapping_cupy's |z - h| > k v would call it an outlier: 0.05 > 0.005).
  FusionStats s = f.fuse(map, ex, cloudAt({0, 0, 0}, {{1.0f, 0.0f, 0.0f, 0}, {1.0f, 0.0f, 0.05f, 0}}));
  EXPECT_EQ(s.outliers, 0);
  EXPECT_NEAR(layerAt(map, L::kElevation, idx), 0.025, 1e-7);
  EXPECT_NEAR(layerAt(map, L::kVariance, idx), 0.00125, 1e-9);
  // 1.0 m away: |1 - 0.025| > 2 sqrt(0.00125 + 0.0025) = 0.1225 -> outlier, variance += 0.01.
  s = f.fuse(map, ex, cloudAt({0, 0, 0}, {{1.0f, 0.0f, 1.0f, 0}}));
  EXPECT_EQ(s.outliers, 1);
  EXPECT_EQ(s.points_fused, 0);
  EXPECT_NEAR(layerAt(map, L::kElevation, idx), 0.025, 1e-7);
  EXPECT_NEAR(layerAt(map, L::kVariance, idx), 0.01125, 1e-8);
  EXPECT_EQ(layerAt(map, L::kHits, idx), 0.0f);
}

// The gate's edge: a residual is an outlier iff |z - h| > k sqrt(v + v_p) (the Mahalanobis
// distance of the residual, whose variance is v + v_p). With v = v_p = a^2 = 0.0025 the edge is
// k * 0.0707 m. Residuals 5 % inside and 5 % outside it, for k = 1, 2, 3, one cell each: a gate
// that compares r^2 with k^2 sigma (sigma where the variance is meant: edge k (v + v_p)^(1/4) =
// k * 0.27 m) or |r| with k v (elevation_mapping_cupy's form: edge k * 0.005 m) puts one of each
// pair on the wrong side.
// 5 % is far above float rounding (~1e-7 relative) of the residuals and the threshold.
TEST(LidarFusion, MahalanobisGateEdgeIsKSigmaOfTheCombinedVariance) {
  for (const double k : {1.0, 2.0, 3.0}) {
    for (const double f : {0.95, 1.05}) {
      LayeredMap map = makeMap();
      LidarFusion fu;
      LidarFusionConfig c = plainConfig();
      c.range_noise_a_m = 0.05;
      c.range_noise_b = 0.0;  // v_p = 0.0025 at any range
      c.mahalanobis_thresh = k;
      fu.configure(c);
      fu.attach(map);
      Executor ex(1);
      const double edge = k * std::sqrt(0.0025 + 0.0025);
      const float dz = static_cast<float>(f * edge);
      const FusionStats s = fu.fuse(map, ex, cloudAt({0, 0, 0}, {{1.0f, 0.0f, 0.0f, 0}, {1.0f, 0.0f, dz, 0}}));
      const Index idx = cellOf(map, 1.0, 0.0);
      if (f < 1.0) {
        // Inside: fused; equal variances -> the mean, variance halved.
        EXPECT_EQ(s.outliers, 0) << "k " << k << " residual " << dz;
        EXPECT_EQ(s.points_fused, 2) << "k " << k;
        EXPECT_NEAR(layerAt(map, L::kElevation, idx), dz / 2, 1e-6) << "k " << k;
        EXPECT_NEAR(layerAt(map, L::kVariance, idx), 0.00125, 1e-9) << "k " << k;
      } else {
        // Outside: rejected, the cell keeps the first point and gains the outlier variance.
        EXPECT_EQ(s.outliers, 1) << "k " << k << " residual " << dz;
        EXPECT_EQ(s.points_fused, 1) << "k " << k;
        EXPECT_FLOAT_EQ(layerAt(map, L::kElevation, idx), 0.0f) << "k " << k;
        EXPECT_NEAR(layerAt(map, L::kVariance, idx), 0.0025 + c.outlier_variance_m2, 1e-8) << "k " << k;
      }
    }
  }
}

TEST(LidarFusion, OutlierAboveMaxVarianceForgetsTheCell) {
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.range_noise_a_m = 0.05;
  c.range_noise_b = 0.0;
  c.max_variance_m2 = 0.01;  // 0.0025 + 0.01 > 0.01: the first outlier forgets the cell
  f.configure(c);
  f.attach(map);
  Executor ex(1);
  const FusionStats s = f.fuse(
      map, ex, cloudAt({0, 0, 0}, {{1.0f, 0.0f, 0.0f, 0}, {1.0f, 0.0f, 1.0f, 0}, {1.0f, 0.0f, 0.7f, 0}}));
  EXPECT_EQ(s.outliers, 1);
  EXPECT_EQ(s.cells_forgotten, 1);
  // After forgetting, the third point initialises the cell afresh.
  const Index idx = cellOf(map, 1.0, 0.0);
  EXPECT_FLOAT_EQ(layerAt(map, L::kElevation, idx), 0.7f);
  EXPECT_NEAR(layerAt(map, L::kVariance, idx), 0.0025, 1e-9);
  EXPECT_EQ(layerAt(map, L::kHits, idx), 2.0f);
}

TEST(LidarFusion, EachGateDropsAndCountsByReason) {
  LayeredMap map = makeMap();
  LidarFusion f;
  Params p = makeParams("lidar", lidarFusionSchema(),
                        {{"max_range_m", 10.0}, {"enable_visibility_cleanup", false}});
  f.configure(p);
  RecordBus bus;
  PluginStats stats;
  Executor ex(1);
  f.attach(map);
  ProcessContext ctx(map, ex, bus, stats, "lidar");
  const float nan = kNaN, inf = std::numeric_limits<float>::infinity();
  PointCloud pc = cloudAt({0, 0, 0}, {
                                         {nan, 0, 0, 0},          // non_finite
                                         {1.0f, inf, 0, 0},       // non_finite
                                         {0.3f, 0.0f, 0.0f, 0},   // too_close (0.3 < 0.5)
                                         {12.0f, 0.0f, -1.0f, 0}, // too_far (12.04 > 10)
                                         {1.9f, 0.0f, 1.5f, 0},   // too_high (1.5 > 1.0)
                                         {0.8f, 0.0f, 0.5f, 0},   // too_high by the ramp: 0.5 > 0.2
                                         {5.0f, 0.0f, -1.0f, 0},  // outside_map (x >= 2)
                                         {1.0f, 1.0f, -1.0f, 0},  // fused
                                     });
  f.process(ctx, Event(pc));
  EXPECT_EQ(stats.dropped["non_finite"], 2);
  EXPECT_EQ(stats.dropped["too_close"], 1);
  EXPECT_EQ(stats.dropped["too_far"], 1);
  EXPECT_EQ(stats.dropped["too_high"], 2);
  EXPECT_EQ(stats.dropped["outside_map"], 1);
  EXPECT_EQ(stats.counters["points_fused"], 1.0);
  EXPECT_EQ(stats.counters["points_in"], 8.0);
  // The ramp sits at (dxy - 1) * 0.3 + 0.2: at dxy = 1.8, 0.44 m is allowed.
  f.process(ctx, Event(cloudAt({0, 0, 0}, {{1.8f, 0.0f, 0.43f, 0}, {1.8f, 0.0f, 0.45f, 0}}, 1.0)));
  EXPECT_EQ(stats.dropped["too_high"], 3);
  f.finish(ctx);
  ASSERT_EQ(stats.records.size(), 1u);
  EXPECT_NE(stats.records[0].find("\"too_high\":3"), std::string::npos);
}

TEST(LidarFusion, ParamsAreCrossChecked) {
  LidarFusion f;
  EXPECT_THROW(f.configure(makeParams("lidar", lidarFusionSchema(), {{"min_range_m", 5.0}, {"max_range_m", 2.0}})),
               ConfigError);
  EXPECT_THROW(makeParams("lidar", lidarFusionSchema(), {{"sensor_noise", std::string("gaussian")}}), ConfigError);
  LidarFusionConfig c;
  c.cleanup_ray_stride = 0;
  EXPECT_THROW(f.configure(c), ConfigError);
  // The fan walk: the walk's name is checked by the schema, its lateral tolerance must be > 0.
  EXPECT_THROW(makeParams("lidar", lidarFusionSchema(), {{"cleanup_walk", std::string("fans")}}), ConfigError);
  const Params fan = makeParams("lidar", lidarFusionSchema(), {{"cleanup_walk", std::string("fan")}});
  EXPECT_EQ(lidarFusionConfigFrom(fan).cleanup_walk, CleanupWalk::Fan);
  c = LidarFusionConfig{};
  c.cleanup_fan_lateral_cells = 0.0;
  const std::string why = configErrorOf([&] { f.configure(c); });
  EXPECT_NE(why.find("cleanup_fan_lateral_cells"), std::string::npos) << why;
}

// A noise model that claims noise-free points is a configuration error, named by its keys.
TEST(LidarFusion, NoiseFreeModelsAreRejectedAtConfiguration) {
  LidarFusion f;
  const std::string yaml = configErrorOf([&] {
    f.configure(makeParams("lidar", lidarFusionSchema(), {{"range_noise_a_m", 0.0}, {"range_noise_b", 0.0}}));
  });
  EXPECT_NE(yaml.find("range_noise_a_m"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("range_noise_b"), std::string::npos) << yaml;
  LidarFusionConfig c;
  c.range_noise_a_m = 0.0;
  c.range_noise_b = 0.0;
  const std::string direct = configErrorOf([&] { f.configure(c); });
  EXPECT_NE(direct.find("range_noise_a_m"), std::string::npos) << direct;
  EXPECT_NE(direct.find("range_noise_b"), std::string::npos) << direct;
  // Either term alone is a noise model.
  c.range_noise_b = 0.001;
  EXPECT_NO_THROW(f.configure(c));
  c.range_noise_a_m = 0.02;
  c.range_noise_b = 0.0;
  EXPECT_NO_THROW(f.configure(c));
  // a = b = 0 does not matter under depth_squared, k = 0 does.
  c.noise_model = NoiseModel::DepthSquared;
  c.range_noise_a_m = 0.0;
  EXPECT_NO_THROW(f.configure(c));
  c.sensor_noise_factor = 0.0;
  const std::string k = configErrorOf([&] { f.configure(c); });
  EXPECT_NE(k.find("sensor_noise_factor"), std::string::npos) << k;
  const std::string kyaml = configErrorOf([&] {
    f.configure(makeParams("lidar", lidarFusionSchema(),
                           {{"sensor_noise", std::string("depth_squared")}, {"sensor_noise_factor", 0.0}}));
  });
  EXPECT_NE(kyaml.find("sensor_noise_factor"), std::string::npos) << kyaml;
  LidarFusionConfig z;
  z.min_variance_m2 = 0.0;
  const std::string fl = configErrorOf([&] { f.configure(z); });
  EXPECT_NE(fl.find("min_variance_m2"), std::string::npos) << fl;
}

// A sensor that quantises heights (here every point of a cell at the same z, from horizontal
// beams, so depth_squared gives v = k * 0^2 = 0): without a floor the first point sets v = 0 and
// the second computes (h*0 + z*0)/0 = NaN with is_valid = 1.
TEST(LidarFusion, IdenticalHeightsWithZeroPointVarianceStayFiniteAndFloored) {
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.noise_model = NoiseModel::DepthSquared;  // k = 0.05
  f.configure(c);
  f.attach(map);
  Executor ex(1);
  // Sensor at z = 0.25 looking along +x: sensor-frame z = 0 for every point, map z = 0.25.
  std::vector<PointXYZI> pts;
  for (int k = 0; k < 200; ++k) pts.push_back({1.23f, -0.47f, 0.0f, 0});
  const FusionStats s = f.fuse(map, ex, cloudAt({0, 0, 0.25}, pts));
  EXPECT_EQ(s.points_fused, 200);
  EXPECT_EQ(s.outliers, 0);
  const Index idx = cellOf(map, 1.23, -0.47);
  EXPECT_EQ(layerAt(map, L::kElevation, idx), 0.25f);
  EXPECT_EQ(layerAt(map, L::kIsValid, idx), 1.0f);
  // Every point has v = floor, so the fused variance is floor/n, floored again at the floor.
  EXPECT_EQ(layerAt(map, L::kVariance, idx), static_cast<float>(c.min_variance_m2));
  // And the cell is not frozen: a point 10 cm higher (sensor-frame z = 0.1, v_p = 0.05 * 0.01
  // = 5e-4) is gated against 2 sqrt(1e-6 + 5e-4) = 4.5 cm: an outlier, which adds 0.01 m^2; the
  // next such point then has weight 0.010001 / 0.010501 = 0.95 and moves the cell to ~0.345 m.
  const std::vector<PointXYZI> up = {{1.23f, -0.47f, 0.1f, 0}};
  const FusionStats s2 = f.fuse(map, ex, cloudAt({0, 0, 0.25}, up));
  EXPECT_EQ(s2.outliers, 1);
  const FusionStats s3 = f.fuse(map, ex, cloudAt({0, 0, 0.25}, up));
  EXPECT_EQ(s3.points_fused, 1);
  EXPECT_GT(layerAt(map, L::kElevation, idx), 0.34f);
  EXPECT_TRUE(std::isfinite(layerAt(map, L::kVariance, idx)));
}

// Range-based noise with a quantising sensor: thousands of identical heights would shrink the
// variance as v_p / n far below anything the sensor supports; the floor stops it there.
TEST(LidarFusion, ManyIdenticalHeightsStopAtTheVarianceFloor) {
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();  // a = 0.02 m: v_p ~ 4.9e-4 m^2 at r ~ 1.4 m
  f.configure(c);
  f.attach(map);
  Executor ex(2);
  // z quantised to 1 cm: every return of the cell reads -0.50 exactly. v_p / n < 1e-6 from
  // n = 490 on; 2000 points would give 2.5e-7 without the floor.
  std::vector<PointXYZI> pts(2000, PointXYZI{1.23f, -0.47f, -0.5f, 0});
  const FusionStats s = f.fuse(map, ex, cloudAt({0, 0, 0}, pts));
  EXPECT_EQ(s.points_fused, 2000);
  const Index idx = cellOf(map, 1.23, -0.47);
  EXPECT_EQ(layerAt(map, L::kElevation, idx), -0.5f);
  EXPECT_EQ(layerAt(map, L::kIsValid, idx), 1.0f);
  EXPECT_GE(layerAt(map, L::kVariance, idx), static_cast<float>(c.min_variance_m2));
  EXPECT_EQ(layerAt(map, L::kVariance, idx), static_cast<float>(c.min_variance_m2));
}

// The cleanup's tests below run with both walks: the rays lie along a grid axis, where the fan
// walk's bin has its centre line on the ray's own line (an odd number of slots per face).
const CleanupWalk kWalks[] = {CleanupWalk::Exact, CleanupWalk::Fan};
const char* walkName(CleanupWalk w) { return w == CleanupWalk::Fan ? "fan walk" : "exact walk"; }

TEST(LidarFusion, RayUnderAStaleCellInvalidatesIt) {
  for (CleanupWalk walk : kWalks) {
  SCOPED_TRACE(walkName(walk));
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.enable_visibility_cleanup = true;
  c.cleanup_ray_stride = 1;
  c.cleanup_walk = walk;
  c.cleanup_step = 0.25;  // exact in binary: 1 -> 0.75 -> 0.5 -> 0.25 (< 0.5: invalid)
  c.time_variance_m2_per_s = 0.0005;
  f.configure(c);
  f.attach(map);
  Executor ex(1);
  const Eigen::Vector3d S(0.0, 0.05, 1.0);
  // Cloud 1: a surface point at (1.05, 0.05, 0.9) in cell A = x in [1.0, 1.1) (a stale
  // obstacle top, say).
  f.advanceTime(map, ex, 0.0);
  f.fuse(map, ex, cloudAt(S, {{1.05f, 0.0f, -0.1f, 0}}, 0.0));
  const Index A = cellOf(map, 1.05, 0.05);
  ASSERT_FLOAT_EQ(layerAt(map, L::kElevation, A), 0.9f);
  const float v0 = layerAt(map, L::kVariance, A);
  // Cloud 2 (1 s later): rays to (2.55, 0.05, -0.5) - outside the map, still walked. The ray
  // enters A's column at x = 1.0 with z = 1 - 1.5 * (1.0 / 2.55) = 0.41176 m, below the
  // surface by more than 2 sigma (sigma <= 0.15 m even after +0.01 m^2 per ray), at
  // cos = 1.5 / 2.95 = 0.51 to the (flat) normal.
  const PointXYZI far{2.55f, 0.0f, -1.5f, 0};
  f.advanceTime(map, ex, 1.0);
  FusionStats s = f.fuse(map, ex, cloudAt(S, {far, far}, 1.0));
  EXPECT_EQ(s.dropped_outside_map, 2);
  EXPECT_EQ(s.rays, 2);
  EXPECT_EQ(s.cells_penetrated, 2);
  EXPECT_EQ(layerAt(map, L::kIsValid, A), 0.5f);
  EXPECT_NEAR(layerAt(map, L::kVariance, A), v0 + 0.0005f + 2 * 0.01f, 1e-7);
  EXPECT_FLOAT_EQ(layerAt(map, L::kElevation, A), 0.9f);
  // A third penetrating ray takes validity below 0.5: the cell is cleared and keeps the ray
  // height as its upper bound.
  s = f.fuse(map, ex, cloudAt(S, {far}, 1.0));
  EXPECT_EQ(s.cells_invalidated, 1);
  EXPECT_TRUE(std::isnan(layerAt(map, L::kElevation, A)));
  EXPECT_TRUE(std::isnan(layerAt(map, L::kVariance, A)));
  EXPECT_EQ(layerAt(map, L::kIsValid, A), 0.0f);
  EXPECT_NEAR(layerAt(map, L::kUpperBound, A), 1.0 - 1.5 / 2.55, 1e-5);
  EXPECT_EQ(layerAt(map, L::kIsUpperBound, A), 1.0f);
  }
}

TEST(LidarFusion, RaysDoNotCleanCellsMeasuredInTheSameCloudOrGrazing) {
  for (CleanupWalk walk : kWalks) {
  SCOPED_TRACE(walkName(walk));
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.enable_visibility_cleanup = true;
  c.cleanup_ray_stride = 1;
  c.cleanup_walk = walk;
  c.cleanup_step = 0.25;
  f.configure(c);
  f.attach(map);
  Executor ex(1);
  const Eigen::Vector3d S(0.0, 0.05, 1.0);
  const PointXYZI far{2.55f, 0.0f, -1.5f, 0};
  // Same cloud: the surface point and the ray under it -> the cell stays valid.
  f.fuse(map, ex, cloudAt(S, {{1.05f, 0.0f, -0.5f, 0}, far, far, far}));
  const Index A = cellOf(map, 1.05, 0.05);
  EXPECT_EQ(layerAt(map, L::kIsValid, A), 1.0f);
  // A horizontal ray at z = 0.3 under the flat cell is grazing (cos = 0 < 0.1): skipped.
  const FusionStats s = f.fuse(map, ex, cloudAt({0.0, 0.05, 0.3}, {{2.55f, 0.0f, 0.0f, 0}}));
  EXPECT_EQ(s.rays, 1);
  EXPECT_EQ(s.cells_penetrated, 0);
  EXPECT_EQ(layerAt(map, L::kIsValid, A), 1.0f);
  }
}

TEST(LidarFusion, UpperBoundOverAnUnknownCell) {
  for (CleanupWalk walk : kWalks) {
  SCOPED_TRACE(walkName(walk));
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.enable_visibility_cleanup = true;
  c.cleanup_ray_stride = 1;
  c.cleanup_walk = walk;
  f.configure(c);
  f.attach(map);
  Executor ex(1);
  // Sensor (0, 0.05, 1); points at (1.55, 0.05, 0) and (1.55, 0.05, -0.5). Cell B = x in
  // [0.5, 0.6): both rays enter it at x = 0.5 (the higher end of a descending ray), at
  // z = 1 - 1.0 * 0.5 / 1.55 = 0.67742 and z = 1 - 1.5 * 0.5 / 1.55 = 0.51613. The bound is
  // the lower of the two.
  f.fuse(map, ex, cloudAt({0.0, 0.05, 1.0}, {{1.55f, 0.0f, -1.0f, 0}}));
  const Index B = cellOf(map, 0.55, 0.05);
  EXPECT_TRUE(std::isnan(layerAt(map, L::kElevation, B)));
  EXPECT_NEAR(layerAt(map, L::kUpperBound, B), 1.0 - 0.5 / 1.55, 1e-5);
  EXPECT_EQ(layerAt(map, L::kIsUpperBound, B), 1.0f);
  // Cells beyond the walk (it stops 0.3 m before the point, at x = 1.297) got no bound.
  EXPECT_TRUE(std::isnan(layerAt(map, L::kUpperBound, cellOf(map, 1.35, 0.05))));
  f.fuse(map, ex, cloudAt({0.0, 0.05, 1.0}, {{1.55f, 0.0f, -1.5f, 0}}));
  EXPECT_NEAR(layerAt(map, L::kUpperBound, B), 1.0 - 1.5 * 0.5 / 1.55, 1e-5);
  // A higher ray later does not loosen it.
  f.fuse(map, ex, cloudAt({0.0, 0.05, 1.0}, {{1.55f, 0.0f, -1.0f, 0}}));
  EXPECT_NEAR(layerAt(map, L::kUpperBound, B), 1.0 - 1.5 * 0.5 / 1.55, 1e-5);
  // Once measured, the cell's upper bound is its elevation and no longer a ray bound.
  f.fuse(map, ex, cloudAt({0.0, 0.05, 1.0}, {{0.55f, 0.0f, -1.2f, 0}}));
  EXPECT_NEAR(layerAt(map, L::kUpperBound, B), -0.2, 1e-6);
  EXPECT_EQ(layerAt(map, L::kIsUpperBound, B), 0.0f);
  }
}

TEST(LidarFusion, FollowRobotMovesByKCells) {
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.follow_robot = true;
  f.configure(c);
  f.attach(map);
  Executor ex(2);
  RecordBus bus;
  PluginStats stats;
  ProcessContext ctx(map, ex, bus, stats, "lidar");
  // One point per cell centre, z = f(x, y) (world coordinates).
  auto height = [](double x, double y) { return static_cast<float>(0.1 * x - 0.05 * y); };
  std::vector<PointXYZI> pts;
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 40; ++j) {
      const Position p = map.geometry().positionOf(Index(i, j));
      pts.push_back({static_cast<float>(p.x()), static_cast<float>(p.y()), height(p.x(), p.y()) - 1.0f, 0});
    }
  Pose pose;
  pose.stamp = 0.0;
  f.process(ctx, Event(pose));  // at the origin: no motion
  PointCloud pc = cloudAt({0, 0, 1.0}, pts, 0.0);
  f.process(ctx, Event(pc));
  // Move the base by (+0.3, -0.2) m: k = (3, -2) cells.
  pose.stamp = 1.0;
  pose.T_map_base.translation() = Eigen::Vector3d(0.3, -0.2, 0.0);
  f.process(ctx, Event(pose));
  EXPECT_NEAR(map.geometry().center().x(), 0.3, 1e-12);
  EXPECT_NEAR(map.geometry().center().y(), -0.2, 1e-12);
  const LayerId e = map.layerId(L::kElevation);
  int known = 0;
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 40; ++j) {
      const Position p = map.geometry().positionOf(Index(i, j));
      const bool was_inside = p.x() < 2.0 && p.x() > -2.0 && p.y() < 2.0 && p.y() > -2.0;
      // The cell that was at logical (i - 3, j + 2): rows 0..2 and columns 38..39 came in.
      EXPECT_EQ(was_inside, i >= 3 && j < 38);
      const float v = map.at(e, Index(i, j));
      if (was_inside) {
        ++known;
        EXPECT_NEAR(v, height(p.x(), p.y()), 1e-6) << i << "," << j;
      } else {
        EXPECT_TRUE(std::isnan(v)) << i << "," << j;
        EXPECT_EQ(map.at(map.layerId(L::kIsValid), Index(i, j)), 0.0f);
      }
    }
  EXPECT_EQ(known, 37 * 38);
  // New points land where indexAt says after the move (lookup tables follow the ring buffer).
  // (2.25, -0.15) is the centre of the new cell (0, 19), in a row that just came in.
  f.process(ctx, Event(cloudAt({0.3, -0.2, 1.0}, {{1.95f, 0.05f, -1.25f, 0}}, 2.0)));
  EXPECT_TRUE((cellOf(map, 2.25, -0.15) == Index(0, 19)).all());
  EXPECT_FLOAT_EQ(map.at(e, Index(0, 19)), -0.25f);
}

TEST(LidarFusion, FollowsTheSensorWithoutPoses) {
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.follow_robot = true;
  f.configure(c);
  f.attach(map);
  Executor ex(1);
  RecordBus bus;
  PluginStats stats;
  ProcessContext ctx(map, ex, bus, stats, "lidar");
  f.process(ctx, Event(cloudAt({5.04, -3.0, 1.0}, {{0.5f, 0.5f, -1.0f, 0}})));
  EXPECT_NEAR(map.geometry().center().x(), 5.0, 1e-12);
  EXPECT_NEAR(map.geometry().center().y(), -3.0, 1e-12);
  EXPECT_FLOAT_EQ(map.at(map.layerId(L::kElevation), cellOf(map, 5.54, -2.5)), 0.0f);
}

TEST(LidarFusion, TimeVarianceGrowsWithElapsedTime) {
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.time_variance_m2_per_s = 0.01;
  c.range_noise_a_m = 0.05;
  c.range_noise_b = 0.0;
  f.configure(c);
  f.attach(map);
  Executor ex(2);
  RecordBus bus;
  PluginStats stats;
  ProcessContext ctx(map, ex, bus, stats, "lidar");
  f.process(ctx, Event(cloudAt({0, 0, 0}, {{1.0f, 0.0f, -1.0f, 0}}, 10.0)));
  const Index idx = cellOf(map, 1.0, 0.0);
  f.process(ctx, Event(Tick{12.5}));
  // 0.0025 + 0.01 * 2.5 = 0.0275 m^2; time 2.5 s; unknown cells stay NaN.
  EXPECT_NEAR(layerAt(map, L::kVariance, idx), 0.0275, 1e-8);
  EXPECT_FLOAT_EQ(layerAt(map, L::kTimeSinceUpdate, idx), 2.5f);
  EXPECT_TRUE(std::isnan(layerAt(map, L::kTimeSinceUpdate, Index(0, 0))));
  EXPECT_TRUE(std::isnan(layerAt(map, L::kVariance, Index(0, 0))));
  // A new point resets the clock and fuses against the grown variance.
  f.process(ctx, Event(cloudAt({0, 0, 0}, {{1.0f, 0.0f, -0.9f, 0}}, 13.0)));
  // 0.5 s more first: v = 0.0325. Then v' = 0.0325 * 0.0025 / 0.035 = 0.00232143 and
  // h' = (-1 * 0.0025 - 0.9 * 0.0325) / 0.035 = -0.907143.
  EXPECT_NEAR(layerAt(map, L::kVariance, idx), 0.0325 * 0.0025 / 0.035, 1e-8);
  EXPECT_NEAR(layerAt(map, L::kElevation, idx), (-1.0 * 0.0025 - 0.9 * 0.0325) / 0.035, 1e-6);
  EXPECT_EQ(layerAt(map, L::kTimeSinceUpdate, idx), 0.0f);
  // Time may not run backwards.
  EXPECT_THROW(f.process(ctx, Event(Tick{12.0})), InputError);
}

TEST(LidarFusion, DriftCompensationShiftsTheMap) {
  LayeredMap map = makeMap();
  LidarFusion f;
  LidarFusionConfig c = plainConfig();
  c.enable_drift_compensation = true;
  c.drift_compensation_alpha = 0.5;
  c.min_height_drift_cnt = 50;
  c.range_noise_a_m = 0.05;
  c.range_noise_b = 0.0;
  f.configure(c);
  f.attach(map);
  Executor ex(2);
  // Flat ground at z = 0 over 10 x 10 cells, 4 points each -> variance 0.000625 (< 0.05).
  std::vector<PointXYZI> ground;
  for (int i = 10; i < 20; ++i)
    for (int j = 10; j < 20; ++j) {
      const Position p = map.geometry().positionOf(Index(i, j));
      for (int r = 0; r < 4; ++r) ground.push_back({float(p.x()), float(p.y()), -1.0f, 0});
    }
  f.fuse(map, ex, cloudAt({0, 0, 1.0}, ground));
  const Index far_cell(12, 12), seen_cell(15, 15);
  // The next cloud (sensor moved 0.1 m) sees half of the cells 0.04 m higher: mean residual
  // 0.04 over 50 inliers (|0.04| < 2 sqrt(0.000625 + 0.0025)); shift 0.5 * 0.04 = 0.02 m.
  std::vector<PointXYZI> pts;
  for (int i = 15; i < 20; ++i)
    for (int j = 10; j < 20; ++j) {
      const Position p = map.geometry().positionOf(Index(i, j));
      pts.push_back({float(p.x() - 0.1), float(p.y()), -0.96f, 0});
    }
  const FusionStats s = f.fuse(map, ex, cloudAt({0.1, 0, 1.0}, pts));
  EXPECT_TRUE(s.drift_applied);
  EXPECT_EQ(s.drift_inliers, 50);
  EXPECT_NEAR(s.drift_m, 0.02, 1e-6);
  EXPECT_NEAR(layerAt(map, L::kElevation, far_cell), 0.02, 1e-6);  // not re-measured: only shifted
  // Re-measured: 0.02 (v 0.000625) fused with 0.04 (v 0.0025) -> 0.024.
  EXPECT_NEAR(layerAt(map, L::kElevation, seen_cell), 0.024, 1e-6);
  // Never without sensor motion (position_noise_thresh_m / orientation_noise_thresh_rad).
  const FusionStats s2 = f.fuse(map, ex, cloudAt({0.1, 0, 1.0}, pts));
  EXPECT_FALSE(s2.drift_applied);
}

// ---- determinism and a plain serial reference ------------------------------------------------

namespace {

/// Seeded synthetic scan: a 128 x 1024 spinning LiDAR over a sloped ground with boxes, plus
/// NaNs and far points, in the sensor frame (sensor 1.8 m above ground).
std::vector<PointXYZI> syntheticScan(std::uint32_t seed, int rows = 64, int cols = 512) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.0f, 0.02f);
  std::vector<PointXYZI> pts;
  for (int r = 0; r < rows; ++r) {
    const double elev = -0.45 + 0.4 * r / rows;  // rad
    for (int c = 0; c < cols; ++c) {
      const double az = 2 * M_PI * c / cols;
      if ((r * cols + c) % 997 == 0) {
        pts.push_back({kNaN, kNaN, kNaN, 0});
        continue;
      }
      const double dx = std::cos(elev) * std::cos(az), dy = std::cos(elev) * std::sin(az), dz = std::sin(elev);
      double range = dz < -0.01 ? 1.8 / -dz : 40.0;
      range = std::min(range, 40.0);
      double x = dx * range, y = dy * range, z = dz * range;
      if (x > 3 && x < 4 && y > -1 && y < 1 && dz > -0.3) z = std::max(z, -1.0);  // a box face
      pts.push_back({float(x) + noise(rng), float(y) + noise(rng), float(z) + noise(rng), 1.0f});
    }
  }
  return pts;
}

struct RunResult {
  std::vector<Eigen::MatrixXf> layers;
};

/// Scan k of a short drive: the sensor moves 0.4 m in x, 0.1 m in y and turns 0.05 rad per scan.
PointCloud movingScan(int k) {
  PointCloud pc;
  pc.stamp = 0.1 * k;
  pc.T_map_sensor = Eigen::Translation3d(0.4 * k, 0.1 * k, 1.8) * Eigen::AngleAxisd(0.05 * k, Eigen::Vector3d::UnitZ());
  pc.points = syntheticScan(42 + k);
  return pc;
}

RunResult runSequence(int threads, bool sparse, const LidarFusionConfig& c) {
  LayeredMap map(Geometry(0.1, Size(200, 200)), MapOptions{32, sparse});
  LidarFusion f;
  f.configure(c);
  f.attach(map);
  Executor ex(threads);
  RecordBus bus;
  PluginStats stats;
  ProcessContext ctx(map, ex, bus, stats, "lidar");
  for (int k = 0; k < 4; ++k) f.process(ctx, Event(movingScan(k)));
  RunResult r;
  for (const char* name : {L::kElevation, L::kVariance, L::kIsValid, L::kTimeSinceUpdate, L::kUpperBound,
                           L::kIsUpperBound, L::kHits})
    r.layers.push_back(map.toMatrix(map.layerId(name)));
  return r;
}

}  // namespace

TEST(LidarFusion, BitIdenticalAtOneAndTwoThreads) {
  LidarFusionConfig c;  // defaults: cleanup on, ramp on
  c.enable_drift_compensation = true;
  c.follow_robot = true;
  c.cleanup_ray_stride = 2;
  for (CleanupWalk walk : kWalks)
  for (bool sparse : {false, true}) {
    SCOPED_TRACE(walkName(walk));
    c.cleanup_walk = walk;
    const RunResult a = runSequence(1, sparse, c);
    const RunResult b = runSequence(2, sparse, c);
    ASSERT_EQ(a.layers.size(), b.layers.size());
    for (size_t l = 0; l < a.layers.size(); ++l) EXPECT_TRUE(sameBits(a.layers[l], b.layers[l])) << "layer " << l;
    // Sanity: something was mapped and bounded.
    EXPECT_GT((a.layers[0].array() == a.layers[0].array()).count(), 5000);
    EXPECT_GT((a.layers[5].array() == 1.0f).count(), 10);
  }
}

using BudgetGuard = terramap::test::MemoryBudgetScope;

TEST(LidarFusion, SparseMapAtItsMemoryBudgetDropsTheTilesItCannotHoldCounted) {
  // A sparse 40 x 40 map in tiles of 8 (25 per layer, 7 layers, 256 bytes a tile) with a budget
  // of 14 tiles: room for the 7 layers of two tiles. One cloud over four tiles: the two lowest
  // tile numbers (decided in tile order, whatever the thread count) are fused, the points of
  // the other two are dropped as "tile_budget", and nothing throws.
  for (int threads : {1, 2}) {
    LayeredMap map = makeMap(8, true);
    LidarFusion f;
    f.configure(plainConfig());
    f.attach(map);
    ASSERT_EQ(map.layerCount(), 8);  // survey_z too, allocated only where a survey lands
    BudgetGuard budget(14 * map.tileBytes());
    RecordBus bus;
    PluginStats stats;
    Executor ex(threads);
    ProcessContext ctx(map, ex, bus, stats, "lidar");
    // Rows i = 4, 14, 24, 34 (x = 1.55, 0.55, -0.45, -1.45): tile rows 0, 1, 3, 4; columns
    // 17..20 (y = 0.25 .. -0.05): tile column 2. Tiles 2, 7, 17, 22 with 3, 2, 4, 1 points.
    std::vector<PointXYZI> pts;
    auto add = [&](float x, std::initializer_list<float> ys) {
      for (float y : ys) pts.push_back({x, y, -0.5f, 0});
    };
    add(-0.45f, {0.05f, -0.05f, 0.15f, 0.25f});
    add(1.55f, {0.05f, -0.05f, 0.15f});
    add(-1.45f, {0.05f});
    add(0.55f, {0.05f, -0.05f});
    f.process(ctx, Event(cloudAt({0, 0, 0}, pts)));
    EXPECT_EQ(stats.dropped["tile_budget"], 5) << threads << " threads";
    EXPECT_EQ(stats.counters["points_fused"], 5.0);
    EXPECT_EQ(stats.counters["tile_budget_refusals"], 2.0);
    long dropped = 0;
    for (const auto& [k, v] : stats.dropped) dropped += v;
    EXPECT_EQ(stats.counters["points_in"], stats.counters["points_fused"] + stats.counters["outliers"] + dropped);
    EXPECT_EQ(map.allocatedTiles(), 14);
    EXPECT_FLOAT_EQ(layerAt(map, L::kElevation, cellOf(map, 1.55, 0.05)), -0.5f);
    EXPECT_FLOAT_EQ(layerAt(map, L::kElevation, cellOf(map, 0.55, -0.05)), -0.5f);
    EXPECT_TRUE(std::isnan(layerAt(map, L::kElevation, cellOf(map, -0.45, 0.05))));
    EXPECT_TRUE(std::isnan(layerAt(map, L::kElevation, cellOf(map, -1.45, 0.05))));
    // The tiles it holds keep taking points.
    f.process(ctx, Event(cloudAt({0, 0, 0}, {{1.55f, 0.05f, -0.5f, 0}, {-1.45f, 0.05f, -0.4f, 0}}, 0.1)));
    EXPECT_EQ(stats.counters["points_fused"], 6.0);
    EXPECT_EQ(stats.dropped["tile_budget"], 6);
    f.finish(ctx);
    ASSERT_EQ(stats.records.size(), 1u);
    EXPECT_NE(stats.records[0].find("\"tile_budget\":6"), std::string::npos) << stats.records[0];
  }
}

TEST(LidarFusion, SparseMapAtItsMemoryBudgetIsBitIdenticalAtOneAndTwoThreads) {
  // The full plugin (cleanup with ray bounds and penetration, drift, following the sensor) on
  // a sparse map whose budget holds less than the scans cover: which tiles exist and what they
  // hold do not depend on the thread count, and the map never exceeds the budget.
  LidarFusionConfig c;
  c.enable_drift_compensation = true;
  c.follow_robot = true;
  c.cleanup_ray_stride = 2;
  auto run = [&](int threads, PluginStats& stats) {
    LayeredMap map(Geometry(0.1, Size(200, 200)), MapOptions{32, true});
    LidarFusion f;
    f.configure(c);
    f.attach(map);
    BudgetGuard budget(100 * map.tileBytes());
    Executor ex(threads);
    RecordBus bus;
    ProcessContext ctx(map, ex, bus, stats, "lidar");
    for (int k = 0; k < 4; ++k) {
      f.process(ctx, Event(movingScan(k)));
      EXPECT_LE(map.allocatedTiles(), 100);
    }
    std::vector<Eigen::MatrixXf> layers;
    for (const auto& name : map.layerNames()) layers.push_back(map.toMatrix(map.layerId(name)));
    return layers;
  };
  PluginStats s1, s2;
  const auto a = run(1, s1), b = run(2, s2);
  for (size_t l = 0; l < a.size(); ++l) EXPECT_TRUE(sameBits(a[l], b[l])) << "layer " << l;
  EXPECT_GT(s1.dropped["tile_budget"], 0);
  EXPECT_EQ(s1.dropped, s2.dropped);
  EXPECT_EQ(s1.counters, s2.counters);
  EXPECT_GT((a[0].array() == a[0].array()).count(), 1000);  // it still maps what it holds
}

TEST(LidarFusion, MatchesAPlainSerialPerPointLoop) {
  // Reference: a plain per-point loop over a std::map keyed by (i, j), written from the
  // ALGORITHMS.md text, not from the plugin. With the same float formulas in the same
  // per-cell order the layers must agree bit for bit.
  LidarFusionConfig c;
  c.enable_visibility_cleanup = false;
  const std::vector<PointXYZI> pts = syntheticScan(7, 128, 1024);
  Eigen::Isometry3d T = Eigen::Translation3d(0.3, -0.2, 1.8) * Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ());
  Geometry g(0.05, Size(400, 400));
  LayeredMap map(g, MapOptions{64, false});
  LidarFusion f;
  f.configure(c);
  f.attach(map);
  Executor ex(2);
  PointCloud pc;
  pc.T_map_sensor = T;
  pc.points = pts;
  const FusionStats s = f.fuse(map, ex, pc);

  struct Cell { float h = kNaN, v = kNaN; int hits = 0; };
  std::map<std::pair<int, int>, Cell> ref;
  long fused = 0, outl = 0;
  for (const PointXYZI& p : pts) {
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) continue;
    const Eigen::Vector3d ps(p.x, p.y, p.z);
    const double r = ps.norm();
    if (r < c.min_range_m || r > c.max_range_m) continue;
    const Eigen::Matrix3d Rm = T.linear();
    const Eigen::Vector3d t = T.translation();
    const Eigen::Vector3d pm(Rm(0, 0) * ps.x() + Rm(0, 1) * ps.y() + Rm(0, 2) * ps.z() + t.x(),
                             Rm(1, 0) * ps.x() + Rm(1, 1) * ps.y() + Rm(1, 2) * ps.z() + t.y(),
                             Rm(2, 0) * ps.x() + Rm(2, 1) * ps.y() + Rm(2, 2) * ps.z() + t.z());
    const double dz = pm.z() - T.translation().z();
    const double dxy = (pm - T.translation()).head<2>().norm();
    if (dz > c.max_height_above_sensor_m) continue;
    if (dz > std::max(dxy - c.ramped_height_range_b_m, 0.0) * c.ramped_height_range_a + c.ramped_height_range_c_m)
      continue;
    const auto idx = g.indexAt(pm.head<2>());
    if (!idx) continue;
    const double sigma = c.range_noise_a_m + c.range_noise_b * r;
    const float vp = float(std::max(sigma * sigma, c.min_variance_m2)), z = float(pm.z());
    const float vmin = float(c.min_variance_m2);
    Cell& cell = ref[{idx->x(), idx->y()}];
    if (std::isnan(cell.h)) {
      cell.h = z;
      cell.v = vp;
    } else {
      const float k2 = float(c.mahalanobis_thresh * c.mahalanobis_thresh);
      cell.v = std::max(cell.v, vmin);
      if ((z - cell.h) * (z - cell.h) > k2 * (cell.v + vp)) {
        cell.v += float(c.outlier_variance_m2);
        ++outl;
        continue;
      }
      const float s2 = cell.v + vp;
      cell.h = (cell.h * vp + z * cell.v) / s2;
      cell.v = std::max((cell.v * vp) / s2, vmin);
    }
    ++cell.hits;
    ++fused;
  }
  EXPECT_EQ(s.points_fused, fused);
  EXPECT_EQ(s.outliers, outl);
  EXPECT_GT(fused, 50000);
  const Eigen::MatrixXf E = map.toMatrix(map.layerId(L::kElevation));
  const Eigen::MatrixXf V = map.toMatrix(map.layerId(L::kVariance));
  const Eigen::MatrixXf H = map.toMatrix(map.layerId(L::kHits));
  long known = 0, mismatches = 0;
  for (int i = 0; i < 400; ++i)
    for (int j = 0; j < 400; ++j) {
      auto it = ref.find({i, j});
      if (it == ref.end()) {
        mismatches += !std::isnan(E(i, j));
        continue;
      }
      ++known;
      mismatches += std::memcmp(&E(i, j), &it->second.h, 4) != 0;
      mismatches += std::memcmp(&V(i, j), &it->second.v, 4) != 0;
      mismatches += H(i, j) != float(it->second.hits);
    }
  EXPECT_EQ(mismatches, 0);
  EXPECT_GT(known, 10000);
}

TEST(LidarFusion, VectorAndScalarGatesAgreeBitForBit) {
#if defined(__x86_64__) && defined(__GNUC__)
  if (!__builtin_cpu_supports("avx2")) GTEST_SKIP() << "no AVX2 on this CPU: only the scalar gates run";
#else
  GTEST_SKIP() << "the AVX2 gate kernel is x86-64 only";
#endif
  // A resolution exact in binary (0.25 m) so that points on cell edges give integral
  // (xmax - x) / res and exercise the ceil(f) - 1 branch; points exactly at min_range_m,
  // at max_height_above_sensor_m and on the ramp; NaN/inf; a tail that is not a multiple of
  // the vector width; several chunks (> 8192 points); a rotated, translated sensor.
  std::vector<PointXYZI> pts = syntheticScan(11, 96, 512);
  const float inf = std::numeric_limits<float>::infinity();
  for (int i = -8; i <= 8; ++i)
    for (int j = -8; j <= 8; ++j) pts.push_back({0.25f * i, 0.25f * j, -1.5f + 0.01f * i, 0});
  pts.push_back({0.5f, 0.0f, 0.0f, 0});     // r == min_range_m: kept by the range gate
  pts.push_back({0.0f, 0.0f, 1.0f, 0});     // dz == max_height_above_sensor_m
  pts.push_back({1.8f, 0.0f, 0.44f, 0});    // near the ramp
  pts.push_back({inf, 0.0f, 0.0f, 0});
  pts.push_back({0.0f, -inf, 0.0f, 0});
  pts.push_back({0.0f, 0.0f, kNaN, 0});
  pts.push_back({1e30f, 1e30f, 1e30f, 0});  // too far
  // Horizontal beams: depth_squared gives v = 0 there, so the variance floor's lane runs too.
  for (int i = 0; i < 21; ++i) pts.push_back({0.6f + 0.25f * i, 0.3f, 0.0f, 0});
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-30.0f, 30.0f);
  for (int i = 0; i < 1003; ++i) pts.push_back({u(rng), u(rng), 0.1f * u(rng), 0});
  ASSERT_GT(pts.size(), 2u * 8192u);
  for (int variant = 0; variant < 2; ++variant) {
    LidarFusionConfig c;
    c.cleanup_ray_stride = 3;
    if (variant == 1) {
      c.noise_model = NoiseModel::DepthSquared;
      c.enable_ramped_height_range = false;
      c.max_range_m = 25.0;
    }
    std::vector<Eigen::MatrixXf> layers[2];
    FusionStats stats[2];
    for (int scalar = 0; scalar < 2; ++scalar) {
      LayeredMap map(Geometry(0.25, Size(120, 120)), MapOptions{16, false});
      LidarFusion f;
      f.configure(c);
      f.forceScalarGates(scalar == 1);
      f.attach(map);
      Executor ex(2);
      PointCloud pc;
      pc.T_map_sensor = Eigen::Translation3d(0.25, -0.5, 1.0) * Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitZ());
      pc.points = pts;
      f.fuse(map, ex, pc);
      pc.T_map_sensor = Eigen::Translation3d(0.0, 0.0, 1.0) * Eigen::AngleAxisd(0.0, Eigen::Vector3d::UnitZ());
      stats[scalar] = f.fuse(map, ex, pc);  // identity rotation: edge points stay on edges
      for (const char* name : {L::kElevation, L::kVariance, L::kIsValid, L::kTimeSinceUpdate, L::kUpperBound,
                               L::kIsUpperBound, L::kHits})
        layers[scalar].push_back(map.toMatrix(map.layerId(name)));
    }
    for (size_t l = 0; l < layers[0].size(); ++l)
      EXPECT_TRUE(sameBits(layers[0][l], layers[1][l])) << "variant " << variant << " layer " << l;
    const FusionStats &a = stats[0], &b = stats[1];
    EXPECT_EQ(a.dropped_non_finite, b.dropped_non_finite);
    EXPECT_EQ(a.dropped_too_close, b.dropped_too_close);
    EXPECT_EQ(a.dropped_too_far, b.dropped_too_far);
    EXPECT_EQ(a.dropped_too_high, b.dropped_too_high);
    EXPECT_EQ(a.dropped_outside_map, b.dropped_outside_map);
    EXPECT_EQ(a.points_fused, b.points_fused);
    EXPECT_EQ(a.rays, b.rays);
    EXPECT_EQ(a.ray_cells, b.ray_cells);
    // Every gate fired, so every lane path of the kernel was compared.
    EXPECT_GT(a.dropped_non_finite, 3);
    EXPECT_GT(a.dropped_too_far, 0);
    EXPECT_GT(a.dropped_too_high, 0);
    EXPECT_GT(a.dropped_outside_map, 0);
    EXPECT_GT(a.points_fused, 10000);
  }
}

TEST(LidarFusion, OneChunkCloudsWithCleanupAtTwoThreads) {
  // A cloud of one chunk runs its ray walk inline on the calling thread even with a 2-thread
  // executor (outside the arena): its upper bounds must land as with 1 thread, also when the
  // next, multi-chunk cloud runs on the arena's threads.
  LidarFusionConfig c = plainConfig();
  c.enable_visibility_cleanup = true;
  c.cleanup_ray_stride = 1;
  for (CleanupWalk walk : kWalks) {
  SCOPED_TRACE(walkName(walk));
  c.cleanup_walk = walk;
  std::vector<Eigen::MatrixXf> layers[2];
  for (int threads : {1, 2}) {
    LayeredMap map = makeMap();
    LidarFusion f;
    f.configure(c);
    f.attach(map);
    Executor ex(threads);
    f.fuse(map, ex, cloudAt({0.0, 0.05, 1.0}, {{1.55f, 0.0f, -1.0f, 0}, {-1.2f, 0.7f, -1.2f, 0}}));
    f.fuse(map, ex, cloudAt({0.1, 0.0, 1.0}, syntheticScan(3, 40, 512)));
    for (const char* name : {L::kElevation, L::kUpperBound, L::kIsUpperBound, L::kIsValid})
      layers[threads - 1].push_back(map.toMatrix(map.layerId(name)));
  }
  for (size_t l = 0; l < layers[0].size(); ++l) EXPECT_TRUE(sameBits(layers[0][l], layers[1][l])) << "layer " << l;
  // Rays did bound unknown cells, so the comparison above is not vacuous.
  EXPECT_GT((layers[1][2].array() == 1.0f).count(), 100);
  }
}
