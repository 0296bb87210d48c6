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
};

/// What one estimate holds (the members' aggregate, as pinn::SoilEstimate documents).
struct PinnEstimate {
  std::array<double, 5> mean{}, var_aleatoric{}, var_nullspace{}, var_epistemic{}, var_total{};
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
};

}  // namespace terramap::soil
