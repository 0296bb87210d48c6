// Mohr-Coulomb slip kernel: closed-form failure angle, carried velocity, 4-colour tiling.
#include "soil_erosion.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace terramap::plugins {

void ErosionGrid::resize(int r, int c) {
  rows = r;
  cols = c;
  const size_t n = static_cast<size_t>(r) * static_cast<size_t>(c);
  H.assign(n, 0.0);
  L.assign(n, 0.0);
  active.assign(n, 1);
  blade.assign(n, 0);
  z_mask.assign(n, std::numeric_limits<double>::quiet_NaN());
}

ErosionSolver::ErosionSolver(const ErosionConfig& cfg, double resolution_m) : cfg_(cfg), r_(resolution_m) {
  auto bad = [](const std::string& what) { throw ConfigError("soil erosion: " + what); };
  if (!(r_ > 0) || !std::isfinite(r_)) bad("resolution must be > 0");
  if (!(cfg_.cohesion_pa >= 0) || !std::isfinite(cfg_.cohesion_pa)) bad("cohesion_pa must be >= 0");
  if (!(cfg_.friction_rad >= 0 && cfg_.friction_rad < 1.5707963267948966)) bad("friction_rad must be in [0, pi/2)");
  if (!(cfg_.unit_weight_n_m3 > 0)) bad("unit_weight_n_m3 must be > 0");
  if (!(cfg_.dt_s > 0) || cfg_.substeps < 1) bad("dt_s must be > 0 and substeps >= 1");
  tan_phi_ = std::tan(cfg_.friction_rad);
  K_ = 2.0 * cfg_.cohesion_pa / cfg_.unit_weight_n_m3;
  // Critical drop: Fs(α*(dh)) decreases monotonically from +inf (dh -> 0) to 0 (dh -> inf),
  // so bisect for Fs = 1 (closed form r tan φ when c = 0).
  double crit = r_ * tan_phi_;
  if (cfg_.cohesion_pa > 0) {
    double lo = 0.0, hi = std::max(r_, 1e-3);
    while (safetyFactor(hi) >= 1.0 && hi < 1e6) hi *= 2.0;
    for (int k = 0; k < 200 && hi - lo > 1e-15 * hi; ++k) {
      const double mid = 0.5 * (lo + hi);
      (safetyFactor(mid) >= 1.0 ? lo : hi) = mid;
    }
    crit = hi;
  }
  dh_crit_ = std::max(crit, r_ * std::tan(std::max(0.0, cfg_.min_slope_rad)));
}

double ErosionSolver::failureTan(double dh) const {
  if (K_ == 0.0) return dh / r_;
  return dh / (r_ + std::sqrt(K_ * (r_ * r_ + dh * dh) / (dh * tan_phi_ + K_)));
}

double ErosionSolver::safetyFactorAt(double dh, double alpha) const {
  const double t = std::tan(alpha), ca = std::cos(alpha), sa = std::sin(alpha);
  const double W = 0.5 * cfg_.unit_weight_n_m3 * r_ * r_ * (dh - r_ * t);
  if (!(W > 0) || !(sa > 0)) return std::numeric_limits<double>::infinity();
  return (cfg_.cohesion_pa * (r_ / ca) * r_ + W * ca * tan_phi_) / (W * sa);
}

double ErosionSolver::safetyFactor(double dh) const {
  if (!(dh > 0)) return std::numeric_limits<double>::infinity();
  const double t = failureTan(dh);
  if (K_ == 0.0) return tan_phi_ / t;  // W -> 0 at α*, the ratio stays tan φ / tan α*
  return safetyFactorAt(dh, std::atan(t));
}

std::pair<int, int> ErosionSolver::offsetsAlong(const Eigen::Vector2d& m) {
  return {m.x() > 0 ? -1 : 1, m.y() > 0 ? -1 : 1};
}

bool ErosionSolver::exchange(ErosionGrid& g, size_t o, size_t n, double& v) const {
  if (!g.active[o] || !g.active[n]) {
    v = 0;
    return false;
  }
  double diff = g.H[o] - g.H[n];
  size_t hi = o, lo = n;
  double sgn = 1.0;
  if (diff < 0) {
    std::swap(hi, lo);
    diff = -diff;
    sgn = -1.0;
  }
  double speed = cfg_.carry_velocity ? v * sgn : 0.0;
  if (!(speed > 0)) speed = 0.0;
  // Stable drop (with a rounding margin, so a pair left exactly at the critical drop does not
  // keep trading ulps forever), or the blade holds the soil in place.
  if (diff <= dh_crit_ * (1.0 + 1e-9) + 1e-12 || g.blade[hi]) {
    v = 0;
    return false;
  }
  const double avail = std::min(diff, g.L[hi]);
  if (!(avail > 0)) {
    v = 0;
    return false;
  }
  const double t = failureTan(avail);
  const double ca = 1.0 / std::sqrt(1.0 + t * t), sa = t * ca;
  const double grav = cfg_.gravity;
  double acc;
  double fs;
  if (cfg_.cohesion_pa > 0) {
    const double W = 0.5 * cfg_.unit_weight_n_m3 * r_ * r_ * (avail - r_ * t);
    if (!(W > 0)) {
      v = 0;
      return false;
    }
    const double coh = cfg_.cohesion_pa * r_ * r_ / ca;  // c L_f r
    fs = (coh + W * ca * tan_phi_) / (W * sa);
    acc = grav * (sa - ca * tan_phi_) - coh * grav / W;
  } else {
    fs = tan_phi_ / t;
    acc = grav * (sa - ca * tan_phi_);
  }
  if (fs >= 1.0 && speed == 0.0) {
    v = 0;
    return false;
  }
  speed = std::max(0.0, speed + acc * cfg_.dt_s);
  if (!(speed > 0)) {
    v = 0;
    return false;
  }
  double h = avail * speed * cfg_.dt_s * ca / r_;
  bool stop = false;
  const double limit = 0.5 * (diff - dh_crit_);
  if (h >= limit) {
    h = limit;
    stop = true;
  }
  if (h > avail) h = avail;
  if (g.blade[lo]) {
    const double room = std::max(g.z_mask[lo] - g.H[lo], 0.0);
    if (!(h < room)) {
      h = room;
      stop = true;
    }
  }
  if (!(h > 0)) {
    v = 0;
    return false;
  }
  g.H[hi] -= h;
  g.L[hi] = std::max(0.0, g.L[hi] - h);
  g.H[lo] += h;
  g.L[lo] += h;
  v = stop ? 0.0 : sgn * speed;
  return true;
}

