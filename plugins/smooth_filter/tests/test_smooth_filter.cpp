#include "smooth_filter.hpp"

#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/plugin_loader.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>

using namespace terramap;
using terramap::plugins::SmoothFilter;

namespace {
struct Fixture {
  LayeredMap map;
  LayerId in, out;
  Fixture(int r, int c, double res = 0.1) : map(Geometry(res, Size(r, c)), MapOptions{16, false}) {
    in = map.addLayer("elevation", "m");
    out = map.addLayer("elevation_smooth", "m");
  }
};
SmoothFilter configured(std::map<std::string, ParamValue> p = {}) {
  SmoothFilter f;
  const Params params = makeParams("smooth", f.schema(), p);
  f.configure(params);
  params.throwIfReported();
  return f;
}
}  // namespace

TEST(SmoothFilter, ConstantFieldStaysConstantAndLinearFieldIsPreservedInside) {
  {
    // The kernel is normalised over the cells it covers, so a constant stays that constant
    // everywhere, the border and the corners included (a kernel normalised over its full
    // footprint would pull border cells towards 0 by the missing weight).
    Fixture fx(40, 30);
    fx.map.fill(fx.in, 1.7f);
    auto f = configured({{"sigma_m", 0.1}, {"radius_m", 0.3}});
    f.run(fx.map, Executor(1), fx.in, fx.out);
    for (int i = 0; i < 40; ++i)
      for (int j = 0; j < 30; ++j) EXPECT_NEAR(fx.map.at(fx.out, Index(i, j)), 1.7f, 2e-6f) << i << " " << j;
  }
  Fixture fx(40, 30);
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 30; ++j) fx.map.set(fx.in, Index(i, j), 0.5f + 0.01f * i - 0.02f * j);
  auto f = configured({{"sigma_m", 0.1}, {"radius_m", 0.3}});
  f.run(fx.map, Executor(1), fx.in, fx.out);
  // A symmetric kernel reproduces a linear field exactly away from the border.
  for (int i = 3; i < 37; ++i)
    for (int j = 3; j < 27; ++j)
      EXPECT_NEAR(fx.map.at(fx.out, Index(i, j)), 0.5f + 0.01f * i - 0.02f * j, 2e-6f);
}

TEST(SmoothFilter, HandComputedImpulseResponse) {
  Fixture fx(11, 11, 1.0);
  fx.map.fill(fx.in, 0.0f);
  fx.map.set(fx.in, Index(5, 5), 1.0f);
  auto f = configured({{"sigma_m", 1.0}, {"radius_m", 1.0}});  // 3x3 kernel, w = [e^-.5, 1, e^-.5]
  f.run(fx.map, Executor(1), fx.in, fx.out);
  const double w0 = 1.0, w1 = std::exp(-0.5), s = w0 + 2 * w1;
  EXPECT_NEAR(fx.map.at(fx.out, Index(5, 5)), w0 * w0 / (s * s), 1e-6);
  EXPECT_NEAR(fx.map.at(fx.out, Index(4, 5)), w1 * w0 / (s * s), 1e-6);
  EXPECT_NEAR(fx.map.at(fx.out, Index(4, 4)), w1 * w1 / (s * s), 1e-6);
  EXPECT_EQ(fx.map.at(fx.out, Index(2, 5)), 0.0f);
}

TEST(SmoothFilter, NaNIsIgnoredNotSpreadAndHolesStayUnlessFilled) {
  Fixture fx(20, 20);
  fx.map.fill(fx.in, 2.0f);
  fx.map.set(fx.in, Index(10, 10), NAN);
  auto f = configured();
  f.run(fx.map, Executor(1), fx.in, fx.out);
  EXPECT_TRUE(std::isnan(fx.map.at(fx.out, Index(10, 10))));
  EXPECT_FLOAT_EQ(fx.map.at(fx.out, Index(10, 11)), 2.0f);  // normalised: no dip next to the hole
  auto g = configured({{"fill_holes", true}});
  g.run(fx.map, Executor(1), fx.in, fx.out);
  EXPECT_FLOAT_EQ(fx.map.at(fx.out, Index(10, 10)), 2.0f);
}

