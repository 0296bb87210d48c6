// Truth terrain: node grid, bilinear queries, mass-moving primitives, pyramid ray casting.
#include <terramap/core/memory_budget.hpp>
#include <terramap/core/error.hpp>
#include <terramap/sim/truth_terrain.hpp>

#include <algorithm>
#include <atomic>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace terramap::sim {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Rounds a double up to the next float so a float bound is never below the double value.
float upperFloat(double v) {
  // Rounded to float, then always bumped up by more than one ulp: an upper bound whichever way
  // the rounding went. Testing which way it went costs a branch that is mispredicted half the
  // time (it was most of the pyramid refresh time); the bound is only used for skipping.
  const float f = static_cast<float>(v);
  return f + (std::abs(f) * 2.4e-7f + 1e-30f);
}

/// Ray-box slab test in xy; returns false if [t0, t1] ∩ box is empty.
bool slabXY(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double x0, double x1, double y0,
            double y1, double& t0, double& t1) {
  for (int a = 0; a < 2; ++a) {
    const double lo = a == 0 ? x0 : y0, hi = a == 0 ? x1 : y1;
    if (d[a] == 0.0) {
      if (o[a] < lo || o[a] > hi) return false;
      continue;
    }
    const double inv = 1.0 / d[a];
    double ta = (lo - o[a]) * inv, tb = (hi - o[a]) * inv;
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
    if (t0 > t1) return false;
  }
  return true;
}

}  // namespace

// ---- DEM ------------------------------------------------------------------------------------

double DemGrid::heightAt(double x, double y) const {
  const double fx = (x - x0_m) / cell_m, fy = (y - y0_m) / cell_m;
  if (!(fx >= 0 && fy >= 0 && fx <= nx - 1 && fy <= ny - 1)) return kNaN;
  int i = std::min(static_cast<int>(fx), nx - 2), j = std::min(static_cast<int>(fy), ny - 2);
  if (nx == 1) i = 0;
  if (ny == 1) j = 0;
  const double u = fx - i, v = fy - j;
  auto at = [&](int a, int b) { return z[static_cast<std::size_t>(std::min(b, ny - 1)) * nx + std::min(a, nx - 1)]; };
  return (1 - u) * (1 - v) * at(i, j) + u * (1 - v) * at(i + 1, j) + (1 - u) * v * at(i, j + 1) +
         u * v * at(i + 1, j + 1);
}

