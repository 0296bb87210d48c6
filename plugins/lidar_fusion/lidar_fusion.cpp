#include "lidar_fusion.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/submap_iterator.hpp>
#include <terramap/core/text.hpp>

#include <fnmatch.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <variant>

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define TERRAMAP_LIDAR_AVX2 1
#endif

namespace terramap::plugins {

namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
/// Points (and rays) per chunk. Fixed, so the chunking - and with it every reduction order -
/// does not depend on the thread count.
constexpr int kChunk = 8192;
/// Rays per visibility-cleanup task (fixed: the tasks' contents never depend on threads).
constexpr int kRayTask = 1024;
/// Side (cells) of the blocks the ray walk decides to skip or walk as a whole: small enough that
/// a ray high above the ground skips most of its path, large enough that the decision costs
/// little next to the cells it saves.
constexpr int kRayBlock = 8;
/// Buckets of the counting sort that orders the rays by steepness.
constexpr int kRaySortBuckets = 2048;
/// Azimuth sectors (octants) of the ray walk: a worker walks a whole sector at a time.
constexpr int kRaySectors = 8;
/// Bins per task of the fan walk (fixed: the tasks' contents never depend on threads).
constexpr int kFanBinsPerTask = 16;
/// Where the cleanup's walk of a ray (sensor-relative end dx, dy, dz in m) ends, as a fraction
/// of the ray: the end margin and max_ray_length_m cut it. Not walked unless > 0 (NaN too);
/// L is set to the ray's length.
inline double rayWalkEnd(double dx, double dy, double dz, double margin, double max_len, double& L) {
  L = std::sqrt(dx * dx + dy * dy + dz * dz);
  if (!(L > 1e-9)) return 0.0;
  return std::min({1.0, (L - margin) / L, max_len / L});
}
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

/// Items ahead of the current one whose cells the fusion loop prefetches.
constexpr int kPrefetchAhead = 8;
constexpr float kRayPenetration = 1.0f;  // Item::aux of a ray passing below a stale surface

// ---- gates: one point -> drop reason or cell ---------------------------------------------------

/// Drop reasons in the order the gates are applied (the first that fails is counted);
/// kInside = fused. Also the index into PointChunk::drops.
enum GateCode : std::int32_t { kNonFinite = 0, kTooClose, kTooFar, kTooHigh, kOutsideMap, kInside };

/// Everything the gate loop reads, by value: behind references the compiler would reload
/// each after every store.
struct GateConsts {
  double r00, r01, r02, r10, r11, r12, r20, r21, r22, tx, ty, tz;
  double xmax, ymax, res, rows, cols;
  double min_r, max_r, max_h, ramp_a, ramp_b, ramp_c;
  double noise_a, noise_b, noise_k, min_var;
  bool ramp, range_based;
};

/// Points gated per block: the block's results stay in L1 between the two passes.
constexpr int kGateBlock = 256;

/// One block of gate results (structure of arrays, for the vector kernel's stores).
struct GateBlock {
  alignas(32) std::int32_t code[kGateBlock];
  alignas(32) std::int32_t li[kGateBlock];  // logical row (0 unless kInside)
  alignas(32) std::int32_t lj[kGateBlock];  // logical column (0 unless kInside)
  alignas(32) float z[kGateBlock];          // map-frame z
  alignas(32) float var[kGateBlock];        // point variance
};

/// The map-frame position of a sensor-frame point: the one formula the gates, the rays and
/// the tests' reference use (left-to-right sums, no fused multiply-add).
inline void toMap(const GateConsts& k, double px, double py, double pz, double& x, double& y, double& z) {
  x = k.r00 * px + k.r01 * py + k.r02 * pz + k.tx;
  y = k.r10 * px + k.r11 * py + k.r12 * pz + k.ty;
  z = k.r20 * px + k.r21 * py + k.r22 * pz + k.tz;
}

/// The gates of one point: its GateCode and, if kInside, its cell and values. The portable
/// reference of gateAvx2 (and what runs where AVX2 does not).
inline GateCode gateOne(const PointXYZI& p, const GateConsts& k, std::int32_t& li, std::int32_t& lj, float& zf,
                        float& varf) {
  if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) return kNonFinite;
  const double px = p.x, py = p.y, pz = p.z;
  const double r = std::sqrt(px * px + py * py + pz * pz);
  if (r < k.min_r) return kTooClose;
  if (r > k.max_r) return kTooFar;
  double x, y, z;
  toMap(k, px, py, pz, x, y, z);
  const double dz = z - k.tz;
  if (dz > k.max_h) return kTooHigh;
  // The ramp allows at least c (a >= 0), so only points above c need the distance.
  if (k.ramp && dz > k.ramp_c) {
    const double dxy = std::sqrt((x - k.tx) * (x - k.tx) + (y - k.ty) * (y - k.ty));
    if (dz > std::max(dxy - k.ramp_b, 0.0) * k.ramp_a + k.ramp_c) return kTooHigh;
  }
  // Same arithmetic as Geometry::indexAt, so a point lands in the cell indexAt names.
  const double fi = (k.xmax - x) / k.res;
  const double fj = (k.ymax - y) / k.res;
  // Inside iff 0 < f <= size; then index = ceil(f) - 1 (truncation is floor for f > 0,
  // and avoids a libm call on targets without SSE4.1 rounding).
  if (!(fi > 0.0) || !(fj > 0.0) || !(fi <= k.rows) || !(fj <= k.cols)) return kOutsideMap;
  const int ti = static_cast<int>(fi), tj = static_cast<int>(fj);
  li = static_cast<double>(ti) == fi ? ti - 1 : ti;
  lj = static_cast<double>(tj) == fj ? tj - 1 : tj;
  double var;
  if (k.range_based) {
    const double sigma = k.noise_a + k.noise_b * r;
    var = sigma * sigma;
  } else {
    var = k.noise_k * pz * pz;
  }
  // The floor keeps a point from claiming certainty (a horizontal beam under depth_squared has
  // z_s = 0); (var < floor) ? floor : var, the operand order _mm256_max_pd(floor, var) matches.
  var = std::max(var, k.min_var);
  zf = static_cast<float>(z);
  varf = static_cast<float>(var);
  return kInside;
}

