#include "scratch_dir.hpp"
#include <terramap/core/error.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/io/render.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <unistd.h>

namespace fs = std::filesystem;
using namespace terramap;
namespace tio = terramap::io;
using tio::Rgba;

namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

::testing::AssertionResult sameColour(const Rgba& got, const Rgba& want) {
  if (got == want) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "got (" << int(got.r) << "," << int(got.g) << "," << int(got.b) << ","
                                       << int(got.a) << ") want (" << int(want.r) << "," << int(want.g) << ","
                                       << int(want.b) << "," << int(want.a) << ")";
}

std::uint8_t grey(double t) { return static_cast<std::uint8_t>(std::lround(255.0 * std::clamp(t, 0.0, 1.0))); }

TEST(Colormap, ControlPointsAndInterpolation) {
  const auto v = tio::Colormap::byName("viridis");
  EXPECT_TRUE(sameColour(v.at(0.0), Rgba{0x44, 0x01, 0x54, 255}));
  EXPECT_TRUE(sameColour(v.at(0.5), Rgba{0x21, 0x91, 0x8C, 255}));
  EXPECT_TRUE(sameColour(v.at(1.0), Rgba{0xFD, 0xE7, 0x25, 255}));
  // Halfway between the first two stops (0x440154 and 0x472D7B): (69.5, 23, 103.5), rounded.
  EXPECT_TRUE(sameColour(v.at(1.0 / 16), Rgba{70, 23, 104, 255}));
  EXPECT_TRUE(sameColour(v.at(-3.0), v.at(0.0)));  // clamped
  EXPECT_TRUE(sameColour(v.at(7.0), v.at(1.0)));
  EXPECT_FALSE(v.diverging());

  const auto d = tio::Colormap::byName("RdBu");  // case-insensitive
  EXPECT_TRUE(d.diverging());
  EXPECT_TRUE(sameColour(d.at(0.0), Rgba{0x67, 0x00, 0x1F, 255}));  // low = dark red
  EXPECT_TRUE(sameColour(d.at(0.5), Rgba{0xF7, 0xF7, 0xF7, 255}));  // centre = near white
  EXPECT_TRUE(sameColour(d.at(1.0), Rgba{0x05, 0x30, 0x61, 255}));  // high = dark blue
  EXPECT_TRUE(sameColour(tio::Colormap::byName("rdbu_r").at(0.0), d.at(1.0)));

  const auto g = tio::Colormap::byName("gray");
  EXPECT_TRUE(sameColour(g.at(0.25), Rgba{64, 64, 64, 255}));  // 63.75 rounds up
  EXPECT_TRUE(sameColour(g.at(0.5), Rgba{128, 128, 128, 255}));

  try {
    tio::Colormap::byName("viridus");
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("did you mean 'viridis'"), std::string::npos) << e.what();
  }
}

TEST(RobustRange, PercentilesIgnoreNaNInfAndOutliers) {
  LayeredMap m(Geometry(1.0, Size(1, 104)), MapOptions{8, false});
  const LayerId id = m.addLayer("v", "1");
  for (int j = 0; j <= 100; ++j) m.set(id, Index(0, j), static_cast<float>(j));
  m.set(id, Index(0, 101), kNaN);
  m.set(id, Index(0, 102), std::numeric_limits<float>::infinity());
  m.set(id, Index(0, 103), kNaN);
  // 101 finite values 0..100: the 2nd percentile sits exactly on rank 2, the 98th on rank 98.
  tio::ValueRange r = tio::robustRange(m, id);
  EXPECT_FLOAT_EQ(r.min, 2.f);
  EXPECT_FLOAT_EQ(r.max, 98.f);
  // Linear interpolation between ranks: 25th percentile of 0..100 = 25, 2.5th = 2.5.
  r = tio::robustRange(m, id, 2.5, 25.0);
  EXPECT_FLOAT_EQ(r.min, 2.5f);
  EXPECT_FLOAT_EQ(r.max, 25.f);
  // One huge outlier replaces 100: the robust range does not move.
  m.set(id, Index(0, 100), 1e9f);
  r = tio::robustRange(m, id);
  EXPECT_FLOAT_EQ(r.max, 98.f);
  EXPECT_THROW(tio::robustRange(m, id, 50, 40), ConfigError);
  EXPECT_THROW(tio::robustRange(m, id, -1, 40), ConfigError);

  LayeredMap unknown(Geometry(1.0, Size(3, 3)), MapOptions{8, true});
  const LayerId u = unknown.addLayer("u", "m");
  r = tio::robustRange(unknown, u);
  EXPECT_EQ(r.min, 0.f);
  EXPECT_EQ(r.max, 1.f);
}

