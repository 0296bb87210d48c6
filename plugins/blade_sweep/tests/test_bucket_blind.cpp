// Bucket blind mapping (README "Buckets"): the tool mesh's swept volume cuts and the soil is
// carried, not deposited beside the cut; a pour puts it where the bucket empties, as a pile at
// its repose; the map's soil plus what the buckets carry is conserved. Against the simulator's
// truth on a dig-and-dump cycle: the trench's heights and the volumes moved.
#include <gtest/gtest.h>

#include <terramap/sim/simulator.hpp>

#include <cmath>
#include <cstdio>
#include <map>
#include <memory>

#include "blade_sweep.hpp"

using namespace terramap;
using namespace terramap::plugins;

namespace {

/// Σ[(H − L) + L/s] res² over known cells plus L/s res² over unknown ones: the map's soil.
double mapSoil(const LayeredMap& map, double swell) {
  const Eigen::MatrixXf H = map.toMatrix(map.layerId("elevation")), L = map.toMatrix(map.layerId("loose"));
  const double cell = map.geometry().resolution() * map.geometry().resolution();
  double v = 0;
  for (int i = 0; i < H.rows(); ++i)
    for (int j = 0; j < H.cols(); ++j) {
      const double l = std::isfinite(L(i, j)) ? L(i, j) : 0.0;
      v += ((std::isfinite(H(i, j)) ? H(i, j) - l : 0.0) + l / swell) * cell;
    }
  return v;
}

}  // namespace

TEST(BucketSweep, CutSoilIsCarriedAndPouredAsAPileWithTheMassKept) {
  LayeredMap map(Geometry(0.05, Size(120, 120), Position(0.0, 0.0)));
  const LayerId h = map.addLayer("elevation", "m");
  map.addLayer("loose", "m", 0.0f);
  map.addLayer("height_sigma", "m");
  map.fromMatrix(h, Eigen::MatrixXf::Zero(120, 120));
  const SweepLayers ids = SweepLayers::of(map);
  SweepConfig cfg;
  const BucketConfig bucket;
  const ToolMesh tool = bucket.mesh();
  Executor ex(2);
  const double soil0 = mapSoil(map, cfg.swell);
  // The bucket, lip down and opening toward -x, dragged 1 m toward -x with its lip 0.2 m deep.
  std::vector<Eigen::Isometry3d> poses;
  for (int k = 0; k <= 20; ++k) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::AngleAxisd(80 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();  // x down
    T.translation() = Eigen::Vector3d(1.0 - 0.05 * k, 0.0, -0.2) - T.linear() * tool.lip + T.translation();
    poses.push_back(T);
  }
  const BucketResult cut = runBucketSweep(map, ids, cfg, tool, poses, 1e9, ex);
  ASSERT_GT(cut.cells_cut, 100);
  EXPECT_NEAR(mapSoil(map, cfg.swell) + cut.cut_bank_m3, soil0, 1e-5) << "what left the map is in the bucket";
  // Nothing was deposited beside the trench: every changed cell went down.
  const Eigen::MatrixXf after_cut = map.toMatrix(h);
  EXPECT_LE(after_cut.maxCoeff(), 0.0f);
  EXPECT_NEAR(after_cut.minCoeff(), -0.2, 0.03) << "the trench floor is the lip's path";

  const Eigen::Vector3d at(-1.5, 1.5, 0.0);
  const BucketResult pour = pourBucket(map, ids, cfg, bucket, at, cut.cut_bank_m3, 8);
  EXPECT_GT(settlePile(map, ids, bucket, at, 100000), 10);
  EXPECT_NEAR(pour.deposit_bank_m3, cut.cut_bank_m3, 1e-12);
  EXPECT_NEAR(mapSoil(map, cfg.swell), soil0, 1e-5);
  // The pile: centred on the pour point, no steeper than its repose anywhere (one cell of slack
  // for the last sweep's remainder).
  const Eigen::MatrixXf H = map.toMatrix(h);
  const auto c = map.geometry().indexAt(at.head<2>());
  ASSERT_TRUE(c);
  EXPECT_GT(H((*c).x(), (*c).y()), 0.1);
  double steepest = 0;
  for (int i = 0; i + 1 < 120; ++i)
    for (int j = 0; j + 1 < 120; ++j)
      if (H(i, j) > 0 || H(i + 1, j) > 0)
        steepest = std::max({steepest, std::abs(double(H(i, j) - H(i + 1, j))), std::abs(double(H(i, j) - H(i, j + 1)))});
  EXPECT_LT(steepest / 0.05, std::tan(bucket.pile_repose_rad) + 0.01);
  EXPECT_GT(steepest / 0.05, std::tan(bucket.pile_repose_rad) - 0.05) << "a pile, not a flat layer";
}

