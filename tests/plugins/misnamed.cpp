// A valid plugin in a file whose name is not its type.
#include <terramap/plugin/abi.hpp>
namespace {
class Misnamed : public terramap::Plugin {
 public:
  terramap::ParamSchema schema() const override { return {}; }
  void configure(const terramap::Params&) override {}
  std::vector<terramap::LayerSpec> layers() const override { return {}; }
  terramap::EventMask events() const override { return 0; }
  void process(terramap::ProcessContext&, const terramap::Event&) override {}
};
}  // namespace
TERRAMAP_PLUGIN(Misnamed, "something_else", "0.0.1", "type differs from the file name")
