#pragma once
/// \file
/// traversability: the layers a planner reads, from an elevation layer (the role of the
/// grid_map / traversability_estimation filter chain: normals, slope, roughness, step,
/// weighted sum). README.md states every formula; in short, per known cell:
///
/// - `slope` (rad, in [0, π/2)): atan of the gradient of the least-squares plane
///   z = a + b·x + c·y through the known cells of the square window of half-width
///   k = ⌊plane_radius_m / resolution⌋ (≥ 1) cells around the cell;
/// - `roughness` (m): root mean square of those cells' distances to that plane, measured along
///   the plane's normal (= RMS vertical residual · cos(slope)), divided by n, not n − 3;
/// - `step_height` (m): max − min of the known heights in the square window of half-width
///   ⌊step_radius_m / resolution⌋ (≥ 1);
/// - `traversability` (1, in [0, 1]): Σ w_i·max(0, 1 − x_i / critical_i) / Σ w_i over slope,
///   roughness and step height (0 where any x_i ≥ critical_i with `any_critical_blocks`).
///
/// NaN (unknown): every output where the elevation cell is NaN; slope, roughness and
/// traversability where the plane window holds fewer than `min_points` known cells or its
/// known cells are collinear. Cells beyond the map's edge count as unknown.
/// Units: elevation in metres, the map's resolution in metres per cell.
///
/// Threading: one task per output tile (parallel.hpp); a cell's values are computed by the same
/// operations whichever thread runs its tile, so the layers are bit-identical for any thread
/// count. Incremental: a call recomputes only the tiles within the windows' reach of an
/// elevation tile written since the previous call (ProcessContext::changedTiles); a tile's
/// cells come out as the same bits as in a whole-map pass.
/// run() and runTiles() may run concurrently on one instance (each task takes its own scratch
/// buffers from a locked pool); configure() and setConfig() may not run while they do.
/// Throws: run()/runTiles() throw LayerError for a layer id the map does not have, never
/// TileBudgetError (a tile past a sparse map's budget is skipped and counted in PassStats).
#include <terramap/plugin/plugin.hpp>

#include <memory>
#include <string>
#include <vector>

namespace terramap::plugins {

/// What the kernel computes and from which window (configure() fills it from the params).
struct TraversabilityConfig {
  double plane_radius_m = 0.3;   ///< half-width of the plane-fit window (m)
  double step_radius_m = 0.15;   ///< half-width of the step window (m)
  long min_points = 6;           ///< known cells the plane fit needs (>= 3)
  double critical_slope_rad = 0.5;
  double critical_roughness_m = 0.05;
  double critical_step_m = 0.2;
  double weight_slope = 1.0, weight_roughness = 1.0, weight_step = 1.0;
  bool any_critical_blocks = true;  ///< a term at or past its critical value makes the cell 0
};

/// The layers the kernel reads and writes (ids in the map at hand).
struct TraversabilityLayers {
  LayerId elevation = -1, slope = -1, roughness = -1, step = -1, traversability = -1;
};

class Traversability : public Plugin {
 public:
  Traversability();
  ~Traversability() override;
  Traversability(Traversability&&) noexcept;
  Traversability& operator=(Traversability&&) noexcept;

  ParamSchema schema() const override;
  void configure(const Params& p) override;
  std::vector<LayerSpec> layers() const override;
  EventMask events() const override;
  void start(ProcessContext& ctx) override;
  void process(ProcessContext& ctx, const Event& e) override;
  void finish(ProcessContext& ctx) override;

  /// For tests and embedders: the kernel with `cfg` instead of params.
  void setConfig(const TraversabilityConfig& cfg) { cfg_ = cfg; }
  const TraversabilityConfig& config() const { return cfg_; }

  /// What a pass did.
  struct PassStats {
    long tiles = 0;         ///< tiles written
    long cells_fitted = 0;  ///< cells that got a slope (a plane fit)
    long tile_budget = 0;   ///< tiles not written: a sparse map at its memory budget
  };
  /// Computes every tile of the four output layers from `l.elevation`.
  PassStats run(LayeredMap& map, const Executor& ex, const TraversabilityLayers& l) const;
  /// Computes only the output tiles `tiles` (buffer-space numbers): the same bits as run() there.
  PassStats runTiles(LayeredMap& map, const Executor& ex, const TraversabilityLayers& l,
                     const std::vector<int>& tiles) const;
  /// Output tiles that read an elevation tile of `changed`: `changed` grown by the wider window.
  std::vector<int> affectedTiles(const LayeredMap& map, const std::vector<int>& changed) const;
  /// The kernel runs in AVX2 where the CPU has it, else in baseline x86-64: the same bits.
  /// For tests: false keeps this instance on the baseline path.
  void setAllowAvx2(bool allow) { allow_avx2_ = allow; }
  static bool avx2Available();
  /// Half-widths in cells of the plane and step windows at `resolution` (m).
  int planeHalfWidth(double resolution) const;
  int stepHalfWidth(double resolution) const;

  struct Scratch;
  struct ScratchPool;

 private:
  TraversabilityConfig cfg_;
  std::string input_, slope_name_, roughness_name_, step_name_, trav_name_;
  bool on_finish_ = true;
  bool allow_avx2_ = true;
  EventMask events_ = 0;
  TraversabilityLayers ids_;
  // Per-task buffers, reused across calls so a pass does not fault in fresh pages for each tile.
  std::unique_ptr<ScratchPool> pool_;
  std::unique_ptr<Scratch> takeScratch() const;
  void giveScratch(std::unique_ptr<Scratch> s) const;
};

}  // namespace terramap::plugins
