// The soil estimator's inference with Eigen and terramap::fee (pinn_inference.hpp): the same
// arithmetic as PinnNet::forward + SoilEstimator::estimate in plugins/soil_pinn, member by member.
#include <terramap/soil/pinn_inference.hpp>

#include <terramap/soil/fee.hpp>

#include <Eigen/Cholesky>
#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace terramap::soil {
namespace {

constexpr int kSoil = 5;
constexpr int kThetaKCols = 6;

/// One member's outputs for one sample.
struct MemberOut {
  Eigen::Matrix<double, kSoil, 1> theta, var_a, var_n;
  double d_res = 0, beta_res = 0, beta_last = 0;
  Eigen::Vector2d F_r = Eigen::Vector2d::Zero();
  std::vector<Eigen::Vector2d> F;
  bool any_valid = false;
};

float sigmoid(float z) { return 1.0f / (1.0f + std::exp(-z)); }

/// fee::Soil from the estimator's order [c, phi, ca, delta, gamma].
fee::Soil toSoil(const Eigen::Matrix<double, kSoil, 1>& t) {
  fee::Soil s;
  s.c_pa = t[0];
  s.phi_rad = t[1];
  s.ca_pa = t[2];
  s.delta_rad = t[3];
  s.gamma_n_m3 = t[4];
  return s;
}

MemberOut runMember(const PinnMemberWeights& m, const Eigen::VectorXf& obs_flat, const float* theta_k,
                    const PinnInferenceOptions& opt) {
  const int P = m.P;
  Eigen::VectorXf x(obs_flat.size() + P * kThetaKCols);
  x.head(obs_flat.size()) = obs_flat;
  for (int p = 0; p < P; ++p)
    for (int k = 0; k < kThetaKCols; ++k)
      x[obs_flat.size() + p * kThetaKCols + k] = (theta_k[p * kThetaKCols + k] - m.theta_k_mean[k]) / m.theta_k_std[k];
  for (std::size_t l = 0; l < m.encoder_W.size(); ++l) x = (m.encoder_W[l] * x + m.encoder_b[l]).array().tanh().matrix();

  MemberOut o;
  const Eigen::VectorXf zt = m.theta_W * x + m.theta_b;
  const Eigen::VectorXf lv = m.logvar_W * x + m.logvar_b;
  const Eigen::VectorXf zr = m.res_W * x + m.res_b;
  const Eigen::VectorXf zf = m.fr_W * x + m.fr_b;
  for (int k = 0; k < kSoil; ++k) {
    o.theta[k] = static_cast<double>(m.soil_lo[k] + m.soil_span[k] * sigmoid(zt[k]));
    o.var_a[k] = std::exp(static_cast<double>(lv[k] + m.logvar_offset[k]));
  }
  o.d_res = static_cast<double>(m.d_res_max_m * std::tanh(zr[0]));
  o.beta_res = static_cast<double>(m.beta_res_max_rad * std::tanh(zr[1]));
  o.F_r = Eigen::Vector2d(m.force_res_scale_n * zf[0], m.force_res_scale_n * zf[1]);
  Eigen::VectorXf gate;
  if (m.edge_thickness_m > 0 && m.gate_observed) {
    gate.resize(P);
    for (int p = 0; p < P; ++p)
      gate[p] = obs_flat[static_cast<Eigen::Index>(m.T - P + p) * m.D_o + m.gate_feature] < m.gate_zero ? 1.0f : 0.0f;
  } else if (m.edge_thickness_m > 0) {
    gate = m.gate_W * x + m.gate_b;
    if (m.gate_feature >= 0)
      for (int p = 0; p < P; ++p)
        gate[p] += m.gate_feature_w * obs_flat[static_cast<Eigen::Index>(m.T - P + p) * m.D_o + m.gate_feature];
    gate = gate.unaryExpr([](float z) { return sigmoid(z); });
  }

  // Physics layer per horizon step, in double.
  const fee::Soil s = toSoil(o.theta);
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(2 * P, kSoil);
  o.F.resize(static_cast<std::size_t>(P));
  for (int p = 0; p < P; ++p) {
    const float* k = theta_k + p * kThetaKCols;
    fee::Geometry g;
    g.rho_rad = k[0];
    g.alpha_rad = k[1];
    g.w_m = k[2];
    g.d_m = static_cast<double>(k[3]) + o.d_res;
    g.q_n = m.q_gamma_ref_n_m3 > 0 ? k[4] * s.gamma_n_m3 / m.q_gamma_ref_n_m3 : k[4];
    double base = std::nan("");
    Eigen::Vector2d dbase(-0.5, 0.0);  // d base / d (phi, delta) of Rankine's angle
    if (m.beta_min) {
      base = fee::betaMin(s, g);
      if (std::isfinite(base)) dbase = fee::betaMinGradient(s, g);
    }
    if (!std::isfinite(base)) base = fee::betaNominal(s);
    const double beta = base + o.beta_res;
    if (p == P - 1) o.beta_last = beta;
    Eigen::Vector2d F = o.F_r;
    if (fee::check(s, g, beta) == fee::Validity::Valid) {
      o.any_valid = true;
      F += fee::evaluate(s, g, beta).F_N;
      const fee::Jacobian Jf = fee::jacobianF(s, g, beta);
      J.block<2, 1>(2 * p, 0) = Jf.col(fee::kC);
      J.block<2, 1>(2 * p, 1) = Jf.col(fee::kPhi) + dbase[0] * Jf.col(fee::kBeta);
      J.block<2, 1>(2 * p, 2) = Jf.col(fee::kCa);
      J.block<2, 1>(2 * p, 3) = Jf.col(fee::kDelta) + dbase[1] * Jf.col(fee::kBeta);
      J.block<2, 1>(2 * p, 4) = Jf.col(fee::kGamma);
      if (m.q_gamma_ref_n_m3 > 0) J.block<2, 1>(2 * p, 4) += Jf.col(fee::kQ) * (k[4] / m.q_gamma_ref_n_m3);
      if (m.edge_thickness_m > 0) {
        const double gp = static_cast<double>(gate[p]);
        const fee::Penetration pen = fee::penetration(s, g.d_m, g.w_m, m.edge_thickness_m);
        F.y() -= gp * pen.force_n;
        const Eigen::Vector4d& dp = pen.gradient;
        J(2 * p + 1, 0) -= gp * dp[0];
        J(2 * p + 1, 1) -= gp * dp[1];
        J(2 * p + 1, 4) -= gp * dp[2];
      }
    }
    o.F[static_cast<std::size_t>(p)] = F;
  }

  // Eq. 7: diag((I - V_k V_k^T) Sigma_a) with the singular directions kept by the tolerances.
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(J, Eigen::ComputeThinV);
  const Eigen::VectorXd& sv = svd.singularValues();
  const double cutoff = std::max(opt.r_tol * (sv.size() > 0 ? sv.maxCoeff() : 0.0), opt.a_tol);
  Eigen::Matrix<double, kSoil, 1> kept_sq = Eigen::Matrix<double, kSoil, 1>::Zero();
  for (int j = 0; j < sv.size(); ++j)
    if (sv[j] > cutoff) kept_sq += svd.matrixV().col(j).cwiseAbs2();
  for (int k = 0; k < kSoil; ++k) o.var_n[k] = std::max(o.var_a[k], (1.0 - kept_sq[k]) * opt.ambiguity_var[static_cast<std::size_t>(k)]);
  return o;
}

}  // namespace

