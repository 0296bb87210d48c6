// Swept-volume intersection: no missed cells at speed, exact footprint for any heading, roll
// and yaw, thresholds, determinism across thread counts.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>

#include "sweep_test_util.hpp"

using namespace terramap;
using namespace terramap::plugins;
using namespace terramap::plugins::test;

namespace {

BladeSweep makePlugin(std::map<std::string, ParamValue> overrides = {}) {
  BladeSweep p;
  p.configure(makeParams("blade", p.schema(), overrides));
  return p;
}

// The approach the paper argues against (D'Adamo): intersect a fixed solid blade volume
// (plate of `thickness` behind the face) with the map at each pose. Returns cut cells.
std::vector<Index> fixedVolumeCut(const LayeredMap& map, LayerId elev, const BladePose& p, double thickness) {
  std::vector<Index> out;
  const Geometry& g = map.geometry();
  const Eigen::Isometry3d inv = p.T_map_blade.inverse();
  for (int i = 0; i < g.size().x(); ++i)
    for (int j = 0; j < g.size().y(); ++j) {
      const Position c = g.positionOf(Index(i, j));
      const double h = map.at(elev, Index(i, j));
      // Cell column from -inf to h intersects the plate if some z <= h lies inside; the plate
      // is upright here, so test the centre's (x, y) at the edge height.
      const Eigen::Vector3d b = inv * Eigen::Vector3d(c.x(), c.y(), p.T_map_blade.translation().z());
      if (b.x() <= 0 && b.x() >= -thickness && std::abs(b.y()) <= 0.5 * p.geometry.width_m &&
          h > p.T_map_blade.translation().z())
        out.push_back(Index(i, j));
    }
  return out;
}

}  // namespace

TEST(SweptVolume, FastBladeMissesNoCellWhileFixedVolumeDoes) {
  // 0.5 m per update on a 5 cm map: the blade jumps 10 cells between poses.
  TestMap tm(0.05, 160);
  tm.setElevation([](const Position&) { return 0.0; });
  TestMap fixed(0.05, 160);
  fixed.setElevation([](const Position&) { return 0.0; });
  BladeSweep plugin = makePlugin();
  Harness h(tm.map, 1);
  plugin.start(h.ctx);
  const double z = -0.1;
  for (int k = 0; k <= 6; ++k) {
    const BladePose p = bladePose(k * 0.5, Eigen::Vector3d(-2.0 + 0.5 * k, 0.0, z), bladeRotation(0.0));
    plugin.process(h.ctx, Event(p));
    for (const Index& c : fixedVolumeCut(fixed.map, fixed.ids.elevation, p, 0.03))
      fixed.map.set(fixed.ids.elevation, c, static_cast<float>(z));
  }
  EXPECT_EQ(plugin.sweeps(), 6);
  long strip = 0, swept_missed = 0, fixed_missed = 0;
  const Geometry& g = tm.map.geometry();
  for (int i = 0; i < 160; ++i)
    for (int j = 0; j < 160; ++j) {
      const Position c = g.positionOf(Index(i, j));
      // Strictly inside the area the edge passed over (x from -2 to 1, |y| < 0.925).
      if (c.x() <= -2.0 + 1e-9 || c.x() >= 1.0 - 1e-9 || std::abs(c.y()) >= 0.925 - 1e-9) continue;
      ++strip;
      if (tm.H(i, j) != static_cast<float>(z)) ++swept_missed;
      if (fixed.H(i, j) != static_cast<float>(z)) ++fixed_missed;
    }
  EXPECT_EQ(strip, 60L * 36L);  // |y| < 0.925 strictly: 18 cell centres per side
  EXPECT_EQ(swept_missed, 0);
  // The fixed plate (3 cm) catches at most one row of cells in every ten.
  EXPECT_GT(fixed_missed, strip * 8 / 10);
}

