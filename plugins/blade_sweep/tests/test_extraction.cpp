// FEE geometry extraction on analytic planes and slopes, with roll, yaw, rake and headings
// not along x. Expectations come from the plane and the blade pose, not from the plugin.
#include <gtest/gtest.h>

#include "sweep_test_util.hpp"

using namespace terramap;
using namespace terramap::plugins;
using namespace terramap::plugins::test;

namespace {

struct Case {
  double heading = 0;      // travel direction (rad)
  double yaw_rel = 0;      // blade normal relative to travel
  double roll = 0;
  double lean_back = 0;    // rake: blade angle = pi/2 - lean_back
  double slope = 0;        // terrain rise along travel (rad)
  double cross = 0;        // terrain rise across travel (rad, towards +t_perp)
  double depth_v = 0.12;   // vertical depth of the edge centre under the surface
  double travel = 0.3;
};

std::shared_ptr<SweepRecord> runCase(const Case& c, double res = 0.05) {
  TestMap tm(res, static_cast<int>(std::lround(8.0 / res)));
  const Eigen::Vector2d t(std::cos(c.heading), std::sin(c.heading)), tp(-t.y(), t.x());
  const double ga = std::tan(c.slope), gc = std::tan(c.cross);
  tm.setElevation([&](const Position& p) { return 1.0 + ga * p.dot(t) + gc * p.dot(tp); });
  // The edge centre follows the surface at constant vertical depth (moving parallel to it).
  auto edge = [&](double s) {
    const Eigen::Vector2d xy = (s - 0.5 * c.travel) * t;
    return Eigen::Vector3d(xy.x(), xy.y(), 1.0 + ga * xy.dot(t) - c.depth_v);
  };
  const Eigen::Matrix3d R = bladeRotation(c.heading + c.yaw_rel, c.roll, c.lean_back);
  std::vector<BladePose> hist;
  for (int k = 0; k <= 3; ++k) hist.push_back(bladePose(k * 0.1, edge(c.travel * k / 3.0), R));
  return runSweep(tm.map, tm.ids, SweepConfig{}, hist, Executor(1));
}

}  // namespace

TEST(Extraction, FlatGroundUprightBlade) {
  Case c;
  const auto r = runCase(c);
  ASSERT_TRUE(r->fee_valid);
  EXPECT_NEAR(r->alpha_rad, 0.0, 1e-6);
  EXPECT_NEAR(r->rho_rad, kPi / 2, 1e-6);
  EXPECT_NEAR(r->d_m, 0.12, 1e-4);
  EXPECT_NEAR(r->w_m, 1.85, 0.05 + 1e-9);  // one cell: the edge ends lie on cell centres
  EXPECT_NEAR(r->fit_residual_m, 0.0, 1e-5);
  EXPECT_NEAR(r->t_hat.x(), 1.0, 1e-12);
  EXPECT_EQ(r->steps.size(), 4u);
  for (const auto& s : r->steps) {
    EXPECT_NEAR(s.d_m, 0.12, 1e-4);
    EXPECT_NEAR(s.w_m, 1.85, 0.05 + 1e-9);
  }
  EXPECT_NEAR(r->var_alpha, 0.0, 1e-10);
  // Only the blade height's own uncertainty remains in var_d on an exact plane.
  EXPECT_NEAR(r->var_d, 0.02 * 0.02, 1e-8);
}

TEST(Extraction, RisingSlopeAlongAnOddHeading) {
  Case c;
  c.heading = 0.5236;  // 30 degrees
  c.slope = 10.0 * kPi / 180;
  const auto r = runCase(c);
  ASSERT_TRUE(r->fee_valid);
  EXPECT_NEAR(r->alpha_rad, c.slope, 1e-4);
  EXPECT_NEAR(r->rho_rad, c.slope + kPi / 2, 1e-4);
  // Depth normal to the surface: vertical depth * cos(alpha).
  EXPECT_NEAR(r->d_m, 0.12 * std::cos(c.slope), 0.05 * std::tan(c.slope));
  EXPECT_NEAR(r->w_m, 1.85, 0.05 + 1e-9);  // one cell: the edge ends lie on cell centres
  EXPECT_NEAR(r->t_hat.x(), std::cos(c.heading), 1e-9);
  EXPECT_NEAR(r->t_hat.y(), std::sin(c.heading), 1e-9);
}

