// Per-scan polar horizon table + exact cell walk (see scan_caster.hpp for why it is exact).
#include <terramap/sim/scan_caster.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

namespace terramap::sim {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr float kNegInf = -std::numeric_limits<float>::infinity();
/// Pyramid level of the blocks inserted into the table (2^4 = 16 cells = 32 cm at 2 cm); range
/// bins are half a block (16 cm). Measured best trade-off of table build vs cell walk.
constexpr int kBlockLevel = 4;
/// Upper bound of blocks inserted per scan: coarser blocks beyond it (huge worlds).
constexpr double kMaxBlocks = 150000;
/// Azimuth bins of the table (0.35 deg, an OS1's column spacing). Rays of one LiDAR column share a bin.
constexpr int kAzimuthBins = 1024;
/// Range bins are grouped by this many for skipping (a ray tests one group maximum first).
constexpr int kGroup = 16;
/// Pseudo-angle margin added on both sides of a block's azimuth interval.
constexpr double kAzMargin = 1e-9;
/// Range bins whose bound is computed per block (a block spans ~sqrt(2) + 1 bins).
constexpr int kMaxSpan = 8;
/// Candidate range bins walked per exact cell walk.
constexpr int kRunBins = 2;

/// Pseudo-angle in [0, 4): monotonic in atan2(y, x) taken counter-clockwise from +x
/// ("diamond angle"); one division, no trigonometry.
inline double pseudoAngle(double x, double y) {
  if (y >= 0) return x >= 0 ? y / (x + y) : 1.0 + (-x) / (-x + y);
  return x <= 0 ? 2.0 + (-y) / (-x - y) : 3.0 + x / (x - y);
}

/// A slope bound rounded up to float with a margin far above the rounding of any ray's slope.
inline float upperBound(double v) {
  if (std::isinf(v)) return static_cast<float>(v);
  v += std::abs(v) * 1e-6 + 1e-7;
  // Float rounding may go down by half an ulp: always step up by an ulp-sized relative amount
  // (cheaper than nextafter, and than a branch on the rounding direction, which is random).
  const float f = static_cast<float>(v);
  return f + (std::abs(f) * 1.2e-7f + 1e-30f);
}

/// Pyramid level of the blocks: `preferred`, coarser while the disc within `reach` (or the
/// grid, if smaller) holds more than kMaxBlocks blocks.
int chooseBlockLevel(const TruthTerrain& terrain, double reach, int preferred) {
  const double res = terrain.resolution();
  int level = std::min(preferred, terrain.pyramidLevels() - 1);
  while (level + 1 < terrain.pyramidLevels()) {
    const double bs = std::ldexp(res, level);
    const double area = std::min(M_PI * reach * reach, (terrain.maxX() - terrain.originX() + bs) *
                                                         (terrain.maxY() - terrain.originY() + bs));
    if (area / (bs * bs) <= kMaxBlocks) break;
    ++level;
  }
  return level;
}

/// What inserting blocks into the table needs: the block grid (relative to the scan origin),
/// the table's shape and the scan's steepest downward slope.
struct BlockGrid {
  const float* zmax;  // block maxima, [by * W + bx]
  int W, H;
  double bs, gx0, gy0, gx1, gy1;  // block size; grid corners relative to the origin (m)
  double oz, reach, min_slope;
  int na, nr;
  double ds, inv_ds, az_scale;
  float* table;  // [a * nr + r]
};

/// Bins [a0, a1] (may wrap below 0 or past na) that the block whose corners have pseudo-angles
/// c00, c10, c01, c11 can be seen in: the azimuth interval of a convex block seen from outside
/// (< 180 deg) is spanned by its corners. Differences to one corner are wrapped into (-2, 2].
void blockAzimuthBins(int na, double az_scale, double c00, double c10, double c01, double c11, int& a0, int& a1) {
  double lo = 0, hi = 0;
  for (const double pq : {c10, c01, c11}) {
    double q = pq - c00;
    if (q > 2.0) q -= 4.0;
    else if (q <= -2.0) q += 4.0;
    lo = std::min(lo, q);
    hi = std::max(hi, q);
  }
  // floor() of values in (-2 na, 2 na) via a positive shift (std::floor is a libm call
  // without SSE4.1).
  a0 = static_cast<int>((c00 + lo - kAzMargin) * az_scale + 2 * na) - 2 * na;
  a1 = static_cast<int>((c00 + hi + kAzMargin) * az_scale + 2 * na) - 2 * na;
  if (a1 - a0 >= na) { a0 = 0; a1 = na - 1; }
}

/// Azimuth bin a of [-na, 2 na) wrapped into [0, na).
inline int wrapBin(int a, int na) { return a < 0 ? a + na : (a >= na ? a - na : a); }

/// Distance from 0 to the interval [lo, hi] (0 inside it).
inline double nearestOffset(double lo, double hi) { return lo > 0 ? lo : (hi < 0 ? -hi : 0.0); }

/// Raises the table's bins [a0, a1] x [r0, r1] (azimuth bins outside [bin0, bin1) left to
/// another task) to the slope bounds of a block dz above the origin, smin..smax away.
void raiseBins(const BlockGrid& g, double dz, double smin, double smax, int r0, int r1, int a0, int a1, int bin0,
               int bin1) {
  float fv[kMaxSpan];
  const int nrr = std::min(kMaxSpan, r1 - r0 + 1);
  for (int q = 0; q < nrr; ++q) {
    const int r = r0 + q;
    double v;
    if (dz > 0) {
      const double s = std::max(smin, r * g.ds);
      v = s > 0 ? dz / s : std::numeric_limits<double>::infinity();
    } else {
      const double s = std::min(smax, (r + 1) * g.ds);
      v = s > 0 ? dz / s : std::numeric_limits<double>::infinity();
    }
    fv[q] = upperBound(v);
  }
  // Blocks spanning more range bins than kMaxSpan (only near a huge block) use a bound
  // valid for all of them: the last one if the block is above the origin (the bound falls
  // with range), dz / smax if below (it rises towards that).
  const float tail = dz > 0 ? fv[nrr - 1] : upperBound(dz / smax);
  for (int a = a0; a <= a1; ++a) {
    const int aw = wrapBin(a, g.na);
    if (aw < bin0 || aw >= bin1) continue;
    float* slot = &g.table[static_cast<std::size_t>(aw) * g.nr + r0];
    for (int q = 0; q < nrr; ++q) slot[q] = std::max(slot[q], fv[q]);
    for (int q = nrr; q <= r1 - r0; ++q) slot[q] = std::max(slot[q], tail);
  }
}

/// Clears the table's azimuth bins of part p (of `parts`, 1 or 4 quadrants) and inserts every
/// block that can be seen in them. With four parts, each task writes only its own bins of the
/// one table (no per-task tables to clear and merge) and walks only the blocks that can reach
/// its quadrant: those on its side of the origin's row and column, plus two rows / columns of
/// overlap (a block two blocks off an axis is at least two bins away from the neighbouring
/// quadrant, for any reach allowed by kMaxBlocks).
void insertBlocks(const BlockGrid& g, int p, int parts) {
  const int W = g.W, H = g.H, quarter = g.na / 4;
  const double bs = g.bs, gx0 = g.gx0, gy0 = g.gy0, gx1 = g.gx1, gy1 = g.gy1;
  int by0 = 0, by1 = H, bx0 = 0, bx1 = W;
  const int bin0 = parts == 4 ? p * quarter : 0, bin1 = parts == 4 ? (p + 1) * quarter : g.na;
  std::fill(g.table + static_cast<std::ptrdiff_t>(bin0) * g.nr, g.table + static_cast<std::ptrdiff_t>(bin1) * g.nr,
            kNegInf);
  if (parts == 4) {
    // Block (bx, by) spans [gx0 + bx bs, gx0 + (bx + 1) bs] x [gy0 + by bs, ...] around the origin.
    const int axis_x = static_cast<int>(std::floor(-gx0 / bs)), axis_y = static_cast<int>(std::floor(-gy0 / bs));
    const bool east = p == 0 || p == 3, north = p == 0 || p == 1;
    if (east) bx0 = std::clamp(axis_x - 2, 0, W);
    else bx1 = std::clamp(axis_x + 3, 0, W);
    if (north) by0 = std::clamp(axis_y - 2, 0, H);
    else by1 = std::clamp(axis_y + 3, 0, H);
  }
  std::vector<double> pa0(W + 1), pa1(W + 1);
  for (int by = by0; by < by1; ++by) {
    const double y0 = gy0 + by * bs, y1 = std::min(gy0 + (by + 1) * bs, gy1);
    const double dyn = nearestOffset(y0, y1);
    const double dyf = std::max(std::abs(y0), std::abs(y1));
    // Pseudo-angles of this row's block corners (shared by neighbouring blocks).
    for (int k = bx0; k <= bx1; ++k) {
      const double x = std::min(gx0 + k * bs, gx1);
      pa0[k] = (x != 0.0 || y0 != 0.0) ? pseudoAngle(x, y0) : 0.0;
      pa1[k] = (x != 0.0 || y1 != 0.0) ? pseudoAngle(x, y1) : 0.0;
    }
    for (int bx = bx0; bx < bx1; ++bx) {
      const double x0 = gx0 + bx * bs, x1 = std::min(gx0 + (bx + 1) * bs, gx1);
      const double dxn = nearestOffset(x0, x1);
      const double smin = std::sqrt(dxn * dxn + dyn * dyn);
      if (smin > g.reach) continue;
      const double dxf = std::max(std::abs(x0), std::abs(x1));
      const double smax = std::sqrt(dxf * dxf + dyf * dyf);
      const int r0 = static_cast<int>(smin * g.inv_ds);
      const int r1 = std::min(g.nr - 1, static_cast<int>(smax * g.inv_ds));
      int a0 = 0, a1 = g.na - 1;
      if (smin > 1e-6) blockAzimuthBins(g.na, g.az_scale, pa0[bx], pa0[bx + 1], pa1[bx], pa1[bx + 1], a0, a1);
      const double dz = static_cast<double>(g.zmax[static_cast<std::size_t>(by) * W + bx]) - g.oz;
      // No ray of the scan is steep enough to come down onto a block below it whose every
      // bound (the largest is dz / smax) is under the scan's steepest slope: leave it out.
      if (dz <= 0 && dz < g.min_slope * smax) continue;
      raiseBins(g, dz, smin, smax, r0, r1, a0, a1, bin0, bin1);
    }
  }
}

}  // namespace