TEST(Render, NorthUpOrientationAndGreyValues) {
  // 2 rows (x) x 3 columns (y): the image is 2 wide and 3 tall; logical (0, 0) (largest x,
  // largest y) is the top-right pixel.
  LayeredMap m(Geometry(1.0, Size(2, 3)), MapOptions{8, false});
  const LayerId id = m.addLayer("v", "m");
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 3; ++j) m.set(id, Index(i, j), static_cast<float>(3 * i + j));
  tio::RenderOptions o;
  o.colormap = "grey";
  o.range = tio::ValueRange{0.f, 5.f};
  const tio::Image img = tio::renderLayer(m, "v", o);
  ASSERT_EQ(img.width, 2);
  ASSERT_EQ(img.height, 3);
  auto g = [](int v) { return Rgba{static_cast<std::uint8_t>(51 * v), static_cast<std::uint8_t>(51 * v),
                                   static_cast<std::uint8_t>(51 * v), 255}; };
  EXPECT_TRUE(sameColour(img.pixel(0, 1), g(0)));  // (0, 0)
  EXPECT_TRUE(sameColour(img.pixel(0, 0), g(3)));  // (1, 0)
  EXPECT_TRUE(sameColour(img.pixel(2, 0), g(5)));  // (1, 2)
  EXPECT_TRUE(sameColour(img.pixel(2, 1), g(2)));  // (0, 2)
  EXPECT_TRUE(sameColour(img.pixel(1, 1), g(1)));  // (0, 1)
}

TEST(Render, RegionOutlinesFollowTheBoundaryOfACategoricalLayer) {
  // 6 x (x) by 4 y cells at 3 pixels a cell; zone 1 where x > 0 (logical rows i < 3 are the
  // larger x: the right half of the north-up picture), a NaN cell inside it.
  LayeredMap m(Geometry(1.0, Size(6, 4)), MapOptions{8, false});
  const LayerId v = m.addLayer("v", "m"), z = m.addLayer("zone", "1");
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 4; ++j) {
      m.set(v, Index(i, j), 0.0f);
      m.set(z, Index(i, j), i < 3 ? 1.0f : -1.0f);
    }
  m.set(z, Index(0, 0), kNaN);
  tio::RenderOptions o;
  o.colormap = "grey";
  o.range = tio::ValueRange{0.f, 1.f};
  o.scale = 3;
  tio::Image img = tio::renderLayer(m, "v", o);
  const Rgba red{255, 0, 0, 255}, black{0, 0, 0, 255};
  tio::outlineRegions(img, m, "zone", 3, red);
  // The boundary is the vertical line between picture columns 2 and 3 (cells), pixels 8 and 9.
  for (int row = 0; row < 12; ++row) {
    EXPECT_TRUE(sameColour(img.pixel(row, 8), red)) << row;
    EXPECT_TRUE(sameColour(img.pixel(row, 9), red)) << row;
    EXPECT_TRUE(sameColour(img.pixel(row, 7), black)) << row;
    EXPECT_TRUE(sameColour(img.pixel(row, 10), black)) << row;
  }
  // The NaN cell is no region: no line around it (top-right cell, pixels 15-17 x 0-2).
  EXPECT_TRUE(sameColour(img.pixel(2, 15), black));
  EXPECT_TRUE(sameColour(img.pixel(3, 16), black));
  tio::Image small = tio::renderLayer(m, "v", tio::RenderOptions{});
  EXPECT_THROW(tio::outlineRegions(small, m, "zone", 3, red), std::invalid_argument);
}

