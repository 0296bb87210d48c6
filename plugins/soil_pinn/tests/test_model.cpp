// PinnNet: its physics layer against the C++ FEE, a 50-step training smoke test on a synthetic
// dataset made here from the C++ FEE, bit-identical reruns, and the save/load round trip.
#include "loss.hpp"
#include "model.hpp"
#include "nullspace.hpp"

#include <terramap/core/error.hpp>
#include <terramap/soil/fee.hpp>

#include <ATen/Parallel.h>
#include <nlohmann/json.hpp>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/grad_mode.h>
#include <torch/optim/adam.h>
#include <torch/serialize/archive.h>

#include <cstdio>
#include <fstream>
#include <iterator>
#include <random>
#include <unistd.h>

namespace terramap::pinn {
namespace {

constexpr int kT = 4, kP = 2, kDo = 3;

/// Random soils -> FEE forces over a horizon of P random geometries (beta nominal: the
/// network can represent it exactly with beta_res = 0); obs = the soil's c, phi, gamma scaled
/// to about [-1, 1] plus noise, repeated over the T history steps.
struct Dataset {
  at::Tensor obs, theta_k, force, mean, std;
};

Dataset makeDataset(int n, unsigned seed) {
  std::mt19937 rng(seed);
  auto U = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  std::normal_distribution<double> noise(0.0, 0.05);
  Dataset ds;
  ds.obs = at::empty({n, kT, kDo}, at::kFloat);
  ds.theta_k = at::empty({n, kP, kThetaKCount}, at::kFloat);
  ds.force = at::empty({n, kP, 2}, at::kDouble);
  for (int i = 0; i < n; ++i) {
    const fee::Soil s{U(0, 40e3), U(20, 40) * kDeg, U(14e3, 20e3), U(0, 15e3), U(10, 30) * kDeg};
    for (int p = 0; p < kP; ++p) {
      fee::Geometry g;
      fee::Result r;
      do {
        g = fee::Geometry{U(-0.1, 0.1), U(1.0, 1.4), U(0.05, 0.25), U(1.5, 1.9), U(0, 2000)};
        r = fee::evaluateAtBetaNominal(s, g);
      } while (!r.valid());
      const double k[kThetaKCount] = {g.rho_rad, g.alpha_rad, g.w_m, g.d_m, g.q_n, U(0.3, 1.0)};
      for (int j = 0; j < kThetaKCount; ++j) ds.theta_k[i][p][j] = static_cast<float>(k[j]);
      ds.force[i][p][0] = r.F_N.x();
      ds.force[i][p][1] = r.F_N.y();
    }
    const double feat[kDo] = {s.c_pa / 20e3 - 1, (s.phi_rad / kDeg - 30) / 10, (s.gamma_n_m3 - 17e3) / 3e3};
    for (int t = 0; t < kT; ++t)
      for (int j = 0; j < kDo; ++j) ds.obs[i][t][j] = static_cast<float>(feat[j] + noise(rng));
  }
  const at::Tensor flat = ds.theta_k.reshape({-1, kThetaKCount});
  ds.mean = flat.mean(0);
  ds.std = flat.std(0);
  return ds;
}

const Dataset& dataset() {
  static const Dataset ds = makeDataset(128, 2024);
  return ds;
}

struct TrainResult {
  PinnNet net{nullptr};
  double first_loss = 0, last_loss = 0;
};

/// 50 full-batch Adam steps (lr 0.01) on the default loss, one intra-op thread.
TrainResult train(int64_t seed, int steps = 50) {
  at::set_num_threads(1);
  const Dataset& ds = dataset();
  TrainResult r;
  r.net = PinnNet(PinnConfig{kT, kP, kDo, {8}, seed});
  r.net->setThetaNormalisation(ds.mean, ds.std);
  torch::optim::Adam opt(r.net->parameters(), torch::optim::AdamOptions(1e-2));
  for (int step = 0; step <= steps; ++step) {
    const LossTerms t = pinnLoss(r.net->forward(ds.obs, ds.theta_k), ds.force);
    const double v = t.total.item<double>();
    if (step == 0) r.first_loss = v;
    r.last_loss = v;
    if (step == steps) break;  // the last evaluation measures the trained net
    opt.zero_grad();
    t.total.backward();
    opt.step();
  }
  return r;
}

std::string tempPath(const std::string& name) {
  return ::testing::TempDir() + "/soil_pinn_" + std::to_string(::getpid()) + "_" + name;
}

/// `net` saved to a temporary file `name` and loaded back (the file removed).
PinnNet throughFile(PinnNet& net, const std::string& name) {
  const std::string path = tempPath(name);
  savePinn(net, path);
  PinnNet loaded = loadPinn(path);
  std::remove(path.c_str());
  return loaded;
}

class PinnModel : public ::testing::Test {
 protected:
  void SetUp() override { at::set_num_threads(1); }
};

/// The network's physics layer against the C++ FEE for one base angle: beta per step, F, J
/// (the base angle's dependence on phi and delta chained in, by central differences of
/// fee::betaMin for beta*), Sigma_F.
/// With q_ref > 0 the surcharge is weighed with the estimated gamma (Q gamma / q_ref) and J's
/// gamma column carries dF/dQ Q / q_ref.
void checkPhysicsLayer(BetaBase base, double q_ref = 0.0) {
  PinnConfig cfg{kT, kP, kDo, {8}, 3, base};
  cfg.q_gamma_ref_n_m3 = q_ref;
  PinnNet net(cfg);
  const Dataset& ds = dataset();
  const int64_t B = 16;
  const PinnOutput o = net->forward(ds.obs.narrow(0, 0, B), ds.theta_k.narrow(0, 0, B));
  ASSERT_EQ(o.F.sizes(), (at::IntArrayRef{B, kP, 2}));
  ASSERT_EQ(o.beta.sizes(), (at::IntArrayRef{B, kP}));
  ASSERT_EQ(o.Sigma_F.sizes(), (at::IntArrayRef{B, kP, 2, 2}));
  ASSERT_EQ(o.log_var.sizes(), (at::IntArrayRef{B, kLogVarCount}));
  auto baseAngle = [base](const fee::Soil& s, const fee::Geometry& g) {
    const double m = base == BetaBase::Min ? fee::betaMin(s, g) : NAN;
    return std::isfinite(m) ? m : fee::betaNominal(s);
  };
  int valid_steps = 0;
  for (int64_t b = 0; b < B; ++b) {
    const at::Tensor th = o.theta_u[b].to(at::kDouble);
    fee::Soil s{th[kSoilC].item<double>(), th[kSoilPhi].item<double>(), th[kSoilGamma].item<double>(),
                th[kSoilCa].item<double>(), th[kSoilDelta].item<double>()};
    const double res = o.beta_res[b].item<float>();
    for (int p = 0; p < kP; ++p) {
      const at::Tensor k = ds.theta_k[b][p].to(at::kDouble);
      const double q_k = k[kKQ].item<double>();
      fee::Geometry g{k[kKAlpha].item<double>(), k[kKRho].item<double>(),
                      k[kKD].item<double>() + static_cast<double>(o.d_res[b].item<float>()), k[kKW].item<double>(),
                      q_ref > 0 ? q_k * s.gamma_n_m3 / q_ref : q_k};
      const double beta = o.beta[b][p].item<double>();
      EXPECT_NEAR(beta, baseAngle(s, g) + res, 1e-9);
      const fee::Result r = fee::evaluate(s, g, beta);
      ASSERT_EQ(o.valid[b][p].item<bool>(), r.valid());
      if (!r.valid()) continue;
      ++valid_steps;
      const Eigen::Vector2d Fr(o.F_r[b][0].item<float>(), o.F_r[b][1].item<float>());
      const Eigen::Vector2d want = r.F_N + Fr;
      for (int i = 0; i < 2; ++i) EXPECT_NEAR(o.F[b][p][i].item<double>(), want[i], 1e-6 * want.norm());
      // J: fee's columns with d(base angle)/d(phi, delta) chained in.
      fee::Jacobian Ja = fee::jacobianF(s, g, beta);
      const double h = 1e-6;
      fee::Soil sp = s, sm = s;
      sp.phi_rad += h;
      sm.phi_rad -= h;
      Ja.col(fee::kPhi) += (baseAngle(sp, g) - baseAngle(sm, g)) / (2 * h) * Ja.col(fee::kBeta);
      sp = s, sm = s;
      sp.delta_rad += h;
      sm.delta_rad -= h;
      Ja.col(fee::kDelta) += (baseAngle(sp, g) - baseAngle(sm, g)) / (2 * h) * Ja.col(fee::kBeta);
      if (q_ref > 0) Ja.col(fee::kGamma) += Ja.col(fee::kQ) * (q_k / q_ref);
      const int cols[kLogVarCount] = {fee::kC, fee::kPhi, fee::kCa, fee::kDelta, fee::kGamma, fee::kD, fee::kBeta};
      Eigen::Matrix<double, 2, kLogVarCount> J;
      for (int j = 0; j < kLogVarCount; ++j) {
        J.col(j) = Ja.col(cols[j]);
        for (int i = 0; i < 2; ++i)
          EXPECT_NEAR(o.J[b][p][i][j].item<double>(), J(i, j), 1e-6 * std::max(1.0, J.col(j).norm())) << "col " << j;
      }
      Eigen::Matrix<double, kLogVarCount, 1> var;
      for (int j = 0; j < kLogVarCount; ++j) var[j] = std::exp(static_cast<double>(o.log_var[b][j].item<float>()));
      const Eigen::Matrix2d Sigma = J * var.asDiagonal() * J.transpose();
      for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j)
          EXPECT_NEAR(o.Sigma_F[b][p][i][j].item<double>(), Sigma(i, j), 1e-6 * Sigma.norm());
    }
  }
  EXPECT_GT(valid_steps, B);
  EXPECT_TRUE(o.Sigma_F.requires_grad());
  EXPECT_FALSE(o.J.requires_grad());
}

TEST_F(PinnModel, PhysicsLayerMatchesCppFeeAtBetaMin) { checkPhysicsLayer(BetaBase::Min); }
TEST_F(PinnModel, PhysicsLayerMatchesCppFeeAtRankinesBeta) { checkPhysicsLayer(BetaBase::Nominal); }
TEST_F(PinnModel, PhysicsLayerMatchesCppFeeWithTheSurchargeWeighedByGamma) {
  checkPhysicsLayer(BetaBase::Min, 14636.0);
}

// The surcharge weighed with the estimated gamma: the force differs from Q as extracted
// wherever the estimate's gamma is not the reference, the gamma column of J is the total
// derivative (central differences of the C++ FEE with Q following gamma), and the setting
// survives a save and load (format 5).
TEST_F(PinnModel, TheSurchargeFollowsTheEstimatedGammaAndRoundTrips) {
  PinnConfig cfg{kT, kP, kDo, {8}, 3, BetaBase::Min};
  PinnNet plain(cfg);
  cfg.q_gamma_ref_n_m3 = 10000.0;
  PinnNet weighed(cfg);
  const Dataset& ds = dataset();
  const PinnOutput a = plain->forward(ds.obs, ds.theta_k), b = weighed->forward(ds.obs, ds.theta_k);
  ASSERT_TRUE(at::equal(a.theta_u, b.theta_u));  // same seed, same weights: only the physics differs
  EXPECT_GT((a.F - b.F).abs().max().item<double>(), 1.0);
  int checked = 0;
  for (int64_t i = 0; i < 8; ++i) {
    const at::Tensor th = b.theta_u[i].to(at::kDouble);
    const fee::Soil s{th[kSoilC].item<double>(), th[kSoilPhi].item<double>(), th[kSoilGamma].item<double>(),
                      th[kSoilCa].item<double>(), th[kSoilDelta].item<double>()};
    const at::Tensor k = ds.theta_k[i][0].to(at::kDouble);
    const double q_k = k[kKQ].item<double>(), beta = b.beta[i][0].item<double>();
    if (!b.valid[i][0].item<bool>() || !(q_k > 0)) continue;
    auto force = [&](double gamma) {
      fee::Soil x = s;
      x.gamma_n_m3 = gamma;
      const fee::Geometry g{k[kKAlpha].item<double>(), k[kKRho].item<double>(),
                            k[kKD].item<double>() + static_cast<double>(b.d_res[i].item<float>()),
                            k[kKW].item<double>(), q_k * gamma / 10000.0};
      return fee::evaluate(x, g, beta).F_N;  // beta held: beta* does not depend on gamma or Q
    };
    const double h = 1.0;
    const Eigen::Vector2d fd = (force(s.gamma_n_m3 + h) - force(s.gamma_n_m3 - h)) / (2 * h);
    for (int r = 0; r < 2; ++r) EXPECT_NEAR(b.J[i][0][r][kSoilGamma].item<double>(), fd[r], 1e-5 * (1 + fd.norm()));
    ++checked;
  }
  EXPECT_GT(checked, 2);
  PinnNet loaded = throughFile(weighed, "q_gamma.pt");
  EXPECT_EQ(loaded->config().q_gamma_ref_n_m3, 10000.0);
  EXPECT_TRUE(at::equal(loaded->forward(ds.obs, ds.theta_k).F, b.F));
  cfg.q_gamma_ref_n_m3 = -1;
  EXPECT_THROW(PinnNet{cfg}, std::invalid_argument);
}

TEST_F(PinnModel, BaseAngleChangesTheForce) {
  // Same weights, the two base angles: the same soil estimate gives other forces (beta* is
  // the N_gamma minimiser; the cohesion and surcharge terms move the other way), so a model
  // file must say which angle it was trained with.
  PinnNet a(PinnConfig{kT, kP, kDo, {8}, 3, BetaBase::Min});
  PinnNet b(PinnConfig{kT, kP, kDo, {8}, 3, BetaBase::Nominal});
  const Dataset& ds = dataset();
  const PinnOutput oa = a->forward(ds.obs, ds.theta_k), ob = b->forward(ds.obs, ds.theta_k);
  EXPECT_TRUE(at::equal(oa.theta_u, ob.theta_u));
  const at::Tensor both = oa.valid & ob.valid;
  ASSERT_GT(both.sum().item<int64_t>(), 100);
  const double diff = at::masked_select((oa.F - ob.F).norm(2, -1), both).sum().item<double>();
  const double size = at::masked_select(ob.F.norm(2, -1), both).sum().item<double>();
  EXPECT_GT(diff, 0.05 * size);
  EXPECT_NE(configHash(a->config()), configHash(b->config()));
}

TEST_F(PinnModel, InferenceWithoutGradAndInflatedVariances) {
  // Inference runs under NoGradGuard; the Jacobian (autograd inside) must still be computed.
  PinnNet net(PinnConfig{kT, kP, kDo, {8}, 5});
  const Dataset& ds = dataset();
  const PinnOutput with_grad = net->forward(ds.obs, ds.theta_k);
  torch::NoGradGuard no_grad;
  const PinnOutput o = net->forward(ds.obs, ds.theta_k);
  EXPECT_TRUE(at::equal(o.J, with_grad.J));
  EXPECT_TRUE(at::equal(o.Sigma_F, with_grad.Sigma_F.detach()));
  const at::Tensor v = soilVariances(o.J, o.log_var, defaultAmbiguityVariance());
  ASSERT_EQ(v.sizes(), (at::IntArrayRef{ds.obs.size(0), kSoilCount}));
  EXPECT_TRUE(at::isfinite(v).all().item<bool>());
  EXPECT_TRUE((v >= at::exp(o.log_var.narrow(1, 0, kSoilCount).to(at::kDouble))).all().item<bool>());
}

TEST_F(PinnModel, ConstructionSeedsFromConfigAndLeavesTheGlobalGeneratorAlone) {
  at::manual_seed(99);
  const at::Tensor want = at::rand({4});
  at::manual_seed(99);
  PinnNet a(PinnConfig{kT, kP, kDo, {8}, 1});
  EXPECT_TRUE(at::equal(at::rand({4}), want));
  PinnNet b(PinnConfig{kT, kP, kDo, {8}, 1});
  EXPECT_TRUE(at::equal(a->headTheta()->weight, b->headTheta()->weight));
}

TEST_F(PinnModel, OutputsStayInTheirRanges) {
  PinnNet net(PinnConfig{kT, kP, kDo, {8}, 4});
  const Dataset& ds = dataset();
  const PinnOutput o = net->forward(ds.obs * 50, ds.theta_k);  // saturate the heads
  for (int k = 0; k < kSoilCount; ++k) {
    EXPECT_GE(o.theta_u.select(1, k).min().item<float>(), kSoilRanges[k].lo * (1 - 1e-6)) << kSoilRanges[k].name;
    EXPECT_LE(o.theta_u.select(1, k).max().item<float>(), kSoilRanges[k].hi * (1 + 1e-6)) << kSoilRanges[k].name;
  }
  EXPECT_LE(o.d_res.abs().max().item<float>(), kDResMaxM);
  EXPECT_LE(o.beta_res.abs().max().item<float>(), kBetaResMaxRad);
}

TEST_F(PinnModel, RejectsBadShapesAndConfigs) {
  PinnNet net(PinnConfig{kT, kP, kDo, {8}, 0});
  EXPECT_THROW(net->forward(at::zeros({2, kT + 1, kDo}), at::zeros({2, kP, 6})), std::invalid_argument);
  EXPECT_THROW(net->forward(at::zeros({2, kT, kDo}), at::zeros({3, kP, 6})), std::invalid_argument);
  EXPECT_THROW(PinnNet(PinnConfig{2, 3, 1, {8}, 0}), std::invalid_argument);  // T < P
  EXPECT_THROW(net->setThetaNormalisation(at::zeros({6}), at::zeros({6})), std::invalid_argument);
}

TEST_F(PinnModel, FiftyAdamStepsCutTheLossAndRerunsAreBitIdentical) {
  const TrainResult a = train(7);
  RecordProperty("first_loss", std::to_string(a.first_loss));
  RecordProperty("last_loss", std::to_string(a.last_loss));
  // Measured (libtorch 1.13.1, Debian): 14.99 -> 4.33, a 3.5x drop, almost all of it the
  // force wMAE (14.6 -> 4.0 kN on forces of 10-60 kN; 300 steps reach 1.7 kN). Require 2.5x:
  // room for another libtorch's rounding, still failing a loss that does not train.
  EXPECT_LT(a.last_loss, a.first_loss / 2.5) << a.first_loss << " -> " << a.last_loss;
  const TrainResult b = train(7);
  const auto pa = a.net->named_parameters(), pb = b.net->named_parameters();
  ASSERT_EQ(pa.size(), pb.size());
  for (const auto& item : pa) EXPECT_TRUE(at::equal(item.value(), pb[item.key()])) << item.key();
  EXPECT_EQ(a.last_loss, b.last_loss);
  // The seed matters (a different one trains to different weights).
  const TrainResult c = train(8, 1);
  EXPECT_FALSE(at::equal(c.net->headTheta()->weight, a.net->headTheta()->weight));
}

TEST_F(PinnModel, SaveLoadRoundTripGivesIdenticalOutputs) {
  TrainResult a = train(11, 5);
  const std::string path = tempPath("roundtrip.pt");
  savePinn(a.net, path);
  PinnNet loaded = loadPinn(path);
  EXPECT_EQ(loaded->config().hidden, std::vector<int>{8});
  EXPECT_EQ(loaded->metadataJson(), a.net->metadataJson());  // normalisation and config hash included
  const Dataset& ds = dataset();
  const PinnOutput x = a.net->forward(ds.obs, ds.theta_k), y = loaded->forward(ds.obs, ds.theta_k);
  EXPECT_TRUE(at::equal(x.theta_u, y.theta_u));
  EXPECT_TRUE(at::equal(x.log_var, y.log_var));
  EXPECT_TRUE(at::equal(x.F, y.F));
  EXPECT_TRUE(at::equal(x.Sigma_F, y.Sigma_F));
  // The same model saved again, under another name, is the same bytes (no file name or process
  // id inside the archive).
  const std::string again = tempPath("roundtrip_again.pt");
  savePinn(a.net, again);
  std::ifstream fa(path, std::ios::binary), fb(again, std::ios::binary);
  const std::string ba((std::istreambuf_iterator<char>(fa)), {}), bb((std::istreambuf_iterator<char>(fb)), {});
  EXPECT_FALSE(ba.empty());
  EXPECT_TRUE(ba == bb);
  std::remove(path.c_str());
  std::remove(again.c_str());
}

/// A model file as format version `version` wrote it, with the given config JSON.
std::string writeWithMetadata(PinnNet& net, const std::string& name, int version, const nlohmann::json& config,
                              const std::string& hash) {
  torch::serialize::OutputArchive ar;
  net->save(ar);
  nlohmann::json j{{"format", "terramap.soil_pinn"}, {"version", version}, {"config", config}, {"config_hash", hash}};
  ar.write("terramap_metadata", c10::IValue(j.dump()));
  const std::string path = tempPath(name);
  ar.save_to(path);
  return path;
}

TEST_F(PinnModel, VersionOneFilesLoadWithRankinesAngle) {
  // Files written before beta_base existed were trained with pi/4 - phi/2 and must keep it.
  PinnNet nominal(PinnConfig{kT, kP, kDo, {8}, 4, BetaBase::Nominal});
  const PinnConfig& c = nominal->config();
  const nlohmann::json v1{{"T", c.T}, {"P", c.P}, {"D_o", c.D_o}, {"hidden", c.hidden}, {"seed", c.seed}};
  const std::string path = writeWithMetadata(nominal, "v1.pt", 1, v1, configHash(c, 1));
  PinnNet loaded = loadPinn(path);
  EXPECT_EQ(loaded->config().beta_base, BetaBase::Nominal);
  const Dataset& ds = dataset();
  EXPECT_TRUE(at::equal(loaded->forward(ds.obs, ds.theta_k).F, nominal->forward(ds.obs, ds.theta_k).F));
  // A version-2 file must name its angle, and a known one.
  nlohmann::json v2 = v1;
  const std::string no_key = writeWithMetadata(nominal, "v2_no_key.pt", 2, v2, configHash(c, 1));
  EXPECT_THROW(loadPinn(no_key), InputError);
  v2["beta_base"] = "steepest";
  const std::string bad = writeWithMetadata(nominal, "v2_bad.pt", 2, v2, configHash(c, 2));
  try {
    loadPinn(bad);
    ADD_FAILURE() << "loaded a model with beta_base 'steepest'";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("steepest"), std::string::npos) << e.what();
  }
  for (const std::string& p : {path, no_key, bad}) std::remove(p.c_str());
}

