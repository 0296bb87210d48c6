#pragma once
/// \file
/// Truth-terrain DEM inputs for the simulator: ESRI ASCII grids, GeoTIFF rasters (through
/// terramap::io::readRaster, i.e. GDAL) and LAS point clouds (ground points, ASPRS class 2,
/// gridded by a per-cell median or mean, holes filled by interpolation).
///
/// Every loader returns a DemGrid in the *map* frame: world coordinates minus a geo origin
/// (DemSpec::geo_origin). Projected coordinates (UTM: eastings ~1e5..1e6 m, northings up to
/// 1e7 m) would waste float precision wherever the simulator or the mapper stores positions or
/// heights in float32, so georeferenced inputs are shifted by default (see GeoOriginMode).
/// The DEM is then resampled bilinearly onto the terrain's node grid (buildTerrain).
#include <terramap/sim/truth_terrain.hpp>

#include <Eigen/Core>
#include <optional>
#include <string>

namespace terramap::sim {

/// Which world point becomes map (0, 0, 0).
enum class GeoOriginMode {
  /// LAS: always the centre of the header bounding box rounded to whole metres (x, y and z),
  /// the same origin terramap::io::readLas picks. GeoTIFF: that rule for the raster's extent
  /// (z: the middle of the finite values) when the raster has a projected CRS with an EPSG
  /// code; (0, 0, 0) for a local or missing CRS (a terramap export is already in map
  /// coordinates). ESRI ASCII (no CRS): (0, 0, 0).
  Auto,
  Explicit,  ///< DemSpec::geo_origin as given
};

enum class DemFormat { EsriAscii, GeoTiff, Las };
enum class DemStatistic { Median, Mean };

struct DemSpec {
  std::string path;  ///< absolute or relative to the working directory (loadScenario resolves)
  DemFormat format = DemFormat::EsriAscii;
  GeoOriginMode origin_mode = GeoOriginMode::Auto;
  Eigen::Vector3d geo_origin = Eigen::Vector3d::Zero();  ///< world (E, N, Z) of map (0, 0, 0), m
  // GeoTIFF
  int band = 1;                 ///< 1-based band number (used when band_name is empty)
  std::string band_name;        ///< band by its description (terramap exports: the layer name)
  // LAS
  double cell_m = 1.0;          ///< gridding cell of the ground points (centres at origin + k cell)
  DemStatistic statistic = DemStatistic::Median;
  int ground_class = 2;         ///< ASPRS class taken as ground
  /// Fill cells without data (no ground point, raster nodata/NaN) by interpolation (see
  /// fillDemHoles). Default on for LAS (sparse by nature), off for rasters (set by the loader
  /// of the scenario: `fill_holes` key).
  std::optional<bool> fill_holes;
};

/// Loads a DEM as described (format-specific rules above), shifted by the (resolved) geo origin.
/// `resolved_origin`, when non-null, receives the origin actually used.
/// \throws InputError naming the file for unreadable or unsuitable input (rotated or non-square
///   raster, missing geotransform, band out of range, no ground points, ...).
DemGrid loadDem(const DemSpec& spec, Eigen::Vector3d* resolved_origin = nullptr);

/// Grids points (map-frame x, y, z) onto cells of size `cell_m` whose centres are at
/// (x0 + i cell_m, y0 + j cell_m), i < nx, j < ny: each cell gets the median (mean of the two
/// middle values for an even count) or the mean of the z of the points nearest to its centre
/// (|x - centre| <= cell/2; a point on a shared border goes to the higher index). Cells
/// without points are NaN. Deterministic (sorted per cell); O(n log n).
DemGrid gridPoints(const std::vector<Eigen::Vector3d>& points, double x0, double y0, double cell_m, int nx,
                   int ny, DemStatistic statistic);

/// Fills NaN cells by interpolation, GDAL FillNodata-style: each hole takes the inverse-
/// distance-squared mean of the first data cell found along each of the 8 grid directions
/// (searched over the whole grid). Holes that see no data cell in any direction are filled in
/// further passes from cells filled before. Deterministic (reads only the previous pass).
/// Returns the number of cells filled. \throws InputError (message `what`) if the grid has no
/// data cell at all.
std::size_t fillDemHoles(DemGrid& grid, const std::string& what);

}  // namespace terramap::sim
