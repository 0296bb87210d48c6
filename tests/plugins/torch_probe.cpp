// A plugin that links libtorch (terramap_add_plugin(... LIBRARIES ${TORCH_LIBRARIES})) and
// follows docs/plugins.md's threading rule for libraries with their own thread pools: the
// engine's arena provides the parallelism (one task per tile), and torch runs with one
// intra-op thread inside each task, so results are bit-identical for any engine thread count.
// Per cell it evaluates a fixed 2-4-1 tanh network of the cell's map position (x, y):
//   out = sum_k tanh(x W[0][k] + y W[1][k] + b[k]).
#include <terramap/plugin/abi.hpp>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <atomic>

namespace {

class TorchProbe : public terramap::Plugin {
 public:
  terramap::ParamSchema schema() const override { return {}; }
  void configure(const terramap::Params&) override {}
  std::vector<terramap::LayerSpec> layers() const override {
    return {terramap::LayerSpec{"torch_probe", terramap::LayerAccess::Create, "1", 0.0f, "fixed tanh network of (x, y)"}};
  }
  terramap::EventMask events() const override { return terramap::mask(terramap::EventKind::Tick); }
  void start(terramap::ProcessContext& ctx) override { id_ = ctx.map().layerId("torch_probe"); }
  void process(terramap::ProcessContext& ctx, const terramap::Event&) override {
    auto& map = ctx.map();
    const at::Tensor W = at::tensor({0.5f, -1.0f, 0.25f, 2.0f, 1.5f, 0.75f, -0.5f, -0.125f}).reshape({2, 4});
    const at::Tensor b = at::tensor({0.1f, -0.2f, 0.3f, 0.0f});
    std::atomic<int> max_threads{0};
    ctx.executor().forEach(map.tileCount(), [&](int t) {
      // OpenMP's thread count is per thread: set it in every task that runs torch.
      at::set_num_threads(1);
      int seen = at::get_num_threads();
      for (int prev = max_threads.load(); seen > prev && !max_threads.compare_exchange_weak(prev, seen);) {
      }
      const terramap::CellRect r = map.tileRect(t);
      at::Tensor X = at::empty({static_cast<long>(r.cells()), 2}, at::kFloat);
      auto x = X.accessor<float, 2>();
      long k = 0;
      for (int br = r.r0; br < r.r0 + r.rows; ++br)
        for (int bc = r.c0; bc < r.c0 + r.cols; ++bc, ++k) {
          const terramap::Position p = map.geometry().positionOf(map.logicalIndex(terramap::Index(br, bc)));
          x[k][0] = static_cast<float>(p.x());
          x[k][1] = static_cast<float>(p.y());
        }
      const at::Tensor y = at::tanh(X.mm(W) + b).sum(1).contiguous();
      const float* yd = y.data_ptr<float>();
      float* d = map.mutableTileData(id_, t);
      k = 0;
      for (int br = 0; br < r.rows; ++br)
        for (int bc = 0; bc < r.cols; ++bc, ++k) d[br * map.tileSize() + bc] = yd[k];
    });
    ctx.addCounter("max_intra_op_threads", max_threads.load());
    ctx.addCounter("ticks", 1);
  }

 private:
  terramap::LayerId id_ = -1;
};

}  // namespace

TERRAMAP_PLUGIN(TorchProbe, "torch_probe", "0.0.1", "test: a libtorch network evaluated per tile in the engine's arena")