DemGrid readEsriAscii(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw InputError(path + ": cannot open DEM file");
  DemGrid g;
  bool corner_x = false, corner_y = false, have_x = false, have_y = false, have_cell = false;
  double nodata = -9999.0, xll = 0, yll = 0;
  bool have_nodata = false;
  std::string line;
  int line_no = 0;
  std::streampos data_start = 0;
  // Header: keyword value pairs until the first line starting with a number.
  while (true) {
    data_start = in.tellg();
    if (!std::getline(in, line)) throw InputError(path + ": unexpected end of file in the header");
    ++line_no;
    std::istringstream ls(line);
    std::string key;
    if (!(ls >> key)) continue;
    if (std::isdigit(static_cast<unsigned char>(key[0])) || key[0] == '-' || key[0] == '.' || key[0] == '+') {
      --line_no;
      break;
    }
    std::string k = key;
    std::transform(k.begin(), k.end(), k.begin(), [](unsigned char c) { return std::tolower(c); });
    double v = 0;
    if (!(ls >> v)) throw InputError(path + ":" + std::to_string(line_no) + ": header '" + key + "' has no numeric value");
    const std::string at = path + ":" + std::to_string(line_no) + ": header '" + key + "' ";
    if (!std::isfinite(v) || std::abs(v) > 1e12)
      throw InputError(at + "is " + line.substr(line.find(key) + key.size()) + ", not a finite value of a plausible magnitude");
    if ((k == "ncols" || k == "nrows") && (v != std::floor(v) || v < 2 || v > 1e9))
      throw InputError(at + "must be a whole number of cells >= 2 (is " + std::to_string(v) + ")");
    if (k == "ncols") g.nx = static_cast<int>(v);
    else if (k == "nrows") g.ny = static_cast<int>(v);
    else if (k == "xllcorner") { xll = v; corner_x = true; have_x = true; }
    else if (k == "xllcenter") { xll = v; have_x = true; }
    else if (k == "yllcorner") { yll = v; corner_y = true; have_y = true; }
    else if (k == "yllcenter") { yll = v; have_y = true; }
    else if (k == "cellsize") { g.cell_m = v; have_cell = true; }
    else if (k == "nodata_value") { nodata = v; have_nodata = true; }
    else throw InputError(path + ":" + std::to_string(line_no) + ": unknown ESRI ASCII header '" + key + "'");
  }
  if (g.nx < 2 || g.ny < 2 || !have_x || !have_y || !have_cell || !(g.cell_m > 0))
    throw InputError(path + ": ESRI ASCII header needs ncols >= 2, nrows >= 2, xll*, yll*, cellsize > 0");
  g.x0_m = xll + (corner_x ? 0.5 * g.cell_m : 0.0);
  g.y0_m = yll + (corner_y ? 0.5 * g.cell_m : 0.0);
  in.clear();
  in.seekg(data_start);
  // Every value takes at least two bytes of the file (a digit and a separator): a header that
  // declares more values than the file can hold is refused before the grid is allocated, and
  // so is one whose grid exceeds the memory budget.
  const std::uint64_t values = saturatingProduct({static_cast<std::uint64_t>(g.nx), static_cast<std::uint64_t>(g.ny)});
  std::error_code ec;
  const std::uint64_t file_bytes = std::filesystem::file_size(path, ec);
  const std::uint64_t body = ec ? 0 : file_bytes - std::min<std::uint64_t>(file_bytes, static_cast<std::uint64_t>(data_start));
  if (!ec && values > body / 2 + 1)
    throw InputError(path + ": ESRI ASCII header declares ncols " + std::to_string(g.nx) + " x nrows " +
                     std::to_string(g.ny) + " = " + std::to_string(values) + " values, but the " + std::to_string(body) +
                     " bytes after the header can hold at most " + std::to_string(body / 2 + 1));
  requireInputBudget(saturatingProduct({values, sizeof(double)}), path + ": ESRI ASCII grid ncols " +
                     std::to_string(g.nx) + " x nrows " + std::to_string(g.ny), "8 bytes per value");
  g.z.assign(static_cast<std::size_t>(g.nx) * g.ny, kNaN);
  for (int r = 0; r < g.ny; ++r) {
    const int j = g.ny - 1 - r;  // first row is the northern one
    for (int i = 0; i < g.nx; ++i) {
      std::string tok;
      if (!(in >> tok))
        throw InputError(path + ": expected " + std::to_string(values) + " values, file ends in row " +
                         std::to_string(r + 1));
      double v = 0;
      try {
        size_t used = 0;
        v = std::stod(tok, &used);
        if (used != tok.size()) throw std::invalid_argument(tok);
      } catch (const std::exception&) {
        throw InputError(path + ": row " + std::to_string(r + 1) + ", column " + std::to_string(i + 1) +
                         ": not a number: '" + tok + "'");
      }
      g.z[static_cast<std::size_t>(j) * g.nx + i] = (have_nodata && v == nodata) ? kNaN : v;
    }
  }
  return g;
}

// ---- grid -----------------------------------------------------------------------------------