#ifdef TERRAMAP_LIDAR_AVX2
// (Helpers, not lambdas: a lambda does not inherit its enclosing function's target.)
/// A 64-bit lane mask as 4 x int32 (lanes 0, 2, 4, 6 of it viewed as eight 32-bit lanes).
__attribute__((target("avx2"))) inline __m128i mask32(__m256d m) {
  const __m256i pick_low = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
  return _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(_mm256_castpd_si256(m), pick_low));
}
/// m0 px + m1 py + m2 pz + t, summed left to right like toMap().
__attribute__((target("avx2"))) inline __m256d dot4(__m256d m0, __m256d m1, __m256d m2, __m256d t, __m256d px,
                                                   __m256d py, __m256d pz) {
  return _mm256_add_pd(
      _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(m0, px), _mm256_mul_pd(m1, py)), _mm256_mul_pd(m2, pz)), t);
}

/// gateOne four points at a time. Every value is computed with the same IEEE operations in
/// the same order (mul, add, sub, div, sqrt are correctly rounded; no FMA: the avx2 target
/// does not enable it), so the results are bit-identical to gateOne - tested.
__attribute__((target("avx2"))) void gateAvx2(const PointXYZI* pts, int n, const GateConsts& k, GateBlock& out) {
  const __m256d r00 = _mm256_set1_pd(k.r00), r01 = _mm256_set1_pd(k.r01), r02 = _mm256_set1_pd(k.r02);
  const __m256d r10 = _mm256_set1_pd(k.r10), r11 = _mm256_set1_pd(k.r11), r12 = _mm256_set1_pd(k.r12);
  const __m256d r20 = _mm256_set1_pd(k.r20), r21 = _mm256_set1_pd(k.r21), r22 = _mm256_set1_pd(k.r22);
  const __m256d tx = _mm256_set1_pd(k.tx), ty = _mm256_set1_pd(k.ty), tz = _mm256_set1_pd(k.tz);
  const __m256d xmax = _mm256_set1_pd(k.xmax), ymax = _mm256_set1_pd(k.ymax), res = _mm256_set1_pd(k.res);
  const __m256d rows = _mm256_set1_pd(k.rows), cols = _mm256_set1_pd(k.cols);
  const __m256d min_r = _mm256_set1_pd(k.min_r), max_r = _mm256_set1_pd(k.max_r), max_h = _mm256_set1_pd(k.max_h);
  const __m256d ra = _mm256_set1_pd(k.ramp_a), rb = _mm256_set1_pd(k.ramp_b), rc = _mm256_set1_pd(k.ramp_c);
  const __m256d na = _mm256_set1_pd(k.noise_a), nb = _mm256_set1_pd(k.noise_b), nk = _mm256_set1_pd(k.noise_k);
  const __m256d vfloor = _mm256_set1_pd(k.min_var);
  const __m256d zero = _mm256_setzero_pd();
  int q = 0;
  for (; q + 4 <= n; q += 4) {
    __m128 a = _mm_loadu_ps(&pts[q].x), b = _mm_loadu_ps(&pts[q + 1].x);
    __m128 c = _mm_loadu_ps(&pts[q + 2].x), d = _mm_loadu_ps(&pts[q + 3].x);
    _MM_TRANSPOSE4_PS(a, b, c, d);  // a = x, b = y, c = z of the four points
    // v - v is 0 for finite v, NaN for NaN or inf: all three finite iff the sum is ordered.
    const __m128 fsum = _mm_add_ps(_mm_add_ps(_mm_sub_ps(a, a), _mm_sub_ps(b, b)), _mm_sub_ps(c, c));
    const __m128i finite = _mm_castps_si128(_mm_cmpord_ps(fsum, fsum));
    const __m256d px = _mm256_cvtps_pd(a), py = _mm256_cvtps_pd(b), pz = _mm256_cvtps_pd(c);
    const __m256d r = _mm256_sqrt_pd(
        _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(px, px), _mm256_mul_pd(py, py)), _mm256_mul_pd(pz, pz)));
    const __m256d close = _mm256_cmp_pd(r, min_r, _CMP_LT_OQ);
    const __m256d far = _mm256_cmp_pd(r, max_r, _CMP_GT_OQ);
    const __m256d x = dot4(r00, r01, r02, tx, px, py, pz), y = dot4(r10, r11, r12, ty, px, py, pz),
                  z = dot4(r20, r21, r22, tz, px, py, pz);
    const __m256d dz = _mm256_sub_pd(z, tz);
    __m256d high = _mm256_cmp_pd(dz, max_h, _CMP_GT_OQ);
    const __m256d above_c = _mm256_cmp_pd(dz, rc, _CMP_GT_OQ);
    // Only lanes above c can fail the ramp (as in gateOne); ground points rarely are.
    if (k.ramp && _mm256_movemask_pd(above_c) != 0) {
      const __m256d ex = _mm256_sub_pd(x, tx), ey = _mm256_sub_pd(y, ty);
      const __m256d dxy = _mm256_sqrt_pd(_mm256_add_pd(_mm256_mul_pd(ex, ex), _mm256_mul_pd(ey, ey)));
      // max(zero, v) returns v when both are zeros or v is NaN, as std::max(v, 0.0) does.
      const __m256d lim = _mm256_add_pd(_mm256_mul_pd(_mm256_max_pd(zero, _mm256_sub_pd(dxy, rb)), ra), rc);
      high = _mm256_or_pd(high, _mm256_and_pd(above_c, _mm256_cmp_pd(dz, lim, _CMP_GT_OQ)));
    }
    const __m256d fi = _mm256_div_pd(_mm256_sub_pd(xmax, x), res);
    const __m256d fj = _mm256_div_pd(_mm256_sub_pd(ymax, y), res);
    const __m256d inside = _mm256_and_pd(
        _mm256_and_pd(_mm256_cmp_pd(fi, zero, _CMP_GT_OQ), _mm256_cmp_pd(fj, zero, _CMP_GT_OQ)),
        _mm256_and_pd(_mm256_cmp_pd(fi, rows, _CMP_LE_OQ), _mm256_cmp_pd(fj, cols, _CMP_LE_OQ)));
    const __m128i ti = _mm256_cvttpd_epi32(fi), tj = _mm256_cvttpd_epi32(fj);
    // index = trunc(f) - 1 where f is integral; the all-ones mask is -1.
    __m128i li = _mm_add_epi32(ti, mask32(_mm256_cmp_pd(_mm256_cvtepi32_pd(ti), fi, _CMP_EQ_OQ)));
    __m128i lj = _mm_add_epi32(tj, mask32(_mm256_cmp_pd(_mm256_cvtepi32_pd(tj), fj, _CMP_EQ_OQ)));
    __m256d var;
    if (k.range_based) {
      const __m256d sigma = _mm256_add_pd(na, _mm256_mul_pd(nb, r));
      var = _mm256_mul_pd(sigma, sigma);
    } else {
      var = _mm256_mul_pd(_mm256_mul_pd(nk, pz), pz);
    }
    // max_pd(a, b) = a > b ? a : b, so (floor, var) is std::max(var, floor) bit for bit.
    var = _mm256_max_pd(vfloor, var);
    // The first failing gate wins: apply them from the last to the first.
    const __m128i in32 = mask32(inside);
    __m128i code = _mm_blendv_epi8(_mm_set1_epi32(kOutsideMap), _mm_set1_epi32(kInside), in32);
    code = _mm_blendv_epi8(code, _mm_set1_epi32(kTooHigh), mask32(high));
    code = _mm_blendv_epi8(code, _mm_set1_epi32(kTooFar), mask32(far));
    code = _mm_blendv_epi8(code, _mm_set1_epi32(kTooClose), mask32(close));
    code = _mm_blendv_epi8(_mm_set1_epi32(kNonFinite), code, finite);
    const __m128i keep = _mm_cmpeq_epi32(code, _mm_set1_epi32(kInside));
    li = _mm_and_si128(li, keep);
    lj = _mm_and_si128(lj, keep);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out.code + q), code);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out.li + q), li);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out.lj + q), lj);
    const __m128 keepf = _mm_castsi128_ps(keep);
    _mm_storeu_ps(out.z + q, _mm_and_ps(_mm256_cvtpd_ps(z), keepf));
    _mm_storeu_ps(out.var + q, _mm_and_ps(_mm256_cvtpd_ps(var), keepf));
  }
  for (; q < n; ++q) {
    out.li[q] = out.lj[q] = 0;
    out.z[q] = out.var[q] = 0.0f;
    out.code[q] = gateOne(pts[q], k, out.li[q], out.lj[q], out.z[q], out.var[q]);
  }
}

