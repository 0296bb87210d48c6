// The localisation error model (sim/localisation.hpp): latency, white noise, bias, drift, the
// perfect estimator, determinism per seed, bad settings.
#include <terramap/sim/localisation.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <vector>

using namespace terramap::sim;

namespace {
Eigen::Isometry3d along(double t) {  // 1 m/s along x, yawing at 0.5 rad/s
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(t, 0.2 * t, 0.1);
  T.linear() = Eigen::AngleAxisd(0.5 * t, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  return T;
}
double yawOf(const Eigen::Isometry3d& T) { return std::atan2(T.linear()(1, 0), T.linear()(0, 0)); }
LocalisationSpec only(int axis, AxisError e) {
  LocalisationSpec s;
  (axis < 3 ? s.position[axis] : s.attitude[axis - 3]) = e;
  return s;
}
}  // namespace

TEST(Localisation, PerfectEstimatesAreTheTruth) {
  PoseEstimator est(LocalisationSpec::none(), 1);
  for (int k = 0; k <= 60; ++k) {
    est.addTruth(k / 60.0, along(k / 60.0));
    EXPECT_TRUE(est.estimate(k / 60.0).isApprox(along(k / 60.0), 1e-15)) << k;
  }
}

TEST(Localisation, LatencyShowsThePoseOfThatLongAgoInterpolated) {
  LocalisationSpec s;
  s.latency_s = 0.025;  // between two 60 Hz truths
  PoseEstimator est(s, 1);
  for (int k = 0; k <= 120; ++k) est.addTruth(k / 60.0, along(k / 60.0));
  const Eigen::Isometry3d T = est.estimate(2.0);
  EXPECT_NEAR(T.translation().x(), 2.0 - 0.025, 1e-12);  // linear motion: interpolation is exact
  EXPECT_NEAR(T.translation().y(), 0.2 * (2.0 - 0.025), 1e-12);
  EXPECT_NEAR(yawOf(T), 0.5 * (2.0 - 0.025), 1e-12);      // constant yaw rate: slerp is exact
  EXPECT_EQ(est.lastError().norm(), 0.0);
}

TEST(Localisation, WhiteNoiseHasItsSigmaAndNoMemory) {
  PoseEstimator est(only(0, AxisError{0.01, 0, 0}), 7);
  const int n = 20000;
  double s = 0, ss = 0, lag = 0, prev = 0;
  for (int k = 0; k < n; ++k) {
    est.addTruth(k * 0.01, along(k * 0.01));
    const double e = est.estimate(k * 0.01).translation().x() - k * 0.01;
    s += e;
    ss += e * e;
    lag += e * prev;
    prev = e;
  }
  const double mean = s / n, sd = std::sqrt(ss / n - mean * mean);
  // Sample sd of n normals: 1-sigma relative error 1/sqrt(2n) = 0.5 %; 4 sigma bounds.
  EXPECT_NEAR(sd, 0.01, 0.01 * 4 / std::sqrt(2.0 * n));
  EXPECT_NEAR(mean, 0.0, 4 * 0.01 / std::sqrt(n));
  EXPECT_NEAR(lag / n / (sd * sd), 0.0, 4 / std::sqrt(n));  // lag-1 autocorrelation
}

TEST(Localisation, BiasIsConstantPerRunAndDrawnPerSeed) {
  std::vector<double> biases;
  for (std::uint64_t seed = 1; seed <= 2000; ++seed) {
    PoseEstimator est(only(5, AxisError{0, 0.002, 0}), seed);
    est.addTruth(0, along(0));
    const double b0 = yawOf(est.estimate(0.0));
    est.addTruth(5, along(5));
    EXPECT_NEAR(yawOf(est.estimate(5.0)) - 2.5, b0, 1e-12);  // the same offset 5 s later
    biases.push_back(b0);
  }
  double ss = 0;
  for (double b : biases) ss += b * b;
  EXPECT_NEAR(std::sqrt(ss / biases.size()), 0.002, 0.002 * 4 / std::sqrt(2.0 * biases.size()));
}

TEST(Localisation, RandomWalkVarianceGrowsLinearlyWithTime) {
  // Var w(T) = random_walk^2 T whatever the step: check at T = 4 s and 16 s over many seeds, with
  // 100 Hz and 25 Hz estimates (the step must not matter).
  for (const double hz : {100.0, 25.0}) {
    double v4 = 0, v16 = 0;
    const int seeds = 1500;
    for (int seed = 0; seed < seeds; ++seed) {
      PoseEstimator est(only(1, AxisError{0, 0, 0.01}), 1000 + seed);
      for (int k = 0; k <= static_cast<int>(16 * hz); ++k) {
        const double t = k / hz;
        est.addTruth(t, along(t));
        const double e = est.estimate(t).translation().y() - 0.2 * t;
        if (k == static_cast<int>(4 * hz)) v4 += e * e;
        if (k == static_cast<int>(16 * hz)) v16 += e * e;
      }
    }
    v4 /= seeds;
    v16 /= seeds;
    // Expected 4e-4 and 1.6e-3 m^2; a sample variance of 1500 normals is within 4 sqrt(2/1500) = 15 %.
    EXPECT_NEAR(v4, 1e-4 * 4, 0.15 * 4e-4) << hz << " Hz";
    EXPECT_NEAR(v16, 1e-4 * 16, 0.15 * 1.6e-3) << hz << " Hz";
  }
}

TEST(Localisation, BoundedDriftSettlesAtItsStationaryVariance) {
  // With drift_time_constant_s tau the drift is Gauss-Markov: Var w(T) = rw^2 tau/2 (1 - e^(-2T/tau))
  // whatever the step. rw = 0.01 m/sqrt(s), tau = 2 s: 0.982e-4 m^2 at T = 4 s and 1e-4 at 20 s,
  // where the walk above has 4e-4 and 2e-3 (an hour-long soak drifts no further than this).
  for (const double hz : {100.0, 25.0}) {
    double v4 = 0, v20 = 0;
    const int seeds = 1500;
    for (int seed = 0; seed < seeds; ++seed) {
      LocalisationSpec spec = only(1, AxisError{0, 0, 0.01});
      spec.drift_time_constant_s = 2.0;
      PoseEstimator est(spec, 1000 + seed);
      for (int k = 0; k <= static_cast<int>(20 * hz); ++k) {
        const double t = k / hz;
        est.addTruth(t, along(t));
        const double e = est.estimate(t).translation().y() - 0.2 * t;
        if (k == static_cast<int>(4 * hz)) v4 += e * e;
        if (k == static_cast<int>(20 * hz)) v20 += e * e;
      }
    }
    v4 /= seeds;
    v20 /= seeds;
    const double e4 = 1e-4 * (1 - std::exp(-4.0)), e20 = 1e-4 * (1 - std::exp(-20.0));
    EXPECT_NEAR(v4, e4, 0.15 * e4) << hz << " Hz";  // as above: 15 % is 4 sigma of 1500 samples
    EXPECT_NEAR(v20, e20, 0.15 * e20) << hz << " Hz";
  }
}

TEST(Localisation, SameSeedSameErrorsOtherSeedOtherErrors) {
  auto run = [](std::uint64_t seed) {
    PoseEstimator est(LocalisationSpec::rtkImu(), seed);
    std::vector<double> out;
    for (int k = 0; k < 200; ++k) {
      est.addTruth(k / 60.0, along(k / 60.0));
      const Eigen::Isometry3d T = est.estimate(k / 60.0);
      out.push_back(T.translation().x());
      const auto c = est.cylinders({0.5, 0.6, 0.7});
      out.push_back(c[0]);
    }
    return out;
  };
  EXPECT_EQ(run(3), run(3));
  EXPECT_NE(run(3), run(4));
}

TEST(Localisation, CylinderSensorsAddBiasAndNoise) {
  LocalisationSpec s;
  s.cylinder_white_m = 0.001;
  PoseEstimator est(s, 2);
  double ss = 0;
  for (int k = 0; k < 4000; ++k) {
    const auto c = est.cylinders({0.5, 0.5, 0.5});
    ss += (c[1] - 0.5) * (c[1] - 0.5);
  }
  EXPECT_NEAR(std::sqrt(ss / 4000), 0.001, 0.001 * 4 / std::sqrt(8000.0));
}

// The reported twist: white noise of its own sigma per axis, no memory, and drawn from a stream
// of its own (asking for twists leaves the pose estimates as they were).
TEST(Localisation, TwistsCarryTheirOwnWhiteNoiseAndLeaveThePosesAlone) {
  LocalisationSpec s = LocalisationSpec::rtkImu();
  s.velocity_white_mps = 0.02;
  s.angular_rate_white_radps = 0.001;
  PoseEstimator with(s, 9), without(s, 9);
  Eigen::Matrix<double, 6, 1> truth;
  truth << 0.8, -0.1, 0.05, 0.01, -0.2, 0.3;
  const int n = 8000;
  double ss[6] = {}, lag = 0, prev = 0;
  for (int k = 0; k < n; ++k) {
    const double t = k / 60.0;
    with.addTruth(t, along(t));
    without.addTruth(t, along(t));
    const Eigen::Matrix<double, 6, 1> e = with.twist(truth) - truth;
    for (int a = 0; a < 6; ++a) ss[a] += e[a] * e[a];
    lag += e[2] * prev;
    prev = e[2];
    ASSERT_TRUE(with.estimate(t).matrix() == without.estimate(t).matrix()) << k;
  }
  for (int a = 0; a < 6; ++a) {
    const double sigma = a < 3 ? 0.02 : 0.001;
    EXPECT_NEAR(std::sqrt(ss[a] / n), sigma, sigma * 4 / std::sqrt(2.0 * n)) << "axis " << a;
  }
  EXPECT_NEAR(lag / ss[2], 0.0, 4 / std::sqrt(static_cast<double>(n)));
  PoseEstimator perfect(LocalisationSpec::none(), 9);
  EXPECT_TRUE(perfect.twist(truth) == truth);
}

TEST(Localisation, BadSettingsAreRefused) {
  LocalisationSpec s;
  s.latency_s = -0.1;
  EXPECT_THROW(PoseEstimator(s, 1), std::invalid_argument);
  s = LocalisationSpec{};
  s.attitude[2].white = NAN;
  EXPECT_THROW(PoseEstimator(s, 1), std::invalid_argument);
  s = LocalisationSpec{};
  s.drift_time_constant_s = 0.0;
  EXPECT_THROW(PoseEstimator(s, 1), std::invalid_argument);
  s = LocalisationSpec{};
  s.velocity_white_mps = -0.01;
  EXPECT_THROW(PoseEstimator(s, 1), std::invalid_argument);
  s = LocalisationSpec{};
  s.angular_rate_white_radps = INFINITY;
  EXPECT_THROW(PoseEstimator(s, 1), std::invalid_argument);
  PoseEstimator ok(LocalisationSpec::rtkImu(), 1);
  EXPECT_THROW(ok.estimate(0.0), std::logic_error);
  ok.addTruth(1.0, along(1.0));
  EXPECT_THROW(ok.addTruth(0.5, along(0.5)), std::invalid_argument);
}
