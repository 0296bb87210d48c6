#include "scratch_dir.hpp"
#include <terramap/core/error.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/io/geotiff.hpp>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <unistd.h>

namespace fs = std::filesystem;
using namespace terramap;
namespace tio = terramap::io;

namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

class GeoTiffTest : public ScratchDirTest {
 protected:
  GeoTiffTest() : ScratchDirTest("geotiff_") {}
};

/// 3 rows (along x) x 4 columns (along y), 0.5 m cells, centred at (10, 20):
/// x spans [9.25, 10.75), y spans [19, 21). elevation(i, j) = 10 i + j + 0.25.
LayeredMap smallMap() {
  LayeredMap m(Geometry(0.5, Size(3, 4), Position(10.0, 20.0)), MapOptions{8, false});
  const LayerId e = m.addLayer("elevation", "m");
  const LayerId c = m.addLayer("count", "count", 0.f);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 4; ++j) m.set(e, Index(i, j), 10.f * i + j + 0.25f);
  m.set(e, Index(1, 2), kNaN);
  m.set(c, Index(0, 3), 7.f);
  return m;
}

std::string run(const std::string& cmd) {
  std::string out;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return out;
  char buf[4096];
  std::size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) out.append(buf, n);
  ::pclose(p);
  return out;
}

bool haveGdalTools() { return ::access("/usr/bin/gdalinfo", X_OK) == 0 && ::access("/usr/bin/gdallocationinfo", X_OK) == 0; }

TEST_F(GeoTiffTest, NorthUpOrientationAndGeoTransform) {
  const LayeredMap m = smallMap();
  const fs::path p = dir_ / "small.tif";
  tio::writeGeoTiff(m, {"elevation", "count"}, p);
  const tio::Raster r = tio::readRaster(p);
  EXPECT_EQ(r.driver, "GTiff");
  // Width = map rows (x extent), height = map columns (y extent).
  ASSERT_EQ(r.width, 3);
  ASSERT_EQ(r.height, 4);
  ASSERT_TRUE(r.geotransform.has_value());
  const std::array<double, 6> want = {9.25, 0.5, 0.0, 21.0, 0.0, -0.5};
  for (int k = 0; k < 6; ++k) EXPECT_DOUBLE_EQ((*r.geotransform)[k], want[k]) << k;
  ASSERT_EQ(r.bands.size(), 2u);
  const auto& e = r.bands[0].values;
  // Top-left pixel = north-west corner = smallest x (i = 2), largest y (j = 0).
  EXPECT_EQ(e(0, 0), 20.25f);
  // Top-right = north-east = largest x (i = 0), largest y (j = 0).
  EXPECT_EQ(e(0, 2), 0.25f);
  // Bottom-left = south-west = (i = 2, j = 3).
  EXPECT_EQ(e(3, 0), 23.25f);
  // Row 2, col 1 = (i = 1, j = 2): the NaN cell.
  EXPECT_TRUE(std::isnan(e(2, 1)));
  EXPECT_EQ(r.bands[1].values(3, 2), 7.f);  // count (0, 3) -> row 3, col 2
  EXPECT_EQ(r.bands[1].values(0, 0), 0.f);  // fill
}

TEST_F(GeoTiffTest, EveryCellLandsWhereItsPositionSaysByGeoTransform) {
  // Independent check: map each cell's centre position through the inverse geotransform.
  LayeredMap m(Geometry(0.2, Size(13, 7), Position(-3.3, 1.7)), MapOptions{8, false});
  const LayerId e = m.addLayer("elevation", "m");
  for (int i = 0; i < 13; ++i)
    for (int j = 0; j < 7; ++j) m.set(e, Index(i, j), static_cast<float>(100 * i + j));
  m.move(Position(-3.3 + 0.2 * 4, 1.7 - 0.2 * 2));  // ring start != 0 must not matter
  for (int i = 0; i < 13; ++i)
    for (int j = 0; j < 7; ++j) m.set(e, Index(i, j), static_cast<float>(100 * i + j));
  const tio::GeoReference geo{32633, 400000.0, 6000000.0};
  const fs::path p = dir_ / "moved.tif";
  tio::writeGeoTiff(m, {"elevation"}, p, tio::GeoTiffOptions{geo, true, {}});
  const tio::Raster r = tio::readRaster(p);
  ASSERT_TRUE(r.geotransform.has_value());
  const auto& gt = *r.geotransform;
  for (int i = 0; i < 13; ++i)
    for (int j = 0; j < 7; ++j) {
      const Position xy = m.geometry().positionOf(Index(i, j));
      const double east = geo.origin_easting + xy.x(), north = geo.origin_northing + xy.y();
      const int col = static_cast<int>(std::floor((east - gt[0]) / gt[1]));
      const int row = static_cast<int>(std::floor((north - gt[3]) / gt[5]));
      ASSERT_EQ(r.bands[0].values(row, col), static_cast<float>(100 * i + j)) << i << "," << j;
      const Eigen::Array2i px = tio::rasterPixelOf(m.geometry(), Index(i, j));
      EXPECT_EQ(px.x(), row);
      EXPECT_EQ(px.y(), col);
      EXPECT_TRUE((tio::logicalIndexOfPixel(m.geometry(), row, col) == Index(i, j)).all());
    }
}

