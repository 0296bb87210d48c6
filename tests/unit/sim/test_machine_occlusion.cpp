// The simulated LiDAR sees the machines (include/terramap/sim/machine_shape.hpp): exact ray-box
// entry against an analytic computation, a box hides the ground behind it and returns points on
// itself, determinism with boxes, and the simulator placing every machine's shape at its true
// pose at the scan instant (the blade hides the ground it is cutting).
#include <terramap/core/error.hpp>
#include <terramap/sim/lidar.hpp>
#include <terramap/sim/machine_shape.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/simulator.hpp>
#include <terramap/sim/world.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>

#include "sim_test_terrain.hpp"

using namespace terramap;
using namespace terramap::sim;

namespace {

PlacedBox boxAt(const Eigen::Vector3d& centre, const Eigen::Vector3d& half, double yaw) {
  std::vector<PlacedBox> out;
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = centre;
  T.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  placeShape({ShapeBox{"b", ShapeBox::Frame::Base, -half, half}}, T, T, out);
  return out.front();
}

/// An OS1-64 at 512 columns without range noise (the exact geometry the tests compare).
SensorSpec noiselessOs1() {
  SensorSpec ss;
  applyLidarPreset("os1_64", ss);
  ss.range_noise_m = 0;
  ss.columns = 512;
  return ss;
}

}  // namespace

TEST(MachineShape, RayEntersABoxWhereTheAnalyticSlabsSay) {
  // An axis-aligned box [1, 3] x [-1, 1] x [0, 2] and rays from the origin at 1 m height: the
  // entry is through the x = 1 face at t = 1 / d_x when the ray is inside the other slabs there.
  const std::vector<PlacedBox> boxes = {boxAt({2, 0, 1}, {1, 1, 1}, 0.0)};
  const Eigen::Vector3d o(0, 0, 1);
  for (double az : {-0.4, -0.1, 0.0, 0.2, 0.44})
    for (double el : {-0.3, 0.0, 0.3}) {
      const Eigen::Vector3d d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
      Eigen::Vector3d n;
      const double t = firstBoxHit(boxes, o, d, 0.0, 100.0, &n);
      const double tx = 1.0 / d.x();
      const Eigen::Vector3d p = o + tx * d;
      const bool through_front = std::abs(p.y()) <= 1.0 && p.z() >= 0.0 && p.z() <= 2.0;
      if (through_front) {
        EXPECT_NEAR(t, tx, 1e-12) << az << " " << el;
        EXPECT_NEAR(n.x(), -1.0, 1e-12);
      } else {
        // Enters through a side (y = +-1) or the top/bottom: still the first slab crossing.
        EXPECT_TRUE(std::isfinite(t) ? t > tx : true) << az << " " << el;
      }
    }
  // Rotated by 90 degrees, the same box spans [1, 3] in y (centre (0, 2)): a ray along +y enters at t = 1.
  const std::vector<PlacedBox> turned = {boxAt({0, 2, 1}, {1, 1, 1}, M_PI / 2)};
  EXPECT_NEAR(firstBoxHit(turned, o, Eigen::Vector3d::UnitY(), 0.0, 100.0, nullptr), 1.0, 1e-12);
  // Misses, range limits, and a ray that starts inside a box (a sensor in its housing).
  EXPECT_TRUE(std::isinf(firstBoxHit(boxes, o, -Eigen::Vector3d::UnitX(), 0.0, 100.0, nullptr)));
  EXPECT_TRUE(std::isinf(firstBoxHit(boxes, o, Eigen::Vector3d::UnitX(), 0.0, 0.9, nullptr)));
  EXPECT_TRUE(std::isinf(firstBoxHit(boxes, o, Eigen::Vector3d::UnitX(), 1.1, 100.0, nullptr)));
  EXPECT_TRUE(std::isinf(firstBoxHit(boxes, Eigen::Vector3d(2, 0, 1), Eigen::Vector3d::UnitX(), 0.0, 100.0, nullptr)));
}

