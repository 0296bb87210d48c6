// `terramap eval-soil-map SCENARIO.yaml`: the soil map against the simulator's truth (paper
// §3.2, Fig. 12). Runs configs/soil_map.yaml (LiDAR, blade, erosion, soil_fit, soil_bayes,
// fee_index) on the scenario and prints what the run report's truth.soil holds
// (eval/truth_report.hpp): per property the error and calibration of the soil layers, per soil
// zone the FEE index and its AUC against the default soil.
#include "command.hpp"
#include "stage_params.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/pipeline/source.hpp>
#include <terramap/io/render.hpp>
#include <terramap/eval/truth_report.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/soil/fee_index.hpp>
#include <terramap/soil/soil_parameters.hpp>
#include <terramap/pipeline/run.hpp>
#include <terramap/sim/scenario.hpp>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>

namespace terramap::cli {
namespace {

namespace fs = std::filesystem;

struct SoilMapArgs {
  std::string scenario, pipeline, model, out = "out/eval_soil_map";
  std::vector<std::string> set;
  int threads = 0;
  double duration = -1;
  bool quiet = false;
};

double num(const nlohmann::json& j) { return j.is_number() ? j.get<double>() : std::nan(""); }

/// The reference cut of the pipeline's (first) fee_index stage; empty without one.
std::optional<soil::FeeIndexConfig> referenceCut(const PipelineSpec& spec) {
  for (const StageSpec& st : spec.stages)
    if (st.type == "fee_index") return feeIndexConfigOf(spec, st);
  return std::nullopt;
}

void printSoil(const nlohmann::json& truth_soil, const sim::Scenario& sc, const std::optional<soil::FeeIndexConfig>& cut) {
  std::printf("soil layers against the truth soil at the surface (%ld cells with an estimate):\n",
              truth_soil.value("cells_estimated", 0L));
  std::printf("  %-12s %8s %12s %12s %12s %10s %10s %16s\n", "property", "cells", "MAE", "bias", "RMSE", "in 1 sd",
              "in 2 sd", "in 1 sd, inside");
  for (int k = 0; k < soil::kSoilParamCount; ++k) {
    const char* name = soil::kSoilParams[k].layer;
    const auto& [scale, unit] = soil::kSoilDisplay[k];
    const nlohmann::json& p = truth_soil["properties"][name];
    const long inside = p.value("cells_inside", 0L);
    char in_range[32] = "    (no cells)";
    if (inside > 0) std::snprintf(in_range, sizeof in_range, "%6.1f%% of %ld", 100 * num(p["within_1sigma_inside"]), inside);
    std::printf("  %-12s %8ld %8.2f %-3s %8.2f %-3s %8.2f %-3s %9.1f%% %9.1f%% %16s\n", name, p.value("cells", 0L),
                num(p["mae"]) * scale, unit, num(p["bias"]) * scale, unit, num(p["rmse"]) * scale, unit,
                100 * num(p["within_1sigma"]), 100 * num(p["within_2sigma"]), in_range);
  }
  std::printf("  (calibrated variances put 68.3 %% of the truths within 1 sd and 95.4 %% within 2; \"inside\": the\n"
              "   cells whose truth lies inside its range, by 1 %% of it: at an end every estimate near it covers it)\n");
  const auto zoneName = [&](int id) {
    return id < 0 ? std::string("default soil")
                  : (id < static_cast<int>(sc.zones.size()) ? sc.zones[static_cast<std::size_t>(id)].name
                                                            : "zone " + std::to_string(id));
  };
  if (truth_soil.contains("properties_by_zone")) {
    std::printf("bias per truth soil zone:\n");
    for (const auto& [key, zp] : truth_soil["properties_by_zone"].items()) {
      std::printf("  %-16s", zoneName(std::stoi(key)).c_str());
      for (int k = 0; k < soil::kSoilParamCount; ++k) {
        const char* name = soil::kSoilParams[k].layer;
        if (!zp.contains(name)) continue;
        const auto& [scale, unit] = soil::kSoilDisplay[k];
        std::printf(" %s %+.2f %s", soil::kSoilParams[k].name, num(zp[name]["bias"]) * scale, unit);
      }
      std::printf("\n");
    }
  }
  if (!truth_soil.contains("fee_index")) return;
  std::printf("FEE index per truth soil zone:\n");
  for (const nlohmann::json& z : truth_soil["fee_index"]["zones"]) {
    const int id = z["zone"].get<int>();
    const std::string name = zoneName(id);
    std::printf("  %-16s %8ld cells, mean %8.2f kN", name.c_str(), z.value("cells", 0L), num(z["mean_index_n"]) * 1e-3);
    // Zones have one soil each (at the surface): the index a perfect estimator would give.
    const auto soilOf = [&](int zone) -> const fee::Soil& {
      return zone >= 0 && zone < static_cast<int>(sc.zones.size()) ? sc.zones[static_cast<std::size_t>(zone)].soil.fee
                                                                    : sc.default_soil.fee;
    };
    double truth = std::nan(""), truth_default = std::nan("");
    if (cut) {
      // What fee_index would show with a perfect estimator (variances 0: the index alone).
      truth = soil::feeIndexOf(soilOf(id), fee::Soil{}, *cut).index_n;
      truth_default = soil::feeIndexOf(sc.default_soil.fee, fee::Soil{}, *cut).index_n;
      std::printf(" (truth soil: %.2f kN)", truth * 1e-3);
    }
    if (z.contains("auc_vs_default")) {
      // report.json's AUC is P(zone cell > default cell). Where the truth's index is lower in
      // the zone (dense gravel against cohesive loam), separating it means ranking it lower.
      const double auc = num(z["auc_vs_default"]);
      if (truth < truth_default)
        std::printf(", AUC in the truth's order (zone lower) %.3f", 1.0 - auc);
      else
        std::printf(", AUC against the default soil %.3f", auc);
    }
    std::printf("\n");
  }
}

/// The index a perfect estimator would map (`truth_fee_index`: the reference cut on the truth
/// soil at each cell's surface), and `fee_index_vs_truth.png`: the mapped and the truth index
/// side by side on one colour range, the truth's soil zones outlined on both (paper Fig. 12).
void addTruthIndex(LayeredMap& map, const Source& src, const soil::FeeIndexConfig& cut, const fs::path& out,
                   TruthComparison& tc) {
  const Geometry& g = map.geometry();
  std::array<Eigen::MatrixXf, soil::kSoilParamCount> truth;
  for (int k = 0; k < soil::kSoilParamCount; ++k) {
    truth[static_cast<std::size_t>(k)].resize(g.size().x(), g.size().y());
    if (!src.truth(soil::kSoilParams[k].layer, g, truth[static_cast<std::size_t>(k)])) return;
  }
  const LayerId id = map.addLayer("truth_fee_index", "N");
  for (int i = 0; i < g.size().x(); ++i)
    for (int j = 0; j < g.size().y(); ++j) {
      soil::SoilParamVector v{};
      for (int k = 0; k < soil::kSoilParamCount; ++k) v[static_cast<std::size_t>(k)] = truth[static_cast<std::size_t>(k)](i, j);
      const double f = std::isfinite(v[0]) ? soil::feeIndexOf(soil::toFee(v), fee::Soil{}, cut).index_n : std::nan("");
      map.set(id, Index(i, j), static_cast<float>(f));
    }
  tc.layers.push_back("truth_fee_index");
  // One colour range for both pictures: the mapped index's cells and the truth's.
  const io::ValueRange a = io::robustRange(map, map.layerId("fee_index")), b = io::robustRange(map, id, 0.0, 100.0);
  io::RenderOptions ro;
  ro.range = io::ValueRange{std::min(a.min, b.min), std::max(a.max, b.max)};
  ro.scale = std::max(1, 600 / std::max(g.size().x(), g.size().y()));
  ro.nan_color = io::Rgba{128, 128, 128, 255};
  io::Annotation an;
  an.outline_regions = map.hasLayer("truth_soil_zone") ? "truth_soil_zone" : "";
  an.title = "fee_index: mapped [kN]";
  an.caption = "white lines: the simulator's soil zones";
  if (const auto z = tc.categories.find("truth_soil_zone"); z != tc.categories.end())
    for (const auto& [v, name] : z->second) an.region_names.emplace_back(v, name.substr(0, name.find(" (")));
  const io::Image left = io::renderPicture(map, "fee_index", ro, an);
  an.title = "truth_fee_index: the truth soil [kN]";
  const io::Image right = io::renderPicture(map, "truth_fee_index", ro, an);
  io::Image both;
  both.width = left.width + right.width;
  both.height = std::max(left.height, right.height);
  both.rgba.assign(static_cast<std::size_t>(both.width) * static_cast<std::size_t>(both.height) * 4, 255);
  // Bottom-aligned: a picture whose colour bar clips has one subtitle line more, and the two
  // maps must still sit side by side row for row (below the map both are laid out alike).
  auto blit = [&](const io::Image& im, int x0) {
    const int y0 = both.height - im.height;
    for (int r = 0; r < im.height; ++r)
      std::copy_n(im.rgba.begin() + static_cast<std::ptrdiff_t>(r) * im.width * 4, im.width * 4,
                  both.rgba.begin() + (static_cast<std::ptrdiff_t>(r + y0) * both.width + x0) * 4);
  };
  blit(left, 0);
  blit(right, left.width);
  io::writePng(both, out / "fee_index_vs_truth.png");
}

Registrar reg{Command{"eval-soil-map", [](CLI::App& app, std::function<int()>& run) {
  auto a = std::make_shared<SoilMapArgs>();
  auto* sub = app.add_subcommand("eval-soil-map",
      "The soil map against the simulator's truth (paper Fig. 12): run SCENARIO through\n"
      "configs/soil_map.yaml (LiDAR, blade, erosion, soil_fit, soil_bayes, fee_index) and print\n"
      "the soil layers' error and calibration per property and the FEE index per soil zone with\n"
      "its AUC against the default soil. Writes the run's outputs to --out: map.tif (with\n"
      "truth_soil_zone and truth_fee_index, the index of the truth soil), fee_index.png and\n"
      "soil_*.png with the zones outlined, fee_index_vs_truth.png (mapped and truth index side by\n"
      "side on one colour range), report.json (truth.soil holds every figure printed).");
  sub->add_option("scenario", a->scenario, "Scenario YAML")->required()->check(CLI::ExistingFile);
  sub->add_option("--pipeline", a->pipeline, "Pipeline YAML (default: configs/soil_map.yaml of the source tree)");
  sub->add_option("--model", a->model,
                  "Soil estimator file for every soil_pinn stage (default: the pipeline's own `model`); without "
                  "--pipeline, configs/soil_map_pinn.yaml (the network in soil_fit's place) is run");
  sub->add_option("--out,-o", a->out, "Output folder");
  sub->add_option("--threads,-j", a->threads, "Worker threads")->check(CLI::Range(1, 256));
  sub->add_option("--duration", a->duration, "Simulate at most this many seconds")->check(CLI::PositiveNumber);
  sub->add_option("--set", a->set,
                  "Stage parameter for this run, STAGE.KEY=VALUE (repeatable; e.g. --set bayes.prior=config)");
  sub->add_flag("--quiet,-q", a->quiet, "Print nothing but errors");
  sub->callback([&run, a] {
    run = [a]() -> int {
      const fs::path configs = embeddedDemoBaseDir();
      // A model names the network: without a pipeline, the soil map with the network in it.
      const char* fallback = a->model.empty() ? "soil_map.yaml" : "soil_map_pinn.yaml";
      PipelineSpec spec = parsePipelineFile(a->pipeline.empty() ? (configs / fallback).string() : a->pipeline);
      if (spec.source.type != "sim")
        throw ConfigError(spec.file + ": eval-soil-map needs a `sim` source (it compares with the simulator's truth)");
      const std::string scenario = fs::absolute(a->scenario).string();
      spec.source.settings["scenario"] = RawParam{ParamValue{scenario}, "eval-soil-map SCENARIO"};
      if (a->duration > 0) spec.source.settings["max_time_s"] = RawParam{ParamValue{a->duration}, "--duration"};
      // A soil estimator stage: the network (soil_pinn, the only one --model applies to) or the
      // pooled fit (soil_fit).
      bool has_estimator = false, has_pinn = false;
      for (StageSpec& st : spec.stages) {
        has_estimator = has_estimator || st.type == "soil_pinn" || st.type == "soil_fit";
        if (st.type != "soil_pinn") continue;
        has_pinn = true;
        if (!a->model.empty()) st.params["model"] = RawParam{ParamValue{fs::absolute(a->model).string()}, "--model"};
      }
      if (!has_estimator) throw ConfigError(spec.file + ": eval-soil-map needs a soil_pinn or soil_fit stage");
      if (!has_pinn && !a->model.empty())
        throw ConfigError(spec.file + ": --model names a soil_pinn model, and the pipeline has no soil_pinn stage");
      applyParamOverrides(spec, a->set);
      RunOptions o;
      o.out_dir = a->out;
      o.threads = a->threads;
      const std::optional<soil::FeeIndexConfig> cut = referenceCut(spec);
      const fs::path out = a->out;
      o.compare_truth = [cut, out](LayeredMap& map, const Source& src) {
        TruthComparison tc = eval::compareWithSourceTruth(map, src);
        if (cut && map.hasLayer("fee_index")) {
          fs::create_directories(out);
          addTruthIndex(map, src, *cut, out, tc);
        }
        return tc;
      };
      const RunResult r = runPipeline(spec, o);
      const nlohmann::json truth = r.truth_json.empty() ? nlohmann::json() : nlohmann::json::parse(r.truth_json);
      if (!truth.contains("soil"))
        throw ConfigError(spec.file + ": the run produced no soil layers to compare (needs soil_bayes)");
      if (!a->quiet) {
        std::printf("eval-soil-map %s: %.1f s wall, outputs in %s\n", a->scenario.c_str(), r.report.wall_s,
                    r.out_dir.c_str());
        printSoil(truth["soil"], sim::loadScenario(scenario), cut);
        if (fs::exists(out / "fee_index_vs_truth.png")) std::printf("wrote %s\n", (out / "fee_index_vs_truth.png").string().c_str());
      }
      return kOk;
    };
  });
}}};

}  // namespace
}  // namespace terramap::cli
