#include <terramap/eval/truth_report.hpp>

#include <terramap/eval/sim_source.hpp>
#include <terramap/eval/statistics.hpp>
#include <terramap/soil/soil_parameters.hpp>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <string>

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

/// Soil layers (soil_bayes) against the source's soil truth; null when the map has no soil
/// layers or the source no soil truth. `zone` receives the truth zone per cell.
nlohmann::json compareSoil(const LayeredMap& map, const Source& source, Eigen::MatrixXf* zone_out) {
  const Geometry& g = map.geometry();
  for (const soil::SoilParamInfo& info : soil::kSoilParams)
    if (!map.hasLayer(info.layer) || !map.hasLayer(std::string(info.layer) + "_var")) return nullptr;
  Eigen::MatrixXf truth(g.size().x(), g.size().y()), zone(g.size().x(), g.size().y());
  if (!source.truth("soil_zone", g, zone)) return nullptr;
  nlohmann::json props = nlohmann::json::object();
  // Per zone too: a bias of the whole map can hide opposite biases in the strip and around it.
  nlohmann::json zone_props = nlohmann::json::object();
  long estimated = 0;
  for (const soil::SoilParamInfo& info : soil::kSoilParams) {
    if (!source.truth(info.layer, g, truth)) return nullptr;
    const Eigen::MatrixXf est = map.toMatrix(map.layerId(info.layer));
    const Eigen::MatrixXf var = map.toMatrix(map.layerId(std::string(info.layer) + "_var"));
    std::vector<double> err;
    long in1 = 0, in2 = 0, inside = 0, in1_inside = 0;
    double abs_sum = 0.0;
    // A truth at an end of the property's range (sand's c = 0) is covered by every estimate the
    // range holds near it, whatever its spread: calibration shows only where the truth is inside.
    const double edge = 0.01 * (info.hi - info.lo);
    std::map<int, std::array<double, 3>> by_zone;  // sum of errors, of |errors|, count
    for (int i = 0; i < est.rows(); ++i)
      for (int j = 0; j < est.cols(); ++j) {
        if (!std::isfinite(est(i, j)) || !std::isfinite(truth(i, j)) || !std::isfinite(var(i, j))) continue;
        const double e = static_cast<double>(est(i, j)) - truth(i, j);
        if (std::isfinite(zone(i, j))) {
          std::array<double, 3>& z = by_zone[static_cast<int>(zone(i, j))];
          z[0] += e;
          z[1] += std::abs(e);
          z[2] += 1.0;
        }
        const double sd = std::sqrt(std::max(0.0, static_cast<double>(var(i, j))));
        err.push_back(e);
        abs_sum += std::abs(e);
        in1 += std::abs(e) <= sd;
        in2 += std::abs(e) <= 2.0 * sd;
        if (truth(i, j) > info.lo + edge && truth(i, j) < info.hi - edge) {
          ++inside;
          in1_inside += std::abs(e) <= sd;
        }
      }
    const long n = static_cast<long>(err.size());
    estimated = std::max(estimated, n);
    const ErrorStats st = errorStats(err);
    auto orNull = [&](double v) { return n ? nlohmann::json(v) : nlohmann::json(nullptr); };
    props[info.layer] = {{"unit", info.unit},
                        {"cells", n},
                        {"mae", orNull(n ? abs_sum / n : 0.0)},
                        {"bias", orNull(st.bias)},
                        {"rmse", orNull(st.rmse)},
                        // Calibration: for Gaussian beliefs 68.3 % and 95.4 % of the truths fall
                        // within 1 and 2 standard deviations.
                        {"within_1sigma", orNull(n ? static_cast<double>(in1) / n : 0.0)},
                        {"within_2sigma", orNull(n ? static_cast<double>(in2) / n : 0.0)},
                        // The same over the cells whose truth lies inside the range (by 1 % of it).
                        {"cells_inside", inside},
                        {"within_1sigma_inside",
                         inside ? nlohmann::json(static_cast<double>(in1_inside) / inside) : nlohmann::json(nullptr)}};
    for (const auto& [z, a] : by_zone)
      zone_props[std::to_string(z)][info.layer] = {{"cells", a[2]}, {"bias", a[0] / a[2]}, {"mae", a[1] / a[2]}};
  }
  nlohmann::json out = {{"cells_estimated", estimated}, {"properties", props}, {"properties_by_zone", zone_props}};
  // The FEE index against the soil zones: how well it tells each zone from the default soil.
  if (map.hasLayer("fee_index")) {
    const Eigen::MatrixXf idx = map.toMatrix(map.layerId("fee_index"));
    std::map<int, std::vector<double>> by_zone;
    for (int i = 0; i < idx.rows(); ++i)
      for (int j = 0; j < idx.cols(); ++j)
        if (std::isfinite(idx(i, j)) && std::isfinite(zone(i, j)))
          by_zone[static_cast<int>(zone(i, j))].push_back(idx(i, j));
    nlohmann::json zones = nlohmann::json::array();
    for (const auto& [z, v] : by_zone) {
      double sum = 0.0;
      for (double x : v) sum += x;
      nlohmann::json e = {{"zone", z}, {"cells", v.size()}, {"mean_index_n", sum / static_cast<double>(v.size())}};
      const auto def = by_zone.find(-1);
      // AUC of the index separating this zone's cells (positives) from the default soil's.
      if (z >= 0) e["auc_vs_default"] = def == by_zone.end() ? nlohmann::json(nullptr)
                                                             : nlohmann::json(rocAuc(v, def->second));
      zones.push_back(e);
    }
    out["fee_index"] = {{"zones", zones}};
  }
  if (zone_out) *zone_out = zone;
  return out;
}

}  // namespace

