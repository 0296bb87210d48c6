// `terramap validate` runs no plugin code, not even of plugins in folders the user trusts: it
// checks each stage against the schema embedded in the plugin file at build time. The libraries
// here record, through a constructor, that their code ran (tests/plugins/load_marker.cpp).
#include "cli_util.hpp"

#include <gtest/gtest.h>

#include <cstdlib>
#include <string>

using namespace terramap_test;

namespace {

const std::string kTestPlugins = std::string(TERRAMAP_BINARY_DIR) + "/test_plugins";

/// A folder holding `library` (a test plugin) as test_probe.so, a pipeline `p.yaml` of
/// `stages` (YAML list items) over it, and the marker file path its constructor would create.
struct PluginFolder {
  fs::path dir, yaml, mark;
  std::string env;
  PluginFolder(const std::string& name, const std::string& library, const std::string& stages) {
    dir = tempDir(name);
    fs::create_directories(dir / "plugins");
    fs::copy_file(kTestPlugins + "/" + library + ".so", dir / "plugins" / "test_probe.so");
    yaml = dir / "p.yaml";
    write(yaml, "version: 1\nmap: {resolution: 0.5, size: [8, 8], tile: 8}\npipeline:\n" + stages +
                    "source: {type: none}\noutputs: {dir: out, png: [], snapshot: false, report: false}\n");
    mark = dir / "code_ran";
    env = "TERRAMAP_TEST_MARK_FILE=" + mark.string() + " ";
  }
  Result validate(const std::string& extra = "") const {
    return sh("validate " + yaml.string() + " --plugin-path " + (dir / "plugins").string() + " " + extra, env);
  }
};

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

}  // namespace

TEST(ValidateNoLoad, APluginInATrustedFolderIsCheckedWithoutRunningItsCode) {
  const PluginFolder s("novalidate_code", "marked_probe", "  - {name: p, type: test_probe, params: {increment: 2}}\n");
  const Result r = s.validate();
  EXPECT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(contains(r.out, "valid (1 stages")) << r.out;
  EXPECT_FALSE(fs::exists(s.mark)) << "validate ran the plugin's code:\n" << r.out;
  // The marker does show a load: the explicit switch loads the plugin (and says nothing unchecked).
  const Result loaded = s.validate("--load-plugins");
  EXPECT_EQ(loaded.code, 0) << loaded.out;
  EXPECT_TRUE(fs::exists(s.mark)) << "--load-plugins did not load the plugin";
  EXPECT_FALSE(contains(loaded.out, "warning:")) << loaded.out;
  fs::remove_all(s.dir);
}

TEST(ValidateNoLoad, TheEmbeddedSchemaCatchesBadValuesUnknownParametersAndLayers) {
  const PluginFolder s("novalidate_schema", "marked_probe",
                "  - {name: p, type: test_probe, params: {increment: 1e9, incremnt: 2}}\n"
                "  - {name: q, type: test_probe, params: {output_layer: q, input_layer: probee}}\n"
                "  - {name: r, type: test_probe, params: {output_layer: r, input_layer: q, records: maybe}}\n");
  const Result r = s.validate();
  EXPECT_EQ(r.code, 8) << r.out;
  EXPECT_TRUE(contains(r.out, "p.yaml:4:42: pipeline[0].params.increment: must be in [-1e+06, 1e+06] (got 1e+09)"))
      << r.out;
  EXPECT_TRUE(contains(r.out, "p.yaml:4:58: pipeline[0].params.incremnt: unknown parameter 'incremnt' for plugin "
                              "'test_probe' (did you mean 'increment'?)"))
      << r.out;
  // Layer names come from the parameters through the schema: p creates 'probe' (its default,
  // though its values are wrong), q reads 'probee', which nobody creates.
  EXPECT_TRUE(contains(r.out, "stage 'q' reads layer 'probee' before any stage creates it (did you mean 'probe'?)"))
      << r.out;
  EXPECT_TRUE(contains(r.out, "p.yaml:6:75: pipeline[2].params.records: must be a bool (got 'maybe')")) << r.out;
  EXPECT_FALSE(contains(r.out, "stage 'r' reads")) << r.out;  // q creates q: no follow-on error
  EXPECT_TRUE(contains(r.out, "invalid (4 problems)")) << r.out;
  EXPECT_FALSE(fs::exists(s.mark)) << "validate ran the plugin's code";
  fs::remove_all(s.dir);
}

