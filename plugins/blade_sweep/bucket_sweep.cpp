// Blind mapping with an excavator's bucket: the swept volume of a closed tool mesh cuts the map
// and the soil is carried, then poured where the bucket empties, as a pile at its repose.
#include "blade_sweep.hpp"

#include <terramap/core/error.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

namespace terramap::plugins {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
double orZero(double v) { return std::isfinite(v) ? v : 0.0; }

/// Largest displacement of a mesh vertex between two poses.
double vertexTravel(const ToolMesh& tool, const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  double d = 0;
  for (const Triangle& t : tool.faces)
    for (const Eigen::Vector3d* v : {&t.a, &t.b, &t.c}) d = std::max(d, (b * *v - a * *v).norm());
  return d;
}

Eigen::Isometry3d interpolate(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b, double f) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::Quaterniond(a.linear()).slerp(f, Eigen::Quaterniond(b.linear())).toRotationMatrix();
  T.translation() = (1 - f) * a.translation() + f * b.translation();
  return T;
}

/// Loose soil slides to the pile's repose: Jacobi sweeps over the window (every flux from one
/// snapshot, a cell gives at most the loose soil it has; height and loose thickness move
/// together, so Σ[(H − L) + L/s] is kept), only between known cells, until no pair is steeper
/// than the repose by more than 0.1 mm or `max_sweeps` have run. Returns the sweeps run.
int settle(SweepSoil& soil, int R, int C, double res, double repose_rad, int max_sweeps) {
  std::vector<double>&H = soil.H, &L = soil.L;
  std::vector<std::uint8_t>& change = soil.change;
  const double max_step = res * std::tan(repose_rad);
  std::vector<double> fx(H.size()), fy(H.size()), scale(H.size());
  int it = 0;
  for (; it < max_sweeps; ++it) {
    bool moved = false;
    auto flux = [&](std::size_t a, std::size_t b) {
      if (!std::isfinite(H[a]) || !std::isfinite(H[b])) return 0.0;
      const double dh = H[a] - H[b], ex = std::abs(dh) - max_step;
      if (!(ex > 1e-4)) return 0.0;
      if (!((dh > 0 ? L[a] : L[b]) > 0)) return 0.0;
      return dh > 0 ? 0.25 * ex : -0.25 * ex;
    };
    for (int r = 0; r < R; ++r)
      for (int c = 0; c < C; ++c) {
        const std::size_t a = static_cast<std::size_t>(r) * C + c;
        fx[a] = c + 1 < C ? flux(a, a + 1) : 0.0;
        fy[a] = r + 1 < R ? flux(a, a + C) : 0.0;
        moved = moved || fx[a] != 0.0 || fy[a] != 0.0;
      }
    if (!moved) break;
    for (int r = 0; r < R; ++r)
      for (int c = 0; c < C; ++c) {
        const std::size_t a = static_cast<std::size_t>(r) * C + c;
        double o = std::max(0.0, fx[a]) + std::max(0.0, fy[a]);
        if (c > 0) o += std::max(0.0, -fx[a - 1]);
        if (r > 0) o += std::max(0.0, -fy[a - C]);
        const double l = orZero(L[a]);
        scale[a] = o > l && o > 0 ? l / o : 1.0;
      }
    auto move = [&](std::size_t from, std::size_t to, double q) {
      H[from] -= q;
      L[from] -= q;
      H[to] += q;
      L[to] = orZero(L[to]) + q;
      if (change[to] == kSweepUnchanged) change[to] = kSweepDeposit;
      if (change[from] == kSweepUnchanged) change[from] = kSweepDeposit;
    };
    for (int r = 0; r < R; ++r)
      for (int c = 0; c < C; ++c) {
        const std::size_t a = static_cast<std::size_t>(r) * C + c;
        if (fx[a] > 0) move(a, a + 1, fx[a] * scale[a]);
        else if (fx[a] < 0) move(a + 1, a, -fx[a] * scale[a + 1]);
        if (fy[a] > 0) move(a, a + C, fy[a] * scale[a]);
        else if (fy[a] < 0) move(a + C, a, -fy[a] * scale[a + C]);
      }
  }
  return it;
}

/// The window a pile at `at` may spread over, allocated; empty when off the map or over budget.
MapWindow pileWindow(LayeredMap& map, const SweepLayers& ids, const BucketConfig& bucket, const Eigen::Vector3d& at,
                     bool& dropped) {
  const double reach = bucket.pile_reach_m + 0.5 * bucket.width_m;
  const MapWindow win = MapWindow::covering(map, {at.head<2>() - Eigen::Vector2d(reach, reach),
                                                  at.head<2>() + Eigen::Vector2d(reach, reach)});
  dropped = !win.empty() && !ids.allocate(map, win);
  return dropped ? MapWindow() : win;
}

}  // namespace