TEST_F(PinnModel, ThePenetrationTermPushesDownWhereTheFeeIsValidAndRoundTrips) {
  // Same seed, same weights for every shared layer: the two networks differ only by the term.
  PinnNet plain(PinnConfig{kT, kP, kDo, {8}, 21, BetaBase::Min});
  PinnNet pen(PinnConfig{kT, kP, kDo, {8}, 21, BetaBase::Min, 0.025});
  const Dataset& ds = dataset();
  const PinnOutput a = plain->forward(ds.obs, ds.theta_k), b = pen->forward(ds.obs, ds.theta_k);
  ASSERT_TRUE(at::equal(a.theta_u, b.theta_u));
  EXPECT_TRUE(at::equal(a.F.select(2, 0), b.F.select(2, 0)));  // horizontal force untouched
  const at::Tensor dz = (b.F.select(2, 1) - a.F.select(2, 1));
  EXPECT_TRUE(at::equal(a.pen_gate, at::zeros_like(a.pen_gate)));
  EXPECT_TRUE(((b.pen_gate > 0) & (b.pen_gate < 1)).all().item<bool>());
  EXPECT_TRUE((dz.masked_select(b.valid) < 0).all().item<bool>()) << "the blade pushes down on the soil it penetrates";
  EXPECT_TRUE((dz.masked_select(~b.valid) == 0).all().item<bool>());
  // The z row of the Jacobian carries the term's soil sensitivities (so does Sigma_F), the x row not.
  EXPECT_FALSE(at::equal(b.J.select(2, 1), a.J.select(2, 1)));
  EXPECT_TRUE(at::equal(b.J.select(2, 0), a.J.select(2, 0)));
  PinnNet loaded = throughFile(pen, "pen.pt");
  EXPECT_EQ(loaded->config().edge_thickness_m, 0.025);
  EXPECT_TRUE(at::equal(loaded->forward(ds.obs, ds.theta_k).F, b.F));
  // A version-2 file (before the key) loads without the term; a version-3 one must name it.
  const PinnConfig& c = plain->config();
  nlohmann::json v2{{"T", c.T}, {"P", c.P}, {"D_o", c.D_o}, {"hidden", c.hidden}, {"seed", c.seed}, {"beta_base", "min"}};
  const std::string old = writeWithMetadata(plain, "v2.pt", 2, v2, configHash(c, 2));
  EXPECT_EQ(loadPinn(old)->config().edge_thickness_m, 0.0);
  const std::string no_key = writeWithMetadata(plain, "v3_no_key.pt", 3, v2, configHash(c, 2));
  EXPECT_THROW(loadPinn(no_key), InputError);
  for (const std::string& p : {old, no_key}) std::remove(p.c_str());
}

