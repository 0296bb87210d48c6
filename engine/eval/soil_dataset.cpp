// The soil estimator's dataset: planning, running and storing episodes (soil_dataset.hpp).
#include <terramap/eval/soil_dataset.hpp>

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>
#include <terramap/io/atomic_file.hpp>
#include <terramap/io/file_seal.hpp>
#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/sim/episode.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/simulator.hpp>
#include <terramap/sim/truth_sampling.hpp>
#include <terramap/sim/world.hpp>

#include "../sim/h5_detail.hpp"
#include "yaml/reader.hpp"

#include <hdf5.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace terramap::eval {
namespace fs = std::filesystem;
using yaml::MapReader;

const char* datasetSplitName(DatasetSplit s) {
  switch (s) {
    case DatasetSplit::Train: return "train";
    case DatasetSplit::Validation: return "validation";
    case DatasetSplit::Test: return "test";
    case DatasetSplit::HeldOut: return "held_out";
  }
  return "unknown";
}

namespace {

constexpr double kDeg = 3.14159265358979323846 / 180.0;


// A stateless stream of draws: splitmix64 over (key, counter). Used instead of <random>'s
// distributions, whose outputs the standard leaves to the library: the plan of an episode must
// be the same bits on any machine that builds terramap.
struct Draws {
  std::uint64_t state;
  std::uint64_t next() {
    std::uint64_t z = (state += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
  }
  double u01() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }
  double in(Range r) { return r.lo + (r.hi - r.lo) * u01(); }
};

Range readRange(MapReader& r, const std::string& key, Range def, double lo, double hi) {
  const std::vector<double> v = r.vec(key, {def.lo, def.hi}, 2);
  Range out{v[0], v[1]};
  if (!(out.lo >= lo && out.hi <= hi && out.lo <= out.hi))
    r.error(r.node(key), key,
            "must be [lo, hi] with " + yaml::showBound(lo) + " <= lo <= hi <= " + yaml::showBound(hi));
  return out;
}

Range readDegRange(MapReader& r, const std::string& key, Range def_rad, double lo_deg, double hi_deg) {
  Range d = readRange(r, key, {def_rad.lo / kDeg, def_rad.hi / kDeg}, lo_deg, hi_deg);
  return {d.lo * kDeg, d.hi * kDeg};
}

soil::SoilFamily readFamily(MapReader& r, const std::string& key, soil::SoilFamily def) {
  const std::string name = r.str(key, soil::soilFamilyName(def));
  soil::SoilFamily f = def;
  if (!soil::parseSoilFamily(name, f))
    r.error(r.node(key), key, "unknown soil family '" + name + "' (one of clay, loam, sand, gravel)");
  return f;
}

std::string resolve(const std::string& base_dir, const std::string& p) {
  if (p.empty() || fs::path(p).is_absolute()) return p;
  return (fs::path(base_dir) / p).lexically_normal().string();
}

}  // namespace

