#pragma once
/// \file
/// The truth section of `terramap run`'s report: the finished map's elevation against the
/// source's truth (the simulator's surface at the cell centres, Source::truth).
#include <terramap/core/layered_map.hpp>
#include <terramap/pipeline/run.hpp>
#include <terramap/pipeline/source.hpp>

namespace terramap::eval {

/// When the map has `elevation` (and no `truth_elevation` yet) and the source knows the truth
/// of `elevation`, adds the layers `truth_elevation` (m, NaN where the truth is unknown) and
/// `elevation_error` (map - truth, m, NaN where either is unknown) and returns, as JSON:
/// layer, cells_with_truth, cells_compared (both known), coverage (compared / with truth),
/// rmse_m, bias_m (mean error), median_m (median error), median_abs_m, median_abs_about_median_m
/// (median |e - median e|: the error once one offset of the whole map is taken out), p95_abs_m,
/// max_abs_m (statistics.hpp; 0 when nothing was compared),
/// and the same as a one-line caption for the two layers' pictures.
/// Otherwise returns an empty comparison and leaves the map alone. Fits
/// RunOptions::compare_truth. \throws LayerError only if the map changes under it.
TERRAMAP_API TruthComparison compareWithSourceTruth(LayeredMap& map, const Source& source);

/// The same statistics as compareWithSourceTruth's JSON, of the map as it is now, without
/// touching it (no layers added): what `terramap run` records once per `outputs.series_interval_s`
/// (RunOptions::truth_stats). Empty when the map has no `elevation` or the source no truth of it.
/// Engine thread (reads the map), between events. \throws nothing of its own.
TERRAMAP_API std::string truthStatsJson(const LayeredMap& map, const Source& source);

}  // namespace terramap::eval
