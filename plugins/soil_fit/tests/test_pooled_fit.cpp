// The pooled fit (pooled_fit.hpp): rows of many depths and surcharges in one soil recover its
// c and φ, which rows of one geometry cannot tell apart (their fit's variance says so); a row's
// modelled force is the FEE's F_total at β* plus the penetration on descending rows; the
// plugin's rows leave stalled rows out and read the edge's descent from the observation.
#include <gtest/gtest.h>

#include <terramap/core/parallel.hpp>
#include <terramap/soil/soil_table.hpp>

#include <cmath>
#include <random>

#include "pooled_fit.hpp"
#include "soil_fit.hpp"

using namespace terramap;
using namespace terramap::soil;

namespace {

// Rows of soil s with the estimator's own model (so the fit's truth is s); varied: random
// depths, rakes, surcharges and edge motion, the blade cutting its full width.
std::vector<FitRow> rowsOf(const fee::Soil& s, int n, bool varied, unsigned seed, double noise_n,
                           const PooledFitOptions& opt = {}) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> N(0.0, 1.0);
  std::vector<FitRow> rows;
  for (int i = 0; i < n; ++i) {
    FitRow r;
    r.geometry = varied ? fee::Geometry{0.05 * (u(rng) - 0.5), 1.25 + 0.2 * u(rng), 0.03 + 0.2 * u(rng), 1.85, 6000 * u(rng)}
                        : fee::Geometry{0.0, 1.4, 0.1, 1.85, 2000};
    r.p_descending = varied && u(rng) < 0.4 ? 1.0 : 0.0;
    Eigen::Vector2d f;
    EXPECT_TRUE(modelForce(s, r, opt, f));
    r.fx_n = f.x() + noise_n * N(rng);
    r.fz_n = f.y() + noise_n * N(rng);
    rows.push_back(r);
  }
  return rows;
}

SoilParamVector middle() {
  SoilParamVector m{};
  for (int k = 0; k < kSoilParamCount; ++k) m[static_cast<std::size_t>(k)] = 0.5 * (kSoilParams[k].lo + kSoilParams[k].hi);
  return m;
}

}  // namespace

TEST(PooledFit, TheModelIsFTotalPlusPenetrationOnDescendingRows) {
  const fee::Soil s = soilProperties(SoilFamily::Loam, 0.5).fee;
  FitRow r;
  r.geometry = {0.0, 1.4, 0.1, 1.85, 2000};
  Eigen::Vector2d up, down;
  const PooledFitOptions opt;
  ASSERT_TRUE(modelForce(s, r, opt, up));
  EXPECT_TRUE(up.isApprox(fee::evaluateAtBetaMin(s, r.geometry).F_total_N));
  r.p_descending = 1.0;
  ASSERT_TRUE(modelForce(s, r, opt, down));
  EXPECT_DOUBLE_EQ(down.x(), up.x());
  EXPECT_NEAR(up.y() - down.y(), fee::penetrationForce(s, 0.1, 1.85, 0.025), 1e-9);
  r.geometry.d_m = -0.1;  // above the surface: no wedge
  EXPECT_FALSE(modelForce(s, r, opt, down));
  EXPECT_EQ(down, Eigen::Vector2d::Zero());
}

// A rolled edge cuts 4 cm at one half of the blade and 12 cm at the other: the slices' FEE is
// the two halves' sum, which one wedge at the cross-section's (depth2/area, area²/depth2)
// reproduces and one at the mean depth over the cutting width does not (its γ term takes
// 8² for (4² + 12²)/2 cm²); the edge meets the penetration over the cutting width at the mean
// depth.
TEST(PooledFit, TheCrossSectionHoldsTheSlicesSum) {
  const fee::Soil s = soilProperties(SoilFamily::Gravel, 0.6).fee;
  const double half = 0.925, d1 = 0.04, d2 = 0.12;
  const fee::Geometry g1{0.0, 1.4, d1, half, 0.0}, g2{0.0, 1.4, d2, half, 0.0};
  const Eigen::Vector2d slices = fee::evaluateAtBetaMin(s, g1).F_total_N + fee::evaluateAtBetaMin(s, g2).F_total_N;
  FitRow r;
  r.geometry = {0.0, 1.4, 0.5 * (d1 + d2), 2 * half, 0.0};
  r.area_m2 = half * (d1 + d2);
  r.depth2_m3 = half * (d1 * d1 + d2 * d2);
  PooledFitOptions with, without;
  without.cross_section = false;
  const RowForce a = rowForce(s, r, with), b = rowForce(s, r, without);
  ASSERT_TRUE(a.valid && b.valid);
  EXPECT_NEAR(a.fee_n.x(), slices.x(), 1e-6 * slices.norm());
  EXPECT_NEAR(a.fee_n.y(), slices.y(), 1e-6 * slices.norm());
  EXPECT_GT(std::abs(b.fee_n.x() - slices.x()), 0.1 * std::abs(slices.x()));
  EXPECT_NEAR(a.penetration_n, fee::penetrationForce(s, 0.5 * (d1 + d2), 2 * half, 0.025), 1e-6 * a.penetration_n);
}

