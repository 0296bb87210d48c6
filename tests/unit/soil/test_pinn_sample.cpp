// The soil estimator's input: features of an observation and the per-sweep sample
// (soil/pinn_sample.hpp), checked against values worked out by hand.
#include <terramap/soil/pinn_inference.hpp>
#include <terramap/soil/pinn_sample.hpp>

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <vector>
#include <random>

using namespace terramap;
using namespace terramap::soil;

namespace {

constexpr double kDt = 1.0 / 60.0;

// A machine driving along map direction `heading` at `speed`, blade 1.9 m ahead and 0.1 m
// below the base origin, force sensor reading `f_base` (soil on blade, base frame).
Observation obsAt(double stamp, double heading, double speed, const Eigen::Vector3d& f_base) {
  Observation o;
  o.stamp = stamp;
  o.machine_id = "m";
  const Eigen::Vector3d pos(speed * stamp * std::cos(heading), speed * stamp * std::sin(heading), 1.0);
  o.T_map_base = Eigen::Translation3d(pos) * Eigen::AngleAxisd(heading, Eigen::Vector3d::UnitZ());
  o.T_map_blade = o.T_map_base * Eigen::Translation3d(1.9, 0.0, -0.1) *
                  Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitY());
  o.twist_base << speed, 0, 0, 0, 0, 0;
  o.twist_blade << speed * std::cos(0.05), 0, speed * std::sin(0.05), 0, 0, 0;  // base velocity in the pitched blade frame
  o.cylinder_length_m = {0.5, 0.6, 0.7};
  o.track_speed_mps = {speed, speed};
  o.engine_speed_rpm = 2400;
  o.force_base_N = f_base;
  return o;
}

SweepRecord sweepAlongX(double t0, double t1) {
  SweepRecord r;
  r.machine_id = "m";
  r.sweep_index = 3;
  r.fee_valid = true;
  r.t0 = t0;
  r.t1 = t1;
  r.t_hat = Eigen::Vector2d::UnitX();
  // Two steps: d goes 0.10 -> 0.20 m, Q 1000 -> 3000 N, alpha/rho/w constant.
  for (double t : {t0, t1}) {
    SweepStep s;
    s.stamp = t;
    const double u = (t - t0) / (t1 - t0);
    s.alpha_rad = 0.02;
    s.rho_rad = 1.4;
    s.w_m = 1.8;
    s.d_m = 0.10 + 0.10 * u;
    s.q_n = 1000 + 2000 * u;
    r.steps.push_back(s);
  }
  return r;
}

}  // namespace

TEST(PinnSample, FeatureNamesMatchTheFeatureCount) {
  EXPECT_EQ(obsFeatureNames().size(), static_cast<std::size_t>(kObsFeatures));
  EXPECT_EQ(thetaKNames().size(), static_cast<std::size_t>(kThetaK));
}

TEST(PinnSample, StalledRowIsTracksTurningWithTheBaseHeld) {
  // The rule reads base_vx and the two track speeds by index: they must be those features.
  ASSERT_EQ(obsFeatureNames()[0], "base_vx_mps");
  ASSERT_EQ(obsFeatureNames()[26], "track_left_mps");
  ASSERT_EQ(obsFeatureNames()[27], "track_right_mps");
  Observation o;
  o.track_speed_mps = {1.0, 0.8};  // mean 0.9 m/s
  o.twist_base[0] = 0.17;          // below 0.2 * 0.9
  EXPECT_TRUE(stalledRow(observationRow(o).features));
  o.twist_base[0] = 0.19;  // above
  EXPECT_FALSE(stalledRow(observationRow(o).features));
  o.track_speed_mps = {0.05, 0.05};  // the tracks barely turn: standing, not stalled
  o.twist_base[0] = 0.0;
  EXPECT_FALSE(stalledRow(observationRow(o).features));
  o.track_speed_mps = {-1.0, -1.0};  // reversing
  EXPECT_FALSE(stalledRow(observationRow(o).features));
  o.track_speed_mps = {std::nan(""), 1.0};
  EXPECT_FALSE(stalledRow(observationRow(o).features));
}

TEST(PinnSample, FeaturesDoNotDependOnWhereOrWhichWayTheMachineWorks) {
  // The same manoeuvre heading east and heading 130 degrees elsewhere on the site: every feature
  // is in the machine's own frames, so they must agree (to float rounding of the poses).
  const ObsRow a = observationRow(obsAt(2.0, 0.0, 0.8, Eigen::Vector3d(-5000, 0, 2000)));
  const ObsRow b = observationRow(obsAt(2.0, 130 * M_PI / 180, 0.8, Eigen::Vector3d(-5000, 0, 2000)));
  for (int k = 0; k < kObsFeatures; ++k) EXPECT_NEAR(a.features[k], b.features[k], 1e-6) << obsFeatureNames()[k];
  // Blade pose in the base frame: 1.9 m ahead, 0.1 m down, pitched 0.05 rad.
  EXPECT_NEAR(a.features[8], 1.9, 1e-6);
  EXPECT_NEAR(a.features[10], -0.1, 1e-6);
  EXPECT_NEAR(a.features[12], 0.05, 1e-6);
  EXPECT_NEAR(a.features[28], 2400, 1e-3);
}

