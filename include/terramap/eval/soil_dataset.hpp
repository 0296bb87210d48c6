#pragma once
/// \file
/// The soil estimator's training data (paper §3.1; ALGORITHMS.md §F), the library behind
/// `terramap dataset CONFIG --out DIR` (MPI ranks via `mpirun -np N terramap dataset ...`).
///
/// An episode is one simulator run of `duration_s` with one compact track loader on a uniform
/// soil (family × I_d), randomized hills and dips, random-walk set-points and a blade rake, played
/// through the mapping pipeline (LiDAR fusion, blade_sweep, erosion on the *mapped* terrain, with
/// the scenario's realistic localisation). Every SweepRecord the pipeline publishes gives one
/// sample (soil/pinn_sample.hpp); the truth soil at the cut is logged beside it for evaluation
/// only. Episodes are planned from (seed, index) alone, so which rank runs an episode, and how
/// many ranks there are, never changes its content.
///
/// Splits: the first `episodes` are in-distribution, assigned to train/validation/test by a hash
/// of (seed, index); the next `held_out.episodes` (their own numbering and random stream, so
/// either count can change without changing the other set's episodes) draw their soil family and I_d range and their
/// blade rake from the `held_out` block, which the in-distribution episodes never draw (the
/// held-out family's I_d range is excluded for it; the held-out rake lies outside `rake_deg`).
///
/// Layout of DIR: `episodes/ep_NNNNN.h5` and `held_NNNNN.h5` (one per episode, written atomically, so a killed run
/// resumes by skipping the files that exist), `manifest.json` (config hash, counts per split and
/// skip reason), `config.yaml` (the config as given). Units: SI (Pa, rad, N/m³, m, N, s).
/// Threading: planning and reading are pure; runEpisode() drives its own Simulator and Engine.
#include <terramap/core/export.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/soil/pinn_sample.hpp>
#include <terramap/soil/soil_table.hpp>

#include <array>
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