// The blade cuts over a third of its width: the pile across the whole blade loads the wedge
// over that third only, and the rest is pushed along the ground (pile_friction times its
// weight, horizontal).
TEST(PooledFit, OnlyThePileAheadOfTheCutLoadsTheWedge) {
  const fee::Soil s = soilProperties(SoilFamily::Sand, 0.4).fee;
  FitRow r;
  r.geometry = {0.0, 1.4, 0.08, 0.6, 9000.0};
  r.blade_width_m = 1.8;
  PooledFitOptions opt, whole;
  whole.surcharge_share = false;
  fee::Geometry third = r.geometry;
  third.q_n = 3000.0;
  const Eigen::Vector2d expect = fee::evaluateAtBetaMin(s, third).F_total_N + Eigen::Vector2d(opt.pile_friction * 6000.0, 0.0);
  const RowForce a = rowForce(s, r, opt), b = rowForce(s, r, whole);
  EXPECT_NEAR(a.fee_n.x(), expect.x(), 1e-6 * expect.norm());
  EXPECT_NEAR(a.fee_n.y(), expect.y(), 1e-6 * expect.norm());
  EXPECT_TRUE(b.fee_n.isApprox(fee::evaluateAtBetaMin(s, r.geometry).F_total_N));
}

// A dense clay's edge meets tens of kN while it descends; the observed vertical speed gets the
// sign wrong on a share of the rows (near zero speed). Taking the speed's sign as the gate, the
// fit must explain 30 kN rows without penetration and rows with it that have none, and its c
// and φ trade off; with the gate a latent switch the force decides it, and the fit recovers
// the soil.
TEST(PooledFit, TheForceDecidesTheGateWhereTheSpeedIsUnsure) {
  const fee::Soil s = soilProperties(SoilFamily::Clay, 0.8).fee;
  std::vector<FitRow> rows = rowsOf(s, 150, true, 11, 400.0);
  std::mt19937 rng(12);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int flipped = 0;
  for (FitRow& r : rows) {
    // The speed's prior: 0.8 / 0.2 where it is sure, and 0.4 / 0.6 (the wrong side) on a fifth.
    const bool down = r.p_descending > 0.5;
    const bool wrong = u(rng) < 0.2;
    flipped += wrong;
    r.p_descending = wrong ? (down ? 0.4 : 0.6) : (down ? 0.8 : 0.2);
  }
  ASSERT_GT(flipped, 20);
  PooledFitOptions mixture, sign;
  sign.gate_mixture = false;
  const PooledFit a = fitPooled(rows, middle(), mixture), b = fitPooled(rows, middle(), sign);
  EXPECT_NEAR(a.mean[kParamC], s.c_pa, 3000.0);
  EXPECT_NEAR(a.mean[kParamPhi], s.phi_rad, 2.0 * kDegree);
  EXPECT_GT(std::abs(b.mean[kParamC] - s.c_pa) + 3000.0 * std::abs(b.mean[kParamPhi] - s.phi_rad) / kDegree,
            3.0 * (std::abs(a.mean[kParamC] - s.c_pa) + 3000.0 * std::abs(a.mean[kParamPhi] - s.phi_rad) / kDegree));
}

TEST(PooledFit, ManyGeometriesOfOneSoilTellCohesionFromFriction) {
  for (const auto& [family, id] : {std::pair{SoilFamily::Clay, 0.1}, std::pair{SoilFamily::Loam, 0.7},
                                   std::pair{SoilFamily::Gravel, 0.5}}) {
    const SoilProperties sp = soilProperties(family, id);
    SCOPED_TRACE(soilFamilyName(family));
    const PooledFit fit = fitPooled(rowsOf(sp.fee, 120, true, 3, 300.0), middle());
    EXPECT_GT(fit.rows, 100);
    EXPECT_NEAR(fit.mean[kParamPhi], sp.fee.phi_rad, 2.0 * kDegree);
    EXPECT_NEAR(fit.mean[kParamC], sp.fee.c_pa, 3000.0);
    EXPECT_LT(std::sqrt(fit.covariance(kParamPhi, kParamPhi)), 2.0 * kDegree);
  }
}

