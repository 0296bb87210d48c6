// The host interface: parameters, layers, events and counters. The kernel is terrain_kernel.cpp.
#include "traversability.hpp"

#include <cmath>
#include <sstream>

namespace terramap::plugins {

namespace {
std::string text(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}
}  // namespace

ParamSchema Traversability::schema() const {
  const TraversabilityConfig d;
  return {
      param::text("input_layer", "elevation", {}, "elevation layer to read (m)"),
      param::text("slope_layer", "slope", {}, "layer to write: slope of the fitted plane (rad, created)"),
      param::text("roughness_layer", "roughness", {}, "layer to write: RMS distance to the fitted plane (m, created)"),
      param::text("step_layer", "step_height", {}, "layer to write: max - min height in the step window (m, created)"),
      param::text("traversability_layer", "traversability", {}, "layer to write: traversability in [0, 1] (created)"),
      param::real("plane_radius_m", d.plane_radius_m, 1e-4, 100.0, "m",
                  "half-width of the square window of the plane fit (k = floor(radius / resolution), at least 1)"),
      param::real("step_radius_m", d.step_radius_m, 1e-4, 100.0, "m",
                  "half-width of the square window of the step height (at least one cell)"),
      param::integer("min_points", d.min_points, 3, 1000000,
                     "known cells the plane fit needs in its window; fewer: slope, roughness, traversability NaN"),
      param::real("critical_slope_rad", d.critical_slope_rad, 1e-6, 1.5707963267948966, "rad",
                  "slope at which the slope term reaches 0"),
      param::real("critical_roughness_m", d.critical_roughness_m, 1e-9, 100.0, "m",
                  "roughness at which the roughness term reaches 0"),
      param::real("critical_step_m", d.critical_step_m, 1e-9, 100.0, "m", "step height at which the step term reaches 0"),
      param::real("weight_slope", d.weight_slope, 0.0, 1e6, "1", "weight of the slope term"),
      param::real("weight_roughness", d.weight_roughness, 0.0, 1e6, "1", "weight of the roughness term"),
      param::real("weight_step", d.weight_step, 0.0, 1e6, "1", "weight of the step term"),
      param::boolean("any_critical_blocks", d.any_critical_blocks,
                     "traversability 0 where any term is at or past its critical value (else only the weighted mean)"),
      param::texts("run_on", {"point_cloud"},
                   "event kinds after which to recompute: point_cloud, pose, blade_pose, observation, tick"),
      param::boolean("on_finish", true, "recompute once more at the end of the run"),
  };
}

void Traversability::configure(const Params& p) {
  input_ = p.getString("input_layer");
  slope_name_ = p.getString("slope_layer");
  roughness_name_ = p.getString("roughness_layer");
  step_name_ = p.getString("step_layer");
  trav_name_ = p.getString("traversability_layer");
  cfg_.plane_radius_m = p.getDouble("plane_radius_m");
  cfg_.step_radius_m = p.getDouble("step_radius_m");
  cfg_.min_points = p.getInt("min_points");
  cfg_.critical_slope_rad = p.getDouble("critical_slope_rad");
  cfg_.critical_roughness_m = p.getDouble("critical_roughness_m");
  cfg_.critical_step_m = p.getDouble("critical_step_m");
  cfg_.weight_slope = p.getDouble("weight_slope");
  cfg_.weight_roughness = p.getDouble("weight_roughness");
  cfg_.weight_step = p.getDouble("weight_step");
  cfg_.any_critical_blocks = p.getBool("any_critical_blocks");
  on_finish_ = p.getBool("on_finish");
  std::string unknown;
  events_ = eventMaskFromNames(p.getStrings("run_on"), &unknown);
  // report(), not fail(): the user sees every problem of this stage at once.
  if (!unknown.empty()) p.report("run_on", "unknown event kind '" + unknown + "'");
  const std::pair<const char*, const std::string*> outs[] = {{"slope_layer", &slope_name_},
                                                             {"roughness_layer", &roughness_name_},
                                                             {"step_layer", &step_name_},
                                                             {"traversability_layer", &trav_name_}};
  for (size_t a = 0; a < 4; ++a) {
    if (*outs[a].second == input_) p.report(outs[a].first, "must differ from input_layer ('" + input_ + "')");
    for (size_t b = 0; b < a; ++b)
      if (*outs[a].second == *outs[b].second)
        p.report(outs[a].first, "must differ from " + std::string(outs[b].first) + " ('" + *outs[b].second + "')");
  }
  if (cfg_.weight_slope + cfg_.weight_roughness + cfg_.weight_step <= 0.0)
    p.report("weight_step", "weight_slope, weight_roughness and weight_step are all 0: traversability would be 0/0");
  if (const Geometry* g = p.mapGeometry()) {
    const double res = g->resolution();
    const int k = planeHalfWidth(res), ks = stepHalfWidth(res);
    // A window narrower than one cell would be widened to one cell each side: not what was asked.
    for (const auto& [key, r] : {std::pair<const char*, double>{"plane_radius_m", cfg_.plane_radius_m},
                                 std::pair<const char*, double>{"step_radius_m", cfg_.step_radius_m}})
      if (r < res && p.isSet(key))
        p.report(key, "must be at least the map's resolution (" + text(res) + " m, got " + text(r) +
                          " m); a window below one cell would be widened to one cell");
    const long full = static_cast<long>(2 * k + 1) * (2 * k + 1);
    if (cfg_.min_points > full)
      p.report("min_points", std::to_string(cfg_.min_points) + " is more than the plane window holds (" +
                                 std::to_string(2 * k + 1) + " x " + std::to_string(2 * k + 1) + " = " +
                                 std::to_string(full) + " cells at " + text(res) + " m)");
    const int across = 2 * std::max(k, ks) + 1;
    if (across > std::min(g->size().x(), g->size().y()))
      p.report(k >= ks ? "plane_radius_m" : "step_radius_m",
               "the window (" + std::to_string(across) + " cells across) does not fit in the map (" +
                   std::to_string(g->size().x()) + " x " + std::to_string(g->size().y()) + " cells)");
  }
}

std::vector<LayerSpec> Traversability::layers() const {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  return {LayerSpec{input_, LayerAccess::Read, "", 0, ""},
          LayerSpec{slope_name_, LayerAccess::Create, "rad", nan,
                    "slope of the least-squares plane through " + input_ +
                        " around the cell; NaN: cell unknown or too few known cells for a fit"},
          LayerSpec{roughness_name_, LayerAccess::Create, "m", nan,
                    "RMS distance of " + input_ + " to that plane, along its normal; NaN as slope"},
          LayerSpec{step_name_, LayerAccess::Create, "m", nan,
                    "max - min of known " + input_ + " in the step window; NaN: cell unknown"},
          LayerSpec{trav_name_, LayerAccess::Create, "1", nan,
                    "traversability in [0, 1] (1 flat, smooth, no step); NaN as slope"}};
}

EventMask Traversability::events() const { return events_; }

void Traversability::start(ProcessContext& ctx) {
  const LayeredMap& map = ctx.map();
  ids_.elevation = map.layerId(input_);
  ids_.slope = map.layerId(slope_name_);
  ids_.roughness = map.layerId(roughness_name_);
  ids_.step = map.layerId(step_name_);
  ids_.traversability = map.layerId(trav_name_);
  ctx.trackChanges(ids_.elevation);
}

void Traversability::process(ProcessContext& ctx, const Event&) {
  LayeredMap& map = ctx.map();
  const std::vector<int> tiles = affectedTiles(map, ctx.changedTiles(ids_.elevation));
  PassStats st;
  if (!tiles.empty()) st = runTiles(map, ctx.executor(), ids_, tiles);
  ctx.addCounter("passes", 1);
  ctx.addCounter("tiles_computed", static_cast<double>(st.tiles));
  ctx.addCounter("cells_fitted", static_cast<double>(st.cells_fitted));
  if (st.tile_budget > 0) ctx.countDrop("tile_budget", st.tile_budget);
}

void Traversability::finish(ProcessContext& ctx) {
  if (on_finish_) process(ctx, Tick{ctx.stamp()});
}

}  // namespace terramap::plugins