TEST_F(GeoTiffTest, BandDescriptionUnitNodataAndLocalCrs) {
  const fs::path p = dir_ / "meta.tif";
  tio::writeGeoTiff(smallMap(), {"count", "elevation"}, p);
  const tio::Raster r = tio::readRaster(p);
  ASSERT_EQ(r.bands.size(), 2u);
  EXPECT_EQ(r.bands[0].description, "count");
  EXPECT_EQ(r.bands[0].unit, "count");
  EXPECT_EQ(r.bands[1].description, "elevation");
  EXPECT_EQ(r.bands[1].unit, "m");
  EXPECT_NE(std::find(r.bands[1].metadata.begin(), r.bands[1].metadata.end(), "unit=m"), r.bands[1].metadata.end());
  for (const auto& b : r.bands) {
    ASSERT_TRUE(b.nodata.has_value());
    EXPECT_TRUE(std::isnan(*b.nodata));
  }
  EXPECT_TRUE(r.crs_local) << r.crs_wkt;
  EXPECT_FALSE(r.crs_projected);
  EXPECT_EQ(r.crs_linear_unit_m, 1.0);
  EXPECT_NE(r.crs_wkt.find("terramap map frame"), std::string::npos) << r.crs_wkt;
  EXPECT_EQ(listing(), std::vector<std::string>{"meta.tif"});  // no temp, no .aux.xml
}

TEST_F(GeoTiffTest, LayerDocIsBandMetadata) {
  const fs::path p = dir_ / "doc.tif";
  tio::GeoTiffOptions o;
  o.layer_docs = {{"elevation", "height of the ground above the map frame's z = 0 [m]; NaN = unseen"}};
  tio::writeGeoTiff(smallMap(), {"count", "elevation"}, p, o);
  const tio::Raster r = tio::readRaster(p);
  ASSERT_EQ(r.bands.size(), 2u);
  const auto& md = r.bands[1].metadata;
  EXPECT_NE(std::find(md.begin(), md.end(), "doc=" + o.layer_docs["elevation"]), md.end());
  for (const auto& item : r.bands[0].metadata) EXPECT_NE(item.rfind("doc=", 0), 0u) << item;  // none given
}

TEST_F(GeoTiffTest, EpsgAndOriginPlaceTheRaster) {
  const fs::path p = dir_ / "utm.tif";
  tio::writeGeoTiff(smallMap(), {"elevation"}, p, tio::GeoTiffOptions{{32632, 500000.0, 5200000.0}, true, {}});
  const tio::Raster r = tio::readRaster(p);
  EXPECT_TRUE(r.crs_projected);
  EXPECT_FALSE(r.crs_local);
  EXPECT_EQ(r.epsg, 32632);
  ASSERT_TRUE(r.geotransform.has_value());
  EXPECT_DOUBLE_EQ((*r.geotransform)[0], 500009.25);
  EXPECT_DOUBLE_EQ((*r.geotransform)[3], 5200021.0);
}

TEST_F(GeoTiffTest, ValuesAreBitExactIncludingLargeTiledRasters) {
  // 300 x 270 > 256: exercises the tiled + DEFLATE + predictor path.
  LayeredMap m(Geometry(0.05, Size(300, 270)), MapOptions{64, false});
  const LayerId e = m.addLayer("elevation", "m");
  std::mt19937 rng(3);
  Eigen::MatrixXf v(300, 270);
  for (Eigen::Index k = 0; k < v.size(); ++k)
    v.data()[k] = (rng() % 17 == 0) ? kNaN : std::uniform_real_distribution<float>(-3.f, 3.f)(rng);
  m.fromMatrix(e, v);
  const fs::path p = dir_ / "big.tif";
  tio::writeGeoTiff(m, {"elevation"}, p);
  const tio::Raster r = tio::readRaster(p);
  const tio::RasterF expect = tio::northUpRaster(m, e);
  ASSERT_EQ(r.bands[0].values.rows(), expect.rows());
  ASSERT_EQ(r.bands[0].values.cols(), expect.cols());
  EXPECT_EQ(0, std::memcmp(r.bands[0].values.data(), expect.data(), sizeof(float) * static_cast<std::size_t>(expect.size())));
  // And the raster helper itself against the definition (row r, col c) = (R-1-c, r).
  for (int row = 0; row < 270; row += 7)
    for (int col = 0; col < 300; col += 11) {
      const float a = expect(row, col), b = v(299 - col, row);
      EXPECT_TRUE((std::isnan(a) && std::isnan(b)) || a == b);
    }
}

