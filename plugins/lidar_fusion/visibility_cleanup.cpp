// lidar_fusion's visibility cleanup around the walks: the view, slots and tasks the walks
// need (exact rays or fan bins) and phase B, applying their minima and penetration items.
#include "lidar_fusion.hpp"
#include "lidar_fusion_internal.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace terramap::plugins {

using namespace lidar_fusion_internal;

namespace {

/// Rays per visibility-cleanup task (fixed: the tasks' contents never depend on threads).
constexpr int kRayTask = 1024;
/// Buckets of the counting sort that orders the rays by steepness.
constexpr int kRaySortBuckets = 2048;
/// Azimuth sectors (octants) of the ray walk: a worker walks a whole sector at a time.
constexpr int kRaySectors = 8;
/// Bins per task of the fan walk (fixed: the tasks' contents never depend on threads).
constexpr int kFanBinsPerTask = 16;

}  // namespace

// ---- visibility cleanup ----------------------------------------------------------------------

void LidarFusion::cleanup(LayeredMap& map, const Executor& ex, const Eigen::Vector3d& S, FusionStats& st) {
  const RayWalkView view = rayWalkView(map, S);
  const int slots = ex.threads();
  prepareRaySlots(slots, map.tileCount(), view.tile_cells);
  const bool fan = config_.cleanup_walk == CleanupWalk::Fan;
  if (fan) prepareFan(map, ex);
  else prepareRayTasks();
  prepareRayBlocks(map);
  const int nc = static_cast<int>(ray_tasks_.size());
  ray_chunks_.resize(static_cast<size_t>(nc));
  std::vector<std::array<long, 3>> per(static_cast<size_t>(nc));

  // Phase A: walk rays (one task per fixed run of rays, or of fan bins); reads the map only.
  // Over unknown cells a ray lowers its slot's per-cell minimum (min is exact and order-free, so
  // neither the task-to-thread assignment nor the order of rays changes the result); under
  // stale surfaces it emits a penetration item (phase B applies them so that their order does
  // not matter either).
  // Exact walk: each worker takes the next azimuth octant and walks its tasks in order, steepest
  // rays first, so the bounds its slot gathers over a block come from the rays that cross it and
  // let the higher rays skip it (walkRayTask). Which octants a slot gets changes only the work.
  // Fan walk: each worker takes the next task.
  std::atomic<int> next{0};
  const int groups = fan ? nc : kRaySectors;
  const int workers = std::max(1, std::min(slots, groups));
  ex.forEach(workers, [&](int) {
    // forEach runs inline (on the caller, maybe outside the arena) for one thread or one task.
    int slot = workers > 1 ? Executor::currentSlot() : 0;
    if (slot < 0 || slot >= slots)
      throw std::logic_error("lidar_fusion: worker slot " + std::to_string(slot) + " outside the executor's " +
                             std::to_string(slots));
    RayMinSlot& mins = ray_min_[static_cast<size_t>(slot)];
    std::vector<double> fan_scratch;  // fan: per bin, its rays' suffix slope minima and reaches
    for (int g = next.fetch_add(1); g < groups; g = next.fetch_add(1)) {
      if (fan) {
        per[static_cast<size_t>(g)] = walkFanTask(view, mins, g, fan_scratch);
        continue;
      }
      for (int c = ray_sector_start_[static_cast<size_t>(g)]; c < ray_sector_start_[static_cast<size_t>(g) + 1]; ++c)
        per[static_cast<size_t>(c)] = walkRayTask(view, mins, c);
    }
  });
  for (const auto& p : per) {
    st.rays += p[0];
    st.ray_cells += p[1];
    st.ray_cells_read += p[2];
  }
  applyRayResults(map, ex, st);
}

