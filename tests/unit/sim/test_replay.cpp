// Replaying recorded commands (`controller: {type: replay}`, sim/command_log.hpp) and comparing
// paths (io::comparePaths): the CSV reader's errors name file and line, the zero-order hold,
// levers scaled by the machine's limits drive it at the speed and turn rate they mean, and the
// alignments of the path comparison recover a known rigid motion.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/io/trajectory.hpp>
#include <terramap/sim/command_log.hpp>
#include <terramap/sim/episode.hpp>
#include <terramap/sim/simulator.hpp>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

using namespace terramap;
using namespace terramap::sim;
namespace fs = std::filesystem;

namespace {

fs::path tempDir(const std::string& name) {
  const fs::path d = fs::path(TERRAMAP_BINARY_DIR) / ("sim_test_replay_" + name);
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

void write(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }

std::string errorOf(const fs::path& p, CommandLog::Units units = CommandLog::Units::Lever) {
  try {
    readCommandLog(p.string(), units);
  } catch (const InputError& e) {
    return e.what();
  }
  return "no error";
}

io::Trajectory line(const Eigen::Isometry3d& T, double t0 = 0) {
  std::vector<io::StampedPose> poses;
  for (int k = 0; k <= 50; ++k) {
    io::StampedPose p;
    p.stamp = t0 + 0.1 * k;
    // A curving, climbing path: every alignment has something to fit.
    Eigen::Isometry3d B = Eigen::Isometry3d::Identity();
    B.translation() = Eigen::Vector3d(0.2 * k, 0.002 * k * k, 0.01 * k);
    p.T_world_body = T * B;
    poses.push_back(p);
  }
  return io::Trajectory(poses, "line");
}

}  // namespace

TEST(Replay, TheCommandLogReaderNamesFileLineAndColumn) {
  const fs::path d = tempDir("reader");
  write(d / "ok.csv", "# a comment\n\nt_s,left,right,lift,tilt,angle\n0,0.5,0.5,0,0,0\n  1.5 , -1, 1, 0.2, 0, -0.1\n");
  const CommandLog ok = readCommandLog((d / "ok.csv").string(), CommandLog::Units::Lever);
  ASSERT_EQ(ok.t.size(), 2u);
  EXPECT_EQ(ok.u[1][0], -1.0);
  EXPECT_EQ(ok.u[1][4], -0.1);
  EXPECT_EQ(ok.hold_last_s, 1.5);  // the mean row spacing
  // Zero-order hold: before the first row and after the last one's hold nothing is in force.
  EXPECT_EQ(ok.rowAt(-0.1), -1);
  EXPECT_EQ(ok.rowAt(0.0), 0);
  EXPECT_EQ(ok.rowAt(1.49), 0);
  EXPECT_EQ(ok.rowAt(1.5), 1);
  EXPECT_EQ(ok.rowAt(2.9, 0), 1);
  EXPECT_EQ(ok.rowAt(3.01, 1), -1);
  write(d / "header.csv", "t,left,right,lift,tilt,angle\n0,0,0,0,0,0\n");
  EXPECT_NE(errorOf(d / "header.csv").find("header.csv:1: expected the header"), std::string::npos);
  write(d / "count.csv", "t_s,left,right,lift,tilt,angle\n0,0,0,0,0\n");
  EXPECT_NE(errorOf(d / "count.csv").find("count.csv:2: expected 6 values"), std::string::npos);
  write(d / "nan.csv", "t_s,left,right,lift,tilt,angle\n0,0,0,0,0,0\n1,0,x,0,0,0\n");
  EXPECT_NE(errorOf(d / "nan.csv").find("nan.csv:3: column 'right': 'x' is not a finite number"), std::string::npos)
      << errorOf(d / "nan.csv");
  write(d / "lever.csv", "t_s,left,right,lift,tilt,angle\n0,0,0,1.2,0,0\n");
  EXPECT_NE(errorOf(d / "lever.csv").find("lever.csv:2: column 'lift': lever 1.2 outside [-1, 1]"), std::string::npos);
  EXPECT_EQ(errorOf(d / "lever.csv", CommandLog::Units::Si), "no error");  // SI commands are not levers
  write(d / "time.csv", "t_s,left,right,lift,tilt,angle\n0,0,0,0,0,0\n0,0,0,0,0,0\n");
  EXPECT_NE(errorOf(d / "time.csv").find("time.csv:3: t_s 0 does not increase"), std::string::npos);
  write(d / "empty.csv", "# nothing\n");
  EXPECT_NE(errorOf(d / "empty.csv").find("no header"), std::string::npos);
  EXPECT_NE(errorOf(d / "missing.csv").find("cannot open"), std::string::npos);
  // Round trip through the writer: the same bits.
  writeCommandLog((d / "again.csv").string(), ok);
  const CommandLog again = readCommandLog((d / "again.csv").string(), CommandLog::Units::Lever);
  EXPECT_EQ(again.t, ok.t);
  EXPECT_EQ(again.u, ok.u);
}

TEST(Replay, LeversDriveTheMachineAtTheSpeedAndTurnRateTheyMean) {
  // 3 s straight at lever 0.5 (0.5 x 2.5 m/s) with the blade lifted (lift lever 1 for 0.5 s:
  // 0.5 m/s x 0.5 s, clamped at the joint's 0.9 m), then 2 s turning on the spot (tracks at
  // -0.2 and +0.2: yaw rate 2 x 0.5 m/s / 1.6 m gauge).
  const fs::path d = tempDir("levers");
  write(d / "c.csv",
        "t_s,left,right,lift,tilt,angle\n0,0.5,0.5,1,0,0\n0.5,0.5,0.5,0,0,0\n3,-0.2,0.2,0,0,0\n4,-0.2,0.2,0,0,0\n");
  write(d / "s.yaml",
        "version: 1\nseed: 1\nduration_s: 7\nlocalisation: perfect\n"
        "terrain: {size_m: [20, 20], origin_m: [-10, -10], resolution_m: 0.02}\n"
        "machines:\n  - id: ctl1\n    pose: {x_m: -5, y_m: 0}\n    controller: {type: replay, file: c.csv}\n");
  Simulator sim(loadScenario((d / "s.yaml").string()));
  std::vector<Event> ev;
  double speed_at_3 = 0, lift_at_3 = 0, yaw_at[3] = {0, 0, 0};
  while (sim.next(ev)) {
    ev.clear();
    const double t = sim.time();
    if (std::abs(t - 3.0) < 1e-9) {
      speed_at_3 = sim.machine(0).speed();
      lift_at_3 = sim.machine(0).joints()[0];
    }
    if (std::abs(t - 4.5) < 1e-9) yaw_at[0] = sim.machine(0).yaw();
    if (std::abs(t - 5.3) < 1e-9) yaw_at[1] = sim.machine(0).yaw();
    if (std::abs(t - 6.9) < 1e-9) yaw_at[2] = sim.machine(0).yaw();
  }
  EXPECT_NEAR(speed_at_3, 1.25, 0.02);  // the tracks slip ~5 mm/s against the rolling resistance
  EXPECT_NEAR(lift_at_3, 0.2 + 0.25, 0.02);  // from the initial 0.2 m
  // Turning, 1.5 s after the step (past the 0.2 s drive and 0.25 s yaw lags): 0.625 rad/s.
  EXPECT_NEAR(std::remainder(yaw_at[1] - yaw_at[0], 2 * M_PI) / 0.8, 0.625, 0.015);
  // The log's last row (4 s) holds for its mean row spacing (4/3 s): 1.6 s later (6.9 s) the
  // machine has stopped turning (0.1 s of the turn would be 0.06 rad).
  EXPECT_NEAR(std::remainder(sim.machine(0).yaw() - yaw_at[2], 2 * M_PI), 0.0, 1e-3);
}

TEST(Replay, ABadLogIsAnInputErrorAfterTheYamlIsRight) {
  const fs::path d = tempDir("bad");
  write(d / "c.csv", "t_s,left,right,lift,tilt,angle\n0,2,0,0,0,0\n");
  write(d / "s.yaml",
        "version: 1\nterrain: {size_m: [10, 10], origin_m: [-5, -5]}\n"
        "machines:\n  - id: ctl1\n    controller: {type: replay, file: c.csv, units: lever}\n");
  try {
    loadScenario((d / "s.yaml").string());
    FAIL() << "expected an InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("c.csv:2: column 'left'"), std::string::npos) << e.what();
  }
  write(d / "u.yaml",
        "version: 1\nterrain: {size_m: [10, 10], origin_m: [-5, -5]}\n"
        "machines:\n  - id: ctl1\n    controller: {type: replay, file: c.csv, units: volts}\n");
  try {
    loadScenario((d / "u.yaml").string());
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("controller.units"), std::string::npos) << e.what();
  }
}

