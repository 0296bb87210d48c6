// A well-behaved probe plugin for engine tests: on every event it adds `increment` to every
// cell of its output layer (tile-parallel), and logs the order in which stages ran.
#include <terramap/plugin/abi.hpp>

#include <cmath>

namespace {
class Probe : public terramap::Plugin {
 public:
  terramap::ParamSchema schema() const override {
    using namespace terramap;
    return {param::text("output_layer", "probe", {}, "layer to create and increment"),
            param::text("input_layer", "", {}, "optional layer to read (checked by the validator)"),
            param::real("increment", 1.0, -1e6, 1e6, "1", "added to every cell per event"),
            param::integer("throw_on_event", -1, -1, 1000000, "throw std::runtime_error on this event number"),
            param::texts("events", {"tick", "point_cloud"}, "event kinds to take"),
            param::text("config_error_in", "", {"", "start", "finish"},
                        "throw a terramap::ConfigError in start() or finish()"),
            param::boolean("records", false, "report a record per event (and one in finish())")};
  }
  void configure(const terramap::Params& p) override {
    out_ = p.getString("output_layer");
    in_ = p.getString("input_layer");
    inc_ = static_cast<float>(p.getDouble("increment"));
    throw_on_ = p.getInt("throw_on_event");
    std::string unknown;
    mask_ = terramap::eventMaskFromNames(p.getStrings("events"), &unknown);
    if (!unknown.empty()) p.report("events", "unknown kind '" + unknown + "'");
    if (in_ == out_) p.report("input_layer", "must differ from output_layer '" + out_ + "'");
    config_error_in_ = p.getString("config_error_in");
    records_ = p.getBool("records");
  }
  std::vector<terramap::LayerSpec> layers() const override {
    using namespace terramap;
    std::vector<LayerSpec> l{LayerSpec{out_, LayerAccess::Create, "1", 0.0f, "probe counter"}};
    if (!in_.empty()) l.push_back(LayerSpec{in_, LayerAccess::Read, "", 0, ""});
    return l;
  }
  terramap::EventMask events() const override { return mask_; }
  void start(terramap::ProcessContext& ctx) override {
    if (config_error_in_ == "start") throw terramap::ConfigError("probe: refused in start() on purpose");
    id_ = ctx.map().layerId(out_);
  }
  void finish(terramap::ProcessContext& ctx) override {
    if (config_error_in_ == "finish") throw terramap::ConfigError("probe: refused in finish() on purpose");
    if (records_) ctx.reportRecord("{\"type\":\"probe.finish\",\"events\":" + std::to_string(count_) + "}");
  }
  void process(terramap::ProcessContext& ctx, const terramap::Event& e) override {
    if (count_++ == throw_on_) throw std::runtime_error("probe asked to throw on event " + std::to_string(throw_on_));
    auto& map = ctx.map();
    const int T = map.tileSize();
    ctx.executor().forEach(map.tileCount(), [&](int t) {
      const auto r = map.tileRect(t);
      float* d = map.mutableTileData(id_, t);
      for (int i = 0; i < r.rows; ++i)
        for (int j = 0; j < r.cols; ++j) d[i * T + j] += inc_;
    });
    ctx.addCounter("events", 1);
    if (records_) ctx.reportRecord("{\"type\":\"probe\",\"event\":" + std::to_string(count_ - 1) + "}");
    if (std::holds_alternative<terramap::PointCloud>(e)) {
      long nan = 0;
      for (const auto& p : std::get<terramap::PointCloud>(e).points) nan += !std::isfinite(p.x);
      if (nan) ctx.countDrop("nan", nan);
    }
  }

 private:
  std::string out_, in_, config_error_in_;
  float inc_ = 1;
  bool records_ = false;
  long throw_on_ = -1, count_ = 0;
  terramap::EventMask mask_ = 0;
  terramap::LayerId id_ = -1;
};
}  // namespace

TERRAMAP_PLUGIN(Probe, "test_probe", "0.0.1", "test probe: increments a layer per event")
