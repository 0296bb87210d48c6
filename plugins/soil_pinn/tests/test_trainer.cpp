// Training and evaluating the ensemble (trainer.hpp, evaluation.hpp) on a small synthetic dataset
// written in the dataset's own HDF5 format: forces from the C++ FEE with known soils, and
// observations that carry the soil (so a network can learn it).
#include "evaluation.hpp"
#include "trainer.hpp"

#include <terramap/core/error.hpp>
#include <terramap/soil/fee.hpp>
#include <terramap/soil/soil_table.hpp>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <unistd.h>

#include <array>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <random>

using namespace terramap;
using namespace terramap::pinn;
namespace fs = std::filesystem;

namespace {

constexpr int kT = 6, kP = 3;

// An empty dataset folder of this process and the config its synthetic episodes are written with.
fs::path freshDatasetDir(const std::string& name, eval::SoilDatasetConfig& cfg) {
  const fs::path dir = fs::temp_directory_path() / ("terramap_trainer_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "episodes");
  cfg.history_T = kT;
  cfg.horizon_P = kP;
  cfg.config_hash = "synthetic";
  return dir;
}

// A random level-ish cut whose FEE (β*) is valid for soil `s`, and that evaluation.
fee::Result randomValidCut(const fee::Soil& s, std::mt19937_64& rng, fee::Geometry& g) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  fee::Result r;
  do {
    g = {0.04 * (u(rng) - 0.5), 1.30 + 0.15 * u(rng), 0.05 + 0.15 * u(rng), 1.0 + 0.8 * u(rng), 3000 * u(rng)};
    r = fee::evaluateAtBetaMin(s, g);
  } while (!r.valid());
  return r;
}

// Episodes of one soil each; every sample a random cut geometry, force = the paper's F of the
// truth soil at beta* (the physics layer's default base angle), constant over the horizon. Observation feature k < 5 is the soil
// property k scaled to about [-1, 1] plus noise; the rest are zero.
/// `quiet_scale` (finite): each sample's noise-free force (EpisodeData::force_quiet) is its
/// force times this; otherwise the episodes keep none (NaN in the file).
fs::path makeDataset(const std::string& name, int episodes, int samples_per_episode,
                     double quiet_scale = std::numeric_limits<double>::quiet_NaN()) {
  eval::SoilDatasetConfig cfg;
  const fs::path dir = freshDatasetDir(name, cfg);
  std::mt19937_64 rng(42);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int e = 0; e < episodes; ++e) {
    eval::EpisodeData ep;
    ep.plan.index = ep.plan.file_index = e;
    ep.plan.split = e % 5 == 3 ? eval::DatasetSplit::Validation : e % 5 == 4 ? eval::DatasetSplit::Test
                                                                             : eval::DatasetSplit::Train;
    ep.plan.family = static_cast<soil::SoilFamily>(e % 4);
    ep.plan.relative_density = 0.05 + 0.9 * u(rng);
    const soil::SoilProperties sp = soil::soilProperties(ep.plan.family, ep.plan.relative_density);
    const double props[5] = {sp.fee.c_pa / 30e3 - 1, sp.fee.phi_rad / 0.5 - 1, sp.fee.ca_pa / 15e3 - 1,
                             sp.fee.delta_rad / 0.4 - 1, sp.fee.gamma_n_m3 / 17e3 - 1};
    for (int s = 0; s < samples_per_episode; ++s) {
      soil::PinnSample smp;
      smp.T = kT;
      smp.P = kP;
      smp.obs.assign(static_cast<std::size_t>(kT) * soil::kObsFeatures, 0.0f);
      for (int t = 0; t < kT; ++t)
        for (int k = 0; k < 5; ++k) smp.obs[static_cast<std::size_t>(t * soil::kObsFeatures + k)] = static_cast<float>(props[k] + 0.05 * (u(rng) - 0.5));
      fee::Geometry g;
      const fee::Result r = randomValidCut(sp.fee, rng, g);
      for (int p = 0; p < kP; ++p) {
        smp.theta_k.insert(smp.theta_k.end(), {static_cast<float>(g.rho_rad), static_cast<float>(g.alpha_rad),
                                               static_cast<float>(g.w_m), static_cast<float>(g.d_m),
                                               static_cast<float>(g.q_n), 0.8f});
        smp.force.insert(smp.force.end(), {static_cast<float>(r.F_N.x()), static_cast<float>(r.F_N.y())});
      }
      if (std::isfinite(quiet_scale)) {
        std::vector<float> q = smp.force;
        for (float& v : q) v = static_cast<float>(quiet_scale * v);
        ep.force_quiet.push_back(q);
      }
      ep.samples.push_back(smp);
      ep.truth.push_back({static_cast<float>(sp.fee.c_pa), static_cast<float>(sp.fee.phi_rad),
                          static_cast<float>(sp.fee.ca_pa), static_cast<float>(sp.fee.delta_rad),
                          static_cast<float>(sp.fee.gamma_n_m3)});
    }
    eval::writeEpisodeFile((dir / "episodes" / eval::episodeFileName(ep.plan)).string(), cfg, ep);
  }
  return dir;
}

TrainConfig smallConfig(const fs::path& data, const fs::path& out) {
  TrainConfig c;
  c.dataset = data.string();
  c.out = out.string();
  c.T = kT;
  c.P = kP;
  c.hidden = {16};
  c.members = 2;
  c.seed = 3;
  c.batch = 20;
  c.max_epochs = 6;
  c.patience = 100;
  c.learning_rate = 3e-3;
  return c;
}