SoilDatasetConfig parseSoilDatasetConfig(const std::string& text, const std::string& name, const std::string& base_dir) {
  yaml::Diagnostics d;
  d.file = name;
  const YAML::Node root = yaml::load(text, name);
  SoilDatasetConfig c;
  c.file = name;
  c.yaml_text = text;
  c.config_hash = fnv1a64Hex(text);
  MapReader r(d, root, "");
  r.integer("version", 1, 1, 1);
  c.seed = r.unsignedInt("seed", c.seed);
  c.episodes = r.integer("episodes", c.episodes, 1, 1000000);
  c.duration_s = r.num("duration_s", c.duration_s, 0.5, 3600);
  c.scenario = resolve(base_dir, r.strRequired("scenario"));
  c.pipeline = resolve(base_dir, r.strRequired("pipeline"));
  if (r.has("split")) {
    MapReader s = r.child("split");
    c.validation_fraction = s.num("validation", c.validation_fraction, 0, 0.5);
    c.test_fraction = s.num("test", c.test_fraction, 0, 0.5);
    s.finish();
  }
  if (r.has("history")) {
    MapReader h = r.child("history");
    c.history_T = h.integer("T", c.history_T, 1, 600);
    c.horizon_P = h.integer("P", c.horizon_P, 1, 600);
    if (c.horizon_P > c.history_T) h.error(h.node("P"), "P", "must not exceed T (the horizon is the end of the history)");
    h.finish();
  }
  if (r.has("families")) {
    c.families.clear();
    const YAML::Node fams = r.node("families");
    if (!fams.IsSequence() || fams.size() == 0) {
      r.error(fams, "families", "must be a non-empty list of soil families");
    } else {
      for (const auto& f : fams) {
        soil::SoilFamily fam{};
        const std::string n = f.IsScalar() ? f.as<std::string>() : "";
        if (!soil::parseSoilFamily(n, fam)) r.error(f, "families", "unknown soil family '" + n + "'");
        else c.families.push_back(fam);
      }
    }
  }
  c.relative_density = readRange(r, "relative_density", c.relative_density, 0, 1);
  c.rake_rad = readDegRange(r, "rake_deg", c.rake_rad, 30, 120);
  if (r.has("held_out")) {
    MapReader h = r.child("held_out");
    c.held_out_episodes = h.integer("episodes", c.held_out_episodes, 0, 1000000);
    c.held_out_family = readFamily(h, "family", c.held_out_family);
    c.held_out_relative_density = readRange(h, "relative_density", c.held_out_relative_density, 0, 1);
    c.held_out_rake_rad = h.num("rake_deg", c.held_out_rake_rad / kDeg, 30, 120) * kDeg;
    if (c.held_out_episodes > 0 && c.held_out_rake_rad >= c.rake_rad.lo && c.held_out_rake_rad <= c.rake_rad.hi)
      h.error(h.node("rake_deg"), "rake_deg", "must lie outside the in-distribution rake_deg range (never seen in training)");
    h.finish();
  } else if (c.held_out_episodes > 0 && c.held_out_rake_rad >= c.rake_rad.lo && c.held_out_rake_rad <= c.rake_rad.hi) {
    r.error(r.node("rake_deg"), "rake_deg", "must not include the held-out rake (" +
            yaml::showBound(c.held_out_rake_rad / kDeg) + " deg by default): give a held_out block");
  }
  c.route_fraction = r.num("route_fraction", c.route_fraction, 0.0, 1.0);
  c.fixed_scenario = r.boolean("fixed_scenario", c.fixed_scenario);
  if (r.has("hills")) {
    MapReader h = r.child("hills");
    c.hill_count = readRange(h, "count", c.hill_count, 0, 1000);
    c.hill_amplitude_m = readRange(h, "amplitude_m", c.hill_amplitude_m, -5, 5);
    c.hill_sigma_m = readRange(h, "sigma_m", c.hill_sigma_m, 0.05, 100);
    h.finish();
  }
  r.finish();
  d.throwIfAny();
  return c;
}

SoilDatasetConfig loadSoilDatasetConfig(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ConfigError(path + ": cannot open the dataset configuration");
  std::ostringstream os;
  os << in.rdbuf();
  const fs::path p(path);
  return parseSoilDatasetConfig(os.str(), path, p.has_parent_path() ? p.parent_path().string() : ".");
}

int episodeCount(const SoilDatasetConfig& cfg) { return cfg.episodes + cfg.held_out_episodes; }

EpisodePlan planEpisode(const SoilDatasetConfig& cfg, int index) {
  if (index < 0 || index >= episodeCount(cfg))
    throw std::out_of_range("planEpisode: index " + std::to_string(index) + " outside the dataset");
  // Held-out episodes draw from their own stream (j = index - episodes), so changing how many
  // in-distribution episodes there are never changes a held-out episode, nor the reverse.
  const bool held = index >= cfg.episodes;
  const std::uint64_t key = held ? 0x8000000000000000ull + static_cast<std::uint64_t>(index - cfg.episodes)
                                 : static_cast<std::uint64_t>(index);
  Draws g{cfg.seed * 0x2545f4914f6cdd1dull + key};
  EpisodePlan p;
  p.index = index;
  p.file_index = held ? index - cfg.episodes : index;
  if (!held) {
    const double u = g.u01();
    p.split = u < cfg.validation_fraction ? DatasetSplit::Validation
              : u < cfg.validation_fraction + cfg.test_fraction ? DatasetSplit::Test
                                                                 : DatasetSplit::Train;
    p.family = cfg.families[std::min(cfg.families.size() - 1,
                                     static_cast<std::size_t>(g.u01() * static_cast<double>(cfg.families.size())))];
    const Range id = cfg.relative_density;
    const Range ho = cfg.held_out_relative_density;
    if (p.family == cfg.held_out_family) {
      // Draw from the in-distribution range minus the held-out one (uniform over what is left).
      const double below = std::max(0.0, std::min(ho.lo, id.hi) - id.lo);
      const double above = std::max(0.0, id.hi - std::max(ho.hi, id.lo));
      const double v = g.u01() * (below + above);
      p.relative_density = v < below ? id.lo + v : std::max(ho.hi, id.lo) + (v - below);
    } else {
      p.relative_density = g.in(id);
    }
    p.rake_rad = g.in(cfg.rake_rad);
  } else {
    p.split = DatasetSplit::HeldOut;
    p.family = cfg.held_out_family;
    p.relative_density = g.in(cfg.held_out_relative_density);
    p.rake_rad = cfg.held_out_rake_rad;
  }
  p.hills = static_cast<int>(std::lround(g.in(cfg.hill_count)));
  p.hill_seed = g.next();
  p.seed = g.next() >> 11;  // below 2^53: survives a round trip through JSON and HDF5 doubles
  for (double& f : p.initial_setpoints) f = g.u01();
  // Drawn last, so the draws above (and the episodes of a dataset without routes) stay as they were.
  p.route = g.u01() < cfg.route_fraction;
  return p;
}