LidarFusion::RayWalkView LidarFusion::rayWalkView(const LayeredMap& map, const Eigen::Vector3d& S) {
  const Geometry& g = map.geometry();
  RayWalkView w;
  w.rows = g.size().x();
  w.cols = g.size().y();
  w.res = g.resolution();
  const Eigen::Array2d half = g.length() * 0.5;
  const double xmax = g.center().x() + half.x(), ymax = g.center().y() + half.y();
  w.u0 = (xmax - S.x()) / w.res;
  w.v0 = (ymax - S.y()) / w.res;
  w.sensor_z = S.z();
  const int ntiles = map.tileCount();
  w.tile_side = map.tileSize();
  w.tile_cells = map.tileSize() * map.tileSize();
  // Read-only views for phase A (the map is not written until phase B).
  w.elev.resize(static_cast<size_t>(ntiles));
  w.var.resize(static_cast<size_t>(ntiles));
  w.hits.resize(static_cast<size_t>(ntiles));
  // An unallocated (sparse) elevation tile reads as NaN: point it at a NaN tile, so the walk
  // needs no null test.
  nan_tile_.assign(static_cast<size_t>(w.tile_cells), kNaN);
  for (int t = 0; t < ntiles; ++t) {
    const float* e = map.tileData(elev_, t);
    w.elev[static_cast<size_t>(t)] = e ? e : nan_tile_.data();
    w.var[static_cast<size_t>(t)] = map.tileData(var_, t);
    w.hits[static_cast<size_t>(t)] = map.tileData(hits_, t);
  }
  return w;
}

// One ray-minimum buffer set per worker slot of the executor's arena (see RayMinSlot).
void LidarFusion::prepareRaySlots(int slots, int ntiles, int tile_cells) {
  if (ray_min_.size() != static_cast<size_t>(slots) || ray_min_[0].tiles.size() != static_cast<size_t>(ntiles) ||
      ray_min_tile_cells_ != tile_cells) {
    ray_min_.clear();
    ray_min_.resize(static_cast<size_t>(slots));
    for (RayMinSlot& m : ray_min_) {
      m.tiles.resize(static_cast<size_t>(ntiles));
      m.active.assign(static_cast<size_t>(ntiles), nullptr);
    }
    ray_min_tile_cells_ = tile_cells;
  }
}

void LidarFusion::prepareRayTasks() {
  // The rays by azimuth octant and, within one, steepest descent first (a stable counting sort;
  // the order changes only how much of the walk is skipped, never the result). Low rays bound
  // the unknown cells near the sensor first; the higher rays that follow find those blocks
  // already bounded below them and skip them. A worker walks a whole octant (its bounds are
  // per worker slot: see cleanup()). Tasks are fixed runs of at most kRayTask rays of one
  // octant (smaller than a chunk, so that the threads stay balanced although ray lengths differ).
  long nr = 0;
  for (const PointChunk& ch : point_chunks_) nr += static_cast<long>(ch.ray_ends.size() / 3);
  ray_keys_.resize(static_cast<size_t>(nr));
  constexpr int nkeys = kRaySectors * kRaySortBuckets;
  std::vector<int> start(nkeys + 1, 0);
  size_t q = 0;
  for (const PointChunk& ch : point_chunks_)
    for (size_t k = 0; k < ch.ray_ends.size(); k += 3, ++q) {
      const float dx = ch.ray_ends[k], dy = ch.ray_ends[k + 1], dz = ch.ray_ends[k + 2];
      const float L = std::sqrt(dx * dx + dy * dy + dz * dz);
      const float sine = L > 0.0f ? dz / L : 0.0f;  // NaN-free: the gates passed only finite points
      const int b = std::clamp(static_cast<int>((sine + 1.0f) * (0.5f * kRaySortBuckets)), 0, kRaySortBuckets - 1);
      const int octant = (dx < 0.0f ? 4 : 0) + (dy < 0.0f ? 2 : 0) + (std::abs(dx) < std::abs(dy) ? 1 : 0);
      const int key = octant * kRaySortBuckets + b;
      ray_keys_[q] = static_cast<std::uint16_t>(key);
      ++start[static_cast<size_t>(key) + 1];
    }
  for (int b = 0; b < nkeys; ++b) start[static_cast<size_t>(b) + 1] += start[static_cast<size_t>(b)];
  ray_sector_start_.resize(kRaySectors + 1);
  ray_tasks_.clear();
  for (int g = 0; g < kRaySectors; ++g) {
    ray_sector_start_[static_cast<size_t>(g)] = static_cast<int>(ray_tasks_.size());
    const int r0 = start[static_cast<size_t>(g) * kRaySortBuckets], r1 = start[static_cast<size_t>(g + 1) * kRaySortBuckets];
    for (int r = r0; r < r1; r += kRayTask) ray_tasks_.push_back({r, std::min(r1, r + kRayTask)});
  }
  ray_sector_start_[kRaySectors] = static_cast<int>(ray_tasks_.size());
  ray_order_.resize(3 * static_cast<size_t>(nr));
  q = 0;
  for (const PointChunk& ch : point_chunks_)
    for (size_t k = 0; k < ch.ray_ends.size(); k += 3, ++q) {
      float* dst = &ray_order_[3 * static_cast<size_t>(start[ray_keys_[q]]++)];
      dst[0] = ch.ray_ends[k];
      dst[1] = ch.ray_ends[k + 1];
      dst[2] = ch.ray_ends[k + 2];
    }
}