std::vector<SoilEstimate> estimates(const fs::path& model, const TrainingData& d) {
  const SoilEstimator e = loadEstimator(model.string());
  return e.estimate(d.obs_raw.data_ptr<float>(), d.theta_k.data_ptr<float>(), d.size(), kT, kP);
}

}  // namespace

TEST(Trainer, LearnsTheForceBetterThanAConstantAndReproducesBitForBit) {
  const fs::path data = makeDataset("learn", 20, 12, 0.9);
  const fs::path dir = data / "runs";
  fs::create_directories(dir);
  std::vector<double> val;
  TrainConfig c = smallConfig(data, dir / "a.pt");
  c.max_epochs = 25;
  const TrainReport rep = trainEnsemble(c, [&](int m, int, double, double v, double) { if (m == 0) val.push_back(v); });
  ASSERT_EQ(rep.members.size(), 2u);
  ASSERT_EQ(val.size(), 25u);
  EXPECT_LT(val.back(), 0.5 * val.front()) << "validation loss " << val.front() << " -> " << val.back();
  const TrainingData td = makeTrainingData(eval::readSoilDataset(data.string()), kT, kP);
  const SoilEvaluation ev = evaluateEstimator(loadEstimator(c.out), td);
  for (const SplitMetrics& m : ev.splits) {
    // Forces were made by the FEE of the truth soil at beta*: that baseline is exact (float
    // rounding), Rankine's angle is not.
    EXPECT_LT(m.force_error_truth_fee_min_pct, 0.01) << m.split;
    EXPECT_GT(m.force_error_truth_fee_pct, 5.0) << m.split;
    // No machine stalled in this dataset: every row is a moving row.
    EXPECT_EQ(m.stalled_row_fraction, 0.0) << m.split;
    EXPECT_DOUBLE_EQ(m.force_error_moving_pct, m.force_error_pct) << m.split;
    if (m.split == "train") {
      EXPECT_LT(m.force_error_pct, 0.6 * m.force_error_mean_pct) << m.force_error_pct;
    }
    // The constant baseline is the training split's: measured on every split present.
    for (int k = 0; k < kSoilCount; ++k) {
      EXPECT_TRUE(std::isfinite(m.mae_constant[k])) << m.split << " " << k;
    }
    // The noise-free force is 0.9 of the measured one: the floor is 10 % on every row.
    EXPECT_NEAR(m.force_error_noise_floor_pct, 10.0, 1e-4) << m.split;
    EXPECT_EQ(m.noise_free_rows, m.valid * kP) << m.split;
  }
  // The estimator against the noise-free force, summed here from its estimates.
  {
    const std::vector<SoilEstimate> es = estimates(c.out, td);
    std::map<std::string, std::array<double, 2>> sums;  // split -> Σ‖F̂ − 0.9 F‖, Σ‖0.9 F‖
    const float* f = td.force.data_ptr<float>();
    for (std::size_t i = 0; i < es.size(); ++i) {
      if (!es[i].valid) continue;
      auto& sum = sums[eval::datasetSplitName(static_cast<eval::DatasetSplit>(td.split[i]))];
      for (int p = 0; p < kP; ++p) {
        const double qx = 0.9 * f[(i * kP + p) * 2], qz = 0.9 * f[(i * kP + p) * 2 + 1];
        sum[0] += std::hypot(es[i].F[static_cast<std::size_t>(p)][0] - qx, es[i].F[static_cast<std::size_t>(p)][1] - qz);
        sum[1] += std::hypot(qx, qz);
      }
    }
    for (const SplitMetrics& m : ev.splits)
      EXPECT_NEAR(m.force_error_noise_free_pct, 100.0 * sums[m.split][0] / sums[m.split][1], 1e-3) << m.split;
  }
  // Without the noise-free force (tensors built by hand, older datasets): no floor, no rows.
  {
    TrainingData none = td;
    none.force_quiet = at::Tensor();
    for (const SplitMetrics& m : evaluateEstimator(loadEstimator(c.out), none).splits) {
      EXPECT_TRUE(std::isnan(m.force_error_noise_floor_pct)) << m.split;
      EXPECT_EQ(m.noise_free_rows, 0) << m.split;
    }
  }
  // Same config, another output: the same bits.
  TrainConfig c2 = c;
  c2.out = (dir / "b.pt").string();
  trainEnsemble(c2);
  const auto ea = estimates(c.out, td), eb = estimates(c2.out, td);
  for (std::size_t i = 0; i < ea.size(); ++i) {
    EXPECT_EQ(ea[i].mean, eb[i].mean);
    EXPECT_EQ(ea[i].var_total, eb[i].var_total);
  }
  fs::remove_all(data);
}

TEST(Trainer, AKilledRunResumesFromItsCheckpointsToTheSameModel) {
  const fs::path data = makeDataset("resume", 10, 8);
  const TrainConfig whole = smallConfig(data, data / "whole.pt");
  trainEnsemble(whole);
  // Interrupted in the second member's third epoch (the callback throws like a kill would stop it).
  TrainConfig part = smallConfig(data, data / "part.pt");
  struct Killed {};
  EXPECT_THROW(trainEnsemble(part, [](int m, int epoch, double, double, double) { if (m == 1 && epoch == 3) throw Killed{}; }),
               Killed);
  EXPECT_FALSE(fs::exists(part.out));
  const TrainReport rep = trainEnsemble(part);
  EXPECT_TRUE(rep.members[0].resumed);
  EXPECT_TRUE(rep.members[1].resumed);
  const TrainingData td = makeTrainingData(eval::readSoilDataset(data.string()), kT, kP);
  const auto a = estimates(whole.out, td), b = estimates(part.out, td);
  for (std::size_t i = 0; i < a.size(); ++i) EXPECT_EQ(a[i].mean, b[i].mean);
  fs::remove_all(data);
}

