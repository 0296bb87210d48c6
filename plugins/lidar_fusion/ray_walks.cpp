// lidar_fusion's ray walks of the visibility cleanup: the column traversal (block by block)
// and its two users, the exact walk of one ray and the fan walk of one azimuth bin.
#include "lidar_fusion.hpp"
#include "lidar_fusion_internal.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>

namespace terramap::plugins {

using namespace lidar_fusion_internal;

namespace {

/// Calls f(offset in the tile) for each cell of ray-walk block `block` of a T x T tile (blocks
/// numbered row-major, ceil(T / kRayBlock) per side; the last row and column may be partial).
template <class F>
inline void forEachBlockCell(int T, int block, F&& f) {
  const int nbs = (T + kRayBlock - 1) / kRayBlock;
  const int r0 = block / nbs * kRayBlock, c0 = block % nbs * kRayBlock;
  for (int r = r0; r < std::min(T, r0 + kRayBlock); ++r)
    for (int c = c0; c < std::min(T, c0 + kRayBlock); ++c) f(r * T + c);
}
/// The column traversal (Amanatides-Woo) of one ray over the grid, in grid coordinates
/// u = (xmax - x)/res, v = (ymax - y)/res (row i covers u in (i, i+1]). Each crossing's parameter
/// is computed from its grid line, t = (n - u0) / du, rather than accumulated, so a walk that
/// jumps over a block lands in exactly the cell and state the cell-by-cell walk reaches. An axis
/// the ray does not move along has its next crossing at +inf (the other axis is then always the
/// nearer one; a ray with both components zero ends in its first cell).
struct ColumnWalk {
  int i = 0, j = 0, si = 1, sj = 1;
  double dsi = 1, dsj = 1, u0 = 0, v0 = 0, idu = 0, idv = 0;
  double nbi = 0, nbj = 0;  // next grid lines (integers)
  double tmi = 0, tmj = 0;  // the ray parameters at which it crosses them
  double t1 = 0;            // the walk ends in the cell that holds t1

