// Truth physics (FEE slices, deformation mass balance), the CTL (stall), determinism and the
// HDF5 episode.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/soil/fee.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/sim/blade_physics.hpp>
#include <terramap/sim/episode.hpp>
#include <terramap/sim/simulator.hpp>


#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <chrono>
#include <fstream>
#include <random>
#include <thread>

using namespace terramap;
using namespace terramap::sim;

namespace {

Eigen::Isometry3d uprightBlade(double x, double y, double z) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(x, y, z);
  return T;
}

TruthTerrain flat(double size = 6.0, double res = 0.02) {
  TerrainSpec s;
  s.size_x_m = size; s.size_y_m = size; s.origin_x_m = -size / 2; s.origin_y_m = -size / 2; s.resolution_m = res;
  return buildTerrain(s);
}

// `track_soil`: the drive model. The Ctl tests below check the fixed-coefficient model's
// formulas (traction = 0.75 W, no ruts), so they ask for it; the track–soil model has its own
// tests (test_track_soil.cpp).
std::string scenarioYaml(const std::string& soil, double depth, double raise_rate, double duration, int threads,
                         bool lidar, const std::string& track_soil = "none") {
  std::string y = "version: 1\nseed: 9\nduration_s: " + std::to_string(duration) + "\nthreads: " + std::to_string(threads) +
                  "\nterrain: {size_m: [14, 6], origin_m: [-3, -3], resolution_m: 0.02, snapshot_interval_s: 0.5,\n"
                  "  hills: {count: 4, amplitude_m: [-0.05, 0.08], sigma_m: [0.8, 1.5], seed: 3}}\n"
                  "soil: {default: " + soil + "}\n"
                  "machines:\n  - id: ctl1\n    controller: {type: route, start_m: [0, 0], length_m: 8, passes: 1, depth_m: " +
                  std::to_string(depth) + ", speed_mps: 0.8, stall: {raise_rate_mps: " + std::to_string(raise_rate) + "}}\n" +
                  "    vehicle: {track_soil: " + track_soil + "}\n"
                  "    sensors:\n      - {id: force, type: force}\n";
  if (lidar) y += "      - {id: top, type: lidar, preset: vlp32, columns: 360, offset_m: [0, 0, 2.0]}\n"
                  "      - {id: line, type: lidar, preset: single_line, offset_m: [0.8, 0, 2.0], rotation_deg: [0, 50, 0]}\n";
  return y;
}

}  // namespace

TEST(BladeForce, SlicesOnFlatGroundSumToTheFeeOfTheWholeBlade) {
  TruthTerrain t = flat();
  const SoilProperties sp = soilProperties(SoilFamily::Loam, 0.6);
  const SoilField field(sp, {});
  BladeGeometry g;
  const int slices = 37;
  const double depth = 0.12;
  const BladeForce bf = bladeSoilForce(t, field, uprightBlade(0, 0, -depth), g, 0.025, slices, 0.0, 0.0, 0.0);
  // Independent: one FEE evaluation for the full width (flat, no surcharge, upright blade).
  fee::Geometry geo;
  geo.alpha_rad = 0; geo.rho_rad = M_PI / 2; geo.d_m = depth; geo.w_m = g.width_m; geo.q_n = 0;
  const fee::Result r = fee::evaluate(sp.fee, geo, fee::betaMin(sp.fee, geo));
  ASSERT_TRUE(r.valid());
  EXPECT_NEAR(bf.fee_map.x(), -r.F_total_N.x(), 1e-6 * std::abs(r.F_total_N.x()));
  EXPECT_NEAR(bf.fee_map.z(), -r.F_total_N.y(), 1e-6 * std::abs(r.F_total_N.x()));
  EXPECT_EQ(bf.truth.cutting_slices, slices);
  EXPECT_NEAR(bf.truth.width_m, g.width_m, 1e-12);
  EXPECT_NEAR(bf.truth.depth_m, depth, 1e-12);
  EXPECT_NEAR(bf.truth.c_pa, sp.fee.c_pa, 1e-9);
  // No contact, no force.
  const BladeForce up = bladeSoilForce(t, field, uprightBlade(0, 0, 0.05), g, 0.025, slices, 1.0, 0.0, 0.0);
  EXPECT_EQ(up.fee_map.norm(), 0.0);
  EXPECT_EQ(up.truth.cutting_slices, 0);
  // Descending into the soil adds the edge bearing resistance (upward).
  const BladeForce pen = bladeSoilForce(t, field, uprightBlade(0, 0, -depth), g, 0.025, slices, 0.0, -0.1, 0.0);
  EXPECT_GT(pen.penetration_map.z(), 0.0);
}

// The truth's cross-section over the cutting slices: a rolled edge on flat ground cuts a depth
// that runs linearly across the blade, so Σ d ds and Σ d² ds have closed forms, and the slices'
// FEE sums to one wedge at depth depth2/area and width area²/depth2 (the FEE is linear in d w and
// in d² w for one α and ρ), not to one at the depth-weighted depth over the cutting width.
TEST(BladeForce, TheCutsCrossSectionHoldsTheSlicesSum) {
  TruthTerrain t = flat();
  const SoilProperties sp = soilProperties(SoilFamily::Clay, 0.5);
  const SoilField field(sp, {});
  BladeGeometry g;
  const int slices = 37;
  const double depth = 0.10, roll = 3.0 * M_PI / 180;
  Eigen::Isometry3d T = uprightBlade(0, 0, -depth);
  T.linear() = Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const BladeForce bf = bladeSoilForce(t, field, T, g, 0.025, slices, 0.0, 0.0, 0.0);
  ASSERT_EQ(bf.truth.cutting_slices, slices);
  // Slice k's centre is at y = (k + 1/2) ds - w/2 along the edge, its depth depth - y sin(roll).
  const double ds = g.width_m / slices;
  double area = 0, depth2 = 0;
  for (int k = 0; k < slices; ++k) {
    const double dk = depth - ((k + 0.5) * ds - 0.5 * g.width_m) * std::sin(roll);
    area += dk * ds;
    depth2 += dk * dk * ds;
  }
  EXPECT_NEAR(bf.truth.area_m2, area, 1e-9);
  EXPECT_NEAR(bf.truth.depth2_m3, depth2, 1e-9);
  fee::Geometry eff;
  eff.alpha_rad = 0; eff.rho_rad = M_PI / 2; eff.q_n = 0;
  eff.d_m = bf.truth.depth2_m3 / bf.truth.area_m2;
  eff.w_m = bf.truth.area_m2 * bf.truth.area_m2 / bf.truth.depth2_m3;
  const fee::Result r = fee::evaluateAtBetaMin(sp.fee, eff);
  ASSERT_TRUE(r.valid());
  EXPECT_NEAR(-bf.fee_map.x(), r.F_total_N.x(), 1e-3 * std::abs(r.F_total_N.x()));
  EXPECT_NEAR(-bf.fee_map.z(), r.F_total_N.y(), 1e-3 * std::abs(r.F_total_N.x()));
  // The summary pair (depth-weighted depth, cutting width) is further off: its γ term takes
  // (Σd²/Σd)² w for Σd².
  fee::Geometry sum = eff;
  sum.d_m = bf.truth.depth_m;
  sum.w_m = bf.truth.width_m;
  const fee::Result rs = fee::evaluateAtBetaMin(sp.fee, sum);
  EXPECT_GT(std::abs(rs.F_total_N.x() + bf.fee_map.x()), 5.0 * std::abs(r.F_total_N.x() + bf.fee_map.x()));
  EXPECT_EQ(bf.truth.q_pushed_n, 0.0);
}