sim::Scenario episodeScenario(const SoilDatasetConfig& cfg, const EpisodePlan& plan) {
  sim::Scenario sc = sim::loadScenario(cfg.scenario);
  if (cfg.fixed_scenario) {
    if (plan.index > 0) sc.seed = plan.seed;
    return sc;
  }
  sc.seed = plan.seed;
  sc.duration_s = cfg.duration_s;
  sc.default_soil = soil::soilProperties(plan.family, plan.relative_density);
  sc.zones.clear();
  sim::TerrainSpec& t = sc.terrain;
  t.bumps.clear();
  Draws g{plan.hill_seed};
  for (int i = 0; i < plan.hills; ++i) {
    sim::GaussianBump b;
    b.x_m = t.origin_x_m + g.u01() * t.size_x_m;
    b.y_m = t.origin_y_m + g.u01() * t.size_y_m;
    b.amplitude_m = g.in(cfg.hill_amplitude_m);
    b.sigma_m = g.in(cfg.hill_sigma_m);
    t.bumps.push_back(b);
  }
  for (sim::MachineSpec& m : sc.machines) {
    m.rake_rad = plan.rake_rad;
    sim::ControllerSpec& c = m.controller;
    sim::RandomWalk* walks[5] = {&c.speed_mps, &c.depth_m, &c.roll_rad, &c.yaw_rad, &c.heading_rad};
    for (int k = 0; k < 5; ++k) walks[k]->initial = walks[k]->min + plan.initial_setpoints[k] * (walks[k]->max - walks[k]->min);
    if (plan.route) {
      // One forward pass from the machine's pose, long enough for the episode, the edge held at
      // a grade this far below the ground under the blade's start (the terrain's hills make the
      // cut deeper, or nothing, along the way, as on a site graded to a plane).
      const double heading = m.yaw_rad + c.heading_rad.initial;
      const Eigen::Vector2d start(m.x_m, m.y_m);
      const Eigen::Vector2d edge = start + m.blade_mount_x_m * Eigen::Vector2d(std::cos(heading), std::sin(heading));
      c.type = sim::ControllerSpec::Type::Route;
      c.route_start = start;
      c.route_heading_rad = heading;
      c.route_speed_mps = c.speed_mps.initial;
      c.route_length_m = c.route_speed_mps * cfg.duration_s + 2.0;
      c.route_passes = 1;
      c.route_grade = true;
      c.grade_first_m = sim::analyticSurfaceAt(t, edge.x(), edge.y()) - std::max(0.03, c.depth_m.initial);
      c.grade_step_m = 0.0;
    }
  }
  return sc;
}


namespace {

const sim::MachineTruth* machineTruthOf(const sim::Simulator& simulator, const std::string& id) {
  for (std::size_t mi = 0; mi < simulator.machineCount(); ++mi)
    if (simulator.machineTruth(mi).id == id) return &simulator.machineTruth(mi);
  return nullptr;
}

/// The simulator's FEE geometry of a cut (alpha, rho, depth, width, q); NaN when not cutting.
std::array<float, 5> feeGeometryOf(const sim::FeeTruth* ft) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  if (ft == nullptr || ft->cutting_slices <= 0) return {nan, nan, nan, nan, nan};
  return {static_cast<float>(ft->alpha_rad), static_cast<float>(ft->rho_rad), static_cast<float>(ft->depth_m),
          static_cast<float>(ft->width_m), static_cast<float>(ft->q_n)};
}

/// The simulator's truth at each observation of each machine (the stamps of the observation
/// histories), so a sample's horizon rows find theirs (EpisodeData's per-row truth).
class TruthRows {
 public:
  explicit TruthRows(std::size_t capacity) : capacity_(capacity) {}

