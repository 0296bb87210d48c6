// The built soil_pinn module loads through the host (its libtorch dependency included) and
// declares what the skeleton promises: a `model` path parameter, Observation and BladePose
// events, no layers.
#include <terramap/pipeline/plugin_loader.hpp>

#include <gtest/gtest.h>

namespace terramap {
namespace {

TEST(SoilPinnModule, LoadsAndDeclaresItsSkeleton) {
  const PluginHandle h = PluginRegistry::createFromFile(std::string(TERRAMAP_PLUGIN_DIR) + "/soil_pinn.so", "soil_pinn");
  ASSERT_TRUE(h);
  const ParamSchema schema = h->schema();
  ASSERT_EQ(schema.size(), 1u);
  EXPECT_EQ(schema[0].name, "model");
  EXPECT_EQ(schema[0].type, ParamType::String);
  EXPECT_EQ(h->events(), EventKind::Observation | EventKind::BladePose);
  EXPECT_TRUE(h->layers().empty());
}

}  // namespace
}  // namespace terramap
