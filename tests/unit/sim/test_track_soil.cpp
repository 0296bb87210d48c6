// Track–soil interaction (sim/track_soil.hpp, `vehicle.track_soil: bekker`, docs/sim.md
// "Track–soil interaction"): the formulas against hand-computed values, ruts as deep as Bekker's
// sinkage that a second pass does not deepen, mass kept with the compaction counted, and a
// machine cutting loose sand slower than without the model while dense ground changes little.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/sim/simulator.hpp>
#include <terramap/sim/track_soil.hpp>

#include <cmath>
#include <cstdio>
#include <string>

using namespace terramap;
using namespace terramap::sim;

namespace {

std::string scenarioYaml(const std::string& soil, const std::string& model, double depth, int passes = 1,
                         double duration = 8) {
  return "version: 1\nseed: 2\nduration_s: " + std::to_string(duration) +
         "\nterrain: {size_m: [16, 8], origin_m: [-4, -4], resolution_m: 0.02}\n"
         "soil: {default: {family: " + soil + "}}\n"
         "machines:\n  - id: ctl1\n    vehicle: {track_soil: " + model + "}\n"
         "    controller: {type: route, start_m: [0, 0], length_m: 6, passes: " + std::to_string(passes) +
         ", spacing_m: 0, depth_m: " + std::to_string(depth) + ", speed_mps: 1.0}\n";
}

struct Outcome {
  double distance = 0, mean_speed = 0, bank = 0, lost = 0, compacted = 0, bank0 = 0;
  std::vector<double> drop;  ///< initial minus final height per node
  double uncarved = 0;       ///< max |initial - (U + pressed)| over nodes: what no rut explains
  double pressed_m3 = 0;     ///< Σ pressed × res² (the rut record's volume)
};

Outcome simulate(const std::string& yaml) {
  Simulator sim(parseScenario(yaml, "s.yaml"));
  Outcome r;
  r.bank0 = sim.truth().bankVolume();
  const double x0 = sim.machine(0).x();
  std::vector<Event> ev;
  while (sim.next(ev)) ev.clear();
  r.distance = sim.machine(0).x() - x0;
  r.mean_speed = r.distance / sim.time();
  const TruthTerrain& t = sim.truth();
  r.bank = t.bankVolume();
  r.lost = t.lostVolume();
  r.compacted = t.compactedVolume();
  for (int j = 0; j < t.ny(); ++j)
    for (int i = 0; i < t.nx(); ++i) {
      r.drop.push_back(t.initialHeight(i, j) - t.height(i, j));
      const Eigen::Vector2d p = t.nodePosition(i, j);
      const double pressed = t.pressedAt(p.x(), p.y());
      r.uncarved = std::max(r.uncarved, std::abs(t.initialHeight(i, j) - (t.undisturbedAt(p.x(), p.y()) + pressed)));
      r.pressed_m3 += pressed * t.resolution() * t.resolution();
    }
  return r;
}

}  // namespace

TEST(TrackSoil, FormulasMatchHandComputedValues) {
  // Loose dry sand (Wong's LLL row): n 1.1, k_c 0.99 kN/m^2.1, k_phi 1528.43 kN/m^3.1, K 2.5 cm.
  const Terramechanics sand = terramechanics(soil::SoilFamily::Sand, 0.0);
  EXPECT_DOUBLE_EQ(sand.n, 1.1);
  EXPECT_NEAR(sand.k_phi, 1528.43e3, 1e-6);
  // A CAT 299-class CTL: 5200 kg on two 0.45 m x 1.9 m tracks: p = 29.83 kPa.
  const double p = 5200 * 9.80665 / (2 * 0.45 * 1.9);
  const double z = std::pow(p / (0.99e3 / 0.45 + 1528.43e3), 1 / 1.1);
  EXPECT_NEAR(bekkerSinkage(sand, p, 0.45), z, 1e-12);
  EXPECT_NEAR(z, 0.0279, 5e-4);
  EXPECT_NEAR(compactionResistance(sand, z, 0.45), 0.45 * (0.99e3 / 0.45 + 1528.43e3) * std::pow(z, 2.1) / 2.1, 1e-9);
  // Janosi–Hanamoto: 0 at no slip, ~ iL/2K for small slip i, odd, 1 - K/L (1 - e^(-L/K)) at full slip.
  EXPECT_EQ(janosiShare(0.0, 1.9, 0.025), 0.0);
  const double x = 1e-4 * 1.9 / 0.025;  // small slip: x / 2 - x^2 / 6 + O(x^3)
  EXPECT_NEAR(janosiShare(1e-4, 1.9, 0.025), x / 2 - x * x / 6, 1e-7);
  EXPECT_NEAR(janosiShare(1.0, 1.9, 0.025), 1 - 0.025 / 1.9 * (1 - std::exp(-1.9 / 0.025)), 1e-12);
  EXPECT_EQ(janosiShare(-0.3, 1.9, 0.025), -janosiShare(0.3, 1.9, 0.025));
  // Denser soil sinks less; the dense end of sand is LETE sand (k_phi 5301 kN/m^(n+2)).
  const Terramechanics dense = terramechanics(soil::SoilFamily::Sand, 1.0);
  EXPECT_NEAR(dense.k_phi, 5301e3, 1e-6);
  EXPECT_LT(bekkerSinkage(dense, p, 0.45), 0.1 * z);
  EXPECT_THROW(terramechanics(soil::SoilFamily::Clay, 1.5), std::invalid_argument);
}