TEST(SmoothFilter, TooLittleSupportStaysUnknown) {
  Fixture fx(20, 20);
  fx.map.set(fx.in, Index(10, 10), 1.0f);  // one lonely cell
  auto f = configured({{"min_weight_fraction", 0.3}});
  f.run(fx.map, Executor(1), fx.in, fx.out);
  EXPECT_TRUE(std::isnan(fx.map.at(fx.out, Index(10, 10))));
  auto g = configured({{"min_weight_fraction", 0.0}});
  g.run(fx.map, Executor(1), fx.in, fx.out);
  EXPECT_FLOAT_EQ(fx.map.at(fx.out, Index(10, 10)), 1.0f);
}

TEST(SmoothFilter, BitIdenticalAtOneAndTwoThreadsOnAMovedMap) {
  auto run = [](int threads) {
    Fixture fx(150, 130);
    std::mt19937 rng(3);
    std::normal_distribution<float> n(0, 1);
    for (int i = 0; i < 150; ++i)
      for (int j = 0; j < 130; ++j) fx.map.set(fx.in, Index(i, j), (i * 7 + j) % 13 == 0 ? NAN : n(rng));
    fx.map.move(Position(0.7, -1.1));
    configured().run(fx.map, Executor(threads), fx.in, fx.out);
    return fx.map.toMatrix(fx.out);
  };
  const auto a = run(1), b = run(2);
  EXPECT_EQ(std::memcmp(a.data(), b.data(), sizeof(float) * a.size()), 0);
}

TEST(SmoothFilter, BadParamsAreRefused) {
  EXPECT_THROW(configured({{"output_layer", std::string("elevation")}}), ConfigError);
  EXPECT_THROW(configured({{"sigma_m", 0.5}, {"radius_m", 0.1}}), ConfigError);
  EXPECT_THROW(configured({{"sigma_m", -1.0}}), ConfigError);
  EXPECT_THROW(configured({{"run_on", std::vector<std::string>{"lidar"}}}), ConfigError);
}

// Checks that need the map run in `terramap validate` too and name the key's file:line:col.
TEST(SmoothFilter, MapDependentChecksReachValidate) {
  const auto spec = parsePipelineString(R"(version: 1
map: {resolution: 0.1, size: [20, 20], tile: 16, layers: [elevation]}
pipeline:
  - {name: s, type: smooth_filter, params: {sigma_m: 0.05, radius_m: 0.05, run_on: [tock]}}
  - {name: w, type: smooth_filter, params: {output_layer: wide, radius_m: 1.5}}
)", "p.yaml", ".");
  const auto errs = Engine::validate(spec, PluginRegistry{});
  std::string all;
  for (const auto& e : errs) all += e + "\n";
  EXPECT_NE(all.find("p.yaml:4:60: pipeline[0].params.radius_m: must be at least the map's resolution (0.1 m, "
                     "got 0.05 m)"),
            std::string::npos)
      << all;
  EXPECT_NE(all.find("pipeline[0].params.run_on: unknown event kind 'tock'"), std::string::npos) << all;
  EXPECT_NE(all.find("pipeline[1].params.radius_m: the kernel (31 cells across) does not fit in the map (20 x 20 "
                     "cells)"),
            std::string::npos)
      << all;
  // Without a map (a plugin configured on its own) the same radius is accepted.
  EXPECT_NO_THROW(configured({{"sigma_m", 0.05}, {"radius_m", 0.05}}));
}

TEST(SmoothFilter, LoadsThroughTheHostAndRunsInAnEngine) {
  EngineOptions o;
  o.geometry = Geometry(0.1, Size(32, 32));
  o.map.tile_size = 16;
  o.layers = {LayerDecl{"elevation", "m", 1.0f, ""}};
  Engine e(o);
  e.addStage("s", PluginRegistry::createFromFile(std::string(TERRAMAP_PLUGIN_DIR) + "/smooth_filter.so"),
             {{"run_on", std::vector<std::string>{"tick"}}});
  e.push(Tick{0});
  EXPECT_FLOAT_EQ(e.map().at(e.map().layerId("elevation_smooth"), Index(16, 16)), 1.0f);
  EXPECT_EQ(e.report().stages[0].stats.counters.at("passes"), 1.0);
}

