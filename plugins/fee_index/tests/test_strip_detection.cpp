// soil_bayes then fee_index on a stream of estimates from a machine driving along +x: a strip of
// dense soil only one wedge long, seen by a single estimate among noisy ones of loose soil, must
// stand out in the index (a strip the size of one wedge is still detected). What it
// checks end to end without the estimator: the wedge lands ahead of the blade where the soil
// was estimated, and a denser estimate gives a larger index there.
#include <gtest/gtest.h>

#include <terramap/eval/statistics.hpp>
#include <terramap/soil/soil_table.hpp>

#include <cmath>

#include "fee_index.hpp"
#include "soil_bayes.hpp"

using namespace terramap;
using namespace terramap::plugins;

namespace {

SoilEstimateRecord::SoilVector soilVector(const fee::Soil& s) {
  return {s.c_pa, s.phi_rad, s.ca_pa, s.delta_rad, s.gamma_n_m3};
}

TEST(StripDetection, AStripOneWedgeLongStandsOutInTheIndex) {
  LayeredMap map(Geometry(0.02, Size(200, 100), Position(1.5, 0.0)), MapOptions{32});
  Executor ex(2);
  RecordBus bus;
  PluginStats st_bayes, st_index;
  ChangeTracker tracker;
  ProcessContext bayes_ctx(map, ex, bus, st_bayes, "bayes"), index_ctx(map, ex, bus, st_index, "index");
  index_ctx.setTracker(&tracker);
  SoilBayes bayes;
  FeeIndex index;
  bayes.configure(makeParams("bayes", bayes.schema()));
  index.configure(makeParams("index", index.schema()));
  for (const LayerSpec& l : bayes.layers())
    if (l.access == LayerAccess::Create) map.addLayer(l.name, l.unit, l.fill);
  for (const LayerSpec& l : index.layers())
    if (l.access == LayerAccess::Create) map.addLayer(l.name, l.unit, l.fill);
  const LayerId h = map.addLayer("elevation", "m");
  map.fill(h, 0.0f);
  bayes.start(bayes_ctx);
  index.start(index_ctx);

  const fee::Soil loose = soil::soilProperties(soil::SoilFamily::Clay, 0.1).fee;
  const fee::Soil dense = soil::soilProperties(soil::SoilFamily::Clay, 0.8).fee;
  // Sweeps every 0.1 m, each wedge 0.1 m long (d = 0.1 m, alpha = 0, beta = 45 deg), 1.85 m wide.
  // The loose estimates scatter by +-15 % (a fixed pseudo-random sequence), with a 15 % sigma.
  const int n = 25, dense_k = 12;  // the dense strip: x in [1.2, 1.3)
  for (int k = 0; k < n; ++k) {
    SoilEstimateRecord e;
    e.T_map_blade1.translation() = Eigen::Vector3d(0.1 * k, 0.0, 0.0);
    e.t_hat = Eigen::Vector2d::UnitX();
    e.alpha_rad = 0.0;
    e.beta_rad = 0.25 * 3.14159265358979323846;
    e.d_m = 0.1;
    e.d_res_m = 0.0;
    e.w_m = 1.85;
    const double wobble = 0.15 * std::sin(2.3 * k + 0.7);
    const SoilEstimateRecord::SoilVector m = soilVector(k == dense_k ? dense : loose);
    for (std::size_t q = 0; q < m.size(); ++q) {
      e.mean[q] = m[q] * (1.0 + (k == dense_k ? 0.0 : wobble));
      e.var_total[q] = (0.15 * m[q]) * (0.15 * m[q]);
    }
    e.valid = true;
    bus.publish<SoilEstimateRecord>(SoilEstimateRecord::kType, 0.1 * k, std::make_shared<const SoilEstimateRecord>(e));
    bayes.process(bayes_ctx, Tick{});
    index.process(index_ctx, Tick{});
    tracker.mark(map);
  }
  // Cells with an index: inside the strip (positives) and outside it (negatives).
  std::vector<double> in, out;
  const LayerId idx = map.layerId("fee_index");
  for (int i = 0; i < 200; ++i)
    for (int j = 0; j < 100; ++j) {
      const float v = map.at(idx, Index(i, j));
      if (!std::isfinite(v)) continue;
      const double x = map.geometry().positionOf(Index(i, j)).x();
      (x >= 1.2 && x < 1.3 ? in : out).push_back(v);
    }
  ASSERT_GT(in.size(), 100u);
  ASSERT_GT(out.size(), 1000u);
  EXPECT_GE(eval::rocAuc(in, out), 0.95);
  EXPECT_DOUBLE_EQ(st_bayes.counters["estimates_fused"], n);
}

}  // namespace