TEST(ValidateNoLoad, AnOptionalInputLayerFollowsItsParameter) {
  // test_probe reads `input_layer` only when it is not empty: the schema says so.
  const PluginFolder s("novalidate_optional", "marked_probe",
                "  - {name: p, type: test_probe, params: {input_layer: ''}}\n"
                "  - {name: q, type: test_probe, params: {output_layer: q, input_layer: nowhere}}\n");
  const Result r = s.validate();
  EXPECT_EQ(r.code, 8) << r.out;
  EXPECT_FALSE(contains(r.out, "stage 'p' reads")) << r.out;
  EXPECT_TRUE(contains(r.out, "stage 'q' reads layer 'nowhere' before any stage creates it")) << r.out;
  EXPECT_TRUE(contains(r.out, "invalid (1 problem)")) << r.out;
  EXPECT_FALSE(fs::exists(s.mark));
  fs::remove_all(s.dir);
}

TEST(ValidateNoLoad, APluginWithoutAnEmbeddedSchemaIsNotLoadedAndTheSwitchIsNamed) {
  const PluginFolder s("novalidate_bare", "marked_probe_bare",
                "  - {name: p, type: test_probe, params: {increment: 1e9}}\n"
                "  - {name: q, type: test_probe, params: {output_layer: q, input_layer: nowhere}}\n");
  const Result r = s.validate();
  EXPECT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(contains(r.out, "warning: " + s.yaml.string() + ":4:21: pipeline[0].type: stage 'p': parameters and "
                              "layers not checked"))
      << r.out;
  EXPECT_TRUE(contains(r.out, "no embedded schema")) << r.out;
  EXPECT_TRUE(contains(r.out, "pass --load-plugins if you trust it")) << r.out;
  EXPECT_TRUE(contains(r.out, "valid (2 stages, source 'none'; 2 not checked, see the warnings)")) << r.out;
  EXPECT_FALSE(fs::exists(s.mark)) << "validate loaded a plugin that has no schema";
  // Loaded on the user's word, it is checked as before.
  const Result loaded = s.validate("--load-plugins");
  EXPECT_EQ(loaded.code, 8) << loaded.out;
  EXPECT_TRUE(contains(loaded.out, "pipeline[0].params.increment: must be in [-1e+06, 1e+06]")) << loaded.out;
  EXPECT_TRUE(fs::exists(s.mark));
  fs::remove_all(s.dir);
}

TEST(ValidateNoLoad, ASchemaCopiedFromAnotherBuildIsNotBelieved) {
  // test_probe.so's schema put into the schema-less build of the same source: the build-ids differ.
  if (std::system("objcopy --version >/dev/null 2>&1") != 0) GTEST_SKIP() << "no objcopy";
  const PluginFolder s("novalidate_forged", "marked_probe_bare", "  - {name: p, type: test_probe, params: {increment: 1e9}}\n");
  const fs::path lib = s.dir / "plugins" / "test_probe.so", json = s.dir / "schema.json";
  ASSERT_EQ(std::system(("objcopy --dump-section .terramap_schema=" + json.string() + " " + kTestPlugins +
                         "/test_probe.so " + (s.dir / "scratch.so").string())
                            .c_str()),
            0);
  ASSERT_EQ(std::system(("objcopy --add-section .terramap_schema=" + json.string() + " " + lib.string()).c_str()), 0);
  const Result r = s.validate();
  EXPECT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(contains(r.out, "its embedded schema was made for another build (build-id ")) << r.out;
  EXPECT_FALSE(contains(r.out, "must be in")) << r.out;
  EXPECT_FALSE(fs::exists(s.mark));
  fs::remove_all(s.dir);
}

TEST(ValidateNoLoad, ATypoInThePluginTypeIsAnsweredFromTheFiles) {
  const PluginFolder s("novalidate_typo", "marked_probe", "  - {name: p, type: test_prob}\n");
  const Result r = s.validate();
  EXPECT_EQ(r.code, 8) << r.out;
  EXPECT_TRUE(contains(r.out, "unknown plugin type 'test_prob' (did you mean 'test_probe'?)")) << r.out;
  EXPECT_FALSE(fs::exists(s.mark));
  fs::remove_all(s.dir);
}

TEST(ValidateNoLoad, ThePluginListSaysWhichPluginsValidateCanCheck) {
  const PluginFolder s("novalidate_list", "marked_probe_bare", "  - {name: p, type: test_probe}\n");
  const Result r = sh("plugins --path " + (s.dir / "plugins").string());
  EXPECT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(contains(r.out, "    schema: none: it has no embedded schema")) << r.out;
  EXPECT_TRUE(contains(r.out, "smooth_filter.so\n    schema: embedded (validate checks it without loading it)")) << r.out;
  fs::remove_all(s.dir);
}
