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

/// The soil layers of soil_bayes (`soil_c`, `soil_phi`, `soil_ca`, `soil_delta`, `soil_gamma` and
/// their `_var`) against the source's soil truth (the simulator's soil at the undisturbed surface
/// at the cell centres, Source::truth "soil_*" and "soil_zone"), as JSON: cells_estimated and per
/// property unit, cells, mae, bias, rmse (estimate − truth, in the property's unit; null when no
/// cell was compared), within_1sigma / within_2sigma (the fraction of the cells whose truth lies
/// within 1 / 2 posterior standard deviations: 0.683 / 0.954 when the variances are calibrated),
/// cells_inside and within_1sigma_inside (the same over the cells whose truth lies inside the
/// property's range by 1 % of it; null without such cells: at an end of the range every estimate
/// near the truth covers it);
/// with a `fee_index` layer also fee_index.zones: per truth zone (-1 = the default soil) cells,
/// mean_index_n and, for the scenario's zones, auc_vs_default (eval::rocAuc with the zone's cells
/// as positives: the probability that a zone cell's index is above a default-soil cell's; where
/// the truth soil's index is lower in the zone, 1 − it is the separation in the truth's order). Empty when the map has no soil layers or
/// the source no soil truth. compareWithSourceTruth puts it under "soil" and adds the layer
/// `truth_soil_zone`. Engine thread, between events. \throws nothing of its own.
TERRAMAP_API std::string soilTruthJson(const LayeredMap& map, const Source& source);

/// The same statistics as compareWithSourceTruth's JSON, of the map as it is now, without
/// touching it (no layers added): what `terramap run` records once per `outputs.series_interval_s`
/// (RunOptions::truth_stats). Empty when the map has no `elevation` or the source no truth of it.
/// Engine thread (reads the map), between events. \throws nothing of its own.
TERRAMAP_API std::string truthStatsJson(const LayeredMap& map, const Source& source);

}  // namespace terramap::eval
