// Trajectory readers and interpolation: hand-computed values, real ICP relative poses, and
// malformed files generated here (each refusal must name file:line).
#include <terramap/io/trajectory.hpp>

#include <terramap/core/error.hpp>

#include "kitti_data.hpp"
#include "test_readers_util.hpp"

#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>

namespace terramap::io {
namespace {

using test::expectErrorWith;
using test::spitText;
using test::TempDir;

const std::string kIcp = test::kittiPath("DERIVED_icp_relative_poses.txt");

Eigen::Isometry3d rotZ(double angle, const Eigen::Vector3d& t) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = t;
  return T;
}

TEST(Trajectory, InterpolatesTranslationLinearlyAndRotationBySlerp) {
  const Trajectory traj({{0.0, rotZ(0.0, {0, 0, 0})}, {2.0, rotZ(M_PI / 2, {2, 4, -6})}, {3.0, rotZ(M_PI / 2, {3, 4, -6})}},
                        "hand");
  // t = 0.5: alpha = 0.25 -> translation (0.5, 1, -1.5), rotation 22.5 deg about z.
  const Eigen::Isometry3d T = traj.at(0.5);
  EXPECT_NEAR(T.translation().x(), 0.5, 1e-12);
  EXPECT_NEAR(T.translation().y(), 1.0, 1e-12);
  EXPECT_NEAR(T.translation().z(), -1.5, 1e-12);
  const double c = std::cos(M_PI / 8), s = std::sin(M_PI / 8);  // 0.92388, 0.38268
  EXPECT_NEAR(T.linear()(0, 0), c, 1e-12);
  EXPECT_NEAR(T.linear()(0, 1), -s, 1e-12);
  EXPECT_NEAR(T.linear()(1, 0), s, 1e-12);
  EXPECT_NEAR(T.linear()(2, 2), 1.0, 1e-12);
  // Second segment: pure translation, t = 2.5 -> x = 2.5.
  EXPECT_NEAR(traj.at(2.5).translation().x(), 2.5, 1e-12);
  EXPECT_NEAR(traj.at(2.5).linear()(1, 0), 1.0, 1e-12);
  // Exact at the stored stamps, including both ends.
  EXPECT_TRUE(traj.at(0.0).isApprox(rotZ(0.0, {0, 0, 0}), 1e-15));
  EXPECT_TRUE(traj.at(2.0).isApprox(rotZ(M_PI / 2, {2, 4, -6}), 1e-15));
  EXPECT_TRUE(traj.at(3.0).isApprox(rotZ(M_PI / 2, {3, 4, -6}), 1e-15));
  EXPECT_TRUE(traj.contains(3.0));
  EXPECT_FALSE(traj.contains(3.0000001));
}

TEST(Trajectory, SlerpTakesTheShortArc) {
  // 170 deg -> -170 deg about z: the short way passes through 180 deg, not 0.
  const Trajectory traj({{0.0, rotZ(170.0 * M_PI / 180, {0, 0, 0})}, {1.0, rotZ(-170.0 * M_PI / 180, {0, 0, 0})}});
  const Eigen::Matrix3d R = traj.at(0.5).linear();
  EXPECT_NEAR(R(0, 0), -1.0, 1e-12);
  EXPECT_NEAR(R(1, 1), -1.0, 1e-12);
}

TEST(Trajectory, OutsideRangeIsAClearError) {
  const Trajectory traj({{10.0, rotZ(0, {0, 0, 0})}, {11.0, rotZ(0, {1, 0, 0})}}, "poses.txt");
  expectErrorWith([&] { traj.at(9.5); }, {"poses.txt", "9.5", "[10, 11]", "not extrapolated"});
  expectErrorWith([&] { traj.at(11.25); }, {"poses.txt", "11.25"});
  expectErrorWith([&] { traj.at(std::nan("")); }, {"poses.txt", "nan"});
  EXPECT_FALSE(traj.tryAt(12.0).has_value());
  expectErrorWith([] { Trajectory().at(0.0); }, {"empty"});
}

TEST(Trajectory, ConstructorRefusesNonIncreasingStamps) {
  expectErrorWith([] { Trajectory({{1.0, Eigen::Isometry3d::Identity()}, {1.0, Eigen::Isometry3d::Identity()}}, "mine"); },
                  {"mine", "strictly increasing", "pose 1"});
  Eigen::Isometry3d sheared = Eigen::Isometry3d::Identity();
  sheared.linear()(0, 1) = 0.2;
  expectErrorWith([&] { Trajectory({{0.0, sheared}}, "mine"); }, {"mine", "pose 0", "rigid"});
}

TEST(TumReader, ParsesCommentsBlankLinesAndNormalisesCloseQuaternions) {
  TempDir dir("tum");
  const std::string p = dir.file("traj.tum");
  spitText(p,
           "# timestamp tx ty tz qx qy qz qw\n"
           "\n"
           "100.0 0 0 0 0 0 0 1\n"
           "   \t\n"
           "101.0 1 2 3 0 0 0.7071068 0.7071068  # 90 deg about z\n"
           "102.0 2 2 3 0 0 0 1.0005\n");  // norm 1.0005: within 1e-3, normalised
  const Trajectory t = readTumTrajectory(p);
  ASSERT_EQ(t.size(), 3u);
  EXPECT_EQ(t.source(), p);
  EXPECT_EQ(t.startStamp(), 100.0);
  EXPECT_EQ(t.poses()[1].T_world_body.translation(), Eigen::Vector3d(1, 2, 3));
  EXPECT_NEAR(t.poses()[1].T_world_body.linear()(1, 0), 1.0, 1e-7);
  EXPECT_NEAR(t.poses()[2].T_world_body.linear()(0, 0), 1.0, 1e-15);
  // Halfway between the first two: 45 deg, translation (0.5, 1, 1.5).
  const Eigen::Isometry3d mid = t.at(100.5);
  EXPECT_NEAR(mid.linear()(1, 0), std::sin(M_PI / 4), 1e-7);
  EXPECT_NEAR(mid.translation().z(), 1.5, 1e-12);
}

TEST(TumReader, MalformedLinesNameFileAndLine) {
  TempDir dir("tum_bad");
  const std::string head = "# comment\n1.0 0 0 0 0 0 0 1\n";
  auto check = [&](const std::string& name, const std::string& line, std::initializer_list<std::string> frags) {
    const std::string p = dir.file(name);
    spitText(p, head + line + "\n");
    std::vector<std::string> all(frags);
    all.push_back(p + ":3:");
    try {
      readTumTrajectory(p);
      ADD_FAILURE() << name << ": no exception";
    } catch (const InputError& e) {
      for (const auto& f : all) EXPECT_NE(std::string(e.what()).find(f), std::string::npos) << name << ": " << e.what();
    }
  };
  check("seven.tum", "2.0 0 0 0 0 0 1", {"expected 8 values", "found 7"});
  check("nine.tum", "2.0 0 0 0 0 0 0 1 5", {"found 9"});
  check("nan.tum", "2.0 nan 0 0 0 0 0 1", {"tx", "NaN"});
  check("inf.tum", "2.0 0 0 0 0 0 0 inf", {"qw"});
  check("word.tum", "2.0 0 zero 0 0 0 0 1", {"'zero' is not a number"});
  check("quat.tum", "2.0 0 0 0 0 0 0 1.01", {"norm", "1.01"});
  check("order.tum", "0.5 0 0 0 0 0 0 1", {"not after"});
  expectErrorWith([&] { readTumTrajectory(dir.file("missing.tum")); }, {"missing.tum", "cannot open"});
}

TEST(KittiPoses, RowsTimesAndPeriod) {
  TempDir dir("kitti_poses");
  const std::string poses = dir.file("00.txt");
  // Frame 0 identity; frame 1 rotated 90 deg about y (camera frame: y down) and moved.
  spitText(poses,
           "1 0 0 0 0 1 0 0 0 0 1 0\n"
           "0 0 1 1.5 0 1 0 -0.25 -1 0 0 4\n");
  const auto rows = readKittiPoseRows(poses);
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[1].translation(), Eigen::Vector3d(1.5, -0.25, 4));
  EXPECT_EQ(rows[1].linear()(0, 2), 1.0);
  EXPECT_EQ(rows[1].linear()(2, 0), -1.0);

