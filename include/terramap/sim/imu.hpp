#pragma once
/// \file
/// A simulated IMU (SensorSpec::Type::Imu): specific force and angular rate of a rigid link,
/// from the link's true poses sampled at the IMU rate, with white noise and random-walk biases.
///
/// Kinematics: the sample at t_k comes from the poses at t_{k-1}, t_k, t_{k+1} (central
/// differences): acceleration (p_{k+1} - 2 p_k + p_{k-1}) / dt^2 (exact for constant acceleration),
/// angular rate the mean of the body-frame rotation vectors of R_{k-1}^T R_k and R_k^T R_{k+1}
/// over 2 dt (exact for a constant body rate). So a sample is known one period after its instant.
/// Specific force f = R_k^T (a - g), g = (0, 0, -9.80665) m/s^2 (map z up).
///
/// Noise (continuous-time densities, as Kalibr and IEEE Std 952 state them): per sample white
/// noise sigma_d = density * sqrt(rate); biases start at N(0, bias_sigma^2) per axis and walk by
/// N(0, (walk * sqrt(dt))^2) per sample. Deterministic for a seed; not thread-safe.
#include <terramap/core/events.hpp>
#include <terramap/sim/scenario.hpp>

#include <Eigen/Geometry>
#include <cstdint>
#include <random>

namespace terramap::sim {

/// What the IMU would read without noise and bias, and the biases it had (for evaluation).
struct ImuTruth {
  double stamp = 0;
  Eigen::Vector3d specific_force = Eigen::Vector3d::Zero();  ///< m/s^2, IMU frame
  Eigen::Vector3d angular_rate = Eigen::Vector3d::Zero();    ///< rad/s, IMU frame
  Eigen::Vector3d accel_bias = Eigen::Vector3d::Zero();      ///< m/s^2
  Eigen::Vector3d gyro_bias = Eigen::Vector3d::Zero();       ///< rad/s
};

class ImuModel {
 public:
  /// `spec` must be of type Imu with rate_hz > 0; `frame` names the samples ("<machine>/<id>").
  ImuModel(const SensorSpec& spec, std::string frame, std::uint64_t seed);

  /// The link's true pose at t = k / rate_hz (k = 0, 1, ... without gaps; the caller samples at
  /// the rate). From the third pose on, returns true and fills the sample of the previous
  /// instant (and its truth, when non-null).
  bool addLinkPose(double t, const Eigen::Isometry3d& T_map_link, ImuSample& out, ImuTruth* truth = nullptr);

  const SensorSpec& spec() const { return spec_; }

 private:
  SensorSpec spec_;
  std::string frame_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  Eigen::Vector3d ba_, bg_;
  Eigen::Isometry3d T_[3];
  double t_[3] = {0, 0, 0};
  int n_ = 0;
};

}  // namespace terramap::sim
