#pragma once
/// \file
/// fee_index: "the force needed to cut here" (ALGORITHMS.md §I; paper §3.2, Fig. 12). For every
/// cell whose soil layers (soil_bayes) hold a belief, the fundamental equation of earthmoving is
/// evaluated for a reference cut, the same everywhere so the map compares soils, not terrain:
/// α = `alpha_rad` (0), ρ = `rho_rad` (80°), w = `w_m` (1.85 m), d = `d_m` (0.2 m), Q = 0, the
/// cell's posterior soil means, and the failure angle β* that minimises N_γ (`beta: min`, what the
/// committed soil model uses) or Rankine's π/4 − φ/2 (`beta: nominal`, the paper's).
///
/// Index (N): `component: magnitude` (default) is the paper's f of Eq. 1 (|F|, the blade's normal
/// plus friction reaction); `horizontal` is F_x, the push along travel. Variance (N²):
/// J Σ Jᵀ with Σ = diag of the soil layers' variances and J the gradient of the index in
/// [c, φ, γ, c_a, δ] from fee::jacobianF with β's dependence on φ and δ chained in
/// (fee::betaMinGradient, or −½ for the nominal angle).
///
/// Layers (created): `fee_index` (N; NaN where a soil layer is NaN or the FEE is invalid for that
/// soil), `fee_index_var` (N²). Read: soil_c, soil_phi, soil_gamma, soil_ca, soil_delta and their
/// `_var`. `soil_prefix` reads another set of soil layers with the same suffixes (e.g.
/// `strata_next_`: octomap_strata's soil expected in the next cut) and `output` names the two
/// created layers (`output`, `output` + "_var"), so two instances can index two soils.
///
/// Incremental and parallel: only tiles whose soil layers were written since the stage last ran
/// are recomputed (ProcessContext::changedTiles), one task per tile; each cell depends on that
/// cell only, so the layers are bit-identical at any thread count and equal to a full recompute.
#include <terramap/plugin/plugin.hpp>
#include <terramap/soil/fee_index.hpp>
#include <terramap/soil/soil_parameters.hpp>

#include <array>

namespace terramap::plugins {

// The index itself is terramap::soil's (soil/fee_index.hpp), shared with eval-soil-map.
using soil::FeeIndexConfig;
using soil::FeeIndexValue;
using soil::feeIndexOf;

class FeeIndex : public Plugin {
 public:
  ParamSchema schema() const override;
  void configure(const Params& params) override;
  std::vector<LayerSpec> layers() const override;
  EventMask events() const override;
  void start(ProcessContext& ctx) override;
  void process(ProcessContext& ctx, const Event& event) override;
  void finish(ProcessContext& ctx) override;

  const FeeIndexConfig& config() const { return cfg_; }
  /// Recomputes the given buffer-space tiles (what process() does with the changed ones).
  /// Returns the number of cells with a valid index.
  long computeTiles(ProcessContext& ctx, const std::vector<int>& tiles);

 private:
  FeeIndexConfig cfg_;
  std::string prefix_ = "soil_", output_ = "fee_index";
  // Means and variances, soil::SoilParam order.
  std::array<LayerId, soil::kSoilParamCount> mean_{}, var_{};
  LayerId index_ = -1, index_var_ = -1;
};

}  // namespace terramap::plugins