TEST(Render, ClampsOutOfRangeAndHandlesNaN) {
  LayeredMap m(Geometry(1.0, Size(1, 4)), MapOptions{8, false});
  const LayerId id = m.addLayer("v", "m");
  // Column j -> image row j, single column.
  m.set(id, Index(0, 0), -5.f);
  m.set(id, Index(0, 1), 12.f);
  m.set(id, Index(0, 2), kNaN);
  m.set(id, Index(0, 3), -std::numeric_limits<float>::infinity());
  tio::RenderOptions o;
  o.colormap = "grey";
  o.range = tio::ValueRange{0.f, 10.f};
  tio::Image img = tio::renderLayer(m, "v", o);
  EXPECT_TRUE(sameColour(img.pixel(0, 0), Rgba{0, 0, 0, 255}));
  EXPECT_TRUE(sameColour(img.pixel(1, 0), Rgba{255, 255, 255, 255}));
  EXPECT_TRUE(sameColour(img.pixel(2, 0), Rgba{0, 0, 0, 0}));  // transparent
  EXPECT_TRUE(sameColour(img.pixel(3, 0), Rgba{0, 0, 0, 255}));
  o.nan_color = Rgba{128, 128, 128, 255};
  img = tio::renderLayer(m, "v", o);
  EXPECT_TRUE(sameColour(img.pixel(2, 0), Rgba{128, 128, 128, 255}));
}

TEST(Render, DivergingAutoRangeIsSymmetricAboutZero) {
  LayeredMap m(Geometry(1.0, Size(1, 101)), MapOptions{8, false});
  const LayerId id = m.addLayer("error", "m");
  for (int j = 0; j <= 100; ++j) m.set(id, Index(0, j), -1.f + 4.f * static_cast<float>(j) / 100.f);
  tio::RenderOptions o;
  o.colormap = "rdbu";
  const tio::Image img = tio::renderLayer(m, "error", o);
  // Robust range is [-0.92, 2.92] -> symmetric [-2.92, 2.92]: 0 is the white centre and
  // 2.92 (j = 98) the blue end.
  EXPECT_TRUE(sameColour(img.pixel(25, 0), Rgba{0xF7, 0xF7, 0xF7, 255}));
  EXPECT_TRUE(sameColour(img.pixel(98, 0), Rgba{0x05, 0x30, 0x61, 255}));
  o.symmetric_auto_range = false;  // plain robust range: 0 is no longer white
  EXPECT_FALSE(sameColour(tio::renderLayer(m, "error", o).pixel(25, 0), Rgba{0xF7, 0xF7, 0xF7, 255}));
}

TEST(Render, ScaleRepeatsEachCellAsABlock) {
  LayeredMap m(Geometry(1.0, Size(2, 2)), MapOptions{8, false});
  const LayerId id = m.addLayer("v", "m");
  m.set(id, Index(0, 0), 1.f);
  tio::RenderOptions o;
  o.colormap = "grey";
  o.range = tio::ValueRange{0.f, 1.f};
  o.scale = 3;
  const tio::Image img = tio::renderLayer(m, "v", o);
  ASSERT_EQ(img.width, 6);
  ASSERT_EQ(img.height, 6);
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) {
      const bool lit = r < 3 && c >= 3;  // cell (0, 0) is the top-right block
      EXPECT_TRUE(sameColour(img.pixel(r, c), lit ? Rgba{255, 255, 255, 255} : Rgba{0, 0, 0, 0})) << r << "," << c;
    }
}

/// 5 x 4 cells of 0.5 m centred at the origin: cell centres x in {1, 0.5, 0, -0.5, -1}.
LayeredMap plane(double dzdx, double dzdy) {
  LayeredMap m(Geometry(0.5, Size(5, 4)), MapOptions{8, false});
  const LayerId id = m.addLayer("elevation", "m");
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 4; ++j) {
      const Position p = m.geometry().positionOf(Index(i, j));
      m.set(id, Index(i, j), static_cast<float>(5.0 + dzdx * p.x() + dzdy * p.y()));
    }
  return m;
}

