// Cut and deposit: swell only on undisturbed soil, mass conservation, unknown and off-map
// deposits kept/counted, height uncertainty updates.
#include <gtest/gtest.h>

#include "sweep_test_util.hpp"

using namespace terramap;
using namespace terramap::plugins;
using namespace terramap::plugins::test;

TEST(CutDeposit, LooseSoilDoesNotSwellTwice) {
  // Flat ground at 0, 4 cm of loose soil on it, blade edge 10 cm deep moving +x by 0.25 m:
  // each cut cell loses 4 cm loose + 6 cm undisturbed; its deposit is 0.04 + 1.2 * 0.06.
  TestMap tm(0.05, 80);
  tm.setElevation([](const Position&) { return 0.0; });
  tm.map.fill(tm.ids.loose, 0.04f);
  std::vector<BladePose> hist{bladePose(0, Eigen::Vector3d(-0.5, 0, -0.1), bladeRotation(0), 0.5),
                              bladePose(1, Eigen::Vector3d(-0.25, 0, -0.1), bladeRotation(0), 0.5)};
  SweepConfig cfg;
  const auto rec = runSweep(tm.map, tm.ids, cfg, hist, Executor(1));
  const double per_cell = 0.04 + 1.2 * 0.06;
  // Row by row: count the cut cells (H == -0.1) and find the one deposit cell ahead (+x).
  long rows_checked = 0;
  for (int j = 0; j < 80; ++j) {
    int cut = 0, dep_i = -1;
    for (int i = 0; i < 80; ++i) {
      if (tm.H(i, j) == -0.1f) {
        ++cut;
        EXPECT_EQ(tm.L(i, j), 0.0f);
      } else if (tm.H(i, j) > 0.0f) {
        EXPECT_EQ(dep_i, -1) << "two deposit cells in column " << j;
        dep_i = i;
      }
    }
    if (cut == 0) continue;
    ++rows_checked;
    ASSERT_GE(dep_i, 0);
    EXPECT_NEAR(tm.H(dep_i, j), cut * per_cell, 1e-6);
    EXPECT_NEAR(tm.L(dep_i, j), 0.04 + cut * per_cell, 1e-6);
    // The deposit cell lies ahead (+x) of the T1 edge, i.e. at a smaller row index.
    EXPECT_GT(tm.map.geometry().positionOf(Index(dep_i, j)).x(), -0.25);
  }
  EXPECT_EQ(rows_checked, 10);  // 0.5 m blade at 5 cm: ten columns of cells
  EXPECT_EQ(rec->cells_cut, 50);
  EXPECT_NEAR(rec->cut_volume_m3, 50 * 0.1 * 0.0025, 1e-9);
  EXPECT_NEAR(rec->cut_bank_volume_m3, 50 * 0.06 * 0.0025, 1e-9);
  EXPECT_NEAR(rec->deposit_volume_m3, 50 * per_cell * 0.0025, 1e-9);
}

TEST(CutDeposit, MassConservedWithUnknownAndOffMapDeposits) {
  // Hilly terrain with an unknown (NaN) patch where the soil lands, a machine that rolls, yaws,
  // pitches and turns, and a final push off the map edge.
  TestMap tm(0.05, 120);  // 6 m x 6 m, x and y in [-3, 3)
  tm.setElevation([](const Position& p) {
    if (p.x() > 0.6 && p.x() < 1.0 && p.y() > -0.5 && p.y() < 0.2) return std::nan("");
    return 0.08 * std::sin(1.7 * p.x()) + 0.05 * std::cos(2.3 * p.y()) + 0.02 * p.x();
  });
  // Some loose soil already lying around.
  for (int i = 40; i < 70; ++i)
    for (int j = 30; j < 90; ++j) tm.map.set(tm.ids.loose, Index(i, j), 0.03f);
  const double s = 1.2;
  const double m0 = soilMass(tm.map, tm.ids, s);
  BladeSweep plugin;
  plugin.configure(makeParams("blade", plugin.schema(), {{"swell", s}}));
  Harness h(tm.map, 2);
  plugin.start(h.ctx);
  double lost = 0, unknown = 0;
  long sweeps = 0;
  for (int k = 0; k <= 60; ++k) {
    const double t = 0.1 * k;
    const double heading = 0.25 * std::sin(0.7 * t);
    const Eigen::Vector3d e(-2.0 + 0.085 * k, 0.4 * std::sin(0.5 * t), -0.06 + 0.04 * std::sin(1.3 * t));
    plugin.process(h.ctx, Event(bladePose(t, e, bladeRotation(heading + 0.2 * std::sin(t), 0.04 * std::cos(2 * t),
                                                             0.15 + 0.1 * std::sin(t)))));
    if (const auto r = h.bus.latestAs<SweepRecord>(SweepRecord::kType); r && r->sweep_index > sweeps) {
      sweeps = r->sweep_index;
      lost += r->lost_volume_m3;
      unknown += r->deposit_unknown_volume_m3;
    }
  }
  EXPECT_GT(sweeps, 15);
  EXPECT_GT(unknown, 0.0) << "the scenario should deposit onto unknown ground";
  EXPECT_GT(lost, 0.0) << "the scenario should push soil off the map";
  const double m1 = soilMass(tm.map, tm.ids, s) + lost / s;
  // Float32 storage: each written cell rounds to ~6e-8 m; allow 1e-7 m per cell of the map.
  EXPECT_NEAR(m1, m0, 120 * 120 * 1e-7 * 0.0025);
  EXPECT_GT(h.stats.counters["cut_volume_m3"], 0.05);
}

TEST(CutDeposit, UncertaintyOfCutAndDepositCells) {
  TestMap tm(0.05, 60);
  tm.setElevation([](const Position&) { return 0.0; });
  tm.map.fill(tm.ids.sigma, 0.01f);
  SweepConfig cfg;
  cfg.sigma_sv_m = 0.03;
  std::vector<BladePose> hist{bladePose(0, Eigen::Vector3d(-0.3, 0, -0.1), bladeRotation(0), 0.3),
                              bladePose(1, Eigen::Vector3d(-0.2, 0, -0.1), bladeRotation(0), 0.3)};
  runSweep(tm.map, tm.ids, cfg, hist, Executor(1));
  long cut = 0, dep = 0;
  for (int i = 0; i < 60; ++i)
    for (int j = 0; j < 60; ++j) {
      const float sg = tm.map.at(tm.ids.sigma, Index(i, j));
      if (tm.H(i, j) < 0) {
        ++cut;
        EXPECT_FLOAT_EQ(sg, 0.03f);  // max(prior 0.01, σ_SV 0.03)
      } else if (tm.H(i, j) > 0) {
        ++dep;
        // Two cut cells per deposit (0.1 m at 5 cm): each adds ((s (Δh + σa + σSV) - s (Δh - σa - σSV))/2)^2
        // = (1.2 * 0.04)^2 to the variance.
        const double per = 1.2 * 0.04;
        EXPECT_NEAR(sg, std::sqrt(0.01 * 0.01 + 2 * per * per), 1e-6);
      }
    }
  EXPECT_EQ(cut, 2 * 6);
  EXPECT_EQ(dep, 6);
}