// prepare / prefetch / finish are `inline` so they can be inlined into castBatch despite -fPIC
// (an exported, non-inline function may be interposed, which blocks inlining).

void ScanCaster::build(const TruthTerrain& terrain, const Eigen::Vector3d& origin, double max_range_m,
                       double min_slope, const Executor* exec) {
  terrain_ = &terrain;
  o_ = origin;
  const double res = terrain.resolution();
  inv_res_ = 1.0 / res;
  // Horizontal reach: the farthest grid corner, capped by the range.
  double far = 0;
  for (double x : {terrain.originX(), terrain.maxX()})
    for (double y : {terrain.originY(), terrain.maxY()}) far = std::max(far, std::hypot(x - o_.x(), y - o_.y()));
  const double reach = std::min(far, std::max(0.0, max_range_m));
  reach_ = reach;
  covers_grid_ = far <= max_range_m;
  top_ = terrain.pyramidMax(terrain.pyramidLevels() - 1)[0];
  // A sparse scan (a few hundred rays) casts too few rays to pay for the fine table: a quarter
  // of the azimuth bins and blocks twice as wide build it ~8x cheaper, and its rays walk a few
  // more cells.
  level_ = chooseBlockLevel(terrain, reach, sparse_ ? kBlockLevel + 1 : kBlockLevel);
  const double bs = std::ldexp(res, level_);
  ds_ = 0.5 * bs;
  inv_ds_ = 1.0 / ds_;
  na_ = sparse_ ? kAzimuthBins / 4 : kAzimuthBins;
  nr_ = static_cast<int>(std::floor(reach * inv_ds_)) + 1;
  ng_ = (nr_ + kGroup - 1) / kGroup;
  const std::size_t cells = static_cast<std::size_t>(na_) * nr_;
  bound_.resize(cells);
  const BlockGrid g{terrain.pyramidMax(level_), terrain.pyramidWidth(level_), terrain.pyramidHeight(level_), bs,
                    terrain.originX() - o_.x(), terrain.originY() - o_.y(), terrain.maxX() - o_.x(),
                    terrain.maxY() - o_.y(), o_.z(), reach, min_slope, na_, nr_, ds_, inv_ds_, na_ / 4.0,
                    bound_.data()};
  // With several threads the table is split by azimuth into the four quadrants (pseudo-angle
  // [q, q + 1)); four uneven tasks balance well enough on two threads by stealing.
  const int parts = (exec && exec->threads() > 1 && g.H > 1 && g.W > 1) ? 4 : 1;
  auto insertPart = [&](int p) { insertBlocks(g, p, parts); };
  if (exec && parts > 1) exec->forEach(parts, insertPart);
  else serialForEach(parts, insertPart);
  finishTable(exec);
}

