// soil_bayes: the update against hand-computed values, the wedge's extent and inflation, each
// estimate fused once per cell, every estimate of an event fused, what a cut does, bit-identity
// at 1 and 2 threads.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>

#include "soil_bayes.hpp"

using namespace terramap;
using namespace terramap::plugins;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// A map with the layers soil_bayes creates (as the host would) and a flat `elevation`.
struct Harness {
  LayeredMap map;
  Executor ex;
  RecordBus bus;
  PluginStats stats;
  ProcessContext ctx;
  SoilBayes plugin;
  explicit Harness(int threads = 1, std::map<std::string, ParamValue> params = {}, double res = 0.02)
      : map(Geometry(res, Size(200, 200))), ex(threads), ctx(map, ex, bus, stats, "bayes") {
    plugin.configure(makeParams("bayes", plugin.schema(), params));
    for (const LayerSpec& l : plugin.layers())
      if (l.access == LayerAccess::Create) map.addLayer(l.name, l.unit, l.fill);
    const LayerId h = map.addLayer("elevation", "m");
    for (int i = 0; i < 200; ++i)
      for (int j = 0; j < 200; ++j) map.set(h, Index(i, j), 0.5f);
    plugin.start(ctx);
  }
  float at(const std::string& layer, const Eigen::Vector2d& p) const {
    return map.at(map.layerId(layer), *map.geometry().indexAt(p));
  }
  void publish(const SoilEstimateRecord& e) {
    bus.publish<SoilEstimateRecord>(SoilEstimateRecord::kType, e.stamp, std::make_shared<const SoilEstimateRecord>(e));
  }
  void event() { plugin.process(ctx, Tick{}); }
};

// An estimate of a sweep ending with the edge centre at `c`, moving along `t`.
SoilEstimateRecord estimate(Eigen::Vector2d c, Eigen::Vector2d t, double c_pa = 12e3) {
  SoilEstimateRecord e;
  e.T_map_blade1.translation() = Eigen::Vector3d(c.x(), c.y(), 0.5);
  e.t_hat = t.normalized();
  e.alpha_rad = 0.0;
  e.beta_rad = 0.25 * 3.14159265358979323846;  // x_max = d / (tan 45° - 0) = d
  e.d_m = 0.3;
  e.d_res_m = 0.0;
  e.w_m = 0.5;
  e.mean = {c_pa, 0.6, 4e3, 0.4, 16e3};
  e.var_total = {4e6, 0.01, 1e6, 0.004, 1e6};
  e.valid = true;
  return e;
}

TEST(SoilBayesUpdate, ProductOfGaussiansAgainstHandComputedValues) {
  // Prior N(10, 4), measurement N(20, 1): mean (1·10 + 4·20)/5 = 18, variance 4·1/5 = 0.8.
  const Belief b = fuseBelief({10.0, 4.0}, 20.0, 1.0);
  EXPECT_DOUBLE_EQ(b.mean, 18.0);
  EXPECT_DOUBLE_EQ(b.var, 0.8);
  // A cell with no prior takes the measurement.
  const Belief first = fuseBelief({kNaN, kNaN}, 20.0, 1.0);
  EXPECT_DOUBLE_EQ(first.mean, 20.0);
  EXPECT_DOUBLE_EQ(first.var, 1.0);
  // A measurement that is not one leaves the prior.
  EXPECT_DOUBLE_EQ(fuseBelief({10.0, 4.0}, kNaN, 1.0).mean, 10.0);
  EXPECT_DOUBLE_EQ(fuseBelief({10.0, 4.0}, 20.0, 0.0).var, 4.0);
}

TEST(SoilBayesUpdate, WedgeLengthFromDepthAndAngles) {
  EXPECT_DOUBLE_EQ(wedgeLength(0.1, 0.0, 0.0, 0.25 * 3.14159265358979323846), 0.1 / std::tan(0.25 * 3.14159265358979323846));
  // α = 0.1, β = 0.6, d + d_res = 0.12: 0.12 / (cos 0.1 (tan 0.7 − tan 0.1)).
  EXPECT_NEAR(wedgeLength(0.1, 0.02, 0.1, 0.6), 0.12 / (std::cos(0.1) * (std::tan(0.7) - std::tan(0.1))), 1e-15);
  EXPECT_TRUE(std::isnan(wedgeLength(-0.1, 0.0, 0.0, 0.7)));
  EXPECT_TRUE(std::isnan(wedgeLength(0.1, 0.0, 0.0, 0.0)));     // tan(α+β) = tan α
  EXPECT_TRUE(std::isnan(wedgeLength(0.1, 0.0, 0.8, 0.8)));     // α + β past 90°
  EXPECT_TRUE(std::isnan(wedgeLength(kNaN, 0.0, 0.0, 0.7)));
}

