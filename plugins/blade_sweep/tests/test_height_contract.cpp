// The height contract (docs/height_contract.md) between blade_sweep and lidar_fusion: after a
// blind cut made with a wrong blade height, LiDAR returns of the real new surface must be fused
// (gated against the blade's sigma, not the stale, tiny LiDAR variance of the old surface) and
// the cell must converge to the truth.
#include <gtest/gtest.h>

#include "lidar_fusion.hpp"
#include "sweep_test_util.hpp"

#include <cmath>
#include <random>

using namespace terramap;
using namespace terramap::plugins;
using namespace terramap::plugins::test;
using FL = LidarFusionLayers;

namespace {

// The scenario's numbers, in one place so the bounds below can be derived from them.
constexpr double kTruthCut = -0.10;     // real blade edge: cuts 10 cm into flat ground at z = 0
constexpr double kBladeError = 0.06;    // the blade pose the mapper gets is 6 cm too high
constexpr double kSigmaSv = 0.05;       // ... and blade_sweep's sigma_sv_m says 5 cm (1.2 sigma off)
constexpr double kPointNoise = 0.005;   // 1 sigma of the simulated returns (the fusion assumes more)
constexpr double kSensorZ = 2.0;        // sensor 2 m above the origin
constexpr int kPriorClouds = 50;        // clouds of the flat ground before the cut
constexpr int kNewClouds = 20;          // clouds of the cut surface after it
constexpr double kTimeVariance = 0.0005;  // lidar_fusion's default growth (m^2/s)
constexpr double kDt = 0.2;             // from the cut to the first cloud that sees it (s)

struct Outcome {
  std::vector<Index> cut_cells;
  std::vector<FusionStats> after;  // per cloud after the cut
  std::vector<float> var_after_cut, sigma_after_cut, valid_after_cut, ub_after_cut, elev_after_cut;
  std::vector<float> var_after_time;
  std::vector<float> elev_final, var_final, valid_final;
  std::vector<float> elev_after_first;
};

// One cloud: a return at every cell centre of `cells`, true height `truth(x, y)` plus noise.
PointCloud cloudOf(const LayeredMap& map, const std::vector<Index>& cells, double stamp, std::mt19937& rng,
                   double truth) {
  std::normal_distribution<double> n(0.0, kPointNoise);
  PointCloud pc;
  pc.stamp = stamp;
  pc.T_map_sensor = Eigen::Isometry3d::Identity();
  pc.T_map_sensor.translation() = Eigen::Vector3d(0, 0, kSensorZ);
  for (const Index& c : cells) {
    const Position p = map.geometry().positionOf(c);
    pc.points.push_back({static_cast<float>(p.x()), static_cast<float>(p.y()),
                         static_cast<float>(truth + n(rng) - kSensorZ), 0});
  }
  return pc;
}

// contract = false runs the same scenario with lidar_fusion's layers hidden from blade_sweep
// (what every version before the contract did): the switch the test is checked against.
Outcome run(bool contract, int threads) {
  LayeredMap map(Geometry(0.1, Size(40, 40)), MapOptions{8, false});  // x, y in [-2, 2)
  LidarFusion fusion;
  LidarFusionConfig fc;
  fc.enable_visibility_cleanup = false;  // no rays: only the gate and the update are under test
  fc.enable_ramped_height_range = false;
  fc.time_variance_m2_per_s = kTimeVariance;
  fusion.configure(fc);
  fusion.attach(map);
  map.addLayer("loose", "m", 0.0f);
  map.addLayer("height_sigma", "m");
  SweepLayers ids = SweepLayers::of(map);
  if (!contract) ids.variance = ids.is_valid = ids.upper_bound = ids.is_upper_bound = -1;
  Executor ex(threads);
  std::mt19937 rng(11);

  // Flat ground at 0 m, well measured: |x| < 1.5, |y| < 1.
  std::vector<Index> ground;
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 40; ++j) {
      const Position p = map.geometry().positionOf(Index(i, j));
      if (std::abs(p.x()) < 1.5 && std::abs(p.y()) < 1.0) ground.emplace_back(i, j);
    }
  double t = 0.0;
  fusion.advanceTime(map, ex, t);  // fuse() leaves time to its caller (process() does both)
  for (int k = 0; k < kPriorClouds; ++k) fusion.fuse(map, ex, cloudOf(map, ground, t, rng, 0.0));