// Per azimuth row: the group maxima, running maxima and row maximum. Rows are independent,
// so this runs in blocks of rows on the executor too. The table is the same for any number
// of parts (each bin is a maximum over the same blocks).
void ScanCaster::finishTable(const Executor* exec) {
  const std::size_t cells = static_cast<std::size_t>(na_) * nr_;
  group_.resize(static_cast<std::size_t>(na_) * ng_);
  prefix_.resize(cells);
  row_.resize(na_);
  constexpr int kRowsPerTask = 64;
  auto finishRows = [&](int task) {
    const int a0 = task * kRowsPerTask, a1 = std::min(na_, a0 + kRowsPerTask);
    for (int a = a0; a < a1; ++a) {
      const float* b = &bound_[static_cast<std::size_t>(a) * nr_];
      float* pre = &prefix_[static_cast<std::size_t>(a) * nr_];
      float rm = kNegInf;
      for (int g = 0; g < ng_; ++g) {
        float m = kNegInf;
        const int e = std::min(nr_, (g + 1) * kGroup);
        for (int r = g * kGroup; r < e; ++r) {
          m = std::max(m, b[r]);
          rm = std::max(rm, b[r]);
          pre[r] = rm;
        }
        group_[static_cast<std::size_t>(a) * ng_ + g] = m;
      }
      row_[a] = rm;
    }
  };
  const int tasks = (na_ + kRowsPerTask - 1) / kRowsPerTask;
  if (exec && exec->threads() > 1) exec->forEach(tasks, finishRows);
  else serialForEach(tasks, finishRows);
}

