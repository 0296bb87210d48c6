#pragma once
/// \file
/// The site survey a scenario may start with (`survey:`, SurveySpec in scenario.hpp): points on
/// the initial truth surface, delivered as ordinary PointClouds so any fusion stage maps them
/// like a sensor's. Pure function of (scenario, terrain): the same bits for any thread count.
#include <terramap/core/events.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/truth_terrain.hpp>

#include <vector>

namespace terramap::sim {

/// The survey clouds of `sc.survey` over `terrain`'s initial surface (empty when the survey is
/// off). One cloud per `block_m` square of the terrain extent holding at least one point,
/// frame "survey", stamp `stamp` (s), sensor `height_m` above the square's highest point with
/// the map's orientation; points in that sensor frame (m), intensity 1. A point lies at a
/// uniformly jittered position inside its `spacing_m` square, at the initial height there plus
/// N(0, sigma_m²); squares whose centre is off the terrain are skipped. Row-major in x then y.
std::vector<PointCloud> surveyClouds(const Scenario& sc, const TruthTerrain& terrain, double stamp);

}  // namespace terramap::sim
