// The localisation wired into the simulator: every pose the mapper receives (cloud sensor
// pose, Pose, BladePose, Observation) comes from the machine's PoseEstimator, while the rays
// are cast from the true sensor pose and MachineTruth stays the truth.
#include <gtest/gtest.h>

#include <terramap/sim/simulator.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

using namespace terramap;
using namespace terramap::sim;

namespace {

/// One CTL cutting a route on gentle hills with a noiseless VLP-32 (range noise and dropout
/// off, so a point's only error is the pose it is placed with).
std::string scenarioYaml(const std::string& localisation, int threads, double duration = 1.5) {
  // The LiDAR sees the terrain only (these tests compare points with the terrain they hit).
  return "version: 1\nseed: 5\nlidar_sees_machines: false\nduration_s: " + std::to_string(duration) +
         "\nthreads: " + std::to_string(threads) +
         "\nterrain: {size_m: [14, 8], origin_m: [-3, -4], resolution_m: 0.02,\n"
         "  hills: {count: 4, amplitude_m: [-0.05, 0.08], sigma_m: [0.8, 1.5], seed: 3}}\n"
         "soil: {default: {family: loam, relative_density: 0.4}}\n"
         "machines:\n  - id: ctl1\n"
         "    controller: {type: route, start_m: [0, 0], length_m: 8, passes: 1, depth_m: 0.08, speed_mps: 0.8}\n"
         "    sensors:\n"
         "      - {id: top, type: lidar, preset: vlp32, columns: 360, offset_m: [0.3, 0, 2.1], range_noise_m: 0,"
         " dropout: 0}\n" +
         (localisation.empty() ? std::string() : "    localisation: " + localisation + "\n");
}

const Eigen::Isometry3d& sensorMount(const Scenario& sc) { return sc.machines[0].sensors[0].T_base_sensor; }

double rotationAngle(const Eigen::Matrix3d& R) { return Eigen::AngleAxisd(R).angle(); }

}  // namespace

// With `perfect` the estimator returns the stored truth itself and the blade keeps the true
// joints, so every pose an event carries is the truth bit for bit (a round trip through a
// quaternion or through the inverse linkage would already differ in the last bits).
TEST(SimLocalisation, PerfectEventsAreTheTruthBitForBit) {
  const Scenario sc = parseScenario(scenarioYaml("perfect", 1), "s.yaml");
  Simulator sim(sc);
  std::vector<Event> ev;
  int poses = 0, clouds = 0;
  while (sim.next(ev)) {
    const MachineTruth& tr = sim.machineTruth(0);
    for (const Event& e : ev) {
      if (const auto* p = std::get_if<Pose>(&e)) {
        ASSERT_TRUE(p->T_map_base.matrix() == tr.T_map_base.matrix()) << "t " << p->stamp;
        ++poses;
      } else if (const auto* b = std::get_if<BladePose>(&e)) {
        ASSERT_TRUE(b->T_map_blade.matrix() == tr.T_map_blade.matrix()) << "t " << b->stamp;
      } else if (const auto* o = std::get_if<Observation>(&e)) {
        ASSERT_TRUE(o->T_map_base.matrix() == tr.T_map_base.matrix());
        ASSERT_TRUE(o->T_map_blade.matrix() == tr.T_map_blade.matrix());
        ASSERT_TRUE(o->twist_base == tr.twist_base);
        for (int k = 0; k < 3; ++k) ASSERT_EQ(o->cylinder_length_m[k], tr.cylinder_length_m[k]);
      } else if (const auto* c = std::get_if<PointCloud>(&e); c && c->stamp == sim.time()) {
        // A scan on the period's last physics step: the truth of the period is the truth at the scan.
        ASSERT_TRUE(c->T_map_sensor.matrix() == (tr.T_map_base * sensorMount(sc)).matrix());
        ++clouds;
      }
    }
    ev.clear();
  }
  EXPECT_EQ(poses, 90);
  EXPECT_GE(clouds, 14);  // scans at k / 10 s, k = 1..15 (scan 0 is at the first physics step)
}

