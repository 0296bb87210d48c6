// beta* (closed form) against a numeric minimisation of N_gamma over beta.
#include "fee_test_util.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <random>

namespace terramap::fee {
namespace {

using test::kPi;

struct NumericMin {
  double beta = 0, value = 0;
  bool interior = false;  ///< false when the minimum sits on an edge of the admissible interval
};

/// Fine scan of N_gamma over the open interval (lo, hi) followed by golden-section refinement
/// around the best sample.
NumericMin minimiseNumerically(double phi, double delta, double alpha, double rho) {
  double lo, hi;
  test::betaInterval(phi, delta, alpha, rho, lo, hi);
  const int n = 20000;
  const double h = (hi - lo) / n;
  auto N = [&](double b) { return test::nGammaRef(phi, delta, alpha, rho, b); };
  int best = 1;
  double bestV = N(lo + h);
  for (int i = 2; i < n; ++i) {
    const double v = N(lo + i * h);
    if (v < bestV) {
      bestV = v;
      best = i;
    }
  }
  NumericMin out;
  out.interior = best > 1 && best < n - 1;
  double a = lo + (best - 1) * h, b = lo + (best + 1) * h;
  const double r = (std::sqrt(5.0) - 1) / 2;
  double x1 = b - r * (b - a), x2 = a + r * (b - a), f1 = N(x1), f2 = N(x2);
  for (int it = 0; it < 200 && b - a > 1e-15; ++it) {
    if (f1 < f2) {
      b = x2;
      x2 = x1;
      f2 = f1;
      x1 = b - r * (b - a);
      f1 = N(x1);
    } else {
      a = x1;
      x1 = x2;
      f1 = f2;
      x2 = a + r * (b - a);
      f2 = N(x2);
    }
  }
  out.beta = 0.5 * (a + b);
  out.value = N(out.beta);
  return out;
}

TEST(FeeBetaMin, MatchesNumericMinimisationForRandomGeometries) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  int interior = 0, total = 0;
  for (int k = 0; k < 400; ++k) {
    Soil s;
    Geometry g;
    s.phi_rad = 0.8 * U(rng);
    s.delta_rad = 0.7 * U(rng);
    g.alpha_rad = -0.5 + 1.1 * U(rng);
    g.rho_rad = 0.3 + 2.0 * U(rng);
    double lo, hi;
    test::betaInterval(s.phi_rad, s.delta_rad, g.alpha_rad, g.rho_rad, lo, hi);
    if (!(hi - lo > 0.05)) continue;
    ++total;
    const NumericMin m = minimiseNumerically(s.phi_rad, s.delta_rad, g.alpha_rad, g.rho_rad);
    const double b = betaMin(s, g);
    if (m.interior) {
      ++interior;
      ASSERT_FALSE(std::isnan(b)) << "sample " << k;
      // N_gamma is flat at its minimum: compare the values tightly and the angles loosely.
      EXPECT_NEAR(test::nGammaRef(s.phi_rad, s.delta_rad, g.alpha_rad, g.rho_rad, b), m.value,
                  1e-12 * m.value)
          << "sample " << k;
      EXPECT_NEAR(b, m.beta, 2e-6) << "sample " << k;
      EXPECT_NEAR(dNgammaDbeta(s, g, b), 0.0, 1e-9 * m.value) << "sample " << k;
    } else if (!std::isnan(b)) {
      // The global minimum is an edge; betaMin may only return a genuine local minimum.
      const double e = 1e-4;
      const double n0 = test::nGammaRef(s.phi_rad, s.delta_rad, g.alpha_rad, g.rho_rad, b);
      EXPECT_LT(n0, test::nGammaRef(s.phi_rad, s.delta_rad, g.alpha_rad, g.rho_rad, b - e));
      EXPECT_LT(n0, test::nGammaRef(s.phi_rad, s.delta_rad, g.alpha_rad, g.rho_rad, b + e));
    }
  }
  std::printf("betaMin: %d of %d random geometries have an interior minimum and were compared\n", interior,
              total);
  // The comparison must actually have been made for most samples.
  EXPECT_GT(total, 300);
  EXPECT_GT(interior, total * 8 / 10) << interior << " of " << total;
}

TEST(FeeBetaMin, ResultIsAdmissibleAndIndependentOfLoads) {
  Soil s;
  s.phi_rad = 0.55;
  s.delta_rad = 0.35;
  Geometry g;
  g.alpha_rad = 0.12;
  g.rho_rad = 1.35;
  g.d_m = 0.2;
  g.w_m = 1.85;
  const double b0 = betaMin(s, g);
  ASSERT_FALSE(std::isnan(b0));
  EXPECT_EQ(check(s, g, b0), Validity::Valid);
  s.c_pa = 1e4;
  s.gamma_n_m3 = 2e4;
  s.ca_pa = 3e3;
  g.d_m = 0.7;
  g.q_n = 1e3;
  EXPECT_EQ(betaMin(s, g), b0);
}

TEST(FeeBetaMin, FlatNGammaGivesTheNominalAngle) {
  // phi = delta = alpha = 0: N_gamma = 1 / (2 sin rho) for every beta (hand-derived:
  // (cot rho + cot beta) sin beta / (2 sin(rho + beta)) = 1 / (2 sin rho)).
  for (double rho : {0.7, 1.1, kPi / 2, 2.0}) {
    Soil s;
    Geometry g;
    g.rho_rad = rho;
    for (double beta : {0.2, 0.7, 1.3})
      EXPECT_NEAR(factors(s, g, beta).N_gamma, 1 / (2 * std::sin(rho)), 1e-14);
    EXPECT_DOUBLE_EQ(betaMin(s, g), kPi / 4) << "rho " << rho;
  }
}

TEST(FeeBetaMin, GradientMatchesCentralDifferences) {
  // d beta*/d phi and d beta*/d delta of the closed form against central differences of
  // betaMin() itself, over random admissible angles (slopes both ways).
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  int checked = 0;
  for (int i = 0; i < 3000 && checked < 500; ++i) {
    Soil s;
    s.phi_rad = 0.05 + 0.8 * U(rng);
    s.delta_rad = 0.6 * U(rng);
    Geometry g;
    g.alpha_rad = -0.5 + U(rng);
    g.rho_rad = 0.4 + 2.2 * U(rng);
    const Eigen::Vector2d grad = betaMinGradient(s, g);
    if (!std::isfinite(betaMin(s, g))) {
      EXPECT_TRUE(std::isnan(grad[0]) && std::isnan(grad[1]));
      continue;
    }
    const double h = 1e-6;
    Soil sp = s, sm = s;
    sp.phi_rad += h, sm.phi_rad -= h;
    const double fp = betaMin(sp, g), fm = betaMin(sm, g);
    Soil tp = s, tm = s;
    tp.delta_rad += h, tm.delta_rad -= h;
    const double gp = betaMin(tp, g), gm = betaMin(tm, g);
    if (!std::isfinite(fp + fm + gp + gm)) continue;  // at the edge of the admissible region
    EXPECT_NEAR(grad[0], (fp - fm) / (2 * h), 1e-6) << "phi " << s.phi_rad << " delta " << s.delta_rad;
    EXPECT_NEAR(grad[1], (gp - gm) / (2 * h), 1e-6) << "phi " << s.phi_rad << " delta " << s.delta_rad;
    ++checked;
  }
  EXPECT_GE(checked, 500);
  // The flat case returns Rankine's angle, whose gradient is (-1/2, 0).
  Soil flat;
  Geometry g;
  g.rho_rad = kPi / 2;
  EXPECT_EQ(betaMinGradient(flat, g), Eigen::Vector2d(-0.5, 0.0));
}

TEST(FeeBetaMin, NaNForOutOfRangeAngles) {
  Soil s;
  s.phi_rad = 0.5;
  Geometry g;
  g.rho_rad = 1.2;
  EXPECT_FALSE(std::isnan(betaMin(s, g)));
  g.rho_rad = -0.1;
  EXPECT_TRUE(std::isnan(betaMin(s, g)));
  g.rho_rad = 1.2;
  s.phi_rad = std::nan("");
  EXPECT_TRUE(std::isnan(betaMin(s, g)));
}

TEST(FeeBetaMin, DerivativeOfNGammaMatchesFiniteDifference) {
  std::mt19937_64 rng(99);
  for (int k = 0; k < 200; ++k) {
    const ParamVector p = test::randomAdmissible(rng);
    Soil s;
    Geometry g;
    double beta;
    unpack(p, s, g, beta);
    const double h = 1e-5;
    auto N = [&](double b) { return test::nGammaRef(s.phi_rad, s.delta_rad, g.alpha_rad, g.rho_rad, b); };
    const double d1 = (N(beta + h) - N(beta - h)) / (2 * h);
    const double d2 = (N(beta + h / 2) - N(beta - h / 2)) / h;
    const double fd = (4 * d2 - d1) / 3;
    const double a = dNgammaDbeta(s, g, beta);
    EXPECT_NEAR(a, fd, 1e-6 * std::max(std::abs(a), N(beta))) << "sample " << k;
  }
}

}  // namespace
}  // namespace terramap::fee