TEST(TrackSoil, TracksPressRutsAsDeepAsTheSinkageOnceAndKeepTheMass) {
  // Blade raised (depth -0.2): only the tracks touch the ground. Loose sand: ruts of Bekker's
  // sinkage under both tracks, nothing between them; a second pass down the same lane (spacing
  // 0) does not deepen them. Mass: bank + lost + compacted is what it was.
  const double p = 5200 * 9.80665 / (2 * 0.45 * 1.9);
  const double z = bekkerSinkage(terramechanics(soil::SoilFamily::Sand, 0.0), p, 0.45);
  const Outcome one = simulate(scenarioYaml("sand, relative_density: 0.0", "bekker", -0.2, 1, 8));
  const Outcome two = simulate(scenarioYaml("sand, relative_density: 0.0", "bekker", -0.2, 2, 22));
  double max_one = 0, max_two = 0;
  long rut_nodes = 0;
  for (std::size_t k = 0; k < one.drop.size(); ++k) {
    max_one = std::max(max_one, one.drop[k]);
    max_two = std::max(max_two, two.drop[k]);
    rut_nodes += one.drop[k] > 0.9 * z;
  }
  EXPECT_NEAR(max_one, z, 1e-9);
  EXPECT_NEAR(max_two, z, 1e-9);
  // Two tracks 0.45 m wide over the ~6 m driven: ~2 x 22 x 300 nodes at 2 cm.
  EXPECT_GT(rut_nodes, 8000);
  EXPECT_GT(one.compacted, 0.0);
  EXPECT_NEAR(one.bank + one.lost + one.compacted, one.bank0, 1e-9 * std::abs(one.bank0) + 1e-9);
  EXPECT_NEAR(two.bank + two.lost + two.compacted, two.bank0, 1e-9 * std::abs(two.bank0) + 1e-9);
  // The truth records what it pressed (TruthSurface::Carved adds it back, so an evaluation does
  // not take the ruts for a cut): with the blade up, U + pressed is the initial surface.
  EXPECT_LT(one.uncarved, 1e-12);
  EXPECT_NEAR(one.pressed_m3, one.compacted, 1e-9 * one.compacted);
  // Without the model no rut at all.
  const Outcome none = simulate(scenarioYaml("sand, relative_density: 0.0", "none", -0.2, 1, 8));
  double max_none = 0;
  for (double d : none.drop) max_none = std::max(max_none, d);
  EXPECT_EQ(max_none, 0.0);
  EXPECT_EQ(none.compacted, 0.0);
}

TEST(TrackSoil, CuttingLooseSandIsSlowerWhileDenseGroundChangesLittle) {
  // Cutting 0.1 m deep at a 1 m/s set-point for 8 s. Loose sand: the tractive limit falls from
  // 0.75 W to W tan(28 deg) = 0.53 W and the ruts add compaction resistance: slower than the
  // same cut without the model. Dense sand: within a few per cent of it.
  const Outcome loose_none = simulate(scenarioYaml("sand, relative_density: 0.0", "none", 0.1));
  const Outcome loose = simulate(scenarioYaml("sand, relative_density: 0.0", "bekker", 0.1));
  const Outcome dense_none = simulate(scenarioYaml("sand, relative_density: 1.0", "none", 0.1));
  const Outcome dense = simulate(scenarioYaml("sand, relative_density: 1.0", "bekker", 0.1));
  EXPECT_LT(loose.mean_speed, 0.95 * loose_none.mean_speed) << loose.mean_speed << " vs " << loose_none.mean_speed;
  EXPECT_NEAR(dense.mean_speed, dense_none.mean_speed, 0.04 * dense_none.mean_speed);
  EXPECT_LT(loose.mean_speed, dense.mean_speed);
  // Every node sinks by the sinkage once, although the loose soil the blade spills slides over
  // the ruts all along: the compacted volume stays within the area the tracks covered (the
  // distance plus a track length, two tracks wide) times the sinkage. (Resetting a node's
  // press on every change of its surface gave 17 % more.)
  const double z = bekkerSinkage(terramechanics(soil::SoilFamily::Sand, 0.0), 5200 * 9.80665 / (2 * 0.45 * 1.9), 0.45);
  EXPECT_LE(loose.compacted, (loose.distance + 1.9) * 2 * 0.45 * z * 1.02);
  EXPECT_GT(loose.compacted, 0.5 * loose.distance * 2 * 0.45 * z);
  // Driving with the blade up, the slip the tracks need to overcome their rolling resistance is
  // a fraction of a per cent: the speed stays within 1 % of the model-free one.
  const Outcome free_loose = simulate(scenarioYaml("sand, relative_density: 0.0", "bekker", -0.2));
  const Outcome free_none = simulate(scenarioYaml("sand, relative_density: 0.0", "none", -0.2));
  EXPECT_NEAR(free_loose.mean_speed, free_none.mean_speed, 0.01 * free_none.mean_speed);
}