TEST(BucketSweep, ARoomLimitCutsExactlyTheRoom) {
  // The same drag with room for a tenth of what it would cut: it cuts exactly that (the station
  // that fills the bucket cuts its cells by one fraction, later stations nothing) and the soil
  // is conserved; with room to spare it cuts more.
  auto drag = [](double room, double& cut, double& balance) {
    LayeredMap map(Geometry(0.05, Size(120, 120), Position(0.0, 0.0)));
    const LayerId h = map.addLayer("elevation", "m");
    map.addLayer("loose", "m", 0.0f);
    map.addLayer("height_sigma", "m");
    map.fromMatrix(h, Eigen::MatrixXf::Zero(120, 120));
    const SweepConfig cfg;
    const ToolMesh tool = BucketConfig{}.mesh();
    Executor ex(2);
    const double soil0 = mapSoil(map, cfg.swell);
    std::vector<Eigen::Isometry3d> poses;
    for (int k = 0; k <= 20; ++k) {
      Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
      T.linear() = Eigen::AngleAxisd(80 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();
      T.translation() = Eigen::Vector3d(1.0 - 0.05 * k, 0.0, -0.2) - T.linear() * tool.lip;
      poses.push_back(T);
    }
    cut = runBucketSweep(map, SweepLayers::of(map), cfg, tool, poses, room, ex).cut_bank_m3;
    balance = mapSoil(map, cfg.swell) + cut - soil0;
  };
  double free_cut = 0, free_balance = 0, cut = 0, balance = 0;
  drag(1e9, free_cut, free_balance);
  ASSERT_GT(free_cut, 0.05);
  drag(0.1 * free_cut, cut, balance);
  EXPECT_NEAR(cut, 0.1 * free_cut, 1e-12);
  EXPECT_NEAR(balance, 0.0, 1e-5);
  EXPECT_NEAR(free_balance, 0.0, 1e-5);
}

namespace {

/// One simulated dig-and-dump run: the events the mapper receives and the truth at the end.
struct DigRun {
  std::vector<Event> events;
  std::unique_ptr<sim::Simulator> sim;  ///< after the run: truth() and machineTruth(0)
};

const DigRun& digRun() {
  // configs/scenarios/excavator_dig_dump.yaml's excavator alone, with its realistic
  // localisation (rtk_imu) and encoders, 32 s: two dig-and-dump cycles.
  static const DigRun run = [] {
    DigRun r;
    r.sim = std::make_unique<sim::Simulator>(sim::parseScenario(
        "version: 1\nseed: 5\nduration_s: 32\nthreads: 1\n"
        "terrain: {size_m: [12, 12], origin_m: [-6, -6], resolution_m: 0.02}\n"
        "soil: {default: {family: loam, relative_density: 0.4}}\n"
        "machines:\n  - id: ex1\n    type: excavator\n"
        "    controller: {type: dig_dump, dig_m: [3.4, 0], dump_m: [0.3, 3.2], depth_m: 0.25, drag_m: 1.0}\n",
        "dig.yaml"));
    std::vector<Event> ev;
    while (r.sim->next(ev)) {
      for (Event& e : ev) r.events.push_back(std::move(e));
      ev.clear();
    }
    return r;
  }();
  return run;
}

/// What blade_sweep (with `overrides`) makes of the run, against the truth.
struct BlindFigures {
  double rmse = 0, rmse_static = 0, rmse_pile = 0, rmse_pile_static = 0;
  long cells = 0, pile_cells = 0;
  double cut = 0, poured = 0, carried = 0, balance = 0;  ///< bank m^3; balance: soil0 - (map + carried)
  /// Inside the dig: cells more than 10 cm off, and the worst one (where; map and truth minus
  /// the initial surface), what the README's account of the RMSE quotes.
  long cells_off_10cm = 0;
  Eigen::Vector2d worst_at = Eigen::Vector2d::Zero();
  double worst_map_dz = 0, worst_truth_dz = 0;
};

BlindFigures mapDigRun(const std::map<std::string, ParamValue>& overrides) {
  const DigRun& run = digRun();
  const sim::TruthTerrain& truth = run.sim->truth();
  // The map starts from the true initial surface; only the bucket's JointStates (and the plow's
  // BladePoses, which never touch the ground) update it.
  LayeredMap map(Geometry(0.05, Size(160, 160), Position(1.5, 1.5)));
  const LayerId h = map.addLayer("elevation", "m");
  map.addLayer("loose", "m", 0.0f);
  map.addLayer("height_sigma", "m");
  const Geometry& geo = map.geometry();
  Eigen::MatrixXf h0(geo.size().x(), geo.size().y());
  for (int i = 0; i < geo.size().x(); ++i)
    for (int j = 0; j < geo.size().y(); ++j) {
      const Position p = geo.positionOf(Index(i, j));
      h0(i, j) = static_cast<float>(truth.initialHeightAt(p.x(), p.y()));
    }
  map.fromMatrix(h, h0);
  Executor ex(2);
  RecordBus bus;
  PluginStats stats;
  ProcessContext ctx(map, ex, bus, stats, "blade");
  BladeSweep plugin;
  plugin.configure(makeParams("blade", plugin.schema(), overrides));
  plugin.start(ctx);
  const double swell = plugin.config().swell;
  const double soil0 = mapSoil(map, swell);
  for (const Event& e : run.events)
    if (plugin.events() & mask(kindOf(e))) plugin.process(ctx, e);
  plugin.finish(ctx);
  BlindFigures f;
  f.cut = stats.counters["bucket_cut_bank_m3"];
  f.poured = stats.counters["bucket_poured_bank_m3"];
  f.carried = stats.counters["bucket_carried_bank_m3"];
  f.balance = soil0 - (mapSoil(map, swell) + f.carried);
  // Heights inside the dig (the cells the truth lowered by more than 3 cm, away from the pile)
  // and on the pile (where the truth or the map rose by more than 1 cm within 1.5 m of the dump
  // point).
  const Eigen::MatrixXf h1 = map.toMatrix(h);
  double se = 0, se_static = 0, se_pile = 0, se_pile_static = 0;
  for (int i = 0; i < geo.size().x(); ++i)
    for (int j = 0; j < geo.size().y(); ++j) {
      const Position p = geo.positionOf(Index(i, j));
      const double t = truth.heightAt(p.x(), p.y()), e = h1(i, j) - t, e0 = h0(i, j) - t;
      const bool near_pile = (p - Eigen::Vector2d(0.3, 3.2)).norm() <= 1.5;
      if (!near_pile && t < h0(i, j) - 0.03) {
        se += e * e;
        se_static += e0 * e0;
        ++f.cells;
        f.cells_off_10cm += std::abs(e) > 0.1;
        if (std::abs(e) > std::abs(f.worst_map_dz - f.worst_truth_dz)) {
          f.worst_at = p;
          f.worst_map_dz = h1(i, j) - h0(i, j);
          f.worst_truth_dz = t - h0(i, j);
        }
      } else if (near_pile && (t > h0(i, j) + 0.01 || h1(i, j) > h0(i, j) + 0.01)) {
        se_pile += e * e;
        se_pile_static += e0 * e0;
        ++f.pile_cells;
      }
    }
  f.rmse = std::sqrt(se / std::max(1L, f.cells));
  f.rmse_static = std::sqrt(se_static / std::max(1L, f.cells));
  f.rmse_pile = std::sqrt(se_pile / std::max(1L, f.pile_cells));
  f.rmse_pile_static = std::sqrt(se_pile_static / std::max(1L, f.pile_cells));
  return f;
}

}  // namespace

TEST(BucketBlind, ADigAndDumpCycleAgainstTheSimulatorsTruth) {
  const sim::MachineTruth& tr = digRun().sim->machineTruth(0);
  ASSERT_GE(tr.arm_cycle, 2) << "two dig-and-dump cycles, the second deepening the trench";
  const BlindFigures f = mapDigRun({});
  // The map's own balance: what it lost is what its buckets still carry.
  EXPECT_NEAR(f.balance, 0.0, 1e-4);
  EXPECT_NEAR(f.cut - f.poured, f.carried, 1e-9);
  ASSERT_GT(f.cells, 100);
  ASSERT_GT(f.pile_cells, 50);
  std::printf("[ bucket-blind ] dig: %ld cells, rmse %.4f m (un-updated %.4f m) | pile: %ld cells, rmse %.4f m "
              "(un-updated %.4f m) | bank dug map %.4f truth %.4f m3, poured map %.4f truth %.4f m3, carried map %.4f "
              "truth %.4f m3\n",
              f.cells, f.rmse, f.rmse_static, f.pile_cells, f.rmse_pile, f.rmse_pile_static, f.cut,
              tr.bucket_dug_bank_m3, f.poured, tr.bucket_dumped_bank_m3, f.carried, tr.bucket_bank_m3);
  std::printf("[ bucket-blind ] dig cells more than 10 cm off: %ld; worst at (%.2f, %.2f): map %+.3f m, truth %+.3f m "
              "from the initial surface\n",
              f.cells_off_10cm, f.worst_at.x(), f.worst_at.y(), f.worst_map_dz, f.worst_truth_dz);
  // The goal is 3 cm (0.98 cm measured); the bound sits at the goal, not the measurement, so the
  // simulator's bucket geometry (README "Buckets") can change without this test pinning it.
  EXPECT_LT(f.rmse, 0.03) << "RMSE inside the dig (goal 3 cm)";
  EXPECT_LT(f.rmse_pile, 0.5 * f.rmse_pile_static) << "the pile is where the truth's is";
  // Mass balance within 1 % (the map moved what the truth's bucket moved).
  EXPECT_NEAR(f.cut, tr.bucket_dug_bank_m3, 0.01 * tr.bucket_dug_bank_m3);
  EXPECT_NEAR(f.poured, tr.bucket_dumped_bank_m3, 0.01 * tr.bucket_dumped_bank_m3);

  // Each part switched off: raw bucket poses (the union of noisy stations widens and deepens the
  // trench) and a bucket without a capacity (it cuts what its mesh sweeps through: here about
  // what the truth took, as the controller curls once the bucket is full; the cap itself is
  // tested in BucketSweep.ARoomLimitCutsExactlyTheRoom).
  const BlindFigures raw = mapDigRun({{"bucket_pose_window", 1L}});
  const BlindFigures bottomless = mapDigRun({{"bucket_capacity_m3", 100.0}});
  std::printf("[ bucket-blind ] switched off: raw poses rmse %.4f m | no capacity: bank dug %.4f m3\n", raw.rmse,
              bottomless.cut);
  EXPECT_GT(raw.rmse, 1.3 * f.rmse);
  EXPECT_GE(bottomless.cut, f.cut);
}
