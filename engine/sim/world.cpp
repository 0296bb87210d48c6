// Truth world construction: terrain surface and soil field.
#include <terramap/core/error.hpp>
#include <terramap/sim/dem.hpp>
#include <terramap/sim/world.hpp>

#include <memory>

#include <cmath>

namespace terramap::sim {

double analyticSurfaceAt(const TerrainSpec& spec, double x, double y) {
  double h = spec.base_height_m + spec.slope_x * (x - spec.origin_x_m) + spec.slope_y * (y - spec.origin_y_m);
  for (const GaussianBump& b : spec.bumps) {
    const double dx = x - b.x_m, dy = y - b.y_m;
    const double r2 = (dx * dx + dy * dy) / (b.sigma_m * b.sigma_m);
    if (r2 < 60.0) h += b.amplitude_m * std::exp(-0.5 * r2);  // exp(-30) ~ 1e-13: negligible beyond
  }
  return h;
}

TruthTerrain buildTerrain(const TerrainSpec& spec) {
  const int nx = static_cast<int>(std::llround(spec.size_x_m / spec.resolution_m)) + 1;
  const int ny = static_cast<int>(std::llround(spec.size_y_m / spec.resolution_m)) + 1;
  TruthTerrain t(spec.origin_x_m, spec.origin_y_m, spec.resolution_m, nx, ny, spec.base_height_m);
  std::shared_ptr<const DemGrid> dem = spec.dem_grid;
  const bool have_dem = !spec.dem.path.empty();
  if (have_dem && !dem) dem = std::make_shared<const DemGrid>(loadDem(spec.dem));
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      const Eigen::Vector2d p = t.nodePosition(i, j);
      double h = analyticSurfaceAt(spec, p.x(), p.y());
      if (have_dem) {
        const double z = dem->heightAt(p.x(), p.y());
        if (std::isnan(z))
          throw InputError(spec.dem.path + ": DEM has no data at terrain node (" + std::to_string(p.x()) + ", " +
                           std::to_string(p.y()) + ") (map frame; outside the DEM or next to a no-data cell: "
                           "choose terrain.size_m/origin_m inside it or set dem.fill_holes)");
        h += z;
      }
      t.setUndisturbed(i, j, h);
    }
  }
  t.captureInitial();
  t.refreshPyramid();
  return t;
}

bool pointInPolygon(const std::vector<Eigen::Vector2d>& poly, const Eigen::Vector2d& p) {
  bool in = false;
  const std::size_t n = poly.size();
  for (std::size_t a = 0, b = n - 1; a < n; b = a++) {
    const Eigen::Vector2d& A = poly[a];
    const Eigen::Vector2d& B = poly[b];
    if ((A.y() > p.y()) != (B.y() > p.y())) {
      const double x = A.x() + (p.y() - A.y()) * (B.x() - A.x()) / (B.y() - A.y());
      if (p.x() < x) in = !in;
    }
  }
  return in;
}

SoilField::SoilField(const SoilProperties& default_soil, std::vector<SoilZone> zones)
    : default_(default_soil), zones_(std::move(zones)) {}

int SoilField::zoneAt(double x, double y, double depth_m) const {
  const double d = std::max(0.0, depth_m);
  for (int k = static_cast<int>(zones_.size()) - 1; k >= 0; --k) {
    const SoilZone& z = zones_[k];
    if (d < z.depthMinAt(x, y) || d > z.depthMaxAt(x, y)) continue;
    bool inside = true;
    switch (z.region) {
      case SoilZone::Region::Everywhere: break;
      case SoilZone::Region::StripX: inside = x >= z.lo_m && x <= z.hi_m; break;
      case SoilZone::Region::StripY: inside = y >= z.lo_m && y <= z.hi_m; break;
      case SoilZone::Region::Polygon: inside = pointInPolygon(z.polygon, {x, y}); break;
    }
    if (inside) return k;
  }
  return -1;
}

const SoilProperties& SoilField::at(double x, double y, double depth_m) const {
  const int k = zoneAt(x, y, depth_m);
  return k < 0 ? default_ : zones_[k].soil;
}

}  // namespace terramap::sim
