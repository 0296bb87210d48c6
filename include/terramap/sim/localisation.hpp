#pragma once
/// \file
/// How a machine's pose estimate differs from the truth: the poses a mapper receives (the base
/// pose, the sensor pose of each cloud, the blade pose) come from an estimator, not from the
/// simulator's state. Per axis the error is
///   e(t) = b + w(t) + n(t),
/// b a constant bias drawn once (1-sigma `bias`), w a random walk (w(t + dt) = w(t) + N(0,
/// random_walk^2 dt): drift; with a finite `drift_time_constant_s` tau a first-order Gauss-Markov
/// process instead, w(t + dt) = w(t) e^(-dt/tau) + N(0, random_walk^2 tau/2 (1 - e^(-2 dt/tau))),
/// which drifts like the walk for dt << tau but stays within random_walk sqrt(tau/2) (1-sigma)
/// however long the run), n white noise (1-sigma `white`, drawn anew per estimate), and the
/// estimate describes the machine as it was `latency_s` earlier (the estimator's pipeline delay).
/// Axes: position x, y, z in the map frame (m); attitude roll, pitch, yaw (rad), applied as a
/// rotation R_err = Rz(yaw) Ry(pitch) Rx(roll) on the map side of the true attitude.
///
/// Defaults (rtkImu()) are representative of a compact track loader with RTK-GNSS (fixed
/// solution: about 1 cm horizontal and 2 cm vertical RMS, mostly slow: bias and drift, with a few
/// millimetres of white noise), a dual-antenna heading over a ~1.5 m baseline (~0.2 deg) and a
/// MEMS IMU for roll and pitch (~0.05 deg), time-tagged and interpolated to each instant (2 ms
/// of clock synchronisation left); the blade's pose comes from the cylinder-length sensors through the
/// joint kinematics, with ~1 mm of noise and bias per cylinder. docs/sim.md ("Localisation")
/// gives the sources of these orders of magnitude and how to change them.
///
/// Determinism: every draw comes from the estimator's own generator, seeded by the scenario's
/// seed and the machine, in the order of the calls; the calls happen in simulated-time order
/// on one thread, so estimates are bit-identical for any thread count.
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <deque>
#include <limits>
#include <random>

namespace terramap::sim {

/// One axis' error process (units of the axis: m or rad; random_walk in units per sqrt(s)).
struct AxisError {
  double white = 0.0;
  double bias = 0.0;
  double random_walk = 0.0;
};

struct LocalisationSpec {
  bool perfect = false;             ///< estimates equal the truth (ablations)
  std::array<AxisError, 3> position{};  ///< x, y, z (map frame), metres
  std::array<AxisError, 3> attitude{};  ///< roll, pitch, yaw, radians
  double latency_s = 0.0;           ///< the estimate shows the pose of this long ago, >= 0
  /// Correlation time of the drift (s, > 0); infinity (the default) = an unbounded random walk.
  /// A walk suits the 30 s episodes the defaults were set for; over an hour it drifts to
  /// several times RTK's specified RMS, which a bounded drift does not (docs/sim.md).
  double drift_time_constant_s = std::numeric_limits<double>::infinity();
  double cylinder_white_m = 0.0;    ///< blade cylinder length sensors: white noise, 1-sigma
  double cylinder_bias_m = 0.0;     ///< ... constant bias per cylinder, 1-sigma
  /// The twists the machine reports (Observation::twist_base / twist_blade) come from its
  /// inertial navigation, not from differencing poses: the true body twist over the observation
  /// period plus white noise per axis, 1-sigma, linear (m/s) and angular (rad/s).
  double velocity_white_mps = 0.0;
  double angular_rate_white_radps = 0.0;

  /// The perfect estimator.
  static LocalisationSpec none();
  /// RTK-GNSS + dual-antenna heading + MEMS IMU on a compact track loader (see the file comment).
  static LocalisationSpec rtkImu();
};

/// The estimator of one machine's base pose. Feed it the true pose at every simulated instant
/// (increasing time), ask for the estimate at instants at or after the last truth fed.
class PoseEstimator {
 public:
  /// \throws std::invalid_argument on a negative latency, a negative / non-finite sigma or a
  /// drift time constant that is not > 0.
  PoseEstimator(const LocalisationSpec& spec, std::uint64_t seed);

  /// Records the true pose at time t. Times must not decrease (equal times replace).
  void addTruth(double t, const Eigen::Isometry3d& T_map_base);
  /// The estimated pose at time t (>= the previous call's t): the truth at t - latency_s
  /// (interpolated: linear in position, slerp in attitude; the oldest truth if earlier; a truth
  /// added at exactly that time is returned bit for bit), with the error process advanced to t.
  /// The perfect estimator returns the truth at t. \throws std::logic_error before any truth
  /// was added.
  Eigen::Isometry3d estimate(double t);
  /// The error part of the last estimate as [x, y, z, roll, pitch, yaw] (bias + walk + white).
  const Eigen::Matrix<double, 6, 1>& lastError() const { return last_error_; }
  /// Noisy cylinder lengths for true lengths `L` (white noise + the per-cylinder bias).
  std::array<double, 3> cylinders(const std::array<double, 3>& L);
  /// The same reading with its white noise drawn from `rng` (a stream of the caller's: a
  /// sensor's pose at a scan), so it takes no draw from the observations' readings.
  std::array<double, 3> cylinders(const std::array<double, 3>& L, std::mt19937_64& rng) const;
  /// The reported body twist [v (m/s), w (rad/s)] for the true one: white noise of
  /// velocity_white_mps / angular_rate_white_radps per axis, from a generator of its own (so
  /// asking for twists changes no pose estimate); the perfect estimator returns it unchanged.
  Eigen::Matrix<double, 6, 1> twist(const Eigen::Matrix<double, 6, 1>& truth);
  const LocalisationSpec& spec() const { return spec_; }

 private:
  /// The truth at time td, interpolated between the stored samples (clamped to their span).
  Eigen::Isometry3d truthAt(double td) const;

  LocalisationSpec spec_;
  /// cylinders' body, its unit normal draws from `unit_normal()`.
  template <class Draw>
  std::array<double, 3> cylindersWith(const std::array<double, 3>& L, Draw&& unit_normal) const;
  std::mt19937_64 rng_;
  std::mt19937_64 twist_rng_;  ///< twist() only
  std::normal_distribution<double> twist_normal_{0.0, 1.0};  ///< its own: a distribution caches draws
  std::normal_distribution<double> normal_{0.0, 1.0};
  Eigen::Matrix<double, 6, 1> bias_ = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> walk_ = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> last_error_ = Eigen::Matrix<double, 6, 1>::Zero();
  std::array<double, 3> cylinder_bias_{};
  double last_t_ = -1e300;
  struct Sample {
    double t;
    Eigen::Isometry3d T;  ///< as given (returned unchanged when looked up at exactly t)
    Eigen::Vector3d p;
    Eigen::Quaterniond q;
  };
  std::deque<Sample> history_;  ///< truths back to latency_s before the newest
};

}  // namespace terramap::sim
