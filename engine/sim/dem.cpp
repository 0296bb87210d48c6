// DEM inputs of the truth terrain: ESRI ASCII, GeoTIFF (GDAL via terramap_io), LAS ground points.
#include <terramap/core/error.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/io/readers.hpp>
#include <terramap/sim/dem.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

namespace terramap::sim {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string fmtNum(double v) {
  char b[64];
  std::snprintf(b, sizeof b, "%.10g", v);
  return b;
}

DemGrid loadLas(const DemSpec& spec, Eigen::Vector3d& origin) {
  io::LasReadOptions opt;
  opt.keep_double_positions = true;  // exact coordinates whatever origin we pick
  opt.origin_mode = io::LasOriginMode::Zero;
  const io::LasCloud cloud = io::readLas(spec.path, opt);
  if (spec.origin_mode == GeoOriginMode::Auto) {
    const Eigen::Vector3d c = 0.5 * (cloud.header.min + cloud.header.max);
    origin = Eigen::Vector3d(std::round(c.x()), std::round(c.y()), std::round(c.z()));
  } else {
    origin = spec.geo_origin;
  }
  std::vector<Eigen::Vector3d> ground;
  for (std::size_t k = 0; k < cloud.size(); ++k)
    if (cloud.classification[k] == spec.ground_class) ground.push_back(cloud.positions[k] - origin);
  if (ground.empty())
    throw InputError(spec.path + ": no points of class " + std::to_string(spec.ground_class) + " (ground) among " +
                     std::to_string(cloud.size()) + " points; set dem.ground_class");
  double xmin = INFINITY, xmax = -INFINITY, ymin = INFINITY, ymax = -INFINITY;
  for (const auto& p : ground) {
    xmin = std::min(xmin, p.x()); xmax = std::max(xmax, p.x());
    ymin = std::min(ymin, p.y()); ymax = std::max(ymax, p.y());
  }
  // Cell centres on multiples of cell_m in the map frame; at least 2 x 2 cells.
  const double c = spec.cell_m;
  const long i0 = static_cast<long>(std::floor(xmin / c + 0.5)), i1 = static_cast<long>(std::floor(xmax / c + 0.5));
  const long j0 = static_cast<long>(std::floor(ymin / c + 0.5)), j1 = static_cast<long>(std::floor(ymax / c + 0.5));
  const long nx = std::max(2L, i1 - i0 + 1), ny = std::max(2L, j1 - j0 + 1);
  if (static_cast<double>(nx) * ny > 2e8)
    throw InputError(spec.path + ": gridding the ground points at cell_m " + fmtNum(c) + " m gives " + std::to_string(nx) +
                     " x " + std::to_string(ny) + " cells; use a larger dem.cell_m");
  DemGrid g = gridPoints(ground, i0 * c, j0 * c, c, static_cast<int>(nx), static_cast<int>(ny), spec.statistic);
  if (spec.fill_holes.value_or(true)) fillDemHoles(g, spec.path + ": ground points");
  return g;
}

DemGrid loadGeoTiff(const DemSpec& spec, Eigen::Vector3d& origin) {
  const io::Raster r = io::readRaster(spec.path);  // InputError with GDAL's message
  if (!r.geotransform) throw InputError(spec.path + ": raster has no geotransform (cannot place it in the map)");
  const auto& gt = *r.geotransform;
  if (gt[2] != 0.0 || gt[4] != 0.0)
    throw InputError(spec.path + ": rotated rasters are not supported (geotransform terms " + fmtNum(gt[2]) + ", " +
                     fmtNum(gt[4]) + ")");
  if (!(gt[1] > 0) || !(gt[5] < 0) || std::abs(gt[1] + gt[5]) > 1e-9 * gt[1])
    throw InputError(spec.path + ": raster must be north-up with square cells (pixel size " + fmtNum(gt[1]) + " x " +
                     fmtNum(gt[5]) + ")");
  if (r.width < 2 || r.height < 2)
    throw InputError(spec.path + ": raster must be at least 2 x 2 cells (is " + std::to_string(r.width) + " x " +
                     std::to_string(r.height) + ")");
  const io::RasterBand* band = nullptr;
  if (!spec.band_name.empty()) {
    std::string names;
    for (const auto& b : r.bands) {
      if (b.description == spec.band_name) band = &b;
      names += (names.empty() ? "" : ", ") + ("'" + b.description + "'");
    }
    if (!band) throw InputError(spec.path + ": no band named '" + spec.band_name + "' (bands: " + names + ")");
  } else {
    if (spec.band < 1 || spec.band > static_cast<int>(r.bands.size()))
      throw InputError(spec.path + ": band " + std::to_string(spec.band) + " out of range (the raster has " +
                       std::to_string(r.bands.size()) + ")");
    band = &r.bands[spec.band - 1];
  }
  const double cell = gt[1];
  const int W = r.width, H = r.height;
  // Cell centres in world coordinates; DemGrid row 0 is the southern (last raster) row.
  const double wx0 = gt[0] + 0.5 * cell, wy0 = gt[3] + (H - 0.5) * gt[5];
  auto isData = [&](float v) {
    if (std::isnan(v)) return false;
    if (band->nodata && !std::isnan(*band->nodata) && static_cast<double>(v) == static_cast<double>(static_cast<float>(*band->nodata)))
      return false;
    return true;
  };
  if (spec.origin_mode == GeoOriginMode::Auto) {
    if (r.crs_projected && r.epsg != 0) {
      double zmin = INFINITY, zmax = -INFINITY;
      for (int row = 0; row < H; ++row)
        for (int col = 0; col < W; ++col) {
          const float v = band->values(row, col);
          if (isData(v)) { zmin = std::min(zmin, double(v)); zmax = std::max(zmax, double(v)); }
        }
      const double cx = gt[0] + 0.5 * W * cell, cy = gt[3] + 0.5 * H * gt[5];
      origin = Eigen::Vector3d(std::round(cx), std::round(cy), zmin <= zmax ? std::round(0.5 * (zmin + zmax)) : 0.0);
    } else {
      origin = Eigen::Vector3d::Zero();
    }
  } else {
    origin = spec.geo_origin;
  }
  DemGrid g;
  g.nx = W;
  g.ny = H;
  g.cell_m = cell;
  g.x0_m = wx0 - origin.x();
  g.y0_m = wy0 - origin.y();
  g.z.assign(static_cast<std::size_t>(W) * H, kNaN);
  for (int row = 0; row < H; ++row) {
    const int j = H - 1 - row;
    for (int col = 0; col < W; ++col) {
      const float v = band->values(row, col);
      if (isData(v)) g.z[static_cast<std::size_t>(j) * W + col] = static_cast<double>(v) - origin.z();
    }
  }
  if (spec.fill_holes.value_or(false)) fillDemHoles(g, spec.path + ": raster");
  return g;
}

}  // namespace