// Against a closed form that shares no code with the FEE: a vertical, smooth (delta = 0, no
// adhesion) wall pushed into flat ground fails the soil in Rankine's passive state, with Bell's
// cohesion term: per unit width F = 1/2 gamma d^2 Kp + 2 c d sqrt(Kp), Kp = tan^2(45 deg + phi/2),
// horizontal (a smooth wall takes no shear). Every slice is such a wall, so the blade's force is
// that times its width, pointing back against the push (-x).
TEST(BladeForce, SmoothUprightBladeOnFlatGroundMeetsBellsPassivePressure) {
  TruthTerrain t = flat();
  for (const auto& [phi_deg, c_pa] : {std::pair{30.0, 0.0}, std::pair{30.0, 5000.0}, std::pair{38.0, 1500.0}}) {
    SoilProperties sp = soilProperties(SoilFamily::Loam, 0.6);
    sp.fee.phi_rad = phi_deg * M_PI / 180.0;
    sp.fee.c_pa = c_pa;
    sp.fee.gamma_n_m3 = 18000.0;
    sp.fee.ca_pa = 0.0;
    sp.fee.delta_rad = 0.0;
    const SoilField field(sp, {});
    BladeGeometry g;
    const double depth = 0.15;
    const BladeForce bf = bladeSoilForce(t, field, uprightBlade(0, 0, -depth), g, 0.025, 25, 0.0, 0.0, 0.0);
    const double kp = std::pow(std::tan(M_PI / 4 + sp.fee.phi_rad / 2), 2);
    const double bell = (0.5 * 18000.0 * depth * depth * kp + 2.0 * c_pa * depth * std::sqrt(kp)) * g.width_m;
    EXPECT_NEAR(bf.fee_map.x(), -bell, 1e-9 * bell) << "phi " << phi_deg << " c " << c_pa;
    EXPECT_NEAR(bf.fee_map.z(), 0.0, 1e-9 * bell) << "phi " << phi_deg << " c " << c_pa;
    EXPECT_NEAR(bf.fee_map.y(), 0.0, 1e-9 * bell);
  }
}

TEST(Deformation, CutPushAndRelaxConserveSoilMass) {
  TerrainSpec s;
  s.size_x_m = 6; s.size_y_m = 4; s.origin_x_m = -3; s.origin_y_m = -2; s.resolution_m = 0.02;
  s.bumps.push_back({0.5, 0.2, 0.15, 0.8});
  TruthTerrain t = buildTerrain(s);
  SoilField field(soilProperties(SoilFamily::Clay, 0.3), {{"sand", soilProperties(SoilFamily::Sand, 0.7),
                                                           SoilZone::Region::StripX, 0.0, 1.0, {}, 0.0, INFINITY}});
  const double m0 = t.bankVolume();
  BladeGeometry g;
  Eigen::Isometry3d T = uprightBlade(-2.0, 0.0, -0.08);
  T.linear() = (Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitX()) *
                Eigen::AngleAxisd(-0.17, Eigen::Vector3d::UnitY()))
                   .toRotationMatrix();
  double cut = 0;
  for (int k = 0; k < 900; ++k) {  // 3.6 m at 4 mm per step, slightly descending
    Eigen::Isometry3d T1 = T;
    T1.translation() += Eigen::Vector3d(0.004 * std::cos(0.2), 0.004 * std::sin(0.2), -0.00005);
    cut += cutAndPush(t, field, T, T1, g, 37).cut_bank_m3;
    if (k % 4 == 3) relaxLoose(t, field, T1, g, 1.5, 0.5, 2);
    T = T1;
  }
  EXPECT_GT(cut, 0.3);  // it really cut (about 1.85 m x 0.1 m x 3.6 m)
  double loose = 0;
  for (int j = 0; j < t.ny(); ++j)
    for (int i = 0; i < t.nx(); ++i) loose += t.loose(i, j);
  EXPECT_GT(loose * 0.02 * 0.02, cut);  // swelled
  EXPECT_NEAR(t.bankVolume() + t.lostVolume(), m0, 1e-9 * std::abs(m0) + 1e-9);
  // (Where loose soil comes to rest is tested on its own below: the windrows this run leaves
  // behind the blade are outside the relaxation's box and keep their slopes.)
}

TEST(Deformation, LooseSoilRestsAtItsReposeAndSlidesBeyondIt) {
  // A ramp of loose clay across the whole grid (no side faces), rising along +x at s times the
  // repose of the soil table's clay (I_d 0.3), ahead of an upright blade facing it: every pair of
  // neighbours along x differs by s * res * tan(repose), along y by nothing. At s = 0.99 the ramp
  // is at rest (relaxLoose moves nothing, bit for bit); at s = 1.01 it slides, conserving the
  // soil, and no pair ends steeper than it began.
  const SoilProperties clay = soilProperties(SoilFamily::Clay, 0.3);
  const double tanr = std::tan(clay.repose_rad), res = 0.02;
  for (const double s : {0.99, 1.01}) {
    TerrainSpec spec;
    spec.size_x_m = 4; spec.size_y_m = 2; spec.origin_x_m = -2; spec.origin_y_m = -1; spec.resolution_m = res;
    TruthTerrain t = buildTerrain(spec);
    const SoilField field(clay, {});
    for (int j = 0; j < t.ny(); ++j)
      for (int i = 0; i < t.nx(); ++i) {
        const double l = std::min(0.3, std::max(0.0, t.nodePosition(i, j).x() + 1.2) * s * tanr);
        if (l > 0) t.addLoose(i, j, l, l / clay.swell);
      }
    const double m0 = t.bankVolume();
    const std::vector<double> h0 = t.heightData();
    auto steepest = [&]() {
      double worst = 0;
      for (int j = 0; j < t.ny(); ++j)
        for (int i = 0; i + 1 < t.nx(); ++i) worst = std::max(worst, std::abs(t.height(i + 1, j) - t.height(i, j)));
      return worst / res;
    };
    const double before = steepest();
    EXPECT_NEAR(before, s * tanr, 1e-9);
    // The blade's edge at x = -1.5, facing the ramp that starts at -1.2; the relaxation box
    // (1.5 m ahead, 0.5 m beside the 1.85 m blade) covers the ramp and the whole 2 m width.
    const CutResult r = relaxLoose(t, field, uprightBlade(-1.5, 0.0, 0.0), BladeGeometry{}, 1.5, 0.5, 20);
    if (s < 1.0) {
      EXPECT_TRUE(r.empty()) << "a ramp below the repose moved";
      EXPECT_TRUE(t.heightData() == h0);
    } else {
      EXPECT_FALSE(r.empty()) << "a ramp beyond the repose did not move";
      EXPECT_FALSE(t.heightData() == h0);
      EXPECT_LE(steepest(), before + 1e-12);
      EXPECT_NEAR(t.bankVolume(), m0, 1e-9 * std::abs(m0) + 1e-12);
    }
  }
}

TEST(Deformation, SpoilPileStaysNearTheRepose) {
  // An 8 cm cut in loam at 0.8 m/s feeds ~0.1 m^2/s of spoil onto the node row ahead of the
  // edge. The pile must run down its front, not stack into a column (it reached 4.7 m before
  // the settling in cutAndPush): the surface nowhere rises much above the blade (0.76 m).
  Simulator sim(parseScenario(scenarioYaml("{family: loam, relative_density: 0.3}", 0.08, 0.0, 9.0, 1, false), "pile.yaml"));
  std::vector<Event> ev;
  double max_rise = 0;
  int step = 0;
  while (sim.next(ev)) {
    ev.clear();
    if (++step % 30) continue;
    const TruthTerrain& t = sim.truth();
    for (int j = 0; j < t.ny(); ++j)
      for (int i = 0; i < t.nx(); ++i) max_rise = std::max(max_rise, t.height(i, j) - t.initialHeight(i, j));
  }
  EXPECT_GT(sim.machineTruth(0).cut_bank_m3, 0.3);  // it did cut and push (~0.5 m^3)
  EXPECT_GT(max_rise, 0.2);
  EXPECT_LT(max_rise, 0.9);
}

