// The FEE against published earth-pressure closed forms (Rankine, Coulomb) and against an
// independent world-frame force polygon of the same trial wedge.
#include "fee_test_util.hpp"

#include <gtest/gtest.h>

namespace terramap::fee {
namespace {

using test::kDeg;
using test::kPi;

double rankineKp(double phi) { return std::pow(std::tan(kPi / 4 + phi / 2), 2); }

/// Coulomb's passive coefficient for a vertical wall, wall friction delta and a backfill
/// rising at i away from the wall (e.g. Das, Principles of Geotechnical Engineering, with the
/// wall inclination theta = 0). The passive force P_p = 1/2 gamma H^2 K_p is the *resultant*,
/// inclined at delta to the wall normal (downward on the soil).
double coulombKp(double phi, double delta, double i) {
  const double root = std::sqrt(std::sin(phi + delta) * std::sin(phi + i) / (std::cos(delta) * std::cos(i)));
  return std::pow(std::cos(phi), 2) / (std::cos(delta) * std::pow(1 - root, 2));
}

Soil soil(double c, double phi, double gamma, double ca, double delta) {
  Soil s;
  s.c_pa = c;
  s.phi_rad = phi;
  s.gamma_n_m3 = gamma;
  s.ca_pa = ca;
  s.delta_rad = delta;
  return s;
}

Geometry geom(double alpha, double rho, double d, double w, double q) {
  Geometry g;
  g.alpha_rad = alpha;
  g.rho_rad = rho;
  g.d_m = d;
  g.w_m = w;
  g.q_n = q;
  return g;
}

TEST(FeeRankine, SmoothVerticalWallCohesionless) {
  for (double phiDeg : {0.0, 10.0, 25.0, 30.0, 37.5, 45.0}) {
    const double phi = phiDeg * kDeg, gamma = 17500, d = 0.8, w = 1.85;
    const Soil s = soil(0, phi, gamma, 0, 0);
    const Geometry g = geom(0, kPi / 2, d, w, 0);
    const double beta = betaNominal(s);
    EXPECT_NEAR(beta, (45 - phiDeg / 2) * kDeg, 1e-15);
    const Result r = evaluate(s, g, beta);
    ASSERT_TRUE(r.valid()) << validityName(r.validity);
    const double expected = 0.5 * rankineKp(phi) * gamma * d * d * w;
    EXPECT_NEAR(r.F_N.x(), expected, 1e-12 * expected) << "phi " << phiDeg;
    EXPECT_NEAR(r.F_N.y(), 0.0, 1e-12 * expected);  // smooth wall: horizontal force only
    EXPECT_NEAR(r.f_N, expected, 1e-12 * expected);
    // For a smooth vertical wall the Rankine plane is also Coulomb's critical plane.
    EXPECT_NEAR(betaMin(s, g), beta, 1e-7);
  }
}

TEST(FeeRankine, CohesionAddsTwoCSqrtKp) {
  for (double phiDeg : {0.0, 20.0, 30.0, 40.0}) {
    const double phi = phiDeg * kDeg, gamma = 19000, c = 12000, d = 0.5, w = 2.0;
    const Soil s = soil(c, phi, gamma, 0, 0);
    const Result r = evaluate(s, geom(0, kPi / 2, d, w, 0), betaNominal(s));
    ASSERT_TRUE(r.valid());
    const double kp = rankineKp(phi);
    const double expected = 0.5 * kp * gamma * d * d * w + 2 * c * d * std::sqrt(kp) * w;
    EXPECT_NEAR(r.F_N.x(), expected, 1e-12 * expected) << "phi " << phiDeg;
    EXPECT_NEAR(r.n.N_c, 2 * std::sqrt(kp), 1e-12 * kp);
  }
}

TEST(FeeRankine, UniformSurchargeOnTheWedgeGivesQKpH) {
  // A uniform surcharge q (Pa) on the wedge top (length d cot beta) weighs Q = q w d cot beta;
  // Rankine's passive surcharge term is q K_p d w.
  for (double phiDeg : {15.0, 30.0, 42.0}) {
    const double phi = phiDeg * kDeg, q = 5000, d = 0.4, w = 1.5;
    const Soil s = soil(0, phi, 0, 0, 0);
    const double beta = betaNominal(s);
    const double Q = q * w * d / std::tan(beta);
    const Result r = evaluate(s, geom(0, kPi / 2, d, w, Q), beta);
    ASSERT_TRUE(r.valid());
    const double expected = q * rankineKp(phi) * d * w;
    EXPECT_NEAR(r.F_N.x(), expected, 1e-12 * expected);
  }
}

TEST(FeeCoulomb, PassiveKpPhi30Delta20) {
  const double phi = 30 * kDeg, delta = 20 * kDeg, gamma = 18000, H = 1.2, w = 1.0;
  const double kp = coulombKp(phi, delta, 0);
  EXPECT_NEAR(kp, 6.105, 1e-3);  // the tabulated value
  const Soil s = soil(0, phi, gamma, 0, delta);
  const Geometry g = geom(0, kPi / 2, H, w, 0);
  const Result r = evaluateAtBetaMin(s, g);
  ASSERT_TRUE(r.valid()) << validityName(r.validity);
  // Coulomb's K_p gives the resultant on the wall: it is f (= |F|); the horizontal
  // component is f cos(delta) and the vertical one -f sin(delta) (friction pushes the soil down).
  const double Pp = 0.5 * gamma * H * H * w * kp;
  EXPECT_NEAR(r.f_N, Pp, 1e-9 * Pp);
  EXPECT_NEAR(r.F_N.norm(), Pp, 1e-9 * Pp);
  EXPECT_NEAR(r.F_N.x(), Pp * std::cos(delta), 1e-9 * Pp);
  EXPECT_NEAR(r.F_N.y(), -Pp * std::sin(delta), 1e-9 * Pp);
  EXPECT_NEAR(2 * r.n.N_gamma, kp, 1e-9 * kp);
  // Wall friction makes the passive failure plane flatter than Rankine's.
  EXPECT_LT(r.beta_rad, betaNominal(s));
}

TEST(FeeCoulomb, PassiveKpManyFrictionAnglesAndBackfillSlopes) {
  // Vertical wall (rho measured from the surface = 90 deg + i), backfill slope i = alpha.
  // The wall height H relates to the FEE depth (normal to the surface) by d = H cos i.
  for (double phiDeg : {20.0, 30.0, 40.0})
    for (double ratio : {0.0, 1.0 / 3, 2.0 / 3})
      for (double iDeg : {-10.0, 0.0, 10.0, 15.0}) {
        const double phi = phiDeg * kDeg, delta = ratio * phi, i = iDeg * kDeg;
        const double gamma = 16000, H = 0.9, w = 1.3;
        const Soil s = soil(0, phi, gamma, 0, delta);
        const Geometry g = geom(i, kPi / 2 + i, H * std::cos(i), w, 0);
        const Result r = evaluateAtBetaMin(s, g);
        ASSERT_TRUE(r.valid()) << validityName(r.validity);
        const double Pp = 0.5 * gamma * H * H * w * coulombKp(phi, delta, i);
        EXPECT_NEAR(r.f_N, Pp, 1e-9 * Pp) << phiDeg << " " << ratio << " " << iDeg;
        // Direction: delta below the (horizontal) wall normal.
        EXPECT_NEAR(std::atan2(-r.F_N.y(), r.F_N.x()), delta, 1e-12);
      }
}

TEST(FeeWedge, ClosedFormEqualsIndependentForcePolygon) {
  std::mt19937_64 rng(20261122);
  for (int k = 0; k < 2000; ++k) {
    const ParamVector p = test::randomAdmissible(rng, 0.02);
    Soil s;
    Geometry g;
    double beta;
    unpack(p, s, g, beta);
    ASSERT_EQ(check(s, g, beta), Validity::Valid);
    const Result r = evaluate(s, g, beta);
    const test::WedgeForce ref = test::wedgeForce(s, g, beta);
    const double scale = std::max(std::abs(ref.P), ref.total.norm());
    EXPECT_NEAR(r.f_N, ref.P, 1e-9 * scale) << "sample " << k;
    EXPECT_NEAR(r.F_N.x(), ref.resultant.x(), 1e-9 * scale) << "sample " << k;
    EXPECT_NEAR(r.F_N.y(), ref.resultant.y(), 1e-9 * scale) << "sample " << k;
    EXPECT_NEAR(r.F_total_N.x(), ref.total.x(), 1e-9 * scale) << "sample " << k;
    EXPECT_NEAR(r.F_total_N.y(), ref.total.y(), 1e-9 * scale) << "sample " << k;
  }
}

TEST(FeeWedge, ForceIsLinearInTheLoadParameters) {
  // f is linear in the loads (gamma, c, Q, ca) at a fixed failure angle: evaluated, the force
  // of the summed loads is the sum of the forces, and scaling the loads scales it.
  const Soil s = soil(8000, 0.5, 17000, 3000, 0.3);
  const Geometry g = geom(0.1, 1.2, 0.3, 1.7, 900);
  const double beta = 0.6;
  const Result r = evaluate(s, g, beta);
  const Factors n = factors(s, g, beta);
  const double d = g.d_m, w = g.w_m;
  const Soil s1 = soil(3000, 0.5, 5000, 1000, 0.3), s2 = soil(5000, 0.5, 12000, 2000, 0.3);
  const Geometry g1 = geom(0.1, 1.2, 0.3, 1.7, 400), g2 = geom(0.1, 1.2, 0.3, 1.7, 500);
  const double f1 = evaluate(s1, g1, beta).f_N, f2 = evaluate(s2, g2, beta).f_N;
  EXPECT_NEAR(r.f_N, f1 + f2, 1e-9 * std::abs(r.f_N));
  EXPECT_NEAR(evaluate(soil(16000, 0.5, 34000, 6000, 0.3), geom(0.1, 1.2, 0.3, 1.7, 1800), beta).f_N, 2 * r.f_N,
              1e-9 * std::abs(r.f_N));
  // Each load alone contributes its own term: with only gamma the force is gamma d^2 w N_gamma.
  EXPECT_NEAR(evaluate(soil(0, 0.5, 17000, 0, 0.3), geom(0.1, 1.2, 0.3, 1.7, 0), beta).f_N,
              s.gamma_n_m3 * d * d * w * n.N_gamma, 1e-9 * std::abs(r.f_N));
  // Hand values at this point (computed from the formulas of ALGORITHMS.md §E by hand/calculator):
  // eta = 0.3 + 1.2 + 0.5 + 0.6 = 2.6
  EXPECT_DOUBLE_EQ(n.eta_rad, 2.6);
  const double S = std::sin(2.6);
  EXPECT_NEAR(n.N_Q, std::sin(0.1 + 0.5 + 0.6) / S, 1e-15);
  EXPECT_NEAR(n.N_c, std::cos(0.5) / (std::sin(0.6) * S), 1e-14);
  EXPECT_NEAR(n.N_ca, -std::cos(1.2 + 0.5 + 0.6) / (std::sin(1.2) * S), 1e-14);
  // The adhesion adds exactly ca d w / sin(rho) along the blade face.
  const Eigen::Vector2d adh = r.F_total_N - r.F_N;
  EXPECT_NEAR(adh.norm(), s.ca_pa * d * w / std::sin(g.rho_rad), 1e-9);
  EXPECT_NEAR(std::atan2(-adh.y(), adh.x()), g.rho_rad - g.alpha_rad, 1e-12);
}

TEST(FeeWedge, NominalEvaluationUsesRankineAngle) {
  const Soil s = soil(1000, 0.6, 16000, 500, 0.4);
  const Geometry g = geom(0.05, 1.3, 0.2, 1.85, 300);
  const Result a = evaluateAtBetaNominal(s, g), b = evaluate(s, g, kPi / 4 - 0.3);
  EXPECT_EQ(a.beta_rad, b.beta_rad);
  EXPECT_EQ(a.f_N, b.f_N);
  EXPECT_TRUE(a.valid());
}

}  // namespace
}  // namespace terramap::fee
