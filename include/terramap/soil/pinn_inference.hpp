#pragma once
/// \file
/// The soil estimator's inference without libtorch: the trained ensemble's weights as Eigen
/// matrices, the physics layer from terramap::fee, the nullspace inflation (paper Eq. 7) with
/// Eigen's SVD. It computes what pinn::SoilEstimator::estimate() computes with libtorch
/// (plugins/soil_pinn/estimator.hpp), to float rounding, in a fraction of the time: libtorch
/// spends ~2 ms per member on per-op dispatch for tensors of a few dozen numbers
/// (plugins/soil_pinn/README.md, "Latency"). The soil_pinn plugin runs this; training and
/// `terramap eval-soil` keep the libtorch path.
///
/// Layouts and units as in pinn_sample.hpp: observations raw (normalised here with the
/// model's mean/std; a non-finite normalised feature becomes 0, the training mean), theta_k
/// [P x 6] raw [rho, alpha, w, d, Q, v] (rad, m, N, m/s); soil vectors in the estimator's order
/// [c (Pa), phi (rad), ca (Pa), delta (rad), gamma (N/m^3)]; forces in N, [along travel, up],
/// blade on soil.
///
/// Threading: estimate() is const and allocates only per call; one PinnInference may be used
/// by several threads at once. No exceptions from estimate() on finite or non-finite inputs
/// (invalid FEE steps are masked as in the libtorch path); the constructor throws
/// std::invalid_argument on inconsistent weights.
#include <Eigen/Core>

#include <array>
#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