// A constant error only (bias; no white noise, drift or latency): each estimate is the truth
// moved by the same (dp, dR). The cloud's pose carries exactly the error of the Pose event of
// its instant, and its points, placed with the TRUE sensor pose, lie on the truth terrain:
// the rays were cast from where the sensor really is.
TEST(SimLocalisation, CloudsCarryTheEstimateButAreCastFromTheTruePose) {
  const std::string bias_only =
      "{position_white_m: [0, 0, 0], position_random_walk_m: [0, 0, 0], position_bias_m: [0.05, 0.05, 0.05],"
      " attitude_white_deg: [0, 0, 0], attitude_random_walk_deg: [0, 0, 0], attitude_bias_deg: [0.5, 0.5, 0.5],"
      " latency_s: 0}";
  const Scenario sc = parseScenario(scenarioYaml(bias_only, 1), "s.yaml");
  Simulator sim(sc);
  std::vector<Event> ev;
  bool have_ref = false;
  // Set from the first period (have_ref); initialised only so that GCC's -Wmaybe-uninitialized,
  // which cannot see the flag, stays quiet.
  Eigen::Vector3d dp_ref = Eigen::Vector3d::Zero();
  Eigen::Matrix3d dR_ref = Eigen::Matrix3d::Identity();
  std::vector<double> dz_true, dz_est;
  int clouds = 0;
  while (sim.next(ev)) {
    const MachineTruth& tr = sim.machineTruth(0);
    const Pose* pose = nullptr;
    for (const Event& e : ev)
      if (const auto* p = std::get_if<Pose>(&e)) pose = p;
    ASSERT_NE(pose, nullptr);
    const Eigen::Vector3d dp = pose->T_map_base.translation() - tr.T_map_base.translation();
    const Eigen::Matrix3d dR = pose->T_map_base.linear() * tr.T_map_base.linear().transpose();
    if (!have_ref) {
      dp_ref = dp;
      dR_ref = dR;
      have_ref = true;
    }
    // The same error at every instant (to rounding of ~10 m coordinates).
    ASSERT_LT((dp - dp_ref).norm(), 1e-12);
    ASSERT_LT((dR - dR_ref).norm(), 1e-12);
    for (const Event& e : ev) {
      const auto* c = std::get_if<PointCloud>(&e);
      if (!c || c->stamp != sim.time()) continue;
      ++clouds;
      // The estimate at the scan's instant, mounted: the Pose event's estimate exactly.
      ASSERT_LT((c->T_map_sensor.matrix() - (pose->T_map_base * sensorMount(sc)).matrix()).norm(), 1e-12);
      const Eigen::Isometry3d T_true = tr.T_map_base * sensorMount(sc);
      for (std::size_t k = 0; k < c->points.size(); k += 7) {
        const PointXYZI& q = c->points[k];
        const Eigen::Vector3d ps(q.x, q.y, q.z);
        const Eigen::Vector3d a = T_true * ps, b = c->T_map_sensor * ps;
        const double ha = sim.truth().heightAt(a.x(), a.y()), hb = sim.truth().heightAt(b.x(), b.y());
        if (std::isfinite(ha)) dz_true.push_back(std::abs(a.z() - ha));
        if (std::isfinite(hb)) dz_est.push_back(std::abs(b.z() - hb));
      }
    }
    ev.clear();
  }
  ASSERT_GE(clouds, 14);
  // The drawn bias (1-sigma 5 cm per axis, 0.5 deg per angle) is not negligible for this seed.
  EXPECT_GT(dp_ref.norm(), 0.01);
  EXPECT_GT(rotationAngle(dR_ref), 1e-3);
  ASSERT_GT(dz_true.size(), 1000u);
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  // Points through the true pose meet the surface they were cast against: only the float
  // storage of sensor-frame points (~1e-6 of a <= 60 m range) and the caster's intersection
  // tolerance separate them, far below a millimetre.
  EXPECT_LT(median(dz_true), 1e-3);
  // Through the estimate they are off by about the vertical bias plus the tilt bias over the
  // range: at least several millimetres for the drawn error.
  EXPECT_GT(median(dz_est), 5e-3);
}