TEST(Trainer, TrainingDataTakesTheEndOfTheHistoryAndDropsNonFiniteForces) {
  const fs::path data = makeDataset("slice", 5, 4);
  eval::SoilDataset ds = eval::readSoilDataset(data.string());
  ds.force[0] = std::nanf("");  // sample 0, first horizon step
  const TrainingData td = makeTrainingData(ds, 4, 2);
  EXPECT_EQ(td.dropped_nonfinite, 0);  // step 0 lies outside the last 2 of 3 horizon steps
  EXPECT_EQ(td.size(), 20);
  ds.force[static_cast<std::size_t>((kP - 1) * 2)] = std::nanf("");  // sample 0, last step
  const TrainingData td2 = makeTrainingData(ds, 4, 2);
  EXPECT_EQ(td2.dropped_nonfinite, 1);
  EXPECT_EQ(td2.size(), 19);
  // The history kept is the last 4 of 6 steps.
  EXPECT_EQ(td.obs_raw[1][0][0].item<float>(), ds.obs[static_cast<std::size_t>((1 * kT + 2) * soil::kObsFeatures)]);
  // Horizon rows where the machine stood stalled are marked: sample 2's last row (tracks at
  // 1 m/s, base still) and, outside the 2-step horizon kept, sample 3's first row.
  auto setRow = [&](long sample, int t, float vx, float track) {
    float* f = ds.obs.data() + (sample * kT + t) * soil::kObsFeatures;
    f[0] = vx;
    f[26] = f[27] = track;
  };
  setRow(2, kT - 1, 0.0f, 1.0f);
  setRow(3, kT - 3, 0.0f, 1.0f);
  setRow(4, kT - 1, 0.5f, 1.0f);  // moving at half the track speed: not stalled
  const TrainingData td3 = makeTrainingData(ds, 4, 2);
  ASSERT_EQ(td3.moving.sizes(), (at::IntArrayRef{19, 2}));
  // td3 dropped sample 0, so sample s is row s - 1.
  EXPECT_FALSE(td3.moving[1][1].item<bool>());
  EXPECT_EQ(td3.moving.logical_not().sum().item<int64_t>(), 1);
  EXPECT_THROW(makeTrainingData(ds, kT + 1, 2), InputError);
  EXPECT_THROW(makeTrainingData(ds, kT, kP + 1), InputError);
  fs::remove_all(data);
}

namespace {

/// Every field of the torch-free estimate against the libtorch one, for every sample of `d`
/// (the encoder runs in float32 in both, with different summation orders: compare to float
/// rounding, relative to each parameter's range). Returns how many samples had a valid FEE.
int expectFastPathMatches(const SoilEstimator& est, const TrainingData& d) {
  const NullspaceTolerances tol{1500.0, 0.05};
  const auto slow = est.estimate(d.obs_raw.data_ptr<float>(), d.theta_k.data_ptr<float>(), d.size(), kT, kP, tol);
  int valid = 0;
  for (long i = 0; i < d.size(); ++i) {
    SCOPED_TRACE("sample " + std::to_string(i));
    soil::PinnSample s;
    s.T = kT;
    s.P = kP;
    s.obs.assign(d.obs_raw[i].data_ptr<float>(), d.obs_raw[i].data_ptr<float>() + kT * soil::kObsFeatures);
    s.theta_k.assign(d.theta_k[i].data_ptr<float>(), d.theta_k[i].data_ptr<float>() + kP * 6);
    const SoilEstimate f = est.estimateFast(s, tol);
    const SoilEstimate& t = slow[static_cast<std::size_t>(i)];
    EXPECT_EQ(f.valid, t.valid);
    EXPECT_EQ(f.valid_members, t.valid_members);
    valid += t.valid;
    for (int k = 0; k < kSoilCount; ++k) {
      const double span = kSoilRanges[k].hi - kSoilRanges[k].lo;
      EXPECT_NEAR(f.mean[k], t.mean[k], 1e-5 * span) << "property " << k;
      EXPECT_NEAR(f.var_aleatoric[k], t.var_aleatoric[k], 1e-4 * t.var_aleatoric[k]) << "property " << k;
      EXPECT_NEAR(f.var_nullspace[k], t.var_nullspace[k], 1e-4 * t.var_nullspace[k]) << "property " << k;
      EXPECT_NEAR(f.var_epistemic[k], t.var_epistemic[k], 1e-4 * t.var_epistemic[k] + 1e-9 * span * span)
          << "property " << k;
    }
    EXPECT_EQ(f.F.size(), t.F.size());
    for (std::size_t p = 0; p < std::min(f.F.size(), t.F.size()); ++p)
      for (int c = 0; c < 2; ++c)
        EXPECT_NEAR(f.F[p][c], t.F[p][c], 1e-4 * std::max(1.0, std::hypot(t.F[p][0], t.F[p][1])));
    EXPECT_NEAR(f.beta_rad, t.beta_rad, 1e-6);
    EXPECT_EQ(std::isnan(f.input_d2), std::isnan(t.input_d2));
    if (!std::isnan(t.input_d2)) {
      EXPECT_NEAR(f.input_d2, t.input_d2, 1e-9 * (1.0 + t.input_d2));
    }
    EXPECT_NEAR(f.d_res_m, t.d_res_m, 1e-7);
    EXPECT_NEAR(f.F_r[0], t.F_r[0], 1e-3);
  }
  return valid;
}

}  // namespace

