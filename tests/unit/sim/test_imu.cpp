// The simulator's IMUs (sim/imu.hpp, docs/sim.md "IMUs"): gravity at rest and the specific force
// and rate of an analytic circular motion, white noise and bias walks that follow their
// densities, and the simulator delivering samples at the rate, in time order, the same bits at
// any thread count, consistent with the machine's turning, and recorded in the episode.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/sim/episode.hpp>
#include <terramap/sim/imu.hpp>
#include <terramap/sim/simulator.hpp>

#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

using namespace terramap;
using namespace terramap::sim;

namespace {

constexpr double kG = 9.80665;

SensorSpec quietImu(double rate_hz) {
  SensorSpec s;
  s.type = SensorSpec::Type::Imu;
  s.rate_hz = rate_hz;
  s.accel_noise_density = s.gyro_noise_density = 0;
  s.accel_bias_walk = s.gyro_bias_walk = 0;
  s.accel_bias_sigma = s.gyro_bias_sigma = 0;
  return s;
}

Eigen::Isometry3d pose(const Eigen::Vector3d& p, double yaw, double pitch = 0, double roll = 0) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = p;
  T.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  return T;
}

std::string scenarioYaml(int threads, const std::string& controller, const std::string& imus) {
  return "version: 1\nseed: 9\nduration_s: 1.0\nthreads: " + std::to_string(threads) +
         "\nlocalisation: perfect\n"
         "terrain: {size_m: [16, 12], origin_m: [-6, -6], resolution_m: 0.02,\n"
         "  hills: {count: 4, amplitude_m: [-0.1, 0.15], sigma_m: [0.8, 1.5], seed: 3}}\n"
         "machines:\n  - id: ctl1\n    controller: " +
         controller +
         "\n    sensors:\n      - {id: top, type: lidar, preset: vlp32, columns: 180, offset_m: [0.3, 0, 2.1]}\n" + imus;
}

}  // namespace

TEST(Imu, ReadsGravityAtRestAndTheSpecificForceAndRateOfACircle) {
  // At rest and level: +g on z, no rate. Mounted rolled by 90 deg about x, the IMU's y axis
  // points up: the ground's reaction to gravity reads +g on y.
  {
    SensorSpec s = quietImu(100);
    s.T_base_sensor.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitX()).toRotationMatrix();
    ImuModel level(quietImu(100), "m/a", 1), rolled(s, "m/b", 1);
    ImuSample a, b;
    ImuTruth tr;
    for (int k = 0; k < 3; ++k) {
      const Eigen::Isometry3d T = pose({1, 2, 3}, 0.3);
      level.addLinkPose(k / 100.0, T, a, &tr);
      rolled.addLinkPose(k / 100.0, T, b);
    }
    EXPECT_NEAR((a.accel_mps2 - Eigen::Vector3d(0, 0, kG)).norm(), 0.0, 1e-9);
    EXPECT_NEAR(a.gyro_radps.norm(), 0.0, 1e-12);
    EXPECT_NEAR((b.accel_mps2 - Eigen::Vector3d(0, kG, 0)).norm(), 0.0, 1e-9) << b.accel_mps2.transpose();
    EXPECT_EQ(a.stamp, 0.01);  // the middle instant of the three poses
    EXPECT_EQ(a.frame, "m/a");
  }
  // A circle of radius 4 m at 0.5 rad/s, counter-clockwise, x along the velocity: the body feels
  // the centripetal acceleration r w^2 = 1 m/s^2 towards the centre (+y, left) and yaw rate w.
  const double r = 4.0, w = 0.5, rate = 120;
  ImuModel imu(quietImu(rate), "m/c", 1);
  int samples = 0;
  for (int k = 0; k < 240; ++k) {
    const double t = k / rate;
    ImuSample s;
    if (!imu.addLinkPose(t, pose({r * std::cos(w * t), r * std::sin(w * t), 0.5}, w * t + M_PI / 2), s)) continue;
    ++samples;
    EXPECT_NEAR(s.accel_mps2.x(), 0.0, 1e-6);
    EXPECT_NEAR(s.accel_mps2.y(), r * w * w, 1e-5);  // central differences: relative error (w dt)^2 / 12
    EXPECT_NEAR(s.accel_mps2.z(), kG, 1e-9);
    EXPECT_NEAR((s.gyro_radps - Eigen::Vector3d(0, 0, w)).norm(), 0.0, 1e-9);
  }
  EXPECT_EQ(samples, 238);
}

