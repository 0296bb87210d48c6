#pragma once
/// \file
/// The PINN soil estimator's network (paper §2.1, ALGORITHMS.md §F): an MLP encoder over the
/// observation history and the known FEE parameters, heads for the soil parameters, their
/// log-variances, the residuals d_res and beta_res and a residual force, and the FEE physics
/// layer (fee_torch.hpp) that turns them into a predicted force with a covariance.
///
/// Tensor layout (fixed; the training dataset produces exactly this):
///  - obs     [B,T,D_o] float32, already normalised by the caller.
///  - theta_k [B,P,6]   float32, RAW physical units, columns ThetaKCol: rho (rad), alpha (rad),
///            w (m), d (m), Q (N), v (m/s). The horizon is the last P steps of the T history.
///            The encoder sees (theta_k - mean) / std with per-column mean and std kept as
///            buffers ("theta_k_mean", "theta_k_std", default 0 and 1) that the caller sets
///            from dataset statistics with setThetaNormalisation(); they are saved with the model.
///  - soil vectors everywhere in SoilCol order [c (Pa), phi (rad), ca (Pa), delta (rad), gamma (N/m^3)].
/// Threading: forward() is ordinary libtorch; callers inside engine tasks set
/// at::set_num_threads(1) (docs/plugins.md). A module must not be used by two threads at once.
/// Determinism: the constructor seeds torch's global generator with PinnConfig::seed before
/// initialising the weights (libtorch's initialisers take no generator), so equal configs
/// give bit-identical initial weights, and then restores the generator's previous state
/// (construction, loadPinn() included, does not disturb the caller's random stream). Do not
/// construct while another thread draws from torch's global CPU generator.
#include "fee_torch.hpp"

#include <terramap/soil/pinn_inference.hpp>
#include <terramap/soil/soil_parameters.hpp>

#include <torch/nn/module.h>
#include <torch/nn/modules/container/sequential.h>
#include <torch/nn/modules/linear.h>
#include <torch/nn/pimpl.h>
#include <torch/serialize/archive.h>

#include <cstdint>
#include <string>
#include <vector>

