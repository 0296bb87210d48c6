#include "trainer.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>
#include <terramap/soil/fee.hpp>

#include <ATen/CPUGeneratorImpl.h>
#include <nlohmann/json.hpp>
#include <torch/optim/adam.h>
#include <torch/serialize.h>
#include <torch/torch.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>

namespace terramap::pinn {
namespace fs = std::filesystem;

std::vector<long> TrainingData::indices(eval::DatasetSplit s) const {
  std::vector<long> out;
  for (std::size_t i = 0; i < split.size(); ++i)
    if (split[i] == static_cast<std::uint8_t>(s)) out.push_back(static_cast<long>(i));
  return out;
}

TrainingData makeTrainingData(const eval::SoilDataset& d, int T, int P, bool sliced) {
  if (T > d.T || P > d.P || P > T || P < 1)
    throw InputError("the dataset stores T = " + std::to_string(d.T) + ", P = " + std::to_string(d.P) +
                     " steps; training asks for T = " + std::to_string(T) + ", P = " + std::to_string(P) +
                     " (need 1 <= P <= T, T <= stored T, P <= stored P)");
  const long n = static_cast<long>(d.size());
  const int D = soil::kObsFeatures;
  std::vector<long> keep;
  TrainingData out;
  for (long i = 0; i < n; ++i) {
    bool ok = true;
    for (int p = d.P - P; p < d.P && ok; ++p)
      for (int k = 0; k < 2; ++k) ok = ok && std::isfinite(d.force[static_cast<std::size_t>((i * d.P + p) * 2 + k)]);
    for (int p = d.P - P; p < d.P && ok; ++p)
      for (int k = 0; k < soil::kThetaK; ++k)
        ok = ok && std::isfinite(d.theta_k[static_cast<std::size_t>((i * d.P + p) * soil::kThetaK + k)]);
    if (ok) keep.push_back(i);
    else ++out.dropped_nonfinite;
  }
  const long m = static_cast<long>(keep.size());
  out.obs_raw = at::empty({m, T, D}, at::kFloat);
  out.theta_k = at::empty({m, P, soil::kThetaK}, at::kFloat);
  out.force = at::empty({m, P, 2}, at::kFloat);
  out.moving = at::empty({m, P}, at::kBool);
  bool* mv = out.moving.data_ptr<bool>();
  out.truth = at::empty({m, 5}, at::kFloat);
  out.truth_geometry = at::full({m, 5}, std::numeric_limits<float>::quiet_NaN(), at::kFloat);
  float* tg = out.truth_geometry.data_ptr<float>();
  out.force_quiet = at::full({m, P, 2}, std::numeric_limits<float>::quiet_NaN(), at::kFloat);
  float* fq = out.force_quiet.data_ptr<float>();
  const bool has_quiet = d.force_quiet.size() == d.force.size();
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  out.truth_geometry_rows = at::full({m, P, 5}, kNaN, at::kFloat);
  out.force_parts = at::full({m, P, 3, 2}, kNaN, at::kFloat);
  out.edge_vz = at::full({m, P}, kNaN, at::kFloat);
  const std::size_t rows_n = d.force.size() / 2;  // N * stored P
  // The last P of the stored rows, `width` values a row.
  const auto copyRows = [&](const std::vector<float>& from, at::Tensor& to, long i, long r, long width) {
    if (from.size() != rows_n * static_cast<std::size_t>(width)) return;
    std::copy_n(from.data() + (i * d.P + (d.P - P)) * width, P * width, to.data_ptr<float>() + r * P * width);
  };
  float* o = out.obs_raw.data_ptr<float>();
  float* th = out.theta_k.data_ptr<float>();
  float* f = out.force.data_ptr<float>();
  float* tr = out.truth.data_ptr<float>();
  long sliced_steps = 0;
  for (long r = 0; r < m; ++r) {
    const long i = keep[static_cast<std::size_t>(r)];
    std::copy_n(d.obs.data() + (i * d.T + (d.T - T)) * D, static_cast<long>(T) * D, o + r * T * D);
    std::copy_n(d.theta_k.data() + (i * d.P + (d.P - P)) * soil::kThetaK, static_cast<long>(P) * soil::kThetaK,
                th + r * P * soil::kThetaK);
    std::copy_n(d.force.data() + (i * d.P + (d.P - P)) * 2, static_cast<long>(P) * 2, f + r * P * 2);
    // The horizon is the last P observation rows of the stored history.
    for (int p = 0; p < P; ++p)
      mv[r * P + p] = !soil::stalledRow(d.obs.data() + (i * d.T + (d.T - P + p)) * D);
    std::copy_n(d.truth.data() + i * 5, 5, tr + r * 5);
    if (d.truth_geometry.size() == d.truth.size()) std::copy_n(d.truth_geometry.data() + i * 5, 5, tg + r * 5);
    if (has_quiet) std::copy_n(d.force_quiet.data() + (i * d.P + (d.P - P)) * 2, static_cast<long>(P) * 2, fq + r * P * 2);
    copyRows(d.truth_geometry_rows, out.truth_geometry_rows, i, r, 5);
    if (sliced) {
      if (d.profile.size() == rows_n * soil::kProfile)
        sliced_steps += soil::applySlicedGeometry(th + r * P * soil::kThetaK,
                                                  d.profile.data() + (i * d.P + (d.P - P)) * soil::kProfile, P);
      // The simulator's rows: alpha, rho, d, w, q beside area, depth2 (truth_profile_rows).
      if (d.truth_profile_rows.size() == rows_n * 8 && d.truth_geometry_rows.size() == rows_n * 5) {
        float* g = out.truth_geometry_rows.data_ptr<float>() + r * P * 5;
        const float* tp = d.truth_profile_rows.data() + (i * d.P + (d.P - P)) * 8;
        for (int p = 0; p < P; ++p) {
          double d = 0, w = 0;
          if (!fee::slicedWedge(tp[p * 8], tp[p * 8 + 1], d, w)) continue;
          g[p * 5 + 2] = static_cast<float>(d);
          g[p * 5 + 3] = static_cast<float>(w);
        }
      }
    }
    copyRows(d.force_parts, out.force_parts, i, r, 6);
    copyRows(d.edge_vz_rows, out.edge_vz, i, r, 1);
    out.split.push_back(d.split[static_cast<std::size_t>(i)]);
    out.family.push_back(d.family[static_cast<std::size_t>(i)]);
    out.relative_density.push_back(d.relative_density[static_cast<std::size_t>(i)]);
  }
  if (sliced && m > 0 && sliced_steps == 0)
    throw InputError("the model takes theta_k's depth and width from the cut's cross-section (geometry: sliced), "
                     "but the dataset's 'profile' array is missing or holds no cut: regenerate it with this build");
  return out;
}

std::string trainConfigHash(const TrainConfig& c) {
  nlohmann::json j;
  j["T"] = c.T;
  j["P"] = c.P;
  j["hidden"] = c.hidden;
  j["members"] = c.members;
  j["seed"] = c.seed;
  j["batch"] = c.batch;
  j["max_epochs"] = c.max_epochs;
  j["patience"] = c.patience;
  j["learning_rate"] = c.learning_rate;
  j["beta_base"] = betaBaseName(c.beta_base);
  j["mask_stalled"] = c.mask_stalled;
  // Only when set, so the hashes of configs written before the key existed stay valid.
  if (c.edge_thickness_m != 0) j["edge_thickness_m"] = c.edge_thickness_m;
  if (c.gate_feature >= 0) j["gate_feature"] = c.gate_feature;
  if (c.q_gamma_ref_n_m3 > 0) j["q_gamma_ref_n_m3"] = c.q_gamma_ref_n_m3;
  if (c.gate_observed) j["gate_observed"] = true;
  if (c.sliced_geometry) j["sliced_geometry"] = true;
  if (c.weights.lambda_prior != 0) j["lambda_prior"] = c.weights.lambda_prior;
  if (c.weights.lambda_soil != 0) j["lambda_soil"] = c.weights.lambda_soil;
  const LossWeights& w = c.weights;
  j["weights"] = {w.lambda_F, w.lambda_NLL, w.lambda_beta, w.lambda_range, w.lambda_res, w.lambda_Fr, w.w_xz[0],
                  w.w_xz[1], w.sigma_floor_n2};
  return fnv1a64Hex(j.dump());
}

namespace {

// Mean and std per feature over the rows `idx` (NaN ignored); a feature that never varies
// keeps std 1 so it normalises to a constant 0 rather than dividing by ~0.
void featureStats(const at::Tensor& x /*[N, ..., D]*/, const std::vector<long>& idx, std::vector<float>& mean,
                  std::vector<float>& stdv) {
  const long D = x.size(-1);
  const long per_row = x.numel() / x.size(0);
  const float* p = x.data_ptr<float>();
  std::vector<double> s(static_cast<std::size_t>(D), 0), s2(static_cast<std::size_t>(D), 0), n(static_cast<std::size_t>(D), 0);
  for (long i : idx)
    for (long k = 0; k < per_row; ++k) {
      const double v = p[i * per_row + k];
      if (!std::isfinite(v)) continue;
      const std::size_t f = static_cast<std::size_t>(k % D);
      s[f] += v;
      s2[f] += v * v;
      n[f] += 1;
    }
  mean.assign(static_cast<std::size_t>(D), 0.0f);
  stdv.assign(static_cast<std::size_t>(D), 1.0f);
  for (std::size_t f = 0; f < static_cast<std::size_t>(D); ++f) {
    if (n[f] < 2) continue;
    const double m = s[f] / n[f];
    const double var = std::max(0.0, s2[f] / n[f] - m * m);
    mean[f] = static_cast<float>(m);
    const double sd = std::sqrt(var);
    stdv[f] = sd > 1e-6 * std::max(1.0, std::abs(m)) ? static_cast<float>(sd) : 1.0f;
  }
}

at::Tensor rows(const at::Tensor& x, const std::vector<long>& idx) {
  return x.index_select(0, at::tensor(idx, at::kLong));
}

void copyInto(PinnNet& dst, PinnNet& src) {
  torch::NoGradGuard g;
  auto dp = dst->named_parameters(), sp = src->named_parameters();
  for (auto& kv : sp) dp[kv.key()].copy_(kv.value());
  auto db = dst->named_buffers(), sb = src->named_buffers();
  for (auto& kv : sb) db[kv.key()].copy_(kv.value());
}

struct MemberState {
  int epoch = 0, best_epoch = 0, stale = 0;
  double best_val = INFINITY, last_train = 0;
  bool done = false;
};

fs::path checkpointPath(const TrainConfig& cfg, int member) {
  const fs::path dir = cfg.checkpoint_dir.empty() ? fs::path(cfg.out + ".ckpt") : fs::path(cfg.checkpoint_dir);
  return dir / ("member_" + std::to_string(member) + ".pt");
}

void saveCheckpoint(const fs::path& path, const std::string& hash, PinnNet& net, PinnNet& best,
                    torch::optim::Adam& opt, const MemberState& st) {
  torch::serialize::OutputArchive ar, net_ar, best_ar, opt_ar;
  savePinnTo(net, net_ar);
  savePinnTo(best, best_ar);
  opt.save(opt_ar);
  ar.write("net", net_ar);
  ar.write("best", best_ar);
  ar.write("optimizer", opt_ar);
  nlohmann::json j{{"hash", hash},          {"epoch", st.epoch}, {"best_epoch", st.best_epoch}, {"stale", st.stale},
                   {"best_val", st.best_val}, {"last_train", st.last_train}, {"done", st.done}};
  ar.write("state", c10::IValue(j.dump()));
  saveArchiveAtomically(ar, path.string(), "a training checkpoint");
}

bool loadCheckpoint(const fs::path& path, const std::string& hash, PinnNet& net, PinnNet& best,
                    torch::optim::Adam& opt, MemberState& st) {
  if (!fs::exists(path)) return false;
  torch::serialize::InputArchive ar, net_ar, best_ar, opt_ar;
  try {
    ar.load_from(path.string());
  } catch (const std::exception&) {
    return false;  // not ours or damaged: train from scratch (it is rewritten atomically)
  }
  c10::IValue state;
  if (!ar.try_read("state", state) || !state.isString()) return false;
  const nlohmann::json j = nlohmann::json::parse(state.toStringRef());
  if (j.value("hash", "") != hash) return false;  // another config: start over
  ar.read("net", net_ar);
  ar.read("best", best_ar);
  ar.read("optimizer", opt_ar);
  PinnNet n = loadPinnFrom(net_ar, path.string()), b = loadPinnFrom(best_ar, path.string());
  copyInto(net, n);
  copyInto(best, b);
  opt.load(opt_ar);
  st.epoch = j.at("epoch");
  st.best_epoch = j.at("best_epoch");
  st.stale = j.at("stale");
  st.best_val = j.at("best_val");
  st.last_train = j.at("last_train");
  st.done = j.at("done");
  return true;
}

/// The input distance of the epistemic variance (soil::PinnInputDistance) fitted on the
/// training split's samples, each property's prior variance its range's (soil::uniformRangeVariances);
/// empty when the split holds fewer samples than the covariance needs (a toy dataset).
soil::PinnInputDistance fitInputDistance(const TrainingData& data, const std::vector<long>& train_idx, int T,
                                         const std::vector<float>& obs_mean, const std::vector<float>& obs_std,
                                         const std::vector<float>& th_mean, const std::vector<float>& th_std) {
  const at::Tensor oc = data.obs_raw.contiguous(), tc = data.theta_k.contiguous();
  const int Ts = static_cast<int>(oc.size(1)), Ds = static_cast<int>(oc.size(2)), Ps = static_cast<int>(tc.size(1));
  if (train_idx.size() < static_cast<std::size_t>(6 + Ds + 1)) return {};
  std::vector<std::vector<double>> feats;
  feats.reserve(train_idx.size());
  for (long i : train_idx)
    feats.push_back(soil::pinnInputFeatures(oc.data_ptr<float>() + i * Ts * Ds, Ts, T, Ds, obs_mean.data(),
                                            obs_std.data(), tc.data_ptr<float>() + i * Ps * 6, Ps, th_mean.data(),
                                            th_std.data()));
  return soil::PinnInputDistance::fit(feats, soil::uniformRangeVariances());
}

/// One split's tensors as the loss takes them (obs normalised; `mask` the rows the force terms
/// use; `truth` only when the loss supervises by it, else undefined, which turns its term off).
struct SplitTensors {
  at::Tensor obs, theta_k, force, mask, truth;
  long size() const { return obs.size(0); }
  /// The rows `idx` ([n] long) or [b0, b0 + len) of every tensor.
  SplitTensors select(const at::Tensor& idx) const { return map([&](const at::Tensor& t) { return t.index_select(0, idx); }); }
  SplitTensors slice(long b0, long len) const { return map([&](const at::Tensor& t) { return t.narrow(0, b0, len); }); }
  LossTerms loss(PinnNet& net, const LossWeights& w) const {
    return pinnLoss(net->forward(obs, theta_k), force, w, mask, truth);
  }