namespace terramap::soil {

/// One member of the ensemble (a PinnNet), as plain arrays. Row-major semantics of a Linear
/// layer: y = W x + b with W [out x in].
struct PinnMemberWeights {
  int T = 0, P = 0, D_o = 0;
  bool beta_min = true;  ///< base failure angle beta* (true) or Rankine's pi/4 - phi/2 (false)
  std::vector<Eigen::MatrixXf> encoder_W;  ///< tanh after each layer
  std::vector<Eigen::VectorXf> encoder_b;
  Eigen::MatrixXf theta_W, logvar_W, res_W, fr_W;  ///< heads: 5, 7, 2, 2 outputs
  Eigen::VectorXf theta_b, logvar_b, res_b, fr_b;
  Eigen::VectorXf theta_k_mean, theta_k_std;       ///< [6] the encoder's theta_k normalisation
  std::array<float, 5> soil_lo{}, soil_span{};     ///< theta_u = lo + span sigmoid(z)
  std::array<float, 7> logvar_offset{};            ///< added to the log-variance head
  float d_res_max_m = 0, beta_res_max_rad = 0, force_res_scale_n = 0;
  /// Penetration term (fee::penetrationForce): edge thickness (m; 0 = none) and the gate head
  /// (P outputs, sigmoid: the probability the edge descended at each horizon step).
  double edge_thickness_m = 0;
  Eigen::MatrixXf gate_W;
  Eigen::VectorXf gate_b;
  /// The observation column whose normalised value at each horizon step adds gate_feature_w
  /// times itself to that step's gate logit (-1 = none).
  int gate_feature = -1;
  float gate_feature_w = 0;
  /// > 0: the surcharge is weighed with the estimated gamma, Q gamma / q_gamma_ref_n_m3
  /// (pinn::PinnConfig); 0 = Q as extracted.
  double q_gamma_ref_n_m3 = 0;
  /// true: the gate is 1 where the normalised gate_feature is below gate_zero, else 0 (no gate
  /// head; pinn::PinnConfig::gate_observed).
  bool gate_observed = false;
  float gate_zero = 0;
};

/// The one rule for the physics-layer options a model carries, for pinn::PinnConfig (a model
/// built or trained) and PinnInference (a model's weights loaded): "" when they are valid, else
/// what is wrong. gate_feature: -1 or an observation column (< D_o) of a model with the
/// penetration term (edge_thickness_m > 0); q_gamma_ref_n_m3: finite and >= 0 (0 = Q as extracted).
inline std::string pinnOptionsError(int gate_feature, int D_o, double edge_thickness_m, double q_gamma_ref_n_m3) {
  if (gate_feature >= D_o || gate_feature < -1 || (gate_feature >= 0 && !(edge_thickness_m > 0)))
    return "gate_feature must be -1 or an observation column (< D_o), and needs edge_thickness_m > 0";
  if (!(q_gamma_ref_n_m3 >= 0 && std::isfinite(q_gamma_ref_n_m3))) return "q_gamma_ref_n_m3 must be >= 0 (0 = Q as extracted)";
  return {};
}

/// How far a sample's inputs lie from the training samples', and what that adds to the
/// epistemic variance. The ensemble's members agree off the training distribution as much as on
/// it (they extrapolate alike: the held-out soil and blade pitch had 0.7-1.4 times the test
/// split's epistemic variance), so the spread alone cannot say "never seen". Like a Gaussian
/// process, whose variance returns to the prior's away from its data, a sample whose features lie
/// beyond the training samples' 99th percentile of Mahalanobis distance gets a share of each
/// property's prior variance (its physical range's, span^2 / 12) added to the spread:
/// share = 1 - exp(-(d^2 - q) / q) for d^2 > q, 0 within. The features (pinnInputFeatures): the
/// sweep geometry theta_k of the last horizon step and the observations averaged over the
/// history, both normalised as the network sees them.
struct PinnInputDistance {
  std::vector<double> mean;           ///< the training features' mean (n = 6 + D_o)
  std::vector<double> whiten;         ///< row-major n x n, L^-1 with L L^T the features' covariance
  double q = 0;                       ///< the training samples' 99th percentile of d^2
  std::array<double, 5> prior_var{};  ///< per property, parameter units squared
  bool empty() const { return mean.empty(); }
  /// Squared Mahalanobis distance of `f` (n values); NaN when empty or f's size differs.
  double d2(const std::vector<double>& f) const;
  /// The share of the prior variance added at d2 (0..1; 0 for NaN).
  double share(double d2) const;
  /// Sets e.input_d2 and e.input_share from the sample's features and adds the share of the
  /// prior variance to e.var_epistemic and e.var_total (nothing when empty).
  void applyTo(const std::vector<double>& features, struct PinnEstimate& e) const;
  /// From the training samples' features (each n long, n >= 1, at least n + 1 of them): mean,
  /// covariance (+ 1e-6 of its mean diagonal, so a constant feature does not make it singular),
  /// its Cholesky factor's inverse and the 99th percentile of the samples' d^2.
  /// \throws std::invalid_argument on too few or ragged features.
  static PinnInputDistance fit(const std::vector<std::vector<double>>& features, const std::array<double, 5>& prior_var);
};

/// The features PinnInputDistance measures, from one sample as PinnInference::estimate takes it
/// (the last T of T_stored observation rows, the last of P_stored theta_k rows): theta_k
/// normalised with theta_mean / theta_std [6], then each of the D_o observation features
/// normalised with obs_mean / obs_std and averaged over the T rows (non-finite: 0, the mean).
std::vector<double> pinnInputFeatures(const float* obs_raw, int T_stored, int T, int D_o, const float* obs_mean,
                                      const float* obs_std, const float* theta_k, int P_stored,
                                      const float* theta_mean, const float* theta_std);

/// What one estimate holds (the members' aggregate, as pinn::SoilEstimate documents).
struct PinnEstimate {
  std::array<double, 5> mean{}, var_aleatoric{}, var_nullspace{}, var_epistemic{}, var_total{};
  /// Squared Mahalanobis distance of the sample's inputs from the training samples'
  /// (PinnInputDistance; NaN for a model without the statistics). var_epistemic includes its
  /// term.
  double input_d2 = std::numeric_limits<double>::quiet_NaN();
  double input_share = 0;  ///< PinnInputDistance::share(input_d2): the prior variance's share added
  std::array<double, 2> F_r{};                  ///< N
  std::vector<std::array<double, 2>> F;         ///< predicted force per horizon step, N
  double d_res_m = 0, beta_res_rad = 0;
  double beta_rad = 0;                          ///< failure angle at the last horizon step, rad
  int valid_members = 0;
  bool valid = false;
};

struct PinnInferenceOptions {
  double a_tol = 1500.0, r_tol = 0.05;  ///< Eq. 7 tolerances (nullspace.hpp)
  std::array<double, 5> ambiguity_var{};  ///< diagonal Sigma_a, parameter units squared
};

class PinnInference {
 public:
  PinnInference() = default;
  /// \throws std::invalid_argument on an empty ensemble, members of different T/P/D_o or
  /// layer sizes that do not chain, or obs_mean/obs_std not D_o long (std > 0).
  PinnInference(std::vector<PinnMemberWeights> members, std::vector<float> obs_mean, std::vector<float> obs_std);

  /// The input-distance term of the epistemic variance (empty: none, the spread alone).
  void setInputDistance(PinnInputDistance d) { distance_ = std::move(d); }
  const PinnInputDistance& inputDistance() const { return distance_; }
  /// Adds that term to `e`, an estimate of the sample (obs_raw, theta_k) as estimate() takes it
  /// (the libtorch path's aggregate gets it here too, so both measure the same features).
  void applyInputDistance(const float* obs_raw, int T_stored, const float* theta_k, int P_stored, PinnEstimate& e) const;

  int T() const { return members_.front().T; }
  int P() const { return members_.front().P; }
  std::size_t size() const { return members_.size(); }

  /// One sample: obs_raw [T_stored x D_o] and theta_k [P_stored x 6], row-major; the last T
  /// and P rows are used. \pre T_stored >= T(), P_stored >= P() (else the result is invalid
  /// with valid_members 0).
  PinnEstimate estimate(const float* obs_raw, int T_stored, const float* theta_k, int P_stored,
                        const PinnInferenceOptions& opt) const;

 private:
  std::vector<PinnMemberWeights> members_;
  std::vector<float> obs_mean_, obs_std_;
  PinnInputDistance distance_;
};

}  // namespace terramap::soil