TEST(MachineShape, ABoxHidesTheGroundBehindItAndReturnsPointsOnItself) {
  const TruthTerrain t = test::flatTerrain40m();
  const LidarModel L(noiselessOs1());
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(0, 0, 2.0);
  // A wall 3 m ahead: x in [3, 3.2], y in [-1, 1], z in [0, 1.5] (a blade-sized obstacle).
  const std::vector<PlacedBox> wall = {boxAt({3.1, 0, 0.75}, {0.1, 1.0, 0.75}, 0.0)};
  std::vector<PointXYZI> bare, seen;
  L.scan(t, T, 9, nullptr, bare);
  L.scan(t, T, 9, nullptr, seen, &wall);
  ASSERT_EQ(bare.size(), seen.size());  // the wall only changes where the rays stop
  long on_wall = 0, behind_before = 0, behind_after = 0;
  // The wall's shadow on the ground, analytically: the segment from the sensor to a ground
  // point crosses the front face (x = 3) or the top face (z = 1.5) within the wall's extent.
  const Eigen::Vector3d o = T.translation();
  auto shadowed = [&](const Eigen::Vector3d& g) {
    if (!(g.x() > 3.2) || std::abs(g.z()) > 1e-6) return false;
    auto at = [&](double x) { return o + (g - o) * ((x - o.x()) / (g.x() - o.x())); };
    const Eigen::Vector3d f = at(3.0), b = at(3.2);
    const bool front = std::abs(f.y()) <= 1.0 && f.z() >= 0.0 && f.z() <= 1.5;
    const double s_top = (1.5 - o.z()) / (g.z() - o.z());  // where the segment crosses z = 1.5
    const Eigen::Vector3d top = o + (g - o) * s_top;
    const bool through_top = f.z() > 1.5 && b.z() <= 1.5 && top.x() >= 3.0 && top.x() <= 3.2 && std::abs(top.y()) <= 1.0;
    return front || through_top;
  };
  for (std::size_t k = 0; k < seen.size(); ++k) {
    const Eigen::Vector3d b = T * Eigen::Vector3d(bare[k].x, bare[k].y, bare[k].z);
    const Eigen::Vector3d s = T * Eigen::Vector3d(seen[k].x, seen[k].y, seen[k].z);
    behind_before += shadowed(b);
    const bool on_box = std::abs(s.x() - 3.1) <= 0.1 + 1e-9 && std::abs(s.y()) <= 1.0 + 1e-9 && s.z() >= -1e-9 &&
                        s.z() <= 1.5 + 1e-9;
    if (on_box) {
      ++on_wall;
      EXPECT_TRUE(shadowed(b)) << k;  // only the rays that would have landed in the shadow stop on the wall
    } else {
      // Every other point is where it was without the wall; none is on the ground in the shadow.
      ASSERT_NEAR((s - b).norm(), 0.0, 1e-9) << k;
      behind_after += shadowed(s);
    }
  }
  EXPECT_GT(behind_before, 500);
  EXPECT_EQ(behind_after, 0);
  EXPECT_EQ(on_wall, behind_before);  // exactly the shadowed rays stop on the wall
}

TEST(MachineShape, ScansWithBoxesAreThreadIndependent) {
  const TruthTerrain t = test::flatTerrain40m();
  SensorSpec ss;
  applyLidarPreset("os1_64", ss);
  ss.dropout = 0.05;
  const LidarModel L(ss);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(0.3, 0, 2.4);
  std::vector<PlacedBox> boxes;
  const Eigen::Isometry3d base = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d blade = Eigen::Isometry3d::Identity();
  blade.translation() = Eigen::Vector3d(1.9, 0, -0.05);
  placeShape(defaultCtlShape(1.6, 1.9, 1.85, 0.76), base, blade, boxes);
  std::vector<PointXYZI> a, b;
  L.scan(t, T, 3, nullptr, a, &boxes);
  Executor ex(2);
  L.scan(t, T, 3, &ex, b, &boxes);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(0, std::memcmp(a.data(), b.data(), a.size() * sizeof(PointXYZI)));
}

