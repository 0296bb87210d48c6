// Pictures that explain themselves (io::annotate): the map is embedded untouched, the colour bar
// shows the colour ramp over the rendered range, the scale bar is as long as it says, errors in
// metres read in centimetres, text is really drawn, a missing font is a clear error.
#include <terramap/core/error.hpp>
#include <terramap/io/render.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>
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
  o.scale = 10;
  tio::AnnotatedLayout l;
  const tio::Image img = tio::annotate(tio::renderLayer(m, "elevation", o), m, "elevation", o, {}, &l);
  EXPECT_EQ(l.scale_bar_m, 5.0);  // the largest of 1, 2, 5 x 10^k m up to a third of 20 m
  EXPECT_EQ(l.scale_bar_px, static_cast<int>(std::lround(5.0 / 0.5 * 10)));
  // Five 1 m segments, black and white in turn, inside a frame.
  for (int k = 0; k < 5; ++k) {
    const int x = l.scale_bar_x + l.scale_bar_px * (2 * k + 1) / 10;  // the segment's middle
    if (k % 2 == 0) EXPECT_LT(img.pixel(l.scale_bar_y + 3, x).r, 60) << k;
    else EXPECT_GT(img.pixel(l.scale_bar_y + 3, x).r, 200) << k;
  }
  EXPECT_LT(img.pixel(l.scale_bar_y, l.scale_bar_x + l.scale_bar_px - 1).r, 60);  // its frame
  // Every tick labelled, the last with the unit: the scale bar's texts are the last drawn.
  ASSERT_GE(l.texts.size(), 6u);
  const std::vector<std::string> labels(l.texts.end() - 6, l.texts.end());
  EXPECT_EQ(labels, (std::vector<std::string>{"0", "1", "2", "3", "4", "5 m"}));
}

TEST(Annotate, AClippedValueGetsAnArrowEndAndTheWholeRangeInTheSubtitle) {
  const LayeredMap m = ramp();  // values 0.1 i - 0.05 j: -1.15 .. 3.9 m
  const auto cmap = tio::Colormap::byName("viridis");
  tio::RenderOptions o;
  o.scale = 4;
  o.range = tio::ValueRange{-1.f, 1.f};  // both ends clip
  tio::AnnotatedLayout l;
  const tio::Image img = tio::annotate(tio::renderLayer(m, "elevation", o), m, "elevation", o, {}, &l);
  EXPECT_TRUE(l.arrow_above);
  EXPECT_TRUE(l.arrow_below);
  // The arrows are filled with the end colours, just outside the bar, on the bar's axis.
  const int mid = l.bar_x + 8;
  EXPECT_EQ(img.pixel(l.bar_y - 3, mid), cmap.at(1.0));
  EXPECT_EQ(img.pixel(l.bar_y + l.bar_height + 2, mid), cmap.at(0.0));
  // The subtitle gives the layer's whole range and where the colours stop.
  ASSERT_GE(l.texts.size(), 2u);
  EXPECT_EQ(l.texts[1], "values -1.15 to 3.90 m; the colours stop at -1.00 and 1.00 (arrows: beyond)");

  // Only the side that clips gets an arrow; a range that holds every value gets none and no note.
  o.range = tio::ValueRange{-2.f, 3.f};
  const tio::Image up = tio::annotate(tio::renderLayer(m, "elevation", o), m, "elevation", o, {}, &l);
  EXPECT_TRUE(l.arrow_above);
  EXPECT_FALSE(l.arrow_below);
  EXPECT_EQ(up.pixel(l.bar_y - 3, mid), cmap.at(1.0));
  EXPECT_EQ(up.pixel(l.bar_y + l.bar_height + 2, mid), (tio::Rgba{255, 255, 255, 255}));
  o.range = tio::ValueRange{-2.f, 4.f};
  const tio::Image none = tio::annotate(tio::renderLayer(m, "elevation", o), m, "elevation", o, {}, &l);
  EXPECT_FALSE(l.arrow_above || l.arrow_below);
  EXPECT_EQ(none.pixel(l.bar_y - 3, mid), (tio::Rgba{255, 255, 255, 255}));
  for (const auto& t : l.texts) EXPECT_EQ(t.find("values"), std::string::npos) << t;
}