TEST_F(GeoTiffTest, RefusesBadRequests) {
  const LayeredMap m = smallMap();
  const fs::path p = dir_ / "x.tif";
  try {
    tio::writeGeoTiff(m, {"elevaton"}, p);
    FAIL();
  } catch (const LayerError& e) {
    EXPECT_NE(std::string(e.what()).find("did you mean 'elevation'"), std::string::npos) << e.what();
  }
  EXPECT_THROW(tio::writeGeoTiff(m, {}, p), ConfigError);
  EXPECT_THROW(tio::writeGeoTiff(m, {"count", "count"}, p), ConfigError);
  auto epsgError = [&](int code) {
    try {
      tio::writeGeoTiff(m, {"elevation"}, p, tio::GeoTiffOptions{{code, 0.0, 0.0}, true, {}});
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(epsgError(4326).find("not a projected CRS"), std::string::npos);
  EXPECT_NE(epsgError(999999).find("unknown EPSG code 999999"), std::string::npos);
  EXPECT_NE(epsgError(2227).find("not metres"), std::string::npos);  // California zone 3, US feet
  EXPECT_THROW(tio::writeGeoTiff(m, {"elevation"}, p, tio::GeoTiffOptions{{0, kNaN, 0.0}, true, {}}), ConfigError);
  EXPECT_TRUE(listing().empty());
}

TEST_F(GeoTiffTest, UnwritableTargetIsOutputErrorAndOldFileSurvives) {
  const LayeredMap m = smallMap();
  try {
    tio::writeGeoTiff(m, {"elevation"}, dir_ / "missing" / "a.tif");
    FAIL();
  } catch (const OutputError& e) {
    EXPECT_NE(std::string(e.what()).find("missing/a.tif"), std::string::npos) << e.what();
  }
  const fs::path p = dir_ / "keep.tif";
  tio::writeGeoTiff(m, {"elevation"}, p);
  EXPECT_THROW(tio::writeGeoTiff(m, {"nope"}, p), LayerError);
  EXPECT_EQ(tio::readRaster(p).bands.size(), 1u);
  EXPECT_THROW(tio::readRaster(dir_ / "absent.tif"), InputError);
}

TEST_F(GeoTiffTest, GdalCommandLineToolsReadTheFile) {
  if (!haveGdalTools()) GTEST_SKIP() << "gdal-bin (gdalinfo, gdallocationinfo) is not installed";
  const fs::path p = dir_ / "tools.tif";
  tio::writeGeoTiff(smallMap(), {"elevation", "count"}, p);
  // gdalinfo -json tries to compute a WGS84 extent, which a local engineering CRS cannot have;
  // PROJ complains on stderr about that (harmless), so stderr is dropped here.
  const auto info = nlohmann::json::parse(run("gdalinfo -json '" + p.string() + "' 2>/dev/null"));
  EXPECT_EQ(info["size"], nlohmann::json::array({3, 4}));
  const auto gt = info["geoTransform"];
  EXPECT_DOUBLE_EQ(gt[0].get<double>(), 9.25);
  EXPECT_DOUBLE_EQ(gt[3].get<double>(), 21.0);
  EXPECT_DOUBLE_EQ(gt[5].get<double>(), -0.5);
  const auto& b1 = info["bands"][0];
  EXPECT_EQ(b1["description"], "elevation");
  EXPECT_EQ(b1["type"], "Float32");
  EXPECT_EQ(b1["noDataValue"], "NaN");
  EXPECT_EQ(b1["unit"], "m");
  EXPECT_EQ(info["bands"][1]["description"], "count");
  const std::string wkt = info["coordinateSystem"]["wkt"].get<std::string>();
  EXPECT_NE(wkt.find("terramap map frame"), std::string::npos) << wkt;
  // gdallocationinfo takes pixel (column, row): column 0 row 0 is the north-west cell (2, 0).
  auto val = [&](int band, int col, int row) {
    return run("gdallocationinfo -valonly -b " + std::to_string(band) + " '" + p.string() + "' " +
               std::to_string(col) + " " + std::to_string(row));
  };
  EXPECT_EQ(val(1, 0, 0), "20.25\n");
  EXPECT_EQ(val(1, 2, 0), "0.25\n");
  EXPECT_EQ(val(1, 1, 2), "nan\n");
  EXPECT_EQ(val(2, 2, 3), "7\n");
  // Geo-referenced query: the centre of cell (0, 3) is x = 10.5, y = 19.25.
  EXPECT_EQ(run("gdallocationinfo -valonly -geoloc -b 2 '" + p.string() + "' 10.5 19.25"), "7\n");
}

}  // namespace