PinnInference::PinnInference(std::vector<PinnMemberWeights> members, std::vector<float> obs_mean,
                             std::vector<float> obs_std)
    : members_(std::move(members)), obs_mean_(std::move(obs_mean)), obs_std_(std::move(obs_std)) {
  if (members_.empty()) throw std::invalid_argument("PinnInference: empty ensemble");
  const PinnMemberWeights& m0 = members_.front();
  for (const PinnMemberWeights& m : members_) {
    if (m.T != m0.T || m.P != m0.P || m.D_o != m0.D_o || m.P < 1 || m.T < m.P || m.D_o < 1)
      throw std::invalid_argument("PinnInference: members differ in T, P or D_o, or 1 <= P <= T fails");
    if (m.encoder_W.size() != m.encoder_b.size())
      throw std::invalid_argument("PinnInference: encoder weights and biases differ in count");
    Eigen::Index width = static_cast<Eigen::Index>(m.T) * m.D_o + static_cast<Eigen::Index>(m.P) * kThetaKCols;
    for (std::size_t l = 0; l < m.encoder_W.size(); ++l) {
      if (m.encoder_W[l].cols() != width || m.encoder_b[l].size() != m.encoder_W[l].rows())
        throw std::invalid_argument("PinnInference: encoder layer " + std::to_string(l) + " does not chain");
      width = m.encoder_W[l].rows();
    }
    auto head = [&](const Eigen::MatrixXf& W, const Eigen::VectorXf& b, Eigen::Index out, const char* name) {
      if (W.cols() != width || W.rows() != out || b.size() != out)
        throw std::invalid_argument(std::string("PinnInference: head ") + name + " has the wrong shape");
    };
    head(m.theta_W, m.theta_b, kSoil, "theta");
    head(m.logvar_W, m.logvar_b, 7, "log_var");
    head(m.res_W, m.res_b, 2, "res");
    head(m.fr_W, m.fr_b, 2, "force_res");
    if (m.edge_thickness_m > 0 && !m.gate_observed) head(m.gate_W, m.gate_b, m.P, "pen_gate");
    if (m.gate_observed && m.gate_feature < 0)
      throw std::invalid_argument("PinnInference: an observed gate needs gate_feature");
    const std::string options = pinnOptionsError(m.gate_feature, m.D_o, m.edge_thickness_m, m.q_gamma_ref_n_m3);
    if (!options.empty()) throw std::invalid_argument("PinnInference: " + options);
    if (m.theta_k_mean.size() != kThetaKCols || m.theta_k_std.size() != kThetaKCols)
      throw std::invalid_argument("PinnInference: theta_k normalisation needs 6 values");
  }
  if (obs_mean_.size() != static_cast<std::size_t>(m0.D_o) || obs_std_.size() != obs_mean_.size())
    throw std::invalid_argument("PinnInference: observation normalisation must have D_o entries");
  for (float s : obs_std_)
    if (!(s > 0) || !std::isfinite(s)) throw std::invalid_argument("PinnInference: observation std must be > 0");
}

