#pragma once
/// \file
/// Blind-mapping evaluation against the simulator's ground truth (paper §3, Fig. 10), the
/// library behind `terramap eval`.
///
/// The experiment: the map starts from the simulator's initial truth (heights sampled at the
/// cell centres), LiDAR is off, and only the blade's poses update it (blade_sweep +
/// soil_erosion). At the end the blind heightmap is compared with the truth:
///  - height error per region (definitions at EvalRegion), against the "no update" baseline
///    (the initial map, i.e. what a map that ignored the blade would show);
///  - mass balance of the blind map (Σ[(H − L) + L/s]) and of the truth (Σ(U + Lc)), cut bank
///    volume of both;
///  - FEE geometry extracted per sweep (α, ρ, d, w, Q of every SweepRecord) against the
///    simulator's truth at the same instant (MachineTruth::fee), as bias and spread.
///
/// Layering: terramap::eval sits above the pipeline and the simulator (it drives an Engine with
/// a Simulator's events); nothing but the CLI and tests depends on it. The simulator itself
/// only produces truth (sim/truth_sampling.hpp). Units: metres, radians, newtons, cubic metres;
/// map frame (z up).
/// Threading: everything here runs on the caller's thread (the mapper uses its own executor).
#include <terramap/core/events.hpp>
#include <terramap/core/geometry.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/eval/statistics.hpp>
#include <terramap/pipeline/engine.hpp>
#include <terramap/plugin/records/sweep_record.hpp>
#include <terramap/sim/simulator.hpp>
#include <terramap/sim/truth_sampling.hpp>
#include <terramap/sim/truth_terrain.hpp>

#include <Eigen/Core>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace terramap::eval {

struct EvalOptions {
  /// A cell outside the cut whose truth surface moved by more than this counts as
  /// EvalRegion::Deposit (spoil, spill, slides) rather than Untouched.
  double change_threshold_m = 0.01;
  /// A cell is EvalRegion::Cut when the truth's bank surface U at its centre dropped by more
  /// than this during the run (only a blade lowers U; sliding loose soil moves on top of it).
  double cut_threshold_m = 0.001;
  /// Colour range of the error PNGs: ±this, fixed and symmetric (white = 0, red = map too low,
  /// blue = map too high), so two runs' PNGs compare by eye.
  double error_range_m = 0.10;
  /// Blind mapping: PointCloud events are not pushed (counted as withheld). false = pass them.
  bool withhold_clouds = true;
  std::string elevation_layer = "elevation";
  /// Loose-soil layer for the mass balance; a map without it counts L = 0.
  std::string loose_layer = "loose";
  /// Swell s for Σ[(H − L) + L/s] when no SweepRecord says which one the mapper used.
  double default_swell = 1.2;
  /// Called after each simulator period with (simulated time, duration), on the caller's thread.
  std::function<void(double t_s, double duration_s)> on_progress;
};

/// Regions the height error is reported over, defined by the truth alone (the simulator's own
/// carved and deposited soil), so a mapper whose footprint is wrong cannot move its error into
/// another region. Every known cell is in exactly one of Cut, Deposit, Untouched;
/// Outside = Deposit ∪ Untouched. CutByMapper is reported beside them, not used to define them.
enum class EvalRegion {
  All,        ///< every cell where the map, its initial state and the truth are known
  Cut,        ///< "inside the cut": the truth's bank surface U was lowered by more than
              ///< cut_threshold_m (a blade went through the original ground there)
  Deposit,    ///< not Cut, but the truth surface moved by more than change_threshold_m: spoil
              ///< ahead of and beside the cut, spill, slides (where the paper's Fig. 10 shows
              ///< the blind map's errors: the two soil-flow models differ)
  Untouched,  ///< neither: ground the truth did not change
  Outside,    ///< "outside the cut": Deposit ∪ Untouched
  CutByMapper,  ///< the mapper's own idea of the cut: under a swept volume whose bottom h^G was
                ///< below the initial surface (SweepRecord masks); overlaps the others
};
constexpr int kEvalRegionCount = 6;
const char* evalRegionName(EvalRegion r);

/// How the mapper's cut footprint (CutByMapper) agrees with the truth's (Cut), in cells.
struct FootprintAgreement {
  long both = 0, truth_only = 0, mapper_only = 0;
  double iou = NAN;  ///< both / (both + truth_only + mapper_only); NaN when neither has a cell
};

/// Height error statistics over one region; error e = map − truth (m, > 0 = map too high).
struct RegionStats {
  long cells = 0;
  double rmse_m = 0, bias_m = 0, p95_abs_m = 0, max_abs_m = 0;  ///< of the blind map
  double baseline_rmse_m = 0, baseline_bias_m = 0;              ///< of the initial map ("no update")
};