TruthTerrain::TruthTerrain(double origin_x_m, double origin_y_m, double resolution_m, int nx, int ny,
                           double height_m)
    : ox_(origin_x_m), oy_(origin_y_m), res_(resolution_m), nx_(nx), ny_(ny) {
  if (!(resolution_m > 0) || nx < 2 || ny < 2)
    throw std::invalid_argument("TruthTerrain: resolution must be > 0 and the grid at least 2x2 nodes");
  // Per node: u, lv, lc, h (double), h0 (float) and the ray-casting pyramid (< 4/3 float).
  requireConfigBudget(saturatingProduct({static_cast<std::uint64_t>(nx), static_cast<std::uint64_t>(ny), 42}),
                      "truth terrain of " + std::to_string(nx) + " x " + std::to_string(ny) +
                          " nodes (terrain.size_m / terrain.resolution_m)",
                      "42 bytes per node");
  const std::size_t n = static_cast<std::size_t>(nx) * ny;
  u_.assign(n, height_m);
  lv_.assign(n, 0.0);
  lc_.assign(n, 0.0);
  h_.assign(n, height_m);
  h0_.assign(n, static_cast<float>(height_m));
  loose_run_.assign((n >> kLooseRunShift) + 1, 0);
  rev_w_ = (nx - 1 + kRevisionBlock - 1) / kRevisionBlock;  // over the (nx - 1) x (ny - 1) cells
  rev_h_ = (ny - 1 + kRevisionBlock - 1) / kRevisionBlock;
  block_rev_.assign(static_cast<std::size_t>(rev_w_) * static_cast<std::size_t>(rev_h_), 0);
  // Pyramid levels over cells.
  int w = nx - 1, h = ny - 1;
  while (true) {
    Level L;
    L.w = w;
    L.h = h;
    L.zmax.assign(static_cast<std::size_t>(w) * h, upperFloat(height_m));
    levels_.push_back(std::move(L));
    if (w == 1 && h == 1) break;
    w = (w + 1) / 2;
    h = (h + 1) / 2;
  }
}

void TruthTerrain::setUndisturbed(int i, int j, double h) {
  const auto k = index(i, j);
  u_[k] = h;
  lv_[k] = 0.0;
  lc_[k] = 0.0;
  h_[k] = u_[k] + lv_[k];
}

void TruthTerrain::captureInitial() {
  for (std::size_t k = 0; k < u_.size(); ++k) h0_[k] = static_cast<float>(h_[k]);
}

TruthTerrain::Removed TruthTerrain::removeBetween(int i, int j, double z_lo, double z_hi) {
  Removed r;
  const auto k = index(i, j);
  const double H = u_[k] + lv_[k];
  const double top = std::min(H, z_hi);
  if (!(top > z_lo)) return r;
  // Loose soil occupies [U, H]; undisturbed below U.
  const double U = u_[k];
  const double loose_part = std::max(0.0, top - std::max(z_lo, U));
  const double bank_part = std::max(0.0, std::min(top, U) - z_lo);
  if (loose_part > 0.0 && lv_[k] > 0.0) {
    const double ratio = lc_[k] / lv_[k];
    const double dv = std::min(loose_part, lv_[k]);
    const double dc = (dv == lv_[k]) ? lc_[k] : dv * ratio;
    lv_[k] -= dv;
    lc_[k] -= dc;
    r.loose_v = dv;
    r.loose_c = dc;
  }
  if (bank_part > 0.0) {
    // Removing bank soil under a loose cover lets the cover drop: U decreases, Lv stays.
    u_[k] -= bank_part;
    r.bank_u = bank_part;
  }
  h_[k] = u_[k] + lv_[k];
  return r;
}

void TruthTerrain::addLoose(int i, int j, double v, double c) {
  const auto k = index(i, j);
  lv_[k] += v;
  lc_[k] += c;
  h_[k] = u_[k] + lv_[k];
  if (lv_[k] > 0.0) loose_run_[k >> kLooseRunShift] = 1;
}

int TruthTerrain::firstLoose(int j, int a, int b) const {
  const std::ptrdiff_t base = static_cast<std::ptrdiff_t>(index(0, j)), end = base + b;
  for (std::ptrdiff_t k = base + a; k <= end;) {
    if (!loose_run_[static_cast<std::size_t>(k) >> kLooseRunShift]) {
      k = (k | ((1 << kLooseRunShift) - 1)) + 1;
      continue;
    }
    for (const std::ptrdiff_t e = std::min(end, k | ((1 << kLooseRunShift) - 1)); k <= e; ++k)
      if (lv_[static_cast<std::size_t>(k)] > 0.0) return static_cast<int>(k - base);
  }
  return b + 1;
}

