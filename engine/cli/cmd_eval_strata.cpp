// `terramap eval-strata SCENARIO.yaml`: the subsurface soil memory (octomap_strata, issue #17)
// against the simulator's truth. Two figures:
//  - boundary: in every column the machine cut through a soil zone's top (the truth's bank surface
//    at the end at least one voxel below it), is the height where the removed soil changes
//    (`strata_change_z_m`) within one voxel of the zone's top?
//  - next pass: at the start of every pass, how well does the FEE index of the soil the strata
//    expect in the next cut (fee_index over strata_next_*) predict the index of the soil that
//    pass actually removes, compared with the surface-only index (fee_index over soil_*)?
// The truth comes from a run of the simulator alone (pass starts: the machine turning from
// reverse to forward); the map at each pass start from a run of the pipeline up to it (the
// simulator is deterministic per seed, so that run is the full run's beginning).
#include "command.hpp"
#include "fee_stage.hpp"

#include <terramap/core/error.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/pipeline/run.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/simulator.hpp>
#include <terramap/soil/fee_index.hpp>
#include <terramap/eval/truth_report.hpp>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>

namespace terramap::cli {
namespace {

namespace fs = std::filesystem;

struct StrataArgs {
  std::string scenario, pipeline, model, out = "out/eval_strata", zone;
  int threads = 0;
  double min_cut_m = 0.02, duration = -1;
  bool quiet = false, boundary_only = false;
  std::vector<std::string> set;  ///< strata stage parameters, KEY=VALUE (numbers)
};

/// The truth terrain's bank surface at the map's cells at one moment.
struct Snapshot {
  double t = 0;
  std::vector<double> bank;  ///< row-major over the map geometry's logical cells
};

/// Runs the simulator alone: the bank surface at the start of every forward pass after the first
/// and at the end, and the initial surface.
std::vector<Snapshot> truthSnapshots(const sim::Scenario& sc, const Geometry& g, std::vector<double>& initial,
                                     bool quiet) {
  sim::Simulator s(sc);
  const int n = g.size().x() * g.size().y();
  auto grab = [&](double t) {
    Snapshot snap;
    snap.t = t;
    snap.bank.resize(static_cast<std::size_t>(n));
    const sim::TruthTerrain& tt = s.truth();
    for (int i = 0; i < g.size().x(); ++i)
      for (int j = 0; j < g.size().y(); ++j) {
        const Position p = g.positionOf(Index(i, j));
        snap.bank[static_cast<std::size_t>(i * g.size().y() + j)] = tt.undisturbedAt(p.x(), p.y());
      }
    return snap;
  };
  initial.resize(static_cast<std::size_t>(n));
  for (int i = 0; i < g.size().x(); ++i)
    for (int j = 0; j < g.size().y(); ++j) {
      const Position p = g.positionOf(Index(i, j));
      initial[static_cast<std::size_t>(i * g.size().y() + j)] = s.truth().initialHeightAt(p.x(), p.y());
    }
  std::vector<Snapshot> out;
  std::vector<Event> ev;
  bool reversing = false;
  while (s.next(ev)) {
    ev.clear();
    const double v = s.machineTruth(0).twist_base(0);
    if (v < -0.05) reversing = true;
    if (reversing && v > 0.05) {
      reversing = false;
      out.push_back(grab(s.time()));
      if (!quiet) std::fprintf(stderr, "\r  truth: pass %zu starts at %.1f s   ", out.size() + 1, s.time());
    }
  }
  out.push_back(grab(s.time()));
  if (!quiet) std::fprintf(stderr, "\n");
  return out;
}

/// A band of a raster by name, sampled at the map geometry's cells (NaN where absent).
std::vector<double> band(const io::Raster& r, const std::string& name, const Geometry& g, const std::string& file) {
  const io::RasterBand* b = nullptr;
  for (const io::RasterBand& x : r.bands)
    if (x.description == name) b = &x;
  if (!b) throw InputError(file + ": no band '" + name + "'");
  if (!r.geotransform) throw InputError(file + ": no geotransform");
  const auto& gt = *r.geotransform;
  std::vector<double> out(static_cast<std::size_t>(g.size().x() * g.size().y()), std::nan(""));
  for (int i = 0; i < g.size().x(); ++i)
    for (int j = 0; j < g.size().y(); ++j) {
      const Position p = g.positionOf(Index(i, j));
      const long c = static_cast<long>(std::floor((p.x() - gt[0]) / gt[1]));
      const long rr = static_cast<long>(std::floor((p.y() - gt[3]) / gt[5]));
      if (c < 0 || rr < 0 || c >= r.width || rr >= r.height) continue;
      out[static_cast<std::size_t>(i * g.size().y() + j)] = b->values(rr, c);
    }
  return out;
}

/// The soil the truth holds between two depths below the initial surface, averaged in 1 cm steps.
fee::Soil truthSoilBetween(const sim::SoilField& f, double x, double y, double d0, double d1) {
  const int n = std::max(1, static_cast<int>(std::ceil((d1 - d0) / 0.01)));
  fee::Soil s{0, 0, 0, 0, 0};
  for (int k = 0; k < n; ++k) {
    const fee::Soil& q = f.at(x, y, d0 + (k + 0.5) * (d1 - d0) / n).fee;
    s.c_pa += q.c_pa / n;
    s.phi_rad += q.phi_rad / n;
    s.gamma_n_m3 += q.gamma_n_m3 / n;
    s.ca_pa += q.ca_pa / n;
    s.delta_rad += q.delta_rad / n;
  }
  return s;
}

std::string paramText(const StageSpec& st, const std::string& key, const std::string& def) {
  const auto it = st.params.find(key);
  if (it == st.params.end()) return def;
  const auto* s = std::get_if<std::string>(&it->second.value);
  return s ? *s : def;
}

struct ErrorSum {
  long n = 0;
  double abs = 0, truth = 0, sq = 0;
  void add(double pred, double truth_v) {
    ++n;
    abs += std::abs(pred - truth_v);
    sq += (pred - truth_v) * (pred - truth_v);
    truth += truth_v;
  }
  nlohmann::json json() const {
    return {{"cells", n}, {"mae_n", n ? abs / n : std::nan("")}, {"rmse_n", n ? std::sqrt(sq / n) : std::nan("")},
            {"relative", truth > 0 ? abs / truth : std::nan("")}};
  }
};

int runEvalStrata(const StrataArgs& a) {
  const fs::path configs = embeddedDemoBaseDir();
  PipelineSpec spec = parsePipelineFile(a.pipeline.empty() ? (configs / "strata.yaml").string() : a.pipeline);
  if (spec.source.type != "sim")
    throw ConfigError(spec.file + ": eval-strata needs a `sim` source (it compares with the simulator's truth)");
  const std::string scenario = fs::absolute(a.scenario).string();
  spec.source.settings["scenario"] = RawParam{ParamValue{scenario}, "eval-strata SCENARIO"};
  sim::Scenario sc = sim::loadScenario(scenario);
  if (a.duration > 0) sc.duration_s = std::min(sc.duration_s, a.duration);
  // The zone whose top is the boundary: --zone, else the first zone that starts below the surface.
  const sim::SoilZone* zone = nullptr;
  for (const sim::SoilZone& z : sc.zones)
    if (a.zone.empty() ? z.depth_min_m > 0 : z.name == a.zone) {
      zone = &z;
      break;
    }
  if (!zone) throw ConfigError(scenario + ": no soil zone " + (a.zone.empty() ? "below the surface (depth_m: [>0, ...])" : "named '" + a.zone + "'"));
  const StageSpec *strata = nullptr, *surface = nullptr, *next = nullptr;
  for (StageSpec& st : spec.stages) {
    if (st.type == "soil_pinn" && !a.model.empty())
      st.params["model"] = RawParam{ParamValue{fs::absolute(a.model).string()}, "--model"};
    if (st.type == "octomap_strata") {
      strata = &st;
      for (const std::string& kv : a.set) {
        const auto eq = kv.find('=');
        if (eq == std::string::npos) throw ConfigError("--set " + kv + ": expected KEY=VALUE");
        try {
          const std::string v = kv.substr(eq + 1);
          std::size_t used = 0;
          const long n = std::stol(v, &used);
          st.params[kv.substr(0, eq)] = used == v.size() ? RawParam{ParamValue{n}, "--set"}
                                                          : RawParam{ParamValue{std::stod(v)}, "--set"};
        } catch (const std::exception&) {
          throw ConfigError("--set " + kv + ": the value must be a number");
        }
      }
    }
    if (st.type == "fee_index") {
      const std::string prefix = paramText(st, "soil_prefix", "soil_");
      if (prefix == "soil_") surface = &st;
      if (prefix == "strata_next_") next = &st;
    }
  }
  if (!strata || !surface || !next)
    throw ConfigError(spec.file + ": eval-strata needs an octomap_strata stage and two fee_index stages, one over "
                      "soil_* and one with soil_prefix: strata_next_");
  const std::string out_surface = paramText(*surface, "output", "fee_index"), out_next = paramText(*next, "output", "fee_index");
  const soil::FeeIndexConfig cut = feeIndexConfigOf(spec, *surface);
  const Geometry g = spec.geometry();
  const double voxel = [&] {
    const auto it = strata->params.find("resolution_m");
    const double* v = it == strata->params.end() ? nullptr : std::get_if<double>(&it->second.value);
    return v ? *v : 0.05;
  }();
  fs::create_directories(a.out);

  if (!a.quiet) std::printf("eval-strata %s: truth run of the simulator\n", a.scenario.c_str());
  std::vector<double> initial;
  const std::vector<Snapshot> snaps = truthSnapshots(sc, g, initial, a.quiet);
  sim::Simulator probe(sc);  // its SoilField: the truth soil by depth
  const sim::SoilField& field = probe.soil();

  // The map at each pass start (snaps[0 .. K-2]) and at the end (snaps[K-1]).
  auto runTo = [&](double t, const fs::path& dir, bool last) {
    PipelineSpec s = spec;
    s.source.settings["max_time_s"] = RawParam{ParamValue{t}, "eval-strata"};
    for (StageSpec& st : s.stages)
      if (st.type == "octomap_strata") {
        for (const char* k : {"save_path", "octovis_path", "section_png"}) {
          const std::string name = std::string(k) == "save_path" ? "strata.ot" : std::string(k) == "octovis_path" ? "strata_octovis.ot" : "section_c.png";
          st.params[k] = RawParam{ParamValue{last ? (fs::absolute(dir) / name).string() : std::string()}, "eval-strata"};
        }
      }
    if (!last) {
      s.outputs.geotiff = {out_surface, out_next};
      s.outputs.png.clear();
      s.outputs.png_all = false;
      s.outputs.snapshot = false;
      s.outputs.report = false;
    } else {
      for (const std::string& l : {out_surface, out_next, std::string("strata_change_z_m"), std::string("strata_cut_m")})
        if (std::find(s.outputs.geotiff.begin(), s.outputs.geotiff.end(), l) == s.outputs.geotiff.end()) s.outputs.geotiff.push_back(l);
    }
    RunOptions o;
    o.out_dir = dir.string();
    o.threads = a.threads;
    if (last) o.compare_truth = eval::compareWithSourceTruth;
    runPipeline(s, o);
    return io::readRaster(dir / "map.tif");
  };

  nlohmann::json report;
  report["scenario"] = scenario;
  report["zone"] = zone->name;
  report["voxel_m"] = voxel;
  ErrorSum total_surface, total_next;
  nlohmann::json passes = nlohmann::json::array();
  if (!a.quiet)
    std::printf("next pass: FEE index of the soil each pass removed (truth) against the map's indices at its start\n"
                "  %-5s %7s %7s %8s %14s %14s\n", "pass", "start", "end", "cells", "surface MAE", "strata MAE");
  for (std::size_t k = 0; !a.boundary_only && k + 1 < snaps.size(); ++k) {
    const fs::path dir = fs::path(a.out) / ("pass_" + std::to_string(k + 2));
    const io::Raster r = runTo(snaps[k].t, dir, false);
    const std::vector<double> fs_ = band(r, out_surface, g, (dir / "map.tif").string());
    const std::vector<double> fn = band(r, out_next, g, (dir / "map.tif").string());
    ErrorSum es, en;
    for (int i = 0; i < g.size().x(); ++i)
      for (int j = 0; j < g.size().y(); ++j) {
        const std::size_t c = static_cast<std::size_t>(i * g.size().y() + j);
        const double b0 = snaps[k].bank[c], b1 = snaps[k + 1].bank[c];
        if (!(b0 - b1 >= a.min_cut_m) || !std::isfinite(fs_[c]) || !std::isfinite(fn[c])) continue;
        const Position p = g.positionOf(Index(i, j));
        const fee::Soil truth = truthSoilBetween(field, p.x(), p.y(), initial[c] - b0, initial[c] - b1);
        const double ti = soil::feeIndexOf(truth, fee::Soil{}, cut).index_n;
        if (!std::isfinite(ti)) continue;
        es.add(fs_[c], ti);
        en.add(fn[c], ti);
        total_surface.add(fs_[c], ti);
        total_next.add(fn[c], ti);
      }
    passes.push_back({{"pass", k + 2}, {"start_s", snaps[k].t}, {"end_s", snaps[k + 1].t}, {"surface", es.json()}, {"strata", en.json()}});
    if (!a.quiet)
      std::printf("  %-5zu %7.1f %7.1f %8ld %11.2f kN %11.2f kN\n", k + 2, snaps[k].t, snaps[k + 1].t, es.n,
                  es.n ? es.abs / es.n * 1e-3 : std::nan(""), en.n ? en.abs / en.n * 1e-3 : std::nan(""));
  }
  report["next_pass"] = {{"passes", passes}, {"surface", total_surface.json()}, {"strata", total_next.json()}};
  if (!a.quiet)
    std::printf("  all   %23ld %11.2f kN %11.2f kN  (relative %.1f %% / %.1f %%)\n", total_surface.n,
                total_surface.n ? total_surface.abs / total_surface.n * 1e-3 : std::nan(""),
                total_next.n ? total_next.abs / total_next.n * 1e-3 : std::nan(""), 100 * total_surface.json()["relative"].get<double>(),
                100 * total_next.json()["relative"].get<double>());

  // The boundary, from the full run.
  const io::Raster r = runTo(snaps.back().t, a.out, true);
  const std::vector<double> cz = band(r, "strata_change_z_m", g, (fs::path(a.out) / "map.tif").string());
  long cut_through = 0, found = 0, within = 0;
  double abs_err = 0;
  for (int i = 0; i < g.size().x(); ++i)
    for (int j = 0; j < g.size().y(); ++j) {
      const std::size_t c = static_cast<std::size_t>(i * g.size().y() + j);
      const Position p = g.positionOf(Index(i, j));
      const double top = initial[c] - zone->depthMinAt(p.x(), p.y());
      // Cut through: the bank at the end at least one voxel below the zone's top.
      if (!(snaps.back().bank[c] <= top - voxel)) continue;
      ++cut_through;
      if (!std::isfinite(cz[c])) continue;
      ++found;
      abs_err += std::abs(cz[c] - top);
      if (std::abs(cz[c] - top) <= voxel) ++within;
    }
  report["boundary"] = {{"columns_cut_through", cut_through}, {"columns_with_change", found}, {"within_one_voxel", within},
                        {"fraction_within", cut_through ? static_cast<double>(within) / cut_through : std::nan("")},
                        {"mae_m_where_found", found ? abs_err / found : std::nan("")}};
  if (!a.quiet)
    std::printf("boundary (top of '%s'): %ld columns cut through it, a change found in %ld, within one voxel (%.2f m) in "
                "%ld = %.1f %% (MAE where found %.3f m)\n",
                zone->name.c_str(), cut_through, found, voxel, within, cut_through ? 100.0 * within / cut_through : std::nan(""),
                found ? abs_err / found : std::nan(""));
  std::ofstream(fs::path(a.out) / "eval_strata.json") << report.dump(2) << "\n";
  if (!a.quiet) std::printf("wrote %s\n", (fs::path(a.out) / "eval_strata.json").string().c_str());
  return kOk;
}

Registrar reg{Command{"eval-strata", [](CLI::App& app, std::function<int()>& run) {
  auto a = std::make_shared<StrataArgs>();
  auto* sub = app.add_subcommand("eval-strata",
      "The subsurface soil memory (octomap_strata) against the simulator's truth: run SCENARIO\n"
      "through configs/strata.yaml and report (1) in the columns cut through a soil zone's top, how\n"
      "often the height where the removed soil changes lies within one voxel of it, and (2) per pass,\n"
      "how well the FEE index of the soil expected in the next cut predicts the index of the soil the\n"
      "pass removed, against the surface-only index. Writes eval_strata.json and the full run's\n"
      "outputs (with strata.ot, strata_octovis.ot, section_c.png) to --out.");
  sub->add_option("scenario", a->scenario, "Scenario YAML")->required()->check(CLI::ExistingFile);
  sub->add_option("--pipeline", a->pipeline, "Pipeline YAML (default: configs/strata.yaml of the source tree)");
  sub->add_option("--model", a->model, "Soil estimator file for every soil_pinn stage");
  sub->add_option("--zone", a->zone, "Soil zone whose top is the boundary (default: the first below the surface)");
  sub->add_option("--min-cut", a->min_cut_m, "A pass must remove at least this much bank soil from a cell (m)")
      ->check(CLI::PositiveNumber);
  sub->add_option("--out,-o", a->out, "Output folder");
  sub->add_option("--duration", a->duration, "Simulate at most this many seconds")->check(CLI::PositiveNumber);
  sub->add_option("--threads,-j", a->threads, "Worker threads")->check(CLI::Range(1, 256));
  sub->add_flag("--boundary-only", a->boundary_only, "Skip the per-pass runs: the boundary figure from the full run only");
  sub->add_option("--set", a->set, "Numeric octomap_strata parameter for this run, KEY=VALUE (repeatable)");
  sub->add_flag("--quiet,-q", a->quiet, "Print nothing but errors");
  sub->callback([&run, a] { run = [a]() -> int { return runEvalStrata(*a); }; });
}}};

}  // namespace
}  // namespace terramap::cli
