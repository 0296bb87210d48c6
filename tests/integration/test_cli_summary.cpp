// End-to-end: what `terramap run` tells its user on the terminal when it ends.
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "cli_util.hpp"

namespace fs = std::filesystem;
using namespace terramap_test;

namespace {

/// The repository's PLY pair fused into a 10 m map with a 20 m range gate, so points are
/// dropped for several reasons, and a declared layer no stage writes (`survey`).
fs::path writeDropRun(const std::string& name) {
  const fs::path d = tempDir(name);
  write(d / "p.yaml", R"(version: 1
map: {resolution: 0.1, size: [100, 100], center: [0, 0], tile: 32, layers: [{name: survey, unit: m}]}
threads: 1
source: {type: sequence, clouds: )" + std::string(TERRAMAP_DATA_DIR) + R"(/gicp_pair, extensions: [.ply]}
pipeline:
  - {name: lidar, type: lidar_fusion, params: {sensor_noise: range_based, max_range_m: 20}}
outputs: {dir: out, geotiff: [elevation, survey], png: [elevation]}
)");
  return d;
}

/// The summary line of stage `name`.
std::string stageLine(const std::string& out, const std::string& name) {
  std::istringstream in(out);
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("  " + name + " ", 0) == 0) return line;
  return {};
}

}  // namespace

TEST(CliSummary, PrintsEachStagesDropsByReasonWithTheirShare) {
  const fs::path d = writeDropRun("summary_drops");
  const Result r = sh("run " + (d / "p.yaml").string());
  ASSERT_EQ(r.code, 0) << r.out;
  const auto report = nlohmann::json::parse(std::ifstream(d / "out" / "report.json"));
  const auto& dropped = report["stages"][0]["dropped"];
  // Not vacuous: the map and the range gate each drop points.
  ASSERT_GT(dropped["outside_map"].get<long>(), 0) << dropped;
  ASSERT_GT(dropped["too_far"].get<long>(), 0) << dropped;
  long total = 0;
  for (const auto& [reason, n] : dropped.items()) total += n.get<long>();

  const std::string line = stageLine(r.out, "lidar");
  ASSERT_FALSE(line.empty()) << r.out;
  EXPECT_NE(line.find("dropped " + std::to_string(total) + " ("), std::string::npos) << line;
  // Every reason of report.json with its count and its share of the stage's drops.
  for (const auto& [reason, n] : dropped.items()) {
    if (n.get<long>() == 0) continue;
    char share[32];
    std::snprintf(share, sizeof share, "%.1f %%", 100.0 * n.get<double>() / static_cast<double>(total));
    EXPECT_NE(line.find(reason + " " + std::to_string(n.get<long>()) + " = " + share), std::string::npos)
        << reason << " in: " << line;
  }
  // Largest first: the reason that explains most of the drops is read first.
  EXPECT_NE(line.find("(outside_map "), std::string::npos) << line;
}

TEST(CliSummary, AnOutputLayerWithoutOneKnownCellIsAWarningNamingIt) {
  const fs::path d = writeDropRun("summary_unknown");
  for (const std::string flags : {"", " --quiet"}) {
    const Result r = sh("run " + (d / "p.yaml").string() + flags);
    ASSERT_EQ(r.code, 0) << r.out;
    EXPECT_NE(r.out.find("warning: output layer 'survey' is entirely unknown"), std::string::npos) << flags << r.out;
    // The fused layer has known cells: no warning for it.
    EXPECT_EQ(r.out.find("output layer 'elevation'"), std::string::npos) << r.out;
  }
  const auto report = nlohmann::json::parse(std::ifstream(d / "out" / "report.json"));
  ASSERT_TRUE(report.contains("warnings")) << report.dump();
  ASSERT_EQ(report["warnings"].size(), 1u);
  EXPECT_EQ(report["warnings"][0]["layer"], "survey");
  EXPECT_EQ(report["warnings"][0]["kind"], "layer_all_unknown");

  // A layer a stage fills is not reported: the same run with `survey` left out of the outputs.
  write(d / "p.yaml", [&] {
    std::ifstream in(d / "p.yaml");
    std::string s((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    return s.replace(s.find("geotiff: [elevation, survey]"), 28, "geotiff: [elevation]");
  }());
  const Result clean = sh("run " + (d / "p.yaml").string());
  ASSERT_EQ(clean.code, 0) << clean.out;
  EXPECT_EQ(clean.out.find("warning:"), std::string::npos) << clean.out;
}