TEST(TrackSoil, AnUnknownModelIsNamed) {
  try {
    parseScenario(scenarioYaml("sand, relative_density: 0.0", "wong", 0.1), "s.yaml");
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("vehicle.track_soil"), std::string::npos) << e.what();
  }
}

TEST(TrackSoil, OnForEveryTrackedMachineUnlessSwitchedOff) {
  // The default (no vehicle key) for a CTL and an excavator; `none` in the scenario, and the
  // ablation override (terramap eval --track-soil, the sim source's track_soil) for all.
  const std::string yaml =
      "version: 1\nduration_s: 1\nterrain: {size_m: [12, 12], origin_m: [-6, -6], resolution_m: 0.02}\n"
      "machines:\n  - id: ctl1\n    controller: {type: route, start_m: [-4, -4], length_m: 2}\n"
      "  - id: ex1\n    type: excavator\n    pose: {x_m: 2, y_m: 2}\n"
      "    controller: {type: dig_dump, dig_m: [5, 2], dump_m: [2, 5]}\n"
      "  - id: ctl2\n    vehicle: {track_soil: none}\n    controller: {type: route, start_m: [-4, 4], length_m: 2}\n";
  Scenario sc = parseScenario(yaml, "s.yaml");
  ASSERT_EQ(sc.machines.size(), 3u);
  EXPECT_TRUE(sc.machines[0].track_soil);
  EXPECT_TRUE(sc.machines[1].track_soil);
  EXPECT_FALSE(sc.machines[2].track_soil);
  overrideTrackSoil(sc, "none", "--track-soil");
  for (const MachineSpec& m : sc.machines) EXPECT_FALSE(m.track_soil);
  overrideTrackSoil(sc, "bekker", "--track-soil");
  for (const MachineSpec& m : sc.machines) EXPECT_TRUE(m.track_soil);
  overrideTrackSoil(sc, "", "--track-soil");  // leaves them
  EXPECT_TRUE(sc.machines[2].track_soil);
  try {
    overrideTrackSoil(sc, "beker", "--track-soil");
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    const std::string w = e.what();
    EXPECT_NE(w.find("--track-soil"), std::string::npos) << w;
    EXPECT_NE(w.find("bekker"), std::string::npos) << w;
  }
}

TEST(TrackSoil, NodeTilesAllocateOnlyWhatIsWritten) {
  // The per-node records of the tracks and of the pressed soil live in tiles allocated on first
  // write: a lane across a large site touches a few of them, not the whole grid.
  NodeTiles<double> t(3000, 3000, -1.0);
  EXPECT_EQ(t.get(2999, 2999), -1.0);
  EXPECT_EQ(t.allocatedTiles(), 0u);
  for (int i = 100; i < 300; ++i) t.at(i, 1500) = i;
  EXPECT_EQ(t.allocatedTiles(), 4u);  // nodes 100..299 of one row: tiles 1..4 of 64
  EXPECT_EQ(t.get(200, 1500), 200.0);
  EXPECT_EQ(t.get(200, 1501), -1.0);  // same tile, not written
  NodeTiles<double> copy = t;
  copy.at(200, 1500) = 7.0;
  EXPECT_EQ(t.get(200, 1500), 200.0) << "a copy owns its tiles";
  EXPECT_EQ(copy.allocatedTiles(), 4u);
}