TEST(Trainer, TheTorchFreeInferenceGivesTheLibtorchEstimate) {
  // A trained ensemble (beta*) and an untrained one with Rankine's angle, on the dataset's
  // samples plus copies cut above the surface (no valid FEE step) and half cut (one step).
  const fs::path data = makeDataset("fast", 6, 6);
  TrainConfig c = smallConfig(data, data / "fast.pt");
  c.max_epochs = 3;
  trainEnsemble(c);
  const TrainingData td = makeTrainingData(eval::readSoilDataset(data.string()), kT, kP);
  TrainingData mixed = td;
  mixed.theta_k = td.theta_k.clone();
  for (long i = 0; i < td.size(); i += 3) mixed.theta_k[i].select(1, kKD).fill_(-0.05);  // above the surface
  for (long i = 1; i < td.size(); i += 3) mixed.theta_k[i][0][kKD] = -0.05;              // one step invalid
  const SoilEstimator trained = loadEstimator(c.out);
  EXPECT_GT(expectFastPathMatches(trained, td), td.size() / 2);
  expectFastPathMatches(trained, mixed);
  {
    // With the input-distance term (its statistics fitted here on standard-normal features: the
    // toy dataset is too small to fit them): the same share in both paths, read back from a file.
    SoilEstimator far_aware = loadEstimator(c.out);
    std::mt19937_64 rng(4);
    std::normal_distribution<double> N(0.0, 1.0);
    std::vector<std::vector<double>> feats(400, std::vector<double>(6 + soil::kObsFeatures));
    for (auto& f : feats)
      for (double& x : f) x = N(rng);
    far_aware.setInputDistance(soil::PinnInputDistance::fit(feats, {1e6, 0.04, 1e6, 0.04, 1e6}));
    expectFastPathMatches(far_aware, td);
    expectFastPathMatches(far_aware, mixed);
    saveEstimator(far_aware, (data / "far.pt").string());
    const SoilEstimator back = loadEstimator((data / "far.pt").string());
    EXPECT_EQ(back.inputDistance().mean, far_aware.inputDistance().mean);
    EXPECT_EQ(back.inputDistance().whiten, far_aware.inputDistance().whiten);
    EXPECT_EQ(back.inputDistance().q, far_aware.inputDistance().q);
    // A blade pitch 100 of the training's standard deviations off: nearly the whole prior is added.
    soil::PinnSample s;
    s.T = kT;
    s.P = kP;
    s.obs.assign(td.obs_raw[0].data_ptr<float>(), td.obs_raw[0].data_ptr<float>() + kT * soil::kObsFeatures);
    s.theta_k.assign(td.theta_k[0].data_ptr<float>(), td.theta_k[0].data_ptr<float>() + kP * 6);
    const SoilEstimate near = back.estimateFast(s);
    const float std_rho = back.members().front()->exportWeights().theta_k_std[0];
    for (int p = 0; p < kP; ++p) s.theta_k[static_cast<std::size_t>(p * 6)] += 100.0f * std_rho;
    const SoilEstimate far = back.estimateFast(s), far_slow = back.estimate(s);
    EXPECT_GT(far.input_share, 0.99);
    EXPECT_NEAR(far.input_share, far_slow.input_share, 1e-6);
    EXPECT_GT(far.var_epistemic[1], near.var_epistemic[1] + 0.99 * 0.04);
    EXPECT_NEAR(far.var_total[1], far.var_nullspace[1] + far.var_epistemic[1], 1e-12);
  }
  std::vector<PinnNet> members;
  for (int64_t seed : {5, 6, 7})
    members.emplace_back(PinnConfig{kT, kP, soil::kObsFeatures, {16, 8}, seed, BetaBase::Nominal});
  const SoilEstimator rankine(std::move(members), trained.obsMean(), trained.obsStd());
  expectFastPathMatches(rankine, mixed);
  // With the penetration term: its gate head and the z row of the Jacobian in both paths.
  std::vector<PinnNet> pen;
  for (int64_t seed : {8, 9, 10})
    pen.emplace_back(PinnConfig{kT, kP, soil::kObsFeatures, {16, 8}, seed, BetaBase::Min, 0.025});
  const SoilEstimator penetrating(std::move(pen), trained.obsMean(), trained.obsStd());
  EXPECT_GT(expectFastPathMatches(penetrating, td), td.size() / 2);
  expectFastPathMatches(penetrating, mixed);
  // And with the gate fed directly by an observation column (the edge's vertical speed), its
  // weight moved off the initial -1 so a wrong column or sign would show.
  std::vector<PinnNet> gated;
  for (int64_t seed : {11, 12, 13}) {
    gated.emplace_back(PinnConfig{kT, kP, soil::kObsFeatures, {16, 8}, seed, BetaBase::Min, 0.025,
                                  soil::kObsFeatures - 1});
    at::NoGradGuard no_grad;
    gated.back()->named_parameters()["pen_gate_feature_weight"].fill_(-3.0f - static_cast<float>(seed));
  }
  const SoilEstimator gate_fed(std::move(gated), trained.obsMean(), trained.obsStd());
  EXPECT_GT(expectFastPathMatches(gate_fed, td), td.size() / 2);
  expectFastPathMatches(gate_fed, mixed);
  // And with the surcharge weighed by the estimated gamma (its force and the Jacobian's gamma column).
  std::vector<PinnNet> weighed;
  for (int64_t seed : {14, 15, 16}) {
    PinnConfig pc{kT, kP, soil::kObsFeatures, {16, 8}, seed, BetaBase::Min, 0.025, soil::kObsFeatures - 1};
    pc.q_gamma_ref_n_m3 = 14636.0;
    weighed.emplace_back(pc);
  }
  const SoilEstimator q_gamma(std::move(weighed), trained.obsMean(), trained.obsStd());
  EXPECT_GT(expectFastPathMatches(q_gamma, td), td.size() / 2);
  expectFastPathMatches(q_gamma, mixed);
  // And with the observed gate (PinnConfig::gate_observed) on a column that varies from sample to
  // sample, its threshold in the middle: open on some samples, shut on others, in both paths.
  std::vector<PinnNet> observed;
  for (int64_t seed : {17, 18}) {
    PinnConfig pc{kT, kP, soil::kObsFeatures, {16, 8}, seed, BetaBase::Min, 0.025, 0};
    pc.gate_observed = true;
    pc.gate_zero = 0.0;
    observed.emplace_back(pc);
  }
  const SoilEstimator gate_seen(std::move(observed), trained.obsMean(), trained.obsStd());
  EXPECT_GT(expectFastPathMatches(gate_seen, td), td.size() / 2);
  expectFastPathMatches(gate_seen, mixed);
  fs::remove_all(data);
}

