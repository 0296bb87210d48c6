// pinnLoss (paper Eq. 8) on hand-made outputs whose every term is computed by hand below,
// the invalid-sample rule, and where the NLL's gradient goes in a real network.
#include "loss.hpp"

#include <ATen/Parallel.h>
#include <gtest/gtest.h>

#include <cmath>

namespace terramap::pinn {
namespace {

at::Tensor leaf(at::Tensor t) { return t.to(at::kDouble).requires_grad_(true); }

/// Sample 0 of the hand-made batch (P = 2 steps), every term non-zero:
///  F^ = [[100, 200], [0, 0]], F = [[90, 220], [-30, 10]]
///  Sigma_F = diag(4, 16) at step 0, [[2, 1], [1, 2]] at step 1
///  dN_gamma/dbeta = [0.5, -1.5]
///  theta_u: c = 70 kPa (10 kPa over its 60 kPa span: 1/6), phi = 5 deg (5 deg under 10 deg,
///           span 40 deg: 1/8), ca, delta, gamma mid-range
///  log_var: S_c = its upper limit + 2 (penalty 2), the rest mid-range
///  d_res = 0.03 m, beta_res = -0.1 rad, F^r = [100, -40] N
/// Sample 1 (only in the two-sample test): invalid at both steps, with garbage everywhere and
/// F^r = [10, 10] N.
struct HandMade {
  PinnOutput out;
  at::Tensor force;
};

HandMade handMade(bool with_invalid_sample) {
  const int64_t B = with_invalid_sample ? 2 : 1, P = 2;
  at::Tensor F = at::zeros({B, P, 2}, at::kDouble), force = at::zeros({B, P, 2}, at::kDouble);
  at::Tensor Sigma = at::zeros({B, P, 2, 2}, at::kDouble);
  at::Tensor dng = at::zeros({B, P}, at::kDouble);
  at::Tensor theta = at::zeros({B, 5}, at::kDouble), lv = at::zeros({B, kLogVarCount}, at::kDouble);
  at::Tensor dres = at::zeros({B}, at::kDouble), bres = at::zeros({B}, at::kDouble), Fr = at::zeros({B, 2}, at::kDouble);
  at::Tensor valid = at::ones({B, P}, at::kBool);
  F[0][0][0] = 100, F[0][0][1] = 200;
  force[0][0][0] = 90, force[0][0][1] = 220, force[0][1][0] = -30, force[0][1][1] = 10;
  Sigma[0][0][0][0] = 4, Sigma[0][0][1][1] = 16;
  Sigma[0][1][0][0] = 2, Sigma[0][1][0][1] = 1, Sigma[0][1][1][0] = 1, Sigma[0][1][1][1] = 2;
  dng[0][0] = 0.5, dng[0][1] = -1.5;
  for (int k = 0; k < kSoilCount; ++k) theta[0][k] = 0.5 * (kSoilRanges[k].lo + kSoilRanges[k].hi);
  theta[0][kSoilC] = 70e3;
  theta[0][kSoilPhi] = 5 * kDeg;
  for (int k = 0; k < kLogVarCount; ++k) lv[0][k] = 0.5 * (logVarLo(k) + logVarHi(k));
  lv[0][kSoilC] = logVarHi(kSoilC) + 2;
  dres[0] = 0.03, bres[0] = -0.1;
  Fr[0][0] = 100, Fr[0][1] = -40;
  if (with_invalid_sample) {
    valid[1].fill_(false);
    F[1].fill_(1e9);
    force[1].fill_(-1e9);
    dng[1].fill_(1e6);
    theta[1].fill_(-1e6);
    lv[1].fill_(1e3);
    dres[1] = 5, bres[1] = 5;
    Fr[1][0] = 10, Fr[1][1] = 10;
  }
  HandMade h;
  h.out.F = leaf(F);
  h.out.Sigma_F = leaf(Sigma);  // Sigma is singular (0) where invalid: must not produce NaN
  h.out.dNgamma_dbeta = leaf(dng);
  h.out.theta_u = leaf(theta);
  h.out.log_var = leaf(lv);
  h.out.d_res = leaf(dres);
  h.out.beta_res = leaf(bres);
  h.out.F_r = leaf(Fr);
  h.out.valid = valid;
  h.force = force;
  return h;
}

LossWeights noFloor() {
  LossWeights w;
  w.sigma_floor_n2 = 0;
  return w;
}

// Hand computation for sample 0 (per-step values, then the mean over P = 2):
constexpr double kForceMae = (10 + 0.5 * 20 + 30 + 0.5 * 10) / 2.0;  // 20 and 35 -> 27.5
// step 0: r = [-10, 20], r^T S^-1 r = 100/4 + 400/16 = 50, det = 64
// step 1: r = [-30, 10], S^-1 = [[2,-1],[-1,2]]/3: (2*900 - 2*(-300) + 2*100)/3 = 2600/3, det = 3
const double kNll = (0.5 * (50 + std::log(64.0)) + 0.5 * (2600.0 / 3 + std::log(3.0))) / 2;  // 230.4810...
constexpr double kDng = (0.5 + 1.5) / 2;                                                 // 1
constexpr double kRange = 1.0 / 6 + 1.0 / 8 + 2.0;                                       // 2.2917
constexpr double kResidual = 0.03 * 0.03 + 0.1 * 0.1;                                   // 0.0109
constexpr double kForceRes = 100 + 0.5 * 40;                                             // 120

class PinnLoss : public ::testing::Test {
 protected:
  void SetUp() override { at::set_num_threads(1); }
};

TEST_F(PinnLoss, EachTermByHand) {
  const HandMade h = handMade(false);
  const LossWeights w = noFloor();
  const LossTerms t = pinnLoss(h.out, h.force, w);
  EXPECT_NEAR(t.force_mae.item<double>(), kForceMae, 1e-12);
  EXPECT_NEAR(t.nll.item<double>(), kNll, 1e-10);
  EXPECT_NEAR(t.dngamma.item<double>(), kDng, 1e-12);
  EXPECT_NEAR(t.range.item<double>(), kRange, 1e-9);
  EXPECT_NEAR(t.residual.item<double>(), kResidual, 1e-12);
  EXPECT_NEAR(t.force_res.item<double>(), kForceRes, 1e-12);
  const double total = w.lambda_F * kForceMae + w.lambda_NLL * kNll + w.lambda_beta * kDng + w.lambda_range * kRange +
                       w.lambda_res * kResidual + w.lambda_Fr * kForceRes;
  EXPECT_NEAR(t.total.item<double>(), total, 1e-9);
}

TEST_F(PinnLoss, SigmaFloorEntersTheNll) {
  // Step 0 with a floor of 1: diag(5, 17): 100/5 + 400/17, det 85.
  const HandMade h = handMade(false);
  const LossTerms t = pinnLoss(h.out, h.force);  // default floor 1 N^2
  // step 1: [[3,1],[1,3]], det 8, inverse [[3,-1],[-1,3]]/8: (3*900 + 600 + 3*100)/8 = 450
  const double want = (0.5 * (20 + 400.0 / 17 + std::log(85.0)) + 0.5 * (450 + std::log(8.0))) / 2;
  EXPECT_NEAR(t.nll.item<double>(), want, 1e-10);
}

TEST_F(PinnLoss, InvalidSampleKeepsOnlyItsResidualForce) {
  // With the garbage sample 1 all invalid, every term is sample 0's over B = 2, except F^r,
  // which averages both samples' (120 and 10 + 0.5 * 10 = 15).
  HandMade h = handMade(true);
  const LossTerms t = pinnLoss(h.out, h.force, noFloor());
  EXPECT_NEAR(t.force_mae.item<double>(), kForceMae / 2, 1e-12);
  EXPECT_NEAR(t.nll.item<double>(), kNll / 2, 1e-10);
  EXPECT_NEAR(t.dngamma.item<double>(), kDng / 2, 1e-12);
  EXPECT_NEAR(t.range.item<double>(), kRange / 2, 1e-9);
  EXPECT_NEAR(t.residual.item<double>(), kResidual / 2, 1e-12);
  EXPECT_NEAR(t.force_res.item<double>(), (kForceRes + 15) / 2, 1e-12);
  t.total.backward();
  for (const at::Tensor* x : {&h.out.F, &h.out.Sigma_F, &h.out.dNgamma_dbeta, &h.out.theta_u, &h.out.log_var,
                              &h.out.d_res, &h.out.beta_res}) {
    ASSERT_TRUE(x->grad().defined());
    EXPECT_TRUE(at::isfinite(x->grad()).all().item<bool>());
    EXPECT_EQ(x->grad()[1].abs().sum().item<double>(), 0.0);  // the invalid sample learns nothing
  }
  EXPECT_GT(h.out.F_r.grad()[1].abs().sum().item<double>(), 0.0);  // ... except to shrink F^r
  EXPECT_GT(h.out.F.grad()[0].abs().sum().item<double>(), 0.0);
}

/// Sample 0 with its step 1 left out (invalid or masked): force terms keep step 0 only,
/// per-sample terms count half, F^r counts whole.
void expectStepOneLeftOut(const LossTerms& t) {
  EXPECT_NEAR(t.force_mae.item<double>(), 20.0 / 2, 1e-12);
  EXPECT_NEAR(t.nll.item<double>(), 0.5 * (50 + std::log(64.0)) / 2, 1e-10);
  EXPECT_NEAR(t.dngamma.item<double>(), 0.5 / 2, 1e-12);
  EXPECT_NEAR(t.range.item<double>(), kRange / 2, 1e-9);
  EXPECT_NEAR(t.residual.item<double>(), kResidual / 2, 1e-12);
  EXPECT_NEAR(t.force_res.item<double>(), kForceRes, 1e-12);
}

TEST_F(PinnLoss, PartlyValidSampleCountsPerStep) {
  // Sample 0 with step 1 invalid: force terms keep step 0 only, per-sample terms count half.
  HandMade h = handMade(false);
  h.out.valid[0][1] = false;
  expectStepOneLeftOut(pinnLoss(h.out, h.force, noFloor()));
}

TEST_F(PinnLoss, MaskedRowCountsAsAnInvalidStep) {
  // A stalled row (row_mask false) leaves every term as an invalid step does, whatever its
  // force: the same numbers as PartlyValidSampleCountsPerStep, with step 1 valid but masked
  // and its measured force made absurd.
  HandMade h = handMade(false);
  h.force[0][1][0] = 1e7;
  at::Tensor mask = at::ones({1, 2}, at::kBool);
  mask[0][1] = false;
  expectStepOneLeftOut(pinnLoss(h.out, h.force, noFloor(), mask));
  // An all-true mask changes nothing.
  const LossTerms all = pinnLoss(h.out, h.force, noFloor(), at::ones({1, 2}, at::kBool));
  const LossTerms none = pinnLoss(h.out, h.force, noFloor());
  EXPECT_EQ(all.total.item<double>(), none.total.item<double>());
  EXPECT_GT(none.force_mae.item<double>(), 1e6);  // the absurd force counts without the mask
}

TEST_F(PinnLoss, RejectsForceOfWrongShape) {
  const HandMade h = handMade(false);
  EXPECT_THROW(pinnLoss(h.out, h.force.narrow(1, 0, 1)), std::invalid_argument);
  EXPECT_THROW(pinnLoss(h.out, h.force, {}, at::ones({1, 3}, at::kBool)), std::invalid_argument);
}

/// A small real network and a valid batch for the gradient-routing tests.
struct NetCase {
  PinnNet net{PinnConfig{4, 2, 3, {8}, 42}};
  at::Tensor obs, theta_k, force;
  NetCase() {
    at::manual_seed(1);
    obs = at::randn({4, 4, 3});
    theta_k = at::empty({4, 2, 6});
    const float row[6] = {1.2f, 0.05f, 1.8f, 0.15f, 500.f, 0.5f};
    for (int k = 0; k < 6; ++k) theta_k.select(2, k).fill_(row[k]);
    force = at::full({4, 2, 2}, 4000.0, at::kDouble);
  }
};

double gradNorm(const torch::nn::Linear& l) {
  const at::Tensor g = l->weight.grad();
  return g.defined() ? g.abs().sum().item<double>() : 0.0;
}

// The optional prior term: the squared distance of each soil property from the middle of its
// range in spans (only c and phi are off the middle in the hand-made sample), added with its
// weight, 0 by default; its gradient reaches the soil head and not the log-variances.
TEST_F(PinnLoss, ThePriorTermIsTheSquaredDistanceFromTheRangesMiddle) {
  const HandMade h = handMade(false);
  LossWeights w = noFloor();
  auto z = [](int k, double v) {
    return (v - 0.5 * (kSoilRanges[k].lo + kSoilRanges[k].hi)) / (kSoilRanges[k].hi - kSoilRanges[k].lo);
  };
  const double prior = std::pow(z(kSoilC, 70e3), 2) + std::pow(z(kSoilPhi, 5 * kDeg), 2);
  const LossTerms off = pinnLoss(h.out, h.force, w);
  EXPECT_NEAR(off.prior.item<double>(), prior, 1e-12);
  w.lambda_prior = 2;
  const LossTerms on = pinnLoss(h.out, h.force, w);
  EXPECT_NEAR(on.total.item<double>() - off.total.item<double>(), 2 * prior, 1e-9);
  NetCase c;
  const PinnOutput out = c.net->forward(c.obs, c.theta_k);
  LossWeights only;
  only.lambda_F = only.lambda_NLL = only.lambda_beta = only.lambda_range = only.lambda_res = only.lambda_Fr = 0;
  only.lambda_prior = 1;
  pinnLoss(out, c.force, only).total.backward();
  EXPECT_GT(gradNorm(c.net->headTheta()), 0.0);
  EXPECT_EQ(gradNorm(c.net->headLogVar()), 0.0);
}

// The optional supervision by the truth soil: the squared distance of the estimate from the
// truth in spans, 0 without a truth, added with its weight; its gradient reaches the soil head
// and not the log-variances; a truth of the wrong shape is refused.
TEST_F(PinnLoss, TheSoilTermIsTheSquaredDistanceFromTheTruthInSpans) {
  const HandMade h = handMade(false);
  const at::Tensor est = h.out.theta_u.to(at::kDouble);
  // The truth: the estimate with c 6 kPa higher and phi 2 deg lower (one sample).
  at::Tensor truth = est.clone();
  truth.select(1, kSoilC).add_(6e3);
  truth.select(1, kSoilPhi).sub_(2 * kDeg);
  auto span = [](int k) { return kSoilRanges[k].hi - kSoilRanges[k].lo; };
  const double soil = std::pow(6e3 / span(kSoilC), 2) + std::pow(2 * kDeg / span(kSoilPhi), 2);
  LossWeights w = noFloor();
  const LossTerms none = pinnLoss(h.out, h.force, w);
  EXPECT_EQ(none.soil.item<double>(), 0.0);
  const LossTerms off = pinnLoss(h.out, h.force, w, {}, truth);
  EXPECT_NEAR(off.soil.item<double>(), soil, 1e-12);
  EXPECT_EQ(off.total.item<double>(), none.total.item<double>());  // lambda_soil 0: not in the total
  w.lambda_soil = 3;
  const LossTerms on = pinnLoss(h.out, h.force, w, {}, truth);
  EXPECT_NEAR(on.total.item<double>() - off.total.item<double>(), 3 * soil, 1e-9);
  EXPECT_THROW(pinnLoss(h.out, h.force, w, {}, truth.narrow(1, 0, 4)), std::invalid_argument);
  NetCase c;
  const PinnOutput out = c.net->forward(c.obs, c.theta_k);
  LossWeights only;
  only.lambda_F = only.lambda_NLL = only.lambda_beta = only.lambda_range = only.lambda_res = only.lambda_Fr = 0;
  only.lambda_soil = 1;
  pinnLoss(out, c.force, only, {}, out.theta_u.detach().to(at::kDouble) + 1.0).total.backward();
  EXPECT_GT(gradNorm(c.net->headTheta()), 0.0);
  EXPECT_EQ(gradNorm(c.net->headLogVar()), 0.0);
}

TEST_F(PinnLoss, NllGradientReachesLogVariancesOnly) {
  NetCase c;
  const PinnOutput out = c.net->forward(c.obs, c.theta_k);
  ASSERT_TRUE(out.valid.all().item<bool>());
  LossWeights w;
  w.lambda_F = w.lambda_beta = w.lambda_range = w.lambda_res = w.lambda_Fr = 0;
  w.lambda_NLL = 1;
  pinnLoss(out, c.force, w).total.backward();
  EXPECT_EQ(gradNorm(c.net->headTheta()), 0.0);
  EXPECT_GT(gradNorm(c.net->headLogVar()), 0.0);
}

TEST_F(PinnLoss, RealNetworkIgnoresASampleCutAboveTheSurface) {
  // Sample 1 gets d = -0.2 m, so d + d_res < 0 (|d_res| <= 0.05): the FEE is invalid at both
  // steps. Without the F^r term its loss is zero, so the two-sample loss is half the loss of
  // sample 0 alone, and every gradient stays finite.
  NetCase c;
  c.theta_k[1].select(1, kKD).fill_(-0.2f);
  LossWeights w;
  w.lambda_Fr = 0;
  const PinnOutput both = c.net->forward(c.obs.narrow(0, 0, 2), c.theta_k.narrow(0, 0, 2));
  EXPECT_TRUE(both.valid[0].all().item<bool>());
  EXPECT_FALSE(both.valid[1].any().item<bool>());
  const LossTerms t2 = pinnLoss(both, c.force.narrow(0, 0, 2), w);
  const PinnOutput one = c.net->forward(c.obs.narrow(0, 0, 1), c.theta_k.narrow(0, 0, 1));
  const LossTerms t1 = pinnLoss(one, c.force.narrow(0, 0, 1), w);
  EXPECT_NEAR(t2.total.item<double>(), t1.total.item<double>() / 2, 1e-12 * t1.total.item<double>());
  t2.total.backward();
  for (const auto& p : c.net->named_parameters())
    EXPECT_TRUE(at::isfinite(p.value().grad()).all().item<bool>()) << p.key();
}

TEST_F(PinnLoss, ForceGradientReachesThetaNotLogVariances) {
  NetCase c;
  const PinnOutput out = c.net->forward(c.obs, c.theta_k);
  LossWeights w;
  w.lambda_NLL = w.lambda_beta = w.lambda_range = w.lambda_res = w.lambda_Fr = 0;
  w.lambda_F = 1;
  pinnLoss(out, c.force, w).total.backward();
  EXPECT_GT(gradNorm(c.net->headTheta()), 0.0);
  EXPECT_EQ(gradNorm(c.net->headLogVar()), 0.0);
}

}  // namespace
}  // namespace terramap::pinn