TEST(SoilBayes, TheWedgeAheadOfTheBladeIsFusedWithVarianceGrowingWithDistance) {
  Harness h(1, {{"prior", std::string("none")}});
  const SoilEstimateRecord e = estimate({0.0, 0.0}, {1.0, 0.0});
  const long cells = h.plugin.fuse(h.ctx, e);
  // x in [0, 0.3) at 2 cm (15 columns of cell centres), |y| <= 0.25 (25 rows: centres at
  // ±0.01, ..., ±0.23 and none at ±0.25).
  EXPECT_GT(cells, 0);
  for (double x : {0.01, 0.11, 0.29}) {
    const Eigen::Vector2d p(x, 0.01);
    EXPECT_FLOAT_EQ(h.at("soil_c", p), 12e3f) << x;
    // No prior: the estimate's variance inflated by exp(C_s x / x_max), x at the cell centre.
    const Eigen::Vector2d centre = h.map.geometry().positionOf(*h.map.geometry().indexAt(p));
    EXPECT_FLOAT_EQ(h.at("soil_c_var", p), static_cast<float>(4e6 * std::exp(centre.x() / 0.3))) << x;
    EXPECT_FLOAT_EQ(h.at("soil_n", p), 1.0f);
    EXPECT_FLOAT_EQ(h.at("soil_z", p), 0.5f);
  }
  EXPECT_LT(h.at("soil_c_var", {0.01, 0.01}), h.at("soil_c_var", {0.29, 0.01}));
  // Behind the blade, beyond x_lim and beyond w/2 across: untouched.
  for (const Eigen::Vector2d& p : {Eigen::Vector2d(-0.01, 0.0), Eigen::Vector2d(0.31, 0.0), Eigen::Vector2d(0.1, 0.27)}) {
    EXPECT_TRUE(std::isnan(h.at("soil_c", p))) << p.transpose();
    EXPECT_FLOAT_EQ(h.at("soil_n", p), 0.0f);
  }
  // Counted cells = cells with soil_n 1.
  long n = 0;
  const LayerId id = h.map.layerId("soil_n");
  for (int i = 0; i < 200; ++i)
    for (int j = 0; j < 200; ++j) n += h.map.at(id, Index(i, j)) == 1.0f;
  EXPECT_EQ(n, cells);
}

TEST(SoilBayes, BehindMReachesTheSoilTheEdgePassedWithVarianceGrowingWithItsDistance) {
  // The horizon's force came from the wedges at every edge position of the horizon: with
  // behind_m the footprint covers the last behind_m of the edge's path too, each cell's variance
  // inflated by its distance from the edge as ahead of it. Without it (the test above) a cell
  // 1 cm behind the edge stays untouched.
  Harness h(1, {{"behind_m", 0.1}});
  const SoilEstimateRecord e = estimate({0.0, 0.0}, {1.0, 0.0});
  const long cells = h.plugin.fuse(h.ctx, e);
  Harness wedge_only(1);
  const long ahead = wedge_only.plugin.fuse(wedge_only.ctx, e);
  EXPECT_EQ(cells * 15, ahead * (15 + 5));  // 15 columns ahead, 5 behind (centres -0.01 ... -0.09)
  for (double x : {-0.01, -0.05, -0.09}) {
    const Eigen::Vector2d p(x, 0.01);
    const Eigen::Vector2d centre = h.map.geometry().positionOf(*h.map.geometry().indexAt(p));
    EXPECT_FLOAT_EQ(h.at("soil_c", p), 12e3f) << x;
    EXPECT_FLOAT_EQ(h.at("soil_c_var", p), static_cast<float>(4e6 * std::exp(-centre.x() / 0.3))) << x;
  }
  EXPECT_TRUE(std::isnan(h.at("soil_c", {-0.11, 0.01})));
  EXPECT_FLOAT_EQ(h.at("soil_c_var", {-0.05, 0.01}), h.at("soil_c_var", {0.05, 0.01}));
}

TEST(SoilBayes, ShortWedgesReachXMinAndAConfiguredPriorIsFusedFirst) {
  Harness h(1, {{"x_min_m", 0.2}, {"prior", std::string("config")}});
  SoilEstimateRecord e = estimate({0.0, 0.0}, {1.0, 0.0});
  e.d_m = 0.05;  // x_max 0.05 < x_min 0.2
  h.plugin.fuse(h.ctx, e);
  const Eigen::Vector2d p(0.15, 0.01);
  const Eigen::Vector2d centre = h.map.geometry().positionOf(*h.map.geometry().indexAt(p));
  EXPECT_FALSE(std::isnan(h.at("soil_c", p)));
  EXPECT_TRUE(std::isnan(h.at("soil_c", {0.21, 0.01})));
  // Prior [30e3, 3e8] (prior_c_pa's default) fused with N(12e3, 4e6 exp(x / 0.05)).
  const double r = 4e6 * std::exp(centre.x() / 0.05);
  const Belief want = fuseBelief({30e3, 60e3 * 60e3 / 12.0}, 12e3, r);
  EXPECT_FLOAT_EQ(h.at("soil_c", p), static_cast<float>(want.mean));
  EXPECT_FLOAT_EQ(h.at("soil_c_var", p), static_cast<float>(want.var));
}

