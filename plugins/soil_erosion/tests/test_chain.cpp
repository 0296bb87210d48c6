// blade_sweep followed by soil_erosion on the same events: soil mass Σ[(H - L) + L/s]
// conserved through cut, deposit and erosion, masks respected, bit-identical at 1 and 2 threads.
#include <gtest/gtest.h>

#include <cstring>
#include <limits>

#include "blade_sweep.hpp"
#include "soil_erosion.hpp"

using namespace terramap;
using namespace terramap::plugins;

namespace {

struct Chain {
  LayeredMap map;
  LayerId h, l, s;
  Executor ex;
  RecordBus bus;
  PluginStats blade_stats, erosion_stats;
  ProcessContext blade_ctx, erosion_ctx;
  BladeSweep blade;
  SoilErosion erosion;
  // contract: also lidar_fusion's layers (docs/height_contract.md), as the LiDAR would have
  // left them: variance kLidarVar and is_valid kLidarValid on the known ground, upper_bound =
  // elevation there; a patch of unseen ground ahead of the blade with a ray upper bound.
  static constexpr float kLidarVar = 1e-4f, kLidarValid = 0.8f, kRayBound = 0.3f;
  LayerId var = -1, valid = -1, ub = -1, isub = -1;
  Chain(int threads, double cohesion, bool contract = false)
      : map(Geometry(0.05, Size(160, 160))),
        h(map.addLayer("elevation", "m")),
        l(map.addLayer("loose", "m", 0.0f)),
        s(map.addLayer("height_sigma", "m")),
        ex(threads),
        blade_ctx(map, ex, bus, blade_stats, "blade"),
        erosion_ctx(map, ex, bus, erosion_stats, "erode") {
    Eigen::MatrixXf m(160, 160);
    for (int i = 0; i < 160; ++i)
      for (int j = 0; j < 160; ++j) {
        const Position p = map.geometry().positionOf(Index(i, j));
        m(i, j) = static_cast<float>(0.05 * std::sin(1.3 * p.x()) + 0.03 * std::cos(0.9 * p.y()));
      }
    if (contract) {
      var = map.addLayer("variance", "m^2");
      valid = map.addLayer("is_valid", "1", 0.0f);
      ub = map.addLayer("upper_bound", "m");
      isub = map.addLayer("is_upper_bound", "1", 0.0f);
      Eigen::MatrixXf v(160, 160), val(160, 160), u(160, 160), iu(160, 160);
      for (int i = 0; i < 160; ++i)
        for (int j = 0; j < 160; ++j) {
          const Position p = map.geometry().positionOf(Index(i, j));
          const bool unseen = p.x() > 0.9 && p.x() < 1.3 && std::abs(p.y()) < 0.6;
          if (unseen) m(i, j) = std::numeric_limits<float>::quiet_NaN();
          v(i, j) = unseen ? m(i, j) : kLidarVar;
          val(i, j) = unseen ? 0.0f : kLidarValid;
          u(i, j) = unseen ? kRayBound : m(i, j);
          iu(i, j) = unseen ? 1.0f : 0.0f;
        }
      map.fromMatrix(var, v);
      map.fromMatrix(valid, val);
      map.fromMatrix(ub, u);
      map.fromMatrix(isub, iu);
    }
    map.fromMatrix(h, m);
    blade.configure(makeParams("blade", blade.schema()));
    erosion.configure(makeParams("erode", erosion.schema(), {{"cohesion_pa", cohesion}}));
    blade.start(blade_ctx);
    erosion.start(erosion_ctx);
  }
  void push(const BladePose& p) {
    blade.process(blade_ctx, Event(p));
    erosion.process(erosion_ctx, Event(p));
  }
  double mass(double swell) const {
    const Eigen::MatrixXf H = map.toMatrix(h), L = map.toMatrix(l);
    double m = 0;
    for (int i = 0; i < H.rows(); ++i)
      for (int j = 0; j < H.cols(); ++j) {
        const double lo = std::isfinite(L(i, j)) ? L(i, j) : 0.0;
        m += std::isfinite(H(i, j)) ? (H(i, j) - lo) + lo / swell : lo / swell;
      }
    return m * 0.05 * 0.05;
  }
};

BladePose poseAt(int k) {
  BladePose p;
  p.stamp = 0.1 * k;
  p.machine_id = "ctl";
  const double t = 0.1 * k;
  p.T_map_blade.linear() =
      (Eigen::AngleAxisd(0.3 * std::sin(0.4 * t), Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(0.03, Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  p.T_map_blade.translation() = Eigen::Vector3d(-2.5 + 0.07 * k, 0.2 * std::sin(0.3 * t), -0.08);
  return p;
}

}  // namespace

TEST(Chain, MassConservedThroughCutDepositAndErosion) {
  for (double c : {0.0, 25.0}) {
    Chain ch(2, c);
    const double m0 = ch.mass(1.2);
    double lost = 0;
    for (int k = 0; k <= 60; ++k) {
      ch.push(poseAt(k));
      if (auto r = ch.bus.latestAs<SweepRecord>(SweepRecord::kType)) lost = ch.blade_stats.counters["lost_volume_m3"];
    }
    EXPECT_GT(ch.erosion.passesRun(), 10);
    EXPECT_GT(ch.erosion_stats.counters["eroded_volume_m3"], 0.001);
    EXPECT_NEAR(ch.mass(1.2) + lost / 1.2, m0, 160 * 160 * 1e-7 * 0.0025) << c;
    // While the blade stands, the surcharge rests against it (masked cells). Lift the blade
    // away (erode on Tick without the masks) and the deposit wall collapses: no neighbour pair
    // differs by more than 0.25 m (the trench walls are undisturbed soil and stay).
    SoilErosion lifted;
    lifted.configure(makeParams("lifted", lifted.schema(),
                                {{"cohesion_pa", c}, {"blade_mask", false}, {"trigger", std::string("sweep_and_tick")}, {"passes", 20L}}));
    lifted.start(ch.erosion_ctx);
    lifted.process(ch.erosion_ctx, Event(Tick{100.0}));
    EXPECT_NEAR(ch.mass(1.2) + lost / 1.2, m0, 160 * 160 * 1e-7 * 0.0025) << c;
    const Eigen::MatrixXf H = ch.map.toMatrix(ch.h);
    float worst = 0;
    for (int i = 0; i + 1 < 160; ++i)
      for (int j = 0; j < 160; ++j) worst = std::max(worst, std::abs(H(i, j) - H(i + 1, j)));
    EXPECT_LT(worst, 0.25f);
  }
}

TEST(Chain, WithoutErosionTheDepositWallStands) {
  Chain ch(1, 0.0);
  for (int k = 0; k <= 60; ++k) ch.blade.process(ch.blade_ctx, Event(poseAt(k)));
  const Eigen::MatrixXf H = ch.map.toMatrix(ch.h);
  float worst = 0;
  for (int i = 0; i + 1 < 160; ++i)
    for (int j = 0; j < 160; ++j) worst = std::max(worst, std::abs(H(i, j) - H(i + 1, j)));
  EXPECT_GT(worst, 0.25f);
}

TEST(Chain, BitIdenticalAtOneAndTwoThreads) {
  Chain a(1, 25.0), b(2, 25.0);
  for (int k = 0; k <= 60; ++k) {
    a.push(poseAt(k));
    b.push(poseAt(k));
  }
  for (LayerId id : {a.h, a.l, a.s}) {
    const Eigen::MatrixXf ma = a.map.toMatrix(id), mb = b.map.toMatrix(id);
    EXPECT_EQ(std::memcmp(ma.data(), mb.data(), sizeof(float) * static_cast<size_t>(ma.size())), 0);
  }
}

TEST(Chain, ErosionOnTickOnlyWhenAsked) {
  Chain ch(1, 0.0);
  for (int k = 0; k <= 10; ++k) ch.push(poseAt(k));
  const long after_sweeps = ch.erosion.passesRun();
  ch.erosion.process(ch.erosion_ctx, Event(Tick{2.0}));
  EXPECT_EQ(ch.erosion.passesRun(), after_sweeps);
  SoilErosion ticking;
  ticking.configure(makeParams("erode", ticking.schema(), {{"trigger", std::string("sweep_and_tick")}}));
  ticking.start(ch.erosion_ctx);
  ticking.process(ch.erosion_ctx, Event(Tick{2.0}));
  EXPECT_EQ(ticking.passesRun(), 1);
}

// Every blind height change keeps lidar_fusion's layers consistent (docs/height_contract.md):
// a cell cut at some point has variance = height_sigma^2 (the cut replaced it, later deposits and
// slips added to both alike) and is_valid = 1; a known cell only deposited on or slipped has
// variance = LiDAR variance + height_sigma^2 and keeps its is_valid; a cell never changed keeps
// both; known cells have upper_bound = elevation; soil dropped on unseen ground clears the ray
// bound there. Checked after 60 poses of cutting, depositing and eroding, at 1 and 2 threads
// (bit-identical).
TEST(Chain, HeightContractLayersFollowEveryChange) {
  Chain a(1, 25.0, true), b(2, 25.0, true);
  for (int k = 0; k <= 60; ++k) {
    a.push(poseAt(k));
    b.push(poseAt(k));
  }
  for (LayerId id : {a.var, a.valid, a.ub, a.isub}) {
    const Eigen::MatrixXf ma = a.map.toMatrix(id), mb = b.map.toMatrix(id);
    EXPECT_EQ(std::memcmp(ma.data(), mb.data(), sizeof(float) * static_cast<size_t>(ma.size())), 0);
  }
  const Eigen::MatrixXf H = a.map.toMatrix(a.h), L = a.map.toMatrix(a.l), S = a.map.toMatrix(a.s),
                        V = a.map.toMatrix(a.var), VAL = a.map.toMatrix(a.valid), U = a.map.toMatrix(a.ub),
                        IU = a.map.toMatrix(a.isub);
  long cut = 0, added = 0, untouched = 0, cleared = 0, kept_bounds = 0;
  for (int i = 0; i < 160; ++i)
    for (int j = 0; j < 160; ++j) {
      if (!std::isfinite(H(i, j))) {
        EXPECT_TRUE(std::isnan(V(i, j)));
        if (L(i, j) > 0) {  // soil on unseen ground: the ray bound no longer holds
          EXPECT_TRUE(std::isnan(U(i, j)));
          EXPECT_EQ(IU(i, j), 0.0f);
          ++cleared;
        } else {
          EXPECT_EQ(U(i, j), Chain::kRayBound);
          ++kept_bounds;
        }
        continue;
      }
      EXPECT_EQ(U(i, j), H(i, j));
      EXPECT_EQ(IU(i, j), 0.0f);
      if (!std::isfinite(S(i, j))) {
        EXPECT_EQ(V(i, j), Chain::kLidarVar);
        EXPECT_EQ(VAL(i, j), Chain::kLidarValid);
        ++untouched;
        continue;
      }
      // Both are sums of the same squared increments in double, stored as float: equal to
      // float rounding (a relative 1e-6 of the larger term).
      const double s2 = double(S(i, j)) * S(i, j);
      if (VAL(i, j) == 1.0f) {
        EXPECT_NEAR(V(i, j), s2, 1e-6 * s2 + 1e-12) << i << "," << j;
        ++cut;
      } else {
        EXPECT_EQ(VAL(i, j), Chain::kLidarValid);
        EXPECT_NEAR(V(i, j), Chain::kLidarVar + s2, 1e-6 * (Chain::kLidarVar + s2)) << i << "," << j;
        ++added;
      }
    }
  EXPECT_GT(cut, 500);
  EXPECT_GT(added, 20);
  EXPECT_GT(untouched, 10000);
  EXPECT_GT(cleared, 0);
  EXPECT_GT(kept_bounds, 0);
}
