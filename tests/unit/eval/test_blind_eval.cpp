// Blind-mapping evaluation (include/terramap/eval/blind_eval.hpp, `terramap eval`): truth sampling on
// the map grid, the statistics, a whole evaluation on a small berm-cut scenario through the
// real engine and plugins, the outputs, and the CLI.
#include <terramap/io/geotiff.hpp>
#include <terramap/eval/blind_eval.hpp>
#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/simulator.hpp>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace fs = std::filesystem;
using namespace terramap;

namespace {

fs::path tempDir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("terramap_eval_" + name + "_" + std::to_string(getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

std::string readText(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// A small berm cut: a 0.17 m ridge across x = 3 m (Gaussians 0.5 m apart along y), one pass
// with the blade 4 cm below the track plane at 0.5 m/s, ending while the blade still cuts.
std::string smallBermScenario() {
  std::string s = R"(version: 1
name: small_berm
seed: 5
duration_s: 6.5
threads: 1
terrain:
  size_m: [8, 5]
  origin_m: [-1.5, -2.5]
  resolution_m: 0.02
  hills:
    list:
)";
  for (int k = 0; k < 17; ++k) {
    char b[128];
    std::snprintf(b, sizeof b, "      - {x_m: 3.0, y_m: %.1f, amplitude_m: 0.057, sigma_m: 0.6}\n", -4.0 + 0.5 * k);
    s += b;
  }
  s += R"(soil:
  default: {family: loam, relative_density: 0.3}
machines:
  - id: ctl1
    pose: {x_m: 0, y_m: 0, yaw_deg: 0}
    controller: {type: route, start_m: [0, 0], heading_deg: 0, length_m: 3.5, passes: 1, depth_m: 0.04, speed_mps: 0.5}
    sensors:
      - {id: front_line, type: lidar, preset: single_line, offset_m: [0.8, 0, 2.0], rotation_deg: [0, 50, 0], columns: 64}
)";
  return s;
}

eval::EvalRun evaluateSmallBerm(int threads, long* scans = nullptr, bool with_stages = true) {
  sim::Simulator simulator(sim::parseScenario(smallBermScenario(), "small_berm.yaml"));
  PipelineSpec spec = parsePipelineString(eval::defaultEvalPipeline(), "<eval>", ".");
  spec.threads = threads;
  if (!with_stages) spec.stages.clear();  // a "mapper" that never updates the map
  const Geometry g = sim::fitGeometry(simulator.truth(), spec.resolution);
  spec.size = g.size();
  spec.center = g.center();
  PluginRegistry registry({TERRAMAP_PLUGIN_DIR});
  auto engine = Engine::fromSpec(spec, registry);
  eval::EvalRun r = eval::runBlindEvaluation(simulator, *engine);
  engine->finish();
  if (scans) *scans = static_cast<long>(simulator.stats().scans);
  return r;
}

long& smallBermScans() {
  static long scans = -1;
  return scans;
}

const eval::EvalRun& smallBermRun() {
  static const eval::EvalRun run = evaluateSmallBerm(2, &smallBermScans());
  return run;
}

}  // namespace

TEST(EvalTruthOnGeometry, PlaneIsSampledExactlyAtCellCentres) {
  // Plane z = 0.3 + 0.05 x - 0.02 y on nodes 2 cm apart; the map's 7 cm cells are not aligned
  // with the nodes and the map sticks out of the truth grid on the +x side.
  sim::TruthTerrain t(-1.0, -0.5, 0.02, 151, 76);  // x in [-1, 2], y in [-0.5, 1]
  auto plane = [](double x, double y) { return 0.3 + 0.05 * x - 0.02 * y; };
  for (int i = 0; i < t.nx(); ++i)
    for (int j = 0; j < t.ny(); ++j) {
      const Eigen::Vector2d p = t.nodePosition(i, j);
      t.setUndisturbed(i, j, plane(p.x(), p.y()));
    }
  t.captureInitial();
  // Loose soil on top of a block of nodes: 4 cm lying, 3 cm bank-equivalent.
  for (int i = 40; i < 60; ++i)
    for (int j = 20; j < 40; ++j) t.addLoose(i, j, 0.04, 0.03);
  const Geometry geo(0.07, Size(40, 20), Position(1.2, 0.25));  // x in [-0.2, 2.6]
  const Eigen::MatrixXf cur = sim::truthOnGeometry(t, geo);
  const Eigen::MatrixXf ini = sim::truthOnGeometry(t, geo, sim::TruthSurface::Initial);
  const Eigen::MatrixXd bank = sim::truthOnGeometryD(t, geo, sim::TruthSurface::Bank);
  ASSERT_EQ(cur.rows(), 40);
  ASSERT_EQ(cur.cols(), 20);
  long inside = 0, outside = 0, loose_cells = 0;
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 20; ++j) {
      const Position p = geo.positionOf(Index(i, j));
      if (p.x() > 2.0) {  // beyond the last node column
        EXPECT_TRUE(std::isnan(cur(i, j))) << i << "," << j;
        EXPECT_TRUE(std::isnan(bank(i, j)));
        ++outside;
        continue;
      }
      ++inside;
      // Loose soil fully covers the cell centre's bilinear stencil only well inside the block.
      const bool in_loose = p.x() > -1.0 + 40 * 0.02 && p.x() < -1.0 + 59 * 0.02 && p.y() > -0.5 + 20 * 0.02 &&
                            p.y() < -0.5 + 39 * 0.02;
      const bool near_loose = p.x() > -1.0 + 39 * 0.02 && p.x() < -1.0 + 60 * 0.02 && p.y() > -0.5 + 19 * 0.02 &&
                              p.y() < -0.5 + 40 * 0.02;
      EXPECT_NEAR(ini(i, j), plane(p.x(), p.y()), 1e-6) << i << "," << j;
      if (in_loose) {
        ++loose_cells;
        EXPECT_NEAR(cur(i, j), plane(p.x(), p.y()) + 0.04, 1e-6);
        EXPECT_NEAR(bank(i, j), plane(p.x(), p.y()) + 0.03, 1e-12);
      } else if (!near_loose) {
        EXPECT_NEAR(cur(i, j), plane(p.x(), p.y()), 1e-6);
        EXPECT_NEAR(bank(i, j), plane(p.x(), p.y()), 1e-12);
      }
    }
  EXPECT_GT(inside, 400);
  EXPECT_GT(outside, 100);
  EXPECT_GT(loose_cells, 10);
}

