// Pictures that explain themselves (io::annotate): the map is embedded untouched, the colour bar
// shows the colour ramp over the rendered range, the scale bar is as long as it says, errors in
// metres read in centimetres, text is really drawn, a missing font is a clear error.
#include <terramap/core/error.hpp>
#include <terramap/io/render.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>

namespace tio = terramap::io;
using namespace terramap;

namespace {
LayeredMap ramp(int cols = 24) {
  LayeredMap m(Geometry(0.5, Size(40, cols), Position(3.0, 1.0)), MapOptions{16, false});
  const LayerId id = m.addLayer("elevation", "m");
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < cols; ++j) m.set(id, Index(i, j), static_cast<float>(0.1 * i - 0.05 * j));
  return m;
}
long darkPixels(const tio::Image& img, int x0, int y0, int w, int h) {
  long n = 0;
  for (int y = y0; y < y0 + h; ++y)
    for (int x = x0; x < x0 + w; ++x) n += img.pixel(y, x).r < 100 ? 1 : 0;
  return n;
}
}  // namespace

TEST(Annotate, EmbedsTheRenderedMapPixelForPixel) {
  const LayeredMap m = ramp();
  tio::RenderOptions o;
  o.scale = 3;
  const tio::Image raw = tio::renderLayer(m, "elevation", o);
  tio::AnnotatedLayout l;
  const tio::Image img = tio::annotate(raw, m, "elevation", o, {}, &l);
  ASSERT_GT(img.width, raw.width);
  ASSERT_GT(img.height, raw.height);
  for (int y = 0; y < raw.height; ++y)
    for (int x = 0; x < raw.width; ++x) ASSERT_EQ(img.pixel(l.map_y + y, l.map_x + x), raw.pixel(y, x)) << y << " " << x;
}

TEST(Annotate, ColourBarRunsTheRampFromTheRangeMaximumDown) {
  const LayeredMap m = ramp(25);  // 25 cells x 5 px = 125 rows: row 62 is exactly half way
  tio::RenderOptions o;
  o.scale = 5;
  o.range = tio::ValueRange{-2.f, 4.f};
  tio::AnnotatedLayout l;
  const tio::Image img = tio::annotate(tio::renderLayer(m, "elevation", o), m, "elevation", o, {}, &l);
  ASSERT_GT(l.bar_height, 10);
  const auto cmap = tio::Colormap::byName("viridis");
  const int x = l.bar_x + 5;
  EXPECT_EQ(img.pixel(l.bar_y, x), cmap.at(1.0));
  EXPECT_EQ(img.pixel(l.bar_y + l.bar_height - 1, x), cmap.at(0.0));
  // Value 1.0 sits at t = 0.5 of [-2, 4]: half way down.
  const int mid = l.bar_y + static_cast<int>(std::lround(0.5 * (l.bar_height - 1)));
  EXPECT_EQ(img.pixel(mid, x), cmap.at(0.5));
}

TEST(Annotate, ScaleBarIsAsLongAsItsLabelSays) {
  const LayeredMap m = ramp();  // 40 cells x 0.5 m = 20 m wide
  tio::RenderOptions o;
  o.scale = 5;
  tio::AnnotatedLayout l;
  const tio::Image img = tio::annotate(tio::renderLayer(m, "elevation", o), m, "elevation", o, {}, &l);
  EXPECT_EQ(l.scale_bar_m, 5.0);  // the largest of 1, 2, 5 x 10^k m up to a third of 20 m
  EXPECT_EQ(l.scale_bar_px, static_cast<int>(std::lround(5.0 / 0.5 * 5)));
  EXPECT_LT(img.pixel(l.scale_bar_y + 3, l.scale_bar_x + 2).r, 60);                   // black half
  EXPECT_GT(img.pixel(l.scale_bar_y + 3, l.scale_bar_x + l.scale_bar_px - 3).r, 200);  // white half
  EXPECT_LT(img.pixel(l.scale_bar_y, l.scale_bar_x + l.scale_bar_px - 1).r, 60);      // its frame
}

TEST(Annotate, ErrorsInMetresReadInCentimetres) {
  EXPECT_EQ(tio::displayUnit("m", true), std::make_pair(std::string("cm"), 100.0));
  EXPECT_EQ(tio::displayUnit("m", false), std::make_pair(std::string("m"), 1.0));
  EXPECT_EQ(tio::displayUnit("", false), std::make_pair(std::string("1"), 1.0));
  EXPECT_EQ(tio::displayUnit("count", true), std::make_pair(std::string("count"), 1.0));
  EXPECT_EQ(tio::displayUnit("N", false), std::make_pair(std::string("kN"), 1e-3));
  EXPECT_EQ(tio::displayUnit("Pa", true), std::make_pair(std::string("kPa"), 1e-3));
  // Angles (soil_phi, soil_delta) in degrees on every picture (issue #48).
  EXPECT_EQ(tio::displayUnit("rad", false).first, "deg");
  EXPECT_NEAR(tio::displayUnit("rad", false).second * 0.5235987755982988, 30.0, 1e-12);
}

TEST(Annotate, TextIsDrawnAndDiffersWithTheTitle) {
  const LayeredMap m = ramp();
  tio::RenderOptions o;
  o.scale = 4;
  tio::AnnotatedLayout l;
  const tio::Image raw = tio::renderLayer(m, "elevation", o);
  tio::Annotation a;
  a.title = "AAAA";
  const tio::Image one = tio::annotate(raw, m, "elevation", o, a, &l);
  a.title = "WWWW WWWW";
  const tio::Image two = tio::annotate(raw, m, "elevation", o, a, &l);
  const long ink1 = darkPixels(one, 0, 0, one.width, l.map_y - 2), ink2 = darkPixels(two, 0, 0, two.width, l.map_y - 2);
  EXPECT_GT(ink1, 20);
  EXPECT_GT(ink2, ink1);  // more and wider letters, more ink
  a.title.clear();
  a.caption = "RMSE 1.00 cm";
  tio::AnnotatedLayout lc;
  const tio::Image cap = tio::annotate(raw, m, "elevation", o, a, &lc);
  EXPECT_GT(lc.map_y, l.map_y);  // the caption takes a line
}

TEST(Annotate, AMissingFontIsAnOutputErrorNamingTheFile) {
  const LayeredMap m = ramp();
  setenv("TERRAMAP_FONT", "/nonexistent/font.ttf", 1);
  try {
    tio::annotate(tio::renderLayer(m, "elevation", {}), m, "elevation", {}, {});
    ADD_FAILURE() << "no error";
  } catch (const OutputError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/font.ttf"), std::string::npos) << e.what();
  }
  unsetenv("TERRAMAP_FONT");
  EXPECT_NO_THROW(tio::annotate(tio::renderLayer(m, "elevation", {}), m, "elevation", {}, {}));
}
