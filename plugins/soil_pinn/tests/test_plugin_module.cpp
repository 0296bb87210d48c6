// The built soil_pinn module loads through the host (its libtorch dependency included) and
// declares its parameters (a required `model` path, the Eq. 7 tolerances, the history
// capacity), Observation and BladePose events and no layers.
#include <terramap/pipeline/plugin_loader.hpp>

#include <gtest/gtest.h>

namespace terramap {
namespace {

TEST(SoilPinnModule, LoadsAndDeclaresItsInterface) {
  const PluginHandle h = PluginRegistry::createFromFile(std::string(TERRAMAP_PLUGIN_DIR) + "/soil_pinn.so", "soil_pinn");
  ASSERT_TRUE(h);
  const ParamSchema schema = h->schema();
  ASSERT_EQ(schema.size(), 4u);
  EXPECT_EQ(schema[0].name, "model");
  EXPECT_EQ(schema[0].type, ParamType::String);
  EXPECT_FALSE(schema[0].default_value.has_value()) << "the model is required";
  EXPECT_EQ(schema[1].name, "nullspace_a_tol");
  EXPECT_EQ(std::get<double>(*schema[1].default_value), 1500.0);
  EXPECT_EQ(schema[2].name, "nullspace_r_tol");
  EXPECT_EQ(std::get<double>(*schema[2].default_value), 0.05);
  EXPECT_EQ(schema[3].name, "history_capacity");
  EXPECT_EQ(h->events(), EventKind::Observation | EventKind::BladePose);
  EXPECT_TRUE(h->layers().empty());
}

}  // namespace
}  // namespace terramap
