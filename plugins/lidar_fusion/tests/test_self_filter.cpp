// lidar_fusion's self-filter (self_filter.hpp): exactly the points inside the boxes placed at the
// latest base / blade poses are dropped and counted as `self`; bad boxes are configuration
// errors; and end to end, a simulator whose LiDAR sees the machine puts the machine into the map
// as a mound unless the filter is on.
#include "lidar_fusion.hpp"
#include "self_filter.hpp"

#include <terramap/core/error.hpp>
#include <terramap/sim/simulator.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <random>

using namespace terramap;
using namespace terramap::plugins;

TEST(SelfFilter, DropsExactlyThePointsInsideThePlacedBoxes) {
  SelfFilter f;
  // A base box [-1, 1] x [-0.5, 0.5] x [0, 2] and a blade box [-0.1, 0] x [-1, 1] x [0, 0.8], no margin.
  f.configure({-1, -0.5, 0, 1, 0.5, 2}, {-0.1, -1, 0, 0, 1, 0.8}, 0.0, "base", "blade");
  Eigen::Isometry3d base = Eigen::Isometry3d::Identity(), blade = Eigen::Isometry3d::Identity();
  base.translation() = Eigen::Vector3d(10, 5, 1);
  base.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  blade = base * Eigen::Translation3d(1.9, 0, -0.05);
  PointCloud cloud;
  cloud.T_map_sensor = base * Eigen::Translation3d(0.3, 0, 2.4);
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-3, 3);
  for (int k = 0; k < 20000; ++k)
    cloud.points.push_back({static_cast<float>(u(rng)), static_cast<float>(u(rng)), static_cast<float>(u(rng) - 1.5), 1});
  // Before any pose nothing is placed, so nothing is dropped.
  PointCloud out;
  EXPECT_EQ(f.apply(cloud, out), 0u);
  f.setBasePose("base", base);
  f.setBladePose("ctl1", blade);
  const std::size_t dropped = f.apply(cloud, out);
  // Independent count: each point into each frame by the inverse poses, then the box test.
  std::size_t expect = 0;
  std::vector<PointXYZI> kept;
  for (const PointXYZI& p : cloud.points) {
    const Eigen::Vector3d pm = cloud.T_map_sensor * Eigen::Vector3d(p.x, p.y, p.z);
    const Eigen::Vector3d pb = base.inverse() * pm, pl = blade.inverse() * pm;
    const bool in_base = pb.x() >= -1 && pb.x() <= 1 && std::abs(pb.y()) <= 0.5 && pb.z() >= 0 && pb.z() <= 2;
    const bool in_blade = pl.x() >= -0.1 && pl.x() <= 0 && std::abs(pl.y()) <= 1 && pl.z() >= 0 && pl.z() <= 0.8;
    if (in_base || in_blade) ++expect;
    else kept.push_back(p);
  }
  EXPECT_GT(expect, 100u);
  EXPECT_EQ(dropped, expect);
  ASSERT_EQ(out.points.size(), kept.size());
  for (std::size_t k = 0; k < kept.size(); ++k) EXPECT_EQ(out.points[k].x, kept[k].x);
  // The margin grows every box: more points go.
  SelfFilter g;
  g.configure({-1, -0.5, 0, 1, 0.5, 2}, {-0.1, -1, 0, 0, 1, 0.8}, 0.1, "base", "blade");
  g.setBasePose("base", base);
  g.setBladePose("ctl1", blade);
  EXPECT_GT(g.apply(cloud, out), dropped);
}

TEST(SelfFilter, LinkBoxesFollowEachExcavatorsJointStates) {
  // A bucket box [0, 0.72] x [-0.3, 0.3] x [0, 0.34] on two excavators' bucket frames, no margin.
  SelfFilter f;
  f.configure({}, {}, 0.0, "base", "blade");
  f.configureLinks({std::vector<double>{}, {}, {}, {0, -0.3, 0, 0.72, 0.3, 0.34}},
                   {"slew", "boom", "arm", "bucket"});
  EXPECT_TRUE(f.placed()) << "link boxes do not hold clouds back (a pipeline may have no excavator)";
  std::array<Eigen::Isometry3d, 4> a, b;
  a.fill(Eigen::Isometry3d::Identity());
  b.fill(Eigen::Isometry3d::Identity());
  a[3].translation() = Eigen::Vector3d(3, 0, 0.5);
  a[3].linear() = Eigen::AngleAxisd(1.2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  b[3].translation() = Eigen::Vector3d(-2, 4, 0.2);
  b[3].linear() = Eigen::AngleAxisd(-0.4, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  PointCloud cloud;
  cloud.T_map_sensor = Eigen::Isometry3d(Eigen::Translation3d(0.5, 1.0, 2.3));
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-4, 4);
  for (int k = 0; k < 40000; ++k)
    cloud.points.push_back({static_cast<float>(u(rng)), static_cast<float>(u(rng)), static_cast<float>(0.5 * u(rng) - 2), 1});
  PointCloud out;
  EXPECT_EQ(f.apply(cloud, out), 0u) << "no JointState yet: nothing placed";
  f.setLinkPoses("ex1", a);
  f.setLinkPoses("ex2", b);
  std::size_t expect = 0;
  for (const PointXYZI& p : cloud.points) {
    const Eigen::Vector3d pm = cloud.T_map_sensor * Eigen::Vector3d(p.x, p.y, p.z);
    bool in = false;
    for (const auto* L : {&a, &b}) {
      const Eigen::Vector3d q = (*L)[3].inverse() * pm;
      in = in || (q.x() >= 0 && q.x() <= 0.72 && std::abs(q.y()) <= 0.3 && q.z() >= 0 && q.z() <= 0.34);
    }
    expect += in ? 1 : 0;
  }
  EXPECT_GT(expect, 20u);
  EXPECT_EQ(f.apply(cloud, out), expect);
  EXPECT_EQ(out.points.size(), cloud.points.size() - expect);
  // The boxes move with the next JointState.
  a[3].translation().x() += 10;
  f.setLinkPoses("ex1", a);
  EXPECT_LT(f.apply(cloud, out), expect);
}

TEST(SelfFilter, BadBoxesAreConfigurationErrors) {
  SelfFilter f;
  EXPECT_THROW(f.configure({1, 2, 3, 4, 5}, {}, 0.05, "self_filter_base_m", "b"), ConfigError);
  try {
    f.configure({0, 0, 0, 1, 1, 1, 2, 0, 0, 1, 1, 1}, {}, 0.05, "self_filter_base_m", "b");
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("self_filter_base_m box 1"), std::string::npos) << e.what();
  }
  EXPECT_THROW(f.configure({}, {}, -0.1, "a", "b"), ConfigError);
  LidarFusionConfig c;
  c.self_filter_blade_m = {0, 0, 0, 1, 1};
  LidarFusion lf;
  EXPECT_THROW(lf.configure(c), ConfigError);
}

