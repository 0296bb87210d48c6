// Analytic Jacobians of F and F_total against central finite differences.
#include "fee_test_util.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <limits>

namespace terramap::fee {
namespace {

/// Typical magnitude of each parameter, to size the finite-difference step.
double paramScale(int j) {
  switch (j) {
    case kC: return 1e4;
    case kGamma: return 1e4;
    case kCa: return 1e4;
    case kQ: return 1e3;
    case kD: return 0.1;
    case kW: return 1.0;
    default: return 1.0;  // angles
  }
}

using ForceFn = Eigen::Vector2d (*)(const ParamVector&);

Eigen::Vector2d forceF(const ParamVector& p) {
  Soil s;
  Geometry g;
  double b;
  unpack(p, s, g, b);
  return evaluate(s, g, b).F_N;
}

Eigen::Vector2d forceTotal(const ParamVector& p) {
  Soil s;
  Geometry g;
  double b;
  unpack(p, s, g, b);
  return evaluate(s, g, b).F_total_N;
}

/// Finite-difference step for parameter j.
double stepOf(const ParamVector& p, int j) { return 1e-4 * std::max(std::abs(p[j]), paramScale(j)); }

/// Central differences with one Richardson step (error O(h^4)).
Jacobian finiteDifference(ForceFn f, const ParamVector& p) {
  Jacobian J;
  for (int j = 0; j < kParamCount; ++j) {
    const double h = stepOf(p, j);
    auto central = [&](double step) {
      ParamVector a = p, b = p;
      a[j] += step;
      b[j] -= step;
      return Eigen::Vector2d((f(a) - f(b)) / (2 * step));
    };
    J.col(j) = (4 * central(h / 2) - central(h)) / 3;
  }
  return J;
}

/// Largest |analytic - fd| / column scale seen, reported at the end of each test.
double gWorst = 0;

void compare(const Jacobian& analytic, const Jacobian& fd, const Eigen::Vector2d& F, const ParamVector& p,
             int sample) {
  for (int j = 0; j < kParamCount; ++j) {
    // Relative to the column (an entry can cancel to ~0 while its column does not), plus the
    // rounding floor of the difference quotient itself: a few hundred ulps of |F| over the step.
    // Without that floor a column that is nearly zero (e.g. N_ca ~ 0 when rho+phi+beta ~ pi/2)
    // would measure the finite difference's own rounding, not the analytic derivative.
    const double colScale = analytic.col(j).norm();
    const double roundoff = 500 * std::numeric_limits<double>::epsilon() * F.norm() / stepOf(p, j);
    for (int i = 0; i < 2; ++i) {
      const double err = std::abs(analytic(i, j) - fd(i, j));
      gWorst = std::max(gWorst, err / (colScale + roundoff / 1e-6));
      EXPECT_LE(err, 1e-6 * colScale + roundoff)
          << "sample " << sample << " row " << i << " param " << j << " analytic " << analytic(i, j) << " fd "
          << fd(i, j) << " p=" << p.transpose();
    }
  }
}

TEST(FeeJacobian, FMatchesFiniteDifferences) {
  gWorst = 0;
  std::mt19937_64 rng(12345);
  for (int k = 0; k < 500; ++k) {
    const ParamVector p = test::randomAdmissible(rng);
    Soil s;
    Geometry g;
    double b;
    unpack(p, s, g, b);
    compare(jacobianF(s, g, b), finiteDifference(forceF, p), forceF(p), p, k);
  }
  std::printf("jacobianF: worst relative deviation from finite differences %.2e (500 points)\n", gWorst);
}

TEST(FeeJacobian, FTotalMatchesFiniteDifferences) {
  gWorst = 0;
  std::mt19937_64 rng(54321);
  for (int k = 0; k < 500; ++k) {
    const ParamVector p = test::randomAdmissible(rng);
    Soil s;
    Geometry g;
    double b;
    unpack(p, s, g, b);
    compare(jacobianFTotal(s, g, b), finiteDifference(forceTotal, p), forceTotal(p), p, k);
  }
  std::printf("jacobianFTotal: worst relative deviation from finite differences %.2e (500 points)\n", gWorst);
}

TEST(FeeJacobian, ZeroLoadsStillHaveTheirSensitivities) {
  // With c = ca = Q = 0 the force does not vanish in its derivatives w.r.t. those loads.
  Soil s;
  s.phi_rad = 0.6;
  s.gamma_n_m3 = 18000;
  s.delta_rad = 0.4;
  Geometry g;
  g.alpha_rad = 0.0;
  g.rho_rad = 1.4;
  g.d_m = 0.3;
  g.w_m = 1.85;
  const double b = 0.5;
  const Jacobian J = jacobianFTotal(s, g, b);
  const Factors n = factors(s, g, b);
  const double th = g.rho_rad + s.delta_rad;
  EXPECT_NEAR(J(0, kC), g.d_m * g.w_m * n.N_c * std::sin(th), 1e-12);
  EXPECT_NEAR(J(0, kQ), n.N_Q * std::sin(th), 1e-15);
  // Adhesion: N_ca along the resultant plus the face term d w / sin(rho) along the blade.
  EXPECT_NEAR(J(0, kCa), g.d_m * g.w_m * (n.N_ca * std::sin(th) + std::cos(g.rho_rad) / std::sin(g.rho_rad)),
              1e-12);
  // The paper's F ignores the face term.
  EXPECT_NEAR(jacobianF(s, g, b)(0, kCa), g.d_m * g.w_m * n.N_ca * std::sin(th), 1e-12);
  ParamVector p = pack(s, g, b);
  compare(J, finiteDifference(forceTotal, p), forceTotal(p), p, -1);
}

TEST(FeeJacobian, PackUnpackRoundTrip) {
  std::mt19937_64 rng(3);
  const ParamVector p = test::randomAdmissible(rng);
  Soil s;
  Geometry g;
  double b;
  unpack(p, s, g, b);
  EXPECT_EQ(pack(s, g, b), p);
  EXPECT_EQ(p[kBeta], b);
  EXPECT_EQ(p[kRho], g.rho_rad);
  EXPECT_EQ(p[kCa], s.ca_pa);
}

}  // namespace
}  // namespace terramap::fee
