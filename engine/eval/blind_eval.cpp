#include <terramap/eval/blind_eval.hpp>

#include <terramap/core/error.hpp>
#include <terramap/io/atomic_file.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/io/render.hpp>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <sstream>
#include <stdexcept>
#include <variant>

namespace terramap::eval {

using sim::FeeTruth;
using sim::MachineSpec;
using sim::MachineTruth;
using sim::Simulator;
using sim::TruthSurface;
using sim::TruthTerrain;
using sim::truthOnGeometry;
using sim::truthOnGeometryD;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kDeg = 180.0 / M_PI;

RegionStats regionStats(const std::vector<double>& err, const std::vector<double>& base) {
  RegionStats r;
  r.cells = static_cast<long>(err.size());
  const ErrorStats e = errorStats(err), b = errorStats(base);
  r.rmse_m = e.rmse;
  r.bias_m = e.bias;
  r.p95_abs_m = e.p95_abs;
  r.max_abs_m = e.max_abs;
  r.baseline_rmse_m = b.rmse;
  r.baseline_bias_m = b.bias;
  return r;
}

ParameterStats paramStats(const std::string& name, const std::string& unit, double scale,
                          const std::vector<ExtractionSample>& samples,
                          double ExtractionSample::*mapped, double ExtractionSample::*truth) {
  ParameterStats p;
  p.name = name;
  p.unit = unit;
  std::vector<double> e;
  double sm = 0, st = 0;
  for (const ExtractionSample& s : samples) {
    if (!s.mapped_valid || !s.truth_valid) continue;
    const double m = s.*mapped * scale, t = s.*truth * scale;
    if (!std::isfinite(m) || !std::isfinite(t)) continue;
    e.push_back(m - t);
    sm += m;
    st += t;
  }
  p.n = static_cast<long>(e.size());
  if (e.empty()) return p;
  const double n = static_cast<double>(e.size());
  p.mapped_mean = sm / n;
  p.truth_mean = st / n;
  const ErrorStats es = errorStats(std::move(e));
  p.bias = es.bias;
  p.rmse = es.rmse;
  p.std = es.std;
  p.p5 = es.p5;
  p.p50 = es.p50;
  p.p95 = es.p95;
  return p;
}

std::string fmt(double v, int prec) {
  if (!std::isfinite(v)) return "–";
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", prec, v);
  return b;
}

int precisionFor(const std::string& unit) {
  if (unit == "deg") return 2;
  if (unit == "m") return 4;
  return 0;  // N
}

/// The latest SweepRecord on the engine's RecordBus (nullptr if none yet) and its sequence
/// number (a new number = a new sweep).
std::shared_ptr<const SweepRecord> latestSweep(Engine& engine, long* sequence) {
  const Record* r = engine.records().latest(SweepRecord::kType);
  if (!r) return nullptr;
  *sequence = r->sequence;
  return std::static_pointer_cast<const SweepRecord>(r->payload);
}

nlohmann::json numberOrNull(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

}  // namespace

const char* evalRegionName(EvalRegion r) {
  switch (r) {
    case EvalRegion::All: return "all";
    case EvalRegion::Cut: return "cut";
    case EvalRegion::Deposit: return "deposit";
    case EvalRegion::Untouched: return "untouched";
    case EvalRegion::CutByMapper: return "cut_by_mapper";
    case EvalRegion::Outside: return "outside";
  }
  return "?";
}

SurfaceAheadTruth surfaceAheadTruth(const TruthTerrain& truth, const Eigen::Isometry3d& T_map_blade,
                                    const BladeGeometry& blade, int slices) {
  SurfaceAheadTruth out;
  if (slices < 1 || !(blade.width_m > 0)) return out;
  const Eigen::Vector3d c = T_map_blade.translation();
  const Eigen::Vector3d xb = T_map_blade.linear().col(0), yb = T_map_blade.linear().col(1),
                        zb = T_map_blade.linear().col(2);
  Eigen::Vector2d n(xb.x(), xb.y());
  if (n.norm() < 1e-6) n = Eigen::Vector2d(-zb.x(), -zb.y());  // face lying flat: push along its top
  if (n.norm() < 1e-9) return out;
  n.normalize();
  out.face_angle_rad = std::atan2(zb.z(), -(zb.x() * n.x() + zb.y() * n.y()));
  const double ds = blade.width_m / slices;
  double wsum = 0, a_alpha = 0, a_d = 0;
  for (int k = 0; k < slices; ++k) {
    const Eigen::Vector3d pe = c + yb * (-0.5 * blade.width_m + (k + 0.5) * ds);
    double sx = 0, sz = 0, sxx = 0, sxz = 0;
    int m = 0;
    for (int q = 0; q < 7; ++q) {
      const double l = 0.05 + 0.075 * q;
      const double z = truth.undisturbedAt(pe.x() + n.x() * l, pe.y() + n.y() * l);
      if (std::isnan(z)) continue;
      sx += l;
      sz += z;
      sxx += l * l;
      sxz += l * z;
      ++m;
    }
    if (m < 2) continue;
    const double den = m * sxx - sx * sx;
    if (!(den > 1e-12)) continue;
    const double slope = (m * sxz - sx * sz) / den;
    const double intercept = (sz - slope * sx) / m;
    const double depth_v = intercept - pe.z();
    if (!(depth_v > 1e-4)) continue;
    const double alpha = std::atan(slope);
    const double d = depth_v * std::cos(alpha);
    ++out.cutting_slices;
    out.w_along_m += ds;
    wsum += d;
    a_alpha += d * alpha;
    a_d += d * d;
  }
  if (wsum > 0) {
    out.alpha_rad = a_alpha / wsum;
    out.d_m = a_d / wsum;
  }
  return out;
}

ExtractionSummary summarizeExtraction(const std::vector<ExtractionSample>& samples) {
  ExtractionSummary s;
  s.sweeps = static_cast<long>(samples.size());
  for (const ExtractionSample& x : samples) {
    if (x.mapped_valid && x.truth_valid) ++s.both_valid;
    else if (x.mapped_valid) ++s.mapped_only;
    else if (x.truth_valid) ++s.truth_only;
    else ++s.neither;
  }
  using S = ExtractionSample;
  s.parameters.push_back(paramStats("alpha", "deg", kDeg, samples, &S::alpha_rad, &S::truth_alpha_rad));
  s.parameters.push_back(paramStats("rho", "deg", kDeg, samples, &S::rho_rad, &S::truth_rho_rad));
  s.parameters.push_back(paramStats("d", "m", 1.0, samples, &S::d_m, &S::truth_d_m));
  s.parameters.push_back(paramStats("w", "m", 1.0, samples, &S::w_m, &S::truth_w_m));
  s.parameters.push_back(paramStats("Q", "N", 1.0, samples, &S::q_n, &S::truth_q_n));
  s.parameters.push_back(paramStats("d_vs_sim_raw", "m", 1.0, samples, &S::d_m, &S::truth_d_raw_m));
  s.parameters.push_back(paramStats("rho_vs_sim_raw", "deg", kDeg, samples, &S::rho_rad, &S::truth_rho_raw_rad));
  s.parameters.push_back(paramStats("w_vs_sim_raw", "m", 1.0, samples, &S::w_m, &S::truth_w_raw_m));
  return s;
}

std::string extractionTableMarkdown(const ExtractionSummary& s) {
  std::ostringstream o;
  o << s.sweeps << " sweeps: " << s.both_valid << " valid on both sides, " << s.mapped_only
    << " extracted but the simulator was not cutting, " << s.truth_only
    << " simulator cutting but nothing extracted, " << s.neither << " neither.\n\n";
  o << "| parameter | unit | n | truth mean | mapped mean | bias | std | RMSE | p5 | p50 | p95 |\n";
  o << "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n";
  const std::map<std::string, std::string> label = {
      {"alpha", "α"}, {"rho", "ρ"}, {"d", "d"}, {"w", "w"}, {"Q", "Q"},
      {"d_vs_sim_raw", "d vs sim's raw FeeTruth depth"},
      {"rho_vs_sim_raw", "ρ vs sim's raw FeeTruth ρ"}, {"w_vs_sim_raw", "w vs sim's raw w (along blade)"}};
  for (const ParameterStats& p : s.parameters) {
    const int k = precisionFor(p.unit);
    const auto it = label.find(p.name);
    o << "| " << (it != label.end() ? it->second : p.name) << " | " << p.unit << " | " << p.n << " | "
      << fmt(p.truth_mean, k) << " | " << fmt(p.mapped_mean, k) << " | " << fmt(p.bias, k) << " | " << fmt(p.std, k)
      << " | " << fmt(p.rmse, k) << " | " << fmt(p.p5, k) << " | " << fmt(p.p50, k) << " | " << fmt(p.p95, k)
      << " |\n";
  }
  return o.str();
}

namespace {

/// What the replay accumulates besides the run itself.
struct Replay {
  Eigen::MatrixXi swept;  // 1 where a sweep's volume reached below the initial surface
  long last_seq = 0;      // sequence number of the last sweep record seen
  bool swell_known = false;
  double swell = 0;
};

/// The cells of a sweep's mask whose swept-volume bottom lies below the initial surface.
void markSwept(const SweepRecord& rec, const Geometry& geo, const Eigen::MatrixXf& initial, Eigen::MatrixXi& swept) {
  for (const SweepMaskCell& c : rec.mask) {
    const auto idx = geo.indexAt(c.position);
    if (!idx) continue;
    const float h0 = initial(idx->x(), idx->y());
    if (std::isfinite(h0) && c.sv_bottom_m < h0) swept(idx->x(), idx->y()) = 1;
  }
}

/// The FEE parameters the mapper extracted for one sweep beside the simulator's truth at its end.
ExtractionSample extractionSample(const SweepRecord& rec, const Simulator& sim, std::size_t machine) {
  ExtractionSample s;
  s.sweep = rec.sweep_index;
  s.machine = rec.machine_id;
  s.stamp = rec.t1;
  if (rec.fee_valid && !rec.steps.empty()) {
    const SweepStep& st = rec.steps.back();
    s.alpha_rad = rec.alpha_rad;
    s.rho_rad = st.rho_rad;
    s.d_m = st.d_m;
    s.w_m = st.w_m;
    s.q_n = st.q_n;
    s.mapped_valid =
        std::isfinite(s.alpha_rad) && std::isfinite(s.rho_rad) && std::isfinite(s.d_m) && std::isfinite(s.w_m);
  }
  const MachineTruth& mt = sim.machineTruth(machine);
  const MachineSpec& spec = sim.scenario().machines[machine];
  const SurfaceAheadTruth sa = surfaceAheadTruth(sim.truth(), mt.T_map_blade, spec.blade, spec.blade_slices);
  const FeeTruth& ft = mt.fee;
  if (sa.cutting_slices > 0) {
    s.truth_valid = true;
    s.truth_alpha_rad = sa.alpha_rad;
    s.truth_d_m = sa.d_m;
    s.truth_rho_rad = sa.face_angle_rad + sa.alpha_rad;
    const Eigen::Vector3d yb = mt.T_map_blade.linear().col(1);
    s.truth_w_m = sa.w_along_m * std::abs(yb.x() * rec.t_perp.x() + yb.y() * rec.t_perp.y());
  }
  if (ft.cutting_slices > 0) {
    s.truth_q_n = ft.q_n;
    s.truth_d_raw_m = ft.depth_m;
    s.truth_rho_raw_rad = ft.rho_rad;
    s.truth_w_raw_m = ft.width_m;
  }
  return s;
}

/// Accounts the engine's latest sweep record if it is new since the last call.
void takeNewSweep(const Simulator& sim, Engine& engine, EvalRun& run, Replay& rp,
                  const std::map<std::string, std::size_t>& machine_index) {
  long seq = 0;
  const std::shared_ptr<const SweepRecord> rec = latestSweep(engine, &seq);
  if (!rec || seq == rp.last_seq) return;
  rp.last_seq = seq;
  ++run.sweeps;
  const auto mit = machine_index.find(rec->machine_id);
  if (mit == machine_index.end())
    throw ConfigError("sweep record " + std::to_string(rec->sweep_index) + " names machine '" + rec->machine_id +
                      "', which the scenario '" + run.scenario + "' does not have");
  MassBalance& mb = run.mass;
  mb.cut_bank_blind_m3 += rec->cut_bank_volume_m3;
  mb.blind_lost_loose_m3 += rec->lost_volume_m3;
  rp.swell = rec->swell;
  rp.swell_known = true;
  markSwept(*rec, run.geometry, run.initial, rp.swept);
  run.samples.push_back(extractionSample(*rec, sim, mit->second));
}

/// Runs the simulator to its end, pushing its events (clouds withheld if asked) into the
/// engine; each new sweep record adds to the mass balance, the swept cells and the samples.
void replay(Simulator& sim, Engine& engine, const EvalOptions& options, EvalRun& run, Replay& rp) {
  std::map<std::string, std::size_t> machine_index;
  for (std::size_t i = 0; i < sim.scenario().machines.size(); ++i) machine_index[sim.scenario().machines[i].id] = i;
  std::vector<Event> events;
  while (sim.next(events)) {
    for (const Event& e : events) {
      if (options.withhold_clouds && std::holds_alternative<PointCloud>(e)) {
        ++run.clouds_withheld;
        continue;
      }
      engine.push(e);
      ++run.events_pushed;
      takeNewSweep(sim, engine, run, rp, machine_index);
    }
    events.clear();
    if (options.on_progress) options.on_progress(sim.time(), sim.scenario().duration_s);
  }
  // The stages' finish(): blade_sweep cuts the motion left over since its last sweep.
  engine.finish();
  takeNewSweep(sim, engine, run, rp, machine_index);
}

/// Sums over the map's cells for the mass balance (heights, m; times the cell area later).
struct HeightSums {
  double blind0 = 0, blind1 = 0, truth_on_map = 0;
};

/// The truth sampled at the cell centres, before (0) and after (1) the run.
struct TruthGrids {
  Eigen::MatrixXd current1;         // H now
  Eigen::MatrixXd bank0, bank1;     // U + Lc: bank-equivalent column
  Eigen::MatrixXd under0, under1;   // U: the bank surface, lowered only by a blade
};

/// Compares the blind map with the truth cell by cell: assigns each cell its region from the
/// truth alone (cut where the truth's bank surface was lowered, deposit where its surface moved
/// otherwise, else untouched), reports the mapper's own footprint beside it, collects the errors
/// per region and the removed / added volumes.
HeightSums compareHeights(EvalRun& run, const EvalOptions& options, const Eigen::MatrixXf& loose1,
                          const TruthGrids& tg, const Eigen::MatrixXi& swept, double swell) {
  const Geometry& geo = run.geometry;
  MassBalance& mb = run.mass;
  const Eigen::MatrixXd &truth1d = tg.current1, &bank0 = tg.bank0, &bank1 = tg.bank1;
  run.region = Eigen::MatrixXi::Constant(geo.size().x(), geo.size().y(), -1);
  run.mapper_cut = swept;
  FootprintAgreement& fp = run.footprint;
  std::vector<double> err[kEvalRegionCount], base[kEvalRegionCount];
  auto add = [&](EvalRegion r, double e, double b) {
    err[static_cast<int>(r)].push_back(e);
    base[static_cast<int>(r)].push_back(b);
  };
  const double a = geo.resolution() * geo.resolution();
  HeightSums sums;
  for (int i = 0; i < geo.size().x(); ++i)
    for (int j = 0; j < geo.size().y(); ++j) {
      const double h0 = run.initial(i, j), h1 = run.blind(i, j), l1 = loose1(i, j), t1 = truth1d(i, j);
      if (std::isfinite(h0)) sums.blind0 += h0;
      if (std::isfinite(h1)) sums.blind1 += (h1 - l1) + l1 / swell;
      else if (std::isfinite(l1)) sums.blind1 += l1 / swell;  // deposits kept on unknown ground
      if (std::isfinite(bank0(i, j)) && std::isfinite(bank1(i, j))) sums.truth_on_map += bank1(i, j) - bank0(i, j);
      if (!std::isfinite(h1) || !std::isfinite(t1) || !std::isfinite(h0)) continue;
      mb.removed_blind_m3 += std::max(0.0, h0 - h1) * a;
      mb.added_blind_m3 += std::max(0.0, h1 - h0) * a;
      mb.removed_truth_m3 += std::max(0.0, h0 - t1) * a;
      mb.added_truth_m3 += std::max(0.0, t1 - h0) * a;
      // Only a tool lowers the truth's bank surface U once the tracks' ruts are added back
      // (TruthSurface::Carved; sliding loose soil moves on top of it), so "carved" is the
      // truth's own record of the cut, whatever the mapper believed.
      const bool carved = tg.under1(i, j) < tg.under0(i, j) - options.cut_threshold_m;
      EvalRegion r = EvalRegion::Untouched;
      if (carved) r = EvalRegion::Cut;
      else if (std::abs(t1 - h0) > options.change_threshold_m) r = EvalRegion::Deposit;
      run.region(i, j) = static_cast<int>(r);
      const double e = h1 - t1, b = h0 - t1;
      add(EvalRegion::All, e, b);
      add(r, e, b);
      if (r != EvalRegion::Cut) add(EvalRegion::Outside, e, b);
      if (swept(i, j)) add(EvalRegion::CutByMapper, e, b);
      fp.both += carved && swept(i, j);
      fp.truth_only += carved && !swept(i, j);
      fp.mapper_only += !carved && swept(i, j);
    }
  for (int r = 0; r < kEvalRegionCount; ++r) run.regions[r] = regionStats(err[r], base[r]);
  const long any = fp.both + fp.truth_only + fp.mapper_only;
  fp.iou = any ? static_cast<double>(fp.both) / static_cast<double>(any) : kNaN;
  return sums;
}

}  // namespace

EvalRun runBlindEvaluation(Simulator& sim, Engine& engine, const EvalOptions& options) {
  if (sim.step() != 0) throw std::invalid_argument("runBlindEvaluation: the simulator has already been stepped");
  const auto wall0 = std::chrono::steady_clock::now();
  EvalRun run;
  run.options = options;
  run.scenario = sim.scenario().name;
  LayeredMap& map = engine.mutableMap();
  const Geometry geo = map.geometry();
  run.geometry = geo;
  // The mapper starts from the true surface, with no loose soil.
  const LayerId hid = map.layerId(options.elevation_layer);  // LayerError names the layer
  const TruthTerrain& truth0 = sim.truth();
  run.initial = truthOnGeometry(truth0, geo, TruthSurface::Current);
  map.fromMatrix(hid, run.initial);
  const bool has_loose = map.hasLayer(options.loose_layer);
  const Eigen::MatrixXf zeros = Eigen::MatrixXf::Zero(geo.size().x(), geo.size().y());
  if (has_loose) map.fromMatrix(map.layerId(options.loose_layer), zeros);
  TruthGrids tg;
  tg.bank0 = truthOnGeometryD(truth0, geo, TruthSurface::Bank);
  tg.under0 = truthOnGeometryD(truth0, geo, TruthSurface::Carved);
  const double truth_vol0 = truth0.bankVolume(), truth_lost0 = truth0.lostVolume();
  const double truth_compacted0 = truth0.compactedVolume();

  Replay rp;
  rp.swept = Eigen::MatrixXi::Zero(geo.size().x(), geo.size().y());
  {
    long s0 = 0;
    if (latestSweep(engine, &s0)) rp.last_seq = s0;  // a record left from before (not ours)
  }
  rp.swell = options.default_swell;
  replay(sim, engine, options, run, rp);
  run.simulated_s = sim.time();
  if (map.geometry() != geo)
    throw ConfigError("the map moved during the evaluation (a stage re-centred it); the evaluation compares fixed "
                      "cells with the truth: use a pipeline whose stages keep the map still");

  run.blind = map.toMatrix(hid);
  const Eigen::MatrixXf loose1 = has_loose ? map.toMatrix(map.layerId(options.loose_layer)) : zeros;
  const TruthTerrain& truth1 = sim.truth();
  tg.current1 = truthOnGeometryD(truth1, geo, TruthSurface::Current);
  run.truth = tg.current1.cast<float>();
  tg.bank1 = truthOnGeometryD(truth1, geo, TruthSurface::Bank);
  tg.under1 = truthOnGeometryD(truth1, geo, TruthSurface::Carved);
  const HeightSums sums = compareHeights(run, options, loose1, tg, rp.swept, rp.swell);

  // Mass: the blind map's change against what it lost, the truth's against its own.
  MassBalance& mb = run.mass;
  const double a = geo.resolution() * geo.resolution();
  mb.swell = rp.swell_known ? rp.swell : options.default_swell;
  mb.blind_initial_m3 = sums.blind0 * a;
  mb.blind_final_m3 = sums.blind1 * a;
  mb.blind_change_m3 = mb.blind_final_m3 - mb.blind_initial_m3;
  mb.blind_residual_m3 = mb.blind_change_m3 + mb.blind_lost_loose_m3 / mb.swell;
  mb.truth_change_m3 = truth1.bankVolume() - truth_vol0;
  mb.truth_lost_m3 = truth1.lostVolume() - truth_lost0;
  mb.truth_compacted_m3 = truth1.compactedVolume() - truth_compacted0;
  mb.truth_residual_m3 = mb.truth_change_m3 + mb.truth_lost_m3 + mb.truth_compacted_m3;
  mb.truth_change_on_map_m3 = sums.truth_on_map * a;
  for (std::size_t i = 0; i < sim.machineCount(); ++i) mb.cut_bank_truth_m3 += sim.machineTruth(i).cut_bank_m3;

  run.extraction = summarizeExtraction(run.samples);
  run.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  return run;
}

std::string evalJson(const EvalRun& run) {
  using nlohmann::json;
  json j;
  j["format"] = "terramap-eval";
  j["version"] = 1;
  j["scenario"] = run.scenario;
  j["map"] = {{"resolution_m", run.geometry.resolution()},
              {"size", {run.geometry.size().x(), run.geometry.size().y()}},
              {"center_m", {run.geometry.center().x(), run.geometry.center().y()}}};
  j["options"] = {{"change_threshold_m", run.options.change_threshold_m},
                  {"error_range_m", run.options.error_range_m},
                  {"withhold_clouds", run.options.withhold_clouds}};
  j["events_pushed"] = run.events_pushed;
  j["clouds_withheld"] = run.clouds_withheld;
  j["sweeps"] = run.sweeps;
  j["simulated_s"] = run.simulated_s;
  j["wall_s"] = run.wall_s;
  json regions = json::object();
  for (int r = 0; r < kEvalRegionCount; ++r) {
    const RegionStats& s = run.regions[r];
    regions[evalRegionName(static_cast<EvalRegion>(r))] = {
        {"cells", s.cells}, {"rmse_m", numberOrNull(s.rmse_m)}, {"bias_m", numberOrNull(s.bias_m)},
        {"p95_abs_m", numberOrNull(s.p95_abs_m)}, {"max_abs_m", numberOrNull(s.max_abs_m)},
        {"baseline_rmse_m", numberOrNull(s.baseline_rmse_m)}, {"baseline_bias_m", numberOrNull(s.baseline_bias_m)}};
  }
  j["height_error"] = regions;
  j["cut_footprint"] = {{"cells_both", run.footprint.both},
                        {"cells_truth_only", run.footprint.truth_only},
                        {"cells_mapper_only", run.footprint.mapper_only},
                        {"iou", numberOrNull(run.footprint.iou)}};
  const MassBalance& m = run.mass;
  j["mass"] = {{"swell", m.swell},
               {"blind_initial_m3", m.blind_initial_m3},
               {"blind_final_m3", m.blind_final_m3},
               {"blind_change_m3", m.blind_change_m3},
               {"blind_lost_loose_m3", m.blind_lost_loose_m3},
               {"blind_residual_m3", m.blind_residual_m3},
               {"truth_change_m3", m.truth_change_m3},
               {"truth_lost_m3", m.truth_lost_m3},
               {"truth_compacted_m3", m.truth_compacted_m3},
               {"truth_residual_m3", m.truth_residual_m3},
               {"truth_change_on_map_m3", m.truth_change_on_map_m3},
               {"cut_bank_blind_m3", m.cut_bank_blind_m3},
               {"cut_bank_truth_m3", m.cut_bank_truth_m3},
               {"removed_blind_m3", m.removed_blind_m3},
               {"removed_truth_m3", m.removed_truth_m3},
               {"added_blind_m3", m.added_blind_m3},
               {"added_truth_m3", m.added_truth_m3}};
  const ExtractionSummary& x = run.extraction;
  json params = json::array();
  for (const ParameterStats& p : x.parameters)
    params.push_back({{"name", p.name}, {"unit", p.unit}, {"n", p.n}, {"truth_mean", numberOrNull(p.truth_mean)},
                      {"mapped_mean", numberOrNull(p.mapped_mean)}, {"bias", numberOrNull(p.bias)},
                      {"std", numberOrNull(p.std)}, {"rmse", numberOrNull(p.rmse)}, {"p5", numberOrNull(p.p5)},
                      {"p50", numberOrNull(p.p50)}, {"p95", numberOrNull(p.p95)}});
  j["extraction"] = {{"sweeps", x.sweeps},         {"both_valid", x.both_valid}, {"mapped_only", x.mapped_only},
                     {"truth_only", x.truth_only}, {"neither", x.neither},       {"parameters", params}};
  return j.dump(2) + "\n";
}

std::vector<std::string> writeEvalOutputs(const EvalRun& run, const std::filesystem::path& dir) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw OutputError(dir.string() + ": cannot create output folder: " + ec.message());
  if (!(run.options.error_range_m > 0) || !std::isfinite(run.options.error_range_m))
    throw ConfigError("error_range_m must be positive and finite, got " + std::to_string(run.options.error_range_m));
  const Geometry& geo = run.geometry;
  LayeredMap m(geo);
  const Eigen::MatrixXf err = run.blind - run.truth, base_err = run.initial - run.truth;
  Eigen::MatrixXf region(geo.size().x(), geo.size().y());
  for (int i = 0; i < geo.size().x(); ++i)
    for (int j = 0; j < geo.size().y(); ++j)
      region(i, j) = run.region(i, j) < 0 ? std::numeric_limits<float>::quiet_NaN() : static_cast<float>(run.region(i, j));
  const Eigen::MatrixXf mapper_cut = run.mapper_cut.size() ? run.mapper_cut.cast<float>() : Eigen::MatrixXf(region.rows(), region.cols()).setZero();
  const std::vector<std::pair<std::string, const Eigen::MatrixXf*>> layers = {
      {"blind", &run.blind}, {"truth", &run.truth}, {"initial", &run.initial},
      {"error", &err},       {"baseline_error", &base_err}, {"region", &region}, {"mapper_cut", &mapper_cut}};
  for (const auto& [name, mat] : layers) m.fromMatrix(m.addLayer(name, (name == "region" || name == "mapper_cut") ? "1" : "m"), *mat);