TEST(Extraction, FallingSlopeRakedBladeBackwardHeading) {
  Case c;
  c.heading = -2.1;
  c.slope = -8.0 * kPi / 180;
  c.lean_back = 15.0 * kPi / 180;
  const auto r = runCase(c);
  ASSERT_TRUE(r->fee_valid);
  EXPECT_NEAR(r->blade_angle_rad, kPi / 2 - c.lean_back, 1e-9);
  EXPECT_NEAR(r->alpha_rad, c.slope, 1e-4);
  EXPECT_NEAR(r->rho_rad, c.slope + kPi / 2 - c.lean_back, 1e-4);
  // Cells under the raked face (soil on the blade) are cut but are not slices: d stays the
  // edge's depth.
  EXPECT_NEAR(r->d_m, 0.12 * std::cos(c.slope), 0.05 * std::tan(std::abs(c.slope)) + 1e-3);
  for (const auto& s : r->steps) EXPECT_NEAR(s.rho_rad, c.slope + kPi / 2 - c.lean_back, 1e-4);
}

TEST(Extraction, YawReducesWidthByCosineAndRollKeepsRake) {
  Case c;
  c.heading = 1.0;
  c.yaw_rel = 25.0 * kPi / 180;
  c.roll = 2.0 * kPi / 180;
  const auto r = runCase(c);
  ASSERT_TRUE(r->fee_valid);
  EXPECT_NEAR(r->alpha_rad, 0.0, 1e-4);
  EXPECT_NEAR(r->rho_rad, kPi / 2, 1e-4);
  EXPECT_NEAR(r->w_m, 1.85 * std::cos(c.roll) * std::cos(c.yaw_rel), 0.05);
  // The rolled edge is 0.12 -/+ 0.925 sin(2 deg) = 0.088 .. 0.152 deep; the exp(C_d d) average
  // leans to the deep end but stays inside.
  EXPECT_GT(r->d_m, 0.12);
  EXPECT_LT(r->d_m, 0.12 + 0.925 * std::sin(c.roll));
  // Partial contact from roll: raise the blade so only the low end cuts.
  Case p = c;
  p.yaw_rel = 0;
  p.roll = 6.0 * kPi / 180;
  p.depth_v = 0.0;  // centre at the surface: the right (low) half is in the ground
  const auto q = runCase(p);
  EXPECT_NEAR(q->w_m, 0.925 * std::cos(p.roll), 0.06);
}

TEST(Extraction, CrossSlopeGivesZeroAlphaAndContactWidth) {
  Case c;
  c.heading = -0.7;
  c.cross = 4.0 * kPi / 180;
  c.depth_v = 0.03;
  const auto r = runCase(c);
  ASSERT_TRUE(r->fee_valid);
  EXPECT_NEAR(r->alpha_rad, 0.0, 1e-4);
  // Ground height over the edge at lateral l: tan(4 deg) l; the edge is 0.03 below the ground
  // at l = 0, so contact where l > -0.03 / tan(4 deg) = -0.429: w = 0.925 + 0.429.
  EXPECT_NEAR(r->w_m, 0.925 + 0.03 / std::tan(c.cross), 0.05);
}

