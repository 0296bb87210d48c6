// A plugin linking libtorch (tests/plugins/torch_probe.cpp), loaded through the host: the
// LIBRARIES of terramap_add_plugin reach it, torch runs inside the engine's arena with one
// intra-op thread per task, and the result is the network's and bit-identical for 1 and 2
// engine threads (docs/plugins.md, "Libraries with their own thread pools").
#include <terramap/core/error.hpp>
#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/plugin_loader.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>

using namespace terramap;

namespace {
const std::string kLib = std::string(TERRAMAP_TEST_PLUGIN_DIR) + "/torch_probe.so";

struct Result {
  Eigen::MatrixXf layer;
  double max_intra_op_threads = 0;
};

Result run(int threads) {
  EngineOptions o;
  o.geometry = Geometry(0.25, Size(70, 45), Position(1.0, -2.0));  // partial edge tiles
  o.map.tile_size = 16;
  o.threads = threads;
  Engine engine(o);
  engine.addStage("torch", PluginRegistry::createFromFile(kLib));
  engine.push(Tick{0.0});
  engine.push(Tick{1.0});
  engine.finish();
  const auto snap = engine.snapshot();
  Result r;
  r.layer = snap->toMatrix(snap->layerId("torch_probe"));
  for (const auto& s : engine.report().stages)
    if (s.name == "torch") r.max_intra_op_threads = s.stats.counters.at("max_intra_op_threads");
  return r;
}
}  // namespace

TEST(TorchPlugin, RunsItsNetworkInTheArenaBitIdenticalForAnyThreadCount) {
  if (!std::filesystem::exists(kLib)) GTEST_SKIP() << "built without TERRAMAP_WITH_TORCH";
  const Result one = run(1), two = run(2);
  ASSERT_EQ(one.layer.rows(), 70);
  ASSERT_EQ(one.layer.cols(), 45);
  EXPECT_EQ(std::memcmp(one.layer.data(), two.layer.data(), sizeof(float) * static_cast<size_t>(one.layer.size())), 0);
  // Two ticks, two adds of 1 per tick counted: the counter is a sum of maxima (1 + 1).
  EXPECT_EQ(one.max_intra_op_threads, 2.0);
  EXPECT_EQ(two.max_intra_op_threads, 2.0);
  // The network, evaluated here without torch.
  const float W[2][4] = {{0.5f, -1.0f, 0.25f, 2.0f}, {1.5f, 0.75f, -0.5f, -0.125f}};
  const float b[4] = {0.1f, -0.2f, 0.3f, 0.0f};
  const Geometry g(0.25, Size(70, 45), Position(1.0, -2.0));
  double worst = 0;
  for (int i = 0; i < 70; ++i)
    for (int j = 0; j < 45; ++j) {
      const Position p = g.positionOf(Index(i, j));
      double want = 0;
      for (int k = 0; k < 4; ++k) want += std::tanh(p.x() * W[0][k] + p.y() * W[1][k] + b[k]);
      worst = std::max(worst, std::abs(want - one.layer(i, j)));
    }
  EXPECT_LT(worst, 1e-5);
}
