// Machines collide (sim/machine_contact.hpp) and settle into their ruts (ctl.hpp, docs/sim.md
// "Machines collide" and "Track–soil interaction"): the overlap of two boxes, two loaders driving
// head-on stop apart (without contact they drove through each other, centres 1.5 cm apart), a
// loader pushes a lighter standing one at low speed, and on loose sand the chassis sinks into its
// ruts over a fraction of a second without an IMU spike beyond free fall (the one-step drop read
// 411 m/s^2 on the first sample).
#include <gtest/gtest.h>

#include <unistd.h>

#include <terramap/sim/machine_contact.hpp>
#include <terramap/sim/simulator.hpp>
#include <terramap/sim/track_soil.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <variant>

using namespace terramap;
using namespace terramap::sim;
namespace fs = std::filesystem;

namespace {

constexpr double kG = 9.80665;

PlacedBox box(const Eigen::Vector3d& c, const Eigen::Vector3d& half, double yaw = 0) {
  PlacedBox b;
  b.centre = c;
  b.R = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  b.half = half;
  b.radius = half.norm();
  return b;
}

std::vector<PlacedBox> boxesOf(const CompactTrackLoader& m) {
  std::vector<PlacedBox> out;
  placeShape(m.spec().shape, m.T_map_base(), m.T_map_blade(), out);
  return out;
}

struct Trace {
  double max_overlap = 0, min_centre_distance = 1e9;
  double x0[2] = {0, 0}, x1[2] = {0, 0};
  double final_speed[2] = {0, 0}, final_drive[2] = {0, 0};
  double a_speed_while_touching = 0;  ///< mean speed of machine 0 while the two are in contact
};

/// Runs a two-machine scenario, checking the machines' boxes every observation period.
Trace runPair(const std::string& yaml) {
  Simulator sim(parseScenario(yaml, "pair.yaml"));
  Trace tr;
  tr.x0[0] = sim.machine(0).x();
  tr.x0[1] = sim.machine(1).x();
  std::vector<Event> ev;
  double touching_speed = 0;
  int touching = 0;
  while (sim.next(ev)) {
    ev.clear();
    const CompactTrackLoader& a = sim.machine(0);
    const CompactTrackLoader& b = sim.machine(1);
    const BoxOverlap o = deepestOverlap(boxesOf(a), boxesOf(b));
    tr.max_overlap = std::max(tr.max_overlap, o.depth);
    tr.min_centre_distance = std::min(tr.min_centre_distance, std::hypot(a.x() - b.x(), a.y() - b.y()));
    // In contact: the boxes within 1 cm of each other (grown boxes overlap).
    std::vector<PlacedBox> grown = boxesOf(a);
    for (PlacedBox& p : grown) p.half += Eigen::Vector3d(0.01, 0.01, 0.0);
    if (deepestOverlap(grown, boxesOf(b)).depth > 0) {
      touching_speed += a.speed();
      ++touching;
    }
  }
  for (int i = 0; i < 2; ++i) {
    tr.x1[i] = sim.machine(i).x();
    tr.final_speed[i] = sim.machine(i).speed();
    tr.final_drive[i] = sim.machine(i).driveSpeed();
  }
  tr.a_speed_while_touching = touching ? touching_speed / touching : 0.0;
  return tr;
}

std::string headOnYaml(bool collide) {
  return std::string("version: 1\nseed: 3\nduration_s: 10\nmachines_collide: ") + (collide ? "true" : "false") +
         "\nterrain: {size_m: [20, 8], origin_m: [-10, -4], resolution_m: 0.02}\n"
         "soil: {default: {family: loam, relative_density: 0.5}}\n"
         "machines:\n"
         "  - id: a\n    pose: {x_m: -4, y_m: 0, yaw_deg: 0}\n"
         "    controller: {type: route, start_m: [-4, 0], heading_deg: 0, length_m: 10, passes: 1, depth_m: -0.2, "
         "speed_mps: 1.0}\n"
         "  - id: b\n    pose: {x_m: 4, y_m: 0, yaw_deg: 180}\n"
         "    controller: {type: route, start_m: [4, 0], heading_deg: 180, length_m: 10, passes: 1, depth_m: -0.2, "
         "speed_mps: 1.0}\n";
}

}  // namespace

