// The plugin description embedded at build time (plugin_schema.hpp): read from the file without
// loading, bound to its build, and telling the same parameters and layers as the loaded code.
#include <terramap/core/error.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/pipeline/plugin_schema.hpp>

#include <gtest/gtest.h>

#include <pipeline/elf_section.hpp>

#include <cstdlib>
#include <filesystem>

using namespace terramap;

namespace {
const std::string kTestDir = TERRAMAP_TEST_PLUGIN_DIR;

std::map<std::string, ParamValue> defaults(const ParamSchema& schema) {
  std::map<std::string, ParamValue> v;
  for (const auto& s : schema)
    if (s.default_value) v[s.name] = *s.default_value;
  return v;
}

std::vector<std::string> names(const std::vector<LayerSpec>& layers) {
  std::vector<std::string> out;
  for (const auto& l : layers) out.push_back(std::string(layerAccessName(l.access)) + " " + l.name);
  return out;
}
}  // namespace

TEST(PluginSchema, ReadFromTheFileWithoutLoadingIt) {
  const PluginFileDescription f = PluginRegistry({kTestDir}).describe("test_probe");
  ASSERT_TRUE(f.description.has_value()) << f.missing;
  const PluginDescription& d = *f.description;
  EXPECT_EQ(d.type, "test_probe");
  EXPECT_EQ(d.build_id, elfBuildId(f.path));
  EXPECT_EQ(d.params.size(), 7u);
  // The output layer is named by output_layer; the input exists only when input_layer is set.
  auto values = defaults(d.params);
  std::string why;
  auto layers = layersFromDescription(d, values, why);
  ASSERT_TRUE(layers) << why;
  EXPECT_EQ(names(*layers), (std::vector<std::string>{"create probe"}));
  values["output_layer"] = std::string("out");
  values["input_layer"] = std::string("in");
  layers = layersFromDescription(d, values, why);
  ASSERT_TRUE(layers) << why;
  EXPECT_EQ(names(*layers), (std::vector<std::string>{"create out", "read in"}));
  // A plugin built with NO_SCHEMA has none.
  EXPECT_FALSE(detail::readElfSection(kTestDir + "/marked_probe_bare.so", TERRAMAP_PLUGIN_SCHEMA_SECTION));
}

TEST(PluginSchema, JsonRoundTripsAndBadTextNamesTheField) {
  const auto d = *PluginRegistry({kTestDir}).describe("test_probe").description;
  const std::string json = descriptionToJson(d);
  EXPECT_EQ(descriptionToJson(descriptionFromJson(json, "x.so")), json);
  const auto refused = [](const std::string& text, const std::string& part) {
    try {
      descriptionFromJson(text, "x.so");
      ADD_FAILURE() << text;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(part), std::string::npos) << e.what();
    }
  };
  refused("{", "x.so: embedded plugin schema: (text): not JSON");
  refused("{\"format\": 2}", ".format: format 2");
  std::string no_type = json;
  no_type.replace(no_type.find("\"type\":\"test_probe\""), 19, "\"typo\":\"test_probe\"");
  refused(no_type, ".type: missing");
  std::string bad_access = json;
  bad_access.replace(bad_access.find("\"access\":\"create\""), 17, "\"access\":\"delete\"");
  refused(bad_access, ".layers[0].access: unknown layer access 'delete'");
}

TEST(PluginSchema, EveryBundledPluginsSchemaAgreesWithItsCode) {
  // What validate reads from the file against what the loaded plugin answers at its defaults:
  // the same schema and the same layers (the probe values where a parameter has none).
  const PluginRegistry reg;
  int checked = 0;
  for (const auto& e : std::filesystem::directory_iterator(PluginRegistry::defaultPluginDir())) {
    if (e.path().extension() != ".so") continue;
    const std::string type = e.path().stem().string();
    const PluginFileDescription f = reg.describe(type);
    ASSERT_TRUE(f.description) << type << ": " << f.missing;
    PluginHandle h = PluginRegistry::createFromFile(f.path, type);
    const ParamSchema schema = h->schema();
    ASSERT_EQ(schema.size(), f.description->params.size()) << type;
    for (size_t i = 0; i < schema.size(); ++i) {
      const ParamSpec &a = schema[i], &b = f.description->params[i];
      EXPECT_TRUE(a.name == b.name && a.type == b.type && a.default_value == b.default_value && a.min == b.min &&
                  a.max == b.max && a.unit == b.unit && a.choices == b.choices && a.list_size == b.list_size)
          << type << "." << a.name;
    }
    Params p(type, schema);
    for (const auto& [k, v] : f.description->probe) p.set(k, v);
    h->configure(p);
    std::string why;
    const auto layers = layersFromDescription(*f.description, p.values(), why);
    ASSERT_TRUE(layers) << type << ": " << why;
    EXPECT_EQ(names(*layers), names(h->layers())) << type;
    ++checked;
  }
  EXPECT_GE(checked, 10);
}

TEST(PluginSchema, LayersThatVaryOtherwiseAreUnknownNotGuessed) {
  PluginDescription d;
  d.params = {param::boolean("extra", false, ""), param::text("out", "o", {}, "")};
  d.probe = {{"extra", false}, {"out", std::string("o")}};
  d.layers.push_back({{{"out", true}, {"_x", false}}, LayerAccess::Create, "m", {}});
  d.layers_vary_with = {"extra"};
  std::string why;
  auto l = layersFromDescription(d, {{"extra", false}, {"out", std::string("a")}}, why);
  ASSERT_TRUE(l);
  EXPECT_EQ(names(*l), (std::vector<std::string>{"create a_x"}));
  EXPECT_FALSE(layersFromDescription(d, {{"extra", true}, {"out", std::string("a")}}, why));
  EXPECT_NE(why.find("depend on 'extra'"), std::string::npos) << why;
  EXPECT_FALSE(layersFromDescription(d, {{"extra", false}}, why));  // out has no value
  // A bool whose other value adds a layer: the layers at that value are described as a variant.
  d.layers_vary_with.clear();
  d.variants.push_back({"extra", true, d.layers});
  d.variants.back().layers.push_back({{{"extra_layer", false}}, LayerAccess::Create, "1", {}});
  l = layersFromDescription(d, {{"extra", true}, {"out", std::string("a")}}, why);
  ASSERT_TRUE(l) << why;
  EXPECT_EQ(names(*l), (std::vector<std::string>{"create a_x", "create extra_layer"}));
  l = layersFromDescription(d, {{"extra", false}, {"out", std::string("a")}}, why);
  ASSERT_TRUE(l) << why;
  EXPECT_EQ(names(*l), (std::vector<std::string>{"create a_x"}));
}
