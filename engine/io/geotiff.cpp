#include "gdal_support.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>
#include <terramap/io/atomic_file.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/io/geotiff.hpp>

#include <ogr_spatialref.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <memory>
#include <set>

namespace terramap::io {

namespace fs = std::filesystem;

namespace {

// WKT1 LOCAL_CS: an engineering CRS in metres with east/north axes. GeoTIFF stores it as a
// user-defined projected model with this citation; GDAL reads it back as LOCAL_CS.
constexpr const char* kLocalCsWkt =
    "LOCAL_CS[\"terramap map frame\","
    "LOCAL_DATUM[\"terramap local datum\",0],"
    "UNIT[\"metre\",1,AUTHORITY[\"EPSG\",\"9001\"]],"
    "AXIS[\"Easting\",EAST],AXIS[\"Northing\",NORTH]]";

struct DatasetCloser {
  void operator()(GDALDataset* ds) const {
    if (ds) GDALClose(GDALDataset::ToHandle(ds));
  }
};
using DatasetPtr = std::unique_ptr<GDALDataset, DatasetCloser>;

OGRSpatialReference makeCrs(const GeoReference& georef) {
  detail::GdalErrorCapture quiet;  // PROJ's "crs not found" goes into our exception, not stderr
  OGRSpatialReference srs;
  srs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  if (georef.epsg == 0) {
    if (srs.importFromWkt(kLocalCsWkt) != OGRERR_NONE)
      throw InternalError("GDAL refused terramap's built-in LOCAL_CS WKT");
    return srs;
  }
  if (georef.epsg < 0 || srs.importFromEPSG(georef.epsg) != OGRERR_NONE)
    throw ConfigError("unknown EPSG code " + std::to_string(georef.epsg) + " (GDAL/PROJ has no such CRS)");
  if (!srs.IsProjected())
    throw ConfigError("EPSG:" + std::to_string(georef.epsg) +
                      " is not a projected CRS; the map needs one whose axes are metres (e.g. a UTM zone)");
  const char* unit_name = nullptr;
  const double unit = srs.GetLinearUnits(&unit_name);
  if (std::abs(unit - 1.0) > 1e-12)
    throw ConfigError("EPSG:" + std::to_string(georef.epsg) + " measures in '" + (unit_name ? unit_name : "?") +
                      "' (" + formatNumber(unit) + " m), not metres");
  srs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  return srs;
}

}  // namespace

RasterF northUpRaster(const LayeredMap& map, LayerId id) {
  const Eigen::MatrixXf m = map.toMatrix(id);  // R x C, logical order, column-major
  const Eigen::Index R = m.rows(), C = m.cols();
  RasterF out(C, R);
  // Raster row r is logical column j = r read from i = R-1 down to 0 (west to east).
  for (Eigen::Index r = 0; r < C; ++r) std::reverse_copy(m.data() + r * R, m.data() + (r + 1) * R, out.data() + r * R);
  return out;
}

Eigen::Array2i rasterPixelOf(const Geometry& g, const Index& logical) {
  return Eigen::Array2i(logical.y(), g.size().x() - 1 - logical.x());
}

Index logicalIndexOfPixel(const Geometry& g, int row, int col) { return Index(g.size().x() - 1 - col, row); }

std::array<double, 6> northUpGeoTransform(const Geometry& g, const GeoReference& georef) {
  const double res = g.resolution();
  const double x_min = g.center().x() - g.length().x() * 0.5;
  const double y_max = g.center().y() + g.length().y() * 0.5;
  return {georef.origin_easting + x_min, res, 0.0, georef.origin_northing + y_max, 0.0, -res};
}

void writeGeoTiff(const LayeredMap& map, const std::vector<std::string>& layers, const fs::path& path,
                  const GeoTiffOptions& options) {
  if (layers.empty()) throw ConfigError("GeoTIFF export of '" + path.string() + "': no layers chosen");
  std::set<std::string> seen;
  std::vector<LayerId> ids;
  for (const auto& name : layers) {
    if (!seen.insert(name).second)
      throw ConfigError("GeoTIFF export of '" + path.string() + "': layer '" + name + "' is listed twice");
    ids.push_back(map.layerId(name));  // LayerError with did-you-mean
  }
  if (!std::isfinite(options.georef.origin_easting) || !std::isfinite(options.georef.origin_northing))
    throw ConfigError("GeoTIFF export of '" + path.string() + "': the origin easting/northing must be finite");
  detail::ensureGdalRegistered();
  const OGRSpatialReference srs = makeCrs(options.georef);

  const int width = map.geometry().size().x(), height = map.geometry().size().y();
  const auto gt = northUpGeoTransform(map.geometry(), options.georef);

  replaceFileAtomically(path, [&](const fs::path& tmp) {
    detail::ScopedGdalOption no_pam("GDAL_PAM_ENABLED", "NO");
    detail::GdalErrorCapture errors;
    auto fail = [&](const std::string& what) {
      throw OutputError("cannot write GeoTIFF '" + path.string() + "': " + what +
                        (errors.failed() ? " (" + errors.message() + ")" : std::string()));
    };
    GDALDriver* drv = GetGDALDriverManager()->GetDriverByName("GTiff");
    if (!drv) fail("GDAL has no GTiff driver");
    CPLStringList co;
    if (options.compress) {
      co.SetNameValue("COMPRESS", "DEFLATE");
      co.SetNameValue("PREDICTOR", "3");
    }
    if (width > 256 || height > 256) {
      co.SetNameValue("TILED", "YES");
      co.SetNameValue("BLOCKXSIZE", "256");
      co.SetNameValue("BLOCKYSIZE", "256");
    }
    co.SetNameValue("BIGTIFF", "IF_SAFER");
    if (ids.size() > 1) co.SetNameValue("INTERLEAVE", "BAND");
    DatasetPtr ds(drv->Create(tmp.c_str(), width, height, static_cast<int>(ids.size()), GDT_Float32, co.List()));
    if (!ds) fail("GDAL could not create the file");
    double gtv[6];
    std::copy(gt.begin(), gt.end(), gtv);
    if (ds->SetGeoTransform(gtv) != CE_None) fail("cannot set the geotransform");
    if (ds->SetSpatialRef(&srs) != CE_None) fail("cannot set the CRS");
    ds->SetMetadataItem("TIFFTAG_SOFTWARE", "terramap");
    ds->SetMetadataItem("TERRAMAP_RESOLUTION_M", formatNumber(map.geometry().resolution()).c_str());
    ds->SetMetadataItem("TERRAMAP_MAP_CENTER_XY_M",
                        (formatNumber(map.geometry().center().x()) + " " + formatNumber(map.geometry().center().y())).c_str());
    ds->SetMetadataItem("TERRAMAP_AXES", "easting = origin_e + map x, northing = origin_n + map y");
    for (std::size_t b = 0; b < ids.size(); ++b) {
      const LayerInfo& info = map.layerInfo(ids[b]);
      GDALRasterBand* band = ds->GetRasterBand(static_cast<int>(b) + 1);
      band->SetDescription(info.name.c_str());
      band->SetUnitType(info.unit.c_str());
      band->SetMetadataItem("unit", info.unit.c_str());
      band->SetMetadataItem("fill", formatNumber(info.fill).c_str());
      if (auto d = options.layer_docs.find(info.name); d != options.layer_docs.end() && !d->second.empty())
        band->SetMetadataItem("doc", d->second.c_str());
      band->SetNoDataValue(std::numeric_limits<double>::quiet_NaN());
      RasterF data = northUpRaster(map, ids[b]);
      if (band->RasterIO(GF_Write, 0, 0, width, height, data.data(), width, height, GDT_Float32, 0, 0, nullptr) !=
          CE_None)
        fail("writing band " + std::to_string(b + 1) + " ('" + info.name + "') failed");
    }
    // Closing flushes: a full disk shows up here, so check errors after the close.
    GDALDataset* raw = ds.release();
    GDALClose(GDALDataset::ToHandle(raw));
    if (errors.failed()) fail("GDAL reported an error while writing");
  });
}

Raster readRaster(const fs::path& path) {
  detail::ensureGdalRegistered();
  detail::ScopedGdalOption no_pam("GDAL_PAM_ENABLED", "NO");
  detail::GdalErrorCapture errors;
  DatasetPtr ds(GDALDataset::FromHandle(GDALOpen(path.c_str(), GA_ReadOnly)));
  if (!ds)
    throw InputError("cannot open raster '" + path.string() + "'" + (errors.failed() ? ": " + errors.message() : ""));
  Raster out;
  out.driver = ds->GetDriver() ? ds->GetDriver()->GetDescription() : "";
  out.width = ds->GetRasterXSize();
  out.height = ds->GetRasterYSize();
  double gt[6];
  if (ds->GetGeoTransform(gt) == CE_None) {
    std::array<double, 6> a;
    std::copy(gt, gt + 6, a.begin());
    out.geotransform = a;
  }
  if (const OGRSpatialReference* srs = ds->GetSpatialRef()) {
    char* wkt = nullptr;
    if (srs->exportToWkt(&wkt) == OGRERR_NONE && wkt) out.crs_wkt = wkt;
    CPLFree(wkt);
    out.crs_local = srs->IsLocal() != 0;
    out.crs_projected = srs->IsProjected() != 0;
    out.crs_linear_unit_m = srs->GetLinearUnits(static_cast<const char**>(nullptr));
    if (out.crs_projected) {
      const char* code = srs->GetAuthorityCode(nullptr);
      if (code) out.epsg = std::atoi(code);
    }
  }
  // Every band is read whole as float32: refuse a raster whose header asks for more than the
  // budget before GDAL decodes anything (a compressed file can declare any size).
  requireInputBudget(saturatingProduct({static_cast<std::uint64_t>(out.width), static_cast<std::uint64_t>(out.height),
                                        static_cast<std::uint64_t>(std::max(ds->GetRasterCount(), 0)), 4}),
                     "raster '" + path.string() + "': size " + std::to_string(out.width) + " x " +
                         std::to_string(out.height) + ", " + std::to_string(ds->GetRasterCount()) + " bands",
                     "every band read as float32");
  for (int b = 1; b <= ds->GetRasterCount(); ++b) {
    GDALRasterBand* band = ds->GetRasterBand(b);
    RasterBand rb;
    rb.description = band->GetDescription() ? band->GetDescription() : "";
    rb.unit = band->GetUnitType() ? band->GetUnitType() : "";
    int has_nodata = 0;
    const double nd = band->GetNoDataValue(&has_nodata);
    if (has_nodata) rb.nodata = nd;
    if (char** md = band->GetMetadata())
      for (char** it = md; *it; ++it) rb.metadata.emplace_back(*it);
    rb.values.resize(out.height, out.width);
    if (band->RasterIO(GF_Read, 0, 0, out.width, out.height, rb.values.data(), out.width, out.height, GDT_Float32, 0,
                       0, nullptr) != CE_None)
      throw InputError("cannot read band " + std::to_string(b) + " of raster '" + path.string() + "': " +
                       errors.message());
    out.bands.push_back(std::move(rb));
  }
  return out;
}

}  // namespace terramap::io