 private:
  template <class F>
  SplitTensors map(F f) const {
    return {f(obs), f(theta_k), f(force), f(mask), truth.defined() ? f(truth) : at::Tensor()};
  }
};

SplitTensors splitTensors(const TrainingData& data, const at::Tensor& obs, const at::Tensor& mask,
                          const std::vector<long>& idx, bool with_truth) {
  return {rows(obs, idx), rows(data.theta_k, idx), rows(data.force, idx), rows(mask, idx),
          with_truth ? rows(data.truth, idx) : at::Tensor()};
}

/// The validation loss (total and force MAE) in batches, without gradients.
double validationLoss(PinnNet& net, const SplitTensors& va, const TrainConfig& cfg, double& force_mae) {
  torch::NoGradGuard g;
  double sum = 0, fsum = 0;
  for (long b0 = 0; b0 < va.size(); b0 += cfg.batch) {
    const long len = std::min<long>(cfg.batch, va.size() - b0);
    const LossTerms t = va.slice(b0, len).loss(net, cfg.weights);
    sum += t.total.item<double>() * static_cast<double>(len);
    fsum += t.force_mae.item<double>() * static_cast<double>(len);
  }
  force_mae = fsum / static_cast<double>(va.size());
  return sum / static_cast<double>(va.size());
}

/// One epoch of Adam over the training split; the mean training loss. The batch order comes
/// from (seed, epoch) alone, so a resumed run draws the same batches.
double trainEpoch(PinnNet& net, torch::optim::Adam& opt, const SplitTensors& tr, const TrainConfig& cfg,
                  std::int64_t seed, int epoch) {
  auto gen = at::make_generator<at::CPUGeneratorImpl>(static_cast<std::uint64_t>(seed) * 7919u + epoch);
  const at::Tensor perm = at::randperm(tr.size(), gen, at::kLong);
  double sum = 0;
  net->train();
  for (long b0 = 0; b0 < perm.size(0); b0 += cfg.batch) {
    const long len = std::min<long>(cfg.batch, perm.size(0) - b0);
    const LossTerms t = tr.select(perm.narrow(0, b0, len)).loss(net, cfg.weights);
    opt.zero_grad();
    t.total.backward();
    opt.step();
    sum += t.total.item<double>() * static_cast<double>(len);
  }
  net->eval();
  return sum / static_cast<double>(perm.size(0));
}

/// Member m of the ensemble, from its checkpoint if one matches `hash`, trained until early
/// stopping; its best copy goes to `best_members`.
MemberReport trainMember(int m, const TrainConfig& cfg, const std::string& hash, const SplitTensors& tr,
                         const SplitTensors& va, const std::vector<float>& th_mean, const std::vector<float>& th_std,
                         double gate_zero,
                         const std::function<void(int, int, double, double, double)>& on_progress,
                         std::vector<PinnNet>& best_members) {
  const std::int64_t seed = cfg.seed * 1000 + m;
  const PinnConfig pc{cfg.T, cfg.P, soil::kObsFeatures, cfg.hidden, seed, cfg.beta_base, cfg.edge_thickness_m,
                      cfg.gate_feature, cfg.q_gamma_ref_n_m3, cfg.gate_observed, gate_zero,
                      cfg.sliced_geometry};
  PinnNet net(pc);
  net->setThetaNormalisation(at::tensor(th_mean), at::tensor(th_std));
  PinnNet best(pc);
  copyInto(best, net);
  torch::optim::Adam opt(net->parameters(), torch::optim::AdamOptions(cfg.learning_rate));
  MemberState st;
  MemberReport mr;
  const fs::path ck = checkpointPath(cfg, m);
  mr.resumed = loadCheckpoint(ck, hash, net, best, opt, st);
  while (!st.done && st.epoch < cfg.max_epochs) {
    st.last_train = trainEpoch(net, opt, tr, cfg, seed, st.epoch);
    double val_force_mae = 0;
    const double val = validationLoss(net, va, cfg, val_force_mae);
    ++st.epoch;
    if (val < st.best_val) {
      st.best_val = val;
      st.best_epoch = st.epoch;
      st.stale = 0;
      copyInto(best, net);
    } else if (++st.stale >= cfg.patience) {
      st.done = true;
    }
    if (st.epoch >= cfg.max_epochs) st.done = true;
    saveCheckpoint(ck, hash, net, best, opt, st);
    if (on_progress) on_progress(m, st.epoch, st.last_train, val, val_force_mae);
  }
  mr.epochs = st.epoch;
  mr.best_epoch = st.best_epoch;
  mr.best_validation_loss = st.best_val;
  mr.final_train_loss = st.last_train;
  best_members.push_back(best);
  return mr;
}

}  // namespace

TrainReport trainEnsemble(const TrainConfig& cfg,
                          const std::function<void(int, int, double, double, double)>& on_progress) {
  const auto wall0 = std::chrono::steady_clock::now();
  at::set_num_threads(1);  // the same bits on any machine: no reduction split across threads
  const eval::SoilDataset ds = eval::readSoilDataset(cfg.dataset);
  const TrainingData data = makeTrainingData(ds, cfg.T, cfg.P, cfg.sliced_geometry);
  const std::vector<long> train_idx = data.indices(eval::DatasetSplit::Train);
  const std::vector<long> val_idx = data.indices(eval::DatasetSplit::Validation);
  if (train_idx.empty() || val_idx.empty())
    throw InputError(cfg.dataset + ": needs train and validation samples (has " + std::to_string(train_idx.size()) +
                     " and " + std::to_string(val_idx.size()) + ")");
  std::vector<float> obs_mean, obs_std, th_mean, th_std;
  featureStats(data.obs_raw, train_idx, obs_mean, obs_std);
  featureStats(data.theta_k, train_idx, th_mean, th_std);
  // A raw 0 of the gate's feature as the network sees it (an observed gate's threshold).
  const double gate_zero = cfg.gate_feature >= 0
      ? -static_cast<double>(obs_mean[static_cast<std::size_t>(cfg.gate_feature)]) / obs_std[static_cast<std::size_t>(cfg.gate_feature)]
      : 0.0;
  // Normalise once; the estimator applies the same mean/std at inference.
  const at::Tensor obs = at::nan_to_num((data.obs_raw - at::tensor(obs_mean)) / at::tensor(obs_std), 0.0, 0.0, 0.0);
  const at::Tensor mask = cfg.mask_stalled ? data.moving : at::ones_like(data.moving);
  const bool supervise = cfg.weights.lambda_soil != 0;
  const SplitTensors tr = splitTensors(data, obs, mask, train_idx, supervise);
  const SplitTensors va = splitTensors(data, obs, mask, val_idx, supervise);
  const std::string hash = trainConfigHash(cfg) + "-" + ds.config_hash;
  std::error_code ec;
  fs::create_directories(checkpointPath(cfg, 0).parent_path(), ec);
  if (ec) throw OutputError(checkpointPath(cfg, 0).parent_path().string() + ": cannot create: " + ec.message());

  TrainReport report;
  report.train_samples = static_cast<long>(train_idx.size());
  report.validation_samples = static_cast<long>(val_idx.size());
  std::vector<PinnNet> best_members;
  for (int m = 0; m < cfg.members; ++m)
    report.members.push_back(trainMember(m, cfg, hash, tr, va, th_mean, th_std, gate_zero, on_progress, best_members));
  nlohmann::json tj;
  tj["train_config_hash"] = trainConfigHash(cfg);
  tj["dataset_config_hash"] = ds.config_hash;
  tj["dataset"] = cfg.dataset;
  tj["train_samples"] = report.train_samples;
  tj["validation_samples"] = report.validation_samples;
  for (const MemberReport& r : report.members)
    tj["members"].push_back({{"epochs", r.epochs}, {"best_epoch", r.best_epoch}, {"best_validation_loss", r.best_validation_loss}});
  SoilEstimator est(best_members, obs_mean, obs_std, tj.dump());
  est.setInputDistance(fitInputDistance(data, train_idx, cfg.T, obs_mean, obs_std, th_mean, th_std));
  saveEstimator(est, cfg.out);
  report.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  return report;
}

}  // namespace terramap::pinn