namespace {
// The CTL's drive (engine/sim/ctl.cpp, docs/sim.md): the tracks push at most
// f_lim = min(mu W cos(pitch), max_drive_force) (mu = 0.75, W = 5200 kg * g: 38.3 kN, below the
// 42 kN drive limit); the force they push grows linearly with the slip v_d - v and mobilises
// f_lim at 0.1 m/s; the grade W sin(pitch) and the rolling resistance 0.04 W oppose it.
constexpr double kW = 5200 * 9.80665, kRoll = 0.04 * kW, kFullSlip = 0.1;
double tractionLimit(double pitch) { return std::min(0.75 * kW * std::cos(pitch), 42000.0); }

/// Pitch of the base and the soil force along the travel direction (N, resisting > 0).
struct DriveSample { double pitch, soil_n, speed, x; bool stalled; };
DriveSample driveSample(const Simulator& sim) {
  const Eigen::Vector3d fwd = sim.machine(0).T_map_base().linear().col(0);
  const Eigen::Vector3d fh = Eigen::Vector3d(fwd.x(), fwd.y(), 0).normalized();
  return {std::asin(fwd.z()), -sim.machineTruth(0).force_map_N.dot(fh), sim.machine(0).speed(), sim.machine(0).x(),
          sim.machineTruth(0).stalled};
}

/// The scenario without the force sensor's noise, so the drive's force balance is exact.
Scenario noiseFree(Scenario sc) {
  sc.machines[0].force_noise_abs_n = 0;
  sc.machines[0].force_noise_rel = 0;
  return sc;
}
}  // namespace

TEST(Ctl, StallsWhenTheCutIsTooDeepForTheTractiveForce) {
  // Dense clay (c = 70 kPa) at 0.3 m: the FEE force across 1.85 m far exceeds the traction.
  // Blade raising is disabled to see the stall. A machine at rest against more soil than its
  // tracks can push mobilises exactly what they can: the soil force it holds is
  // f_lim - W sin(pitch) - 0.04 W (36.2 kN on the flat), to rounding, at every step at rest;
  // and it stays at rest (the blade only goes deeper).
  Scenario deep = noiseFree(parseScenario(scenarioYaml("{family: clay, relative_density: 1.0}", 0.30, 0.0, 6.0, 1, false), "deep.yaml"));
  deep.machines[0].lift_down_force_n = 1e9;  // let the blade reach the depth
  deep.machines[0].joint_min[0] = -0.35;
  Simulator sim(deep);
  std::vector<Event> ev;
  int steps = 0, at_rest = 0, first_rest = -1, moved_after_rest = 0, off = 0, held_steps = 0;
  double x_rest = 0;
  while (sim.next(ev)) {
    ev.clear();
    const DriveSample d = driveSample(sim);
    ++steps;
    if (d.speed != 0.0) {
      moved_after_rest += first_rest >= 0;
      continue;
    }
    ++at_rest;
    EXPECT_TRUE(d.stalled) << "step " << steps;
    if (first_rest < 0) {  // the step it stopped in mobilised its momentum too: not judged
      first_rest = steps;
      x_rest = d.x;
      continue;
    }
    EXPECT_EQ(d.x, x_rest);
    const double held = tractionLimit(d.pitch) - kW * std::sin(d.pitch) - kRoll;
    ++held_steps;
    if (std::abs(d.soil_n - held) > 1e-9 * held) ++off;
  }
  ASSERT_GE(first_rest, 0) << "never stopped";
  EXPECT_EQ(moved_after_rest, 0);
  EXPECT_EQ(at_rest, steps - first_rest + 1);  // at rest from the first stop to the end
  // The lift lowers the blade at 0.5 m/s (joint_max_rate): the 0.3 m cut, and with it the stall,
  // comes within the first second of the six, not at the end.
  EXPECT_GT(at_rest, steps / 2);
  EXPECT_EQ(held_steps, at_rest - 1);
  EXPECT_EQ(off, 0) << "steps at rest whose soil force is not traction - grade - rolling resistance";
}

TEST(Ctl, ShallowCutCoversTheRouteAtTheCommandedSpeedLessTheSlip) {
  // Shallow cut in loose sand: never stalls, and the distance follows from the drive model.
  // The track speed follows the 0.8 m/s command with the 0.2 s lag tau (it covers 0.8 (T - tau));
  // the machine runs behind it by the slip that mobilises the resistance,
  // s = 0.1 m/s * (R + 0.04 W + W sin(pitch)) / f_lim, plus (0.1 m / f_lim) dv/dt while it
  // accelerates. Integrated: x(T) = 0.8 (T - tau) - 0.1 / f_lim * int(R + 0.04 W + W sin) dt
  // - (0.1 m / f_lim) v(T). Valid while the slip stays under 0.1 m/s (checked: the largest
  // load is below f_lim). Tolerance: the lag's discretisation (0.8 m/s * one 1/240 s physics
  // step) plus the load sampled once per 1/60 s observation (a Riemann sum: total variation of
  // the load * 1/60 s, times 0.1 / f_lim).
  const Scenario sc = noiseFree(parseScenario(scenarioYaml("{family: sand, relative_density: 0.1}", 0.05, 0.0, 6.0, 1, false), "easy.yaml"));
  Simulator easy(sc);
  std::vector<Event> ev;
  const double dt_obs = 1.0 / sc.observation_hz, dt_phys = 1.0 / sc.physics_hz, f_lim = tractionLimit(0.0);
  int stalled = 0;
  double load_int = 0, load_max = 0, tv = 0, prev = 0;
  while (easy.next(ev)) {
    ev.clear();
    const DriveSample d = driveSample(easy);
    stalled += d.stalled ? 1 : 0;
    const double load = d.soil_n + kRoll + kW * std::sin(d.pitch);
    load_int += load * dt_obs;
    load_max = std::max(load_max, load);
    tv += std::abs(d.soil_n - prev);
    prev = d.soil_n;
  }
  EXPECT_EQ(stalled, 0);
  ASSERT_LT(load_max, f_lim);  // the slip never saturates: the linear drive model holds
  const double T = sc.duration_s, tau = sc.machines[0].drive_time_constant_s;
  const double expect = 0.8 * (T - tau) - kFullSlip / f_lim * load_int - kFullSlip * 5200 / f_lim * easy.machine(0).speed();
  const double tol = 0.8 * dt_phys + kFullSlip / f_lim * tv * dt_obs;
  EXPECT_NEAR(easy.machine(0).x(), expect, tol) << "tolerance " << tol;
  EXPECT_LT(tol, 0.02);  // the check is centimetre-sharp (the slip alone costs ~0.2 m here)
}

TEST(Ctl, SpeedControllerRaisesTheBladeWhenTrackingFails) {
  // The same deep cut with the stall raise on (0.3 m/s once the speed stayed under half the
  // 0.8 m/s set-point for stall_time_s = 0.3 s). While at rest the machine holds what its tracks
  // can push (as above); no raise before the speed has been low for stall_time_s (to one 1/60 s
  // observation); it can only start again once the soil force has fallen below
  // f_lim - grade - rolling resistance (from rest the tracks push at most f_lim), which takes a
  // raise; and it does start again.
  Scenario deep = noiseFree(parseScenario(scenarioYaml("{family: clay, relative_density: 1.0}", 0.30, 0.3, 8.0, 1, false), "deep.yaml"));
  deep.machines[0].lift_down_force_n = 1e9;
  deep.machines[0].joint_min[0] = -0.35;
  const double dt_obs = 1.0 / deep.observation_hz;
  const double stall_time = deep.machines[0].controller.stall_time_s;
  Simulator sim(deep);
  std::vector<Event> ev;
  double max_raise = 0, slow_for = 0, prev_speed = -1, prev_x = NAN, x_rest = NAN;
  int off = 0, held_steps = 0, early_raise = 0, restarts = 0, bad_restarts = 0;
  while (sim.next(ev)) {
    ev.clear();
    const DriveSample d = driveSample(sim);
    // At rest through the whole observation period (every physics step in it started at rest).
    const bool held = d.speed == 0.0 && prev_speed == 0.0 && d.x == prev_x;
    prev_x = d.x;
    const double raise = sim.machineTruth(0).raise_offset_m;
    max_raise = std::max(max_raise, raise);
    slow_for = d.speed < 0.5 * 0.8 ? slow_for + dt_obs : 0.0;
    if (max_raise == 0.0 && raise > 0.0 && slow_for < stall_time - dt_obs) ++early_raise;
    const double can_push = tractionLimit(d.pitch) - kW * std::sin(d.pitch) - kRoll;
    if (d.speed == 0.0) {
      if (std::isnan(x_rest)) x_rest = d.x;
      if (held) {
        ++held_steps;
        if (std::abs(d.soil_n - can_push) > 1e-9 * can_push) ++off;
      }
    } else if (prev_speed == 0.0) {
      ++restarts;
      if (!(d.soil_n < can_push) || !(raise > 0.0)) ++bad_restarts;
    }
    prev_speed = d.speed;
  }
  ASSERT_FALSE(std::isnan(x_rest)) << "never stalled";
  EXPECT_GT(held_steps, 0);
  EXPECT_EQ(off, 0);
  EXPECT_EQ(early_raise, 0);
  EXPECT_GT(restarts, 0);
  EXPECT_EQ(bad_restarts, 0);
  EXPECT_GT(max_raise, 0.0);
  EXPECT_GT(sim.machine(0).x(), x_rest + 1.0);  // it got going again and kept going
}