TEST(SoilBayes, ByDefaultACellTakesItsFirstEstimateAsItIs) {
  // The estimator's variance already holds the prior's where the force cannot tell a property
  // (Eq. 7's ambiguity variance is the physical range's span^2 / 12, prior_*'s default), so the
  // default does not fuse the prior again (README, "Why no prior by default").
  Harness h(1, {{"c_s", 0.0}});
  SoilEstimateRecord e = estimate({0.0, 0.0}, {1.0, 0.0}, 5e3);
  e.var_total[0] = 4e8;
  h.plugin.fuse(h.ctx, e);
  const Eigen::Vector2d p(0.15, 0.01);
  EXPECT_FLOAT_EQ(h.at("soil_c", p), 5e3f);
  EXPECT_FLOAT_EQ(h.at("soil_c_var", p), 4e8f);
  // The second estimate is fused with the first.
  e.mean[0] = 9e3;
  e.var_total[0] = 1e8;
  h.plugin.fuse(h.ctx, e);
  const Belief want = fuseBelief({5e3, 4e8}, 9e3, 1e8);
  EXPECT_FLOAT_EQ(h.at("soil_c", p), static_cast<float>(want.mean));
  EXPECT_FLOAT_EQ(h.at("soil_c_var", p), static_cast<float>(want.var));
  EXPECT_FLOAT_EQ(h.at("soil_n", p), 2.0f);
}

TEST(SoilBayes, EachEstimateIsFusedOncePerCellWhateverTheWedgeOrientation) {
  // A diagonal wedge: sampling the wedge by points (the authors' update) meets cells several
  // times; walking cells meets each once, so every cell's variance is the once-fused one.
  Harness h(1, {{"prior", std::string("none")}, {"c_s", 0.0}});
  const SoilEstimateRecord e = estimate({0.05, -0.03}, {1.0, 1.0});
  const long cells = h.plugin.fuse(h.ctx, e);
  ASSERT_GT(cells, 100);
  const LayerId n = h.map.layerId("soil_n"), v = h.map.layerId("soil_phi_var");
  long seen = 0;
  for (int i = 0; i < 200; ++i)
    for (int j = 0; j < 200; ++j) {
      const float k = h.map.at(n, Index(i, j));
      if (k == 0.0f) continue;
      ++seen;
      EXPECT_EQ(k, 1.0f);
      EXPECT_FLOAT_EQ(h.map.at(v, Index(i, j)), 0.01f);  // C_s = 0: the estimate's own variance
    }
  EXPECT_EQ(seen, cells);
  // A second estimate halves the variance of every cell both wedges cover.
  h.plugin.fuse(h.ctx, e);
  for (int i = 0; i < 200; ++i)
    for (int j = 0; j < 200; ++j) {
      if (h.map.at(n, Index(i, j)) == 0.0f) continue;
      EXPECT_FLOAT_EQ(h.map.at(v, Index(i, j)), 0.005f);
    }
}

TEST(SoilBayes, EveryEstimatePublishedInOneEventIsFusedAndInvalidOnesAreCounted) {
  Harness h(1, {{"prior", std::string("none")}, {"c_s", 0.0}});
  SoilEstimateRecord a = estimate({0.0, 0.0}, {1.0, 0.0}, 10e3), b = estimate({0.0, 0.0}, {1.0, 0.0}, 20e3);
  SoilEstimateRecord bad = estimate({0.0, 0.0}, {1.0, 0.0}, 90e3);
  bad.valid = false;
  h.publish(a);
  h.publish(bad);
  h.publish(b);
  h.event();
  // Both valid ones, equal variances: the mean is their average.
  EXPECT_FLOAT_EQ(h.at("soil_c", {0.1, 0.0}), 15e3f);
  EXPECT_FLOAT_EQ(h.at("soil_n", {0.1, 0.0}), 2.0f);
  EXPECT_EQ(h.stats.dropped["estimate_invalid"], 1);
  EXPECT_DOUBLE_EQ(h.stats.counters["estimates_fused"], 2.0);
  h.event();  // nothing new: nothing fused again
  EXPECT_FLOAT_EQ(h.at("soil_n", {0.1, 0.0}), 2.0f);
}

