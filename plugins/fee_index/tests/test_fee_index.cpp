// fee_index: the index and its variance against finite differences of the FEE, the layers over
// a soil patch, incremental recomputation of changed tiles only, bit-identity at 1 and 2 threads.
#include <gtest/gtest.h>

#include <algorithm>

#include <cmath>
#include <cstring>
#include <limits>

#include "fee_index.hpp"

using namespace terramap;
using namespace terramap::plugins;

namespace {

const fee::Soil kClay{12e3, 0.45, 17e3, 6e3, 0.3};
const fee::Soil kClayVar{4e6, 0.004, 4e5, 1e6, 0.002};

// The index with β re-derived for the soil, as the plugin defines it, by plain evaluation.
double indexOf(const fee::Soil& s, const FeeIndexConfig& cfg) {
  const double beta = cfg.beta_min ? fee::betaMin(s, cfg.geometry) : fee::betaNominal(s);
  const fee::Result r = fee::evaluate(s, cfg.geometry, beta);
  return cfg.horizontal ? r.F_N.x() : r.F_N.norm();
}

// Σ_k (∂index/∂θ_k)² var_k by central differences.
double varianceByFiniteDifferences(const fee::Soil& s, const fee::Soil& var, const FeeIndexConfig& cfg) {
  const double v[5] = {var.c_pa, var.phi_rad, var.gamma_n_m3, var.ca_pa, var.delta_rad};
  const double base[5] = {s.c_pa, s.phi_rad, s.gamma_n_m3, s.ca_pa, s.delta_rad};
  double out = 0.0;
  for (int k = 0; k < 5; ++k) {
    const double h = 1e-6 * std::max(1.0, std::abs(base[k]));
    double p[5], m[5];
    for (int q = 0; q < 5; ++q) p[q] = m[q] = base[q];
    p[k] += h;
    m[k] -= h;
    const double g = (indexOf({p[0], p[1], p[2], p[3], p[4]}, cfg) - indexOf({m[0], m[1], m[2], m[3], m[4]}, cfg)) / (2 * h);
    out += g * g * v[k];
  }
  return out;
}

TEST(FeeIndexValue, VarianceMatchesFiniteDifferencesOfTheFee) {
  for (bool beta_min : {true, false})
    for (bool horizontal : {false, true}) {
      FeeIndexConfig cfg;
      cfg.beta_min = beta_min;
      cfg.horizontal = horizontal;
      const FeeIndexValue f = feeIndexOf(kClay, kClayVar, cfg);
      ASSERT_EQ(f.validity, fee::Validity::Valid);
      EXPECT_DOUBLE_EQ(f.index_n, indexOf(kClay, cfg));
      const double fd = varianceByFiniteDifferences(kClay, kClayVar, cfg);
      EXPECT_NEAR(f.var_n2, fd, 1e-5 * fd) << "beta_min " << beta_min << " horizontal " << horizontal;
      EXPECT_GT(f.index_n, 1e3);  // kN-scale for a 0.2 m cut 1.85 m wide
    }
}

TEST(FeeIndexValue, ADenserSoilNeedsMoreForce) {
  const FeeIndexConfig cfg;
  fee::Soil dense = kClay;
  dense.c_pa *= 3;
  dense.phi_rad += 0.1;
  EXPECT_GT(feeIndexOf(dense, kClayVar, cfg).index_n, 1.5 * feeIndexOf(kClay, kClayVar, cfg).index_n);
  // No soil, no index.
  fee::Soil nan = kClay;
  nan.phi_rad = std::numeric_limits<double>::quiet_NaN();
  EXPECT_TRUE(std::isnan(feeIndexOf(nan, kClayVar, cfg).index_n));
}

// A sparse-free map with soil_bayes's layers: a patch of soil and NaN elsewhere.
struct Harness {
  LayeredMap map;
  Executor ex;
  RecordBus bus;
  PluginStats stats;
  ChangeTracker tracker;
  ProcessContext ctx;
  FeeIndex plugin;
  explicit Harness(int threads) : map(Geometry(0.05, Size(150, 130)), MapOptions{32}), ex(threads), ctx(map, ex, bus, stats, "idx") {
    ctx.setTracker(&tracker);
    plugin.configure(makeParams("idx", plugin.schema()));
    for (const char* l : {"soil_c", "soil_phi", "soil_gamma", "soil_ca", "soil_delta"}) {
      map.addLayer(l, "");
      map.addLayer(std::string(l) + "_var", "");
    }
    for (const LayerSpec& l : plugin.layers())
      if (l.access == LayerAccess::Create) map.addLayer(l.name, l.unit, l.fill);
    plugin.start(ctx);
  }
  void setSoil(const Index& i, const fee::Soil& s, const fee::Soil& v) {
    const double m[5] = {s.c_pa, s.phi_rad, s.gamma_n_m3, s.ca_pa, s.delta_rad};
    const double vv[5] = {v.c_pa, v.phi_rad, v.gamma_n_m3, v.ca_pa, v.delta_rad};
    const char* names[5] = {"soil_c", "soil_phi", "soil_gamma", "soil_ca", "soil_delta"};
    for (int k = 0; k < 5; ++k) {
      map.set(map.layerId(names[k]), i, static_cast<float>(m[k]));
      map.set(map.layerId(std::string(names[k]) + "_var"), i, static_cast<float>(vv[k]));
    }
  }
  void run() {
    plugin.process(ctx, Tick{});
    tracker.mark(map);
  }
  float index(const Index& i) const { return map.at(map.layerId("fee_index"), i); }
};

fee::Soil soilAt(int i, int j) {
  fee::Soil s = kClay;
  s.c_pa += 100.0 * i;
  s.phi_rad += 0.001 * j;
  return s;
}

TEST(FeeIndex, LayersHoldTheIndexOfEachCellsSoilAndNaNElsewhere) {
  Harness h(2);
  for (int i = 20; i < 80; ++i)
    for (int j = 10; j < 50; ++j) h.setSoil(Index(i, j), soilAt(i, j), kClayVar);
  h.run();
  const FeeIndexConfig cfg;
  for (const Index& i : {Index(20, 10), Index(79, 49), Index(50, 33)}) {
    // The layers hold float32: the index of the soil as stored.
    fee::Soil s = soilAt(i.x(), i.y()), v = kClayVar;
    s = {static_cast<float>(s.c_pa), static_cast<float>(s.phi_rad), static_cast<float>(s.gamma_n_m3),
         static_cast<float>(s.ca_pa), static_cast<float>(s.delta_rad)};
    v = {static_cast<float>(v.c_pa), static_cast<float>(v.phi_rad), static_cast<float>(v.gamma_n_m3),
         static_cast<float>(v.ca_pa), static_cast<float>(v.delta_rad)};
    const FeeIndexValue f = feeIndexOf(s, v, cfg);
    EXPECT_FLOAT_EQ(h.index(i), static_cast<float>(f.index_n));
    EXPECT_FLOAT_EQ(h.map.at(h.map.layerId("fee_index_var"), i), static_cast<float>(f.var_n2));
  }
  EXPECT_TRUE(std::isnan(h.index(Index(19, 10))));
  EXPECT_TRUE(std::isnan(h.index(Index(100, 100))));
  EXPECT_LT(h.index(Index(20, 10)), h.index(Index(79, 10)));  // cohesion grows with i
}

TEST(FeeIndex, OnlyTilesWhoseSoilChangedAreRecomputed) {
  Harness h(1);
  for (int i = 0; i < 150; ++i)
    for (int j = 0; j < 130; ++j) h.setSoil(Index(i, j), kClay, kClayVar);
  h.run();
  const double first = h.stats.counters["tiles_computed"];
  EXPECT_EQ(first, h.map.tileCount());
  h.run();  // nothing changed
  EXPECT_EQ(h.stats.counters["tiles_computed"], first);
  fee::Soil denser = kClay;
  denser.c_pa = 30e3;
  h.setSoil(Index(70, 70), denser, kClayVar);
  const float before_next = h.index(Index(70, 71));
  h.run();
  EXPECT_EQ(h.stats.counters["tiles_computed"], first + 1);
  EXPECT_GT(h.index(Index(70, 70)), h.index(Index(70, 71)));
  EXPECT_EQ(h.index(Index(70, 71)), before_next);
}

TEST(FeeIndex, BitIdenticalAtOneAndTwoThreads) {
  auto run = [](int threads) {
    Harness h(threads);
    for (int i = 0; i < 150; i += 1)
      for (int j = (i % 3); j < 130; j += 2) h.setSoil(Index(i, j), soilAt(i % 60, j % 50), kClayVar);
    h.run();
    std::vector<float> out(150 * 130 * 2);
    h.map.readLayer(h.map.layerId("fee_index"), out.data(), 150, 130);
    h.map.readLayer(h.map.layerId("fee_index_var"), out.data() + 150 * 130, 150, 130);
    return out;
  };
  const auto a = run(1), b = run(2);
  EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(float)), 0);
}

}  // namespace