  const Trajectory byPeriod = readKittiTrajectory(poses, 0.1, 5.0);
  EXPECT_EQ(byPeriod.poses()[1].stamp, 5.1);
  EXPECT_NEAR(byPeriod.at(5.05).translation().z(), 2.0, 1e-12);

  const std::string times = dir.file("times.txt");
  spitText(times, "0.000000e+00\n1.036896e-01\n");
  const Trajectory byTimes = readKittiTrajectory(poses, times);
  EXPECT_EQ(byTimes.endStamp(), 1.036896e-01);

  spitText(times, "0\n0.1\n0.2\n");
  expectErrorWith([&] { readKittiTrajectory(poses, times); }, {poses, times, "2 rows", "3 stamps"});
  expectErrorWith<ConfigError>([&] { readKittiTrajectory(poses, 0.0); }, {poses, "period"});
}

TEST(KittiPoses, MalformedRowsNameFileAndLine) {
  TempDir dir("kitti_bad");
  const std::string ok = "1 0 0 0 0 1 0 0 0 0 1 0\n";
  const std::string p = dir.file("bad.txt");
  spitText(p, ok + "1.1 0 0 0 0 1 0 0 0 0 1 0\n");  // scaled: not orthonormal
  expectErrorWith([&] { readKittiPoseRows(p); }, {p + ":2:", "not orthonormal"});
  spitText(p, ok + ok + "-1 0 0 0 0 1 0 0 0 0 1 0\n");  // reflection: det = -1
  expectErrorWith([&] { readKittiPoseRows(p); }, {p + ":3:", "det = -1"});
  spitText(p, ok + "1 0 0 0 0 1 0 0 0 0 1\n");
  expectErrorWith([&] { readKittiPoseRows(p); }, {p + ":2:", "expected 12", "found 11"});
  spitText(p, "1 0 0 0 0 1 0 NaN 0 0 1 0\n");
  expectErrorWith([&] { readKittiPoseRows(p); }, {p + ":1:", "value 8", "NaN"});
  // Six printed digits are accepted and projected onto SO(3).
  spitText(p, "0.999995 -0.003034 0.000223 0 0.003034 0.999995 0.000043 0 -0.000223 -0.000043 1.000000 0\n");
  const Eigen::Matrix3d R = readKittiPoseRows(p)[0].linear();
  EXPECT_LT((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff(), 1e-14);
  EXPECT_NEAR(R(0, 1), -0.003034, 1e-6);
}

// Parses a line of the ICP file independently: label, 16 numbers, res=.
Eigen::Matrix4d icpRow(int row) {
  std::ifstream in(kIcp);
  std::string line;
  int k = 0;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    if (++k != row) continue;
    std::istringstream ls(line);
    std::string label;
    ls >> label;
    Eigen::Matrix4d M;
    for (int i = 0; i < 16; ++i) ls >> M(i / 4, i % 4);
    return M;
  }
  ADD_FAILURE() << "row " << row << " not found";
  return Eigen::Matrix4d::Identity();
}

