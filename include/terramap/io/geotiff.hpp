#pragma once
/// \file
/// GeoTIFF export of map layers (GDAL), and a small GDAL-backed raster reader.
///
/// ## Orientation: map frame -> north-up raster
/// The map frame is placed on the ground with **x = easting offset** and **y = northing
/// offset** (both metres; map frame right-handed, z up, so this is an ENU placement):
///   easting  = origin_easting  + x
///   northing = origin_northing + y
/// A GeoTIFF is north-up: raster row 0 is the *top* (largest northing = largest y) and raster
/// column 0 is the *left* (smallest easting = smallest x). LayeredMap's logical index (i, j)
/// grows towards -x and -y (geometry.hpp), so the raster is a transposition plus a flip:
///   raster width  = rows R of the map (size.x),  raster height = columns C (size.y)
///   raster (row r, col c)  <->  logical (i = R - 1 - c, j = r)
/// and the geotransform (pixel corner convention) is
///   [E0 + x_min, res, 0, N0 + y_max, 0, -res],  x_min = cx - R*res/2, y_max = cy + C*res/2.
/// The PNG renderer (render.hpp) uses the same orientation, so images and GeoTIFFs overlay.
///
/// ## CRS
/// Without an EPSG code the file carries a local engineering CRS in metres (WKT1 LOCAL_CS,
/// "terramap map frame", axes Easting/Northing), so GIS tools measure distances correctly but
/// do not pretend to know where on Earth the map is. With an EPSG code (a projected CRS whose
/// axes are metres, e.g. UTM 32632) and the origin, the raster lands at its true place.
///
/// ## Values
/// One Float32 band per chosen layer, in the order given; band description = layer name,
/// band unit type and metadata item "unit" = layer unit, metadata "fill" = layer fill.
/// Cell values are written bit for bit (NaN stays NaN = unknown; nodata is NaN). DEFLATE with
/// the floating-point predictor, tiled 256x256 when larger than one tile.
///
/// Threading: exports read the map through const accessors; do not mutate the map while
/// exporting (export `map.snapshot()` instead). Concurrent exports on different threads are
/// fine (GDAL error handlers and options are set per thread).
#include <terramap/core/layered_map.hpp>

#include <Eigen/Core>

#include <array>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace terramap::io {

/// Where the map frame sits on Earth.
struct GeoReference {
  /// 0 = local metric CRS (the default); otherwise an EPSG code of a projected CRS in metres.
  int epsg = 0;
  double origin_easting = 0.0;   ///< easting of map-frame position (x, y) = (0, 0), metres
  double origin_northing = 0.0;  ///< northing of map-frame position (0, 0), metres
};

struct GeoTiffOptions {
  GeoReference georef;
  bool compress = true;  ///< DEFLATE + floating-point predictor (lossless)
  /// Layer name -> one line of meaning (LayerSpec::doc), written as the band's "doc" metadata
  /// item; layers not listed (or with an empty doc) get none.
  std::map<std::string, std::string> layer_docs;
};

/// Row-major float raster (height x width), the storage order of GeoTIFF and PNG.
using RasterF = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// Layer `id` in north-up raster order: rows = map columns C (north first), columns = map rows
/// R (west first); see the file comment. Bits are copied, not converted.
/// \throws LayerError on a bad id.
RasterF northUpRaster(const LayeredMap& map, LayerId id);

/// Raster pixel (row, col) that shows logical cell `logical` in a north-up export, and back.
Eigen::Array2i rasterPixelOf(const Geometry& g, const Index& logical);
Index logicalIndexOfPixel(const Geometry& g, int row, int col);

/// GDAL geotransform of a north-up export (see the file comment).
std::array<double, 6> northUpGeoTransform(const Geometry& g, const GeoReference& georef = {});

/// Writes `layers` (names, at least one, no duplicates) of `map` to a GeoTIFF at `path`,
/// atomically (temp file + rename).
/// \throws LayerError for an unknown layer (with did-you-mean); ConfigError for an empty or
///   duplicated layer list, an EPSG code GDAL does not know, a CRS that is not projected in
///   metres, or a non-finite origin; OutputError if GDAL or the file system fails (GDAL's
///   message and the path included).
void writeGeoTiff(const LayeredMap& map, const std::vector<std::string>& layers,
                  const std::filesystem::path& path, const GeoTiffOptions& options = {});

/// One band of a raster read by readRaster.
struct RasterBand {
  std::string description;          ///< GDAL band description (terramap: the layer name)
  std::string unit;                 ///< GDAL unit type ("" if none)
  std::optional<double> nodata;     ///< nodata value if the file declares one (may be NaN)
  std::vector<std::string> metadata;  ///< "KEY=VALUE" items of the default domain
  RasterF values;                   ///< converted to float32, height x width
};

/// Any GDAL-readable raster (GeoTIFF, PNG, ...), for tests and tools that check an export.
struct Raster {
  std::string driver;               ///< GDAL driver short name, e.g. "GTiff", "PNG"
  int width = 0, height = 0;
  std::optional<std::array<double, 6>> geotransform;  ///< absent if the file has none
  std::string crs_wkt;              ///< WKT1 of the CRS, "" if none
  bool crs_local = false;           ///< a LOCAL_CS / engineering CRS
  bool crs_projected = false;
  int epsg = 0;                     ///< authority code of a projected CRS, 0 if none
  double crs_linear_unit_m = 0.0;   ///< metres per CRS unit (0 if no CRS)
  std::vector<RasterBand> bands;
};

/// \throws InputError naming the file and GDAL's message if GDAL cannot open or read it.
Raster readRaster(const std::filesystem::path& path);

}  // namespace terramap::io
