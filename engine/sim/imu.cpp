// Simulated IMU: central differences of the link's true poses, white noise, random-walk biases.
#include <terramap/sim/imu.hpp>

#include <cmath>

namespace terramap::sim {
namespace {

constexpr double kGravity = 9.80665;

/// Rotation vector of R (axis * angle), in R's own frame.
Eigen::Vector3d rotationVector(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.axis() * aa.angle();
}

}  // namespace

ImuModel::ImuModel(const SensorSpec& spec, std::string frame, std::uint64_t seed)
    : spec_(spec), frame_(std::move(frame)), rng_(seed) {
  for (int a = 0; a < 3; ++a) ba_[a] = spec_.accel_bias_sigma * normal_(rng_);
  for (int a = 0; a < 3; ++a) bg_[a] = spec_.gyro_bias_sigma * normal_(rng_);
}

bool ImuModel::addLinkPose(double t, const Eigen::Isometry3d& T_map_link, ImuSample& out, ImuTruth* truth) {
  T_[0] = T_[1];
  T_[1] = T_[2];
  T_[2] = T_map_link * spec_.T_base_sensor;  // T_base_sensor is the IMU's mount on its link
  t_[0] = t_[1];
  t_[1] = t_[2];
  t_[2] = t;
  if (++n_ < 3) return false;
  const double dt = 1.0 / spec_.rate_hz;
  const Eigen::Matrix3d& R = T_[1].linear();
  const Eigen::Vector3d a_map =
      (T_[2].translation() - 2.0 * T_[1].translation() + T_[0].translation()) / (dt * dt);
  const Eigen::Vector3d f = R.transpose() * (a_map + Eigen::Vector3d(0, 0, kGravity));
  const Eigen::Vector3d w = (rotationVector(T_[0].linear().transpose() * R) +
                             rotationVector(R.transpose() * T_[2].linear())) /
                            (2.0 * dt);
  // Biases walk once per sample, then the white noise of this sample.
  const double sa = spec_.accel_noise_density * std::sqrt(spec_.rate_hz);
  const double sg = spec_.gyro_noise_density * std::sqrt(spec_.rate_hz);
  const double wa = spec_.accel_bias_walk * std::sqrt(dt), wg = spec_.gyro_bias_walk * std::sqrt(dt);
  for (int a = 0; a < 3; ++a) ba_[a] += wa * normal_(rng_);
  for (int a = 0; a < 3; ++a) bg_[a] += wg * normal_(rng_);
  out.stamp = t_[1];
  out.frame = frame_;
  for (int a = 0; a < 3; ++a) out.accel_mps2[a] = f[a] + ba_[a] + sa * normal_(rng_);
  for (int a = 0; a < 3; ++a) out.gyro_radps[a] = w[a] + bg_[a] + sg * normal_(rng_);
  if (truth) {
    truth->stamp = t_[1];
    truth->specific_force = f;
    truth->angular_rate = w;
    truth->accel_bias = ba_;
    truth->gyro_bias = bg_;
  }
  return true;
}

}  // namespace terramap::sim