int TruthTerrain::lastLoose(int j, int a, int b) const {
  const std::ptrdiff_t base = static_cast<std::ptrdiff_t>(index(0, j)), start = base + a;
  for (std::ptrdiff_t k = base + b; k >= start;) {
    const std::ptrdiff_t run0 = k & ~static_cast<std::ptrdiff_t>((1 << kLooseRunShift) - 1);
    if (!loose_run_[static_cast<std::size_t>(k) >> kLooseRunShift]) {
      k = run0 - 1;
      continue;
    }
    for (const std::ptrdiff_t e = std::max(start, run0); k >= e; --k)
      if (lv_[static_cast<std::size_t>(k)] > 0.0) return static_cast<int>(k - base);
  }
  return a - 1;
}

void TruthTerrain::compact(int i, int j, double dz) {
  if (!(dz > 0.0)) return;
  const auto k = index(i, j);
  // Loose soil can lose its swell (Lv - Lc) without losing mass.
  const double loose_room = std::max(0.0, lv_[k] - lc_[k]);
  const double from_loose = std::min(dz, loose_room);
  lv_[k] -= from_loose;
  const double from_bank = dz - from_loose;
  if (from_bank > 0.0) {
    // Below the loose layer, bank soil: lower U under the (unchanged) loose layer.
    u_[k] -= from_bank;
    compacted_m3_ += from_bank * res_ * res_;
    if (pressed_.empty()) pressed_.reset(nx_, ny_, 0.0);
    pressed_.at(i, j) += from_bank;
  }
  h_[k] = u_[k] + lv_[k];
}

double TruthTerrain::heightAt(double x, double y) const { return bilinear(h_, x, y); }

double TruthTerrain::undisturbedAt(double x, double y) const { return bilinear(u_, x, y); }

double TruthTerrain::pressedAt(double x, double y) const {
  return bilinearAt(x, y, [this](int i, int j) { return pressed_.empty() ? 0.0 : pressed_.get(i, j); });
}

double TruthTerrain::initialHeightAt(double x, double y) const {
  return bilinearAt(x, y, [this](int i, int j) { return static_cast<double>(h0_[index(i, j)]); });
}

Eigen::Vector2d TruthTerrain::gradientAt(double x, double y) const {
  const double fx = (x - ox_) / res_, fy = (y - oy_) / res_;
  if (!(fx >= 0 && fy >= 0 && fx <= nx_ - 1 && fy <= ny_ - 1)) return {kNaN, kNaN};
  const int i = std::min(static_cast<int>(fx), nx_ - 2), j = std::min(static_cast<int>(fy), ny_ - 2);
  const double u = fx - i, v = fy - j;
  const double z00 = height(i, j), z10 = height(i + 1, j), z01 = height(i, j + 1), z11 = height(i + 1, j + 1);
  const double c = z00 - z10 - z01 + z11;
  return {((z10 - z00) + c * v) / res_, ((z01 - z00) + c * u) / res_};
}

double TruthTerrain::bankVolume(double datum) const {
  // Kahan-free but order-fixed sum: deterministic.
  double s = 0.0;
  for (std::size_t k = 0; k < u_.size(); ++k) s += (u_[k] - datum) + lc_[k];
  return s * res_ * res_;
}

// ---- pyramid --------------------------------------------------------------------------------

double TruthTerrain::nodeMaxCell(int ci, int cj) const {
  return std::max(std::max(height(ci, cj), height(ci + 1, cj)), std::max(height(ci, cj + 1), height(ci + 1, cj + 1)));
}