// Per cloud, before the walk: every slot's block bounds reset (+inf: not bounded yet) and
// their surfaces marked not computed.
void LidarFusion::prepareRayBlocks(const LayeredMap& map) {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  const size_t nblocks = static_cast<size_t>(map.tileCount()) * static_cast<size_t>(blocks_per_tile_);
  for (RayMinSlot& m : ray_min_) {
    m.block_max.assign(nblocks, kInf);
    m.block_dirty.assign(nblocks, 0);
    m.block_kmax.assign(nblocks, kNaN);
  }
}

// The rays binned: the face of the square around the sensor their azimuth points at (+x, +y,
// -x, -y) and, along it, the slot of c = the other component over this one (|c| <= 1, slots
// 2/K wide, K per face). Binning on c needs no trigonometry, and a slot spans at most 2/K rad
// (d atan(c) / dc <= 1), so a ray lies within reach/K of its slot's centre line: K is chosen to
// make that cleanup_fan_lateral_cells. A stable counting sort over the point chunks (each
// chunk counts its rays per bin in parallel, then places them), so a bin holds its rays in
// input order whatever the threads.
void LidarFusion::prepareFan(const LayeredMap& map, const Executor& ex) {
  const LidarFusionConfig& cf = config_;
  const Geometry& g = map.geometry();
  const double reach = std::min(cf.max_ray_length_m, std::hypot(g.length().x(), g.length().y()));
  const double slots = std::ceil(reach / (cf.cleanup_fan_lateral_cells * g.resolution()));
  // Odd, so that one slot is centred on each axis: a ray along a grid axis keeps its own line.
  fan_slots_ = static_cast<int>(std::clamp(slots, 1.0, 16383.0)) | 1;
  const int K = fan_slots_, nbins = 4 * K;
  const int nch = static_cast<int>(point_chunks_.size());
  std::vector<size_t> first(static_cast<size_t>(nch) + 1, 0);
  for (int c = 0; c < nch; ++c)
    first[static_cast<size_t>(c) + 1] = first[static_cast<size_t>(c)] + point_chunks_[static_cast<size_t>(c)].ray_ends.size() / 3;
  fan_keys_.resize(first[static_cast<size_t>(nch)]);
  fan_ends_.resize(first[static_cast<size_t>(nch)]);
  fan_hist_.resize(static_cast<size_t>(nch));
  ex.forEach(nch, [&](int c) {
    const std::vector<float>& e = point_chunks_[static_cast<size_t>(c)].ray_ends;
    std::vector<int>& hist = fan_hist_[static_cast<size_t>(c)];
    hist.assign(static_cast<size_t>(nbins), 0);
    std::uint32_t* key = fan_keys_.data() + first[static_cast<size_t>(c)];
    double* t_end = fan_ends_.data() + first[static_cast<size_t>(c)];
    for (size_t k = 0; k < e.size(); k += 3) {
      const double dx = e[k], dy = e[k + 1], dz = e[k + 2];
      double L;
      t_end[k / 3] = rayWalkEnd(dx, dy, dz, cf.cleanup_end_margin_m, cf.max_ray_length_m, L);
      if (!(t_end[k / 3] > 0.0)) {
        key[k / 3] = ~0u;
        continue;
      }
      const double ax = std::abs(dx), ay = std::abs(dy);
      int face;
      double cc;
      if (ax >= ay) {
        face = dx >= 0.0 ? 0 : 2;
        cc = ax > 0.0 ? dy / ax : 0.0;  // a vertical ray: the sensor's own column, any bin
      } else {
        face = dy > 0.0 ? 1 : 3;
        cc = dx / ay;
      }
      const int slot = std::clamp(static_cast<int>((cc + 1.0) * 0.5 * K), 0, K - 1);
      const std::uint32_t b = static_cast<std::uint32_t>(face * K + slot);
      key[k / 3] = b;
      ++hist[b];
    }
  });
  // Bin-major, chunk-minor: each chunk's count becomes its first place in the bin.
  fan_bin_start_.resize(static_cast<size_t>(nbins) + 1);
  int pos = 0;
  for (int b = 0; b < nbins; ++b) {
    fan_bin_start_[static_cast<size_t>(b)] = pos;
    for (int c = 0; c < nch; ++c) {
      int& h = fan_hist_[static_cast<size_t>(c)][static_cast<size_t>(b)];
      const int n = h;
      h = pos;
      pos += n;
    }
  }
  fan_bin_start_[static_cast<size_t>(nbins)] = pos;
  fan_rays_.resize(static_cast<size_t>(pos));
  ex.forEach(nch, [&](int c) {
    const std::vector<float>& e = point_chunks_[static_cast<size_t>(c)].ray_ends;
    int* place = fan_hist_[static_cast<size_t>(c)].data();
    const std::uint32_t* key = fan_keys_.data() + first[static_cast<size_t>(c)];
    const double* t_end = fan_ends_.data() + first[static_cast<size_t>(c)];
    for (size_t k = 0; k < e.size(); k += 3) {
      const std::uint32_t b = key[k / 3];
      if (b == ~0u) continue;
      FanRay& r = fan_rays_[static_cast<size_t>(place[b]++)];
      const double dx = e[k], dy = e[k + 1], dz = e[k + 2];
      r.t_end = t_end[k / 3];
      r.rho = std::sqrt(dx * dx + dy * dy);
      r.R = r.t_end * r.rho;
      r.s = r.rho > 0.0 ? dz / r.rho : 0.0;
      r.dx = e[k], r.dy = e[k + 1], r.dz = e[k + 2];
      r.seq = static_cast<std::uint32_t>(first[static_cast<size_t>(c)] + k / 3);
    }
  });
  ray_tasks_.clear();
  for (int b = 0; b < nbins; b += kFanBinsPerTask) ray_tasks_.push_back({b, std::min(nbins, b + kFanBinsPerTask)});
}

