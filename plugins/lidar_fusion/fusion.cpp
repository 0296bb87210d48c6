// lidar_fusion's fusion: drift compensation, then one task per tile fuses its points in input
// order (Mahalanobis gate, precision-weighted update).
#include "lidar_fusion.hpp"
#include "lidar_fusion_internal.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <utility>

namespace terramap::plugins {

using namespace lidar_fusion_internal;

namespace {

/// Items ahead of the current one whose cells the fusion loop prefetches.
constexpr int kPrefetchAhead = 8;

}  // namespace

// ---- fusion ----------------------------------------------------------------------------------

FusionStats LidarFusion::fuse(LayeredMap& map, const Executor& ex, const PointCloud& cloud) {
  if (bound_map_ != &map)
    throw LayerError("lidar_fusion: fuse() on a map it is not attached to (call attach(map) first)");
  if (!cloud.T_map_sensor.matrix().allFinite())
    throw InputError("lidar_fusion: point cloud at stamp " + formatNumber(cloud.stamp) + " s has a non-finite T_map_sensor");
  FusionStats st;
  st.points_in = static_cast<long>(cloud.points.size());
  buildIndexTables(map);
  // A machine's cloud ("<machine>/<sensor>") in the survey's datum: shifted down by the
  // machine's offset so far (survey_datum).
  const bool survey = survey_z_ >= 0 && cloud.frame == config_.survey_frame;
  const std::size_t slash = cloud.frame.find('/');
  const std::string machine = survey_z_ >= 0 && !survey && slash != std::string::npos && slash > 0
                                  ? cloud.frame.substr(0, slash) : std::string();
  Eigen::Isometry3d T = cloud.T_map_sensor;
  if (!machine.empty()) {
    const auto it = datum_.find(machine);
    if (it != datum_.end()) {
      T.translation().z() -= it->second.offset_m;
      st.datum_shift_m = it->second.offset_m;
    }
  }

  // 1) transform, gate, noise, cell, and a stable sort by tile inside each fixed chunk.
  preparePoints(map, ex, cloud, T);
  for (const PointChunk& ch : point_chunks_) {
    st.dropped_non_finite += ch.drops[0];
    st.dropped_too_close += ch.drops[1];
    st.dropped_too_far += ch.drops[2];
    st.dropped_too_high += ch.drops[3];
    st.dropped_outside_map += ch.drops[4];
  }
  // Per-tile totals and the tile lists (serial, tiles x chunks integer adds).
  const int ntiles = map.tileCount();
  tile_points_.assign(static_cast<size_t>(ntiles), 0);
  for (const PointChunk& ch : point_chunks_)
    for (int t = 0; t < ntiles; ++t)
      tile_points_[static_cast<size_t>(t)] += ch.start[static_cast<size_t>(t) + 1] - ch.start[static_cast<size_t>(t)];
  active_tiles_.clear();
  for (int t = 0; t < ntiles; ++t)
    if (tile_points_[static_cast<size_t>(t)] > 0) active_tiles_.push_back(t);

  // 2) drift compensation against the map before this cloud; the survey datum.
  if (config_.enable_drift_compensation) driftCompensation(map, ex, T, st);
  if (!machine.empty()) measureDatum(map, ex, machine, cloud.stamp, st);
  prev_T_map_sensor_ = T;
  have_prev_sensor_ = true;

  // 3) per-tile sequential fusion (which first clears the previous cloud's hits).
  fuseTiles(map, ex, st);
  if (survey) recordSurvey(map);

  // 4) visibility cleanup and upper bounds.
  if (config_.enable_visibility_cleanup) cleanup(map, ex, T.translation(), st);

  accumulate(st);
  return st;
}

void LidarFusion::driftCompensation(LayeredMap& map, const Executor& ex, const Eigen::Isometry3d& T,
                                    FusionStats& st) {
  const LidarFusionConfig& cf = config_;
  const int na = static_cast<int>(active_tiles_.size());
  std::vector<double> sums(static_cast<size_t>(na), 0.0);
  std::vector<long> counts(static_cast<size_t>(na), 0);
  const float k2 = static_cast<float>(cf.mahalanobis_thresh * cf.mahalanobis_thresh);
  const float vin = static_cast<float>(cf.drift_compensation_variance_inlier_m2);
  ex.forEach(na, [&](int k) {
    const int t = active_tiles_[static_cast<size_t>(k)];
    const float* E = map.tileData(elev_, t);
    const float* V = map.tileData(var_, t);
    if (!E || !V) return;
    double s = 0.0;
    long cnt = 0;
    for (const PointChunk& ch : point_chunks_) {
      for (int q = ch.start[static_cast<size_t>(t)]; q < ch.start[static_cast<size_t>(t) + 1]; ++q) {
        const PointItem& it = ch.items[static_cast<size_t>(q)];
        const float h = E[it.off], v = V[it.off];
        if (!(v < vin)) continue;  // also rejects NaN (unknown)
        const float r = it.z - h;
        if (r * r > k2 * (v + it.var)) continue;
        s += r;
        ++cnt;
      }
    }
    sums[static_cast<size_t>(k)] = s;
    counts[static_cast<size_t>(k)] = cnt;
  });
  double sum = 0.0;
  long cnt = 0;
  for (int k = 0; k < na; ++k) {  // fixed (tile) order: deterministic
    sum += sums[static_cast<size_t>(k)];
    cnt += counts[static_cast<size_t>(k)];
  }
  st.drift_inliers = cnt;
  if (cnt < cf.min_height_drift_cnt || cnt == 0) return;
  bool moved = !have_prev_sensor_;
  if (have_prev_sensor_) {
    const double dp = (T.translation() - prev_T_map_sensor_.translation()).norm();
    const double da = Eigen::AngleAxisd(prev_T_map_sensor_.linear().transpose() * T.linear()).angle();
    moved = dp > cf.position_noise_thresh_m || da > cf.orientation_noise_thresh_rad;
  }
  if (!moved) return;
  const double mean = sum / static_cast<double>(cnt);
  if (!(std::abs(mean) < cf.max_drift_m)) return;
  const float shift = static_cast<float>(mean * cf.drift_compensation_alpha);
  const int n = map.tileSize() * map.tileSize();
  ex.forEach(map.tileCount(), [&](int t) {
    if (!tile_known_[static_cast<size_t>(t)]) return;
    for (LayerId id : {elev_, ub_}) {
      if (!map.tileData(id, t)) continue;
      float* d = map.mutableTileData(id, t);
      for (int c = 0; c < n; ++c) d[c] += shift;  // NaN stays NaN
    }
  });
  st.drift_applied = true;
  st.drift_m = shift;
}

void LidarFusion::measureDatum(LayeredMap& map, const Executor& ex, const std::string& machine, double stamp,
                               FusionStats& st) {
  const LidarFusionConfig& cf = config_;
  const int na = static_cast<int>(active_tiles_.size());
  // Per active tile, in tile order, the residuals (point height - survey height) of the points
  // within the gate: the points are already shifted by the offset so far, so these are what
  // is left of it.
  std::vector<std::vector<float>> per_tile(static_cast<size_t>(na));
  const float gate = static_cast<float>(cf.datum_gate_m);
  ex.forEach(na, [&](int k) {
    const int t = active_tiles_[static_cast<size_t>(k)];
    const float* Z = map.tileData(survey_z_, t);
    if (!Z) return;
    std::vector<float>& out = per_tile[static_cast<size_t>(k)];
    for (const PointChunk& ch : point_chunks_)
      for (int q = ch.start[static_cast<size_t>(t)]; q < ch.start[static_cast<size_t>(t) + 1]; ++q) {
        const PointItem& it = ch.items[static_cast<size_t>(q)];
        const float r = it.z - Z[it.off];
        if (std::abs(r) < gate) out.push_back(r);  // NaN survey heights fail the test
      }
  });
  std::vector<float> r;
  for (const auto& v : per_tile) r.insert(r.end(), v.begin(), v.end());
  st.datum_points = static_cast<long>(r.size());
  if (st.datum_points < cf.datum_min_points) return;
  // The median: the ground changed since the survey (cuts, piles, ruts) is a minority of the
  // points within the gate and only moves the tail.
  auto mid = r.begin() + static_cast<long>(r.size() / 2);
  std::nth_element(r.begin(), mid, r.end());
  const double median = *mid;
  auto found = datum_.find(machine);
  const bool first = found == datum_.end();
  VerticalDatumRecord::Machine m = first ? VerticalDatumRecord::Machine{} : found->second;
  const double k = first || cf.datum_tau_s <= 0 ? 1.0 : 1.0 - std::exp(-std::max(0.0, stamp - m.stamp) / cf.datum_tau_s);
  const double next = m.offset_m + k * median;
  if (!(std::abs(next) <= cf.datum_max_m)) return;
  m.offset_m = next;
  m.stamp = stamp;
  m.points = st.datum_points;
  ++m.updates;
  datum_[machine] = m;
  st.datum_updated = true;
}

void LidarFusion::recordSurvey(LayeredMap& map) {
  for (const int t : active_tiles_) {
    const float* E = map.tileData(elev_, t);
    const float* Hh = map.tileData(hits_, t);
    if (!E || !Hh || !map.tryAllocateTile(t, {survey_z_})) continue;
    float* Z = map.mutableTileData(survey_z_, t);
    const int n = map.tileSize() * map.tileSize();
    for (int c = 0; c < n; ++c)
      if (Hh[c] > 0.0f) Z[c] = E[c];
  }
}

// The previous cloud's hit lists become prev_*, this cloud's are laid out; the tiles to visit
// (task_tiles_) in task order. Returns whether there are previous lists to clear.
bool LidarFusion::layoutHitLists(int ntiles) {
  // The previous cloud's hit lists become prev_*; this cloud's are laid out per tile with
  // room for every point of the tile (the distinct cells are at most that many).
  std::swap(hit_start_, prev_hit_start_);
  std::swap(hit_count_, prev_hit_count_);
  std::swap(hit_offs_, prev_hit_offs_);
  const bool have_prev = prev_hit_count_.size() == static_cast<size_t>(ntiles);
  hit_start_.resize(static_cast<size_t>(ntiles) + 1);
  hit_count_.assign(static_cast<size_t>(ntiles), 0);
  task_tiles_.clear();
  int run = 0;
  for (int t = 0; t < ntiles; ++t) {
    hit_start_[static_cast<size_t>(t)] = run;
    const int np = tile_points_[static_cast<size_t>(t)];
    run += np;
    if (np > 0 || (have_prev && prev_hit_count_[static_cast<size_t>(t)] > 0)) task_tiles_.push_back(t);
  }
  hit_start_[static_cast<size_t>(ntiles)] = run;
  hit_offs_.resize(static_cast<size_t>(run));
  // Heaviest tiles first (ties by tile index: a fixed order), so that the last tasks to run
  // are small and the threads finish together. Each tile is written by its own task only, so
  // the order changes nothing in the map; the statistics are integer sums.
  std::sort(task_tiles_.begin(), task_tiles_.end(), [&](int a, int b) {
    const int pa = tile_points_[static_cast<size_t>(a)], pb = tile_points_[static_cast<size_t>(b)];
    return pa != pb ? pa > pb : a < b;
  });
  return have_prev;
}

// A sparse map at its memory budget cannot take every new tile: which ones it gets is decided
// here, serially in tile order, so the result does not depend on the thread count; the points
// of a refused tile are dropped, counted, rather than the run failing half-way through a cloud.
// Per tile, whether it was refused (empty for a dense map: nothing to allocate).
std::vector<char> LidarFusion::tilesRefusedByBudget(LayeredMap& map) const {
  std::vector<char> refused;
  if (map.options().sparse) {
    refused.assign(static_cast<size_t>(map.tileCount()), 0);
    for (const int t : active_tiles_)
      refused[static_cast<size_t>(t)] = !map.tryAllocateTile(t, {elev_, var_, valid_, time_, ub_, isub_, hits_});
  }
  return refused;
}

// Clear the cells the previous cloud hit in tile t (a whole-tile fill would cost 16 KB per tile
// per cloud). An unallocated (sparse) tile already reads as 0. Runs inside the tile's own task.
void LidarFusion::clearPreviousHits(LayeredMap& map, int t) const {
  if (prev_hit_count_[static_cast<size_t>(t)] > 0 && map.tileData(hits_, t)) {
    float* H = map.mutableTileData(hits_, t);
    const std::uint32_t* o = prev_hit_offs_.data() + prev_hit_start_[static_cast<size_t>(t)];
    for (int q = 0; q < prev_hit_count_[static_cast<size_t>(t)]; ++q) H[o[q]] = 0.0f;
  }
}

void LidarFusion::fuseTiles(LayeredMap& map, const Executor& ex, FusionStats& st) {
  const bool have_prev = layoutHitLists(map.tileCount());
  const int nt = static_cast<int>(task_tiles_.size());
  std::vector<std::array<long, 5>> per(static_cast<size_t>(nt));
  const float k2 = static_cast<float>(config_.mahalanobis_thresh * config_.mahalanobis_thresh);
  const float ov = static_cast<float>(config_.outlier_variance_m2);
  const float vmax = static_cast<float>(config_.max_variance_m2);
  const float vmin = static_cast<float>(config_.min_variance_m2);
  const std::vector<char> refused = tilesRefusedByBudget(map);
  ex.forEach(nt, [&](int k) {
    const int t = task_tiles_[static_cast<size_t>(k)];
    if (have_prev) clearPreviousHits(map, t);
    if (tile_points_[static_cast<size_t>(t)] == 0) {
      per[static_cast<size_t>(k)] = {0, 0, 0, 0, 0};
      return;
    }
    if (!refused.empty() && refused[static_cast<size_t>(t)]) {
      hit_count_[static_cast<size_t>(t)] = 0;
      per[static_cast<size_t>(k)] = {0, 0, 0, tile_points_[static_cast<size_t>(t)], 0};
      return;
    }
    // mutableTileData inside the tile's own task: distinct tiles may be un-shared/allocated
    // concurrently (layered_map.hpp).
    float* E = map.mutableTileData(elev_, t);
    float* V = map.mutableTileData(var_, t);
    float* VAL = map.mutableTileData(valid_, t);
    float* TM = map.mutableTileData(time_, t);
    float* UB = map.mutableTileData(ub_, t);
    float* ISUB = map.mutableTileData(isub_, t);
    float* H = map.mutableTileData(hits_, t);
    std::uint32_t* hit_list = hit_offs_.data() + hit_start_[static_cast<size_t>(t)];
    int nhit = 0;
    long fused = 0, outl = 0, forgot = 0;
    // Chunks in order, each chunk's items of this tile in input order: input order overall.
    for (const PointChunk& ch : point_chunks_) {
      const PointItem* it = ch.items.data() + ch.start[static_cast<size_t>(t)];
      const PointItem* end = ch.items.data() + ch.start[static_cast<size_t>(t) + 1];
      for (; it != end; ++it) {
        // The cells of a large map are cache misses (7 layers each): ask for the cells of a
        // few items ahead so the misses overlap instead of stalling one after another.
        if (end - it > kPrefetchAhead) {
          const std::uint32_t po = it[kPrefetchAhead].off;
          for (float* layer : {E, V, VAL, TM, UB, ISUB, H}) __builtin_prefetch(layer + po, 1);
        }
        const std::uint32_t o = it->off;
        const float z = it->z, vp = it->var;
        const float h = E[o];
        float nh;
        // A known height without a variance breaks the height contract (docs/height_contract.md:
        // whoever writes a finite elevation writes its variance); treat it as unknown rather than
        // fuse with NaN weights.
        if (std::isnan(h) || std::isnan(V[o])) {
          // Unknown cell: the first point is the estimate (an uninformative prior).
          nh = z;
          V[o] = vp;
        } else {
          // Another writer (a blind cut with sigma_sv_m = 0) may have left less than the floor.
          const float v = std::max(V[o], vmin);
          const float r = z - h;
          const float s = v + vp;
          if (r * r > k2 * s) {
            ++outl;
            const float nv = v + ov;
            if (nv > vmax) {
              ++forgot;
              E[o] = kNaN;
              V[o] = kNaN;
              VAL[o] = 0.0f;
              UB[o] = kNaN;
              ISUB[o] = 0.0f;
            } else {
              V[o] = nv;
            }
            continue;
          }
          nh = (h * vp + z * v) / s;
          // n equal points would otherwise drive v to v_p/n -> 0 and freeze the cell; the
          // floor also keeps s > 0 for the next point (no 0/0 with identical heights).
          V[o] = std::max((v * vp) / s, vmin);
        }
        E[o] = nh;
        VAL[o] = 1.0f;
        TM[o] = 0.0f;
        const float hits = H[o];
        if (hits == 0.0f) hit_list[nhit++] = o;
        H[o] = hits + 1.0f;
        UB[o] = nh;
        ISUB[o] = 0.0f;
        ++fused;
      }
    }
    hit_count_[static_cast<size_t>(t)] = nhit;
    per[static_cast<size_t>(k)] = {fused, outl, forgot, 0, nhit};
  });
  for (int k = 0; k < nt; ++k) {
    st.points_fused += per[static_cast<size_t>(k)][0];
    st.outliers += per[static_cast<size_t>(k)][1];
    st.cells_forgotten += per[static_cast<size_t>(k)][2];
    st.dropped_tile_budget += per[static_cast<size_t>(k)][3];
    st.tile_budget_refusals += per[static_cast<size_t>(k)][3] > 0 ? 1 : 0;
    st.cells_fused += per[static_cast<size_t>(k)][4];
  }
  for (int t : active_tiles_) tile_known_[static_cast<size_t>(t)] = 1;
  st.tiles_touched = static_cast<long>(active_tiles_.size());
}

}  // namespace terramap::plugins