void TruthTerrain::capturePatch(int i0, int j0, int i1, int j1, Patch& out) const {
  out.i0 = std::max(0, i0); out.j0 = std::max(0, j0);
  out.i1 = std::min(nx_ - 1, i1); out.j1 = std::min(ny_ - 1, j1);
  out.lost_m3 = lost_m3_;
  out.compacted_m3 = compacted_m3_;
  const int w = std::max(0, out.i1 - out.i0 + 1), hgt = std::max(0, out.j1 - out.j0 + 1);
  const std::size_t n = out.nodes();
  if (out.u.size() < n) {
    out.u.resize(n);
    out.lv.resize(n);
    out.lc.resize(n);
  }
  for (int j = 0; j < hgt; ++j) {
    const std::size_t src = index(out.i0, out.j0 + j), dst = static_cast<std::size_t>(j) * w;
    std::copy_n(&u_[src], w, &out.u[dst]);
    std::copy_n(&lv_[src], w, &out.lv[dst]);
    std::copy_n(&lc_[src], w, &out.lc[dst]);
  }
}

void TruthTerrain::applyPatch(const Patch& p) {
  lost_m3_ = p.lost_m3;
  compacted_m3_ = p.compacted_m3;
  const int w = p.i1 - p.i0 + 1, hgt = p.j1 - p.j0 + 1;
  if (w <= 0 || hgt <= 0) return;
  if (p.i0 < 0 || p.j0 < 0 || p.i1 >= nx_ || p.j1 >= ny_ || p.u.size() < p.nodes() || p.lv.size() < p.nodes() ||
      p.lc.size() < p.nodes())
    throw std::invalid_argument("TruthTerrain::applyPatch: the patch does not fit this grid");
  for (int j = 0; j < hgt; ++j) {
    const std::size_t src = static_cast<std::size_t>(j) * w, dst = index(p.i0, p.j0 + j);
    std::copy_n(&p.u[src], w, &u_[dst]);
    std::copy_n(&p.lv[src], w, &lv_[dst]);
    std::copy_n(&p.lc[src], w, &lc_[dst]);
    for (int i = 0; i < w; ++i) {
      h_[dst + i] = u_[dst + i] + lv_[dst + i];
      if (lv_[dst + i] > 0.0) loose_run_[(dst + i) >> kLooseRunShift] = 1;
    }
  }
}

std::uint64_t TruthTerrain::InstanceId::next() {
  static std::atomic<std::uint64_t> counter{0};
  return ++counter;
}

bool TruthTerrain::cellsTouching(int i0, int j0, int i1, int j1, int& c0, int& r0, int& c1, int& r1) const {
  c0 = std::max(0, std::min(i0, i1) - 1), c1 = std::min(nx_ - 2, std::max(i0, i1));
  r0 = std::max(0, std::min(j0, j1) - 1), r1 = std::min(ny_ - 2, std::max(j0, j1));
  return c0 <= c1 && r0 <= r1;
}

bool TruthTerrain::changedSince(std::uint64_t r, int i0, int j0, int i1, int j1) const {
  int c0, r0, c1, r1;
  if (!cellsTouching(i0, j0, i1, j1, c0, r0, c1, r1)) return false;
  for (int by = r0 / kRevisionBlock; by <= r1 / kRevisionBlock; ++by)
    for (int bx = c0 / kRevisionBlock; bx <= c1 / kRevisionBlock; ++bx)
      if (blockRevision(bx, by) > r) return true;
  return false;
}

void TruthTerrain::refreshPyramid(int i0, int j0, int i1, int j1) {
  int c0, r0, c1, r1;
  if (!cellsTouching(i0, j0, i1, j1, c0, r0, c1, r1)) return;
  ++revision_;
  for (int by = r0 / kRevisionBlock; by <= r1 / kRevisionBlock; ++by)
    std::fill_n(&block_rev_[static_cast<std::size_t>(by) * rev_w_ + c0 / kRevisionBlock],
                c1 / kRevisionBlock - c0 / kRevisionBlock + 1, revision_);
  Level& L0 = levels_[0];
  for (int cj = r0; cj <= r1; ++cj) {
    const double* h0 = &h_[index(0, cj)];
    const double* h1 = h0 + nx_;
    float* out = &L0.zmax[static_cast<std::size_t>(cj) * L0.w];
    double prev = std::max(h0[c0], h1[c0]);
    for (int ci = c0; ci <= c1; ++ci) {
      const double nxt = std::max(h0[ci + 1], h1[ci + 1]);
      out[ci] = upperFloat(std::max(prev, nxt));
      prev = nxt;
    }
  }
  for (std::size_t l = 1; l < levels_.size(); ++l) {
    c0 /= 2; c1 /= 2; r0 /= 2; r1 /= 2;
    const Level& P = levels_[l - 1];
    Level& L = levels_[l];
    for (int by = r0; by <= r1; ++by) {
      for (int bx = c0; bx <= c1; ++bx) {
        float m = -std::numeric_limits<float>::infinity();
        for (int dy = 0; dy < 2; ++dy)
          for (int dx = 0; dx < 2; ++dx) {
            const int px = 2 * bx + dx, py = 2 * by + dy;
            if (px < P.w && py < P.h) m = std::max(m, P.zmax[static_cast<std::size_t>(py) * P.w + px]);
          }
        L.zmax[static_cast<std::size_t>(by) * L.w + bx] = m;
      }
    }
  }
}

