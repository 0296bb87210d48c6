// Scenario validation through the shared strict reader (engine/yaml): every mistake of a file
// in one ConfigError, each with file:line:col and key path, as for pipelines.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/sim/scenario.hpp>

#include <algorithm>
#include <string>

using namespace terramap;
using namespace terramap::sim;

namespace {

std::string configErrorOf(const std::string& yaml) {
  try {
    parseScenario(yaml, "s.yaml");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

void expectHas(const std::string& msg, const std::string& part) {
  EXPECT_NE(msg.find(part), std::string::npos) << "expected '" << part << "' in:\n" << msg;
}

std::size_t lines(const std::string& msg) {
  return msg.empty() ? 0 : 1 + static_cast<std::size_t>(std::count(msg.begin(), msg.end(), '\n'));
}

}  // namespace

// Three kinds of mistake in three sections, the first one in the file first: a reader that
// stopped at the first error would report only the terrain's.
TEST(ScenarioErrors, ThreeMistakesAreAllReportedWithLineAndColumn) {
  const std::string e = configErrorOf(R"(version: 1
seed: 3
terrain: {size_m: [4, 4], resolution_m: 0.02, slop: [0, 0]}
machines:
  - id: m1
    blade: {width_m: wide}
    vehicle: {mass_kg: 50}
)");
  expectHas(e, "s.yaml:3:47: terrain.slop: unknown key (did you mean 'slope'?)");
  expectHas(e, "s.yaml:6:22: machines[0].blade.width_m: must be a number (got 'wide')");
  expectHas(e, "s.yaml:7:24: machines[0].vehicle.mass_kg: must be in [100, 1e+06] (got 50)");
  EXPECT_EQ(lines(e), 3u) << e;
}

TEST(ScenarioErrors, ErrorsInListsAndAcrossMachinesAreCollected) {
  const std::string e = configErrorOf(R"(version: 1
terrain: {size_m: [4, 4]}
soil:
  zones:
    - {family: sand, relative_density: 2}
    - {family: cley, relative_density: 0.5}
machines:
  - {id: a, pose: {x_m: 9}}
  - {id: a}
)");
  expectHas(e, "s.yaml:5:40: soil.zones[0].relative_density: must be in [0, 1] (got 2)");
  expectHas(e, "s.yaml:6:16: soil.zones[1].family: unknown soil family 'cley' (did you mean 'clay'?)");
  expectHas(e, "machines[0].pose: machine starts outside the terrain");
  expectHas(e, "s.yaml:9:10: machines[1].id: duplicate machine id 'a'");
  EXPECT_EQ(lines(e), 4u) << e;
}

// A mistyped type leaves its keys unchecked rather than calling each of them unknown.
TEST(ScenarioErrors, UnknownSensorTypeDoesNotCascade) {
  const std::string e = configErrorOf(R"(version: 1
terrain: {size_m: [4, 4]}
machines:
  - id: m1
    sensors: [{id: l, type: lidr, beams: 16}]
)");
  expectHas(e, "s.yaml:5:29: machines[0].sensors[0].type: unknown sensor type 'lidr' (did you mean 'lidar'?)");
  EXPECT_EQ(lines(e), 1u) << e;
}

TEST(ScenarioErrors, AngleRangeIsShownInTheUnitWritten) {
  const std::string e = configErrorOf(R"(version: 1
terrain: {size_m: [4, 4]}
machines: [{id: m1, blade: {rake_deg: 200}}]
)");
  expectHas(e, "s.yaml:3:39: machines[0].blade.rake_deg: must be in [30, 120] (got 200)");
}

// The YAML's own mistakes come first; a DEM that cannot be read is reported (as the InputError
// it is) once the file is otherwise clean.
TEST(ScenarioErrors, UnreadableDemComesAfterTheYamlMistakes) {
  const std::string dem = "terrain: {resolution_m: 0.02, dem: {file: /nonexistent/dem.asc}}\n";
  const std::string e = configErrorOf("version: 1\n" + dem + "machines: [{id: a, speed: 1}]\n");
  expectHas(e, "s.yaml:3:20: machines[0].speed: unknown key");
  EXPECT_EQ(lines(e), 1u) << e;
  try {
    parseScenario("version: 1\n" + dem + "machines: [{id: a}]\n", "s.yaml");
    FAIL() << "an unreadable DEM was accepted";
  } catch (const InputError& err) {
    expectHas(err.what(), "/nonexistent/dem.asc");
  }
}

// One reader: the same mistake reads the same in a pipeline and in a scenario.
// Keys that are not names: the pipeline's parser threw YAML::BadConversion on them
// (fuzz_pipeline_yaml); the scenario's reported an unknown key ''. Both now say what is wrong.
TEST(ScenarioErrors, KeysThatAreNotNamesAreReported) {
  const std::string e = configErrorOf("version: 1\nterrain: {size_m: [4, 4], resolution_m: 0.02}\nmachines:\n  - id: m1\n    {}: 3\n");
  expectHas(e, "s.yaml:5:5: machines[0]: a key must be a name, not a mapping");
}

// Found by fuzz_scenario_yaml: the node count of a terrain too large for the message was
// converted to long long, undefined beyond 9.2e18 (UBSan stopped there; plain builds printed
// -9223372036854775808 nodes).
TEST(ScenarioErrors, HugeTerrainIsRefusedWithItsSizeInScientificNotation) {
  const std::string e = configErrorOf("terrain:\n size_m: [1111111111111111,5]\n");  // minimised
  expectHas(e, "s.yaml:2:2: terrain.size_m: terrain too large: 1.39e+19 nodes");
}

TEST(ScenarioErrors, PipelineAndScenarioWordAMistakeAlike) {
  std::string pipeline_error;
  try {
    parsePipelineString("version: 1\nthreads: many\npipeline: []\n", "p.yaml");
  } catch (const ConfigError& e) {
    pipeline_error = e.what();
  }
  const std::string scenario_error =
      configErrorOf("version: 1\nthreads: many\nterrain: {size_m: [4, 4]}\nmachines: [{id: a}]\n");
  expectHas(pipeline_error, "p.yaml:2:10: threads: must be an integer (got 'many')");
  expectHas(scenario_error, "s.yaml:2:10: threads: must be an integer (got 'many')");
}

// ---- localisation: ---------------------------------------------------------------------------

namespace {
const char* kLocBase = R"(version: 1
terrain: {size_m: [4, 4]}
)";
}  // namespace

TEST(ScenarioLocalisation, AbsentIsRtkImuAndPerfectAndOverridesAreRead) {
  // Absent everywhere: the realistic default.
  Scenario sc = parseScenario(std::string(kLocBase) + "machines: [{id: a}]\n", "s.yaml");
  const LocalisationSpec rtk = LocalisationSpec::rtkImu();
  EXPECT_FALSE(sc.machines[0].localisation.perfect);
  EXPECT_EQ(sc.machines[0].localisation.position[2].white, rtk.position[2].white);
  EXPECT_EQ(sc.machines[0].localisation.latency_s, rtk.latency_s);
  // Scenario-wide perfect reaches a machine without its own key; a machine's own key wins.
  sc = parseScenario(std::string(kLocBase) + "localisation: perfect\nmachines:\n  - {id: a}\n"
                                             "  - {id: b, localisation: {latency_s: 0.05, attitude_white_deg: [0.1, 0.1, 0.5],"
                                             " position_bias_m: [0, 0, 0.03], cylinder_white_m: 0.002}}\n",
                     "s.yaml");
  EXPECT_TRUE(sc.machines[0].localisation.perfect);
  const LocalisationSpec& b = sc.machines[1].localisation;
  EXPECT_FALSE(b.perfect);
  EXPECT_EQ(b.latency_s, 0.05);
  EXPECT_DOUBLE_EQ(b.attitude[2].white, 0.5 * M_PI / 180);
  EXPECT_EQ(b.position[2].bias, 0.03);
  EXPECT_EQ(b.position[0].bias, 0.0);
  EXPECT_EQ(b.cylinder_white_m, 0.002);
  // Keys not given keep rtk_imu's values.
  EXPECT_EQ(b.position[0].white, rtk.position[0].white);
  EXPECT_EQ(b.cylinder_bias_m, rtk.cylinder_bias_m);
  sc = parseScenario(std::string(kLocBase) + "localisation: perfect\nmachines: [{id: a, localisation: rtk_imu}]\n",
                     "s.yaml");
  EXPECT_FALSE(sc.machines[0].localisation.perfect);
}

TEST(ScenarioLocalisation, MistakesNameTheKeyAndValue) {
  std::string e = configErrorOf(std::string(kLocBase) + "machines: [{id: a, localisation: perfekt}]\n");
  expectHas(e, "machines[0].localisation: unknown localisation 'perfekt' (did you mean 'perfect'?)");
  e = configErrorOf(std::string(kLocBase) + "machines: [{id: a, localisation: {position_white_m: [0.01, -0.01, 0.02]}}]\n");
  expectHas(e, "machines[0].localisation.position_white_m: sigmas must be >= 0 and finite (got -0.01 at [1])");
  e = configErrorOf(std::string(kLocBase) + "machines: [{id: a, localisation: {attitude_bias_deg: [0.1, 0.1]}}]\n");
  expectHas(e, "machines[0].localisation.attitude_bias_deg: must be a list of 3 numbers");
  e = configErrorOf(std::string(kLocBase) + "machines: [{id: a, localisation: {latency_s: -0.02}}]\n");
  expectHas(e, "machines[0].localisation.latency_s");
  e = configErrorOf(std::string(kLocBase) + "machines: [{id: a, localisation: {latency: 0.02}}]\n");
  expectHas(e, "machines[0].localisation.latency: unknown key (did you mean 'latency_s'?)");
  e = configErrorOf(std::string(kLocBase) + "localisation: [perfect]\nmachines: [{id: a}]\n");
  expectHas(e, "localisation");
  EXPECT_EQ(lines(e), 1u) << e;
  // The old pose sensor is refused with the way forward, not silently ignored.
  e = configErrorOf(std::string(kLocBase) + "machines: [{id: a, sensors: [{id: gnss, type: pose}]}]\n");
  expectHas(e, "machines[0].sensors[0].type: the 'pose' sensor was replaced by the machine's 'localisation:' key");
}
