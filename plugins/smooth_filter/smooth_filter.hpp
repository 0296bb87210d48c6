#pragma once
/// \file
/// smooth_filter: NaN-aware Gaussian smoothing of one layer into another (the role of
/// elevation_mapping_cupy's smooth_filter plugin, but Gaussian and normalised).
///
/// out(c) = sum_k w_k v(c+k) / sum_k w_k over the *valid* (finite) neighbours k within
/// `radius_m`, w_k = exp(-|k|^2 / (2 sigma^2)). A cell stays NaN if the valid weight around it
/// is below `min_weight_fraction` of the full kernel's weight (so holes are not invented),
/// and (optionally) when the input cell itself is NaN (`fill_holes: false`).
/// Separable: a row pass then a column pass, each tile one task, fixed summation order, so
/// the output is bit-identical for any thread count.
/// Incremental: each call recomputes only the output tiles within the kernel radius of an
/// input tile written since the previous call (ProcessContext::changedTiles), with the same
/// sums in the same order, so the output is bit-identical to smoothing the whole map.
#include <terramap/plugin/plugin.hpp>

#include <vector>

namespace terramap::plugins {

class SmoothFilter : public Plugin {
 public:
  ParamSchema schema() const override;
  void configure(const Params& p) override;
  std::vector<LayerSpec> layers() const override;
  EventMask events() const override;
  void start(ProcessContext& ctx) override;
  void process(ProcessContext& ctx, const Event& e) override;
  void finish(ProcessContext& ctx) override;

  /// The kernel itself, for tests and embedders: smooths `in` into `out` on `map`.
  void run(LayeredMap& map, const Executor& ex, LayerId in, LayerId out) const;
  /// Recomputes only output tiles `tiles` (buffer-space numbers); the same bits as run() there.
  void runTiles(LayeredMap& map, const Executor& ex, LayerId in, LayerId out, const std::vector<int>& tiles) const;
  /// Output tiles that read an input tile of `changed`: `changed` grown by the kernel radius.
  std::vector<int> affectedTiles(const LayeredMap& map, const std::vector<int>& changed) const;

 private:
  std::string input_, output_;
  double sigma_m_ = 0.1, radius_m_ = 0.3, min_weight_fraction_ = 0.3;
  bool fill_holes_ = false, on_finish_ = true;
  EventMask events_ = 0;
  LayerId in_id_ = -1, out_id_ = -1;
  int kernelHalfWidth(double resolution) const;
  std::vector<float> weights(double resolution, double& w1) const;
};

}  // namespace terramap::plugins
