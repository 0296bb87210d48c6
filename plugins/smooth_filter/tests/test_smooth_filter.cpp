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
  f.configure(makeParams("smooth", f.schema(), p));
  return f;
}
}  // namespace

TEST(SmoothFilter, ConstantFieldStaysConstantAndLinearFieldIsPreservedInside) {
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
  SmoothFilter f;
  EXPECT_THROW(f.configure(makeParams("s", f.schema(), {{"output_layer", std::string("elevation")}})), ConfigError);
  EXPECT_THROW(f.configure(makeParams("s", f.schema(), {{"sigma_m", 0.5}, {"radius_m", 0.1}})), ConfigError);
  EXPECT_THROW(makeParams("s", f.schema(), {{"sigma_m", -1.0}}), ConfigError);
  EXPECT_THROW(f.configure(makeParams("s", f.schema(), {{"run_on", std::vector<std::string>{"lidar"}}})),
               ConfigError);
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
