#pragma once
/// \file
/// Small plots as PNG-ready images: panels of x/y data with markers, error bars and lines,
/// axes with ticks, titles and a shared legend (e.g. the soil estimator's Fig. 11 analogue).
/// Text is drawn with FreeType from DejaVu Sans like annotate() (TERRAMAP_FONT overrides).
/// Thread-safe (the font is guarded); pure otherwise.
#include <terramap/io/render.hpp>

#include <string>
#include <vector>

namespace terramap::io {

/// One data series of a panel. NaN x or y skips a point; y_err (same length as y, or empty)
/// draws a vertical bar y ± y_err; `line` joins consecutive finite points instead of markers.
struct ChartSeries {
  std::string name;  ///< legend entry; series of the same name in several panels share one
  Rgba colour{0, 0, 0, 255};
  std::vector<double> x, y, y_err;
  bool line = false;
};

struct ChartPanel {
  std::string title, x_label, y_label;
  std::vector<ChartSeries> series;
};

struct ChartOptions {
  std::string title;         ///< above all panels
  std::string caption;       ///< one line under the title
  int columns = 3;           ///< panels per row
  int panel_width = 340, panel_height = 250;  ///< pixels of each plot area
};

/// Lays the panels out in a grid; each panel's axes cover its finite data (bars included) with
/// nice ticks. \throws ConfigError on no panels, columns < 1 or a series whose y_err does not
/// match y; OutputError when the font cannot be loaded.
Image renderChart(const std::vector<ChartPanel>& panels, const ChartOptions& options);

}  // namespace terramap::io
