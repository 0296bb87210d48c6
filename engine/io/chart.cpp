// Plots for reports (chart.hpp): panels of markers, error bars and lines on nice axes.
#include "canvas.hpp"

#include <terramap/io/chart.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

namespace terramap::io {
namespace {

using detail::Canvas;
using detail::Font;
using detail::kInk;
using detail::label;
using detail::niceStep;

constexpr int kMargin = 14, kTitlePx = 16, kCaptionPx = 12, kPanelTitlePx = 13, kTickPx = 11;
constexpr int kLeft = 58, kBottom = 40, kTop = 24, kRight = 12;  // around each plot area
const Rgba kGrid{225, 225, 225, 255};

struct Range {
  double lo = std::numeric_limits<double>::infinity(), hi = -std::numeric_limits<double>::infinity();
  void add(double v) {
    if (!std::isfinite(v)) return;
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  /// Padded to nice tick multiples; a single value gets a unit-wide range around it.
  void finish(double& step) {
    if (!(lo <= hi)) lo = 0, hi = 1;
    if (hi - lo < 1e-12 * std::max(1.0, std::abs(hi))) lo -= 0.5, hi += 0.5;
    step = niceStep(hi - lo, 5);
    // A value on a tick (to rounding) keeps that tick as the end of the axis.
    lo = std::floor(lo / step + 1e-9) * step;
    hi = std::ceil(hi / step - 1e-9) * step;
  }
};

/// Anti-aliasing is not worth it here: 1-2 px lines with Bresenham's steps.
void line(Canvas& c, int x0, int y0, int x1, int y1, Rgba col, int width = 1) {
  const int dx = std::abs(x1 - x0), dy = -std::abs(y1 - y0), sx = x0 < x1 ? 1 : -1, sy = y0 < y1 ? 1 : -1;
  int err = dx + dy;
  for (;;) {
    c.fill(x0 - (width - 1) / 2, y0 - (width - 1) / 2, width, width, col);
    if (x0 == x1 && y0 == y1) break;
    const int e2 = 2 * err;
    if (e2 >= dy) err += dy, x0 += sx;
    if (e2 <= dx) err += dx, y0 += sy;
  }
}

void drawPanel(Canvas& c, Font& f, const ChartPanel& p, int x0, int y0, int w, int h) {
  Range rx, ry;
  for (const ChartSeries& s : p.series)
    for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      rx.add(s.x[i]);
      const double e = i < s.y_err.size() && std::isfinite(s.y_err[i]) ? s.y_err[i] : 0.0;
      ry.add(s.y[i] - e);
      ry.add(s.y[i] + e);
    }
  double sx = 1, sy = 1;
  rx.finish(sx);
  ry.finish(sy);
  auto px = [&](double x) { return x0 + static_cast<int>(std::lround((x - rx.lo) / (rx.hi - rx.lo) * (w - 1))); };
  auto py = [&](double y) { return y0 + h - 1 - static_cast<int>(std::lround((y - ry.lo) / (ry.hi - ry.lo) * (h - 1))); };
  // Grid and ticks.
  for (double v = rx.lo; v <= rx.hi + sx * 1e-9; v += sx) {
    const int x = px(v);
    c.fill(x, y0, 1, h, kGrid);
    const std::string t = label(v, sx);
    f.draw(c, x - f.width(t, kTickPx) / 2, y0 + h + 14, t, kTickPx, kInk);
  }
  for (double v = ry.lo; v <= ry.hi + sy * 1e-9; v += sy) {
    const int y = py(v);
    c.fill(x0, y, w, 1, kGrid);
    const std::string t = label(v, sy);
    f.draw(c, x0 - 6 - f.width(t, kTickPx), y + 4, t, kTickPx, kInk);
  }
  c.frame(x0, y0, w, h, kInk);
  f.draw(c, x0 + (w - f.width(p.title, kPanelTitlePx)) / 2, y0 - 8, p.title, kPanelTitlePx, kInk);
  f.draw(c, x0 + (w - f.width(p.x_label, kTickPx)) / 2, y0 + h + 32, p.x_label, kTickPx, kInk);
  f.draw(c, x0 - kLeft + 2, y0 - 8, p.y_label, kTickPx, kInk);
  // Data: lines first, then bars and markers on top.
  for (const ChartSeries& s : p.series) {
    if (!s.line) continue;
    int lx = 0, ly = 0;
    bool have = false;
    for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) {
        have = false;
        continue;
      }
      const int x = px(s.x[i]), y = py(s.y[i]);
      if (have) line(c, lx, ly, x, y, s.colour, 2);
      c.fill(x - 1, y - 1, 3, 3, s.colour);
      lx = x, ly = y, have = true;
    }
  }
  for (const ChartSeries& s : p.series) {
    if (s.line) continue;
    for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      const int x = px(s.x[i]), y = py(s.y[i]);
      if (i < s.y_err.size() && std::isfinite(s.y_err[i]) && s.y_err[i] > 0) {
        const int ya = py(s.y[i] + s.y_err[i]), yb = py(s.y[i] - s.y_err[i]);
        line(c, x, ya, x, yb, s.colour);
        line(c, x - 3, ya, x + 3, ya, s.colour);
        line(c, x - 3, yb, x + 3, yb, s.colour);
      }
      c.fill(x - 3, y - 3, 7, 7, s.colour);
    }
  }
}

}  // namespace