double PinnInputDistance::d2(const std::vector<double>& f) const {
  const std::size_t n = mean.size();
  if (n == 0 || f.size() != n || whiten.size() != n * n) return std::numeric_limits<double>::quiet_NaN();
  double s = 0;
  for (std::size_t r = 0; r < n; ++r) {
    double z = 0;
    for (std::size_t c = 0; c <= r; ++c) z += whiten[r * n + c] * (f[c] - mean[c]);  // lower triangular
    s += z * z;
  }
  return s;
}

double PinnInputDistance::share(double d2v) const {
  if (!(d2v > q) || !(q > 0)) return 0.0;
  return 1.0 - std::exp(-(d2v - q) / q);
}

void PinnInputDistance::applyTo(const std::vector<double>& features, PinnEstimate& e) const {
  if (empty()) return;
  e.input_d2 = d2(features);
  e.input_share = share(e.input_d2);
  for (std::size_t k = 0; k < e.var_epistemic.size(); ++k) {
    e.var_epistemic[k] += e.input_share * prior_var[k];
    e.var_total[k] = e.var_nullspace[k] + e.var_epistemic[k];
  }
}

PinnInputDistance PinnInputDistance::fit(const std::vector<std::vector<double>>& features,
                                         const std::array<double, 5>& prior_var) {
  if (features.empty() || features.front().empty())
    throw std::invalid_argument("PinnInputDistance::fit: no features");
  const std::size_t n = features.front().size();
  if (features.size() < n + 1) throw std::invalid_argument("PinnInputDistance::fit: fewer samples than features + 1");
  Eigen::VectorXd mu = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(n));
  for (const auto& f : features) {
    if (f.size() != n) throw std::invalid_argument("PinnInputDistance::fit: ragged features");
    mu += Eigen::Map<const Eigen::VectorXd>(f.data(), static_cast<Eigen::Index>(n));
  }
  mu /= static_cast<double>(features.size());
  Eigen::MatrixXd C = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(n), static_cast<Eigen::Index>(n));
  for (const auto& f : features) {
    const Eigen::VectorXd d = Eigen::Map<const Eigen::VectorXd>(f.data(), static_cast<Eigen::Index>(n)) - mu;
    C.noalias() += d * d.transpose();
  }
  C /= static_cast<double>(features.size() - 1);
  C.diagonal().array() += 1e-6 * std::max(C.diagonal().mean(), 1e-12);
  const Eigen::LLT<Eigen::MatrixXd> llt(C);
  if (llt.info() != Eigen::Success) throw std::invalid_argument("PinnInputDistance::fit: covariance not positive definite");
  const Eigen::MatrixXd W = llt.matrixL().solve(Eigen::MatrixXd::Identity(C.rows(), C.cols()));
  PinnInputDistance out;
  out.prior_var = prior_var;
  out.mean.assign(mu.data(), mu.data() + n);
  out.whiten.resize(n * n);
  for (std::size_t r = 0; r < n; ++r)
    for (std::size_t c = 0; c < n; ++c)
      out.whiten[r * n + c] = c <= r ? W(static_cast<Eigen::Index>(r), static_cast<Eigen::Index>(c)) : 0.0;
  std::vector<double> d2s;
  d2s.reserve(features.size());
  for (const auto& f : features) d2s.push_back(out.d2(f));
  // The 99th percentile (nearest rank).
  const std::size_t k = std::min(d2s.size() - 1, static_cast<std::size_t>(std::ceil(0.99 * static_cast<double>(d2s.size()))) - 1);
  std::nth_element(d2s.begin(), d2s.begin() + static_cast<std::ptrdiff_t>(k), d2s.end());
  out.q = d2s[k];
  return out;
}