  /// An observation's truth; an older stamp is ignored, as ObservationHistory::push does.
  void record(double stamp, const sim::MachineTruth& mt) {
    auto& rows = rows_[mt.id];
    if (!rows.empty() && stamp < rows.back().stamp) return;
    const float nan = std::numeric_limits<float>::quiet_NaN();
    const bool cut = mt.fee.cutting_slices > 0;
    const std::array<float, 8> profile =
        cut ? std::array<float, 8>{static_cast<float>(mt.fee.area_m2), static_cast<float>(mt.fee.depth2_m3),
                                   static_cast<float>(mt.fee.q_pushed_n), static_cast<float>(mt.fee.c_pa),
                                   static_cast<float>(mt.fee.phi_rad), static_cast<float>(mt.fee.ca_pa),
                                   static_cast<float>(mt.fee.delta_rad), static_cast<float>(mt.fee.gamma_n_m3)}
            : std::array<float, 8>{nan, nan, static_cast<float>(mt.fee.q_pushed_n), nan, nan, nan, nan, nan};
    rows.push_back({stamp, feeGeometryOf(&mt.fee), profile,
                    {mt.force_fee_map_N, mt.force_inertia_map_N, mt.force_penetration_map_N},
                    static_cast<float>(mt.edge_vz_mps)});
    while (rows.size() > capacity_) rows.pop_front();
  }

  /// The last P rows up to the sweep's end (the rows buildSample took: same stamps, same rule),
  /// forces in the sample's frame (along t̂, up; blade on soil); NaN rows when fewer are kept.
  void appendTo(const SweepRecord& rec, int P, EpisodeData& out) const {
    const std::size_t n = static_cast<std::size_t>(P);
    std::vector<float> geo, profile, parts, vz;
    const auto found = rows_.find(rec.machine_id);
    if (found != rows_.end()) {
      const auto& rows = found->second;
      const auto end = std::upper_bound(rows.begin(), rows.end(), rec.t1 + 1e-9,
                                        [](double t, const Row& r) { return t < r.stamp; });
      for (auto it = end - std::min<long>(P, end - rows.begin()); it != end; ++it) {
        geo.insert(geo.end(), it->geometry.begin(), it->geometry.end());
        profile.insert(profile.end(), it->profile.begin(), it->profile.end());
        for (const Eigen::Vector3d& f : it->parts) {
          parts.push_back(static_cast<float>(-f.head<2>().dot(rec.t_hat)));
          parts.push_back(static_cast<float>(-f.z()));
        }
        vz.push_back(it->edge_vz);
      }
    }
    if (vz.size() < n) {
      const float nan = std::numeric_limits<float>::quiet_NaN();
      geo.assign(n * 5, nan);
      profile.assign(n * 8, nan);
      parts.assign(n * 6, nan);
      vz.assign(n, nan);
    }
    out.truth_geometry_rows.push_back(std::move(geo));
    out.truth_profile_rows.push_back(std::move(profile));
    out.force_parts.push_back(std::move(parts));
    out.edge_vz_rows.push_back(std::move(vz));
  }

 private:
  struct Row {
    double stamp;
    std::array<float, 5> geometry;
    std::array<float, 8> profile;  // area, depth2, q_pushed, the soil c, phi, ca, delta, gamma
    Eigen::Vector3d parts[3];  // map frame, soil on blade
    float edge_vz;
  };
  std::size_t capacity_;
  std::map<std::string, std::deque<Row>> rows_;
};

}  // namespace