TEST(Imu, NoiseAndBiasWalksFollowTheirDensities) {
  // A still IMU for 200 s at 100 Hz. White noise: the reading minus truth and bias has
  // sigma = density * sqrt(rate) per axis. Bias walk: its steps have sigma = walk * sqrt(dt).
  SensorSpec s = quietImu(100);
  s.accel_noise_density = 2e-3;
  s.gyro_noise_density = 1.7e-4;
  s.accel_bias_walk = 3e-3;
  s.gyro_bias_walk = 2e-5;
  s.accel_bias_sigma = 0.05;
  ImuModel imu(s, "m/i", 42);
  double w2a = 0, w2g = 0, b2a = 0, b2g = 0;
  long n = 0, nb = 0;
  Eigen::Vector3d ba_prev = Eigen::Vector3d::Zero(), bg_prev = Eigen::Vector3d::Zero(), ba_first = Eigen::Vector3d::Zero();
  bool have_prev = false;
  for (int k = 0; k < 20000; ++k) {
    ImuSample m;
    ImuTruth tr;
    if (!imu.addLinkPose(k / 100.0, pose({0, 0, 0}, 0.0), m, &tr)) continue;
    const Eigen::Vector3d ea = m.accel_mps2 - tr.specific_force - tr.accel_bias;
    const Eigen::Vector3d eg = m.gyro_radps - tr.angular_rate - tr.gyro_bias;
    w2a += ea.squaredNorm();
    w2g += eg.squaredNorm();
    n += 3;
    if (have_prev) {
      b2a += (tr.accel_bias - ba_prev).squaredNorm();
      b2g += (tr.gyro_bias - bg_prev).squaredNorm();
      nb += 3;
    } else {
      ba_first = tr.accel_bias;
    }
    ba_prev = tr.accel_bias;
    bg_prev = tr.gyro_bias;
    have_prev = true;
  }
  // 60 k draws: the sample sigma is within 1 % of the true one at 3 sigma; 2 % allowed.
  EXPECT_NEAR(std::sqrt(w2a / n) / (2e-3 * 10.0), 1.0, 0.02);
  EXPECT_NEAR(std::sqrt(w2g / n) / (1.7e-4 * 10.0), 1.0, 0.02);
  EXPECT_NEAR(std::sqrt(b2a / nb) / (3e-3 * 0.1), 1.0, 0.02);
  EXPECT_NEAR(std::sqrt(b2g / nb) / (2e-5 * 0.1), 1.0, 0.02);
  EXPECT_GT(ba_first.norm(), 1e-3);  // the turn-on bias was drawn
  // Same seed, same samples; another seed, others.
  ImuModel again(s, "m/i", 42), other(s, "m/i", 43);
  ImuSample x, y, z;
  for (int k = 0; k < 3; ++k) {
    again.addLinkPose(k / 100.0, pose({0, 0, 0}, 0.0), x);
    other.addLinkPose(k / 100.0, pose({0, 0, 0}, 0.0), y);
  }
  ImuModel first(s, "m/i", 42);
  for (int k = 0; k < 3; ++k) first.addLinkPose(k / 100.0, pose({0, 0, 0}, 0.0), z);
  EXPECT_EQ(x.accel_mps2, z.accel_mps2);
  EXPECT_NE(x.accel_mps2, y.accel_mps2);
}

