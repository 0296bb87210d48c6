// Pictures that explain themselves: title, colour bar in the display unit (arrow ends where values
// lie beyond it), categorical legends, a scale bar labelled at each tick, map coordinates.
// Text comes from FreeType (DejaVu Sans); lines and boxes are drawn directly into the RGBA image.
#include "canvas.hpp"

#include <terramap/core/error.hpp>
#include <terramap/io/render.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace terramap::io {

namespace {

using detail::Canvas;
using detail::Font;
using detail::kInk;
using detail::kWhite;
using detail::label;
using detail::niceLength;
using detail::niceStep;

// ---- parts of the picture ---------------------------------------------------------------------

constexpr int kMargin = 16, kTitlePx = 16, kCaptionPx = 13, kLabelPx = 12, kBarWidth = 16, kArrowPx = 12;

/// Every text drawn, in order, when the caller asked for the layout (tests read them).
struct Writer {
  Font& f;
  Canvas& c;
  std::vector<std::string>* texts;
  void operator()(int x, int y, const std::string& s, int px) {
    f.draw(c, x, y, s, px, kInk);
    if (texts) texts->push_back(s);
  }
};

/// A triangle of colour `fill` whose base is the bar's top (up = true) or bottom edge: the
/// colour the values beyond that end of the range are drawn in, pointing away from the bar.
void drawArrowEnd(Canvas& c, int x, int base_y, bool up, Rgba fill) {
  for (int k = 0; k < kArrowPx; ++k) {
    // Row k from the base: the triangle narrows from the bar's width to a point.
    const double half = 0.5 * kBarWidth * (1.0 - static_cast<double>(k) / kArrowPx);
    const int y = up ? base_y - 1 - k : base_y + k;
    const int x0 = x + static_cast<int>(std::lround(0.5 * kBarWidth - half));
    const int x1 = x + static_cast<int>(std::lround(0.5 * kBarWidth + half)) - 1;
    for (int xx = x0; xx <= x1; ++xx) c.set(xx, y, xx == x0 || xx == x1 ? kInk : fill);
  }
}

void drawColourBar(Canvas& c, Writer& w, const Colormap& cmap, ValueRange range, double scale,
                   const std::string& unit, int x, int y, int h, bool above, bool below) {
  for (int r = 0; r < h; ++r) {
    const double t = h > 1 ? 1.0 - static_cast<double>(r) / (h - 1) : 0.5;
    c.fill(x, y + r, kBarWidth, 1, cmap.at(t));
  }
  c.frame(x, y, kBarWidth, h, kInk);
  if (above) drawArrowEnd(c, x, y, true, cmap.at(1.0));
  if (below) drawArrowEnd(c, x, y + h, false, cmap.at(0.0));
  w(x, y - kArrowPx - 6, "[" + unit + "]", kLabelPx);
  const double lo = range.min * scale, hi = range.max * scale, step = niceStep(hi - lo, 5);
  for (double v = std::ceil(lo / step - 1e-9) * step; v <= hi + step * 1e-9; v += step) {
    const double t = (v - lo) / (hi - lo);
    const int row = y + static_cast<int>(std::lround((1.0 - t) * (h - 1)));
    c.fill(x + kBarWidth, row, 5, 1, kInk);
    w(x + kBarWidth + 8, row + kLabelPx / 2 - 1, label(v, step), kLabelPx);
  }
}

void drawCategories(Canvas& c, Writer& w, const Colormap& cmap, ValueRange range,
                    const std::vector<std::pair<float, std::string>>& cats, int x, int y) {
  for (std::size_t k = 0; k < cats.size(); ++k) {
    const double t = (cats[k].first - range.min) / (range.max - range.min);
    const int row = y + static_cast<int>(k) * 22;
    c.fill(x, row, kBarWidth, kBarWidth, cmap.at(t));
    c.frame(x, row, kBarWidth, kBarWidth, kInk);
    w(x + kBarWidth + 6, row + kBarWidth - 3, cats[k].second, kLabelPx);
  }
}

/// Smallest and largest finite value of a layer; NaN both when it has none.
std::pair<double, double> finiteExtent(const LayeredMap& map, LayerId id) {
  const Eigen::MatrixXf m = map.toMatrix(id);
  double lo = NAN, hi = NAN;
  for (Eigen::Index k = 0; k < m.size(); ++k) {
    const float v = m.data()[k];
    if (!std::isfinite(v)) continue;
    if (!(v >= lo)) lo = v;
    if (!(v <= hi)) hi = v;
  }
  return {lo, hi};
}

/// Number with about three significant digits, for the range note.
std::string number(double v) {
  char b[32];
  std::snprintf(b, sizeof b, std::abs(v) >= 100 || v == 0 ? "%.0f" : std::abs(v) >= 10 ? "%.1f" : std::abs(v) >= 1 ? "%.2f" : "%.3g", v);
  return b;
}

/// Each region's name on the map, in the outline colour over a dark halo so it reads on any
/// colour, at the middle of the longest run of the region's cells in its northmost row: inside
/// the region even when it is split (the default soil on both sides of a strip).
void drawRegionNames(Canvas& c, Font& font, const LayeredMap& map, const Annotation& a, int mx, int my, int map_w,
                     std::vector<std::string>* texts) {
  const RasterF z = northUpRaster(map, map.layerId(a.outline_regions));
  const double S = static_cast<double>(map_w) / static_cast<double>(z.cols());
  for (const auto& [value, name] : a.region_names) {
    int row = -1, best_start = 0, best_len = 0;
    for (int r = 0; r < z.rows() && row < 0; ++r)
      for (int col = 0, start = -1; col <= z.cols(); ++col) {
        const bool in = col < z.cols() && z(r, col) == value;
        if (in && start < 0) start = col;
        if (!in && start >= 0) {
          row = r;
          if (col - start > best_len) best_start = start, best_len = col - start;
          start = -1;
        }
      }
    if (row < 0) continue;
    const int cx = mx + static_cast<int>((best_start + 0.5 * best_len) * S);
    const int tw = font.width(name, kLabelPx);
    const int x = std::clamp(cx - tw / 2, mx + 2, std::max(mx + 2, mx + map_w - tw - 2));
    const int y = my + static_cast<int>(row * S) + kLabelPx + 3;
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx)
        if (dx || dy) font.draw(c, x + dx, y + dy, name, kLabelPx, kInk);
    font.draw(c, x, y, name, kLabelPx, a.outline_colour);
    if (texts) texts->push_back(name);
  }
}