namespace terramap::eval {

enum class DatasetSplit : int { Train = 0, Validation = 1, Test = 2, HeldOut = 3 };
TERRAMAP_API const char* datasetSplitName(DatasetSplit s);

struct Range {
  double lo = 0, hi = 0;
};

/// `terramap dataset` configuration (configs/dataset/pinn.yaml documents every key).
struct SoilDatasetConfig {
  std::string file;          ///< where it was loaded from ("" from a string)
  std::string yaml_text;     ///< verbatim
  std::string config_hash;   ///< FNV-1a 64 of yaml_text, hex
  std::uint64_t seed = 1;
  int episodes = 300;        ///< in-distribution episodes
  double duration_s = 10;
  double validation_fraction = 0.15, test_fraction = 0.15;
  int history_T = 60;        ///< observations per sample (the trainer may use a suffix)
  int horizon_P = 20;        ///< horizon steps per sample (the trainer may use a suffix)
  std::vector<soil::SoilFamily> families{soil::SoilFamily::Clay, soil::SoilFamily::Loam,
                                         soil::SoilFamily::Sand, soil::SoilFamily::Gravel};
  Range relative_density{0.01, 1.0};
  Range rake_rad{76 * 3.14159265358979323846 / 180, 84 * 3.14159265358979323846 / 180};
  // Held-out set: a soil (family, I_d range) and a rake never drawn in-distribution.
  int held_out_episodes = 32;
  soil::SoilFamily held_out_family = soil::SoilFamily::Gravel;
  Range held_out_relative_density{0.7, 1.0};
  double held_out_rake_rad = 70 * 3.14159265358979323846 / 180;
  // Terrain: hills and dips per episode (mixture of Gaussians).
  Range hill_count{5, 25};
  Range hill_amplitude_m{-0.25, 0.3};
  Range hill_sigma_m{1.0, 4.0};
  /// Share of the episodes (in-distribution and held-out alike) driven as a site is graded:
  /// one pass of a route controller holding the cutting edge at a grade below the start
  /// (GNSS machine control: the edge holds a plane while the chassis pitches over the hills)
  /// instead of the random-walk set-points. The grade depth, speed and heading come from the
  /// episode's initial set-points (depth at least 3 cm).
  double route_fraction = 0.0;
  /// The base scenario as it is (its soil and zones, terrain, controller and duration; the
  /// config's duration_s, families, ranges, hills and routes are not used), only the seed
  /// replaced: episode 0 keeps the scenario's own, episode k takes a draw of (seed, k). For the
  /// rows of a given scenario (the soil-map scenarios) beside their truth, for diagnosis.
  bool fixed_scenario = false;
  /// Base scenario (machine, sensors, controller ranges, terrain size); per episode the soil,
  /// seed, duration, hills, rake and the controller's initial set-points are replaced.
  std::string scenario;
  /// Mapping pipeline (its map is fitted to the terrain; its source is ignored).
  std::string pipeline;
};

/// Loads and validates (every error at once, file:line:col). Relative paths resolve against the
/// config's folder. \throws ConfigError.
TERRAMAP_API SoilDatasetConfig loadSoilDatasetConfig(const std::string& path);
TERRAMAP_API SoilDatasetConfig parseSoilDatasetConfig(const std::string& yaml_text, const std::string& name,
                                                      const std::string& base_dir);

/// What makes episode `index` what it is (drawn from (seed, index) only).
struct EpisodePlan {
  int index = 0;       ///< in [0, episodeCount): in-distribution first, then held-out
  int file_index = 0;  ///< index within its set (in-distribution or held-out): the file's number
  DatasetSplit split = DatasetSplit::Train;
  std::uint64_t seed = 0;  ///< the scenario's seed
  soil::SoilFamily family = soil::SoilFamily::Loam;
  double relative_density = 0.5;
  double rake_rad = 80 * 3.14159265358979323846 / 180;
  int hills = 0;
  std::uint64_t hill_seed = 0;
  std::array<double, 5> initial_setpoints{};  ///< speed, depth, roll, yaw, heading
  bool route = false;  ///< graded by a route controller (SoilDatasetConfig::route_fraction)
};
TERRAMAP_API int episodeCount(const SoilDatasetConfig& cfg);
/// \throws std::out_of_range when index is not in [0, episodeCount(cfg)).
TERRAMAP_API EpisodePlan planEpisode(const SoilDatasetConfig& cfg, int index);

/// One episode's samples and bookkeeping.
struct EpisodeData {
  EpisodePlan plan;
  std::vector<soil::PinnSample> samples;
  std::vector<std::array<float, 5>> truth;  ///< per sample: c, phi, ca, delta, gamma at the cut
  /// Per sample, for diagnosis only (how far the mapped Θ_k is from the simulator's): the
  /// simulator's own FEE geometry of the cut at the end of the sweep's observation period
  /// (sim::FeeTruth: alpha, rho, depth, width, surcharge q), NaN when it was not cutting.
  std::vector<std::array<float, 5>> truth_geometry;
  /// Per sample, P × 2 (along t̂, up; blade on soil, N) like PinnSample::force: the simulator's
  /// force at the same horizon rows without its coloured noise (sim::MachineTruth::
  /// force_quiet_map_N) and without the sensor's: soil::buildSample on the same observations with
  /// the force sensor reading that force (NaN if that sample could not be built). For
  /// evaluation only: the error of an estimator that predicted this force exactly is the floor
  /// that the measured force's noise puts under every estimator's force error.
  std::vector<std::vector<float>> force_quiet;
  /// Per sample and horizon row, for diagnosis only (where the estimator's force error lives,
  /// `eval-soil`'s decomposition): the simulator's FEE geometry of that row's period
  /// (sim::FeeTruth alpha, rho, depth, width, q; P × 5, NaN when not cutting), and the parts of
  /// force_quiet at that row (P × 3 × 2: FEE over the slices and inertia as mobilised, and the
  /// edge's penetration resistance; along t̂ and up, blade on soil, N), and the edge's true
  /// vertical speed (P, m/s). Empty vectors when the rows could not be matched.
  std::vector<std::vector<float>> truth_geometry_rows, force_parts, edge_vz_rows;
  /// Per sample and horizon row, for diagnosis only: the simulator's cut cross-section over its
  /// cutting slices and the surcharge ahead of the slices that push without cutting
  /// (sim::FeeTruth area_m2, depth2_m3, q_pushed_n), and the soil of that row's cut (its c, φ,
  /// c_a, δ, γ; a sample's rows can straddle a soil boundary); P × 8, NaN rows when unmatched.
  std::vector<std::vector<float>> truth_profile_rows;
  long sweeps = 0;                           ///< SweepRecords seen
  std::map<std::string, long> skipped;       ///< by soil::sampleSkipName
  double simulated_s = 0, wall_s = 0;
};

/// The simulator scenario of one episode: the config's base scenario with the plan's seed,
/// soil, hills, blade rake and controller (random-walk set-points, or a graded route pass when
/// plan.route). \throws as sim::loadScenario.
TERRAMAP_API sim::Scenario episodeScenario(const SoilDatasetConfig& cfg, const EpisodePlan& plan);
/// Runs episode `plan` through the simulator and the mapping pipeline.
/// `threads` > 0 overrides the simulator's ray-casting threads and the pipeline's threads
/// (results do not depend on either). `on_progress(t, duration)` is called after each
/// observation period. \throws ConfigError / InputError from the scenario or the pipeline,
/// PluginError.
TERRAMAP_API EpisodeData runDatasetEpisode(const SoilDatasetConfig& cfg, const EpisodePlan& plan, int threads = 0,
                                           const std::function<void(double, double)>& on_progress = {});

/// Episode file name in DIR/episodes: ep_NNNNN.h5 (in-distribution) or held_NNNNN.h5.
TERRAMAP_API std::string episodeFileName(const EpisodePlan& plan);
/// Writes one episode file atomically (HDF5: obs [N,T,35] f32, theta_k [N,P,6], force [N,P,2],
/// truth [N,5], truth_geometry [N,5], force_quiet [N,P,2], truth_geometry_rows [N,P,5],
/// force_parts [N,P,3,2], edge_vz [N,P], anchor [N] f64 stamps; attributes:
/// plan, T, P, feature names, config hash).
/// \throws OutputError.
TERRAMAP_API void writeEpisodeFile(const std::string& path, const SoilDatasetConfig& cfg, const EpisodeData& ep);

/// A dataset in memory (what the trainer reads), samples of all episodes in episode order.
struct SoilDataset {
  int T = 0, P = 0;
  std::string config_hash;
  std::vector<float> obs, theta_k, force, truth;  ///< N*T*34, N*P*6, N*P*2, N*5
  std::vector<float> truth_geometry;               ///< N*5 (EpisodeData::truth_geometry; NaN in v1 files)
  std::vector<float> force_quiet;                  ///< N*P*2 (EpisodeData::force_quiet; NaN in files without it)
  /// N*P*5, N*P*3*2, N*P (EpisodeData's per-row truth; NaN in files without them).
  std::vector<float> truth_geometry_rows, force_parts, edge_vz_rows;
  /// N*P*2 the mapped cut's cross-section [Σ d ds (m²), Σ d² ds (m³)] per row (PinnSample::profile),
  /// N*P*8 the simulator's (EpisodeData::truth_profile_rows); NaN in files without them.
  std::vector<float> profile, truth_profile_rows;
  std::vector<int> episode;                        ///< N
  std::vector<std::uint8_t> split;                 ///< N (DatasetSplit)
  std::vector<std::uint8_t> family;                ///< N (soil::SoilFamily)
  std::vector<float> relative_density, rake_rad;   ///< N
  std::size_t size() const { return episode.size(); }
};
/// Reads every episode file of DIR/episodes (in index order). \throws InputError naming the file
/// and dataset on a malformed or inconsistent file (T, P or config hash differing), OutputError never.
TERRAMAP_API SoilDataset readSoilDataset(const std::string& dir);

/// Summary of DIR's episode files as JSON (what `manifest.json` holds): config hash, episodes
/// and samples per split, per family, sweeps and skip reasons, simulated seconds.
/// \throws InputError on a malformed file.
TERRAMAP_API std::string datasetManifestJson(const std::string& dir);

}  // namespace terramap::eval