namespace {

MachineSpec excavatorWith(double mass_factor) {
  // The TB235-class excavator's undercarriage; heavier by mass_factor with its drive force scaled
  // alike (the drive keeps its share of the weight, so only the ruts change the balance).
  const std::string yaml =
      "version: 1\nduration_s: 1\nterrain: {size_m: [20, 6], origin_m: [-3, -3], resolution_m: 0.02}\n"
      "machines:\n  - id: ex\n    type: excavator\n"
      "    controller: {type: dig_dump, dig_m: [3, 0], dump_m: [0, 3]}\n";
  MachineSpec m = parseScenario(yaml, "s.yaml").machines.at(0);
  m.mass_kg *= mass_factor;
  m.max_drive_force_n *= mass_factor;
  return m;
}

struct FloorRow {
  SteadyTravel sand, loam;
  double slow_down;  ///< 1 - v_sand / v_loam at the same track speed; NaN: stuck in sand
};

FloorRow floorRow(const MachineSpec& m, double rut_pressure_factor) {
  FloorRow r;
  r.sand = steadyTravel(m, soil::SoilFamily::Sand, 0.0, rut_pressure_factor);
  r.loam = steadyTravel(m, soil::SoilFamily::Loam, 0.4, rut_pressure_factor);
  r.slow_down = 1 - (1 - r.sand.slip) / (1 - r.loam.slip);
  return r;
}

void printRow(const char* label, double x, const FloorRow& r) {
  std::printf("| %s %.3g | %.1f | %.2f | %.2f | %.3f | %.3f | %.3f | %.3f |\n", label, x,
              r.sand.pressure_pa / 1e3, 100 * r.sand.sinkage_m, 100 * r.loam.sinkage_m,
              r.sand.resistance_n / r.sand.traction_limit_n, 100 * r.sand.slip, 100 * r.loam.slip,
              100 * r.slow_down);
}

}  // namespace

TEST(TrackSoil, SlowDownFloorOfTheExcavatorInLooseSandAgainstLoam) {
  // TERA's Fig. 4 by terramechanics alone (steadyTravel, the state the simulator settles into):
  // the excavator's steady slow-down at full lever in loose sand (I_d 0) against loam (I_d 0.4),
  // (1) as its weight on the same tracks raises the mean ground pressure, (2) as the pressure
  // that sets the ruts rises above the mean (what pressure peaks under the rollers would do).
  // Prints the table docs/sim.md quotes.
  std::printf("| case | mean pressure kPa | rut in sand cm | rut in loam cm | sand R / limit | slip sand %% | "
              "slip loam %% | slow-down %% |\n|---|---|---|---|---|---|---|---|\n");
  const FloorRow one = floorRow(excavatorWith(1), 1);
  double last = 0;
  for (double k : {1.0, 2.0, 4.0, 8.0, 16.0}) {
    const FloorRow r = floorRow(excavatorWith(k), 1);
    printRow("mass x", k, r);
    // Compaction is the work of pressing the ruts: b k z^(n+1) / (n+1) per track, = W z / (L (n+1))
    // for both under uniform pressure.
    const Terramechanics t = terramechanics(soil::SoilFamily::Sand, 0.0);
    const double W = excavatorWith(k).mass_kg * 9.80665;
    EXPECT_NEAR(r.sand.compaction_n, W * r.sand.sinkage_m / (1.85 * (t.n + 1)), 1e-6 * r.sand.compaction_n);
    EXPECT_GT(r.slow_down, last) << "grows with the pressure";
    last = r.slow_down;
    if (k <= 8) {
      EXPECT_LT(r.slow_down, 0.01) << "below 1 % up to 8 x the weight (247 kPa, ruts 19 cm)";
    }
  }
  // The TB235-class machine itself: 30.9 kPa, ruts 2.9 cm, a slow-down of about 0.16 %.
  EXPECT_NEAR(one.sand.pressure_pa, 30.9e3, 0.1e3);
  EXPECT_GT(one.slow_down, 0.001);
  EXPECT_LT(one.slow_down, 0.003);
  const MachineSpec tb = excavatorWith(1);
  for (double f : {2.0, 4.0, 5.0, 6.0, 8.0}) printRow("rut pressure x", f, floorRow(tb, f));
  // The rut pressure (as a multiple of the mean) at which the slow-down reaches 1 % and 3 %:
  // between the 4 x and 8 x rows; at 8 x (Rowland-class mean maximum pressures) the machine
  // cannot move in sand at all.
  for (double target : {0.01, 0.03}) {
    double lo = 1, hi = 8;
    for (int it = 0; it < 60; ++it) {
      const double f = 0.5 * (lo + hi);
      const FloorRow r = floorRow(tb, f);
      (std::isnan(r.slow_down) || r.slow_down > target ? hi : lo) = f;
    }
    const FloorRow r = floorRow(tb, lo);
    std::printf("slow-down %.0f %%: rut pressure %.2f x the mean (%.0f kPa), rut in sand %.1f cm (%.3f of the track "
                "length), rut resistance %.2f W\n",
                100 * target, lo, lo * r.sand.pressure_pa / 1e3, 100 * r.sand.sinkage_m,
                r.sand.sinkage_m / tb.track_length_m,
                (r.sand.compaction_n + r.sand.bulldozing_n) / (tb.mass_kg * 9.80665));
    EXPECT_GT(lo, 3.0);
    EXPECT_LT(lo, 8.0);
  }
  EXPECT_TRUE(std::isnan(floorRow(tb, 8).sand.slip)) << "stuck";
}