bool ErosionSolver::colour(ErosionGrid& g, int pr, int pc, int di, int dj, int row_begin, int row_end,
                           int col_begin, int col_end) const {
  bool any = false;
  for (int i = row_begin; i < row_end; ++i) {
    if ((i & 1) != pr) continue;
    const int ni = i + di;
    const bool row_ok = ni >= 0 && ni < g.rows;
    for (int j = col_begin + ((col_begin & 1) != pc ? 1 : 0); j < col_end; j += 2) {
      const size_t o = g.at(i, j);
      if (row_ok) any |= exchange(g, o, g.at(ni, j), g.vi[o]);
      const int nj = j + dj;
      if (nj >= 0 && nj < g.cols) any |= exchange(g, o, g.at(i, nj), g.vj[o]);
    }
  }
  return any;
}

namespace {
// Block of cells that can change in the next sub-step: cells holding loose soil or carrying a
// velocity, grown by kReach. Soil moves at most one cell per exchange and a cell takes part in
// two exchanges per colour, so within one sub-step (4 colours) nothing travels further than
// kReach cells; every owner outside the block would only run no-op exchanges (no loose soil
// on either side, velocity already zero). Skipping them changes no bit of the result.
constexpr int kReach = 9;
struct Block {
  int r0, r1, c0, c1;
};
Block liveBlock(const ErosionGrid& g, const Block& in) {
  int r0 = g.rows, r1 = -1, c0 = g.cols, c1 = -1;
  for (int i = in.r0; i < in.r1; ++i)
    for (int j = in.c0; j < in.c1; ++j) {
      const size_t k = g.at(i, j);
      if (g.L[k] > 0 || g.vi[k] != 0 || g.vj[k] != 0) {
        r0 = std::min(r0, i);
        r1 = std::max(r1, i);
        c0 = std::min(c0, j);
        c1 = std::max(c1, j);
      }
    }
  if (r1 < 0) return {0, 0, 0, 0};
  return {std::max(0, r0 - kReach), std::min(g.rows, r1 + kReach + 1), std::max(0, c0 - kReach),
          std::min(g.cols, c1 + kReach + 1)};
}
}  // namespace

void ErosionSolver::pass(ErosionGrid& g, int di, int dj, const Executor& ex) const {
  if (g.rows == 0 || g.cols == 0) return;
  g.vi.assign(g.H.size(), 0.0);
  g.vj.assign(g.H.size(), 0.0);
  static const int order[4][2] = {{0, 0}, {0, 1}, {1, 0}, {1, 1}};
  Block b{0, g.rows, 0, g.cols};
  for (int s = 0; s < cfg_.substeps; ++s) {
    b = liveBlock(g, b);
    const int rows = b.r1 - b.r0;
    if (rows <= 0) break;  // nothing loose and nothing moving: the pass is over
    // Below ~4k owners per colour a task costs more than it saves; the result is the same
    // either way (each cell has one writer per colour), so the split is free to vary.
    const long owners = static_cast<long>(rows) * (b.c1 - b.c0) / 4;
    const int chunks = (ex.threads() == 1 || owners < 4096) ? 1 : std::min(rows / 2, ex.threads() * 2);
    bool any = false;
    for (const auto& c : order) {
      if (chunks <= 1) {
        any |= colour(g, c[0], c[1], di, dj, b.r0, b.r1, b.c0, b.c1);
      } else {
        std::vector<char> moved(static_cast<size_t>(chunks), 0);
        ex.forEach(chunks, [&](int k) {
          const int rb = b.r0 + rows * k / chunks, re = b.r0 + rows * (k + 1) / chunks;
          moved[static_cast<size_t>(k)] = colour(g, c[0], c[1], di, dj, rb, re, b.c0, b.c1) ? 1 : 0;
        });
        for (char m : moved) any |= m != 0;
      }
    }
    // A sub-step in which nothing moved and every velocity is zero leaves the state exactly as
    // it found it, so every later sub-step would too.
    if (!any) break;
  }
}

void ErosionSolver::passSerial(ErosionGrid& g, int di, int dj) const {
  // Every owner, every sub-step, no live-block skipping: the plain reference.
  g.vi.assign(g.H.size(), 0.0);
  g.vj.assign(g.H.size(), 0.0);
  for (int s = 0; s < cfg_.substeps; ++s)
    for (int pr = 0; pr < 2; ++pr)
      for (int pc = 0; pc < 2; ++pc) colour(g, pr, pc, di, dj, 0, g.rows, 0, g.cols);
}

}  // namespace terramap::plugins
