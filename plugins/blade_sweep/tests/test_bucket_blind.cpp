// Bucket blind mapping (README "Buckets"): the tool mesh's swept volume cuts and the soil is
// carried, not deposited beside the cut; a pour puts it where the bucket empties, as a pile at
// its repose; the map's soil plus what the buckets carry is conserved. Against the simulator's
// truth on a dig-and-dump cycle: the trench's heights and the volumes moved.
#include <gtest/gtest.h>

#include <terramap/sim/simulator.hpp>

#include <cmath>
#include <cstdio>
#include <cstdlib>

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

TEST(BucketBlind, ADigAndDumpCycleAgainstTheSimulatorsTruth) {
  // configs/scenarios/excavator_dig_dump.yaml's excavator alone, with its realistic localisation
  // (rtk_imu) and encoders: the map starts from the true initial surface and only the bucket's
  // JointStates (and the plow's BladePoses, which never touch the ground) update it.
  const std::string yaml =
      "version: 1\nseed: 5\nduration_s: 32\nthreads: 1\n"
      "terrain: {size_m: [12, 12], origin_m: [-6, -6], resolution_m: 0.02}\n"
      "soil: {default: {family: loam, relative_density: 0.4}}\n"
      "machines:\n  - id: ex1\n    type: excavator\n"
      "    controller: {type: dig_dump, dig_m: [3.4, 0], dump_m: [0.3, 3.2], depth_m: 0.25, drag_m: 1.0}\n";
  sim::Simulator sim(sim::parseScenario(yaml, "dig.yaml"));
  LayeredMap map(Geometry(0.05, Size(160, 160), Position(1.5, 1.5)));
  const LayerId h = map.addLayer("elevation", "m");
  map.addLayer("loose", "m", 0.0f);
  map.addLayer("height_sigma", "m");
  const Geometry& geo = map.geometry();
  Eigen::MatrixXf h0(geo.size().x(), geo.size().y());
  for (int i = 0; i < geo.size().x(); ++i)
    for (int j = 0; j < geo.size().y(); ++j) {
      const Position p = geo.positionOf(Index(i, j));
      h0(i, j) = static_cast<float>(sim.truth().initialHeightAt(p.x(), p.y()));
    }
  map.fromMatrix(h, h0);
  Executor ex(2);
  RecordBus bus;
  PluginStats stats;
  ProcessContext ctx(map, ex, bus, stats, "blade");
  BladeSweep plugin;
  plugin.configure(makeParams("blade", plugin.schema()));
  plugin.start(ctx);
  const double swell = 1.2;  // the plugin's default
  const double soil0 = mapSoil(map, swell);
  std::vector<Event> events;
  while (sim.next(events)) {
    for (const Event& e : events)
      if (plugin.events() & mask(kindOf(e))) plugin.process(ctx, e);
    events.clear();
  }
  plugin.finish(ctx);
  const sim::MachineTruth& tr = sim.machineTruth(0);
  ASSERT_GE(tr.arm_cycle, 2) << "two dig-and-dump cycles, the second deepening the trench";
  const double cut = stats.counters["bucket_cut_bank_m3"], poured = stats.counters["bucket_poured_bank_m3"];
  const double carried = stats.counters["bucket_carried_bank_m3"];
  // The map's own balance: what it lost is what its buckets still carry.
  EXPECT_NEAR(mapSoil(map, swell) + carried, soil0, 1e-4);
  EXPECT_NEAR(cut - poured, carried, 1e-9);
  // Heights inside the dig: the cells the truth lowered by more than 3 cm, away from the pile.
  const Eigen::MatrixXf h1 = map.toMatrix(h);
  double se = 0, se_static = 0;
  long n = 0;
  for (int i = 0; i < geo.size().x(); ++i)
    for (int j = 0; j < geo.size().y(); ++j) {
      const Position p = geo.positionOf(Index(i, j));
      const double truth = sim.truth().heightAt(p.x(), p.y());
      if (!(truth < h0(i, j) - 0.03) || (p - Eigen::Vector2d(0.3, 3.2)).norm() < 1.5) continue;
      se += (h1(i, j) - truth) * (h1(i, j) - truth);
      if (std::getenv("BUCKET_BLIND_DUMP") && std::abs(h1(i, j) - truth) > 0.05)
        std::printf("cell %.2f %.2f map %.3f truth %.3f init %.3f\n", p.x(), p.y(), h1(i, j), truth, h0(i, j));
      se_static += (h0(i, j) - truth) * (h0(i, j) - truth);
      ++n;
    }
  ASSERT_GT(n, 100);
  const double rmse = std::sqrt(se / n), rmse_static = std::sqrt(se_static / n);
  // The pile, where the truth or the map rose by more than 1 cm within 1.5 m of the dump point.
  double se_pile = 0, se_pile_static = 0;
  long n_pile = 0;
  for (int i = 0; i < geo.size().x(); ++i)
    for (int j = 0; j < geo.size().y(); ++j) {
      const Position p = geo.positionOf(Index(i, j));
      const double truth = sim.truth().heightAt(p.x(), p.y());
      if ((p - Eigen::Vector2d(0.3, 3.2)).norm() > 1.5 || !(truth > h0(i, j) + 0.01 || h1(i, j) > h0(i, j) + 0.01)) continue;
      se_pile += (h1(i, j) - truth) * (h1(i, j) - truth);
      se_pile_static += (h0(i, j) - truth) * (h0(i, j) - truth);
      ++n_pile;
    }
  ASSERT_GT(n_pile, 50);
  const double rmse_pile = std::sqrt(se_pile / n_pile), rmse_pile_static = std::sqrt(se_pile_static / n_pile);
  if (std::getenv("BUCKET_BLIND_DUMP")) {
    // Volume change per 10 cm band of x over |y| < 1.5 m: map and truth.
    for (double x0 = 2.0; x0 < 4.2; x0 += 0.1) {
      double vm = 0, vt = 0;
      for (int i = 0; i < geo.size().x(); ++i)
        for (int j = 0; j < geo.size().y(); ++j) {
          const Position p = geo.positionOf(Index(i, j));
          if (p.x() < x0 || p.x() >= x0 + 0.1 || std::abs(p.y()) > 1.5) continue;
          vm += (h1(i, j) - h0(i, j)) * 0.0025;
          vt += (sim.truth().heightAt(p.x(), p.y()) - h0(i, j)) * 0.0025;
        }
      std::printf("band %.1f map %.4f truth %.4f\n", x0, vm, vt);
    }
  }
  if (std::getenv("BUCKET_BLIND_DUMP"))
    for (double x = 1.5; x < 4.6; x += 0.1) {
      const auto idx = geo.indexAt(Position(x, 0.01));
      std::printf("x %.2f map %.3f truth %.3f init %.3f\n", x, map.at(h, *idx), sim.truth().heightAt(x, 0.01),
                  sim.truth().initialHeightAt(x, 0.01));
    }
  std::printf("[ bucket-blind ] dig: %ld cells, rmse %.4f m (un-updated %.4f m) | pile: %ld cells, rmse %.4f m "
              "(un-updated %.4f m) | bank dug map %.4f truth %.4f m3, poured map %.4f truth %.4f m3, carried map %.4f "
              "truth %.4f m3\n",
              n, rmse, rmse_static, n_pile, rmse_pile, rmse_pile_static, cut, tr.bucket_dug_bank_m3, poured,
              tr.bucket_dumped_bank_m3, carried, tr.bucket_bank_m3);
  EXPECT_LT(rmse, 0.03) << "#19: RMSE inside the dig <= 3 cm";
  EXPECT_LT(rmse_pile, 0.5 * rmse_pile_static) << "the pile is where the truth's is";
  // #19: mass balance within 1 % (the map moved what the truth's bucket moved).
  EXPECT_NEAR(cut, tr.bucket_dug_bank_m3, 0.01 * tr.bucket_dug_bank_m3);
  EXPECT_NEAR(poured, tr.bucket_dumped_bank_m3, 0.01 * tr.bucket_dumped_bank_m3);
}