TEST(Replay, PathComparisonAlignmentsRecoverARigidMotion) {
  const io::Trajectory ref = line(Eigen::Isometry3d::Identity());
  // The same path, moved by a rotation about z of 30 deg and a shift: se2 removes it exactly.
  Eigen::Isometry3d M = Eigen::Isometry3d::Identity();
  M.linear() = Eigen::AngleAxisd(M_PI / 6, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  M.translation() = Eigen::Vector3d(3, -2, 0.5);
  const io::Trajectory moved = line(M);
  const io::PathComparison same = io::comparePaths(ref, ref, io::PathAlignment::None);
  EXPECT_EQ(same.pairs, 51u);
  EXPECT_EQ(same.rmse_m, 0.0);
  EXPECT_NEAR(same.length_m, same.reference_length_m, 1e-12);
  const io::PathComparison none = io::comparePaths(moved, ref, io::PathAlignment::None);
  EXPECT_GT(none.rmse_m, 1.0);
  EXPECT_NEAR(none.length_m, none.reference_length_m, 1e-9);  // a rigid motion keeps lengths
  const io::PathComparison se2 = io::comparePaths(moved, ref, io::PathAlignment::Se2);
  EXPECT_NEAR(se2.rmse_xy_m, 0.0, 1e-9);
  EXPECT_NEAR(se2.rmse_m, 0.5, 1e-9);  // se2 leaves the height offset
  EXPECT_NEAR(io::comparePaths(moved, ref, io::PathAlignment::Se3).rmse_m, 0.0, 1e-9);
  // A tilt is beyond se2 but not se3.
  Eigen::Isometry3d Tilt = M;
  Tilt.linear() = Tilt.linear() * Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const io::Trajectory tilted = line(Tilt);
  EXPECT_GT(io::comparePaths(tilted, ref, io::PathAlignment::Se2).rmse_m, 0.01);
  EXPECT_NEAR(io::comparePaths(tilted, ref, io::PathAlignment::Se3).rmse_m, 0.0, 1e-9);
  // Only stamps inside the reference's span pair; none at all is an error naming both.
  EXPECT_EQ(io::comparePaths(line(Eigen::Isometry3d::Identity(), 2.0), ref, io::PathAlignment::None).pairs, 31u);
  try {
    io::comparePaths(line(Eigen::Isometry3d::Identity(), 10.0), ref, io::PathAlignment::None);
    FAIL() << "expected an InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("reference's span"), std::string::npos) << e.what();
  }
  EXPECT_THROW(io::parsePathAlignment("sim3", "--align"), ConfigError);
}

TEST(Replay, AnExcavatorsExportedLeversRetraceItsArm) {
  // A dig-and-dump episode's commands (tracks, plow and the arm's steady-state rates, si units:
  // the `--export-commands` CSV) drive the same excavator through the replay controller: its
  // joints follow the original ones. The log holds the 60 Hz observations of levers the
  // controller changed at 240 Hz, so the replay is close, not exact.
  const std::string base =
      "version: 1\nseed: 4\nduration_s: 12\nthreads: 1\n"
      "terrain: {size_m: [12, 12], origin_m: [-6, -6], resolution_m: 0.02}\n"
      "soil: {default: {family: loam, relative_density: 0.4}}\n"
      "machines:\n  - id: ex1\n    type: excavator\n    localisation: perfect\n";
  const fs::path d = tempDir("excavator");
  const Scenario original = parseScenario(
      base + "    controller: {type: dig_dump, dig_m: [3.4, 0], dump_m: [0.3, 3.2], depth_m: 0.25, drag_m: 1.0}\n", "ex.yaml");
  const std::string episode = runEpisode(original, (d / "original").string());
  const CommandLog log = episodeCommands(episode, "ex1");
  ASSERT_EQ(log.arm.size(), log.t.size()) << "the excavator's levers are in the export";
  writeCommandLog((d / "levers.csv").string(), log);
  const CommandLog back = readCommandLog((d / "levers.csv").string(), CommandLog::Units::Si);
  ASSERT_EQ(back.arm, log.arm) << "written and read back at full precision";

  auto joints = [](const Scenario& sc) {
    Simulator sim(sc);
    std::vector<std::array<double, 4>> q;
    double dug = 0;
    std::vector<Event> ev;
    while (sim.next(ev)) {
      ev.clear();
      q.push_back(sim.machineTruth(0).arm_q);
      dug = sim.machineTruth(0).bucket_dug_bank_m3;
    }
    return std::make_pair(q, dug);
  };
  const auto a = joints(original);
  const auto b = joints(parseScenario(base + "    controller: {type: replay, file: levers.csv, units: si}\n", "ex.yaml",
                                      d.string()));
  ASSERT_EQ(a.first.size(), b.first.size());
  for (int k = 0; k < 4; ++k) {
    double se = 0, range = 0;
    for (std::size_t s = 0; s < a.first.size(); ++s) {
      se += std::pow(a.first[s][k] - b.first[s][k], 2);
      range = std::max(range, std::abs(a.first[s][k] - a.first[0][k]));
    }
    const double rmse = std::sqrt(se / static_cast<double>(a.first.size()));
    std::printf("[ excavator-replay ] joint %d: rmse %.4f rad (moved up to %.3f rad)\n", k, rmse, range);
    EXPECT_LT(rmse, 0.03) << "joint " << k << " (moved up to " << range << " rad)";
  }
  EXPECT_GT(a.second, 0.05);
  std::printf("[ excavator-replay ] bank dug: original %.4f m3, replay %.4f m3\n", a.second, b.second);
  EXPECT_NEAR(b.second, a.second, 0.15 * a.second) << "the replayed bucket digs as much";
}