EpisodeData runDatasetEpisode(const SoilDatasetConfig& cfg, const EpisodePlan& plan, int threads,
                              const std::function<void(double, double)>& on_progress) {
  const auto wall0 = std::chrono::steady_clock::now();
  sim::Scenario sc = episodeScenario(cfg, plan);
  if (threads > 0) sc.threads = threads;
  sim::Simulator simulator(sc);
  PipelineSpec spec = parsePipelineFile(cfg.pipeline);
  if (threads > 0) spec.threads = threads;
  const Geometry g = sim::fitGeometry(simulator.truth(), spec.resolution);
  spec.size = g.size();
  spec.center = g.center();
  // A dataset's pipeline file may not choose where code is loaded from (PluginRegistry's trust rule).
  const PluginRegistry registry = PluginRegistry::forPipeline(spec.plugin_paths, spec.plugin_paths_where);
  auto engine = Engine::fromSpec(spec, registry);

  EpisodeData out;
  out.plan = plan;
  std::map<std::string, soil::ObservationHistory> history;
  const std::size_t capacity = static_cast<std::size_t>(cfg.history_T) + 64;
  // The same observations with the force sensor reading the simulator's force without its noise:
  // buildSample on them gives that force in the sample's own frame, sign and rows.
  std::map<std::string, soil::ObservationHistory> quiet_history;
  TruthRows truth_rows(capacity);
  long last_sequence = 0;
  std::vector<std::shared_ptr<const SweepRecord>> pending;
  auto collect = [&] {
    const Record* r = engine->records().latest(SweepRecord::kType);
    if (r != nullptr && r->sequence != last_sequence) {
      last_sequence = r->sequence;
      pending.push_back(std::static_pointer_cast<const SweepRecord>(r->payload));
    }
  };
  // Samples are built once the whole observation period has been pushed, so the observation
  // at the sweep's last pose (same stamp, whatever the event order) is in the history.
  auto build = [&] {
    for (const auto& rec : pending) {
      ++out.sweeps;
      auto it = history.find(rec->machine_id);
      soil::PinnSample s;
      const soil::SampleSkip why = it == history.end()
          ? soil::SampleSkip::ShortHistory
          : soil::buildSample(it->second, *rec, cfg.history_T, cfg.horizon_P, s);
      if (why != soil::SampleSkip::None) {
        ++out.skipped[soil::sampleSkipName(why)];
        continue;
      }
      // Truth soil where the blade cut: the soil field at the cutting edge, at the cut depth.
      const Eigen::Vector3d edge = rec->T_map_blade1.translation();
      const soil::SoilProperties& truth = simulator.soil().at(edge.x(), edge.y(), std::max(0.0, rec->d_m));
      out.truth.push_back({static_cast<float>(truth.fee.c_pa), static_cast<float>(truth.fee.phi_rad),
                           static_cast<float>(truth.fee.ca_pa), static_cast<float>(truth.fee.delta_rad),
                           static_cast<float>(truth.fee.gamma_n_m3)});
      const sim::MachineTruth* mt = machineTruthOf(simulator, rec->machine_id);
      out.truth_geometry.push_back(feeGeometryOf(mt ? &mt->fee : nullptr));
      const float nan = std::numeric_limits<float>::quiet_NaN();
      // Both histories hold the same stamps and features, so the same rows are taken.
      const auto qh = quiet_history.find(rec->machine_id);
      soil::PinnSample qs;
      const bool quiet_known = qh != quiet_history.end() &&
          soil::buildSample(qh->second, *rec, cfg.history_T, cfg.horizon_P, qs) == soil::SampleSkip::None;
      out.force_quiet.push_back(quiet_known ? std::move(qs.force) : std::vector<float>(s.force.size(), nan));
      truth_rows.appendTo(*rec, s.P, out);
      out.samples.push_back(std::move(s));
    }
    pending.clear();
  };
  std::vector<Event> events;
  while (simulator.next(events)) {
    for (const Event& e : events) {
      if (const auto* o = std::get_if<Observation>(&e)) {
        auto it = history.try_emplace(o->machine_id, capacity).first;
        it->second.push(*o);
        // Between two periods machineTruth() is this period's, the period of this observation.
        if (const sim::MachineTruth* mt = machineTruthOf(simulator, o->machine_id)) {
          Observation quiet = *o;
          quiet.force_base_N = mt->T_map_base.linear().transpose() * mt->force_quiet_map_N;
          quiet_history.try_emplace(o->machine_id, capacity).first->second.push(quiet);
          truth_rows.record(o->stamp, *mt);
        }
      }
      engine->push(e);
      collect();
    }
    events.clear();
    build();
    if (on_progress) on_progress(simulator.time(), sc.duration_s);
  }
  engine->finish();
  collect();
  build();
  out.simulated_s = simulator.time();
  out.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  return out;
}

std::string episodeFileName(const EpisodePlan& plan) {
  char buf[32];
  std::snprintf(buf, sizeof buf, plan.split == DatasetSplit::HeldOut ? "held_%05d.h5" : "ep_%05d.h5", plan.file_index);
  return buf;
}