/// Scale bar of `len_m` metres at (sx, sy): alternating black and white segments of round
/// lengths (5 m: 1 m or 2.5 m; 2 m: 0.5 m or 1 m; 1 m: 0.2 m or 0.5 m), as many as leave room for
/// each tick's label, every tick labelled (the last with the unit). Returns its length in pixels.
int drawScaleBar(Canvas& c, Font& font, Writer& w, int sx, int sy, double len_m, double px_per_m) {
  const int len_px = std::max(1, static_cast<int>(std::lround(len_m * px_per_m)));
  const double mant = len_m / std::pow(10.0, std::floor(std::log10(len_m) + 1e-9));
  int segments = 1;
  for (int n : mant > 1.5 && mant < 4.5 ? std::vector<int>{4, 2} : std::vector<int>{5, 2}) {
    int widest = 0;
    for (int k = 0; k <= n; ++k) widest = std::max(widest, font.width(label(k * len_m / n, len_m / n), kLabelPx));
    if (len_px / n >= widest + 8) {
      segments = n;
      break;
    }
  }
  c.fill(sx, sy, len_px, 6, kInk);
  for (int k = 1; k < segments; k += 2) {
    const int a0 = sx + len_px * k / segments, a1 = sx + len_px * (k + 1) / segments;
    c.fill(a0, sy + 1, a1 - a0 - (k + 1 == segments ? 1 : 0), 4, kWhite);
  }
  const double seg_m = len_m / segments;
  for (int k = 0; k <= segments; ++k) {
    const int px = sx + len_px * k / segments - (k == segments ? 1 : 0);
    c.fill(px, sy, 1, 9, kInk);
    std::string s = label(k * seg_m, seg_m) + (k == segments ? " m" : "");
    const int lw = font.width(k == segments ? label(k * seg_m, seg_m) : s, kLabelPx);
    w(px - (k == 0 ? 0 : lw / 2), sy + 9 + 2 + kLabelPx, s, kLabelPx);
  }
  return len_px;
}

}  // namespace