namespace {
/// Highest (map - truth) within 3 m of the machine at the end of a short demo-like run.
double worstMoundNearTheMachine(bool self_filter, long* self_drops) {
  const char* yaml = R"(version: 1
name: self
seed: 2
duration_s: 3
threads: 1
localisation: perfect
terrain: {size_m: [14, 10], origin_m: [-4, -5], resolution_m: 0.02}
soil: {default: {family: loam, relative_density: 0.3}}
machines:
  - id: ctl1
    pose: {x_m: 0, y_m: 0, yaw_deg: 0}
    controller: {type: route, start_m: [0, 0], heading_deg: 0, length_m: 6, passes: 1, depth_m: 0.04, speed_mps: 0.5}
    sensors:
      - {id: lidar_top, type: lidar, preset: os1_64, offset_m: [0.3, 0, 2.4], columns: 512}
      - {id: front_line, type: lidar, preset: single_line, offset_m: [0.8, 0, 2.0], rotation_deg: [0, 50, 0]}
)";
  sim::Simulator sim(sim::parseScenario(yaml, "self.yaml"));
  LayeredMap map(Geometry(0.05, Size(280, 200), Position(3.0, 0.0)));
  LidarFusionConfig c;
  c.max_range_m = 12;
  c.max_height_above_sensor_m = 0.5;
  if (self_filter) {
    // The simulator's default shape (docs/sim.md "Occlusion"), as configs/demo.yaml gives it.
    c.self_filter_base_m = {-1.2, 0.575, 0.0,  1.2, 1.025, 0.55, -1.2, -1.025, 0.0, 1.2, -0.575, 0.55,
                            -1.45, -1.025, 0.35, 0.95, 1.025, 1.3, -0.9, -0.5, 1.2, 0.6, 0.5, 2.05};
    c.self_filter_blade_m = {-0.05, -0.925, 0.1, 0.0, 0.925, 0.76};
  }
  LidarFusion lf;
  lf.configure(c);
  Executor ex(1);
  RecordBus bus;
  PluginStats stats;
  ProcessContext ctx(map, ex, bus, stats, "lidar");
  lf.attach(map);
  lf.start(ctx);
  std::vector<Event> ev;
  while (sim.next(ev)) {
    for (const Event& e : ev) {
      lf.process(ctx, e);
    }
    ev.clear();
  }
  *self_drops = stats.dropped["self"];
  const LayerId E = map.layerId("elevation");
  const Eigen::Vector3d base = sim.machineTruth(0).T_map_base.translation();
  double worst = -INFINITY;
  for (int i = 0; i < map.geometry().size().x(); ++i)
    for (int j = 0; j < map.geometry().size().y(); ++j) {
      const Position p = map.geometry().positionOf(Index(i, j));
      if ((p - base.head<2>()).norm() > 3.0) continue;
      const float h = map.at(E, Index(i, j));
      if (std::isnan(h)) continue;
      worst = std::max(worst, static_cast<double>(h) - sim.truth().heightAt(p.x(), p.y()));
    }
  return worst;
}
}  // namespace

TEST(SelfFilter, TheMachineIsNotMappedAsAMound) {
  // Without the filter the cab, tracks and blade the LiDAR sees are fused as ground: cells near
  // the machine end decimetres above the truth (the blade top is 0.76 m above its edge). With it
  // no cell near the machine is more than the range noise and a cell's slope above the truth:
  // 0.3 m is far above both (sigma 2 cm; 5 cm cells).
  long drops_off = 0, drops_on = 0;
  const double off = worstMoundNearTheMachine(false, &drops_off);
  const double on = worstMoundNearTheMachine(true, &drops_on);
  EXPECT_EQ(drops_off, 0);
  EXPECT_GT(drops_on, 1000);
  EXPECT_GT(off, 0.3) << "without the filter the machine should show as a mound";
  EXPECT_LT(on, 0.3) << "self points were fused";
}
