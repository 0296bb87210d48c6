// An out-of-tree plugin: the terrain slope (rad) of an elevation layer by central differences.
#include <terramap/plugin/abi.hpp>

#include <cmath>

namespace {
class SlopeLayer : public terramap::Plugin {
 public:
  terramap::ParamSchema schema() const override {
    using namespace terramap;
    return {param::text("input_layer", "elevation", {}, "elevation layer (m)"),
            param::text("output_layer", "slope", {}, "slope layer to create (rad)")};
  }
  void configure(const terramap::Params& p) override {
    in_ = p.getString("input_layer");
    out_ = p.getString("output_layer");
  }
  std::vector<terramap::LayerSpec> layers() const override {
    using namespace terramap;
    return {LayerSpec{in_, LayerAccess::Read, "", 0, ""},
            LayerSpec{out_, LayerAccess::Create, "rad", std::numeric_limits<float>::quiet_NaN(), "terrain slope"}};
  }
  terramap::EventMask events() const override { return terramap::mask(terramap::EventKind::Tick); }
  void start(terramap::ProcessContext& ctx) override {
    in_id_ = ctx.map().layerId(in_);
    out_id_ = ctx.map().layerId(out_);
  }
  void process(terramap::ProcessContext& ctx, const terramap::Event&) override { finish(ctx); }
  void finish(terramap::ProcessContext& ctx) override {
    auto& m = ctx.map();
    const Eigen::MatrixXf h = m.toMatrix(in_id_);
    Eigen::MatrixXf s = Eigen::MatrixXf::Constant(h.rows(), h.cols(), NAN);
    const float r2 = 2.0f * static_cast<float>(m.geometry().resolution());
    for (int i = 1; i + 1 < h.rows(); ++i)
      for (int j = 1; j + 1 < h.cols(); ++j) {
        const float gx = (h(i - 1, j) - h(i + 1, j)) / r2, gy = (h(i, j - 1) - h(i, j + 1)) / r2;
        s(i, j) = std::atan(std::sqrt(gx * gx + gy * gy));
      }
    m.fromMatrix(out_id_, s);
  }

 private:
  std::string in_, out_;
  terramap::LayerId in_id_ = -1, out_id_ = -1;
};
}  // namespace

TERRAMAP_PLUGIN(SlopeLayer, "slope_layer", "0.1.0", "out-of-tree test: slope of an elevation layer")
