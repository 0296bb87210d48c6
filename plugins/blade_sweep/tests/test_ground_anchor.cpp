// Ground anchoring (GroundAnchorConfig): a pose estimate whose height is off by a bias moves the
// blade's cut floor by the same amount in the map, unless the plugin anchors the blade height to
// the map under the tracks. Flat known ground at z = 0; the machine's estimated base and blade
// poses are both 3 cm too high (a GNSS height bias); the true blade edge cuts 5 cm deep.
#include <gtest/gtest.h>

#include "sweep_test_util.hpp"

using namespace terramap;
using namespace terramap::plugins;
using namespace terramap::plugins::test;

namespace {

/// Drives 2 m at 0.5 m/s with 60 Hz poses, blade edge 1.9 m ahead of the base at z = -0.05
/// (true), every pose reported `bias` too high; returns the mean cut floor over cells the blade
/// crossed after the first metre.
double cutFloor(bool anchor, double bias, long* updates, double depth = 0.05) {
  TestMap tm(0.05, 160, Position(2.0, 0.0));
  tm.setElevation([](const Position&) { return 0.0; });
  BladeSweep plugin;
  plugin.configure(makeParams("blade", plugin.schema(), {{"ground_anchor", anchor}}));
  Harness h(tm.map, 1);
  plugin.start(h.ctx);
  for (int k = 0; k <= 240; ++k) {
    const double t = k / 60.0, x = 0.5 * t - 1.0;
    Pose pose;
    pose.stamp = t;
    pose.frame = "base";
    pose.T_map_base = Eigen::Isometry3d::Identity();
    pose.T_map_base.translation() = Eigen::Vector3d(x, 0.0, bias);  // tracks on z = 0 in truth
    plugin.process(h.ctx, Event(pose));
    plugin.process(h.ctx, Event(bladePose(t, Eigen::Vector3d(x + 1.9, 0.0, -depth + bias), bladeRotation(0))));
  }
  plugin.finish(h.ctx);
  *updates = static_cast<long>(h.stats.counters["ground_anchor_updates"]);
  double sum = 0;
  int n = 0;
  for (double x = 1.9; x <= 2.7; x += 0.05) {
    const auto idx = tm.map.geometry().indexAt(Position(x, 0.0));
    sum += tm.H(idx->x(), idx->y());
    ++n;
  }
  return sum / n;
}

}  // namespace

TEST(GroundAnchor, BladeHeightFollowsTheMapUnderTheTracksNotTheBiasedPose) {
  long updates = 0;
  // Without the anchor the map's cut floor carries the bias: 5 cm - 3 cm = 2 cm deep.
  EXPECT_NEAR(cutFloor(false, 0.03, &updates), -0.02, 1e-3);
  EXPECT_EQ(updates, 0);
  // With it, the contact plane the pose gives (3 cm above the map) is pulled back to the map
  // from the first pose on (the map under the tracks is flat and known, so every difference is
  // exactly the bias): the floor is at the true 5 cm.
  EXPECT_NEAR(cutFloor(true, 0.03, &updates), -0.05, 1e-3);
  EXPECT_EQ(updates, 241);
  // An unbiased pose is left alone.
  EXPECT_NEAR(cutFloor(true, 0.0, &updates), -0.05, 1e-3);
  // A difference beyond ground_anchor_max_m (0.15 m: stale map, wrong machine) is not applied:
  // a 20 cm bias on a 25 cm cut leaves the floor 5 cm deep.
  EXPECT_NEAR(cutFloor(true, 0.20, &updates, 0.25), -0.05, 1e-3);
  EXPECT_EQ(updates, 0);
}