  // The blind cut: a 1 m blade pushed +x from x = -1 to x = 1 with its edge at the height the
  // mapper believes, kTruthCut + kBladeError.
  const double edge_z = kTruthCut + kBladeError;
  std::vector<BladePose> hist{bladePose(t, Eigen::Vector3d(-1.0, 0, edge_z), bladeRotation(0), 1.0),
                              bladePose(t + 0.5, Eigen::Vector3d(1.0, 0, edge_z), bladeRotation(0), 1.0)};
  SweepConfig sc;
  sc.sigma_sv_m = kSigmaSv;
  runSweep(map, ids, sc, hist, ex);

  Outcome o;
  const LayerId E = map.layerId(FL::kElevation), V = map.layerId(FL::kVariance), VAL = map.layerId(FL::kIsValid),
                UB = map.layerId(FL::kUpperBound), S = map.layerId("height_sigma");
  for (const Index& c : ground)
    if (map.at(E, c) == static_cast<float>(edge_z)) o.cut_cells.push_back(c);
  for (const Index& c : o.cut_cells) {
    o.var_after_cut.push_back(map.at(V, c));
    o.sigma_after_cut.push_back(map.at(S, c));
    o.valid_after_cut.push_back(map.at(VAL, c));
    o.ub_after_cut.push_back(map.at(UB, c));
    o.elev_after_cut.push_back(map.at(E, c));
  }
  // Time runs on: lidar_fusion's growth applies to what the blade wrote.
  t += kDt;
  fusion.advanceTime(map, ex, t);
  for (const Index& c : o.cut_cells) o.var_after_time.push_back(map.at(V, c));

  // The LiDAR sees the real new surface (it comes out from behind the blade).
  for (int k = 0; k < kNewClouds; ++k) {
    o.after.push_back(fusion.fuse(map, ex, cloudOf(map, o.cut_cells, t, rng, kTruthCut)));
    if (k == 0)
      for (const Index& c : o.cut_cells) o.elev_after_first.push_back(map.at(E, c));
  }
  for (const Index& c : o.cut_cells) {
    o.elev_final.push_back(map.at(E, c));
    o.var_final.push_back(map.at(V, c));
    o.valid_final.push_back(map.at(VAL, c));
  }
  return o;
}

}  // namespace

TEST(BladeFusionContract, CutCellsCarryTheBladeSigmaAsVariance) {
  const Outcome o = run(true, 1);
  // 1 m blade over 2 m of travel at 0.1 m: about 10 x 20 cut cells.
  ASSERT_GE(o.cut_cells.size(), 150u);
  for (size_t k = 0; k < o.cut_cells.size(); ++k) {
    // A cut replaces the height, so its variance is the blade's sigma^2 (height_sigma^2; the
    // ground had never been changed blind, so height_sigma = sigma_sv_m).
    EXPECT_EQ(o.sigma_after_cut[k], static_cast<float>(kSigmaSv));
    EXPECT_FLOAT_EQ(o.var_after_cut[k], static_cast<float>(kSigmaSv * kSigmaSv));
    EXPECT_EQ(o.valid_after_cut[k], 1.0f);
    EXPECT_EQ(o.ub_after_cut[k], o.elev_after_cut[k]);  // valid cell: upper_bound = elevation
    // advanceTime grows the blade-written variance like any fused one.
    EXPECT_FLOAT_EQ(o.var_after_time[k], static_cast<float>(kSigmaSv * kSigmaSv + kTimeVariance * kDt));
  }
}