TEST(SoilBayes, ACutDeeperThanTheFusedSoilInflatesTheVarianceAndReanchors) {
  Harness h(1, {{"prior", std::string("none")}, {"c_s", 0.0}, {"cut_depth_m", 0.2}});
  h.plugin.fuse(h.ctx, estimate({0.0, 0.0}, {1.0, 0.0}));
  const Eigen::Vector2d deep(0.05, 0.01), shallow(0.15, 0.01), uncut(0.25, 0.01);
  const LayerId el = h.map.layerId("elevation");
  h.map.set(el, *h.map.geometry().indexAt(deep), 0.5f - 0.3f);
  h.map.set(el, *h.map.geometry().indexAt(shallow), 0.5f - 0.1f);
  SweepRecord s;
  for (const Eigen::Vector2d& p : {deep, shallow}) {
    SweepMaskCell m;
    m.position = h.map.geometry().positionOf(*h.map.geometry().indexAt(p));
    m.cut = true;
    s.mask.push_back(m);
  }
  EXPECT_EQ(h.plugin.applyCut(h.ctx, s), 1);
  const double depth = 0.5 - static_cast<double>(0.5f - 0.3f);
  EXPECT_FLOAT_EQ(h.at("soil_c_var", deep), static_cast<float>(4e6 * std::exp(depth / 0.2)));
  EXPECT_FLOAT_EQ(h.at("soil_phi_var", deep), static_cast<float>(0.01 * std::exp(depth / 0.2)));
  EXPECT_FLOAT_EQ(h.at("soil_c", deep), 12e3f);  // the mean is kept
  EXPECT_FLOAT_EQ(h.at("soil_z", deep), 0.5f - 0.3f);
  EXPECT_FLOAT_EQ(h.at("soil_c_var", shallow), 4e6f);
  EXPECT_FLOAT_EQ(h.at("soil_z", shallow), 0.5f);
  EXPECT_FLOAT_EQ(h.at("soil_c_var", uncut), 4e6f);
  // The same cut seen again changes nothing (re-anchored).
  EXPECT_EQ(h.plugin.applyCut(h.ctx, s), 0);
}

TEST(SoilBayes, LoosePushedAheadOfTheBladeIsNotTakenForTheSoilSurface) {
  // A berm of 0.25 m loose soil on the cell when the estimate is fused; the next pass removes
  // it and cuts 0.05 m into the bank: 0.05 m of bank, not 0.30 m of surface, so no inflation.
  Harness h(1, {{"prior", std::string("none")}, {"c_s", 0.0}, {"cut_depth_m", 0.2}});
  const LayerId loose = h.map.addLayer("loose", "m", 0.0f);
  h.plugin.start(h.ctx);
  const Eigen::Vector2d p(0.05, 0.01);
  const Index i = *h.map.geometry().indexAt(p);
  h.map.set(loose, i, 0.25f);
  h.plugin.fuse(h.ctx, estimate({0.0, 0.0}, {1.0, 0.0}));
  EXPECT_FLOAT_EQ(h.at("soil_z", p), 0.25f);
  h.map.set(h.map.layerId("elevation"), i, 0.2f);
  h.map.set(loose, i, 0.0f);
  SweepRecord s;
  SweepMaskCell m;
  m.position = h.map.geometry().positionOf(i);
  m.cut = true;
  s.mask.push_back(m);
  EXPECT_EQ(h.plugin.applyCut(h.ctx, s), 0);
  EXPECT_FLOAT_EQ(h.at("soil_c_var", p), 4e6f);
}

TEST(SoilBayes, LayersAreBitIdenticalAtOneAndTwoThreads) {
  auto run = [](int threads) {
    Harness h(threads);
    for (int k = 0; k < 12; ++k) {
      const double a = 0.4 * k;
      SoilEstimateRecord e = estimate({0.3 * std::cos(a), 0.3 * std::sin(a)}, {-std::sin(a), std::cos(a)}, 8e3 + 900 * k);
      e.var_total[0] *= 1.0 + 0.1 * k;
      h.publish(e);
      h.event();
    }
    std::vector<float> out;
    for (const char* l : {"soil_c", "soil_c_var", "soil_phi", "soil_gamma_var", "soil_n"}) {
      const LayerId id = h.map.layerId(l);
      for (int i = 0; i < 200; ++i)
        for (int j = 0; j < 200; ++j) out.push_back(h.map.at(id, Index(i, j)));
    }
    return out;
  };
  const std::vector<float> one = run(1), two = run(2);
  ASSERT_EQ(one.size(), two.size());
  EXPECT_EQ(std::memcmp(one.data(), two.data(), one.size() * sizeof(float)), 0);
  long fused = 0;
  for (std::size_t k = 4 * 40000; k < one.size(); ++k) fused += one[k] > 1.0f;
  EXPECT_GT(fused, 0) << "some cells hold several estimates";
}

}  // namespace