TEST(MachineContact, OverlapOfTwoBoxesIsTheirMinimumTranslation) {
  const Eigen::Vector3d half(1.0, 0.5, 0.5);
  const std::vector<PlacedBox> a{box({0, 0, 0.5}, half)};
  // 0.1 m into a along x (0.8 m along y would be the longer way out).
  BoxOverlap o = deepestOverlap(a, {box({1.9, 0.2, 0.5}, half)});
  EXPECT_NEAR(o.depth, 0.1, 1e-12);
  EXPECT_NEAR(o.normal.x(), 1.0, 1e-12);
  // Turned 90 degrees: its half-width 0.5 faces a, 0.1 m deep; from the other side the normal flips.
  o = deepestOverlap(a, {box({-1.4, 0, 0.5}, half, M_PI / 2)});
  EXPECT_NEAR(o.depth, 0.1, 1e-12);
  EXPECT_NEAR(o.normal.x(), -1.0, 1e-12);
  // Above it (z intervals apart) or beside it: no contact.
  EXPECT_LE(deepestOverlap(a, {box({1.9, 0.2, 1.6}, half)}).depth, 0.0);
  EXPECT_LE(deepestOverlap(a, {box({2.1, 0.2, 0.5}, half)}).depth, 0.0);
  // A box turned 45 degrees over a's corner: the way out is along its own face normal (the
  // diagonal), 0.5 - 0.6 / sqrt(2) deep, not along a's axes (0.41 m).
  o = deepestOverlap(a, {box({1.3, 0.8, 0.5}, Eigen::Vector3d(0.5, 0.5, 0.5), M_PI / 4)});
  EXPECT_NEAR(o.depth, 0.5 - 0.6 / std::sqrt(2.0), 1e-12);
  EXPECT_NEAR(o.normal.x(), std::sqrt(0.5), 1e-12);
  EXPECT_NEAR(o.normal.y(), std::sqrt(0.5), 1e-12);
}

TEST(MachineContact, HeadOnLoadersStopApart) {
  // Two loaders on head-on routes at 1 m/s, blades up. Without contact they drive through each
  // other (centres 1.5 cm apart on the way); with it their blades meet and they stop there, the
  // tracks still turning (the drives keep their set-points, the slip takes the difference).
  const Trace off = runPair(headOnYaml(false));
  EXPECT_GT(off.max_overlap, 1.0) << "the ablation must show the failure";
  EXPECT_LT(off.min_centre_distance, 0.1);
  const Trace on = runPair(headOnYaml(true));
  EXPECT_LT(on.max_overlap, 1e-3);
  // Each blade's edge is 1.9 m ahead of its base (MachineSpec::blade_mount_x_m): stopped at
  // about 3.8 m, not a box-length further in.
  EXPECT_GT(on.min_centre_distance, 3.7);
  for (int i = 0; i < 2; ++i) {
    EXPECT_LT(std::abs(on.final_speed[i]), 0.02) << i;
    EXPECT_GT(std::abs(on.final_drive[i]), 0.5) << i;
  }
}

std::string pushYaml(double standing_mass_kg) {
  return
      "version: 1\nseed: 3\nduration_s: 10\n"
      "terrain: {size_m: [24, 8], origin_m: [-10, -4], resolution_m: 0.02}\n"
      "soil: {default: {family: loam, relative_density: 0.5}}\n"
      "machines:\n"
      "  - id: a\n    pose: {x_m: -4, y_m: 0, yaw_deg: 0}\n"
      "    controller: {type: route, start_m: [-4, 0], heading_deg: 0, length_m: 12, passes: 1, depth_m: -0.2, "
      "speed_mps: 1.0}\n"
      "  - id: b\n    pose: {x_m: 1, y_m: 0, yaw_deg: 180}\n    vehicle: {mass_kg: " + std::to_string(standing_mass_kg) + "}\n"
      "    controller: {type: random_walk, speed_mps: {initial: 0, range: [0, 0], sigma: 0}, "
      "depth_m: {initial: -0.2, range: [-0.2, -0.2], sigma: 0}, heading_deg: {initial: 0, range: [0, 0], sigma: 0}}\n";
}

TEST(MachineContact, ALoaderPushesAStandingOneSlowerTheHeavierItIs) {
  // A 5.2 t loader drives at 1 m/s into a loader standing with its levers at zero, whose tracks
  // brake it up to its traction limit (min(A c + W tan(phi), drive limit), mobilised with slip).
  // A 2 t one it pushes back at most of its speed; an equal one only creeps back, at the speed
  // where the standing one's braking slip mobilises as much of its grip as the pusher's slip
  // mobilises of its own. The boxes never interpenetrate.
  const Trace light = runPair(pushYaml(2000));
  EXPECT_LT(light.max_overlap, 1e-3);
  EXPECT_GT(light.x1[1] - light.x0[1], 1.0) << "the standing loader is pushed back";
  EXPECT_GT(light.a_speed_while_touching, 0.5);
  EXPECT_LT(light.a_speed_while_touching, 0.9) << "pushing is slower than driving alone (0.997 m/s)";
  const Trace equal = runPair(pushYaml(5200));
  EXPECT_LT(equal.max_overlap, 1e-3);
  EXPECT_GT(equal.x1[1] - equal.x0[1], 0.1);
  EXPECT_LT(equal.a_speed_while_touching, 0.15);
  EXPECT_LT(equal.a_speed_while_touching, 0.2 * light.a_speed_while_touching);
  std::string off_yaml = pushYaml(2000);
  off_yaml.insert(std::string("version: 1\n").size(), "machines_collide: false\n");
  const Trace off = runPair(off_yaml);
  EXPECT_NEAR(off.x1[1], off.x0[1], 1e-9) << "without contact nothing moves it";
  EXPECT_GT(off.max_overlap, 1.0);
}

