// octomap_strata: the strata model (strata.hpp) fed by the record bus, and its map layers.
#include "octomap_strata.hpp"

#include <terramap/core/error.hpp>
#include <terramap/io/render.hpp>
#include <terramap/soil/prior_params.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <map>
#include <set>

namespace terramap::plugins {

namespace {

constexpr float kNaNf = std::numeric_limits<float>::quiet_NaN();
std::string squared(const std::string& unit) { return unit.find('^') == std::string::npos ? unit + "^2" : "(" + unit + ")^2"; }

std::vector<std::string> paramNames() {
  std::vector<std::string> v;
  for (const soil::SoilParamInfo& i : soil::kSoilParams) v.push_back(i.name);
  return v;
}

int paramIndex(const std::string& name) {
  for (int k = 0; k < soil::kSoilParamCount; ++k)
    if (name == soil::kSoilParams[k].name) return k;
  return 0;
}

/// The cells at `positions`, each grown by `reach` cells on every side, and every cell of
/// `whole_tiles`, as (tile, offset in the tile), each once, in tile then offset order. Marked in
/// a bitmap per tile: sorting and de-duplicating the pairs took a quarter of the plugin's time
/// once the change pass grew every dirty cell (each sweep's cells again, then 25 neighbours each).
std::vector<std::pair<int, int>> cellsToCompute(const LayeredMap& map, const std::vector<Eigen::Vector2d>& positions,
                                                const std::vector<int>& whole_tiles, int reach) {
  const Geometry& geo = map.geometry();
  const int T = map.tileSize();
  std::map<int, std::vector<std::uint64_t>> marks;
  const std::size_t words = (static_cast<std::size_t>(T) * static_cast<std::size_t>(T) + 63) / 64;
  int last_tile = -1;
  std::vector<std::uint64_t>* last_bits = nullptr;
  const auto mark = [&](int t, int o) {
    if (t != last_tile) {
      last_bits = &marks[t];
      if (last_bits->empty()) last_bits->assign(words, 0);
      last_tile = t;
    }
    (*last_bits)[static_cast<std::size_t>(o) >> 6] |= std::uint64_t{1} << (o & 63);
  };
  for (const Eigen::Vector2d& p : positions) {
    const auto idx = geo.indexAt(p);
    if (!idx) continue;
    for (int a = -reach; a <= reach; ++a)
      for (int b = -reach; b <= reach; ++b) {
        const Index l(idx->x() + a, idx->y() + b);
        if (l.x() < 0 || l.y() < 0 || l.x() >= geo.size().x() || l.y() >= geo.size().y()) continue;
        const Index buf = map.bufferIndex(l);
        const int t = map.tileOfBuffer(buf.x(), buf.y());
        const CellRect r = map.tileRect(t);
        mark(t, (buf.x() - r.r0) * T + (buf.y() - r.c0));
      }
  }
  for (int t : whole_tiles) {
    const CellRect r = map.tileRect(t);
    for (int a = 0; a < r.rows; ++a)
      for (int b = 0; b < r.cols; ++b) mark(t, a * T + b);
  }
  std::vector<std::pair<int, int>> todo;
  for (const auto& [t, bits] : marks)
    for (std::size_t w = 0; w < bits.size(); ++w)
      for (std::uint64_t m = bits[w]; m != 0; m &= m - 1)
        todo.emplace_back(t, static_cast<int>(w * 64 + static_cast<std::size_t>(__builtin_ctzll(m))));
  return todo;
}

}  // namespace

std::vector<strata::CellCut> cellCutsOf(const SweepRecord& sweep) {
  std::vector<strata::CellCut> out;
  std::size_t s = 0;  // slices follow the cut cells of the mask, in order
  for (const SweepMaskCell& m : sweep.mask) {
    if (!m.cut) continue;
    strata::CellCut c;
    c.position = m.position;
    c.cell_m = sweep.resolution_m;
    c.new_surface_m = m.sv_bottom_m;
    c.old_surface_m = std::numeric_limits<double>::quiet_NaN();
    if (s < sweep.slices.size()) {
      const SweepSlice& sl = sweep.slices[s];
      // The slice's fitted bank surface. Without a valid fit it stays unknown: the cell's height
      // before the cut (swept bottom + removed height) would count the pile pushed over it as
      // bank, and a column's first surface sets every depth in it.
      if (sl.valid && std::isfinite(sl.surface_z_m)) c.old_surface_m = sl.surface_z_m;
    }
    ++s;
    out.push_back(c);
  }
  return out;
}

ParamSchema OctomapStrata::schema() const {
  const OctomapStrataConfig d;
  ParamSchema s{
      param::real("resolution_m", d.strata.resolution_m, 0.005, 10.0, "m", "voxel edge"),
      param::reals("extent_min_m", {d.strata.min_m.x(), d.strata.min_m.y(), d.strata.min_m.z()}, 3, -1e5, 1e5, "m",
                   "lower corner of the strata's extent (map frame); columns outside are ignored and counted"),
      param::reals("extent_max_m", {d.strata.max_m.x(), d.strata.max_m.y(), d.strata.max_m.z()}, 3, -1e5, 1e5, "m",
                   "upper corner of the extent"),
      param::real("inflation_depth_m", d.strata.inflation_depth_m, 1e-3, 100.0, "m",
                  "the soil below a cut inherits the cut's estimate with its variance grown by exp(depth / this)"),
      param::text("inherit", "filter", {"filter", "last"},
                  "the soil below a column: every estimate that cut it, filtered down the column (filter), or the last one"),
      param::text("prior", d.strata.use_prior ? "config" : "none", {"config", "none"},
                  "the voxels a sweep removed hold its estimate fused with the prior_* beliefs (config) or as is (none: "
                  "the estimator's variance already holds the prior's where the force cannot tell the property); the "
                  "prior stays the belief of columns no sweep cut"),
      param::boolean("prior_below", d.strata.prior_below,
                     "the soil below a cut column is the inherited estimate with its variance inflated by depth (false), "
                     "or that times the prior_* beliefs (true: far down the prior's mean takes over)"),
      param::integer("max_pending_sweeps", d.strata.max_pending_sweeps, 1, 100000,
                     "sweeps waiting for their estimate; the oldest beyond keep their prediction"),
      param::real("next_cut_m", d.next_cut_m, 1e-3, 10.0, "m", "depth of the cut the strata_next_* layers describe"),
      param::boolean("surface_fallback", d.surface_fallback,
                     "cells whose column was never cut take soil_bayes' surface layers (soil_*) when the map has them"),
      param::integer("change_min_voxels", d.change_min_voxels, 1, 1000,
                     "strata_change_depth_m: removed voxels with an estimate needed on each side of a change"),
      param::real("change_min_gain", d.change_min_gain, 0.0, 1.0, "1",
                  "strata_change_depth_m: share of the column's spread the split must explain"),
      param::real("change_radius_m", d.change_radius_m, 0.0, 10.0, "m",
                  "strata_change_*: columns within this distance pool their removed soil by level"),
      param::texts("change_properties", paramNames(),
                   "strata_change_*: the soil properties the change is sought in (c, phi, ca, delta, gamma); one the "
                   "estimator cannot tell adds only its noise"),
      param::real("change_interval_s", d.change_interval_s, 0.0, 1e6, "s",
                  "strata_change_* are recomputed at most this often (event time) and at the end; 0 = every event"),
      param::real("pristine_margin_m", d.pristine_margin_m, -1.0, 10.0, "m",
                  "a first cut whose fitted bank surface lies more than this above strata_pristine_m (the surface "
                  "before any sweep touched the cell) starts from strata_pristine_m; negative = always the fit"),
      param::path("save_path", "", "write the whole model here at the end (.ot + terramap trailer); empty = no"),
      param::path("octovis_path", "", "write an octovis ColorOcTree (.ot) here at the end; empty = no"),
      param::text("octovis_param", "c", paramNames(), "soil property the ColorOcTree's colours show"),
      param::real("octovis_below_m", d.octovis_below_m, 0.0, 100.0, "m",
                  "the ColorOcTree also shows the predicted soil this far below each cut column's surface"),
      param::path("section_png", "", "write a cross-section picture here at the end; empty = no"),
      param::reals("section_line_m", {0, 0, 1, 0}, 4, -1e5, 1e5, "m", "cross-section from (x0, y0) to (x1, y1)"),
      param::text("section_param", "c", paramNames(), "soil property the cross-section shows"),
  };
  soil::addPriorParams(s, "where no estimate reached");
  return s;
}

void OctomapStrata::configure(const Params& p) {
  OctomapStrataConfig c;
  c.strata.resolution_m = p.getDouble("resolution_m");
  const std::vector<double>& lo = p.getDoubles("extent_min_m");
  const std::vector<double>& hi = p.getDoubles("extent_max_m");
  c.strata.min_m = {lo[0], lo[1], lo[2]};
  c.strata.max_m = {hi[0], hi[1], hi[2]};
  for (int a = 0; a < 3; ++a)
    if (!(lo[static_cast<std::size_t>(a)] < hi[static_cast<std::size_t>(a)]))
      p.fail("extent_max_m", std::string("must exceed extent_min_m along ") + "xyz"[a]);
  c.strata.inflation_depth_m = p.getDouble("inflation_depth_m");
  c.strata.max_pending_sweeps = static_cast<int>(p.getInt("max_pending_sweeps"));
  c.strata.filter_inheritance = p.getString("inherit") == "filter";
  c.strata.use_prior = p.getString("prior") == "config";
  c.strata.prior_below = p.getBool("prior_below");
  soil::readPriorParams(p, c.strata.prior_mean, c.strata.prior_var);
  c.next_cut_m = p.getDouble("next_cut_m");
  c.surface_fallback = p.getBool("surface_fallback");
  c.change_min_voxels = static_cast<int>(p.getInt("change_min_voxels"));
  c.change_min_gain = p.getDouble("change_min_gain");
  c.change_radius_m = p.getDouble("change_radius_m");
  c.change_properties.fill(false);
  const std::vector<std::string> names = paramNames();
  for (const std::string& name : p.getStrings("change_properties")) {
    const auto it = std::find(names.begin(), names.end(), name);
    if (it == names.end()) p.fail("change_properties", "'" + name + "' is not a soil property (c, phi, ca, delta, gamma)");
    c.change_properties[static_cast<std::size_t>(it - names.begin())] = true;
  }
  if (std::none_of(c.change_properties.begin(), c.change_properties.end(), [](bool b) { return b; }))
    p.fail("change_properties", "needs at least one soil property");
  c.change_interval_s = p.getDouble("change_interval_s");
  c.pristine_margin_m = p.getDouble("pristine_margin_m");
  c.save_path = p.getString("save_path");
  c.octovis_path = p.getString("octovis_path");
  c.octovis_param = paramIndex(p.getString("octovis_param"));
  c.octovis_below_m = p.getDouble("octovis_below_m");
  c.section_png = p.getString("section_png");
  c.section_line = p.getDoubles("section_line_m");
  c.section_param = paramIndex(p.getString("section_param"));
  try {
    strata::Strata probe(c.strata);  // every check of the model, reported against the stage
  } catch (const ConfigError& e) {
    p.fail("resolution_m", e.what());
  }
  cfg_ = c;
}

std::vector<LayerSpec> OctomapStrata::layers() const {
  std::vector<LayerSpec> out;
  for (const soil::SoilParamInfo& info : soil::kSoilParams) {
    const std::string l = std::string("strata_next_") + info.name;
    out.push_back({l, LayerAccess::Create, info.unit, kNaNf,
                   std::string(info.name) + " of the soil the next cut of next_cut_m would remove; NaN = nothing known"});
    out.push_back({l + "_var", LayerAccess::Create, squared(info.unit), kNaNf, "variance of " + l});
  }
  out.push_back({"strata_cut_m", LayerAccess::Create, "m", kNaNf,
                 "bank soil removed since the column was first cut; NaN = never cut"});
  out.push_back({"strata_change_depth_m", LayerAccess::Create, "m", kNaNf,
                 "depth below the first-cut surface of the strongest change in the removed soil; NaN = none found"});
  out.push_back({"strata_change_z_m", LayerAccess::Create, "m", kNaNf,
                 "height (map z) of that change: the first-cut surface minus strata_change_depth_m; NaN = none found"});
  out.push_back({"strata_pristine_m", LayerAccess::Create, "m", kNaNf,
                 "bank surface (elevation - loose) before any sweep touched the cell; NaN = never known, "
                 "-inf = touched before the map knew it"});
  out.push_back({"elevation", LayerAccess::Read, "", kNaNf, ""});
  return out;
}

// blade_sweep publishes on BladePose and Pose, soil_pinn on Observation and BladePose.
EventMask OctomapStrata::events() const { return EventKind::Observation | EventKind::BladePose | EventKind::Pose; }

void OctomapStrata::start(ProcessContext& ctx) {
  strata_.emplace(cfg_.strata);
  LayeredMap& map = ctx.map();
  for (int k = 0; k < soil::kSoilParamCount; ++k) {
    const std::string n = std::string("strata_next_") + soil::kSoilParams[k].name;
    next_[static_cast<std::size_t>(k)] = map.layerId(n);
    next_var_[static_cast<std::size_t>(k)] = map.layerId(n + "_var");
  }
  cut_ = map.layerId("strata_cut_m");
  change_ = map.layerId("strata_change_depth_m");
  change_z_ = map.layerId("strata_change_z_m");
  elevation_ = map.layerId("elevation");
  loose_ = map.hasLayer("loose") ? map.layerId("loose") : LayerId(-1);
  pristine_ = map.layerId("strata_pristine_m");
  ctx.trackChanges(elevation_);
  have_surface_ = cfg_.surface_fallback;
  for (int k = 0; have_surface_ && k < soil::kSoilParamCount; ++k)
    have_surface_ = map.hasLayer(soil::kSoilParams[k].layer) && map.hasLayer(std::string(soil::kSoilParams[k].layer) + "_var");
  if (have_surface_)
    for (int k = 0; k < soil::kSoilParamCount; ++k) {
      surf_[static_cast<std::size_t>(k)] = map.layerId(soil::kSoilParams[k].layer);
      surf_var_[static_cast<std::size_t>(k)] = map.layerId(std::string(soil::kSoilParams[k].layer) + "_var");
      ctx.trackChanges(surf_[static_cast<std::size_t>(k)]);
      ctx.trackChanges(surf_var_[static_cast<std::size_t>(k)]);
    }
  const Record* e = ctx.records().latest(SoilEstimateRecord::kType);
  last_estimate_ = e ? e->sequence : 0;
  const Record* s = ctx.records().latest(SweepRecord::kType);
  last_sweep_ = s ? s->sequence : 0;
}

void OctomapStrata::collect(ProcessContext& ctx, std::vector<Eigen::Vector2d>& cells, std::vector<int>& fallback_tiles) {
  const strata::StrataCounters before = strata_->counters();
  const RecordBus::Since sweeps = ctx.records().since(SweepRecord::kType, last_sweep_);
  if (sweeps.missed > 0) ctx.countDrop("sweep_missed", sweeps.missed);
  for (const Record& r : sweeps.records) {
    last_sweep_ = r.sequence;
    const auto& sw = *std::static_pointer_cast<const SweepRecord>(r.payload);
    std::vector<strata::CellCut> cut = cellCutsOf(sw);
    applyPristine(ctx, sw, cut);
    if (cut.empty()) continue;
    ctx.addCounter("voxels_removed", static_cast<double>(strata_->applyCut(sw.sweep_index, cut)));
    for (const strata::CellCut& c : cut) {
      cells.push_back(c.position);
      change_dirty_.push_back(c.position);
    }
  }
  const RecordBus::Since est = ctx.records().since(SoilEstimateRecord::kType, last_estimate_);
  if (est.missed > 0) ctx.countDrop("estimate_missed", est.missed);
  for (const Record& r : est.records) {
    last_estimate_ = r.sequence;
    const auto& e = *std::static_pointer_cast<const SoilEstimateRecord>(r.payload);
    // The estimate changes the columns its sweep cut: their cells are recomputed.
    const std::size_t first = cells.size();
    const long n = e.valid ? strata_->assignEstimate(e.sweep_index, &e.mean, &e.var_total, &cells)
                           : strata_->assignEstimate(e.sweep_index, nullptr, nullptr, &cells);
    ctx.addCounter("voxels_estimated", static_cast<double>(e.valid ? n : 0));
    change_dirty_.insert(change_dirty_.end(), cells.begin() + static_cast<std::ptrdiff_t>(first), cells.end());
  }
  const strata::StrataCounters& after = strata_->counters();
  if (after.estimates_invalid > before.estimates_invalid)
    ctx.countDrop("estimate_invalid", after.estimates_invalid - before.estimates_invalid);
  if (after.estimates_unmatched > before.estimates_unmatched)
    ctx.countDrop("estimate_removed_nothing", after.estimates_unmatched - before.estimates_unmatched);
  if (after.pending_evicted > before.pending_evicted)
    ctx.countDrop("estimate_never_came", after.pending_evicted - before.pending_evicted);
  if (after.columns_outside > before.columns_outside)
    ctx.countDrop("column_outside_extent", after.columns_outside - before.columns_outside);
  if (after.columns_unknown_surface > before.columns_unknown_surface)
    ctx.countDrop("column_surface_unknown", after.columns_unknown_surface - before.columns_unknown_surface);
  if (have_surface_)
    for (int k = 0; k < soil::kSoilParamCount; ++k) {
      for (int t : ctx.changedTiles(surf_[static_cast<std::size_t>(k)])) fallback_tiles.push_back(t);
      for (int t : ctx.changedTiles(surf_var_[static_cast<std::size_t>(k)])) fallback_tiles.push_back(t);
    }
}

void OctomapStrata::applyPristine(ProcessContext& ctx, const SweepRecord& sweep, std::vector<strata::CellCut>& cut) {
  LayeredMap& map = ctx.map();
  const Geometry& g = map.geometry();
  std::size_t k = 0;  // cut cells are the mask's cut cells, in order
  for (const SweepMaskCell& m : sweep.mask) {
    const std::optional<Index> idx = g.indexAt(m.position);
    const float pristine = idx ? map.at(pristine_, *idx) : kNaNf;
    if (m.cut && k < cut.size()) {
      strata::CellCut& c = cut[k++];
      if (cfg_.pristine_margin_m >= 0 && std::isfinite(pristine) &&
          (std::isnan(c.old_surface_m) || c.old_surface_m - pristine > cfg_.pristine_margin_m)) {
        c.old_surface_m = pristine;
        ctx.addCounter("first_surface_from_pristine", 1);
      }
    }
    if (idx && std::isnan(pristine)) {
      // A sparse map past its memory budget: the cell stays unknown (NaN), counted.
      const Index b = map.bufferIndex(*idx);
      if (map.tryAllocateTile(map.tileOfBuffer(b.x(), b.y()), {pristine_}))
        map.set(pristine_, *idx, -std::numeric_limits<float>::infinity());
      else
        ctx.countDrop("pristine_tile_budget");
    }
  }
}

void OctomapStrata::recordPristine(ProcessContext& ctx) {
  LayeredMap& map = ctx.map();
  const int ts = map.tileSize();
  for (int t : ctx.changedTiles(elevation_)) {
    const float* el = map.tileData(elevation_, t);
    if (!el) continue;
    const float* lo = loose_ >= 0 ? map.tileData(loose_, t) : nullptr;
    const float* known = map.tileData(pristine_, t);
    float* out = nullptr;  // taken (allocated, un-shared) only when a cell is written
    const CellRect r = map.tileRect(t);
    bool refused = false;
    for (int i = 0; i < r.rows && !refused; ++i)
      for (int j = 0; j < r.cols; ++j) {
        const int k = i * ts + j;
        if ((known && !std::isnan(known[k])) || !std::isfinite(el[k])) continue;
        if (!out) {
          refused = !map.tryAllocateTile(t, {pristine_});  // a sparse map past its memory budget
          if (refused) {
            ctx.countDrop("pristine_tile_budget");
            break;
          }
          known = out = map.mutableTileData(pristine_, t);
        }
        out[k] = el[k] - (lo && std::isfinite(lo[k]) ? lo[k] : 0.0f);
      }
  }
}

void OctomapStrata::process(ProcessContext& ctx, const Event&) { update(ctx, false); }

void OctomapStrata::update(ProcessContext& ctx, bool final) {
  std::vector<Eigen::Vector2d> cells;
  std::vector<int> fallback;
  collect(ctx, cells, fallback);  // first: the sweeps of this event mark the cells they touched
  recordPristine(ctx);
  if (final) strata_->flushPending();
  std::sort(fallback.begin(), fallback.end());
  fallback.erase(std::unique(fallback.begin(), fallback.end()), fallback.end());
  // Fallback first: a cell whose column was just cut is then overwritten with the strata's.
  ctx.addCounter("fallback_tiles", static_cast<double>(fallback.size()));
  if (!fallback.empty()) computeCells(ctx, {}, fallback, Pass::Fallback);
  if (!cells.empty()) computeCells(ctx, cells, {}, Pass::Next);
  const double now = ctx.stamp();
  if (!change_dirty_.empty() && (final || !(now - last_change_s_ < cfg_.change_interval_s))) {
    computeCells(ctx, change_dirty_, {}, Pass::Change);
    change_dirty_.clear();
    last_change_s_ = now;
  }
}

void OctomapStrata::finish(ProcessContext& ctx) {
  update(ctx, true);
  const strata::StrataCounters& c = strata_->counters();
  ctx.addCounter("columns", static_cast<double>(strata_->columns()));
  ctx.addCounter("tree_nodes", static_cast<double>(strata_->nodes()));
  ctx.addCounter("memory_bytes", static_cast<double>(strata_->memoryBytes()));
  ctx.addCounter("estimates_assigned", static_cast<double>(c.estimates_assigned));
  writeFiles(ctx);
}

void OctomapStrata::computeCells(ProcessContext& ctx, const std::vector<Eigen::Vector2d>& positions,
                                 const std::vector<int>& whole_tiles, Pass pass) {
  LayeredMap& map = ctx.map();
  const Geometry& geo = map.geometry();
  const int T = map.tileSize();
  // Change grows the cells by the pooling radius.
  const int reach = pass == Pass::Change ? static_cast<int>(std::ceil(cfg_.change_radius_m / geo.resolution())) : 0;
  const std::vector<std::pair<int, int>> todo = cellsToCompute(map, positions, whole_tiles, reach);
  // One task per tile.
  std::vector<std::size_t> starts;
  for (std::size_t k = 0; k < todo.size(); ++k)
    if (k == 0 || todo[k].first != todo[k - 1].first) starts.push_back(k);
  starts.push_back(todo.size());
  const int ntiles = static_cast<int>(starts.size()) - 1;
  const strata::Strata& st = *strata_;
  std::vector<long> budget(static_cast<std::size_t>(std::max(0, ntiles)), 0);
  ctx.executor().forEach(ntiles, [&](int n) {
    const int t = todo[starts[static_cast<std::size_t>(n)]].first;
    const bool ok = pass == Pass::Change
                        ? map.tryAllocateTile(t, {change_, change_z_})
                        : map.tryAllocateTile(t, {next_[0], next_[1], next_[2], next_[3], next_[4], next_var_[0],
                                                  next_var_[1], next_var_[2], next_var_[3], next_var_[4], cut_});
    if (!ok) {
      budget[static_cast<std::size_t>(n)] = 1;
      return;
    }
    const CellRect r = map.tileRect(t);
    strata::VoxelCache cache;  // this tile's cells pool overlapping columns
    std::array<float*, soil::kSoilParamCount> m{}, v{};
    std::array<const float*, soil::kSoilParamCount> sm{}, sv{};
    float *cut = nullptr, *change = nullptr, *change_z = nullptr;
    if (pass == Pass::Change) {
      change = map.mutableTileData(change_, t);
      change_z = map.mutableTileData(change_z_, t);
    } else {
      for (std::size_t k = 0; k < m.size(); ++k) {
        m[k] = map.mutableTileData(next_[k], t);
        v[k] = map.mutableTileData(next_var_[k], t);
        if (have_surface_) {
          sm[k] = map.tileData(surf_[k], t);
          sv[k] = map.tileData(surf_var_[k], t);
        }
      }
      cut = map.mutableTileData(cut_, t);
    }
    for (std::size_t k = starts[static_cast<std::size_t>(n)]; k < starts[static_cast<std::size_t>(n) + 1]; ++k) {
      const int o = todo[k].second;
      const Position p = geo.positionOf(map.logicalIndex(Index(r.r0 + o / T, r.c0 + o % T)));
      const double top = st.surfaceAt(p.x(), p.y());
      if (pass == Pass::Change) {
        const double z = std::isfinite(top) ? st.changeHeightAt(p.x(), p.y(), cfg_.change_min_voxels, cfg_.change_min_gain,
                                                                cfg_.change_radius_m, &cache, &cfg_.change_properties)
                                            : std::numeric_limits<double>::quiet_NaN();
        change_z[o] = static_cast<float>(z);
        change[o] = static_cast<float>(st.initialSurfaceAt(p.x(), p.y()) - z);
      } else if (std::isfinite(top)) {
        if (pass == Pass::Fallback) continue;  // the strata's own belief stands
        const strata::SoilBelief e = st.expectedCut(p.x(), p.y(), top, cfg_.next_cut_m);
        for (std::size_t q = 0; q < m.size(); ++q) {
          m[q][o] = static_cast<float>(e.mean[q]);
          v[q][o] = static_cast<float>(e.var[q]);
        }
        cut[o] = static_cast<float>(st.initialSurfaceAt(p.x(), p.y()) - top);
      } else {
        for (std::size_t q = 0; q < m.size(); ++q) {
          m[q][o] = sm[q] ? sm[q][o] : kNaNf;
          v[q][o] = sv[q] ? sv[q][o] : kNaNf;
        }
        cut[o] = kNaNf;
      }
    }
  });
  long nb = 0;
  for (long b : budget) nb += b;
  if (nb > 0) ctx.countDrop("tile_budget", nb);
  ctx.addCounter(pass == Pass::Change ? "cells_change_computed" : "cells_computed",
                 static_cast<double>(todo.size()));
}

void OctomapStrata::writeFiles(ProcessContext& ctx) const {
  if (!cfg_.save_path.empty()) strata_->save(cfg_.save_path);
  if (!cfg_.octovis_path.empty())
    strata_->exportColorOt(cfg_.octovis_path, cfg_.octovis_param, cfg_.octovis_below_m);
  if (cfg_.section_png.empty()) return;
  // The cross-section as a small map: rows along the line (x = distance), columns in z.
  const std::vector<double>& L = cfg_.section_line;
  const Eigen::Vector2d a(L[0], L[1]), b(L[2], L[3]);
  const double len = (b - a).norm(), res = cfg_.strata.resolution_m;
  if (!(len > 0.0)) throw ConfigError("octomap_strata: section_line_m has zero length");
  // z range: the cut columns along the line, from the 95th percentile of their first surfaces
  // down to 0.3 m below the 5th percentile of their surfaces (a few columns first cut under a
  // pile, or cut off the site's edge, would stretch a min/max range).
  const int ns = std::max(2, static_cast<int>(std::ceil(len / res)));
  std::vector<double> tops, inits;
  for (int s = 0; s < ns; ++s) {
    const Eigen::Vector2d p = a + (b - a) * ((s + 0.5) / ns);
    const double top = strata_->surfaceAt(p.x(), p.y()), init = strata_->initialSurfaceAt(p.x(), p.y());
    if (std::isfinite(top)) tops.push_back(top);
    if (std::isfinite(init)) inits.push_back(init);
  }
  double zlo = std::numeric_limits<double>::quiet_NaN(), zhi = zlo;
  if (!tops.empty()) {
    std::sort(tops.begin(), tops.end());
    std::sort(inits.begin(), inits.end());
    zlo = tops[tops.size() / 20] - 0.3;
    zhi = inits[inits.size() - 1 - inits.size() / 20] + 2 * res;
  }
  if (!std::isfinite(zlo) || !std::isfinite(zhi)) {
    ctx.countDrop("section_nothing_cut");
    return;
  }
  // Heights are exaggerated so the strata show on a long line: the z extent fills about half of
  // the picture's length (at most 20 times).
  const double exaggeration = std::clamp(std::floor(len / (2.0 * (zhi - zlo))), 1.0, 20.0);
  const int nz = std::max(2, static_cast<int>(std::ceil((zhi - zlo) * exaggeration / res)));
  // Geometry rows run along x (distance), columns along y: y = (z - zlo) * exaggeration.
  const Geometry g(res, Size(ns, nz), Position(0.5 * ns * res, 0.5 * nz * res));
  LayeredMap sec(g);
  const LayeredMap& map = ctx.map();
  auto bankAt = [&](const Eigen::Vector2d& p) {
    const auto idx = map.geometry().indexAt(p);
    if (!idx) return std::numeric_limits<double>::quiet_NaN();
    const float l = loose_ >= 0 ? map.at(loose_, *idx) : 0.0f;
    return static_cast<double>(map.at(elevation_, *idx)) - (std::isfinite(l) ? std::max(0.0f, l) : 0.0f);
  };
  const soil::SoilParamInfo& info = soil::kSoilParams[cfg_.section_param];
  const std::string layer = std::string("strata_") + info.name;
  const LayerId id = sec.addLayer(layer, info.unit);
  for (int s = 0; s < ns; ++s) {
    // Distance along the line from the cell's x (logical rows run towards -x).
    const Eigen::Vector2d p = a + (b - a) * (g.positionOf(Index(s, 0)).x() / (ns * res));
    for (int j = 0; j < nz; ++j) {
      const double z = zlo + g.positionOf(Index(s, j)).y() / exaggeration;
      const strata::SoilBelief sb = strata_->soilAt(p.x(), p.y(), z);
      if (sb.source == strata::SoilSource::Air || sb.source == strata::SoilSource::Outside) continue;
      // A column never cut has no surface of its own: the prior below the map's bank surface.
      if (sb.source == strata::SoilSource::Prior && !(z <= bankAt(p))) continue;
      sec.set(id, Index(s, j), static_cast<float>(sb.mean[static_cast<std::size_t>(cfg_.section_param)]));
    }
  }
  io::RenderOptions ro;
  ro.range = io::ValueRange{static_cast<float>(info.lo), static_cast<float>(info.hi)};
  ro.scale = std::clamp(static_cast<int>(std::lround(700.0 / ns)), 1, 16);  // about 700 pixels long
  io::Annotation an;
  an.title = std::string("strata ") + info.name + " along (" + std::to_string(L[0]).substr(0, 5) + ", " +
             std::to_string(L[1]).substr(0, 5) + ") -> (" + std::to_string(L[2]).substr(0, 5) + ", " +
             std::to_string(L[3]).substr(0, 5) + ")";
  char cap[200];
  std::snprintf(cap, sizeof cap,
                "horizontal: distance along the line; vertical: height z from %.2f to %.2f m, exaggerated %.0fx; blank = air or nothing known",
                zlo, zhi, exaggeration);
  an.caption = cap;
  io::renderPng(sec, layer, cfg_.section_png, ro, an);
}

}  // namespace terramap::plugins