TEST(Extraction, PerStepDepthFollowsTheEdgeAndSurchargeIsMeasured) {
  TestMap tm(0.05, 160);
  tm.setElevation([](const Position&) { return 0.0; });
  // 10 cm of loose soil over 1 m x 2 m ahead of the start (x in [-1, 0]).
  for (int i = 0; i < 160; ++i)
    for (int j = 0; j < 160; ++j) {
      const Position p = tm.map.geometry().positionOf(Index(i, j));
      if (p.x() > -1.0 && p.x() < 0.0 && std::abs(p.y()) < 1.0) {
        tm.map.set(tm.ids.loose, Index(i, j), 0.1f);
        tm.map.set(tm.ids.elevation, Index(i, j), 0.1f);
      }
    }
  std::vector<BladePose> hist;
  for (int k = 0; k <= 4; ++k)
    hist.push_back(bladePose(k * 0.25, Eigen::Vector3d(-2.0 + 0.1 * k, 0, -0.05 - 0.025 * k), bladeRotation(0)));
  const auto r = runSweep(tm.map, tm.ids, SweepConfig{}, hist, Executor(1));
  ASSERT_EQ(r->steps.size(), 5u);
  for (int k = 0; k <= 4; ++k) {
    EXPECT_NEAR(r->steps[static_cast<size_t>(k)].d_m, 0.05 + 0.025 * k, 1e-4) << k;
    EXPECT_NEAR(r->steps[static_cast<size_t>(k)].tau, k / 4.0, 1e-12);
  }
  // Ahead of the T0 edge (x from -2 to -1) there is no loose soil; ahead of T1 (x in
  // [-1.6, -0.6]) lie the loose strip x in (-1, -0.6), 0.4 m x 1.85 m x 0.1 m (the region
  // clips at the blade's width), and everything this sweep deposited just ahead of the edge.
  EXPECT_NEAR(r->vq0_m3, 0.0, 1e-12);
  EXPECT_GT(r->deposit_volume_m3, 0.05);
  EXPECT_NEAR(r->vq1_m3, 0.4 * 1.85 * 0.1 + r->deposit_volume_m3, 0.05 * 1.85 * 0.1);
  EXPECT_NEAR(r->steps[2].vq_m3, 0.5 * r->vq1_m3, 1e-12);
  EXPECT_NEAR(r->q1_n, r->vq1_m3 * 14636.0 / 1.2, 1e-6);
}

// V_Q against a hand count on a hand-built map. The blade passes 0.5 m above flat ground (no
// cut, no deposit: the loose layer is the same before and after) from x = -1.0 to -0.8 along +x,
// upright, so the region ahead of the edge is the rectangle x in [edge, edge + fit_length_m = 1],
// |y| <= 0.925 (half the 1.85 m width). Loose patches, every cell centre at least a cell from
// the region's boundaries (so none is a boundary coin flip and var_vq = 0):
//   P1 x in [-0.70, -0.30], |y| < 0.5, 0.10 m: 0.4 x 1.0 x 0.10 = 0.040 m^3, ahead of both edges;
//   P2 x in [-0.95, -0.85], |y| < 0.3, 0.20 m: 0.1 x 0.6 x 0.20 = 0.012 m^3, ahead of the T0
//      edge, behind the T1 edge;
//   P3 x in [ 0.05,  0.15], |y| < 0.5, 0.05 m: 0.1 x 1.0 x 0.05 = 0.005 m^3, more than 1 m
//      ahead of the T0 edge, within 1 m of the T1 edge;
//   P4 x in [-0.70, -0.30], y in [1.0, 1.2], 0.30 m: beside the blade, in neither.
// So V_Q(T0) = 0.040 + 0.012 = 0.052 m^3, V_Q(T1) = 0.040 + 0.005 = 0.045 m^3, and Q = gamma/s V_Q.
TEST(Extraction, SurchargeIsTheLooseVolumeAheadOfTheEdgeCountedByHand) {
  const double res = 0.05;
  TestMap tm(res, 160);  // x, y in [-4, 4), cell edges on multiples of 5 cm
  tm.setElevation([](const Position&) { return 0.0; });
  struct Patch { double x0, x1, y0, y1, l; };
  const Patch patches[] = {{-0.70, -0.30, -0.5, 0.5, 0.10},
                           {-0.95, -0.85, -0.3, 0.3, 0.20},
                           {0.05, 0.15, -0.5, 0.5, 0.05},
                           {-0.70, -0.30, 1.0, 1.2, 0.30}};
  int loaded = 0;
  for (int i = 0; i < 160; ++i)
    for (int j = 0; j < 160; ++j) {
      const Position p = tm.map.geometry().positionOf(Index(i, j));
      for (const Patch& q : patches)
        if (p.x() > q.x0 && p.x() < q.x1 && p.y() > q.y0 && p.y() < q.y1) {
          tm.map.set(tm.ids.loose, Index(i, j), static_cast<float>(q.l));
          tm.map.set(tm.ids.elevation, Index(i, j), static_cast<float>(q.l));
          ++loaded;
        }
    }
  // 8 x 20 + 2 x 12 + 2 x 20 + 8 x 4 cells.
  ASSERT_EQ(loaded, 160 + 24 + 40 + 32);
  std::vector<BladePose> hist;
  for (int k = 0; k <= 2; ++k) hist.push_back(bladePose(k * 0.5, Eigen::Vector3d(-1.0 + 0.1 * k, 0, 0.5), bladeRotation(0)));
  const auto r = runSweep(tm.map, tm.ids, SweepConfig{}, hist, Executor(1));
  EXPECT_FALSE(r->fee_valid);  // nothing cut
  EXPECT_NEAR(r->deposit_volume_m3, 0.0, 1e-12);
  // Loose thicknesses are floats (relative error ~6e-8 of each cell's volume).
  EXPECT_NEAR(r->vq0_m3, 0.052, 1e-8);
  EXPECT_NEAR(r->vq1_m3, 0.045, 1e-8);
  EXPECT_NEAR(r->var_vq, 0.0, 1e-15);
  const double gamma_l = 14636.0 / 1.2;  // SweepConfig: unit weight and swell defaults
  EXPECT_NEAR(r->q0_n, gamma_l * 0.052, 1e-4);
  EXPECT_NEAR(r->q1_n, gamma_l * 0.045, 1e-4);
  // Per step, linear in time between the ends: tau = 0.5 halfway, 1-sigma tau (1-tau) |dV|.
  ASSERT_EQ(r->steps.size(), 3u);
  EXPECT_NEAR(r->steps[0].vq_m3, 0.052, 1e-8);
  EXPECT_NEAR(r->steps[1].vq_m3, 0.0485, 1e-8);
  EXPECT_NEAR(r->steps[2].vq_m3, 0.045, 1e-8);
  EXPECT_NEAR(r->steps[1].var_vq, std::pow(0.25 * 0.007, 2), 1e-12);
}

