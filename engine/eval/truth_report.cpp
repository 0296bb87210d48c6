#include <terramap/eval/truth_report.hpp>

#include <terramap/eval/statistics.hpp>

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <limits>

namespace terramap::eval {

TruthComparison compareWithSourceTruth(LayeredMap& map, const Source& source) {
  if (!map.hasLayer("elevation") || map.hasLayer("truth_elevation")) return {};
  const Geometry& g = map.geometry();
  Eigen::MatrixXf truth(g.size().x(), g.size().y());
  if (!source.truth("elevation", g, truth)) return {};
  const Eigen::MatrixXf est = map.toMatrix(map.layerId("elevation"));
  Eigen::MatrixXf err = Eigen::MatrixXf::Constant(est.rows(), est.cols(), std::numeric_limits<float>::quiet_NaN());
  std::vector<double> errors;
  long truth_cells = 0;
  for (int i = 0; i < est.rows(); ++i)
    for (int j = 0; j < est.cols(); ++j) {
      if (!std::isfinite(truth(i, j))) continue;
      ++truth_cells;
      if (!std::isfinite(est(i, j))) continue;
      err(i, j) = est(i, j) - truth(i, j);
      errors.push_back(err(i, j));
    }
  map.fromMatrix(map.addLayer("truth_elevation", "m"), truth);
  map.fromMatrix(map.addLayer("elevation_error", "m"), err);
  const std::size_t compared = errors.size();
  const ErrorStats s = errorStats(std::move(errors));
  auto orZero = [&](double v) { return compared ? v : 0.0; };
  const nlohmann::json j = {{"layer", "elevation"},
                            {"cells_with_truth", truth_cells},
                            {"cells_compared", compared},
                            {"coverage", truth_cells ? static_cast<double>(compared) / truth_cells : 0.0},
                            {"rmse_m", orZero(s.rmse)},
                            {"median_abs_m", orZero(s.median_abs)},
                            {"p95_abs_m", orZero(s.p95_abs)},
                            {"max_abs_m", orZero(s.max_abs)}};
  char caption[256];
  std::snprintf(caption, sizeof caption,
                "|map - truth|: RMSE %.2f cm, median %.2f cm, p95 %.2f cm; coverage %.1f %% of %ld cells",
                100.0 * orZero(s.rmse), 100.0 * orZero(s.median_abs), 100.0 * orZero(s.p95_abs),
                100.0 * (truth_cells ? static_cast<double>(compared) / truth_cells : 0.0), truth_cells);
  return TruthComparison{j.dump(), {"truth_elevation", "elevation_error"}, caption};
}

}  // namespace terramap::eval
