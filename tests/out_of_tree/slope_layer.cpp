// An out-of-tree plugin: the terrain slope (rad) of an elevation layer by central differences.
// It reads and writes whole layers through the inline matrix helpers (toMatrix/fromMatrix,
// compiled into this plugin with its own flags) and checks them against the host's per-cell
// access (LayeredMap::at, compiled with the host's): the elevation it read and the slope it
// wrote must be the host's values bit for bit, and the slope must be the central-difference
// slope of the host's heights. finish() reports the counts; the test asserts them.
#include <terramap/plugin/abi.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace {
bool sameBits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }

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
  void process(terramap::ProcessContext& ctx, const terramap::Event&) override { compute(ctx); }
  void finish(terramap::ProcessContext& ctx) override {
    compute(ctx);
    char buf[512];
    std::snprintf(buf, sizeof buf,
                  "{\"type\": \"slope_layer\", \"cells\": %ld, \"finite\": %ld, \"nonzero\": %ld, "
                  "\"read_mismatch\": %ld, \"write_mismatch\": %ld, \"slope_off\": %ld, \"max_slope\": %.6f}",
                  cells_, finite_, nonzero_, read_mismatch_, write_mismatch_, slope_off_, max_slope_);
    ctx.reportRecord(buf);
  }

 private:
  void compute(terramap::ProcessContext& ctx) {
    using terramap::Index;
    auto& m = ctx.map();
    const Eigen::MatrixXf h = m.toMatrix(in_id_);
    Eigen::MatrixXf s = Eigen::MatrixXf::Constant(h.rows(), h.cols(), NAN);
    const double res = m.geometry().resolution();
    const float r2 = 2.0f * static_cast<float>(res);
    for (int i = 1; i + 1 < h.rows(); ++i)
      for (int j = 1; j + 1 < h.cols(); ++j) {
        const float gx = (h(i - 1, j) - h(i + 1, j)) / r2, gy = (h(i, j - 1) - h(i, j + 1)) / r2;
        s(i, j) = std::atan(std::sqrt(gx * gx + gy * gy));
      }
    m.fromMatrix(out_id_, s);
    cells_ = finite_ = nonzero_ = read_mismatch_ = write_mismatch_ = slope_off_ = 0;
    max_slope_ = 0;
    for (int i = 0; i < h.rows(); ++i)
      for (int j = 0; j < h.cols(); ++j) {
        ++cells_;
        read_mismatch_ += sameBits(m.at(in_id_, Index(i, j)), h(i, j)) ? 0 : 1;
        write_mismatch_ += sameBits(m.at(out_id_, Index(i, j)), s(i, j)) ? 0 : 1;
        if (!std::isfinite(s(i, j))) continue;
        ++finite_;
        nonzero_ += s(i, j) > 1e-3f ? 1 : 0;
        max_slope_ = std::max(max_slope_, static_cast<double>(s(i, j)));
        // The slope of the host's heights, in double: float rounding of the differences and
        // of atan/sqrt keeps the plugin's within 1e-5 rad of it (heights of metres, 1e-7
        // relative; a 0.5 m cell turns that into ~1e-6 of gradient).
        auto H = [&](int a, int b) { return static_cast<double>(m.at(in_id_, Index(a, b))); };
        const double gx = (H(i - 1, j) - H(i + 1, j)) / (2 * res), gy = (H(i, j - 1) - H(i, j + 1)) / (2 * res);
        if (std::abs(std::atan(std::hypot(gx, gy)) - s(i, j)) > 1e-5) ++slope_off_;
      }
  }

  std::string in_, out_;
  terramap::LayerId in_id_ = -1, out_id_ = -1;
  long cells_ = 0, finite_ = 0, nonzero_ = 0, read_mismatch_ = 0, write_mismatch_ = 0, slope_off_ = 0;
  double max_slope_ = 0;
};
}  // namespace

TERRAMAP_PLUGIN(SlopeLayer, "slope_layer", "0.1.0", "out-of-tree test: slope of an elevation layer")