ToolMesh ToolMesh::prism(const std::vector<Eigen::Vector2d>& profile_in, double width_m) {
  if (profile_in.size() < 3) throw ConfigError("a tool profile needs at least three vertices");
  if (!(width_m > 0)) throw ConfigError("a tool's width must be > 0");
  std::vector<Eigen::Vector2d> p = profile_in;
  double area = 0;
  for (std::size_t k = 0; k < p.size(); ++k) {
    const Eigen::Vector2d &a = p[k], &b = p[(k + 1) % p.size()];
    area += a.x() * b.y() - a.y() * b.x();
  }
  if (area < 0) std::reverse(p.begin(), p.end());
  ToolMesh m;
  m.width_m = width_m;
  m.volume_m3 = 0.5 * std::abs(area) * width_m;
  const double h = 0.5 * width_m;
  auto at = [&](std::size_t k, double y) { return Eigen::Vector3d(p[k].x(), y, p[k].y()); };
  // End caps as fans, the sides as two triangles per profile edge.
  for (std::size_t k = 1; k + 1 < p.size(); ++k) {
    m.faces.push_back({at(0, -h), at(k, -h), at(k + 1, -h)});
    m.faces.push_back({at(0, h), at(k + 1, h), at(k, h)});
  }
  for (std::size_t k = 0; k < p.size(); ++k) {
    const std::size_t n = (k + 1) % p.size();
    m.faces.push_back({at(k, -h), at(n, -h), at(n, h)});
    m.faces.push_back({at(k, -h), at(n, h), at(k, h)});
  }
  std::size_t lip = 0;
  for (std::size_t k = 1; k < p.size(); ++k)
    if (p[k].x() > p[lip].x()) lip = k;
  m.lip = at(lip, 0.0);
  return m;
}

ToolMesh BucketConfig::mesh() const {
  const double L = length_m, D = depth_m;
  return ToolMesh::prism({{0.0, 0.0}, {L, 0.0}, {0.62 * L, D}, {0.12 * L, 0.88 * D}}, width_m);
}

BucketResult runBucketSweep(LayeredMap& map, const SweepLayers& ids, const SweepConfig& cfg, const ToolMesh& tool,
                            const std::vector<Eigen::Isometry3d>& poses, double room_bank_m3, const Executor& ex) {
  BucketResult out;
  if (poses.size() < 2) return out;
  const Geometry& geo = map.geometry();
  const double res = geo.resolution(), cell = res * res;
  // Stations no mesh vertex of which moves more than half a cell from one to the next: their
  // union is the swept volume to within that half cell. They cut in order (the bucket fills as
  // it goes), each down to the mesh's bottom at that station.
  std::vector<Eigen::Isometry3d> stations{poses.front()};
  for (std::size_t k = 1; k < poses.size(); ++k) {
    const int n = std::max(1, static_cast<int>(std::ceil(vertexTravel(tool, poses[k - 1], poses[k]) / (0.5 * res))));
    for (int s = 1; s <= n; ++s) stations.push_back(s == n ? poses[k] : interpolate(poses[k - 1], poses[k], double(s) / n));
  }
  std::vector<std::vector<Triangle>> tris(stations.size());
  std::vector<CellRect> blocks(stations.size());
  CellRect block;
  for (std::size_t k = 0; k < stations.size(); ++k) {
    for (const Triangle& t : tool.faces) tris[k].push_back({stations[k] * t.a, stations[k] * t.b, stations[k] * t.c});
    blocks[k] = footprintBlock(tris[k], geo);
    block.add(blocks[k]);
  }
  if (block.empty()) return out;
  const MapWindow win(map, block.r0, block.c0, block.rows, block.cols);
  if (!ids.allocate(map, win)) {
    out.dropped = true;
    return out;
  }
  SweepSoil soil(map, ids, win);
  std::vector<double>&H = soil.H, &L = soil.L, &S = soil.S;
  std::vector<std::uint8_t> unknown(H.size(), 0);
  // Bank-equivalent volume of cutting dh from a cell with loose thickness L (loose soil first).
  auto bankOf = [&](double l, double dh) {
    const double dh_l = std::min(std::max(0.0, orZero(l)), dh);
    return ((dh - dh_l) + dh_l / cfg.swell) * cell;
  };
  const Executor serial(1);  // one station's mesh is a dozen triangles
  std::vector<double> zlow;
  for (std::size_t k = 0; k < stations.size() && out.cut_bank_m3 < room_bank_m3; ++k) {
    const CellRect& b = blocks[k];
    if (b.empty()) continue;
    lowestIntersection(tris[k], geo, b, zlow, serial);
    // This station's cuts, then scaled down together if they overfill the bucket.
    struct Cut { std::size_t w; double dh; };
    std::vector<Cut> cuts;
    double bank = 0;
    for (int r = 0; r < b.rows; ++r)
      for (int c = 0; c < b.cols; ++c) {
        const double zl = zlow[static_cast<std::size_t>(r) * b.cols + c];
        if (!std::isfinite(zl)) continue;
        const std::size_t w = static_cast<std::size_t>(win.local(b.r0 + r, b.c0 + c));
        if (!std::isfinite(H[w])) {
          unknown[w] = 1;
          continue;
        }
        const double dh = H[w] - zl;
        if (!(dh > cfg.min_cut_m)) continue;
        bank += bankOf(L[w], dh);
        cuts.push_back({w, dh});
      }
    const double f = bank > room_bank_m3 - out.cut_bank_m3 ? (room_bank_m3 - out.cut_bank_m3) / bank : 1.0;
    for (const Cut& ct : cuts) {
      const double dh = ct.dh * f;
      out.cut_volume_m3 += dh * cell;
      out.cut_bank_m3 += bankOf(L[ct.w], dh);
      H[ct.w] -= dh;
      L[ct.w] = std::max(std::max(0.0, orZero(L[ct.w])) - dh, 0.0);
      S[ct.w] = std::isfinite(S[ct.w]) ? std::max(S[ct.w], cfg.sigma_sv_m) : cfg.sigma_sv_m;
      if (soil.change[ct.w] != kSweepCut) ++out.cells_cut;
      soil.change[ct.w] = kSweepCut;
    }
  }
  for (std::uint8_t u : unknown) out.cells_unknown += u;
  soil.write(map, ids, win);
  return out;
}

