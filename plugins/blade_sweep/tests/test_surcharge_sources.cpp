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

// The blade's capacity, loose m^3: width x height^2 / (2 tan 33 deg) = 0.82 m^3.
double capacityLooseM3() { return 1.85 * 0.76 * 0.76 / (2.0 * std::tan(0.576)); }

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
    // The mapped region's variance plus a quarter of the squared distance to the mapped V_Q.
    const double d0 = 0.5 * (r->vq0_m3 - m->vq0_m3), d1 = 0.5 * (r->vq1_m3 - m->vq1_m3);
    EXPECT_NEAR(r->var_vq, m->var_vq + std::max(d0 * d0, d1 * d1), 1e-12) << s;
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
  const double cap_bank = capacityLooseM3() / 1.2;  // 0.69 m^3
  for (int s = 0; s < 30; ++s) p.sweep(0.2, -0.15);  // 0.055 m^3 a sweep
  EXPECT_NEAR(p.pile.bank_m3, cap_bank, 1e-12);
}

// Beyond the capacity, carried_overflow_share s keeps s of the excess in V_Q and adds the
// variance of a uniform between the capacity and all of the cut: the bookkeeping still counts
// the whole cut, so the estimate moves with it instead of freezing at the capacity.
TEST(CarriedSurcharge, BeyondTheCapacityTheOverflowShareIsCountedWithItsUncertainty) {
  const double cap_loose = capacityLooseM3();
  Pass capped(true), half(true), mapped(false);
  half.cfg.carried_overflow_share = 0.5;
  double cut = 0.0;
  std::shared_ptr<SweepRecord> rc, rh, rm;
  for (int s = 0; s < 30; ++s) {
    rc = capped.sweep(0.2, -0.15);
    rh = half.sweep(0.2, -0.15);
    rm = mapped.sweep(0.2, -0.15);  // the same map edits: the mapped V_Q and its variance
    ASSERT_TRUE(rc && rh && rm);
    cut += rh->cut_bank_volume_m3;
    if (cut * 1.2 <= cap_loose) {  // below the capacity both count the same cut
      EXPECT_EQ(rh->vq1_m3, rc->vq1_m3) << s;
      EXPECT_EQ(rh->var_vq, rc->var_vq) << s;
    }
  }
  const double excess = cut * 1.2 - cap_loose;
  ASSERT_GT(excess, 0.5);  // well past the capacity
  EXPECT_NEAR(rc->vq1_m3, cap_loose, 1e-12);
  EXPECT_NEAR(half.pile.bank_m3, cut, 1e-12);
  EXPECT_NEAR(rh->vq1_m3, cap_loose + 0.5 * excess, 1e-9);
  EXPECT_NEAR(rh->q1_n, rh->vq1_m3 * 14636.0 / 1.2, 1e-6);
  // The mapped region's variance, the distance to the mapped V_Q, and the overflow's uniform
  // (its excess before this sweep's cut is the smaller one; the variance takes the larger).
  const double d0 = 0.5 * (rh->vq0_m3 - rm->vq0_m3), d1 = 0.5 * (rh->vq1_m3 - rm->vq1_m3);
  EXPECT_NEAR(rh->var_vq, rm->var_vq + std::max(d0 * d0, d1 * d1) + excess * excess / 12.0, 1e-9);
  const double c0 = 0.5 * (rc->vq0_m3 - rm->vq0_m3), c1 = 0.5 * (rc->vq1_m3 - rm->vq1_m3);
  EXPECT_NEAR(rc->var_vq, rm->var_vq + std::max(c0 * c0, c1 * c1), 1e-9);
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

// The bank reference: a pile the sensors see ahead of the blade but the bookkeeping never put
// there (the real blade's pile runs further than the map's) raises elevation - loose, so
// without the reference the cut looks as deep as the pile is tall. The bank surface recorded
// while the ground ahead was still bare keeps the depth the ground's.
TEST(BankReference, TheDepthIsMeasuredFromTheGroundBeforeThePileCame) {
  for (const bool bank : {true, false}) {
    TestMap tm(0.05, 160);
    tm.setElevation([](const Position&) { return 0.0; });
    SweepConfig cfg;
    cfg.bank_reference = bank;
    if (bank) tm.ids.bank = tm.map.addLayer("bank_surface", "m");
    // A first sweep above the ground at x -3.5 .. -3.3: nothing cut, the ground ahead recorded.
    std::vector<BladePose> first;
    for (int k = 0; k <= 2; ++k) first.push_back(bladePose(0.1 * k, Eigen::Vector3d(-3.5 + 0.1 * k, 0, 0.05), bladeRotation(0)));
    runSweep(tm.map, tm.ids, cfg, first, Executor(1));
    // The LiDAR now sees a 15 cm pile from x = -2.0 to -1.0 that the bookkeeping does not hold.
    for (int i = 0; i < 160; ++i)
      for (int j = 0; j < 160; ++j) {
        const Position p = tm.map.geometry().positionOf(Index(i, j));
        if (p.x() > -2.0 && p.x() < -1.0 && std::abs(p.y()) < 1.2) tm.map.set(tm.ids.elevation, Index(i, j), 0.15f);
      }
    // The blade cuts 8 cm deep into the pile's ground.
    std::vector<BladePose> hist;
    for (int k = 0; k <= 3; ++k) hist.push_back(bladePose(1.0 + 0.1 * k, Eigen::Vector3d(-1.9 + 0.1 * k, 0, -0.08), bladeRotation(0)));
    const auto r = runSweep(tm.map, tm.ids, cfg, hist, Executor(1));
    ASSERT_TRUE(r->fee_valid);
    if (bank) {
      EXPECT_NEAR(r->d_m, 0.08, 0.005);
      EXPECT_NEAR(r->steps.back().area_m2, 0.08 * 1.85, 0.08 * 0.1);
      // The cut floor is bank too: the cut cells' bank surface is the floor now.
      const Index under = *tm.map.geometry().indexAt(Position(-1.75, 0.0));
      EXPECT_NEAR(tm.map.at(tm.ids.bank, under), -0.08f, 1e-4);
    } else {
      EXPECT_GT(r->d_m, 0.18);  // the unrecorded pile counts as ground
    }
  }
}