TEST(MachineShape, TheSimulatorsBladeHidesTheGroundItCuts) {
  // One machine cutting with a single-line LiDAR looking down over the blade (as in the demo).
  // The physics does not depend on what the LiDAR sees, so both runs cast the same rays at the
  // same poses: with the machines visible, the rays that reach the ground within 1.5 m ahead of
  // the blade face (within its width) past its top in the ablation stop on the plate instead,
  // at the blade's true pose; the ablation has no point on the blade.
  const char* yaml = R"(version: 1
name: occlusion
seed: 3
duration_s: 2
threads: 1
localisation: perfect
terrain: {size_m: [12, 8], origin_m: [-3, -4], resolution_m: 0.02}
soil: {default: {family: loam, relative_density: 0.3}}
machines:
  - id: ctl1
    pose: {x_m: 0, y_m: 0, yaw_deg: 0}
    controller: {type: route, start_m: [0, 0], heading_deg: 0, length_m: 5, passes: 1, depth_m: 0.04, speed_mps: 0.5}
    sensors:
      - {id: front_line, type: lidar, preset: single_line, offset_m: [0.8, 0, 2.0], rotation_deg: [0, 50, 0], range_noise_m: 0}
)";
  long on_blade_seen[2] = {0, 0}, ahead_seen[2] = {0, 0};
  for (bool sees : {true, false}) {
    Scenario sc = parseScenario(yaml, "occlusion.yaml");
    sc.lidar_sees_machines = sees;
    Simulator sim(sc);
    std::vector<Event> ev;
    long on_blade = 0, ahead = 0;
    while (sim.next(ev)) {
      for (const Event& e : ev) {
        const auto* pc = std::get_if<PointCloud>(&e);
        if (!pc) continue;
        const Eigen::Isometry3d T_blade_map = sim.machineTruth(0).T_map_blade.inverse();
        for (const PointXYZI& p : pc->points) {
          if (std::isnan(p.x)) continue;
          const Eigen::Vector3d pm = pc->T_map_sensor * Eigen::Vector3d(p.x, p.y, p.z);
          const Eigen::Vector3d pb = T_blade_map * pm;
          // On the plate (its back, x = -0.05 m, or its top), within the blade's motion between
          // the scan and the period's end (< 1 cm at 0.5 m/s over 1/60 s).
          if (pb.x() > -0.06 && pb.x() < 0.01 && std::abs(pb.y()) <= 0.935 && pb.z() > -0.01 && pb.z() < 0.77) ++on_blade;
          else if (pb.x() > 0.02 && pb.x() < 1.5 && std::abs(pb.y()) < 0.9) ++ahead;
        }
      }
      ev.clear();
    }
    on_blade_seen[sees] = on_blade;
    ahead_seen[sees] = ahead;
  }
  EXPECT_EQ(on_blade_seen[0], 0);
  EXPECT_GT(on_blade_seen[1], 200);
  // The rays that stopped on the blade are missing from the ground ahead of it (most of them:
  // a few would have reached the ground beyond 1.5 m or beside the 0.9 m half-width band).
  EXPECT_LT(ahead_seen[1], ahead_seen[0] - on_blade_seen[1] / 2) << ahead_seen[1] << " " << ahead_seen[0] << " "
                                                                  << on_blade_seen[1];
}

TEST(MachineShape, ScenarioShapeKeyReplacesTheDefaultAndReportsMistakes) {
  const std::string head = R"(version: 1
terrain: {size_m: [6, 6], origin_m: [-3, -3], resolution_m: 0.02}
soil: {default: {family: loam, relative_density: 0.3}}
machines:
  - id: ctl1
)";
  const Scenario def = parseScenario(head, "s.yaml");
  ASSERT_EQ(def.machines[0].shape.size(), 7u);  // tracks, body, cab, arms, blade
  EXPECT_EQ(def.machines[0].shape.back().frame, ShapeBox::Frame::Blade);
  EXPECT_TRUE(def.lidar_sees_machines);
  const Scenario none = parseScenario(head + "    shape: []\n", "s.yaml");
  EXPECT_TRUE(none.machines[0].shape.empty());
  const Scenario one = parseScenario(head + "    shape: [{name: mast, frame: base, min: [0, -0.1, 2], max: [0.2, 0.1, 3]}]\n", "s.yaml");
  ASSERT_EQ(one.machines[0].shape.size(), 1u);
  EXPECT_EQ(one.machines[0].shape[0].max.z(), 3.0);
  try {
    parseScenario(head + "    shape: [{frame: side, min: [0, 0, 0], max: [1, 1, -1]}]\n", "s.yaml");
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("machines[0].shape[0].frame"), std::string::npos) << m;
    EXPECT_NE(m.find("'side'"), std::string::npos) << m;
    EXPECT_NE(m.find("machines[0].shape[0].max"), std::string::npos) << m;
  }
}

