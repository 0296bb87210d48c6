// DEM inputs of the truth terrain: ESRI ASCII, GeoTIFF (GDAL via terramap_io), LAS ground points.
#include <terramap/core/error.hpp>
#include <terramap/core/memory_budget.hpp>
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
  for (std::size_t k = 0; k < cloud.size(); ++k) {
    if (cloud.classification[k] != spec.ground_class) continue;
    // A header scale or offset near the double range makes int x scale + offset overflow.
    if (!cloud.positions[k].allFinite())
      throw InputError(spec.path + ": ground point " + std::to_string(k) + " has a non-finite coordinate (" +
                       fmtNum(cloud.positions[k].x()) + ", " + fmtNum(cloud.positions[k].y()) + ", " +
                       fmtNum(cloud.positions[k].z()) + "): the header's scale or offset overflows");
    ground.push_back(cloud.positions[k] - origin);
  }
  if (ground.empty())
    throw InputError(spec.path + ": no points of class " + std::to_string(spec.ground_class) + " (ground) among " +
                     std::to_string(cloud.size()) + " points; set dem.ground_class");
  double xmin = INFINITY, xmax = -INFINITY, ymin = INFINITY, ymax = -INFINITY;
  for (const auto& p : ground) {
    xmin = std::min(xmin, p.x()); xmax = std::max(xmax, p.x());
    ymin = std::min(ymin, p.y()); ymax = std::max(ymax, p.y());
  }
  // Cell centres on multiples of cell_m in the map frame; at least 2 x 2 cells. Sized in double
  // first: converting a cell index beyond the range of long is undefined.
  const double c = spec.cell_m;
  const double fi0 = std::floor(xmin / c + 0.5), fi1 = std::floor(xmax / c + 0.5);
  const double fj0 = std::floor(ymin / c + 0.5), fj1 = std::floor(ymax / c + 0.5);
  const double fnx = std::max(2.0, fi1 - fi0 + 1), fny = std::max(2.0, fj1 - fj0 + 1);
  if (!(fnx * fny <= 2e8) || !(std::max({std::abs(fi0), std::abs(fi1), std::abs(fj0), std::abs(fj1)}) < 1e15))
    throw InputError(spec.path + ": gridding the ground points at cell_m " + fmtNum(c) + " m gives " + fmtNum(fnx) +
                     " x " + fmtNum(fny) + " cells; use a larger dem.cell_m");
  const long i0 = static_cast<long>(fi0), j0 = static_cast<long>(fj0);
  const long nx = static_cast<long>(fnx), ny = static_cast<long>(fny);
  // The grid (8 bytes a cell) and the sorted (cell, z) pairs (16 bytes a ground point).
  requireInputBudget(saturatingProduct({static_cast<std::uint64_t>(nx), static_cast<std::uint64_t>(ny), 8}) +
                         saturatingProduct({ground.size(), 16}),
                     spec.path + ": the ground points gridded at cell_m " + fmtNum(c) + " m (" + std::to_string(nx) +
                         " x " + std::to_string(ny) + " cells, " + std::to_string(ground.size()) + " points)",
                     "8 bytes per cell, 16 per point");
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
  if (holes == 0) return 0;
  // Per cell: the previous pass, and the weight and weighted sum being gathered.
  requireInputBudget(saturatingProduct({grid.z.size(), 3 * sizeof(double)}),
                     what + ": filling the holes of a " + std::to_string(nx) + " x " + std::to_string(ny) + " grid",
                     "3 doubles per cell");
  static const int kDir[8][2] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}, {1, 1}, {1, -1}, {-1, 1}, {-1, -1}};
  std::vector<double> sw(grid.z.size()), sz(grid.z.size());
  auto index = [nx](long i, long j) { return static_cast<std::size_t>(j) * static_cast<std::size_t>(nx) + static_cast<std::size_t>(i); };
  while (holes > 0) {
    const std::vector<double> prev = grid.z;  // each pass reads only the previous pass
    std::fill(sw.begin(), sw.end(), 0.0);
    std::fill(sz.begin(), sz.end(), 0.0);
    // Direction by direction, each grid line walked once against the direction, carrying the
    // first data cell ahead: linear in the cells per direction, where searching from every hole
    // was cells x line length (hours on a sparse grid of 10^7 cells). The weights are added to
    // each hole in the order of kDir, as before, so the sums are bit for bit the same.
    for (const auto& d : kDir) {
      for (int j0 = 0; j0 < ny; ++j0) {
        for (int i0 = 0; i0 < nx; ++i0) {
          const long ia = i0 + d[0], ja = j0 + d[1];
          if (ia >= 0 && ja >= 0 && ia < nx && ja < ny) continue;  // not the last cell of its line
          double ahead = 0;
          long steps = 0;  // 0: no data cell ahead yet
          for (long i = i0, j = j0; i >= 0 && j >= 0 && i < nx && j < ny; i -= d[0], j -= d[1]) {
            const std::size_t k = index(i, j);
            if (steps > 0 && std::isnan(prev[k])) {
              const double dist2 = static_cast<double>(steps) * steps * (d[0] != 0 && d[1] != 0 ? 2.0 : 1.0);
              sw[k] += 1.0 / dist2;
              sz[k] += ahead / dist2;
            }
            if (!std::isnan(prev[k])) {
              ahead = prev[k];
              steps = 1;
            } else if (steps > 0) {
              ++steps;
            }
          }
        }
      }
    }
    std::size_t now = 0;
    for (std::size_t k = 0; k < grid.z.size(); ++k) {
      if (std::isnan(prev[k]) && sw[k] > 0) {
        grid.z[k] = sz[k] / sw[k];
        ++now;
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
