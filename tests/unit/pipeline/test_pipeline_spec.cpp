#include <terramap/core/error.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>

#include <gtest/gtest.h>

using namespace terramap;

namespace {
std::string errorOf(const std::string& yaml) {
  try {
    parsePipelineString(yaml, "p.yaml");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}
void expectHas(const std::string& msg, const std::string& part) {
  EXPECT_NE(msg.find(part), std::string::npos) << "expected '" << part << "' in:\n" << msg;
}
}  // namespace

TEST(PipelineSpec, ParsesAFullPipeline) {
  const auto spec = parsePipelineString(R"(
version: 1
map: {resolution: 0.1, size: [100, 80], center: [1.5, -2], tile: 32, sparse: true,
      layers: [elevation, {name: hits, unit: count, fill: 0}]}
threads: 2
source: {type: none}
pipeline:
  - {name: s, type: smooth_filter, params: {sigma_m: 0.2, run_on: [tick], fill_holes: true}}
outputs: {dir: out/x, geotiff: [elevation], png: all}
)",
                                        "p.yaml", "/base");
  EXPECT_DOUBLE_EQ(spec.resolution, 0.1);
  EXPECT_EQ(spec.size.x(), 100);
  EXPECT_EQ(spec.size.y(), 80);
  EXPECT_DOUBLE_EQ(spec.center.x(), 1.5);
  EXPECT_EQ(spec.map_options.tile_size, 32);
  EXPECT_TRUE(spec.map_options.sparse);
  ASSERT_EQ(spec.layers.size(), 2u);
  EXPECT_EQ(spec.layers[1].unit, "count");
  EXPECT_EQ(spec.layers[1].fill, 0.0f);
  EXPECT_EQ(spec.threads, 2);
  ASSERT_EQ(spec.stages.size(), 1u);
  EXPECT_EQ(spec.stages[0].type, "smooth_filter");
  EXPECT_DOUBLE_EQ(std::get<double>(spec.stages[0].params.at("sigma_m").value), 0.2);
  EXPECT_TRUE(std::get<bool>(spec.stages[0].params.at("fill_holes").value));
  EXPECT_EQ(std::get<std::vector<std::string>>(spec.stages[0].params.at("run_on").value)[0], "tick");
  EXPECT_EQ(spec.stages[0].params.at("sigma_m").where, "p.yaml:8:45: pipeline[0].params.sigma_m");
  EXPECT_EQ(spec.outputs.dir, "/base/out/x");
  EXPECT_TRUE(spec.outputs.png_all);
}

TEST(PipelineSpec, CommandLineOverridesSetStageParamsAndNameThemselves) {
  PipelineSpec spec = parsePipelineString(R"(
version: 1
source: {type: none}
pipeline:
  - {name: s, type: smooth_filter, params: {sigma_m: 0.2}}
  - {name: t, type: smooth_filter}
)",
                                          "p.yaml");
  applyParamOverrides(spec, {"s.sigma_m=0.5", "s.run_on=[tick, pose]", "t.fill_holes=true", "t.output_layer='3'",
                             "t.radius_m=2"});
  EXPECT_DOUBLE_EQ(std::get<double>(spec.stages[0].params.at("sigma_m").value), 0.5);
  EXPECT_EQ(spec.stages[0].params.at("sigma_m").where, "--set s.sigma_m=0.5");
  EXPECT_EQ(std::get<std::vector<std::string>>(spec.stages[0].params.at("run_on").value),
            (std::vector<std::string>{"tick", "pose"}));
  EXPECT_TRUE(std::get<bool>(spec.stages[1].params.at("fill_holes").value));
  EXPECT_EQ(std::get<std::string>(spec.stages[1].params.at("output_layer").value), "3");  // quoted: text
  EXPECT_EQ(std::get<long>(spec.stages[1].params.at("radius_m").value), 2);
  // Every malformed override at once, each named.
  try {
    applyParamOverrides(spec, {"s.sigma_m", "sigma_m=1", "u.x=1", "s.x={a: 1}", "s.y=[1,"});
    FAIL() << "no ConfigError";
  } catch (const ConfigError& e) {
    const std::string m = e.what();
    expectHas(m, "--set s.sigma_m: expected STAGE.KEY=VALUE");
    expectHas(m, "--set sigma_m=1: expected STAGE.KEY=VALUE");
    expectHas(m, "--set u.x=1: no stage named 'u' (the pipeline's: s, t)");
    expectHas(m, "--set s.x={a: 1}: the value must be a scalar or a list of scalars");
    expectHas(m, "--set s.y=[1,");
  }
  EXPECT_DOUBLE_EQ(std::get<double>(spec.stages[0].params.at("sigma_m").value), 0.5);  // left as it was
}

