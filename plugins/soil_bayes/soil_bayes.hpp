#pragma once
/// \file
/// soil_bayes: the soil-property map layers (ALGORITHMS.md §G, §L; paper Alg. 4). Every valid
/// per-sweep estimate of `soil_pinn` (SoilEstimateRecord) is fused into the cells of the wedge of
/// soil ahead of the blade, per cell and per property, as a product of Gaussians.
///
/// Wedge: the cells whose centre p, relative to the blade edge centre c at the sweep's end
/// (T_map_blade1), lies at x = (p − c)·t̂ in [0, x_lim) along the sweep direction t̂ and within
/// |(p − c)·t̂⊥| ≤ w/2 across it, with x_lim = max(x_max, x_min) and the failure wedge's length
///   x_max = (d + d_res) / (cos α · (tan(α + β) − tan α))
/// (d, α, β, d_res from the record; x_max is NaN when the wedge is not defined, and then x_min
/// alone bounds it). The estimate's variance σ² (`var_total`) is inflated with the distance:
/// σ²₊ = σ² · exp(C_s · x / x_max) (ω = 1 − x/x_max, e^{C_s(1−ω)} in the authors' code; x / x_min
/// when x_max is undefined). Update of a cell with prior N(μ⁻, σ²⁻):
///   μ = (σ²₊ μ⁻ + σ²⁻ μ̂) / (σ²⁻ + σ²₊),   σ² = σ²⁻ σ²₊ / (σ²⁻ + σ²₊);
/// a cell with no prior (NaN) takes the configured prior first, or with `prior: none` the
/// estimate itself (μ̂, σ²₊). Each cell of the wedge is fused exactly once per estimate (the
/// window is walked cell by cell; the authors' update fused a cell once per point that fell in
/// it and raced on it).
///
/// What a cut does (the layers describe the soil at the surface now): each fused cell remembers
/// the undisturbed surface it was fused at (`soil_z` = elevation − loose, the bank surface under
/// any loose soil the blade pushed there; `loose` counts 0 where the map has none). After every
/// sweep, a cell of the sweep's cut set whose bank surface is now more than `cut_depth_m` below
/// `soil_z` has had soil removed that the
/// estimates described and exposes soil none of them saw: its variances are multiplied by
/// exp((soil_z − elevation) / cut_depth_m) and `soil_z` becomes the new surface (the means are
/// kept: the best guess for the soil below is the soil above, with less confidence). A fill
/// (surface rising) changes nothing: the deposited soil is the soil cut nearby.
///
/// Layers (created; NaN = no estimate reached the cell yet): `soil_c` (Pa), `soil_phi` (rad),
/// `soil_ca` (Pa), `soil_delta` (rad), `soil_gamma` (N/m³) and each one's `*_var` (unit²);
/// `soil_n` (estimates fused into the cell, 0 = none); `soil_z` (m, the surface the cell's soil
/// was last fused or re-anchored at). Read: `elevation`, and `loose` when the map has it.
///
/// Parallel: the wedge's rows are updated in parallel (each cell's update reads and writes only
/// that cell), so the layers are bit-identical at any thread count.
#include <terramap/plugin/plugin.hpp>
#include <terramap/plugin/records/soil_estimate_record.hpp>
#include <terramap/plugin/records/sweep_record.hpp>
#include <terramap/soil/belief.hpp>

#include <array>
#include <string>

namespace terramap::plugins {

// The belief and its update are terramap::soil's (soil/belief.hpp), shared with octomap_strata.
using soil::Belief;
using soil::fuseBelief;

/// The wedge length x_max of the header (m); NaN when d + d_res ≤ 0, cos α ≤ 0 or
/// tan(α + β) ≤ tan α, or any input is not finite.
double wedgeLength(double d_m, double d_res_m, double alpha_rad, double beta_rad);

struct SoilBayesConfig {
  double c_s = 1.0;             ///< C_s: variance inflation with distance into the wedge
  double x_min_m = 0.1;         ///< the wedge reaches at least this far ahead of the blade
  /// The footprint also reaches this far behind the edge (m, >= 0; 0 = the wedge only): the
  /// horizon's force came from the wedges at every edge position of the horizon, so the soil the
  /// edge passed through in it is the estimate's too. Cells behind the edge take the variance of
  /// the wedge's first cell.
  double behind_m = 0.0;
  /// false (`prior: none`, the default): a cell's first estimate is taken as is; true (`prior:
  /// config`): it is fused with prior_mean / prior_var (README, "Why no prior by default").
  bool use_prior = false;
  SoilEstimateRecord::SoilVector prior_mean{};  ///< [c, φ, c_a, δ, γ] in SI units
  SoilEstimateRecord::SoilVector prior_var{};   ///< their variances
  double cut_depth_m = 0.2;     ///< a cut deeper than this below the fused surface inflates
};

class SoilBayes : public Plugin {
 public:
  ParamSchema schema() const override;
  void configure(const Params& params) override;
  std::vector<LayerSpec> layers() const override;
  EventMask events() const override;
  void start(ProcessContext& ctx) override;
  void process(ProcessContext& ctx, const Event& event) override;
  void finish(ProcessContext& ctx) override;

  const SoilBayesConfig& config() const { return cfg_; }
  /// Fuses one estimate into its wedge (what process() does for each new valid record).
  /// Returns the number of cells updated.
  long fuse(ProcessContext& ctx, const SoilEstimateRecord& est);
  /// Applies one sweep's cuts to the layers (the header's "What a cut does"). Returns the
  /// number of cells whose variance was inflated.
  long applyCut(ProcessContext& ctx, const SweepRecord& sweep);

 private:
  void collect(ProcessContext& ctx);

  SoilBayesConfig cfg_;
  std::array<LayerId, SoilEstimateRecord::kCount> mean_{}, var_{};
  LayerId n_ = -1, z_ = -1, elevation_ = -1, loose_ = -1;
  long last_estimate_ = 0, last_sweep_ = 0;
};

}  // namespace terramap::plugins
