// The soil map (`terramap eval-soil-map`, configs/soil_map.yaml) on a dense strip of each soil
// family: Fig. 12's clay and the loam, sand and gravel strips of configs/scenarios (other
// densities, strip positions, seeds and terrains). Issue #48's goals are |phi bias| <= 3 deg,
// |c bias| <= 5 kPa and AUC >= 0.95 on each; the bounds below are what the default soil map
// holds today (docs/soil_estimator.md "A centred window", one build, 2026-11-29):
//
//   scenario            phi bias   c bias     AUC     (soil_pinn, configs/soil_map_pinn.yaml)
//   fig12_dense_strip   -4.0 deg   +2.9 kPa   0.965   (+16.8 deg, -18.7 kPa, 0.968)
//   soil_strip_loam     -2.0 deg   +2.7 kPa   0.801   (+7.3 deg, -3.9 kPa, 0.884)
//   soil_strip_sand     +6.3 deg    0.0 kPa   0.807   (+4.0 deg, +6.6 kPa, 0.694)
//   soil_strip_gravel    0.0 deg   +0.7 kPa   0.883   (-0.5 deg, +5.8 kPa, 0.846)
//
// so a change that loses what the pooled fit and its centred window gained fails here: the
// network's soil map fails the phi bound on Fig. 12 and loam, the c bound on sand and gravel,
// and the AUC bound on sand; the window of the last sweeps (lookahead_sweeps 0) fails the AUC
// bound on Fig. 12, sand and gravel (0.797, 0.666, 0.696).
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <string>

#include "cli_util.hpp"

namespace {

using namespace terramap_test;

struct Strip {
  const char* scenario;
  double phi_bound_deg, c_bound_kpa, auc_min;
};

class SoilMapStrip : public ::testing::TestWithParam<Strip> {};

TEST_P(SoilMapStrip, TheDefaultSoilMapKeepsItsValuesAndSeparatesTheStrip) {
  const Strip& s = GetParam();
  const fs::path d = tempDir(std::string("soil_strip_") + s.scenario);
  const std::string scen = std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/" + s.scenario + ".yaml";
  const Result r = sh("eval-soil-map " + scen + " -q --out " + d.string());
  ASSERT_EQ(r.code, 0) << r.out;
  const auto report = nlohmann::json::parse(std::ifstream(d / "report.json"));
  const auto& soil = report["truth"]["soil"];
  const double phi_bias_deg = soil["properties"]["soil_phi"]["bias"].get<double>() * 180.0 / M_PI;
  const double c_bias_kpa = soil["properties"]["soil_c"]["bias"].get<double>() * 1e-3;
  EXPECT_LE(std::abs(phi_bias_deg), s.phi_bound_deg) << s.scenario;
  EXPECT_LE(std::abs(c_bias_kpa), s.c_bound_kpa) << s.scenario;
  // Every zone has its bias too (the map's bias can hide opposite ones in and around the strip).
  ASSERT_TRUE(soil["properties_by_zone"].contains("0")) << soil.dump();
  ASSERT_TRUE(soil["properties_by_zone"].contains("-1")) << soil.dump();
  double auc = -1, strip = 0, ground = 0;
  for (const auto& z : soil["fee_index"]["zones"]) {
    if (z["zone"].get<int>() == 0) {
      auc = z["auc_vs_default"].get<double>();
      strip = z["mean_index_n"].get<double>();
    } else {
      ground = z["mean_index_n"].get<double>();
    }
  }
  // Each strip is denser than the ground around it, so its truth index is the higher one.
  EXPECT_GE(auc, s.auc_min) << s.scenario;
  EXPECT_GT(strip, ground) << s.scenario;
}

INSTANTIATE_TEST_SUITE_P(Families, SoilMapStrip,
                         ::testing::Values(Strip{"fig12_dense_strip", 6.0, 5.0, 0.93},
                                           Strip{"soil_strip_loam", 6.0, 5.0, 0.75},
                                           Strip{"soil_strip_sand", 8.0, 5.0, 0.75},
                                           Strip{"soil_strip_gravel", 6.0, 5.0, 0.80}),
                         [](const ::testing::TestParamInfo<Strip>& i) { return std::string(i.param.scenario); });

}  // namespace