bool cpuHasAvx2() {
  static const bool has = __builtin_cpu_supports("avx2");
  return has;
}
#endif

}  // namespace

// ---- parameters ------------------------------------------------------------------------------

ParamSchema lidarFusionSchema() {
  const double inf = std::numeric_limits<double>::infinity();
  return {
      param::text("sensor_noise", "range_based", {"range_based", "depth_squared"},
                  "noise model: range_based sigma = a + b*range (LiDAR); depth_squared v = k*z_s^2 "
                  "(camera, z_s = sensor-frame z)"),
      param::real("range_noise_a_m", 0.02, 0.0, 10.0, "m", "range_based: sigma at zero range"),
      param::real("range_noise_b", 0.001, 0.0, 1.0, "m/m", "range_based: sigma growth per metre of range"),
      param::real("sensor_noise_factor", 0.05, 0.0, 100.0, "1", "depth_squared: k in v = k*z_s^2"),
      param::texts("depth_squared_frames", {},
                   "clouds whose frame matches one of these shell patterns (e.g. '*/cam') use depth_squared "
                   "whatever sensor_noise says: a depth camera (points in its optical frame) beside a LiDAR"),
      param::real("min_range_m", 0.5, 0.0, inf, "m", "drop points closer to the sensor"),
      param::real("max_range_m", 100.0, 0.0, inf, "m", "drop points farther from the sensor"),
      param::real("max_height_above_sensor_m", 1.0, -inf, inf, "m",
                  "drop points higher than this above the sensor (map-frame z)"),
      param::boolean("enable_ramped_height_range", true,
                     "also drop z - z_sensor > max(d_xy - b, 0)*a + c (ceiling near the robot)"),
      param::real("ramped_height_range_a", 0.3, 0.0, inf, "m/m", "ramp slope"),
      param::real("ramped_height_range_b_m", 1.0, 0.0, inf, "m", "horizontal distance where the ramp starts"),
      param::real("ramped_height_range_c_m", 0.2, -inf, inf, "m", "height allowed next to the sensor"),
      param::real("min_variance_m2", 1e-6, 0.0, 1.0, "m^2",
                  "variance floor of every point and every fused cell (must be > 0)"),
      param::real("mahalanobis_thresh", 2.0, 0.0, inf, "1",
                  "outlier if |z - h| > k*sqrt(v_cell + v_point)"),
      param::real("outlier_variance_m2", 0.01, 0.0, inf, "m^2", "added to a cell's variance per outlier"),
      param::real("max_variance_m2", 100.0, 0.0, inf, "m^2",
                  "a cell whose variance exceeds this after an outlier is forgotten"),
      param::real("time_variance_m2_per_s", 0.0005, 0.0, inf, "m^2/s", "variance growth of valid cells"),
      param::boolean("enable_visibility_cleanup", true, "walk rays: clear stale cells, bound unknown ones"),
      param::integer("cleanup_ray_stride", 1, 1, 1000000, "walk the ray of every n-th point"),
      param::real("max_ray_length_m", 10.0, 0.0, inf, "m", "walk at most this far from the sensor"),
      param::real("cleanup_step", 0.1, 0.0, 1.0, "1", "is_valid lost per penetrating ray"),
      param::real("cleanup_cos_thresh", 0.1, 0.0, 1.0, "1",
                  "ignore rays whose |cos| to the surface normal is below this (grazing)"),
      param::real("cleanup_end_margin_m", 0.3, 0.0, inf, "m", "stop each walk this far before its point"),
      param::text("cleanup_walk", "fan", {"exact", "fan"},
                  "exact: each ray along its own line; fan: rays binned by azimuth, each bin walked once along "
                  "its centre line (within cleanup_fan_lateral_cells of every ray of the bin)"),
      param::real("cleanup_fan_lateral_cells", 0.5, 0.0, 8.0, "cells",
                  "fan walk: largest distance between a ray and its bin's centre line, at max_ray_length_m"),
      param::boolean("enable_drift_compensation", false, "shift the map by the mean inlier residual"),
      param::real("drift_compensation_alpha", 0.1, 0.0, 1.0, "1", "fraction of the mean residual applied"),
      param::real("drift_compensation_variance_inlier_m2", 0.05, 0.0, inf, "m^2",
                  "only cells with a variance below this vote"),
      param::real("max_drift_m", 0.1, 0.0, inf, "m", "larger mean residuals are not applied"),
      param::integer("min_height_drift_cnt", 100, 1, 1000000000, "minimum inlier points for a correction"),
      param::real("position_noise_thresh_m", 0.01, 0.0, inf, "m",
                  "sensor translation since the last cloud needed for a correction"),
      param::real("orientation_noise_thresh_rad", 0.01, 0.0, inf, "rad",
                  "or sensor rotation since the last cloud"),
      param::reals("self_filter_base_m", {}, -1, -100.0, 100.0, "m",
                   "self-filter boxes in the base frame, [xmin, ymin, zmin, xmax, ymax, zmax] per box"),
      param::reals("self_filter_blade_m", {}, -1, -100.0, 100.0, "m",
                   "self-filter boxes in the blade frame, 6 numbers per box"),
      param::reals("self_filter_slew_m", {}, -1, -100.0, 100.0, "m",
                   "self-filter boxes on an excavator's upper structure (JointState slew frame), 6 numbers per box"),
      param::reals("self_filter_boom_m", {}, -1, -100.0, 100.0, "m", "the same in the boom frame"),
      param::reals("self_filter_arm_m", {}, -1, -100.0, 100.0, "m", "the same in the arm frame"),
      param::reals("self_filter_bucket_m", {}, -1, -100.0, 100.0, "m", "the same in the bucket frame"),
      param::real("self_filter_margin_m", 0.1, 0.0, 10.0, "m", "self-filter boxes grown by this on every side"),
      param::boolean("follow_robot", false,
                     "re-centre the map on each Pose (or, before any Pose, on the sensor)"),
  };
}