// Fills `ray` in place: returning the struct made the compiler assemble it on the stack with
// scalar stores and copy it with vector loads, a store-forwarding stall per ray (perf: 45 % of
// castBatch's samples on a depth camera).
inline void ScanCaster::prepare(const Eigen::Vector3d& d, double t_min, double t_max, Ray& ray) const {
  const TruthTerrain& T = *terrain_;
  ray.mode = Ray::Miss;
  ray.dep = kAlways;
  ray.inv_d[0] = ray.inv_d[1] = 0.0;
  // Rays that do not descend from above the highest point of the terrain cannot hit it.
  if (d.z() >= 0.0 && o_.z() > top_) return;  // mode Miss
  ray.dxy = std::sqrt(d.x() * d.x() + d.y() * d.y());
  if (ray.dxy >= 1e-9) {
    ray.m = d.z() / ray.dxy;
    int a = static_cast<int>(pseudoAngle(d.x(), d.y()) * (na_ / 4.0));
    if (a >= na_) a -= na_;
    ray.a = a;
    // Above every bound of its azimuth row: clear of the surface wherever the table reaches.
    ray.dep = nr_;
    if (covers_grid_ && ray.m > row_[a]) return;
    ray.dep = -1;  // a miss of the grid's extent depends on no bin
  }
  ray.t0 = t_min;
  ray.t1 = t_max;
  // Clip to the grid's xy extent (slab test; inlined here, this runs for every descending ray).
  {
    const double lo[2] = {T.originX(), T.originY()}, hi[2] = {T.maxX(), T.maxY()};
    for (int ax = 0; ax < 2; ++ax) {
      if (d[ax] == 0.0) {
        if (o_[ax] < lo[ax] || o_[ax] > hi[ax]) return;
        continue;
      }
      const double inv = 1.0 / d[ax];
      ray.inv_d[ax] = inv;
      double ta = (lo[ax] - o_[ax]) * inv, tb = (hi[ax] - o_[ax]) * inv;
      if (ta > tb) std::swap(ta, tb);
      ray.t0 = std::max(ray.t0, ta);
      ray.t1 = std::min(ray.t1, tb);
      if (ray.t0 > ray.t1) return;
    }
  }
  // (Near-)vertical rays stay in one or two cells: walk them directly.
  if (ray.dxy < 1e-9) {
    ray.mode = Ray::Direct;
    ray.ta = ray.t0;
    return;
  }
  const int r_first = static_cast<int>(ray.t0 * ray.dxy * inv_ds_);
  ray.r_last = static_cast<int>(ray.t1 * ray.dxy * inv_ds_);
  ray.dep = nr_;
  if (ray.r_last < nr_ && ray.m > row_[ray.a]) return;
  // First bin whose running maximum from the origin reaches m (binary search: the running
  // maximum never decreases). If it lies past r_first, every bin in between is clear.
  const float* pre = &prefix_[static_cast<std::size_t>(ray.a) * nr_];
  // Branch-free halving (the comparisons are unpredictable from ray to ray); pre[nr_] counts
  // as >= m.
  int lo = 0, len = nr_;
  while (len > 0) {
    const int half = len >> 1;
    const bool right = ray.m > pre[lo + half];
    lo = right ? lo + half + 1 : lo;
    len = right ? len - half - 1 : half;
  }
  ray.r = std::max(r_first, lo);
  ray.mode = Ray::Bins;
  ray.ta = std::max(ray.t0, ray.r * ds_ / ray.dxy * (1.0 - 1e-12));
}