std::pair<std::string, double> displayUnit(const std::string& unit, bool diverging) {
  if (unit == "m" && diverging) return {"cm", 100.0};
  // Forces and stresses of soil cutting run to tens of thousands of newtons and pascals.
  if (unit == "N") return {"kN", 1e-3};
  if (unit == "Pa") return {"kPa", 1e-3};
  // A person reads angles in degrees (friction and slope angles); the layers keep radians.
  if (unit == "rad") return {"deg", 180.0 / 3.14159265358979323846};
  return {unit.empty() ? "1" : unit, 1.0};
}

Image annotate(const Image& map_image, const LayeredMap& map, const std::string& layer, const RenderOptions& o,
               const Annotation& a, AnnotatedLayout* layout) {
  const LayerId id = map.layerId(layer);
  const Colormap cmap = Colormap::byName(o.colormap);
  const ValueRange range = renderRange(map, id, o);
  const LayerInfo& info = map.layerInfo(id);
  auto [unit, scale] = displayUnit(info.unit, cmap.diverging());
  if (!a.display_unit.empty()) unit = a.display_unit;
  if (a.display_scale > 0) scale = a.display_scale;
  const bool categorical = !a.categories.empty();

  // Values the bar cannot show are drawn in its end colours: the bar gets arrow ends and the
  // subtitle the layer's whole range, so a saturated colour is not read as the largest value.
  const auto [vmin, vmax] = finiteExtent(map, id);
  const bool below = !categorical && vmin < range.min, above = !categorical && vmax > range.max;
  std::vector<std::string> captions;
  if (!a.caption.empty()) captions.push_back(a.caption);
  if (below || above)
    captions.push_back("values " + number(vmin * scale) + " to " + number(vmax * scale) + " " + unit +
                       "; the colours stop at " + number(range.min * scale) + " and " + number(range.max * scale) +
                       " (arrows: beyond)");

  Font& font = Font::get();
  std::lock_guard<std::mutex> lock(font.mutex());
  // A category id has no unit worth showing ("[1]").
  const std::string title = !a.title.empty() ? a.title : categorical ? layer : layer + " [" + unit + "]";

  // Map coordinates (m) along the bottom (x) and left (y) edges; the picture is north-up,
  // column 0 = smallest x, row 0 = largest y (geotiff.hpp).
  const Geometry& g = map.geometry();
  const double res = g.resolution();
  const double x0 = g.center().x() - 0.5 * g.size().x() * res, y0 = g.center().y() - 0.5 * g.size().y() * res;
  const double len_x = g.size().x() * res, len_y = g.size().y() * res;
  const double px_per_m = map_image.width / len_x;
  auto ticks = [&](double from, double span, int px) {
    const double step = niceStep(span, std::max(2, std::min(8, px / 60)));
    std::vector<std::pair<double, std::string>> t;
    for (double v = std::ceil(from / step - 1e-9) * step; v <= from + span + step * 1e-9; v += step)
      t.emplace_back(v, label(v, step));
    return t;
  };
  const auto xt = ticks(x0, len_x, map_image.width), yt = ticks(y0, len_y, map_image.height);
  int ylabel_w = font.width("y [m]", kLabelPx);
  for (const auto& [v, s] : yt) ylabel_w = std::max(ylabel_w, font.width(s, kLabelPx));

  const int top = kMargin + kTitlePx + 6 + static_cast<int>(captions.size()) * (kCaptionPx + 6) + 12 + kArrowPx;
  const int mx = kMargin + ylabel_w + 10, my = top;
  int legend_w = 64;
  for (const auto& [v, name] : a.categories) legend_w = std::max(legend_w, font.width(name, kLabelPx) + 8);
  const int right = 24 + kBarWidth + 8 + legend_w;
  const int bottom = 4 + kLabelPx + 10 + 6 + 4 + kLabelPx + kMargin;
  int min_w = font.width(title, kTitlePx);
  for (const auto& line : captions) min_w = std::max(min_w, font.width(line, kCaptionPx));
  const int W = std::max(mx + map_image.width + right, min_w + 2 * kMargin);
  const int H = top + map_image.height + std::max(bottom, kArrowPx + 12 + kBarWidth + kMargin);
  Canvas c(W, H);
  std::vector<std::string> texts;
  Writer w{font, c, layout ? &texts : nullptr};

  w(kMargin, kMargin + kTitlePx, title, kTitlePx);
  for (std::size_t k = 0; k < captions.size(); ++k)
    w(kMargin, kMargin + kTitlePx + static_cast<int>(k + 1) * (6 + kCaptionPx), captions[k], kCaptionPx);
  c.paste(map_image, mx, my);
  c.frame(mx, my, map_image.width, map_image.height, kInk);

  // Coordinate ticks: outward from the frame, labels centred under (x) or left of (y) them.
  const int mb = my + map_image.height;
  for (const auto& [v, s] : xt) {
    const int px = mx + static_cast<int>(std::lround((v - x0) * px_per_m));
    c.fill(px, mb, 1, 4, kInk);
    w(std::max(0, px - font.width(s, kLabelPx) / 2), mb + 4 + kLabelPx, s, kLabelPx);
  }
  for (const auto& [v, s] : yt) {
    const int py = my + static_cast<int>(std::lround((y0 + len_y - v) * px_per_m));
    c.fill(mx - 4, py, 4, 1, kInk);
    w(mx - 6 - font.width(s, kLabelPx), py + kLabelPx / 2 - 1, s, kLabelPx);
  }
  w(mx + map_image.width - font.width("x [m]", kLabelPx), mb + 4 + 2 * kLabelPx + 2, "x [m]", kLabelPx);
  w(mx - 6 - font.width("y [m]", kLabelPx), my - 4, "y [m]", kLabelPx);

  if (!a.outline_regions.empty() && !a.region_names.empty())
    drawRegionNames(c, font, map, a, mx, my, map_image.width, layout ? &texts : nullptr);

  const int bx = mx + map_image.width + 24;
  if (!categorical)
    drawColourBar(c, w, cmap, range, scale, unit, bx, my, map_image.height, above, below);
  else
    drawCategories(c, w, cmap, range, a.categories, bx, my);
  if (o.nan_color.a > 0) {  // unknown cells are drawn: say what their colour means
    // Under the colour bar (and its arrow end), or under the last category swatch.
    const int sx = bx;
    const int sy = categorical ? my + static_cast<int>(a.categories.size()) * 22 : my + map_image.height + kArrowPx + 4;
    c.fill(sx, sy, kBarWidth, kBarWidth, o.nan_color);
    c.frame(sx, sy, kBarWidth, kBarWidth, kInk);
    w(sx + kBarWidth + 6, sy + kBarWidth - 3, "unknown", kLabelPx);
  }

  const int sx = mx, sy = mb + 4 + kLabelPx + 10;
  const double len_m = niceLength(map_image.width / px_per_m / 3.0);
  const int len_px = drawScaleBar(c, font, w, sx, sy, len_m, px_per_m);

  if (layout) {
    *layout = AnnotatedLayout{};
    layout->map_x = mx, layout->map_y = my;
    layout->bar_x = bx, layout->bar_y = my, layout->bar_height = categorical ? 0 : map_image.height;
    layout->scale_bar_x = sx, layout->scale_bar_y = sy, layout->scale_bar_px = len_px, layout->scale_bar_m = len_m;
    layout->texts = std::move(texts);
    layout->arrow_above = above;
    layout->arrow_below = below;
  }
  return std::move(c.img);
}

}  // namespace terramap::io
