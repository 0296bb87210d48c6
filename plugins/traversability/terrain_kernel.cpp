// The per-tile kernel: gather a tile's elevation with a halo in logical order, then plane-fit
// moments by running sums (O(1) per cell whatever the window), step height by van Herk /
// Gil-Werman max and min filters, and the four outputs written straight into the tile.
#include "traversability.hpp"

#include <algorithm>
#include <cmath>
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
  std::vector<float> g;                       // gathered heights, (h + 2K) x (w + 2K), row-major
  std::vector<double> p0, p1, p2, pz, p1z, pzz;  // prefix sums along one gathered row
  std::vector<double> a0, a1, a2, b0, b1, c0;    // row-window moments, (h + 2k) x w
  std::vector<double> n, qx, qxx, y, qxy, yy, z, qxz, yz, zz;  // column running sums, w each
  std::vector<float> hmax, hmin;              // row-window max / min, (h + 2ks) x w
  std::vector<float> gmax, gmin, rmax, rmin;  // van Herk prefix / suffix buffers
  std::vector<float> smax, smin;              // window max / min of one output row, w each
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

// Van Herk / Gil-Werman: out[x] = max (or min) of in[x .. x + L - 1] for x in [0, n - L + 1),
// through block prefix (pre) and suffix (suf) extremes over blocks of L: three comparisons per
// element whatever L. Max and min are exact, so the result is the brute-force one bit for bit.
template <bool kMax>
void slidingExtreme(const float* in, int n, int L, float* pre, float* suf, float* out) {
  auto pick = [](float a, float b) { return kMax ? (a > b ? a : b) : (a < b ? a : b); };
  for (int x = 0; x < n; ++x) pre[x] = (x % L == 0) ? in[x] : pick(pre[x - 1], in[x]);
  suf[n - 1] = in[n - 1];
  for (int x = n - 2; x >= 0; --x) suf[x] = ((x + 1) % L == 0) ? in[x] : pick(suf[x + 1], in[x]);
  for (int x = 0; x + L <= n; ++x) out[x] = pick(suf[x], pre[x + L - 1]);
}

}  // namespace