void writeEpisodeFile(const std::string& path, const SoilDatasetConfig& cfg, const EpisodeData& ep) {
  const hsize_t n = ep.samples.size();
  const hsize_t T = static_cast<hsize_t>(cfg.history_T), P = static_cast<hsize_t>(cfg.horizon_P);
  std::vector<float> obs, theta, profile, force, truth, truth_geo, force_quiet, geo_rows, profile_rows, parts, vz_rows;
  std::vector<double> anchor;
  std::vector<long long> sweep;
  obs.reserve(n * T * soil::kObsFeatures);
  for (std::size_t i = 0; i < ep.samples.size(); ++i) {
    const soil::PinnSample& s = ep.samples[i];
    obs.insert(obs.end(), s.obs.begin(), s.obs.end());
    theta.insert(theta.end(), s.theta_k.begin(), s.theta_k.end());
    if (s.profile.size() == static_cast<std::size_t>(s.P) * soil::kProfile) profile.insert(profile.end(), s.profile.begin(), s.profile.end());
    else profile.insert(profile.end(), static_cast<std::size_t>(s.P) * soil::kProfile, std::numeric_limits<float>::quiet_NaN());
    force.insert(force.end(), s.force.begin(), s.force.end());
    truth.insert(truth.end(), ep.truth[i].begin(), ep.truth[i].end());
    if (i < ep.truth_geometry.size()) truth_geo.insert(truth_geo.end(), ep.truth_geometry[i].begin(), ep.truth_geometry[i].end());
    else truth_geo.insert(truth_geo.end(), 5, std::numeric_limits<float>::quiet_NaN());
    if (i < ep.force_quiet.size() && ep.force_quiet[i].size() == s.force.size())
      force_quiet.insert(force_quiet.end(), ep.force_quiet[i].begin(), ep.force_quiet[i].end());
    else
      force_quiet.insert(force_quiet.end(), s.force.size(), std::numeric_limits<float>::quiet_NaN());
    const auto perRow = [&](const std::vector<std::vector<float>>& from, std::vector<float>& to, std::size_t width) {
      const std::size_t count = static_cast<std::size_t>(s.P) * width;
      if (i < from.size() && from[i].size() == count) to.insert(to.end(), from[i].begin(), from[i].end());
      else to.insert(to.end(), count, std::numeric_limits<float>::quiet_NaN());
    };
    perRow(ep.truth_geometry_rows, geo_rows, 5);
    perRow(ep.truth_profile_rows, profile_rows, 8);
    perRow(ep.force_parts, parts, 6);
    perRow(ep.edge_vz_rows, vz_rows, 1);
    anchor.push_back(s.anchor_stamp);
    sweep.push_back(s.sweep_index);
  }
  const EpisodePlan& p = ep.plan;
  const double plan[9] = {static_cast<double>(p.file_index), static_cast<double>(p.split), static_cast<double>(p.family),
                          p.relative_density, p.rake_rad, static_cast<double>(p.hills), static_cast<double>(p.seed),
                          ep.simulated_s, p.route ? 1.0 : 0.0};
  std::string skipped;
  for (const auto& [k, v] : ep.skipped) skipped += (skipped.empty() ? "" : ",") + k + "=" + std::to_string(v);
  io::replaceFileAtomically(path, [&](const fs::path& tmp) {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    const hid_t fcpl = H5Pcreate(H5P_FILE_CREATE);
    H5Pset_userblock(fcpl, io::kSealBytes);  // room for the seal (io/file_seal.hpp)
    const hid_t f = H5Fcreate(tmp.c_str(), H5F_ACC_TRUNC, fcpl, H5P_DEFAULT);
    H5Pclose(fcpl);
    if (f < 0) throw OutputError(path + ": cannot create HDF5 file");
    try {
      using namespace h5detail;
      attrU64(f, "version", 1);
      attrString(f, "config_hash", cfg.config_hash);
      attrString(f, "obs_features", joinStrings(soil::obsFeatureNames(), ","));
      attrString(f, "theta_k", joinStrings(soil::thetaKNames(), ","));
      attrString(f, "truth", "c_pa,phi_rad,ca_pa,delta_rad,gamma_n_m3");
      attrString(f, "plan", "index,split,family,relative_density,rake_rad,hills,seed,simulated_s,route");
      attrString(f, "split", datasetSplitName(p.split));
      attrString(f, "family", soil::soilFamilyName(p.family));
      attrString(f, "skipped", skipped);
      attrU64(f, "sweeps", static_cast<std::uint64_t>(ep.sweeps));
      writeArray(f, "plan", H5T_NATIVE_DOUBLE, plan, {9}, 0, path);
      writeArray(f, "obs", H5T_NATIVE_FLOAT, obs.data(), {n, T, static_cast<hsize_t>(soil::kObsFeatures)}, 4, path);
      writeArray(f, "theta_k", H5T_NATIVE_FLOAT, theta.data(), {n, P, static_cast<hsize_t>(soil::kThetaK)}, 4, path);
      writeArray(f, "profile", H5T_NATIVE_FLOAT, profile.data(), {n, P, static_cast<hsize_t>(soil::kProfile)}, 4, path);
      attrString(f, "profile", "area_m2,depth2_m3");
      writeArray(f, "force", H5T_NATIVE_FLOAT, force.data(), {n, P, 2}, 4, path);
      writeArray(f, "truth", H5T_NATIVE_FLOAT, truth.data(), {n, 5}, 4, path);
      writeArray(f, "truth_geometry", H5T_NATIVE_FLOAT, truth_geo.data(), {n, 5}, 4, path);
      attrString(f, "truth_geometry", "alpha_rad,rho_rad,d_m,w_m,q_n");
      writeArray(f, "force_quiet", H5T_NATIVE_FLOAT, force_quiet.data(), {n, P, 2}, 4, path);
      writeArray(f, "truth_geometry_rows", H5T_NATIVE_FLOAT, geo_rows.data(), {n, P, 5}, 4, path);
      writeArray(f, "truth_profile_rows", H5T_NATIVE_FLOAT, profile_rows.data(), {n, P, 8}, 4, path);
      attrString(f, "truth_profile_rows", "area_m2,depth2_m3,q_pushed_n,c_pa,phi_rad,ca_pa,delta_rad,gamma_n_m3");
      writeArray(f, "force_parts", H5T_NATIVE_FLOAT, parts.data(), {n, P, 3, 2}, 4, path);
      attrString(f, "force_parts", "fee_mobilised,inertia_mobilised,penetration");
      writeArray(f, "edge_vz", H5T_NATIVE_FLOAT, vz_rows.data(), {n, P}, 4, path);
      writeArray(f, "anchor_stamp", H5T_NATIVE_DOUBLE, anchor.data(), {n}, 4, path);
      writeArray(f, "sweep_index", H5T_NATIVE_LLONG, sweep.data(), {n}, 4, path);
    } catch (...) {
      H5Fclose(f);
      throw;
    }
    if (H5Fclose(f) < 0) throw OutputError(path + ": cannot close HDF5 file");
    io::sealFile(tmp);
  });
}