namespace terramap::pinn {

/// Columns of theta_k.
enum ThetaKCol : int { kKRho = 0, kKAlpha, kKW, kKD, kKQ, kKV, kThetaKCount };

/// Columns of the log-variance output: the five soil parameters (SoilCol order), then the two
/// residuals.
enum LogVarCol : int { kLvDRes = kSoilCount, kLvBetaRes, kLogVarCount };

/// The ranges theta_u is squashed into by a sigmoid (theta = lo + (hi - lo) sigmoid(z)),
/// SoilCol order (= soil::SoilParam order); the range penalty of the loss uses the same table.
/// The one table is terramap::soil's (soil_parameters.hpp), shared with the soil layers.
using ParamRange = soil::SoilParamInfo;
inline constexpr const ParamRange (&kSoilRanges)[soil::kSoilParamCount] = soil::kSoilParams;
inline constexpr double kDeg = soil::kDegree;
/// d_res = kDResMaxM tanh(z) (m); beta_res = kBetaResMaxRad tanh(z) (rad).
inline constexpr double kDResMaxM = 0.05;
inline constexpr double kBetaResMaxRad = 0.2;
/// F_r = kForceResScaleN * z (N), so a unit network output is a force of the order of the
/// measured ones and F_r can act from the first step.
inline constexpr double kForceResScaleN = 1000.0;

/// Span of the parameter behind log-variance column k (hi - lo, or the residual's bound).
double logVarSpan(int k);
/// Allowed range of log-variance k: [2 ln(1e-3 span), 2 ln(span)], i.e. a standard deviation
/// between 0.1 % and 100 % of the parameter's span (used by the loss's range penalty).
double logVarLo(int k);
double logVarHi(int k);
/// Offset added to the raw log-variance output: 2 ln(0.1 span), so an untrained network
/// starts at a 10 % standard deviation instead of 1 in mixed units.
double logVarInit(int k);

struct PinnConfig {
  int T = 8;                     ///< history length (steps), >= P
  int P = 4;                     ///< prediction horizon (steps)
  int D_o = 1;                   ///< observation features per step
  std::vector<int> hidden{64, 64};  ///< encoder layer widths (tanh after each)
  int64_t seed = 0;              ///< weight initialisation seed
  /// Base failure angle of the physics layer (fee_torch.hpp). Model files of format version 1
  /// predate the key and load as Nominal.
  BetaBase beta_base = BetaBase::Min;
  /// Thickness of the cutting edge (m) for the penetration term of the physics layer: while
  /// the edge descends the soil bears on it with Terzaghi's strip capacity
  /// q_b = c N_c(phi) + gamma d N_q(phi) over t_e w, a vertical force the FEE does not hold
  /// (ALGORITHMS.md §J's truth force has it). The network gives, per horizon step, the
  /// probability g that the edge was descending (a sigmoid head; the observations say when,
  /// the soil says how much); F_z -= g q_b t_e w where the FEE is valid. 0 = no such term (and
  /// no head: model files of format version <= 2 load so).
  double edge_thickness_m = 0.0;
  /// An observation feature (index into obs' D_o columns; -1 = none) whose normalised value at
  /// each horizon step enters that step's gate logit with one learned weight
  /// ("pen_gate_feature_weight", initialised to -1): the edge's vertical speed in the map frame
  /// says directly whether it descends, which the encoder's tanh layers learned poorly from
  /// the flattened history. Needs edge_thickness_m > 0. Files of format version <= 3 load with -1.
  int gate_feature = -1;
  /// The unit weight (N/m^3) the sweep computed its surcharge Q with (blade_sweep's
  /// `unit_weight_n_m3`, 14636 by default); > 0 makes the physics layer weigh the pushed soil
  /// with the estimated gamma instead, Q gamma / q_gamma_ref_n_m3, so the surcharge term carries
  /// gamma too (the Jacobian's gamma column gains dF/dQ Q / ref). 0 = Q as extracted (the
  /// paper's). Files of format version <= 4 load with 0.
  double q_gamma_ref_n_m3 = 0.0;
  /// true: the penetration gate is the observation itself, not learned: 1 at the horizon steps
  /// whose gate_feature (the edge's vertical speed in the map frame) is below 0, 0 elsewhere, as
  /// the simulator switches its penetration resistance with the sign of that speed
  /// (docs/soil_estimator.md, "Where the error lives"). Needs gate_feature; no gate head.
  /// Files of format version <= 5 load with false.
  bool gate_observed = false;
  /// With gate_observed: the normalised value of a raw 0 of gate_feature, -mean / std of the
  /// training split's observations (the network sees normalised observations).
  double gate_zero = 0.0;
  /// true: theta_k's depth and width are the one wedge that holds the cut's cross-section
  /// (soil::applySlicedGeometry on the sample's profile), not the sweep's mean depth and cutting
  /// width. The network does not apply it itself: whoever builds theta_k for this model does
  /// (makeTrainingData, the soil_pinn stage; SoilEstimator::slicedGeometry() says so).
  /// Files of format version <= 6 load with false.
  bool sliced_geometry = false;
};

/// What forward() returns. B batch, P horizon.
struct PinnOutput {
  at::Tensor theta_u;   ///< [B,5] float32, soil estimate in physical units (SoilCol order)
  at::Tensor log_var;   ///< [B,7] float32, S: ln variances of theta_u, d_res (m^2), beta_res (rad^2)
  at::Tensor d_res;     ///< [B] float32, m
  at::Tensor beta_res;  ///< [B] float32, rad
  at::Tensor F_r;       ///< [B,2] float32, N, residual force (constant over the horizon)
  /// [B,P] float64, rad: failureAngle(config().beta_base, phi, delta, alpha_p, rho_p) + beta_res.
  at::Tensor beta;
  /// [B,P,2] float64, N: FEE(theta_u; rho, alpha, w, d + d_res, Q, beta) + F_r; only F_r where
  /// the FEE is invalid.
  at::Tensor F;
  at::Tensor valid;     ///< [B,P] bool, FEE validity (includes d + d_res > 0)
  /// [B,P,2,7] float64, detached: dF/d[theta_u, d_res, beta_res] (LogVarCol order), with the
  /// base angle's dependence on phi (and delta, for beta*) chained in; 0 where invalid.
  at::Tensor J;
  /// [B,P,2,2] float64, N^2: J diag(exp(S)) J^T (paper Eq. 6); differentiable w.r.t. S only.
  at::Tensor Sigma_F;
  /// [B,P] float64: dN_gamma/dbeta at beta with every other angle detached, so its gradient
  /// reaches beta_res only (Eq. 8's beta-arrow); 0 where invalid.
  at::Tensor dNgamma_dbeta;
  /// [B,P] float32: probability the edge was descending (penetration gate); zeros without the term.
  at::Tensor pen_gate;
};

class PinnNetImpl : public torch::nn::Module {
 public:
  /// \throws std::invalid_argument if T < P, P < 1, D_o < 1 or a hidden width < 1.
  explicit PinnNetImpl(PinnConfig cfg);