// The cut's cross-section per step: with the edge rolled, the depth runs linearly across the
// blade, so Σ d ds and Σ d² ds have closed forms; a mean depth times the extent holds the first
// but not the second (the FEE's γ term), which is why the steps carry both sums.
TEST(Extraction, StepCrossSectionHoldsTheDepthProfileAcrossARolledEdge) {
  for (const double roll_deg : {0.0, 2.0, 3.0}) {
    Case c;
    c.heading = 0.3;
    c.roll = roll_deg * kPi / 180;
    const double res = 0.05;
    const auto r = runCase(c, res);
    ASSERT_TRUE(r->fee_valid);
    // Horizontal edge length L, vertical depth 0.12 -/+ h at its ends (alpha = 0: d = depth_v).
    const double L = 1.85 * std::cos(c.roll), h = 0.925 * std::sin(c.roll);
    const double area = 0.12 * L, depth2 = L * (0.12 * 0.12 + h * h / 3.0);
    for (const auto& s : r->steps) {
      ASSERT_TRUE(std::isfinite(s.area_m2) && std::isfinite(s.depth2_m3));
      // One bin at each end may be in or out (the ends fall on cell centres), up to 0.152 m deep.
      EXPECT_NEAR(s.area_m2, area, res * (0.12 + h) + 1e-3) << roll_deg;
      EXPECT_NEAR(s.depth2_m3, depth2, res * (0.12 + h) * (0.12 + h) + 2e-4) << roll_deg;
      // The effective depth depth2 / area is the depth-weighted one, deeper than the mean once
      // the edge is rolled.
      if (roll_deg >= 3.0) EXPECT_GT(s.depth2_m3 / s.area_m2, 0.12 + 0.8 * h * h / (3.0 * 0.12)) << roll_deg;
    }
  }
  // Partial contact: with the centre at the surface only the low half cuts, its depth rising
  // from 0 to 0.925 sin(6 deg) = 9.7 cm: area = L/2 * h/2, depth2 = L/2 * h^2/3.
  Case p;
  p.roll = 6.0 * kPi / 180;
  p.depth_v = 0.0;
  const auto q = runCase(p);
  const double L = 1.85 * std::cos(p.roll), h = 0.925 * std::sin(p.roll);
  const SweepStep& s = q->steps.back();
  EXPECT_NEAR(s.area_m2, 0.5 * L * 0.5 * h, 0.05 * h);
  EXPECT_NEAR(s.depth2_m3, 0.5 * L * h * h / 3.0, 0.05 * h * h);
  // d_m^2 w_m (the exp(C_d d)-weighted mean depth over the contact width) is 13 % short of it
  // here (a plain mean would be a quarter short).
  EXPECT_LT(s.d_m * s.d_m * s.w_m, 0.92 * s.depth2_m3);
}