TEST(Hillshade, TiltedPlanesMatchHandComputedShade) {
  // Slope 0.5 downhill towards the east, light from the east at 45 deg:
  // n = (0.5, 0, 1)/sqrt(1.25), l = (cos45, 0, sin45) -> n.l = 1.5 cos45 / sqrt(1.25) = 0.948683.
  const double toward = 1.5 * std::cos(M_PI / 4) / std::sqrt(1.25);
  const double away = 0.5 * std::cos(M_PI / 4) / std::sqrt(1.25);  // uphill towards the light
  const double side = std::sin(M_PI / 4) / std::sqrt(1.25);         // light across the slope
  const LayeredMap down_east = plane(-0.5, 0.0), up_east = plane(0.5, 0.0), down_north = plane(0.0, -0.5);
  const LayeredMap flat = plane(0.0, 0.0);
  auto all = [](const tio::RasterF& s, double want) {
    for (Eigen::Index k = 0; k < s.size(); ++k)
      if (!(std::abs(s.data()[k] - want) < 1e-5)) return ::testing::AssertionFailure() << s.data()[k] << " vs " << want << " at " << k;
    return ::testing::AssertionSuccess();
  };
  // Edges and corners included: off-map neighbours are mirrored, so a plane shades uniformly.
  EXPECT_TRUE(all(tio::hillshade(down_east, 0, 90.0, 45.0), toward));
  EXPECT_TRUE(all(tio::hillshade(up_east, 0, 90.0, 45.0), away));
  EXPECT_TRUE(all(tio::hillshade(down_north, 0, 0.0, 45.0), toward));  // light from north
  EXPECT_TRUE(all(tio::hillshade(down_east, 0, 0.0, 45.0), side));
  EXPECT_TRUE(all(tio::hillshade(flat, 0, 123.0, 30.0), 0.5));       // sin 30
  EXPECT_GT(toward, away);
  // z_factor 2 on slope 0.25 equals slope 0.5.
  EXPECT_TRUE(all(tio::hillshade(plane(-0.25, 0.0), 0, 90.0, 45.0, 2.0), toward));
}

TEST(Hillshade, HolesStayUnknownAndDoNotDisturbNeighbours) {
  LayeredMap m = plane(-0.5, 0.0);
  m.set(0, Index(2, 1), kNaN);
  const tio::RasterF s = tio::hillshade(m, 0, 90.0, 45.0);
  const Eigen::Array2i hole = tio::rasterPixelOf(m.geometry(), Index(2, 1));
  const double toward = 1.5 * std::cos(M_PI / 4) / std::sqrt(1.25);
  for (int r = 0; r < s.rows(); ++r)
    for (int c = 0; c < s.cols(); ++c) {
      if (r == hole.x() && c == hole.y()) {
        EXPECT_TRUE(std::isnan(s(r, c)));
      } else {
        EXPECT_NEAR(s(r, c), toward, 1e-5) << r << "," << c;
      }
    }
  EXPECT_THROW(tio::hillshade(m, 0, 90.0, 0.0), ConfigError);
  EXPECT_THROW(tio::hillshade(m, 0, 90.0, 45.0, -1.0), ConfigError);
}

TEST(Render, HillshadeMultipliesTheColourAndLitSlopesAreBrighter) {
  tio::RenderOptions o;
  o.colormap = "grey";
  o.range = tio::ValueRange{0.f, 10.f};
  o.hillshade = true;
  o.azimuth_deg = 90.0;
  o.altitude_deg = 45.0;
  const LayeredMap toward = plane(-0.5, 0.0), away = plane(0.5, 0.0);
  const tio::Image a = tio::renderLayer(toward, "elevation", o), b = tio::renderLayer(away, "elevation", o);
  // Cell i = 2 (x = 0) has elevation 5 -> grey 127.5 before shading in both planes.
  const Eigen::Array2i px = tio::rasterPixelOf(toward.geometry(), Index(2, 1));
  const double s_toward = 1.5 * std::cos(M_PI / 4) / std::sqrt(1.25), s_away = 0.5 * std::cos(M_PI / 4) / std::sqrt(1.25);
  EXPECT_EQ(a.pixel(px.x(), px.y()).r, std::lround(127.5 * s_toward));
  EXPECT_EQ(b.pixel(px.x(), px.y()).r, std::lround(127.5 * s_away));
  EXPECT_GT(a.pixel(px.x(), px.y()).r, b.pixel(px.x(), px.y()).r);
  // Ambient lifts the floor: k = 0.4 + 0.6 * shade.
  o.ambient = 0.4;
  const tio::Image c = tio::renderLayer(away, "elevation", o);
  EXPECT_EQ(c.pixel(px.x(), px.y()).r, std::lround(127.5 * (0.4 + 0.6 * s_away)));
}

