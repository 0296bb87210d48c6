// The library's one export. A skeleton for now: it declares its parameter and the events it
// will need (observations for the history, blade poses for the FEE geometry) and only counts
// them; the estimator logic (model.hpp, loss.hpp, nullspace.hpp) is wired in later.
#include <terramap/plugin/abi.hpp>

namespace {

class SoilPinn : public terramap::Plugin {
 public:
  terramap::ParamSchema schema() const override {
    return {terramap::param::text("model", "", {}, "path of a trained soil_pinn model file (empty: none yet)")};
  }
  void configure(const terramap::Params& p) override { model_path_ = p.getString("model"); }
  std::vector<terramap::LayerSpec> layers() const override { return {}; }
  terramap::EventMask events() const override {
    return terramap::EventKind::Observation | terramap::EventKind::BladePose;
  }
  void start(terramap::ProcessContext&) override {}
  void process(terramap::ProcessContext& ctx, const terramap::Event&) override { ctx.addCounter("events", 1); }

 private:
  std::string model_path_;
};

}  // namespace

TERRAMAP_PLUGIN(SoilPinn, "soil_pinn", "0.0.1", "PINN soil estimator (skeleton: counts its events)")