TEST(DefaultModel, TheCommittedModelHasTheDocumentedSettingsAndRuns) {
  // models/soil_pinn.pt: `terramap train configs/train/pinn.yaml` on the dataset of
  // configs/dataset/pinn.yaml (docs/soil_estimator.md). Loading it checks its format, version
  // and the observation features of this build; the settings below are those of the config.
  const SoilEstimator est = loadEstimator(std::string(TERRAMAP_SOURCE_DIR) + "/models/soil_pinn.pt");
  ASSERT_EQ(est.size(), 5u);
  const PinnConfig& c = est.members().front()->config();
  EXPECT_EQ(c.T, 30);
  EXPECT_EQ(c.P, 10);
  EXPECT_EQ(c.hidden, (std::vector<int>{128, 128}));
  EXPECT_EQ(c.beta_base, BetaBase::Min);
  TrainConfig tc;  // configs/train/pinn.yaml
  tc.T = 30;
  tc.P = 10;
  tc.hidden = {128, 128};
  tc.members = 5;
  tc.seed = 1;
  tc.batch = 100;
  tc.max_epochs = 60;
  tc.patience = 8;
  tc.learning_rate = 0.001;
  tc.weights.lambda_Fr = 2e-5;
  tc.beta_base = BetaBase::Min;
  tc.mask_stalled = true;
  tc.edge_thickness_m = 0.025;
  tc.gate_feature = soil::kObsFeatures - 1;  // blade_vz_map_mps
  tc.gate_observed = true;
  tc.weights.w_xz = {1.0, 1.0};
  EXPECT_TRUE(c.gate_observed);
  EXPECT_FALSE(c.sliced_geometry);
  EXPECT_EQ(c.edge_thickness_m, 0.025);
  EXPECT_EQ(c.gate_feature, soil::kObsFeatures - 1);
  EXPECT_EQ(soil::obsFeatureNames()[static_cast<std::size_t>(c.gate_feature)], "blade_vz_map_mps");
  const nlohmann::json tj = nlohmann::json::parse(est.trainingJson());
  EXPECT_EQ(tj.at("train_config_hash").get<std::string>(), trainConfigHash(tc));
  EXPECT_EQ(tj.at("train_samples").get<long>(), 12683);  // the pinn_v14 dataset (docs/soil_estimator.md)
  // The input distance fitted on those samples: the 41 features (theta_k and the observations).
  EXPECT_EQ(est.inputDistance().mean.size(), 6u + soil::kObsFeatures);
  EXPECT_GT(est.inputDistance().q, 0.0);
  // A plausible cut: a valid estimate inside the soil ranges, the same by both paths.
  soil::PinnSample s;
  s.T = 30;
  s.P = 10;
  s.obs.assign(static_cast<std::size_t>(s.T) * soil::kObsFeatures, 0.0f);
  for (int t = 0; t < s.T; ++t) {
    float* f = s.obs.data() + t * soil::kObsFeatures;
    for (int k = 0; k < soil::kObsFeatures; ++k) f[k] = est.obsMean()[static_cast<std::size_t>(k)];
  }
  for (int p = 0; p < s.P; ++p) s.theta_k.insert(s.theta_k.end(), {1.40f, 0.0f, 1.8f, 0.08f, 1500.0f, 0.6f});
  const SoilEstimate fast = est.estimateFast(s), slow = est.estimate(s);
  ASSERT_TRUE(fast.valid);
  for (int k = 0; k < kSoilCount; ++k) {
    EXPECT_GE(fast.mean[k], kSoilRanges[k].lo);
    EXPECT_LE(fast.mean[k], kSoilRanges[k].hi);
    EXPECT_NEAR(fast.mean[k], slow.mean[k], 1e-5 * (kSoilRanges[k].hi - kSoilRanges[k].lo));
  }
}