TEST(PooledFit, OneGeometryLeavesFrictionToThePrior) {
  const SoilProperties sp = soilProperties(SoilFamily::Clay, 0.1);
  const PooledFit one = fitPooled(rowsOf(sp.fee, 120, false, 4, 300.0), middle());
  const PooledFit many = fitPooled(rowsOf(sp.fee, 120, true, 4, 300.0), middle());
  // The same number of rows: only their spread of depth, surcharge and edge motion differs.
  EXPECT_GT(one.covariance(kParamPhi, kParamPhi), 10.0 * many.covariance(kParamPhi, kParamPhi));
  EXPECT_GT(std::abs(one.mean[kParamPhi] - sp.fee.phi_rad), std::abs(many.mean[kParamPhi] - sp.fee.phi_rad));
}

// Rows four times noisier than the fit assumes: the covariance takes the residuals' scale, so
// the reported 1 sigma of phi still covers the error about as often as a 1 sigma should.
TEST(PooledFit, TheCovarianceFollowsTheResidualsScatter) {
  const SoilProperties sp = soilProperties(SoilFamily::Loam, 0.4);
  int covered = 0, fits = 0;
  for (unsigned seed = 10; seed < 40; ++seed, ++fits) {
    const PooledFit f = fitPooled(rowsOf(sp.fee, 60, true, seed, 6000.0), middle());
    EXPECT_GT(f.rms_n, 3.0 * PooledFitOptions{}.force_sigma_n);
    covered += std::abs(f.mean[kParamPhi] - sp.fee.phi_rad) <= std::sqrt(f.covariance(kParamPhi, kParamPhi));
  }
  EXPECT_GE(covered, fits / 2) << covered << " of " << fits;
}

TEST(PooledFit, NoRowsGiveThePrior) {
  const PooledFit f = fitPooled({}, middle());
  EXPECT_FALSE(f.converged);
  EXPECT_EQ(f.rows, 0);
  EXPECT_NEAR(f.mean[kParamPhi], middle()[kParamPhi], 1e-12);
}

TEST(SoilFitPlugin, RowsLeaveStalledAndUncutRowsOutAndReadTheDescent) {
  PinnSample s;
  s.T = 3;
  s.P = 3;
  s.obs.assign(static_cast<std::size_t>(s.T) * kObsFeatures, 0.0f);
  for (int p = 0; p < 3; ++p) {
    s.theta_k.insert(s.theta_k.end(), {1.4f, 0.0f, 1.85f, p == 1 ? -0.02f : 0.1f, 2000.0f, 0.5f});
    s.profile.insert(s.profile.end(), {0.185f, 0.0185f});
    s.force.insert(s.force.end(), {5000.0f + p, -1000.0f});
  }
  float* row0 = s.obs.data();
  row0[kObsFeatures - 1] = 0.2f;    // rising fast: surely not descending
  float* row2 = s.obs.data() + 2 * kObsFeatures;
  row2[kObsFeatures - 1] = -0.05f;  // descending at one sigma of the speed's uncertainty
  std::vector<FitRow> rows = plugins::fitRows(s, 1.85, 0.05);
  ASSERT_EQ(rows.size(), 2u);  // row 1 cuts nothing
  EXPECT_LT(rows[0].p_descending, 1e-4);
  EXPECT_NEAR(rows[1].p_descending, 0.8413, 1e-3);  // Φ(1)
  EXPECT_EQ(rows[1].fx_n, 5002.0);
  EXPECT_FLOAT_EQ(static_cast<float>(rows[1].area_m2), 0.185f);
  EXPECT_EQ(rows[1].blade_width_m, 1.85);
  // Without a speed uncertainty the gate is the speed's sign.
  EXPECT_EQ(plugins::fitRows(s, 1.85, 0.0)[1].p_descending, 1.0);
  // Row 0 stalled: tracks turning (feature 26, 27) while the base (feature 0) stands.
  s.obs[26] = s.obs[27] = 1.0f;
  rows = plugins::fitRows(s, 1.85, 0.05);
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_GT(rows[0].p_descending, 0.5);
}