  // One height colour range for the blind and truth renders, so equal colours mean equal
  // heights: the 0.1 and 99.9 percentiles of both, so a few cells of a spoil spike do not wash
  // out the rest (they clip; the hillshade still shows them).
  std::vector<double> hv;
  for (const Eigen::MatrixXf* mat : {&run.truth, &run.blind})
    for (Eigen::Index k = 0; k < mat->size(); ++k)
      if (std::isfinite(mat->data()[k])) hv.push_back(mat->data()[k]);
  std::sort(hv.begin(), hv.end());
  float lo = static_cast<float>(percentileSorted(hv, 0.1)), hi = static_cast<float>(percentileSorted(hv, 99.9));
  if (!(lo < hi)) {  // flat or empty
    lo = std::isfinite(lo) ? lo - 0.01f : -0.01f;
    hi = lo + 0.02f;
  }
  std::vector<std::string> files;
  io::RenderOptions height;
  height.scale = std::max(1, 800 / std::max(geo.size().x(), geo.size().y()));
  height.nan_color = io::Rgba{128, 128, 128, 255};
  height.range = io::ValueRange{lo, hi};
  height.hillshade = true;
  height.ambient = 0.35;
  io::RenderOptions error = height;
  error.hillshade = false;
  error.colormap = "rdbu";
  error.range = io::ValueRange{static_cast<float>(-run.options.error_range_m), static_cast<float>(run.options.error_range_m)};
  io::RenderOptions reg = height;
  reg.hillshade = false;
  reg.range = io::ValueRange{static_cast<float>(EvalRegion::Cut), static_cast<float>(EvalRegion::Untouched)};
  char cap[256];
  const RegionStats &cut = run.stats(EvalRegion::Cut), &out = run.stats(EvalRegion::Outside);
  std::snprintf(cap, sizeof cap, "RMSE inside the cut %.2f cm (no update: %.2f cm), outside %.2f cm (%.2f cm)",
                100 * cut.rmse_m, 100 * cut.baseline_rmse_m, 100 * out.rmse_m, 100 * out.baseline_rmse_m);
  const std::string caption = cap;
  auto annotation = [](std::string title, std::string text) {
    io::Annotation a;
    a.title = std::move(title);
    a.caption = std::move(text);
    return a;
  };
  const io::Annotation a_blind = annotation("blind heightmap [m]: blade only, no LiDAR", run.scenario);
  const io::Annotation a_truth = annotation("truth heightmap [m] at the end", run.scenario);
  const io::Annotation a_error = annotation("error: blind map - truth [cm]", caption);
  const io::Annotation a_base = annotation("error of the no-update baseline: initial map - truth [cm]", caption);
  io::Annotation a_reg = annotation("regions of the evaluation (from the truth's own cut and moved soil)", run.scenario);
  a_reg.categories = {{static_cast<float>(EvalRegion::Cut), "cut"},
                      {static_cast<float>(EvalRegion::Deposit), "deposit"},
                      {static_cast<float>(EvalRegion::Untouched), "untouched"}};
  const std::vector<std::tuple<std::string, std::string, const io::RenderOptions*, const io::Annotation*>> pngs = {
      {"blind", "blind_heightmap.png", &height, &a_blind}, {"truth", "truth_heightmap.png", &height, &a_truth},
      {"error", "error.png", &error, &a_error},            {"baseline_error", "baseline_error.png", &error, &a_base},
      {"region", "regions.png", &reg, &a_reg}};
  for (const auto& [layer, file, opt, ann] : pngs) {
    io::renderPng(m, layer, dir / file, *opt, *ann);
    files.push_back((dir / file).string());
  }
  std::vector<std::string> bands;
  for (const auto& l : layers) bands.push_back(l.first);
  io::writeGeoTiff(m, bands, dir / "eval.tif");
  files.push_back((dir / "eval.tif").string());
  io::writeFileAtomically(dir / "eval.json", evalJson(run));
  files.push_back((dir / "eval.json").string());