TEST(SweptVolume, ExactFootprintForAnyHeadingRollAndYaw) {
  for (const double heading : {0.0, 0.5236, 2.3, -1.9}) {
    for (const double yaw_rel : {0.0, 0.35, -0.6}) {
      for (const double roll : {0.0, 0.05, -0.08}) {
        TestMap tm(0.05, 120);
        tm.setElevation([](const Position&) { return 0.3; });
        const Eigen::Matrix3d R = bladeRotation(heading + yaw_rel, roll);
        const Eigen::Vector3d dir(std::cos(heading), std::sin(heading), 0.0);
        const Eigen::Vector3d e0(-0.3 * dir.x(), -0.3 * dir.y(), 0.0);
        const Eigen::Vector3d e1 = e0 + 0.6 * dir;
        std::vector<BladePose> hist{bladePose(0, e0, R), bladePose(1, e1, R)};
        const auto rec = runSweep(tm.map, tm.ids, SweepConfig{}, hist, Executor(1));
        // Independent expectation: the edge translates, so its path is the planar
        // parallelogram E_R + f (E_L - E_R) + s (e1 - e0); the cut floor is that plane.
        const auto c = bladeCorners(hist[0].T_map_blade, hist[0].geometry);
        const Eigen::Vector2d er = c[0].head<2>(), ev = (c[1] - c[0]).head<2>(), tv = (e1 - e0).head<2>();
        const double det = ev.x() * tv.y() - ev.y() * tv.x();
        // A rolled blade's side edge leans out by height * sin(roll) at its top: that overhang
        // legitimately cuts beside the edge's path, so "outside" starts beyond it.
        const double df = 0.76 * std::abs(std::sin(roll)) / (c[1] - c[0]).head<2>().norm();
        long inside = 0, wrong = 0;
        for (int i = 0; i < 120; ++i)
          for (int j = 0; j < 120; ++j) {
            const Eigen::Vector2d p = tm.map.geometry().positionOf(Index(i, j)) - er;
            const double f = (p.x() * tv.y() - p.y() * tv.x()) / det;
            const double s = (ev.x() * p.y() - ev.y() * p.x()) / det;
            const double hij = tm.H(i, j);
            if (f > 1e-6 && f < 1 - 1e-6 && s > 1e-6 && s < 1 - 1e-6) {
              ++inside;
              const double zexp = c[0].z() + f * (c[1].z() - c[0].z());
              if (std::abs(hij - zexp) > 1e-5) ++wrong;
            } else if (f < -df - 1e-6 || f > 1 + df + 1e-6 || s < -1e-6 || s > 1 + 1e-6) {
              if (hij < 0.3f) ++wrong;  // outside: never cut (deposits only raise)
            }
          }
        EXPECT_GT(inside, 100) << heading << " " << yaw_rel << " " << roll;
        EXPECT_EQ(wrong, 0) << "heading " << heading << " yaw " << yaw_rel << " roll " << roll;
        if (roll == 0.0) {
          EXPECT_EQ(rec->cells_cut, rec->cells_under_sv - rec->cells_unknown_under_sv);
        }
      }
    }
  }
}

TEST(SweptVolume, LoweringRotatingBladeCutsToTheLowestEnvelope) {
  // Blade pitched forward and back (lean 0.1 sin k rad) while it translates and dips: station k
  // has its edge along y at x_k = -0.4 + 0.1 k, z_k = 0.2 - 0.3 sin(pi k / 8) (down to -0.1 at
  // x = 0). Hand-computed swept region: the edge's path is the piecewise-linear ribbon through
  // the stations (slerp stations in between move the edge along the same segments), and it is
  // the lowest part of the swept volume over every column it passes: the leaning face rises
  // from the edge at 1 / tan(0.1) ~ 10 m per m of lean, the path at most 0.3 pi / 0.8 ~ 1.2 m/m,
  // so every face, top and side triangle lies above the path. Hence on the 0.5 m ground:
  //  - cells with centres strictly inside x in (-0.4, 0.4), |y| < 0.925 end at z_path(x);
  //  - every other cell is not cut (>= 0.5; spoil is put outside the footprint and only raises).
  // The floor is sampled at cell centres, so z_path is exact there: the slack is the float
  // storage of the elevation layer (half an ulp at 0.5 m: 3e-8 m) plus the barycentric
  // arithmetic (1e-12 of the 5 cm cell): 1e-6 m. Centres on the blade's side lines (|y| =
  // 0.925: a resolution multiple) are boundary cases either way and not judged.
  TestMap tm(0.05, 100);
  tm.setElevation([](const Position&) { return 0.5; });
  std::vector<BladePose> hist;
  auto zk = [](int k) { return 0.2 - 0.3 * std::sin(kPi * k / 8.0); };
  for (int k = 0; k <= 8; ++k) {
    const double x = -0.4 + 0.1 * k;
    hist.push_back(bladePose(k * 0.1, Eigen::Vector3d(x, 0.0, zk(k)), bladeRotation(0.0, 0.0, 0.1 * std::sin(k))));
  }
  const auto rec = runSweep(tm.map, tm.ids, SweepConfig{}, hist, Executor(1));
  auto zPath = [&](double x) {
    const double f = (x + 0.4) / 0.1;
    const int k = std::clamp(static_cast<int>(std::floor(f)), 0, 7);
    return zk(k) + (f - k) * (zk(k + 1) - zk(k));
  };
  long inside = 0, wrong_inside = 0, wrong_outside = 0;
  double max_err = 0;
  for (int i = 0; i < 100; ++i)
    for (int j = 0; j < 100; ++j) {
      const Position c = tm.map.geometry().positionOf(Index(i, j));
      if (std::abs(std::abs(c.y()) - 0.925) < 1e-6) continue;
      const double h = tm.H(i, j);
      if (c.x() > -0.4 + 1e-6 && c.x() < 0.4 - 1e-6 && std::abs(c.y()) < 0.925) {
        ++inside;
        const double err = std::abs(h - zPath(c.x()));
        max_err = std::max(max_err, err);
        if (err > 1e-6) ++wrong_inside;
      } else if (h < 0.5f) {
        ++wrong_outside;
      }
    }
  EXPECT_EQ(inside, 16L * 36L);  // 16 centres along x, 18 per side strictly inside |y| < 0.925
  EXPECT_EQ(wrong_inside, 0) << "largest error " << max_err << " m";
  EXPECT_EQ(wrong_outside, 0);
  // The dip itself: the cells either side of x = 0 end 5.7 mm above the -0.1 m low point
  // (the path at x = 0.025 is z_4 + 0.25 (z_5 - z_4), z_5 - z_4 = 0.3 (1 - sin(5 pi/8))).
  const auto idx = tm.map.geometry().indexAt(Position(0.001, 0.001));
  ASSERT_TRUE(idx.has_value());
  EXPECT_NEAR(tm.H(idx->x(), idx->y()), -0.1 + 0.25 * 0.3 * (1 - std::sin(5 * kPi / 8)), 1e-6);
  // Cut cells = those with centres under the swept volume (all start above it here), counted
  // by the record too.
  EXPECT_EQ(rec->cells_cut, rec->cells_under_sv);
  EXPECT_GE(rec->cells_cut, inside);
}

