// One swept-volume update: intersection, FEE extraction, cut and deposit, per-step values.
#include "blade_sweep.hpp"

#include <terramap/core/grid_line.hpp>
#include <terramap/core/map_window.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

namespace terramap::plugins {

namespace {
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

double orZero(double v) { return std::isfinite(v) ? v : 0.0; }

Eigen::Vector2d horizontal(const Eigen::Vector3d& v) { return Eigen::Vector2d(v.x(), v.y()); }

// Surface samples for a slice are read by bilinear interpolation between cell centres, which
// is exact on planar terrain whatever the direction t̂ (a nearest-cell DDA is off by up to half
// a cell across the line, which biases the fit on cross slopes).
struct SurfaceSampler {
  const MapWindow& win;
  const std::vector<double>& surf;  // elevation - loose, NaN unknown
  double xmax, ymax, inv_res;
  // NaN if a cell with non-zero weight is unknown or outside the window.
  double operator()(const Eigen::Vector2d& q) const {
    const double u = (xmax - q.x()) * inv_res - 0.5, v = (ymax - q.y()) * inv_res - 0.5;
    const double fu0 = std::floor(u), fv0 = std::floor(v);
    const int i = static_cast<int>(fu0), j = static_cast<int>(fv0);
    const double fu = u - fu0, fv = v - fv0;
    double acc = 0.0;
    const double w[4] = {(1 - fu) * (1 - fv), (1 - fu) * fv, fu * (1 - fv), fu * fv};
    const int di[4] = {0, 0, 1, 1}, dj[4] = {0, 1, 0, 1};
    for (int k = 0; k < 4; ++k) {
      if (w[k] == 0.0) continue;
      const int ci = i + di[k], cj = j + dj[k];
      if (!win.contains(ci, cj)) return kNaN;
      const double s = surf[static_cast<size_t>(win.local(ci, cj))];
      if (!std::isfinite(s)) return kNaN;
      acc += w[k] * s;
    }
    return acc;
  }
};

// Fitted surface line z = z0 + b x (x along t̂ from the slice cell), with its covariance.
struct LineFit {
  bool ok = false;
  double z0 = kNaN, b = kNaN, var_z0 = kNaN, var_b = kNaN, cov = kNaN, residual = kNaN;
  int n = 0;
};

LineFit fitLine(const std::vector<double>& x, const std::vector<double>& z, double cx) {
  LineFit f;
  double sw = 0, swx = 0, swxx = 0, swz = 0, swxz = 0;
  const size_t n = x.size();
  for (size_t k = 0; k < n; ++k) {
    const double w = std::exp(-cx * x[k]);
    sw += w;
    swx += w * x[k];
    swxx += w * x[k] * x[k];
    swz += w * z[k];
    swxz += w * x[k] * z[k];
  }
  f.n = static_cast<int>(n);
  const double det = sw * swxx - swx * swx;
  if (n < 3 || !(det > 1e-300)) return f;
  f.b = (sw * swxz - swx * swz) / det;
  f.z0 = (swz - f.b * swx) / sw;
  double ssr = 0;
  for (size_t k = 0; k < n; ++k) {
    const double r = z[k] - f.z0 - f.b * x[k];
    ssr += std::exp(-cx * x[k]) * r * r;
  }
  // Weights are relative (not inverse variances): scale them to sum to n, estimate the noise
  // variance from the residuals with n - 2 degrees of freedom, covariance s^2 (X'W'X)^-1.
  const double s2 = (ssr * static_cast<double>(n) / sw) / static_cast<double>(n - 2);
  const double scale = s2 * sw / static_cast<double>(n) / det;
  f.var_b = scale * sw;
  f.var_z0 = scale * swxx;
  f.cov = -scale * swx;
  f.residual = std::sqrt(ssr / sw);
  f.ok = std::isfinite(f.z0) && std::isfinite(f.b);
  return f;
}

// Loose volume in the parallelogram ahead of the blade edge at T: edge + s t̂, s in [0, L].
// Returns {volume, variance}; cells within half a cell of the region's boundary are a coin
// flip (in or out), variance (L res^2)^2 / 4 each.
std::pair<double, double> surchargeVolume(const Eigen::Isometry3d& T, const BladeGeometry& g,
                                          const Eigen::Vector2d& t_hat, double length, const Geometry& geo,
                                          const MapWindow& win, const std::vector<double>& loose) {
  const auto c = bladeCorners(T, g);
  const Eigen::Vector2d er = horizontal(c[0]), e = horizontal(c[1]) - er;
  const double det = e.x() * t_hat.y() - e.y() * t_hat.x();
  const double elen = e.norm();
  if (std::abs(det) < 1e-9 * std::max(elen, 1e-9) || elen < 1e-9) return {0.0, 0.0};
  const double sinang = std::abs(det) / elen;
  const double res = geo.resolution(), cell = res * res;
  double vol = 0, var = 0;
  for (int r = 0; r < win.rows(); ++r)
    for (int cc = 0; cc < win.cols(); ++cc) {
      const double l = loose[static_cast<size_t>(r) * win.cols() + cc];
      if (!(l > 0)) continue;
      const Eigen::Vector2d p = geo.positionOf(Index(win.i0() + r, win.j0() + cc)) - er;
      // p = u e + s t̂
      const double u = (p.x() * t_hat.y() - p.y() * t_hat.x()) / det;
      const double s = (e.x() * p.y() - e.y() * p.x()) / det;
      if (u < 0 || u > 1 || s < 0 || s > length) continue;
      vol += l * cell;
      const double dist = std::min({s * sinang, (length - s) * sinang, u * elen * sinang, (1 - u) * elen * sinang});
      if (dist < 0.5 * res) var += 0.25 * (l * cell) * (l * cell);
    }
  return {vol, var};
}

// Travel, blade-normal and deposit directions of a sweep (horizontal unit vectors), the edge's
// start point and the blade angle halfway.
struct SweepDirections {
  Eigen::Vector2d e0, t_hat, n_hat, m_hat;
  double theta_mid = kNaN;
};

// Cells of the footprint under the swept volume where the surface is above its bottom.
struct CutCell {
  int i, j;
  long w;      // window index
  double dh, zl, ze;  // cut, SV bottom, cutting-edge path height (NaN: not under the edge path)
};

// Lowest swept-volume (zlow) and edge-path (zedge) heights per footprint cell, NaN off it.
struct SweptCells {
  CellRect fp;
  std::vector<double> zlow, zedge;
};

// The record's header: time span, poses, geometry and the configuration it was made with.
std::shared_ptr<SweepRecord> newRecord(const std::vector<BladePose>& history, const SweepConfig& cfg, double res) {
  auto rec = std::make_shared<SweepRecord>();
  rec->machine_id = history.front().machine_id;
  rec->t0 = history.front().stamp;
  rec->t1 = history.back().stamp;
  rec->T_map_blade0 = history.front().T_map_blade;
  rec->T_map_blade1 = history.back().T_map_blade;
  rec->geometry = history.front().geometry;
  rec->resolution_m = res;
  rec->swell = cfg.swell;
  rec->sigma_sv_m = cfg.sigma_sv_m;
  rec->fit_length_m = cfg.fit_length_m;
  rec->slice_step_m = res;
  rec->loose_unit_weight_n_m3 = cfg.unit_weight_n_m3 / cfg.swell;
  return rec;
}

SweepDirections sweepDirections(const std::vector<BladePose>& history, const SweepConfig& cfg, SweepRecord& rec) {
  const Eigen::Isometry3d& T0 = history.front().T_map_blade;
  const Eigen::Isometry3d& T1 = history.back().T_map_blade;
  const Eigen::Vector2d e0 = horizontal(T0.translation()), e1 = horizontal(T1.translation());
  Eigen::Vector2d n_hat = horizontal(T0.linear().col(0));
  Eigen::Vector2d t_hat = e1 - e0;
  if (n_hat.norm() < 1e-9) n_hat = t_hat.norm() > 1e-9 ? t_hat : Eigen::Vector2d::UnitX();
  n_hat.normalize();
  if (t_hat.norm() < 1e-9) t_hat = n_hat;  // rotation or lift in place: push along the normal
  t_hat.normalize();
  Eigen::Vector2d m = cfg.deposit_normal_weight * n_hat + (1.0 - cfg.deposit_normal_weight) * t_hat;
  if (m.norm() < 1e-6) m = t_hat;  // blade dragged backwards with λ = 0.5: normal and travel cancel
  m.normalize();
  rec.t_hat = t_hat;
  rec.t_perp = Eigen::Vector2d(-t_hat.y(), t_hat.x());
  rec.n_hat = n_hat;
  rec.m_hat = m;
  for (size_t k = 1; k < history.size(); ++k)
    rec.travel_m += (history[k].T_map_blade.translation() - history[k - 1].T_map_blade.translation()).norm();
  const Eigen::Quaterniond q0(T0.linear()), q1(T1.linear());
  rec.rotation_rad = q0.angularDistance(q1);
  Eigen::Isometry3d Tmid = Eigen::Isometry3d::Identity();
  Tmid.linear() = q0.slerp(0.5, q1).toRotationMatrix();
  Tmid.translation() = 0.5 * (T0.translation() + T1.translation());
  const double theta_mid = bladeAngle(Tmid, t_hat);
  rec.blade_angle_rad = theta_mid;
  return {e0, t_hat, n_hat, m, theta_mid};
}

// Swept volume and its intersection with the cells (Alg. 1 l. 8-9).
SweptCells sweptCells(const std::vector<BladePose>& history, const SweepConfig& cfg, const Geometry& geo,
                      const Executor& ex) {
  const BladeGeometry& bg = history.front().geometry;
  std::vector<Eigen::Isometry3d> poses;
  poses.reserve(history.size());
  for (const auto& p : history) poses.push_back(p.T_map_blade);
  const auto stations = meshStations(poses, cfg.max_stations, cfg.max_station_rotation_rad);
  const auto tris = sweptVolumeMesh(stations, bg);
  SweptCells sc;
  sc.fp = footprintBlock(tris, geo);
  lowestIntersection(tris, geo, sc.fp, sc.zlow, ex);
  lowestIntersection(edgeSweepMesh(stations, bg), geo, sc.fp, sc.zedge, ex);
  return sc;
}

// Window: footprint + the fit length ahead along t̂ + 2 cells (deposit cells sit at most one
// cell outside the footprint; bilinear samples need one more).
MapWindow sweepWindow(const LayeredMap& map, const CellRect& fp, const SweepConfig& cfg,
                      const Eigen::Vector2d& t_hat, double res) {
  const int reach_i = static_cast<int>(std::ceil(cfg.fit_length_m * std::abs(t_hat.x()) / res));
  const int reach_j = static_cast<int>(std::ceil(cfg.fit_length_m * std::abs(t_hat.y()) / res));
  const int ai = t_hat.x() > 0 ? reach_i : 0, bi = t_hat.x() > 0 ? 0 : reach_i;  // +x is -i
  const int aj = t_hat.y() > 0 ? reach_j : 0, bj = t_hat.y() > 0 ? 0 : reach_j;
  return MapWindow(map, fp.r0 - ai - 2, fp.c0 - aj - 2, fp.rows + ai + bi + 4, fp.cols + aj + bj + 4);
}

// The swept mask of the record and the cells to cut, in footprint order.
std::vector<CutCell> cutCells(const SweptCells& sc, const MapWindow& win, const std::vector<double>& H0,
                              const Geometry& geo, const SweepConfig& cfg, SweepRecord& rec) {
  const CellRect& fp = sc.fp;
  std::vector<CutCell> cuts;
  rec.mask.reserve(static_cast<size_t>(fp.rows) * static_cast<size_t>(std::max(0, fp.cols)) / 2);
  for (int r = 0; r < fp.rows; ++r)
    for (int c = 0; c < fp.cols; ++c) {
      const double zl = sc.zlow[static_cast<size_t>(r) * fp.cols + c];
      if (!std::isfinite(zl)) continue;
      const int i = fp.r0 + r, j = fp.c0 + c;
      const long w = win.local(i, j);
      const double h = H0[static_cast<size_t>(w)];
      SweepMaskCell mc;
      mc.position = geo.positionOf(Index(i, j));
      mc.sv_bottom_m = static_cast<float>(zl);
      ++rec.cells_under_sv;
      if (!std::isfinite(h)) {
        ++rec.cells_unknown_under_sv;
      } else if (h - zl > cfg.min_cut_m) {
        mc.cut = true;
        cuts.push_back({i, j, w, h - zl, zl, sc.zedge[static_cast<size_t>(r) * fp.cols + c]});
      }
      rec.mask.push_back(mc);
    }
  rec.cells_cut = static_cast<long>(cuts.size());
  return cuts;
}

// FEE extraction (Alg. 2) on the surface before the cut: one fitted slice per cut cell under
// the edge's path, in cut order.
void extractSlices(const std::vector<CutCell>& cuts, const MapWindow& win, const std::vector<double>& H0,
                   const std::vector<double>& L0, const std::vector<double>& K0, const Geometry& geo,
                   const SweepConfig& cfg, const SweepDirections& dir, const Executor& ex, SweepRecord& rec) {
  const double res = geo.resolution();
  const Eigen::Vector2d& t_hat = dir.t_hat;
  std::vector<double> surf(H0.size());
  for (size_t k = 0; k < H0.size(); ++k) surf[k] = H0[k] - orZero(L0[k]);
  // The bank height the map knew before the pile came, where it has one; the surface is never
  // taken above the elevation (a cell the sensors see lower lost soil the bank did not record).
  if (!K0.empty())
    for (size_t k = 0; k < H0.size(); ++k)
      if (std::isfinite(K0[k]) && std::isfinite(H0[k])) surf[k] = std::min(K0[k], H0[k]);
  const SurfaceSampler sampler{win, surf, geo.center().x() + 0.5 * geo.length().x(),
                               geo.center().y() + 0.5 * geo.length().y(), 1.0 / res};
  const int nsamples = static_cast<int>(std::floor(cfg.fit_length_m / res + 1e-9)) + 1;
  rec.slices.resize(cuts.size());
  std::vector<LineFit> fits(cuts.size());
  const int nc = static_cast<int>(cuts.size());
  const int chunks = std::min(nc, std::max(1, ex.threads() * 4));
  ex.forEach(chunks, [&](int ch) {
    std::vector<double> xs, zs;
    for (int k = nc * ch / chunks; k < nc * (ch + 1) / chunks; ++k) {
      const CutCell& a = cuts[static_cast<size_t>(k)];
      SweepSlice& sl = rec.slices[static_cast<size_t>(k)];
      sl.position = geo.positionOf(Index(a.i, a.j));
      sl.cut_m = a.dh;
      sl.cut_bottom_m = a.ze;
      sl.lateral_m = (sl.position - dir.e0).dot(rec.t_perp);
      if (!std::isfinite(a.ze)) continue;  // only under the face, not the edge's path: no slice
      xs.clear();
      zs.clear();
      for (int s = 0; s < nsamples; ++s) {
        const double x = s * res;
        const double z = sampler(sl.position + x * t_hat);
        if (!std::isfinite(z)) continue;
        xs.push_back(x);
        zs.push_back(z);
      }
      const LineFit f = fitLine(xs, zs, cfg.fit_distance_weight);
      fits[static_cast<size_t>(k)] = f;
      sl.samples = f.n;
      if (!f.ok) continue;
      const double alpha = std::atan(f.b);
      const double ca = std::cos(alpha), sa = std::sin(alpha);
      const double dv = f.z0 - a.ze;  // vertical depth of the edge path under the surface line
      const double dalpha_db = 1.0 / (1.0 + f.b * f.b);
      sl.alpha_rad = alpha;
      sl.rho_rad = alpha + dir.theta_mid;
      sl.surface_z_m = f.z0;
      sl.d_m = std::max(0.0, dv * ca);
      sl.var_alpha = f.var_b * dalpha_db * dalpha_db;
      // d = (z0 - z_cut) cos(atan b): gradient w.r.t. (z0, b), plus the SV height's own 1σ.
      const double gz = ca, gb = -dv * sa * dalpha_db;
      sl.var_d = gz * gz * f.var_z0 + gb * gb * f.var_b + 2 * gz * gb * f.cov +
                 ca * ca * cfg.sigma_sv_m * cfg.sigma_sv_m;
      sl.residual_m = f.residual;
      sl.weight = std::exp(cfg.depth_weight * sl.d_m);
      sl.valid = std::isfinite(sl.alpha_rad) && std::isfinite(sl.d_m) && std::isfinite(sl.var_d);
      if (!sl.valid) sl.weight = 0;
    }
  });
}

// The sweep's FEE values: weighted averages (exp(C_d d)) over the valid slices, in slice order
// (deterministic).
void averageSlices(bool any_cut, double res, SweepRecord& rec) {
  const double cell = res * res;
  double sw = 0, sa = 0, sr = 0, sd = 0, sres = 0;
  double lat_min = std::numeric_limits<double>::infinity(), lat_max = -lat_min;
  for (const auto& sl : rec.slices) {
    lat_min = std::min(lat_min, sl.lateral_m);
    lat_max = std::max(lat_max, sl.lateral_m);
    if (!sl.valid) {
      ++rec.slices_invalid;
      continue;
    }
    ++rec.slices_valid;
    sw += sl.weight;
    sa += sl.weight * sl.alpha_rad;
    sr += sl.weight * sl.rho_rad;
    sd += sl.weight * sl.d_m;
    sres += sl.weight * sl.residual_m;
  }
  if (any_cut) {
    rec.w_m = lat_max - lat_min + res;
    rec.var_w = cell / 12.0;
  }
  if (sw > 0) {
    rec.alpha_rad = sa / sw;
    rec.rho_rad = sr / sw;
    rec.d_m = sd / sw;
    rec.fit_residual_m = sres / sw;
    double va = 0, vr = 0, vd = 0;
    for (const auto& sl : rec.slices) {
      if (!sl.valid) continue;
      va += sl.weight * (sl.var_alpha + (sl.alpha_rad - rec.alpha_rad) * (sl.alpha_rad - rec.alpha_rad));
      vr += sl.weight * (sl.var_alpha + (sl.rho_rad - rec.rho_rad) * (sl.rho_rad - rec.rho_rad));
      vd += sl.weight * (sl.var_d + (sl.d_m - rec.d_m) * (sl.d_m - rec.d_m));
    }
    rec.var_alpha = va / sw;
    rec.var_rho = vr / sw;
    rec.var_d = vd / sw;
    rec.fee_valid = rec.d_m > 0 && std::isfinite(rec.rho_rad);
  }
}

// What cutAndDeposit did to a window cell (cut and deposit cells are disjoint: deposits land
// off the footprint).

// Cut and deposit (Alg. 3, mass-conserving) on the window's copies H, L, S: each cut cell's soil
// goes, swollen, to the first cell off the footprint along m̂.
void cutAndDeposit(const std::vector<CutCell>& cuts, const SweptCells& sc, const MapWindow& win,
                   const Geometry& geo, const SweepConfig& cfg, const Eigen::Vector2d& m, std::vector<double>& H,
                   std::vector<double>& L, std::vector<double>& S, std::vector<std::uint8_t>& change,
                   SweepRecord& rec) {
  const CellRect& fp = sc.fp;
  const double res = geo.resolution(), cell = res * res;
  const double du = -m.x(), dv = -m.y();  // m̂ in grid coordinates (u = -x, v = -y)
  const double s = cfg.swell, ssv = cfg.sigma_sv_m;
  std::vector<char> deposited(H.size(), 0);
  auto inFootprint = [&](int i, int j) {
    return fp.contains(i, j) && std::isfinite(sc.zlow[static_cast<size_t>(fp.local(i, j))]);
  };
  const int max_steps = 2 * (fp.rows + fp.cols) + 8;
  for (const CutCell& a : cuts) {
    const size_t wa = static_cast<size_t>(a.w);
    const double la = std::max(0.0, orZero(L[wa]));
    const double sig_a = orZero(S[wa]);
    const double dh = a.dh;
    const double dh_l = std::min(la, dh);
    const double dep = dh_l + s * (dh - dh_l);
    rec.cut_volume_m3 += dh * cell;
    rec.cut_bank_volume_m3 += (dh - dh_l) * cell;
    H[wa] = a.zl;
    L[wa] = std::max(la - dh, 0.0);
    S[wa] = std::isfinite(S[wa]) ? std::max(S[wa], ssv) : ssv;
    change[wa] = kSweepCut;

    // Walk from the centre of a along m̂ to the first cell off the footprint.
    GridLine walk = GridLine::fromCellCentre(Index(a.i, a.j), du, dv);
    bool found = false;
    for (int step = 0; step < max_steps; ++step) {
      walk.step();
      if (!inFootprint(walk.row(), walk.col())) {
        found = true;
        break;
      }
    }
    TERRAMAP_CHECK(found, "deposit DDA did not leave the swept footprint");
    const int ci = walk.row(), cj = walk.col();
    if (!geo.contains(Index(ci, cj))) {
      rec.lost_volume_m3 += dep * cell;
      ++rec.cells_lost;
      continue;
    }
    TERRAMAP_CHECK(win.contains(ci, cj), "deposit cell outside the sweep window");
    const size_t wb = static_cast<size_t>(win.local(ci, cj));
    if (!std::isfinite(H[wb])) {
      // Unknown ground: keep the soil as loose thickness of known amount on it (its elevation
      // stays unknown until a sensor sees it), so no volume disappears.
      L[wb] = orZero(L[wb]) + dep;
      change[wb] = kSweepDepositUnknown;
      rec.deposit_unknown_volume_m3 += dep * cell;
      ++rec.cells_deposit_unknown;
      continue;
    }
    // 1σ worst case of the deposit given the uncertain surface (σ[a]) and blade (σ_SV).
    const double hi = dh + sig_a + ssv, lo = std::max(0.0, dh - sig_a - ssv);
    auto depositOf = [&](double x) {
      const double xl = std::min(la, x);
      return xl + s * (x - xl);
    };
    const double dh_max = depositOf(hi) - depositOf(lo);
    H[wb] += dep;
    L[wb] = orZero(L[wb]) + dep;
    const double sb = orZero(S[wb]);
    S[wb] = std::sqrt(sb * sb + 0.25 * dh_max * dh_max);
    change[wb] = kSweepDeposit;
    rec.deposit_volume_m3 += dep * cell;
    if (!deposited[wb]) {
      deposited[wb] = 1;
      ++rec.cells_deposit;
    }
  }
}

// The height contract (docs/height_contract.md) on the layers lidar_fusion owns, where they
// exist. A cut sets the height to the blade's bottom: the old surface and what the LiDAR knew
// of it are gone, so the variance is replaced by the blade's own sigma^2, and the cell is a fresh
// estimate (is_valid = 1; rays that had penetrated the old, higher surface agreed with the cut).
// A deposit adds soil to a surface that is still there: the variance grows by the deposit's
// share of sigma^2 (S^2 - S0^2) and is_valid is kept (rays that penetrated the old surface speak
// even more against the higher one). Where the height is known, upper_bound follows it (the
// valid-cell convention); a deposit on unknown ground contradicts a ray bound taken over the old
// surface, so the bound is cleared, not raised by the map's deposit: the real spoil need not
// be where the map put it, and a bound must never be below the surface.
void updateFusionLayers(LayeredMap& map, const SweepLayers& ids, const MapWindow& win,
                        const std::vector<std::uint8_t>& change, const std::vector<double>& H,
                        const std::vector<double>& S0, const std::vector<double>& S) {
  const bool var = ids.variance >= 0, valid = ids.is_valid >= 0, ub = ids.upper_bound >= 0 && ids.is_upper_bound >= 0;
  if (!var && !valid && !ub) return;
  std::vector<double> V0, VAL0, UB0, ISUB0;
  if (var) win.gather(map, ids.variance, V0);
  if (valid) win.gather(map, ids.is_valid, VAL0);
  if (ub) {
    win.gather(map, ids.upper_bound, UB0);
    win.gather(map, ids.is_upper_bound, ISUB0);
  }
  std::vector<double> V = V0, VAL = VAL0, UB = UB0, ISUB = ISUB0;
  for (size_t k = 0; k < change.size(); ++k) {
    const std::uint8_t c = change[k];
    if (c == kSweepUnchanged) continue;
    if (c == kSweepDepositUnknown) {
      if (ub) {
        UB[k] = kNaN;
        ISUB[k] = 0.0;
      }
      continue;
    }
    if (var) {
      if (c == kSweepCut) {
        V[k] = S[k] * S[k];
      } else {
        // A known height the LiDAR never measured (no variance) inherits the blind sigma so far.
        const double s0 = orZero(S0[k]);
        const double base = std::isfinite(V0[k]) ? V0[k] : s0 * s0;
        V[k] = base + (S[k] * S[k] - s0 * s0);
      }
    }
    if (valid && c == kSweepCut) VAL[k] = 1.0;
    if (ub) {
      UB[k] = H[k];
      ISUB[k] = 0.0;
    }
  }
  if (var) win.scatterChanged(map, ids.variance, V0, V);
  if (valid) win.scatterChanged(map, ids.is_valid, VAL0, VAL);
  if (ub) {
    win.scatterChanged(map, ids.upper_bound, UB0, UB);
    win.scatterChanged(map, ids.is_upper_bound, ISUB0, ISUB);
  }
}

// The cut's cross-section at one pose (SweepStep::area_m2, depth2_m3): the slices' depths dk at
// that pose binned one cell wide across the edge by their lateral position (a bin's depth the
// mean of its cells'), bins between two cut ones that no slice fell in interpolated linearly.
void crossSection(const std::vector<SweepSlice>& slices, const std::vector<double>& dk, double res, SweepStep& st) {
  double lat_min = std::numeric_limits<double>::infinity();
  for (std::size_t a = 0; a < slices.size(); ++a)
    if (std::isfinite(dk[a])) lat_min = std::min(lat_min, slices[a].lateral_m);
  if (!std::isfinite(lat_min)) return;
  std::vector<double> sum, count;
  for (std::size_t a = 0; a < slices.size(); ++a) {
    if (!std::isfinite(dk[a])) continue;
    const auto b = static_cast<std::size_t>(std::lround((slices[a].lateral_m - lat_min) / res));
    if (b >= sum.size()) {
      sum.resize(b + 1, 0.0);
      count.resize(b + 1, 0.0);
    }
    sum[b] += dk[a];
    count[b] += 1.0;
  }
  double area = 0.0, depth2 = 0.0;
  std::size_t last = 0;  // the previous filled bin
  for (std::size_t b = 0; b < sum.size(); ++b) {
    if (count[b] == 0.0) continue;
    const double d = sum[b] / count[b];
    const double d_last = sum[last] / count[last];
    for (std::size_t g = last + 1; g < b; ++g) {  // a gap between filled bins
      const double u = static_cast<double>(g - last) / static_cast<double>(b - last);
      const double dg = (1.0 - u) * d_last + u * d;
      area += dg * res;
      depth2 += dg * dg * res;
    }
    area += d * res;
    depth2 += d * d * res;
    last = b;
  }
  st.area_m2 = area;
  st.depth2_m3 = depth2;
}

// One step of the pose history (Alg. 1 l. 12): depth and width under the edge at that pose from
// the sweep's slices; surcharge interpolated between the two ends.
SweepStep stepValues(const std::vector<BladePose>& history, size_t k, const SweepDirections& dir, double res,
                     const SweepRecord& rec) {
  const double cell = res * res;
  const double gamma_l = rec.loose_unit_weight_n_m3;
  const double span = rec.t1 - rec.t0;
  const Eigen::Vector2d& t_hat = dir.t_hat;
  SweepStep st;
  st.stamp = history[k].stamp;
  st.tau = span > 0 ? std::clamp((st.stamp - rec.t0) / span, 0.0, 1.0) : (k + 1 == history.size() ? 1.0 : 0.0);
  st.T_map_blade = history[k].T_map_blade;
  const auto c = bladeCorners(st.T_map_blade, rec.geometry);
  const double lat_r = (horizontal(c[0]) - dir.e0).dot(rec.t_perp);
  const double lat_l = (horizontal(c[1]) - dir.e0).dot(rec.t_perp);
  double wsum = 0, dsum = 0, cmin = std::numeric_limits<double>::infinity(), cmax = -cmin;
  std::vector<double> dk(rec.slices.size(), kNaN);
  if (std::abs(lat_l - lat_r) > 1e-9) {
    const double tol = 0.5 * res / std::abs(lat_l - lat_r);
    for (size_t a = 0; a < rec.slices.size(); ++a) {
      const SweepSlice& sl = rec.slices[a];
      if (!sl.valid) continue;
      const double f = (sl.lateral_m - lat_r) / (lat_l - lat_r);  // where along the edge
      if (f < -tol || f > 1 + tol) continue;
      const double fc = std::clamp(f, 0.0, 1.0);
      const Eigen::Vector3d pe = c[0] + fc * (c[1] - c[0]);
      const double xe = (horizontal(pe) - sl.position).dot(t_hat);
      const double zs = sl.surface_z_m + std::tan(sl.alpha_rad) * xe;
      const double d = std::max(0.0, (zs - pe.z()) * std::cos(sl.alpha_rad));
      dk[a] = d;
      wsum += sl.weight;
      dsum += sl.weight * d;
      if (d > 0) {
        cmin = std::min(cmin, sl.lateral_m);
        cmax = std::max(cmax, sl.lateral_m);
      }
    }
  }
  st.alpha_rad = rec.alpha_rad;
  st.var_alpha = rec.var_alpha;
  st.rho_rad = rec.alpha_rad + bladeAngle(st.T_map_blade, t_hat);
  st.var_rho = rec.var_alpha;
  if (wsum > 0) {
    st.d_m = dsum / wsum;
    double v = 0;
    for (size_t a = 0; a < rec.slices.size(); ++a)
      if (std::isfinite(dk[a])) {
        const auto& sl = rec.slices[a];
        v += sl.weight * (sl.var_d + (dk[a] - st.d_m) * (dk[a] - st.d_m));
      }
    st.var_d = v / wsum;
    st.w_m = cmax >= cmin ? cmax - cmin + res : 0.0;
    st.var_w = cell / 12.0;
    crossSection(rec.slices, dk, res, st);
  }
  st.vq_m3 = (1 - st.tau) * rec.vq0_m3 + st.tau * rec.vq1_m3;
  // Linear interpolation between two measured ends: 1σ error taken as τ(1-τ)|ΔV| on top of
  // the ends' own boundary variance.
  const double interp = st.tau * (1 - st.tau) * (rec.vq1_m3 - rec.vq0_m3);
  st.var_vq = rec.var_vq + interp * interp;
  st.q_n = gamma_l * st.vq_m3;
  st.var_q = gamma_l * gamma_l * st.var_vq;
  return st;
}

}  // namespace

namespace {

// The carried pile's V_Q before and after this sweep (CarriedPile; runSweep's contract).
void carriedSurcharge(const SweepConfig& cfg, const BladeGeometry& bg, const SweepDirections& dir, CarriedPile& pile,
                      SweepRecord& rec) {
  const double before = pile.bank_m3;
  const bool pushing = dir.t_hat.dot(dir.n_hat) > 0.0;
  const double cap_loose = bg.width_m * bg.height_m * bg.height_m / (2.0 * std::tan(cfg.carried_repose_rad));
  const double share = cfg.carried_overflow_share;
  if (!pushing || !(rec.cut_volume_m3 > 0.0)) {
    pile.bank_m3 = 0.0;
  } else {
    pile.bank_m3 = before + rec.cut_bank_volume_m3;
    if (!(share > 0.0)) pile.bank_m3 = std::min(pile.bank_m3, cap_loose / cfg.swell);
  }
  // Beyond the capacity the pile lies between the capacity (all of the excess spilled) and all
  // of it (none did): `share` of the way, with the uniform's variance over that interval.
  const auto carried = [&](double bank_m3) {
    const double loose = bank_m3 * cfg.swell;
    return share > 0.0 && loose > cap_loose ? cap_loose + share * (loose - cap_loose) : loose;
  };
  const double v0 = carried(before), v1 = carried(pile.bank_m3);
  const double excess = share > 0.0 ? std::max(0.0, std::max(before, pile.bank_m3) * cfg.swell - cap_loose) : 0.0;
  const double var_over = excess * excess / 12.0;
  const double d0 = 0.5 * (v0 - rec.vq0_m3), d1 = 0.5 * (v1 - rec.vq1_m3);
  rec.var_vq += std::max(d0 * d0, d1 * d1) + var_over;
  rec.vq0_m3 = v0;
  rec.vq1_m3 = v1;
}

}  // namespace

bool SweepLayers::allocate(LayeredMap& map, const MapWindow& win) const {
  return win.tryAllocate(map, {elevation, loose, sigma, variance, is_valid, upper_bound, is_upper_bound, base, bank});
}

SweepSoil::SweepSoil(const LayeredMap& map, const SweepLayers& ids, const MapWindow& win) {
  win.gather(map, ids.elevation, H0);
  win.gather(map, ids.loose, Lg);
  win.gather(map, ids.sigma, S0);
  L0 = Lg;
  if (ids.base >= 0) {
    win.gather(map, ids.base, B0);
    // Only the blade and erosion move loose soil, and both keep elevation - loose fixed where
    // they do not cut; lidar_fusion moves the elevation alone. What it moved is soil that is, or
    // is not, where the bookkeeping put it (the real pile spreads ahead of the blade, the
    // bookkept one stands in the first cell off the footprint): the loose thickness is what
    // stands above the undisturbed surface now, so the blade pushes, and the surcharge counts,
    // the soil the sensors see. Ground seen below the base lowers the base (no loose).
    for (std::size_t k = 0; k < H0.size(); ++k)
      if (std::isfinite(H0[k]) && std::isfinite(B0[k])) L0[k] = std::max(0.0, H0[k] - B0[k]);
  }
  H = H0;
  L = L0;
  S = S0;
  if (ids.bank >= 0) {
    win.gather(map, ids.bank, K0);
    K = K0;
  }
  change.assign(H.size(), kSweepUnchanged);
}

void SweepSoil::write(LayeredMap& map, const SweepLayers& ids, const MapWindow& win) const {
  // Only what changed, so snapshots keep sharing untouched tiles.
  win.scatterChanged(map, ids.elevation, H0, H);
  win.scatterChanged(map, ids.loose, Lg, L);
  win.scatterChanged(map, ids.sigma, S0, S);
  if (ids.bank >= 0) win.scatterChanged(map, ids.bank, K0, K);
  if (ids.base >= 0) {
    // Every known cell of the window is tracked from now on, with its base where the update left
    // it (a cut lowers it, a deposit leaves it); a cell still unknown stays untracked.
    std::vector<double> B(H.size());
    for (std::size_t k = 0; k < H.size(); ++k) B[k] = std::isfinite(H[k]) ? H[k] - std::max(0.0, L[k]) : B0[k];
    win.scatterChanged(map, ids.base, B0, B);
  }
  updateFusionLayers(map, ids, win, change, H, S0, S);
}

namespace {

// SweepConfig::bank_reference: every cell from the edge at `T` to bank_reach_m ahead along t̂
// (the edge's width plus half a metre each side) that has no bank height yet, a known elevation
// and no loose soil takes its elevation as its bank height. Cells the map cannot allocate (a
// sparse map at its budget) are left without one: the depth then falls back to elevation - loose.
void recordBankAhead(LayeredMap& map, const SweepLayers& ids, const Eigen::Isometry3d& T, const BladeGeometry& bg,
                     const Eigen::Vector2d& t_hat, const SweepConfig& cfg) {
  const auto c = bladeCorners(T, bg);
  Eigen::Vector2d a = horizontal(c[0]), b = horizontal(c[1]);
  const Eigen::Vector2d along = b - a;
  if (along.norm() < 1e-9) return;
  const Eigen::Vector2d u = along.normalized();
  a -= 0.5 * u;
  b += 0.5 * u;
  const Eigen::Vector2d ahead = cfg.bank_reach_m * t_hat;
  const MapWindow win = MapWindow::covering(map, {a, b, a + ahead, b + ahead});
  if (win.empty() || !win.tryAllocate(map, {ids.bank})) return;
  std::vector<double> K0, H, L;
  win.gather(map, ids.bank, K0);
  win.gather(map, ids.elevation, H);
  win.gather(map, ids.loose, L);
  std::vector<double> K = K0;
  const Geometry& geo = map.geometry();
  const Eigen::Vector2d e = b - a;
  const double det = e.x() * ahead.y() - e.y() * ahead.x();
  if (std::abs(det) < 1e-12) return;
  for (int r = 0; r < win.rows(); ++r)
    for (int cc = 0; cc < win.cols(); ++cc) {
      const size_t k = static_cast<size_t>(r) * win.cols() + cc;
      if (std::isfinite(K0[k]) || !std::isfinite(H[k]) || orZero(L[k]) > 0.0) continue;
      const Eigen::Vector2d p = geo.positionOf(Index(win.i0() + r, win.j0() + cc)) - a;
      const double s = (p.x() * ahead.y() - p.y() * ahead.x()) / det;  // along the edge, 0..1
      const double f = (e.x() * p.y() - e.y() * p.x()) / det;          // ahead, 0..1
      if (s < 0 || s > 1 || f < 0 || f > 1) continue;
      K[k] = H[k];
    }
  win.scatterChanged(map, ids.bank, K0, K);
}

}  // namespace

std::shared_ptr<SweepRecord> runSweep(LayeredMap& map, const SweepLayers& ids, const SweepConfig& cfg,
                                      const std::vector<BladePose>& history, const Executor& ex, CarriedPile* pile) {
  TERRAMAP_CHECK(history.size() >= 2, "runSweep needs at least two poses");
  const Geometry& geo = map.geometry();
  const double res = geo.resolution();
  const BladeGeometry& bg = history.front().geometry;
  auto rec = newRecord(history, cfg, res);
  const SweepDirections dir = sweepDirections(history, cfg, *rec);
  const SweptCells sc = sweptCells(history, cfg, geo, ex);

  const MapWindow win = sweepWindow(map, sc.fp, cfg, dir.t_hat, res);
  // A sparse map at its memory budget: the sweep is dropped whole (the caller counts it) rather
  // than written in part.
  if (!ids.allocate(map, win)) return nullptr;
  if (ids.bank >= 0 && cfg.bank_reference) recordBankAhead(map, ids, history.front().T_map_blade, bg, dir.t_hat, cfg);
  SweepSoil soil(map, ids, win);
  const std::vector<double>&H0 = soil.H0, &L0 = soil.L0;

  const std::vector<CutCell> cuts = cutCells(sc, win, H0, geo, cfg, *rec);
  extractSlices(cuts, win, H0, L0, soil.K0, geo, cfg, dir, ex, *rec);
  // The blade removes bank soil down to the floor it leaves: the bank surface there is the floor.
  if (!soil.K.empty())
    for (const CutCell& a : cuts) {
      double& k = soil.K[static_cast<size_t>(a.w)];
      if (!(k <= a.zl)) k = a.zl;
    }
  averageSlices(!cuts.empty(), res, *rec);

  // Surcharge ahead of the blade before the cut, the cut and deposit, the surcharge after.
  const auto vq0 = surchargeVolume(rec->T_map_blade0, bg, dir.t_hat, cfg.fit_length_m, geo, win, L0);
  rec->vq0_m3 = vq0.first;
  cutAndDeposit(cuts, sc, win, geo, cfg, dir.m_hat, soil.H, soil.L, soil.S, soil.change, *rec);
  const auto vq1 = surchargeVolume(rec->T_map_blade1, bg, dir.t_hat, cfg.fit_length_m, geo, win, soil.L);
  rec->vq1_m3 = vq1.first;
  // The mapped region's own variance first: the carried pile adds its terms to it (until
  // 2026-12-02 this assignment came after and dropped them).
  rec->var_vq = std::max(vq0.second, vq1.second);
  if (pile != nullptr && cfg.surcharge_carried) carriedSurcharge(cfg, bg, dir, *pile, *rec);
  const double gamma_l = rec->loose_unit_weight_n_m3;
  rec->q0_n = gamma_l * rec->vq0_m3;
  rec->q1_n = gamma_l * rec->vq1_m3;

  rec->steps.reserve(history.size());
  for (size_t k = 0; k < history.size(); ++k) rec->steps.push_back(stepValues(history, k, dir, res, *rec));

  soil.write(map, ids, win);
  return rec;
}

}  // namespace terramap::plugins