DemGrid gridPoints(const std::vector<Eigen::Vector3d>& points, double x0, double y0, double cell_m, int nx, int ny,
                   DemStatistic statistic) {
  DemGrid g;
  g.x0_m = x0;
  g.y0_m = y0;
  g.cell_m = cell_m;
  g.nx = nx;
  g.ny = ny;
  g.z.assign(static_cast<std::size_t>(nx) * ny, kNaN);
  // (cell, z) pairs sorted by cell then z: every cell's values are contiguous and ordered.
  std::vector<std::pair<std::size_t, double>> kz;
  kz.reserve(points.size());
  for (const Eigen::Vector3d& p : points) {
    const double fi = std::floor((p.x() - x0) / cell_m + 0.5), fj = std::floor((p.y() - y0) / cell_m + 0.5);
    if (!(fi >= 0 && fj >= 0 && fi < nx && fj < ny) || !std::isfinite(p.z())) continue;
    kz.emplace_back(static_cast<std::size_t>(fj) * nx + static_cast<std::size_t>(fi), p.z());
  }
  std::sort(kz.begin(), kz.end());
  for (std::size_t a = 0; a < kz.size();) {
    std::size_t b = a;
    while (b < kz.size() && kz[b].first == kz[a].first) ++b;
    const std::size_t n = b - a;
    double v;
    if (statistic == DemStatistic::Median) {
      v = (n % 2 == 1) ? kz[a + n / 2].second : 0.5 * (kz[a + n / 2 - 1].second + kz[a + n / 2].second);
    } else {
      double s = 0;
      for (std::size_t k = a; k < b; ++k) s += kz[k].second;
      v = s / static_cast<double>(n);
    }
    g.z[kz[a].first] = v;
    a = b;
  }
  return g;
}

std::size_t fillDemHoles(DemGrid& grid, const std::string& what) {
  const int nx = grid.nx, ny = grid.ny;
  std::size_t filled = 0, holes = 0;
  for (double v : grid.z) holes += std::isnan(v) ? 1 : 0;
  if (holes == grid.z.size()) throw InputError(what + ": no cell has data, nothing to interpolate from");
  static const int kDir[8][2] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}, {1, 1}, {1, -1}, {-1, 1}, {-1, -1}};
  while (holes > 0) {
    const std::vector<double> prev = grid.z;  // each pass reads only the previous pass
    std::size_t now = 0;
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        const std::size_t k = static_cast<std::size_t>(j) * nx + i;
        if (!std::isnan(prev[k])) continue;
        double sw = 0, sz = 0;
        for (const auto& d : kDir) {
          int a = i + d[0], b = j + d[1], steps = 1;
          while (a >= 0 && b >= 0 && a < nx && b < ny) {
            const double v = prev[static_cast<std::size_t>(b) * nx + a];
            if (!std::isnan(v)) {
              const double dist2 = static_cast<double>(steps) * steps * (d[0] != 0 && d[1] != 0 ? 2.0 : 1.0);
              sw += 1.0 / dist2;
              sz += v / dist2;
              break;
            }
            a += d[0]; b += d[1]; ++steps;
          }
        }
        if (sw > 0) {
          grid.z[k] = sz / sw;
          ++now;
        }
      }
    }
    if (now == 0) throw InputError(what + ": holes cannot be filled (no data cell reachable)");  // not reachable
    filled += now;
    holes -= now;
  }
  return filled;
}

DemGrid loadDem(const DemSpec& spec, Eigen::Vector3d* resolved_origin) {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  DemGrid g;
  switch (spec.format) {
    case DemFormat::EsriAscii: {
      g = readEsriAscii(spec.path);
      origin = spec.origin_mode == GeoOriginMode::Explicit ? spec.geo_origin : Eigen::Vector3d::Zero();
      g.x0_m -= origin.x();
      g.y0_m -= origin.y();
      for (double& z : g.z) z -= origin.z();
      if (spec.fill_holes.value_or(false)) fillDemHoles(g, spec.path + ": grid");
      break;
    }
    case DemFormat::GeoTiff: g = loadGeoTiff(spec, origin); break;
    case DemFormat::Las: g = loadLas(spec, origin); break;
  }
  if (resolved_origin) *resolved_origin = origin;
  return g;
}

}  // namespace terramap::sim
