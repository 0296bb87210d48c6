// `terramap eval SCENARIO.yaml`: blind mapping against the simulator's truth (paper Fig. 10) and
// FEE-geometry extraction statistics. The work is in include/terramap/eval/blind_eval.hpp.
#include "command.hpp"

#include <terramap/eval/blind_eval.hpp>
#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/simulator.hpp>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>

namespace terramap::cli {
namespace {

struct EvalArgs {
  std::string scenario, out = "out/eval", pipeline;
  bool fit_map = false, lidar = false, quiet = false;
  std::string localisation;
  std::string track_soil;
  int threads = 0;
  double duration = -1, change_threshold = 0.01, error_range = 0.10;
  long long seed = -1;
};

void printRun(const eval::EvalRun& r) {
  const Geometry& g = r.geometry;
  std::printf("eval %s: %.2f s simulated, %ld sweeps, %ld events pushed, %ld clouds withheld, %.2f s wall\n",
              r.scenario.c_str(), r.simulated_s, r.sweeps, r.events_pushed, r.clouds_withheld, r.wall_s);
  std::printf("map %d x %d cells at %.3f m, centre (%.3f, %.3f)\n\n", g.size().x(), g.size().y(), g.resolution(),
              g.center().x(), g.center().y());
  std::printf("height error, map - truth (m)      cells     RMSE     bias   p95|e|    max|e|   no-update RMSE\n");
  const std::pair<eval::EvalRegion, const char*> rows[] = {
      {eval::EvalRegion::Cut, "inside the cut"},
      {eval::EvalRegion::Outside, "outside the cut"},
      {eval::EvalRegion::Deposit, "  deposit (truth moved)"},
      {eval::EvalRegion::Untouched, "  untouched"},
      {eval::EvalRegion::All, "all known cells"},
      {eval::EvalRegion::CutByMapper, "mapper's own cut footprint"}};
  for (const auto& [reg, label] : rows) {
    const eval::RegionStats& s = r.stats(reg);
    std::printf("  %-32s %8ld %8.4f %8.4f %8.4f %9.4f %16.4f\n", label, s.cells, s.rmse_m, s.bias_m, s.p95_abs_m,
                s.max_abs_m, s.baseline_rmse_m);
  }
  const eval::FootprintAgreement& fp = r.footprint;
  std::printf("cut footprint: truth (bank lowered) vs mapper (swept volume below the initial surface): %ld both, "
              "%ld truth only, %ld mapper only, IoU %.3f\n",
              fp.both, fp.truth_only, fp.mapper_only, fp.iou);
  const eval::MassBalance& m = r.mass;
  std::printf("\nmass balance (m^3 of bank soil; blind: sum[(H - L) + L/s], s = %.3f; truth: sum(U + Lc))\n", m.swell);
  std::printf("  blind map:  change %+.6f, lost off the map %.6f (loose %.6f), residual %+.2e\n", m.blind_change_m3,
              m.blind_lost_loose_m3 / m.swell, m.blind_lost_loose_m3, m.blind_residual_m3);
  std::printf("  truth:      change %+.6f, lost off the grid %.6f, residual %+.2e; over the map's area %+.6f\n",
              m.truth_change_m3, m.truth_lost_m3, m.truth_residual_m3, m.truth_change_on_map_m3);
  std::printf("  bank volume cut:  blind %.4f, truth %.4f\n", m.cut_bank_blind_m3, m.cut_bank_truth_m3);
  std::printf("  surface removed:  blind %.4f, truth %.4f; added: blind %.4f, truth %.4f\n\n", m.removed_blind_m3,
              m.removed_truth_m3, m.added_blind_m3, m.added_truth_m3);
  std::printf("FEE geometry per sweep, mapped - truth at the sweep's end (angles in degrees):\n%s",
              eval::extractionTableMarkdown(r.extraction).c_str());
}

Registrar reg{Command{"eval", [](CLI::App& app, std::function<int()>& run) {
  auto a = std::make_shared<EvalArgs>();
  auto* sub = app.add_subcommand("eval",
      "Blind mapping against the simulator's truth (paper Fig. 10): run SCENARIO with LiDAR off\n"
      "through a pipeline (default: blade_sweep + soil_erosion, configs/eval_blind.yaml, with the\n"
      "map fitted to the scenario's terrain), the map's `elevation` starting from the simulator's\n"
      "initial truth. Prints the height RMSE inside the cut (cells the blade went through below\n"
      "the initial surface) and outside it (split into deposit: truth moved by more than\n"
      "--change-threshold, and untouched), next to the no-update baseline (the initial map); the\n"
      "mass balance of map and truth; and the FEE geometry of every sweep\n"
      "(alpha, rho, d, w, Q) against the simulator's truth: bias, std, RMSE, 5/50/95 percentiles.\n"
      "Writes to --out: blind_heightmap.png, truth_heightmap.png, error.png and baseline_error.png\n"
      "(map - truth, red = map too low, blue = too high, fixed range +-error-range), regions.png,\n"
      "eval.tif (all of them as bands), eval.json (every figure) and extraction.csv (per sweep).\n"
      "The pipeline's `source` and `outputs` are not used. Details: docs/sim.md, 'Fig. 10 reproduction'.");
  sub->add_option("scenario", a->scenario, "Simulator scenario YAML (e.g. configs/scenarios/fig10_berm_cut.yaml)")
      ->required();
  sub->add_option("--out,-o", a->out, "Output folder (created if needed)")->capture_default_str();
  sub->add_option("--pipeline,-p", a->pipeline,
                  "Pipeline YAML to evaluate instead of the embedded blind pipeline; its map geometry is used "
                  "as written unless --fit-map; it must declare or create `elevation`");
  sub->add_flag("--fit-map", a->fit_map,
                "With --pipeline: replace its map's size and centre by the largest map (at its resolution) "
                "inside the scenario's terrain");
  sub->add_option("--threads,-j", a->threads, "Worker threads of the engine (results do not depend on it)")
      ->check(CLI::Range(1, 256));
  sub->add_option("--duration", a->duration, "Override the scenario's duration_s")->check(CLI::PositiveNumber);
  sub->add_option("--seed", a->seed, "Override the scenario's seed")->check(CLI::NonNegativeNumber);
  sub->add_option("--change-threshold", a->change_threshold,
                  "Truth height change (m) that makes a cell outside the cut count as deposit, not untouched")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  sub->add_option("--error-range", a->error_range, "Colour range of the error PNGs: +-this (m)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  sub->add_flag("--lidar", a->lidar, "Pass the scenario's LiDAR clouds to the pipeline (default: withheld, blind)");
  sub->add_flag("--quiet,-q", a->quiet, "Print only the files written");
  sub->add_option("--localisation", a->localisation,
                  "Override every machine's localisation: perfect or rtk_imu (ablation; default: the scenario's)");
  sub->add_option("--track-soil", a->track_soil,
                  "Override every machine's track-soil model: bekker or none (ablation; default: the scenario's)");
  sub->callback([&run, a] {
    run = [a]() -> int {
      sim::Scenario sc = sim::loadScenario(a->scenario);
      sim::overrideLocalisation(sc, a->localisation, "--localisation");
      sim::overrideTrackSoil(sc, a->track_soil, "--track-soil");
      if (a->duration > 0) sc.duration_s = a->duration;
      if (a->seed >= 0) sc.seed = static_cast<std::uint64_t>(a->seed);
      const bool embedded = a->pipeline.empty();
      PipelineSpec spec = embedded
          ? parsePipelineString(eval::defaultEvalPipeline(), "<embedded eval_blind.yaml>", ".")
          : parsePipelineFile(a->pipeline);
      if (a->threads > 0) spec.threads = a->threads;
      sim::Simulator simulator(sc);
      if (embedded || a->fit_map) {
        const Geometry g = sim::fitGeometry(simulator.truth(), spec.resolution);
        spec.size = g.size();
        spec.center = g.center();
      }
      if (!a->quiet && spec.source.type != "none")
        std::fprintf(stderr, "note: %s: the pipeline's source (%s) is not used; eval plays %s\n", spec.file.c_str(),
                     spec.source.type.c_str(), a->scenario.c_str());
      const PluginRegistry registry = PluginRegistry::forPipeline(spec.plugin_paths, spec.plugin_paths_where);
      auto engine = Engine::fromSpec(spec, registry);
      eval::EvalOptions opt;
      opt.change_threshold_m = a->change_threshold;
      opt.error_range_m = a->error_range;
      opt.withhold_clouds = !a->lidar;
      const bool tty = !a->quiet && isatty(fileno(stderr));
      int last_pct = -1;
      if (tty)
        opt.on_progress = [&last_pct](double t, double d) {
          const int pct = d > 0 ? static_cast<int>(100.0 * t / d) : 0;
          if (pct == last_pct) return;
          last_pct = pct;
          std::fprintf(stderr, "\r  simulating %3d%%", pct);
          std::fflush(stderr);
        };
      const eval::EvalRun r = eval::runBlindEvaluation(simulator, *engine, opt);
      if (tty) std::fprintf(stderr, "\r                     \r");
      const std::vector<std::string> files = eval::writeEvalOutputs(r, a->out);
      if (!a->quiet) {
        printRun(r);
        std::printf("\n");
      }
      for (const auto& f : files) std::printf("wrote %s\n", f.c_str());
      return kOk;
    };
  });
}}};

}  // namespace
}  // namespace terramap::cli