TEST(PipelineSpec, UnknownKeyHasLocationPathAndDidYouMean) {
  const auto m = errorOf("version: 1\nmap: {resolution: 0.1, sise: [10, 10]}\npipeline: []\n");
  expectHas(m, "p.yaml:2:24: map.sise: unknown key (did you mean 'size'?)");
}

TEST(PipelineSpec, EveryErrorIsReportedAtOnce) {
  const auto m = errorOf(R"(version: 1
map: {resolution: -1, size: [10], tile: 3}
threads: many
pipelin: []
)");
  expectHas(m, "p.yaml:2:19: map.resolution: must be in [0.0001, 1000] (got -1)");
  expectHas(m, "map.size: must be a list of 2 numbers");
  expectHas(m, "map.tile: must be in [8, 1024] (got 3)");
  expectHas(m, "p.yaml:3:10: threads: must be an integer (got 'many')");
  expectHas(m, "p.yaml:4:1: pipelin: unknown key (did you mean 'pipeline'?)");
  expectHas(m, "pipeline: is required");
}

// Found by fuzz_pipeline_yaml (docs/reliability.md, "Fuzzing"): a key that is not a name
// (empty, a mapping, a list) made yaml-cpp throw YAML::BadConversion out of the parser
// instead of a ConfigError.
TEST(PipelineSpec, KeysThatAreNotNamesAreConfigErrors) {
  expectHas(errorOf(":\n{}"), "p.yaml:1:1: a key must be a name, not empty");  // minimised
  expectHas(errorOf("version: 1\nmap: {resolution: 0.1, [a]: 2}\npipeline: []\n"),
            "p.yaml:2:24: map: a key must be a name, not a list");
  expectHas(errorOf("version: 1\nsource: {type: kitti, {x: 1}: 2}\npipeline: []\n"),
            "p.yaml:2:23: source: a key must be a name, not a mapping");
  expectHas(errorOf("version: 1\npipeline:\n  - {name: a, type: smooth_filter, params: {[1]: 2}}\n"),
            "pipeline[0].params: a key must be a name, not a list");
}

TEST(PipelineSpec, DuplicateStageNamesAreRefused) {
  const auto m = errorOf(R"(version: 1
pipeline:
  - {name: a, type: smooth_filter}
  - {name: a, type: inpaint}
)");
  expectHas(m, "p.yaml:4:12: pipeline[1].name: duplicate stage name 'a' (first used at p.yaml:3:5: pipeline[0])");
}

TEST(PipelineSpec, SyntaxErrorsAndVersion) {
  expectHas(errorOf("version: 1\npipeline: [\n"), "p.yaml:3:1: YAML syntax error");
  expectHas(errorOf("version: 2\npipeline: []\n"), "unsupported pipeline version 2");
  expectHas(errorOf("pipeline: []\n"), "version: is required");
  expectHas(errorOf("- 1\n- 2\n"), "must be a YAML mapping");
  expectHas(errorOf("version: 1\npipeline:\n  - {name: a}\n"), "pipeline[0].type: is required");
  expectHas(errorOf("version: 1\npipeline: []\noutputs: {origin: [1, 2]}\n"),
            "outputs.origin: is only meaningful with outputs.epsg");
}

TEST(PipelineSpec, MissingFileIsAConfigError) {
  EXPECT_THROW(parsePipelineFile("/nonexistent/x.yaml"), ConfigError);
}
