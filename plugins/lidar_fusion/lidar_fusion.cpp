// lidar_fusion's host interface: the layers it writes, the events it takes, the per-cloud
// sequence (process: time update, fusion, cleanup) and the run's summary. The steps live in
// parameters.cpp, time_update.cpp, gating.cpp, fusion.cpp, visibility_cleanup.cpp and
// ray_walks.cpp.
#include "lidar_fusion.hpp"
#include "lidar_fusion_internal.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/submap_iterator.hpp>
#include <terramap/core/text.hpp>

#include <sstream>
#include <variant>

namespace terramap::plugins {

using namespace lidar_fusion_internal;

// ---- layers / events -------------------------------------------------------------------------

std::vector<LayerSpec> LidarFusion::layers() const {
  using L = LidarFusionLayers;
  std::vector<LayerSpec> out = {
      {L::kElevation, LayerAccess::Create, "m", kNaN, "fused surface height, map-frame z; NaN = unknown"},
      {L::kVariance, LayerAccess::Create, "m^2", kNaN, "variance of elevation; NaN = unknown"},
      {L::kIsValid, LayerAccess::Create, "1", 0.0f,
       "1 = measured; lowered by penetrating rays; 0 = unknown (elevation NaN)"},
      {L::kTimeSinceUpdate, LayerAccess::Create, "s", kNaN, "time since the last fused point; NaN = never"},
      {L::kUpperBound, LayerAccess::Create, "m", kNaN,
       "valid cells: elevation; unknown cells: lowest ray height seen above them; NaN = none"},
      {L::kIsUpperBound, LayerAccess::Create, "1", 0.0f, "1 where upper_bound comes from rays, not points"},
      {L::kHits, LayerAccess::Create, "count", 0.0f, "points fused into the cell by the latest cloud"},
  };
  if (config_.survey_datum)
    out.push_back({L::kSurveyZ, LayerAccess::Create, "m", kNaN,
                   "map-frame z the site survey's clouds gave the cell (survey_datum); NaN = not surveyed"});
  return out;
}

EventMask LidarFusion::events() const {
  return EventKind::PointCloud | EventKind::Pose | EventKind::BladePose | EventKind::Tick | EventKind::JointState;
}

void LidarFusion::bindLayers(const LayeredMap& map) {
  using L = LidarFusionLayers;
  elev_ = map.layerId(L::kElevation);
  var_ = map.layerId(L::kVariance);
  valid_ = map.layerId(L::kIsValid);
  time_ = map.layerId(L::kTimeSinceUpdate);
  ub_ = map.layerId(L::kUpperBound);
  isub_ = map.layerId(L::kIsUpperBound);
  hits_ = map.layerId(L::kHits);
  survey_z_ = config_.survey_datum && map.hasLayer(L::kSurveyZ) ? map.layerId(L::kSurveyZ) : LayerId(-1);
  bound_map_ = &map;
  tile_known_.assign(static_cast<size_t>(map.tileCount()), 0);
  hit_start_.clear();
  hit_count_.clear();
  hit_offs_.clear();
  prev_hit_start_.clear();
  prev_hit_count_.clear();
  prev_hit_offs_.clear();
  tables_start_ = Index(-1, -1);
}

void LidarFusion::attach(LayeredMap& map) {
  for (const LayerSpec& s : layers())
    if (!map.hasLayer(s.name)) map.addLayer(s.name, s.unit, s.fill);
  bindLayers(map);
}

void LidarFusion::start(ProcessContext& ctx) { bindLayers(ctx.map()); }

void LidarFusion::buildIndexTables(const LayeredMap& map) {
  if ((tables_start_ == map.startIndex()).all()) return;
  const int R = map.geometry().size().x(), C = map.geometry().size().y(), T = map.tileSize();
  const Index s = map.startIndex();
  // Indexed by *logical* row/column: folds the ring-buffer shift into the lookup.
  row_tile_.resize(static_cast<size_t>(R));
  row_local_.resize(static_cast<size_t>(R));
  col_tile_.resize(static_cast<size_t>(C));
  col_local_.resize(static_cast<size_t>(C));
  for (int i = 0; i < R; ++i) {
    const AxisCell a = axisCell(i, s.x(), R, T);
    row_tile_[static_cast<size_t>(i)] = a.tile * map.tileCols();
    row_local_[static_cast<size_t>(i)] = a.offset * T;
  }
  for (int j = 0; j < C; ++j) {
    const AxisCell a = axisCell(j, s.y(), C, T);
    col_tile_[static_cast<size_t>(j)] = a.tile;
    col_local_[static_cast<size_t>(j)] = a.offset;
  }
  // Ray-walk blocks: kRayBlock x kRayBlock cells of one tile. A block's logical rows are a run
  // of consecutive logical rows with the same tile row and local row / kRayBlock (the ring
  // buffer's wrap ends a tile, so it ends a block too).
  const int nbs = (T + kRayBlock - 1) / kRayBlock;
  blocks_per_tile_ = nbs * nbs;
  auto blocks = [&](int n, const std::vector<std::int32_t>& tile, auto blk, std::vector<AxisBlock>& out) {
    out.resize(static_cast<size_t>(n));
    int a = 0;
    for (int q = 1; q <= n; ++q)
      if (q == n || tile[static_cast<size_t>(q)] != tile[static_cast<size_t>(a)] || blk(q) != blk(a)) {
        for (int r = a; r < q; ++r) out[static_cast<size_t>(r)] = {tile[static_cast<size_t>(r)], blk(r), a, q};
        a = q;
      }
  };
  blocks(R, row_tile_, [&](int i) { return row_local_[static_cast<size_t>(i)] / T / kRayBlock * nbs; }, row_blocks_);
  blocks(C, col_tile_, [&](int j) { return col_local_[static_cast<size_t>(j)] / kRayBlock; }, col_blocks_);
  tables_start_ = s;
}

// ---- host interface --------------------------------------------------------------------------

void LidarFusion::accumulate(const FusionStats& s) {
  FusionStats& t = totals_;
  t.points_in += s.points_in;
  t.dropped_non_finite += s.dropped_non_finite;
  t.dropped_too_close += s.dropped_too_close;
  t.dropped_too_far += s.dropped_too_far;
  t.dropped_too_high += s.dropped_too_high;
  t.dropped_outside_map += s.dropped_outside_map;
  t.dropped_tile_budget += s.dropped_tile_budget;
  t.tile_budget_refusals += s.tile_budget_refusals;
  t.points_fused += s.points_fused;
  t.cells_fused += s.cells_fused;
  t.outliers += s.outliers;
  t.cells_forgotten += s.cells_forgotten;
  t.tiles_touched += s.tiles_touched;
  t.rays += s.rays;
  t.ray_cells += s.ray_cells;
  t.ray_cells_read += s.ray_cells_read;
  t.cells_penetrated += s.cells_penetrated;
  t.cells_invalidated += s.cells_invalidated;
  t.upper_bounds += s.upper_bounds;
  t.drift_applied = t.drift_applied || s.drift_applied;
  t.drift_m += s.drift_m;
  t.drift_inliers += s.drift_inliers;
  ++clouds_;
}

void LidarFusion::process(ProcessContext& ctx, const Event& event) {
  LayeredMap& map = ctx.map();
  if (bound_map_ != &map) bindLayers(map);
  if (const auto* pc = std::get_if<PointCloud>(&event)) {
    advanceTime(map, ctx.executor(), pc->stamp);
    if (config_.follow_robot && !have_pose_) followTo(map, pc->T_map_sensor.translation());
    std::size_t self_points = 0;
    if (self_filter_.enabled() && !self_filter_.placed()) {
      // The machine's pose is not known yet, so its own points cannot be told from the ground:
      // fusing them would build the machine into the map. Skip the cloud, counted.
      ctx.countDrop("self_no_pose", static_cast<long>(pc->points.size()));
      ctx.addCounter("points_in", static_cast<double>(pc->points.size()));
      ctx.addCounter("clouds_no_pose", 1);  // so clouds fused + these = clouds received
      return;
    }
    if (self_filter_.enabled()) self_points = self_filter_.apply(*pc, filtered_);
    const FusionStats s = fuse(map, ctx.executor(), self_filter_.enabled() ? filtered_ : *pc);
    if (self_filter_.enabled()) ctx.countDrop("self", static_cast<long>(self_points));
    ctx.countDrop("non_finite", s.dropped_non_finite);
    ctx.countDrop("too_close", s.dropped_too_close);
    ctx.countDrop("too_far", s.dropped_too_far);
    ctx.countDrop("too_high", s.dropped_too_high);
    ctx.countDrop("outside_map", s.dropped_outside_map);
    if (s.dropped_tile_budget) ctx.countDrop("tile_budget", s.dropped_tile_budget);
    if (s.tile_budget_refusals) ctx.addCounter("tile_budget_refusals", static_cast<double>(s.tile_budget_refusals));
    ctx.addCounter("points_in", static_cast<double>(s.points_in + self_points));
    ctx.addCounter("points_fused", static_cast<double>(s.points_fused));
    ctx.addCounter("outliers", static_cast<double>(s.outliers));
    ctx.addCounter("cells_forgotten", static_cast<double>(s.cells_forgotten));
    ctx.addCounter("rays", static_cast<double>(s.rays));
    ctx.addCounter("ray_cells", static_cast<double>(s.ray_cells));
    ctx.addCounter("cells_penetrated", static_cast<double>(s.cells_penetrated));
    ctx.addCounter("cells_invalidated", static_cast<double>(s.cells_invalidated));
    ctx.addCounter("upper_bound_updates", static_cast<double>(s.upper_bounds));
    if (s.drift_applied) ctx.addCounter("drift_m", s.drift_m);
    if (s.datum_updated) {
      ctx.addCounter("datum_updates", 1);
      ctx.addCounter("datum_points", static_cast<double>(s.datum_points));
      auto rec = std::make_shared<VerticalDatumRecord>();
      rec->machines = datum_;
      ctx.records().publish<VerticalDatumRecord>(VerticalDatumRecord::kType, pc->stamp, std::move(rec));
    }
  } else if (const auto* pose = std::get_if<Pose>(&event)) {
    advanceTime(map, ctx.executor(), pose->stamp);
    if (!pose->T_map_base.matrix().allFinite())
      throw InputError("lidar_fusion: pose at stamp " + formatNumber(pose->stamp) + " s is not finite");
    have_pose_ = true;
    self_filter_.setBasePose(pose->frame, pose->T_map_base);
    followTo(map, pose->T_map_base.translation());
  } else if (const auto* bp = std::get_if<BladePose>(&event)) {
    if (bp->T_map_blade.matrix().allFinite()) self_filter_.setBladePose(bp->machine_id, bp->T_map_blade);
  } else if (const auto* js = std::get_if<JointState>(&event)) {
    bool finite = true;
    for (const Eigen::Isometry3d& T : js->T_map_link) finite = finite && T.matrix().allFinite();
    if (finite) self_filter_.setLinkPoses(js->machine_id, js->T_map_link);
  } else if (const auto* tick = std::get_if<Tick>(&event)) {
    advanceTime(map, ctx.executor(), tick->stamp);
  }
}

void LidarFusion::finish(ProcessContext& ctx) {
  const FusionStats& t = totals_;
  std::ostringstream os;
  os << "{\"type\":\"lidar_fusion.summary\",\"clouds\":" << clouds_ << ",\"points_in\":" << t.points_in
     << ",\"points_fused\":" << t.points_fused << ",\"outliers\":" << t.outliers
     << ",\"dropped\":{\"non_finite\":" << t.dropped_non_finite << ",\"too_close\":" << t.dropped_too_close
     << ",\"too_far\":" << t.dropped_too_far << ",\"too_high\":" << t.dropped_too_high
     << ",\"outside_map\":" << t.dropped_outside_map << ",\"tile_budget\":" << t.dropped_tile_budget
     << "},\"tile_budget_refusals\":" << t.tile_budget_refusals << ",\"cells_forgotten\":" << t.cells_forgotten
     << ",\"rays\":" << t.rays << ",\"cells_penetrated\":" << t.cells_penetrated
     << ",\"cells_invalidated\":" << t.cells_invalidated << ",\"upper_bound_updates\":" << t.upper_bounds
     << ",\"drift_total_m\":" << formatNumber(t.drift_m) << "}";
  ctx.reportRecord(os.str());
}

}  // namespace terramap::plugins