namespace {
/// The lane (0, 1, ..) of every forward pass a route drives, from the true base position while
/// the controller drives forward with its blade down, one entry per pass; and whether the
/// controller was still driving at the end.
struct LaneLog {
  std::vector<int> lanes;
  bool driving_at_end = false;
};
LaneLog forwardLanes(bool loop, double duration_s) {
  const std::string yaml =
      "version: 1\nseed: 4\nduration_s: " + std::to_string(duration_s) +
      "\nthreads: 1\nterrain: {size_m: [12, 8], origin_m: [-4, -3], resolution_m: 0.02}\n"
      "soil: {default: {family: sand, relative_density: 0.1}}\n"
      "machines:\n  - id: ctl1\n    controller: {type: route, start_m: [0, 0], length_m: 1.5, spacing_m: 1.2, passes: 2, "
      "depth_m: 0.0, speed_mps: 0.8, loop: " + std::string(loop ? "true" : "false") + "}\n";
  Simulator sim(noiseFree(parseScenario(yaml, "loop.yaml")));
  std::vector<Event> ev;
  LaneLog log;
  bool in_pass = false;
  while (sim.next(ev)) {
    ev.clear();
    const MachineTruth& m = sim.machineTruth(0);
    const bool forward = m.setpoints[0] > 0 && m.twist_base[0] > 0.2;
    if (forward && !in_pass) log.lanes.push_back(static_cast<int>(std::lround(m.T_map_base.translation().y() / 1.2)));
    in_pass = forward;
    log.driving_at_end = m.setpoints[0] > 0;
  }
  return log;
}
}  // namespace

TEST(Ctl, LoopingRouteGoesBackAndForthOverItsLanesAndNeverEnds) {
  // Two lanes, 1.5 m long: without `loop` the route ends after lane 1; with it, the lanes
  // are driven 0, 1, 0, 1, .. for as long as the episode runs (a soak drives one for an hour).
  const LaneLog once = forwardLanes(false, 40.0);
  EXPECT_EQ(once.lanes, (std::vector<int>{0, 1}));
  EXPECT_FALSE(once.driving_at_end);
  const LaneLog looped = forwardLanes(true, 40.0);
  ASSERT_GE(looped.lanes.size(), 5u) << "a pass of 1.5 m and the return take well under 8 s";
  for (size_t k = 0; k < looped.lanes.size(); ++k) EXPECT_EQ(looped.lanes[k], static_cast<int>(k % 2)) << "pass " << k;
  EXPECT_TRUE(looped.driving_at_end);
}

TEST(Ctl, RouteGivesUpAPassItIsStuckInAndTakesTheNextLane) {
  // A 0.6 m berm of dense clay across both lanes (1.2 m apart) at x = 5, a shallow cut and a
  // blade that never rises: the machine stalls at the berm for good. With stall.give_up_s = 2 it
  // backs off after 2 s stuck, reverses onto lane 1 and drives it up to the berm; without, it
  // stays at the berm in lane 0 for the whole episode (as the one-hour soak's machine did at a
  // pile of its own spoil, the map frozen with it).
  auto run = [](double give_up_s) {
    const std::string yaml =
        "version: 1\nseed: 9\nduration_s: 25\nthreads: 1\n"
        "terrain: {size_m: [14, 8], origin_m: [-3, -3], resolution_m: 0.02, hills: {list: ["
        "{x_m: 5, y_m: -1, amplitude_m: 0.6, sigma_m: 0.5}, {x_m: 5, y_m: 0, amplitude_m: 0.6, sigma_m: 0.5}, "
        "{x_m: 5, y_m: 1, amplitude_m: 0.6, sigma_m: 0.5}, {x_m: 5, y_m: 2, amplitude_m: 0.6, sigma_m: 0.5}]}}\n"
        "soil: {default: {family: clay, relative_density: 1.0}}\n"
        "machines:\n  - id: ctl1\n    controller: {type: route, start_m: [0, 0], length_m: 8, spacing_m: 1.2, passes: 2, "
        "depth_m: 0.02, speed_mps: 0.8, stall: {raise_rate_mps: 0.0, give_up_s: " + std::to_string(give_up_s) + "}}\n";
    Simulator sim(noiseFree(parseScenario(yaml, "berm.yaml")));
    std::vector<Event> ev;
    double max_x = -1e9, max_y = -1e9;
    while (sim.next(ev)) {
      ev.clear();
      max_x = std::max(max_x, sim.machine(0).x());
      max_y = std::max(max_y, sim.machine(0).y());
    }
    return std::make_pair(max_x, max_y);
  };
  const auto stuck = run(0.0), gave_up = run(2.0);
  EXPECT_LT(stuck.first, 3.0) << "the berm stops the machine well before the 8 m lane ends";
  EXPECT_LT(stuck.second, 0.3) << "without give_up_s it never leaves lane 0";
  EXPECT_GT(gave_up.second, 1.1) << "with it, it drove lane 1 (y = 1.2 m)";
  EXPECT_LT(gave_up.first, 3.0) << "and stopped at the berm there too";
}

TEST(Ctl, CutToGradeDeepensTheLaneByTheStepEveryPass) {
  // Loose sand, one 6 m lane driven three times to grade: -0.05 m, then -0.10, -0.15 (or with a
  // step of 0.03 m: -0.03, -0.06, -0.09); the middle of the lane ends at the last grade.
  auto run = [](double step) {
    const std::string yaml =
        std::string("version: 1\nseed: 3\nduration_s: 60\nthreads: 1\n") +
        "terrain: {size_m: [12, 6], origin_m: [-3, -3], resolution_m: 0.02}\n"
        "soil: {default: {family: sand, relative_density: 0.1}}\n"
        "machines:\n  - id: ctl1\n    controller: {type: route, start_m: [0, 0], length_m: 6, spacing_m: 0, passes: 3, "
        "depth_m: 0.05, speed_mps: 0.6, stall: {raise_rate_mps: 0.0}"
        ", grade: {first_m: " + std::to_string(step) + ", step_m: " + std::to_string(step) + ", lowest_m: -0.5}}\n"
        // The controller's grading under the fixed-coefficient drive (with the track–soil model
        // on this loose sand the lane ends at -0.11 m after the three passes, not -0.15 m).
        "    vehicle: {track_soil: none}\n";
    Simulator sim(noiseFree(parseScenario(yaml, "grade.yaml")));
    std::vector<Event> ev;
    std::vector<double> edge;  // edge heights while driving forward over x in [3, 5] on pass 0
    bool reversed = false;
    while (sim.next(ev)) {
      ev.clear();
      const MachineTruth& t = sim.machineTruth(0);
      if (t.twist_base(0) < -0.05) reversed = true;
      const double xe = t.T_map_blade.translation().x();
      if (!reversed && t.twist_base(0) > 0.05 && xe > 3.0 && xe < 5.0) edge.push_back(t.T_map_blade.translation().z());
    }
    std::sort(edge.begin(), edge.end());
    const double median = edge.empty() ? std::nan("") : edge[edge.size() / 2];
    return std::make_pair(median, sim.truth().undisturbedAt(4.0, 0.0));
  };
  const auto [edge5, bank5] = run(-0.05);
  const auto [edge3, bank3] = run(-0.03);
  EXPECT_NEAR(edge5, -0.05, 0.02) << "pass 0 holds its grade";
  EXPECT_NEAR(edge3, -0.03, 0.02);
  EXPECT_NEAR(bank5, -0.15, 0.03) << "three passes, three steps";
  EXPECT_NEAR(bank3, -0.09, 0.03);
}

