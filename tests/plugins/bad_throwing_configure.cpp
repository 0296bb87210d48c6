// Broken on purpose: configure() throws a plain std::runtime_error.
#include <terramap/plugin/abi.hpp>

#include <stdexcept>

namespace {
class Thrower : public terramap::Plugin {
 public:
  terramap::ParamSchema schema() const override { return {}; }
  void configure(const terramap::Params&) override { throw std::runtime_error("configure exploded on purpose"); }
  std::vector<terramap::LayerSpec> layers() const override { return {}; }
  terramap::EventMask events() const override { return 0; }
  void process(terramap::ProcessContext&, const terramap::Event&) override {}
};
}  // namespace
TERRAMAP_PLUGIN(Thrower, "bad_throwing_configure", "0.0.1", "configure throws")