// A cohesionless soil's rows hardly tell adhesion apart: free in its range, c_a stays near the
// prior's middle (15 kPa) and the FEE index reads a loose sand as strong; bounded by the
// cohesion (c_a = a c), it follows c to zero. The same for δ against φ.
TEST(PooledFit, TheInterfaceBoundedBySoilKeepsAdhesionOffACohesionlessSoil) {
  const SoilProperties sp = soilProperties(SoilFamily::Sand, 0.2);
  ASSERT_EQ(sp.fee.c_pa, 0.0);
  // The rows as the map gives them: the force of the whole pile, but the surcharge the mapped
  // pile holds (a median 0.6 of the simulator's on sand: docs/soil_estimator.md).
  std::vector<FitRow> rows = rowsOf(sp.fee, 120, true, 5, 300.0);
  for (FitRow& r : rows) r.geometry.q_n *= 0.6;
  PooledFitOptions bounded, free_interface;
  free_interface.interface_bounded_by_soil = false;
  const PooledFit b = fitPooled(rows, middle(), bounded);
  const PooledFit f = fitPooled(rows, middle(), free_interface);
  EXPECT_LE(b.mean[kParamCa], b.mean[kParamC] + 1e-9);
  EXPECT_LE(b.mean[kParamDelta], b.mean[kParamPhi] + 1e-12);
  EXPECT_LT(b.mean[kParamCa], 1000.0);
  EXPECT_GT(f.mean[kParamCa], 2000.0);  // what the bound removes (4.1 kPa here)
  // The reference cut's force (what fee_index reads) is then the sand's, not a cohesive soil's.
  const fee::Geometry ref{0.0, 1.4, 0.15, 1.85, 0.0};
  auto refForce = [&](const PooledFit& p) { return fee::evaluateAtBetaMin(toFee(p.mean), ref).F_total_N.x(); };
  const double truth = fee::evaluateAtBetaMin(sp.fee, ref).F_total_N.x();
  EXPECT_LT(std::abs(refForce(b) - truth), std::abs(refForce(f) - truth));  // 1.30 against 1.69 kN
  // The covariance is in SI units through the ratios' Jacobian: finite, positive, c_a's no wider
  // than c's range allows.
  for (int k = 0; k < kSoilParamCount; ++k) EXPECT_GT(b.covariance(k, k), 0.0) << k;
  EXPECT_TRUE(b.covariance.allFinite());
}

// A pass crossing from a loose soil into a dense strip at x = 3 m, one sweep every 0.2 m. A
// window of the last 10 sweeps fits the strip's first sweeps mostly with the loose soil's rows,
// so the estimate crosses to the strip about half a window (1 m) late and paints the strip's
// leading metre as loose ground; a window centred on each sweep (5 after it) crosses at the edge.
TEST(SoilFitWindow, ACentredWindowPutsTheStripEdgeWhereItIs) {
  const fee::Soil loose = soilProperties(SoilFamily::Clay, 0.1).fee, dense = soilProperties(SoilFamily::Clay, 0.8).fee;
  const fee::Geometry ref{0.0, 1.4, 0.15, 1.85, 0.0};
  auto refForce = [&](const fee::Soil& s) { return fee::evaluateAtBetaMin(s, ref).F_total_N.x(); };
  const double f_loose = refForce(loose), f_dense = refForce(dense);
  ASSERT_GT(f_dense, 1.5 * f_loose);
  // Where the estimate first reads nearer the dense soil than the loose one (m).
  auto crossing = [&](int lookahead) {
    plugins::SweepWindow window(10, lookahead, 2.0);
    constexpr int kSweeps = 30;
    for (int k = 0; k < kSweeps; ++k) {
      const double x = 0.2 * k;
      window.add({x, 0.0, 0.0}, rowsOf(x < 3.0 - 1e-9 ? loose : dense, 10, true, 100 + k, 300.0));
    }
    SoilParamVector start = middle();
    for (int k = 0; k < kSweeps; ++k) {
      EXPECT_TRUE(window.complete(k) || k + lookahead >= kSweeps);
      int sweeps = 0;
      const std::vector<FitRow> rows = window.rowsFor(k, &sweeps);
      EXPECT_EQ(sweeps, std::min({10, k + 1 + lookahead, kSweeps - k + 9 - lookahead, kSweeps}));
      const PooledFit fit = fitPooled(rows, start, PooledFitOptions{});
      start = fit.mean;
      const double f = refForce(toFee(fit.mean));
      if (std::abs(f - f_dense) < std::abs(f - f_loose)) return 0.2 * k;
    }
    return 1e9;
  };
  const double centred = crossing(5), causal = crossing(0);
  EXPECT_NEAR(centred, 3.0, 0.21);  // the edge, within a sweep
  EXPECT_GE(causal, 3.6);           // what the centring removes
}