// The gate feature: each horizon step's gate logit moves by the learned weight times that
// step's value of the named observation column, and nothing else changes.
TEST_F(PinnModel, AGateFeatureMovesEachStepsGateByItsValue) {
  PinnNet pen(PinnConfig{kT, kP, kDo, {8}, 21, BetaBase::Min, 0.025});
  PinnNet fed(PinnConfig{kT, kP, kDo, {8}, 21, BetaBase::Min, 0.025, 1});
  {
    at::NoGradGuard no_grad;
    fed->named_parameters()["pen_gate_feature_weight"].fill_(-2.5f);
  }
  const Dataset& ds = dataset();
  const PinnOutput a = pen->forward(ds.obs, ds.theta_k), b = fed->forward(ds.obs, ds.theta_k);
  ASSERT_TRUE(at::equal(a.theta_u, b.theta_u));
  auto logit = [](const at::Tensor& g) { return at::log(g / (1 - g)); };
  const at::Tensor feature = ds.obs.slice(1, kT - kP, kT).select(2, 1);
  EXPECT_TRUE(at::allclose(logit(b.pen_gate) - logit(a.pen_gate), -2.5f * feature, 1e-4, 1e-4));
  // A strongly negative value (an edge going down fast) opens the gate, a positive one closes it.
  at::Tensor down = ds.obs.clone(), up = ds.obs.clone();
  down.slice(1, kT - kP, kT).select(2, 1).fill_(-10.0f);
  up.slice(1, kT - kP, kT).select(2, 1).fill_(10.0f);
  EXPECT_TRUE((fed->forward(down, ds.theta_k).pen_gate > 0.999).all().item<bool>());
  EXPECT_TRUE((fed->forward(up, ds.theta_k).pen_gate < 0.001).all().item<bool>());
  // The column and the weight survive a file; a version-3 file (before the key) has no feature.
  PinnNet loaded = throughFile(fed, "fed.pt");
  EXPECT_EQ(loaded->config().gate_feature, 1);
  EXPECT_TRUE(at::equal(loaded->forward(ds.obs, ds.theta_k).pen_gate, b.pen_gate));
  const PinnConfig& c = pen->config();
  nlohmann::json v3{{"T", c.T}, {"P", c.P}, {"D_o", c.D_o}, {"hidden", c.hidden}, {"seed", c.seed},
                    {"beta_base", "min"}, {"edge_thickness_m", 0.025}};
  const std::string old = writeWithMetadata(pen, "v3.pt", 3, v3, configHash(c, 3));
  EXPECT_EQ(loadPinn(old)->config().gate_feature, -1);
  std::remove(old.c_str());
  // A column past the observations, or a gate without the penetration term, is refused.
  EXPECT_THROW(PinnNet(PinnConfig{kT, kP, kDo, {8}, 21, BetaBase::Min, 0.025, kDo}), std::invalid_argument);
  EXPECT_THROW(PinnNet(PinnConfig{kT, kP, kDo, {8}, 21, BetaBase::Min, 0.0, 1}), std::invalid_argument);
}