  /// obs [B,T,D_o], theta_k [B,P,6] (float32, other dtypes are cast).
  /// \throws std::invalid_argument on a shape that does not match the config.
  PinnOutput forward(const at::Tensor& obs, const at::Tensor& theta_k);

  /// Sets the theta_k input normalisation, mean and std [6] in theta_k units (std > 0).
  /// \throws std::invalid_argument otherwise.
  void setThetaNormalisation(const at::Tensor& mean, const at::Tensor& std);

  const PinnConfig& config() const { return cfg_; }
  /// The metadata stored with the model (see savePinn()).
  std::string metadataJson() const;

  /// The weights as plain arrays for the torch-free inference (terramap/soil/pinn_inference.hpp).
  soil::PinnMemberWeights exportWeights() const;

  /// The heads, exposed for tests and for freezing parts in training.
  torch::nn::Linear headTheta() const { return head_theta_; }
  torch::nn::Linear headLogVar() const { return head_logvar_; }

 private:
  PinnConfig cfg_;
  torch::nn::Sequential encoder_{nullptr};
  torch::nn::Linear head_theta_{nullptr}, head_logvar_{nullptr}, head_res_{nullptr}, head_fr_{nullptr};
  torch::nn::Linear head_gate_{nullptr};  ///< only with edge_thickness_m > 0
  at::Tensor gate_feature_w_;              ///< [1], only with gate_feature >= 0
  at::Tensor theta_mean_, theta_std_, logvar_offset_;
};
TORCH_MODULE(PinnNet);

/// Writes the model to `path` as one torch archive: the module's parameters and buffers plus
/// a key "terramap_metadata" holding JSON {format "terramap.soil_pinn", version, config,
/// theta_k normalisation, config_hash}. Written to path + ".tmp" and renamed, so a reader
/// never sees a partial file.
/// \throws terramap::OutputError if the file cannot be written.
void savePinn(PinnNet& net, const std::string& path);

/// Reads a file written by savePinn(): rebuilds the network from the stored config and loads
/// its parameters and buffers.
/// \throws terramap::InputError on a missing/unreadable file, a foreign format, a newer
/// version or a config hash that does not match the stored config.
PinnNet loadPinn(const std::string& path);

/// Writes `ar` to `path` through io::replaceFileAtomically (temp file, fsync, rename), so a
/// reader never sees a partial file. `what` names the content in messages. \throws OutputError.
void saveArchiveAtomically(torch::serialize::OutputArchive& ar, const std::string& path, const std::string& what);
/// The same into / out of an archive the caller owns (e.g. one member of an ensemble file).
/// `path` only names the file in messages. \throws as loadPinn().
void savePinnTo(PinnNet& net, torch::serialize::OutputArchive& ar);
PinnNet loadPinnFrom(torch::serialize::InputArchive& ar, const std::string& path);

/// FNV-1a 64 of the config's canonical JSON, as 16 hex digits. `format_version` 1 hashes the
/// JSON without beta_base (the files written before it existed), 2 without edge_thickness_m,
/// 3 without gate_feature, 4 without q_gamma_ref_n_m3, 5 without gate_observed and gate_zero,
/// 6 without sliced_geometry. The default is the version this build writes.
std::string configHash(const PinnConfig& cfg, int format_version = 7);

}  // namespace terramap::pinn