TEST(Simulator, EventsAreTimeOrderedAndMassIsConserved) {
  // With the default track–soil model: its ruts compact bank soil, which the balance counts.
  Simulator sim(parseScenario(scenarioYaml("{family: loam, relative_density: 0.4}", 0.1, 0.15, 2.0, 2, true, "bekker"), "s.yaml"));
  const double m0 = sim.truth().bankVolume();
  std::vector<Event> ev;
  double last = -1;
  int clouds = 0, obs = 0;
  while (sim.next(ev)) {
    for (const Event& e : ev) {
      ASSERT_GE(stampOf(e), last);
      last = stampOf(e);
      clouds += std::holds_alternative<PointCloud>(e);
      obs += std::holds_alternative<Observation>(e);
    }
    ev.clear();
  }
  EXPECT_EQ(obs, 120);
  // Scans at k / rate for k = 0.. (scan 0 at the first physics step): 21 vlp32 + 51 single line.
  EXPECT_EQ(clouds, 21 + 51);
  EXPECT_GT(sim.machineTruth(0).cut_bank_m3, 0.01);
  EXPECT_GT(sim.truth().compactedVolume(), 0.0);
  EXPECT_NEAR(sim.truth().bankVolume() + sim.truth().lostVolume() + sim.truth().compactedVolume(), m0,
              1e-9 * std::abs(m0) + 1e-9);
}

namespace {
void flatten(const std::vector<Event>& ev, std::vector<double>& nums, std::vector<float>& pts) {
  for (const Event& e : ev) {
    nums.push_back(stampOf(e));
    if (const auto* p = std::get_if<PointCloud>(&e)) {
      pts.insert(pts.end(), reinterpret_cast<const float*>(p->points.data()),
                 reinterpret_cast<const float*>(p->points.data()) + 4 * p->points.size());
      for (int k = 0; k < 16; ++k) nums.push_back(p->T_map_sensor.matrix().data()[k]);
    } else if (const auto* o = std::get_if<Observation>(&e)) {
      for (int k = 0; k < 16; ++k) nums.push_back(o->T_map_blade.matrix().data()[k]);
      for (int k = 0; k < 16; ++k) nums.push_back(o->T_map_base.matrix().data()[k]);
      for (int k = 0; k < 6; ++k) nums.push_back(o->twist_base[k]);
      for (int k = 0; k < 3; ++k) nums.push_back(o->cylinder_length_m[k]);
      for (int k = 0; k < 3; ++k) nums.push_back(o->force_base_N[k]);
      nums.push_back(o->engine_speed_rpm);
    } else if (const auto* q = std::get_if<Pose>(&e)) {
      for (int k = 0; k < 16; ++k) nums.push_back(q->T_map_base.matrix().data()[k]);
    } else if (const auto* b = std::get_if<BladePose>(&e)) {
      for (int k = 0; k < 16; ++k) nums.push_back(b->T_map_blade.matrix().data()[k]);
    }
  }
}
}  // namespace

TEST(Simulator, SameSeedIsBitIdenticalForAnyThreadCount) {
  // Runs 0-2: 1 thread (serial), 2 threads with the physics overlapping the scans (default),
  // 2 threads without overlap; run 3: another seed; run 4: 2 threads overlapping on the
  // std::thread executor (ThreadSanitizer builds' default). The scenario has the default (rtk_imu)
  // localisation, so the estimator's draws (cloud, base and blade poses) are part of the stream. Besides the events, what a caller reads
  // between periods (truth(), machineTruth(), machine()) must be that period's, in every mode.
  std::vector<double> n[5], views[5];
  std::vector<float> p[5];
  for (int run = 0; run < 5; ++run) {
    Scenario sc = parseScenario(scenarioYaml("{family: loam, relative_density: 0.4}", 0.1, 0.15, 1.5, run == 0 || run == 3 ? 1 : 2, true), "s.yaml");
    if (run == 2) sc.overlap_scans = false;
    if (run == 3) sc.seed = 10;
    Simulator sim(sc, run == 4 ? Executor::Backend::kThreads : Executor::kDefaultBackend);
    std::vector<Event> ev;
    while (sim.next(ev)) {
      if (sim.step() % 7 != 3) continue;
      const TruthTerrain& t = sim.truth();
      views[run].insert(views[run].end(), t.heightData().begin(), t.heightData().end());
      views[run].insert(views[run].end(), t.looseBankData().begin(), t.looseBankData().end());
      views[run].push_back(t.lostVolume());
      views[run].push_back(sim.time());
      views[run].push_back(sim.machineTruth(0).cut_bank_m3);
      views[run].push_back(sim.machineTruth(0).force_map_N.x());
      views[run].push_back(sim.machine(0).x());
      views[run].push_back(static_cast<double>(sim.stats().scans));
    }
    flatten(ev, n[run], p[run]);
    const TruthTerrain& t = sim.truth();
    views[run].insert(views[run].end(), t.undisturbedData().begin(), t.undisturbedData().end());
    views[run].insert(views[run].end(), t.looseData().begin(), t.looseData().end());
  }
  for (int run : {1, 2, 4}) {
    ASSERT_EQ(n[0].size(), n[run].size());
    ASSERT_EQ(p[0].size(), p[run].size());
    ASSERT_EQ(views[0].size(), views[run].size());
    EXPECT_EQ(0, std::memcmp(n[0].data(), n[run].data(), n[0].size() * sizeof(double))) << "run " << run;
    EXPECT_EQ(0, std::memcmp(p[0].data(), p[run].data(), p[0].size() * sizeof(float))) << "run " << run;
    EXPECT_EQ(0, std::memcmp(views[0].data(), views[run].data(), views[0].size() * sizeof(double))) << "run " << run;
  }
  // A different seed changes the noise.
  EXPECT_FALSE(p[0].size() == p[3].size() && std::memcmp(p[0].data(), p[3].data(), p[0].size() * sizeof(float)) == 0);
}

TEST(Simulator, StopsCleanlyWhileThePhysicsRunsAhead) {
  // Destroyed a few periods in, while producer tasks may be queued or running (a sanitizer
  // or a hang would show a task outliving the simulator), on either executor backend.
  // (TBB is not instrumented, so ThreadSanitizer builds run the std::thread backend only.)
  for (auto backend : TERRAMAP_THREAD_SANITIZER ? std::vector<Executor::Backend>{Executor::Backend::kThreads}
                                                : std::vector<Executor::Backend>{Executor::Backend::kTbb,
                                                                                 Executor::Backend::kThreads})
    for (int k = 1; k < 6; ++k) {
      Simulator sim(parseScenario(scenarioYaml("{family: loam, relative_density: 0.4}", 0.1, 0.15, 1.5, 2, true), "s.yaml"),
                    backend);
      std::vector<Event> ev;
      for (int i = 0; i < k; ++i) ASSERT_TRUE(sim.next(ev));
      EXPECT_EQ(sim.step(), k);
    }
  // Run to the end: next() stays false after the last period.
  Simulator sim(parseScenario(scenarioYaml("{family: loam, relative_density: 0.4}", 0.1, 0.15, 0.2, 2, true), "s.yaml"));
  std::vector<Event> ev;
  int periods = 0;
  while (sim.next(ev)) ++periods;
  EXPECT_EQ(periods, 12);
  EXPECT_FALSE(sim.next(ev));
}

