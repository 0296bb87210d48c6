#pragma once
/// \file
/// The deployed soil estimator: a deep ensemble of PinnNet members (the epistemic uncertainty
/// the paper names as its open failure, ALGORITHMS.md §F) with the observation normalisation
/// they were trained with, in one model file.
///
/// Per sample it returns, in SoilCol order [c (Pa), phi (rad), ca (Pa), delta (rad), gamma (N/m^3)]:
///  - mean: the members' mean estimate;
///  - var_aleatoric: the members' mean predicted variance exp(S) (the paper's Σ_Θ);
///  - var_nullspace: max(var_aleatoric, diag Σ_n) with Σ_n of Eq. 7 per member, averaged;
///  - var_epistemic: the spread of the members' estimates (population variance);
///  - var_total = var_nullspace + var_epistemic (what the Bayesian layers fuse).
/// F^r, the predicted force and the failure angle are the members' means; `valid` is false when a majority of the
/// members found the FEE invalid at every horizon step (then the estimate must not be fused).
///
/// Threading: estimate() runs ATen on the calling thread; call at::set_num_threads(1) first
/// inside engine tasks (docs/plugins.md). One estimator must not be used by two threads at once.
/// Units as above; forces in N ([x along travel, z up], blade on soil).
#include "model.hpp"
#include "nullspace.hpp"

#include <terramap/soil/pinn_sample.hpp>

#include <array>
#include <string>
#include <vector>

namespace terramap::pinn {

/// One estimate (fields documented with soil::PinnEstimate; soil vectors in SoilCol order).
using SoilEstimate = soil::PinnEstimate;

class SoilEstimator {
 public:
  SoilEstimator() = default;
  /// `members` share one PinnConfig; obs_mean / obs_std [D_o] (std > 0).
  /// \throws std::invalid_argument on an empty ensemble, mixed configs or bad normalisation.
  SoilEstimator(std::vector<PinnNet> members, std::vector<float> obs_mean, std::vector<float> obs_std,
                std::string training_json = "{}");

  int T() const { return members_.front()->config().T; }
  int P() const { return members_.front()->config().P; }
  /// Whether theta_k must carry the cut's cross-section as one wedge (PinnConfig::
  /// sliced_geometry): the caller applies soil::applySlicedGeometry before estimate().
  bool slicedGeometry() const { return members_.front()->config().sliced_geometry; }
  std::size_t size() const { return members_.size(); }
  const std::vector<PinnNet>& members() const { return members_; }
  /// JSON with what made the model (training config, dataset hash, epochs): stored in the file.
  const std::string& trainingJson() const { return training_json_; }
  const std::vector<float>& obsMean() const { return obs_mean_; }
  const std::vector<float>& obsStd() const { return obs_std_; }

  /// Normalised observation tensor [B, T, D_o] from raw features (the last T steps of each
  /// sample's history; NaN features become 0, the training mean).
  at::Tensor normaliseObs(const float* raw, long batch, int T_stored) const;

  /// Estimates for a batch: obs_raw [B * T_stored * D_o] (row-major), theta_k [B * P_stored * 6];
  /// the last T and P steps are used. \throws std::invalid_argument if T_stored < T or
  /// P_stored < P.
  std::vector<SoilEstimate> estimate(const float* obs_raw, const float* theta_k, long batch, int T_stored,
                                     int P_stored, const NullspaceTolerances& tol = {}) const;
  /// One sample built by soil::buildSample with at least T history and P horizon steps.
  SoilEstimate estimate(const soil::PinnSample& s, const NullspaceTolerances& tol = {}) const;

  /// The same estimate without libtorch (terramap/soil/pinn_inference.hpp): equal to
  /// estimate() to float rounding of the encoder (tested), some 50x faster for one sample.
  /// What the plugin runs. Safe to call from several threads at once.
  SoilEstimate estimateFast(const soil::PinnSample& s, const NullspaceTolerances& tol = {}) const;
  const soil::PinnInference& inference() const { return fast_; }

  /// The input-distance term of the epistemic variance (soil::PinnInputDistance; empty: none),
  /// for both estimate() and estimateFast(). The trainer fits it on the training split.
  void setInputDistance(soil::PinnInputDistance d) { fast_.setInputDistance(std::move(d)); }
  const soil::PinnInputDistance& inputDistance() const { return fast_.inputDistance(); }

 private:
  std::vector<PinnNet> members_;
  std::vector<float> obs_mean_, obs_std_;
  std::string training_json_;
  soil::PinnInference fast_;
  std::array<double, kSoilCount> ambiguity_var_{};  ///< defaultAmbiguityVariance()
};

/// One file: a torch archive with a sub-archive per member (savePinnTo) and the key
/// "terramap_estimator" holding JSON {format "terramap.soil_estimator", version, members,
/// obs_mean, obs_std, obs_features, training, input_distance (version 2; absent: none)}.
/// Atomic (temp + rename). \throws OutputError.
void saveEstimator(const SoilEstimator& e, const std::string& path);
/// \throws InputError naming the file on anything that is not such a model (or a newer version,
/// or observation features other than this build's soil::obsFeatureNames()).
SoilEstimator loadEstimator(const std::string& path);

}  // namespace terramap::pinn
