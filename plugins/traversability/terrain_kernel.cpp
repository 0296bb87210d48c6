// The per-tile kernel: gather a tile's elevation with a halo in logical order, then plane-fit
// moments by running sums (O(1) per cell whatever the window), step height by van Herk /
// Gil-Werman max and min filters, and the four outputs written straight into the tile.
#include "traversability.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <mutex>

namespace terramap::plugins {

namespace {
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();

// One run of buffer cells that is contiguous in logical order too: the ring's seam cuts a
// tile's rows (or columns) at most once.
struct Run {
  int buffer = 0;   // first buffer index
  int logical = 0;  // its logical index
  int len = 0;
};

int logicalRuns(int b0, int n, int start, int size, Run out[2]) {
  const int l0 = ((b0 - start) % size + size) % size;
  if (l0 + n <= size) {
    out[0] = {b0, l0, n};
    return 1;
  }
  const int first = size - l0;
  out[0] = {b0, l0, first};
  out[1] = {b0 + first, 0, n - first};
  return 2;
}
}  // namespace

// Buffers of one block (a tile's logical rectangle with its halo). Sizes grow to the largest
// block seen and stay.
struct Traversability::Scratch {
  std::vector<float> g;          // gathered heights, (h + 2K) x (w + 2K), row-major
  std::vector<std::int32_t> iprefix;  // mask prefix sums of two gathered rows, 3 planes of W + 1 each
  std::vector<double> prefix;    // height prefix sums of two gathered rows, 3 planes of W + 1 each
  std::vector<double> mom;       // 6 row-window moments, (h + 2k) x w each
  std::vector<double> acc;       // 10 column running sums, w each
  std::vector<float> hmax, hmin;  // row-window max / min, (h + 2ks) x w
  std::vector<float> vpmax, vpmin, vsmax, vsmin;  // column block prefix / suffix extremes, same size
  std::vector<float> rowmax, rowmin, rowpre, rowsuf;  // one gathered row, W each
  std::vector<float> gm, rough, slope, step;  // one output row, w each
};

struct Traversability::ScratchPool {
  std::mutex mu;
  std::vector<std::unique_ptr<Scratch>> free;
};

Traversability::Traversability() : pool_(std::make_unique<ScratchPool>()) {}
Traversability::~Traversability() = default;
Traversability::Traversability(Traversability&&) noexcept = default;
Traversability& Traversability::operator=(Traversability&&) noexcept = default;

std::unique_ptr<Traversability::Scratch> Traversability::takeScratch() const {
  std::lock_guard<std::mutex> lk(pool_->mu);
  if (pool_->free.empty()) return std::make_unique<Scratch>();
  std::unique_ptr<Scratch> s = std::move(pool_->free.back());
  pool_->free.pop_back();
  return s;
}

void Traversability::giveScratch(std::unique_ptr<Scratch> s) const {
  std::lock_guard<std::mutex> lk(pool_->mu);
  pool_->free.push_back(std::move(s));
}

int Traversability::planeHalfWidth(double resolution) const {
  return std::max(1, static_cast<int>(std::floor(cfg_.plane_radius_m / resolution + 1e-9)));
}

int Traversability::stepHalfWidth(double resolution) const {
  return std::max(1, static_cast<int>(std::floor(cfg_.step_radius_m / resolution + 1e-9)));
}

std::vector<int> Traversability::affectedTiles(const LayeredMap& map, const std::vector<int>& changed) const {
  const double res = map.geometry().resolution();
  return map.tilesWithin(changed, std::max(planeHalfWidth(res), stepHalfWidth(res)));
}

Traversability::PassStats Traversability::run(LayeredMap& map, const Executor& ex, const TraversabilityLayers& l) const {
  std::vector<int> all(static_cast<size_t>(map.tileCount()));
  for (int t = 0; t < map.tileCount(); ++t) all[static_cast<size_t>(t)] = t;
  return runTiles(map, ex, l, all);
}

namespace {

// Logical rows [i0, i0 + H) x columns [j0, j0 + W) of layer `id` into g (row-major, stride W);
// cells beyond the map, and unallocated tiles whose fill is not finite, read as NaN.
void gather(const LayeredMap& map, LayerId id, int i0, int j0, int H, int W, float* g) {
  const int R = map.geometry().size().x(), C = map.geometry().size().y();
  const int T = map.tileSize();
  const Index s = map.startIndex();
  const float fill = map.layerInfo(id).fill;
  for (int a = 0; a < H; ++a) {
    float* row = g + static_cast<size_t>(a) * static_cast<size_t>(W);
    const int i = i0 + a;
    if (i < 0 || i >= R) {
      std::fill(row, row + W, kNaN);
      continue;
    }
    const int bi = (i + s.x()) % R;
    const int tr = bi / T, ri = bi % T;
    int b = 0, j = j0;
    for (; b < W && j < 0; ++b, ++j) row[b] = kNaN;
    while (b < W && j < C) {
      const int bj = (j + s.y()) % C;
      const int cj = bj % T;
      const int run = std::min({W - b, C - j, T - cj, C - bj});
      const float* td = map.tileData(id, tr * map.tileCols() + bj / T);
      if (td)
        std::memcpy(row + b, td + static_cast<size_t>(ri) * static_cast<size_t>(T) + static_cast<size_t>(cj),
                    sizeof(float) * static_cast<size_t>(run));
      else
        std::fill(row + b, row + b + run, fill);
      b += run;
      j += run;
    }
    for (; b < W; ++b) row[b] = kNaN;
  }
}

template <class V>
void grow(V& v, size_t n) {
  if (v.size() < n) v.resize(n);
}

#define TM_INLINE inline __attribute__((always_inline))

// One step of running window sums down the columns: the row `in` enters with weights 1, q_in,
// q_in², the row `out` leaves with 1, q_out, q_out² (f0 = 0 when no row leaves: 0 · x is 0, and
// 1 · x and integer weights multiply exactly). One pass over each pass-1 row feeds every sum
// weighted from it.
TM_INLINE void slide3(double* __restrict s0, double* __restrict s1, double* __restrict s2, const double* __restrict in,
                      const double* __restrict out, double f0, double wi, double wo, int n) {
  const double wi2 = wi * wi, wo2 = wo * wo;
  for (int c = 0; c < n; ++c) {
    const double a = in[c], b = out[c];
    s0[c] += a - f0 * b;
    s1[c] += wi * a - wo * b;
    s2[c] += wi2 * a - wo2 * b;
  }
}
TM_INLINE void slide2(double* __restrict s0, double* __restrict s1, const double* __restrict in,
                      const double* __restrict out, double f0, double wi, double wo, int n) {
  for (int c = 0; c < n; ++c) {
    const double a = in[c], b = out[c];
    s0[c] += a - f0 * b;
    s1[c] += wi * a - wo * b;
  }
}
TM_INLINE void slide1(double* __restrict s0, const double* __restrict in, const double* __restrict out, double f0, int n) {
  for (int c = 0; c < n; ++c) s0[c] += in[c] - f0 * out[c];
}
TM_INLINE void maxMin(float* __restrict mx, float* __restrict mn, const float* __restrict ax, const float* __restrict an,
                      const float* __restrict bx, const float* __restrict bn, int n) {
  for (int c = 0; c < n; ++c) {
    mx[c] = ax[c] > bx[c] ? ax[c] : bx[c];
    mn[c] = an[c] < bn[c] ? an[c] : bn[c];
  }
}

// Van Herk / Gil-Werman along one row: max and min of in[x .. x + L - 1] for x in [0, n - L + 1),
// from prefix extremes within blocks of L (pre) and suffix extremes (suf): three comparisons
// per element whatever L. Max and min are exact, so the result is the brute-force one bit for bit.
TM_INLINE void slidingMaxMin(const float* __restrict hi, const float* __restrict lo, int n, int L, float* __restrict pre,
                             float* __restrict suf, float* __restrict premin, float* __restrict sufmin,
                             float* __restrict outmax, float* __restrict outmin) {
  for (int b0 = 0; b0 < n; b0 += L) {
    const int e = std::min(n, b0 + L);
    pre[b0] = hi[b0], premin[b0] = lo[b0];
    for (int x = b0 + 1; x < e; ++x) {
      pre[x] = pre[x - 1] > hi[x] ? pre[x - 1] : hi[x];
      premin[x] = premin[x - 1] < lo[x] ? premin[x - 1] : lo[x];
    }
    suf[e - 1] = hi[e - 1], sufmin[e - 1] = lo[e - 1];
    for (int x = e - 2; x >= b0; --x) {
      suf[x] = suf[x + 1] > hi[x] ? suf[x + 1] : hi[x];
      sufmin[x] = sufmin[x + 1] < lo[x] ? sufmin[x + 1] : lo[x];
    }
  }
  for (int x = 0; x + L <= n; ++x) {
    outmax[x] = suf[x] > pre[x + L - 1] ? suf[x] : pre[x + L - 1];
    outmin[x] = sufmin[x] < premin[x + L - 1] ? sufmin[x] : premin[x + L - 1];
  }
}

// One block's geometry: output rows h x columns w, gathered with a halo of K (rows and columns);
// plane half-width k, step half-width ks (both <= K).
struct BlockShape {
  int h, w, K, k, ks;
  int W() const { return w + 2 * K; }
};

// What the outputs of one block row are computed from.
struct Limits {
  double min_n, inv_res2;
  float cs, cr, ch, ws, wr, wh, wsum;
  bool blocks;
};

// Prefix sums along two gathered rows of the six pass-1 quantities: the mask ones (m, x m, x² m,
// with m = 1 for a known cell) in int32 at I (planes of W + 1: exact, and in integer registers,
// which leaves the vector registers to the height ones), the height ones (z, x z, z², z the height
// above zref) in double at P. Row a's planes first, then row b's.
TM_INLINE void prefixRows2(const float* __restrict ra, const float* __restrict rb, int W, double zref,
                           std::int32_t* __restrict I, double* __restrict P) {
  // Two rows in lockstep: each running sum is a chain of dependent adds, and two rows give the
  // core twice as many independent chains to overlap.
  const size_t ps = static_cast<size_t>(W) + 1;
  std::int32_t a0 = 0, a1 = 0, a2 = 0, b0 = 0, b1 = 0, b2 = 0;
  double az = 0, a1z = 0, azz = 0, bz = 0, b1z = 0, bzz = 0;
  for (int j = 0; j < 6; ++j) I[j * ps] = 0, P[j * ps] = 0.0;
  for (int x = 0; x < W; ++x) {
    const double xd = x;
    const float va = ra[x], vb = rb[x];
    const bool ka = va - va == 0.0f, kb = vb - vb == 0.0f;  // finite
    const std::int32_t ma = ka, mb = kb;
    const double za = ka ? static_cast<double>(va) - zref : 0.0, zb = kb ? static_cast<double>(vb) - zref : 0.0;
    a0 += ma, a1 += ma * x, a2 += ma * x * x, b0 += mb, b1 += mb * x, b2 += mb * x * x;
    az += za, a1z += xd * za, azz += za * za, bz += zb, b1z += xd * zb, bzz += zb * zb;
    const size_t o = static_cast<size_t>(x) + 1;
    I[o] = a0, I[ps + o] = a1, I[2 * ps + o] = a2, I[3 * ps + o] = b0, I[4 * ps + o] = b1, I[5 * ps + o] = b2;
    P[o] = az, P[ps + o] = a1z, P[2 * ps + o] = azz, P[3 * ps + o] = bz, P[4 * ps + o] = b1z, P[5 * ps + o] = bzz;
  }
}

// The window moments of one row for every output column from its prefix sums (three int32
// planes at I, three double planes at P), with column offsets x - x_c: a0 = Σ m,
// a1 = Σ (x - x_c) m, a2 = Σ (x - x_c)² m, b0 = Σ z, b1 = Σ (x - x_c) z, c0 = Σ z², into planes of
// n1 at M + o. The mask moments are small integers, exact in double.
TM_INLINE void windowRow(const std::int32_t* __restrict I, const double* __restrict P, int W, int w, int K, int k,
                         double* __restrict M, size_t n1, size_t o) {
  const size_t ps = static_cast<size_t>(W) + 1;
  const std::int32_t* __restrict p0 = I;
  const std::int32_t* __restrict p1 = I + ps;
  const std::int32_t* __restrict p2 = I + 2 * ps;
  const double* __restrict pz = P;
  const double* __restrict p1z = P + ps;
  const double* __restrict pzz = P + 2 * ps;
  double* __restrict a0 = M + o;
  double* __restrict a1 = M + n1 + o;
  double* __restrict a2 = M + 2 * n1 + o;
  double* __restrict b0 = M + 3 * n1 + o;
  double* __restrict b1 = M + 4 * n1 + o;
  double* __restrict c0 = M + 5 * n1 + o;
  const int lo = K - k, hi = K + k + 1;
  for (int c = 0; c < w; ++c) {
    const double g = K + c;
    const double m0 = p0[hi + c] - p0[lo + c], m1 = p1[hi + c] - p1[lo + c], m2 = p2[hi + c] - p2[lo + c];
    const double mz = pz[hi + c] - pz[lo + c];
    a0[c] = m0;
    a1[c] = m1 - g * m0;
    a2[c] = m2 - 2.0 * g * m1 + g * g * m0;
    b0[c] = mz;
    b1[c] = (p1z[hi + c] - p1z[lo + c]) - g * mz;
    c0[c] = pzz[hi + c] - pzz[lo + c];
  }
}

// Plane fit, pass 1: along each gathered row, the moments of the 2k + 1 cells around every
// output column; I and P hold 6 prefix planes of W + 1 each (prefixRows2).
TM_INLINE void planeRows(const float* __restrict G, const BlockShape& b, double zref, std::int32_t* __restrict I,
                         double* __restrict P, double* __restrict M) {
  const int W = b.W(), w = b.w, k = b.k, K = b.K;
  const int rows1 = b.h + 2 * k;
  const size_t n1 = static_cast<size_t>(rows1) * static_cast<size_t>(w);
  const size_t half = 3 * (static_cast<size_t>(W) + 1);  // row b's planes
  for (int q = 0; q < rows1; q += 2) {
    const float* ra = G + static_cast<size_t>(K - k + q) * static_cast<size_t>(W);
    const bool two = q + 1 < rows1;
    prefixRows2(ra, two ? ra + W : ra, W, zref, I, P);
    windowRow(I, P, W, w, K, k, M, n1, static_cast<size_t>(q) * static_cast<size_t>(w));
    if (two) windowRow(I + half, P + half, W, w, K, k, M, n1, static_cast<size_t>(q + 1) * static_cast<size_t>(w));
  }
}

// Step height, both passes: rows of max / min over 2ks + 1 columns (van Herk per gathered row),
// then block prefix and suffix extremes down the columns, all columns of a row at once.
TM_INLINE void stepPasses(const float* __restrict G, const BlockShape& b, Traversability::Scratch& s) {
  const int W = b.W(), w = b.w, ks = b.ks, K = b.K;
  const int L = 2 * ks + 1, rows2 = b.h + 2 * ks;
  float* __restrict hin = s.rowmax.data();
  float* __restrict lin = s.rowmin.data();
  for (int q = 0; q < rows2; ++q) {
    const float* __restrict row = G + static_cast<size_t>(K - ks + q) * static_cast<size_t>(W);
    // Unknown cells neutral for max and min. Output column c's window starts at K + c - ks.
    for (int x = 0; x < W; ++x) {
      const bool known = row[x] - row[x] == 0.0f;
      hin[x] = known ? row[x] : -kInf;
      lin[x] = known ? row[x] : kInf;
    }
    const size_t o = static_cast<size_t>(q) * static_cast<size_t>(w);
    slidingMaxMin(hin + (K - ks), lin + (K - ks), w + 2 * ks, L, s.rowpre.data(), s.rowsuf.data(),
                  s.rowpre.data() + W, s.rowsuf.data() + W, s.hmax.data() + o, s.hmin.data() + o);
  }
  const size_t W2 = static_cast<size_t>(w);
  for (int b0 = 0; b0 < rows2; b0 += L) {
    const int e = std::min(rows2, b0 + L);
    std::memcpy(s.vpmax.data() + b0 * W2, s.hmax.data() + b0 * W2, sizeof(float) * W2);
    std::memcpy(s.vpmin.data() + b0 * W2, s.hmin.data() + b0 * W2, sizeof(float) * W2);
    for (int q = b0 + 1; q < e; ++q)
      maxMin(s.vpmax.data() + q * W2, s.vpmin.data() + q * W2, s.vpmax.data() + (q - 1) * W2,
             s.vpmin.data() + (q - 1) * W2, s.hmax.data() + q * W2, s.hmin.data() + q * W2, w);
    std::memcpy(s.vsmax.data() + (e - 1) * W2, s.hmax.data() + (e - 1) * W2, sizeof(float) * W2);
    std::memcpy(s.vsmin.data() + (e - 1) * W2, s.hmin.data() + (e - 1) * W2, sizeof(float) * W2);
    for (int q = e - 2; q >= b0; --q)
      maxMin(s.vsmax.data() + q * W2, s.vsmin.data() + q * W2, s.vsmax.data() + (q + 1) * W2,
             s.vsmin.data() + (q + 1) * W2, s.hmax.data() + q * W2, s.hmin.data() + q * W2, w);
  }
}

// The plane of one output row from the column sums: the gradient magnitude (m/m) and the
// roughness, NaN where there is no fit (centre unknown, fewer than min_n cells, collinear).
TM_INLINE void solveRow(const double* __restrict acc, int w, double qc, const float* __restrict centre,
                        const Limits& lim, float* __restrict gm, float* __restrict rough) {
  const double* __restrict N = acc;
  const double* __restrict Qx = acc + w;
  const double* __restrict Qxx = acc + 2 * w;
  const double* __restrict Y = acc + 3 * w;
  const double* __restrict Qxy = acc + 4 * w;
  const double* __restrict YY = acc + 5 * w;
  const double* __restrict Z = acc + 6 * w;
  const double* __restrict Qxz = acc + 7 * w;
  const double* __restrict YZ = acc + 8 * w;
  const double* __restrict ZZ = acc + 9 * w;
  for (int c = 0; c < w; ++c) {
    const double n = N[c];
    // Sums over the window with offsets x (rows) and y (columns) from its middle.
    const double Sx = Qx[c] - qc * n, Sxx = Qxx[c] - 2.0 * qc * Qx[c] + qc * qc * n;
    const double Sy = Y[c], Sxy = Qxy[c] - qc * Y[c], Syy = YY[c];
    const double Sz = Z[c], Sxz = Qxz[c] - qc * Z[c], Syz = YZ[c], Szz = ZZ[c];
    // n² times the covariances: the mask ones are exact integers, so collinear cells give
    // det == 0 exactly.
    const double Dxx = n * Sxx - Sx * Sx, Dyy = n * Syy - Sy * Sy, Dxy = n * Sxy - Sx * Sy;
    const double Dxz = n * Sxz - Sx * Sz, Dyz = n * Syz - Sy * Sz, Dzz = n * Szz - Sz * Sz;
    const double det = Dxx * Dyy - Dxy * Dxy;
    const bool ok = (n >= lim.min_n) & (det > 0.0) & (centre[c] - centre[c] == 0.0f);
    const double inv = 1.0 / (ok ? det : 1.0);
    const double bx = (Dyy * Dxz - Dxy * Dyz) * inv;  // m per cell along rows
    const double by = (Dxx * Dyz - Dxy * Dxz) * inv;  // m per cell along columns
    const double g2 = (bx * bx + by * by) * lim.inv_res2;
    const double ssr = Dzz - bx * Dxz - by * Dyz;  // n times the sum of squared vertical residuals
    // Mean square distance along the normal: ssr / n² · cos²(slope), cos² = 1 / (1 + g²).
    const double r2 = (ssr > 0.0 ? ssr : 0.0) / ((ok ? n * n : 1.0) * (1.0 + g2));
    // Computed for every cell and then selected, so the loop has no branch and vectorises.
    const float g = std::sqrt(static_cast<float>(g2));
    const float ro = std::sqrt(static_cast<float>(r2));
    gm[c] = ok ? g : kNaN;
    rough[c] = ok ? ro : kNaN;
  }
}

// Step height of one output row: max - min of the window from the block suffix at its first
// row and the block prefix at its last; NaN where the cell itself is unknown.
TM_INLINE void stepRow(const float* __restrict sufmax, const float* __restrict premax, const float* __restrict sufmin,
                       const float* __restrict premin, const float* __restrict centre, int w, float* __restrict step) {
  for (int c = 0; c < w; ++c) {
    const float mx = sufmax[c] > premax[c] ? sufmax[c] : premax[c];
    const float mn = sufmin[c] < premin[c] ? sufmin[c] : premin[c];
    step[c] = centre[c] - centre[c] == 0.0f ? mx - mn : kNaN;
  }
}

// atan(x) for x >= 0 in float arithmetic without a library call, so the loop vectorises (the
// same operations in every lane and in the scalar tail: the same bits wherever a cell falls).
// Reduced to |u| <= tan(π/8) by atan(x) = π/4 + atan((x - 1) / (x + 1)) and π/2 + atan(-1 / x);
// there atan(u) = u P(u²), P of degree 4 fitted for this file by least squares on Chebyshev nodes
// (max error 7e-9 rad; 4e-8 rad with float evaluation; with the offsets, under 2e-7 rad).
TM_INLINE float atanNonNegative(float x) {
  const bool mid = x > 0.41421356f, high = x > 2.41421356f;
  const float num = high ? -1.0f : mid ? x - 1.0f : x;
  const float den = high ? x : mid ? x + 1.0f : 1.0f;
  const float offset = high ? 1.57079633f : mid ? 0.78539816f : 0.0f;
  const float u = num / den, s = u * u;
  const float p = (((0.0799363926f * s - 0.138544559f) * s + 0.199747241f) * s - 0.333328079f) * s + 0.999999982f;
  return offset + u * p;
}

// slope = atan(|gradient|), NaN where there is no fit. Returns the cells with a slope.
TM_INLINE long slopeRow(const float* __restrict gm, int w, float* __restrict slope) {
  long n = 0;
  for (int c = 0; c < w; ++c) {
    const float g = gm[c];
    slope[c] = atanNonNegative(g);  // NaN stays NaN
    n += g == g;
  }
  return n;
}

// The four outputs of one output row.
TM_INLINE void writeRow(const float* __restrict slope, const float* __restrict rough, const float* __restrict step,
                        int w, const Limits& lim, float* __restrict o_slope, float* __restrict o_rough,
                        float* __restrict o_step, float* __restrict o_trav) {
  const float cs = lim.cs, cr = lim.cr, ch = lim.ch, ws = lim.ws, wr = lim.wr, wh = lim.wh, wsum = lim.wsum;
  const float blocks = lim.blocks ? 1.0f : 0.0f;
  // Selects only, no branch, so the loop vectorises.
  for (int c = 0; c < w; ++c) {
    const float sl = slope[c], ro = rough[c], st = step[c];
    const float xs = sl / cs, xr = ro / cr, xh = st / ch;
    const float ts = 1.0f - (xs < 1.0f ? xs : 1.0f);
    const float tr = 1.0f - (xr < 1.0f ? xr : 1.0f);
    const float th = 1.0f - (xh < 1.0f ? xh : 1.0f);
    const float mean = (ws * ts + wr * tr + wh * th) / wsum;
    const float least = ts < tr ? (ts < th ? ts : th) : (tr < th ? tr : th);
    const float blocked = least <= 0.0f ? blocks : 0.0f;  // a term at or past its critical value
    o_slope[c] = sl;
    o_rough[c] = ro;
    o_step[c] = st;
    o_trav[c] = sl == sl ? (blocked > 0.0f ? 0.0f : mean) : kNaN;
  }
}

// One block: outputs for logical rows [i0, i0 + h) x columns [j0, j0 + w) from the gathered
// heights G, written to the four output arrays at `ob` with row stride T. Returns the cells fitted.
TM_INLINE long computeBlock(const float* __restrict G, const BlockShape& b, const Limits& lim,
                            Traversability::Scratch& s, float* const out[4], size_t ob, int T) {
  const int W = b.W(), w = b.w, h = b.h, k = b.k, K = b.K;
  const int rows1 = h + 2 * k, rows2 = h + 2 * b.ks, L = 2 * b.ks + 1;
  const size_t n1 = static_cast<size_t>(rows1) * static_cast<size_t>(w);
  const size_t n2 = static_cast<size_t>(rows2) * static_cast<size_t>(w);
  grow(s.prefix, 6 * (static_cast<size_t>(W) + 1));
  grow(s.iprefix, 6 * (static_cast<size_t>(W) + 1));
  grow(s.mom, 6 * n1);
  grow(s.acc, 10 * static_cast<size_t>(w));
  for (auto* v : {&s.hmax, &s.hmin, &s.vpmax, &s.vpmin, &s.vsmax, &s.vsmin}) grow(*v, n2);
  for (auto* v : {&s.rowmax, &s.rowmin}) grow(*v, static_cast<size_t>(W));
  for (auto* v : {&s.rowpre, &s.rowsuf}) grow(*v, 2 * static_cast<size_t>(W));
  for (auto* v : {&s.gm, &s.rough, &s.slope, &s.step}) grow(*v, static_cast<size_t>(w));

  // Heights relative to the block's first known one, so the squared sums keep their digits at
  // any altitude (the fit does not depend on the offset).
  double zref = 0.0;
  for (size_t x = 0, e = static_cast<size_t>(b.h + 2 * K) * static_cast<size_t>(W); x < e; ++x)
    if (G[x] - G[x] == 0.0f) {
      zref = G[x];
      break;
    }
  planeRows(G, b, zref, s.iprefix.data(), s.prefix.data(), s.mom.data());
  stepPasses(G, b, s);

  // Plane fit, pass 2: running sums down the columns over the 2k + 1 rows of the window; row q
  // of pass 1 weighs with its index q, recentred on the window's middle in solveRow().
  double* acc = s.acc.data();
  std::fill(acc, acc + 10 * static_cast<size_t>(w), 0.0);
  const double* M = s.mom.data();
  // acc planes: n, qx, qxx, y, qxy, yy, z, qxz, yz, zz; from mom planes a0, a1, a2, b0, b1, c0.
  auto moveWindow = [&](int qin, int qout) {
    const bool leaves = qout >= 0;
    const double f0 = leaves ? 1.0 : 0.0, wi = qin, wo = leaves ? qout : 0.0;
    const size_t oi = static_cast<size_t>(qin) * static_cast<size_t>(w);
    const size_t oo = static_cast<size_t>(leaves ? qout : qin) * static_cast<size_t>(w);
    auto acc_ = [&](int a) { return acc + static_cast<size_t>(a) * static_cast<size_t>(w); };
    auto mom = [&](int p) { return M + static_cast<size_t>(p) * n1; };
    slide3(acc_(0), acc_(1), acc_(2), mom(0) + oi, mom(0) + oo, f0, wi, wo, w);  // a0: n, qx, qxx
    slide2(acc_(3), acc_(4), mom(1) + oi, mom(1) + oo, f0, wi, wo, w);           // a1: y, qxy
    slide1(acc_(5), mom(2) + oi, mom(2) + oo, f0, w);                            // a2: yy
    slide2(acc_(6), acc_(7), mom(3) + oi, mom(3) + oo, f0, wi, wo, w);           // b0: z, qxz
    slide1(acc_(8), mom(4) + oi, mom(4) + oo, f0, w);                            // b1: yz
    slide1(acc_(9), mom(5) + oi, mom(5) + oo, f0, w);                            // c0: zz
  };
  for (int q = 0; q < 2 * k; ++q) moveWindow(q, -1);
  long fitted = 0;
  for (int r = 0; r < h; ++r) {
    moveWindow(r + 2 * k, r - 1);
    const float* centre = G + static_cast<size_t>(K + r) * static_cast<size_t>(W) + K;
    solveRow(acc, w, r + k, centre, lim, s.gm.data(), s.rough.data());
    // Step window of output row r: pass-1 rows [r, r + L - 1] (block suffix at r, prefix at its end).
    const size_t lo = static_cast<size_t>(r) * static_cast<size_t>(w), hi = static_cast<size_t>(r + L - 1) * static_cast<size_t>(w);
    stepRow(s.vsmax.data() + lo, s.vpmax.data() + hi, s.vsmin.data() + lo, s.vpmin.data() + hi, centre, w,
            s.step.data());
    fitted += slopeRow(s.gm.data(), w, s.slope.data());
    const size_t o = ob + static_cast<size_t>(r) * static_cast<size_t>(T);
    writeRow(s.slope.data(), s.rough.data(), s.step.data(), w, lim, out[0] + o, out[1] + o, out[2] + o, out[3] + o);
  }
  return fitted;
}

// The same kernel compiled twice: for the baseline x86-64 (SSE2) and for AVX2, chosen at run
// time. AVX2 without FMA: GCC contracts nothing into fused multiply-adds, every lane does the
// same IEEE operations as the baseline's, so both give the same bits (tested).
long computeBlockBaseline(const float* G, const BlockShape& b, const Limits& lim, Traversability::Scratch& s,
                          float* const out[4], size_t ob, int T) {
  return computeBlock(G, b, lim, s, out, ob, T);
}
#if defined(__x86_64__) && defined(__GNUC__)
__attribute__((target("avx2"))) long computeBlockAvx2(const float* G, const BlockShape& b, const Limits& lim,
                                                      Traversability::Scratch& s, float* const out[4], size_t ob,
                                                      int T) {
  return computeBlock(G, b, lim, s, out, ob, T);
}
bool cpuHasAvx2() {
  static const bool has = __builtin_cpu_supports("avx2");
  return has;
}
#else
long computeBlockAvx2(const float* G, const BlockShape& b, const Limits& lim, Traversability::Scratch& s,
                      float* const out[4], size_t ob, int T) {
  return computeBlock(G, b, lim, s, out, ob, T);
}
bool cpuHasAvx2() { return false; }
#endif

}  // namespace

bool Traversability::avx2Available() { return cpuHasAvx2(); }

Traversability::PassStats Traversability::runTiles(LayeredMap& map, const Executor& ex, const TraversabilityLayers& l,
                                                   const std::vector<int>& tiles) const {
  for (const LayerId id : {l.elevation, l.slope, l.roughness, l.step, l.traversability})
    (void)map.layerInfo(id);  // throws LayerError on an id the map does not have
  const Geometry& geo = map.geometry();
  const int R = geo.size().x(), C = geo.size().y();
  const int T = map.tileSize();
  const double res = geo.resolution();
  const int k = planeHalfWidth(res), ks = stepHalfWidth(res);
  const int K = std::max(k, ks);
  const Index start = map.startIndex();
  Limits lim;
  lim.min_n = static_cast<double>(cfg_.min_points);
  lim.inv_res2 = 1.0 / (res * res);
  lim.cs = static_cast<float>(cfg_.critical_slope_rad);
  lim.cr = static_cast<float>(cfg_.critical_roughness_m);
  lim.ch = static_cast<float>(cfg_.critical_step_m);
  lim.ws = static_cast<float>(cfg_.weight_slope);
  lim.wr = static_cast<float>(cfg_.weight_roughness);
  lim.wh = static_cast<float>(cfg_.weight_step);
  lim.wsum = lim.ws + lim.wr + lim.wh;
  lim.blocks = cfg_.any_critical_blocks;
  const bool avx2 = allow_avx2_ && cpuHasAvx2();

  std::vector<long> fitted(tiles.size(), 0), budget(tiles.size(), 0), written(tiles.size(), 0);
  ex.forEach(static_cast<int>(tiles.size()), [&](int task) {
    const int t = tiles[static_cast<size_t>(task)];
    const CellRect rect = map.tileRect(t);
    Run rr[2], cr[2];
    const int nr = logicalRuns(rect.r0, rect.rows, start.x(), R, rr);
    const int nc = logicalRuns(rect.c0, rect.cols, start.y(), C, cr);
    std::unique_ptr<Scratch> sp = takeScratch();
    Scratch& s = *sp;
    float* out[4] = {nullptr, nullptr, nullptr, nullptr};
    long fit = 0;
    for (int ri = 0; ri < nr; ++ri)
      for (int ci = 0; ci < nc; ++ci) {
        const BlockShape b{rr[ri].len, cr[ci].len, K, k, ks};
        const int H = b.h + 2 * K, W = b.W();
        grow(s.g, static_cast<size_t>(H) * static_cast<size_t>(W));
        gather(map, l.elevation, rr[ri].logical - K, cr[ci].logical - K, H, W, s.g.data());
        const float* G = s.g.data();
        // A sparse map's tile with nothing known around it needs no outputs; one whose outputs
        // exist is rewritten (its elevation may have been reset by a move).
        if (!out[0]) {
          bool any = false;
          for (size_t x = 0, e = static_cast<size_t>(H) * static_cast<size_t>(W); x < e && !any; ++x)
            any = std::isfinite(G[x]);
          if (!any && !map.tileAllocated(l.slope, t) && !map.tileAllocated(l.roughness, t) &&
              !map.tileAllocated(l.step, t) && !map.tileAllocated(l.traversability, t))
            continue;
          if (!map.tryAllocateTile(t, {l.slope, l.roughness, l.step, l.traversability})) {
            budget[static_cast<size_t>(task)] = 1;
            giveScratch(std::move(sp));
            return;
          }
          out[0] = map.mutableTileData(l.slope, t);
          out[1] = map.mutableTileData(l.roughness, t);
          out[2] = map.mutableTileData(l.step, t);
          out[3] = map.mutableTileData(l.traversability, t);
        }
        const size_t ob = static_cast<size_t>(rr[ri].buffer - rect.r0) * static_cast<size_t>(T) +
                          static_cast<size_t>(cr[ci].buffer - rect.c0);
        fit += avx2 ? computeBlockAvx2(G, b, lim, s, out, ob, T) : computeBlockBaseline(G, b, lim, s, out, ob, T);
      }
    giveScratch(std::move(sp));
    fitted[static_cast<size_t>(task)] = fit;
    written[static_cast<size_t>(task)] = out[0] ? 1 : 0;
  });
  PassStats st;
  for (size_t x = 0; x < tiles.size(); ++x) {
    st.tiles += written[x];
    st.cells_fitted += fitted[x];
    st.tile_budget += budget[x];
  }
  return st;
}

}  // namespace terramap::plugins
