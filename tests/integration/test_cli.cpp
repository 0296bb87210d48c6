// End-to-end: the `terramap` binary as a user runs it.
#include <terramap/io/geotiff.hpp>
#include <terramap/io/snapshot.hpp>
#include <terramap/plugin/abi.hpp>
#include <terramap/sim/episode.hpp>
#include <terramap/sim/scenario.hpp>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>

#include "cli_util.hpp"
#include "kitti_data.hpp"

namespace fs = std::filesystem;
using namespace terramap_test;

TEST(Cli, HelpEverywhere) {
  for (const char* sub : {"", "run", "validate", "plugins", "export", "fee", "sim", "eval", "dataset", "train", "eval-soil",
                          "eval-soil-map", "eval-strata", "path-compare"}) {
    const Result r = sh(std::string(sub) + " --help");
    EXPECT_EQ(r.code, 0) << sub << "\n" << r.out;
    EXPECT_NE(r.out.find("Usage"), std::string::npos) << sub;
  }
  EXPECT_EQ(sh("no_such_command").code, 2);
}

TEST(Cli, ValidatePrintsEveryErrorAndExitsNonZero) {
  const fs::path d = tempDir("validate");
  write(d / "bad.yaml", R"(version: 1
map: {resolution: 0.1, size: [20, 20], tile: 16}
pipeline:
  - {name: t, type: smooth_filter, params: {sigma_m: 0.1, input_layer: elevation}}
  - {name: u, type: inpaint, params: {max_distance_m: -5}}
  - {name: v, type: smooth_filter, params: {sigma: 1, input_layer: t_out}}
  - {name: s, type: smooth_filtr}
)");
  // The unknown type comes last: after it nobody knows which layers exist, so "reads layer X
  // before any stage creates it" is no longer reported for later stages (no follow-on noise).
  const Result r = sh("validate " + (d / "bad.yaml").string());
  EXPECT_EQ(r.code, 8) << r.out;
  EXPECT_NE(r.out.find("bad.yaml:7:21: pipeline[3].type: unknown plugin type 'smooth_filtr' (did you mean "
                       "'smooth_filter'?)"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("bad.yaml:6:45: pipeline[2].params.sigma: unknown parameter 'sigma' for plugin "
                       "'smooth_filter' (did you mean 'sigma_m'?)"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("stage 't' reads layer 'elevation' before any stage creates it"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("pipeline[1].params.max_distance_m: must be in [-1, 10000] (got -5)"), std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("invalid (4 problems)"), std::string::npos) << r.out;

  write(d / "good.yaml", R"(version: 1
map: {resolution: 0.1, size: [20, 20], tile: 16, layers: [{name: elevation, unit: m, fill: 0}]}
pipeline:
  - {name: t, type: smooth_filter, params: {sigma_m: 0.1}}
)");
  const Result ok = sh("validate " + (d / "good.yaml").string());
  EXPECT_EQ(ok.code, 0) << ok.out;
  // With the override run --set would apply: checked the same way, named in the message.
  const Result set_bad = sh("validate " + (d / "good.yaml").string() + " --set t.sigma_m=-1");
  EXPECT_EQ(set_bad.code, 8) << set_bad.out;
  EXPECT_NE(set_bad.out.find("--set t.sigma_m=-1"), std::string::npos) << set_bad.out;
  EXPECT_EQ(sh("validate " + (d / "good.yaml").string() + " --set t.sigma_m=0.3").code, 0);
  EXPECT_EQ(sh("validate " + (d / "missing.yaml").string()).code, 8);
}

/// A 24 x 20 map of elevation 2.5 and one smooth_filter stage `s` that runs once at the end,
/// written to dir/p.yaml; `outputs` is its outputs: mapping.
static void writeSmoothRun(const fs::path& dir, int threads, const std::string& outputs) {
  write(dir / "p.yaml", "version: 1\n"
                        "map: {resolution: 0.5, size: [24, 20], tile: 16, layers: [{name: elevation, unit: m, fill: 2.5}]}\n"
                        "threads: " + std::to_string(threads) + "\n"
                        "source: {type: none}\n"
                        "pipeline:\n"
                        "  - {name: s, type: smooth_filter, params: {run_on: []}}\n"
                        "outputs: " + outputs + "\n");
}

TEST(Cli, RunWritesOutputsAndExportReadsTheSnapshot) {
  const fs::path d = tempDir("run");
  writeSmoothRun(d, 2, "{dir: out, geotiff: [elevation, elevation_smooth], png: all}");
  const Result r = sh("run " + (d / "p.yaml").string());
  ASSERT_EQ(r.code, 0) << r.out;
  const fs::path out = d / "out";
  for (const char* f : {"map.tif", "elevation.png", "elevation_smooth.png", "map.tmap", "report.json"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  const auto raster = terramap::io::readRaster(out / "map.tif");
  EXPECT_EQ(raster.driver, "GTiff");
  ASSERT_EQ(raster.bands.size(), 2u);
  EXPECT_EQ(raster.width, 24);  // columns = map rows (x), north up
  EXPECT_EQ(raster.height, 20);
  EXPECT_FLOAT_EQ(raster.bands[1].values(10, 10), 2.5f);
  const auto report = nlohmann::json::parse(std::ifstream(out / "report.json"));
  EXPECT_EQ(report["stages"][0]["type"], "smooth_filter");
  EXPECT_EQ(report["stages"][0]["counters"]["passes"], 1.0);

  const Result ex = sh("export " + (out / "map.tmap").string() + " --layer elevation_smooth --format png --out " +
                       (d / "e.png").string());
  EXPECT_EQ(ex.code, 0) << ex.out;
  EXPECT_TRUE(fs::exists(d / "e.png"));
  const Result ex2 = sh("export " + (out / "map.tmap").string() + " --layer elevaton --format geotiff --out " +
                        (d / "e.tif").string());
  EXPECT_EQ(ex2.code, 6) << ex2.out;  // layer error
  EXPECT_NE(ex2.out.find("did you mean 'elevation'"), std::string::npos) << ex2.out;
}

TEST(Cli, RunSetsStageParamsFromTheCommandLine) {
  const fs::path d = tempDir("run_set");
  writeSmoothRun(d, 1, "{dir: out, png: all}");
  // The override reaches the plugin: its output layer is renamed.
  const Result r = sh("run " + (d / "p.yaml").string() + " -q --set s.output_layer=smoothed --set s.sigma_m=0.2");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(fs::exists(d / "out" / "smoothed.png"));
  EXPECT_FALSE(fs::exists(d / "out" / "elevation_smooth.png"));
  // A value the plugin refuses: a configuration error naming the override.
  const Result bad = sh("run " + (d / "p.yaml").string() + " -q --set s.sigma_m=-1");
  EXPECT_EQ(bad.code, 3) << bad.out;
  EXPECT_NE(bad.out.find("--set s.sigma_m=-1"), std::string::npos) << bad.out;
  const Result no_stage = sh("run " + (d / "p.yaml").string() + " -q --set lidar.max_range_m=10");
  EXPECT_EQ(no_stage.code, 3) << no_stage.out;
  EXPECT_NE(no_stage.out.find("no stage named 'lidar'"), std::string::npos) << no_stage.out;
}

TEST(Cli, TheSeriesLastEntryIsTheRunsEndAfterFinish) {
  // test_probe reports a record per event and one more in finish(): the series' last entry
  // must include it (it is taken after finish()), so it matches the report's totals.
  const fs::path d = tempDir("series");
  write(d / "p.yaml", R"(version: 1
map: {resolution: 0.5, size: [8, 8], tile: 8}
plugin_paths: [)" + std::string(TERRAMAP_BINARY_DIR) + R"(/test_plugins]
pipeline:
  - {name: p, type: test_probe, params: {records: true, events: [point_cloud]}}
source: {type: sequence, clouds: )" + std::string(TERRAMAP_DATA_DIR) + R"(/gicp_pair, extensions: [.ply]}
outputs: {dir: out, png: [], snapshot: false, series_interval_s: 0.05}
)");
  const Result r = sh("run " + (d / "p.yaml").string() + " --allow-config-plugin-paths");
  ASSERT_EQ(r.code, 0) << r.out;
  const auto report = nlohmann::json::parse(std::ifstream(d / "out" / "report.json"));
  const auto& series = report["series"];
  ASSERT_FALSE(series.empty());
  EXPECT_EQ(report["stages"][0]["records_total"], 3);  // the pair's two clouds + finish()
  EXPECT_EQ(series.back()["records_total"], report["stages"][0]["records_total"]);
  EXPECT_EQ(series.back()["events"], report["events_total"]);
}

TEST(Cli, ExitCodesPerErrorClass) {
  const fs::path d = tempDir("codes");
  write(d / "syntax.yaml", "version: 1\npipeline: [\n");
  EXPECT_EQ(sh("run " + (d / "syntax.yaml").string()).code, 3);  // config
  // A corrupt snapshot is an input error.
  write(d / "bad.tmap", "TMAPgarbage");
  EXPECT_EQ(sh("export " + (d / "bad.tmap").string() + " --layer a --format png").code, 4);
  write(d / "plug.yaml", R"(version: 1
map: {resolution: 0.5, size: [8, 8], tile: 8}
plugin_paths: [)" + std::string(TERRAMAP_BINARY_DIR) + R"(/test_plugins]
pipeline:
  - {name: p, type: test_probe, params: {throw_on_event: 0, events: [point_cloud]}}
source: {type: sequence, clouds: )" + std::string(TERRAMAP_DATA_DIR) + R"(/gicp_pair, extensions: [.ply], max_frames: 1}
outputs: {dir: out, png: [], snapshot: false, report: false}
)");
  const Result r = sh("run " + (d / "plug.yaml").string() + " --allow-config-plugin-paths");
  EXPECT_EQ(r.code, 5) << r.out;  // plugin
  EXPECT_NE(r.out.find("stage 'p' (test_probe) threw on point_cloud"), std::string::npos) << r.out;
}

TEST(Cli, PluginsListsFoundAndRefused) {
  const Result r = sh(std::string("plugins --path ") + TERRAMAP_BINARY_DIR + "/test_plugins");
  EXPECT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("smooth_filter"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("test_probe"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("ABI version mismatch: expected " + std::to_string(TERRAMAP_PLUGIN_ABI_VERSION) + ", found 99"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("missing symbol 'terramap_plugin_create'"), std::string::npos) << r.out;
  // Plugins built with flags that must match the host's are listed as refused, and the listing
  // survives them (an instrumented one would abort the process inside dlopen()).
  EXPECT_NE(r.out.find("eigen-align-32-32"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("changed the floating-point environment"), std::string::npos) << r.out;
  if (fs::exists(std::string(TERRAMAP_BINARY_DIR) + "/test_plugins/bad_sanitizer.so")) {
    EXPECT_NE(r.out.find("asan-1"), std::string::npos) << r.out;
  }
}

TEST(Cli, PluginsParamsPrintsLayersWithTheirDocs) {
  const Result r = sh(std::string("plugins --params --path ") + TERRAMAP_BINARY_DIR + "/test_plugins");
  EXPECT_EQ(r.code, 0) << r.out;
  // test_probe creates its output layer ('probe' by default) with the doc "probe counter".
  EXPECT_NE(r.out.find("layers (with default parameters):"), std::string::npos) << r.out;
  EXPECT_TRUE(std::regex_search(r.out, std::regex("create +probe +\\[1\\] probe counter"))) << r.out;
}

TEST(Cli, EvalSoilMapComparesTheSoilLayersWithTheTruthZones) {
  // Fig. 12's command on the whole dense-strip scenario (75 s simulated, ~5 s), run from the
  // build folder: the pipeline's model path is relative to the pipeline's folder, not to the
  // working one.
  const fs::path d = tempDir("eval_soil_map");
  const std::string scen = std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/fig12_dense_strip.yaml";
  const Result r = sh("eval-soil-map " + scen + " --out " + d.string());
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("soil_c"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("AUC against the default soil"), std::string::npos) << r.out;
  const auto report = nlohmann::json::parse(std::ifstream(d / "report.json"));
  const auto& soil = report["truth"]["soil"];
  EXPECT_GT(soil["cells_estimated"].get<long>(), 100);
  EXPECT_GT(soil["properties"]["soil_c"]["cells"].get<long>(), 100);
  EXPECT_TRUE(fs::exists(d / "fee_index.png"));
  EXPECT_TRUE(fs::exists(d / "fee_index_vs_truth.png"));
  // The truth's index, cell by cell: the strip's (dense clay) above the loose clay's.
  const auto raster = terramap::io::readRaster(d / "map.tif");
  const terramap::io::RasterBand* t = nullptr;
  for (const auto& b : raster.bands)
    if (b.description == "truth_fee_index") t = &b;
  ASSERT_NE(t, nullptr);
  const auto& gt = *raster.geotransform;
  auto at = [&](double x, double y) {
    return t->values(static_cast<long>((y - gt[3]) / gt[5]), static_cast<long>((x - gt[0]) / gt[1]));
  };
  EXPECT_GT(at(7.5, 0.0), 2.0f * at(3.0, 0.0));  // 88 vs 21 kN
  // The mapped index separates the dense strip from the loose clay (issue #48's goal is
  // AUC >= 0.95, which the default soil map meets since 2026-12-02 at 0.983: the bound here
  // only says the command's report carries a separating index;
  // tests/integration/test_soil_map_strips.cpp holds the goal and the other families).
  double auc = -1;
  for (const auto& z : soil["fee_index"]["zones"])
    if (z["zone"].get<int>() == 0) auc = z["auc_vs_default"].get<double>();
  EXPECT_GE(auc, 0.80);
  // A scenario path that does not exist is a usage error.
  EXPECT_EQ(sh("eval-soil-map /nonexistent.yaml").code, 2);
}

TEST(Cli, EvalTrackSoilAblationTakesTheRutsAwayAndNamesABadModel) {
  // terramap eval --track-soil: the ablation of docs/sim.md "Track–soil interaction". With the
  // default model the truth's tracks compact soil (eval.json's truth mass balance carries it);
  // with `none` nothing is compacted; a misspelt model is a configuration error naming the option.
  const std::string scen = std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/fig10_berm_cut.yaml";
  auto compacted = [&](const std::string& extra) {
    const fs::path d = tempDir("eval_track_soil");
    const Result r = sh("eval " + scen + " --duration 4 -q --out " + d.string() + extra);
    EXPECT_EQ(r.code, 0) << r.out;
    const auto j = nlohmann::json::parse(std::ifstream(d / "eval.json"));
    EXPECT_LT(std::abs(j["mass"]["truth_residual_m3"].get<double>()), 1e-9);
    return j["mass"]["truth_compacted_m3"].get<double>();
  };
  EXPECT_GT(compacted(""), 0.0);
  EXPECT_EQ(compacted(" --track-soil none"), 0.0);
  const Result bad = sh("eval " + scen + " --duration 1 -q --track-soil beker --out " + tempDir("eval_ts_bad").string());
  EXPECT_EQ(bad.code, 3) << bad.out;
  EXPECT_NE(bad.out.find("--track-soil"), std::string::npos) << bad.out;
  EXPECT_NE(bad.out.find("bekker"), std::string::npos) << bad.out;
}

TEST(Cli, EvalStrataComparesTheNextPassForceIndicesAndTheBoundaryWithTheTruth) {
  // The strata's command on the first three passes (35 s) of its scenario.
  const fs::path d = tempDir("eval_strata");
  const std::string scen = std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/strata_loam_over_clay.yaml";
  const Result r = sh("eval-strata " + scen + " --duration 35 --out " + d.string());
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("surface MAE"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("boundary (top of 'clay')"), std::string::npos) << r.out;
  const auto j = nlohmann::json::parse(std::ifstream(d / "eval_strata.json"));
  ASSERT_GE(j["next_pass"]["passes"].size(), 2u) << j.dump(1);
  const auto& first = j["next_pass"]["passes"][0];
  EXPECT_EQ(first["pass"].get<int>(), 2);
  EXPECT_GT(first["surface"]["cells"].get<long>(), 100);
  EXPECT_EQ(first["surface"]["cells"], first["strata"]["cells"]);  // the same cells judged twice
  EXPECT_GT(j["next_pass"]["strata"]["mae_n"].get<double>(), 0.0);
  // The issue's comparison, against the simulator's force: every step the truth blade cut in
  // passes 2-4, judged for both beliefs and for the truth soil on the same steps. The truth soil's
  // FEE on each step's truth geometry is the truth's own draft to ~1 %, which only holds when the
  // step's geometry, force, push direction and time are paired right. On |F| it is 36 % off: the
  // edge's bearing while it descends is in the truth's vertical and in no FEE.
  const auto& force = j["next_pass_force"];
  ASSERT_GE(force["passes"].size(), 2u) << force.dump(1);
  EXPECT_GT(force["surface"]["steps"].get<long>(), 200) << force.dump(1);
  EXPECT_EQ(force["surface"]["steps"], force["strata"]["steps"]);
  EXPECT_EQ(force["surface"]["steps"], force["truth_soil"]["steps"]);
  EXPECT_LT(force["truth_soil"]["relative"].get<double>(), 0.05) << force.dump(1);
  EXPECT_GT(force["surface"]["relative"].get<double>(), force["truth_soil"]["relative"].get<double>()) << force.dump(1);
  EXPECT_TRUE(force.contains("strata_closer_fraction"));
  EXPECT_GT(force["truth_soil_abs_force"]["relative"].get<double>(), 0.2) << force.dump(1);
  EXPECT_TRUE(j["boundary"].contains("columns_cut_through"));
  EXPECT_GT(j["estimator"]["estimates"]["default"].get<long>(), 0);  // the loam is cut from the first pass
  EXPECT_TRUE(j["estimator"]["properties"]["c"].contains("d_prime"));
  for (const char* f : {"strata.ot", "strata_octovis.ot", "section_c.png", "map.tif"}) EXPECT_TRUE(fs::exists(d / f)) << f;
  // A pipeline without an octomap_strata stage is a configuration error naming what is missing.
  const Result bad = sh("eval-strata " + scen + " --pipeline " + std::string(TERRAMAP_SOURCE_DIR) + "/configs/soil_map.yaml --out " +
                        d.string());
  EXPECT_EQ(bad.code, 3) << bad.out;
  EXPECT_NE(bad.out.find("octomap_strata"), std::string::npos) << bad.out;
}

TEST(Cli, EvalStrataWithSoilPinnFindsTheClaysTopWithinAVoxelInFourColumnsOfFive) {
  // Issue #48's strata goal on the whole scenario with the committed model: the boundary's depth
  // within one voxel in >= 80 % of the columns cut through it. configs/strata.yaml seeks the
  // change in c, the one property soil_pinn can tell; in all five (the plugin's default) the other
  // four's noise splits the columns a voxel or two high (69.3 % on 2026-12-02).
  const fs::path d = tempDir("eval_strata_boundary");
  const std::string scen = std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/strata_loam_over_clay.yaml";
  const Result r = sh("eval-strata " + scen + " --boundary-only -q --out " + d.string());
  ASSERT_EQ(r.code, 0) << r.out;
  const auto j = nlohmann::json::parse(std::ifstream(d / "eval_strata.json"));
  const auto& depth = j["boundary"]["depth"];
  EXPECT_GT(j["boundary"]["columns_cut_through"].get<long>(), 1000) << j["boundary"].dump(1);
  EXPECT_GE(depth["fraction_within"].get<double>(), 0.80) << j["boundary"].dump(1);
  const Result all = sh("eval-strata " + scen + " --boundary-only -q --set strata.change_properties=[c,phi,ca,delta,gamma] --out " +
                        d.string());
  ASSERT_EQ(all.code, 0) << all.out;
  const auto ja = nlohmann::json::parse(std::ifstream(d / "eval_strata.json"));
  EXPECT_LT(ja["boundary"]["depth"]["fraction_within"].get<double>(), 0.75) << ja["boundary"].dump(1);
  // Each estimate is listed beside the truth it was judged by (sweep, t1, class, truth c, c, sd).
  ASSERT_FALSE(j["estimator"]["records"].empty());
  EXPECT_EQ(j["estimator"]["records"][0].size(), 6u);
}

TEST(Cli, EvalStrataWithTheOracleFeedsTheTruthSoilToTheStrata) {
  // --oracle-noise 0: soil_oracle replaces soil_pinn and publishes the soil the truth blade cut,
  // so the estimates the command prints for the loam are the loam's, but for the few sweeps that
  // also cut the clay (soil_pinn's are 30 % off).
  const fs::path d = tempDir("eval_strata_oracle");
  const std::string scen = std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/strata_loam_over_clay.yaml";
  const Result r = sh("eval-strata " + scen + " --duration 25 --boundary-only --oracle-noise 0 --localisation perfect --out " +
                      d.string());
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("replaced by soil_oracle"), std::string::npos) << r.out;
  EXPECT_TRUE(fs::exists(d / "oracle_soil.json"));
  const auto j = nlohmann::json::parse(std::ifstream(d / "eval_strata.json"));
  EXPECT_EQ(j["oracle_noise"].get<double>(), 0.0);
  EXPECT_TRUE(j["boundary"]["depth"].contains("fraction_within")) << j["boundary"].dump(1);
  const auto& c = j["estimator"]["properties"]["c"];
  ASSERT_GT(j["estimator"]["estimates"]["default"].get<long>(), 10) << j["estimator"].dump(1);
  EXPECT_NEAR(c["mean"][0].get<double>(), c["truth"][0].get<double>(), 0.05 * c["truth"][0].get<double>()) << c.dump();
  // The FEE index of the estimates (the strength the force tells) is the loam's index alike.
  const auto& index = j["estimator"]["properties"]["fee_index"];
  EXPECT_NEAR(index["mean"][0].get<double>(), index["truth"][0].get<double>(), 0.05 * index["truth"][0].get<double>()) << index.dump();
  EXPECT_GT(index["truth"][1].get<double>(), 2 * index["truth"][0].get<double>()) << index.dump();  // clay: 55.9 kN, loam 16.1
  const auto report = nlohmann::json::parse(std::ifstream(d / "report.json"));
  bool oracle = false;
  for (const auto& st : report["stages"]) oracle = oracle || st["type"] == "soil_oracle";
  EXPECT_TRUE(oracle);
  // Noise of 0.5 x the soils' difference: the loam's estimates scatter by about that much.
  const Result noisy = sh("eval-strata " + scen + " --duration 25 --boundary-only -q --oracle-noise 0.5 --out " + d.string());
  ASSERT_EQ(noisy.code, 0) << noisy.out;
  const auto jn = nlohmann::json::parse(std::ifstream(d / "eval_strata.json"));
  const double diff = std::abs(c["truth"][1].get<double>() - c["truth"][0].get<double>());
  EXPECT_NEAR(jn["estimator"]["properties"]["c"]["sd"][0].get<double>(), 0.5 * diff, 0.25 * diff) << jn["estimator"].dump(1);
  const Result bad = sh("eval-strata " + scen + " --duration 5 -q --localisation exact --out " + d.string());
  EXPECT_EQ(bad.code, 3) << bad.out;
  EXPECT_NE(bad.out.find("--localisation"), std::string::npos) << bad.out;
  // The oracle replaces soil_pinn with its parameters: a --set on it would be lost, so it is refused.
  const Result lost = sh("eval-strata " + scen + " --duration 5 -q --oracle-noise 0 --set soil.history_capacity=200 --out " + d.string());
  EXPECT_EQ(lost.code, 3) << lost.out;
  EXPECT_NE(lost.out.find("--set soil.history_capacity=200"), std::string::npos) << lost.out;
}

TEST(Cli, EmbeddedDemoWritesGeoTiffPngAndReport) {
  const fs::path d = tempDir("demo");
  const Result r = sh("run --out " + d.string());
  ASSERT_EQ(r.code, 0) << r.out;
  const auto raster = terramap::io::readRaster(d / "map.tif");
  EXPECT_GE(raster.bands.size(), 1u);
  EXPECT_EQ(raster.bands[0].description, "elevation");
  bool any_png = false;
  for (const auto& e : fs::directory_iterator(d)) any_png = any_png || e.path().extension() == ".png";
  EXPECT_TRUE(any_png);
  const auto report = nlohmann::json::parse(std::ifstream(d / "report.json"));
  EXPECT_GT(report["events_total"].get<long>(), 0);
  EXPECT_GT(report["stages"][0]["counters"]["points_fused"].get<double>(), 0.0);
  // Event seconds per wall second of the whole loop (simulator included), what it says it is.
  ASSERT_TRUE(report.contains("real_time_factor"));
  EXPECT_NEAR(report["real_time_factor"].get<double>(),
              (report["last_stamp"].get<double>() - report["first_stamp"].get<double>()) / report["run_wall_s"].get<double>(),
              1e-9);
  EXPECT_NE(r.out.find("x real time"), std::string::npos) << r.out;
  // The demo's source is the simulator: the run compares the map with its truth.
  ASSERT_TRUE(report.contains("truth")) << report.dump(1);
  EXPECT_GT(report["truth"]["coverage"].get<double>(), 0.9);
  // The whole chain: soil layers and the FEE index as bands and pictures, judged against the
  // simulator's soil (truth.soil).
  std::vector<std::string> bands;
  for (const auto& b : raster.bands) bands.push_back(b.description);
  for (const char* l : {"soil_c", "soil_phi", "fee_index", "fee_index_var", "truth_soil_zone"}) {
    EXPECT_NE(std::find(bands.begin(), bands.end(), l), bands.end()) << l;
  }
  EXPECT_TRUE(fs::exists(d / "fee_index.png"));
  ASSERT_TRUE(report["truth"].contains("soil")) << report["truth"].dump(1);
  EXPECT_GT(report["truth"]["soil"]["cells_estimated"].get<long>(), 1000);
  // With exact poses the fused cells are well inside the LiDAR's 2 cm range noise. The demo's
  // poses come from the realistic (rtk_imu) localisation, so a return's height also carries the
  // pose's vertical error, e_z + r e_tilt at horizontal range r. Its RMS per axis is what the
  // episode of the same scenario logs (estimate/error_base; the estimator's draws do not depend
  // on threads, so they are the demo's). r = 5.1 m is the ground range of the lowest beam
  // (2.1 m / tan 22.5 deg), the nearest returns, which the range-based noise weights most.
  const std::string scen = std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/dense_strip.yaml";
  terramap::sim::EpisodeOptions opt;
  opt.clouds = false;
  const std::string ep = terramap::sim::runEpisode(terramap::sim::loadScenario(scen), (d / "episode").string(), opt);
  std::vector<std::uint64_t> dims;
  const auto err = terramap::sim::readEpisodeDataset(ep, "/machines/ctl1/estimate/error_base", dims);
  ASSERT_EQ(dims.size(), 2u);
  double ms_z = 0, ms_tilt = 0;
  const std::size_t n = dims[0];
  for (std::size_t k = 0; k < n; ++k) {
    ms_z += err[k * 6 + 2] * err[k * 6 + 2] / n;
    ms_tilt += (err[k * 6 + 3] * err[k * 6 + 3] + err[k * 6 + 4] * err[k * 6 + 4]) / n;
  }
  const double r_near = 2.1 / std::tan(22.5 * M_PI / 180);
  EXPECT_LT(report["truth"]["median_abs_m"].get<double>(), 0.02 + std::hypot(std::sqrt(ms_z), r_near * std::sqrt(ms_tilt)));
  EXPECT_TRUE(fs::exists(d / "elevation_error.png"));
  EXPECT_TRUE(fs::exists(d / "truth_elevation.png"));
}

TEST(Cli, KittiPipelineFusesRealFramesAndReportsDrops) {
  TERRAMAP_SKIP_WITHOUT_KITTI();
  const fs::path d = tempDir("kitti");
  const Result r = sh("run " + std::string(TERRAMAP_SOURCE_DIR) + "/configs/kitti.yaml --out " + d.string());
  ASSERT_EQ(r.code, 0) << r.out;
  const auto report = nlohmann::json::parse(std::ifstream(d / "report.json"));
  EXPECT_EQ(report["events"]["point_cloud"], 6);
  const auto& lidar = report["stages"][0];
  // points_in is every point of the six frames, counted here from the files (16 bytes each).
  long in_files = 0;
  for (const auto& e : fs::directory_iterator(terramap::test::kittiDir()))
    if (e.path().extension() == ".bin") in_files += static_cast<long>(fs::file_size(e.path()) / 16);
  ASSERT_GT(in_files, 600000);
  const auto& c = lidar["counters"];
  EXPECT_EQ(static_cast<long>(c["points_in"].get<double>()), in_files);
  // Every point is either fused, counted as an outlier or dropped by a named gate: nothing is
  // lost unaccounted, and each of the three is a real share (the map is 40 m across, the HDL-64E
  // sees 120 m, so points fall outside it and beyond max_range_m).
  long dropped = 0;
  for (const auto& [k, v] : lidar["dropped"].items()) dropped += v.get<long>();
  const long fused = static_cast<long>(c["points_fused"].get<double>()), outliers = static_cast<long>(c["outliers"].get<double>());
  EXPECT_EQ(fused + outliers + dropped, in_files);
  EXPECT_GT(lidar["dropped"]["outside_map"].get<long>(), 0);
  EXPECT_GT(fused, in_files / 2);
  const auto raster = terramap::io::readRaster(d / "map.tif");
  ASSERT_EQ(raster.bands.size(), 4u);
  EXPECT_EQ(raster.bands[3].description, "elevation_smooth");
}

/// Runs the pipeline at 1 and 2 threads and requires the same snapshot bytes. The snapshot holds
/// every layer's bits and no timing, so equal runs give equal files.
static void expectBitIdenticalAtOneAndTwoThreads(const std::string& cfg, const fs::path& d) {
  ASSERT_EQ(sh("run " + cfg + " --threads 1 --quiet --out " + (d / "t1").string()).code, 0);
  ASSERT_EQ(sh("run " + cfg + " --threads 2 --quiet --out " + (d / "t2").string()).code, 0);
  auto bytes = [](const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  };
  const std::string a = bytes(d / "t1" / "map.tmap"), b = bytes(d / "t2" / "map.tmap");
  ASSERT_GT(a.size(), 1000u);
  EXPECT_TRUE(a == b) << "snapshots differ between 1 and 2 threads";
}

TEST(Cli, WholePipelineIsBitIdenticalAtOneAndTwoThreads) {
  TERRAMAP_SKIP_WITHOUT_KITTI();
  expectBitIdenticalAtOneAndTwoThreads(std::string(TERRAMAP_SOURCE_DIR) + "/configs/kitti.yaml", tempDir("threads"));
}

TEST(Cli, WholePipelineOnTheRepositorysPlyPairIsBitIdenticalAtOneAndTwoThreads) {
  // The same guarantee on the data every clone carries (data/gicp_pair), fused, inpainted and
  // smoothed as configs/kitti.yaml does.
  const fs::path d = tempDir("threads_ply");
  write(d / "p.yaml", R"(version: 1
map: {resolution: 0.1, size: [400, 400], center: [0, 0], tile: 64}
source: {type: sequence, clouds: )" + std::string(TERRAMAP_DATA_DIR) + R"(/gicp_pair, extensions: [.ply]}
pipeline:
  - {name: lidar, type: lidar_fusion, params: {sensor_noise: range_based, max_range_m: 40, enable_visibility_cleanup: true}}
  - {name: fill, type: inpaint, params: {input_layer: elevation, output_layer: elevation_inpainted, max_distance_m: 1.0}}
  - {name: smooth, type: smooth_filter, params: {input_layer: elevation_inpainted, output_layer: elevation_smooth,
                                                 sigma_m: 0.15, radius_m: 0.45, run_on: [], on_finish: true}}
outputs: {png: [], snapshot: true}
)");
  expectBitIdenticalAtOneAndTwoThreads((d / "p.yaml").string(), d);
  // Not vacuous: the pair's points reach the map (about half of its 138,880 pass the gates).
  const auto report = nlohmann::json::parse(std::ifstream(d / "t1" / "report.json"));
  EXPECT_GT(report["stages"][0]["counters"]["points_fused"].get<double>(), 50000.0);
}

TEST(Cli, SizesBeyondTheMemoryBudgetAreConfigurationOrInputErrors) {
  // The two ways a new user took terramap down with std::bad_alloc: a huge map.size, and an
  // ESRI ASCII DEM whose header declares 100000 x 100000 values and holds three.
  const fs::path d = tempDir("budget");
  write(d / "big.yaml", R"(version: 1
map: {resolution: 0.1, size: [100000, 100000], center: [0, 0]}
source: {type: none}
pipeline:
  - {name: lidar, type: lidar_fusion}
)");
  Result r = sh("--memory-budget 8G validate " + (d / "big.yaml").string());
  EXPECT_EQ(r.code, 8) << r.out;
  EXPECT_NE(r.out.find("big.yaml:2:30: map.size: a dense map of 100000 x 100000 cells needs 37.3 GiB per layer, more "
                       "than the memory budget of 8.0 GiB"),
            std::string::npos)
      << r.out;
  r = sh("run " + (d / "big.yaml").string() + " --out " + (d / "o").string() + " --memory-budget 8G");
  EXPECT_EQ(r.code, 3) << r.out;
  EXPECT_NE(r.out.find("map.size"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("bad_alloc"), std::string::npos) << r.out;

  write(d / "dem.asc", "ncols 100000\nnrows 100000\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2 3\n");
  write(d / "dem.yaml", R"(version: 1
name: dem_bomb
duration_s: 1
terrain: {resolution_m: 0.02, dem: {file: dem.asc}}
soil: {default: {family: loam, relative_density: 0.3}}
machines:
  - id: ctl1
    pose: {x_m: 0, y_m: 0, yaw_deg: 0}
    controller: {type: route, start_m: [0, 0], heading_deg: 0, length_m: 3, passes: 1, depth_m: 0.04, speed_mps: 0.5}
)");
  r = sh("sim " + (d / "dem.yaml").string() + " --out " + (d / "sim").string());
  EXPECT_EQ(r.code, 4) << r.out;
  EXPECT_NE(r.out.find("dem.asc: ESRI ASCII header declares ncols 100000 x nrows 100000"), std::string::npos) << r.out;

  r = sh("--memory-budget lots validate " + (d / "big.yaml").string());
  EXPECT_EQ(r.code, 3) << r.out;
  EXPECT_NE(r.out.find("--memory-budget: 'lots' is not a memory size"), std::string::npos) << r.out;
  fs::remove_all(d);
}

// A mast LiDAR's lowest beam reaches the ground metres ahead of the machine, so without a
// survey the ground the blade starts cutting is unknown to the map and blade_sweep can neither
// cut it nor extract the FEE there (nor count the pile it pushes); with `survey:` it knows it
// from the first sweep.
TEST(Cli, ASurveyedSiteIsKnownUnderTheBladeFromTheFirstSweep) {
  const fs::path d = tempDir("survey");
  auto run = [&](const std::string& survey) {
    write(d / "s.yaml", "version: 1\nseed: 3\nduration_s: 2.5\n" + survey +
                            "terrain: {size_m: [14, 8], origin_m: [-4, -4], resolution_m: 0.02}\n"
                            "machines:\n  - id: ctl1\n"
                            "    controller: {type: route, start_m: [0, 0], length_m: 6, passes: 1, depth_m: 0.08}\n"
                            "    sensors:\n      - {id: top, type: lidar, preset: os1_64, offset_m: [0.3, 0, 2.4]}\n");
    write(d / "p.yaml",
          "version: 1\nmap: {resolution: 0.05, size: [280, 160], center: [3, 0]}\nthreads: 2\n"
          "source: {type: sim, scenario: s.yaml}\npipeline:\n"
          "  - {name: lidar, type: lidar_fusion, params: {max_range_m: 30, max_height_above_sensor_m: -0.5}}\n"
          "  - {name: blade, type: blade_sweep, params: {min_translation_m: 0.2}}\n");
    const fs::path out = d / (survey.empty() ? "plain" : "survey");
    const auto r = sh("run " + (d / "p.yaml").string() + " --quiet --out " + out.string());
    EXPECT_EQ(r.code, 0) << r.out;
    const auto rep = nlohmann::json::parse(std::ifstream(out / "report.json"));
    long under = 0, unknown = 0, cut = 0;
    for (const auto& s : rep["stages"])
      if (s["name"] == "blade")
        for (const auto& rec : s["records"]) {
          under += rec["cells_under_sv"].get<long>();
          unknown += rec["cells_unknown_under_sv"].get<long>();
          cut += rec["cells_cut"].get<long>();
        }
    return std::array<long, 3>{under, unknown, cut};
  };
  const auto plain = run(""), surveyed = run("survey: {spacing_m: 0.025, sigma_m: 0.02}\n");
  ASSERT_GT(plain[0], 500);
  EXPECT_GT(plain[1], plain[0] / 2) << "the LiDAR alone should not see the first metres under the blade";
  EXPECT_LT(plain[2], plain[0] / 10);
  ASSERT_GT(surveyed[0], 500);
  // Known: the visibility cleanup may still let a few cells near the blade go (19 of 2,407 once
  // the clouds are in the survey's datum, lidar_fusion survey_datum), against more than half
  // without the survey.
  EXPECT_LE(surveyed[1], surveyed[0] / 50);
  EXPECT_GT(surveyed[2], surveyed[0] / 4);
}

TEST(Cli, AnEpisodesCommandsReplayedRetraceItsPath) {
  // A random-walk episode's commands (60 Hz, SI) replayed on the same terrain: the machine
  // retraces the path within a few centimetres (the original controller commands every 240 Hz
  // physics step, the log holds each 60 Hz sample), and path-compare says so.
  const fs::path d = tempDir("replay");
  const std::string terrain =
      "version: 1\nseed: 4\nduration_s: 6\nterrain: {size_m: [16, 12], origin_m: [-6, -6], resolution_m: 0.02,\n"
      "  hills: {count: 5, amplitude_m: [-0.15, 0.2], sigma_m: [1.0, 2.0], seed: 5}}\n"
      "soil: {default: {family: loam, relative_density: 0.5}}\nmachines:\n  - id: ctl1\n    pose: {x_m: -3, y_m: 0}\n";
  write(d / "orig.yaml", terrain + "    controller: {type: random_walk}\n");
  write(d / "replay.yaml", terrain + "    controller: {type: replay, file: commands.csv, units: si}\n");
  const Result a = sh("sim " + (d / "orig.yaml").string() + " --out " + (d / "orig").string() + " --no-clouds --export-commands " +
                      (d / "commands.csv").string() + " --export-tum " + (d / "orig.tum").string());
  ASSERT_EQ(a.code, 0) << a.out;
  const Result b = sh("sim " + (d / "replay.yaml").string() + " --out " + (d / "replay").string() + " --no-clouds");
  ASSERT_EQ(b.code, 0) << b.out;
  const Result c = sh("path-compare " + (d / "replay" / "episode.h5").string() + " " + (d / "orig.tum").string() +
                      " --json " + (d / "cmp.json").string());
  ASSERT_EQ(c.code, 0) << c.out;
  EXPECT_NE(c.out.find("RMSE"), std::string::npos) << c.out;
  const auto j = nlohmann::json::parse(std::ifstream(d / "cmp.json"));
  EXPECT_EQ(j["pairs"].get<int>(), 360);
  EXPECT_GT(j["reference_length_m"].get<double>(), 2.5);
  EXPECT_LT(j["rmse_m"].get<double>(), 0.1);
  EXPECT_NEAR(j["length_m"].get<double>(), j["reference_length_m"].get<double>(), 0.05 * j["reference_length_m"].get<double>());
  // Without the commands (a log of zeros) the machine stays put: the comparison sees it.
  write(d / "zeros.csv", "t_s,left,right,lift,tilt,angle\n0,0,0,0,0,0\n6,0,0,0,0,0\n");
  write(d / "still.yaml", terrain + "    controller: {type: replay, file: zeros.csv}\n");
  ASSERT_EQ(sh("sim " + (d / "still.yaml").string() + " --out " + (d / "still").string() + " --no-clouds").code, 0);
  const Result e = sh("path-compare " + (d / "still" / "episode.h5").string() + " " + (d / "orig" / "episode.h5").string() +
                      " --json " + (d / "still.json").string());
  ASSERT_EQ(e.code, 0) << e.out;
  EXPECT_GT(nlohmann::json::parse(std::ifstream(d / "still.json"))["rmse_m"].get<double>(), 0.5);
  EXPECT_EQ(sh("path-compare " + (d / "orig.tum").string() + " " + (d / "orig.tum").string() + " --align sim3").code, 3);
}

TEST(Cli, SimSaysHowManyRaysAStillSensorKept) {
  // A machine that stands still (a replayed log of zeros, no ruts to sink into) with a LiDAR:
  // from its third scan on every ray takes its kept hit, and `terramap sim` says how many.
  const fs::path d = tempDir("kept");
  write(d / "zeros.csv", "t_s,left,right,lift,tilt,angle\n0,0,0,0,0,0\n2,0,0,0,0,0\n");
  write(d / "still.yaml",
        "version: 1\nseed: 4\nduration_s: 1\nterrain: {size_m: [16, 12], origin_m: [-6, -6], resolution_m: 0.02}\n"
        "machines:\n  - id: ctl1\n    controller: {type: replay, file: zeros.csv}\n"
        "    vehicle: {track_soil: none}\n"
        "    sensors:\n      - {id: top, type: lidar, preset: os1_64, columns: 512, offset_m: [0.3, 0, 2.4]}\n");
  const Result r = sh("sim " + (d / "still.yaml").string() + " --out " + (d / "out").string() + " --no-clouds");
  ASSERT_EQ(r.code, 0) << r.out;
  const std::size_t at = r.out.find(" rays cast or kept, ");
  ASSERT_NE(at, std::string::npos) << r.out;
  const std::size_t line = r.out.rfind('\n', at);
  const double rays = std::stod(r.out.substr(line == std::string::npos ? 0 : line + 1));
  const double kept = std::stod(r.out.substr(at + std::string(" rays cast or kept, ").size()));
  EXPECT_EQ(rays, 11 * 64 * 512) << r.out;  // scans at 1/240 s, then 0.1, ..., 1.0 s
  // Every downward ray (32 of the 64 beams; the upward ones are never cast) of the 9 scans
  // after the first two: the first keeps nothing (the sensor had no previous pose), the second
  // keeps its hits (same pose), the others take them.
  EXPECT_EQ(kept, 9 * 32 * 512) << r.out;
  fs::remove_all(d);
}

TEST(Cli, TheExcavatorPipelineFiltersItsArmAndMapsItsBucket) {
  // configs/excavator.yaml as shipped (30 s: two dig-and-dump cycles beside a grading loader):
  // the excavator's camera sees its own boom, arm and bucket, which the link boxes of the
  // self-filter drop (RMSE 5.07 cm with them, 12.4 cm without: plugins/lidar_fusion/README.md), and
  // blade_sweep carries what the bucket digs to the pile.
  const fs::path d = tempDir("excavator");
  const Result r = sh("run " + std::string(TERRAMAP_SOURCE_DIR) + "/configs/excavator.yaml --quiet --out " + d.string());
  ASSERT_EQ(r.code, 0) << r.out;
  const auto rep = nlohmann::json::parse(std::ifstream(d / "report.json"));
  EXPECT_LT(rep["truth"]["rmse_m"].get<double>(), 0.07);
  EXPECT_LT(rep["truth"]["median_abs_m"].get<double>(), 0.02);
  for (const auto& s : rep["stages"]) {
    if (s["name"] == "lidar") {
      EXPECT_GT(s["dropped"]["self"].get<long>(), 1000000) << "the arm in the camera's view";
      EXPECT_EQ(s["events"]["joint_state"].get<long>(), 1800);
    }
    if (s["name"] == "blade") {
      EXPECT_GT(s["counters"]["bucket_cut_bank_m3"].get<double>(), 0.15);
    }
  }
}

TEST(Cli, TheDepthCameraPipelineMapsTheGroundBesideItsLiDAR) {
  // configs/depth_camera.yaml as shipped: a mast LiDAR and a depth camera fused by one
  // lidar_fusion (the camera's frame through depth_squared_frames), IMU events in the stream
  // that no stage takes. Its docs/sim.md figures: coverage 0.994, RMSE 1.80 cm.
  const fs::path d = tempDir("depth_camera");
  const Result r = sh("run " + std::string(TERRAMAP_SOURCE_DIR) + "/configs/depth_camera.yaml --quiet --out " + d.string());
  ASSERT_EQ(r.code, 0) << r.out;
  const auto rep = nlohmann::json::parse(std::ifstream(d / "report.json"));
  EXPECT_GT(rep["truth"]["coverage"].get<double>(), 0.95);
  EXPECT_LT(rep["truth"]["rmse_m"].get<double>(), 0.02);
  long clouds = 0;
  for (const auto& s : rep["stages"])
    if (s["name"] == "lidar") clouds = s["events"]["point_cloud"].get<long>();
  EXPECT_EQ(clouds, 120 + 180 + 2);  // 10 Hz LiDAR + 15 Hz camera over 12 s, each one at t = 0 as well
}