TEST(Simulator, ProgressesWhenTheExecutorsWorkerIsBusyElsewhere) {
  // Another arena's tasks hold TBB's worker(s) until the simulator has delivered 20 periods:
  // its physics must then run on the caller's thread instead of waiting for a worker.
  std::atomic<int> periods{0};
  Executor other(2);
  std::thread hog([&] {
    other.forEach(2, [&](int) {
      while (periods.load() < 20) std::this_thread::yield();
    });
  });
  Scenario sc = parseScenario(scenarioYaml("{family: loam, relative_density: 0.4}", 0.1, 0.15, 1.0, 2, true), "s.yaml");
  std::vector<Event> ev;
  {
    // Destroyed with a physics task queued and no worker to take it: must not hang.
    Simulator early(sc);
    for (int i = 0; i < 5; ++i) ASSERT_TRUE(early.next(ev));
  }
  Simulator sim(sc);
  while (sim.next(ev)) periods.fetch_add(1);
  hog.join();
  EXPECT_EQ(periods.load(), 60);
}

// Found by fuzz_episode_h5 (docs/reliability.md, "Fuzzing"): asked for a dataset this damaged
// file lacks, the reader probed the root's "version" attribute for its hint, and libhdf5
// 1.10.8 read past its buffer decoding the damaged attribute (SEGV). The hint now comes from the
// dataset's name; the attributes are never decoded.
TEST(Episode, DamagedFileIsAnInputErrorWithoutReachingLibhdf5) {
  // fuzz_episode_h5's finding was an unsealed file whose root attribute was damaged. The same
  // kind of file, made here: a real episode with its seal wiped (the 512-byte user block, which
  // libhdf5 skips) and the bytes after the root's "version" attribute name overwritten. It is
  // refused by its (missing) seal before libhdf5 opens it.
  const std::string dir = std::string(TERRAMAP_BINARY_DIR) + "/sim_test_episode_unsealed";
  std::filesystem::remove_all(dir);
  const Scenario sc = parseScenario(scenarioYaml("{family: loam, relative_density: 0.4}", 0.1, 0.15, 0.2, 1, true), "s.yaml");
  const std::string path = runEpisode(sc, dir, EpisodeOptions{});
  {
    std::ifstream in(path, std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    in.close();
    ASSERT_GT(bytes.size(), 4096u);
    std::fill(bytes.begin(), bytes.begin() + 512, '\0');
    const std::size_t at = bytes.find("version", 512);
    ASSERT_NE(at, std::string::npos);
    std::fill(bytes.begin() + static_cast<std::ptrdiff_t>(at) + 7, bytes.begin() + static_cast<std::ptrdiff_t>(at) + 23, '\xff');
    std::ofstream(path, std::ios::binary | std::ios::trunc).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  }
  std::vector<std::uint64_t> dims;
  for (const char* name : {"/terrain/height", "/machines/ctl1/T_map_base", "/machines/ctl1/estimate/T_map_base"}) {
    try {
      readEpisodeDataset(path, name, dims);
      ADD_FAILURE() << "expected an InputError for " << name;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("no terramap seal"), std::string::npos) << e.what();
    }
  }
  std::filesystem::remove_all(dir);
}

TEST(Episode, AByteDamagedInsideTheDataIsRefusedNotReadAsOtherValues) {
  // One flipped bit in the raw (uncompressed) initial terrain reads back as another height
  // through libhdf5 without any error; the seal turns it into an InputError.
  const std::string dir = std::string(TERRAMAP_BINARY_DIR) + "/sim_test_episode_damage";
  std::filesystem::remove_all(dir);
  const Scenario sc = parseScenario(scenarioYaml("{family: loam, relative_density: 0.4}", 0.1, 0.15, 0.2, 2, true), "s.yaml");
  EpisodeOptions opt;
  opt.compression = 0;
  const std::string path = runEpisode(sc, dir, opt);
  std::vector<std::uint64_t> dims;
  const std::vector<double> before = readEpisodeDataset(path, "/terrain/initial_height", dims);
  ASSERT_GT(before.size(), 1000u);
  // The file offset of the dataset's middle value: find its bytes in the file.
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  in.close();
  const std::size_t mid = before.size() / 2;
  float row[4];
  for (int k = 0; k < 4; ++k) row[k] = static_cast<float>(before[mid + k]);
  const std::size_t at = bytes.find(std::string(reinterpret_cast<const char*>(row), sizeof row));
  ASSERT_NE(at, std::string::npos);
  bytes[at + 1] = static_cast<char>(bytes[at + 1] ^ 0x01);
  std::ofstream(path, std::ios::binary | std::ios::trunc).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  try {
    readEpisodeDataset(path, "/terrain/initial_height", dims);
    ADD_FAILURE() << "a damaged value was read without an error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("damaged: checksum"), std::string::npos) << e.what();
  }
  std::filesystem::remove_all(dir);
}

TEST(Episode, HdfLayoutReadsBack) {
  const std::string dir = std::string(TERRAMAP_BINARY_DIR) + "/sim_test_episode";
  std::filesystem::remove_all(dir);
  const Scenario sc = parseScenario(scenarioYaml("{family: loam, relative_density: 0.4}", 0.1, 0.15, 1.0, 2, true), "s.yaml");
  const std::string path = runEpisode(sc, dir);
  // Reference values from a second, identical run.
  Simulator sim(sc);
  std::vector<Event> ev;
  std::vector<Observation> obs;
  std::vector<MachineTruth> truths;
  std::size_t top_points = 0, top_scans = 0;
  std::vector<PointXYZI> top_values;
  while (sim.next(ev)) {
    for (auto& e : ev) {
      if (auto* o = std::get_if<Observation>(&e)) {
        obs.push_back(*o);
        truths.push_back(sim.machineTruth(0));
      }
      if (auto* p = std::get_if<PointCloud>(&e); p && p->frame == "ctl1/top") {
        top_points += p->points.size();
        ++top_scans;
        top_values.insert(top_values.end(), p->points.begin(), p->points.end());
      }
    }
    ev.clear();
  }
  std::vector<std::uint64_t> dims;
  auto readDoubles = [&path](const char* name, std::vector<std::uint64_t>& d) { return readEpisodeDataset(path, name, d); };
  const auto stamp = readDoubles("/machines/ctl1/stamp", dims);
  ASSERT_EQ(stamp.size(), obs.size());
  const auto force = readDoubles("/machines/ctl1/force_base_N", dims);
  ASSERT_EQ(dims.size(), 2u);
  EXPECT_EQ(dims[1], 3u);
  // Top level: the truth; estimate/: what the mapper received (the default rtk_imu
  // localisation, so the two differ) and their difference.
  const auto Tb = readDoubles("/machines/ctl1/T_map_blade", dims);
  ASSERT_EQ(dims.size(), 3u);
  const auto Tbe = readDoubles("/machines/ctl1/estimate/T_map_blade", dims);
  ASSERT_EQ(dims.size(), 3u);
  const auto Tbase = readDoubles("/machines/ctl1/T_map_base", dims);
  const auto Tbase_e = readDoubles("/machines/ctl1/estimate/T_map_base", dims);
  const auto cyl = readDoubles("/machines/ctl1/cylinder_length_m", dims);
  const auto cyl_e = readDoubles("/machines/ctl1/estimate/cylinder_length_m", dims);
  const auto err = readDoubles("/machines/ctl1/estimate/error_base", dims);
  ASSERT_EQ(dims.size(), 2u);
  EXPECT_EQ(dims[1], 6u);
  double max_err = 0;
  for (std::size_t k = 0; k < obs.size(); ++k) {
    ASSERT_EQ(stamp[k], obs[k].stamp);
    for (int a = 0; a < 3; ++a) ASSERT_EQ(force[k * 3 + a], obs[k].force_base_N[a]);
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) {
        ASSERT_EQ(Tb[k * 16 + r * 4 + c], truths[k].T_map_blade.matrix()(r, c));
        ASSERT_EQ(Tbe[k * 16 + r * 4 + c], obs[k].T_map_blade.matrix()(r, c));
        ASSERT_EQ(Tbase[k * 16 + r * 4 + c], truths[k].T_map_base.matrix()(r, c));
        ASSERT_EQ(Tbase_e[k * 16 + r * 4 + c], obs[k].T_map_base.matrix()(r, c));
      }
    for (int a = 0; a < 3; ++a) {
      ASSERT_EQ(cyl[k * 3 + a], truths[k].cylinder_length_m[a]);
      ASSERT_EQ(cyl_e[k * 3 + a], obs[k].cylinder_length_m[a]);
      ASSERT_EQ(err[k * 6 + a], obs[k].T_map_base.translation()[a] - truths[k].T_map_base.translation()[a]);
      max_err = std::max(max_err, std::abs(err[k * 6 + a]));
    }
  }
  EXPECT_GT(max_err, 0.0);
  const auto pts = readDoubles("/machines/ctl1/clouds/top/points", dims);
  EXPECT_EQ(dims[0], top_points);
  // The points themselves, in order (runEpisode hands the clouds' buffers to the writer).
  ASSERT_EQ(pts.size(), 4 * top_values.size());
  long wrong_points = 0;
  for (std::size_t k = 0; k < top_values.size(); ++k) {
    const PointXYZI& q = top_values[k];
    const float got[4] = {static_cast<float>(pts[4 * k]), static_cast<float>(pts[4 * k + 1]),
                          static_cast<float>(pts[4 * k + 2]), static_cast<float>(pts[4 * k + 3])};
    const float want[4] = {q.x, q.y, q.z, q.intensity};
    for (int a = 0; a < 4; ++a) wrong_points += !(got[a] == want[a] || (std::isnan(got[a]) && std::isnan(want[a])));
  }
  EXPECT_EQ(wrong_points, 0);
  const auto cnt = readDoubles("/machines/ctl1/clouds/top/count", dims);
  EXPECT_EQ(dims[0], top_scans);
  const auto h = readDoubles("/terrain/height", dims);
  ASSERT_EQ(dims.size(), 3u);
  EXPECT_EQ(dims[0], 3u);  // t = 0, 0.5, 1.0
  EXPECT_EQ(dims[1], 301u);
  EXPECT_EQ(dims[2], 701u);
  const auto c = readDoubles("/soil/c_pa", dims);
  EXPECT_NEAR(c[0], soilProperties(SoilFamily::Loam, 0.4).fee.c_pa, 1e-2);
  EXPECT_THROW(readEpisodeDataset(path, "/nope", dims), InputError);
  {
    // The terrain dataset (3 x 301 x 701 doubles, 5.1 MB) over a 1 MB memory budget: refused
    // before it is allocated, naming the file and the dataset.
    const std::uint64_t saved = memoryBudget();
    setMemoryBudget(1u << 20);
    try {
      readEpisodeDataset(path, "/terrain/height", dims);
      ADD_FAILURE() << "expected an InputError";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("dataset '/terrain/height' of 633003 values"), std::string::npos) << e.what();
    }
    setMemoryBudget(saved);
  }
  // No temporary files are left behind.
  int files = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) files += e.is_regular_file();
  EXPECT_EQ(files, 1);
}

