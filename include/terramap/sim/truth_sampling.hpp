#pragma once
/// \file
/// The simulator's truth on a map's grid: what an evaluation compares a map with, and what
/// the `sim` pipeline source hands the runner (Source::truth).
/// Units: metres, map frame (z up). Pure functions of the terrain: safe from any thread that
/// does not mutate it at the same time.
#include <terramap/core/geometry.hpp>
#include <terramap/sim/truth_terrain.hpp>

#include <Eigen/Core>

namespace terramap::sim {

/// Which truth surface truthOnGeometry samples.
enum class TruthSurface {
  Current,  ///< H = U + Lv now (bank plus loose as it lies): what a height map should show
  Initial,  ///< the surface at t = 0 (stored by the truth as float)
  Bank,     ///< U + Lc now: the bank-equivalent column (soil mass per area / bank density)
  Undisturbed,  ///< U now: the bank surface, which a blade, a bucket or a track's rut lowers
  Carved,  ///< U + what the tracks pressed out of it: the bank surface as only the tools left it
};

/// The truth surface sampled at the centres of the cells of `geometry`, bilinearly between
/// the truth's nodes (TruthTerrain::heightAt and friends), as a size.x() x size.y() matrix in
/// the geometry's logical order (row i, column j: what LayeredMap::fromMatrix takes). A point
/// sample, not a cell average: the map is initialised with the same samples, so the initial
/// error is exactly zero. NaN where the cell centre lies outside the truth grid.
Eigen::MatrixXf truthOnGeometry(const TruthTerrain& truth, const Geometry& geometry,
                                TruthSurface surface = TruthSurface::Current);
/// Same in double precision (mass sums).
Eigen::MatrixXd truthOnGeometryD(const TruthTerrain& truth, const Geometry& geometry,
                                 TruthSurface surface = TruthSurface::Current);

/// The largest map at `resolution_m` whose cell centres all lie inside the truth grid,
/// centred on it. \throws ConfigError if the resolution is not positive or finite, the truth
/// is smaller than one cell, or the map would exceed `max_cells` (name both sizes).
Geometry fitGeometry(const TruthTerrain& truth, double resolution_m, long max_cells = 40'000'000);

}  // namespace terramap::sim