// ---- ray casting ----------------------------------------------------------------------------

// `inline`: lets castCells inline it despite -fPIC (only this file calls it).
inline double TruthTerrain::cellHitZ(int ci, int cj, double z00, double z10, double z01, double z11, const Eigen::Vector3d& o,
                              const Eigen::Vector3d& d, double ta, double tb) const {
  const double a = z10 - z00, b = z01 - z00, c = z00 - z10 - z01 + z11;
  // Local coordinates at the interval start (s = t - ta).
  const double u0 = (o.x() + d.x() * ta - (ox_ + ci * res_)) / res_;
  const double v0 = (o.y() + d.y() * ta - (oy_ + cj * res_)) / res_;
  const double du = d.x() / res_, dv = d.y() / res_;
  const double h0 = z00 + a * u0 + b * v0 + c * u0 * v0;
  const double h1 = a * du + b * dv + c * (u0 * dv + v0 * du);
  const double h2 = c * du * dv;
  // f(s) = ray z - surface = C + B s + A s^2
  const double C = (o.z() + d.z() * ta) - h0;
  const double B = d.z() - h1;
  const double A = -h2;
  if (C <= 0.0) return ta;  // entered the cell at or below the surface
  const double len = tb - ta;
  double best = kNaN;
  if (std::abs(A) * len < 1e-12 * (std::abs(B) + 1e-300)) {
    if (B < 0.0) {
      const double s = -C / B;
      if (s <= len) best = s;
    }
  } else {
    const double disc = B * B - 4.0 * A * C;
    if (disc >= 0.0) {
      // The roots are q / A and C / q (the stable pair). With C > 0 only one of them can be
      // the first non-negative root, so one division: for B < 0, q > 0 and C / q is the
      // smaller positive root (A > 0) or the only one (A < 0); for B >= 0, q < 0, C / q < 0 and
      // q / A is positive only when A < 0 (B^2 >= 4AC makes C / q the smaller root when both are
      // positive; at a tangent the two may round either way).
      const double sq = std::sqrt(disc);
      if (B < 0.0) {
        const double r = C / (-0.5 * (B - sq));
        if (r <= len) best = r;
      } else if (A < 0.0) {
        const double r = (-0.5 * (B + sq)) / A;
        if (r >= 0.0 && r <= len) best = r;
      }
    }
  }
  return std::isnan(best) ? kNaN : ta + best;
}

double TruthTerrain::cellHit(int ci, int cj, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double ta,
                             double tb) const {
  const std::size_t k = index(ci, cj);
  return cellHitZ(ci, cj, h_[k], h_[k + 1], h_[k + nx_], h_[k + nx_ + 1], o, d, ta, tb);
}