TEST(PinnSample, ForceIsTheBladeOnTheSoilInTheMapFrame) {
  // Heading 90 degrees (north): the soil pushes the blade back (-x base = south) and up; the
  // blade pushes the soil north and down.
  const ObsRow r = observationRow(obsAt(1.0, M_PI / 2, 0.8, Eigen::Vector3d(-5000, 0, 2000)));
  EXPECT_NEAR(r.force_map_N.x(), 0.0, 1e-9);
  EXPECT_NEAR(r.force_map_N.y(), 5000.0, 1e-9);
  EXPECT_NEAR(r.force_map_N.z(), -2000.0, 1e-9);
  // The edge moves north at the machine's speed.
  EXPECT_NEAR(r.blade_velocity_map.y(), 0.8, 1e-9);
  EXPECT_NEAR(r.blade_velocity_map.x(), 0.0, 1e-9);
}

TEST(PinnSample, HorizonIsTheEndOfTheHistoryWithThetaKInterpolatedInTime) {
  ObservationHistory h(100);
  for (int i = 0; i <= 60; ++i) h.push(obsAt(i * kDt, 0.0, 0.8, Eigen::Vector3d(-4000 - i, 0, 1500)));
  const double t0 = 50 * kDt, t1 = 60 * kDt;
  PinnSample s;
  ASSERT_EQ(buildSample(h, sweepAlongX(t0, t1), 20, 4, s), SampleSkip::None);
  ASSERT_EQ(s.obs.size(), 20u * kObsFeatures);
  ASSERT_EQ(s.theta_k.size(), 4u * kThetaK);
  // The last observation is the one at t1; the horizon is observations 57..60.
  EXPECT_DOUBLE_EQ(s.anchor_stamp, t1);
  for (int p = 0; p < 4; ++p) {
    const int i = 57 + p;
    const double u = (i * kDt - t0) / (t1 - t0);
    const float* th = &s.theta_k[static_cast<std::size_t>(p) * kThetaK];
    EXPECT_NEAR(th[kDepth], 0.10 + 0.10 * u, 1e-6) << "p " << p;
    EXPECT_NEAR(th[kSurcharge], 1000 + 2000 * u, 1e-3);
    EXPECT_NEAR(th[kRho], 1.4, 1e-6);
    EXPECT_NEAR(th[kSpeed], 0.8, 1e-6);
    // Blade on soil along t_hat = +x: +(4000 + i); up: -1500.
    EXPECT_NEAR(s.force[static_cast<std::size_t>(p) * 2], 4000 + i, 1e-3);
    EXPECT_NEAR(s.force[static_cast<std::size_t>(p) * 2 + 1], -1500, 1e-3);
  }
  // The history's first row is observation 41 (60 - 20 + 1).
  EXPECT_NEAR(s.obs[0], 0.8, 1e-6);  // base vx
  // A horizon reaching before the sweep's first pose takes the first step's values (clamped).
  ASSERT_EQ(buildSample(h, sweepAlongX(t0, t1), 20, 15, s), SampleSkip::None);
  EXPECT_NEAR(s.theta_k[kDepth], 0.10, 1e-6);
}

TEST(PinnSample, SaysWhyASweepGivesNoSample) {
  ObservationHistory h(100);
  for (int i = 0; i <= 30; ++i) h.push(obsAt(i * kDt, 0.0, 0.8, Eigen::Vector3d(-4000, 0, 1500)));
  PinnSample s;
  SweepRecord r = sweepAlongX(20 * kDt, 30 * kDt);
  r.fee_valid = false;
  EXPECT_EQ(buildSample(h, r, 10, 5, s), SampleSkip::FeeInvalid);
  r = sweepAlongX(20 * kDt, 30 * kDt);
  EXPECT_EQ(buildSample(h, r, 40, 5, s), SampleSkip::ShortHistory);
  r = sweepAlongX(20 * kDt + 1.0, 30 * kDt + 1.0);  // observations stopped a second ago
  EXPECT_EQ(buildSample(h, r, 10, 5, s), SampleSkip::StaleHistory);
  r = sweepAlongX(20 * kDt, 30 * kDt);
  for (auto& st : r.steps) st.d_m = std::nan("");
  EXPECT_EQ(buildSample(h, r, 10, 5, s), SampleSkip::NonFiniteThetaK);
  r.steps.clear();
  EXPECT_EQ(buildSample(h, r, 10, 5, s), SampleSkip::NoSteps);
  EXPECT_THROW(buildSample(h, sweepAlongX(0, 1), 4, 5, s), std::invalid_argument);
  EXPECT_STREQ(sampleSkipName(SampleSkip::StaleHistory), "stale_history");
}