namespace {

// An episode file's plan (writeEpisodeFile's layout): 9 values since the route flag, the first 8
// in files written before it.
std::vector<double> readPlan(const sim::EpisodeFile& file, const std::string& path) {
  std::vector<std::uint64_t> dims;
  std::vector<double> plan = file.read("plan", dims);
  if (plan.size() != 8 && plan.size() != 9) throw InputError(path + ": dataset 'plan' must hold 8 or 9 values");
  return plan;
}

// ep_NNNNN.h5 then held_NNNNN.h5 of DIR/episodes in index order (temporaries of a killed writer are not listed).
std::vector<fs::path> episodeFiles(const std::string& dir) {
  const fs::path ep_dir = fs::path(dir) / "episodes";
  std::vector<fs::path> files;
  std::error_code ec;
  for (fs::directory_iterator it(ep_dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if ((name.rfind("ep_", 0) == 0 || name.rfind("held_", 0) == 0) && it->path().extension() == ".h5")
      files.push_back(it->path());
  }
  if (ec) throw InputError(ep_dir.string() + ": cannot list the episode files: " + ec.message());
  if (files.empty()) throw InputError(ep_dir.string() + ": no episode files (ep_NNNNN.h5); run `terramap dataset` first");
  std::sort(files.begin(), files.end());  // "ep_" before "held_", each in index order
  return files;
}


}  // namespace

std::string datasetManifestJson(const std::string& dir) {
  nlohmann::ordered_json j;
  nlohmann::ordered_json splits = nlohmann::ordered_json::object(), families = nlohmann::ordered_json::object(),
                         skipped = nlohmann::ordered_json::object();
  long episodes = 0, samples = 0;
  double simulated = 0;
  std::string hash;
  for (const fs::path& f : episodeFiles(dir)) {
    const std::string path = f.string();
    const sim::EpisodeFile file(path);
    if (hash.empty()) hash = file.rootAttribute("config_hash");
    std::vector<std::uint64_t> dims;
    const std::vector<double> plan = readPlan(file, path);
    file.read("truth", dims);
    const long n = dims.empty() ? 0 : static_cast<long>(dims[0]);
    const std::string split = datasetSplitName(static_cast<DatasetSplit>(static_cast<int>(plan[1])));
    const std::string fam = soil::soilFamilyName(static_cast<soil::SoilFamily>(static_cast<int>(plan[2])));
    if (!splits.contains(split)) splits[split] = {{"episodes", 0L}, {"samples", 0L}};
    auto& s = splits[split];
    s["episodes"] = s.value("episodes", 0L) + 1;
    s["samples"] = s.value("samples", 0L) + n;
    families[fam] = families.value(fam, 0L) + n;
    std::stringstream ss(file.rootAttribute("skipped"));
    for (std::string item; std::getline(ss, item, ',');) {
      const auto eq = item.find('=');
      if (eq == std::string::npos) continue;
      const std::string k = item.substr(0, eq);
      skipped[k] = skipped.value(k, 0L) + std::stol(item.substr(eq + 1));
    }
    ++episodes;
    samples += n;
    simulated += plan[7];
  }
  j["config_hash"] = hash;
  j["episodes"] = episodes;
  j["samples"] = samples;
  j["simulated_s"] = simulated;
  j["splits"] = splits;
  j["samples_per_family"] = families;
  j["sweeps_skipped"] = skipped;
  return j.dump(2);
}

SoilDataset readSoilDataset(const std::string& dir) {
  const std::vector<fs::path> files = episodeFiles(dir);
  SoilDataset d;
  for (const fs::path& f : files) {
    const std::string path = f.string();
    const sim::EpisodeFile file(path);
    std::vector<std::uint64_t> dims;
    {
      const std::string hash = file.rootAttribute("config_hash");
      if (d.config_hash.empty()) d.config_hash = hash;
      else if (hash != d.config_hash)
        throw InputError(path + ": written with another configuration (config_hash " + hash + ", the first file has " +
                         d.config_hash + "); a dataset folder holds one configuration's episodes");
    }
    const std::vector<double> plan = readPlan(file, path);
    const std::vector<double> obs = file.read("obs", dims);
    if (dims.size() != 3 || dims[2] != static_cast<std::uint64_t>(soil::kObsFeatures))
      throw InputError(path + ": dataset 'obs' must be [N, T, " + std::to_string(soil::kObsFeatures) + "]");
    const std::size_t n = dims[0];
    const int T = static_cast<int>(dims[1]);
    const std::vector<double> theta = file.read("theta_k", dims);
    if (dims.size() != 3 || dims[0] != n || dims[2] != static_cast<std::uint64_t>(soil::kThetaK))
      throw InputError(path + ": dataset 'theta_k' must be [N, P, 6] with the N of 'obs'");
    const int P = static_cast<int>(dims[1]);
    const std::vector<double> force = file.read("force", dims);
    if (dims.size() != 3 || dims[0] != n || dims[1] != static_cast<std::uint64_t>(P) || dims[2] != 2)
      throw InputError(path + ": dataset 'force' must be [N, P, 2]");
    const std::vector<double> truth = file.read("truth", dims);
    if (dims.size() != 2 || dims[0] != n || dims[1] != 5) throw InputError(path + ": dataset 'truth' must be [N, 5]");
    if (d.T == 0 && d.P == 0) {
      d.T = T;
      d.P = P;
    } else if (T != d.T || P != d.P) {
      throw InputError(path + ": T = " + std::to_string(T) + ", P = " + std::to_string(P) + " differ from the first file's " +
                       std::to_string(d.T) + ", " + std::to_string(d.P));
    }
    d.obs.insert(d.obs.end(), obs.begin(), obs.end());
    d.theta_k.insert(d.theta_k.end(), theta.begin(), theta.end());
    d.force.insert(d.force.end(), force.begin(), force.end());
    d.truth.insert(d.truth.end(), truth.begin(), truth.end());
    // Diagnosis-only datasets that older files lack: NaN (never trained on). Files of the first
    // layout have no truth geometry, files written before the noise-free force was kept no
    // force_quiet.
    const auto optional = [&](const char* name, std::vector<float>& to, const std::vector<std::uint64_t>& want,
                              const char* shape) {
      try {
        const std::vector<double> v = file.read(name, dims);
        if (dims != want) throw InputError(path + ": dataset '" + name + "' must be " + shape);
        to.insert(to.end(), v.begin(), v.end());
      } catch (const InputError& e) {
        if (std::string(e.what()).find("no dataset") == std::string::npos) throw;
        std::uint64_t count = 1;
        for (const std::uint64_t w : want) count *= w;
        to.insert(to.end(), count, std::numeric_limits<float>::quiet_NaN());
      }
    };
    optional("truth_geometry", d.truth_geometry, {n, 5}, "[N, 5]");
    optional("force_quiet", d.force_quiet, {n, static_cast<std::uint64_t>(P), 2}, "[N, P, 2] with the N and P of 'force'");
    const std::uint64_t Pu = static_cast<std::uint64_t>(P);
    optional("truth_geometry_rows", d.truth_geometry_rows, {n, Pu, 5}, "[N, P, 5] with the N and P of 'force'");
    optional("force_parts", d.force_parts, {n, Pu, 3, 2}, "[N, P, 3, 2] with the N and P of 'force'");
    optional("edge_vz", d.edge_vz_rows, {n, Pu}, "[N, P] with the N and P of 'force'");
    optional("profile", d.profile, {n, Pu, static_cast<std::uint64_t>(soil::kProfile)}, "[N, P, 2] with the N and P of 'force'");
    optional("truth_profile_rows", d.truth_profile_rows, {n, Pu, 8}, "[N, P, 8] with the N and P of 'force'");
    for (std::size_t i = 0; i < n; ++i) {
      d.episode.push_back(static_cast<int>(plan[0]));
      d.split.push_back(static_cast<std::uint8_t>(plan[1]));
      d.family.push_back(static_cast<std::uint8_t>(plan[2]));
      d.relative_density.push_back(static_cast<float>(plan[3]));
      d.rake_rad.push_back(static_cast<float>(plan[4]));
    }
  }
  return d;
}

}  // namespace terramap::eval