TEST(Evaluation, SkillIsAConstantsMaeAndThePearsonCorrelation) {
  const std::vector<double> truth{1, 2, 3, 4};
  PropertySkill s = propertySkill(truth, {2, 4, 6, 8}, 2.5);
  EXPECT_DOUBLE_EQ(s.mae_constant, 1.0);  // (1.5 + 0.5 + 0.5 + 1.5) / 4
  EXPECT_NEAR(s.correlation, 1.0, 1e-15);
  EXPECT_NEAR(propertySkill(truth, {8, 6, 4, 2}, 0).correlation, -1.0, 1e-15);
  // Deviations (-1.5, -0.5, 0.5, 1.5) and (-1.5, 0.5, -0.5, 1.5): 4 / 5.
  EXPECT_NEAR(propertySkill(truth, {1, 3, 2, 4}, 0).correlation, 0.8, 1e-15);
  EXPECT_DOUBLE_EQ(propertySkill(truth, {1, 3, 2, 4}, 0).mae_constant, 2.5);
  // A constant estimate has no correlation; nothing to measure gives NaN.
  EXPECT_TRUE(std::isnan(propertySkill(truth, {5, 5, 5, 5}, 0).correlation));
  s = propertySkill({}, {}, 1.0);
  EXPECT_TRUE(std::isnan(s.mae_constant));
  EXPECT_TRUE(std::isnan(s.correlation));
}

TEST(Evaluation, Fig11TrendIsTheRankCorrelationOfBinMeansPerFamily) {
  // Spearman: monotone but not linear is +1 (Pearson would not be), reversed is -1, ties take
  // their mean rank, and a flat series has no order to keep.
  EXPECT_NEAR(rankCorrelation({1, 2, 3, 4}, {1, 10, 100, 1000}), 1.0, 1e-15);
  EXPECT_NEAR(rankCorrelation({1, 2, 3, 4}, {9, 3, 2, 1}), -1.0, 1e-15);
  // Ranks (1, 2, 3, 4) and (1, 3, 2, 4): 1 - 6 * 2 / (4 * 15) = 0.8.
  EXPECT_NEAR(rankCorrelation({1, 2, 3, 4}, {5, 7, 6, 8}), 0.8, 1e-15);
  // Ranks (1, 2, 3) and (1.5, 1.5, 3): deviations (-1, 0, 1), (-0.5, -0.5, 1): 1.5 / sqrt(2 * 1.5).
  EXPECT_NEAR(rankCorrelation({1, 2, 3}, {4, 4, 6}), 1.5 / std::sqrt(3.0), 1e-15);
  EXPECT_TRUE(std::isnan(rankCorrelation({1, 2, 3}, {2, 2, 2})));
  EXPECT_TRUE(std::isnan(rankCorrelation({1, 2}, {1, 2})));

  // Two families: clay's estimate of phi follows the truth up three bins but its c comes down;
  // sand holds c at 0 (the truth is flat there: no trend to keep) and has a bin without samples.
  std::vector<Fig11Bin> bins;
  auto add = [&](soil::SoilFamily f, int bin, long samples, double c_t, double c_e, double phi_t, double phi_e) {
    Fig11Bin b;
    b.family = static_cast<int>(f);
    b.bin = bin;
    b.samples = samples;
    b.truth[0] = c_t;
    b.mean[0] = c_e;
    b.truth[1] = phi_t;
    b.mean[1] = phi_e;
    for (int k = 2; k < kSoilCount; ++k) b.truth[k] = b.mean[k] = bin;  // rise together
    bins.push_back(b);
  };
  add(soil::SoilFamily::Clay, 1, 10, 10e3, 30e3, 0.30, 0.40);
  add(soil::SoilFamily::Clay, 2, 10, 20e3, 25e3, 0.32, 0.41);
  add(soil::SoilFamily::Clay, 3, 10, 30e3, 20e3, 0.34, 0.45);
  add(soil::SoilFamily::Sand, 1, 5, 0, 1e3, 0.50, 0.60);
  add(soil::SoilFamily::Sand, 4, 5, 0, 2e3, 0.60, 0.55);
  add(soil::SoilFamily::Sand, 6, 5, 0, 3e3, 0.70, 0.50);
  add(soil::SoilFamily::Sand, 8, 0, 0, 0, 0.0, 9.0);  // no samples: not a bin of the trend
  const std::vector<Fig11Trend> t = fig11Trends(bins);
  ASSERT_EQ(t.size(), 2u);
  const Fig11Trend& clay = t[0].family == static_cast<int>(soil::SoilFamily::Clay) ? t[0] : t[1];
  const Fig11Trend& sand = &clay == &t[0] ? t[1] : t[0];
  EXPECT_EQ(clay.bins, 3);
  EXPECT_EQ(sand.bins, 3);
  EXPECT_NEAR(clay.rank_correlation[0], -1.0, 1e-15);
  EXPECT_NEAR(clay.rank_correlation[1], 1.0, 1e-15);
  EXPECT_TRUE(std::isnan(sand.rank_correlation[0]));
  EXPECT_NEAR(sand.rank_correlation[1], -1.0, 1e-15);
  for (int k = 2; k < kSoilCount; ++k) EXPECT_NEAR(clay.rank_correlation[k], 1.0, 1e-15);
  // The report carries it per family, null where the truth is flat.
  SoilEvaluation ev;
  ev.fig11 = bins;
  ev.fig11_trend = t;
  const nlohmann::json j = nlohmann::json::parse(evaluationJson(ev));
  EXPECT_DOUBLE_EQ(j["fig11_trend"]["clay"]["rank_correlation"]["phi"].get<double>(), 1.0);
  EXPECT_TRUE(j["fig11_trend"]["sand"]["rank_correlation"]["c"].is_null());
  EXPECT_NE(evaluationMarkdown(ev).find("Fig. 11's trend"), std::string::npos);
}