TEST(BladeFusionContract, ReturnsAfterABlindCutAreFusedAndConverge) {
  const Outcome o = run(true, 2);
  ASSERT_GE(o.cut_cells.size(), 150u);
  // Gate of the first return: |z - h| = |kBladeError + n| <= 0.06 + 4 * 0.005 = 0.08 m (4 sigma
  // of the simulated noise), against k sqrt(v + v_p) = 2 sqrt(0.0025 + 0.0001 + v_p) >= 0.11 m.
  // Later returns see a smaller residual. So no return may be an outlier.
  for (size_t k = 0; k < o.after.size(); ++k) {
    EXPECT_EQ(o.after[k].outliers, 0) << "cloud " << k;
    EXPECT_EQ(o.after[k].points_fused, static_cast<long>(o.cut_cells.size())) << "cloud " << k;
  }
  // Convergence: the fused height is the precision-weighted mean of the prior (the blade's
  // height, error kBladeError, variance v0 = 0.0025 + 0.0001) and M returns of variance
  // v_p = (a + b r)^2 with a = 0.02, b = 0.001, r <= sqrt(2.1^2 + 1.0^2 + 0.55^2) < 2.4 m, so
  // v_p <= 0.0224^2. The prior's weight is (1/v0) / (1/v0 + M/v_p) <= 385 / (385 + 20 * 1993)
  // = 0.0096: a 0.6 mm residue of the blade error. The returns' noise averages to a weighted
  // mean of M = 20 errors of sigma 5 mm: sigma <= 5 mm / sqrt(20) (1 + 0.0096) = 1.13 mm; 5 sigma
  // (over ~200 cells) is 5.6 mm. Bound: about 6.2 mm.
  const double v0 = kSigmaSv * kSigmaSv + kTimeVariance * kDt;
  const double vp_max = std::pow(0.02 + 0.001 * 2.4, 2);
  const double w0 = (1 / v0) / (1 / v0 + kNewClouds / vp_max);
  const double bound = kBladeError * w0 + 5.0 * kPointNoise / std::sqrt(double(kNewClouds)) * (1 + w0);
  double worst = 0;
  for (size_t k = 0; k < o.cut_cells.size(); ++k) {
    worst = std::max(worst, std::abs(o.elev_final[k] - kTruthCut));
    EXPECT_EQ(o.valid_final[k], 1.0f);
    EXPECT_TRUE(std::isfinite(o.var_final[k]));
  }
  EXPECT_LT(worst, bound);
  // And one cloud already moves most of the way: weight v0 / (v0 + v_p) >= 0.0026 / 0.0031 = 0.84
  // of the error, so at most 16 % (9.7 mm) of it stays, plus 5 sigma of one return (25 mm).
  for (size_t k = 0; k < o.cut_cells.size(); ++k)
    EXPECT_LT(std::abs(o.elev_after_first[k] - kTruthCut), kBladeError * (vp_max / (v0 + vp_max)) + 5 * kPointNoise);
}

TEST(BladeFusionContract, WithoutTheContractTheReturnsAreRejected) {
  // The failure the contract removes: the cut cells keep the variance of 50 flat-ground clouds
  // (v_p / 50 ~ 1e-5, + 0.0001 of time growth), and the first returns of the real surface,
  // 0.06 +- 0.005 m away, face the gate 2 sqrt(1.1e-4 + v_p <= 5.02e-4) <= 0.0495 m: one passes
  // only if its noise is below -10.5 mm (2.1 sigma, 2 %). Nearly all are rejected as outliers.
  const Outcome o = run(false, 1);
  ASSERT_GE(o.cut_cells.size(), 150u);
  EXPECT_GT(o.after[0].outliers, static_cast<long>(o.cut_cells.size() / 2));
  const Outcome with = run(true, 1);
  EXPECT_EQ(with.after[0].outliers, 0);
}

TEST(BladeFusionContract, BitIdenticalAtOneAndTwoThreads) {
  const Outcome a = run(true, 1), b = run(true, 2);
  ASSERT_EQ(a.cut_cells.size(), b.cut_cells.size());
  for (size_t k = 0; k < a.cut_cells.size(); ++k) {
    EXPECT_EQ(a.var_after_cut[k], b.var_after_cut[k]);
    EXPECT_EQ(a.elev_final[k], b.elev_final[k]);
    EXPECT_EQ(a.var_final[k], b.var_final[k]);
  }
}