/// Soil volumes, m^3 of bank (undisturbed) soil unless named loose.
struct MassBalance {
  double swell = 1.2;  ///< s the blind map's loose soil is de-swelled with
  /// Blind map: Σ res² [(H − L) + L/s] over known cells (+ L/s where H is NaN), before/after.
  double blind_initial_m3 = 0, blind_final_m3 = 0, blind_change_m3 = 0;
  double blind_lost_loose_m3 = 0;  ///< deposits off the map (SweepRecord::lost_volume_m3, loose)
  /// blind_change + lost/s: zero up to float rounding for a mass-conserving mapper.
  double blind_residual_m3 = 0;
  /// Truth over its whole grid: Σ res_t² (U + Lc) change, bank volume that left the grid, bank
  /// volume the tracks pressed denser (TruthTerrain::compactedVolume), and their sum (zero up to
  /// rounding: the simulator conserves mass).
  double truth_change_m3 = 0, truth_lost_m3 = 0, truth_compacted_m3 = 0, truth_residual_m3 = 0;
  /// Truth bank column U + Lc sampled at the map's cell centres, change × res²: soil that the
  /// truth moved into (> 0) or out of the map's area. The blind map's change should match it.
  double truth_change_on_map_m3 = 0;
  double cut_bank_blind_m3 = 0;  ///< Σ SweepRecord::cut_bank_volume_m3
  double cut_bank_truth_m3 = 0;  ///< Σ over machines MachineTruth::cut_bank_m3
  /// Surface volume removed / added on the map (Σ res² max(0, ∓(H1 − H0))), blind and truth.
  double removed_blind_m3 = 0, removed_truth_m3 = 0, added_blind_m3 = 0, added_truth_m3 = 0;
};

/// The truth FEE geometry of a blade pose, recomputed by the evaluation from the truth
/// terrain (why: see the second paragraph). Per slice across the blade (the simulator's
/// own slicing: `slices` slices of width W/slices along the edge), the undisturbed surface U is
/// sampled along the horizontal blade normal at 0.05, 0.125, ..., 0.5 m ahead of the edge and a
/// least-squares line is fitted (the simulator's own slope fit); the surface height *at the
/// edge* is that line's intercept, depth_v = intercept − edge z, and the slice cuts when
/// depth_v > 0.1 mm: α = atan(slope), d = depth_v cos α. α and d are depth-weighted means over
/// cutting slices, w_along the summed width of the cutting slices along the edge,
/// face angle = atan2(ẑ_b.z, −ẑ_b · n̂) (the blade face from the horizontal, through the soil).
///
/// The simulator's own FeeTruth now uses the same construction (it used to read the surface at
/// the already carved edge and saw 0-100 % of the depth); this stays the evaluation's
/// reference because it is computed from the truth terrain alone, at exactly the record's T1.
struct SurfaceAheadTruth {
  int cutting_slices = 0;
  double alpha_rad = NAN, d_m = NAN, w_along_m = 0, face_angle_rad = NAN;
};
/// Evaluates it at `T_map_blade` (blade frame of core/events.hpp). No horizontal push direction
/// (face normal and face direction both vertical) or `slices` < 1 gives no cutting slices and a
/// NaN face angle. Pure and thread-safe (reads the terrain only).
SurfaceAheadTruth surfaceAheadTruth(const sim::TruthTerrain& truth, const Eigen::Isometry3d& T_map_blade,
                                    const BladeGeometry& blade, int slices);

/// One sweep's extracted FEE geometry next to the simulator's truth at the sweep's end (T1,
/// the pose the simulator reports after the period that produced the record's last BladePose).
/// The mapper's values: the sweep's α (SweepRecord::alpha_rad) and the per-step ρ, d, w, Q at T1
/// (SweepRecord::steps.back()). The truth, in soil/fee.hpp's conventions (the estimator's):
///  - α, d: SurfaceAheadTruth at T1; `truth_d_raw_m` keeps the simulator's FeeTruth::depth_m.
///  - ρ: measured from the surface line, ρ = α + face angle (fee.hpp), as FeeTruth::rho_rad
///    (kept as `truth_rho_raw_rad`).
///  - w: the contact width across the travel direction (blade_sweep's w ∝ cos yaw): the
///    cutting slices' width along the edge projected on the record's t_perp,
///    w_along · |ŷ_blade · t_perp|; FeeTruth::width_m (along the edge) kept as `truth_w_raw_m`.
///  - Q: FeeTruth::q_n as it is (γ_bank · bank-equivalent loose volume within 1 m ahead of the
///    cutting slices; blade_sweep's is γ_l · loose volume ahead of the whole edge with a fixed
///    γ_l, so its bias includes the unit-weight assumption); NaN when the simulator's own slices
///    did not cut.
struct ExtractionSample {
  long sweep = 0;
  std::string machine;
  double stamp = 0;
  bool mapped_valid = false;  ///< SweepRecord::fee_valid with finite per-step values
  bool truth_valid = false;   ///< the blade was cutting at T1 (SurfaceAheadTruth::cutting_slices > 0)
  double alpha_rad = NAN, rho_rad = NAN, d_m = NAN, w_m = NAN, q_n = NAN;  ///< mapped
  double truth_alpha_rad = NAN, truth_rho_rad = NAN, truth_d_m = NAN, truth_w_m = NAN, truth_q_n = NAN;
  double truth_d_raw_m = NAN, truth_rho_raw_rad = NAN, truth_w_raw_m = NAN;  ///< MachineTruth::fee as is
};