// Incremental updates (ProcessContext::changedTiles) must give the bits of a whole-map pass.
// The map's 147 x 130 cells in 16-cell tiles leave partial last tiles of 3 and 2 cells, less
// than the kernel's 6-cell half-width, and the map moves: then buffer rows 141-143 (tile 8) are
// logical neighbours of buffer row 0 (tile 0) across the partial tile 9, which growing the
// changed tiles by ceil(k / T) = 1 alone would miss. Cells there are written on every step.
TEST(SmoothFilter, IncrementalUpdatesEqualAWholeMapPass) {
  EngineOptions o;
  o.geometry = Geometry(0.1, Size(147, 130));
  o.map.tile_size = 16;
  o.threads = 2;
  o.layers = {LayerDecl{"elevation", "m", 0.0f, ""}};
  Engine e(o);
  std::mt19937 rng(11);
  std::normal_distribution<float> z(0, 1);
  const LayerId in = e.map().layerId("elevation");
  // A dense random surface with holes: every output cell has support, so a stale one shows.
  for (int i = 0; i < 147; ++i)
    for (int j = 0; j < 130; ++j) e.mutableMap().set(in, Index(i, j), (i * 7 + j) % 11 == 0 ? NAN : z(rng));
  e.addStage("s", PluginRegistry::createFromFile(std::string(TERRAMAP_PLUGIN_DIR) + "/smooth_filter.so"),
             {{"run_on", std::vector<std::string>{"tick"}}, {"sigma_m", 0.3}, {"radius_m", 0.6}});
  const SmoothFilter reference = configured({{"sigma_m", 0.3}, {"radius_m", 0.6}});
  std::uniform_int_distribution<int> ri(0, 146), cj(0, 129);
  double partial_updates = 0;
  for (int step = 0; step < 12; ++step) {
    // A few cells written, some at the map's edges (next to the ring's seam after a move).
    for (int n = 0; n < 3; ++n) e.mutableMap().set(in, Index(ri(rng), cj(rng)), z(rng));
    e.mutableMap().set(in, Index(step % 2 ? 0 : 146, cj(rng)), z(rng));
    e.mutableMap().set(in, Index(ri(rng), step % 2 ? 129 : 0), z(rng));
    e.mutableMap().set(in, e.map().logicalIndex(Index(141 + step % 3, cj(rng))), z(rng));
    e.mutableMap().set(in, e.map().logicalIndex(Index(ri(rng), 124 + step % 4)), z(rng));
    if (step == 5) e.mutableMap().move(e.map().geometry().center() + Position(0.7, -1.1));
    const double before = e.report().stages[0].stats.counters.count("tiles_smoothed")
                              ? e.report().stages[0].stats.counters.at("tiles_smoothed")
                              : 0.0;
    e.push(Tick{0.1 * step});
    const double tiles = e.report().stages[0].stats.counters.at("tiles_smoothed") - before;
    if (tiles < e.map().tileCount()) ++partial_updates;
    LayeredMap full = *e.snapshot();
    reference.run(full, Executor(1), full.layerId("elevation"), full.layerId("elevation_smooth"));
    const Eigen::MatrixXf want = full.toMatrix(full.layerId("elevation_smooth"));
    const Eigen::MatrixXf got = e.map().toMatrix(e.map().layerId("elevation_smooth"));
    ASSERT_GT((want.array() == want.array()).count(), want.size() / 2) << "most cells must have a value";
    ASSERT_EQ(std::memcmp(want.data(), got.data(), sizeof(float) * want.size()), 0) << "step " << step;
  }
  EXPECT_GT(partial_updates, 0) << "every call smoothed the whole map: nothing was incremental";
}