TEST(MachineShape, AColumnsBeamRangesKeepEveryRayThatHitsABox) {
  // The scan tries a box only on the beams whose elevation reaches its slice by the column's
  // plane. Against every ray tried on every box (and the terrain's exact cast): boxes all round
  // a tilted 64-beam sensor, above, below, behind, astride its vertical and around it, turned
  // every way; the organised, noise-free cloud must be the same ray for ray.
  const TruthTerrain t = test::flatTerrain40m();
  SensorSpec ss = noiselessOs1();
  ss.dropout = 0;
  ss.keep_dropouts = true;
  const LidarModel L(ss);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(0.12, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(-0.08, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.3, 0.1, 2.4);
  std::vector<PlacedBox> boxes;
  placeShape(defaultCtlShape(1.6, 1.9, 1.85, 0.76), Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity(), boxes);
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> U(-1, 1);
  for (int k = 0; k < 40; ++k) {
    Eigen::Isometry3d B = Eigen::Isometry3d::Identity();
    B.linear() = (Eigen::AngleAxisd(3 * U(rng), Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(U(rng), Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(U(rng), Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    // Near the sensor (some hold it or its vertical) and farther out.
    const double reach = k < 10 ? 0.8 : 6.0;
    B.translation() = T.translation() + Eigen::Vector3d(reach * U(rng), reach * U(rng), (k < 10 ? 0.8 : 2.0) * U(rng));
    const Eigen::Vector3d half(0.1 + 0.6 * std::abs(U(rng)), 0.05 + 0.4 * std::abs(U(rng)), 0.05 + 0.5 * std::abs(U(rng)));
    placeShape({ShapeBox{"b", ShapeBox::Frame::Base, -half, half}}, B, B, boxes);
  }
  std::vector<PointXYZI> cloud;
  L.scan(t, T, 5, nullptr, cloud, &boxes);
  ASSERT_EQ(cloud.size(), L.directions().size());
  std::vector<int> all(boxes.size());
  for (std::size_t q = 0; q < boxes.size(); ++q) all[q] = static_cast<int>(q);
  const Eigen::Vector3d o = T.translation();
  long on_boxes = 0, differ = 0;
  for (std::size_t k = 0; k < cloud.size(); ++k) {
    const Eigen::Vector3d& ds = L.directions()[k];
    const Eigen::Vector3d dm = T.linear() * ds;
    double tr = t.raycast(o, dm, ss.min_range_m, ss.max_range_m);
    const double tb = firstBoxHit(boxes.data(), all.data(), static_cast<int>(all.size()), o, dm, ss.min_range_m,
                                  std::isnan(tr) ? ss.max_range_m : tr, nullptr);
    if (tb < std::numeric_limits<double>::infinity()) {
      tr = tb;
      ++on_boxes;
    }
    const PointXYZI& p = cloud[k];
    if (std::isnan(tr) != std::isnan(p.x)) {
      ++differ;
      continue;
    }
    if (!std::isnan(tr) && (Eigen::Vector3d(p.x, p.y, p.z) - ds * tr).norm() > 1e-4) ++differ;
  }
  EXPECT_GT(on_boxes, 2000) << "the boxes stand in the scan";
  EXPECT_EQ(differ, 0) << "rays whose point differs from every box and the terrain tried";
}