TEST(PinnSample, HistoryIgnoresObservationsFromThePastAndKeepsItsCapacity) {
  ObservationHistory h(8);
  for (int i = 0; i < 20; ++i) EXPECT_TRUE(h.push(obsAt(i * kDt, 0.0, 0.8, Eigen::Vector3d::Zero())));
  EXPECT_FALSE(h.push(obsAt(3 * kDt, 0.0, 0.8, Eigen::Vector3d::Zero())));
  ASSERT_EQ(h.rows().size(), 8u);
  EXPECT_DOUBLE_EQ(h.rows().back().stamp, 19 * kDt);
  EXPECT_DOUBLE_EQ(h.rows().front().stamp, 12 * kDt);
}

TEST(PinnInputDistance, NothingIsAddedWithinTheTrainingSamplesAndThePriorFarFromThem) {
  // Features of a correlated Gaussian cloud (the whitening must undo the correlation): the fit's
  // mean sits at the cloud's, its 99th percentile leaves 1 % of the samples beyond it, a point
  // far along a direction the cloud never varies in gets almost the whole prior variance, and
  // the share grows with the distance.
  std::mt19937_64 rng(3);
  std::normal_distribution<double> N(0.0, 1.0);
  const int n = 6;
  std::vector<std::vector<double>> f;
  for (int s = 0; s < 2000; ++s) {
    const double a = N(rng), b = N(rng);
    f.push_back({a, a + 0.1 * b, 2.0 * b, N(rng), 5.0 + N(rng), 0.01 * N(rng)});
  }
  const std::array<double, 5> prior{1, 2, 3, 4, 5};
  const soil::PinnInputDistance d = soil::PinnInputDistance::fit(f, prior);
  ASSERT_EQ(d.mean.size(), static_cast<std::size_t>(n));
  EXPECT_NEAR(d.mean[4], 5.0, 0.1);
  EXPECT_NEAR(d.d2(d.mean), 0.0, 1e-12);
  EXPECT_EQ(d.share(d.d2(d.mean)), 0.0);
  long beyond = 0;
  for (const auto& x : f) beyond += d.share(d.d2(x)) > 0;
  EXPECT_LE(beyond, 20);  // 1 % of 2000
  EXPECT_GE(beyond, 15);
  // Mahalanobis, not Euclidean: 0.05 off along the direction of feature 5 (std 0.01) is far; 3
  // along feature 1's is not.
  std::vector<double> across = d.mean, along = d.mean;
  across[5] += 0.05;
  along[0] += 3.0;
  along[1] += 3.0;
  EXPECT_GT(d.d2(across), d.d2(along));
  std::vector<double> far = d.mean;
  far[5] += 1.0;  // 100 standard deviations
  EXPECT_GT(d.share(d.d2(far)), 0.99);
  double last = -1;
  for (double off : {0.01, 0.03, 0.05, 0.1, 0.3}) {
    std::vector<double> x = d.mean;
    x[5] += off;
    const double sh = d.share(d.d2(x));
    EXPECT_GE(sh, last);
    last = sh;
  }
  EXPECT_TRUE(std::isnan(d.d2({1.0, 2.0})));  // the wrong length
  EXPECT_THROW(soil::PinnInputDistance::fit({{1.0, 2.0}}, prior), std::invalid_argument);
}

TEST(SlicedGeometry, TheOneWedgeHoldsTheCrossSectionsSums) {
  // Two steps of a cut 1 m wide whose left half is 0.10 m deep and right half 0.20 m: the mean
  // depth over the cutting width (0.15 m) under-weighs the deep half in gamma d^2 w, the FEE
  // summed over the two slices is gamma (0.1^2 + 0.2^2) 0.5 N_gamma + c (0.1 + 0.2) 0.5 N_c.
  std::vector<float> theta = {1.3f, 0.0f, 1.0f, 0.15f, 2000.0f, 0.8f,   // step 0
                              1.3f, 0.0f, 1.0f, 0.15f, 2000.0f, 0.8f};  // step 1: no profile
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<float> profile = {0.15f, 0.025f, nan, nan};
  ASSERT_EQ(applySlicedGeometry(theta.data(), profile.data(), 2), 1);
  const double d = theta[kDepth], w = theta[kWidth];
  EXPECT_NEAR(d * w, 0.15, 1e-6);        // the c and c_a terms: sum d ds
  EXPECT_NEAR(d * d * w, 0.025, 1e-6);   // the gamma term: sum d^2 ds
  EXPECT_GT(d * d * w, 0.15 * 0.15 * 1.0 * 1.1);  // the mean depth would miss 10 % of it
  EXPECT_EQ(theta[kRho], 1.3f);          // nothing else moves
  EXPECT_EQ(theta[kSurcharge], 2000.0f);
  EXPECT_EQ(theta[kThetaK + kDepth], 0.15f);  // the step without a cross-section keeps its own
  EXPECT_EQ(theta[kThetaK + kWidth], 1.0f);
  const std::vector<float> empty = {0.0f, 0.0f, -1.0f, 0.01f};
  EXPECT_EQ(applySlicedGeometry(theta.data(), empty.data(), 2), 0);
}