// The trainer hands the truth soil to the loss when lambda_soil is set: on a dataset whose
// observations carry the soil, the supervised ensemble's estimates lie far closer to the truth
// than the one trained on forces alone, with the same seed and epochs.
TEST(Trainer, SupervisionByTheTruthSoilReachesTheLoss) {
  const fs::path data = makeDataset("supervised", 15, 8);
  const TrainingData td = makeTrainingData(eval::readSoilDataset(data.string()), kT, kP);
  auto soilError = [&](const fs::path& model) {  // mean over samples of sum |est - truth| / span
    const std::vector<SoilEstimate> es = estimates(model, td);
    double e = 0;
    for (std::size_t i = 0; i < es.size(); ++i)
      for (int k = 0; k < kSoilCount; ++k)
        e += std::abs(es[i].mean[k] - td.truth[static_cast<long>(i)][k].item<float>()) /
             (kSoilRanges[k].hi - kSoilRanges[k].lo);
    return e / static_cast<double>(es.size());
  };
  TrainConfig c = smallConfig(data, data / "force_only.pt");
  c.max_epochs = 40;
  trainEnsemble(c);
  TrainConfig sup = c;
  sup.out = (data / "supervised.pt").string();
  sup.weights.lambda_soil = 100;
  trainEnsemble(sup);
  const double plain = soilError(c.out), supervised = soilError(sup.out);
  EXPECT_LT(supervised, 0.5 * plain) << "force only " << plain << ", supervised " << supervised;
  fs::remove_all(data);
}

// The decomposition of eval-soil (ForceDecomposition): on rows whose noise-free force
// is exactly the simulator-like F_total of the truth soil on the truth geometry plus the edge's
// penetration on the rows observed descending, and whose parts say so, the ladder's F_total step
// on the truth geometry misses by nothing; (a), the paper's F + penetration, misses by exactly the
// face adhesion; a mapped depth 20 % short makes (b) worse; (c) is the estimator's error
// against that force, recomputed here from its estimates; each x / z part bounds its total.
TEST(Evaluation, DecompositionSeparatesModelClassGeometryAndEstimator) {
  eval::SoilDatasetConfig cfg;
  const fs::path dir = freshDatasetDir("decomp", cfg);
  std::mt19937_64 rng(7);
  constexpr double kEdge = 0.025;
  double adhesion_miss = 0, norm = 0;
  for (int e = 0; e < 4; ++e) {
    eval::EpisodeData ep;
    ep.plan.index = ep.plan.file_index = e;
    ep.plan.split = eval::DatasetSplit::Test;
    ep.plan.family = static_cast<soil::SoilFamily>(e % 4);
    ep.plan.relative_density = 0.2 + 0.2 * e;
    const soil::SoilProperties sp = soil::soilProperties(ep.plan.family, ep.plan.relative_density);
    for (int s = 0; s < 6; ++s) {
      soil::PinnSample smp;
      smp.T = kT;
      smp.P = kP;
      smp.obs.assign(static_cast<std::size_t>(kT) * soil::kObsFeatures, 0.0f);
      std::vector<float> quiet, geo, parts, vz;
      for (int p = 0; p < kP; ++p) {
        fee::Geometry g;
        const fee::Result r = randomValidCut(sp.fee, rng, g);
        const bool down = (s + p) % 3 == 0;
        // Every fifth row the observed vertical speed has the wrong sign (what localisation
        // noise does to a slow edge): the truth soil then misses the penetration term there.
        const bool seen_down = (s + p) % 5 == 1 ? !down : down;
        smp.obs[static_cast<std::size_t>((kT - kP + p) * soil::kObsFeatures + soil::kObsFeatures - 1)] = seen_down ? -0.05f : 0.05f;
        const double pen = down ? fee::penetrationForce(sp.fee, g.d_m, g.w_m, kEdge) : 0.0;
        const Eigen::Vector2d fq = r.F_total_N + Eigen::Vector2d(0.0, -pen);
        smp.theta_k.insert(smp.theta_k.end(), {static_cast<float>(g.rho_rad), static_cast<float>(g.alpha_rad),
                                               static_cast<float>(g.w_m), static_cast<float>(0.8 * g.d_m),
                                               static_cast<float>(g.q_n), 0.0f});
        smp.force.insert(smp.force.end(), {static_cast<float>(fq.x()), static_cast<float>(fq.y())});
        quiet.insert(quiet.end(), {static_cast<float>(fq.x()), static_cast<float>(fq.y())});
        geo.insert(geo.end(), {static_cast<float>(g.alpha_rad), static_cast<float>(g.rho_rad), static_cast<float>(g.d_m),
                               static_cast<float>(g.w_m), static_cast<float>(g.q_n)});
        parts.insert(parts.end(), {static_cast<float>(r.F_total_N.x()), static_cast<float>(r.F_total_N.y()), 0.0f, 0.0f,
                                   0.0f, static_cast<float>(-pen)});
        vz.push_back(down ? -0.05f : 0.05f);
        adhesion_miss += (r.F_total_N - r.F_N).norm();
        norm += fq.norm();
      }
      ep.samples.push_back(smp);
      ep.force_quiet.push_back(quiet);
      ep.truth_geometry_rows.push_back(geo);
      ep.force_parts.push_back(parts);
      ep.edge_vz_rows.push_back(vz);
      ep.truth.push_back({static_cast<float>(sp.fee.c_pa), static_cast<float>(sp.fee.phi_rad),
                          static_cast<float>(sp.fee.ca_pa), static_cast<float>(sp.fee.delta_rad),
                          static_cast<float>(sp.fee.gamma_n_m3)});
    }
    eval::writeEpisodeFile((dir / "episodes" / eval::episodeFileName(ep.plan)).string(), cfg, ep);
  }
  const TrainingData td = makeTrainingData(eval::readSoilDataset(dir.string()), kT, kP);
  ASSERT_EQ(td.size(), 24);
  std::vector<PinnNet> members;
  members.emplace_back(PinnConfig{kT, kP, soil::kObsFeatures, {8}, 5, BetaBase::Min, kEdge});
  const SoilEstimator est(std::move(members), std::vector<float>(soil::kObsFeatures, 0.0f),
                          std::vector<float>(soil::kObsFeatures, 1.0f));
  const SoilEvaluation ev = evaluateEstimator(est, td);
  ASSERT_EQ(ev.splits.size(), 1u);
  const ForceDecomposition& d = ev.splits[0].decomposition;
  const std::vector<SoilEstimate> es = est.estimate(td.obs_raw.data_ptr<float>(), td.theta_k.data_ptr<float>(), td.size(), kT, kP);
  double est_miss = 0, est_norm = 0;
  long rows = 0;
  for (long i = 0; i < td.size(); ++i) {
    if (!es[static_cast<std::size_t>(i)].valid) continue;
    for (int p = 0; p < kP; ++p) {
      const Eigen::Vector2d q(td.force_quiet[i][p][0].item<float>(), td.force_quiet[i][p][1].item<float>());
      const Eigen::Vector2d f(es[static_cast<std::size_t>(i)].F[static_cast<std::size_t>(p)][0],
                              es[static_cast<std::size_t>(i)].F[static_cast<std::size_t>(p)][1]);
      est_miss += (f - q).norm();
      est_norm += q.norm();
      ++rows;
    }
  }
  ASSERT_GT(rows, 30);
  EXPECT_EQ(d.rows, rows);
  // F_total + penetration is the force but for the rows whose observed sign lied: all of the
  // ladder's error, and the penetration term's, is theirs and vertical.
  EXPECT_GT(d.ladder_truth[2].z, 1.0);
  EXPECT_LT(d.ladder_truth[2].x, 1e-3);
  EXPECT_NEAR(d.penetration_term.total, d.ladder_truth[2].total, 1e-3);
  EXPECT_LT(d.wedge_vs_slices.total, 1e-3);
  // With the edge's true descent as the gate, only the face adhesion is missing; with the
  // observed one, the rows whose sign lied miss their penetration term too.
  EXPECT_NEAR(d.truth_geometry_true_gate.total, 100.0 * adhesion_miss / norm, 0.05 * 100.0 * adhesion_miss / norm);
  EXPECT_GT(d.truth_geometry_true_gate.total, 1.0);
  EXPECT_GT(d.truth_geometry.z, d.truth_geometry_true_gate.z + 2.0);
  EXPECT_NEAR(d.truth_geometry.x, d.truth_geometry_true_gate.x, 1e-9);  // the term is vertical
  EXPECT_GT(d.mapped_geometry.total, d.truth_geometry.total + 5.0);
  EXPECT_GT(d.mapped_geometry.total, d.mapped_geometry_true_gate.total);
  EXPECT_NEAR(d.estimator.total, 100.0 * est_miss / est_norm, 1e-3 * 100.0 * est_miss / est_norm + 1e-6);
  for (const ForceGap* g : {&d.truth_geometry, &d.mapped_geometry, &d.estimator}) {
    EXPECT_LE(std::max(g->x, g->z), g->total + 1e-9);
    EXPECT_GE(g->x + g->z, g->total - 1e-9);
  }
  EXPECT_NEAR(d.share_inertia, 0.0, 1e-12);
  EXPECT_LT(d.observed_descending_true, d.observed_descending);
  EXPECT_LT(d.observed_descending_true, d.true_descending);
  EXPECT_GT(d.observed_descending_true, 0);
  fs::remove_all(dir);
}