TEST(SweptVolume, UpdateThresholdsTranslationResolutionAndRotation) {
  {
    TestMap tm(0.05, 100);
    tm.setElevation([](const Position&) { return 0.0; });
    BladeSweep plugin = makePlugin();
    Harness h(tm.map, 1);
    plugin.start(h.ctx);
    for (int k = 0; k <= 8; ++k)
      plugin.process(h.ctx, Event(bladePose(k, Eigen::Vector3d(0.06 * k, 0, 0.1), bladeRotation(0))));
    // 0.24 m > 0.2 m after 4 poses: sweeps at k = 4 and k = 8.
    EXPECT_EQ(plugin.sweeps(), 2);
  }
  {
    // A coarse map raises the threshold to res * sqrt(2) = 0.2828 m: sweeps at k = 5 only.
    TestMap tm(0.2, 40);
    tm.setElevation([](const Position&) { return 0.0; });
    BladeSweep plugin = makePlugin({{"fit_length_m", 1.0}});
    Harness h(tm.map, 1);
    plugin.start(h.ctx);
    for (int k = 0; k <= 8; ++k)
      plugin.process(h.ctx, Event(bladePose(k, Eigen::Vector3d(0.06 * k, 0, 0.1), bladeRotation(0))));
    EXPECT_EQ(plugin.sweeps(), 1);
  }
  {
    // Rotation in place, 4 degrees per pose about the edge centre: 12 > 10 degrees at k = 3.
    // (The edge ends move 0.065 m per pose, below the translation threshold until k = 4.)
    TestMap tm(0.05, 100);
    tm.setElevation([](const Position&) { return 0.0; });
    BladeSweep plugin = makePlugin({{"min_translation_m", 1.0}});
    Harness h(tm.map, 1);
    plugin.start(h.ctx);
    for (int k = 0; k <= 6; ++k)
      plugin.process(h.ctx, Event(bladePose(k, Eigen::Vector3d(0, 0, 0.1), bladeRotation(k * 4.0 * kPi / 180))));
    EXPECT_EQ(plugin.sweeps(), 2);
  }
  {
    // A teleport resets the history without cutting; out-of-order stamps are counted.
    TestMap tm(0.05, 100);
    tm.setElevation([](const Position&) { return 0.0; });
    BladeSweep plugin = makePlugin();
    Harness h(tm.map, 1);
    plugin.start(h.ctx);
    plugin.process(h.ctx, Event(bladePose(0, Eigen::Vector3d(-2, 0, -0.1), bladeRotation(0))));
    plugin.process(h.ctx, Event(bladePose(1, Eigen::Vector3d(1.5, 0, -0.1), bladeRotation(0))));
    plugin.process(h.ctx, Event(bladePose(0.5, Eigen::Vector3d(1.6, 0, -0.1), bladeRotation(0))));
    EXPECT_EQ(plugin.sweeps(), 0);
    EXPECT_EQ(h.stats.counters["pose_jumps"], 1.0);
    EXPECT_EQ(h.stats.dropped["stamp_out_of_order"], 1);
  }
}