TEST(Episode, TerrainSnapshotsReadBackBitForBitAsTheTruthTheyRecorded) {
  // The writer deflates only the snapshot chunks that changed and writes the others from the
  // previous snapshot's bytes (engine/sim/episode.cpp, GridSeries), on its writer thread. Read
  // back through libhdf5's own filters, every snapshot must be the truth terrain (as float) at
  // the time it was taken: unchanged chunks, cut chunks, partial edge chunks, with and without
  // compression. 14 m x 6 m at 2 cm = 701 x 301 nodes: 6 x 3 chunks of 128, the last ones partial;
  // the blade cuts along y = 0 only, so chunks away from it stay the same between snapshots.
  for (int gzip : {1, 0}) {
    const std::string dir = std::string(TERRAMAP_BINARY_DIR) + "/sim_test_snapshots_" + std::to_string(gzip);
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir);
    const std::string path = dir + "/episode.h5";
    const Scenario sc = parseScenario(scenarioYaml("{family: loam, relative_density: 0.4}", 0.1, 0.15, 1.6, 2, false), "s.yaml");
    Simulator sim(sc);
    std::vector<std::vector<float>> truth, truth_loose;
    auto take = [&] {
      const TruthTerrain& t = sim.truth();
      std::vector<float> h(static_cast<std::size_t>(t.nx()) * static_cast<std::size_t>(t.ny())), l(h.size());
      for (int j = 0; j < t.ny(); ++j)
        for (int i = 0; i < t.nx(); ++i) {
          h[static_cast<std::size_t>(j) * t.nx() + i] = static_cast<float>(t.height(i, j));
          l[static_cast<std::size_t>(j) * t.nx() + i] = static_cast<float>(t.looseData()[static_cast<std::size_t>(j) * t.nx() + i]);
        }
      truth.push_back(std::move(h));
      truth_loose.push_back(std::move(l));
    };
    EpisodeOptions opt;
    opt.compression = gzip;
    opt.clouds = false;
    {
      EpisodeWriter w(path, sim, opt);
      take();  // t = 0, written by the constructor
      double next = 0.5, last = 0.0;
      std::vector<Event> ev;
      while (sim.next(ev)) {
        w.record(sim, ev);
        ev.clear();
        if (sim.time() + 1e-9 >= next) {  // the writer's schedule (snapshot_interval_s 0.5)
          take();
          last = sim.time();
          while (next <= sim.time() + 1e-9) next += 0.5;
        }
      }
      if (std::abs(sim.time() - last) > 1e-9) take();  // close() adds the final state
      w.close(sim);
    }
    std::vector<std::uint64_t> dims;
    const std::vector<double> h = readEpisodeDataset(path, "/terrain/height", dims);
    ASSERT_EQ(dims.size(), 3u);
    ASSERT_EQ(dims[0], truth.size());
    ASSERT_GE(truth.size(), 4u);
    const std::vector<double> l = readEpisodeDataset(path, "/terrain/loose", dims);
    ASSERT_EQ(l.size(), h.size());
    const std::size_t n = truth[0].size();
    for (std::size_t k = 0; k < truth.size(); ++k) {
      long wrong = 0, wrong_loose = 0;
      for (std::size_t q = 0; q < n; ++q) {
        wrong += static_cast<float>(h[k * n + q]) != truth[k][q];
        wrong_loose += static_cast<float>(l[k * n + q]) != truth_loose[k][q];
      }
      EXPECT_EQ(wrong, 0) << "gzip " << gzip << ", snapshot " << k;
      EXPECT_EQ(wrong_loose, 0) << "gzip " << gzip << ", snapshot " << k;
    }
    // Not vacuous: the terrain did change between the first and the last snapshot, loose soil
    // included, and some chunks did not (the writer skips those).
    long changed = 0, changed_loose = 0;
    for (std::size_t q = 0; q < n; ++q) {
      changed += truth.front()[q] != truth.back()[q];
      changed_loose += truth_loose.front()[q] != truth_loose.back()[q];
    }
    EXPECT_GT(changed, 1000) << "gzip " << gzip;
    EXPECT_GT(changed_loose, 1000) << "gzip " << gzip;
    std::filesystem::remove_all(dir);
  }
}

