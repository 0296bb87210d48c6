#include "smooth_filter.hpp"

#include <cmath>
#include <sstream>

namespace terramap::plugins {

namespace {
std::string text(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}
}  // namespace

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
  // report(), not fail(): the user sees every problem of this stage at once.
  if (input_ == output_) p.report("output_layer", "must differ from input_layer ('" + input_ + "')");
  if (radius_m_ < sigma_m_) p.report("radius_m", "should be at least sigma_m so the kernel is not truncated flat");
  if (!unknown.empty()) p.report("run_on", "unknown event kind '" + unknown + "'");
  if (const Geometry* g = p.mapGeometry()) {
    // run() widens a kernel narrower than one cell to one cell each side: not what was asked
    // (the default radius is left to widen quietly on a coarse map).
    if (radius_m_ < g->resolution() && p.isSet("radius_m"))
      p.report("radius_m", "must be at least the map's resolution (" + text(g->resolution()) + " m, got " +
                               text(radius_m_) + " m); a kernel below one cell would be widened to one cell");
    const int k = kernelHalfWidth(g->resolution());
    if (2 * k + 1 > std::min(g->size().x(), g->size().y()))
      p.report("radius_m", "the kernel (" + std::to_string(2 * k + 1) + " cells across) does not fit in the map (" +
                               std::to_string(g->size().x()) + " x " + std::to_string(g->size().y()) + " cells)");
  }
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
  ctx.trackChanges(in_id_);
}

void SmoothFilter::process(ProcessContext& ctx, const Event&) {
  LayeredMap& map = ctx.map();
  const std::vector<int> tiles = affectedTiles(map, ctx.changedTiles(in_id_));
  if (!tiles.empty()) runTiles(map, ctx.executor(), in_id_, out_id_, tiles);
  ctx.addCounter("passes", 1);
  ctx.addCounter("tiles_smoothed", static_cast<double>(tiles.size()));
}

int SmoothFilter::kernelHalfWidth(double resolution) const {
  return std::max(1, static_cast<int>(std::floor(radius_m_ / resolution + 1e-9)));
}

std::vector<float> SmoothFilter::weights(double resolution, double& w1) const {
  const int k = kernelHalfWidth(resolution);
  std::vector<float> w(static_cast<size_t>(2 * k + 1));
  w1 = 0.0;
  for (int d = -k; d <= k; ++d) {
    const double x = d * resolution;
    w[static_cast<size_t>(d + k)] = static_cast<float>(std::exp(-x * x / (2 * sigma_m_ * sigma_m_)));
    w1 += w[static_cast<size_t>(d + k)];
  }
  return w;
}

std::vector<int> SmoothFilter::affectedTiles(const LayeredMap& map, const std::vector<int>& changed) const {
  return map.tilesWithin(changed, kernelHalfWidth(map.geometry().resolution()));
}

void SmoothFilter::finish(ProcessContext& ctx) {
  if (on_finish_) process(ctx, Tick{ctx.stamp()});
}

void SmoothFilter::run(LayeredMap& map, const Executor& ex, LayerId in, LayerId out) const {
  std::vector<int> all(static_cast<size_t>(map.tileCount()));
  for (int t = 0; t < map.tileCount(); ++t) all[static_cast<size_t>(t)] = t;
  runTiles(map, ex, in, out, all);
}

void SmoothFilter::runTiles(LayeredMap& map, const Executor& ex, LayerId in, LayerId out,
                            const std::vector<int>& tiles) const {
  const Geometry& g = map.geometry();
  const int R = g.size().x(), C = g.size().y();
  const int k = kernelHalfWidth(g.resolution());
  double w1 = 0.0;
  const std::vector<float> w = weights(g.resolution(), w1);
  const float min_w = static_cast<float>(min_weight_fraction_ * w1 * w1);

  // Which row sums the column pass of these tiles reads: their logical columns, and their
  // logical rows grown by k. A cell's sums do not depend on which others are computed, so a
  // part of the map gets the bits a whole-map pass gives it.
  std::vector<char> need_row(static_cast<size_t>(R), 0), need_col(static_cast<size_t>(C), 0);
  for (const int t : tiles) {
    const CellRect r = map.tileRect(t);
    for (int br = r.r0; br < r.r0 + r.rows; ++br) {
      const int i = map.logicalIndex(Index(br, r.c0)).x();
      for (int ii = std::max(0, i - k); ii <= std::min(R - 1, i + k); ++ii) need_row[static_cast<size_t>(ii)] = 1;
    }
    for (int bc = r.c0; bc < r.c0 + r.cols; ++bc) need_col[static_cast<size_t>(map.logicalIndex(Index(r.r0, bc)).y())] = 1;
  }

  // Logical-order copy of the input (one pass, parallel over tiles), so neighbours across
  // tiles and across the ring-buffer seam are plain array reads.
  const Eigen::MatrixXf src = map.toMatrix(in);
  // Row pass (along j): numerator and weight per cell, parallel over blocks of rows.
  Eigen::MatrixXf num(R, C), den(R, C);
  const int block = 32;
  const int nblocks = (R + block - 1) / block;
  ex.forEach(nblocks, [&](int b) {
    for (int i = b * block; i < std::min(R, (b + 1) * block); ++i) {
      if (!need_row[static_cast<size_t>(i)]) continue;
      for (int j = 0; j < C; ++j) {
        if (!need_col[static_cast<size_t>(j)]) continue;
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
    }
  });
  // Column pass (along i), written straight into the output tiles: one task per tile.
  const int T = map.tileSize();
  ex.forEach(static_cast<int>(tiles.size()), [&](int n) {
    const int t = tiles[static_cast<size_t>(n)];
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