TEST(EvalTruthOnGeometry, FitGeometryKeepsEveryCellCentreInsideTheTruth) {
  sim::TruthTerrain t(-3.0, 2.0, 0.02, 501, 201);  // 10 m x 4 m
  const Geometry g = sim::fitGeometry(t, 0.07);
  EXPECT_EQ(g.size().x(), 142);  // floor(10 / 0.07)
  EXPECT_EQ(g.size().y(), 57);   // floor(4 / 0.07)
  EXPECT_NEAR(g.center().x(), 2.0, 1e-12);
  EXPECT_NEAR(g.center().y(), 4.0, 1e-12);
  const Eigen::MatrixXf h = sim::truthOnGeometry(t, g);
  EXPECT_FALSE(h.array().isNaN().any());
  const Geometry exact = sim::fitGeometry(t, 0.05);  // a whole number of cells is kept
  EXPECT_EQ(exact.size().x(), 200);
  EXPECT_EQ(exact.size().y(), 80);
  EXPECT_THROW(sim::fitGeometry(t, 20.0), ConfigError);
  EXPECT_THROW(sim::fitGeometry(t, 0.0), ConfigError);
  EXPECT_THROW(sim::fitGeometry(t, 0.001, 1000), ConfigError);
}

TEST(EvalExtraction, SurfaceAheadTruthOnASlope) {
  // Plane z = 0.1 x (rising ahead of a blade facing +x).
  sim::TruthTerrain t(-2.0, -2.0, 0.02, 301, 201);
  for (int i = 0; i < t.nx(); ++i)
    for (int j = 0; j < t.ny(); ++j) t.setUndisturbed(i, j, 0.1 * t.nodePosition(i, j).x());
  t.captureInitial();
  const BladeGeometry blade{1.85, 0.76};
  // Upright blade, edge 5 cm below the surface at x = 2.
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(2.0, 0.0, 0.15);
  eval::SurfaceAheadTruth s = eval::surfaceAheadTruth(t, T, blade, 37);
  EXPECT_EQ(s.cutting_slices, 37);
  EXPECT_NEAR(s.alpha_rad, std::atan(0.1), 1e-9);
  EXPECT_NEAR(s.d_m, 0.05 * std::cos(std::atan(0.1)), 1e-9);
  EXPECT_NEAR(s.w_along_m, 1.85, 1e-12);
  EXPECT_NEAR(s.face_angle_rad, M_PI / 2, 1e-12);
  // Yawed by 30 deg: the slope along the normal is 0.1 cos 30; the depth varies along the edge
  // (the edge runs uphill to the right), d-weighted like the simulator.
  T.linear() = Eigen::AngleAxisd(M_PI / 6, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  s = eval::surfaceAheadTruth(t, T, blade, 37);
  const double alpha = std::atan(0.1 * std::cos(M_PI / 6));
  double sd = 0, sdd = 0;
  for (int k = 0; k < 37; ++k) {
    const double ys = -0.925 + (k + 0.5) * 1.85 / 37;
    const double d = (0.1 * (2.0 - 0.5 * ys) - 0.15) * std::cos(alpha);
    sd += d;
    sdd += d * d;
  }
  EXPECT_EQ(s.cutting_slices, 37);
  EXPECT_NEAR(s.alpha_rad, alpha, 1e-9);
  EXPECT_NEAR(s.d_m, sdd / sd, 1e-9);
  // Raked back by 10 deg (face 80 deg from the horizontal through the soil), edge 1 cm above
  // the surface: nothing cuts, the face angle is still reported.
  T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(2.0, 0.0, 0.21);
  T.linear() = Eigen::AngleAxisd(-10 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();
  s = eval::surfaceAheadTruth(t, T, blade, 37);
  EXPECT_EQ(s.cutting_slices, 0);
  EXPECT_TRUE(std::isnan(s.d_m));
  EXPECT_NEAR(s.face_angle_rad, 80 * M_PI / 180, 1e-9);
  // Rolled: the right end dips below the surface, the left end stays above it.
  T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(2.0, 0.0, 0.2);
  T.linear() = Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitX()).toRotationMatrix();
  s = eval::surfaceAheadTruth(t, T, blade, 37);
  EXPECT_EQ(s.cutting_slices, 18);  // slices with ys < 0 (slice 18 sits at ys = 0: no cut)
  EXPECT_NEAR(s.w_along_m, 18 * 1.85 / 37, 1e-12);
}

TEST(EvalExtraction, StatisticsAreHandComputable) {
  std::vector<eval::ExtractionSample> v;
  // Five sweeps valid on both sides with d errors 1..5 cm, alpha errors of 0.01 rad, and
  // Q unknown on the mapped side for one of them; plus one of each other kind.
  for (int k = 0; k < 5; ++k) {
    eval::ExtractionSample s;
    s.sweep = k + 1;
    s.mapped_valid = s.truth_valid = true;
    s.truth_d_m = 0.10;
    s.d_m = 0.10 + 0.01 * (k + 1);
    s.truth_alpha_rad = 0.05 * k;
    s.alpha_rad = s.truth_alpha_rad + 0.01;
    s.rho_rad = 1.4;
    s.truth_rho_raw_rad = 1.3;
    s.truth_rho_rad = 1.3 + 0.05 * k;
    s.w_m = 1.80;
    s.truth_w_raw_m = 1.85;
    s.truth_w_m = 1.85 * std::cos(0.1);
    s.q_n = k == 2 ? NAN : 1000.0 + 100 * k;
    s.truth_q_n = 1000.0;
    v.push_back(s);
  }
  eval::ExtractionSample m;
  m.mapped_valid = true;
  m.d_m = 5.0;  // must not enter the statistics
  v.push_back(m);
  eval::ExtractionSample t;
  t.truth_valid = true;
  t.truth_d_m = 5.0;
  v.push_back(t);
  v.push_back(eval::ExtractionSample{});
  const eval::ExtractionSummary s = eval::summarizeExtraction(v);
  EXPECT_EQ(s.sweeps, 8);
  EXPECT_EQ(s.both_valid, 5);
  EXPECT_EQ(s.mapped_only, 1);
  EXPECT_EQ(s.truth_only, 1);
  EXPECT_EQ(s.neither, 1);
  ASSERT_EQ(s.parameters.size(), 8u);
  const eval::ParameterStats& d = s.parameters[2];
  EXPECT_EQ(d.name, "d");
  EXPECT_EQ(d.unit, "m");
  EXPECT_EQ(d.n, 5);
  EXPECT_NEAR(d.bias, 0.03, 1e-12);
  EXPECT_NEAR(d.std, std::sqrt(0.00025), 1e-12);           // sample std of 1..5 cm
  EXPECT_NEAR(d.rmse, std::sqrt(0.0055 / 5.0), 1e-12);     // (1+4+9+16+25) cm^2 / 5
  EXPECT_NEAR(d.p5, 0.012, 1e-12);                          // 1 + 0.05 * 4 * 1 cm
  EXPECT_NEAR(d.p50, 0.03, 1e-12);
  EXPECT_NEAR(d.p95, 0.048, 1e-12);
  EXPECT_NEAR(d.truth_mean, 0.10, 1e-12);
  const eval::ParameterStats& a = s.parameters[0];
  EXPECT_EQ(a.unit, "deg");
  EXPECT_NEAR(a.bias, 0.01 * 180 / M_PI, 1e-9);
  EXPECT_NEAR(a.std, 0.0, 1e-9);
  const eval::ParameterStats& q = s.parameters[4];
  EXPECT_EQ(q.n, 4);  // the NaN one is left out
  EXPECT_NEAR(q.bias, (0 + 100 + 300 + 400) / 4.0, 1e-9);
  const eval::ParameterStats& rho = s.parameters[1];
  EXPECT_NEAR(rho.bias, (0.1 - 0.1) * 180 / M_PI, 1e-9);    // mean of 0.1 - 0.05 k, k = 0..4
  EXPECT_EQ(s.parameters[5].name, "d_vs_sim_raw");
  EXPECT_EQ(s.parameters[5].n, 0);  // no raw depths given
  const eval::ParameterStats& rho_raw = s.parameters[6];
  EXPECT_NEAR(rho_raw.bias, 0.1 * 180 / M_PI, 1e-9);
  const eval::ParameterStats& w = s.parameters[3];
  EXPECT_NEAR(w.bias, 1.80 - 1.85 * std::cos(0.1), 1e-12);
  EXPECT_NEAR(s.parameters[7].bias, -0.05, 1e-12);
  const std::string md = eval::extractionTableMarkdown(s);
  EXPECT_NE(md.find("| d | m | 5 | 0.1000 | 0.1300 | 0.0300 |"), std::string::npos) << md;
  EXPECT_NE(md.find("8 sweeps: 5 valid on both sides"), std::string::npos) << md;
}

TEST(EvalPipeline, EmbeddedDefaultEqualsConfigsEvalBlind) {
  EXPECT_EQ(eval::defaultEvalPipeline(), readText(fs::path(TERRAMAP_SOURCE_DIR) / "configs" / "eval_blind.yaml"));
  const PipelineSpec spec = parsePipelineFile(std::string(TERRAMAP_SOURCE_DIR) + "/configs/eval_blind.yaml");
  ASSERT_EQ(spec.stages.size(), 2u);
  EXPECT_EQ(spec.stages[0].type, "blade_sweep");
  EXPECT_EQ(spec.stages[1].type, "soil_erosion");
  // The shipped scenarios load.
  EXPECT_NO_THROW(sim::loadScenario(std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/fig10_berm_cut.yaml"));
  EXPECT_NO_THROW(sim::loadScenario(std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/extraction_random_walk.yaml"));
}

TEST(EvalRun, BlindMapBeatsTheNoUpdateMapAndConservesMass) {
  const eval::EvalRun& r = smallBermRun();
  const eval::RegionStats& cut = r.stats(eval::EvalRegion::Cut);
  const eval::RegionStats& dep = r.stats(eval::EvalRegion::Deposit);
  const eval::RegionStats& unt = r.stats(eval::EvalRegion::Untouched);
  std::printf("[ eval ] %ld sweeps; cut %ld cells rmse %.4f (no update %.4f); deposit %ld rmse %.4f (%.4f); "
              "untouched %ld rmse %.5f p95 %.5f; mass blind residual %.3e, cut bank blind %.4f truth %.4f\n",
              r.sweeps, cut.cells, cut.rmse_m, cut.baseline_rmse_m, dep.cells, dep.rmse_m, dep.baseline_rmse_m,
              unt.cells, unt.rmse_m, unt.p95_abs_m, r.mass.blind_residual_m3, r.mass.cut_bank_blind_m3,
              r.mass.cut_bank_truth_m3);
  const eval::RegionStats& mcut = r.stats(eval::EvalRegion::CutByMapper);
  std::printf("[ eval ] cut footprint: %ld both, %ld truth only, %ld mapper only (IoU %.3f); mapper's cut %ld cells rmse %.4f\n",
              r.footprint.both, r.footprint.truth_only, r.footprint.mapper_only, r.footprint.iou, mcut.cells, mcut.rmse_m);
  EXPECT_GT(r.sweeps, 10);
  // Blind: every scan of the single-line LiDAR was withheld, not pushed.
  EXPECT_GT(smallBermScans(), 20);
  EXPECT_EQ(r.clouds_withheld, smallBermScans());
  // The blade went through ~2.5 m x 1.85 m of ground below the initial surface (1850 cells of 5 cm).
  EXPECT_GT(cut.cells, 1000);
  // Inside the cut, blind mapping must beat a map that ignored the blade by far: the no-update
  // map is off by the berm and the cut depth there, the blind map only by the difference of the
  // two models' cut floors and spoil left in the cut (measured 2026-11-22: 1.2 cm vs 6.8-10.6 cm
  // while the simulator's deposit model was being reworked; bound with margin).
  EXPECT_LT(cut.rmse_m, 0.35 * cut.baseline_rmse_m);
  EXPECT_LT(cut.rmse_m, 0.03);
  // Untouched ground: the blind map differs only where its erosion spread spoil wider than the
  // truth's, a thin fringe (95 % of the cells within 1 cm).
  EXPECT_LT(unt.p95_abs_m, 0.01);
  // The mapper's own footprint agrees with the truth's cut (reported beside it): most cut cells
  // are in both; the rest are partial cells at the cut's sides and ends.
  EXPECT_GT(r.footprint.iou, 0.9);
  // The deposits are where the two soil-flow models differ (paper Fig. 10): reported, not
  // bounded against the truth, whose deposit model is its own.
  // Mass: blade_sweep and soil_erosion conserve Σ[(H - L) + L/s] in double precision but store
  // float32 heights. Each stored value is rounded by at most 2^-24 |H| (|H| < 0.5 m here, so
  // 3e-8 m); each sweep rewrites at most the erosion ROI (6 m x 3.85 m = 9240 cells) in two
  // layers for 20 sub-steps, so over r.sweeps sweeps the rounding is bounded by
  // sweeps * 9240 * 2 * 20 * 3e-8 m * res^2. Nothing was deposited off the map here.
  const double res2 = r.geometry.resolution() * r.geometry.resolution();
  const double bound = static_cast<double>(r.sweeps) * 9240 * 2 * 20 * 3e-8 * res2;
  EXPECT_LT(std::abs(r.mass.blind_residual_m3), bound) << "bound " << bound;
  EXPECT_EQ(r.mass.blind_lost_loose_m3, 0.0);
  // The truth conserves its own mass in double precision.
  EXPECT_LT(std::abs(r.mass.truth_residual_m3), 1e-9);
  // Both cut about the same bank volume (the blind map from the blade's path, the truth with
  // its own model; within 15 %).
  EXPECT_GT(r.mass.cut_bank_truth_m3, 0.3);
  EXPECT_NEAR(r.mass.cut_bank_blind_m3, r.mass.cut_bank_truth_m3, 0.15 * r.mass.cut_bank_truth_m3);
  // Extraction pairs one sample per sweep.
  EXPECT_EQ(static_cast<long>(r.samples.size()), r.sweeps);
  EXPECT_GT(r.extraction.both_valid, 5);
}

TEST(EvalRun, RegionsComeFromTheTruthNotFromTheMapper) {
  // The same scenario with a mapper that never touches the map: the truth carved the same
  // ground, so the cut region must be the same cells, and there the map's error is the no-update
  // error. Regions defined by the mapper's swept mask would leave this run with no cut at all
  // and its whole error "outside the cut".
  const eval::EvalRun none = evaluateSmallBerm(1, nullptr, false);
  const eval::EvalRun& blind = smallBermRun();
  EXPECT_EQ(none.sweeps, 0);
  EXPECT_EQ(none.stats(eval::EvalRegion::CutByMapper).cells, 0);
  const eval::RegionStats& cut = none.stats(eval::EvalRegion::Cut);
  EXPECT_EQ(cut.cells, blind.stats(eval::EvalRegion::Cut).cells);
  EXPECT_GT(cut.cells, 1000);
  EXPECT_TRUE((none.region.array() == static_cast<int>(eval::EvalRegion::Cut))
                  .cwiseEqual(blind.region.array() == static_cast<int>(eval::EvalRegion::Cut))
                  .all());
  EXPECT_DOUBLE_EQ(cut.rmse_m, cut.baseline_rmse_m);
  EXPECT_EQ(none.footprint.both, 0);
  EXPECT_EQ(none.footprint.truth_only, cut.cells);
}

TEST(EvalRun, BitIdenticalAtOneAndTwoThreads) {
  const eval::EvalRun one = evaluateSmallBerm(1);
  const eval::EvalRun& two = smallBermRun();
  ASSERT_EQ(one.blind.size(), two.blind.size());
  EXPECT_EQ(0, std::memcmp(one.blind.data(), two.blind.data(), sizeof(float) * one.blind.size()));
  EXPECT_EQ(one.mass.blind_residual_m3, two.mass.blind_residual_m3);
  EXPECT_EQ(one.stats(eval::EvalRegion::Cut).rmse_m, two.stats(eval::EvalRegion::Cut).rmse_m);
}

TEST(EvalRun, RefusesASteppedSimulatorAndAMapWithoutElevation) {
  sim::Simulator simulator(sim::parseScenario(smallBermScenario(), "small_berm.yaml"));
  PipelineSpec spec = parsePipelineString(eval::defaultEvalPipeline(), "<eval>", ".");
  PluginRegistry registry({TERRAMAP_PLUGIN_DIR});
  auto engine = Engine::fromSpec(spec, registry);
  eval::EvalOptions o;
  o.elevation_layer = "height";
  EXPECT_THROW(eval::runBlindEvaluation(simulator, *engine, o), LayerError);
  std::vector<Event> ev;
  simulator.next(ev);
  EXPECT_THROW(eval::runBlindEvaluation(simulator, *engine), std::invalid_argument);
}

TEST(EvalOutputs, PngsGeoTiffJsonAndCsvAreWritten) {
  const eval::EvalRun& r = smallBermRun();
  const fs::path d = tempDir("outputs") / "nested";
  const std::vector<std::string> files = eval::writeEvalOutputs(r, d);
  for (const char* f : {"blind_heightmap.png", "truth_heightmap.png", "error.png", "baseline_error.png", "regions.png",
                        "eval.tif", "eval.json", "extraction.csv"}) {
    EXPECT_TRUE(fs::exists(d / f)) << f;
    EXPECT_GT(fs::file_size(d / f), 100u) << f;
  }
  EXPECT_EQ(files.size(), 8u);
  // No temporaries left behind.
  for (const auto& e : fs::directory_iterator(d)) EXPECT_EQ(e.path().string().find(".tmp."), std::string::npos);
  const std::string png = readText(d / "error.png");
  EXPECT_EQ(png.substr(1, 3), "PNG");
  const nlohmann::json j = nlohmann::json::parse(readText(d / "eval.json"));
  EXPECT_EQ(j["format"], "terramap-eval");
  EXPECT_EQ(j["sweeps"].get<long>(), r.sweeps);
  EXPECT_DOUBLE_EQ(j["height_error"]["cut"]["rmse_m"].get<double>(), r.stats(eval::EvalRegion::Cut).rmse_m);
  EXPECT_EQ(j["height_error"]["outside"]["cells"].get<long>(), r.stats(eval::EvalRegion::Outside).cells);
  EXPECT_DOUBLE_EQ(j["mass"]["blind_residual_m3"].get<double>(), r.mass.blind_residual_m3);
  EXPECT_EQ(j["extraction"]["parameters"].size(), 8u);
  const io::Raster ras = io::readRaster(d / "eval.tif");
  ASSERT_EQ(ras.bands.size(), 7u);
  EXPECT_EQ(ras.bands[6].description, "mapper_cut");
  EXPECT_EQ(ras.bands[0].description, "blind");
  EXPECT_EQ(ras.bands[3].description, "error");
  EXPECT_EQ(ras.width * ras.height, r.geometry.cellCount());
  std::istringstream csv(readText(d / "extraction.csv"));
  std::string line;
  long rows = -1;
  while (std::getline(csv, line)) ++rows;
  EXPECT_EQ(rows, r.sweeps);
}

TEST(EvalCli, WritesPngsAndJsonAndReportsErrors) {
  const std::string bin = std::string(TERRAMAP_BINARY_DIR) + "/bin/terramap";
  const fs::path d = tempDir("cli");
  { std::ofstream(d / "small_berm.yaml") << smallBermScenario(); }
  auto sh = [&](const std::string& args, std::string* out = nullptr) {
    const std::string cmd = "TERRAMAP_PLUGIN_PATH= " + bin + " " + args + " 2>&1";
    FILE* p = popen(cmd.c_str(), "r");
    std::array<char, 4096> buf{};
    std::string o;
    std::size_t n;
    while ((n = fread(buf.data(), 1, buf.size(), p)) > 0) o.append(buf.data(), n);
    const int st = pclose(p);
    if (out) *out = o;
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  };
  std::string out;
  ASSERT_EQ(sh("eval --help", &out), 0) << out;
  EXPECT_NE(out.find("Usage"), std::string::npos);
  EXPECT_NE(out.find("--pipeline"), std::string::npos);
  ASSERT_EQ(sh("eval " + (d / "small_berm.yaml").string() + " --out " + (d / "out").string(), &out), 0) << out;
  EXPECT_NE(out.find("inside the cut"), std::string::npos) << out;
  EXPECT_NE(out.find("| d | m |"), std::string::npos) << out;
  for (const char* f : {"blind_heightmap.png", "truth_heightmap.png", "error.png", "eval.json"})
    EXPECT_TRUE(fs::exists(d / "out" / f)) << f;
  const nlohmann::json j = nlohmann::json::parse(readText(d / "out" / "eval.json"));
  EXPECT_EQ(j["scenario"], "small_berm");
  EXPECT_GT(j["height_error"]["cut"]["baseline_rmse_m"].get<double>(),
            2 * j["height_error"]["cut"]["rmse_m"].get<double>());
  // The shipped configs/eval_blind.yaml with --fit-map is the embedded default: same figures.
  const std::string shipped = std::string(TERRAMAP_SOURCE_DIR) + "/configs/eval_blind.yaml";
  ASSERT_EQ(sh("eval " + (d / "small_berm.yaml").string() + " -q --pipeline " + shipped + " --fit-map --out " +
               (d / "out2").string(), &out), 0) << out;
  nlohmann::json j2 = nlohmann::json::parse(readText(d / "out2" / "eval.json"));
  nlohmann::json j1 = j;
  j1.erase("wall_s");
  j2.erase("wall_s");
  EXPECT_EQ(j1, j2);
  // Without --fit-map the pipeline's 200 x 200 map at (0, 0) is used as written: its cells
  // beyond the truth (x < -1.5 m, |y| > 2.5 m) are unknown and left out of the statistics.
  ASSERT_EQ(sh("eval " + (d / "small_berm.yaml").string() + " -q --pipeline " + shipped + " --out " +
               (d / "out3").string(), &out), 0) << out;
  const nlohmann::json j3 = nlohmann::json::parse(readText(d / "out3" / "eval.json"));
  EXPECT_EQ(j3["map"]["size"][0].get<int>(), 200);
  EXPECT_LT(j3["height_error"]["all"]["cells"].get<long>(), 200L * 200L);
  // A missing scenario is a configuration error (exit 3), an unknown option a usage error (2).
  EXPECT_EQ(sh("eval " + (d / "nope.yaml").string() + " --out " + (d / "o2").string(), &out), 3) << out;
  EXPECT_EQ(sh("eval " + (d / "small_berm.yaml").string() + " --no-such-flag", &out), 2) << out;
  // A pipeline without an elevation layer is refused before anything runs (exit 3 or 6).
  { std::ofstream(d / "bad.yaml") << "version: 1\nmap: {resolution: 0.1, size: [10, 10]}\npipeline:\n"
                                      "  - {name: blade, type: blade_sweep}\n"; }
  const int rc = sh("eval " + (d / "small_berm.yaml").string() + " --pipeline " + (d / "bad.yaml").string() +
                    " --out " + (d / "o3").string(), &out);
  EXPECT_TRUE(rc == 3 || rc == 6) << rc << "\n" << out;
  EXPECT_NE(out.find("elevation"), std::string::npos) << out;
}
