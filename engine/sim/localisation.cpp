#include <terramap/sim/localisation.hpp>

#include <cmath>
#include <stdexcept>
#include <string>

namespace terramap::sim {

namespace {
constexpr double kDeg = M_PI / 180.0;

void checkSigma(double v, const char* what) {
  if (!(v >= 0.0) || !std::isfinite(v)) throw std::invalid_argument(std::string("localisation: ") + what + " must be >= 0 and finite");
}
}  // namespace

LocalisationSpec LocalisationSpec::none() {
  LocalisationSpec s;
  s.perfect = true;
  return s;
}

LocalisationSpec LocalisationSpec::rtkImu() {
  LocalisationSpec s;
  // RTK fixed solution fused with an IMU: about 1 cm horizontal and 2 cm vertical RMS in all,
  // most of it slow (multipath, atmospheric residuals: a bias and a drift over a run); the
  // epoch-to-epoch (white) part of the fused output is a few millimetres.
  s.position = {AxisError{0.003, 0.007, 0.001}, AxisError{0.003, 0.007, 0.001}, AxisError{0.005, 0.015, 0.0015}};
  // MEMS IMU roll/pitch ~0.05 deg; dual-antenna heading ~0.2 deg over a ~1.5 m baseline.
  s.attitude = {AxisError{0.05 * kDeg, 0.03 * kDeg, 0.005 * kDeg}, AxisError{0.05 * kDeg, 0.03 * kDeg, 0.005 * kDeg},
                AxisError{0.20 * kDeg, 0.10 * kDeg, 0.02 * kDeg}};
  // Time-tagged output interpolated to each scan's and pose's instant: what remains is the clock
  // synchronisation between the receiver and the other sensors (PPS / PTP: about a millisecond).
  s.latency_s = 0.002;
  s.cylinder_white_m = 0.0005;
  s.cylinder_bias_m = 0.001;
  // Velocities from the RTK/INS solution (a few cm/s) and body rates from the IMU's gyros
  // (hundredths of a degree per second after the observation period's averaging).
  s.velocity_white_mps = 0.02;
  s.angular_rate_white_radps = 0.05 * kDeg;
  return s;
}

PoseEstimator::PoseEstimator(const LocalisationSpec& spec, std::uint64_t seed)
    : spec_(spec), rng_(seed), twist_rng_(seed ^ 0x5851f42d4c957f2dULL) {
  if (!(spec.latency_s >= 0.0) || !std::isfinite(spec.latency_s))
    throw std::invalid_argument("localisation: latency_s must be >= 0 and finite");
  for (int k = 0; k < 3; ++k) {
    for (const AxisError* a : {&spec.position[k], &spec.attitude[k]}) {
      checkSigma(a->white, "white");
      checkSigma(a->bias, "bias");
      checkSigma(a->random_walk, "random_walk");
    }
  }
  if (!(spec.drift_time_constant_s > 0.0))
    throw std::invalid_argument("localisation: drift_time_constant_s must be > 0 (infinity: a random walk)");
  checkSigma(spec.cylinder_white_m, "cylinder_white_m");
  checkSigma(spec.cylinder_bias_m, "cylinder_bias_m");
  checkSigma(spec.velocity_white_mps, "velocity_white_mps");
  checkSigma(spec.angular_rate_white_radps, "angular_rate_white_radps");
  if (spec.perfect) return;
  for (int k = 0; k < 3; ++k) {
    bias_[k] = normal_(rng_) * spec.position[k].bias;
    bias_[3 + k] = normal_(rng_) * spec.attitude[k].bias;
  }
  for (double& b : cylinder_bias_) b = normal_(rng_) * spec.cylinder_bias_m;
}

void PoseEstimator::addTruth(double t, const Eigen::Isometry3d& T) {
  if (!history_.empty() && t < history_.back().t)
    throw std::invalid_argument("localisation: truths must come in time order");
  if (!history_.empty() && t == history_.back().t) history_.pop_back();
  history_.push_back(Sample{t, T, T.translation(), Eigen::Quaterniond(T.linear())});
  // Keep what a delayed look-up can still reach: everything after the first sample older
  // than newest - latency.
  while (history_.size() > 2 && history_[1].t <= t - spec_.latency_s) history_.pop_front();
}

Eigen::Isometry3d PoseEstimator::truthAt(double td) const {
  auto pose = [](const Eigen::Vector3d& p, const Eigen::Quaterniond& q) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = q.toRotationMatrix();
    T.translation() = p;
    return T;
  };
  // A look-up at a sample's own time (or outside the span) returns that sample untouched, so
  // the perfect estimator is the truth bit for bit (the quaternion round trip is not).
  if (td <= history_.front().t) return history_.front().T;
  if (td >= history_.back().t) return history_.back().T;
  std::size_t k = 0;
  while (history_[k + 1].t <= td) ++k;  // history_[k].t <= td < history_[k + 1].t
  const Sample &a = history_[k], &b = history_[k + 1];
  if (td == a.t) return a.T;
  const double u = (td - a.t) / (b.t - a.t);
  return pose(a.p + u * (b.p - a.p), a.q.slerp(u, b.q));
}