TEST(Trainer, ASlicedModelsDataCarriesTheCutsCrossSectionAndNeedsIt) {
  const fs::path data = makeDataset("sliced", 5, 4);
  eval::SoilDataset ds = eval::readSoilDataset(data.string());
  // The synthetic episodes keep no profile (a dataset written before the array): a model that
  // needs it must say so rather than train on the mean geometry.
  ASSERT_EQ(ds.profile.size(), ds.force.size());  // N * P * 2, all NaN
  EXPECT_THROW(makeTrainingData(ds, kT, kP, true), InputError);
  // Sample 1's last horizon step: a cut 0.3 m^2 in section whose sum of d^2 ds is 0.05 m^3.
  const std::size_t row = static_cast<std::size_t>(1 * kP + (kP - 1));
  ds.profile[row * 2] = 0.3f;
  ds.profile[row * 2 + 1] = 0.05f;
  const TrainingData mean = makeTrainingData(ds, kT, kP), sliced = makeTrainingData(ds, kT, kP, true);
  EXPECT_NEAR(sliced.theta_k[1][kP - 1][soil::kDepth].item<float>(), 0.05 / 0.3, 1e-6);
  EXPECT_NEAR(sliced.theta_k[1][kP - 1][soil::kWidth].item<float>(), 0.3 * 0.3 / 0.05, 1e-5);
  // Every other entry is the mean geometry's.
  sliced.theta_k[1][kP - 1][soil::kDepth] = mean.theta_k[1][kP - 1][soil::kDepth];
  sliced.theta_k[1][kP - 1][soil::kWidth] = mean.theta_k[1][kP - 1][soil::kWidth];
  EXPECT_TRUE(at::equal(sliced.theta_k, mean.theta_k));
  fs::remove_all(data);
}
