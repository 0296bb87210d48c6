// The two ways the soil a blade pushes can reach the FEE's surcharge besides the mapped loose
// soil ahead of the edge (docs/soil_estimator.md, "The surcharge the map holds"): the pile the
// blade's own bookkeeping carries (surcharge_carried), and a loose layer that follows what the
// sensors show (loose_follows_elevation). Expectations are hand counts on flat ground.
#include <gtest/gtest.h>

#include "sweep_test_util.hpp"

using namespace terramap;
using namespace terramap::plugins;
using namespace terramap::plugins::test;

namespace {

// A blade cutting flat ground 5 cm deep along +x (or back along -x), 0.2 m per sweep: each
// forward sweep cuts 0.2 x 1.85 x 0.05 = 0.0185 m^3 of bank soil (up to a cell at the ends).
struct Pass {
  TestMap tm{0.05, 240};
  SweepConfig cfg;
  CarriedPile pile;
  double x = -5.0;
  explicit Pass(bool carried) {
    tm.setElevation([](const Position&) { return 0.0; });
    cfg.surcharge_carried = carried;
  }
  std::shared_ptr<SweepRecord> sweep(double dx, double z = -0.05) {
    std::vector<BladePose> hist;
    for (int k = 0; k <= 2; ++k)
      hist.push_back(bladePose(k * 0.1, Eigen::Vector3d(x + dx * k / 2.0, 0, z), bladeRotation(0)));
    x += dx;
    return runSweep(tm.map, tm.ids, cfg, hist, Executor(1), &pile);
  }
};

}  // namespace

TEST(CarriedSurcharge, TheQIsTheBankSoilCutSinceThePassBegan) {
  Pass on(true), off(false);
  double cut = 0.0;
  for (int s = 0; s < 12; ++s) {
    const double before = cut;
    const auto r = on.sweep(0.2);
    const auto m = off.sweep(0.2);
    ASSERT_TRUE(r && m);
    cut += r->cut_bank_volume_m3;
    EXPECT_NEAR(r->cut_bank_volume_m3, 0.0185, 0.004) << s;
    // Before and after the cut: what the blade had, and what it has now (loose = bank x swell).
    EXPECT_NEAR(r->vq0_m3, before * 1.2, 1e-12) << s;
    EXPECT_NEAR(r->vq1_m3, cut * 1.2, 1e-12) << s;
    EXPECT_NEAR(r->q1_n, cut * 14636.0, 1e-6) << s;
    EXPECT_GE(r->var_vq, m->var_vq) << s;
  }
  EXPECT_NEAR(on.pile.bank_m3, cut, 1e-12);
  // The same sweeps without the option: the mapped pile ahead of the edge, another number.
  Pass& m = off;
  EXPECT_EQ(m.pile.bank_m3, 0.0);
}

TEST(CarriedSurcharge, APassEndsWhenTheBladeLeavesTheSoilOrReverses) {
  Pass p(true);
  for (int s = 0; s < 5; ++s) p.sweep(0.2);
  ASSERT_GT(p.pile.bank_m3, 0.05);
  const auto lifted = p.sweep(0.2, 3.0);  // the blade 3 m up, above the ridge it left: nothing cut
  EXPECT_EQ(lifted->cut_volume_m3, 0.0);
  EXPECT_EQ(p.pile.bank_m3, 0.0);
  EXPECT_EQ(lifted->vq1_m3, 0.0);
  for (int s = 0; s < 5; ++s) p.sweep(0.2);
  ASSERT_GT(p.pile.bank_m3, 0.05);
  p.sweep(-0.2);  // backing up with the blade down: the pile stays where it was
  EXPECT_EQ(p.pile.bank_m3, 0.0);
}

TEST(CarriedSurcharge, TheBladeHoldsAtMostItsCapacity) {
  Pass p(true);
  p.cfg.carried_repose_rad = 0.576;
  const double cap_bank = 1.85 * 0.76 * 0.76 / (2.0 * std::tan(0.576)) / 1.2;  // 0.41 m^3
  for (int s = 0; s < 30; ++s) p.sweep(0.2, -0.15);  // 0.055 m^3 a sweep
  EXPECT_NEAR(p.pile.bank_m3, cap_bank, 1e-12);
}

// lidar_fusion moves the elevation alone. A cell the bookkeeping holds 20 cm of loose soil on,
// which the sensors then see 15 cm lower (the pile is not there), holds 5 cm once a sweep reads
// it with loose_follows_elevation (and still 20 cm without); a cell seen 10 cm higher than its
// tracked base holds 10 cm of loose soil.
TEST(LooseFollowsElevation, TheLooseLayerIsWhatStandsAboveTheTrackedBase) {
  for (const bool follow : {false, true}) {
    SCOPED_TRACE(follow);
    TestMap tm(0.05, 160);
    if (follow) tm.ids.base = tm.map.addLayer("loose_base", "m");
    tm.setElevation([](const Position&) { return 0.0; });
    const Index lowered = *tm.map.geometry().indexAt(Position(-1.5, 0.5)), raised = *tm.map.geometry().indexAt(Position(-1.5, -0.6));
    tm.map.set(tm.ids.loose, lowered, 0.2f);
    tm.map.set(tm.ids.elevation, lowered, 0.2f);
    std::vector<BladePose> hist;
    auto sweepAbove = [&](double x0) {  // passes over without cutting: only reads and writes back
      hist.clear();
      for (int k = 0; k <= 2; ++k) hist.push_back(bladePose(k * 0.1, Eigen::Vector3d(x0 + 0.1 * k, 0, 1.0), bladeRotation(0)));
      return runSweep(tm.map, tm.ids, SweepConfig{}, hist, Executor(1));
    };
    ASSERT_TRUE(sweepAbove(-2.0));  // the window covers both cells: their base is tracked now
    if (follow) {
      EXPECT_NEAR(tm.map.at(tm.ids.base, lowered), 0.0f, 1e-6);
      EXPECT_NEAR(tm.map.at(tm.ids.base, raised), 0.0f, 1e-6);
    }
    tm.map.set(tm.ids.elevation, lowered, 0.05f);  // what a LiDAR does to these cells
    tm.map.set(tm.ids.elevation, raised, 0.10f);
    ASSERT_TRUE(sweepAbove(-1.9));
    EXPECT_NEAR(tm.map.at(tm.ids.loose, lowered), follow ? 0.05f : 0.2f, 1e-6);
    EXPECT_NEAR(tm.map.at(tm.ids.loose, raised), follow ? 0.10f : 0.0f, 1e-6);
  }
}