/// Error statistics of one extracted parameter over the samples valid on both sides.
/// Percentiles are linearly interpolated (numpy's default).
struct ParameterStats {
  std::string name, unit;  ///< unit of every figure below (degrees for angles)
  long n = 0;
  double truth_mean = NAN, mapped_mean = NAN;
  double bias = NAN, std = NAN, rmse = NAN, p5 = NAN, p50 = NAN, p95 = NAN;  ///< of mapped − truth
};

struct ExtractionSummary {
  long sweeps = 0, both_valid = 0, mapped_only = 0, truth_only = 0, neither = 0;
  /// α, ρ, d, w, Q (convention-aligned truth), then d, ρ and w against the simulator's raw
  /// FeeTruth values (names "d_vs_sim_raw", "rho_vs_sim_raw", "w_vs_sim_raw").
  std::vector<ParameterStats> parameters;
};

/// Statistics over `samples` (see ExtractionSample for the conventions).
ExtractionSummary summarizeExtraction(const std::vector<ExtractionSample>& samples);
/// The summary as a Markdown table (one row per parameter) with a line of counts above it.
std::string extractionTableMarkdown(const ExtractionSummary& summary);

/// Everything one evaluation produced. Matrices are in the map geometry's logical order.
struct EvalRun {
  std::string scenario;
  Geometry geometry;
  Eigen::MatrixXf initial;  ///< the map's elevation before the first event (= truth at t = 0)
  Eigen::MatrixXf blind;    ///< the map's elevation at the end
  Eigen::MatrixXf truth;    ///< truth surface H at the end, at the cell centres
  Eigen::MatrixXi region;   ///< per cell: EvalRegion Cut/Deposit/Untouched as int, -1 = unknown
  Eigen::MatrixXi mapper_cut;  ///< per cell: 1 = in the mapper's cut footprint (CutByMapper)
  FootprintAgreement footprint;
  RegionStats regions[kEvalRegionCount];  ///< indexed by EvalRegion
  MassBalance mass;
  std::vector<ExtractionSample> samples;
  ExtractionSummary extraction;
  long events_pushed = 0, clouds_withheld = 0, sweeps = 0;
  double simulated_s = 0, wall_s = 0;
  EvalOptions options;

  const RegionStats& stats(EvalRegion r) const { return regions[static_cast<int>(r)]; }
};

/// Initialises the engine map's elevation from the truth (TruthSurface::Current at the cell
/// centres; NaN outside the truth grid) and its loose layer, if any, to 0, then plays the
/// simulator through the engine to the end, finishes the engine (Engine::finish(): blade_sweep
/// cuts the motion left since its last sweep) and evaluates; sweeps are read from the engine's
/// RecordBus (SweepRecord::kType). `sim` must not have been stepped yet.
/// \throws LayerError if the map has no elevation layer; ConfigError if a plugin moved the
///   map (the evaluation compares fixed cells) or a record names an unknown machine;
///   std::invalid_argument if `sim` has already been stepped; whatever push() throws.
EvalRun runBlindEvaluation(sim::Simulator& sim, Engine& engine, const EvalOptions& options = {});

/// Writes into `dir` (created if needed), each file atomically:
///   blind_heightmap.png  blind elevation, hillshaded, viridis over the 0.1-99.9 percentiles
///                        of the blind and truth heights together
///   truth_heightmap.png  truth at the end, same colours
///   error.png            blind − truth, "rdbu", ±error_range_m
///   baseline_error.png   initial − truth (the "no update" map), same colours
///   regions.png          Cut / Deposit / Untouched (grey for unknown)
///   eval.tif             GeoTIFF, bands blind, truth, initial, error, baseline_error, region
///   eval.json            every figure of the run (regions, mass, extraction summary)
///   extraction.csv       one row per sweep (ExtractionSample)
/// Returns the paths written. \throws OutputError.
std::vector<std::string> writeEvalOutputs(const EvalRun& run, const std::filesystem::path& dir);

/// The run as JSON text (what eval.json holds).
std::string evalJson(const EvalRun& run);

/// The default evaluation pipeline (blade_sweep + soil_erosion on a map that declares
/// `elevation`), the same text as configs/eval_blind.yaml (a test keeps them equal).
std::string defaultEvalPipeline();

}  // namespace terramap::eval
