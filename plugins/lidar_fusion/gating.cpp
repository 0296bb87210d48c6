// lidar_fusion's gates and binning: each point gated (scalar or AVX2, bit-identical), given
// its noise and binned per tile; the ray ends kept for the cleanup.
#include "lidar_fusion.hpp"

#include <fnmatch.h>

#include <algorithm>
#include <cmath>
#include <string>

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define TERRAMAP_LIDAR_AVX2 1
#endif

namespace terramap::plugins {

namespace {

/// Points (and rays) per chunk. Fixed, so the chunking - and with it every reduction order -
/// does not depend on the thread count.
constexpr int kChunk = 8192;

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

/// The gates' constants for one cloud: the sensor pose, the map's box and the config's gates
/// and noise model (range_based: false where the cloud's frame takes depth_squared).
GateConsts gateConsts(const Geometry& g, const Eigen::Isometry3d& T_map_sensor, const LidarFusionConfig& cf,
                      bool range_based) {
  GateConsts k;
  const Eigen::Matrix3d Rm = T_map_sensor.linear();
  const Eigen::Vector3d tv = T_map_sensor.translation();
  const Eigen::Array2d half = g.length() * 0.5;
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
  k.range_based = range_based;
  return k;
}

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

bool LidarFusion::depthSquaredFrame(const std::string& frame) const {
  for (const std::string& pattern : config_.depth_squared_frames)
    if (::fnmatch(pattern.c_str(), frame.c_str(), 0) == 0) return true;
  return false;
}

void LidarFusion::preparePoints(const LayeredMap& map, const Executor& ex, const PointCloud& cloud,
                                const Eigen::Isometry3d& T) {
  const LidarFusionConfig& cf = config_;
  const GateConsts k = gateConsts(map.geometry(), T, cf,
                                  cf.noise_model == NoiseModel::RangeBased && !depthSquaredFrame(cloud.frame));
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
    sortChunkByTile(ch, m, ntiles);
  });
}

// Stable counting sort of a chunk's m kept points (scratch, tiles) by tile into items, from
// the per-tile counts in start[t + 1]: start[t] becomes the first slot of tile t; the scatter
// advances it to the first slot of t + 1, so shifting by one restores the starts.
void LidarFusion::sortChunkByTile(PointChunk& ch, int m, int ntiles) {
  const PointItem* out = ch.scratch.data();
  const std::int32_t* out_tile = ch.tiles.data();
  int* start = ch.start.data();
  for (int t = 0; t < ntiles; ++t) start[t + 1] += start[t];
  ch.items.resize(static_cast<size_t>(m));
  PointItem* items = ch.items.data();
  for (int q = 0; q < m; ++q) items[start[out_tile[q]]++] = out[q];
  for (int t = ntiles; t > 0; --t) start[t] = start[t - 1];
  start[0] = 0;
}

}  // namespace terramap::plugins
