#include "inpaint.hpp"

#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/plugin_loader.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>

using namespace terramap;
using terramap::plugins::Inpaint;

TEST(Inpaint, KnownCellsAreUntouchedAndAPlaneIsFilledSmoothly) {
  Eigen::MatrixXf in(32, 32);
  for (int i = 0; i < 32; ++i)
    for (int j = 0; j < 32; ++j) in(i, j) = 1.0f + 0.1f * i;
  for (int i = 10; i < 14; ++i)
    for (int j = 10; j < 14; ++j) in(i, j) = NAN;  // a 4x4 hole in a plane
  const Eigen::MatrixXf out = Inpaint::fill(in, -1, Executor(1));
  for (int i = 0; i < 32; ++i)
    for (int j = 0; j < 32; ++j) {
      if (std::isfinite(in(i, j))) EXPECT_EQ(out(i, j), in(i, j));
      else {
        // Inside the hole: between the heights of the rows around it, close to the plane.
        EXPECT_GE(out(i, j), 1.0f + 0.1f * 9 - 1e-5f);
        EXPECT_LE(out(i, j), 1.0f + 0.1f * 14 + 1e-5f);
      }
    }
  // Smoothly: data that rises with i and does not depend on j must be filled rising with i
  // (push-pull averages are monotone in their inputs), and symmetric in j about the hole's
  // centre line (the hole and the data are symmetric about j = 11.5).
  for (int i = 9; i < 14; ++i)
    for (int j = 10; j < 14; ++j) EXPECT_GE(out(i + 1, j), out(i, j) - 1e-6f) << i << " " << j;
  for (int i = 10; i < 14; ++i)
    for (int j = 10; j < 12; ++j) EXPECT_NEAR(out(i, j), out(i, 23 - j), 1e-5f) << i << " " << j;
}

TEST(Inpaint, ConstantDataFillsWithTheConstant) {
  Eigen::MatrixXf in = Eigen::MatrixXf::Constant(20, 17, NAN);
  in(3, 4) = 5.0f;
  in(15, 12) = 5.0f;
  const Eigen::MatrixXf out = Inpaint::fill(in, -1, Executor(2));
  EXPECT_TRUE((out.array() == 5.0f).all());
}

TEST(Inpaint, DistanceLimitLeavesFarCellsUnknown) {
  Eigen::MatrixXf in = Eigen::MatrixXf::Constant(30, 30, NAN);
  in(0, 0) = 1.0f;
  const Eigen::MatrixXf d = Inpaint::distanceToKnown(in);
  EXPECT_FLOAT_EQ(d(0, 0), 0.0f);
  EXPECT_FLOAT_EQ(d(5, 0), 5.0f);            // along an axis: exact
  EXPECT_FLOAT_EQ(d(5, 5), 20.0f / 3.0f);  // 3-4 chamfer: 5 diagonal steps of 4/3 (true 7.07)
  const Eigen::MatrixXf out = Inpaint::fill(in, 4.0, Executor(1));
  EXPECT_FLOAT_EQ(out(4, 0), 1.0f);
  EXPECT_TRUE(std::isnan(out(5, 0)));
  EXPECT_TRUE(std::isnan(out(29, 29)));
}

TEST(Inpaint, NothingKnownStaysUnknown) {
  const Eigen::MatrixXf out = Inpaint::fill(Eigen::MatrixXf::Constant(8, 8, NAN), -1, Executor(1));
  EXPECT_TRUE(out.array().isNaN().all());
}

TEST(Inpaint, BitIdenticalAtOneAndTwoThreads) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0, 1);
  Eigen::MatrixXf in(257, 190);
  for (int i = 0; i < in.rows(); ++i)
    for (int j = 0; j < in.cols(); ++j) in(i, j) = u(rng) < 0.7f ? NAN : u(rng);
  const auto a = Inpaint::fill(in, 3.0, Executor(1)), b = Inpaint::fill(in, 3.0, Executor(2));
  EXPECT_EQ(std::memcmp(a.data(), b.data(), sizeof(float) * a.size()), 0);
}

TEST(Inpaint, RunsInAnEngineAtFinishAndCountsFilledCells) {
  EngineOptions o;
  o.geometry = Geometry(0.1, Size(20, 20));
  o.map.tile_size = 16;
  o.layers = {LayerDecl{"elevation", "m", NAN, ""}};
  Engine e(o);
  e.mutableMap().set(0, Index(10, 10), 3.0f);
  e.addStage("fill", PluginRegistry::createFromFile(std::string(TERRAMAP_PLUGIN_DIR) + "/inpaint.so"),
             {{"max_distance_m", 0.25}});
  e.finish();
  const LayerId out = e.map().layerId("elevation_inpainted");
  EXPECT_FLOAT_EQ(e.map().at(out, Index(12, 10)), 3.0f);
  EXPECT_TRUE(std::isnan(e.map().at(out, Index(13, 10))));
  // Cells within 2.5 cells (chamfer) of the single known cell: the 5x5 block without its 4
  // corners (corner chamfer distance 8/3 > 2.5) = 21, minus the known cell itself = 20.
  EXPECT_EQ(e.report().stages[0].stats.counters.at("cells_filled"), 20.0);
}

// A call with no input or output tile written since the previous one is skipped; any write
// (here one cell, or another stage's write into the output) brings the whole pass back.
TEST(Inpaint, SkipsACallOnlyWhenNothingChanged) {
  EngineOptions o;
  o.geometry = Geometry(0.1, Size(48, 40));
  o.map.tile_size = 16;
  o.layers = {LayerDecl{"elevation", "m", std::numeric_limits<float>::quiet_NaN(), ""}};
  Engine e(o);
  for (int i = 0; i < 48; i += 5)
    for (int j = 0; j < 40; j += 7) e.mutableMap().set(0, Index(i, j), 0.01f * static_cast<float>(i * j));
  e.addStage("f", PluginRegistry::createFromFile(std::string(TERRAMAP_PLUGIN_DIR) + "/inpaint.so"),
             {{"run_on", std::vector<std::string>{"tick"}}, {"max_distance_m", -1.0}});
  auto skipped = [&] {
    const RunReport r = e.report();  // a copy: report() returns by value
    const auto& c = r.stages[0].stats.counters;
    return c.count("passes_skipped") ? c.at("passes_skipped") : 0.0;
  };
  auto expectFullPass = [&](const char* when) {
    const Eigen::MatrixXf want = Inpaint::fill(e.map().toMatrix(0), -1.0, Executor(1));
    const Eigen::MatrixXf got = e.map().toMatrix(e.map().layerId("elevation_inpainted"));
    EXPECT_EQ(std::memcmp(want.data(), got.data(), sizeof(float) * want.size()), 0) << when;
  };
  e.push(Tick{0});
  EXPECT_EQ(skipped(), 0.0);
  expectFullPass("first call");
  e.push(Tick{0.1});
  EXPECT_EQ(skipped(), 1.0);
  expectFullPass("nothing changed");
  e.mutableMap().set(0, Index(47, 39), 5.0f);
  e.push(Tick{0.2});
  EXPECT_EQ(skipped(), 1.0);
  expectFullPass("one input cell written");
  e.mutableMap().set(e.map().layerId("elevation_inpainted"), Index(0, 0), -3.0f);
  e.push(Tick{0.3});
  EXPECT_EQ(skipped(), 1.0);
  expectFullPass("output overwritten by someone else");
}
