// Truth soil-tool force (FEE per slice) and truth terrain deformation (cut, push, relax).
#include <terramap/soil/fee.hpp>
#include <terramap/sim/blade_physics.hpp>

#include <algorithm>
#include <cmath>
#include <utility>

namespace terramap::sim {
namespace {

constexpr double kG = 9.80665;

Eigen::Vector3d horizontal(const Eigen::Vector3d& v) { return {v.x(), v.y(), 0.0}; }

/// Terzaghi strip-footing bearing capacity factors (N_c, N_q) for friction angle phi.
void bearingFactors(double phi, double& nc, double& nq) {
  if (phi < 1e-6) {
    nq = 1.0;
    nc = M_PI + 2.0;  // Prandtl, phi = 0
    return;
  }
  const double t = std::tan(M_PI / 4 + phi / 2);
  nq = std::exp(M_PI * std::tan(phi)) * t * t;
  nc = (nq - 1.0) / std::tan(phi);
}

struct BladeFrame {
  Eigen::Vector3d c, xb, yb, zb, n_h, e_h;  // edge centre, axes, horizontal push dir, horizontal edge dir
  double half_lat = 0;                      // horizontal half-length of the edge
  bool ok = true;
};

BladeFrame frameOf(const Eigen::Isometry3d& T, const BladeGeometry& g) {
  BladeFrame f;
  f.c = T.translation();
  f.xb = T.linear().col(0);
  f.yb = T.linear().col(1);
  f.zb = T.linear().col(2);
  Eigen::Vector3d n = horizontal(f.xb);
  if (n.norm() < 1e-6) n = -horizontal(f.zb);
  if (n.norm() < 1e-9) {
    f.ok = false;
    n = Eigen::Vector3d::UnitX();
  }
  f.n_h = n.normalized();
  Eigen::Vector3d e = horizontal(f.yb);
  const double el = e.norm();
  f.e_h = el > 1e-9 ? Eigen::Vector3d(e / el) : Eigen::Vector3d(-f.n_h.y(), f.n_h.x(), 0.0);
  f.half_lat = 0.5 * g.width_m * el;
  return f;
}

/// Nodes i0..i1 of row j that can satisfy lat_lo <= (p - c).e <= lat_hi and s_lo <= (p - c).n <= s_hi
/// (p = node position; e, n horizontal): a superset, two nodes wider than the analytic interval,
/// so exact per-node tests on it find the same nodes as on the whole row. Empty: lo > hi.
std::pair<int, int> rowInterval(const TruthTerrain& terrain, int i0, int i1, int j, const Eigen::Vector3d& c,
                                const Eigen::Vector3d& e, double lat_lo, double lat_hi, const Eigen::Vector3d& n,
                                double s_lo, double s_hi) {
  const double res = terrain.resolution();
  const Eigen::Vector2d p0 = terrain.nodePosition(i0, j);
  const double dy = p0.y() - c.y(), ox = p0.x() - c.x();
  // x interval (relative to c) where both constraints can hold; a constraint whose x
  // coefficient is ~0 is left to the exact test.
  double xlo = -1e300, xhi = 1e300;
  auto clip = [&](double coef, double off, double lo, double hi) {  // lo <= coef x + off <= hi
    if (std::abs(coef) < 1e-9) return;
    double a = (lo - off) / coef, b = (hi - off) / coef;
    if (a > b) std::swap(a, b);
    xlo = std::max(xlo, a);
    xhi = std::min(xhi, b);
  };
  clip(e.x(), dy * e.y(), lat_lo, lat_hi);
  clip(n.x(), dy * n.y(), s_lo, s_hi);
  if (xlo > xhi) return {1, 0};
  const int w = i1 - i0 + 1;
  const double ia = std::max(-1.0, std::floor((xlo - ox) / res) - 2), ib = std::min(static_cast<double>(w), std::ceil((xhi - ox) / res) + 2);
  return {i0 + std::max(0, static_cast<int>(ia)), i0 + std::min(w - 1, static_cast<int>(ib))};
}

/// One Jacobi sweep of loose-soil sliding over the node box [i0, i1] x [j0, j1]; nodes under
/// the blade (behind the edge within `back_band`) neither give nor take. False if nothing moved.
/// Serial: a sweep is ~10^4 nodes, too little to pay for handing row blocks to another thread
/// (measured: no gain at 2 threads), and serially each node's outflow limit can be computed in
/// the same pass as its fluxes (it needs only its own and its -x / -y neighbours' fluxes). The
/// moves are applied afterwards in raster order.
bool relaxSweep(TruthTerrain& terrain, const BladeFrame& f, double res, double back_band, double max_step, int i0,
                int j0, int i1, int j1, CellRect& changed) {
  const int w = i1 - i0 + 1, h = j1 - j0 + 1;
  // Scratch buffers reused across calls (per calling thread) to avoid page faults at 60 Hz.
  thread_local std::vector<unsigned char> mask;
  thread_local std::vector<double> fx, fy, outsum;
  const std::size_t n = static_cast<std::size_t>(w) * h;
  mask.resize(n);
  fx.resize(n);
  fy.resize(n);
  outsum.resize(n);
  auto idx = [w](int i, int j) { return static_cast<std::size_t>(j) * w + i; };
  double* fxp = fx.data();
  double* fyp = fy.data();
  double* op = outsum.data();
  unsigned char* mp = mask.data();
  // Heights and loose thicknesses are read in place (no moves happen before the last pass):
  // node (i, j) of the box is at terrain index base + j * stride + i.
  const double* Hg = terrain.heightData().data();
  const double* Lg = terrain.looseData().data();
  const std::size_t base = terrain.index(i0, j0), stride = static_cast<std::size_t>(terrain.nx());
  auto gidx = [&](int i, int j) { return base + static_cast<std::size_t>(j) * stride + i; };
  // The blade footprint is a rectangle, so on each row it covers one interval of nodes: the
  // exact per-node test runs only on a superset of that interval (two nodes wider than the
  // analytic one), the rest of the row is clear. Same mask as testing every node.
  const double lat_max = f.half_lat + 0.5 * res;
  for (int j = 0; j < h; ++j) {
    unsigned char* row = mp + idx(0, j);
    std::fill(row, row + w, static_cast<unsigned char>(0));
    const auto [ia, ib] = rowInterval(terrain, i0, i1, j0 + j, f.c, f.e_h, -lat_max, lat_max, f.n_h, -back_band, 0.0);
    for (int i = ia - i0; i <= ib - i0; ++i) {
      const Eigen::Vector2d p = terrain.nodePosition(i0 + i, j0 + j);
      const double dx = p.x() - f.c.x(), dyy = p.y() - f.c.y();
      const double lat = dx * f.e_h.x() + dyy * f.e_h.y();
      const double s = dx * f.n_h.x() + dyy * f.n_h.y();
      row[i] = (std::abs(lat) <= lat_max && s <= 0.0 && s > -back_band) ? 1 : 0;
    }
  }
  // Edge fluxes (positive = from (i, j) to the +x / +y neighbour); only loose soil slides.
  // Then the node's outflow, summed in raster order of its edges (the -y edge, the -x edge,
  // the +x edge, the +y edge), turned into a scale: a node gives at most the loose soil it has
  // (bank soil does not slide).
  // Only edges with loose soil at one end can carry flux, so each row is visited only over
  // [first loose node - 1, last loose node] of itself and of the row above (its +y edges):
  // about 60 % of the box on a spoil pile. The outflow of a node without loose soil is never
  // used (it gives nothing), so it is not computed; a node with loose soil lies inside its
  // row's span and inside the span of the row below, so the fluxes its outflow sums were
  // computed in this sweep. Same fluxes and moves, in the same order, as visiting every node.
  thread_local std::vector<int> ext_lo, ext_hi, span_lo, span_hi;
  ext_lo.assign(h + 1, w);
  ext_hi.assign(h + 1, -1);
  span_lo.resize(h);
  span_hi.resize(h);
  for (int j = 0; j < h; ++j) {
    const double* Lr = Lg + gidx(0, j);
    int a = 0, b = w - 1;
    while (a < w && !(Lr[a] > 0.0)) ++a;
    if (a == w) continue;
    while (!(Lr[b] > 0.0)) --b;
    ext_lo[j] = a;
    ext_hi[j] = b;
  }
  bool moved = false;
  for (int j = 0; j < h; ++j) {
    const double* Hr = Hg + gidx(0, j);
    const double* Lr = Lg + gidx(0, j);
    const int lo = std::max(0, std::min(ext_lo[j] - 1, ext_lo[j + 1]));
    const int hi = std::min(w - 1, std::max(ext_hi[j], ext_hi[j + 1]));
    span_lo[j] = lo;
    span_hi[j] = hi;
    for (int i = lo; i <= hi; ++i) {
      const std::size_t a = idx(i, j);
      double qx = 0.0, qy = 0.0;
      if (!mp[a]) {
        const double ha = Hr[i];
        const bool la = Lr[i] > 0.0;
        if (i + 1 < w && !mp[a + 1] && (la || Lr[i + 1] > 0.0)) {
          const double dh = ha - Hr[i + 1];
          const double ex = std::abs(dh) - max_step;
          if (ex > 0 && (dh > 0 ? Lr[i] : Lr[i + 1]) > 0.0) qx = dh > 0 ? 0.25 * ex : -0.25 * ex;
        }
        const std::size_t b = a + static_cast<std::size_t>(w);
        if (j + 1 < h && !mp[b] && (la || Lr[i + stride] > 0.0)) {
          const double dh = ha - Hr[i + stride];
          const double ex = std::abs(dh) - max_step;
          if (ex > 0 && (dh > 0 ? Lr[i] : Lr[i + stride]) > 0.0) qy = dh > 0 ? 0.25 * ex : -0.25 * ex;
        }
      }
      fxp[a] = qx;
      fyp[a] = qy;
      moved = moved || qx != 0.0 || qy != 0.0;
      if (!(Lr[i] > 0.0)) continue;
      double o = 0.0;
      if (j > 0 && fyp[a - w] < 0) o += -fyp[a - w];
      if (i > 0 && fxp[a - 1] < 0) o += -fxp[a - 1];
      if (qx > 0) o += qx;
      if (qy > 0) o += qy;
      op[a] = (o > Lr[i] && o > 0) ? Lr[i] / o : 1.0;
    }
  }
  if (!moved) return false;
  // The box of the nodes that moved soil (often much smaller than the sweep's box): what the
  // pyramid refresh and the simulator's terrain patches have to cover.
  int ci0 = w, ci1 = -1, cj0 = h, cj1 = -1;
  for (int j = 0; j < h; ++j) {
    int ri0 = w, ri1 = -1;
    for (int i = span_lo[j]; i <= span_hi[j]; ++i) {
      const std::size_t a = idx(i, j);
      const double ax = fxp[a];
      const double ay = fyp[a];
      if (ax == 0.0 && ay == 0.0) continue;
      if (ax > 0) terrain.moveLoose(i0 + i, j0 + j, i0 + i + 1, j0 + j, ax * op[a]);
      else if (ax < 0) terrain.moveLoose(i0 + i + 1, j0 + j, i0 + i, j0 + j, -ax * op[a + 1]);
      if (ay > 0) terrain.moveLoose(i0 + i, j0 + j, i0 + i, j0 + j + 1, ay * op[a]);
      else if (ay < 0) terrain.moveLoose(i0 + i, j0 + j + 1, i0 + i, j0 + j, -ay * op[a + w]);
      ri0 = std::min(ri0, i);
      ri1 = std::max(ri1, ax != 0.0 ? i + 1 : i);
      cj0 = std::min(cj0, j);
      cj1 = std::max(cj1, ay != 0.0 ? j + 1 : j);
    }
    ci0 = std::min(ci0, ri0);
    ci1 = std::max(ci1, ri1);
  }
  if (ci1 >= ci0) changed.add(CellRect::inclusive(i0 + ci0, j0 + cj0, i0 + ci1, j0 + cj1));
  return true;
}

}  // namespace

BladeForce bladeSoilForce(const TruthTerrain& terrain, const SoilField& soil, const Eigen::Isometry3d& T_map_blade,
                          const BladeGeometry& blade, double edge_thickness_m, int slices, double normal_speed_mps,
                          double edge_vz_mps, double accel_mps2, const Executor* exec) {
  BladeForce out;
  const BladeFrame f = frameOf(T_map_blade, blade);
  out.push_dir = f.n_h;
  if (!f.ok || slices < 1) return out;
  const double rho = std::atan2(f.zb.z(), -f.zb.dot(f.n_h));
  const double ds = blade.width_m / slices;
  const double res = terrain.resolution();
  const double q_step = std::max(res, 0.04);
  // Each slice only reads the terrain and the soil, so the slices are evaluated independently
  // (in parallel when an executor is given) into one record each; the records are then summed
  // serially in slice order, with the same expressions as a single serial loop, so the result
  // is bit-identical for any thread count.
  struct Slice {
    int kind = 0;  // 0: nothing, 1: pushing a loose pile, 2: cutting
    double q = 0, pile = 0, alpha = 0, rho_s = 0, d = 0, beta = 0, f_in = 0, qb = 0;
    Eigen::Vector2d F = Eigen::Vector2d::Zero();
    bool valid = false;
    const SoilProperties* sp = nullptr;
  };
  thread_local std::vector<Slice> rec;
  rec.assign(static_cast<std::size_t>(slices), Slice{});
  Slice* recp = rec.data();
  auto evalSlice = [&](int k) {
    Slice& o = recp[k];
    const double ys = -0.5 * blade.width_m + (k + 0.5) * ds;
    const Eigen::Vector3d pe = f.c + f.yb * ys;
    const double ue = terrain.undisturbedAt(pe.x(), pe.y());
    if (std::isnan(ue)) return;
    // Surcharge: loose soil (bank-equivalent thickness) ahead of the slice within 1 m.
    double lc_sum = 0.0;
    for (double l = 0.5 * q_step; l < 1.0; l += q_step) {
      const double lc = terrain.looseBankAt(pe.x() + f.n_h.x() * l, pe.y() + f.n_h.y() * l);
      if (!std::isnan(lc)) lc_sum += lc;
    }
    // The intact surface ahead of the edge (least squares over 0.05..0.5 m) gives both the
    // slope and, by its intercept at the edge, the height the blade is cutting into: the node
    // at the edge itself has already been carved by this step's deformation, so reading it
    // would see anything from 0 to 100 % of the real depth.
    double sx = 0, sz = 0, sxx = 0, sxz = 0;
    int n = 0;
    for (int m = 0; m < 7; ++m) {
      const double l = 0.05 + 0.075 * m;
      const double z = terrain.undisturbedAt(pe.x() + f.n_h.x() * l, pe.y() + f.n_h.y() * l);
      if (std::isnan(z)) continue;
      sx += l; sz += z; sxx += l * l; sxz += l * z; ++n;
    }
    double slope = 0.0, surface_at_edge = ue;
    if (n >= 2) {
      const double den = n * sxx - sx * sx;
      if (den > 1e-12) slope = (n * sxz - sx * sz) / den;
      surface_at_edge = (sz - slope * sx) / n;
    }
    const double depth_v = surface_at_edge - pe.z();
    const double h0 = terrain.initialHeightAt(pe.x(), pe.y());
    const double mid_depth = h0 - (pe.z() + std::max(0.0, depth_v) * 0.5);
    const SoilProperties& sp = soil.at(pe.x(), pe.y(), mid_depth);
    const double q = sp.fee.gamma_n_m3 * lc_sum * q_step * ds;
    if (depth_v <= 1e-4) {
      // Not cutting: pushing a loose pile only if the edge is below the pile surface.
      const double hf = terrain.heightAt(pe.x() + f.n_h.x() * res, pe.y() + f.n_h.y() * res);
      if (q > 0 && !std::isnan(hf) && hf > pe.z()) {
        o.kind = 1;
        o.pile = q * std::tan(sp.repose_rad);
      }
      return;
    }
    o.kind = 2;
    o.sp = &sp;
    o.q = q;
    const double alpha = std::atan(slope);
    const double d = depth_v * std::cos(alpha);
    // fee.hpp measures the rake from the soil surface (rho = alpha + face angle from the
    // horizontal) and d normal to it; on level ground both conventions agree.
    const double rho_s = rho + alpha;
    fee::Geometry g;
    g.alpha_rad = alpha;
    g.rho_rad = rho_s;
    g.d_m = d;
    g.w_m = ds;
    g.q_n = q;
    double beta = fee::betaMin(sp.fee, g);
    if (!std::isfinite(beta)) beta = fee::betaNominal(sp.fee);
    const fee::Result r = fee::evaluate(sp.fee, g, beta);
    o.valid = r.valid();
    if (o.valid) o.F = r.F_total_N;
    if (normal_speed_mps > 0) {
      const double mass_flux = sp.fee.gamma_n_m3 / kG * d * ds * normal_speed_mps;  // kg/s entering the wedge
      o.f_in = mass_flux * normal_speed_mps + q / kG * std::max(0.0, accel_mps2);
    }
    if (edge_vz_mps < 0) {
      double nc = 0, nq = 0;
      bearingFactors(sp.fee.phi_rad, nc, nq);
      o.qb = sp.fee.c_pa * nc + sp.fee.gamma_n_m3 * depth_v * nq;
    }
    o.alpha = alpha; o.rho_s = rho_s; o.d = d; o.beta = beta;
  };
  if (exec != nullptr && exec->threads() > 1 && slices > 1) {
    // A few slices per task: one slice (~8 k instructions) is too small to schedule alone.
    const int per = std::max(1, (slices + 4 * exec->threads() - 1) / (4 * exec->threads()));
    const int tasks = (slices + per - 1) / per;
    exec->forEach(tasks, [&](int t) {
      for (int k = t * per, e = std::min(slices, k + per); k < e; ++k) evalSlice(k);
    });
  } else {
    for (int k = 0; k < slices; ++k) evalSlice(k);
  }
  FeeTruth& tr = out.truth;
  double wsum = 0, a_alpha = 0, a_rho = 0, a_d = 0, a_c = 0, a_phi = 0, a_g = 0, a_ca = 0, a_delta = 0, a_beta = 0;
  for (int k = 0; k < slices; ++k) {
    const Slice& o = recp[k];
    if (o.kind == 1) out.fee_map -= f.n_h * o.pile;
    if (o.kind != 2) continue;
    const SoilProperties& sp = *o.sp;
    ++tr.cutting_slices;
    if (!o.valid) {
      ++tr.invalid_slices;
    } else {
      // F_total is the blade's force on the soil in (push, up); the soil pushes back.
      out.fee_map -= f.n_h * o.F.x() + Eigen::Vector3d::UnitZ() * o.F.y();
    }
    if (normal_speed_mps > 0) out.inertia_map -= f.n_h * o.f_in;
    if (edge_vz_mps < 0) out.penetration_map.z() += o.qb * edge_thickness_m * ds;
    const double w = o.d;  // depth-weighted summaries
    wsum += w;
    a_alpha += w * o.alpha; a_rho += w * o.rho_s; a_d += w * o.d; a_beta += w * o.beta;
    a_c += w * sp.fee.c_pa; a_phi += w * sp.fee.phi_rad; a_g += w * sp.fee.gamma_n_m3;
    a_ca += w * sp.fee.ca_pa; a_delta += w * sp.fee.delta_rad;
    tr.width_m += ds;
    tr.q_n += o.q;
  }
  if (wsum > 0) {
    tr.alpha_rad = a_alpha / wsum; tr.rho_rad = a_rho / wsum; tr.depth_m = a_d / wsum; tr.beta_rad = a_beta / wsum;
    tr.c_pa = a_c / wsum; tr.phi_rad = a_phi / wsum; tr.gamma_n_m3 = a_g / wsum; tr.ca_pa = a_ca / wsum;
    tr.delta_rad = a_delta / wsum;
  }
  return out;
}

namespace {
/// Passes and reach (nodes) of the spoil settling ahead of the blade in cutAndPush.
constexpr int kSettleNodes = 150;
/// A pair slides once it is steeper than (1 + slack) x the repose, then settles to the repose
/// (the gap between the angle of maximum stability and of repose): a pile front at repose
/// does not shift its whole face forward by microns on every step.
constexpr double kSettleSlack = 0.2;
}  // namespace

CutResult cutAndPush(TruthTerrain& terrain, const SoilField& soil, const Eigen::Isometry3d& T_old,
                     const Eigen::Isometry3d& T_new, const BladeGeometry& blade, int slices) {
  CutResult out;
  const BladeFrame f0 = frameOf(T_old, blade), f1 = frameOf(T_new, blade);
  if (!f1.ok || slices < 1) return out;
  const double forward = (f1.c - f0.c).dot(f1.n_h);
  if (forward < 0.0) return out;  // reversing: no backdrag model
  const double res = terrain.resolution();
  // Node box around the old and new edges.
  double xmin = 1e300, xmax = -1e300, ymin = 1e300, ymax = -1e300;
  for (const BladeFrame* f : {&f0, &f1})
    for (double s : {-1.0, 1.0}) {
      const Eigen::Vector3d p = f->c + f->yb * (0.5 * s * blade.width_m);
      xmin = std::min(xmin, p.x()); xmax = std::max(xmax, p.x());
      ymin = std::min(ymin, p.y()); ymax = std::max(ymax, p.y());
    }
  const int i0 = std::max(0, static_cast<int>(std::floor((xmin - terrain.originX()) / res)) - 2);
  const int j0 = std::max(0, static_cast<int>(std::floor((ymin - terrain.originY()) / res)) - 2);
  const int i1 = std::min(terrain.nx() - 1, static_cast<int>(std::ceil((xmax - terrain.originX()) / res)) + 2);
  const int j1 = std::min(terrain.ny() - 1, static_cast<int>(std::ceil((ymax - terrain.originY()) / res)) + 2);
  if (i0 > i1 || j0 > j1) return out;
  std::vector<double> acc_v(slices, 0.0), acc_c(slices, 0.0);
  const double yb_h = std::hypot(f1.yb.x(), f1.yb.y());
  const double top = f1.zb.z() * blade.height_m;
  bool any = false;
  // Nodes the edge swept this step lie in a band behind the new edge line no deeper than
  // `band` (|s0 - s1| <= |c1 - c0| + |p - c1| |n0 - n1|); only that band of each row is tested.
  const double turn = (f1.n_h - f0.n_h).norm(), shift = (f1.c - f0.c).norm();
  double band = res + shift + (f1.half_lat + 1.0) * turn + res;
  if (band > 1.0) band = 1e300;  // a jump (not a physics step): test whole rows
  for (int j = j0; j <= j1; ++j) {
    const auto [ra, rb] = rowInterval(terrain, i0, i1, j, f1.c, f1.e_h, -f1.half_lat, f1.half_lat, f1.n_h, -band, 0.0);
    for (int i = ra; i <= rb; ++i) {
      const Eigen::Vector2d p = terrain.nodePosition(i, j);
      const double dx1 = p.x() - f1.c.x(), dy1 = p.y() - f1.c.y();
      const double lat = dx1 * f1.e_h.x() + dy1 * f1.e_h.y();
      if (std::abs(lat) > f1.half_lat) continue;
      const double s1 = dx1 * f1.n_h.x() + dy1 * f1.n_h.y();
      if (s1 > 0.0) continue;
      const double s0 = (p.x() - f0.c.x()) * f0.n_h.x() + (p.y() - f0.c.y()) * f0.n_h.y();
      if (!(s0 > 0.0 || s1 > -res)) continue;
      const double t = yb_h > 1e-9 ? lat / yb_h : 0.0;  // position along the edge (m)
      const double ze = f1.c.z() + f1.yb.z() * t;
      if (terrain.height(i, j) <= ze) continue;
      double depth0 = terrain.initialHeight(i, j) - 0.5 * (ze + terrain.undisturbed(i, j));
      const TruthTerrain::Removed rm = terrain.removeBetween(i, j, ze, ze + top);
      if (rm.bank_u <= 0 && rm.loose_v <= 0) continue;
      const SoilProperties& sp = soil.at(p.x(), p.y(), depth0);
      int k = static_cast<int>(std::floor((lat + f1.half_lat) / (2 * f1.half_lat) * slices));
      k = std::clamp(k, 0, slices - 1);
      acc_v[k] += rm.bank_u * sp.swell + rm.loose_v;
      acc_c[k] += rm.bank_u + rm.loose_c;
      out.cut_bank_m3 += rm.bank_u * res * res;
      out.moved_loose_m3 += rm.loose_c * res * res;
      any = true;
    }
  }
  if (!any) return out;
  out.add(CellRect::inclusive(i0, j0, i1, j1));
  for (int k = 0; k < slices; ++k) {
    if (acc_c[k] <= 0.0 && acc_v[k] <= 0.0) continue;
    const double lat = -f1.half_lat + (k + 0.5) * (2 * f1.half_lat / slices);
    int di = 0, dj = 0;
    bool placed = false;
    double ahead = 1.5 * res;
    for (; ahead < 4.0 * res; ahead += 0.5 * res) {
      const Eigen::Vector3d q = f1.c + f1.e_h * lat + f1.n_h * ahead;
      terrain.nearestNode(q.x(), q.y(), di, dj);
      const Eigen::Vector2d pn(terrain.originX() + di * res, terrain.originY() + dj * res);
      const double s1 = (pn.x() - f1.c.x()) * f1.n_h.x() + (pn.y() - f1.c.y()) * f1.n_h.y();
      if (s1 > 0.5 * res) {
        placed = true;
        break;
      }
    }
    if (!placed || !terrain.inside(di, dj)) {
      const double lost = acc_c[k] * res * res;
      terrain.addLost(lost);
      out.lost_m3 += lost;
      continue;
    }
    terrain.addLoose(di, dj, acc_v[k], acc_c[k]);
    out.deposited_m3 += acc_c[k] * res * res;
    out.add(CellRect::inclusive(di, dj, di, dj));
    // The spoil runs down the front of the pile at once. Without this it stays on the one node
    // row ahead of the edge (the relaxation spreads at most ~0.6 m^2/s per metre of blade on a
    // 2 cm grid, a 0.8 m/s cut feeds 0.1 m^2/s onto 2 cm) and grows into columns metres high.
    // Along the slice's line ahead of the edge, the deposit node's loose soil fills the nodes in
    // front up to a repose line from a common apex H (mass balance fixes H; the line stops at
    // the first node already above it). It only slides once the first step is steeper than
    // (1 + kSettleSlack) x the repose, so a front at repose does not move its whole face by
    // microns every step. The sideways spreading is left to relaxLoose.
    // Nodes along the line are generated only as far as the fill reaches.
    int line_i[kSettleNodes], line_j[kSettleNodes];
    double line_d[kSettleNodes];  // horizontal distance from the deposit node (m)
    int n_line = 0, walk = 0, pi = di, pj = dj;
    auto extend = [&]() {
      while (n_line < kSettleNodes && walk < 2 * kSettleNodes) {
        ++walk;
        const Eigen::Vector3d q = f1.c + f1.e_h * lat + f1.n_h * (ahead + walk * res);
        int ni = 0, nj = 0;
        terrain.nearestNode(q.x(), q.y(), ni, nj);
        if (ni == pi && nj == pj) continue;
        if (!terrain.inside(ni, nj)) {
          walk = 2 * kSettleNodes;
          return false;
        }
        line_i[n_line] = ni;
        line_j[n_line] = nj;
        line_d[n_line] = res * std::sqrt(static_cast<double>((ni - di) * (ni - di) + (nj - dj) * (nj - dj)));
        ++n_line;
        pi = ni;
        pj = nj;
        return true;
      }
      return false;
    };
    if (!extend()) continue;
    const double tanr = std::tan(soil.at(terrain.originX() + di * res, terrain.originY() + dj * res, 0.0).repose_rad);
    const double z0 = terrain.height(di, dj);
    if (!(z0 - terrain.height(line_i[0], line_j[0]) > (1.0 + kSettleSlack) * line_d[0] * tanr)) continue;
    // Apex with K receiving nodes: z0 - H = sum_{m<K} (H - d_m tanr - z_m).
    double sum = 0.0;
    int K = 0;
    while (K < n_line || extend()) {
      const double zk = terrain.height(line_i[K], line_j[K]), rk = line_d[K] * tanr;
      const double h_try = (z0 + sum + rk + zk) / (K + 2);
      if (!(h_try - rk > zk)) break;
      sum += rk + zk;
      ++K;
    }
    if (K == 0) continue;
    const double H = (z0 + sum) / (K + 1);
    double give = 0.0;
    double fill[kSettleNodes];
    for (int m = 0; m < K; ++m) {
      fill[m] = std::max(0.0, H - line_d[m] * tanr - terrain.height(line_i[m], line_j[m]));
      give += fill[m];
    }
    const double avail = terrain.loose(di, dj);
    const double scale = give > avail ? avail / give : 1.0;
    for (int m = 0; m < K; ++m) {
      if (!(fill[m] > 0.0)) continue;
      terrain.moveLoose(di, dj, line_i[m], line_j[m], fill[m] * scale);
      out.add(CellRect::inclusive(line_i[m], line_j[m], line_i[m], line_j[m]));
    }
  }
  return out;
}

CutResult relaxLoose(TruthTerrain& terrain, const SoilField& soil, const Eigen::Isometry3d& T_map_blade,
                     const BladeGeometry& blade, double ahead_m, double side_m, int iterations) {
  CutResult out;
  const BladeFrame f = frameOf(T_map_blade, blade);
  if (!f.ok) return out;
  const double res = terrain.resolution();
  const double back_band = std::max(res, blade.height_m * std::abs(horizontal(f.zb).norm())) + res;
  double xmin = 1e300, xmax = -1e300, ymin = 1e300, ymax = -1e300;
  for (double s : {-1.0, 1.0})
    for (double a : {-back_band - side_m, ahead_m}) {
      const Eigen::Vector3d p = f.c + f.e_h * (s * (f.half_lat + side_m)) + f.n_h * a;
      xmin = std::min(xmin, p.x()); xmax = std::max(xmax, p.x());
      ymin = std::min(ymin, p.y()); ymax = std::max(ymax, p.y());
    }
  const int i0 = std::max(0, static_cast<int>(std::floor((xmin - terrain.originX()) / res)));
  const int j0 = std::max(0, static_cast<int>(std::floor((ymin - terrain.originY()) / res)));
  const int i1 = std::min(terrain.nx() - 1, static_cast<int>(std::ceil((xmax - terrain.originX()) / res)));
  const int j1 = std::min(terrain.ny() - 1, static_cast<int>(std::ceil((ymax - terrain.originY()) / res)));
  if (i1 - i0 < 1 || j1 - j0 < 1) return out;
  // Repose of the loose soil around the blade: that of the soil at the edge centre.
  const double h0 = terrain.initialHeightAt(f.c.x(), f.c.y());
  const double tanr = std::tan(soil.at(f.c.x(), f.c.y(), std::isnan(h0) ? 0.0 : h0 - f.c.z()).repose_rad);
  const double max_step = res * tanr;
  // Only edges touching a node with loose soil carry flux, so each sweep works on the bounding
  // box of the loose nodes grown by one (usually a thin band ahead of the blade, not the whole
  // box). Restricting the raster keeps the move order, hence the result, unchanged.
  // Loose soil moves at most one node per sweep, so sweep k works on the initial bounding box
  // grown by k nodes (a superset of the exact one gives the same result).
  int li0 = i1 + 1, li1 = i0 - 1, lj0 = j1 + 1, lj1 = j0 - 1;
  const std::vector<double>& lvd = terrain.looseData();
  for (int j = j0; j <= j1; ++j) {
    const double* row = &lvd[terrain.index(0, j)];
    int a = i0, b = i1;
    while (a <= i1 && !(row[a] > 0.0)) ++a;
    if (a > i1) continue;
    while (!(row[b] > 0.0)) --b;
    li0 = std::min(li0, a); li1 = std::max(li1, b);
    lj0 = std::min(lj0, j); lj1 = std::max(lj1, j);
  }
  if (li1 < li0) return out;
  for (int it = 0; it < iterations; ++it) {
    const int si0 = std::max(i0, li0 - 1 - it), si1 = std::min(i1, li1 + 1 + it);
    const int sj0 = std::max(j0, lj0 - 1 - it), sj1 = std::min(j1, lj1 + 1 + it);
    if (!relaxSweep(terrain, f, res, back_band, max_step, si0, sj0, si1, sj1, out)) break;
  }
  return out;
}

}  // namespace terramap::sim
