// Embedding an Engine built in code (no YAML) with the example plugin `roughness`:
// - the map, the layers that exist before any plugin, and the stages with their parameters;
// - the engine's thread writes elevation and pushes events; another thread takes snapshots
//   at any time (the thread-safety contract of engine.hpp);
// - checks what it can derive: the roughness of a plane z = a * i in a (2w+1)^2 window is
//   a * sqrt(((2w+1)^2 - 1) / 12) (the standard deviation of 2w+1 equally spaced rows), and
//   the incrementally updated layer has the bits of a whole-map pass.
// Exit 0 and "embed_app: ok ..." when both hold.
#include <terramap/pipeline/engine.hpp>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <thread>

using namespace terramap;

namespace {
EngineOptions mapOptions() {
  EngineOptions o;
  o.geometry = Geometry(0.1, Size(96, 80));
  o.map.tile_size = 16;
  o.threads = 2;
  LayerDecl elevation;
  elevation.name = "elevation";
  elevation.unit = "m";  // fill NaN: unknown until written
  o.layers = {elevation};
  return o;
}
std::unique_ptr<Engine> makeEngine() {
  auto e = std::make_unique<Engine>(mapOptions());
  PluginRegistry registry({EXAMPLE_PLUGIN_DIR});
  e->addStage("rough", registry.create("roughness"),
              {{"window_m", 0.3}, {"run_on", std::vector<std::string>{"tick"}}});
  return e;
}
}  // namespace

int main() {
  auto engine = makeEngine();
  const LayeredMap& map = engine->map();  // reads on the engine's thread, between push() calls
  const LayerId z = map.layerId("elevation");
  const int R = map.geometry().size().x(), C = map.geometry().size().y();
  const double a = 0.01;  // m per row
  // Writes go through editMap() (under the engine's lock) because the reader below may take a
  // snapshot at any moment.
  auto write = [&](int i0, int j0, int rows, int cols, auto value) {
    engine->editMap([&](LayeredMap& m) {
      for (int i = i0; i < std::min(R, i0 + rows); ++i)
        for (int j = j0; j < std::min(C, j0 + cols); ++j) m.set(z, Index(i, j), value(i));
    });
  };

  std::atomic<bool> stop{false};
  std::atomic<long> snapshots{0};
  std::thread reader([&] {
    while (!stop) {
      const auto snap = engine->snapshot();  // any thread, any time
      if (snap->hasLayer("roughness")) ++snapshots;
    }
  });
  write(0, 0, R, C, [&](int i) { return static_cast<float>(a * i); });
  engine->push(Tick{0.0});
  const LayerId rough = map.layerId("roughness");
  const int w = 3;  // window_m 0.3 / resolution 0.1
  const double expected = a * std::sqrt(((2 * w + 1) * (2 * w + 1) - 1) / 12.0);
  const double got = map.at(rough, Index(R / 2, C / 2));
  if (std::abs(got - expected) > 1e-6 * expected + 1e-7) {
    std::printf("embed_app: roughness of the plane %.9f, expected %.9f\n", got, expected);
    stop = true;
    reader.join();
    return 1;
  }

  std::mt19937 rng(5);
  std::uniform_int_distribution<int> ri(0, R - 1), cj(0, C - 1);
  for (int k = 1; k <= 8; ++k) {
    write(ri(rng), cj(rng), 3, 3, [&](int) { return 0.2f * static_cast<float>(k); });
    engine->push(Tick{0.1 * k});
  }
  engine->finish();
  stop = true;
  reader.join();

  // The same elevation through a fresh engine: one whole-map pass.
  auto full = makeEngine();
  const Eigen::MatrixXf elevation = map.toMatrix(z);
  full->mutableMap().fromMatrix(z, elevation);
  full->push(Tick{1.0});
  full->finish();
  const Eigen::MatrixXf inc = map.toMatrix(rough), ref = full->map().toMatrix(rough);
  const bool same = std::memcmp(inc.data(), ref.data(), sizeof(float) * static_cast<size_t>(inc.size())) == 0;
  const double updated = engine->report().stages[0].stats.counters.at("tiles_updated");
  const int all = 9 * map.tileCount();  // 9 events
  std::printf("embed_app: %s plane %.6f m (expected %.6f), %.0f of %d tile updates, %ld snapshots\n",
              same && updated < all ? "ok" : "FAILED", got, expected, updated, all, snapshots.load());
  return same && updated < all ? 0 : 1;
}