// The window's reach in space: a sweep whose blade ended more than window_m away (here on the
// next lane, 2.6 m off) is not fitted with this one even when it is among its sweeps; forgetting
// keeps what a waiting sweep still needs.
TEST(SoilFitWindow, TheReachLeavesOtherLanesOutAndForgettingKeepsWhatIsNeeded) {
  plugins::SweepWindow window(4, 1, 2.0);
  FitRow row;
  row.geometry = {0.0, 1.4, 0.1, 1.85, 0.0};
  row.fx_n = 1.0;
  const std::vector<FitRow> one(3, row);
  window.add({0.0, 0.0, 0.0}, one);
  window.add({0.2, 0.0, 0.0}, one);
  window.add({0.4, 1.6, 0.0}, one);  // the next lane, 1.6 m over: within 2 m of sweep 1
  window.add({2.2, 1.6, 0.0}, one);
  int sweeps = 0;
  EXPECT_EQ(window.rowsFor(1, &sweeps).size(), 9u);  // sweeps 0, 1, 2 (2 is its lookahead)
  EXPECT_EQ(sweeps, 3);
  EXPECT_EQ(window.rowsFor(3, &sweeps).size(), 6u);  // 2 and 3; 1 is 2.6 m away
  EXPECT_EQ(sweeps, 2);
  EXPECT_FALSE(window.complete(3));
  EXPECT_TRUE(window.complete(2));
  window.forgetBefore(3);  // sweep 3 reaches back two sweeps: 1 and 2 stay
  EXPECT_EQ(window.rowsFor(1, &sweeps).size(), 6u);  // sweep 0 forgotten
  EXPECT_EQ(window.rowsFor(0, &sweeps).size(), 0u);
}

// A unit weight known on site (a sand-cone test): γ's prior holds it where the rows cannot tell
// it, and the pile's missing weight no longer goes into γ. Rows of a loose sand whose mapped pile
// holds 0.6 of its weight, fitted with the pile weighed by the fitted γ: with the wide prior γ
// climbs well above the sand's to carry the missing weight; with the sand's γ as a firm prior it
// stays there (and the fit's φ carries the rest instead).
TEST(PooledFit, AKnownUnitWeightHoldsGammaWhereTheRowsCannotTellIt) {
  const SoilProperties sp = soilProperties(SoilFamily::Sand, 0.2);
  std::vector<FitRow> rows = rowsOf(sp.fee, 120, true, 7, 300.0);
  constexpr double kRef = 14636.0;  // blade_sweep's unit weight for the mapped Q
  for (FitRow& r : rows) r.geometry.q_n *= 0.6 * kRef / sp.fee.gamma_n_m3;  // Q as blade_sweep maps it
  PooledFitOptions wide, known;
  wide.q_gamma_ref_n_m3 = known.q_gamma_ref_n_m3 = kRef;
  known.gamma_prior_n_m3 = sp.fee.gamma_n_m3;
  known.gamma_prior_sd_n_m3 = 200.0;
  const PooledFit w = fitPooled(rows, middle(), wide), k = fitPooled(rows, middle(), known);
  EXPECT_GT(w.mean[kParamGamma], sp.fee.gamma_n_m3 + 2000.0);
  EXPECT_NEAR(k.mean[kParamGamma], sp.fee.gamma_n_m3, 500.0);
  EXPECT_GT(k.mean[kParamPhi], sp.fee.phi_rad);  // the missing weight, now in φ
  EXPECT_LT(std::sqrt(k.covariance(kParamGamma, kParamGamma)), 300.0);
}

// The same pass across a strip edge at 3 m: the centred window blends the two soils over the
// sweeps near the edge (its estimate there is neither), while fitting each sweep with the window
// before it, the centred one and the one after it, and keeping the one whose soil explains the
// sweep's own rows best, puts every sweep near the edge on its own side.
TEST(SoilFitWindow, TheWindowThatExplainsTheSweepKeepsTheEdgeSharp) {
  const fee::Soil loose = soilProperties(SoilFamily::Clay, 0.1).fee, dense = soilProperties(SoilFamily::Clay, 0.8).fee;
  constexpr int kSweeps = 30;
  plugins::SweepWindow window = plugins::SweepWindow::keeping(9, 9, 2.0);
  for (int k = 0; k < kSweeps; ++k) {
    const double x = 0.2 * k;
    window.add({x, 0.0, 0.0}, rowsOf(x < 3.0 - 1e-9 ? loose : dense, 10, true, 200 + k, 300.0));
  }
  // How far, in kPa, each sweep's c sits from its own soil's, over the four sweeps at the edge.
  auto edgeError = [&](double margin) {
    double worst = 0.0;
    for (int k = 13; k <= 16; ++k) {
      const plugins::WindowChoice w = plugins::fitWindow(window, k, 10, 5, margin, 10, {middle()}, PooledFitOptions{});
      const double truth = 0.2 * k < 3.0 - 1e-9 ? loose.c_pa : dense.c_pa;
      worst = std::max(worst, std::abs(w.fit.mean[kParamC] - truth));
    }
    return worst;
  };
  const double sharp = edgeError(0.7), centred = edgeError(0.0);
  EXPECT_LT(sharp, 6000.0);
  EXPECT_GT(centred, 2.0 * sharp);
}

