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
///    removed soil, pooled over the columns within `change_radius_m` (Strata::changeHeightAt;
///    NaN = no change found), and `strata_change_z_m`, its
///    height in the map frame (what to compare with a boundary known in absolute terms);
///  - `strata_pristine_m`: the bank surface (elevation − loose) the map held at a cell before any
///    sweep touched it (m, map z; NaN = never known; −inf = a sweep touched it before the map
///    knew it). A column's first surface is the first sweep's fitted bank surface, unless that
///    lies more than `pristine_margin_m` above this one or there is no fit: then this one (the
///    fit counts spoil pushed over the ground before the first cut as bank). On a sparse map past
///    its memory budget a pristine tile that cannot be stored is dropped, counted as
///    `pristine_tile_budget` (those cells stay NaN).
/// Read: `elevation` (and `loose`, `soil_*` when present).
///
/// Files, written at the end of the run when their parameter is set (atomically): `save_path`
/// (the whole model, Strata::load reads it), `octovis_path` (a ColorOcTree for octovis coloured
/// by `octovis_param`), `section_png` (a cross-section along `section_line_m` with a colour bar).
///
/// Incremental: strata_next_* and strata_cut_m are recomputed for the cells a sweep cut (when
/// the sweep arrives and again when its estimate does) and, from soil_*, for never-cut cells of
/// tiles soil_bayes wrote; strata_change_* (the costlier split) for the cells around changed
/// columns at most every `change_interval_s` of event time and at the end of the run.
///
/// Threading: the tree is updated on the calling thread in record order; the layers are
/// recomputed one task per tile from const queries, so they are bit-identical at any thread
/// count.
#include "strata.hpp"

#include <terramap/plugin/plugin.hpp>
#include <terramap/plugin/records/soil_estimate_record.hpp>
#include <terramap/plugin/records/sweep_record.hpp>

#include <limits>
#include <map>
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
  int change_min_voxels = 2;
  double change_min_gain = 0.3;
  double change_radius_m = 0.075;
  strata::PropertyMask change_properties{true, true, true, true, true};
  double change_interval_s = 5.0;
  /// A first cut whose fitted bank surface lies more than this above the surface the map held
  /// before any sweep touched the cell (strata_pristine_m) starts from the latter; < 0 = never.
  double pristine_margin_m = 0.05;
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

 private:
  /// Which layers a computation writes: strata_next_* and strata_cut_m of the given cells
  /// (Next), the same for never-cut cells of whole tiles from soil_* (Fallback), or
  /// strata_change_* of the given cells grown by change_radius_m (Change).
  enum class Pass { Next, Fallback, Change };
  void collect(ProcessContext& ctx, std::vector<Eigen::Vector2d>& cells, std::vector<int>& fallback_tiles);
  /// strata_pristine_m: the bank surface (elevation − loose) of cells in tiles where the elevation
  /// changed, for cells the map did not know before and no sweep has touched (those hold −inf).
  void recordPristine(ProcessContext& ctx);
  /// Cells a sweep touched stop taking the map's surface as pristine; a first cut whose fit lies
  /// above the pristine surface by more than the margin (or has no fit) starts from it.
  void applyPristine(ProcessContext& ctx, const SweepRecord& sweep, std::vector<strata::CellCut>& cut);
  void update(ProcessContext& ctx, bool final);
  void computeCells(ProcessContext& ctx, const std::vector<Eigen::Vector2d>& positions, const std::vector<int>& whole_tiles,
                    Pass pass);
  void writeFiles(ProcessContext& ctx) const;  // reads the map: needs the host's exclusive access

  OctomapStrataConfig cfg_;
  std::optional<strata::Strata> strata_;
  std::array<LayerId, soil::kSoilParamCount> next_{}, next_var_{}, surf_{}, surf_var_{};
  LayerId cut_ = -1, change_ = -1, change_z_ = -1, elevation_ = -1, loose_ = -1, pristine_ = -1;
  bool have_surface_ = false;
  long last_estimate_ = 0, last_sweep_ = 0;
  std::vector<Eigen::Vector2d> change_dirty_;  ///< cells whose removed soil changed since strata_change_* last ran
  double last_change_s_ = -std::numeric_limits<double>::infinity();
};

}  // namespace terramap::plugins