TEST(RelativePoses, ChainingRealIcpRowsGivesAbsolutePoses) {
  TERRAMAP_SKIP_WITHOUT_KITTI();
  const auto rel = readRelativePoses(kIcp);
  ASSERT_EQ(rel.size(), 5u);
  EXPECT_EQ(rel[0].prev, 0);
  EXPECT_EQ(rel[0].cur, 1);
  EXPECT_EQ(rel[4].cur, 5);
  EXPECT_DOUBLE_EQ(rel[0].residual_m, 0.0300);
  EXPECT_DOUBLE_EQ(rel[4].residual_m, 0.0271);
  const auto abs = chainRelativePoses(rel);
  ASSERT_EQ(abs.size(), 6u);
  EXPECT_TRUE(abs[0].isApprox(Eigen::Isometry3d::Identity()));
  // T_0_1 is row 1 itself (up to the projection onto SO(3) of 6-digit numbers).
  EXPECT_LT((abs[1].matrix() - icpRow(1)).cwiseAbs().maxCoeff(), 2e-6);
  EXPECT_DOUBLE_EQ(abs[1].translation().x(), 0.681965);
  // T_0_2 = row1 * row2 computed independently from the raw numbers.
  EXPECT_LT((abs[2].matrix() - icpRow(1) * icpRow(2)).cwiseAbs().maxCoeff(), 5e-6);
  const Eigen::Matrix4d T05 = icpRow(1) * icpRow(2) * icpRow(3) * icpRow(4) * icpRow(5);
  EXPECT_LT((abs[5].matrix() - T05).cwiseAbs().maxCoeff(), 2e-5);
  // The car moves ~0.7 m per frame forward: 0.682+0.696+0.716+0.731+0.745 ~= 3.57 m.
  EXPECT_NEAR(abs[5].translation().x(), 3.57, 0.01);
}

