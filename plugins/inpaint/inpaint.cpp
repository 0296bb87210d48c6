#include "inpaint.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

namespace terramap::plugins {

namespace {
using Mat = Eigen::MatrixXf;
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

struct Level {
  Mat v;  // weighted mean value (0 where weight 0)
  Mat w;  // weight in [0, 1]
};

// Bilinear sample of a coarse level at the position of fine cell (i, j): cell centres of
// level l+1 sit at 2i+0.5 in level-l cell units.
float sampleCoarse(const Level& c, int i, int j) {
  const double ci = (i + 0.5) / 2.0 - 0.5, cj = (j + 0.5) / 2.0 - 0.5;
  const int i0 = static_cast<int>(std::floor(ci)), j0 = static_cast<int>(std::floor(cj));
  const double fi = ci - i0, fj = cj - j0;
  double sv = 0, sw = 0;
  for (int di = 0; di <= 1; ++di)
    for (int dj = 0; dj <= 1; ++dj) {
      const int ii = std::clamp(i0 + di, 0, static_cast<int>(c.v.rows()) - 1);
      const int jj = std::clamp(j0 + dj, 0, static_cast<int>(c.v.cols()) - 1);
      const double b = (di ? fi : 1 - fi) * (dj ? fj : 1 - fj) * c.w(ii, jj);
      sv += b * c.v(ii, jj);
      sw += b;
    }
  return sw > 0 ? static_cast<float>(sv / sw) : kNaN;
}
}  // namespace

Mat Inpaint::distanceToKnown(const Mat& in) {
  const int R = static_cast<int>(in.rows()), C = static_cast<int>(in.cols());
  const float inf = std::numeric_limits<float>::infinity();
  Mat d(R, C);
  for (int i = 0; i < R; ++i)
    for (int j = 0; j < C; ++j) d(i, j) = std::isfinite(in(i, j)) ? 0.f : inf;
  // Two-pass 3-4 chamfer: distances in units of 1/3 cell, exact along axes, 5.7 % short at 45°.
  auto relax = [&](int i, int j, int di, int dj, float cost) {
    const int ii = i + di, jj = j + dj;
    if (ii < 0 || jj < 0 || ii >= R || jj >= C) return;
    d(i, j) = std::min(d(i, j), d(ii, jj) + cost);
  };
  for (int i = 0; i < R; ++i)
    for (int j = 0; j < C; ++j) {
      relax(i, j, -1, 0, 3), relax(i, j, 0, -1, 3), relax(i, j, -1, -1, 4), relax(i, j, -1, 1, 4);
    }
  for (int i = R - 1; i >= 0; --i)
    for (int j = C - 1; j >= 0; --j) {
      relax(i, j, 1, 0, 3), relax(i, j, 0, 1, 3), relax(i, j, 1, 1, 4), relax(i, j, 1, -1, 4);
    }
  return d / 3.0f;
}

Mat Inpaint::fill(const Mat& in, double max_distance_cells, const Executor& ex) {
  std::vector<Level> levels;
  Level l0;
  l0.v = Mat::Zero(in.rows(), in.cols());
  l0.w = Mat::Zero(in.rows(), in.cols());
  bool any = false;
  for (int i = 0; i < in.rows(); ++i)
    for (int j = 0; j < in.cols(); ++j)
      if (std::isfinite(in(i, j))) {
        l0.v(i, j) = in(i, j);
        l0.w(i, j) = 1.f;
        any = true;
      }
  if (!any) return Mat::Constant(in.rows(), in.cols(), kNaN);
  levels.push_back(std::move(l0));
  // Push: 2x2 weighted means down to a single cell.
  while (levels.back().v.rows() > 1 || levels.back().v.cols() > 1) {
    const Level& f = levels.back();
    const int R = static_cast<int>((f.v.rows() + 1) / 2), C = static_cast<int>((f.v.cols() + 1) / 2);
    Level c;
    c.v = Mat::Zero(R, C);
    c.w = Mat::Zero(R, C);
    ex.forEach(R, [&](int i) {
      for (int j = 0; j < C; ++j) {
        double sv = 0, sw = 0;
        for (int di = 0; di < 2; ++di)
          for (int dj = 0; dj < 2; ++dj) {
            const int ii = 2 * i + di, jj = 2 * j + dj;
            if (ii >= f.v.rows() || jj >= f.v.cols()) continue;
            sv += static_cast<double>(f.w(ii, jj)) * f.v(ii, jj);
            sw += f.w(ii, jj);
          }
        c.w(i, j) = static_cast<float>(std::min(1.0, sw));
        c.v(i, j) = sw > 0 ? static_cast<float>(sv / sw) : 0.f;
      }
    });
    levels.push_back(std::move(c));
  }
  // Pull: blend each level with the (already filled) coarser one.
  for (int l = static_cast<int>(levels.size()) - 2; l >= 0; --l) {
    Level& f = levels[static_cast<size_t>(l)];
    const Level& c = levels[static_cast<size_t>(l + 1)];
    const int R = static_cast<int>(f.v.rows()), C = static_cast<int>(f.v.cols());
    ex.forEach(R, [&](int i) {
      for (int j = 0; j < C; ++j) {
        const float w = f.w(i, j);
        if (w >= 1.f) continue;
        const float cv = sampleCoarse(c, i, j);
        f.v(i, j) = w * f.v(i, j) + (1.f - w) * cv;
        f.w(i, j) = 1.f;
      }
    });
  }
  Mat out = levels.front().v;
  const Mat dist = max_distance_cells >= 0 ? distanceToKnown(in) : Mat();
  for (int i = 0; i < in.rows(); ++i)
    for (int j = 0; j < in.cols(); ++j) {
      if (std::isfinite(in(i, j))) out(i, j) = in(i, j);  // known cells are never changed
      else if (max_distance_cells >= 0 && dist(i, j) > max_distance_cells) out(i, j) = kNaN;
    }
  return out;
}

ParamSchema Inpaint::schema() const {
  return {
      param::text("input_layer", "elevation", {}, "layer with holes (NaN = unknown)"),
      param::text("output_layer", "elevation_inpainted", {}, "layer to write (created)"),
      param::real("max_distance_m", 1.0, -1.0, 1e4, "m",
                  "leave cells farther than this from known data unknown; -1 = fill everything"),
      param::texts("run_on", {}, "event kinds after which to inpaint (default: only at the end)"),
      param::boolean("on_finish", true, "inpaint at the end of the run"),
  };
}

void Inpaint::configure(const Params& p) {
  input_ = p.getString("input_layer");
  output_ = p.getString("output_layer");
  max_distance_m_ = p.getDouble("max_distance_m");
  on_finish_ = p.getBool("on_finish");
  if (input_ == output_) p.fail("output_layer", "must differ from input_layer ('" + input_ + "')");
  if (max_distance_m_ < 0 && max_distance_m_ != -1.0) p.fail("max_distance_m", "must be >= 0, or -1 for no limit");
  std::string unknown;
  events_ = eventMaskFromNames(p.getStrings("run_on"), &unknown);
  if (!unknown.empty()) p.fail("run_on", "unknown event kind '" + unknown + "'");
  if (!events_ && !on_finish_) p.fail("on_finish", "with run_on empty and on_finish false this stage never runs");
}

std::vector<LayerSpec> Inpaint::layers() const {
  return {LayerSpec{input_, LayerAccess::Read, "", 0, ""},
          LayerSpec{output_, LayerAccess::Create, "m", kNaN,
                    input_ + " with holes filled by push-pull; NaN beyond max_distance_m of data"}};
}

EventMask Inpaint::events() const { return events_; }

void Inpaint::start(ProcessContext& ctx) {
  in_id_ = ctx.map().layerId(input_);
  out_id_ = ctx.map().layerId(output_);
  ctx.trackChanges(in_id_);
  ctx.trackChanges(out_id_);
}

void Inpaint::process(ProcessContext& ctx, const Event&) {
  // Push-pull reaches across the whole map (its coarse levels), so a change anywhere may change
  // any output cell: the only incremental step that keeps the bits is skipping a call when
  // neither the input nor the output (another stage may write it) changed since the last one.
  if (ctx.changedTiles(in_id_).empty() && ctx.changedTiles(out_id_).empty()) {
    ctx.addCounter("cells_filled", static_cast<double>(filled_last_));  // the same cells as last time
    ctx.addCounter("passes", 1);
    ctx.addCounter("passes_skipped", 1);
    return;
  }
  const Mat in = ctx.map().toMatrix(in_id_);
  const double lim = max_distance_m_ < 0 ? -1.0 : max_distance_m_ / ctx.map().geometry().resolution();
  const Mat out = fill(in, lim, ctx.executor());
  long filled = 0;
  for (int i = 0; i < in.rows(); ++i)
    for (int j = 0; j < in.cols(); ++j) filled += !std::isfinite(in(i, j)) && std::isfinite(out(i, j));
  ctx.map().fromMatrix(out_id_, out);
  filled_last_ = filled;
  ctx.addCounter("cells_filled", static_cast<double>(filled));
  ctx.addCounter("passes", 1);
}

void Inpaint::finish(ProcessContext& ctx) {
  if (on_finish_) process(ctx, Tick{ctx.stamp()});
}

}  // namespace terramap::plugins