TruthComparison compareWithSourceTruth(LayeredMap& map, const Source& source) {
  if (map.hasLayer("truth_elevation")) return {};
  Compared c;
  if (!compare(map, source, c)) return {};
  map.fromMatrix(map.addLayer("truth_elevation", "m"), c.truth);
  map.fromMatrix(map.addLayer("elevation_error", "m"), c.err);
  nlohmann::json j = statsJson(std::move(c.errors), c.truth_cells);
  std::vector<std::string> layers{"truth_elevation", "elevation_error"};
  std::map<std::string, std::vector<std::pair<float, std::string>>> categories;
  Eigen::MatrixXf zone;
  const nlohmann::json soil = compareSoil(map, source, &zone);
  if (!soil.is_null()) {
    j["soil"] = soil;
    if (!map.hasLayer("truth_soil_zone")) {
      map.fromMatrix(map.addLayer("truth_soil_zone", "1"), zone);
      layers.push_back("truth_soil_zone");
      // Its picture's legend: the zones the map shows, by name.
      std::vector<std::pair<float, std::string>> legend;
      for (const auto& [id, name] : sim::simSoilZoneNames(source))
        if ((zone.array() == static_cast<float>(id)).any()) legend.emplace_back(static_cast<float>(id), name);
      categories["truth_soil_zone"] = legend;
    }
  }
  char caption[256];
  std::snprintf(caption, sizeof caption,
                "|map - truth|: RMSE %.2f cm, median %.2f cm, p95 %.2f cm; coverage %.1f %% of %ld cells",
                100.0 * j["rmse_m"].get<double>(), 100.0 * j["median_abs_m"].get<double>(),
                100.0 * j["p95_abs_m"].get<double>(), 100.0 * j["coverage"].get<double>(), c.truth_cells);
  return TruthComparison{j.dump(), layers, caption, categories};
}

std::string soilTruthJson(const LayeredMap& map, const Source& source) {
  const nlohmann::json j = compareSoil(map, source, nullptr);
  return j.is_null() ? std::string() : j.dump();
}

std::string truthStatsJson(const LayeredMap& map, const Source& source) {
  Compared c;
  if (!compare(map, source, c)) return {};
  return statsJson(std::move(c.errors), c.truth_cells).dump();
}

}  // namespace terramap::eval