Eigen::Isometry3d PoseEstimator::estimate(double t) {
  if (history_.empty()) throw std::logic_error("PoseEstimator::estimate before any truth");
  if (spec_.perfect) return truthAt(t);  // no delay either
  const double dt = last_t_ < -1e299 ? 0.0 : std::max(0.0, t - last_t_);
  last_t_ = t;
  Eigen::Matrix<double, 6, 1> e;
  const double tau = spec_.drift_time_constant_s;
  // Exact discretisation of the Gauss-Markov drift (any dt); the walk keeps its own expression so
  // the default stays bit for bit what it was. The same draws either way.
  const double decay = std::isinf(tau) ? 1.0 : std::exp(-dt / tau);
  const double step_sd = std::isinf(tau) ? std::sqrt(dt) : std::sqrt(0.5 * tau * (1.0 - decay * decay));
  for (int k = 0; k < 6; ++k) {
    const AxisError& a = k < 3 ? spec_.position[k] : spec_.attitude[k - 3];
    if (std::isinf(tau)) walk_[k] += normal_(rng_) * a.random_walk * step_sd;
    else walk_[k] = walk_[k] * decay + normal_(rng_) * a.random_walk * step_sd;
    e[k] = bias_[k] + walk_[k] + normal_(rng_) * a.white;
  }
  last_error_ = e;
  Eigen::Isometry3d T = truthAt(t - spec_.latency_s);
  T.translation() += e.head<3>();
  T.linear() = (Eigen::AngleAxisd(e[5], Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(e[4], Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(e[3], Eigen::Vector3d::UnitX()))
                   .toRotationMatrix() *
               T.linear();
  return T;
}

template <class Draw>
std::array<double, 3> PoseEstimator::cylindersWith(const std::array<double, 3>& L, Draw&& unit_normal) const {
  if (spec_.perfect) return L;
  std::array<double, 3> out{};
  for (int k = 0; k < 3; ++k) out[k] = L[k] + cylinder_bias_[k] + unit_normal() * spec_.cylinder_white_m;
  return out;
}

std::array<double, 3> PoseEstimator::cylinders(const std::array<double, 3>& L) {
  return cylindersWith(L, [&] { return normal_(rng_); });
}

std::array<double, 3> PoseEstimator::cylinders(const std::array<double, 3>& L, std::mt19937_64& rng) const {
  std::normal_distribution<double> N(0.0, 1.0);
  return cylindersWith(L, [&] { return N(rng); });
}

Eigen::Matrix<double, 6, 1> PoseEstimator::twist(const Eigen::Matrix<double, 6, 1>& truth) {
  if (spec_.perfect) return truth;
  Eigen::Matrix<double, 6, 1> out = truth;
  for (int k = 0; k < 6; ++k)
    out[k] += twist_normal_(twist_rng_) * (k < 3 ? spec_.velocity_white_mps : spec_.angular_rate_white_radps);
  return out;
}

}  // namespace terramap::sim