double TruthTerrain::raycast(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min, double t_max) const {
  double t0 = t_min, t1 = t_max;
  if (!slabXY(o, d, ox_, maxX(), oy_, maxY(), t0, t1)) return kNaN;
  // Quadtree descent in ray order. A node's interval is split at the ray's crossings of the
  // node's two mid-lines, which gives the children it visits in order without any box test.
  struct Item { int level, bx, by; double ta, tb; };
  std::array<Item, 160> stack;
  int sp = 0;
  const int top = static_cast<int>(levels_.size()) - 1;
  stack[sp++] = {top, 0, 0, t0, t1};
  const double invx = d.x() != 0.0 ? 1.0 / d.x() : INFINITY;
  const double invy = d.y() != 0.0 ? 1.0 / d.y() : INFINITY;
  while (sp > 0) {
    const Item it = stack[--sp];
    const Level& L = levels_[it.level];
    const double za = o.z() + d.z() * it.ta, zb = o.z() + d.z() * it.tb;
    if (std::min(za, zb) > L.zmax[static_cast<std::size_t>(it.by) * L.w + it.bx]) continue;
    if (it.level == 0) {
      const double t = cellHit(it.bx, it.by, o, d, it.ta, it.tb);
      if (!std::isnan(t)) return t;
      continue;
    }
    const int cl = it.level - 1;
    const Level& C = levels_[cl];
    const int half = 1 << cl;
    const double xmid = ox_ + static_cast<double>((2 * it.bx + 1) * half) * res_;
    const double ymid = oy_ + static_cast<double>((2 * it.by + 1) * half) * res_;
    const double tm = 0.5 * (it.ta + it.tb);
    // Child at the interval start (decided at the midpoint side if the start lies on a line).
    const double pxa = o.x() + d.x() * it.ta, pya = o.y() + d.y() * it.ta;
    int cx = pxa > xmid || (pxa == xmid && d.x() > 0) ? 1 : 0;
    int cy = pya > ymid || (pya == ymid && d.y() > 0) ? 1 : 0;
    (void)tm;
    double tx = (xmid - o.x()) * invx, ty = (ymid - o.y()) * invy;
    if (!(tx > it.ta && tx < it.tb)) tx = INFINITY;
    if (!(ty > it.ta && ty < it.tb)) ty = INFINITY;
    Item seg[3];
    int ns = 0;
    double ts = it.ta;
    for (int k = 0; k < 3; ++k) {
      const double te = std::min(std::min(tx, ty), it.tb);
      const int gx = 2 * it.bx + cx, gy = 2 * it.by + cy;
      if (gx < C.w && gy < C.h) seg[ns++] = {cl, gx, gy, ts, te};
      if (te >= it.tb) break;
      if (tx <= ty) { cx ^= 1; tx = INFINITY; if (ty == te) { cy ^= 1; ty = INFINITY; } }
      else { cy ^= 1; ty = INFINITY; }
      ts = te;
    }
    for (int k = ns - 1; k >= 0; --k) stack[sp++] = seg[k];
  }
  return kNaN;
}

bool TruthTerrain::clipToGrid(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double& t0, double& t1) const {
  return slabXY(o, d, ox_, maxX(), oy_, maxY(), t0, t1);
}

double TruthTerrain::castCells(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_a, double t_b, int* cell_i,
                               int* cell_j) const {
  return castCells(o, d, d.x() != 0.0 ? 1.0 / d.x() : 0.0, d.y() != 0.0 ? 1.0 / d.y() : 0.0, t_a, t_b, cell_i, cell_j);
}