  /// The parameter of row line n (+inf on an axis the ray does not move along).
  double rowLine(int n) const { return idu != 0.0 ? (n - u0) * idu : std::numeric_limits<double>::infinity(); }
  double colLine(int n) const { return idv != 0.0 ? (n - v0) * idv : std::numeric_limits<double>::infinity(); }
  bool rowFirst() const { return tmi <= tmj; }
  void stepRow() { i += si, nbi += dsi, tmi = (nbi - u0) * idu; }
  void stepCol() { j += sj, nbj += dsj, tmj = (nbj - v0) * idv; }
  /// To the cell that holds t1, without reading the map (stopping at its edge).
  void toEnd(unsigned rows, unsigned cols) {
    while (std::min(tmi, tmj) < t1) {
      if (rowFirst()) {
        if (static_cast<unsigned>(i + si) >= rows) return;
        stepRow();
      } else {
        if (static_cast<unsigned>(j + sj) >= cols) return;
        stepCol();
      }
    }
  }
  /// Out of a block whose far lines far_r / far_c the ray crosses at t_r / t_c, tex the first
  /// of them (< t1): the crossings before it in the order the cell walk takes them (ties: row
  /// first), then the exit itself. The new cell may be off the map.
  void leaveBlock(int far_r, int far_c, double t_r, double t_c, double tex) {
    if (t_r <= t_c) {
      while (tmj < tex) stepCol();
      i = si > 0 ? far_r : far_r - 1, nbi = far_r + si, tmi = (nbi - u0) * idu;
    } else {
      while (tmi <= tex) stepRow();
      j = sj > 0 ? far_c : far_c - 1, nbj = far_c + sj, tmj = (nbj - v0) * idv;
    }
  }
};

/// The row (column) of n that holds the point at parameter t of a line from grid coordinate p0
/// moving dp per unit of t (row i covers (i, i+1]), clamped to the grid.
inline int gridCell(double p0, double dp, double t, int n) {
  return std::clamp(static_cast<int>(std::ceil(p0 + t * dp)) - 1, 0, n - 1);
}

/// The walk of the ray from the sensor (grid point u0, v0) along (dx, dy) (m, map frame),
/// clipped to [0, t1] (end margin, max length) and to the map box rows x cols (Liang-Barsky) of
/// cells res wide; false if nothing of it lies on the map. t0: where it enters.
bool startColumnWalk(double dx, double dy, double t1, double u0, double v0, double res, int rows,
                     int cols, ColumnWalk& cw, double& t0) {
  const double du = -dx / res, dv = -dy / res;
  t0 = 0.0;
  auto clip = [&](double p0, double dp, double hi) {
    if (dp == 0.0) {
      if (p0 < 0.0 || p0 > hi) t1 = -1.0;
      return;
    }
    double ta = (0.0 - p0) / dp, tb = (hi - p0) / dp;
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  };
  clip(u0, du, rows);
  clip(v0, dv, cols);
  if (!(t1 > t0)) return false;
  // Start cell: the one containing the point just after t0.
  const double tm = t0 + 1e-9 * (t1 - t0);
  cw.i = gridCell(u0, du, tm, rows);
  cw.j = gridCell(v0, dv, tm, cols);
  cw.si = du > 0 ? 1 : -1, cw.sj = dv > 0 ? 1 : -1;
  cw.dsi = cw.si, cw.dsj = cw.sj;
  cw.u0 = u0, cw.v0 = v0;
  cw.idu = du != 0.0 ? 1.0 / du : 0.0, cw.idv = dv != 0.0 ? 1.0 / dv : 0.0;
  cw.nbi = du > 0 ? cw.i + 1 : cw.i, cw.nbj = dv > 0 ? cw.j + 1 : cw.j;
  cw.tmi = cw.rowLine(static_cast<int>(cw.nbi)), cw.tmj = cw.colLine(static_cast<int>(cw.nbj));
  cw.t1 = t1;
  return true;
}

/// What a walk does on entering a block: read its cells, jump to its exit, or stop.
enum class BlockStep { Walk, Jump, Stop };

/// Walks `cw` from parameter `ta` to its end over the grid, block by block (L: the walk's tables,
/// LidarFusion::WalkLocals; per logical row and column an AxisBlock {tile, block, lo, hi}). On entering
/// a block, enter(tile, block in the tile, ta, tex) (tex: where the walk would leave it) decides;
/// a jump lands in exactly the cell and state the cell walk reaches. Otherwise
/// visit(i, j, tile, block index, offset in the tile, ta, tb) is called for each cell of the
/// block in walk order ([ta, tb]: the walk's parameters over the cell) and stops the walk by
/// returning false. On return cw holds the last cell on the map. Both cleanup walks (one ray,
/// one fan bin) go through here; inlined, so the callbacks cost no call.
template <class Locals, class Enter, class Visit>
__attribute__((always_inline)) inline void walkBlocks(ColumnWalk& cw, double ta, const Locals& L, Enter&& enter, Visit&& visit) {
  const unsigned Ru = L.rows, Cu = L.cols;
  const auto* const row_blocks = L.row_blocks;
  const auto* const col_blocks = L.col_blocks;
  const std::int32_t* const row_local = L.row_local;
  const std::int32_t* const col_local = L.col_local;
  while (true) {
    // Entering the block of (i, j), from a step or a jump that may have left the map.
    if (static_cast<unsigned>(cw.i) >= Ru) {
      cw.i -= cw.si;
      return;
    }
    if (static_cast<unsigned>(cw.j) >= Cu) {
      cw.j -= cw.sj;
      return;
    }
    const auto rb = row_blocks[cw.i], cb = col_blocks[cw.j];
    const std::int32_t tile = rb.tile + cb.tile;
    const int in_tile = rb.blk + cb.blk, blk = tile * L.blocks_per_tile + in_tile;
    const int far_r = cw.si > 0 ? rb.hi : rb.lo, far_c = cw.sj > 0 ? cb.hi : cb.lo;
    const double t_r = cw.rowLine(far_r), t_c = cw.colLine(far_c);
    const double tex = std::min(std::min(t_r, t_c), cw.t1);
    const BlockStep step = enter(tile, in_tile, ta, tex);
    if (step == BlockStep::Stop) return;
    if (step == BlockStep::Jump) {
      if (tex >= cw.t1) {  // the walk ends in this block
        cw.toEnd(Ru, Cu);
        return;
      }
      cw.leaveBlock(far_r, far_c, t_r, t_c, tex);
      ta = tex;
      continue;
    }
    // Walk the block cell by cell; the block's bounds keep (i, j) on the map.
    std::int32_t rl = row_local[cw.i], cl = col_local[cw.j];
    while (true) {
      const double tb = std::min(std::min(cw.tmi, cw.tmj), cw.t1);
      if (!visit(cw.i, cw.j, tile, blk, static_cast<std::uint32_t>(rl + cl), ta, tb)) return;
      if (tb >= cw.t1) return;
      ta = tb;
      if (cw.rowFirst()) {
        cw.stepRow();
        if (cw.i < rb.lo || cw.i >= rb.hi) break;  // next block
        rl = row_local[cw.i];
      } else {
        cw.stepCol();
        if (cw.j < cb.lo || cw.j >= cb.hi) break;
        cl = col_local[cw.j];
      }
    }
  }
}

constexpr float kRayPenetration = 1.0f;  // Item::aux of a ray passing below a stale surface

/// Highest point (map z, m) over its last column of a ray that ends there, the column entered
/// at horizontal distance da.
inline double endingRayZ(double Sz, double rho, double t_end, float dz, double da) {
  return dz >= 0.0f ? Sz + t_end * dz : Sz + (rho > 0.0 ? da / rho : 0.0) * dz;
}

}  // namespace

// A block's surface for the skip test, computed on the first entry of one of the slot's rays:
// the highest known cell this cloud did not hit, and -inf as the bound of a block without
// unknown cells (there is nothing to bound).
void LidarFusion::blockSurface(const RayWalkView& w, RayMinSlot& mins, std::int32_t tile, int block) const {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  const float* E = w.elev[static_cast<size_t>(tile)];
  const float* H = w.hits[static_cast<size_t>(tile)];
  float kmax = -kInf;
  bool unknown = false;
  forEachBlockCell(w.tile_side, block, [&](int off) {
    const float h = E[off];
    if (std::isnan(h)) unknown = true;
    else if (!(H && H[off] > 0.0f)) kmax = std::max(kmax, h);
  });
  const size_t b = static_cast<size_t>(tile) * static_cast<size_t>(blocks_per_tile_) + static_cast<size_t>(block);
  mins.block_kmax[b] = kmax;
  if (!unknown) mins.block_max[b] = -kInf;
}

// The largest minimum a slot holds over the unknown cells of one block (+inf where a cell has
// none, or the tile no buffer).
float LidarFusion::blockMax(const RayWalkView& w, const RayMinSlot& mins, std::int32_t tile, int block) const {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  const float* m = mins.active[static_cast<size_t>(tile)];
  if (!m) return kInf;
  const float* E = w.elev[static_cast<size_t>(tile)];
  float b = -kInf;
  forEachBlockCell(w.tile_side, block, [&](int off) {
    if (std::isnan(E[off])) b = std::max(b, m[off]);
  });
  return b;
}

// Whether a ray whose lowest point over a block is at zlow (m) would change no cell of it: no
// surface this cloud missed reaches up to zlow there, and the slot already bounds every unknown
// cell of the block at or below zlow. The block's surface is computed on the slot's first visit,
// its bound again (with `refresh`) only when a ray lowered one of its minima and the old bound
// does not decide; without `refresh` a block with unknown cells is never skipped.
// (Inlined into the walk: as a call it cost 10 % more instructions.)
__attribute__((always_inline)) inline bool LidarFusion::blockUnchanged(const RayWalkView& w, RayMinSlot& mins,
                                                                    std::int32_t tile, int block, double zlow, bool refresh) const {
  const size_t b = static_cast<size_t>(tile) * static_cast<size_t>(blocks_per_tile_) + static_cast<size_t>(block);
  if (std::isnan(mins.block_kmax[b])) blockSurface(w, mins, tile, block);
  if (!(zlow >= mins.block_kmax[b])) return false;
  const float zf = static_cast<float>(zlow);
  if (refresh && !(zf >= mins.block_max[b]) && mins.block_dirty[b]) {
    mins.block_max[b] = blockMax(w, mins, tile, block);
    mins.block_dirty[b] = 0;
  }
  return zf >= mins.block_max[b];
}

// An unknown cell under a ray at z (m): the slot's minimum over it lowered to z, its block
// marked (the bound the skip test keeps for the block may be stale).
__attribute__((always_inline)) inline void LidarFusion::lowerMinimum(RayMinSlot& mins, const WalkLocals& tab,
                                                                   std::int32_t tile, int blk, std::uint32_t off,
                                                                   double z) const {
  float* m = tab.active[tile];
  if (!m) m = minTile(mins, tile);
  const float zf = static_cast<float>(z);
  if (zf < m[off]) {
    m[off] = zf;
    tab.dirty[blk] = 1;
  }
}

LidarFusion::WalkLocals LidarFusion::walkLocals(const RayWalkView& w, RayMinSlot& mins) const {
  return WalkLocals{row_local_.data(),  col_local_.data(),  row_blocks_.data(), col_blocks_.data(),
                    blocks_per_tile_,   static_cast<unsigned>(w.rows), static_cast<unsigned>(w.cols),
                    w.elev.data(),      mins.active.data(), mins.block_dirty.data()};
}

// The slot's minimum buffer of a tile, allocated (all +inf) on first use and listed as active
// for phase B.
float* LidarFusion::minTile(RayMinSlot& mins, std::int32_t tile) const {
  std::unique_ptr<float[]>& buf = mins.tiles[static_cast<size_t>(tile)];
  if (!buf) {
    buf.reset(new float[static_cast<size_t>(ray_min_tile_cells_)]);
    std::fill(buf.get(), buf.get() + ray_min_tile_cells_, std::numeric_limits<float>::infinity());
  }
  mins.active[static_cast<size_t>(tile)] = buf.get();
  mins.list.push_back(tile);
  return buf.get();
}

std::array<double, 2> LidarFusion::surfaceGradient(const RayWalkView& w, int i, int j, float h) const {
  auto elevAt = [&](int li, int lj) -> float {
    if (li < 0 || lj < 0 || li >= w.rows || lj >= w.cols) return kNaN;
    return w.elev[static_cast<size_t>(row_tile_[static_cast<size_t>(li)] + col_tile_[static_cast<size_t>(lj)])]
                 [row_local_[static_cast<size_t>(li)] + col_local_[static_cast<size_t>(lj)]];
  };
  auto slope = [&](float a, float b, float m, double dist) {
    if (!std::isnan(a) && !std::isnan(b)) return (a - b) / (2.0 * dist);
    if (!std::isnan(a)) return (a - m) / dist;
    if (!std::isnan(b)) return (m - b) / dist;
    return 0.0;
  };
  // Row i-1 lies towards +x, column j-1 towards +y.
  return {slope(elevAt(i - 1, j), elevAt(i + 1, j), h, w.res), slope(elevAt(i, j - 1), elevAt(i, j + 1), h, w.res)};
}

// A known cell under the ray: a penetration item if the cell is stale (not measured by this
// cloud), its surface is above the ray by k sigma and the ray is not grazing. Rare next to the
// unknown-cell case: kept out of line, away from the walk's registers.
__attribute__((noinline)) void LidarFusion::staleCell(const RayWalkView& w, int i, int j, std::int32_t tile,
                                                      std::uint32_t off, float h, double zhi, double dirx,
                                                      double diry, double dirz, std::vector<Item>& items) const {
  if (!(staleBelow(w, tile, off, h) > zhi)) return;
  const auto [gx, gy] = surfaceGradient(w, i, j, h);
  if (notGrazing(gx, gy, dirx, diry, dirz)) items.push_back(Item{tile, off, static_cast<float>(zhi), kRayPenetration});
}

// The height a ray must pass below to clean a known cell of height h: its surface less k sigma
// (-inf for a cell this cloud measured: never cleaned by it).
double LidarFusion::staleBelow(const RayWalkView& w, std::int32_t tile, std::uint32_t off, float h) const {
  const float* ht = w.hits[static_cast<size_t>(tile)];
  if (ht && ht[off] > 0.0f) return -std::numeric_limits<double>::infinity();
  const float* vv = w.var[static_cast<size_t>(tile)];
  const double var = vv ? vv[off] : 0.0;
  return h - config_.mahalanobis_thresh * std::sqrt(std::max(var, 0.0));
}

// Whether a ray of unit direction dir meets a surface of gradient (gx, gy) at |cos| of at least
// cleanup_cos_thresh (a grazing ray cleans nothing).
bool LidarFusion::notGrazing(double gx, double gy, double dirx, double diry, double dirz) const {
  const double nn = std::sqrt(gx * gx + gy * gy + 1.0);
  return std::abs(-gx * dirx - gy * diry + dirz) / nn >= config_.cleanup_cos_thresh;
}

std::array<long, 3> LidarFusion::walkRayTask(const RayWalkView& w, RayMinSlot& mins, int c) {
  const LidarFusionConfig& cf = config_;
  std::vector<Item>& out = ray_chunks_[static_cast<size_t>(c)];
  out.clear();
  const RayTask task = ray_tasks_[static_cast<size_t>(c)];
  const float* ends = ray_order_.data();
  const WalkLocals tab = walkLocals(w, mins);
  const double Sz = w.sensor_z;
  long nrays = 0, ncells = 0, nread = 0;
  const bool may_skip = !force_cell_walk_;
  for (size_t q = 3 * static_cast<size_t>(task.begin); q < 3 * static_cast<size_t>(task.end); q += 3) {
    const double dx = ends[q], dy = ends[q + 1], dz = ends[q + 2];
    double L;
    const double t_end = rayWalkEnd(dx, dy, dz, cf.cleanup_end_margin_m, cf.max_ray_length_m, L);
    if (!(t_end > 0.0)) continue;
    ++nrays;
    ColumnWalk cw;
    double ta;
    if (!startColumnWalk(dx, dy, t_end, w.u0, w.v0, w.res, w.rows, w.cols, cw, ta)) continue;
    const int i_start = cw.i, j_start = cw.j;
    const double dirx = dx / L, diry = dy / L, dirz = dz / L;
    const bool up = dz >= 0;
    walkBlocks(
        cw, ta, tab,
        // The ray's lowest point over the block (its exit for a descending ray) decides: where no
        // cell of the block would change, the walk jumps to the block's exit.
        [&](std::int32_t tile, int in_tile, double t_in, double tex) {
          return may_skip && blockUnchanged(w, mins, tile, in_tile, Sz + (up ? t_in : tex) * dz, true) ? BlockStep::Jump
                                                                                                      : BlockStep::Walk;
        },
        [&](int i, int j, std::int32_t tile, int blk, std::uint32_t off, double t_a, double t_b) {
          // Highest point of the ray inside this column: the ground under the crossing is below it.
          const double zhi = Sz + (up ? t_b : t_a) * dz;
          const float h = tab.elev[tile][off];
          ++nread;
          if (std::isnan(h)) {
            lowerMinimum(mins, tab, tile, blk, off, zhi);
          } else if (h > zhi) {
            // (Necessary for h - k sigma > zhi, as k sigma >= 0: most known cells stop here.)
            staleCell(w, i, j, tile, off, h, zhi, dirx, diry, dirz, out);
          }
          return true;
        });
    // Cells the walk spans (visited or jumped over): one per crossing plus the first.
    ncells += std::abs(cw.i - i_start) + std::abs(cw.j - j_start) + 1;
  }
  return {nrays, ncells, nread};
}

// ---- the fan walk (CleanupWalk::Fan) -----------------------------------------------------------
//
// A LiDAR's rays come in azimuth columns: tens of rays at nearly one azimuth, which the exact
// walk takes one by one through nearly the same cells. The fan walk bins them by azimuth and
// walks each bin once, along its centre line. Over one column of that line (horizontal
// distances [da, db] from the sensor) the ray heights are those of the exact walk:
//  - a ray that goes on past the column is highest at its entry if it descends, at its exit
//    if it climbs: z = Sz + s * (s < 0 ? da : db). With the bin's rays sorted by reach R, those
//    going on are a suffix of them, and their lowest is the one of the suffix's smallest slope;
//  - a ray that ends in the column (da < R <= db) is highest at its entry if it descends, at
//    its end if it climbs; each ends once, so these are taken one by one.
// One read per cell for the whole bin, instead of one per ray.

// The bins [begin, end) of one task: each bin's rays sorted by reach (ties by input order: one
// order whatever the threads), the suffix minima of their slopes, then the centre line walked
// from the sensor to the farthest reach, jumping over the blocks that hold no unknown cell and
// no missed surface up to a lower bound of the bin's rays over the block (blockUnchanged
// without refreshing a block's bound on its unknown cells: a bin reads one cell per column, so
// recomputing that bound, 64 reads, cost more than it saved; and walking every block cost more
// in the demo than these jumps). Counters: rays, the cells each ray spans (of the centre line),
// the cells read.
std::array<long, 3> LidarFusion::walkFanTask(const RayWalkView& w, RayMinSlot& mins, int c, std::vector<double>& scratch) {
  std::vector<Item>& out = ray_chunks_[static_cast<size_t>(c)];
  out.clear();
  const RayTask task = ray_tasks_[static_cast<size_t>(c)];
  const int K = fan_slots_;
  const WalkLocals tab = walkLocals(w, mins);
  const double Sz = w.sensor_z;
  const bool may_skip = !force_cell_walk_;
  constexpr double kInf = std::numeric_limits<double>::infinity();
  long nrays = 0, ncells = 0, nread = 0;
  for (int b = task.begin; b < task.end; ++b) {
    const int r0 = fan_bin_start_[static_cast<size_t>(b)];
    const int n = fan_bin_start_[static_cast<size_t>(b) + 1] - r0;
    if (n == 0) continue;
    FanRay* rays = fan_rays_.data() + r0;
    std::sort(rays, rays + n, [](const FanRay& x, const FanRay& y) { return x.R < y.R || (x.R == y.R && x.seq < y.seq); });
    // The suffix minima of the slopes, and the reaches in a dense array (the walk's loops read
    // them every column), each with a sentinel at n: +inf ends every advance there.
    scratch.resize(2 * (static_cast<size_t>(n) + 1));
    double* const suffix = scratch.data();
    double* const reach = suffix + n + 1;
    suffix[n] = kInf;
    reach[n] = kInf;
    for (int k = n - 1; k >= 0; --k) {
      suffix[k] = std::min(suffix[k + 1], rays[k].s);
      reach[k] = rays[k].R;
    }
    nrays += n;
    const int face = b / K;
    const double cc = -1.0 + (b % K + 0.5) * 2.0 / K;
    const double ux = face == 0 ? 1.0 : face == 2 ? -1.0 : cc, uy = face == 1 ? 1.0 : face == 3 ? -1.0 : cc;
    const double un = std::sqrt(ux * ux + uy * uy), Rmax = rays[n - 1].R;
    const double lx = ux / un * Rmax, ly = uy / un * Rmax;
    ColumnWalk cw;
    double ta;
    if (!startColumnWalk(lx, ly, 1.0, w.u0, w.v0, w.res, w.rows, w.cols, cw, ta)) continue;
    // Cells each ray spans: those of the centre line from its first on the map to the one that
    // holds the ray's reach (or the map's edge), whether the walk reads them or jumps over them.
    {
      const double t0 = ta, t1 = cw.t1, du = -lx / w.res, dv = -ly / w.res;
      const int i0 = cw.i, j0 = cw.j;
      for (int k = 0; k < n; ++k) {
        if (t0 > 0.0 && !(rays[k].R > t0 * Rmax)) continue;  // ends before the map
        const double t = Rmax > 0.0 ? std::min(rays[k].R / Rmax, t1) : 0.0;
        ncells += std::abs(gridCell(w.u0, du, t, w.rows) - i0) + std::abs(gridCell(w.v0, dv, t, w.cols) - j0) + 1;
      }
    }
    int p = 0, q = 0;  // rays [p, q) end in the current column, [q, n) go on past it
    walkBlocks(
        cw, ta, tab,
        // No ray of the bin passes lower over the block than a descending one at the block's exit
        // (with the smallest slope of those still on: a lower bound), or than the sensor.
        [&](std::int32_t tile, int in_tile, double t_in, double tex) {
          const double dentry = t_in * Rmax;
          if (dentry > 0.0)
            while (reach[p] <= dentry) ++p;
          if (p == n) return BlockStep::Stop;
          const double zlow = Sz + std::min(suffix[static_cast<size_t>(p)], 0.0) * (tex * Rmax);
          return may_skip && blockUnchanged(w, mins, tile, in_tile, zlow, false) ? BlockStep::Jump : BlockStep::Walk;
        },
        [&](int i, int j, std::int32_t tile, int blk, std::uint32_t off, double t_a, double t_b) {
          const double da = t_a * Rmax, db = t_b * Rmax;
          // The rays over this column: those reaching past its entry (all of them in the sensor's).
          if (da > 0.0)
            while (reach[p] <= da) ++p;
          if (p == n) return false;
          q = std::max(q, p);
          while (reach[q] <= db) ++q;
          double z = kInf;  // the lowest of their highest points over the column
          for (int k = p; k < q; ++k) z = std::min(z, endingRayZ(Sz, rays[k].rho, rays[k].t_end, rays[k].dz, da));
          if (q < n) z = std::min(z, Sz + suffix[static_cast<size_t>(q)] * (suffix[static_cast<size_t>(q)] < 0.0 ? da : db));
          ++nread;
          const float h = tab.elev[tile][off];
          if (std::isnan(h)) {
            lowerMinimum(mins, tab, tile, blk, off, z);
          } else if (h > z) {
            staleFanCell(w, i, j, tile, off, h, rays, p, q, n, z, da, db, out);
          }
          return true;
        });
  }
  return {nrays, ncells, nread};
}

// A known cell under the bin's lowest ray (z): as staleCell, for each of the bin's rays over
// the column ([p, q) ending there, [q, n) going on), in their sorted order.
void LidarFusion::staleFanCell(const RayWalkView& w, int i, int j, std::int32_t tile, std::uint32_t off, float h,
                               const FanRay* rays, int p, int q, int n, double z, double da, double db,
                               std::vector<Item>& items) const {
  const double H = staleBelow(w, tile, off, h);
  if (!(H > z)) return;
  const auto [gx, gy] = surfaceGradient(w, i, j, h);
  const double Sz = w.sensor_z;
  for (int k = p; k < n; ++k) {
    const FanRay& r = rays[k];
    const double zk = k < q ? endingRayZ(Sz, r.rho, r.t_end, r.dz, da) : Sz + r.s * (r.s < 0.0 ? da : db);
    if (!(H > zk)) continue;
    const double dx = r.dx, dy = r.dy, dz = r.dz;
    const double L = std::sqrt(dx * dx + dy * dy + dz * dz);
    if (notGrazing(gx, gy, dx / L, dy / L, dz / L)) items.push_back(Item{tile, off, static_cast<float>(zk), kRayPenetration});
  }
}

}  // namespace terramap::plugins