// The observed gate (PinnConfig::gate_observed): each horizon step's gate is 1 exactly where the
// gate feature lies below gate_zero and 0 elsewhere, whatever the encoder says; the penetration
// force follows it; config and threshold survive a file; a version-5 file loads with a learned gate.
TEST_F(PinnModel, AnObservedGateIsTheSignOfItsFeature) {
  PinnConfig cfg{kT, kP, kDo, {8}, 21, BetaBase::Min, 0.025, 1};
  cfg.gate_observed = true;
  cfg.gate_zero = 0.3;
  PinnNet net(cfg);
  const Dataset& ds = dataset();
  at::Tensor obs = ds.obs.clone();
  const at::Tensor feature = obs.slice(1, kT - kP, kT).select(2, 1);
  feature.copy_(at::where(at::arange(kP).unsqueeze(0).expand_as(feature) % 2 == 0, at::full_like(feature, 0.29f),
                          at::full_like(feature, 0.31f)));
  const PinnOutput o = net->forward(obs, ds.theta_k);
  EXPECT_TRUE(at::equal(o.pen_gate, (feature < 0.3).to(at::kFloat)));
  EXPECT_TRUE((o.pen_gate.slice(1, 0, kP, 2) == 1).all().item<bool>());
  EXPECT_TRUE((o.pen_gate.slice(1, 1, kP, 2) == 0).all().item<bool>());
  // The same soil with the gate shut everywhere: the vertical force differs exactly on open steps.
  at::Tensor shut = obs.clone();
  shut.slice(1, kT - kP, kT).select(2, 1).fill_(5.0f);
  const PinnOutput c = net->forward(shut, ds.theta_k);
  EXPECT_TRUE((c.pen_gate == 0).all().item<bool>());
  PinnNet loaded = throughFile(net, "observed_gate.pt");
  EXPECT_TRUE(loaded->config().gate_observed);
  EXPECT_DOUBLE_EQ(loaded->config().gate_zero, 0.3);
  EXPECT_TRUE(at::equal(loaded->forward(obs, ds.theta_k).F, o.F));
  // A model without a learned gate has no gate head to train.
  for (const auto& kv : net->named_parameters()) EXPECT_EQ(kv.key().find("gate"), std::string::npos) << kv.key();
  PinnConfig bad = cfg;
  bad.gate_feature = -1;
  EXPECT_THROW(PinnNet{bad}, std::invalid_argument);
  PinnNet learned(PinnConfig{kT, kP, kDo, {8}, 21, BetaBase::Min, 0.025, 1});
  const PinnConfig& lc = learned->config();
  nlohmann::json v5{{"T", lc.T}, {"P", lc.P}, {"D_o", lc.D_o}, {"hidden", lc.hidden}, {"seed", lc.seed},
                    {"beta_base", "min"}, {"edge_thickness_m", 0.025}, {"gate_feature", 1}, {"q_gamma_ref_n_m3", 0.0}};
  const std::string old = writeWithMetadata(learned, "v5.pt", 5, v5, configHash(lc, 5));
  EXPECT_FALSE(loadPinn(old)->config().gate_observed);
  std::remove(old.c_str());
}