double TruthTerrain::castCells(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double inv_dx, double inv_dy,
                               double t_a, double t_b, int* cell_i, int* cell_j) const {
  if (!(t_b >= t_a)) return kNaN;
  // Cell of the start point (clamped: the caller clipped [t_a, t_b] to the grid, so only
  // rounding can put it a hair outside).
  // Reciprocals instead of quotients (this runs for every ray of a scan): they differ from the
  // quotients by an ulp at most, and a root at a cell boundary is found by either neighbouring cell.
  const double inv_res = 1.0 / res_;
  const double px = (o.x() + d.x() * t_a - ox_) * inv_res, py = (o.y() + d.y() * t_a - oy_) * inv_res;
  // Truncation equals floor here once clamped to >= 0 (and avoids a libm floor call).
  int ci = std::clamp(static_cast<int>(std::clamp(px, -1.0, static_cast<double>(nx_))), 0, nx_ - 2);
  int cj = std::clamp(static_cast<int>(std::clamp(py, -1.0, static_cast<double>(ny_))), 0, ny_ - 2);
  const int sx = d.x() > 0 ? 1 : -1, sy = d.y() > 0 ? 1 : -1;
  // Ray parameter of the next cell boundary in x / y: exact (as in the pyramid walk and the
  // reference) for the first boundary, then stepped by res / |d| (the walk is short, so the
  // accumulated rounding stays ~1e-15 relative; a root at a boundary is found by either cell).
  const double tx0 = d.x() != 0.0 ? (ox_ + (ci + (sx > 0 ? 1 : 0)) * res_ - o.x()) * inv_dx : INFINITY;
  const double ty0 = d.y() != 0.0 ? (oy_ + (cj + (sy > 0 ? 1 : 0)) * res_ - o.y()) * inv_dy : INFINITY;
  const double dtx = d.x() != 0.0 ? res_ * std::abs(inv_dx) : INFINITY;
  const double dty = d.y() != 0.0 ? res_ * std::abs(inv_dy) : INFINITY;
  double tx = tx0, ty = ty0;
  double t = t_a;
  double za = o.z() + d.z() * t;
  const double* h = h_.data();
  std::size_t k = static_cast<std::size_t>(cj) * nx_ + ci;
  const std::ptrdiff_t kx = sx, ky = sy > 0 ? nx_ : -static_cast<std::ptrdiff_t>(nx_);
  // Steps left before leaving the grid in x / y.
  int left_x = sx > 0 ? nx_ - 2 - ci : ci, left_y = sy > 0 ? ny_ - 2 - cj : cj;
  while (true) {
    const double te = std::min(std::min(tx, ty), t_b);
    if (te >= t) {
      const double zb = o.z() + d.z() * te;
      // The cell's own corners bound its bilinear patch exactly (and cellHitZ needs them
      // anyway): two cache lines, no pyramid access.
      const double z00 = h[k], z10 = h[k + 1], z01 = h[k + nx_], z11 = h[k + nx_ + 1];
      if (!(std::min(za, zb) > std::max(std::max(z00, z10), std::max(z01, z11)))) {
        const double hit = cellHitZ(ci, cj, z00, z10, z01, z11, o, d, t, te);
        if (!std::isnan(hit)) {
          if (cell_i) *cell_i = ci;
          if (cell_j) *cell_j = cj;
          return hit;
        }
      }
      t = te;
      za = zb;
    }
    if (te >= t_b) return kNaN;
    // The cell is tracked as (ci, cj) beside k: recovering it from k costs a 64-bit division.
    if (tx <= ty) {
      if (--left_x < 0) return kNaN;
      k += kx;
      ci += sx;
      tx += dtx;
    } else {
      if (--left_y < 0) return kNaN;
      k += ky;
      cj += sy;
      ty += dty;
    }
  }
}

double TruthTerrain::raycastReference(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min,
                                      double t_max) const {
  double t0 = t_min, t1 = t_max;
  if (!slabXY(o, d, ox_, maxX(), oy_, maxY(), t0, t1)) return kNaN;
  // Test every cell whose box the ray crosses, in order of entry (slow; tests only).
  struct Hit { double ta; int ci, cj; double tb; };
  std::vector<Hit> cells;
  for (int cj = 0; cj < ny_ - 1; ++cj) {
    for (int ci = 0; ci < nx_ - 1; ++ci) {
      double a = t0, b = t1;
      if (slabXY(o, d, ox_ + ci * res_, ox_ + (ci + 1) * res_, oy_ + cj * res_, oy_ + (cj + 1) * res_, a, b))
        cells.push_back({a, ci, cj, b});
    }
  }
  std::sort(cells.begin(), cells.end(), [](const Hit& p, const Hit& q) { return p.ta < q.ta; });
  for (const Hit& h : cells) {
    const double t = cellHit(h.ci, h.cj, o, d, h.ta, h.tb);
    if (!std::isnan(t)) return t;
  }
  return kNaN;
}

}  // namespace terramap::sim