namespace {
// {key, message} if the noise model claims noise-free points (a point of variance 0 makes its
// cell certain: no later point can move it, and two such points give 0/0), else {"", ""}.
std::pair<std::string, std::string> noiseModelProblem(const LidarFusionConfig& c) {
  if (!(c.min_variance_m2 > 0.0) || !std::isfinite(c.min_variance_m2))
    return {"min_variance_m2", "must be > 0 and finite (got " + formatNumber(c.min_variance_m2) + ")"};
  if (c.noise_model == NoiseModel::RangeBased && c.range_noise_a_m == 0.0 && c.range_noise_b == 0.0)
    return {"range_noise_a_m", "range_noise_a_m = 0 and range_noise_b = 0 under sensor_noise: range_based model a "
                               "noise-free LiDAR; give the sensor's range noise (e.g. range_noise_a_m: 0.02)"};
  if ((c.noise_model == NoiseModel::DepthSquared || !c.depth_squared_frames.empty()) && c.sensor_noise_factor == 0.0)
    return {"sensor_noise_factor", "sensor_noise_factor = 0 under sensor_noise: depth_squared models a noise-free "
                                   "sensor; give k in v = k*z_s^2 (e.g. 0.05)"};
  return {};
}
}  // namespace

LidarFusionConfig lidarFusionConfigFrom(const Params& p) {
  LidarFusionConfig c;
  c.noise_model = p.getString("sensor_noise") == "depth_squared" ? NoiseModel::DepthSquared
                                                                 : NoiseModel::RangeBased;
  c.range_noise_a_m = p.getDouble("range_noise_a_m");
  c.range_noise_b = p.getDouble("range_noise_b");
  c.sensor_noise_factor = p.getDouble("sensor_noise_factor");
  c.depth_squared_frames = p.getStrings("depth_squared_frames");
  c.min_range_m = p.getDouble("min_range_m");
  c.max_range_m = p.getDouble("max_range_m");
  c.max_height_above_sensor_m = p.getDouble("max_height_above_sensor_m");
  c.enable_ramped_height_range = p.getBool("enable_ramped_height_range");
  c.ramped_height_range_a = p.getDouble("ramped_height_range_a");
  c.ramped_height_range_b_m = p.getDouble("ramped_height_range_b_m");
  c.ramped_height_range_c_m = p.getDouble("ramped_height_range_c_m");
  c.min_variance_m2 = p.getDouble("min_variance_m2");
  c.mahalanobis_thresh = p.getDouble("mahalanobis_thresh");
  c.outlier_variance_m2 = p.getDouble("outlier_variance_m2");
  c.max_variance_m2 = p.getDouble("max_variance_m2");
  c.time_variance_m2_per_s = p.getDouble("time_variance_m2_per_s");
  c.enable_visibility_cleanup = p.getBool("enable_visibility_cleanup");
  c.cleanup_ray_stride = static_cast<int>(p.getInt("cleanup_ray_stride"));
  c.max_ray_length_m = p.getDouble("max_ray_length_m");
  c.cleanup_step = p.getDouble("cleanup_step");
  c.cleanup_cos_thresh = p.getDouble("cleanup_cos_thresh");
  c.cleanup_end_margin_m = p.getDouble("cleanup_end_margin_m");
  c.cleanup_walk = p.getString("cleanup_walk") == "fan" ? CleanupWalk::Fan : CleanupWalk::Exact;
  c.cleanup_fan_lateral_cells = p.getDouble("cleanup_fan_lateral_cells");
  c.enable_drift_compensation = p.getBool("enable_drift_compensation");
  c.drift_compensation_alpha = p.getDouble("drift_compensation_alpha");
  c.drift_compensation_variance_inlier_m2 = p.getDouble("drift_compensation_variance_inlier_m2");
  c.max_drift_m = p.getDouble("max_drift_m");
  c.min_height_drift_cnt = p.getInt("min_height_drift_cnt");
  c.position_noise_thresh_m = p.getDouble("position_noise_thresh_m");
  c.orientation_noise_thresh_rad = p.getDouble("orientation_noise_thresh_rad");
  c.follow_robot = p.getBool("follow_robot");
  c.self_filter_base_m = p.getDoubles("self_filter_base_m");
  c.self_filter_blade_m = p.getDoubles("self_filter_blade_m");
  const char* link_keys[4] = {"self_filter_slew_m", "self_filter_boom_m", "self_filter_arm_m", "self_filter_bucket_m"};
  for (int k = 0; k < 4; ++k) c.self_filter_link_m[k] = p.getDoubles(link_keys[k]);
  c.self_filter_margin_m = p.getDouble("self_filter_margin_m");
  if (!(c.min_range_m < c.max_range_m))
    p.fail("min_range_m", "must be smaller than max_range_m (" + formatNumber(c.max_range_m) + "), got " +
                              formatNumber(c.min_range_m));
  if (const auto why = noiseModelProblem(c); !why.first.empty()) p.fail(why.first, why.second);
  return c;
}

