// fee_torch against the C++ FEE (terramap::fee): forces, factors, dN_gamma/dbeta, the
// autograd Jacobian against the hand-derived fee::jacobianF, and the validity mask rule by rule.
#include "fee_torch.hpp"

#include <terramap/soil/fee.hpp>

#include <ATen/Parallel.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

namespace terramap::pinn {
namespace {

constexpr double kPi = 3.14159265358979323846;

struct Case {
  fee::Soil s;
  fee::Geometry g;
  double beta = 0;
};

/// A batch [B,P] of cases as the tensors feeForward() takes (soil per sample, the rest per step).
struct Batch {
  at::Tensor soil, rho, alpha, w, d, q, beta;
};

Batch toTensors(const std::vector<Case>& cases, int64_t B, int64_t P) {
  Batch t;
  t.soil = at::empty({B, 5}, at::kDouble);
  for (at::Tensor* x : {&t.rho, &t.alpha, &t.w, &t.d, &t.q, &t.beta}) *x = at::empty({B, P}, at::kDouble);
  for (int64_t b = 0; b < B; ++b) {
    const fee::Soil& s = cases[b * P].s;
    const double soil[5] = {s.c_pa, s.phi_rad, s.ca_pa, s.delta_rad, s.gamma_n_m3};
    for (int k = 0; k < 5; ++k) t.soil[b][k] = soil[k];
    for (int64_t p = 0; p < P; ++p) {
      const Case& c = cases[b * P + p];
      t.rho[b][p] = c.g.rho_rad;
      t.alpha[b][p] = c.g.alpha_rad;
      t.w[b][p] = c.g.w_m;
      t.d[b][p] = c.g.d_m;
      t.q[b][p] = c.g.q_n;
      t.beta[b][p] = c.beta;
    }
  }
  return t;
}

/// B samples of P valid steps each: one soil per sample, random slope/geometry/beta per step.
std::vector<Case> randomValidCases(int B, int P, unsigned seed) {
  std::mt19937 rng(seed);
  auto U = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  std::vector<Case> out;
  while (static_cast<int>(out.size()) < B * P) {
    fee::Soil s{U(0, 50e3), U(0.1, 0.8), U(12e3, 22e3), U(0, 20e3), U(0.05, 0.6)};
    std::vector<Case> sample;
    for (int tries = 0; static_cast<int>(sample.size()) < P && tries < 100; ++tries) {
      fee::Geometry g{U(-0.4, 0.4), U(0.5, 2.2), U(0.02, 0.4), U(0.5, 2.0), U(0, 5000)};
      const double beta = fee::betaNominal(s) + U(-0.2, 0.2);
      if (fee::check(s, g, beta) == fee::Validity::Valid) sample.push_back({s, g, beta});
    }
    if (static_cast<int>(sample.size()) == P) out.insert(out.end(), sample.begin(), sample.end());
  }
  return out;
}

class FeeTorch : public ::testing::Test {
 protected:
  void SetUp() override { at::set_num_threads(1); }
};

TEST_F(FeeTorch, ForcesAndFactorsMatchCppFee) {
  const int B = 64, P = 3;
  const auto cases = randomValidCases(B, P, 7);
  const Batch t = toTensors(cases, B, P);
  const FeeOut o = feeForward(t.soil, t.rho, t.alpha, t.w, t.d, t.q, t.beta);
  ASSERT_EQ(o.F.sizes(), (at::IntArrayRef{B, P, 2}));
  ASSERT_EQ(o.F.scalar_type(), at::kDouble);
  for (int b = 0; b < B; ++b)
    for (int p = 0; p < P; ++p) {
      const Case& c = cases[b * P + p];
      const fee::Result r = fee::evaluate(c.s, c.g, c.beta);
      ASSERT_TRUE(o.valid[b][p].item<bool>());
      const double scale = r.F_N.norm();
      EXPECT_NEAR(o.F[b][p][0].item<double>(), r.F_N.x(), 1e-6 * scale) << b << "," << p;
      EXPECT_NEAR(o.F[b][p][1].item<double>(), r.F_N.y(), 1e-6 * scale) << b << "," << p;
      EXPECT_NEAR(o.N_gamma[b][p].item<double>(), r.n.N_gamma, 1e-6 * std::abs(r.n.N_gamma));
      EXPECT_NEAR(o.N_c[b][p].item<double>(), r.n.N_c, 1e-6 * std::abs(r.n.N_c));
      EXPECT_NEAR(o.N_Q[b][p].item<double>(), r.n.N_Q, 1e-6 * std::abs(r.n.N_Q));
      EXPECT_NEAR(o.N_ca[b][p].item<double>(), r.n.N_ca, 1e-6 * std::abs(r.n.N_ca) + 1e-12);
      EXPECT_NEAR(o.eta[b][p].item<double>(), r.n.eta_rad, 1e-12);
      const double dn = fee::dNgammaDbeta(c.s, c.g, c.beta);
      const double dt = dNgammaDbeta(t.soil[b][1], t.soil[b][3], t.alpha[b][p], t.rho[b][p], t.beta[b][p]).item<double>();
      EXPECT_NEAR(dt, dn, 1e-6 * std::abs(dn) + 1e-12);
    }
}

TEST_F(FeeTorch, BetaPerSampleBroadcastsAndDtypeFollowsSoil) {
  const int B = 8, P = 2;
  const auto cases = randomValidCases(B, P, 11);
  Batch t = toTensors(cases, B, P);
  const at::Tensor beta_b = betaNominal(t.soil.select(1, kSoilPhi));  // [B]
  const FeeOut o1 = feeForward(t.soil, t.rho, t.alpha, t.w, t.d, t.q, beta_b);
  const FeeOut o2 = feeForward(t.soil, t.rho, t.alpha, t.w, t.d, t.q, beta_b.unsqueeze(1).expand({B, P}));
  EXPECT_TRUE(at::equal(o1.F, o2.F));
  const FeeOut of = feeForward(t.soil.to(at::kFloat), t.rho.to(at::kFloat), t.alpha, t.w, t.d, t.q, beta_b);
  EXPECT_EQ(of.F.scalar_type(), at::kFloat);
  EXPECT_THROW(feeForward(t.soil, t.rho, t.alpha.narrow(1, 0, 1), t.w, t.d, t.q, beta_b), std::invalid_argument);
}

TEST_F(FeeTorch, AutogradJacobianMatchesAnalytic) {
  const int B = 32, P = 2;
  const auto cases = randomValidCases(B, P, 3);
  const Batch t = toTensors(cases, B, P);
  const at::Tensor J = feeJacobian(t.soil, t.rho, t.alpha, t.w, t.d, t.q, t.beta);
  ASSERT_EQ(J.sizes(), (at::IntArrayRef{B, P, 2, kJacCount}));
  const int cols[kJacCount] = {fee::kC, fee::kPhi, fee::kCa, fee::kDelta, fee::kGamma, fee::kD, fee::kBeta};
  for (int b = 0; b < B; ++b)
    for (int p = 0; p < P; ++p) {
      const Case& c = cases[b * P + p];
      const fee::Jacobian Ja = fee::jacobianF(c.s, c.g, c.beta);
      for (int j = 0; j < kJacCount; ++j) {
        // Relative to the column's norm: a component that cancels to ~0 has no relative scale of its own.
        const double scale = Ja.col(cols[j]).norm();
        for (int i = 0; i < 2; ++i)
          EXPECT_NEAR(J[b][p][i][j].item<double>(), Ja(i, cols[j]), 1e-6 * scale) << b << "," << p << " col " << j;
      }
    }
}

TEST_F(FeeTorch, BetaMinMatchesCppFeeEverywhereItExists) {
  // Angles over (and beyond) every range, including slopes steeper than phi on both sides:
  // where fee::betaMin() finds a failure plane the torch closed form gives the same angle,
  // and where it does not, the torch one says so and returns the fallback.
  std::mt19937 rng(11);
  auto U = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  const int n = 4000;
  at::Tensor phi = at::empty({n}, at::kDouble), delta = at::empty({n}, at::kDouble);
  at::Tensor alpha = at::empty({n}, at::kDouble), rho = at::empty({n}, at::kDouble);
  for (int i = 0; i < n; ++i) {
    phi[i] = U(-0.1, 1.6);
    delta[i] = U(-0.1, 1.0);
    alpha[i] = U(-1.0, 1.0);
    rho[i] = U(0.2, 2.8);
  }
  const at::Tensor fallback = at::full({n}, 0.123, at::kDouble);
  const BetaMinOut o = betaMinTorch(phi, delta, alpha, rho, fallback);
  int found = 0, missing = 0;
  for (int i = 0; i < n; ++i) {
    const fee::Soil s{0, phi[i].item<double>(), 0, 0, delta[i].item<double>()};
    const fee::Geometry g{alpha[i].item<double>(), rho[i].item<double>(), 0.1, 1, 0};
    const double want = fee::betaMin(s, g);
    if (std::isfinite(want)) {
      ASSERT_TRUE(o.found[i].item<bool>()) << "case " << i << ": fee::betaMin = " << want;
      EXPECT_NEAR(o.beta[i].item<double>(), want, 1e-12) << "case " << i;
      ++found;
    } else {
      EXPECT_FALSE(o.found[i].item<bool>()) << "case " << i;
      EXPECT_EQ(o.beta[i].item<double>(), 0.123) << "case " << i;
      ++missing;
    }
  }
  // Both kinds well represented, or the test says little.
  EXPECT_GT(found, n / 4);
  EXPECT_GT(missing, n / 10);
}

TEST_F(FeeTorch, BetaMinGradientMatchesFiniteDifferencesOfCppFee) {
  const auto cases = randomValidCases(64, 1, 21);
  int checked = 0;
  for (const Case& c : cases) {
    const double b0 = fee::betaMin(c.s, c.g);
    if (!std::isfinite(b0)) continue;
    at::Tensor x = at::tensor({c.s.phi_rad, c.s.delta_rad, c.g.alpha_rad, c.g.rho_rad}, at::kDouble).requires_grad_(true);
    const BetaMinOut o = betaMinTorch(x[0], x[1], x[2], x[3], at::zeros({}, at::kDouble));
    ASSERT_TRUE(o.found.item<bool>());
    o.beta.backward();
    const double h = 1e-6;
    for (int k = 0; k < 4; ++k) {
      fee::Soil sp = c.s, sm = c.s;
      fee::Geometry gp = c.g, gm = c.g;
      double* fp[4] = {&sp.phi_rad, &sp.delta_rad, &gp.alpha_rad, &gp.rho_rad};
      double* fm[4] = {&sm.phi_rad, &sm.delta_rad, &gm.alpha_rad, &gm.rho_rad};
      *fp[k] += h;
      *fm[k] -= h;
      const double fd = (fee::betaMin(sp, gp) - fee::betaMin(sm, gm)) / (2 * h);
      ASSERT_TRUE(std::isfinite(fd));
      EXPECT_NEAR(x.grad()[k].item<double>(), fd, 1e-6 * std::max(1.0, std::abs(fd))) << "angle " << k;
    }
    ++checked;
  }
  EXPECT_GT(checked, 32);
}

TEST_F(FeeTorch, ChainedJacobianMatchesFiniteDifferencesOfCppFeeAtBetaMin) {
  // beta = beta*(phi, delta, alpha, rho) + beta_res: the phi and delta columns are total
  // derivatives. Central differences of the C++ FEE re-evaluated at the moved soil's beta*.
  const int B = 24, P = 2;
  const auto cases = randomValidCases(B, P, 5);
  const Batch t = toTensors(cases, B, P);
  const at::Tensor res = at::linspace(-0.05, 0.05, B, at::kDouble);
  const at::Tensor J = feeJacobianChained(t.soil, t.rho, t.alpha, t.w, t.d, t.q, res, BetaBase::Min);
  const at::Tensor Jn = feeJacobianChained(t.soil, t.rho, t.alpha, t.w, t.d, t.q, res, BetaBase::Nominal);
  auto force = [](fee::Soil s, fee::Geometry g, double r, bool min) {
    const double b = min ? fee::betaMin(s, g) : fee::betaNominal(s);
    return fee::evaluate(s, g, (std::isfinite(b) ? b : fee::betaNominal(s)) + r);
  };
  int checked = 0;
  for (int b = 0; b < B; ++b)
    for (int p = 0; p < P; ++p) {
      const Case& c = cases[b * P + p];
      const double r = res[b].item<double>();
      for (bool min : {true, false}) {
        const at::Tensor& Jt = min ? J : Jn;
        if (!force(c.s, c.g, r, min).valid()) {
          for (int j = 0; j < kJacCount; ++j) EXPECT_EQ(Jt[b][p][0][j].item<double>(), 0.0);
          continue;
        }
        for (int j = 0; j < kJacCount; ++j) {
          const double h = j == kJacC || j == kJacCa || j == kJacGamma ? 1.0 : 1e-7;
          fee::Soil sp = c.s, sm = c.s;
          fee::Geometry gp = c.g, gm = c.g;
          double rp = r, rm = r;
          double* xp[kJacCount] = {&sp.c_pa, &sp.phi_rad, &sp.ca_pa, &sp.delta_rad, &sp.gamma_n_m3, &gp.d_m, &rp};
          double* xm[kJacCount] = {&sm.c_pa, &sm.phi_rad, &sm.ca_pa, &sm.delta_rad, &sm.gamma_n_m3, &gm.d_m, &rm};
          *xp[j] += h;
          *xm[j] -= h;
          const fee::Result fp = force(sp, gp, rp, min), fm = force(sm, gm, rm, min);
          if (!fp.valid() || !fm.valid()) continue;  // at a rule's edge
          const Eigen::Vector2d fd = (fp.F_N - fm.F_N) / (2 * h);
          for (int i = 0; i < 2; ++i)
            EXPECT_NEAR(Jt[b][p][i][j].item<double>(), fd[i], 1e-5 * std::max(1.0, fd.norm()))
                << (min ? "min" : "nominal") << " case " << b << "," << p << " col " << j;
        }
        ++checked;
      }
    }
  EXPECT_GT(checked, B);
}

TEST_F(FeeTorch, ValidityMaskMatchesEveryRule) {
  using V = fee::Validity;
  const fee::Soil s0{10e3, 0.5, 16e3, 5e3, 0.3};
  const fee::Geometry g0{0.05, 1.2, 0.15, 1.8, 500};
  const double b0 = 0.5;
  const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();
  struct Mod {
    V expect;
    fee::Soil s;
    fee::Geometry g;
    double beta;
  };
  std::vector<Mod> mods;
  auto add = [&](V v, auto edit) {
    Mod m{v, s0, g0, b0};
    edit(m);
    mods.push_back(m);
  };
  add(V::Valid, [](Mod&) {});
  add(V::NotFinite, [&](Mod& m) { m.s.c_pa = nan; });
  add(V::NotFinite, [&](Mod& m) { m.g.q_n = inf; });
  add(V::NotFinite, [&](Mod& m) { m.beta = nan; });
  add(V::DepthNotPositive, [](Mod& m) { m.g.d_m = 0; });
  add(V::DepthNotPositive, [](Mod& m) { m.g.d_m = -0.05; });
  add(V::WidthNotPositive, [](Mod& m) { m.g.w_m = 0; });
  add(V::NegativeCohesion, [](Mod& m) { m.s.c_pa = -1; });
  add(V::NegativeAdhesion, [](Mod& m) { m.s.ca_pa = -1; });
  add(V::NegativeUnitWeight, [](Mod& m) { m.s.gamma_n_m3 = -1; });
  add(V::NegativeSurcharge, [](Mod& m) { m.g.q_n = -1; });
  add(V::PhiOutOfRange, [](Mod& m) { m.s.phi_rad = -0.1; });
  add(V::PhiOutOfRange, [](Mod& m) { m.s.phi_rad = kPi / 2; });
  add(V::DeltaOutOfRange, [](Mod& m) { m.s.delta_rad = -0.1; });
  add(V::AlphaOutOfRange, [](Mod& m) { m.g.alpha_rad = 1.6; });
  add(V::RhoOutOfRange, [](Mod& m) { m.g.rho_rad = 0; });
  add(V::RhoOutOfRange, [](Mod& m) { m.g.rho_rad = 3.2; });
  add(V::BetaOutOfRange, [](Mod& m) { m.beta = 0; });
  add(V::BetaOutOfRange, [](Mod& m) { m.beta = 1.6; });
  add(V::RhoPlusBetaTooLarge, [](Mod& m) { m.g.rho_rad = 2.8; });
  add(V::EtaOutOfRange, [](Mod& m) { m.g.rho_rad = 2.0; });  // eta = 0.3 + 2.0 + 0.5 + 0.5 = 3.3
  add(V::AlphaPhiBetaOutOfRange, [](Mod& m) {
    m.g.alpha_rad = -1.2;
    m.s.phi_rad = 0.1;
    m.beta = 0.3;
  });
  std::vector<Case> cases;
  for (const Mod& m : mods) {
    ASSERT_EQ(fee::check(m.s, m.g, m.beta), m.expect) << fee::validityName(m.expect) << " case does not hit its rule";
    cases.push_back({m.s, m.g, m.beta});
  }
  const int64_t B = static_cast<int64_t>(cases.size());
  Batch t = toTensors(cases, B, 1);
  t.soil.requires_grad_(true);
  t.beta.requires_grad_(true);
  const FeeOut o = feeForward(t.soil, t.rho, t.alpha, t.w, t.d, t.q, t.beta);
  const at::Tensor mask = feeValid(t.soil, t.rho, t.alpha, t.w, t.d, t.q, t.beta);
  for (int64_t b = 0; b < B; ++b) {
    const bool want = mods[b].expect == V::Valid;
    EXPECT_EQ(o.valid[b][0].item<bool>(), want) << fee::validityName(mods[b].expect);
    EXPECT_EQ(mask[b][0].item<bool>(), want) << fee::validityName(mods[b].expect);
    if (!want) {
      EXPECT_EQ(o.F[b][0].abs().sum().item<double>(), 0.0);
    }
  }
  // Invalid entries (poles included) give finite outputs and exactly zero gradients.
  EXPECT_TRUE(at::isfinite(o.F).all().item<bool>());
  o.F.sum().backward();
  EXPECT_TRUE(at::isfinite(t.beta.grad()).all().item<bool>());
  for (int64_t b = 1; b < B; ++b) {
    if (mods[b].expect == V::NotFinite) continue;  // a NaN input's own gradient slot is still 0
    EXPECT_EQ(t.beta.grad()[b][0].item<double>(), 0.0) << fee::validityName(mods[b].expect);
  }
  EXPECT_NE(t.beta.grad()[0][0].item<double>(), 0.0);
  const at::Tensor gs = t.soil.grad();
  EXPECT_TRUE(at::isfinite(gs).all().item<bool>());
  EXPECT_EQ(gs.narrow(0, 1, B - 1).abs().sum().item<double>(), 0.0);
}


TEST_F(FeeTorch, PenetrationTermMatchesCppFeeAndItsJacobianAndGradients) {
  const int B = 16, P = 3;
  const auto cases = randomValidCases(B, P, 5);
  const Batch t = toTensors(cases, B, P);
  const double edge = 0.025;
  at::Tensor soil = t.soil.clone().set_requires_grad(true);
  const at::Tensor gate = at::rand({B, P}, at::kDouble);
  const PenetrationOut o = penetrationForward(soil, t.w, t.d, gate, edge);
  ASSERT_EQ(o.Fz.sizes(), (at::IntArrayRef{B, P}));
  ASSERT_EQ(o.J.sizes(), (at::IntArrayRef{B, P, 2, kJacCount}));
  for (int b = 0; b < B; ++b)
    for (int p = 0; p < P; ++p) {
      const Case& c = cases[b * P + p];
      const double g = gate[b][p].item<double>();
      const double f = fee::penetrationForce(c.s, c.g.d_m, c.g.w_m, edge);
      EXPECT_NEAR(o.Fz[b][p].item<double>(), -g * f, 1e-9 * f) << b << "," << p;
      const Eigen::Vector4d dp = fee::penetration(c.s, c.g.d_m, c.g.w_m, edge).gradient;
      const double scale = dp.norm();
      EXPECT_NEAR(o.J[b][p][1][kSoilC].item<double>(), -g * dp[0], 1e-9 * scale);
      EXPECT_NEAR(o.J[b][p][1][kSoilPhi].item<double>(), -g * dp[1], 1e-9 * scale);
      EXPECT_NEAR(o.J[b][p][1][kSoilGamma].item<double>(), -g * dp[2], 1e-9 * scale);
      EXPECT_NEAR(o.J[b][p][1][kSoilCount].item<double>(), -g * dp[3], 1e-9 * scale);  // d_res
      for (int k : {int(kSoilCa), int(kSoilDelta), kSoilCount + 1}) EXPECT_EQ(o.J[b][p][1][k].item<double>(), 0.0);
      for (int k = 0; k < kJacCount; ++k) EXPECT_EQ(o.J[b][p][0][k].item<double>(), 0.0);  // no horizontal part
    }
  // Autograd through the forward gives the same soil gradients as the analytic Jacobian.
  o.Fz.sum().backward();
  const at::Tensor gsum = o.J.select(2, 1).sum(1);  // [B,7]
  for (int b = 0; b < B; ++b)
    for (int k : {int(kSoilC), int(kSoilPhi), int(kSoilGamma)})
      EXPECT_NEAR(soil.grad()[b][k].item<double>(), gsum[b][k].item<double>(), 1e-9 * std::abs(gsum[b][k].item<double>()) + 1e-12);
}

}  // namespace
}  // namespace terramap::pinn
