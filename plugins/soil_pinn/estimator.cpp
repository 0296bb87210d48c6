#include "estimator.hpp"

#include <terramap/core/error.hpp>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>
#include <torch/serialize/archive.h>
#include <torch/torch.h>

#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace terramap::pinn {
namespace {
constexpr const char* kEstimatorKey = "terramap_estimator";
constexpr const char* kEstimatorFormat = "terramap.soil_estimator";
/// Version 2: the input distance ("input_distance"; version 1 files have none).
constexpr int kEstimatorVersion = 2;
}  // namespace

SoilEstimator::SoilEstimator(std::vector<PinnNet> members, std::vector<float> obs_mean, std::vector<float> obs_std,
                             std::string training_json)
    : members_(std::move(members)),
      obs_mean_(std::move(obs_mean)),
      obs_std_(std::move(obs_std)),
      training_json_(std::move(training_json)) {
  if (members_.empty()) throw std::invalid_argument("SoilEstimator: no members");
  const PinnConfig& c0 = members_.front()->config();
  for (const auto& m : members_) {
    const PinnConfig& c = m->config();
    if (c.T != c0.T || c.P != c0.P || c.D_o != c0.D_o || c.hidden != c0.hidden || c.beta_base != c0.beta_base)
      throw std::invalid_argument("SoilEstimator: members differ in T, P, D_o, hidden sizes or beta_base");
  }
  if (obs_mean_.size() != static_cast<std::size_t>(c0.D_o) || obs_std_.size() != obs_mean_.size())
    throw std::invalid_argument("SoilEstimator: observation normalisation must have D_o entries");
  for (float s : obs_std_)
    if (!(s > 0) || !std::isfinite(s)) throw std::invalid_argument("SoilEstimator: observation std must be > 0");
  std::vector<soil::PinnMemberWeights> weights;
  for (const PinnNet& m : members_) weights.push_back(m->exportWeights());
  fast_ = soil::PinnInference(std::move(weights), obs_mean_, obs_std_);
  const at::Tensor sa = defaultAmbiguityVariance();
  for (int k = 0; k < kSoilCount; ++k) ambiguity_var_[static_cast<std::size_t>(k)] = sa[k].item<double>();
}

at::Tensor SoilEstimator::normaliseObs(const float* raw, long batch, int T_stored) const {
  const int T = this->T(), D = members_.front()->config().D_o;
  at::Tensor out = at::empty({batch, T, D}, at::kFloat);
  float* o = out.data_ptr<float>();
  for (long b = 0; b < batch; ++b)
    for (int t = 0; t < T; ++t) {
      const float* src = raw + (b * T_stored + (T_stored - T + t)) * D;
      float* dst = o + (b * T + t) * D;
      for (int k = 0; k < D; ++k) {
        const float z = (src[k] - obs_mean_[static_cast<std::size_t>(k)]) / obs_std_[static_cast<std::size_t>(k)];
        dst[k] = std::isfinite(z) ? z : 0.0f;
      }
    }
  return out;
}