inline void ScanCaster::prefetch(const Eigen::Vector3d& d, const Ray& ray) const {
  if (ray.mode == Ray::Miss || !(ray.ta <= ray.t1)) return;
  const TruthTerrain& T = *terrain_;
  const int ci = std::clamp(static_cast<int>((o_.x() + d.x() * ray.ta - T.originX()) * inv_res_), 0, T.nx() - 2);
  const int cj = std::clamp(static_cast<int>((o_.y() + d.y() * ray.ta - T.originY()) * inv_res_), 0, T.ny() - 2);
  const double* p = &T.heightData()[static_cast<std::size_t>(cj) * T.nx() + ci];
  __builtin_prefetch(p);
  __builtin_prefetch(p + T.nx());
}

inline double ScanCaster::finish(const Eigen::Vector3d& d, const Ray& ray, int* cell_i, int* cell_j,
                                 int& dep_r) const {
  const TruthTerrain& T = *terrain_;
  dep_r = ray.dep;
  if (ray.mode == Ray::Miss) return kNaN;
  dep_r = kAlways;
  if (ray.mode == Ray::Direct) return T.castCells(o_, d, ray.inv_d[0], ray.inv_d[1], ray.t0, ray.t1, cell_i, cell_j);
  const int r_end = std::min(ray.r_last, nr_ - 1);  // last range bin the table covers
  const float* row = &bound_[static_cast<std::size_t>(ray.a) * nr_];
  const float* grp = &group_[static_cast<std::size_t>(ray.a) * ng_];
  const double inv_dxy = 1.0 / ray.dxy;
  const double m = ray.m;
  int r = ray.r;
  while (r <= r_end) {
    if (r % kGroup == 0 && m > grp[r / kGroup]) {
      r += kGroup;
      continue;
    }
    if (m > row[r]) {
      ++r;
      continue;
    }
    // Walk a few candidate bins at a time: past the first candidate nearly every bin is one
    // (the ray is below the horizon there), and the hit is almost always in the first.
    int re = r;
    while (re < r_end && re - r < kRunBins - 1 && !(m > row[re + 1])) ++re;
    // Bin edges in ray parameter, widened by a relative hair against rounding.
    const double ta = std::max(ray.t0, r * ds_ * inv_dxy * (1.0 - 1e-12));
    const double tb = std::min(ray.t1, (re + 1) * ds_ * inv_dxy * (1.0 + 1e-12));
    const double t = T.castCells(o_, d, ray.inv_d[0], ray.inv_d[1], ta, tb, cell_i, cell_j);
    if (!std::isnan(t)) {
      // The walk read the row up to re + 1 (the run's extent) and the cells under bins <= re.
      dep_r = re + 1;
      return t;
    }
    r = re + 1;
  }
  if (ray.r_last >= nr_) {
    // Beyond the table's reach (t_max larger than the range it was built for): exact walk.
    const double ta = std::max(ray.t0, nr_ * ds_ * inv_dxy * (1.0 - 1e-12));
    return T.castCells(o_, d, ray.inv_d[0], ray.inv_d[1], ta, ray.t1, cell_i, cell_j);  // dep_r: kAlways
  }
  dep_r = nr_;
  return kNaN;
}