std::vector<double> pinnInputFeatures(const float* obs_raw, int T_stored, int T, int D_o, const float* obs_mean,
                                      const float* obs_std, const float* theta_k, int P_stored,
                                      const float* theta_mean, const float* theta_std) {
  std::vector<double> f(static_cast<std::size_t>(kThetaKCols + D_o), 0.0);
  const float* tk = theta_k + static_cast<std::ptrdiff_t>(P_stored - 1) * kThetaKCols;
  for (int k = 0; k < kThetaKCols; ++k) {
    const float z = (tk[k] - theta_mean[k]) / theta_std[k];
    f[static_cast<std::size_t>(k)] = std::isfinite(z) ? z : 0.0f;
  }
  for (int t = T_stored - T; t < T_stored; ++t)
    for (int k = 0; k < D_o; ++k) {
      const float z = (obs_raw[t * D_o + k] - obs_mean[k]) / obs_std[k];
      f[static_cast<std::size_t>(kThetaKCols + k)] += std::isfinite(z) ? z : 0.0f;
    }
  for (int k = 0; k < D_o; ++k) f[static_cast<std::size_t>(kThetaKCols + k)] /= T;
  return f;
}

void PinnInference::applyInputDistance(const float* obs_raw, int T_stored, const float* theta_k, int P_stored,
                                       PinnEstimate& e) const {
  if (distance_.empty()) return;
  // Every member was trained with the same theta_k normalisation.
  const PinnMemberWeights& m0 = members_.front();
  distance_.applyTo(pinnInputFeatures(obs_raw, T_stored, T(), m0.D_o, obs_mean_.data(), obs_std_.data(), theta_k,
                                      P_stored, m0.theta_k_mean.data(), m0.theta_k_std.data()),
                    e);
}

PinnEstimate PinnInference::estimate(const float* obs_raw, int T_stored, const float* theta_k, int P_stored,
                                     const PinnInferenceOptions& opt) const {
  PinnEstimate e;
  const int T = this->T(), P = this->P(), D = members_.front().D_o;
  if (T_stored < T || P_stored < P) return e;
  Eigen::VectorXf obs(static_cast<Eigen::Index>(T) * D);
  for (int t = 0; t < T; ++t)
    for (int k = 0; k < D; ++k) {
      const float raw = obs_raw[(T_stored - T + t) * D + k];
      const float z = (raw - obs_mean_[static_cast<std::size_t>(k)]) / obs_std_[static_cast<std::size_t>(k)];
      obs[t * D + k] = std::isfinite(z) ? z : 0.0f;
    }
  const float* tk = theta_k + static_cast<std::ptrdiff_t>(P_stored - P) * kThetaKCols;
  const double M = static_cast<double>(members_.size());
  Eigen::Matrix<double, kSoil, 1> mean = Eigen::Matrix<double, kSoil, 1>::Zero(), sq = mean, va = mean, vn = mean;
  Eigen::Vector2d fr = Eigen::Vector2d::Zero();
  std::vector<Eigen::Vector2d> F(static_cast<std::size_t>(P), Eigen::Vector2d::Zero());
  std::vector<Eigen::Matrix<double, kSoil, 1>> thetas;
  for (const PinnMemberWeights& m : members_) {
    const MemberOut o = runMember(m, obs, tk, opt);
    mean += o.theta;
    thetas.push_back(o.theta);
    va += o.var_a;
    vn += o.var_n;
    fr += o.F_r;
    for (int p = 0; p < P; ++p) F[static_cast<std::size_t>(p)] += o.F[static_cast<std::size_t>(p)];
    e.d_res_m += o.d_res;
    e.beta_res_rad += o.beta_res;
    e.beta_rad += o.beta_last;
    e.valid_members += o.any_valid ? 1 : 0;
  }
  mean /= M;
  for (const auto& t : thetas) sq += (t - mean).cwiseAbs2();
  for (int k = 0; k < kSoil; ++k) {
    const std::size_t ku = static_cast<std::size_t>(k);
    e.mean[ku] = mean[k];
    e.var_aleatoric[ku] = va[k] / M;
    e.var_nullspace[ku] = vn[k] / M;
    e.var_epistemic[ku] = sq[k] / M;  // population variance, as the libtorch path
    e.var_total[ku] = e.var_nullspace[ku] + e.var_epistemic[ku];
  }
  applyInputDistance(obs_raw, T_stored, theta_k, P_stored, e);
  e.F_r = {fr.x() / M, fr.y() / M};
  for (const auto& f : F) e.F.push_back({f.x() / M, f.y() / M});
  e.d_res_m /= M;
  e.beta_res_rad /= M;
  e.beta_rad /= M;
  e.valid = 2 * e.valid_members > static_cast<int>(members_.size());
  return e;
}

}  // namespace terramap::soil