// Base error off, cylinder sensors noisy: the blade pose the mapper receives differs from the
// truth only through the measured cylinder lengths. The linkage is linear (L_k = base_k +
// lever_k q_k), so dq_k = dL_k / lever_k; with T_base_blade = Trans(mount, 0, lift) Rz(angle)
// Rx(tilt) Ry(.), the blade origin (the cutting-edge centre) moves by dq_0 vertically in the
// base frame and not at all horizontally, and the blade rotates by Rz(angle + dq_2) Rx(dq_1)
// Rz(-angle): an angle of sqrt(dq_1^2 + dq_2^2) up to second order (|dq_1 dq_2|).
TEST(SimLocalisation, BladePoseErrorFollowsTheCylinderNoiseThroughTheLinkage) {
  const double sw = 0.0005, sb = 0.001;  // cylinder white noise and bias, 1-sigma (m)
  const std::string cyl_only =
      "{position_white_m: [0, 0, 0], position_random_walk_m: [0, 0, 0], position_bias_m: [0, 0, 0],"
      " attitude_white_deg: [0, 0, 0], attitude_random_walk_deg: [0, 0, 0], attitude_bias_deg: [0, 0, 0],"
      " latency_s: 0, cylinder_white_m: " +
      std::to_string(sw) + ", cylinder_bias_m: " + std::to_string(sb) + "}";
  const Scenario sc = parseScenario(scenarioYaml(cyl_only, 1, 2.0), "s.yaml");
  Simulator sim(sc);
  const double half_w = 0.5 * sc.machines[0].blade.width_m;
  double l[3];
  for (int k = 0; k < 3; ++k) l[k] = CompactTrackLoader::cylinderLever(k);
  std::vector<Event> ev;
  std::vector<double> dL[3];
  double max_tip = 0;
  while (sim.next(ev)) {
    const MachineTruth& tr = sim.machineTruth(0);
    for (const Event& e : ev) {
      const auto* o = std::get_if<Observation>(&e);
      if (!o) continue;
      // Zero base sigmas: the base estimate is the truth (no rotation, no shift is added).
      ASSERT_TRUE(o->T_map_base.matrix() == tr.T_map_base.matrix());
      double dq[3];
      for (int k = 0; k < 3; ++k) {
        dL[k].push_back(o->cylinder_length_m[k] - tr.cylinder_length_m[k]);
        dq[k] = dL[k].back() / l[k];
      }
      const Eigen::Isometry3d B_est = tr.T_map_base.inverse() * o->T_map_blade;
      const Eigen::Isometry3d B_true = tr.T_map_base.inverse() * tr.T_map_blade;
      const Eigen::Vector3d d0 = B_est.translation() - B_true.translation();
      ASSERT_NEAR(d0.z(), dq[0], 1e-9);
      ASSERT_NEAR(d0.x(), 0.0, 1e-9);
      ASSERT_NEAR(d0.y(), 0.0, 1e-9);
      const double ang = rotationAngle(B_est.linear() * B_true.linear().transpose());
      ASSERT_NEAR(ang, std::hypot(dq[1], dq[2]), std::abs(dq[1] * dq[2]) + 1e-9);
      // The BladePose carries the same pose.
      for (const Event& f : ev) {
        if (const auto* b = std::get_if<BladePose>(&f)) {
          ASSERT_TRUE(b->T_map_blade.matrix() == o->T_map_blade.matrix());
        }
      }
      // Displacement of the edge's ends (+-w/2 along the blade's y axis).
      for (double s : {-half_w, half_w}) {
        const Eigen::Vector3d tip(0, s, 0);
        max_tip = std::max(max_tip, (B_est * tip - B_true * tip).norm());
      }
    }
    ev.clear();
  }
  const std::size_t n = dL[0].size();
  ASSERT_EQ(n, 120u);
  for (int k = 0; k < 3; ++k) {
    double mean = 0, var = 0;
    for (double x : dL[k]) mean += x / n;
    for (double x : dL[k]) var += (x - mean) * (x - mean) / (n - 1);
    // White part: the sample sigma of n = 120 Gaussians is within 1/sqrt(2n) = 6.5 % of sw at
    // 1-sigma; +-25 % is about 4 sigma.
    EXPECT_NEAR(std::sqrt(var), sw, 0.25 * sw) << "cylinder " << k;
    // Bias: one N(0, sb) draw per cylinder plus the mean of the white noise: 4-sigma bound.
    EXPECT_LT(std::abs(mean), 4 * sb + 4 * sw / std::sqrt(static_cast<double>(n))) << "cylinder " << k;
  }
  // The edge ends move by at most |dq_0| + (w/2) |(dq_1, dq_2)| (first order): with every
  // |dL_k| <= 4 (sb + sw) (4-sigma bias plus 4-sigma white noise over 120 draws per cylinder),
  // the bound below. It is about 2.6 cm for the default linkage and blade: a millimetre of
  // cylinder error is magnified by the 0.3 m tilt lever over the 0.9 m half-blade.
  const double dLmax = 4 * (sb + sw);
  const double bound = dLmax / l[0] + half_w * std::hypot(dLmax / l[1], dLmax / l[2]);
  EXPECT_LT(max_tip, bound);
  EXPECT_GT(max_tip, 0.0);
}

