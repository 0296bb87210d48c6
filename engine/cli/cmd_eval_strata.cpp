// `terramap eval-strata SCENARIO.yaml`: the subsurface soil memory (octomap_strata; ALGORITHMS.md §K)
// against the simulator's truth. Two figures:
//  - boundary: in every column the machine cut through a soil zone's top (the truth's bank surface
//    at the end at least one voxel below it), is the height where the removed soil changes
//    (`strata_change_z_m`) within one voxel of the zone's top, and its depth below the strata's
//    first surface (`strata_change_depth_m`) within one voxel of the zone's depth?
//  - next pass, force (the figure): at the start of every pass, the map's two soil
//    beliefs under the blade's edge (strata_next_*, the soil the strata expect in the next cut,
//    and the surface-only soil_*) put through the FEE on the geometry of every step the pass cut,
//    against the simulator's truth force along the push (the draft) in that step; the FEE of the
//    truth soil on the same steps is the floor.
//  - next pass, index: how well the FEE index of the reference cut over each belief (fee_next,
//    fee_index) predicts the index of the truth soil each cell lost in that pass.
// The truth comes from a run of the simulator alone (pass starts: the machine turning from
// reverse to forward); the map from one run of the pipeline, its index layers sampled at the
// first event of each pass start (the simulator is deterministic per seed: both runs see the
// same machine). --oracle-noise swaps soil_pinn for soil_oracle fed from the truth run, to tell
// the estimator's share of the error from the strata's.
#include "command.hpp"
#include "stage_params.hpp"

#include <terramap/core/error.hpp>
#include <terramap/io/atomic_file.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/pipeline/run.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/simulator.hpp>
#include <terramap/soil/fee_index.hpp>
#include <terramap/soil/soil_parameters.hpp>
#include <terramap/eval/truth_report.hpp>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
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
  std::string scenario, pipeline, model, out = "out/eval_strata", zone, localisation;
  int threads = 0;
  double min_cut_m = 0.02, duration = -1;
  /// --oracle-noise: the oracle's noise per property, as a fraction of the two soils' difference
  /// (so the oracle's d' between them is 1 / this); < 0 = no oracle (soil_pinn estimates).
  double oracle_noise = -1;
  bool quiet = false, boundary_only = false;
  std::vector<std::string> set;  ///< strata stage parameters, KEY=VALUE (numbers)
};

/// The truth terrain's bank surface at the map's cells at one moment.
struct Snapshot {
  double t = 0;
  std::vector<double> bank;  ///< row-major over the map geometry's logical cells
};

/// The soil the blade was cutting, per observation period of the truth run (NaN: not cutting).
struct CutSoil {
  std::vector<double> t;
  std::vector<soil::SoilParamVector> soil;
};

/// One observation period of the truth run in which the blade cut soil moving forward: where its
/// edge was, the geometry the simulator's FEE saw there and the force the truth physics produced,
/// for the next-pass force figure; `surface` and `strata` are the map's soil under the edge at the
/// start of the step's pass (filled during the pipeline run; NaN where the map had none).
struct ForceStep {
  double t = 0;
  Eigen::Vector3d edge = Eigen::Vector3d::Zero();     ///< cutting-edge centre, map frame, m
  Eigen::Vector3d lateral = Eigen::Vector3d::UnitY();  ///< along the edge, unit
  fee::Geometry geometry;  ///< the simulator's summary of the cut (depth-weighted over its slices)
  fee::Soil truth_soil;    ///< the soil the truth cut (depth-weighted over its slices)
  /// The truth force without its sensor noise (MachineTruth::force_quiet_map_N), the blade's on
  /// the soil (as fee::Result::F_total_N) along its push and up, N: the draft (x) is what the
  /// FEE predictions are judged against, the vertical shows why (nextPassForces).
  Eigen::Vector2d force_n = Eigen::Vector2d::Zero();
  fee::Soil surface{NAN, NAN, NAN, NAN, NAN}, strata{NAN, NAN, NAN, NAN, NAN};
};