  std::ostringstream csv;
  csv.precision(9);
  csv << "sweep,machine,stamp_s,mapped_valid,truth_valid,alpha_rad,truth_alpha_rad,rho_rad,truth_rho_rad,"
         "truth_rho_raw_rad,d_m,truth_d_m,truth_d_raw_m,w_m,truth_w_m,truth_w_raw_m,q_n,truth_q_n\n";
  auto num = [](double v) { return std::isfinite(v) ? v : std::numeric_limits<double>::quiet_NaN(); };
  for (const ExtractionSample& s : run.samples)
    csv << s.sweep << ',' << s.machine << ',' << s.stamp << ',' << s.mapped_valid << ',' << s.truth_valid << ','
        << num(s.alpha_rad) << ',' << num(s.truth_alpha_rad) << ',' << num(s.rho_rad) << ',' << num(s.truth_rho_rad)
        << ',' << num(s.truth_rho_raw_rad) << ',' << num(s.d_m) << ',' << num(s.truth_d_m) << ',' << num(s.truth_d_raw_m) << ',' << num(s.w_m) << ','
        << num(s.truth_w_m) << ',' << num(s.truth_w_raw_m) << ',' << num(s.q_n) << ',' << num(s.truth_q_n) << '\n';
  io::writeFileAtomically(dir / "extraction.csv", csv.str());
  files.push_back((dir / "extraction.csv").string());
  return files;
}

std::string defaultEvalPipeline() {
  // Keep byte-equal to configs/eval_blind.yaml (tests/unit/sim/test_eval.cpp checks it).
  return R"(# Blind mapping evaluation (paper §3, Fig. 10): LiDAR off, only the blade updates the map.
# `terramap eval SCENARIO.yaml` runs this pipeline (it is compiled in; a test keeps the two
# equal) with the map fitted to the scenario's terrain; `--pipeline FILE` runs another one with
# its own map geometry (add `--fit-map` to fit it). `source` and `outputs` are not used by eval:
# the scenario drives the engine and eval writes its own outputs (--out).
# elevation is declared here because no LiDAR stage creates it; eval fills it with the
# simulator's initial truth before the first event.
version: 1
map: {resolution: 0.05, size: [200, 200], center: [0, 0], tile: 64, layers: [{name: elevation, unit: m}]}
threads: 2
source: {type: none}
pipeline:
  - {name: blade, type: blade_sweep, params: {swell: 1.2, min_translation_m: 0.2, report_steps: false}}
  - {name: erode, type: soil_erosion, params: {cohesion_pa: 25, friction_rad: 0.26}}
outputs: {dir: ../out/eval, snapshot: false, report: false}
)";
}

}  // namespace terramap::eval