BucketResult pourBucket(LayeredMap& map, const SweepLayers& ids, const SweepConfig& cfg, const BucketConfig& bucket,
                        const Eigen::Vector3d& at, double bank_m3, int max_sweeps) {
  BucketResult out;
  if (!(bank_m3 > 0)) return out;
  const Geometry& geo = map.geometry();
  const double res = geo.resolution(), cell = res * res;
  const MapWindow win = pileWindow(map, ids, bucket, at, out.dropped);
  if (out.dropped) return out;
  if (win.empty()) {
    out.lost_bank_m3 = bank_m3;
    return out;
  }
  SweepSoil soil(map, ids, win);
  std::vector<double>&H = soil.H, &L = soil.L, &S = soil.S;
  std::vector<std::uint8_t>& change = soil.change;
  // The disc under the lip (its own cell at least).
  std::vector<std::size_t> disc;
  const double r2 = 0.25 * bucket.width_m * bucket.width_m;
  for (int r = 0; r < win.rows(); ++r)
    for (int c = 0; c < win.cols(); ++c) {
      const Eigen::Vector2d p = geo.positionOf(Index(win.i0() + r, win.j0() + c));
      if ((p - at.head<2>()).squaredNorm() <= r2) disc.push_back(static_cast<std::size_t>(r) * win.cols() + c);
    }
  if (disc.empty()) {
    const auto idx = geo.indexAt(at.head<2>());
    if (!idx || !win.contains(idx->x(), idx->y())) {
      out.lost_bank_m3 = bank_m3;
      return out;
    }
    disc.push_back(static_cast<std::size_t>(win.local(idx->x(), idx->y())));
  }
  const double dep = bank_m3 * cfg.swell / (cell * static_cast<double>(disc.size()));
  for (std::size_t w : disc) {
    L[w] = orZero(L[w]) + dep;
    if (!std::isfinite(H[w])) {
      // Unknown ground: kept as loose thickness of known amount (elevation stays unknown).
      change[w] = kSweepDepositUnknown;
      out.unknown_bank_m3 += dep / cfg.swell * cell;
      continue;
    }
    H[w] += dep;
    S[w] = std::sqrt(orZero(S[w]) * orZero(S[w]) + 0.25 * dep * dep);
    change[w] = kSweepDeposit;
    out.deposit_bank_m3 += dep / cfg.swell * cell;
    ++out.cells_deposit;
  }
  settle(soil, win.rows(), win.cols(), res, bucket.pile_repose_rad, max_sweeps);
  soil.write(map, ids, win);
  return out;
}

int settlePile(LayeredMap& map, const SweepLayers& ids, const BucketConfig& bucket, const Eigen::Vector3d& at,
               int max_sweeps) {
  bool dropped = false;
  const MapWindow win = pileWindow(map, ids, bucket, at, dropped);
  if (win.empty()) return 0;
  SweepSoil soil(map, ids, win);
  const int n = settle(soil, win.rows(), win.cols(), map.geometry().resolution(), bucket.pile_repose_rad, max_sweeps);
  soil.write(map, ids, win);
  return n;
}

}  // namespace terramap::plugins
