// End-to-end: the pictures `terramap run` writes compare and name what they show.
#include <terramap/eval/sim_source.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/source.hpp>

#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "cli_util.hpp"

namespace fs = std::filesystem;
using namespace terramap_test;

TEST(RunPictures, ATruthAndItsEstimateShareOneColourRange) {
  // Two flat layers, 1 m and 2 m: alone each range is degenerate (mid colour for both); shared,
  // the estimate sits at the bottom of the ramp and the truth at its top.
  const fs::path d = tempDir("pictures_shared");
  write(d / "p.yaml", "version: 1\n"
                      "map: {resolution: 0.5, size: [24, 20], tile: 16, layers: [{name: elevation, unit: m, fill: 1.0},\n"
                      "                                                        {name: truth_elevation, unit: m, fill: 2.0}]}\n"
                      "source: {type: none}\n"
                      "pipeline:\n"
                      "  - {name: s, type: smooth_filter, params: {run_on: []}}\n"
                      "outputs: {dir: out, png: [elevation, truth_elevation]}\n");
  const Result r = sh("run " + (d / "p.yaml").string() + " -q");
  ASSERT_EQ(r.code, 0) << r.out;
  const auto est = terramap::io::readRaster(d / "out" / "elevation.png");
  const auto tru = terramap::io::readRaster(d / "out" / "truth_elevation.png");
  ASSERT_EQ(est.bands.size(), 4u);
  ASSERT_EQ(est.width, tru.width);
  ASSERT_EQ(est.height, tru.height);
  // A pixel inside the map (the map takes most of the picture's width left of the colour bar).
  const int row = est.height / 2, col = est.width / 3;
  auto rgb = [&](const terramap::io::Raster& img) {
    return std::vector<float>{img.bands[0].values(row, col), img.bands[1].values(row, col), img.bands[2].values(row, col)};
  };
  const auto e = rgb(est), t = rgb(tru);
  // Viridis, hillshaded alike: the low end is blue over green, the high end red and green over blue.
  EXPECT_GT(e[2], e[1]) << "estimate not at the low end of the shared range";
  EXPECT_GT(t[0], t[2]) << "truth not at the high end of the shared range";
  EXPECT_GT(t[1], e[1] + 50);
}

TEST(RunPictures, TheSimulatorNamesItsSoilZonesForTheZoneLegend) {
  terramap::sim::registerSimSource();
  const std::string scen = std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/fig12_dense_strip.yaml";
  const auto spec = terramap::parsePipelineString("version: 1\nmap: {resolution: 0.5, size: [10, 10]}\n"
                                                  "source: {type: sim, scenario: " + scen + ", max_time_s: 0.1}\n"
                                                  "pipeline: []\n");
  const auto src = terramap::makeSource(spec);
  const std::vector<std::pair<int, std::string>> want{{-1, "default soil (clay, I_d 0.10)"}, {0, "dense_strip (clay, I_d 0.80)"}};
  EXPECT_EQ(terramap::sim::simSoilZoneNames(*src), want);
  // Any other source has none.
  const auto none = terramap::makeSource(terramap::parsePipelineString(
      "version: 1\nmap: {resolution: 0.5, size: [10, 10]}\nsource: {type: none}\npipeline: []\n"));
  EXPECT_TRUE(terramap::sim::simSoilZoneNames(*none).empty());
}
