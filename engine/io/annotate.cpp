// Pictures that explain themselves: title, colour bar in the display unit, scale bar, axes.
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

constexpr int kMargin = 16, kTitlePx = 16, kCaptionPx = 13, kLabelPx = 12, kBarWidth = 16;

void drawColourBar(Canvas& c, Font& f, const Colormap& cmap, ValueRange range, double scale,
                   const std::string& unit, int x, int y, int h) {
  for (int r = 0; r < h; ++r) {
    const double t = h > 1 ? 1.0 - static_cast<double>(r) / (h - 1) : 0.5;
    c.fill(x, y + r, kBarWidth, 1, cmap.at(t));
  }
  c.frame(x, y, kBarWidth, h, kInk);
  f.draw(c, x, y - 6, "[" + unit + "]", kLabelPx, kInk);
  const double lo = range.min * scale, hi = range.max * scale, step = niceStep(hi - lo, 5);
  for (double v = std::ceil(lo / step - 1e-9) * step; v <= hi + step * 1e-9; v += step) {
    const double t = (v - lo) / (hi - lo);
    const int row = y + static_cast<int>(std::lround((1.0 - t) * (h - 1)));
    c.fill(x + kBarWidth, row, 5, 1, kInk);
    f.draw(c, x + kBarWidth + 8, row + kLabelPx / 2 - 1, label(v, step), kLabelPx, kInk);
  }
}

void drawCategories(Canvas& c, Font& f, const Colormap& cmap, ValueRange range,
                    const std::vector<std::pair<float, std::string>>& cats, int x, int y) {
  for (std::size_t k = 0; k < cats.size(); ++k) {
    const double t = (cats[k].first - range.min) / (range.max - range.min);
    const int row = y + static_cast<int>(k) * 22;
    c.fill(x, row, kBarWidth, kBarWidth, cmap.at(t));
    c.frame(x, row, kBarWidth, kBarWidth, kInk);
    f.draw(c, x + kBarWidth + 6, row + kBarWidth - 3, cats[k].second, kLabelPx, kInk);
  }
}

void drawArrow(Canvas& c, int x0, int y0, int dx, int dy, int len) {
  for (int k = 0; k <= len; ++k) c.set(x0 + dx * k, y0 + dy * k, kInk);
  const int hx = x0 + dx * len, hy = y0 + dy * len;
  for (int k = 1; k <= 4; ++k)  // arrow head: two short strokes back from the tip
    for (int s : {-1, 1}) c.set(hx - dx * k + (dx == 0 ? s * k : 0), hy - dy * k + (dy == 0 ? s * k : 0), kInk);
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

  Font& font = Font::get();
  std::lock_guard<std::mutex> lock(font.mutex());
  const std::string title = a.title.empty() ? layer + " [" + unit + "]" : a.title;
  const int top = kMargin + kTitlePx + 6 + (a.caption.empty() ? 0 : kCaptionPx + 6) + 12;
  const int right = a.categories.empty() ? 24 + kBarWidth + 8 + 64 : 24 + kBarWidth + 8 + 96;
  const int bottom = 56;
  const int min_w = std::max(font.width(title, kTitlePx), font.width(a.caption, kCaptionPx)) + 2 * kMargin;
  const int W = std::max(kMargin + map_image.width + right, min_w), H = top + map_image.height + bottom;
  Canvas c(W, H);

  font.draw(c, kMargin, kMargin + kTitlePx, title, kTitlePx, kInk);
  if (!a.caption.empty()) font.draw(c, kMargin, kMargin + kTitlePx + 6 + kCaptionPx, a.caption, kCaptionPx, kInk);
  const int mx = kMargin, my = top;
  c.paste(map_image, mx, my);
  c.frame(mx, my, map_image.width, map_image.height, kInk);

  const int bx = mx + map_image.width + 24;
  if (a.categories.empty())
    drawColourBar(c, font, cmap, range, scale, unit, bx, my, map_image.height);
  else
    drawCategories(c, font, cmap, range, a.categories, bx, my);
  if (o.nan_color.a > 0) {  // unknown cells are drawn: say what their colour means
    // Under the colour bar, or under the last category swatch.
    const int sx = bx;
    const int sy = a.categories.empty() ? my + map_image.height + 12 : my + static_cast<int>(a.categories.size()) * 22;
    c.fill(sx, sy, kBarWidth, kBarWidth, o.nan_color);
    c.frame(sx, sy, kBarWidth, kBarWidth, kInk);
    font.draw(c, sx + kBarWidth + 6, sy + kBarWidth - 3, "unknown", kLabelPx, kInk);
  }

  // Scale bar: a nice length up to a third of the map's width, half black, half white.
  const double px_per_m = map_image.width / (map.geometry().size().x() * map.geometry().resolution());
  const double len_m = niceLength(map_image.width / px_per_m / 3.0);
  const int len_px = std::max(1, static_cast<int>(std::lround(len_m * px_per_m)));
  const int sx = mx, sy = my + map_image.height + 14;
  c.fill(sx, sy, len_px, 6, kInk);
  c.fill(sx + len_px / 2, sy + 1, len_px - len_px / 2 - 1, 4, kWhite);
  char lb[64];
  std::snprintf(lb, sizeof lb, len_m >= 1 ? "%.0f m" : "%.2g m", len_m);
  font.draw(c, sx, sy + 6 + 4 + kLabelPx, lb, kLabelPx, kInk);

  // Axes of the map frame as the picture shows them: x to the right, y up.
  const int ax = sx + len_px + 40, ay = sy + 22;
  drawArrow(c, ax, ay, 1, 0, 22);
  drawArrow(c, ax, ay, 0, -1, 22);
  font.draw(c, ax + 26, ay + 4, "x", kLabelPx, kInk);
  font.draw(c, ax - 3, ay - 26, "y", kLabelPx, kInk);

  if (layout) {
    *layout = AnnotatedLayout{mx, my, bx, my, a.categories.empty() ? map_image.height : 0, sx, sy, len_px, len_m};
  }
  return std::move(c.img);
}

}  // namespace terramap::io
