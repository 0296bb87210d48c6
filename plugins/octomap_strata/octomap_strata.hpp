#pragma once
/// \file
/// octomap_strata: subsurface soil memory (ALGORITHMS.md §K) as a pipeline stage. Every sweep of
/// `blade_sweep` (SweepRecord) removes, in each cut column, the voxels between the surface the
/// blade left and the column's bank surface; every estimate of `soil_pinn` (SoilEstimateRecord)
/// is assigned to the voxels its sweep removed, and the columns inherit it below (strata.hpp has
/// the model, its units and what NaN means).
///
/// Layers (created; NaN = nothing known):
///  - `strata_next_c`, `strata_next_phi`, `strata_next_ca`, `strata_next_delta`,
///    `strata_next_gamma` and each `_var`: the soil a cut of `next_cut_m` below the bank surface
///    would remove (Strata::expectedCut). A cell whose column no sweep cut takes the surface
///    layers of soil_bayes (`soil_*`) when `surface_fallback` is on and the map has them, else
///    NaN. `fee_index` with `soil_prefix: strata_next_` turns them into a force index;
///  - `strata_cut_m`: bank soil removed since the column's first cut (m);
///  - `strata_change_depth_m`: depth below the first-cut surface of the strongest change in the
///    removed soil (Strata::changeDepthAt; NaN = no change found).
/// Read: `elevation` (and `loose`, `soil_*` when present).
///
/// Files, written at the end of the run when their parameter is set (atomically): `save_path`
/// (the whole model, Strata::load reads it), `octovis_path` (a ColorOcTree for octovis coloured
/// by `octovis_param`), `section_png` (a cross-section along `section_line_m` with a colour bar).
///
/// Threading: the tree is updated on the calling thread in record order; the layers are
/// recomputed one task per tile from const queries, so they are bit-identical at any thread
/// count.
#include "strata.hpp"

#include <terramap/plugin/plugin.hpp>
#include <terramap/plugin/records/soil_estimate_record.hpp>
#include <terramap/plugin/records/sweep_record.hpp>

#include <memory>
#include <optional>

namespace terramap::plugins {

/// The cut cells of a sweep as the strata take them: new surface = swept-volume bottom, old
/// surface = the slice's fitted bank surface.
std::vector<strata::CellCut> cellCutsOf(const SweepRecord& sweep);

struct OctomapStrataConfig {
  strata::StrataConfig strata;
  double next_cut_m = 0.2;
  bool surface_fallback = true;
  int change_min_voxels = 1;
  double change_min_gain = 0.5;
  std::string save_path, octovis_path, section_png;
  int octovis_param = 0, section_param = 0;
  double octovis_below_m = 0.5;
  std::vector<double> section_line;  ///< x0, y0, x1, y1 (m)
};

class OctomapStrata : public Plugin {
 public:
  ParamSchema schema() const override;
  void configure(const Params& params) override;
  std::vector<LayerSpec> layers() const override;
  EventMask events() const override;
  void start(ProcessContext& ctx) override;
  void process(ProcessContext& ctx, const Event& event) override;
  void finish(ProcessContext& ctx) override;

  const OctomapStrataConfig& config() const { return cfg_; }
  /// The model (after start()).
  const strata::Strata& model() const { return *strata_; }
  /// Recomputes the layers on these tiles (what process() does for the tiles it touched).
  void computeTiles(ProcessContext& ctx, const std::vector<int>& tiles);

 private:
  void collect(ProcessContext& ctx, std::vector<int>& tiles);
  void writeFiles(ProcessContext& ctx) const;

  OctomapStrataConfig cfg_;
  std::optional<strata::Strata> strata_;
  std::array<LayerId, soil::kSoilParamCount> next_{}, next_var_{}, surf_{}, surf_var_{};
  LayerId cut_ = -1, change_ = -1, elevation_ = -1, loose_ = -1;
  bool have_surface_ = false;
  long last_estimate_ = 0, last_sweep_ = 0;
};

}  // namespace terramap::plugins