double ScanCaster::cast(const Eigen::Vector3d& d, double t_min, double t_max, int* cell_i, int* cell_j) const {
  Ray ray;
  prepare(d, t_min, t_max, ray);
  int dep_r;
  return finish(d, ray, cell_i, cell_j, dep_r);
}

void ScanCaster::castBatch(const Eigen::Vector3d* d, int n, double t_min, double t_max, double* t, int* cell_i,
                           int* cell_j, RayDep* dep) const {
  if (dep) castBatchAs<true>(d, n, t_min, t_max, t, cell_i, cell_j, dep);
  else castBatchAs<false>(d, n, t_min, t_max, t, cell_i, cell_j, dep);
}

template <bool kDeps>
void ScanCaster::castBatchAs(const Eigen::Vector3d* d, int n, double t_min, double t_max, double* t, int* cell_i,
                             int* cell_j, RayDep* dep) const {
  // Rays are independent, so locating the first candidate cell of a few rays and prefetching
  // its two rows before walking any of them overlaps their cache misses (a scan touches the
  // terrain at scattered places; the misses, not the arithmetic, set its speed).
  constexpr int kWindow = 8;
  Ray rays[kWindow];
  for (int k0 = 0; k0 < n; k0 += kWindow) {
    const int m = std::min(kWindow, n - k0);
    for (int q = 0; q < m; ++q) {
      prepare(d[k0 + q], t_min, t_max, rays[q]);
      prefetch(d[k0 + q], rays[q]);
    }
    for (int q = 0; q < m; ++q) {
      int dep_r;
      t[k0 + q] = finish(d[k0 + q], rays[q], &cell_i[k0 + q], &cell_j[k0 + q], dep_r);
      if constexpr (kDeps) dep[k0 + q] = {rays[q].a, dep_r};
    }
  }
}

void ScanCaster::changedRows(std::uint64_t since, std::vector<int>& first) const {
  first.assign(static_cast<std::size_t>(na_), kAlways);
  const TruthTerrain& T = *terrain_;
  const int B = TruthTerrain::kRevisionBlock;
  // A changed revision block moves the table's entries over its whole table block (the
  // table's blocks are at least as large: level >= 4), and the cells under the revision block.
  const int span = std::max(1 << level_, B);
  const double res = T.resolution();
  const int cells_x = T.nx() - 1, cells_y = T.ny() - 1;
  int last_bx = -1, last_by = -1;  // the table block last marked (neighbouring revision blocks share one)
  for (int by = 0; by < T.revisionHeight(); ++by)
    for (int bx = 0; bx < T.revisionWidth(); ++bx) {
      if (T.blockRevision(bx, by) <= since) continue;
      const int tx = bx * B / span, ty = by * B / span;
      if (tx == last_bx && ty == last_by) continue;
      last_bx = tx, last_by = ty;
      const double x0 = T.originX() + tx * span * res - o_.x(), y0 = T.originY() + ty * span * res - o_.y();
      const double x1 = T.originX() + std::min((tx + 1) * span, cells_x) * res - o_.x();
      const double y1 = T.originY() + std::min((ty + 1) * span, cells_y) * res - o_.y();
      const double smin = std::hypot(nearestOffset(x0, x1), nearestOffset(y0, y1));
      if (smin > reach_ + ds_) continue;  // beyond every ray the table serves
      const int r0 = std::max(0, static_cast<int>(smin * inv_ds_) - 1);
      int a0 = 0, a1 = na_ - 1;
      if (smin > 1e-6) {
        blockAzimuthBins(na_, na_ / 4.0, pseudoAngle(x0, y0), pseudoAngle(x1, y0), pseudoAngle(x0, y1),
                         pseudoAngle(x1, y1), a0, a1);
        --a0, ++a1;  // a bin more on each side
        if (a1 - a0 >= na_) a0 = 0, a1 = na_ - 1;
      }
      for (int a = a0; a <= a1; ++a) {
        int& f = first[static_cast<std::size_t>(wrapBin(a, na_))];
        f = std::min(f, r0);
      }
    }
}

}  // namespace terramap::sim