// Phase B, one task per tile that has ray minima or penetration items: apply the minima
// (and reset the buffers), then the penetration items in ray order.
void LidarFusion::applyRayResults(LayeredMap& map, const Executor& ex, FusionStats& st) {
  const LidarFusionConfig& cf = config_;
  const int ntiles = map.tileCount();
  const int tile_cells = map.tileSize() * map.tileSize();
  constexpr float kInf = std::numeric_limits<float>::infinity();
  binItems(ex, ray_chunks_, ntiles);  // penetration items, stable by tile
  std::vector<char> mark(static_cast<size_t>(ntiles), 0);
  for (const RayMinSlot& m : ray_min_)
    for (int t : m.list) mark[static_cast<size_t>(t)] = 1;
  for (int t : ray_tiles_) mark[static_cast<size_t>(t)] = 1;
  std::vector<int> tiles;
  for (int t = 0; t < ntiles; ++t)
    if (mark[static_cast<size_t>(t)]) tiles.push_back(t);
  const int na = static_cast<int>(tiles.size());
  std::vector<std::array<long, 4>> res3(static_cast<size_t>(na));
  const float step = static_cast<float>(cf.cleanup_step);
  const float ov = static_cast<float>(cf.outlier_variance_m2);
  // As in fuseTiles: a sparse map's tiles are allocated here, serially in tile order (tiles is
  // ascending), for the bounds (upper_bound, is_upper_bound) and the penetration items (which
  // lie over valid cells: elevation exists, the other layers may not). 1 = no room for bounds,
  // 2 = none for items.
  std::vector<char> refused(static_cast<size_t>(na), 0);
  if (map.options().sparse)
    for (int q = 0; q < na; ++q) {
      const int t = tiles[static_cast<size_t>(q)];
      bool bounds = false;
      for (const RayMinSlot& m : ray_min_) bounds = bounds || m.active[static_cast<size_t>(t)] != nullptr;
      char& r = refused[static_cast<size_t>(q)];
      if (bounds && !map.tryAllocateTile(t, {ub_, isub_})) r |= 1;
      if (bin_start_[static_cast<size_t>(t) + 1] > bin_start_[static_cast<size_t>(t)] &&
          !map.tryAllocateTile(t, {elev_, var_, valid_, ub_, isub_}))
        r |= 2;
    }
  ex.forEach(na, [&](int q) {
    const int t = tiles[static_cast<size_t>(q)];
    long pen = 0, inv = 0, ubs = 0;
    std::vector<float*> bufs;
    for (RayMinSlot& m : ray_min_) {
      float*& a = m.active[static_cast<size_t>(t)];
      if (a) bufs.push_back(a);
      a = nullptr;
    }
    const int nb = static_cast<int>(bufs.size());
    const char no_room = refused[static_cast<size_t>(q)];
    if (nb > 0 && (no_room & 1)) {
      // No room for this tile's upper bounds: skip them, with the buffers reset for the next cloud.
      for (float* b : bufs) std::fill(b, b + tile_cells, kInf);
    } else if (nb > 0) {
      // Cells that were unknown in phase A (and still are: phase B changes valid cells only).
      float* UB = map.mutableTileData(ub_, t);
      float* ISUB = map.mutableTileData(isub_, t);
      for (int cidx = 0; cidx < tile_cells; ++cidx) {
        float m = bufs[0][cidx];
        bufs[0][cidx] = kInf;
        for (int b = 1; b < nb; ++b) {
          m = std::min(m, bufs[b][cidx]);
          bufs[b][cidx] = kInf;
        }
        if (m == kInf) continue;
        if (!(UB[cidx] <= m)) UB[cidx] = m;  // also replaces NaN (no bound yet)
        ISUB[cidx] = 1.0f;
        ++ubs;
      }
    }
    const int b0 = bin_start_[static_cast<size_t>(t)], b1 = bin_start_[static_cast<size_t>(t) + 1];
    if (b1 > b0 && !(no_room & 2)) {
      float* Ew = map.mutableTileData(elev_, t);
      float* Vw = map.mutableTileData(var_, t);
      float* VAL = map.mutableTileData(valid_, t);
      float* UB = map.mutableTileData(ub_, t);
      float* ISUB = map.mutableTileData(isub_, t);
      for (int b = b0; b < b1; ++b) {
        const Item& it = binned_[static_cast<size_t>(b)];
        const std::uint32_t o = it.off;
        if (std::isnan(Ew[o])) {
          // Invalidated by an earlier ray of this cloud (its bound: the loop below).
          ++ubs;
          continue;
        }
        ++pen;
        VAL[o] -= step;
        Vw[o] += ov;
        if (VAL[o] < 0.5f) {
          ++inv;
          Ew[o] = kNaN;
          Vw[o] = kNaN;
          VAL[o] = 0.0f;
          UB[o] = it.z;
          ISUB[o] = 1.0f;
        }
      }
      // A cell invalidated by this cloud is bounded by the lowest of all its rays, those before
      // the invalidating one included: the result does not depend on the order of the rays
      // (phase A walks them steepest first, not in input order).
      for (int b = b0; b < b1; ++b) {
        const Item& it = binned_[static_cast<size_t>(b)];
        if (std::isnan(Ew[it.off]) && it.z < UB[it.off]) UB[it.off] = it.z;
      }
    }
    res3[static_cast<size_t>(q)] = {pen, inv, ubs, no_room ? 1 : 0};
  });
  for (RayMinSlot& m : ray_min_) m.list.clear();
  for (int q = 0; q < na; ++q) {
    st.cells_penetrated += res3[static_cast<size_t>(q)][0];
    st.cells_invalidated += res3[static_cast<size_t>(q)][1];
    st.upper_bounds += res3[static_cast<size_t>(q)][2];
    st.tile_budget_refusals += res3[static_cast<size_t>(q)][3];
    tile_known_[static_cast<size_t>(tiles[static_cast<size_t>(q)])] = 1;
  }
}

}  // namespace terramap::plugins