// A fit at 49 deg +- 3.6 deg (Fig. 12's strip, where the blade rode 1 cm deep and the pile's
// N_q took the force) ran into the wall of phi's range [10, 50] deg: 1 % of the range (0.4 deg)
// does not see it, one standard deviation does. A fit well inside keeps its estimate whatever
// its spread, and without a variance the 1 % margin still holds.
TEST(SoilFitPlugin, AFitWhoseStandardDeviationReachesPastPhisRangeIsAtTheBound) {
  const double deg = M_PI / 180.0;
  const double var = (3.6 * deg) * (3.6 * deg);
  EXPECT_FALSE(plugins::phiAtBound(49.0 * deg, var, 0.0));
  EXPECT_TRUE(plugins::phiAtBound(49.0 * deg, var, 1.0));
  EXPECT_TRUE(plugins::phiAtBound(12.0 * deg, var, 1.0));  // the other end
  EXPECT_FALSE(plugins::phiAtBound(30.0 * deg, var, 1.0));
  EXPECT_FALSE(plugins::phiAtBound(30.0 * deg, var, 5.0));
  EXPECT_TRUE(plugins::phiAtBound(30.0 * deg, var, 6.0));
  EXPECT_TRUE(plugins::phiAtBound(49.9 * deg, std::nan(""), 1.0));
  EXPECT_FALSE(plugins::phiAtBound(49.0 * deg, std::nan(""), 1.0));
}

TEST(SoilFitPlugin, AFitAsWideAsPhisRangeIsUninformative) {
  // φ's range is 10-50 deg: a uniform belief over it has a standard deviation of 40 / sqrt 12 =
  // 11.55 deg. The gravel strip's exit read 31.1 +- 17.7 deg (published, inflated): wider than
  // the range says nothing, yet a cell it alone reaches would show its mean as the soil.
  const double deg = M_PI / 180.0;
  const double uniform = 40.0 / std::sqrt(12.0);
  EXPECT_TRUE(plugins::phiUninformative((17.7 * deg) * (17.7 * deg), 1.0));
  EXPECT_TRUE(plugins::phiUninformative(((uniform + 0.01) * deg) * ((uniform + 0.01) * deg), 1.0));
  EXPECT_FALSE(plugins::phiUninformative(((uniform - 0.01) * deg) * ((uniform - 0.01) * deg), 1.0));
  EXPECT_FALSE(plugins::phiUninformative((17.7 * deg) * (17.7 * deg), 2.0));
  EXPECT_FALSE(plugins::phiUninformative((17.7 * deg) * (17.7 * deg), 0.0));  // off
  EXPECT_FALSE(plugins::phiUninformative(std::nan(""), 1.0));
}

// The fits of a sweep (three windows, four starts each) run as tasks of the engine's executor;
// the estimate is bit for bit the serial one whatever the thread count (here at a soil
// boundary, where the windows disagree and the choice between them matters).
TEST(SoilFitWindow, TheFitsInParallelGiveTheSerialEstimate) {
  const fee::Soil loose = soilProperties(SoilFamily::Clay, 0.1).fee, dense = soilProperties(SoilFamily::Clay, 0.8).fee;
  plugins::SweepWindow window = plugins::SweepWindow::keeping(9, 9, 2.0);
  for (int k = 0; k < 24; ++k) window.add({0.2 * k, 0.0, 0.0}, rowsOf(k < 12 ? loose : dense, 10, true, 400 + k, 300.0));
  for (long seq : {10L, 12L}) {
    const plugins::WindowChoice serial = plugins::fitWindow(window, seq, 10, 5, 0.7, 10, {middle()}, PooledFitOptions{});
    // The chosen window's fit is fitPooledMultiStart's on its rows.
    const std::pair<int, int> span[] = {{-4, 5}, {-9, 0}, {0, 9}};
    ASSERT_GE(serial.chosen, 0);
    const auto& [from, to] = span[serial.chosen];
    const PooledFit direct = fitPooledMultiStart(window.rowsIn(seq, from, to, nullptr), {middle()}, PooledFitOptions{});
    EXPECT_EQ(direct.cost, serial.fit.cost) << seq;
    EXPECT_EQ(direct.mean[kParamPhi], serial.fit.mean[kParamPhi]) << seq;
    for (int threads : {1, 2, 3}) {
      const Executor ex(threads);
      const plugins::WindowChoice par = plugins::fitWindow(window, seq, 10, 5, 0.7, 10, {middle()}, PooledFitOptions{}, &ex);
      EXPECT_EQ(par.chosen, serial.chosen) << seq << " " << threads;
      EXPECT_EQ(par.rows, serial.rows);
      for (int k = 0; k < kSoilParamCount; ++k) EXPECT_EQ(par.fit.mean[k], serial.fit.mean[k]) << k;
      EXPECT_TRUE((par.fit.covariance.array() == serial.fit.covariance.array()).all());
      EXPECT_EQ(par.fit.cost, serial.fit.cost);
    }
  }
}