TEST(SweptVolume, FinishCutsTheMotionLeftAfterTheLastSweep) {
  // The blade cuts 5 cm deep and stops after 0.15 m, below the 0.2 m sweep threshold: during
  // the run nothing is cut; finish() must cut the 0.15 m it travelled, or the soil it moved
  // never reaches the map (the blind evaluation then blames the mapper for a cut it saw).
  TestMap tm(0.05, 100);
  tm.setElevation([](const Position&) { return 0.0; });
  BladeSweep plugin = makePlugin();
  Harness h(tm.map, 1);
  plugin.start(h.ctx);
  for (int k = 0; k <= 3; ++k)
    plugin.process(h.ctx, Event(bladePose(k, Eigen::Vector3d(0.05 * k, 0, -0.05), bladeRotation(0))));
  ASSERT_EQ(plugin.sweeps(), 0);
  // Cells strictly between the two edge positions along x, inside the blade width: cut to -5 cm.
  const Index probe = *tm.map.geometry().indexAt(Position(0.075, 0.0));
  EXPECT_FLOAT_EQ(tm.H(probe.x(), probe.y()), 0.0f);
  plugin.finish(h.ctx);
  EXPECT_EQ(plugin.sweeps(), 1);
  EXPECT_EQ(h.stats.counters["final_partial_sweeps"], 1.0);
  EXPECT_NEAR(tm.H(probe.x(), probe.y()), -0.05, 1e-4);
  // A machine that did not move since its last sweep cuts nothing more at finish().
  BladeSweep still = makePlugin();
  Harness h2(tm.map, 1);
  still.start(h2.ctx);
  still.process(h2.ctx, Event(bladePose(0, Eigen::Vector3d(1.0, 0, -0.05), bladeRotation(0))));
  still.process(h2.ctx, Event(bladePose(1, Eigen::Vector3d(1.0, 0, -0.05), bladeRotation(0))));
  still.finish(h2.ctx);
  EXPECT_EQ(still.sweeps(), 0);
}

TEST(SweptVolume, BadBladeGeometryIsAnInputError) {
  TestMap tm(0.05, 40);
  BladeSweep plugin = makePlugin();
  Harness h(tm.map, 1);
  plugin.start(h.ctx);
  BladePose p = bladePose(0, Eigen::Vector3d::Zero(), bladeRotation(0), -1.0);
  EXPECT_THROW(plugin.process(h.ctx, Event(p)), InputError);
  BladePose q = bladePose(0, Eigen::Vector3d::Zero(), bladeRotation(0));
  q.T_map_blade.translation().x() = std::nan("");
  plugin.process(h.ctx, Event(q));
  EXPECT_EQ(h.stats.dropped["non_finite_pose"], 1);
}

TEST(SweptVolume, BitIdenticalAtOneAndTwoThreads) {
  auto run = [](int threads) {
    auto tm = std::make_unique<TestMap>(0.02, 256, Position::Zero(), 32);
    tm->setElevation([](const Position& p) { return 0.1 * std::sin(2.0 * p.x()) + 0.05 * std::cos(3.0 * p.y()); });
    BladeSweep plugin = makePlugin({{"min_translation_m", 0.15}});
    Harness h(tm->map, threads);
    plugin.start(h.ctx);
    for (int k = 0; k <= 30; ++k) {
      const double t = k * 0.1;
      const Eigen::Vector3d e(-1.5 + 0.1 * k, 0.3 * std::sin(t), -0.05 - 0.03 * std::sin(2 * t));
      plugin.process(h.ctx, Event(bladePose(t, e, bladeRotation(0.3 * std::sin(t), 0.05 * std::cos(t), 0.1))));
    }
    std::string recs;
    for (const auto& r : h.stats.records) recs += r;
    return std::make_pair(std::move(tm), recs);
  };
  auto a = run(1);
  auto b = run(2);
  EXPECT_EQ(a.second, b.second);
  for (LayerId id : {a.first->ids.elevation, a.first->ids.loose, a.first->ids.sigma}) {
    const Eigen::MatrixXf ma = a.first->map.toMatrix(id), mb = b.first->map.toMatrix(id);
    EXPECT_EQ(std::memcmp(ma.data(), mb.data(), sizeof(float) * static_cast<size_t>(ma.size())), 0);
  }
  EXPECT_FALSE(a.second.empty());
}