TEST(Episode, TheSameScenarioWritesTheSameBytes) {
  // An episode's bytes depend on the scenario only: HDF5 objects carry no creation or
  // modification time (h5detail::makeGroup), so a sha1 of the file checks a reproduction. The two
  // runs are over a second apart, the resolution of HDF5's object times.
  const Scenario sc = parseScenario(scenarioYaml("{family: loam, relative_density: 0.4}", 0.1, 0.15, 1.0, 2, true), "s.yaml");
  std::string bytes[2];
  for (int run = 0; run < 2; ++run) {
    if (run == 1) std::this_thread::sleep_for(std::chrono::milliseconds(1100));
    const std::string dir = std::string(TERRAMAP_BINARY_DIR) + "/sim_test_episode_bytes_" + std::to_string(run);
    std::filesystem::remove_all(dir);
    const std::string path = runEpisode(sc, dir);
    std::ifstream in(path, std::ios::binary);
    bytes[run].assign((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    std::filesystem::remove_all(dir);
  }
  ASSERT_GT(bytes[0].size(), 100000u);
  EXPECT_EQ(bytes[0].size(), bytes[1].size());
  std::size_t differ = 0;
  for (std::size_t k = 0; k < std::min(bytes[0].size(), bytes[1].size()); ++k) differ += bytes[0][k] != bytes[1][k];
  EXPECT_EQ(differ, 0u);
}

TEST(TruthTerrain, ChangedSinceNamesTheBlocksARefreshCovered) {
  // 300 x 200 nodes: revision blocks of 16 x 16 cells; a node box counts the cells touching it.
  TruthTerrain t(0, 0, 0.02, 300, 200, 1.0);
  const std::uint64_t r0 = t.revision();
  EXPECT_FALSE(t.changedSince(r0, 0, 0, 299, 199));
  t.setUndisturbed(70, 10, 1.2);  // node (70, 10): block (1, 0)
  t.refreshPyramid(70, 10, 70, 10);
  EXPECT_GT(t.revision(), r0);
  EXPECT_TRUE(t.changedSince(r0, 64, 0, 127, 63));
  EXPECT_TRUE(t.changedSince(r0, 0, 0, 299, 199));
  EXPECT_FALSE(t.changedSince(r0, 0, 0, 63, 199));     // the blocks left of it
  EXPECT_FALSE(t.changedSince(r0, 128, 0, 299, 199));  // right of it
  EXPECT_FALSE(t.changedSince(r0, 64, 64, 127, 199));  // below it
  const std::uint64_t r1 = t.revision();
  EXPECT_FALSE(t.changedSince(r1, 0, 0, 299, 199));
  // A box over two blocks' edge stamps both; clamping and reversed corners are accepted.
  t.refreshPyramid(130, 70, 120, 60);
  EXPECT_TRUE(t.changedSince(r1, 64, 0, 127, 63));
  EXPECT_TRUE(t.changedSince(r1, 128, 64, 191, 127));
  EXPECT_FALSE(t.changedSince(r1, 192, 0, 1000, 1000));
  EXPECT_FALSE(t.changedSince(r1, 0, 0, 63, 63));
  // A copy (the simulator's LiDAR view) carries the revisions on.
  const TruthTerrain copy = t;
  EXPECT_EQ(copy.revision(), t.revision());
  EXPECT_TRUE(copy.changedSince(r1, 128, 64, 128, 64));
}

TEST(TruthTerrain, APatchReusedForASmallerBoxCarriesOnlyThatBox) {
  // The simulator hands applied patches back to the physics, whose buffers then only grow: a
  // patch refilled for a smaller box holds stale nodes past nodes() that must not be applied.
  TruthTerrain src(0, 0, 0.02, 120, 80, 1.0), dst(0, 0, 0.02, 120, 80, 1.0);
  for (int j = 0; j < 80; ++j)
    for (int i = 0; i < 120; ++i) src.setUndisturbed(i, j, 1.0 + 0.001 * i + 0.01 * j);
  TruthTerrain::Patch p;
  src.capturePatch(0, 0, 119, 79, p);  // the whole grid: the buffers' size
  EXPECT_EQ(p.nodes(), 120u * 80u);
  src.capturePatch(10, 20, 29, 24, p);  // 20 x 5 nodes into the same buffers
  EXPECT_EQ(p.nodes(), 100u);
  EXPECT_GE(p.u.size(), 120u * 80u);
  dst.applyPatch(p);
  for (int j = 0; j < 80; ++j)
    for (int i = 0; i < 120; ++i) {
      const bool in = i >= 10 && i <= 29 && j >= 20 && j <= 24;
      ASSERT_EQ(dst.height(i, j), in ? src.height(i, j) : 1.0) << i << ", " << j;
    }
  // A patch whose arrays are shorter than its box is refused, not read past its end.
  TruthTerrain::Patch bad = p;
  bad.lc.resize(99);
  EXPECT_THROW(dst.applyPatch(bad), std::invalid_argument);
}

TEST(TruthTerrain, FirstAndLastLooseFindWhatAScanOfEveryNodeFinds) {
  // The relaxation finds the loose soil in its box with firstLoose / lastLoose, which skip runs
  // of nodes flagged as never holding any: every way loose soil arrives (added, moved in, a
  // patch, a copy of the terrain) must flag its run, or the relaxation would miss soil.
  TruthTerrain t(0, 0, 0.02, 101, 23, 1.0), other(0, 0, 0.02, 101, 23, 1.0);
  std::mt19937_64 rng(5);
  std::uniform_int_distribution<int> I(0, 100), J(0, 22);
  auto check = [](const TruthTerrain& T, const char* when) {
    for (int j = 0; j < T.ny(); ++j)
      for (int a = 0; a < T.nx(); a += 7)
        for (int b = a; b < T.nx(); b += 11) {
          int first = b + 1, last = a - 1;
          for (int i = a; i <= b; ++i)
            if (T.loose(i, j) > 0.0) {
              if (first > b) first = i;
              last = i;
            }
          ASSERT_EQ(T.firstLoose(j, a, b), first) << when << ": row " << j << " [" << a << ", " << b << "]";
          ASSERT_EQ(T.lastLoose(j, a, b), last) << when << ": row " << j << " [" << a << ", " << b << "]";
        }
  };
  check(t, "flat");
  for (int k = 0; k < 12; ++k) t.addLoose(I(rng), J(rng), 0.01, 0.008);
  check(t, "added");
  // Moved out of its run into ones that never held any (the relaxation's moves).
  std::vector<std::pair<int, int>> holding;
  for (int j = 0; j < 23; ++j)
    for (int i = 0; i < 101; ++i)
      if (t.loose(i, j) > 0.0) holding.emplace_back(i, j);
  ASSERT_GE(holding.size(), 10u);
  for (const auto& [i, j] : holding) {
    t.moveLoose(i, j, (i + 9) % 101, j, 0.5 * t.loose(i, j));
    t.moveLoose(i, j, i, (j + 1) % 23, t.loose(i, j));  // all of it: the node holds none after
  }
  check(t, "moved");
  // Taken away again (the blade cutting it, a track pressing it): found no more.
  for (int j = 0; j < 23; ++j)
    for (int i = 0; i < 101; i += 2) t.removeBetween(i, j, 1.0, 2.0);  // the loose layer over U = 1
  check(t, "removed");
  for (int k = 0; k < 12; ++k) other.addLoose(I(rng), J(rng), 0.02, 0.015);
  TruthTerrain::Patch p;
  other.capturePatch(0, 0, 100, 22, p);
  t.applyPatch(p);  // the LiDAR view follows its physics terrain this way
  check(t, "patched");
  const TruthTerrain copy = t;
  check(copy, "copied");
}

TEST(Episode, ItsTimingSaysWhatTheWriterCost) {
  // What `terramap sim` prints beside the real-time factor: the writer thread's CPU (it runs on
  // the simulation's cores) and the close's share of the run (last writes, checksum, fsync).
  const std::string dir = std::string(TERRAMAP_BINARY_DIR) + "/sim_test_episode_timing";
  std::filesystem::remove_all(dir);
  const Scenario sc = parseScenario(scenarioYaml("{family: loam, relative_density: 0.4}", 0.1, 0.15, 1.0, 2, true), "s.yaml");
  EpisodeTiming tm;
  runEpisode(sc, dir, EpisodeOptions{}, &tm);
  EXPECT_GT(tm.setup_s, 0.0);
  EXPECT_GT(tm.writer_cpu_s, 0.0);  // it wrote the clouds and snapshots
  EXPECT_GT(tm.close_s, 0.0);
  EXPECT_LT(tm.close_s, tm.run_s);
  std::filesystem::remove_all(dir);
}
