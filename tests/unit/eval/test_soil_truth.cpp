// The simulator source's soil truth (Source::truth "soil_*", "soil_zone") and the soil section
// of the run report (eval::soilTruthJson): errors, calibration and the FEE index's AUC per zone.
#include <terramap/eval/sim_source.hpp>
#include <terramap/eval/truth_report.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/source.hpp>
#include <terramap/soil/soil_table.hpp>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>

using namespace terramap;
namespace fs = std::filesystem;

namespace {

// `ground` (loam by default) everywhere, a dense clay strip at x in [1, 2].
std::unique_ptr<Source> stripSource(const std::string& ground = "loam") {
  const fs::path dir = fs::path(TERRAMAP_BINARY_DIR) / "test_tmp" / ("soil_truth_" + ground);
  fs::create_directories(dir);
  std::ofstream(dir / "s.yaml") << "version: 1\nseed: 1\nduration_s: 0.1\n"
                                   "terrain: {size_m: [4, 3], origin_m: [-1, -1.5], resolution_m: 0.02}\n"
                                   "soil:\n  default: {family: " << ground << ", relative_density: 0.3}\n"
                                   "  zones:\n    - {name: strip, family: clay, relative_density: 0.8, strip: {axis: x, range_m: [1, 2]}}\n"
                                   "machines:\n  - id: ctl1\n    controller: {type: route, start_m: [0, 0], length_m: 1, passes: 1}\n";
  sim::registerSimSource();
  return makeSource(parsePipelineString("version: 1\nmap: {resolution: 0.1, size: [20, 20]}\nsource: {type: sim, scenario: s.yaml}\n"
                                        "pipeline: []\n",
                                        "p.yaml", dir.string()));
}

TEST(SoilTruth, TheSimulatorSourceGivesTheSoilOfEachCellsZone) {
  const auto src = stripSource();
  const Geometry g(0.1, Size(30, 20), Position(1.0, 0.0));  // x in [-0.5, 2.5]
  Eigen::MatrixXf c(30, 20), zone(30, 20);
  ASSERT_TRUE(src->truth("soil_c", g, c));
  ASSERT_TRUE(src->truth("soil_zone", g, zone));
  const double loam = soil::soilProperties(soil::SoilFamily::Loam, 0.3).fee.c_pa;
  const double clay = soil::soilProperties(soil::SoilFamily::Clay, 0.8).fee.c_pa;
  const Index in_strip = *g.indexAt(Position(1.55, 0.05)), outside = *g.indexAt(Position(0.25, 0.05));
  EXPECT_FLOAT_EQ(c(in_strip.x(), in_strip.y()), static_cast<float>(clay));
  EXPECT_FLOAT_EQ(zone(in_strip.x(), in_strip.y()), 0.0f);
  EXPECT_FLOAT_EQ(c(outside.x(), outside.y()), static_cast<float>(loam));
  EXPECT_FLOAT_EQ(zone(outside.x(), outside.y()), -1.0f);
  EXPECT_FALSE(src->truth("soil_unknown", g, c));
}

TEST(SoilTruth, TheReportGivesErrorsCalibrationAndTheIndexAucPerZone) {
  const auto src = stripSource();
  LayeredMap map(Geometry(0.1, Size(30, 20), Position(1.0, 0.0)));
  Eigen::MatrixXf truth(30, 20), zone(30, 20);
  ASSERT_TRUE(src->truth("soil_zone", map.geometry(), zone));
  const char* names[] = {"soil_c", "soil_phi", "soil_ca", "soil_delta", "soil_gamma"};
  for (const char* n : names) {
    ASSERT_TRUE(src->truth(n, map.geometry(), truth));
    // Estimates in the left half only, off by +1 σ (σ = 10 % of the truth) on every other
    // row and by +3 σ on the rest: half within 1σ and 2σ.
    Eigen::MatrixXf est = Eigen::MatrixXf::Constant(30, 20, NAN), var = est;
    for (int i = 0; i < 30; ++i)
      for (int j = 0; j < 10; ++j) {
        const float sd = 0.1f * truth(i, j);
        est(i, j) = truth(i, j) + (i % 2 ? 0.5f : 3.0f) * sd;
        var(i, j) = sd * sd;
      }
    map.fromMatrix(map.addLayer(n, ""), est);
    map.fromMatrix(map.addLayer(std::string(n) + "_var", ""), var);
  }
  // An index that is higher in the strip except for one cell pair out of order.
  Eigen::MatrixXf idx = Eigen::MatrixXf::Constant(30, 20, NAN);
  for (int i = 0; i < 30; ++i)
    for (int j = 0; j < 10; ++j) idx(i, j) = zone(i, j) >= 0 ? 20e3f + i : 10e3f + i;
  map.fromMatrix(map.addLayer("fee_index", "N"), idx);
  const nlohmann::json j = nlohmann::json::parse(eval::soilTruthJson(map, *src));
  EXPECT_EQ(j["cells_estimated"].get<long>(), 300);
  const auto& c = j["properties"]["soil_c"];
  EXPECT_EQ(c["cells"].get<long>(), 300);
  EXPECT_NEAR(c["within_1sigma"].get<double>(), 0.5, 1e-12);
  EXPECT_NEAR(c["within_2sigma"].get<double>(), 0.5, 1e-12);
  EXPECT_GT(c["bias"].get<double>(), 0.0);
  const auto& zones = j["fee_index"]["zones"];
  ASSERT_EQ(zones.size(), 2u);
  EXPECT_EQ(zones[0]["zone"].get<int>(), -1);
  EXPECT_EQ(zones[1]["zone"].get<int>(), 0);
  EXPECT_DOUBLE_EQ(zones[1]["auc_vs_default"].get<double>(), 1.0);
  EXPECT_GT(zones[1]["mean_index_n"].get<double>(), zones[0]["mean_index_n"].get<double>());
  // No soil layers: no section.
  LayeredMap bare(Geometry(0.1, Size(30, 20), Position(1.0, 0.0)));
  EXPECT_TRUE(eval::soilTruthJson(bare, *src).empty());
}

// Sand (c = 0, the end of c's range) with the clay strip: estimates of c 0.5 kPa +- 1 kPa on the
// sand cover its truth, 3 sd off on the clay do not. Over the map half the truths are covered;
// inside the range (the clay's cells only) none.
TEST(SoilTruth, CoverageInsideTheRangeLeavesTruthsAtItsEndOut) {
  const auto src = stripSource("sand");
  // x in [0.5, 2.5]: 5 rows of sand, 10 of clay, 5 of sand.
  LayeredMap map(Geometry(0.1, Size(20, 20), Position(1.5, 0.0)));
  Eigen::MatrixXf truth(20, 20), zone(20, 20);
  ASSERT_TRUE(src->truth("soil_zone", map.geometry(), zone));
  for (const char* n : {"soil_c", "soil_phi", "soil_ca", "soil_delta", "soil_gamma"}) {
    ASSERT_TRUE(src->truth(n, map.geometry(), truth));
    Eigen::MatrixXf est(20, 20), var = Eigen::MatrixXf::Constant(20, 20, 1e6f);
    for (int i = 0; i < 20; ++i)
      for (int j = 0; j < 20; ++j) est(i, j) = zone(i, j) >= 0 ? truth(i, j) + 3000.0f : truth(i, j) + 500.0f;
    map.fromMatrix(map.addLayer(n, ""), est);
    map.fromMatrix(map.addLayer(std::string(n) + "_var", ""), var);
  }
  const nlohmann::json j = nlohmann::json::parse(eval::soilTruthJson(map, *src));
  const auto& c = j["properties"]["soil_c"];
  ASSERT_EQ(c["cells"].get<long>(), 400);
  EXPECT_NEAR(c["within_1sigma"].get<double>(), 0.5, 1e-12);
  EXPECT_EQ(c["cells_inside"].get<long>(), 200);
  EXPECT_EQ(c["within_1sigma_inside"].get<double>(), 0.0);
  // γ lies inside its range on both soils: the two figures agree.
  const auto& g = j["properties"]["soil_gamma"];
  EXPECT_EQ(g["cells_inside"].get<long>(), 400);
  EXPECT_EQ(g["within_1sigma_inside"].get<double>(), g["within_1sigma"].get<double>());
}

}  // namespace