TEST(TrackSoil, ChassisSettlesIntoLooseSandWithoutAnImuSpike) {
  // A loader placed on loose sand (Bekker sinkage 2.79 cm) drives off at 1 m/s; a noise-free IMU
  // on its base at 120 Hz. The tracks press their ruts at once, but the chassis sinks into them
  // under gravity through the soil's loading curve, critically damped: it can fall no faster than
  // freely (specific force >= 0) and stops without overshoot (the soil pushes it up by less
  // than it weighs), so over the first second the vertical specific force stays within g of the
  // resting g. The one-step drop of the kinematic placement read 411 m/s^2 on the first sample.
  const std::string yaml =
      "version: 1\nseed: 2\nduration_s: 1\n"
      "terrain: {size_m: [16, 8], origin_m: [-4, -4], resolution_m: 0.02}\n"
      "soil: {default: {family: sand, relative_density: 0.0}}\n"
      "machines:\n  - id: ctl1\n"
      "    controller: {type: route, start_m: [0, 0], length_m: 10, passes: 1, depth_m: -0.2, speed_mps: 1.0}\n"
      "    sensors:\n      - {id: imu, type: imu, link: base, rate_hz: 120, offset_m: [0, 0, 0.5], "
      "accel_noise_density: 0, gyro_noise_density: 0, accel_bias_walk: 0, gyro_bias_walk: 0, accel_bias_sigma: 0, "
      "gyro_bias_sigma: 0}\n";
  Simulator sim(parseScenario(yaml, "settle.yaml"));
  const double z0 = sim.machine(0).T_map_base().translation().z();
  const double zs = bekkerSinkage(terramechanics(soil::SoilFamily::Sand, 0.0), 5200 * kG / (2 * 0.45 * 1.9), 0.45);
  std::vector<Event> ev;
  double worst_z = 0, worst_xy = 0, sunk_first = -1;
  int samples = 0;
  while (sim.next(ev)) {
    for (const Event& e : ev)
      if (const auto* s = std::get_if<ImuSample>(&e)) {
        ++samples;
        worst_z = std::max(worst_z, std::abs(s->accel_mps2.z() - kG));
        worst_xy = std::max(worst_xy, std::hypot(s->accel_mps2.x() - 0.0, s->accel_mps2.y()));
      }
    ev.clear();
    if (sunk_first < 0) sunk_first = z0 - sim.machine(0).T_map_base().translation().z();
  }
  EXPECT_GE(samples, 118);
  EXPECT_LE(worst_z, kG) << "beyond free fall";
  // Forward acceleration from rest to 1 m/s (the drive's 0.2 s lag) and the pitch of the settling.
  EXPECT_LE(worst_xy, 6.0);
  // Not a one-step drop: after the first observation period (1/60 s) less than a fifth of the
  // sinkage; after a second the chassis rests at the ruts' depth.
  EXPECT_LT(sunk_first, 0.2 * zs);
  EXPECT_NEAR(z0 - sim.machine(0).T_map_base().translation().z(), zs, 2e-4);
}

namespace {

/// The excavator's steady speed after `seconds` at full lever on flat ground of one soil; `vehicle`
/// overrides its undercarriage (YAML flow map, e.g. "mass_kg: 28000, max_drive_force_n: 240000").
double fullLeverSpeed(const std::string& soil, double seconds, const std::string& vehicle = "") {
  // One folder per test process: CTest runs this file's tests in parallel, and two of them writing
  // one s.yaml made one simulate the other's machine (CI: a 3.5 t excavator at the 28 t one's speed).
  const fs::path d = fs::path(TERRAMAP_BINARY_DIR) / "test_tmp" /
                     ("full_lever_" + std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()) +
                      "_" + std::to_string(::getpid()));
  fs::create_directories(d);
  std::ofstream(d / "full.csv") << "t_s,left,right,lift,tilt,angle,slew,boom,arm,bucket\n0,1,1,0,0,0,0,0,0,0\n"
                                << seconds << ",1,1,0,0,0,0,0,0,0\n";
  std::ofstream(d / "s.yaml") << "version: 1\nseed: 2\nduration_s: " << seconds
                              << "\nterrain: {size_m: [20, 6], origin_m: [-3, -3], resolution_m: 0.02}\n"
                                 "soil: {default: {family: " << soil << "}}\n"
                                 "machines:\n  - id: ex\n    type: excavator\n"
                              << (vehicle.empty() ? "" : "    vehicle: {" + vehicle + "}\n")
                              << "    controller: {type: replay, file: full.csv, units: lever}\n";
  Simulator sim(loadScenario((d / "s.yaml").string()));
  std::vector<Event> ev;
  while (sim.next(ev)) ev.clear();
  const double v = sim.machine(0).speed();
  fs::remove_all(d);
  return v;
}

