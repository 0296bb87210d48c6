#include <terramap/eval/truth_report.hpp>

#include <terramap/eval/statistics.hpp>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

namespace terramap::eval {

namespace {

/// The map's elevation against the source's truth on the map's geometry; false when the map
/// has no elevation or the source no truth of it.
struct Compared {
  Eigen::MatrixXf truth, err;
  std::vector<double> errors;
  long truth_cells = 0;
};

bool compare(const LayeredMap& map, const Source& source, Compared& c) {
  if (!map.hasLayer("elevation")) return false;
  const Geometry& g = map.geometry();
  c.truth.resize(g.size().x(), g.size().y());
  if (!source.truth("elevation", g, c.truth)) return false;
  const Eigen::MatrixXf est = map.toMatrix(map.layerId("elevation"));
  c.err = Eigen::MatrixXf::Constant(est.rows(), est.cols(), std::numeric_limits<float>::quiet_NaN());
  for (int i = 0; i < est.rows(); ++i)
    for (int j = 0; j < est.cols(); ++j) {
      if (!std::isfinite(c.truth(i, j))) continue;
      ++c.truth_cells;
      if (!std::isfinite(est(i, j))) continue;
      c.err(i, j) = est(i, j) - c.truth(i, j);
      c.errors.push_back(c.err(i, j));
    }
  return true;
}

nlohmann::json statsJson(std::vector<double> errors, long truth_cells) {
  const std::size_t compared = errors.size();
  const ErrorStats s = errorStats(errors);
  // The error about its median: what is left once one offset of the whole map (a vertical
  // pose error shifts every cell alike) is taken out, i.e. the map's shape against the truth.
  for (double& e : errors) e = std::abs(e - s.p50);
  std::sort(errors.begin(), errors.end());
  const double mad = percentileSorted(errors, 50.0);
  auto orZero = [&](double v) { return compared ? v : 0.0; };
  return {{"layer", "elevation"},
          {"cells_with_truth", truth_cells},
          {"cells_compared", compared},
          {"coverage", truth_cells ? static_cast<double>(compared) / truth_cells : 0.0},
          {"rmse_m", orZero(s.rmse)},
          {"bias_m", orZero(s.bias)},
          {"median_m", orZero(s.p50)},
          {"median_abs_m", orZero(s.median_abs)},
          {"median_abs_about_median_m", orZero(mad)},
          {"p95_abs_m", orZero(s.p95_abs)},
          {"max_abs_m", orZero(s.max_abs)}};
}

}  // namespace

TruthComparison compareWithSourceTruth(LayeredMap& map, const Source& source) {
  if (map.hasLayer("truth_elevation")) return {};
  Compared c;
  if (!compare(map, source, c)) return {};
  map.fromMatrix(map.addLayer("truth_elevation", "m"), c.truth);
  map.fromMatrix(map.addLayer("elevation_error", "m"), c.err);
  const nlohmann::json j = statsJson(std::move(c.errors), c.truth_cells);
  char caption[256];
  std::snprintf(caption, sizeof caption,
                "|map - truth|: RMSE %.2f cm, median %.2f cm, p95 %.2f cm; coverage %.1f %% of %ld cells",
                100.0 * j["rmse_m"].get<double>(), 100.0 * j["median_abs_m"].get<double>(),
                100.0 * j["p95_abs_m"].get<double>(), 100.0 * j["coverage"].get<double>(), c.truth_cells);
  return TruthComparison{j.dump(), {"truth_elevation", "elevation_error"}, caption};
}

std::string truthStatsJson(const LayeredMap& map, const Source& source) {
  Compared c;
  if (!compare(map, source, c)) return {};
  return statsJson(std::move(c.errors), c.truth_cells).dump();
}

}  // namespace terramap::eval