/// Runs the simulator alone: the bank surface at the start of every forward pass after the first
/// and at the end, the initial surface, the soil the blade cut when, and the steps it cut in.
std::vector<Snapshot> truthSnapshots(const sim::Scenario& sc, const Geometry& g, std::vector<double>& initial,
                                     CutSoil& cut_soil, std::vector<ForceStep>& steps, bool quiet) {
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
    const sim::MachineTruth& mt = s.machineTruth(0);
    const sim::FeeTruth& f = mt.fee;
    cut_soil.t.push_back(s.time());
    cut_soil.soil.push_back({f.c_pa, f.phi_rad, f.ca_pa, f.delta_rad, f.gamma_n_m3});
    const double v = mt.twist_base(0);
    if (v > 0.05 && !mt.stalled && f.cutting_slices > 0 && f.invalid_slices == 0 && std::isfinite(f.depth_m)) {
      ForceStep st;
      st.t = s.time();
      st.edge = mt.T_map_blade.translation();
      st.lateral = mt.T_map_blade.linear().col(1);
      st.geometry = {f.alpha_rad, f.rho_rad, f.depth_m, f.width_m, f.q_n};
      st.truth_soil = soil::toFee(cut_soil.soil.back());
      // The push direction as the simulator takes it: the blade's x axis on the ground plane.
      Eigen::Vector3d push = mt.T_map_blade.linear().col(0);
      push.z() = 0;
      if (push.norm() > 1e-6) {
        push.normalize();
        st.force_n = {-mt.force_quiet_map_N.dot(push), -mt.force_quiet_map_N.z()};
        steps.push_back(st);
      }
    }
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

struct ErrorSum {
  long n = 0;
  double abs = 0, truth = 0, sq = 0;
  std::vector<double> errors;  ///< |pred - truth| each, for the median
  void add(double pred, double truth_v) {
    const double e = pred - truth_v;
    ++n;
    errors.push_back(std::abs(e));
    abs += std::abs(e);
    sq += e * e;
    truth += truth_v;
  }
  void merge(const ErrorSum& o) {
    errors.insert(errors.end(), o.errors.begin(), o.errors.end());
    n += o.n;
    abs += o.abs;
    truth += o.truth;
    sq += o.sq;
  }
  double mae() const { return n ? abs / n : std::nan(""); }
  double relative() const { return truth > 0 ? abs / truth : std::nan(""); }
  /// The median absolute error: a few predictions near the FEE's singularity (η → π) can carry
  /// the mean alone.
  double median() const {
    if (errors.empty()) return std::nan("");
    std::vector<double> e = errors;
    const auto mid = e.begin() + static_cast<std::ptrdiff_t>(e.size() / 2);
    std::nth_element(e.begin(), mid, e.end());
    if (e.size() % 2 == 1) return *mid;
    return 0.5 * (*mid + *std::max_element(e.begin(), mid));
  }
  /// `count` names what was counted (cells, steps).
  nlohmann::json json(const char* count = "cells") const {
    return {{count, n},
            {"mae_n", mae()},
            {"rmse_n", n ? std::sqrt(sq / n) : std::nan("")},
            {"relative", relative()},
            {"median_abs_n", median()}};
  }
};

/// What eval-strata needs from the pipeline: its strata stage and its two index layers.
struct Stages {
  std::string surface_index, next_index;  ///< fee_index outputs over soil_* and strata_next_*
  soil::FeeIndexConfig cut;               ///< the surface index's reference cut
  double voxel_m = 0;                     ///< the strata's resolution
};

/// Finds the stages (and applies --model and --set to them). \throws ConfigError.
Stages findStages(PipelineSpec& spec, const StrataArgs& a) {
  Stages out;
  StageSpec *strata = nullptr, *surface = nullptr, *next = nullptr;
  for (StageSpec& st : spec.stages) {
    if (st.type == "soil_pinn" && !a.model.empty() && a.oracle_noise < 0)
      st.params["model"] = RawParam{ParamValue{fs::absolute(a.model).string()}, "--model"};
    if (st.type == "octomap_strata") strata = &st;
    if (st.type == "fee_index") {
      const std::string prefix = stageParams(spec, st).getString("soil_prefix");
      if (prefix == "soil_") surface = &st;
      if (prefix == "strata_next_") next = &st;
    }
  }
  if (!strata || !surface || !next)
    throw ConfigError(spec.file + ": eval-strata needs an octomap_strata stage and two fee_index stages, one over "
                      "soil_* and one with soil_prefix: strata_next_");
  // A bare KEY=VALUE is the octomap_strata stage's (the form this command took first); every
  // override then goes through the pipeline's one mechanism (values read as YAML, checked by the
  // stage's schema).
  std::vector<std::string> overrides;
  for (const std::string& kv : a.set) {
    const auto eq = kv.find('=');
    const bool staged = eq != std::string::npos && kv.substr(0, eq).find('.') != std::string::npos;
    overrides.push_back(staged || eq == std::string::npos ? kv : strata->name + "." + kv);
  }
  applyParamOverrides(spec, overrides);
  out.surface_index = stageParams(spec, *surface).getString("output");
  out.next_index = stageParams(spec, *next).getString("output");
  out.cut = feeIndexConfigOf(spec, *surface);
  out.voxel_m = stageParams(spec, *strata).getDouble("resolution_m");
  // The full run's strata files, in the output folder.
  for (const auto& [key, name] : {std::pair<const char*, const char*>{"save_path", "strata.ot"},
                                  {"octovis_path", "strata_octovis.ot"}, {"section_png", "section_c.png"}})
    strata->params[key] = RawParam{ParamValue{(fs::absolute(a.out) / name).string()}, "eval-strata"};
  for (const std::string& l : {out.surface_index, out.next_index, std::string("strata_change_z_m"), std::string("strata_cut_m")})
    if (std::find(spec.outputs.geotiff.begin(), spec.outputs.geotiff.end(), l) == spec.outputs.geotiff.end())
      spec.outputs.geotiff.push_back(l);
  return out;
}

/// --oracle-noise drops the soil_pinn stages' parameters, so --model, or a --set on such a stage,
/// would be lost silently: a ConfigError naming it, before the truth run.
void checkOracleOptions(const PipelineSpec& spec, const StrataArgs& a) {
  if (a.oracle_noise < 0) return;
  if (!a.model.empty())
    throw ConfigError("--model " + a.model + ": --oracle-noise replaces every soil_pinn stage, so no model is loaded");
  for (const StageSpec& st : spec.stages)
    if (st.type == "soil_pinn")
      for (const auto& [key, raw] : st.params)
        if (raw.where.rfind("--set ", 0) == 0)
          throw ConfigError(raw.where + ": --oracle-noise replaces the soil_pinn stage '" + st.name + "', which this sets");
}

/// --oracle-noise: every soil_pinn stage becomes a soil_oracle over the truth run's table of the
/// soil the blade cut (written to --out), with noise of `oracle_noise` times the two soils'
/// difference per property (the soil_pinn stage's own parameters are dropped). The boundary's
/// ceiling with a perfect (or a d' = 1 / noise) estimator: what the strata could do if the
/// estimator were that good.
void useOracle(PipelineSpec& spec, const StrataArgs& a, const sim::Scenario& sc, const sim::SoilZone& zone,
               const CutSoil& truth) {
  nlohmann::json table = {{"t_s", truth.t}, {"soil", nlohmann::json::array()}};
  for (const soil::SoilParamVector& v : truth.soil) {
    if (!std::isfinite(v[soil::kParamC])) {
      table["soil"].push_back(nullptr);
      continue;
    }
    table["soil"].push_back(v);
  }
  const fs::path path = fs::absolute(fs::path(a.out) / "oracle_soil.json");
  io::writeFileAtomically(path, table.dump() + "\n");
  const soil::SoilParamVector s0 = soil::fromFee(sc.default_soil.fee), s1 = soil::fromFee(zone.soil.fee);
  std::vector<double> sd(soil::kSoilParamCount);
  for (int q = 0; q < soil::kSoilParamCount; ++q)
    sd[static_cast<std::size_t>(q)] = a.oracle_noise * std::abs(s1[static_cast<std::size_t>(q)] - s0[static_cast<std::size_t>(q)]);
  int swapped = 0;
  for (StageSpec& st : spec.stages) {
    if (st.type != "soil_pinn") continue;
    st.type = "soil_oracle";
    st.params.clear();
    st.params["table"] = RawParam{ParamValue{path.string()}, "eval-strata --oracle"};
    st.params["noise_sd"] = RawParam{ParamValue{sd}, "eval-strata --oracle-noise"};
    ++swapped;
  }
  if (swapped == 0) throw ConfigError(spec.file + ": --oracle-noise replaces the soil_pinn stage, and the pipeline has none");
  // The pipeline's change_properties name what soil_pinn can tell; the oracle's noise is the same
  // fraction in every property, so its change is sought in all of them (unless --set says which).
  for (StageSpec& st : spec.stages) {
    if (st.type != "octomap_strata") continue;
    const auto it = st.params.find("change_properties");
    if (it != st.params.end() && it->second.where.rfind("--set ", 0) != 0) st.params.erase(it);
  }
}

/// The map's layers sampled during the run: both indices at each pass start, the change height
/// at the end. Row-major over the map geometry's logical cells, NaN where unknown.
struct MapSamples {
  std::vector<std::vector<double>> surface, next;  ///< [pass start k][cell]
  std::vector<double> change_z, change_depth, cut;  ///< at the end
};

std::vector<double> sampleLayer(const LayeredMap& map, const std::string& layer) {
  const Geometry& g = map.geometry();
  const LayerId id = map.layerId(layer);
  std::vector<double> out(static_cast<std::size_t>(g.size().x() * g.size().y()));
  for (int i = 0; i < g.size().x(); ++i)
    for (int j = 0; j < g.size().y(); ++j) out[static_cast<std::size_t>(i * g.size().y() + j)] = map.at(id, Index(i, j));
  return out;
}

using SoilLayerIds = std::array<LayerId, soil::kSoilParamCount>;

SoilLayerIds soilLayers(const LayeredMap& map, const std::string& prefix) {
  SoilLayerIds ids{};
  for (int q = 0; q < soil::kSoilParamCount; ++q)
    ids[static_cast<std::size_t>(q)] = map.layerId(prefix + soil::kSoilParams[q].name);
  return ids;
}

/// The map's soil under a blade edge `width_m` wide: each property's mean over the cells under
/// points spread across it where all five layers hold a value; NaN fields where none does.
fee::Soil soilUnderEdge(const LayeredMap& map, const SoilLayerIds& ids, const ForceStep& s, double width_m) {
  constexpr int kPoints = 9;  // a point every ~0.2 m of a 1.85 m blade: four cells apart at 5 cm
  soil::SoilParamVector sum{};
  int n = 0;
  for (int k = 0; k < kPoints; ++k) {
    const Eigen::Vector3d p = s.edge + s.lateral * (width_m * ((k + 0.5) / kPoints - 0.5));
    const std::optional<Index> idx = map.geometry().indexAt(Position(p.x(), p.y()));
    if (!idx) continue;
    soil::SoilParamVector v{};
    bool all = true;
    for (std::size_t q = 0; q < v.size(); ++q) {
      v[q] = map.at(ids[q], *idx);
      all = all && std::isfinite(v[q]);
    }
    if (!all) continue;
    for (std::size_t q = 0; q < v.size(); ++q) sum[q] += v[q];
    ++n;
  }
  if (n == 0) return {NAN, NAN, NAN, NAN, NAN};
  for (double& v : sum) v /= n;
  return soil::toFee(sum);
}

/// One pipeline run over the whole scenario, with its usual outputs in --out. At each pass start
/// it samples both index layers and, for every step of the truth run in that pass, the two soil
/// beliefs under the edge's position then (`steps`, sorted by time; a blade `blade_width_m` wide).
MapSamples runAndSample(const PipelineSpec& spec, const StrataArgs& a, const Stages& st, const std::vector<Snapshot>& snaps,
                        std::vector<ForceStep>& steps, double blade_width_m) {
  MapSamples m;
  std::size_t next_start = 0;  // snaps[0 .. K-2] are pass starts, the last one the end
  std::size_t step = 0;
  RunOptions o;
  o.out_dir = a.out;
  o.threads = a.threads;
  o.on_event = [&](const LayeredMap& map, double stamp) {
    while (!a.boundary_only && next_start + 1 < snaps.size() && stamp >= snaps[next_start].t) {
      m.surface.push_back(sampleLayer(map, st.surface_index));
      m.next.push_back(sampleLayer(map, st.next_index));
      const SoilLayerIds surface = soilLayers(map, "soil_"), next = soilLayers(map, "strata_next_");
      while (step < steps.size() && steps[step].t < snaps[next_start].t) ++step;  // the first pass: no map yet
      for (; step < steps.size() && steps[step].t < snaps[next_start + 1].t; ++step) {
        steps[step].surface = soilUnderEdge(map, surface, steps[step], blade_width_m);
        steps[step].strata = soilUnderEdge(map, next, steps[step], blade_width_m);
      }
      ++next_start;
    }
  };
  o.compare_truth = [&](LayeredMap& map, const Source& src) {
    m.change_z = sampleLayer(map, "strata_change_z_m");
    m.change_depth = sampleLayer(map, "strata_change_depth_m");
    m.cut = sampleLayer(map, "strata_cut_m");
    return eval::compareWithSourceTruth(map, src);
  };
  PipelineSpec s = spec;
  s.source.settings["max_time_s"] = RawParam{ParamValue{snaps.back().t}, "eval-strata"};
  runPipeline(s, o);
  return m;
}

/// Per pass k + 2: the indices at its start against the index of the truth soil it removed.
nlohmann::json nextPassErrors(const StrataArgs& a, const Stages& st, const Geometry& g, const sim::SoilField& field,
                              const std::vector<double>& initial, const std::vector<Snapshot>& snaps, const MapSamples& m) {
  ErrorSum total_surface, total_next;
  nlohmann::json passes = nlohmann::json::array();
  if (!a.quiet)
    std::printf("next pass: FEE index of the soil each pass removed (truth) against the map's indices at its start\n"
                "  %-5s %7s %7s %8s %14s %14s\n", "pass", "start", "end", "cells", "surface MAE", "strata MAE");
  for (std::size_t k = 0; k < m.surface.size(); ++k) {
    ErrorSum es, en;
    for (int i = 0; i < g.size().x(); ++i)
      for (int j = 0; j < g.size().y(); ++j) {
        const std::size_t c = static_cast<std::size_t>(i * g.size().y() + j);
        const double b0 = snaps[k].bank[c], b1 = snaps[k + 1].bank[c], fs_ = m.surface[k][c], fn = m.next[k][c];
        if (!(b0 - b1 >= a.min_cut_m) || !std::isfinite(fs_) || !std::isfinite(fn)) continue;
        const Position p = g.positionOf(Index(i, j));
        const double ti =
            soil::feeIndexOf(truthSoilBetween(field, p.x(), p.y(), initial[c] - b0, initial[c] - b1), fee::Soil{}, st.cut).index_n;
        if (!std::isfinite(ti)) continue;
        es.add(fs_, ti);
        en.add(fn, ti);
      }
    total_surface.merge(es);
    total_next.merge(en);
    passes.push_back({{"pass", k + 2}, {"start_s", snaps[k].t}, {"end_s", snaps[k + 1].t}, {"surface", es.json()}, {"strata", en.json()}});
    if (!a.quiet)
      std::printf("  %-5zu %7.1f %7.1f %8ld %11.2f kN %11.2f kN\n", k + 2, snaps[k].t, snaps[k + 1].t, es.n,
                  es.mae() * 1e-3, en.mae() * 1e-3);
  }
  if (!a.quiet && total_surface.n > 0)
    std::printf("  all   %23ld %11.2f kN %11.2f kN  (relative %.1f %% / %.1f %%)\n", total_surface.n,
                total_surface.mae() * 1e-3, total_next.mae() * 1e-3, 100 * total_surface.relative(),
                100 * total_next.relative());
  return {{"passes", passes}, {"surface", total_surface.json()}, {"strata", total_next.json()}};
}

/// The FEE's force (F_total: with the adhesion along the face, as the simulator's truth; along
/// the push and up) of `soil` on one step's cut; NaN where the FEE has no valid solution. β*
/// where it exists, else Rankine's angle, as the simulator takes it.
Eigen::Vector2d feeForceOn(const fee::Soil& soil, const ForceStep& s) {
  double beta = fee::betaMin(soil, s.geometry);
  if (!std::isfinite(beta)) beta = fee::betaNominal(soil);
  const fee::Result r = fee::evaluate(soil, s.geometry, beta);
  return r.valid() ? r.F_total_N : Eigen::Vector2d::Constant(std::nan(""));
}

/// The comparison: per pass k + 2, the FEE draft of the map's two soil beliefs at the
/// pass's start (surface-only `soil_*`, strata `strata_next_*`, under the edge) on every step the
/// truth blade cut, against the simulator's truth force along the push in that step (without
/// sensor noise). The geometry of each step (depth, slope, rake, width, surcharge) is the truth's
/// for all three, so only the soil differs; the FEE of the truth's own soil on it is the floor
/// (what the FEE on one soil cannot model: the slices' own depths and soils, inertia). The draft,
/// not |F|: the truth's vertical force is mostly the edge's bearing while it descends, which no
/// FEE of any soil holds, so |F| would judge that term instead of the soil; the command prints
/// the truth soil's error on |F| and both vertical means to show it.
nlohmann::json nextPassForces(const StrataArgs& a, const std::vector<Snapshot>& snaps,
                              const std::vector<ForceStep>& steps) {
  ErrorSum total_surface, total_next, total_truth, truth_abs;  // truth_abs: the truth soil on |F|
  double vertical_truth = 0, vertical_fee = 0;                  // sums over the judged steps, N
  long no_belief = 0, fee_invalid = 0, strata_closer = 0, surface_closer = 0;  // the rest: equally close
  nlohmann::json passes = nlohmann::json::array();
  if (!a.quiet)
    std::printf("next pass, force: the FEE draft of each belief at the pass's start on every step the pass cut, against the "
                "simulator's truth draft\n  %-5s %7s %7s %8s %14s %14s %14s\n", "pass", "start", "end", "steps", "surface MAE",
                "strata MAE", "truth soil MAE");
  std::size_t i = 0;
  for (std::size_t k = 0; k + 1 < snaps.size(); ++k) {
    ErrorSum es, en, et;
    while (i < steps.size() && steps[i].t < snaps[k].t) ++i;
    for (; i < steps.size() && steps[i].t < snaps[k + 1].t; ++i) {
      const ForceStep& s = steps[i];
      if (!std::isfinite(s.surface.c_pa) || !std::isfinite(s.strata.c_pa)) {
        ++no_belief;
        continue;
      }
      const Eigen::Vector2d f_truth_soil = feeForceOn(s.truth_soil, s);
      const double fs_ = feeForceOn(s.surface, s).x(), fn = feeForceOn(s.strata, s).x(), ft = f_truth_soil.x();
      if (!std::isfinite(fs_) || !std::isfinite(fn) || !std::isfinite(ft)) {
        ++fee_invalid;
        continue;
      }
      const double truth = s.force_n.x();
      truth_abs.add(f_truth_soil.norm(), s.force_n.norm());
      vertical_truth += s.force_n.y();
      vertical_fee += f_truth_soil.y();
      es.add(fs_, truth);
      en.add(fn, truth);
      et.add(ft, truth);
      if (std::abs(fn - truth) < std::abs(fs_ - truth)) ++strata_closer;
      if (std::abs(fs_ - truth) < std::abs(fn - truth)) ++surface_closer;
    }
    total_surface.merge(es);
    total_next.merge(en);
    total_truth.merge(et);
    passes.push_back({{"pass", k + 2}, {"start_s", snaps[k].t}, {"end_s", snaps[k + 1].t}, {"surface", es.json("steps")},
                      {"strata", en.json("steps")}, {"truth_soil", et.json("steps")}});
    if (!a.quiet)
      std::printf("  %-5zu %7.1f %7.1f %8ld %11.2f kN %11.2f kN %11.2f kN\n", k + 2, snaps[k].t, snaps[k + 1].t, es.n,
                  es.mae() * 1e-3, en.mae() * 1e-3, et.mae() * 1e-3);
  }
  const double closer = total_surface.n ? static_cast<double>(strata_closer) / total_surface.n : std::nan(""),
               surface_closer_share = total_surface.n ? static_cast<double>(surface_closer) / total_surface.n : std::nan("");
  if (!a.quiet && total_surface.n > 0)
    std::printf("  all   %23ld %11.2f kN %11.2f kN %11.2f kN  (relative %.1f %% / %.1f %% / %.1f %%)\n"
                "  median  %29.2f kN %11.2f kN %11.2f kN; the closer: the strata's in %.1f %% of the steps, the surface's in "
                "%.1f %%\n"
                "  steps left out: %ld without a belief under the edge, %ld where a belief's FEE had no valid solution\n"
                "  why the draft: the truth soil's FEE on |F| is %.1f %% off; the vertical force averages %.2f kN in the "
                "truth, %.2f kN in that FEE (the edge's bearing while it descends)\n",
                total_surface.n, total_surface.mae() * 1e-3, total_next.mae() * 1e-3, total_truth.mae() * 1e-3,
                100 * total_surface.relative(), 100 * total_next.relative(), 100 * total_truth.relative(),
                total_surface.median() * 1e-3, total_next.median() * 1e-3, total_truth.median() * 1e-3, 100 * closer, 100 * surface_closer_share,
                no_belief, fee_invalid, 100 * truth_abs.relative(), vertical_truth / total_truth.n * 1e-3,
                vertical_fee / total_truth.n * 1e-3);
  return {{"passes", passes}, {"surface", total_surface.json("steps")}, {"strata", total_next.json("steps")},
          {"truth_soil", total_truth.json("steps")}, {"strata_closer_fraction", closer}, {"surface_closer_fraction", surface_closer_share},
          {"steps_without_belief", no_belief}, {"steps_fee_invalid", fee_invalid},
          {"truth_soil_abs_force", truth_abs.json("steps")},
          {"vertical_mean_n", {{"truth", total_truth.n ? vertical_truth / total_truth.n : std::nan("")},
                               {"truth_soil_fee", total_truth.n ? vertical_fee / total_truth.n : std::nan("")}}}};
}

/// In the columns cut through the zone's top (the bank at the end at least one voxel below it):
/// is the change height within one voxel of it?
nlohmann::json boundaryFigure(const StrataArgs& a, const sim::SoilZone& zone, double voxel, const Geometry& g,
                              const std::vector<double>& initial, const Snapshot& end, const MapSamples& m) {
  const std::vector<double>& change_z = m.change_z;
  long cut_through = 0, found = 0, within = 0;
  double abs_err = 0, signed_err = 0;
  // Where the change is found, the strata's first and last bank surfaces (first = change height +
  // change depth, last = first − cut) against the truth's: a bias there shifts every voxel.
  double first_err = 0, last_err = 0;
  long surfaces = 0;
  // The figure is the boundary's *depth*: below the strata's first surface (the map's
  // own frame) against the zone's depth below the initial surface. A vertical offset of the
  // map frame (the localisation's slow error) shifts the height but cancels in the depth.
  long depth_found = 0, depth_within = 0;
  double depth_abs = 0;
  // Of those, the columns whose first surface is within half a voxel of the truth's: the depth
  // measured from a right start (a wrong one is the surface fit's error, e.g. under spoil).
  long good_start = 0, good_start_within = 0;
  // Signed errors (found − truth) in voxels, rounded, clamped to ±kBins: which way a miss goes
  // tells a late estimate (the change found too low) from an early one.
  constexpr int kBins = 4;
  std::array<long, 2 * kBins + 1> hist{};
  for (int i = 0; i < g.size().x(); ++i)
    for (int j = 0; j < g.size().y(); ++j) {
      const std::size_t c = static_cast<std::size_t>(i * g.size().y() + j);
      const Position p = g.positionOf(Index(i, j));
      const double top = initial[c] - zone.depthMinAt(p.x(), p.y());
      if (!(end.bank[c] <= top - voxel)) continue;
      ++cut_through;
      if (std::isfinite(m.change_depth[c])) {
        const double ed = m.change_depth[c] - zone.depthMinAt(p.x(), p.y());
        ++depth_found;
        depth_abs += std::abs(ed);
        if (std::abs(ed) <= voxel) ++depth_within;
        if (std::abs(change_z[c] + m.change_depth[c] - initial[c]) <= 0.5 * voxel) {
          ++good_start;
          if (std::abs(ed) <= voxel) ++good_start_within;
        }
      }
      if (!std::isfinite(change_z[c])) continue;
      ++found;
      const double e = change_z[c] - top;
      abs_err += std::abs(e);
      signed_err += e;
      const double first = change_z[c] + m.change_depth[c];
      if (std::isfinite(first) && std::isfinite(m.cut[c])) {
        first_err += first - initial[c];
        last_err += first - m.cut[c] - end.bank[c];
        ++surfaces;
      }
      if (std::abs(e) <= voxel) ++within;
      ++hist[static_cast<std::size_t>(std::clamp(static_cast<int>(std::lround(e / voxel)), -kBins, kBins) + kBins)];
    }
  if (!a.quiet) {
    std::printf("boundary (top of '%s'): %ld columns cut through it, a change found in %ld, within one voxel (%.2f m) in "
                "%ld = %.1f %% (MAE where found %.3f m, mean %+.3f m)\n  found - truth, voxels:",
                zone.name.c_str(), cut_through, found, voxel, within, cut_through ? 100.0 * within / cut_through : std::nan(""),
                found ? abs_err / found : std::nan(""), found ? signed_err / found : std::nan(""));
    for (int b = -kBins; b <= kBins; ++b)
      std::printf(" %s%+d: %ld", b == -kBins ? "<=" : b == kBins ? ">=" : "", b, hist[static_cast<std::size_t>(b + kBins)]);
    std::printf("\n  there, the strata's bank surfaces - the truth's: first %+.3f m, last %+.3f m (means)\n",
                surfaces ? first_err / surfaces : std::nan(""), surfaces ? last_err / surfaces : std::nan(""));
    std::printf("boundary depth (below the first surface): within one voxel in %ld = %.1f %% (MAE where found %.3f m)\n"
                "  in the %ld columns whose first surface is within half a voxel of the truth's: %ld = %.1f %%\n",
                depth_within, cut_through ? 100.0 * depth_within / cut_through : std::nan(""),
                depth_found ? depth_abs / depth_found : std::nan(""), good_start, good_start_within,
                good_start ? 100.0 * good_start_within / good_start : std::nan(""));
  }
  nlohmann::json histogram = nlohmann::json::object();
  for (int b = -kBins; b <= kBins; ++b) histogram[std::to_string(b)] = hist[static_cast<std::size_t>(b + kBins)];
  return {{"columns_cut_through", cut_through}, {"columns_with_change", found}, {"within_one_voxel", within},
          {"fraction_within", cut_through ? static_cast<double>(within) / cut_through : std::nan("")},
          {"mae_m_where_found", found ? abs_err / found : std::nan("")},
          {"mean_error_m_where_found", found ? signed_err / found : std::nan("")},
          {"error_voxels_histogram", histogram},
          {"first_surface_bias_m", surfaces ? first_err / surfaces : std::nan("")},
          {"last_surface_bias_m", surfaces ? last_err / surfaces : std::nan("")},
          {"depth", {{"columns_with_change", depth_found}, {"within_one_voxel", depth_within},
                     {"fraction_within", cut_through ? static_cast<double>(depth_within) / cut_through : std::nan("")},
                     {"mae_m_where_found", depth_found ? depth_abs / depth_found : std::nan("")},
                     {"columns_with_first_surface_within_half_a_voxel", good_start},
                     {"within_one_voxel_there", good_start_within}}}};
}

/// How far apart the soil estimator's estimates of the two soils are: every valid estimate of
/// the run (report.json's soil_pinn, soil_fit or soil_oracle records) paired with the soil the truth blade was cutting at
/// its sweep's end, classed by the nearer of the default soil and the zone's in cohesion. Per
/// property, and for the FEE index of the reference cut (`cut`) of each estimate's mean (the
/// strength the force can tell, whatever mix of properties gives it): truth, estimates' mean and
/// spread, and d' = (mean difference) / pooled spread. The boundary can only be as sharp as these
/// classes are apart.
nlohmann::json estimatorSeparation(const StrataArgs& a, const sim::Scenario& sc, const sim::SoilZone& zone, const CutSoil& truth,
                                   const soil::FeeIndexConfig& cut) {
  const nlohmann::json run = nlohmann::json::parse(std::ifstream(fs::path(a.out) / "report.json"));
  const soil::SoilParamVector soils[2] = {soil::fromFee(sc.default_soil.fee), soil::fromFee(zone.soil.fee)};
  std::array<std::vector<soil::SoilParamVector>, 2> est;
  // Each valid estimate beside the truth it is classed by, for tracing a miss to its sweep:
  // [sweep_index, t1 (s), class (0 default, 1 zone), the truth's c (Pa), the estimate's c (Pa), its sd (Pa)].
  nlohmann::json listed = nlohmann::json::array();
  for (const nlohmann::json& stage : run["stages"]) {
    if ((stage["type"] != "soil_pinn" && stage["type"] != "soil_fit" && stage["type"] != "soil_oracle") ||
        !stage.contains("records"))
      continue;
    for (const nlohmann::json& r : stage["records"]) {
      if (!r.value("valid", false)) continue;
      const double t1 = r["t1"].get<double>();
      const auto it = std::lower_bound(truth.t.begin(), truth.t.end(), t1 - 1e-9);
      if (it == truth.t.end()) continue;
      const soil::SoilParamVector& cut_soil = truth.soil[static_cast<std::size_t>(it - truth.t.begin())];
      if (!std::isfinite(cut_soil[soil::kParamC])) continue;  // the blade was not cutting
      const int cls = std::abs(cut_soil[soil::kParamC] - soils[1][soil::kParamC]) <
                      std::abs(cut_soil[soil::kParamC] - soils[0][soil::kParamC]);
      soil::SoilParamVector m{};
      for (int q = 0; q < soil::kSoilParamCount; ++q) m[static_cast<std::size_t>(q)] = r["mean"][static_cast<std::size_t>(q)].get<double>();
      est[static_cast<std::size_t>(cls)].push_back(m);
      listed.push_back({r.value("sweep_index", -1L), t1, cls, cut_soil[soil::kParamC], m[soil::kParamC],
                        r.contains("sd_total") ? r["sd_total"][soil::kParamC].get<double>() : std::nan("")});
    }
  }
  nlohmann::json out = {{"estimates", {{"default", est[0].size()}, {zone.name, est[1].size()}}},
                        {"records", std::move(listed)}};
  if (!a.quiet)
    std::printf("soil estimates by the soil being cut (%zu in the default soil, %zu in '%s'):\n  %-6s %-32s %-32s %6s\n",
                est[0].size(), est[1].size(), zone.name.c_str(), "", "default: truth / estimates", "zone: truth / estimates", "d'");
  // Column q < kSoilParamCount: that property; q == kSoilParamCount: the index (NaN where the
  // FEE has no valid solution for the soil: left out of the statistics).
  const auto value = [&](const soil::SoilParamVector& v, int q) {
    return q < soil::kSoilParamCount ? v[static_cast<std::size_t>(q)] : soil::feeIndexOf(soil::toFee(v), fee::Soil{}, cut).index_n;
  };
  for (int q = 0; q <= soil::kSoilParamCount; ++q) {
    double mean[2] = {std::nan(""), std::nan("")}, sd[2] = {std::nan(""), std::nan("")};
    for (int c = 0; c < 2; ++c) {
      double s1 = 0, s2 = 0;
      long n = 0;
      for (const auto& e : est[static_cast<std::size_t>(c)]) {
        const double x = value(e, q);
        if (!std::isfinite(x)) continue;
        s1 += x;
        s2 += x * x;
        ++n;
      }
      if (n == 0) continue;
      mean[c] = s1 / n;
      sd[c] = std::sqrt(std::max(0.0, s2 / n - mean[c] * mean[c]));
    }
    const double d = (mean[1] - mean[0]) / std::sqrt(0.5 * (sd[0] * sd[0] + sd[1] * sd[1]));
    const bool index = q == soil::kSoilParamCount;
    const char* name = index ? "fee_index" : soil::kSoilParams[q].name;
    const char* unit = index ? "N" : soil::kSoilParams[q].unit;
    const double t0 = value(soils[0], q), t1 = value(soils[1], q);
    out["properties"][name] = {{"unit", unit}, {"truth", {t0, t1}}, {"mean", {mean[0], mean[1]}}, {"sd", {sd[0], sd[1]}},
                               {"d_prime", d}};
    // Printed as a person reads it (soil::kSoilDisplay); the JSON keeps SI.
    const double k = index ? 1.0 : soil::kSoilDisplay[q].scale;
    if (!a.quiet)
      std::printf("  %-6s %9.4g / %9.4g +- %-9.3g %9.4g / %9.4g +- %-9.3g %6.2f  [%s]\n", index ? "index" : name, k * t0,
                  k * mean[0], k * sd[0], k * t1, k * mean[1], k * sd[1], d, index ? unit : soil::kSoilDisplay[q].unit);
  }
  return out;
}

int runEvalStrata(const StrataArgs& a) {
  const fs::path configs = embeddedDemoBaseDir();
  PipelineSpec spec = parsePipelineFile(a.pipeline.empty() ? (configs / "strata.yaml").string() : a.pipeline);
  if (spec.source.type != "sim")
    throw ConfigError(spec.file + ": eval-strata needs a `sim` source (it compares with the simulator's truth)");
  const std::string scenario = fs::absolute(a.scenario).string();
  spec.source.settings["scenario"] = RawParam{ParamValue{scenario}, "eval-strata SCENARIO"};
  sim::Scenario sc = sim::loadScenario(scenario);
  if (a.duration > 0) sc.duration_s = std::min(sc.duration_s, a.duration);
  // The same ablation in both runs: the controller steers by the localisation, so the truth run
  // must drive the machine the pipeline's run drives.
  if (!a.localisation.empty()) {
    sim::overrideLocalisation(sc, a.localisation, "--localisation");
    spec.source.settings["localisation"] = RawParam{ParamValue{a.localisation}, "--localisation"};
  }
  // The zone whose top is the boundary: --zone, else the first zone that starts below the surface.
  const sim::SoilZone* zone = nullptr;
  for (const sim::SoilZone& z : sc.zones)
    if (a.zone.empty() ? z.depth_min_m > 0 : z.name == a.zone) {
      zone = &z;
      break;
    }
  if (!zone) throw ConfigError(scenario + ": no soil zone " + (a.zone.empty() ? "below the surface (depth_m: [>0, ...])" : "named '" + a.zone + "'"));
  const Stages st = findStages(spec, a);
  checkOracleOptions(spec, a);
  const Geometry g = spec.geometry();
  fs::create_directories(a.out);

  if (!a.quiet) std::printf("eval-strata %s: truth run of the simulator\n", a.scenario.c_str());
  std::vector<double> initial;
  CutSoil cut_soil;
  std::vector<ForceStep> steps;
  const std::vector<Snapshot> snaps = truthSnapshots(sc, g, initial, cut_soil, steps, a.quiet);
  if (!a.quiet) std::printf("pipeline run\n");
  if (a.oracle_noise >= 0) {
    useOracle(spec, a, sc, *zone, cut_soil);
    if (!a.quiet) std::printf("soil_pinn replaced by soil_oracle (noise %.3g x the soils' difference)\n", a.oracle_noise);
  }
  const MapSamples m = runAndSample(spec, a, st, snaps, steps, sc.machines.front().blade.width_m);

  nlohmann::json report;
  report["scenario"] = scenario;
  report["zone"] = zone->name;
  if (a.oracle_noise >= 0) report["oracle_noise"] = a.oracle_noise;
  report["voxel_m"] = st.voxel_m;
  if (!a.boundary_only) {
    report["next_pass"] = nextPassErrors(a, st, g, sim::SoilField(sc.default_soil, sc.zones), initial, snaps, m);
    report["next_pass_force"] = nextPassForces(a, snaps, steps);
  }
  report["boundary"] = boundaryFigure(a, *zone, st.voxel_m, g, initial, snaps.back(), m);
  report["estimator"] = estimatorSeparation(a, sc, *zone, cut_soil, st.cut);
  io::writeFileAtomically(fs::path(a.out) / "eval_strata.json", report.dump(2) + "\n");
  if (!a.quiet) std::printf("wrote %s\n", (fs::path(a.out) / "eval_strata.json").string().c_str());
  return kOk;
}

Registrar reg{Command{"eval-strata", [](CLI::App& app, std::function<int()>& run) {
  auto a = std::make_shared<StrataArgs>();
  auto* sub = app.add_subcommand("eval-strata",
      "The subsurface soil memory (octomap_strata) against the simulator's truth: run SCENARIO\n"
      "through configs/strata.yaml and report (1) in the columns cut through a soil zone's top, how\n"
      "often the height where the removed soil changes lies within one voxel of it, and (2) per pass,\n"
      "how well the soil expected in the next cut predicts, through the FEE, the simulator's force on\n"
      "the blade in that pass (and its FEE index the index of the soil the pass removed), against the\n"
      "surface-only soil. Writes eval_strata.json and the run's outputs\n"
      "(with strata.ot, strata_octovis.ot, section_c.png) to --out.");
  sub->add_option("scenario", a->scenario, "Scenario YAML")->required()->check(CLI::ExistingFile);
  sub->add_option("--pipeline", a->pipeline, "Pipeline YAML (default: configs/strata.yaml of the source tree)");
  sub->add_option("--model", a->model, "Soil estimator file for every soil_pinn stage");
  sub->add_option("--zone", a->zone, "Soil zone whose top is the boundary (default: the first below the surface)");
  sub->add_option("--min-cut", a->min_cut_m, "A pass must remove at least this much bank soil from a cell (m)")
      ->check(CLI::PositiveNumber);
  sub->add_option("--out,-o", a->out, "Output folder");
  sub->add_option("--duration", a->duration, "Simulate at most this many seconds")->check(CLI::PositiveNumber);
  sub->add_option("--threads,-j", a->threads, "Worker threads")->check(CLI::Range(1, 256));
  sub->add_option("--oracle-noise", a->oracle_noise,
                  "Replace soil_pinn by soil_oracle: the truth soil the blade cut, with noise of this fraction of the "
                  "two soils' difference per property (0: perfect; d' between the soils = 1 / this)")
      ->check(CLI::NonNegativeNumber);
  sub->add_option("--localisation", a->localisation,
                  "Every machine's localisation in both runs: perfect or rtk_imu (default: the scenario's)");
  sub->add_flag("--boundary-only", a->boundary_only, "The boundary figure only (no per-pass comparison)");
  sub->add_option("--set", a->set,
                  "octomap_strata parameter for this run, KEY=VALUE, or any stage's, STAGE.KEY=VALUE "
                  "(repeatable; e.g. --set change_min_voxels=2 --set bayes.prior=config)");
  sub->add_flag("--quiet,-q", a->quiet, "Print nothing but errors");
  sub->callback([&run, a] { run = [a]() -> int { return runEvalStrata(*a); }; });
}}};

}  // namespace
}  // namespace terramap::cli
