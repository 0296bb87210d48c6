// The PINN network and its physics layer (paper §2.1 Eq. 1, 5, 6; ALGORITHMS.md §F).
#include "model.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>
#include <terramap/io/atomic_file.hpp>

#include <ATen/CPUGeneratorImpl.h>
#include <nlohmann/json.hpp>
#include <torch/nn/modules/activation.h>
#include <torch/serialize/archive.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>
#include <stdexcept>

namespace terramap::pinn {
namespace {

// 2: the config holds beta_base (version 1 files load with BetaBase::Nominal).
// 3: the config holds edge_thickness_m (older files load with 0: no penetration term).
// 4: the config holds gate_feature (older files load with -1: the gate from the encoder only).
// 5: the config holds q_gamma_ref_n_m3 (older files load with 0: Q as extracted).
// 6: the config holds gate_observed and gate_zero (older files load with a learned gate).
// 7: the config holds sliced_geometry (older files load with false: the sweep's mean d and w).
constexpr int kFormatVersion = 7;  // configHash()'s default in model.hpp follows it
constexpr const char* kFormat = "terramap.soil_pinn";
constexpr const char* kMetadataKey = "terramap_metadata";

nlohmann::json configJson(const PinnConfig& c, int format_version = kFormatVersion) {
  nlohmann::json j = {{"T", c.T}, {"P", c.P}, {"D_o", c.D_o}, {"hidden", c.hidden}, {"seed", c.seed}};
  if (format_version >= 2) j["beta_base"] = betaBaseName(c.beta_base);
  if (format_version >= 3) j["edge_thickness_m"] = c.edge_thickness_m;
  if (format_version >= 4) j["gate_feature"] = c.gate_feature;
  if (format_version >= 5) j["q_gamma_ref_n_m3"] = c.q_gamma_ref_n_m3;
  if (format_version >= 6) {
    j["gate_observed"] = c.gate_observed;
    j["gate_zero"] = c.gate_zero;
  }
  if (format_version >= 7) j["sliced_geometry"] = c.sliced_geometry;
  return j;
}

std::vector<double> toVector(const at::Tensor& t) {
  const at::Tensor d = t.detach().to(at::kDouble).contiguous();
  return std::vector<double>(d.data_ptr<double>(), d.data_ptr<double>() + d.numel());
}

/// where(valid, x, stand-in) for the dN_gamma/dbeta term (fee_torch.hpp: invalid entries).
at::Tensor pick(const at::Tensor& valid, const at::Tensor& x, double standin) {
  return at::where(valid, x, at::full_like(x, standin));
}

}  // namespace

double logVarSpan(int k) {
  if (k >= 0 && k < kSoilCount) return kSoilRanges[k].hi - kSoilRanges[k].lo;
  if (k == kLvDRes) return kDResMaxM;
  if (k == kLvBetaRes) return kBetaResMaxRad;
  throw std::out_of_range("logVarSpan: column " + std::to_string(k));
}
double logVarLo(int k) { return 2 * std::log(1e-3 * logVarSpan(k)); }
double logVarHi(int k) { return 2 * std::log(logVarSpan(k)); }
double logVarInit(int k) { return 2 * std::log(0.1 * logVarSpan(k)); }

std::string configHash(const PinnConfig& cfg, int format_version) {
  return fnv1a64Hex(configJson(cfg, format_version).dump());
}

PinnNetImpl::PinnNetImpl(PinnConfig cfg) : cfg_(std::move(cfg)) {
  if (cfg_.P < 1 || cfg_.T < cfg_.P || cfg_.D_o < 1)
    throw std::invalid_argument("PinnConfig: need 1 <= P <= T and D_o >= 1");
  if (!(cfg_.edge_thickness_m >= 0 && cfg_.edge_thickness_m < 1))
    throw std::invalid_argument("PinnConfig: edge_thickness_m must be in [0, 1) m");
  for (int h : cfg_.hidden)
    if (h < 1) throw std::invalid_argument("PinnConfig: hidden widths must be >= 1");
  const std::string options =
      soil::pinnOptionsError(cfg_.gate_feature, cfg_.D_o, cfg_.edge_thickness_m, cfg_.q_gamma_ref_n_m3);
  if (!options.empty()) throw std::invalid_argument("PinnConfig: " + options);
  if (cfg_.gate_observed && !(cfg_.gate_feature >= 0 && std::isfinite(cfg_.gate_zero)))
    throw std::invalid_argument("PinnConfig: gate_observed needs gate_feature and a finite gate_zero");
  // Initialise from cfg.seed, then give the global generator its state back so building a
  // network (or loading one) does not disturb anyone else's random stream.
  at::Generator gen = at::detail::getDefaultCPUGenerator();
  const at::Tensor saved_state = gen.get_state();
  gen.set_current_seed(static_cast<std::uint64_t>(cfg_.seed));
  int64_t width = static_cast<int64_t>(cfg_.T) * cfg_.D_o + static_cast<int64_t>(cfg_.P) * kThetaKCount;
  encoder_ = register_module("encoder", torch::nn::Sequential());
  for (int h : cfg_.hidden) {
    encoder_->push_back(torch::nn::Linear(width, h));
    encoder_->push_back(torch::nn::Tanh());
    width = h;
  }
  head_theta_ = register_module("head_theta", torch::nn::Linear(width, kSoilCount));
  head_logvar_ = register_module("head_log_var", torch::nn::Linear(width, kLogVarCount));
  head_res_ = register_module("head_res", torch::nn::Linear(width, 2));
  head_fr_ = register_module("head_force_res", torch::nn::Linear(width, 2));
  const bool learned_gate = cfg_.edge_thickness_m > 0 && !cfg_.gate_observed;
  if (learned_gate) head_gate_ = register_module("head_pen_gate", torch::nn::Linear(width, cfg_.P));
  gen.set_state(saved_state);
  if (learned_gate && cfg_.gate_feature >= 0) gate_feature_w_ = register_parameter("pen_gate_feature_weight", at::full({1}, -1.0f));
  theta_mean_ = register_buffer("theta_k_mean", at::zeros({kThetaKCount}, at::kFloat));
  theta_std_ = register_buffer("theta_k_std", at::ones({kThetaKCount}, at::kFloat));
  std::vector<float> off(kLogVarCount);
  for (int k = 0; k < kLogVarCount; ++k) off[k] = static_cast<float>(logVarInit(k));
  logvar_offset_ = at::tensor(off);
}

void PinnNetImpl::setThetaNormalisation(const at::Tensor& mean, const at::Tensor& std) {
  if (mean.numel() != kThetaKCount || std.numel() != kThetaKCount)
    throw std::invalid_argument("setThetaNormalisation: mean and std need 6 values");
  if (!(std.gt(0).all().item<bool>()) || !at::isfinite(mean).all().item<bool>())
    throw std::invalid_argument("setThetaNormalisation: std must be > 0 and mean finite");
  at::NoGradGuard no_grad;
  theta_mean_.copy_(mean.reshape({kThetaKCount}));
  theta_std_.copy_(std.reshape({kThetaKCount}));
}

PinnOutput PinnNetImpl::forward(const at::Tensor& obs, const at::Tensor& theta_k) {
  if (obs.dim() != 3 || obs.size(1) != cfg_.T || obs.size(2) != cfg_.D_o)
    throw std::invalid_argument("PinnNet::forward: obs must be [B," + std::to_string(cfg_.T) + "," +
                                std::to_string(cfg_.D_o) + "], got " + c10::str(obs.sizes()));
  const int64_t B = obs.size(0), P = cfg_.P;
  if (theta_k.dim() != 3 || theta_k.size(0) != B || theta_k.size(1) != P || theta_k.size(2) != kThetaKCount)
    throw std::invalid_argument("PinnNet::forward: theta_k must be [B," + std::to_string(P) + ",6], got " +
                                c10::str(theta_k.sizes()));
  // Encoder over [flatten(obs), flatten(normalised theta_k)].
  const at::Tensor tk = theta_k.to(at::kFloat);
  at::Tensor h = at::cat({obs.to(at::kFloat).reshape({B, -1}), ((tk - theta_mean_) / theta_std_).reshape({B, -1})}, 1);
  if (!encoder_->is_empty()) h = encoder_->forward(h);

  PinnOutput out;
  std::vector<float> lo(kSoilCount), span(kSoilCount);
  for (int k = 0; k < kSoilCount; ++k) {
    lo[k] = static_cast<float>(kSoilRanges[k].lo);
    span[k] = static_cast<float>(kSoilRanges[k].hi - kSoilRanges[k].lo);
  }
  out.theta_u = at::tensor(lo) + at::tensor(span) * at::sigmoid(head_theta_(h));
  out.log_var = head_logvar_(h) + logvar_offset_;
  const at::Tensor res = at::tanh(head_res_(h));
  out.d_res = kDResMaxM * res.select(1, 0);
  out.beta_res = kBetaResMaxRad * res.select(1, 1);
  out.F_r = kForceResScaleN * head_fr_(h);

  // Physics layer in float64.
  const at::Tensor soil = out.theta_u.to(at::kDouble);
  const at::Tensor k = tk.to(at::kDouble);
  const at::Tensor rho = k.select(2, kKRho), alpha = k.select(2, kKAlpha), w = k.select(2, kKW);
  const at::Tensor q_k = k.select(2, kKQ);
  // The surcharge weighed with the estimated gamma (PinnConfig::q_gamma_ref_n_m3), or as extracted.
  const bool q_gamma = cfg_.q_gamma_ref_n_m3 > 0;
  const at::Tensor q = q_gamma ? q_k * (soil.select(1, kSoilGamma) / cfg_.q_gamma_ref_n_m3).unsqueeze(1) : q_k;
  const at::Tensor d = k.select(2, kKD) + out.d_res.to(at::kDouble).unsqueeze(1);
  const at::Tensor phi = soil.select(1, kSoilPhi), delta = soil.select(1, kSoilDelta);
  const at::Tensor base = failureAngle(cfg_.beta_base, phi, delta, alpha, rho);  // [B,P]
  const at::Tensor beta_res = out.beta_res.to(at::kDouble);
  out.beta = base + beta_res.unsqueeze(1);
  const FeeOut fee = feeForward(soil, rho, alpha, w, d, q, out.beta);
  out.valid = fee.valid;
  out.F = fee.F + out.F_r.to(at::kDouble).unsqueeze(1);

  // Eq. 5/6, the base angle's dependence on the soil chained in.
  at::Tensor J = feeJacobianChained(soil, rho, alpha, w, d, q, beta_res, cfg_.beta_base);
  if (q_gamma) {
    // Q = Q_k gamma / ref adds dF/dQ Q_k / ref to the gamma column; F = f [sin, cos](rho + delta
    // - alpha) with f linear in Q, so dF/dQ = N_Q [sin, cos] (N_Q is 0 where the FEE is invalid).
    at::NoGradGuard ng;
    const at::Tensor th = rho + delta.detach().unsqueeze(1) - alpha;
    const at::Tensor dFdQ = fee.N_Q.detach().unsqueeze(-1) * at::stack({at::sin(th), at::cos(th)}, -1);  // [B,P,2]
    J = J.clone();
    J.select(3, kSoilGamma).add_(dFdQ * (q_k / cfg_.q_gamma_ref_n_m3).unsqueeze(-1));
  }
  if (cfg_.edge_thickness_m > 0) {
    const at::Tensor feature = cfg_.gate_feature >= 0
                                   ? obs.to(at::kFloat).slice(1, cfg_.T - P, cfg_.T).select(2, cfg_.gate_feature)
                                   : at::Tensor();
    if (cfg_.gate_observed) {
      out.pen_gate = (feature < cfg_.gate_zero).to(at::kFloat);
    } else {
      at::Tensor logit = head_gate_(h);
      if (cfg_.gate_feature >= 0) logit = logit + gate_feature_w_ * feature;
      out.pen_gate = at::sigmoid(logit);
    }
    const PenetrationOut pen = penetrationForward(soil, w, d, out.pen_gate.to(at::kDouble), cfg_.edge_thickness_m);
    const at::Tensor zero = at::zeros_like(pen.Fz);
    out.F = out.F + at::stack({zero, at::where(fee.valid, pen.Fz, zero)}, -1);
    J = J + at::where(fee.valid.unsqueeze(-1).unsqueeze(-1), pen.J, at::zeros_like(pen.J));
  } else {
    out.pen_gate = at::zeros({B, P}, at::kFloat);
  }
  out.J = J;  // columns [c, phi, ca, delta, gamma, d(_res), beta(_res)] = LogVarCol
  const at::Tensor var = at::exp(out.log_var.to(at::kDouble)).reshape({B, 1, 1, kLogVarCount});
  out.Sigma_F = at::matmul(J * var, J.transpose(-2, -1));

  // Eq. 8's dN_gamma/dbeta term: gradient only into beta (through beta_res).
  const at::Tensor& v = fee.valid;
  auto perStep = [&](const at::Tensor& x) { return x.unsqueeze(1).expand({B, P}); };
  const at::Tensor phi_d = perStep(phi.detach()), delta_d = perStep(delta.detach());
  const at::Tensor beta_g = base.detach() + beta_res.unsqueeze(1);
  const at::Tensor dng = dNgammaDbeta(pick(v, phi_d, 0.5), pick(v, delta_d, 0.3), pick(v, alpha, 0.0),
                                      pick(v, rho, 1.2), pick(v, beta_g, 0.5));
  out.dNgamma_dbeta = at::where(v, dng, at::zeros_like(dng));
  return out;
}

soil::PinnMemberWeights PinnNetImpl::exportWeights() const {
  using RowMajor = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  auto mat = [](const at::Tensor& t) {
    const at::Tensor c = t.detach().to(at::kFloat).contiguous();
    return Eigen::MatrixXf(Eigen::Map<const RowMajor>(c.data_ptr<float>(), c.size(0), c.size(1)));
  };
  auto vec = [](const at::Tensor& t) {
    const at::Tensor c = t.detach().to(at::kFloat).contiguous();
    return Eigen::VectorXf(Eigen::Map<const Eigen::VectorXf>(c.data_ptr<float>(), c.numel()));
  };
  soil::PinnMemberWeights w;
  w.T = cfg_.T;
  w.P = cfg_.P;
  w.D_o = cfg_.D_o;
  w.beta_min = cfg_.beta_base == BetaBase::Min;
  for (const auto& m : encoder_->children())
    if (const auto* lin = m->as<torch::nn::Linear>()) {
      w.encoder_W.push_back(mat(lin->weight));
      w.encoder_b.push_back(vec(lin->bias));
    }
  w.theta_W = mat(head_theta_->weight);
  w.theta_b = vec(head_theta_->bias);
  w.logvar_W = mat(head_logvar_->weight);
  w.logvar_b = vec(head_logvar_->bias);
  w.res_W = mat(head_res_->weight);
  w.res_b = vec(head_res_->bias);
  w.fr_W = mat(head_fr_->weight);
  w.fr_b = vec(head_fr_->bias);
  w.theta_k_mean = vec(theta_mean_);
  w.theta_k_std = vec(theta_std_);
  for (int k = 0; k < kSoilCount; ++k) {
    w.soil_lo[static_cast<std::size_t>(k)] = static_cast<float>(kSoilRanges[k].lo);
    w.soil_span[static_cast<std::size_t>(k)] = static_cast<float>(kSoilRanges[k].hi - kSoilRanges[k].lo);
  }
  const at::Tensor off = logvar_offset_.contiguous();
  for (int k = 0; k < kLogVarCount; ++k) w.logvar_offset[static_cast<std::size_t>(k)] = off[k].item<float>();
  w.d_res_max_m = static_cast<float>(kDResMaxM);
  w.beta_res_max_rad = static_cast<float>(kBetaResMaxRad);
  w.force_res_scale_n = static_cast<float>(kForceResScaleN);
  w.edge_thickness_m = cfg_.edge_thickness_m;
  w.gate_observed = cfg_.gate_observed;
  w.gate_zero = static_cast<float>(cfg_.gate_zero);
  if (cfg_.edge_thickness_m > 0 && !cfg_.gate_observed) {
    w.gate_W = mat(head_gate_->weight);
    w.gate_b = vec(head_gate_->bias);
  }
  w.gate_feature = cfg_.gate_feature;
  w.q_gamma_ref_n_m3 = cfg_.q_gamma_ref_n_m3;
  if (cfg_.gate_feature >= 0 && !cfg_.gate_observed) w.gate_feature_w = gate_feature_w_.detach().to(at::kFloat).item<float>();
  return w;
}

std::string PinnNetImpl::metadataJson() const {
  nlohmann::json j;
  j["format"] = kFormat;
  j["version"] = kFormatVersion;
  j["config"] = configJson(cfg_);
  j["config_hash"] = configHash(cfg_);
  j["theta_k_columns"] = {"rho_rad", "alpha_rad", "w_m", "d_m", "q_n", "v_m_s"};
  j["theta_k_mean"] = toVector(theta_mean_);
  j["theta_k_std"] = toVector(theta_std_);
  return j.dump();
}

void saveArchiveAtomically(torch::serialize::OutputArchive& ar, const std::string& path, const std::string& what) {
  try {
    // Through a stream: torch names the archive's top folder after the file it writes, and the
    // temporary file's name holds the process id, so the same model saved twice differed.
    std::ostringstream os(std::ios::binary);
    ar.save_to(os);
    io::writeFileAtomically(path, os.str());
  } catch (const OutputError&) {
    throw;
  } catch (const std::exception& e) {
    throw OutputError(path + ": cannot write " + what + ": " + e.what());
  }
}

void savePinnTo(PinnNet& net, torch::serialize::OutputArchive& ar) {
  net->save(ar);
  ar.write(kMetadataKey, c10::IValue(net->metadataJson()));
}

void savePinn(PinnNet& net, const std::string& path) {
  torch::serialize::OutputArchive ar;
  savePinnTo(net, ar);
  saveArchiveAtomically(ar, path, "the soil_pinn model");
}

PinnNet loadPinn(const std::string& path) {
  torch::serialize::InputArchive ar;
  try {
    ar.load_from(path);
  } catch (const std::exception& e) {
    const std::string what = e.what();
    throw InputError(path + ": not a readable soil_pinn model: " + what.substr(0, what.find('\n')));
  }
  return loadPinnFrom(ar, path);
}

PinnNet loadPinnFrom(torch::serialize::InputArchive& ar, const std::string& path) {
  c10::IValue meta;
  if (!ar.try_read(kMetadataKey, meta) || !meta.isString())
    throw InputError(path + ": torch archive without soil_pinn metadata");
  PinnConfig cfg;
  try {
    const nlohmann::json j = nlohmann::json::parse(meta.toStringRef());
    if (j.at("format").get<std::string>() != kFormat) throw InputError(path + ": format is not " + kFormat);
    const int version = j.at("version").get<int>();
    if (version > kFormatVersion)
      throw InputError(path + ": soil_pinn model version " + std::to_string(version) + " is newer than this build (" +
                       std::to_string(kFormatVersion) + ")");
    const nlohmann::json& c = j.at("config");
    cfg.T = c.at("T").get<int>();
    cfg.P = c.at("P").get<int>();
    cfg.D_o = c.at("D_o").get<int>();
    cfg.hidden = c.at("hidden").get<std::vector<int>>();
    cfg.seed = c.at("seed").get<int64_t>();
    cfg.beta_base = version >= 2 ? parseBetaBase(c.at("beta_base").get<std::string>()) : BetaBase::Nominal;
    cfg.edge_thickness_m = version >= 3 ? c.at("edge_thickness_m").get<double>() : 0.0;
    cfg.gate_feature = version >= 4 ? c.at("gate_feature").get<int>() : -1;
    cfg.q_gamma_ref_n_m3 = version >= 5 ? c.at("q_gamma_ref_n_m3").get<double>() : 0.0;
    cfg.gate_observed = version >= 6 ? c.at("gate_observed").get<bool>() : false;
    cfg.gate_zero = version >= 6 ? c.at("gate_zero").get<double>() : 0.0;
    cfg.sliced_geometry = version >= 7 ? c.at("sliced_geometry").get<bool>() : false;
    if (configHash(cfg, version) != j.at("config_hash").get<std::string>())
      throw InputError(path + ": config_hash does not match the stored config");
  } catch (const nlohmann::json::exception& e) {
    throw InputError(path + ": bad soil_pinn metadata: " + e.what());
  } catch (const std::invalid_argument& e) {
    throw InputError(path + ": bad soil_pinn metadata: " + e.what());
  }
  PinnNet net(cfg);
  try {
    net->load(ar);
  } catch (const std::exception& e) {
    const std::string what = e.what();
    throw InputError(path + ": parameters do not fit the stored config: " + what.substr(0, what.find('\n')));
  }
  return net;
}

}  // namespace terramap::pinn
