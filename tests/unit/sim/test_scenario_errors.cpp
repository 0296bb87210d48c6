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