Traversability::PassStats Traversability::runTiles(LayeredMap& map, const Executor& ex, const TraversabilityLayers& l,
                                                   const std::vector<int>& tiles) const {
  const Geometry& geo = map.geometry();
  const int R = geo.size().x(), C = geo.size().y();
  const int T = map.tileSize();
  const double res = geo.resolution();
  const int k = planeHalfWidth(res), ks = stepHalfWidth(res);
  const int K = std::max(k, ks);
  const Index start = map.startIndex();
  const TraversabilityConfig cfg = cfg_;
  const double wsum = cfg.weight_slope + cfg.weight_roughness + cfg.weight_step;
  const double inv_res2 = 1.0 / (res * res);

  std::vector<long> fitted(tiles.size(), 0), budget(tiles.size(), 0), written(tiles.size(), 0);
  ex.forEach(static_cast<int>(tiles.size()), [&](int task) {
    const int t = tiles[static_cast<size_t>(task)];
    const CellRect rect = map.tileRect(t);
    Run rr[2], cr[2];
    const int nr = logicalRuns(rect.r0, rect.rows, start.x(), R, rr);
    const int nc = logicalRuns(rect.c0, rect.cols, start.y(), C, cr);
    std::unique_ptr<Scratch> sp = takeScratch();
    Scratch& s = *sp;
    float* out_slope = nullptr;
    float* out_rough = nullptr;
    float* out_step = nullptr;
    float* out_trav = nullptr;
    long fit = 0;
    for (int ri = 0; ri < nr; ++ri)
      for (int ci = 0; ci < nc; ++ci) {
        const int h = rr[ri].len, w = cr[ci].len;
        const int H = h + 2 * K, W = w + 2 * K;
        grow(s.g, static_cast<size_t>(H) * static_cast<size_t>(W));
        gather(map, l.elevation, rr[ri].logical - K, cr[ci].logical - K, H, W, s.g.data());
        const float* G = s.g.data();
        // A sparse map's tile with nothing known around it needs no outputs; one whose outputs
        // exist is rewritten (its elevation may have been reset by a move).
        if (!out_slope) {
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
          out_slope = map.mutableTileData(l.slope, t);
          out_rough = map.mutableTileData(l.roughness, t);
          out_step = map.mutableTileData(l.step, t);
          out_trav = map.mutableTileData(l.traversability, t);
        }
        // Heights relative to the block's first known one, so the squared sums keep their
        // digits at any altitude (the fit does not depend on the offset).
        double zref = 0.0;
        for (size_t x = 0, e = static_cast<size_t>(H) * static_cast<size_t>(W); x < e; ++x)
          if (std::isfinite(G[x])) {
            zref = G[x];
            break;
          }

        // ---- plane fit, pass 1: along each gathered row, moments of the 2k + 1 cells around
        // every output column (prefix sums, then differences). Mask moments are small integers,
        // exact in double.
        const int rows1 = h + 2 * k;
        const size_t n1 = static_cast<size_t>(rows1) * static_cast<size_t>(w);
        grow(s.a0, n1), grow(s.a1, n1), grow(s.a2, n1), grow(s.b0, n1), grow(s.b1, n1), grow(s.c0, n1);
        for (auto* v : {&s.p0, &s.p1, &s.p2, &s.pz, &s.p1z, &s.pzz}) grow(*v, static_cast<size_t>(W) + 1);
        for (int q = 0; q < rows1; ++q) {
          const float* row = G + static_cast<size_t>(K - k + q) * static_cast<size_t>(W);
          double P0 = 0, P1 = 0, P2 = 0, Pz = 0, P1z = 0, Pzz = 0;
          s.p0[0] = s.p1[0] = s.p2[0] = s.pz[0] = s.p1z[0] = s.pzz[0] = 0.0;
          for (int x = 0; x < W; ++x) {
            const float v = row[x];
            if (std::isfinite(v)) {
              const double z = static_cast<double>(v) - zref;
              const double xd = x;
              P0 += 1.0;
              P1 += xd;
              P2 += xd * xd;
              Pz += z;
              P1z += xd * z;
              Pzz += z * z;
            }
            s.p0[x + 1] = P0, s.p1[x + 1] = P1, s.p2[x + 1] = P2;
            s.pz[x + 1] = Pz, s.p1z[x + 1] = P1z, s.pzz[x + 1] = Pzz;
          }
          const size_t o = static_cast<size_t>(q) * static_cast<size_t>(w);
          for (int c = 0; c < w; ++c) {
            const int gc = K + c, lo = gc - k, hi = gc + k + 1;
            const double g = gc;
            const double m0 = s.p0[hi] - s.p0[lo], m1 = s.p1[hi] - s.p1[lo], m2 = s.p2[hi] - s.p2[lo];
            const double mz = s.pz[hi] - s.pz[lo], m1z = s.p1z[hi] - s.p1z[lo];
            s.a0[o + c] = m0;
            s.a1[o + c] = m1 - g * m0;
            s.a2[o + c] = m2 - 2.0 * g * m1 + g * g * m0;
            s.b0[o + c] = mz;
            s.b1[o + c] = m1z - g * mz;
            s.c0[o + c] = s.pzz[hi] - s.pzz[lo];
          }
        }

        // ---- step height, pass 1: max and min of the 2ks + 1 cells around every output column.
        const int L = 2 * ks + 1;
        const int rows2 = h + 2 * ks;
        const size_t n2 = static_cast<size_t>(rows2) * static_cast<size_t>(w);
        grow(s.hmax, n2), grow(s.hmin, n2);
        const int span = std::max(W, rows2);
        for (auto* v : {&s.gmax, &s.gmin, &s.rmax, &s.rmin}) grow(*v, static_cast<size_t>(span) * static_cast<size_t>(w));
        for (int q = 0; q < rows2; ++q) {
          const float* row = G + static_cast<size_t>(K - ks + q) * static_cast<size_t>(W);
          float* hi_in = s.rmax.data();  // the row with unknown cells neutral for max / min
          float* lo_in = s.rmin.data();
          for (int x = 0; x < W; ++x) {
            const bool known = std::isfinite(row[x]);
            hi_in[x] = known ? row[x] : -kInf;
            lo_in[x] = known ? row[x] : kInf;
          }
          const size_t o = static_cast<size_t>(q) * static_cast<size_t>(w);
          // Output column c's window starts at gathered column K + c - ks.
          slidingExtreme<true>(hi_in + (K - ks), w + 2 * ks, L, s.gmax.data(), s.gmin.data(), s.hmax.data() + o);
          slidingExtreme<false>(lo_in + (K - ks), w + 2 * ks, L, s.gmax.data(), s.gmin.data(), s.hmin.data() + o);
        }
        // Pass 2 down the columns, all columns of a row at once (contiguous, vectorised):
        // block prefix / suffix extremes over rows, van Herk again.
        {
          float* pmax = s.gmax.data();
          float* pmin = s.gmin.data();
          float* qmax = s.rmax.data();
          float* qmin = s.rmin.data();
          const size_t W2 = static_cast<size_t>(w);
          for (int q = 0; q < rows2; ++q) {
            const float* hx = s.hmax.data() + q * W2;
            const float* hn = s.hmin.data() + q * W2;
            float* px = pmax + q * W2;
            float* pn = pmin + q * W2;
            if (q % L == 0) {
              std::memcpy(px, hx, sizeof(float) * W2);
              std::memcpy(pn, hn, sizeof(float) * W2);
            } else {
              const float* ppx = px - W2;
              const float* ppn = pn - W2;
              for (size_t c = 0; c < W2; ++c) {
                px[c] = ppx[c] > hx[c] ? ppx[c] : hx[c];
                pn[c] = ppn[c] < hn[c] ? ppn[c] : hn[c];
              }
            }
          }
          for (int q = rows2 - 1; q >= 0; --q) {
            const float* hx = s.hmax.data() + q * W2;
            const float* hn = s.hmin.data() + q * W2;
            float* sx = qmax + q * W2;
            float* sn = qmin + q * W2;
            if (q == rows2 - 1 || (q + 1) % L == 0) {
              std::memcpy(sx, hx, sizeof(float) * W2);
              std::memcpy(sn, hn, sizeof(float) * W2);
            } else {
              const float* nx = sx + W2;
              const float* nn = sn + W2;
              for (size_t c = 0; c < W2; ++c) {
                sx[c] = nx[c] > hx[c] ? nx[c] : hx[c];
                sn[c] = nn[c] < hn[c] ? nn[c] : hn[c];
              }
            }
          }
        }

        // ---- plane fit, pass 2: running sums down the columns over the 2k + 1 rows of the
        // window; row q of pass 1 weighs with its index q, recentred on the window's middle.
        for (auto* v : {&s.n, &s.qx, &s.qxx, &s.y, &s.qxy, &s.yy, &s.z, &s.qxz, &s.yz, &s.zz}) {
          grow(*v, static_cast<size_t>(w));
          std::fill(v->begin(), v->begin() + w, 0.0);
        }
        auto addRow = [&](int q, double sign) {
          const size_t o = static_cast<size_t>(q) * static_cast<size_t>(w);
          const double wq = q, wqq = static_cast<double>(q) * q;
          for (int c = 0; c < w; ++c) {
            const double A0 = sign * s.a0[o + c], A1 = sign * s.a1[o + c], B0 = sign * s.b0[o + c];
            s.n[c] += A0;
            s.qx[c] += wq * A0;
            s.qxx[c] += wqq * A0;
            s.y[c] += A1;
            s.qxy[c] += wq * A1;
            s.yy[c] += sign * s.a2[o + c];
            s.z[c] += B0;
            s.qxz[c] += wq * B0;
            s.yz[c] += sign * s.b1[o + c];
            s.zz[c] += sign * s.c0[o + c];
          }
        };
        for (int q = 0; q < 2 * k; ++q) addRow(q, 1.0);
        const double min_n = static_cast<double>(cfg.min_points);
        const float fcs = static_cast<float>(cfg.critical_slope_rad);
        const float fcr = static_cast<float>(cfg.critical_roughness_m);
        const float fch = static_cast<float>(cfg.critical_step_m);
        for (int r = 0; r < h; ++r) {
          addRow(r + 2 * k, 1.0);
          const double qc = r + k;
          const float* centre = G + static_cast<size_t>(K + r) * static_cast<size_t>(W) + K;
          // Step window of output row r: pass-1 rows [r, r + L - 1].
          const float* smax_lo = s.rmax.data() + static_cast<size_t>(r) * static_cast<size_t>(w);
          const float* smax_hi = s.gmax.data() + static_cast<size_t>(r + L - 1) * static_cast<size_t>(w);
          const float* smin_lo = s.rmin.data() + static_cast<size_t>(r) * static_cast<size_t>(w);
          const float* smin_hi = s.gmin.data() + static_cast<size_t>(r + L - 1) * static_cast<size_t>(w);
          const size_t ob = static_cast<size_t>(rr[ri].buffer - rect.r0 + r) * static_cast<size_t>(T) +
                            static_cast<size_t>(cr[ci].buffer - rect.c0);
          for (int c = 0; c < w; ++c) {
            float slope = kNaN, rough = kNaN, step = kNaN, trav = kNaN;
            const double n = s.n[c];
            if (std::isfinite(centre[c])) {
              const float mx = smax_lo[c] > smax_hi[c] ? smax_lo[c] : smax_hi[c];
              const float mn = smin_lo[c] < smin_hi[c] ? smin_lo[c] : smin_hi[c];
              step = mx - mn;
              if (n >= min_n) {
                // Sums over the window with offsets x (rows) and y (columns) from its middle.
                const double Sx = s.qx[c] - qc * n, Sxx = s.qxx[c] - 2.0 * qc * s.qx[c] + qc * qc * n;
                const double Sy = s.y[c], Sxy = s.qxy[c] - qc * s.y[c], Syy = s.yy[c];
                const double Sz = s.z[c], Sxz = s.qxz[c] - qc * s.z[c], Syz = s.yz[c], Szz = s.zz[c];
                // n² times the covariances: the mask ones are exact integers, so collinear
                // cells give det == 0 exactly.
                const double Dxx = n * Sxx - Sx * Sx, Dyy = n * Syy - Sy * Sy, Dxy = n * Sxy - Sx * Sy;
                const double Dxz = n * Sxz - Sx * Sz, Dyz = n * Syz - Sy * Sz, Dzz = n * Szz - Sz * Sz;
                const double det = Dxx * Dyy - Dxy * Dxy;
                if (det > 0.0) {
                  const double b = (Dyy * Dxz - Dxy * Dyz) / det;  // m per cell along rows
                  const double cc = (Dxx * Dyz - Dxy * Dxz) / det;  // m per cell along columns
                  const double g2 = (b * b + cc * cc) * inv_res2;
                  const double msr = std::max(0.0, Dzz - b * Dxz - cc * Dyz) / (n * n);
                  slope = static_cast<float>(std::atan(std::sqrt(g2)));
                  rough = static_cast<float>(std::sqrt(msr / (1.0 + g2)));
                  const float ts = 1.0f - std::min(1.0f, slope / fcs);
                  const float tr = 1.0f - std::min(1.0f, rough / fcr);
                  const float th = 1.0f - std::min(1.0f, step / fch);
                  if (cfg.any_critical_blocks && (ts <= 0.0f || tr <= 0.0f || th <= 0.0f))
                    trav = 0.0f;
                  else
                    trav = static_cast<float>((cfg.weight_slope * ts + cfg.weight_roughness * tr +
                                               cfg.weight_step * th) / wsum);
                  ++fit;
                }
              }
            }
            out_slope[ob + c] = slope;
            out_rough[ob + c] = rough;
            out_step[ob + c] = step;
            out_trav[ob + c] = trav;
          }
          addRow(r, -1.0);
        }
      }
    giveScratch(std::move(sp));
    fitted[static_cast<size_t>(task)] = fit;
    written[static_cast<size_t>(task)] = out_slope ? 1 : 0;
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
