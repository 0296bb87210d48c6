// Every validity rule of ALGORITHMS.md §E, each triggered on its own.
#include "fee_test_util.hpp"

#include <gtest/gtest.h>

#include <limits>
#include <set>
#include <string>

namespace terramap::fee {
namespace {

using test::kPi;

struct Case {
  Soil s;
  Geometry g;
  double beta;
};

/// A comfortably valid point that each case perturbs in one place.
Case base() {
  Case c;
  c.s.c_pa = 5000;
  c.s.phi_rad = 0.5;
  c.s.gamma_n_m3 = 17000;
  c.s.ca_pa = 2000;
  c.s.delta_rad = 0.3;
  c.g.alpha_rad = 0.1;
  c.g.rho_rad = 1.3;
  c.g.d_m = 0.25;
  c.g.w_m = 1.85;
  c.g.q_n = 400;
  c.beta = 0.6;
  return c;
}

TEST(FeeValidity, BaseIsValid) {
  const Case c = base();
  EXPECT_EQ(check(c.s, c.g, c.beta), Validity::Valid);
  EXPECT_TRUE(evaluate(c.s, c.g, c.beta).valid());
}

TEST(FeeValidity, EachRuleFailsAlone) {
  struct Trial {
    Validity expected;
    void (*mutate)(Case&);
  };
  const Trial trials[] = {
      {Validity::DepthNotPositive, [](Case& c) { c.g.d_m = 0; }},
      {Validity::WidthNotPositive, [](Case& c) { c.g.w_m = -0.1; }},
      {Validity::NegativeCohesion, [](Case& c) { c.s.c_pa = -1; }},
      {Validity::NegativeAdhesion, [](Case& c) { c.s.ca_pa = -1; }},
      {Validity::NegativeUnitWeight, [](Case& c) { c.s.gamma_n_m3 = -1; }},
      {Validity::NegativeSurcharge, [](Case& c) { c.g.q_n = -1; }},
      {Validity::PhiOutOfRange, [](Case& c) { c.s.phi_rad = -0.01; }},
      {Validity::DeltaOutOfRange, [](Case& c) { c.s.delta_rad = kPi / 2; }},
      {Validity::AlphaOutOfRange, [](Case& c) { c.g.alpha_rad = -1.6; }},
      {Validity::RhoOutOfRange, [](Case& c) { c.g.rho_rad = 0; }},
      {Validity::BetaOutOfRange, [](Case& c) { c.beta = kPi / 2; }},
      // rho + beta >= pi while every single-angle rule holds: rho 2.8, beta 0.5
      {Validity::RhoPlusBetaTooLarge, [](Case& c) {
         c.g.rho_rad = 2.8;
         c.beta = 0.5;
         c.s.delta_rad = 0;
         c.s.phi_rad = 0;
       }},
      // eta = 0.7 + 1.4 + 0.6 + 0.5 = 3.2 >= pi, rho + beta = 1.9
      {Validity::EtaOutOfRange, [](Case& c) {
         c.s.delta_rad = 0.7;
         c.g.rho_rad = 1.4;
         c.s.phi_rad = 0.6;
         c.beta = 0.5;
       }},
      // alpha + phi + beta = -1.2 + 0.3 + 0.5 < 0
      {Validity::AlphaPhiBetaOutOfRange, [](Case& c) {
         c.g.alpha_rad = -1.2;
         c.s.phi_rad = 0.3;
         c.beta = 0.5;
       }},
      // alpha + phi + beta = 1.4 + 1.0 + 0.8 = 3.2 >= pi while eta = 0 + 0.3 + 1.0 + 0.8 = 2.1
      {Validity::AlphaPhiBetaOutOfRange, [](Case& c) {
         c.g.alpha_rad = 1.4;
         c.s.phi_rad = 1.0;
         c.beta = 0.8;
         c.g.rho_rad = 0.3;
         c.s.delta_rad = 0;
       }},
      {Validity::NotFinite, [](Case& c) { c.beta = std::numeric_limits<double>::quiet_NaN(); }},
  };
  std::set<Validity> seen;
  for (const Trial& t : trials) {
    Case c = base();
    t.mutate(c);
    const Validity v = check(c.s, c.g, c.beta);
    EXPECT_EQ(v, t.expected) << "expected " << validityName(t.expected) << ", got " << validityName(v);
    const Result r = evaluate(c.s, c.g, c.beta);
    EXPECT_EQ(r.validity, t.expected);
    EXPECT_FALSE(r.valid());
    seen.insert(v);
  }
  // Every rule of the enum except Valid and NoAdmissibleBeta (evaluateAtBetaMin only) is covered.
  EXPECT_EQ(seen.size(), 15u);
}

TEST(FeeValidity, EveryParameterNonFiniteIsReportedAsSuch) {
  const double bad[] = {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity(),
                        -std::numeric_limits<double>::infinity()};
  for (int j = 0; j < kParamCount; ++j)
    for (double b : bad) {
      const Case c0 = base();
      ParamVector p = pack(c0.s, c0.g, c0.beta);
      p[j] = b;
      Case c;
      unpack(p, c.s, c.g, c.beta);
      EXPECT_EQ(check(c.s, c.g, c.beta), Validity::NotFinite) << "param " << j << " = " << b;
    }
}

TEST(FeeValidity, BoundariesAreExclusiveOrInclusiveAsSpecified) {
  Case c = base();
  c.s.phi_rad = 0;  // 0 <= phi: allowed
  c.s.delta_rad = 0;
  c.s.c_pa = c.s.ca_pa = c.s.gamma_n_m3 = c.g.q_n = 0;  // >= 0: allowed
  EXPECT_EQ(check(c.s, c.g, c.beta), Validity::Valid);
  c = base();
  c.beta = 0;  // 0 < beta: refused
  EXPECT_EQ(check(c.s, c.g, c.beta), Validity::BetaOutOfRange);
  c = base();
  c.g.alpha_rad = kPi / 2;  // |alpha| < pi/2: refused
  EXPECT_EQ(check(c.s, c.g, c.beta), Validity::AlphaOutOfRange);
  c = base();
  c.g.rho_rad = kPi;
  EXPECT_EQ(check(c.s, c.g, c.beta), Validity::RhoOutOfRange);
  c = base();
  c.s.phi_rad = kPi / 2;
  EXPECT_EQ(check(c.s, c.g, c.beta), Validity::PhiOutOfRange);
}

TEST(FeeValidity, FirstFailingRuleWinsInDocumentedOrder) {
  Case c = base();
  c.g.d_m = -1;
  c.s.c_pa = -1;
  c.beta = 2;
  EXPECT_EQ(check(c.s, c.g, c.beta), Validity::DepthNotPositive);
  c.g.d_m = 1;
  EXPECT_EQ(check(c.s, c.g, c.beta), Validity::NegativeCohesion);
  c.s.c_pa = 1;
  EXPECT_EQ(check(c.s, c.g, c.beta), Validity::BetaOutOfRange);
}

TEST(FeeValidity, InvalidInputsStillComputeTheNumbers) {
  Case c = base();
  const Result ok = evaluate(c.s, c.g, c.beta);
  c.g.q_n = -400;  // invalid, but the formula is still defined
  const Result r = evaluate(c.s, c.g, c.beta);
  EXPECT_EQ(r.validity, Validity::NegativeSurcharge);
  EXPECT_NEAR(r.f_N, ok.f_N - 800 * ok.n.N_Q, 1e-9 * ok.f_N);
}

TEST(FeeValidity, NoAdmissibleBetaStar) {
  // Ground falling away much faster than phi: N_gamma has no admissible minimum.
  Case c = base();
  c.g.alpha_rad = -1.4;
  c.s.phi_rad = 0.1;
  c.s.delta_rad = 0.0;
  c.g.rho_rad = 0.4;
  EXPECT_TRUE(std::isnan(betaMin(c.s, c.g)));
  const Result r = evaluateAtBetaMin(c.s, c.g);
  EXPECT_EQ(r.validity, Validity::NoAdmissibleBeta);
  EXPECT_TRUE(std::isnan(r.beta_rad));
  EXPECT_TRUE(std::isnan(r.F_total_N.x()));
  // A beta-independent failure is reported as itself, not as NoAdmissibleBeta.
  c.g.d_m = 0;
  EXPECT_EQ(evaluateAtBetaMin(c.s, c.g).validity, Validity::DepthNotPositive);
}

TEST(FeeValidity, RuleTextsAreDistinctAndNamed) {
  std::set<std::string> rules, names;
  for (int v = static_cast<int>(Validity::Valid); v <= static_cast<int>(Validity::NoAdmissibleBeta); ++v) {
    rules.insert(validityRule(static_cast<Validity>(v)));
    names.insert(validityName(static_cast<Validity>(v)));
  }
  EXPECT_EQ(rules.size(), 17u);
  EXPECT_EQ(names.size(), 17u);
  EXPECT_STREQ(validityRule(Validity::BetaOutOfRange), "0 < beta < pi/2");
  EXPECT_STREQ(validityName(Validity::EtaOutOfRange), "EtaOutOfRange");
}

}  // namespace
}  // namespace terramap::fee