std::vector<SoilEstimate> SoilEstimator::estimate(const float* obs_raw, const float* theta_k, long batch, int T_stored,
                                                  int P_stored, const NullspaceTolerances& tol) const {
  const int T = this->T(), P = this->P();
  if (T_stored < T || P_stored < P)
    throw std::invalid_argument("SoilEstimator::estimate: the samples hold fewer steps than the model needs");
  torch::NoGradGuard no_grad;
  const at::Tensor obs = normaliseObs(obs_raw, batch, T_stored);
  at::Tensor th = at::from_blob(const_cast<float*>(theta_k), {batch, P_stored, 6}, at::kFloat)
                      .narrow(1, P_stored - P, P)
                      .contiguous();
  const at::Tensor sigma_a = defaultAmbiguityVariance();
  const long M = static_cast<long>(members_.size());
  at::Tensor means = at::empty({M, batch, kSoilCount}, at::kDouble);
  at::Tensor var_a = at::empty({M, batch, kSoilCount}, at::kDouble);
  at::Tensor var_n = at::empty({M, batch, kSoilCount}, at::kDouble);
  at::Tensor fr = at::zeros({batch, 2}, at::kDouble);
  at::Tensor fpred = at::zeros({batch, P, 2}, at::kDouble);
  at::Tensor dres = at::zeros({batch}, at::kDouble), bres = at::zeros({batch}, at::kDouble);
  at::Tensor beta_last = at::zeros({batch}, at::kDouble);
  at::Tensor member_valid = at::empty({M, batch}, at::kBool);
  for (long m = 0; m < M; ++m) {
    PinnNet net = members_[static_cast<std::size_t>(m)];
    const PinnOutput out = net->forward(obs, th);
    means[m] = out.theta_u.to(at::kDouble);
    var_a[m] = out.log_var.narrow(1, 0, kSoilCount).to(at::kDouble).exp();
    var_n[m] = soilVariances(out.J, out.log_var.to(at::kDouble), sigma_a, tol);
    fr += out.F_r.to(at::kDouble);
    fpred += out.F.to(at::kDouble);
    dres += out.d_res.to(at::kDouble);
    bres += out.beta_res.to(at::kDouble);
    beta_last += out.beta.select(1, P - 1).to(at::kDouble);
    member_valid[m] = out.valid.any(1);
  }
  const at::Tensor mean = means.mean(0);
  const at::Tensor epi = means.var(0, /*unbiased=*/false);
  const at::Tensor va = var_a.mean(0), vn = var_n.mean(0);
  fr /= static_cast<double>(M);
  fpred /= static_cast<double>(M);
  auto fp_a = fpred.accessor<double, 3>();
  dres /= static_cast<double>(M);
  bres /= static_cast<double>(M);
  beta_last /= static_cast<double>(M);
  auto beta_a = beta_last.accessor<double, 1>();
  const at::Tensor nvalid = member_valid.to(at::kLong).sum(0);
  std::vector<SoilEstimate> res(static_cast<std::size_t>(batch));
  auto mean_a = mean.accessor<double, 2>(), va_a = va.accessor<double, 2>(), vn_a = vn.accessor<double, 2>(),
       epi_a = epi.accessor<double, 2>(), fr_a = fr.accessor<double, 2>();
  auto nv = nvalid.accessor<int64_t, 1>();
  auto dres_a = dres.accessor<double, 1>(), bres_a = bres.accessor<double, 1>();
  for (long b = 0; b < batch; ++b) {
    SoilEstimate& e = res[static_cast<std::size_t>(b)];
    for (int k = 0; k < kSoilCount; ++k) {
      e.mean[k] = mean_a[b][k];
      e.var_aleatoric[k] = va_a[b][k];
      e.var_nullspace[k] = vn_a[b][k];
      e.var_epistemic[k] = epi_a[b][k];
      e.var_total[k] = vn_a[b][k] + epi_a[b][k];
    }
    e.F_r = {fr_a[b][0], fr_a[b][1]};
    for (int p = 0; p < P; ++p) e.F.push_back({fp_a[b][p][0], fp_a[b][p][1]});
    e.d_res_m = dres_a[b];
    e.beta_res_rad = bres_a[b];
    e.beta_rad = beta_a[b];
    e.valid_members = static_cast<int>(nv[b]);
    e.valid = 2 * e.valid_members > M;
    fast_.applyInputDistance(obs_raw + b * T_stored * members_.front()->config().D_o, T_stored,
                             theta_k + b * P_stored * 6, P_stored, e);
  }
  return res;
}

SoilEstimate SoilEstimator::estimate(const soil::PinnSample& s, const NullspaceTolerances& tol) const {
  return estimate(s.obs.data(), s.theta_k.data(), 1, s.T, s.P, tol).front();
}

SoilEstimate SoilEstimator::estimateFast(const soil::PinnSample& s, const NullspaceTolerances& tol) const {
  soil::PinnInferenceOptions opt;
  opt.a_tol = tol.a_tol;
  opt.r_tol = tol.r_tol;
  opt.ambiguity_var = ambiguity_var_;
  return fast_.estimate(s.obs.data(), s.T, s.theta_k.data(), s.P, opt);
}