void LidarFusion::configure(const LidarFusionConfig& c) {
  auto bad = [](const std::string& key, const std::string& msg) {
    throw ConfigError("lidar_fusion: " + key + ": " + msg);
  };
  auto finiteNonNeg = [&](const char* key, double v) {
    if (!(v >= 0.0) || std::isnan(v)) bad(key, "must be >= 0 (got " + formatNumber(v) + ")");
  };
  finiteNonNeg("range_noise_a_m", c.range_noise_a_m);
  finiteNonNeg("range_noise_b", c.range_noise_b);
  finiteNonNeg("sensor_noise_factor", c.sensor_noise_factor);
  finiteNonNeg("min_range_m", c.min_range_m);
  finiteNonNeg("mahalanobis_thresh", c.mahalanobis_thresh);
  finiteNonNeg("outlier_variance_m2", c.outlier_variance_m2);
  finiteNonNeg("max_variance_m2", c.max_variance_m2);
  finiteNonNeg("time_variance_m2_per_s", c.time_variance_m2_per_s);
  finiteNonNeg("max_ray_length_m", c.max_ray_length_m);
  finiteNonNeg("cleanup_end_margin_m", c.cleanup_end_margin_m);
  if (!(c.min_range_m < c.max_range_m))
    bad("min_range_m", "must be smaller than max_range_m (" + formatNumber(c.max_range_m) + "), got " + formatNumber(c.min_range_m));
  if (const auto why = noiseModelProblem(c); !why.first.empty()) bad(why.first, why.second);
  if (c.cleanup_ray_stride < 1) bad("cleanup_ray_stride", "must be >= 1 (got " + formatNumber(c.cleanup_ray_stride) + ")");
  if (!(c.cleanup_step >= 0.0 && c.cleanup_step <= 1.0))
    bad("cleanup_step", "must be in [0, 1] (got " + formatNumber(c.cleanup_step) + ")");
  if (!(c.cleanup_cos_thresh >= 0.0 && c.cleanup_cos_thresh <= 1.0))
    bad("cleanup_cos_thresh", "must be in [0, 1] (got " + formatNumber(c.cleanup_cos_thresh) + ")");
  if (!(c.cleanup_fan_lateral_cells > 0.0 && c.cleanup_fan_lateral_cells <= 8.0))
    bad("cleanup_fan_lateral_cells", "must be in (0, 8] (got " + formatNumber(c.cleanup_fan_lateral_cells) + ")");
  if (!(c.drift_compensation_alpha >= 0.0 && c.drift_compensation_alpha <= 1.0))
    bad("drift_compensation_alpha", "must be in [0, 1] (got " + formatNumber(c.drift_compensation_alpha) + ")");
  self_filter_.configure(c.self_filter_base_m, c.self_filter_blade_m, c.self_filter_margin_m, "self_filter_base_m",
                         "self_filter_blade_m");
  self_filter_.configureLinks(c.self_filter_link_m,
                              {"self_filter_slew_m", "self_filter_boom_m", "self_filter_arm_m", "self_filter_bucket_m"});
  config_ = c;
}

