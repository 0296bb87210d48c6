// renderChart: the data land where the axes say, error bars span y ± err, lines join points,
// the legend lists each series once, and bad requests are ConfigErrors.
#include <terramap/core/error.hpp>
#include <terramap/io/chart.hpp>

#include <gtest/gtest.h>

namespace tio = terramap::io;

namespace {

bool is(const tio::Image& img, int x, int y, tio::Rgba c) {
  const tio::Rgba p = img.pixel(y, x);
  return p.r == c.r && p.g == c.g && p.b == c.b;
}

/// Bounding box of the pixels of colour c.
struct Box {
  int x0 = 1 << 30, y0 = 1 << 30, x1 = -1, y1 = -1, n = 0;
};
Box find(const tio::Image& img, tio::Rgba c, int x_from = 0, int x_to = 1 << 30) {
  Box b;
  for (int y = 0; y < img.height; ++y)
    for (int x = x_from; x < std::min(img.width, x_to); ++x)
      if (is(img, x, y, c)) {
        b.x0 = std::min(b.x0, x), b.x1 = std::max(b.x1, x), b.y0 = std::min(b.y0, y), b.y1 = std::max(b.y1, y);
        ++b.n;
      }
  return b;
}

}  // namespace

TEST(Chart, MarkersAndBarsLandWhereTheAxesSay) {
  // One panel, one series: (0, 0) and (1, 10) with a bar of ±5 on the second point; the axes
  // cover [0, 1] x [0, 15] exactly (nice ticks), so the first marker sits in the bottom-left
  // corner of the plot area, the second in the right column at two thirds of the height, and
  // its bar reaches the top.
  const tio::Rgba red{200, 0, 0, 255};
  tio::ChartPanel p;
  p.title = "t";
  p.series.push_back({"", red, {0.0, 1.0}, {0.0, 10.0}, {0.0, 5.0}, false});  // no name: no legend entry
  tio::ChartOptions o;
  o.panel_width = 201;
  o.panel_height = 151;
  const tio::Image img = tio::renderChart({p}, o);
  ASSERT_GT(img.width, 201);
  // The plot area is the black frame's inside; markers are 7 x 7 squares of the colour.
  const Box all = find(img, red);
  ASSERT_GT(all.n, 49);
  EXPECT_EQ(all.x1 - all.x0, 200 + 6);  // marker centres 200 px apart, 3 px half-width each side
  EXPECT_EQ(all.y1 - all.y0, 150 + 3);  // from the bar's top (y = 15) to the lower marker's bottom
  // The upper marker's centre sits at y = 10: one third of the height below the top.
  const Box right = find(img, red, all.x1 - 3, all.x1 + 1);
  EXPECT_EQ(right.y0, all.y0);  // the bar (its end cap) is the topmost red
  EXPECT_TRUE(is(img, all.x1 - 3, all.y0 + 50, red));  // marker centre at 15 - 10 = 5 -> 50 px from the top
}

TEST(Chart, LinesJoinPointsAndTheLegendListsEachSeriesOnce) {
  const tio::Rgba blue{0, 0, 210, 255}, green{0, 150, 0, 255};
  auto panels = [&](bool named) {
    std::vector<tio::ChartPanel> ps(2);
    for (auto& p : ps) {
      p.series.push_back({named ? "truth" : "", blue, {0, 1, 2}, {0, 2, 1}, {}, true});
      p.series.push_back({named ? "estimate" : "", green, {0, 2}, {1, 1}, {0.5, 0.5}, false});
    }
    return ps;
  };
  tio::ChartOptions o;
  o.columns = 2;
  const tio::Image bare = tio::renderChart(panels(false), o), named = tio::renderChart(panels(true), o);
  const Box line = find(bare, blue);
  EXPECT_GT(line.n, 2 * 2 * o.panel_width);  // a 2-px polyline across each of the two panels
  // The named chart adds one legend swatch per series, not one per panel: a 21 x 2 px line
  // (about 44 px) and a 7 x 7 square.
  const int extra_blue = find(named, blue).n - line.n, extra_green = find(named, green).n - find(bare, green).n;
  EXPECT_GE(extra_blue, 40);
  EXPECT_LE(extra_blue, 50);
  EXPECT_EQ(extra_green, 49);
}

TEST(Chart, BadRequestsAreConfigErrors) {
  EXPECT_THROW(tio::renderChart({}, {}), terramap::ConfigError);
  tio::ChartPanel p;
  p.series.push_back({"s", {0, 0, 0, 255}, {0, 1}, {0, 1}, {0.1}, false});
  try {
    tio::renderChart({p}, {});
    ADD_FAILURE() << "accepted one error bar for two values";
  } catch (const terramap::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("'s'"), std::string::npos) << e.what();
  }
  tio::ChartOptions o;
  o.columns = 0;
  EXPECT_THROW(tio::renderChart({tio::ChartPanel{}}, o), terramap::ConfigError);
}