Image renderChart(const std::vector<ChartPanel>& panels, const ChartOptions& o) {
  if (panels.empty()) throw ConfigError("renderChart: no panels");
  if (o.columns < 1 || o.panel_width < 40 || o.panel_height < 40)
    throw ConfigError("renderChart: need columns >= 1 and panels of at least 40 x 40 pixels");
  for (const ChartPanel& p : panels)
    for (const ChartSeries& s : p.series)
      if (!s.y_err.empty() && s.y_err.size() != s.y.size())
        throw ConfigError("renderChart: series '" + s.name + "' in panel '" + p.title + "' has " +
                          std::to_string(s.y_err.size()) + " error bars for " + std::to_string(s.y.size()) + " values");
  // Legend: one entry per distinct (name, line) in first-seen order.
  std::vector<const ChartSeries*> legend;
  std::map<std::pair<std::string, bool>, bool> seen;
  for (const ChartPanel& p : panels)
    for (const ChartSeries& s : p.series)
      if (!s.name.empty() && !seen[{s.name, s.line}]) {
        seen[{s.name, s.line}] = true;
        legend.push_back(&s);
      }
  Font& f = Font::get();
  std::lock_guard<std::mutex> lock(f.mutex());
  const int cols = std::min<int>(o.columns, static_cast<int>(panels.size()));
  const int rows = (static_cast<int>(panels.size()) + cols - 1) / cols;
  const int cell_w = kLeft + o.panel_width + kRight, cell_h = kTop + o.panel_height + kBottom;
  const int head = kMargin + kTitlePx + (o.caption.empty() ? 0 : kCaptionPx + 6) + 10;
  int legend_w = 0;
  for (const ChartSeries* s : legend) legend_w = std::max(legend_w, f.width(s->name, kTickPx));
  legend_w += 40;
  const int width = 2 * kMargin + cols * cell_w + legend_w;
  const int height = head + rows * cell_h + kMargin;
  Canvas c(width, height);
  f.draw(c, kMargin, kMargin + kTitlePx, o.title, kTitlePx, kInk);
  if (!o.caption.empty()) f.draw(c, kMargin, kMargin + kTitlePx + 6 + kCaptionPx, o.caption, kCaptionPx, kInk);
  for (std::size_t k = 0; k < panels.size(); ++k) {
    const int r = static_cast<int>(k) / cols, col = static_cast<int>(k) % cols;
    drawPanel(c, f, panels[k], kMargin + col * cell_w + kLeft, head + r * cell_h + kTop, o.panel_width, o.panel_height);
  }
  const int lx = kMargin + cols * cell_w + 8;
  int ly = head + kTop + 8;
  for (const ChartSeries* s : legend) {
    if (s->line) {
      line(c, lx, ly - 4, lx + 20, ly - 4, s->colour, 2);
    } else {
      c.fill(lx + 7, ly - 7, 7, 7, s->colour);
    }
    f.draw(c, lx + 26, ly, s->name, kTickPx, kInk);
    ly += 18;
  }
  return c.img;
}

}  // namespace terramap::io