TEST_F(PinnModel, TheSlicedGeometryFlagRoundTripsAndOlderFilesLoadWithoutIt) {
  PinnConfig c{kT, kP, kDo, {8}, 22, BetaBase::Min, 0.025, 1};
  c.sliced_geometry = true;
  PinnNet sliced(c);
  EXPECT_TRUE(throughFile(sliced, "sliced.pt")->config().sliced_geometry);
  PinnConfig m = c;
  m.sliced_geometry = false;
  EXPECT_NE(configHash(c), configHash(m));  // the flag is part of what the file's hash guards
  PinnNet mean(m);
  EXPECT_FALSE(throughFile(mean, "mean.pt")->config().sliced_geometry);
  // A version-6 file (before the flag) was trained on the sweep's mean geometry.
  nlohmann::json v6{{"T", c.T}, {"P", c.P}, {"D_o", c.D_o}, {"hidden", c.hidden}, {"seed", c.seed},
                    {"beta_base", "min"}, {"edge_thickness_m", 0.025}, {"gate_feature", 1}, {"q_gamma_ref_n_m3", 0.0},
                    {"gate_observed", false}, {"gate_zero", 0.0}};
  const std::string old = writeWithMetadata(mean, "v6.pt", 6, v6, configHash(m, 6));
  EXPECT_FALSE(loadPinn(old)->config().sliced_geometry);
  std::remove(old.c_str());
}

TEST_F(PinnModel, LoadRejectsWhatIsNotAModel) {
  EXPECT_THROW(loadPinn(tempPath("does_not_exist.pt")), InputError);
  const std::string junk = tempPath("junk.pt");
  std::ofstream(junk) << "not a torch archive";
  EXPECT_THROW(loadPinn(junk), InputError);
  const std::string bare = tempPath("bare.pt");
  torch::serialize::OutputArchive ar;
  ar.write("x", at::zeros({2}));
  ar.save_to(bare);
  EXPECT_THROW(loadPinn(bare), InputError);  // a torch archive, but no soil_pinn metadata
  std::remove(junk.c_str());
  std::remove(bare.c_str());
}

}  // namespace
}  // namespace terramap::pinn