TEST(RelativePoses, UnlabelledAndMalformedRows) {
  TempDir dir("rel");
  const std::string p = dir.file("rel.txt");
  spitText(p, "1 0 0 1 0 1 0 0 0 0 1 0\n1 0 0 2 0 1 0 0 0 0 1 0\n");
  const auto rel = readRelativePoses(p);
  ASSERT_EQ(rel.size(), 2u);
  EXPECT_EQ(rel[1].prev, 1);
  EXPECT_TRUE(std::isnan(rel[0].residual_m));
  EXPECT_DOUBLE_EQ(chainRelativePoses(rel)[2].translation().x(), 3.0);

  const std::string row = " 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1";
  spitText(p, "0->1" + row + "\n2->3" + row + "\n");
  expectErrorWith([&] { readRelativePoses(p); }, {p + ":2:", "consecutive"});
  spitText(p, "0->2" + row + "\n");
  expectErrorWith([&] { readRelativePoses(p); }, {p + ":1:", "cur = prev + 1"});
  spitText(p, "0->1 1 0 0 0 0 1 0 0 0 0 1 0 0 0 1 1\n");
  expectErrorWith([&] { readRelativePoses(p); }, {p + ":1:", "bottom row"});
  spitText(p, "# header\n0->1 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0\n");
  expectErrorWith([&] { readRelativePoses(p); }, {p + ":2:", "found 15"});
  RelativePose a, b;
  b.prev = 5;
  b.cur = 6;
  expectErrorWith([&] { chainRelativePoses({a, b}); }, {"consecutive"});
}

// Found by fuzz_trajectory_relative (docs/reliability.md, "Fuzzing"): prev + 1 overflowed an int
// for the largest label (undefined behaviour; UBSan stops there), and a row after frame
// 2147483647 wrapped round to frame -2147483648 and was accepted.
TEST(RelativePoses, FrameNumbersAtTheTopOfTheIntRangeAreRefusedNotWrapped) {
  TempDir dir("rel");
  const std::string p = dir.file("rel.txt");
  spitText(p, "2147483647->0");  // the fuzzer's input, minimised
  expectErrorWith([&] { readRelativePoses(p); }, {p + ":1:", "cur = prev + 1"});
  const std::string row = " 1 0 0 0 0 1 0 0 0 0 1 0\n";
  spitText(p, "2147483647->2147483648" + row);
  expectErrorWith([&] { readRelativePoses(p); }, {p + ":1:", "not of the form"});
  spitText(p, "2147483646->2147483647" + row + row);
  expectErrorWith([&] { readRelativePoses(p); }, {p + ":2:", "frame 2147483647 is the last"});
  RelativePose a;
  a.prev = std::numeric_limits<int>::max();
  a.cur = std::numeric_limits<int>::min();
  expectErrorWith([&] { chainRelativePoses({a}); }, {"consecutive"});
}

}  // namespace
}  // namespace terramap::io
