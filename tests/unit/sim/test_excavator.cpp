// The excavator (sim/excavator.hpp, docs/sim.md "Excavators"): TERA's Eq. 1 followed exactly at
// any physics step, the inverse kinematics, joint efforts equal to the gradient of the potential
// energy (and to the virtual work of a lip force), the relief stall, the bucket mesh's vertical
// spans against point sampling, and a dig-and-dump cycle that moves soil from a trench to a
// pile with the mass kept, bit-identical at 1 and 2 threads beside a LiDAR-carrying loader.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/sim/excavator.hpp>
#include <terramap/sim/simulator.hpp>

#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>

using namespace terramap;
using namespace terramap::sim;

namespace {

constexpr double kG = 9.80665;
constexpr double kDeg = M_PI / 180;

/// ∫_0^t e^{-βs} sin(ηs + φ) ds (Eq. 1's transient, integrated by hand).
double transientIntegral(double eta, double beta, double phi, double t) {
  auto F = [&](double s) {
    return std::exp(-beta * s) * (-beta * std::sin(eta * s + phi) - eta * std::cos(eta * s + phi)) /
           (beta * beta + eta * eta);
  };
  return F(t) - F(0);
}

Eigen::Isometry3d tiltedBase() {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(3 * kDeg, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(5 * kDeg, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(1.0, -2.0, 0.3);
  return T;
}

/// Potential energy (J) of the links beyond the slew bearing and a load in the bucket, from the
/// link positions alone.
double potential(const ExcavatorArm& arm, const std::array<double, 4>& q, const Eigen::Isometry3d& T_map_base,
                 double load_kg) {
  const ArmSpec& s = arm.spec();
  const Eigen::Isometry3d T_map_slew = T_map_base * arm.T_base_slew(q);
  const auto c = arm.chain(q);
  auto z = [&](const Eigen::Vector2d& p) { return (T_map_slew * Eigen::Vector3d(p.x(), 0, p.y())).z(); };
  const double z_bucket = (T_map_base * arm.T_base_bucket(q) * arm.mesh().centroid()).z();
  return kG * (s.mass_kg[0] * T_map_slew.translation().z() + s.mass_kg[1] * 0.5 * (z(c[0]) + z(c[1])) +
               s.mass_kg[2] * 0.5 * (z(c[1]) + z(c[2])) + (s.mass_kg[3] + load_kg) * z_bucket);
}

std::string digDumpYaml(int threads, double duration, bool with_loader) {
  std::string y = "version: 1\nseed: 4\nduration_s: " + std::to_string(duration) + "\nthreads: " + std::to_string(threads) +
                  "\nterrain: {size_m: [12, 12], origin_m: [-6, -6], resolution_m: 0.02}\n"
                  "soil: {default: {family: loam, relative_density: 0.4}}\n"
                  "machines:\n"
                  "  - id: ex1\n    type: excavator\n"
                  "    controller: {type: dig_dump, dig_m: [3.4, 0], dump_m: [0.3, 3.2], depth_m: 0.25, drag_m: 1.0}\n";
  if (with_loader)
    y += "  - id: ctl1\n    pose: {x_m: -4, y_m: -4}\n"
         "    controller: {type: route, start_m: [-4, -4], length_m: 6, passes: 1, depth_m: 0.05}\n"
         "    sensors:\n      - {id: lidar, type: lidar, preset: vlp32, offset_m: [0.3, 0, 2.4], columns: 512}\n";
  return y;
}

}  // namespace

TEST(Excavator, AJointFollowsTeraEq1WhateverThePhysicsStep) {
  // The closed form of Eq. 1 from rest, integrated: q(t) = q0 + w_ss (t + ∫ sin(ηs+φ) e^{-βs} ds).
  // A step of 1/20 s is η dt = 1 rad per step: an Euler integration of the oscillator is far
  // off there; the superposed closed form is exact at any step.
  for (double phi : {0.0, -0.5 * M_PI, 0.4}) {
    ArmSpec spec;
    spec.joints[kArm].phi = phi;
    const ArmJointSpec& J = spec.joints[kArm];
    const double w_ss = 0.6 * J.max_rate_rps, t = 0.5;
    const double expected = transientIntegral(J.eta, J.beta, phi, t);
    for (int steps : {120, 10}) {
      ExcavatorArm arm(spec);
      const double q0 = arm.q()[kArm];
      ArmCommand c;
      c.lever[kArm] = 0.6;
      for (int k = 0; k < steps; ++k) arm.step(t / steps, c, Eigen::Isometry3d::Identity(), Eigen::Vector3d::Zero(), 0);
      EXPECT_NEAR(arm.q()[kArm], q0 + w_ss * (t + expected), 1e-9) << "phi " << phi << ", " << steps << " steps";
      EXPECT_NEAR(arm.q()[kBoom], spec.initial_rad[kBoom], 1e-12) << "a joint without a lever stays";
    }
  }
}

TEST(Excavator, InverseKinematicsPutsTheLipWhereAsked) {
  const ExcavatorArm arm{ArmSpec{}};
  int checked = 0;
  for (double x : {2.2, 3.0, 3.8})
    for (double z : {-1.4, -0.6, 0.3})
      for (double psi : {-80 * kDeg, -125 * kDeg, -200 * kDeg}) {
        std::array<double, 4> q = arm.inverse({0.3, 0, 0, 0}, x, z, psi);
        ASSERT_EQ(q[kSlew], 0.3);
        const Eigen::Vector3d lip =
            Eigen::AngleAxisd(-0.3, Eigen::Vector3d::UnitZ()) * (arm.lipInBase(q) - arm.T_base_slew(q).translation());
        // Only reachable targets come back exactly; the others are moved onto the reach ring.
        if (std::hypot(lip.x() - x, lip.z() - z) > 1e-6) continue;
        EXPECT_NEAR(lip.y(), 0.0, 1e-12);
        EXPECT_NEAR(std::remainder(q[kBoom] + q[kArm] + q[kBucket] - psi, 2 * M_PI), 0.0, 1e-12);
        EXPECT_LT(q[kArm], 0.0) << "elbow up";
        ++checked;
      }
  EXPECT_GE(checked, 20);
}

TEST(Excavator, JointEffortsAreTheGradientOfThePotentialEnergy) {
  const ExcavatorArm arm{ArmSpec{}};
  const Eigen::Isometry3d Tb = tiltedBase();
  const std::array<double, 4> q{0.4, 15 * kDeg, -95 * kDeg, -60 * kDeg};
  for (double load : {0.0, 180.0}) {
    const auto tau = arm.efforts(q, Tb, Eigen::Vector3d::Zero(), load);
    for (int k = 0; k < 4; ++k) {
      std::array<double, 4> a = q, b = q;
      a[k] += 1e-6;
      b[k] -= 1e-6;
      const double dV = (potential(arm, a, Tb, load) - potential(arm, b, Tb, load)) / 2e-6;
      EXPECT_NEAR(tau[k], dV, 1e-3 * std::max(1.0, std::abs(dV))) << "joint " << k << ", load " << load;
    }
    if (load > 0) {
      EXPECT_GT(std::abs(tau[kBucket]), 1.0) << "a load in the bucket loads its joint";
    }
  }
  // A soil force on the lip: the effort balances its virtual work, -F . d(lip)/dq.
  const Eigen::Vector3d F(-4000, 700, 2500);
  const auto tau_f = arm.efforts(q, Tb, F, 0), tau_0 = arm.efforts(q, Tb, Eigen::Vector3d::Zero(), 0);
  for (int k = 0; k < 4; ++k) {
    std::array<double, 4> a = q, b = q;
    a[k] += 1e-6;
    b[k] -= 1e-6;
    const Eigen::Vector3d dp = (Tb * arm.lipInBase(a) - Tb * arm.lipInBase(b)) / 2e-6;
    EXPECT_NEAR(tau_f[k] - tau_0[k], -F.dot(dp), 1e-3 * std::max(1.0, F.norm() * dp.norm())) << "joint " << k;
  }
}

TEST(Excavator, AJointStallsAgainstALoadBeyondItsReliefButLowersUnderIt) {
  ArmSpec weak;
  weak.joints[kBoom].max_torque_nm = 2000;  // the boom's own weight needs several kN·m
  for (double lever : {1.0, -1.0}) {
    ExcavatorArm arm(weak), strong{ArmSpec{}};
    const double q0 = arm.q()[kBoom];
    ArmCommand c;
    c.lever[kBoom] = lever;
    for (int k = 0; k < 60; ++k) {
      arm.step(1.0 / 240, c, Eigen::Isometry3d::Identity(), Eigen::Vector3d::Zero(), 0);
      strong.step(1.0 / 240, c, Eigen::Isometry3d::Identity(), Eigen::Vector3d::Zero(), 0);
    }
    EXPECT_GT(arm.torque()[kBoom], weak.joints[kBoom].max_torque_nm);
    if (lever > 0) {
      EXPECT_EQ(arm.q()[kBoom], q0) << "the boom cannot lift itself";
      EXPECT_TRUE(arm.stalled()[kBoom]);
      EXPECT_GT(strong.q()[kBoom], q0 + 0.05) << "with its real relief it lifts";
    } else {
      EXPECT_LT(arm.q()[kBoom], q0 - 0.05) << "lowering works with the load";
      EXPECT_FALSE(arm.stalled()[kBoom]);
    }
  }
}

TEST(Excavator, TheBucketMeshsVerticalSpanMatchesPointSampling) {
  const BucketMesh mesh = bucketMesh(ArmSpec{});
  // The default profile's area by the shoelace formula: 0.7128 L D (0.105 m^3: a TB235's bucket).
  EXPECT_NEAR(mesh.volume(), 0.7128 * 0.72 * 0.34 * 0.6, 1e-12);
  auto inside = [&](const Eigen::Vector3d& b) {
    if (std::abs(b.y()) > 0.5 * mesh.width_m) return false;
    for (std::size_t k = 0; k < mesh.profile.size(); ++k) {
      const Eigen::Vector2d p = mesh.profile[k], e = mesh.profile[(k + 1) % mesh.profile.size()] - p;
      if (e.x() * (b.z() - p.y()) - e.y() * (b.x() - p.x()) < 0) return false;
    }
    return true;
  };
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> U(-1, 1);
  int hits = 0, lines = 0;
  for (int pose = 0; pose < 6; ++pose) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = (Eigen::AngleAxisd(3 * U(rng), Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(3 * U(rng), Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(0.3 * U(rng), Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    T.translation() = Eigen::Vector3d(U(rng), U(rng), U(rng));
    for (int n = 0; n < 200; ++n) {
      const double x = T.translation().x() + 0.8 * U(rng), y = T.translation().y() + 0.8 * U(rng);
      double lo = 1e300, hi = -1e300;
      for (double z = T.translation().z() - 1.0; z <= T.translation().z() + 1.0; z += 5e-4)
        if (inside(T.inverse() * Eigen::Vector3d(x, y, z))) {
          lo = std::min(lo, z);
          hi = std::max(hi, z);
        }
      double zl, zh;
      const bool hit = mesh.verticalSpan(T, x, y, zl, zh);
      ++lines;
      if (lo > hi) {
        EXPECT_TRUE(!hit || zh - zl < 1e-3) << "a line the samples miss";
        continue;
      }
      ASSERT_TRUE(hit);
      ++hits;
      EXPECT_NEAR(zl, lo, 5e-4);
      EXPECT_NEAR(zh, hi, 5e-4);
    }
  }
  EXPECT_GT(hits, lines / 10);
}

TEST(Excavator, ABucketTakesItsWidthWhereverItStandsOnTheNodeGrid) {
  // A bucket 0.61 m wide (30.5 node spacings at 2 cm), square to the grid, 0.1 m into flat
  // ground, centred at several offsets. Each node counts its whole 2 cm cell, so the volume is
  // the cross-section times the width wherever the walls fall; a node taken whole or not at all
  // made the bucket 0.60 or 0.62 m wide by where it stood.
  BucketMesh mesh = bucketMesh(ArmSpec{});
  mesh.width_m = 0.61;
  const SoilField soil(soilProperties(SoilFamily::Loam, 0.4), {});
  auto dig = [&](double yc, double& cross_m2) {
    TruthTerrain t(-1.0, -1.0, 0.02, 101, 101);
    t.captureInitial();
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation() = Eigen::Vector3d(0.0, yc, -0.1);
    BucketLoad load;
    const CutResult r = bucketDig(t, soil, mesh, T, 1e9, load);
    // The cross-section along the node row through the bucket's middle.
    int ic, jc;
    t.nearestNode(0.3, yc, ic, jc);
    cross_m2 = 0;
    for (int i = 0; i < t.nx(); ++i) cross_m2 += (t.initialHeight(i, jc) - t.height(i, jc)) * t.resolution();
    return r.cut_bank_m3;
  };
  for (double yc : {0.0, 0.01, 0.005, -0.013}) {
    double cross = 0;
    const double v = dig(yc, cross);
    ASSERT_GT(cross, 0.01);
    EXPECT_NEAR(v / (cross * mesh.width_m), 1.0, 1e-6) << "bucket centred at y = " << yc;
  }
}

TEST(Excavator, DigAndDumpMovesSoilFromTheTrenchToThePileKeepingItsMass) {
  Simulator sim(parseScenario(digDumpYaml(2, 15, false), "ex.yaml"));
  const TruthTerrain before = sim.truth();
  const double bank0 = before.bankVolume();
  std::vector<Event> ev;
  double worst = 0, max_load = 0;
  while (sim.next(ev)) {
    ev.clear();
    const TruthTerrain& t = sim.truth();
    const MachineTruth& tr = sim.machineTruth(0);
    max_load = std::max(max_load, tr.bucket_bank_m3);
    worst = std::max(worst, std::abs(t.bankVolume() + t.lostVolume() + t.compactedVolume() + tr.bucket_bank_m3 - bank0));
  }
  EXPECT_LT(worst, 1e-9) << "terrain + lost + compacted + in the bucket is constant";
  const MachineTruth& tr = sim.machineTruth(0);
  EXPECT_GE(tr.arm_cycle, 1) << "one dig-and-dump cycle in 15 s";
  EXPECT_GT(max_load, 0.05) << "the bucket filled (TB235 class: ~0.1 m^3 heaped)";
  EXPECT_NEAR(tr.bucket_dumped_bank_m3, tr.bucket_dug_bank_m3 - tr.bucket_bank_m3, 1e-12);
  EXPECT_GT(tr.bucket_dumped_bank_m3, 0.05);
  // Where the soil went: down along the drag line in front of the machine, up around the dump.
  const TruthTerrain& after = sim.truth();
  double dug = 0, piled = 0;
  const double a = after.resolution() * after.resolution();
  for (int j = 0; j < after.ny(); ++j)
    for (int i = 0; i < after.nx(); ++i) {
      const Eigen::Vector2d p = after.nodePosition(i, j);
      const double dh = after.height(i, j) - before.height(i, j);
      if ((p - Eigen::Vector2d(0.3, 3.2)).norm() < 1.5) piled += dh * a;
      else if (std::abs(p.y()) < 0.6 && p.x() > 1.5 && p.x() < 4.2) dug -= dh * a;
    }
  EXPECT_GT(dug, 0.8 * tr.bucket_dug_bank_m3) << "the trench lost what the bucket took";
  const double swell = soilProperties(SoilFamily::Loam, 0.4).swell;
  EXPECT_NEAR(piled, tr.bucket_dumped_bank_m3 * swell, 0.1 * tr.bucket_dumped_bank_m3 * swell)
      << "the pile holds the dumped soil, loose";
}

TEST(Excavator, TwoExcavatorsDigTheirOwnTrenchesKeepingTheMass) {
  // Several excavators in one scenario: each digs its trench and piles its spoil where
  // its controller says, and the mass of terrain and both buckets is conserved.
  const std::string yaml =
      "version: 1\nseed: 4\nduration_s: 15\nthreads: 2\n"
      "terrain: {size_m: [12, 16], origin_m: [-6, -10], resolution_m: 0.02}\n"
      "soil: {default: {family: loam, relative_density: 0.4}}\n"
      "machines:\n"
      "  - id: ex1\n    type: excavator\n"
      "    controller: {type: dig_dump, dig_m: [3.4, 0], dump_m: [0.3, 3.2], depth_m: 0.25, drag_m: 1.0}\n"
      "  - id: ex2\n    type: excavator\n    pose: {x_m: 0, y_m: -5}\n"
      "    controller: {type: dig_dump, dig_m: [3.4, -5], dump_m: [0.3, -8.2], depth_m: 0.25, drag_m: 1.0}\n";
  Simulator sim(parseScenario(yaml, "two.yaml"));
  const TruthTerrain before = sim.truth();
  const double bank0 = before.bankVolume();
  std::vector<Event> ev;
  double worst = 0;
  while (sim.next(ev)) {
    ev.clear();
    const TruthTerrain& t = sim.truth();
    const double in_buckets = sim.machineTruth(0).bucket_bank_m3 + sim.machineTruth(1).bucket_bank_m3;
    worst = std::max(worst, std::abs(t.bankVolume() + t.lostVolume() + t.compactedVolume() + in_buckets - bank0));
  }
  EXPECT_LT(worst, 1e-9) << "terrain + lost + compacted + in both buckets is constant";
  const TruthTerrain& after = sim.truth();
  const double a = after.resolution() * after.resolution();
  const std::array<Eigen::Vector2d, 2> base{Eigen::Vector2d(0, 0), Eigen::Vector2d(0, -5)};
  const std::array<Eigen::Vector2d, 2> dump{Eigen::Vector2d(0.3, 3.2), Eigen::Vector2d(0.3, -8.2)};
  for (int m = 0; m < 2; ++m) {
    const MachineTruth& tr = sim.machineTruth(m);
    EXPECT_GE(tr.arm_cycle, 1) << "machine " << m;
    EXPECT_GT(tr.bucket_dumped_bank_m3, 0.05) << "machine " << m;
    double dug = 0, piled = 0;
    for (int j = 0; j < after.ny(); ++j)
      for (int i = 0; i < after.nx(); ++i) {
        const Eigen::Vector2d p = after.nodePosition(i, j);
        const double dh = after.height(i, j) - before.height(i, j);
        const Eigen::Vector2d q = p - base[m];
        if ((p - dump[m]).norm() < 1.5) piled += dh * a;
        else if (std::abs(q.y()) < 0.6 && q.x() > 1.5 && q.x() < 4.2) dug -= dh * a;
      }
    EXPECT_GT(dug, 0.8 * tr.bucket_dug_bank_m3) << "machine " << m << ": its trench lost what its bucket took";
    EXPECT_GT(piled, 0.8 * tr.bucket_dumped_bank_m3) << "machine " << m << ": its pile holds what it dumped";
  }
}

TEST(Excavator, EncodersAndInclinometersReadTheJointsWithTheirNoise) {
  // On flat ground the base is level, so each link's angle to gravity is the sum of the joints
  // before it (the default bucket's lip lies on its pivot->lip line).
  Simulator sim(parseScenario(digDumpYaml(1, 6, false), "ex.yaml"));
  std::vector<Event> ev;
  double enc2 = 0, inc2 = 0;
  int n = 0;
  while (sim.next(ev)) {
    ev.clear();
    const MachineTruth& tr = sim.machineTruth(0);
    const double sums[3] = {tr.arm_q[kBoom], tr.arm_q[kBoom] + tr.arm_q[kArm],
                            tr.arm_q[kBoom] + tr.arm_q[kArm] + tr.arm_q[kBucket]};
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(std::remainder(tr.arm_inclination[k] - sums[k], 2 * M_PI), 0.0, 2e-3) << "link " << k;
      const double e = std::remainder(tr.arm_inclination_measured[k] - tr.arm_inclination[k], 2 * M_PI);
      inc2 += e * e;
    }
    for (int k = 0; k < 4; ++k) enc2 += std::pow(tr.arm_q_measured[k] - tr.arm_q[k], 2);
    ++n;
  }
  ASSERT_GT(n, 300);
  const ArmSpec spec;
  EXPECT_NEAR(std::sqrt(enc2 / (4 * n)), spec.encoder_noise_rad, 0.1 * spec.encoder_noise_rad);
  EXPECT_NEAR(std::sqrt(inc2 / (3 * n)), spec.inclinometer_noise_rad, 0.1 * spec.inclinometer_noise_rad);
}

TEST(Excavator, ItsJointStatesReachThePipelineAtTheObservationRate) {
  Simulator sim(parseScenario(digDumpYaml(1, 5, false), "ex.yaml"));
  std::vector<Event> ev;
  int states = 0, periods = 0;
  double max_load = 0;
  while (sim.next(ev)) {
    ++periods;
    const Observation* ob = nullptr;
    for (const Event& e : ev) {
      if (const auto* o = std::get_if<Observation>(&e)) ob = o;
      const auto* js = std::get_if<JointState>(&e);
      if (!js) continue;
      ++states;
      ASSERT_NE(ob, nullptr) << "after the machine's Observation";
      const MachineTruth& tr = sim.machineTruth(0);
      EXPECT_EQ(js->machine_id, "ex1");
      EXPECT_EQ(js->stamp, ob->stamp);
      EXPECT_EQ(js->position_rad, tr.arm_q_measured);
      EXPECT_EQ(js->effort_nm, tr.arm_torque_nm);
      EXPECT_EQ(js->bucket_load_kg, tr.bucket_load_kg);
      // The bucket where the machine believes it is: within the localisation's and encoders' error.
      EXPECT_LT((js->T_map_bucket.translation() - tr.T_map_bucket.translation()).norm(), 0.1);
      max_load = std::max(max_load, js->bucket_load_kg);
    }
    ev.clear();
  }
  EXPECT_EQ(states, periods);
  EXPECT_GT(max_load, 10.0);
  EXPECT_STREQ(kindName(EventKind::JointState), "joint_state");
  EXPECT_EQ(eventMaskFromNames({"joint_state"}), mask(EventKind::JointState));
}

TEST(Excavator, ItsCameraSeesItsOwnArmAndBucket) {
  // The depth camera on the cab looks at the dig: points more than 5 cm above the true surface
  // can only lie on the machine (its plow is outside the view), i.e. on the boom, arm or bucket.
  // Without the arm's boxes (shape: tracks only) there are none.
  auto above = [](bool arm_boxes) {
    // Noise-free camera and perfect poses, so a point above the surface is an object there.
    std::string y = digDumpYaml(2, 4, false) +
                    "    localisation: perfect\n"
                    "    sensors:\n      - {id: cam, type: depth_camera, offset_m: [0.2, 0.45, 2.3], rotation_deg: [0, 35, 0],"
                    " noise_abs_m: 0, noise_k_per_m: 0}\n";
    if (!arm_boxes) y += "    shape: [{name: t, frame: base, min: [-1.1, -0.8, 0], max: [1.1, 0.8, 0.5]}]\n";
    Simulator sim(parseScenario(y, "ex.yaml"));
    std::vector<Event> ev;
    long n = 0;
    while (sim.next(ev)) {
      for (const Event& e : ev)
        if (const auto* pc = std::get_if<PointCloud>(&e))
          for (const PointXYZI& p : pc->points) {
            if (!std::isfinite(p.x)) continue;
            const Eigen::Vector3d m = pc->T_map_sensor * Eigen::Vector3d(p.x, p.y, p.z);
            if (m.z() > sim.truth().heightAt(m.x(), m.y()) + 0.05) ++n;
          }
      ev.clear();
    }
    return n;
  };
  const long with = above(true), without = above(false);
  std::printf("[ camera-sees-arm ] points above the surface: %ld with the arm's boxes, %ld without\n", with, without);
  EXPECT_GT(with, 500);
  EXPECT_EQ(without, 0);
}

TEST(Excavator, AnImuOnTheBoomTurnsWithTheBoom) {
  // On level ground with the base still, the boom frame turns about its own y axis by -(boom
  // angle) and about the vertical with the slew, which has no y component there: the integrated
  // y rate of a boom IMU (biases off) is minus the boom's angle change, all along the run.
  const std::string y = digDumpYaml(1, 12, false) + "    localisation: perfect\n    sensors:\n"
                        "      - {id: imu_boom, type: imu, link: boom, rate_hz: 120, offset_m: [1.0, 0.0, 0.2],"
                        " gyro_bias_sigma: 0, gyro_bias_walk: 0}\n";
  Simulator sim(parseScenario(y, "ex.yaml"));
  std::vector<Event> ev;
  double integral = 0, worst = 0, travel = 0, q0 = NAN, q_prev = NAN;
  while (sim.next(ev)) {
    for (const Event& e : ev)
      if (const auto* u = std::get_if<ImuSample>(&e)) integral += u->gyro_radps.y() / 120.0;
    ev.clear();
    const double q = sim.machineTruth(0).arm_q[kBoom];
    if (std::isnan(q0)) q0 = q;
    if (!std::isnan(q_prev)) travel += std::abs(q - q_prev);
    q_prev = q;
    worst = std::max(worst, std::abs(integral + (q - q0)));
  }
  EXPECT_GT(travel, 0.3) << "the boom worked";
  EXPECT_LT(worst, 0.02) << "rad";
}

TEST(Excavator, ABesideALoaderWithALidarIsBitIdenticalAtOneAndTwoThreads) {
  std::vector<double> h[2];
  std::array<double, 4> q[2];
  double load[2];
  for (int n : {1, 2}) {
    Simulator sim(parseScenario(digDumpYaml(n, 6, true), "ex.yaml"));
    std::vector<Event> ev;
    while (sim.next(ev)) ev.clear();
    h[n - 1] = sim.truth().heightData();
    q[n - 1] = sim.machineTruth(0).arm_q;
    load[n - 1] = sim.machineTruth(0).bucket_load_kg;
  }
  EXPECT_GT(load[0], 10.0) << "the bucket is digging at 6 s";
  EXPECT_TRUE(h[0] == h[1]);
  EXPECT_EQ(q[0], q[1]);
  EXPECT_EQ(load[0], load[1]);
}

TEST(Excavator, ScenarioMistakesAreNamed) {
  auto message = [](const std::string& machine) {
    try {
      parseScenario("version: 1\nterrain: {size_m: [10, 10], origin_m: [-5, -5]}\nmachines:\n" + machine, "bad.yaml");
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message("  - {id: ex, type: excavator}\n").find("dig_dump"), std::string::npos);
  const std::string far = message("  - {id: ex, type: excavator, controller: {type: dig_dump, dig_m: [4.0, 0], dump_m: [0, 7]}}\n");
  EXPECT_NE(far.find("dump_m: [0, 7] is"), std::string::npos) << far;
  EXPECT_NE(far.find("reaches from 1 m to 5.07 m"), std::string::npos) << far;
  EXPECT_EQ(far.find("dig_m"), std::string::npos) << "the dig point is within reach: " << far;
  EXPECT_NE(message("  - {id: c, arm: {boom_m: 2}}\n").find("only a machine of type excavator"), std::string::npos);
  EXPECT_NE(message("  - {id: c, controller: {type: dig_dump}}\n").find("excavator"), std::string::npos);
  const std::string bent = message(
      "  - {id: ex, type: excavator, controller: {type: dig_dump},\n"
      "     arm: {bucket: {profile_m: [[0, 0], [0.7, 0], [0.2, 0.1], [0.5, 0.3]]}}}\n");
  EXPECT_NE(bent.find("convex"), std::string::npos) << bent;
  EXPECT_NE(bent.find("bad.yaml:"), std::string::npos) << bent;
  EXPECT_NE(message("  - {id: ex, type: excavator, controller: {type: dig_dump}, arm: {joints: {bom: {}}}}\n").find("boom"),
            std::string::npos);
}