// The profile along φ tells a soil near φ's end from a fit that slid along the c–φ valley: a
// dense gravel (φ 44.7°, c 0) cut at many depths is fitted near 45° and the rows rule 50° out;
// rows of one geometry of a clay hold only a combination of c and φ, so with φ held at 50° the
// rows are explained as well by less cohesion.
TEST(SoilFitPlugin, TheProfileAlongPhiKeepsASoilNearTheEndAndDropsAValleyFit) {
  const PooledFitOptions opt;
  const fee::Soil gravel = soilProperties(SoilFamily::Gravel, 0.9).fee;
  const std::vector<FitRow> varied = rowsOf(gravel, 100, true, 11, 300.0);
  const PooledFit near_end = fitPooledMultiStart(varied, {middle()}, opt);
  EXPECT_NEAR(near_end.mean[kParamPhi], gravel.phi_rad, 2.0 * M_PI / 180.0);
  EXPECT_FALSE(plugins::phiEndInsideProfile(varied, near_end, 1.0, 1.5, opt));
  const fee::Soil clay = soilProperties(SoilFamily::Clay, 0.8).fee;
  const std::vector<FitRow> one = rowsOf(clay, 100, false, 12, 300.0);
  PooledFitOptions held = opt;
  held.fixed_phi_rad = 47.0 * M_PI / 180.0;
  const PooledFit valley = fitPooled(one, middle(), held);
  ASSERT_NEAR(valley.mean[kParamPhi], held.fixed_phi_rad, 1e-4);
  EXPECT_TRUE(plugins::phiEndInsideProfile(one, valley, 1.0, 1.5, opt));
}

// The angle cache (PooledFitOptions::angle_cache) changes the time, not the fit: the same soil,
// covariance, cost and iterations bit for bit, on varied rows with the latent gate (whose rounds
// re-evaluate the rows at an unchanged soil) and on the bounded interface (where the c_a column
// moves c_a only).
TEST(PooledFit, TheAngleCacheGivesTheUncachedFitBitForBit) {
  for (bool bounded : {true, false}) {
    PooledFitOptions cached;
    cached.interface_bounded_by_soil = bounded;
    PooledFitOptions fresh = cached;
    fresh.angle_cache = false;
    const std::vector<FitRow> rows = rowsOf(soilProperties(SoilFamily::Loam, 0.6).fee, 80, true, 21, 500.0);
    const PooledFit a = fitPooled(rows, middle(), cached), b = fitPooled(rows, middle(), fresh);
    ASSERT_GT(a.iterations, 2);
    EXPECT_EQ(a.iterations, b.iterations);
    EXPECT_EQ(a.cost, b.cost);
    for (int k = 0; k < kSoilParamCount; ++k) EXPECT_EQ(a.mean[k], b.mean[k]) << k;
    EXPECT_TRUE((a.covariance.array() == b.covariance.array()).all());
  }
}

// A strip shorter than the window (6 sweeps, 1.2 m, of dense clay in loose): every window of
// 10 sweeps that holds a strip sweep straddles an edge, so none holds the strip's soil alone;
// windows of 5 ending or starting at the sweep do (short_sweeps), and the strip's sweeps read
// its cohesion closer.
TEST(SoilFitWindow, ShortSideWindowsResolveAStripShorterThanTheWindow) {
  const fee::Soil loose = soilProperties(SoilFamily::Clay, 0.1).fee, dense = soilProperties(SoilFamily::Clay, 0.8).fee;
  plugins::SweepWindow window = plugins::SweepWindow::keeping(9, 9, 2.0);
  for (int k = 0; k < 30; ++k) window.add({0.2 * k, 0.0, 0.0}, rowsOf(k >= 12 && k <= 17 ? dense : loose, 10, true, 600 + k, 300.0));
  auto stripError = [&](int short_sweeps) {
    double sum = 0.0;
    for (int k = 12; k <= 17; ++k) {
      const plugins::WindowChoice w =
          plugins::fitWindow(window, k, 10, 5, 0.7, 10, {middle()}, PooledFitOptions{}, nullptr, short_sweeps);
      sum += std::abs(w.fit.mean[kParamC] - dense.c_pa);
    }
    return sum / 6.0;
  };
  const double with_short = stripError(5), without = stripError(0);
  EXPECT_LT(with_short, 0.5 * without) << with_short << " against " << without;
}