TEST(Render, RefusesBadOptions) {
  const LayeredMap m = plane(0.0, 0.0);
  tio::RenderOptions o;
  o.scale = 0;
  EXPECT_THROW(tio::renderLayer(m, "elevation", o), ConfigError);
  o = {};
  o.range = tio::ValueRange{3.f, 3.f};
  EXPECT_THROW(tio::renderLayer(m, "elevation", o), ConfigError);
  o = {};
  o.colormap = "jet";
  EXPECT_THROW(tio::renderLayer(m, "elevation", o), ConfigError);
  EXPECT_THROW(tio::renderLayer(m, "elevaton", {}), LayerError);
}

class PngTest : public ScratchDirTest {
 protected:
  PngTest() : ScratchDirTest("png_") {}
};

TEST_F(PngTest, WrittenPngReadsBackPixelForPixel) {
  LayeredMap m(Geometry(0.1, Size(9, 6)), MapOptions{8, false});
  const LayerId id = m.addLayer("elevation", "m");
  std::mt19937 rng(5);
  for (int i = 0; i < 9; ++i)
    for (int j = 0; j < 6; ++j) m.set(id, Index(i, j), (rng() % 7 == 0) ? kNaN : static_cast<float>(rng() % 1000) / 100.f);
  tio::RenderOptions o;
  o.scale = 2;
  o.hillshade = true;
  const tio::Image img = tio::renderLayer(m, "elevation", o);
  const fs::path p = dir_ / "e.png";
  tio::writePng(img, p);
  {
    std::ifstream in(p, std::ios::binary);
    char sig[8];
    in.read(sig, 8);
    EXPECT_EQ(std::string(sig, 8), std::string("\x89PNG\r\n\x1a\n", 8));
  }
  const tio::Raster r = tio::readRaster(p);
  EXPECT_EQ(r.driver, "PNG");
  ASSERT_EQ(r.width, img.width);
  ASSERT_EQ(r.height, img.height);
  ASSERT_EQ(r.bands.size(), 4u);
  for (int row = 0; row < img.height; ++row)
    for (int col = 0; col < img.width; ++col) {
      const Rgba px = img.pixel(row, col);
      ASSERT_EQ(r.bands[0].values(row, col), px.r);
      ASSERT_EQ(r.bands[1].values(row, col), px.g);
      ASSERT_EQ(r.bands[2].values(row, col), px.b);
      ASSERT_EQ(r.bands[3].values(row, col), px.a);
    }
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir_)) names.push_back(e.path().filename().string());
  EXPECT_EQ(names, std::vector<std::string>{"e.png"});
}

TEST_F(PngTest, OrientationMatchesTheGeoTiff) {
  LayeredMap m(Geometry(0.25, Size(7, 11), Position(2.0, -1.0)), MapOptions{8, false});
  const LayerId id = m.addLayer("elevation", "m");
  std::mt19937 rng(11);
  for (int i = 0; i < 7; ++i)
    for (int j = 0; j < 11; ++j) m.set(id, Index(i, j), static_cast<float>(rng() % 256));
  const fs::path tif = dir_ / "e.tif", png = dir_ / "e.png";
  tio::writeGeoTiff(m, {"elevation"}, tif);
  tio::RenderOptions o;
  o.colormap = "grey";
  o.range = tio::ValueRange{0.f, 255.f};
  tio::renderPng(m, "elevation", png, o);
  const tio::Raster t = tio::readRaster(tif), p = tio::readRaster(png);
  ASSERT_EQ(t.width, p.width);
  ASSERT_EQ(t.height, p.height);
  for (int row = 0; row < t.height; ++row)
    for (int col = 0; col < t.width; ++col)
      ASSERT_EQ(p.bands[0].values(row, col), static_cast<float>(grey(t.bands[0].values(row, col) / 255.0)));
}

TEST_F(PngTest, UnwritableTargetIsOutputError) {
  const tio::Image img = tio::renderLayer(plane(0, 0), "elevation", {});
  EXPECT_THROW(tio::writePng(img, dir_ / "missing" / "x.png"), OutputError);
  tio::Image bad = img;
  bad.rgba.pop_back();
  EXPECT_THROW(tio::writePng(bad, dir_ / "x.png"), OutputError);
}

}  // namespace
