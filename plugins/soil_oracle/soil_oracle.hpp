#pragma once
/// \file
/// soil_oracle: the perfect soil estimator, for evaluation only. It takes soil_pinn's place in a
/// pipeline and publishes, for every sweep of `blade_sweep`, the soil the simulator's truth says
/// the blade was cutting, optionally with noise of a chosen spread. What it is for: measuring
/// what the stages after the estimator (soil_bayes, octomap_strata, fee_index) can reach with a
/// perfect estimate, and how that degrades as the estimate gets noisier, so a shortfall can be
/// put on the estimator or on the mapping. `terramap eval-strata --oracle` writes the table from
/// its truth run and swaps this stage in. A real vehicle has no such table: nothing but an
/// evaluation should load this plugin.
///
/// Table (`table`, JSON): {"t_s": [t0, t1, ...], "soil": [[c, φ, c_a, δ, γ] or null, ...]}, one row
/// per instant in non-decreasing t (s, the source's clock), soil in SI units in
/// SoilEstimateRecord::Soil order (Pa, rad, Pa, rad, N/m³); null (or a NaN) = the blade was not
/// cutting then. eval-strata writes the simulator's FeeTruth soil at every observation period:
/// the label soil_pinn is trained to estimate.
///
/// Per SweepRecord [t0, t1]: the mean of the finite rows with t0 <= t <= t1 (the row at the first
/// t >= t1 when none lies inside); none finite → an invalid record ("truth_not_cutting"), as
/// soil_pinn publishes one when its estimate fails. Noise: each property k gets an independent
/// N(0, noise_sd[k]²) draw from a generator seeded by (`seed`, sweep_index), so the same sweep
/// gets the same draw whatever else the run does; the result is clamped to the property's
/// physical range (soil_parameters.hpp), as soil_pinn's output is squashed into it.
/// Reported variance: max(noise_sd[k], min_sd_fraction × range span)², so the stages that fuse
/// the estimate weigh it as honestly as the noise allows. The failure angle is Rankine's
/// π/4 − φ/2 of the published φ, the residuals 0; geometry is copied from the SweepRecord.
///
/// Order and timing: `blade_sweep` must be an earlier stage; the record is published in the event
/// that carries the sweep, stamp t1 (soil_pinn waits for the observation at t1; stages that
/// match estimates by sweep_index, as octomap_strata does, see no difference).
/// Threading: all work on the calling (engine) thread; results do not depend on the thread count.
#include <terramap/plugin/plugin.hpp>
#include <terramap/plugin/records/soil_estimate_record.hpp>
#include <terramap/plugin/records/sweep_record.hpp>

#include <array>
#include <string>
#include <vector>

namespace terramap::plugins {

/// The truth table: rows sorted by t; soil rows NaN where the blade was not cutting.
struct SoilTruthTable {
  std::vector<double> t_s;
  std::vector<SoilEstimateRecord::SoilVector> soil;
};

/// Reads a table file. \throws InputError naming the file and the row or key at fault.
SoilTruthTable loadSoilTruthTable(const std::string& path);

/// The truth soil of a sweep over [t0, t1] (see the file comment); NaNs when the blade was not cutting.
SoilEstimateRecord::SoilVector truthOfSweep(const SoilTruthTable& table, double t0, double t1);

class SoilOracle : public Plugin {
 public:
  ParamSchema schema() const override;
  /// Loads the table. \throws ConfigError naming `table` (and the file's problem) or `noise_sd`.
  void configure(const Params& params) override;
  std::vector<LayerSpec> layers() const override { return {}; }
  EventMask events() const override { return mask(EventKind::BladePose); }
  void start(ProcessContext& ctx) override;
  void process(ProcessContext& ctx, const Event& event) override;
  void finish(ProcessContext& ctx) override;

  /// The record for one sweep (pure: the plugin and the tests share it).
  SoilEstimateRecord estimate(const SweepRecord& sweep) const;

 private:
  void collect(ProcessContext& ctx);

  SoilTruthTable table_;
  SoilEstimateRecord::SoilVector noise_sd_{};
  double min_sd_fraction_ = 0.01;
  long seed_ = 1;
  long last_sequence_ = 0;
};

}  // namespace terramap::plugins
