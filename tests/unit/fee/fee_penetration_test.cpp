// Bearing-capacity factors and the edge's penetration resistance (fee::bearingFactors,
// fee::penetration): textbook values and central differences.
#include <gtest/gtest.h>

#include <terramap/soil/fee.hpp>

#include <cmath>

using namespace terramap::fee;

TEST(FeeBearing, FactorsMatchTheTextbookTable) {
  // Prandtl/Reissner factors (e.g. Das, Principles of Foundation Engineering, Table 3.3 with
  // Prandtl's N_c): phi = 0: 5.14, 1; 20 deg: 14.83, 6.40; 30 deg: 30.14, 18.40; 40 deg: 75.31, 64.20.
  const double deg = M_PI / 180;
  struct Row { double phi, nc, nq; } rows[] = {{0, 5.14, 1.0}, {20, 14.83, 6.40}, {30, 30.14, 18.40}, {40, 75.31, 64.20}};
  for (const Row& r : rows) {
    const BearingFactors b = bearingFactors(r.phi * deg);
    EXPECT_NEAR(b.N_c, r.nc, 0.01) << r.phi;
    EXPECT_NEAR(b.N_q, r.nq, 0.01) << r.phi;
  }
}

TEST(FeeBearing, DerivativesMatchCentralDifferences) {
  for (double phi = 0.1; phi < 0.95; phi += 0.05) {
    const double h = 1e-6;
    const BearingFactors b = bearingFactors(phi), p = bearingFactors(phi + h), m = bearingFactors(phi - h);
    EXPECT_NEAR(b.dN_q, (p.N_q - m.N_q) / (2 * h), 1e-5 * std::abs(b.dN_q)) << phi;
    EXPECT_NEAR(b.dN_c, (p.N_c - m.N_c) / (2 * h), 1e-5 * std::abs(b.dN_c)) << phi;
  }
}

TEST(FeePenetration, ForceByHandAndGradientByCentralDifferences) {
  Soil s;
  s.c_pa = 12000;
  s.phi_rad = 0.5;
  s.gamma_n_m3 = 17500;
  s.ca_pa = 4000;
  s.delta_rad = 0.3;
  const double d = 0.08, w = 1.7, t = 0.025;
  const BearingFactors b = bearingFactors(s.phi_rad);
  EXPECT_DOUBLE_EQ(penetrationForce(s, d, w, t), (s.c_pa * b.N_c + s.gamma_n_m3 * d * b.N_q) * t * w);
  const Eigen::Vector4d g = penetration(s, d, w, t).gradient;
  auto fd = [&](auto set, double h) {
    Soil a = s, c = s;
    double da = d, dc = d;
    set(a, da, +h);
    set(c, dc, -h);
    return (penetrationForce(a, da, w, t) - penetrationForce(c, dc, w, t)) / (2 * h);
  };
  EXPECT_NEAR(g[0], fd([](Soil& x, double&, double h) { x.c_pa += h; }, 1.0), 1e-6 * std::abs(g[0]));
  EXPECT_NEAR(g[1], fd([](Soil& x, double&, double h) { x.phi_rad += h; }, 1e-6), 1e-5 * std::abs(g[1]));
  EXPECT_NEAR(g[2], fd([](Soil& x, double&, double h) { x.gamma_n_m3 += h; }, 1.0), 1e-6 * std::abs(g[2]));
  EXPECT_NEAR(g[3], fd([](Soil&, double& dd, double h) { dd += h; }, 1e-6), 1e-5 * std::abs(g[3]));
  // Adhesion and soil-tool friction do not bear on the edge.
  Soil o = s;
  o.ca_pa = 0;
  o.delta_rad = 0.1;
  EXPECT_EQ(penetrationForce(o, d, w, t), penetrationForce(s, d, w, t));
}
