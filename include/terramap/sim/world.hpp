#pragma once
/// \file
/// Building the truth world from a scenario: the terrain surface and the soil field.
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/truth_terrain.hpp>

namespace terramap::sim {

/// The terrain's analytic surface at map (x, y), m: base + plane + Gaussian bumps, without the
/// DEM (the part of buildTerrain's nodes a scenario defines in closed form). Thread-safe.
double analyticSurfaceAt(const TerrainSpec& spec, double x, double y);

/// Builds the truth terrain of a scenario: base + plane + Gaussian bumps (+ DEM if given),
/// sampled at every node; calls captureInitial() and refreshPyramid().
/// \throws InputError if the DEM does not cover a node of the grid (names the file and node).
TruthTerrain buildTerrain(const TerrainSpec& spec);

/// Truth soil as a function of position and depth below the initial surface. Zones are tested
/// from the last to the first (later zones override earlier ones); none matching gives the
/// default soil. Thread-safe (immutable after construction).
class SoilField {
 public:
  SoilField(const SoilProperties& default_soil, std::vector<SoilZone> zones);
  /// Soil at map (x, y) and `depth_m` below the initial surface (negative depths clamp to 0).
  const SoilProperties& at(double x, double y, double depth_m) const;
  /// Index of the zone that applies (-1 = default soil).
  int zoneAt(double x, double y, double depth_m) const;
  const std::vector<SoilZone>& zones() const { return zones_; }
  const SoilProperties& defaultSoil() const { return default_; }

 private:
  SoilProperties default_;
  std::vector<SoilZone> zones_;
};

/// Point-in-polygon (crossing number; points on an edge count as inside for one side only).
bool pointInPolygon(const std::vector<Eigen::Vector2d>& poly, const Eigen::Vector2d& p);

}  // namespace terramap::sim