// The machine's reported velocities are its inertial navigation's: within a few sigma of the
// true twist, on the base and on the blade, so the soil estimator can tell a descending edge
// from a rising one. Differencing two pose estimates (each with millimetres of white noise)
// at 60 Hz instead gave ~0.5 m/s of noise, 20 times the default sigma.
TEST(SimLocalisation, ReportedTwistsAreTheTrueOnesWithTheNavigationsNoise) {
  const Scenario sc = parseScenario(scenarioYaml("rtk_imu", 1, 2.0), "s.yaml");
  const LocalisationSpec& ls = sc.machines[0].localisation;
  ASSERT_GT(ls.velocity_white_mps, 0.0);
  ASSERT_GT(ls.angular_rate_white_radps, 0.0);
  Simulator sim(sc);
  std::vector<Event> ev;
  double ss[2][6] = {};
  long n = 0, same_sign = 0, moving = 0;
  while (sim.next(ev)) {
    const MachineTruth& tr = sim.machineTruth(0);
    for (const Event& e : ev) {
      const auto* o = std::get_if<Observation>(&e);
      if (!o) continue;
      ++n;
      for (int a = 0; a < 6; ++a) {
        ss[0][a] += std::pow(o->twist_base[a] - tr.twist_base[a], 2);
        ss[1][a] += std::pow(o->twist_blade[a] - tr.twist_blade[a], 2);
      }
      // The edge's vertical speed in the map frame, where it is not tiny: the sign is right.
      const double vz_true = (tr.T_map_blade.linear() * tr.twist_blade.head<3>()).z();
      const double vz_est = (o->T_map_blade.linear() * o->twist_blade.head<3>()).z();
      if (std::abs(vz_true) > 4 * ls.velocity_white_mps) {
        ++moving;
        same_sign += (vz_true > 0) == (vz_est > 0);
      }
    }
    ev.clear();
  }
  ASSERT_EQ(n, 120);
  for (int b = 0; b < 2; ++b)
    for (int a = 0; a < 6; ++a) {
      const double sigma = a < 3 ? ls.velocity_white_mps : ls.angular_rate_white_radps;
      // 120 draws: the sample sigma is within +-30 % of sigma at about 4.6 sigma.
      EXPECT_NEAR(std::sqrt(ss[b][a] / n), sigma, 0.3 * sigma) << (b ? "blade" : "base") << " axis " << a;
    }
  ASSERT_GT(moving, 10);
  EXPECT_GE(same_sign, moving - 1);
}

// The realistic default: the cloud poses are the estimator's (not the truth) and the stream
// is bit-identical with one thread, two threads with the physics running ahead of the scans,
// and two threads without: the estimator is driven by the producer in simulated-time order.
TEST(SimLocalisation, RealisticCloudPosesDifferFromTheTruthAndAreThreadIndependent) {
  std::vector<double> runs[3];
  double max_dev = 0;
  for (int run = 0; run < 3; ++run) {
    Scenario sc = parseScenario(scenarioYaml("", run == 0 ? 1 : 2), "s.yaml");
    if (run == 2) sc.overlap_scans = false;
    Simulator sim(sc);
    std::vector<Event> ev;
    while (sim.next(ev)) {
      for (const Event& e : ev) {
        const auto* c = std::get_if<PointCloud>(&e);
        if (!c) continue;
        runs[run].insert(runs[run].end(), c->T_map_sensor.data(), c->T_map_sensor.data() + 16);
        if (run == 0 && c->stamp == sim.time())
          max_dev = std::max(max_dev, (c->T_map_sensor.translation() -
                                       (sim.machineTruth(0).T_map_base * sensorMount(sc)).translation())
                                          .norm());
      }
      ev.clear();
    }
  }
  ASSERT_FALSE(runs[0].empty());
  for (int run = 1; run < 3; ++run) {
    ASSERT_EQ(runs[0].size(), runs[run].size());
    EXPECT_EQ(0, std::memcmp(runs[0].data(), runs[run].data(), runs[0].size() * sizeof(double))) << "run " << run;
  }
  // rtk_imu: ~1-2 cm per axis, and 20 ms of latency at 0.8 m/s is 1.6 cm along the track.
  EXPECT_GT(max_dev, 5e-3);
}
