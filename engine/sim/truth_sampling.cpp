#include <terramap/sim/truth_sampling.hpp>

#include <terramap/core/error.hpp>

#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

namespace terramap::sim {

namespace {

double sampleTruth(const TruthTerrain& t, double x, double y, TruthSurface s) {
  switch (s) {
    case TruthSurface::Current: return t.heightAt(x, y);
    case TruthSurface::Initial: return t.initialHeightAt(x, y);
    case TruthSurface::Bank: return t.undisturbedAt(x, y) + t.looseBankAt(x, y);
    case TruthSurface::Undisturbed: return t.undisturbedAt(x, y);
    case TruthSurface::Carved: return t.undisturbedAt(x, y) + t.pressedAt(x, y);
  }
  return std::numeric_limits<double>::quiet_NaN();
}

}  // namespace

Eigen::MatrixXd truthOnGeometryD(const TruthTerrain& truth, const Geometry& geometry, TruthSurface surface) {
  Eigen::MatrixXd m(geometry.size().x(), geometry.size().y());
  for (int i = 0; i < geometry.size().x(); ++i)
    for (int j = 0; j < geometry.size().y(); ++j) {
      const Position p = geometry.positionOf(Index(i, j));
      m(i, j) = sampleTruth(truth, p.x(), p.y(), surface);
    }
  return m;
}

Eigen::MatrixXf truthOnGeometry(const TruthTerrain& truth, const Geometry& geometry, TruthSurface surface) {
  return truthOnGeometryD(truth, geometry, surface).cast<float>();
}

Geometry fitGeometry(const TruthTerrain& truth, double resolution_m, long max_cells) {
  if (!(resolution_m > 0) || !std::isfinite(resolution_m))
    throw ConfigError("map resolution must be positive and finite, got " + std::to_string(resolution_m));
  const double ex = truth.maxX() - truth.originX(), ey = truth.maxY() - truth.originY();
  // A small tolerance so an extent that is a whole number of cells is not lost to rounding.
  const long nx = static_cast<long>(std::floor(ex / resolution_m + 1e-9));
  const long ny = static_cast<long>(std::floor(ey / resolution_m + 1e-9));
  char b[256];
  if (nx < 1 || ny < 1) {
    std::snprintf(b, sizeof b, "truth terrain %.3f x %.3f m is smaller than one %.3f m map cell", ex, ey, resolution_m);
    throw ConfigError(b);
  }
  if (nx * ny > max_cells) {
    std::snprintf(b, sizeof b,
                  "a map covering the truth terrain (%.1f x %.1f m) at %.3f m needs %ld x %ld cells, more than %ld: "
                  "give a pipeline with a smaller map (--pipeline, without --fit-map)",
                  ex, ey, resolution_m, nx, ny, max_cells);
    throw ConfigError(b);
  }
  const Position c(0.5 * (truth.originX() + truth.maxX()), 0.5 * (truth.originY() + truth.maxY()));
  return Geometry(resolution_m, Size(static_cast<int>(nx), static_cast<int>(ny)), c);
}

}  // namespace terramap::sim
