// The soil map (`terramap eval-soil-map`, configs/soil_map.yaml) on a dense strip of each soil
// family: Fig. 12's clay and the loam, sand and gravel strips of configs/scenarios (other
// densities, strip positions, seeds and terrains). Issue #48's goals are |phi bias| <= 3 deg,
// |c bias| <= 5 kPa, the strip's FEE index within 25 % of the truth soil's and AUC >= 0.95 on
// each, and the layers' 1σ coverage within 0.68 ± 0.10; the bounds below hold what the default
// soil map measures (docs/soil_estimator.md "Fits that ran into φ's wall", "Short side windows",
// "Fits as wide as φ's range" and "Fits on c's zero end", one build, 2026-12-02; before: the map
// of 2026-12-01):
//
//   scenario            phi bias   c bias     strip index / truth    AUC    1σ c / φ    (before: phi, c, index, AUC)
//   fig12_dense_strip   +0.4 deg   -2.0 kPa   80.8 / 88.2 kN        0.989  0.64 / 0.70 (-0.4, -1.9, 74.3, 0.928)
//   soil_strip_loam     -1.5 deg   +1.0 kPa   54.8 / 53.5 kN        0.995  0.73 / 0.70 (-1.3, +1.1, 54.8, 0.982)
//   soil_strip_sand     -1.1 deg   +0.2 kPa    7.5 /  8.5 kN        0.976     - / 0.66 (-1.8, +0.3,  7.3, 0.961)
//   soil_strip_gravel   -1.4 deg   +0.2 kPa    7.5 /  8.4 kN        0.970     - / 0.75 (-2.1, +0.3,  7.2, 0.936)
//
// What got them there: the vertical datum (lidar_fusion survey_datum), the bank reference and
// the carried pile (blade_sweep), soil_fit's slices' cross-section, pile share, gate mixture and
// the window that explains each sweep best, soil_bayes' footprint behind the edge (without it the
// AUCs were 0.872 / 0.993 / 0.922 / 0.913), no fusing of fits whose φ lies within one standard
// deviation of its range's end (soil_fit phi_bound_sd; with 0 Fig. 12 reads 0.928 and fails
// here), the short side windows (short_window_sweeps, for strips shorter than the window) and no
// fusing of fits whose φ is wider than its range (phi_uninformative_sd; with 0 gravel reads
// 0.943 and fails here) and the posterior truncated at c = 0 (soil_fit truncated_covariance; with
// false sand's and gravel's φ coverage read 0.83 / 0.80 and fail here).
// A change that loses one of them fails here.
#include <terramap/io/geotiff.hpp>

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
  double index_share;  ///< the strip's mean index within this share of the truth soil's
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
  // The layers' 1σ covers the truth about as often as a 1σ should (issue #48: 0.68 ± 0.10), over
  // the cells whose truth lies inside the range: at an end of it, as sand's and gravel's c = 0,
  // every estimate the range holds covers the truth whatever its spread (no cell inside).
  for (const char* prop : {"soil_phi", "soil_c"}) {
    const auto& q = soil["properties"][prop];
    if (q["cells_inside"].get<double>() < 0.5 * q["cells"].get<double>()) continue;
    const double cov = q["within_1sigma_inside"].get<double>();
    EXPECT_NEAR(cov, 0.68, 0.10) << s.scenario << " " << prop;
  }
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
  // The strip's index against the truth soil's: map.tif's truth_fee_index (the reference cut
  // on the truth soil) over the strip's cells (truth_soil_zone 0).
  const auto raster = terramap::io::readRaster(d / "map.tif");
  const terramap::io::RasterBand *ti = nullptr, *tz = nullptr;
  for (const auto& b : raster.bands) {
    if (b.description == "truth_fee_index") ti = &b;
    if (b.description == "truth_soil_zone") tz = &b;
  }
  ASSERT_TRUE(ti && tz);
  double sum = 0;
  long n = 0;
  for (long i = 0; i < ti->values.rows(); ++i)
    for (long j = 0; j < ti->values.cols(); ++j)
      if (tz->values(i, j) == 0.0f && std::isfinite(ti->values(i, j))) {
        sum += ti->values(i, j);
        ++n;
      }
  ASSERT_GT(n, 0);
  const double truth = sum / static_cast<double>(n);
  EXPECT_NEAR(strip / truth, 1.0, s.index_share) << s.scenario << ": " << strip << " against " << truth;
}

INSTANTIATE_TEST_SUITE_P(Families, SoilMapStrip,
                         ::testing::Values(Strip{"fig12_dense_strip", 3.0, 5.0, 0.95, 0.25},
                                           Strip{"soil_strip_loam", 3.0, 5.0, 0.95, 0.25},
                                           Strip{"soil_strip_sand", 3.0, 5.0, 0.95, 0.25},
                                           Strip{"soil_strip_gravel", 3.0, 5.0, 0.95, 0.25}),
                         [](const ::testing::TestParamInfo<Strip>& i) { return std::string(i.param.scenario); });

}  // namespace