TEST(Imu, TheSimulatorDeliversSamplesInTimeOrderAtAnyThreadCountAndTheyTrackTheTurns) {
  const std::string controller =
      "{type: random_walk, heading_deg: {initial: 0, range: [-40, 40], sigma: 40}, speed_mps: {initial: 0.8, range: [0.5, 1.0], sigma: 0.1}}";
  const std::string imus =
      "      - {id: imu_base, type: imu, rate_hz: 120, offset_m: [0.2, 0.1, 0.9], accel_noise_density: 0, "
      "gyro_noise_density: 0, accel_bias_walk: 0, gyro_bias_walk: 0, accel_bias_sigma: 0, gyro_bias_sigma: 0}\n"
      "      - {id: imu_blade, type: imu, link: blade, rate_hz: 240}\n";
  std::vector<std::vector<ImuSample>> runs;
  double yaw_change = 0;
  for (int threads : {1, 2}) {
    Simulator sim(parseScenario(scenarioYaml(threads, controller, imus), "s.yaml"));
    const double yaw0 = sim.machine(0).yaw();
    std::vector<Event> ev;
    std::vector<ImuSample> got;
    while (sim.next(ev)) {
      for (std::size_t k = 1; k < ev.size(); ++k) ASSERT_LE(stampOf(ev[k - 1]), stampOf(ev[k]));
      for (auto& e : ev)
        if (auto* s = std::get_if<ImuSample>(&e)) got.push_back(*s);
      ev.clear();
    }
    yaw_change = std::remainder(sim.machine(0).yaw() - yaw0, 2 * M_PI);
    runs.push_back(std::move(got));
  }
  ASSERT_EQ(runs[0].size(), runs[1].size());
  for (std::size_t k = 0; k < runs[0].size(); ++k) {
    ASSERT_EQ(runs[0][k].frame, runs[1][k].frame);
    ASSERT_EQ(runs[0][k].stamp, runs[1][k].stamp);
    ASSERT_EQ(runs[0][k].accel_mps2, runs[1][k].accel_mps2);
    ASSERT_EQ(runs[0][k].gyro_radps, runs[1][k].gyro_radps);
  }
  // 1 s: instants 1/120 .. 119/120 (t = 0 has no earlier pose; t = 1 s waits for the next one).
  std::vector<double> base_stamps;
  double yaw_integral = 0, fz = 0;
  long blade = 0;
  for (const ImuSample& s : runs[0]) {
    if (s.frame == "ctl1/imu_blade") {
      ++blade;
      continue;
    }
    ASSERT_EQ(s.frame, "ctl1/imu_base");
    base_stamps.push_back(s.stamp);
    yaw_integral += s.gyro_radps.z() / 120.0;  // the base's z is near map-up on gentle hills
    fz += s.accel_mps2.z();
  }
  ASSERT_EQ(base_stamps.size(), 119u);
  for (std::size_t k = 0; k < base_stamps.size(); ++k) EXPECT_NEAR(base_stamps[k], (k + 1) / 120.0, 1e-12);
  EXPECT_EQ(blade, 239);
  // The noise-free base IMU's yaw rate integrates to the machine's turn (the samples cover
  // [1/240, 1 - 1/240] s of it): within 5 % of a turn that is itself clearly non-zero.
  EXPECT_GT(std::abs(yaw_change), 0.02);
  EXPECT_NEAR(yaw_integral, yaw_change, 0.05 * std::abs(yaw_change) + 0.01);
  EXPECT_NEAR(fz / 119.0, kG, 0.5);  // on average the ground carries the machine
}

TEST(Imu, TheEpisodeRecordsEverySample) {
  const std::string imus = "      - {id: imu_base, type: imu, rate_hz: 60}\n";
  const Scenario sc = parseScenario(
      scenarioYaml(1, "{type: route, start_m: [0, 0], length_m: 4, passes: 1, depth_m: 0.05}", imus), "s.yaml");
  const std::string dir = std::string(TERRAMAP_BINARY_DIR) + "/sim_test_imu_episode";
  std::filesystem::remove_all(dir);
  const std::string path = runEpisode(sc, dir);
  Simulator sim(sc);
  std::vector<Event> ev;
  std::vector<ImuSample> want;
  while (sim.next(ev)) {
    for (auto& e : ev)
      if (auto* s = std::get_if<ImuSample>(&e)) want.push_back(*s);
    ev.clear();
  }
  ASSERT_EQ(want.size(), 59u);
  std::vector<std::uint64_t> dims;
  const auto stamp = readEpisodeDataset(path, "/machines/ctl1/imu/imu_base/stamp", dims);
  ASSERT_EQ(stamp.size(), want.size());
  const auto acc = readEpisodeDataset(path, "/machines/ctl1/imu/imu_base/accel_mps2", dims);
  ASSERT_EQ(dims.size(), 2u);
  const auto gyr = readEpisodeDataset(path, "/machines/ctl1/imu/imu_base/gyro_radps", dims);
  for (std::size_t k = 0; k < want.size(); ++k) {
    EXPECT_EQ(stamp[k], want[k].stamp);
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(acc[3 * k + a], want[k].accel_mps2[a]);
      EXPECT_EQ(gyr[3 * k + a], want[k].gyro_radps[a]);
    }
  }
}

TEST(Imu, BadKeysAreNamed) {
  auto message = [](const std::string& sensor) {
    try {
      parseScenario(scenarioYaml(1, "{type: route}", sensor), "s.yaml");
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const std::string rate = message("      - {id: u, type: imu, rate_hz: 100}\n");  // 240 / 100 is not whole
  EXPECT_NE(rate.find("sensors[1].rate_hz"), std::string::npos) << rate;
  const std::string link = message("      - {id: u, type: imu, link: boom}\n");
  EXPECT_NE(link.find("sensors[1].link"), std::string::npos) << link;
  const std::string key = message("      - {id: u, type: imu, accel_noise: 0.1}\n");
  EXPECT_NE(key.find("sensors[1].accel_noise"), std::string::npos) << key;
}