TEST(Annotate, ACategoricalLayerGetsALegendNamingEachCategory) {
  LayeredMap m(Geometry(0.5, Size(30, 20), Position(0, 0)), MapOptions{16, false});
  const LayerId id = m.addLayer("truth_soil_zone", "1");
  for (int i = 0; i < 30; ++i)
    for (int j = 0; j < 20; ++j) m.set(id, Index(i, j), static_cast<float>(i / 10 - 1));  // -1, 0, 1
  tio::RenderOptions o;
  o.scale = 4;
  o.range = tio::ValueRange{-1.f, 1.f};
  tio::Annotation a;
  a.categories = {{-1.f, "default soil"}, {0.f, "dense_strip"}, {1.f, "sand_patch"}};
  tio::AnnotatedLayout l;
  const tio::Image img = tio::annotate(tio::renderLayer(m, "truth_soil_zone", o), m, "truth_soil_zone", o, a, &l);
  EXPECT_EQ(l.bar_height, 0);  // no continuous bar
  EXPECT_EQ(l.texts.front(), "truth_soil_zone");  // an id has no unit: no "[1]"
  const auto cmap = tio::Colormap::byName("viridis");
  for (std::size_t k = 0; k < a.categories.size(); ++k) {
    EXPECT_NE(std::find(l.texts.begin(), l.texts.end(), a.categories[k].second), l.texts.end()) << a.categories[k].second;
    // Each swatch has its category's colour in the map.
    EXPECT_EQ(img.pixel(l.bar_y + static_cast<int>(k) * 22 + 8, l.bar_x + 8), cmap.at(0.5 * static_cast<double>(k)));
  }
  for (const auto& t : l.texts) EXPECT_EQ(t.find("values"), std::string::npos) << t;  // ids are not clipped
}

TEST(Annotate, OutlinedRegionsAreNamedOnTheMap) {
  LayeredMap m = ramp();
  const LayerId zone = m.addLayer("zone", "1");
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 24; ++j) m.set(zone, Index(i, j), i >= 15 && i < 25 ? 0.f : -1.f);  // a strip across x
  tio::RenderOptions o;
  o.scale = 8;
  o.range = tio::ValueRange{-2.f, 4.f};
  tio::Annotation a;
  a.outline_regions = "zone";
  tio::AnnotatedLayout plain, named;
  const tio::Image raw = tio::renderLayer(m, "elevation", o);
  const tio::Image without = tio::annotate(raw, m, "elevation", o, a, &plain);
  a.region_names = {{-1.f, "default soil"}, {0.f, "dense_strip"}};
  const tio::Image with = tio::annotate(raw, m, "elevation", o, a, &named);
  for (const char* name : {"default soil", "dense_strip"})
    EXPECT_NE(std::find(named.texts.begin(), named.texts.end(), name), named.texts.end()) << name;
  // Written on the map: the strip's name in white over the strip's northmost cells.
  long white_in_strip = 0, changed = 0;
  for (int y = named.map_y; y < named.map_y + 24; ++y)
    for (int x = named.map_x + 15 * 8; x < named.map_x + 25 * 8; ++x)
      white_in_strip += with.pixel(y, x).r > 200 && with.pixel(y, x).g > 200 && with.pixel(y, x).b > 200 ? 1 : 0;
  for (int y = named.map_y; y < named.map_y + raw.height; ++y)
    for (int x = named.map_x; x < named.map_x + raw.width; ++x) changed += with.pixel(y, x) != without.pixel(y, x) ? 1 : 0;
  EXPECT_GT(white_in_strip, 20);
  EXPECT_GT(changed, 100);
}

TEST(Annotate, AxesShowMapCoordinatesInMetres) {
  const LayeredMap m = ramp();  // 20 m x 12 m centred on (3, 1): x -7 .. 13, y -5 .. 7
  tio::RenderOptions o;
  o.scale = 10;  // 20 px per metre
  tio::AnnotatedLayout l;
  const tio::Image img = tio::annotate(tio::renderLayer(m, "elevation", o), m, "elevation", o, {}, &l);
  auto has = [&](const std::string& s) { return std::find(l.texts.begin(), l.texts.end(), s) != l.texts.end(); };
  EXPECT_TRUE(has("x [m]"));
  EXPECT_TRUE(has("y [m]"));
  for (const char* s : {"-5", "0", "5", "10"}) EXPECT_TRUE(has(s)) << s;
  // The tick of x = 0 is 7 m right of the map's left edge, under its frame; y = 0 is 7 m below its top.
  const int bottom = l.map_y + 12 * 20;
  EXPECT_LT(img.pixel(bottom + 2, l.map_x + 140).r, 60);
  EXPECT_GT(img.pixel(bottom + 2, l.map_x + 145).r, 200);
  EXPECT_LT(img.pixel(l.map_y + 140, l.map_x - 2).r, 60);
  EXPECT_GT(img.pixel(l.map_y + 145, l.map_x - 2).r, 200);
}

TEST(Annotate, ErrorsInMetresReadInCentimetres) {
  EXPECT_EQ(tio::displayUnit("m", true), std::make_pair(std::string("cm"), 100.0));
  EXPECT_EQ(tio::displayUnit("m", false), std::make_pair(std::string("m"), 1.0));
  EXPECT_EQ(tio::displayUnit("", false), std::make_pair(std::string("1"), 1.0));
  EXPECT_EQ(tio::displayUnit("count", true), std::make_pair(std::string("count"), 1.0));
  EXPECT_EQ(tio::displayUnit("N", false), std::make_pair(std::string("kN"), 1e-3));
  EXPECT_EQ(tio::displayUnit("Pa", true), std::make_pair(std::string("kPa"), 1e-3));
  // Angles (soil_phi, soil_delta) in degrees on every picture: readers think of friction angles in degrees.
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