void saveEstimator(const SoilEstimator& e, const std::string& path) {
  torch::serialize::OutputArchive root;
  for (std::size_t m = 0; m < e.members().size(); ++m) {
    torch::serialize::OutputArchive sub;
    PinnNet net = e.members()[m];
    savePinnTo(net, sub);
    root.write("member" + std::to_string(m), sub);
  }
  nlohmann::json j;
  j["format"] = kEstimatorFormat;
  j["version"] = kEstimatorVersion;
  j["members"] = e.members().size();
  j["obs_mean"] = e.obsMean();
  j["obs_std"] = e.obsStd();
  j["obs_features"] = soil::obsFeatureNames();
  j["training"] = nlohmann::json::parse(e.trainingJson());
  if (const soil::PinnInputDistance& d = e.inputDistance(); !d.empty())
    j["input_distance"] = {{"mean", d.mean}, {"whiten", d.whiten}, {"q", d.q}, {"prior_var", d.prior_var}};
  root.write(kEstimatorKey, c10::IValue(j.dump()));
  saveArchiveAtomically(root, path, "the soil estimator");
}

SoilEstimator loadEstimator(const std::string& path) {
  torch::serialize::InputArchive root;
  try {
    root.load_from(path);
  } catch (const std::exception& ex) {
    const std::string what = ex.what();
    throw InputError(path + ": not a readable soil estimator: " + what.substr(0, what.find('\n')));
  }
  c10::IValue meta;
  if (!root.try_read(kEstimatorKey, meta) || !meta.isString())
    throw InputError(path + ": torch archive without soil estimator metadata (a single PinnNet file?)");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(meta.toStringRef());
    if (j.at("format").get<std::string>() != kEstimatorFormat) throw InputError(path + ": format is not " + kEstimatorFormat);
    if (j.at("version").get<int>() > kEstimatorVersion)
      throw InputError(path + ": soil estimator version " + std::to_string(j.at("version").get<int>()) +
                       " is newer than this build (" + std::to_string(kEstimatorVersion) + ")");
    if (j.at("obs_features").get<std::vector<std::string>>() != soil::obsFeatureNames())
      throw InputError(path + ": trained on other observation features than this build computes "
                              "(soil/pinn_sample.hpp changed): train it again");
  } catch (const nlohmann::json::exception& ex) {
    throw InputError(path + ": bad soil estimator metadata: " + ex.what());
  }
  const std::size_t n = j.at("members").get<std::size_t>();
  std::vector<PinnNet> members;
  for (std::size_t m = 0; m < n; ++m) {
    torch::serialize::InputArchive sub;
    if (!root.try_read("member" + std::to_string(m), sub))
      throw InputError(path + ": member " + std::to_string(m) + " of " + std::to_string(n) + " is missing");
    members.push_back(loadPinnFrom(sub, path + " (member " + std::to_string(m) + ")"));
  }
  try {
    SoilEstimator est(std::move(members), j.at("obs_mean").get<std::vector<float>>(),
                      j.at("obs_std").get<std::vector<float>>(), j.value("training", nlohmann::json::object()).dump());
    if (j.contains("input_distance")) {
      const nlohmann::json& dj = j.at("input_distance");
      soil::PinnInputDistance d;
      d.mean = dj.at("mean").get<std::vector<double>>();
      d.whiten = dj.at("whiten").get<std::vector<double>>();
      d.q = dj.at("q").get<double>();
      d.prior_var = dj.at("prior_var").get<std::array<double, 5>>();
      const std::size_t n = 6 + est.obsMean().size();  // theta_k and the observation features
      if (d.mean.size() != n || d.whiten.size() != n * n || !(d.q > 0))
        throw InputError(path + ": input_distance does not match the model's " + std::to_string(n) + " features");
      est.setInputDistance(std::move(d));
    }
    return est;
  } catch (const std::invalid_argument& ex) {
    throw InputError(path + ": " + ex.what());
  } catch (const nlohmann::json::exception& ex) {
    throw InputError(path + ": bad input_distance: " + ex.what());
  }
}

}  // namespace terramap::pinn