/// The excavator's spec (TB235-class defaults) with `vehicle` overrides, as a scenario gives it.
MachineSpec excavatorSpec(const std::string& vehicle = "") {
  const std::string yaml =
      "version: 1\nduration_s: 1\nterrain: {size_m: [20, 6], origin_m: [-3, -3], resolution_m: 0.02}\n"
      "machines:\n  - id: ex\n    type: excavator\n" +
      (vehicle.empty() ? std::string() : "    vehicle: {" + vehicle + "}\n") +
      "    controller: {type: dig_dump, dig_m: [3, 0], dump_m: [0, 3]}\n";
  return parseScenario(yaml, "s.yaml").machines.at(0);
}

/// What terramechanics says (steadyTravel): the speed at which the Janosi–Hanamoto share of the
/// traction limit A c + W tan(phi) (capped by the drive) carries the running gear's rolling
/// resistance plus the compaction and bulldozing resistances of both tracks' ruts.
double theorySpeed(soil::SoilFamily family, double I_d, const std::string& vehicle = "") {
  const MachineSpec m = excavatorSpec(vehicle);
  const SteadyTravel s = steadyTravel(m, family, I_d);
  // The simulator's step takes the resistances off after solving the traction (ctl.cpp), so its
  // steady speed sits one step's deceleration by them, dt R / m, below (scenario's 240 Hz).
  return m.max_speed_mps * (1 - s.slip) - s.resistance_n / (240.0 * m.mass_kg);
}

}  // namespace

TEST(TrackSoil, AtFullLeverTheExcavatorIsSlowerInLooseSandThanInLoamByWhatTheRutsResist) {
  // TERA's Fig. 4: at the same lever its excavator slows in sand. Here the TB235-class excavator
  // (3.5 t, 0.3 m shoes, 1.3 m/s) at full lever for 6 s: on loose sand its ruts are 2.8 cm deep
  // and the compaction (Bekker) and bulldozing (Bekker, Wong) resistances of pressing them,
  // 0.25 kN and 0.19 kN, add to the running gear's 1.37 kN; on loam (1.6 mm ruts) they are
  // negligible, and loam's cohesion gives the tracks more grip. Its steady speed in each is the
  // one at which the tracks' slip mobilises that resistance (Janosi–Hanamoto), to 1e-5 m/s.
  const double loam = fullLeverSpeed("loam, relative_density: 0.4", 6);
  const double sand = fullLeverSpeed("sand, relative_density: 0.0", 6);
  EXPECT_NEAR(loam, theorySpeed(soil::SoilFamily::Loam, 0.4), 1e-5);
  EXPECT_NEAR(sand, theorySpeed(soil::SoilFamily::Sand, 0.0), 1e-5);
  EXPECT_LT(sand, loam);
}

TEST(TrackSoil, OnTheSameTracksEightTimesHeavierTheExcavatorSlowsMoreInSandAsItsRutsDeepen) {
  // The same undercarriage (0.3 m x 1.85 m tracks) carrying 28 t, its drive force scaled with its
  // weight: 247 kPa, ruts 19 cm deep in loose sand (3.9 cm in loam). The simulator's speed is
  // still what terramechanics gives on both soils, and the sand's slow-down against loam is
  // several times the 3.5 t machine's: deeper ruts resist more. (Without the track-soil model
  // both soils give the same speed.)
  const std::string heavy = "mass_kg: 28000, max_drive_force_n: 240000";
  const double loam = fullLeverSpeed("loam, relative_density: 0.4", 6, heavy);
  const double sand = fullLeverSpeed("sand, relative_density: 0.0", 6, heavy);
  EXPECT_NEAR(loam, theorySpeed(soil::SoilFamily::Loam, 0.4, heavy), 1e-5);
  EXPECT_NEAR(sand, theorySpeed(soil::SoilFamily::Sand, 0.0, heavy), 1e-5);
  const double light = 1 - fullLeverSpeed("sand, relative_density: 0.0", 6) /
                               fullLeverSpeed("loam, relative_density: 0.4", 6);
  const double slow = 1 - sand / loam;
  EXPECT_GT(slow, 3.0 * light) << slow << " vs " << light;
  EXPECT_GT(slow, 0.004);
}