// ---- layers / events -------------------------------------------------------------------------

std::vector<LayerSpec> LidarFusion::layers() const {
  using L = LidarFusionLayers;
  return {
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

// ---- time and motion -------------------------------------------------------------------------

void LidarFusion::advanceTime(LayeredMap& map, const Executor& ex, double stamp) {
  if (!std::isfinite(stamp)) throw InputError("lidar_fusion: event stamp is not finite");
  if (!have_stamp_) {
    have_stamp_ = true;
    last_stamp_ = stamp;
    return;
  }
  if (stamp < last_stamp_)
    throw InputError("lidar_fusion: event stamp " + formatNumber(stamp) + " s is earlier than the previous " +
                     formatNumber(last_stamp_) + " s (events must be time-ordered)");
  const double dt = stamp - last_stamp_;
  last_stamp_ = stamp;
  if (dt == 0.0 || bound_map_ == nullptr) return;
  const float fdt = static_cast<float>(dt);
  const float dv = static_cast<float>(config_.time_variance_m2_per_s * dt);
  const int n = static_cast<int>(map.tileSize()) * map.tileSize();
  std::vector<int> tiles;
  for (int t = 0; t < map.tileCount(); ++t)
    if (tile_known_[static_cast<size_t>(t)]) tiles.push_back(t);
  ex.forEach(static_cast<int>(tiles.size()), [&](int k) {
    const int t = tiles[static_cast<size_t>(k)];
    // NaN + x stays NaN: unknown cells need no branch, and the loops vectorise.
    if (map.tileData(time_, t)) {
      float* tm = map.mutableTileData(time_, t);
      for (int c = 0; c < n; ++c) tm[c] += fdt;
    }
    if (dv != 0.0f && map.tileData(var_, t)) {
      float* v = map.mutableTileData(var_, t);
      for (int c = 0; c < n; ++c) v[c] += dv;
    }
  });
}

void LidarFusion::followTo(LayeredMap& map, const Eigen::Vector3d& position) {
  if (!config_.follow_robot) return;
  if (!position.allFinite()) throw InputError("lidar_fusion: follow_robot position is not finite");
  map.move(Position(position.x(), position.y()));
}

// ---- binning ---------------------------------------------------------------------------------

void LidarFusion::binItems(const Executor& ex, std::vector<std::vector<Item>>& chunks, int ntiles) {
  const int nc = static_cast<int>(chunks.size());
  // Per-chunk histograms (parallel), then a prefix over (tile, chunk): items keep their chunk
  // order and, within a chunk, their input order - a stable counting sort by tile.
  std::vector<int> counts(static_cast<size_t>(nc) * static_cast<size_t>(ntiles), 0);
  ex.forEach(nc, [&](int c) {
    int* h = &counts[static_cast<size_t>(c) * static_cast<size_t>(ntiles)];
    for (const Item& it : chunks[static_cast<size_t>(c)]) ++h[it.tile];
  });
  bin_start_.assign(static_cast<size_t>(ntiles) + 1, 0);
  ray_tiles_.clear();
  int run = 0;
  for (int t = 0; t < ntiles; ++t) {
    bin_start_[static_cast<size_t>(t)] = run;
    for (int c = 0; c < nc; ++c) {
      int& h = counts[static_cast<size_t>(c) * static_cast<size_t>(ntiles) + static_cast<size_t>(t)];
      const int k = h;
      h = run;
      run += k;
    }
    if (run > bin_start_[static_cast<size_t>(t)]) ray_tiles_.push_back(t);
  }
  bin_start_[static_cast<size_t>(ntiles)] = run;
  binned_.resize(static_cast<size_t>(run));
  ex.forEach(nc, [&](int c) {
    int* h = &counts[static_cast<size_t>(c) * static_cast<size_t>(ntiles)];
    for (const Item& it : chunks[static_cast<size_t>(c)]) binned_[static_cast<size_t>(h[it.tile]++)] = it;
  });
}

// ---- fusion ----------------------------------------------------------------------------------

FusionStats LidarFusion::fuse(LayeredMap& map, const Executor& ex, const PointCloud& cloud) {
  if (bound_map_ != &map)
    throw LayerError("lidar_fusion: fuse() on a map it is not attached to (call attach(map) first)");
  const Eigen::Isometry3d& T = cloud.T_map_sensor;
  if (!T.matrix().allFinite())
    throw InputError("lidar_fusion: point cloud at stamp " + formatNumber(cloud.stamp) + " s has a non-finite T_map_sensor");
  FusionStats st;
  st.points_in = static_cast<long>(cloud.points.size());
  buildIndexTables(map);

  // 1) transform, gate, noise, cell, and a stable sort by tile inside each fixed chunk.
  preparePoints(map, ex, cloud);
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

  // 2) drift compensation against the map before this cloud.
  if (config_.enable_drift_compensation) driftCompensation(map, ex, T, st);
  prev_T_map_sensor_ = T;
  have_prev_sensor_ = true;

  // 3) per-tile sequential fusion (which first clears the previous cloud's hits).
  fuseTiles(map, ex, st);

  // 4) visibility cleanup and upper bounds.
  if (config_.enable_visibility_cleanup) cleanup(map, ex, T.translation(), st);

  accumulate(st);
  return st;
}

bool LidarFusion::depthSquaredFrame(const std::string& frame) const {
  for (const std::string& pattern : config_.depth_squared_frames)
    if (::fnmatch(pattern.c_str(), frame.c_str(), 0) == 0) return true;
  return false;
}

void LidarFusion::preparePoints(const LayeredMap& map, const Executor& ex, const PointCloud& cloud) {
  GateConsts k;
  const Geometry& g = map.geometry();
  const Eigen::Matrix3d Rm = cloud.T_map_sensor.linear();
  const Eigen::Vector3d tv = cloud.T_map_sensor.translation();
  const Eigen::Array2d half = g.length() * 0.5;
  const LidarFusionConfig& cf = config_;
  k.r00 = Rm(0, 0), k.r01 = Rm(0, 1), k.r02 = Rm(0, 2);
  k.r10 = Rm(1, 0), k.r11 = Rm(1, 1), k.r12 = Rm(1, 2);
  k.r20 = Rm(2, 0), k.r21 = Rm(2, 1), k.r22 = Rm(2, 2);
  k.tx = tv.x(), k.ty = tv.y(), k.tz = tv.z();
  k.xmax = g.center().x() + half.x(), k.ymax = g.center().y() + half.y();
  k.res = g.resolution();
  k.rows = g.size().x(), k.cols = g.size().y();
  k.min_r = cf.min_range_m, k.max_r = cf.max_range_m, k.max_h = cf.max_height_above_sensor_m;
  k.ramp_a = cf.ramped_height_range_a, k.ramp_b = cf.ramped_height_range_b_m, k.ramp_c = cf.ramped_height_range_c_m;
  k.noise_a = cf.range_noise_a_m, k.noise_b = cf.range_noise_b, k.noise_k = cf.sensor_noise_factor;
  k.min_var = cf.min_variance_m2;
  k.ramp = cf.enable_ramped_height_range;
  k.range_based = cf.noise_model == NoiseModel::RangeBased && !depthSquaredFrame(cloud.frame);
  const bool rays = cf.enable_visibility_cleanup;
  const int stride = cf.cleanup_ray_stride;
#ifdef TERRAMAP_LIDAR_AVX2
  const bool simd = !force_scalar_gates_ && cpuHasAvx2();
#else
  const bool simd = false;
#endif

  const int n = static_cast<int>(cloud.points.size());
  const int nc = (n + kChunk - 1) / kChunk;
  const int ntiles = map.tileCount();
  point_chunks_.resize(static_cast<size_t>(nc));
  const PointXYZI* pts = cloud.points.data();
  const std::int32_t* row_tile = row_tile_.data();
  const std::int32_t* row_local = row_local_.data();
  const std::int32_t* col_tile = col_tile_.data();
  const std::int32_t* col_local = col_local_.data();

  ex.forEach(nc, [&, k](int c) {
    PointChunk& ch = point_chunks_[static_cast<size_t>(c)];
    const int i0 = c * kChunk, i1 = std::min(n, i0 + kChunk);
    ch.scratch.resize(static_cast<size_t>(i1 - i0));
    ch.tiles.resize(static_cast<size_t>(i1 - i0));
    ch.start.assign(static_cast<size_t>(ntiles) + 1, 0);
    ch.ray_ends.clear();
    PointItem* out = ch.scratch.data();
    std::int32_t* out_tile = ch.tiles.data();
    int* count = ch.start.data() + 1;  // histogram, shifted by one for the prefix sum below
    long drops[kInside + 1] = {0, 0, 0, 0, 0, 0};
    int m = 0;
    int ray_phase = i0 % stride;  // i % stride, advanced incrementally
    // Rays of points that passed the range and height gates (also outside the map).
    auto ray = [&](int i, std::int32_t code) {
      if (ray_phase == 0 && code >= kOutsideMap) {
        const PointXYZI& p = pts[i];
        double x, y, z;
        toMap(k, p.x, p.y, p.z, x, y, z);
        ch.ray_ends.push_back(static_cast<float>(x - k.tx));
        ch.ray_ends.push_back(static_cast<float>(y - k.ty));
        ch.ray_ends.push_back(static_cast<float>(z - k.tz));
      }
      if (++ray_phase == stride) ray_phase = 0;
    };
#ifdef TERRAMAP_LIDAR_AVX2
    if (simd) {
      // Gate a block with the vector kernel, then append its points without branches.
      GateBlock blk;
      for (int b0 = i0; b0 < i1; b0 += kGateBlock) {
        const int nb = std::min(kGateBlock, i1 - b0);
        gateAvx2(pts + b0, nb, k, blk);
        for (int q = 0; q < nb; ++q) {
          const std::int32_t code = blk.code[q];
          ++drops[code];
          if (rays) ray(b0 + q, code);
          // Rejected points write a slot (li = lj = 0) that is not kept.
          const int keep = code == kInside;
          const std::int32_t li = blk.li[q], lj = blk.lj[q];
          const std::int32_t tile = row_tile[li] + col_tile[lj];
          out_tile[m] = tile;
          out[m] = PointItem{static_cast<std::uint32_t>(row_local[li] + col_local[lj]), blk.z[q], blk.var[q]};
          count[tile] += keep;
          m += keep;
        }
      }
    } else
#endif
    {
      for (int i = i0; i < i1; ++i) {
        std::int32_t li = 0, lj = 0;
        float z = 0.0f, var = 0.0f;
        const GateCode code = gateOne(pts[i], k, li, lj, z, var);
        ++drops[code];
        if (rays) ray(i, code);
        if (code != kInside) continue;
        const std::int32_t tile = row_tile[li] + col_tile[lj];
        out_tile[m] = tile;
        out[m] = PointItem{static_cast<std::uint32_t>(row_local[li] + col_local[lj]), z, var};
        ++count[tile];
        ++m;
      }
    }
    for (int r = 0; r < kInside; ++r) ch.drops[static_cast<size_t>(r)] = drops[r];
    // Stable counting sort by tile: start[t] becomes the first slot of tile t; the scatter
    // advances it to the first slot of t + 1, so shifting by one restores the starts.
    int* start = ch.start.data();
    for (int t = 0; t < ntiles; ++t) start[t + 1] += start[t];
    ch.items.resize(static_cast<size_t>(m));
    PointItem* items = ch.items.data();
    for (int q = 0; q < m; ++q) items[start[out_tile[q]]++] = out[q];
    for (int t = ntiles; t > 0; --t) start[t] = start[t - 1];
    start[0] = 0;
  });
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

void LidarFusion::fuseTiles(LayeredMap& map, const Executor& ex, FusionStats& st) {
  const bool have_prev = layoutHitLists(map.tileCount());
  const int nt = static_cast<int>(task_tiles_.size());
  std::vector<std::array<long, 5>> per(static_cast<size_t>(nt));
  const float k2 = static_cast<float>(config_.mahalanobis_thresh * config_.mahalanobis_thresh);
  const float ov = static_cast<float>(config_.outlier_variance_m2);
  const float vmax = static_cast<float>(config_.max_variance_m2);
  const float vmin = static_cast<float>(config_.min_variance_m2);
  // A sparse map at its memory budget cannot take every new tile: which ones it gets is decided
  // here, serially in tile order, so the result does not depend on the thread count; the points
  // of a refused tile are dropped, counted, rather than the run failing half-way through a cloud.
  std::vector<char> refused;
  if (map.options().sparse) {
    refused.assign(static_cast<size_t>(map.tileCount()), 0);
    for (const int t : active_tiles_)
      refused[static_cast<size_t>(t)] = !map.tryAllocateTile(t, {elev_, var_, valid_, time_, ub_, isub_, hits_});
  }
  ex.forEach(nt, [&](int k) {
    const int t = task_tiles_[static_cast<size_t>(k)];
    // Clear the cells the previous cloud hit in this tile (a whole-tile fill would cost 16 KB
    // per tile per cloud). An unallocated (sparse) tile already reads as 0.
    if (have_prev && prev_hit_count_[static_cast<size_t>(t)] > 0 && map.tileData(hits_, t)) {
      float* H = map.mutableTileData(hits_, t);
      const std::uint32_t* o = prev_hit_offs_.data() + prev_hit_start_[static_cast<size_t>(t)];
      for (int q = 0; q < prev_hit_count_[static_cast<size_t>(t)]; ++q) H[o[q]] = 0.0f;
    }
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

namespace {
/// Highest point (map z, m) over its last column of a ray that ends there, the column entered
/// at horizontal distance da.
inline double endingRayZ(double Sz, double rho, double t_end, float dz, double da) {
  return dz >= 0.0f ? Sz + t_end * dz : Sz + (rho > 0.0 ? da / rho : 0.0) * dz;
}
}  // namespace

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
