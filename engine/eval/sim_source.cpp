// The `sim` pipeline source (see sim_source.hpp for why it lives here).
#include <terramap/eval/sim_source.hpp>

#include <terramap/core/error.hpp>
#include <terramap/pipeline/source.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/simulator.hpp>
#include <terramap/sim/truth_sampling.hpp>
#include <terramap/sim/world.hpp>
#include <terramap/soil/soil_parameters.hpp>

#include <algorithm>
#include <cstdio>
#include <cmath>
#include <deque>
#include <limits>
#include <mutex>

namespace terramap::sim {

namespace {

/// The soil now at the undisturbed surface (the soil a blade cuts next): the truth soil at
/// the depth the bank surface was lowered to below the initial surface, at the cell centres.
/// Layers: soil_c (Pa), soil_phi (rad), soil_ca (Pa), soil_delta (rad), soil_gamma (N/m³),
/// soil_zone (index of the scenario's soil zone, -1 = default soil). NaN off the terrain.
bool soilTruth(const Simulator& sim, const std::string& layer, const Geometry& g, Eigen::Ref<Eigen::MatrixXf> out) {
  // soil::kSoilParams' layers, then soil_zone.
  int which = layer == "soil_zone" ? soil::kSoilParamCount : -1;
  for (int k = 0; k < soil::kSoilParamCount; ++k)
    if (layer == soil::kSoilParams[k].layer) which = k;
  if (which < 0) return false;
  TERRAMAP_CHECK(out.rows() == g.size().x() && out.cols() == g.size().y(), "truth view of the wrong size");
  const TruthTerrain& t = sim.truth();
  const SoilField& field = sim.soil();
  for (int i = 0; i < g.size().x(); ++i)
    for (int j = 0; j < g.size().y(); ++j) {
      const Position p = g.positionOf(Index(i, j));
      const double depth = t.initialHeightAt(p.x(), p.y()) - t.undisturbedAt(p.x(), p.y());
      if (!std::isfinite(depth)) {
        out(i, j) = std::numeric_limits<float>::quiet_NaN();
        continue;
      }
      out(i, j) = which == soil::kSoilParamCount
                      ? static_cast<float>(field.zoneAt(p.x(), p.y(), depth))
                      : static_cast<float>(soil::fromFee(field.at(p.x(), p.y(), depth).fee)[static_cast<std::size_t>(which)]);
    }
  return true;
}

/// The simulator, live: each step's events in time order.
class SimEventSource : public Source {
 public:
  explicit SimEventSource(const Scenario& sc, double max_time_s)
      : sim_(std::make_unique<Simulator>(sc)), duration_(std::min(sc.duration_s, max_time_s)) {}
  bool next(Event& e) override {
    while (queue_.empty()) {
      if (sim_->time() >= duration_) return false;
      std::vector<Event> batch;
      if (!sim_->next(batch)) return false;
      for (auto& ev : batch) queue_.push_back(std::move(ev));
    }
    e = std::move(queue_.front());
    queue_.pop_front();
    return true;
  }
  double progress() const override { return duration_ > 0 ? std::min(1.0, sim_->time() / duration_) : 1.0; }
  const Simulator& simulator() const { return *sim_; }
  bool truth(const std::string& layer, const Geometry& g, Eigen::Ref<Eigen::MatrixXf> out) const override {
    if (layer == "elevation") {
      TERRAMAP_CHECK(out.rows() == g.size().x() && out.cols() == g.size().y(), "truth view of the wrong size");
      out = truthOnGeometry(sim_->truth(), g);  // surface (bank + loose) at cell centres, NaN off it
      return true;
    }
    return soilTruth(*sim_, layer, g, out);
  }

 private:
  std::unique_ptr<Simulator> sim_;
  double duration_;
  std::deque<Event> queue_;
};

std::unique_ptr<Source> makeSim(const PipelineSpec& spec) {
  const SourceSpec& s = spec.source;
  checkSourceKeys(s, {"scenario", "max_time_s", "localisation", "lidar_sees_machines", "track_soil"});
  Scenario sc = loadScenario(spec.resolvePath(sourceString(s, "scenario", true)));
  // Ablations of the honest reference without editing the scenario.
  if (s.settings.count("localisation"))
    overrideLocalisation(sc, sourceString(s, "localisation", false), s.settings.at("localisation").where + ": localisation");
  if (s.settings.count("track_soil"))
    overrideTrackSoil(sc, sourceString(s, "track_soil", false), s.settings.at("track_soil").where + ": track_soil");
  if (const auto it = s.settings.find("lidar_sees_machines"); it != s.settings.end()) {
    const bool* b = std::get_if<bool>(&it->second.value);
    if (!b) throw ConfigError(it->second.where + ": lidar_sees_machines must be true or false");
    sc.lidar_sees_machines = *b;
  }
  const double max_t = sourceDouble(s, "max_time_s", false, INFINITY);
  if (!(max_t > 0)) throw ConfigError(s.settings.at("max_time_s").where + ": must be > 0");
  return std::make_unique<SimEventSource>(sc, max_t);
}


}  // namespace

std::vector<std::pair<int, std::string>> simSoilZoneNames(const Source& source) {
  const auto* sim = dynamic_cast<const SimEventSource*>(&source);
  if (!sim) return {};
  auto describe = [](const std::string& name, const auto& p) {
    char b[160];
    std::snprintf(b, sizeof b, "%s (%s, I_d %.2f)", name.c_str(), soil::soilFamilyName(p.family), p.relative_density);
    return std::string(b);
  };
  const SoilField& field = sim->simulator().soil();
  std::vector<std::pair<int, std::string>> names{{-1, describe("default soil", field.defaultSoil())}};
  for (std::size_t k = 0; k < field.zones().size(); ++k) {
    const SoilZone& z = field.zones()[k];
    names.emplace_back(static_cast<int>(k), describe(z.name.empty() ? "zone " + std::to_string(k) : z.name, z.soil));
  }
  return names;
}

void registerSimSource() {
  static std::once_flag once;
  std::call_once(once, [] { registerSource("sim", makeSim); });
}

}  // namespace terramap::sim