TEST(FeeIndex, AnotherSoilPrefixFeedsAnotherOutput) {
  // Two soils on one map (the surface's and the strata's next cut): each instance reads its own
  // layers and writes its own index.
  LayeredMap map(Geometry(0.05, Size(40, 40)), MapOptions{32});
  Executor ex(1);
  RecordBus bus;
  PluginStats stats;
  ChangeTracker tracker;
  ProcessContext ctx(map, ex, bus, stats, "next");
  ctx.setTracker(&tracker);
  FeeIndex plugin;
  plugin.configure(makeParams("next", plugin.schema(),
                              {{"soil_prefix", ParamValue{std::string("strata_next_")}}, {"output", ParamValue{std::string("fee_next")}}}));
  std::vector<std::string> read, created;
  for (const LayerSpec& l : plugin.layers()) (l.access == LayerAccess::Create ? created : read).push_back(l.name);
  EXPECT_EQ(created, (std::vector<std::string>{"fee_next", "fee_next_var"}));
  EXPECT_NE(std::find(read.begin(), read.end(), "strata_next_phi_var"), read.end());
  EXPECT_EQ(std::find(read.begin(), read.end(), "soil_c"), read.end());
  const char* names[5] = {"strata_next_c", "strata_next_phi", "strata_next_gamma", "strata_next_ca", "strata_next_delta"};
  const double m[5] = {kClay.c_pa, kClay.phi_rad, kClay.gamma_n_m3, kClay.ca_pa, kClay.delta_rad};
  for (int k = 0; k < 5; ++k) {
    map.addLayer(names[k], "");
    map.addLayer(std::string(names[k]) + "_var", "");
  }
  for (const std::string& l : created) map.addLayer(l, "");
  plugin.start(ctx);
  for (int k = 0; k < 5; ++k) {
    map.set(map.layerId(names[k]), Index(5, 5), static_cast<float>(m[k]));
    map.set(map.layerId(std::string(names[k]) + "_var"), Index(5, 5), 1.0f);
  }
  plugin.process(ctx, Tick{});
  const fee::Soil s{static_cast<float>(kClay.c_pa), static_cast<float>(kClay.phi_rad), static_cast<float>(kClay.gamma_n_m3),
                    static_cast<float>(kClay.ca_pa), static_cast<float>(kClay.delta_rad)};
  EXPECT_FLOAT_EQ(map.at(map.layerId("fee_next"), Index(5, 5)),
                  static_cast<float>(feeIndexOf(s, fee::Soil{1, 1, 1, 1, 1}, FeeIndexConfig{}).index_n));
}
