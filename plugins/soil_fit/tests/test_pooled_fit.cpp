// The pooled fit (pooled_fit.hpp): rows of many depths and surcharges in one soil recover its
// c and φ, which rows of one geometry cannot tell apart (their fit's variance says so); a row's
// modelled force is the FEE's F_total at β* plus the penetration on descending rows; the
// plugin's rows leave stalled rows out and read the edge's descent from the observation.
#include <gtest/gtest.h>

#include <terramap/soil/soil_table.hpp>

#include <cmath>
#include <random>

#include "pooled_fit.hpp"
#include "soil_fit.hpp"

using namespace terramap;
using namespace terramap::soil;

namespace {

std::vector<FitRow> rowsOf(const fee::Soil& s, int n, bool varied, unsigned seed, double noise_n) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> N(0.0, 1.0);
  std::vector<FitRow> rows;
  for (int i = 0; i < n; ++i) {
    FitRow r;
    r.geometry = varied ? fee::Geometry{0.05 * (u(rng) - 0.5), 1.25 + 0.2 * u(rng), 0.03 + 0.2 * u(rng), 1.85, 6000 * u(rng)}
                        : fee::Geometry{0.0, 1.4, 0.1, 1.85, 2000};
    r.descending = varied ? u(rng) < 0.4 : false;
    Eigen::Vector2d f;
    EXPECT_TRUE(modelForce(s, r, 0.025, f));
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
  FitRow r{{0.0, 1.4, 0.1, 1.85, 2000}, false, 0, 0};
  Eigen::Vector2d up, down;
  ASSERT_TRUE(modelForce(s, r, 0.025, up));
  EXPECT_TRUE(up.isApprox(fee::evaluateAtBetaMin(s, r.geometry).F_total_N));
  r.descending = true;
  ASSERT_TRUE(modelForce(s, r, 0.025, down));
  EXPECT_DOUBLE_EQ(down.x(), up.x());
  EXPECT_NEAR(up.y() - down.y(), fee::penetrationForce(s, 0.1, 1.85, 0.025), 1e-9);
  r.geometry.d_m = -0.1;  // above the surface: no wedge
  EXPECT_FALSE(modelForce(s, r, 0.025, down));
  EXPECT_EQ(down, Eigen::Vector2d::Zero());
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
    s.force.insert(s.force.end(), {5000.0f + p, -1000.0f});
  }
  float* row2 = s.obs.data() + 2 * kObsFeatures;
  row2[kObsFeatures - 1] = -0.05f;  // descending
  std::vector<FitRow> rows = plugins::fitRows(s);
  ASSERT_EQ(rows.size(), 2u);  // row 1 cuts nothing
  EXPECT_FALSE(rows[0].descending);
  EXPECT_TRUE(rows[1].descending);
  EXPECT_EQ(rows[1].fx_n, 5002.0);
  // Row 0 stalled: tracks turning (feature 26, 27) while the base (feature 0) stands.
  s.obs[26] = s.obs[27] = 1.0f;
  rows = plugins::fitRows(s);
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_TRUE(rows[0].descending);
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
