#include "smooth_filter.hpp"

#include <cmath>

namespace terramap::plugins {

ParamSchema SmoothFilter::schema() const {
  return {
      param::text("input_layer", "elevation", {}, "layer to smooth"),
      param::text("output_layer", "elevation_smooth", {}, "layer to write (created)"),
      param::real("sigma_m", 0.1, 1e-4, 100.0, "m", "Gaussian standard deviation"),
      param::real("radius_m", 0.3, 1e-4, 100.0, "m", "kernel half-width (cells within it contribute)"),
      param::real("min_weight_fraction", 0.3, 0.0, 1.0, "1",
                  "minimum valid kernel weight, as a fraction of the full kernel, to output a value"),
      param::boolean("fill_holes", false, "also output a value where the input cell is NaN"),
      param::texts("run_on", {"point_cloud"},
                   "event kinds after which to smooth: point_cloud, pose, blade_pose, observation, tick"),
      param::boolean("on_finish", true, "smooth once more at the end of the run"),
  };
}

void SmoothFilter::configure(const Params& p) {
  input_ = p.getString("input_layer");
  output_ = p.getString("output_layer");
  sigma_m_ = p.getDouble("sigma_m");
  radius_m_ = p.getDouble("radius_m");
  min_weight_fraction_ = p.getDouble("min_weight_fraction");
  fill_holes_ = p.getBool("fill_holes");
  on_finish_ = p.getBool("on_finish");
  std::string unknown;
  events_ = eventMaskFromNames(p.getStrings("run_on"), &unknown);
  if (input_ == output_) p.fail("output_layer", "must differ from input_layer ('" + input_ + "')");
  if (radius_m_ < sigma_m_) p.fail("radius_m", "should be at least sigma_m so the kernel is not truncated flat");
  if (!unknown.empty()) p.fail("run_on", "unknown event kind '" + unknown + "'");
}

std::vector<LayerSpec> SmoothFilter::layers() const {
  return {LayerSpec{input_, LayerAccess::Read, "", 0, ""},
          LayerSpec{output_, LayerAccess::Create, "m", std::numeric_limits<float>::quiet_NaN(),
                    "Gaussian-smoothed " + input_ + "; NaN where too little valid input"}};
}

EventMask SmoothFilter::events() const { return events_; }

void SmoothFilter::start(ProcessContext& ctx) {
  in_id_ = ctx.map().layerId(input_);
  out_id_ = ctx.map().layerId(output_);
}

void SmoothFilter::process(ProcessContext& ctx, const Event&) {
  run(ctx.map(), ctx.executor(), in_id_, out_id_);
  ctx.addCounter("passes", 1);
}

void SmoothFilter::finish(ProcessContext& ctx) {
  if (on_finish_) process(ctx, Tick{ctx.stamp()});
}

void SmoothFilter::run(LayeredMap& map, const Executor& ex, LayerId in, LayerId out) const {
  const Geometry& g = map.geometry();
  const int R = g.size().x(), C = g.size().y();
  const int k = std::max(1, static_cast<int>(std::floor(radius_m_ / g.resolution() + 1e-9)));
  std::vector<float> w(static_cast<size_t>(2 * k + 1));
  double w1 = 0.0;
  for (int d = -k; d <= k; ++d) {
    const double x = d * g.resolution();
    w[static_cast<size_t>(d + k)] = static_cast<float>(std::exp(-x * x / (2 * sigma_m_ * sigma_m_)));
    w1 += w[static_cast<size_t>(d + k)];
  }
  const float min_w = static_cast<float>(min_weight_fraction_ * w1 * w1);

  // Logical-order copy of the input (one pass, parallel over tiles), so neighbours across
  // tiles and across the ring-buffer seam are plain array reads.
  const Eigen::MatrixXf src = map.toMatrix(in);
  // Row pass (along j): numerator and weight per cell, parallel over blocks of rows.
  Eigen::MatrixXf num(R, C), den(R, C);
  const int block = 32;
  const int nblocks = (R + block - 1) / block;
  ex.forEach(nblocks, [&](int b) {
    for (int i = b * block; i < std::min(R, (b + 1) * block); ++i)
      for (int j = 0; j < C; ++j) {
        float sn = 0, sd = 0;
        for (int d = -k; d <= k; ++d) {
          const int jj = j + d;
          if (jj < 0 || jj >= C) continue;
          const float v = src(i, jj);
          if (!std::isfinite(v)) continue;
          const float ww = w[static_cast<size_t>(d + k)];
          sn += ww * v;
          sd += ww;
        }
        num(i, j) = sn;
        den(i, j) = sd;
      }
  });
  // Column pass (along i), written straight into the output tiles: one task per tile.
  const int T = map.tileSize();
  ex.forEach(map.tileCount(), [&](int t) {
    const CellRect r = map.tileRect(t);
    float* o = map.mutableTileData(out, t);
    for (int br = r.r0; br < r.r0 + r.rows; ++br)
      for (int bc = r.c0; bc < r.c0 + r.cols; ++bc) {
        const Index li = map.logicalIndex(Index(br, bc));
        const int i = li.x(), j = li.y();
        float sn = 0, sd = 0;
        for (int d = -k; d <= k; ++d) {
          const int ii = i + d;
          if (ii < 0 || ii >= R) continue;
          const float ww = w[static_cast<size_t>(d + k)];
          sn += ww * num(ii, j);
          sd += ww * den(ii, j);
        }
        float v = std::numeric_limits<float>::quiet_NaN();
        if (sd > 0 && sd >= min_w && (fill_holes_ || std::isfinite(src(i, j)))) v = sn / sd;
        o[(br - r.r0) * T + (bc - r.c0)] = v;
      }
  });
}

}  // namespace terramap::plugins