// A cohesionless sand cut at depths and surcharges of one narrow band: c and φ trade along the
// FEE's valley (correlation about -0.85), and about every other fit leaves c on its zero end (the
// unconstrained optimum lies below 0). Its untruncated curvature still spreads φ along the
// valley into negative cohesions the box rules out. Truncated there, φ keeps less: no less than
// what c = 0 leaves free (the conditional variance, the Schur complement) and no more than the
// untruncated; with the prior's mass on cohesionless soils (the default) the spike at c = 0
// outweighs the slab (σ_c is a few per cent of c's range), so φ is near its conditional spread,
// and that is what the fits' errors scatter with: the truth is c = 0. Fits off c's end keep
// the untruncated covariance; the mean is the same bit for bit either way.
TEST(PooledFit, AFitOnCohesionsZeroEndPublishesTheTruncatedPosterior) {
  const SoilProperties sp = soilProperties(SoilFamily::Sand, 0.3);
  ASSERT_EQ(sp.fee.c_pa, 0.0);
  PooledFitOptions untruncated, slab_only;
  untruncated.truncated_covariance = false;
  slab_only.cohesionless_prior_mass = 0.0;
  int at_end = 0, off_end = 0, covered = 0, covered_untruncated = 0;
  for (unsigned seed = 100; seed < 180; ++seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    std::normal_distribution<double> N(0.0, 1.0);
    std::vector<FitRow> rows;
    for (int i = 0; i < 20; ++i) {
      FitRow r;
      r.geometry = fee::Geometry{0.0, 1.4, 0.1 + 0.05 * uni(rng), 1.85, 2000 * uni(rng)};
      Eigen::Vector2d f;
      ASSERT_TRUE(modelForce(sp.fee, r, {}, f));
      r.fx_n = f.x() + 2000.0 * N(rng);
      r.fz_n = f.y() + 2000.0 * N(rng);
      rows.push_back(r);
    }
    const PooledFit t = fitPooled(rows, middle());
    const PooledFit s = fitPooled(rows, middle(), slab_only);
    const PooledFit u = fitPooled(rows, middle(), untruncated);
    for (int k = 0; k < kSoilParamCount; ++k) ASSERT_EQ(t.mean[k], u.mean[k]) << seed;
    const double err = std::abs(t.mean[kParamPhi] - sp.fee.phi_rad);
    if (t.truncated_at_c_zero) {
      ++at_end;
      EXPECT_EQ(t.mean[kParamC], 0.0);
      const auto& U = u.covariance;
      const double conditional = U(kParamPhi, kParamPhi) - U(kParamPhi, kParamC) * U(kParamPhi, kParamC) / U(kParamC, kParamC);
      EXPECT_LT(s.covariance(kParamPhi, kParamPhi), U(kParamPhi, kParamPhi)) << seed;
      EXPECT_GT(s.covariance(kParamPhi, kParamPhi), conditional) << seed;
      EXPECT_LT(t.covariance(kParamPhi, kParamPhi), s.covariance(kParamPhi, kParamPhi)) << seed;
      EXPECT_NEAR(t.covariance(kParamPhi, kParamPhi), conditional, 0.1 * conditional) << seed;
      EXPECT_GT(t.cohesionless_weight, 0.9) << seed;
      EXPECT_EQ(s.cohesionless_weight, 0.0);
      EXPECT_GT(t.covariance(kParamC, kParamC), 0.0) << seed;
      EXPECT_LT(t.covariance(kParamC, kParamC), U(kParamC, kParamC)) << seed;
      covered += err <= std::sqrt(t.covariance(kParamPhi, kParamPhi));
      covered_untruncated += err <= std::sqrt(U(kParamPhi, kParamPhi));
    } else {
      ++off_end;
      EXPECT_EQ(t.covariance, u.covariance) << seed;
      EXPECT_EQ(t.cohesionless_weight, 0.0);
    }
  }
  ASSERT_GE(at_end, 20);
  EXPECT_GE(off_end, 10);
  std::printf("fits at c = 0: %d, off it: %d; phi within 1 sd: %d truncated, %d untruncated\n", at_end, off_end,
              covered, covered_untruncated);
  EXPECT_LT(covered, covered_untruncated);
}
