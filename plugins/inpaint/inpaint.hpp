#pragma once
/// \file
/// inpaint: fills unknown (NaN) cells of a layer from the known ones around them (the role of
/// elevation_mapping_cupy's inpainting plugin, which calls OpenCV's Telea inpainting).
///
/// Method: push-pull interpolation. A pyramid of 2x2 weighted means is built down to one
/// cell ("push"); going back up, each cell keeps its own value in proportion to its weight and
/// takes the rest from a bilinear sample of the coarser level ("pull"). Known cells are
/// copied unchanged; unknown cells get a smooth blend of the nearest known surface. Cells
/// farther than `max_distance_m` from any known cell (chamfer distance) stay NaN, so a
/// planner never sees invented terrain far from data.
/// Deterministic: every output cell is a fixed function of the level below it.
/// A call skips the work when no tile of the input or output layer was written since the
/// previous call (ProcessContext::changedTiles): the output would be the same bits.
#include <terramap/plugin/plugin.hpp>

#include <Eigen/Core>

namespace terramap::plugins {

class Inpaint : public Plugin {
 public:
  ParamSchema schema() const override;
  void configure(const Params& p) override;
  std::vector<LayerSpec> layers() const override;
  EventMask events() const override;
  void start(ProcessContext& ctx) override;
  void process(ProcessContext& ctx, const Event& e) override;
  void finish(ProcessContext& ctx) override;

  /// Pure kernel on a logical-order matrix (NaN = unknown). `max_distance_cells` < 0 = no limit.
  static Eigen::MatrixXf fill(const Eigen::MatrixXf& in, double max_distance_cells, const Executor& ex);
  /// Chamfer (3-4) distance, in cells, from each cell to the nearest finite cell (inf if none).
  static Eigen::MatrixXf distanceToKnown(const Eigen::MatrixXf& in);

 private:
  std::string input_, output_;
  double max_distance_m_ = 1.0;
  bool on_finish_ = true;
  EventMask events_ = 0;
  LayerId in_id_ = -1, out_id_ = -1;
  long filled_last_ = 0;
};

}  // namespace terramap::plugins
