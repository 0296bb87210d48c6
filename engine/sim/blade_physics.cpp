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

/// The node box of one relaxation sweep and its scratch buffers (per calling thread, reused
/// across calls to avoid page faults at 60 Hz). Box node (i, j) is at idx(i, j) in the buffers
/// and at gidx(i, j) in the terrain's arrays.
struct SweepBox {
  int i0, j0, i1, j1, w, h;
  std::size_t base, stride;
  unsigned char* mask;  // 1: under the blade
  // Two rows each, row j at slot(j): a sweep computes row j's fluxes, then applies row j - 1's
  // moves (relaxSweepRows), so no more rows are ever needed at once.
  double *fx, *fy;      // edge fluxes to the +x / +y neighbour
  double* out_scale;    // share of its outflow a node can give
  int *ext_lo, *ext_hi;    // per row: first and last node with loose soil (h + 1 rows)
  int *span_lo, *span_hi;  // per row: the nodes whose fluxes were computed
  std::size_t idx(int i, int j) const { return static_cast<std::size_t>(j) * w + i; }
  std::size_t slot(int j) const { return static_cast<std::size_t>(j & 1) * w; }
  std::size_t gidx(int i, int j) const { return base + static_cast<std::size_t>(j) * stride + i; }
};

SweepBox sweepBox(const TruthTerrain& terrain, int i0, int j0, int i1, int j1) {
  thread_local std::vector<unsigned char> mask;
  thread_local std::vector<double> fx, fy, outsum;
  thread_local std::vector<int> ext_lo, ext_hi, span_lo, span_hi;
  const int w = i1 - i0 + 1, h = j1 - j0 + 1;
  const std::size_t n = static_cast<std::size_t>(w) * h;
  mask.resize(n);
  fx.resize(2 * static_cast<std::size_t>(w));
  fy.resize(2 * static_cast<std::size_t>(w));
  outsum.resize(2 * static_cast<std::size_t>(w));
  ext_lo.assign(h + 1, w);
  ext_hi.assign(h + 1, -1);
  span_lo.resize(h);
  span_hi.resize(h);
  return SweepBox{i0, j0, i1, j1, w, h, terrain.index(i0, j0), static_cast<std::size_t>(terrain.nx()),
                  mask.data(), fx.data(), fy.data(), outsum.data(), ext_lo.data(), ext_hi.data(),
                  span_lo.data(), span_hi.data()};
}

/// Marks the nodes under the blade (behind the edge within `back_band`). The blade footprint is
/// a rectangle, so on each row it covers one interval of nodes: the exact per-node test runs
/// only on a superset of that interval (two nodes wider than the analytic one), the rest of the
/// row is clear. Same mask as testing every node.
void markUnderBlade(const TruthTerrain& terrain, const BladeFrame& f, double res, double back_band, SweepBox& b) {
  const double lat_max = f.half_lat + 0.5 * res;
  for (int j = 0; j < b.h; ++j) {
    unsigned char* row = b.mask + b.idx(0, j);
    std::fill(row, row + b.w, static_cast<unsigned char>(0));
    const auto [ia, ib] =
        rowInterval(terrain, b.i0, b.i1, b.j0 + j, f.c, f.e_h, -lat_max, lat_max, f.n_h, -back_band, 0.0);
    for (int i = ia - b.i0; i <= ib - b.i0; ++i) {
      const Eigen::Vector2d p = terrain.nodePosition(b.i0 + i, b.j0 + j);
      const double dx = p.x() - f.c.x(), dyy = p.y() - f.c.y();
      const double lat = dx * f.e_h.x() + dyy * f.e_h.y();
      const double s = dx * f.n_h.x() + dyy * f.n_h.y();
      row[i] = (std::abs(lat) <= lat_max && s <= 0.0 && s > -back_band) ? 1 : 0;
    }
  }
}

/// Per row, the first and last node with loose soil (rows without any keep w and -1).
void findLooseExtents(const TruthTerrain& terrain, SweepBox& b) {
  for (int j = 0; j < b.h; ++j) {
    const int a = terrain.firstLoose(b.j0 + j, b.i0, b.i1);
    if (a > b.i1) continue;
    b.ext_lo[j] = a - b.i0;
    b.ext_hi[j] = terrain.lastLoose(b.j0 + j, a, b.i1) - b.i0;
  }
}

/// Row j's edge fluxes (positive = from (i, j) to the +x / +y neighbour); only loose soil
/// slides. Then the outflow of its nodes, summed in raster order of their edges (the -y edge,
/// the -x edge, the +x edge, the +y edge), turned into a scale: a node gives at most the loose
/// soil it has (bank soil does not slide). Reads rows j and j + 1 of the terrain and row j - 1's
/// fluxes.
/// Only edges with loose soil at one end can carry flux, so the row is visited only over
/// [first loose node - 1, last loose node] of itself and of the row above (its +y edges):
/// about 60 % of the box on a spoil pile. The outflow of a node without loose soil is never
/// used (it gives nothing), so it is not computed; a node with loose soil lies inside its
/// row's span and inside the span of the row below, so the fluxes its outflow sums were
/// computed in this sweep. Same fluxes as visiting every node. True if an edge carries flux.
bool fluxRow(const double* Hg, const double* Lg, double max_step, SweepBox& b, int j) {
  const int w = b.w, h = b.h;
  const std::size_t stride = b.stride;
  const unsigned char* mp = b.mask;
  double* fxp = b.fx + b.slot(j);
  double* fyp = b.fy + b.slot(j);
  double* op = b.out_scale + b.slot(j);
  const double* fy_below = j > 0 ? b.fy + b.slot(j - 1) : nullptr;
  bool moved = false;
  const double* Hr = Hg + b.gidx(0, j);
  const double* Lr = Lg + b.gidx(0, j);
  const int lo = std::max(0, std::min(b.ext_lo[j] - 1, b.ext_lo[j + 1]));
  const int hi = std::min(w - 1, std::max(b.ext_hi[j], b.ext_hi[j + 1]));
  b.span_lo[j] = lo;
  b.span_hi[j] = hi;
  for (int i = lo; i <= hi; ++i) {
    const std::size_t a = b.idx(i, j);
    double qx = 0.0, qy = 0.0;
    if (!mp[a]) {
      const double ha = Hr[i];
      const bool la = Lr[i] > 0.0;
      if (i + 1 < w && !mp[a + 1] && (la || Lr[i + 1] > 0.0)) {
        const double dh = ha - Hr[i + 1];
        const double ex = std::abs(dh) - max_step;
        if (ex > 0 && (dh > 0 ? Lr[i] : Lr[i + 1]) > 0.0) qx = dh > 0 ? 0.25 * ex : -0.25 * ex;
      }
      const std::size_t up = a + static_cast<std::size_t>(w);
      if (j + 1 < h && !mp[up] && (la || Lr[i + stride] > 0.0)) {
        const double dh = ha - Hr[i + stride];
        const double ex = std::abs(dh) - max_step;
        if (ex > 0 && (dh > 0 ? Lr[i] : Lr[i + stride]) > 0.0) qy = dh > 0 ? 0.25 * ex : -0.25 * ex;
      }
    }
    fxp[i] = qx;
    fyp[i] = qy;
    moved = moved || qx != 0.0 || qy != 0.0;
    if (!(Lr[i] > 0.0)) continue;
    double o = 0.0;
    if (j > 0 && fy_below[i] < 0) o += -fy_below[i];
    if (i > 0 && fxp[i - 1] < 0) o += -fxp[i - 1];
    if (qx > 0) o += qx;
    if (qy > 0) o += qy;
    op[i] = (o > Lr[i] && o > 0) ? Lr[i] / o : 1.0;
  }
  return moved;
}

/// Row j's moves, in raster order (needs row j + 1's outflow scales); grows the box of the
/// nodes that moved soil, [ci0, ci1] x [cj0, cj1] in box coordinates.
void applyRow(TruthTerrain& terrain, const SweepBox& b, int j, int& ci0, int& ci1, int& cj0, int& cj1) {
  const int w = b.w;
  const std::size_t stride = b.stride;
  const double* fxp = b.fx + b.slot(j);
  const double* fyp = b.fy + b.slot(j);
  const double* op = b.out_scale + b.slot(j);
  const double* op_up = b.out_scale + b.slot(j + 1);
  int ri0 = w, ri1 = -1;
  const std::size_t grow = b.gidx(0, j);
  for (int i = b.span_lo[j]; i <= b.span_hi[j]; ++i) {
    const std::size_t g = grow + i;
    const double ax = fxp[i];
    const double ay = fyp[i];
    if (ax == 0.0 && ay == 0.0) continue;
    if (ax > 0) terrain.moveLooseAt(g, g + 1, ax * op[i]);
    else if (ax < 0) terrain.moveLooseAt(g + 1, g, -ax * op[i + 1]);
    if (ay > 0) terrain.moveLooseAt(g, g + stride, ay * op[i]);
    else if (ay < 0) terrain.moveLooseAt(g + stride, g, -ay * op_up[i]);
    ri0 = std::min(ri0, i);
    ri1 = std::max(ri1, ax != 0.0 ? i + 1 : i);
    cj0 = std::min(cj0, j);
    cj1 = std::max(cj1, ay != 0.0 ? j + 1 : j);
  }
  ci0 = std::min(ci0, ri0);
  ci1 = std::max(ci1, ri1);
}

/// One Jacobi sweep over the box: every flux from the state before the sweep, the moves applied
/// in raster order, and the box of the nodes that moved soil (often much smaller than the
/// sweep's) added to `changed`: what the pyramid refresh and the simulator's terrain patches
/// have to cover. Row j's fluxes read rows j and j + 1; row j - 1's moves, applied right after,
/// change rows j - 1 and j only, so row j + 1's fluxes still read the state before the sweep:
/// the same fluxes and moves, in the same order, as computing all fluxes first, with two rows of
/// fluxes in memory instead of the whole box (three arrays of it, written and read back, were
/// most of a step's cache traffic with eight environments on a core pair). False if no edge
/// carries flux (then nothing moved).
bool sweepRows(TruthTerrain& terrain, double max_step, SweepBox& b, CellRect& changed) {
  const double* Hg = terrain.heightData().data();
  const double* Lg = terrain.looseData().data();
  bool moved = false;
  int ci0 = b.w, ci1 = -1, cj0 = b.h, cj1 = -1;
  for (int j = 0; j < b.h; ++j) {
    if (fluxRow(Hg, Lg, max_step, b, j)) moved = true;
    if (j > 0) applyRow(terrain, b, j - 1, ci0, ci1, cj0, cj1);
  }
  if (b.h > 0) applyRow(terrain, b, b.h - 1, ci0, ci1, cj0, cj1);
  if (ci1 >= ci0) changed.add(CellRect::inclusive(b.i0 + ci0, b.j0 + cj0, b.i0 + ci1, b.j0 + cj1));
  return moved;
}

/// One Jacobi sweep of loose-soil sliding over the node box [i0, i1] x [j0, j1]; nodes under
/// the blade (behind the edge within `back_band`) neither give nor take. False if nothing moved.
/// Serial: a sweep is ~10^4 nodes, too little to pay for handing row blocks to another thread
/// (measured: no gain at 2 threads), and serially each node's outflow limit can be computed in
/// the same pass as its fluxes (it needs only its own and its -x / -y neighbours' fluxes). The
/// moves follow one row behind, in raster order (sweepRows).
bool relaxSweep(TruthTerrain& terrain, const BladeFrame& f, double res, double back_band, double max_step, int i0,
                int j0, int i1, int j1, CellRect& changed) {
  SweepBox b = sweepBox(terrain, i0, j0, i1, j1);
  markUnderBlade(terrain, f, res, back_band, b);
  findLooseExtents(terrain, b);
  return sweepRows(terrain, max_step, b, changed);
}

/// One blade slice's contribution to the force, evaluated independently of the others.
struct SliceRecord {
  int kind = 0;  // 0: nothing, 1: pushing a loose pile, 2: cutting
  double q = 0, pile = 0, alpha = 0, rho_s = 0, d = 0, beta = 0, f_in = 0, qb = 0;
  Eigen::Vector2d F = Eigen::Vector2d::Zero();
  bool valid = false;
  const SoilProperties* sp = nullptr;
};

/// What every slice of one bladeSoilForce call shares.
struct SliceInputs {
  const TruthTerrain& terrain;
  const SoilField& soil;
  const BladeFrame& f;
  const BladeGeometry& blade;
  double rho, ds, res, q_step, normal_speed_mps, edge_vz_mps, accel_mps2;
};

/// Surcharge: loose soil (bank-equivalent thickness) ahead of the slice within 1 m, summed
/// over samples `q_step` apart.
double looseAhead(const SliceInputs& in, const Eigen::Vector3d& pe) {
  double lc_sum = 0.0;
  for (double l = 0.5 * in.q_step; l < 1.0; l += in.q_step) {
    const double lc = in.terrain.looseBankAt(pe.x() + in.f.n_h.x() * l, pe.y() + in.f.n_h.y() * l);
    if (!std::isnan(lc)) lc_sum += lc;
  }
  return lc_sum;
}

/// The intact surface ahead of the edge (least squares over 0.05..0.5 m) gives both the slope
/// and, by its intercept at the edge, the height the blade is cutting into: the node at the
/// edge itself has already been carved by this step's deformation, so reading it would see
/// anything from 0 to 100 % of the real depth. Keeps `slope` and `surface_at_edge` with fewer
/// than two samples.
void surfaceAhead(const SliceInputs& in, const Eigen::Vector3d& pe, double& slope, double& surface_at_edge) {
  double sx = 0, sz = 0, sxx = 0, sxz = 0;
  int n = 0;
  for (int m = 0; m < 7; ++m) {
    const double l = 0.05 + 0.075 * m;
    const double z = in.terrain.undisturbedAt(pe.x() + in.f.n_h.x() * l, pe.y() + in.f.n_h.y() * l);
    if (std::isnan(z)) continue;
    sx += l; sz += z; sxx += l * l; sxz += l * z; ++n;
  }
  if (n >= 2) {
    const double den = n * sxx - sx * sx;
    if (den > 1e-12) slope = (n * sxz - sx * sz) / den;
    surface_at_edge = (sz - slope * sx) / n;
  }
}

/// The FEE wedge of a cutting slice, its inertia and the edge's penetration resistance.
void cuttingSlice(const SliceInputs& in, const SoilProperties& sp, double q, double slope, double depth_v,
                  SliceRecord& o) {
  o.kind = 2;
  o.sp = &sp;
  o.q = q;
  const double alpha = std::atan(slope);
  const double d = depth_v * std::cos(alpha);
  // fee.hpp measures the rake from the soil surface (rho = alpha + face angle from the
  // horizontal) and d normal to it; on level ground both conventions agree.
  const double rho_s = in.rho + alpha;
  fee::Geometry g;
  g.alpha_rad = alpha;
  g.rho_rad = rho_s;
  g.d_m = d;
  g.w_m = in.ds;
  g.q_n = q;
  double beta = fee::betaMin(sp.fee, g);
  if (!std::isfinite(beta)) beta = fee::betaNominal(sp.fee);
  const fee::Result r = fee::evaluate(sp.fee, g, beta);
  o.valid = r.valid();
  if (o.valid) o.F = r.F_total_N;
  if (in.normal_speed_mps > 0) {
    const double mass_flux = sp.fee.gamma_n_m3 / kG * d * in.ds * in.normal_speed_mps;  // kg/s entering the wedge
    o.f_in = mass_flux * in.normal_speed_mps + q / kG * std::max(0.0, in.accel_mps2);
  }
  if (in.edge_vz_mps < 0) {
    const fee::BearingFactors bf = fee::bearingFactors(sp.fee.phi_rad);
    o.qb = sp.fee.c_pa * bf.N_c + sp.fee.gamma_n_m3 * depth_v * bf.N_q;
  }
  o.alpha = alpha; o.rho_s = rho_s; o.d = d; o.beta = beta;
}

void evaluateSlice(const SliceInputs& in, int k, SliceRecord& o) {
  const Eigen::Vector3d pe = in.f.c + in.f.yb * (-0.5 * in.blade.width_m + (k + 0.5) * in.ds);
  const double ue = in.terrain.undisturbedAt(pe.x(), pe.y());
  if (std::isnan(ue)) return;
  const double lc_sum = looseAhead(in, pe);
  double slope = 0.0, surface_at_edge = ue;
  surfaceAhead(in, pe, slope, surface_at_edge);
  const double depth_v = surface_at_edge - pe.z();
  const double h0 = in.terrain.initialHeightAt(pe.x(), pe.y());
  const double mid_depth = h0 - (pe.z() + std::max(0.0, depth_v) * 0.5);
  const SoilProperties& sp = in.soil.at(pe.x(), pe.y(), mid_depth);
  const double q = sp.fee.gamma_n_m3 * lc_sum * in.q_step * in.ds;
  if (depth_v <= 1e-4) {
    // Not cutting: pushing a loose pile only if the edge is below the pile surface.
    const double hf = in.terrain.heightAt(pe.x() + in.f.n_h.x() * in.res, pe.y() + in.f.n_h.y() * in.res);
    if (q > 0 && !std::isnan(hf) && hf > pe.z()) {
      o.kind = 1;
      o.q = q;
      o.pile = q * std::tan(sp.repose_rad);
    }
    return;
  }
  cuttingSlice(in, sp, q, slope, depth_v, o);
}

/// Each slice only reads the terrain and the soil, so the slices are evaluated independently
/// (in parallel when an executor is given) into one record each.
void evaluateSlices(const SliceInputs& in, int slices, const Executor* exec, SliceRecord* rec) {
  if (exec != nullptr && exec->threads() > 1 && slices > 1) {
    // A few slices per task: one slice (~8 k instructions) is too small to schedule alone.
    const int per = std::max(1, (slices + 4 * exec->threads() - 1) / (4 * exec->threads()));
    const int tasks = (slices + per - 1) / per;
    exec->forEach(tasks, [&](int t) {
      for (int k = t * per, e = std::min(slices, k + per); k < e; ++k) evaluateSlice(in, k, rec[k]);
    });
  } else {
    for (int k = 0; k < slices; ++k) evaluateSlice(in, k, rec[k]);
  }
}

/// Sums the records serially in slice order, with the same expressions as a single serial
/// loop, so the result is bit-identical for any thread count.
void sumSlices(const SliceInputs& in, const SliceRecord* rec, int slices, double edge_thickness_m, BladeForce& out) {
  const Eigen::Vector3d& n_h = in.f.n_h;
  const double ds = in.ds;
  FeeTruth& tr = out.truth;
  double wsum = 0, a_alpha = 0, a_rho = 0, a_d = 0, a_c = 0, a_phi = 0, a_g = 0, a_ca = 0, a_delta = 0, a_beta = 0;
  for (int k = 0; k < slices; ++k) {
    const SliceRecord& o = rec[k];
    if (o.kind == 1) {
      out.fee_map -= n_h * o.pile;
      tr.q_pushed_n += o.q;
    }
    if (o.kind != 2) continue;
    const SoilProperties& sp = *o.sp;
    ++tr.cutting_slices;
    if (!o.valid) {
      ++tr.invalid_slices;
    } else {
      // F_total is the blade's force on the soil in (push, up); the soil pushes back.
      out.fee_map -= n_h * o.F.x() + Eigen::Vector3d::UnitZ() * o.F.y();
    }
    if (in.normal_speed_mps > 0) out.inertia_map -= n_h * o.f_in;
    if (in.edge_vz_mps < 0) out.penetration_map.z() += o.qb * edge_thickness_m * ds;
    const double w = o.d;  // depth-weighted summaries
    wsum += w;
    a_alpha += w * o.alpha; a_rho += w * o.rho_s; a_d += w * o.d; a_beta += w * o.beta;
    a_c += w * sp.fee.c_pa; a_phi += w * sp.fee.phi_rad; a_g += w * sp.fee.gamma_n_m3;
    a_ca += w * sp.fee.ca_pa; a_delta += w * sp.fee.delta_rad;
    tr.width_m += ds;
    tr.area_m2 += o.d * ds;
    tr.depth2_m3 += o.d * o.d * ds;
    tr.q_n += o.q;
  }
  if (wsum > 0) {
    tr.alpha_rad = a_alpha / wsum; tr.rho_rad = a_rho / wsum; tr.depth_m = a_d / wsum; tr.beta_rad = a_beta / wsum;
    tr.c_pa = a_c / wsum; tr.phi_rad = a_phi / wsum; tr.gamma_n_m3 = a_g / wsum; tr.ca_pa = a_ca / wsum;
    tr.delta_rad = a_delta / wsum;
  }
}

}  // namespace

BladeForce bladeSoilForce(const TruthTerrain& terrain, const SoilField& soil, const Eigen::Isometry3d& T_map_blade,
                          const BladeGeometry& blade, double edge_thickness_m, int slices, double normal_speed_mps,
                          double edge_vz_mps, double accel_mps2, const Executor* exec) {
  BladeForce out;
  const BladeFrame f = frameOf(T_map_blade, blade);
  out.push_dir = f.n_h;
  if (!f.ok || slices < 1) return out;
  const double res = terrain.resolution();
  const SliceInputs in{terrain, soil, f, blade, std::atan2(f.zb.z(), -f.zb.dot(f.n_h)), blade.width_m / slices,
                       res, std::max(res, 0.04), normal_speed_mps, edge_vz_mps, accel_mps2};
  thread_local std::vector<SliceRecord> rec;
  rec.assign(static_cast<std::size_t>(slices), SliceRecord{});
  evaluateSlices(in, slices, exec, rec.data());
  sumSlices(in, rec.data(), slices, edge_thickness_m, out);
  return out;
}

namespace {
/// Passes and reach (nodes) of the spoil settling ahead of the blade in cutAndPush.
constexpr int kSettleNodes = 150;
/// A pair slides once it is steeper than (1 + slack) x the repose, then settles to the repose
/// (the gap between the angle of maximum stability and of repose): a pile front at repose
/// does not shift its whole face forward by microns on every step.
constexpr double kSettleSlack = 0.2;

/// Node box [i0, i1] x [j0, j1] around the old and new edges, two nodes of margin, clipped to
/// the grid. False when it is empty.
bool edgeBox(const TruthTerrain& terrain, const BladeFrame& f0, const BladeFrame& f1, const BladeGeometry& blade,
             int& i0, int& j0, int& i1, int& j1) {
  const double res = terrain.resolution();
  double xmin = 1e300, xmax = -1e300, ymin = 1e300, ymax = -1e300;
  for (const BladeFrame* f : {&f0, &f1})
    for (double s : {-1.0, 1.0}) {
      const Eigen::Vector3d p = f->c + f->yb * (0.5 * s * blade.width_m);
      xmin = std::min(xmin, p.x()); xmax = std::max(xmax, p.x());
      ymin = std::min(ymin, p.y()); ymax = std::max(ymax, p.y());
    }
  i0 = std::max(0, static_cast<int>(std::floor((xmin - terrain.originX()) / res)) - 2);
  j0 = std::max(0, static_cast<int>(std::floor((ymin - terrain.originY()) / res)) - 2);
  i1 = std::min(terrain.nx() - 1, static_cast<int>(std::ceil((xmax - terrain.originX()) / res)) + 2);
  j1 = std::min(terrain.ny() - 1, static_cast<int>(std::ceil((ymax - terrain.originY()) / res)) + 2);
  return i0 <= i1 && j0 <= j1;
}

/// Cuts the nodes the edge swept this step (those of the box now behind the new edge line that
/// were ahead of the old one, or within a node of it) down to the edge, and collects per slice
/// the soil removed: loose volume in acc_v, bank-equivalent in acc_c. True if anything was cut.
bool carveSwept(TruthTerrain& terrain, const SoilField& soil, const BladeFrame& f0, const BladeFrame& f1,
                const BladeGeometry& blade, int slices, int i0, int j0, int i1, int j1, std::vector<double>& acc_v,
                std::vector<double>& acc_c, CutResult& out) {
  const double res = terrain.resolution();
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
  return any;
}

/// The node where a slice's spoil lands: the first, from 1.5 to 4 nodes ahead of the new edge
/// at lateral offset `lat`, that lies more than half a node ahead of it. `ahead` ends at the
/// distance used. False when none is.
bool depositNode(const TruthTerrain& terrain, const BladeFrame& f1, double lat, double& ahead, int& di, int& dj) {
  const double res = terrain.resolution();
  for (ahead = 1.5 * res; ahead < 4.0 * res; ahead += 0.5 * res) {
    const Eigen::Vector3d q = f1.c + f1.e_h * lat + f1.n_h * ahead;
    terrain.nearestNode(q.x(), q.y(), di, dj);
    const Eigen::Vector2d pn(terrain.originX() + di * res, terrain.originY() + dj * res);
    const double s1 = (pn.x() - f1.c.x()) * f1.n_h.x() + (pn.y() - f1.c.y()) * f1.n_h.y();
    if (s1 > 0.5 * res) return true;
  }
  return false;
}

/// The nodes in front of a deposit node along its slice's line ahead of the edge, generated
/// only as far as a fill reaches (at most kSettleNodes).
struct SettleLine {
  const TruthTerrain& terrain;
  const BladeFrame& f1;
  double lat, ahead, res;
  int di, dj;
  int i[kSettleNodes], j[kSettleNodes];
  double d[kSettleNodes];  // horizontal distance from the deposit node (m)
  int n = 0, walk = 0, pi, pj;

  SettleLine(const TruthTerrain& t, const BladeFrame& f, double lat_m, double ahead_m, int di_, int dj_)
      : terrain(t), f1(f), lat(lat_m), ahead(ahead_m), res(t.resolution()), di(di_), dj(dj_), pi(di_), pj(dj_) {}

  /// Appends the next node; false at the grid's border or the line's end.
  bool extend() {
    while (n < kSettleNodes && walk < 2 * kSettleNodes) {
      ++walk;
      const Eigen::Vector3d q = f1.c + f1.e_h * lat + f1.n_h * (ahead + walk * res);
      int ni = 0, nj = 0;
      terrain.nearestNode(q.x(), q.y(), ni, nj);
      if (ni == pi && nj == pj) continue;
      if (!terrain.inside(ni, nj)) {
        walk = 2 * kSettleNodes;
        return false;
      }
      i[n] = ni;
      j[n] = nj;
      d[n] = res * std::sqrt(static_cast<double>((ni - di) * (ni - di) + (nj - dj) * (nj - dj)));
      ++n;
      pi = ni;
      pj = nj;
      return true;
    }
    return false;
  }
};

/// The spoil runs down the front of the pile at once. Without this it stays on the one node
/// row ahead of the edge (the relaxation spreads at most ~0.6 m^2/s per metre of blade on a
/// 2 cm grid, a 0.8 m/s cut feeds 0.1 m^2/s onto 2 cm) and grows into columns metres high.
/// Along the slice's line ahead of the edge, the deposit node's loose soil fills the nodes in
/// front up to a repose line from a common apex H (mass balance fixes H; the line stops at
/// the first node already above it). It only slides once the first step is steeper than
/// (1 + kSettleSlack) x the repose, so a front at repose does not move its whole face by
/// microns every step. The sideways spreading is left to relaxLoose.
void settleSpoil(TruthTerrain& terrain, const SoilField& soil, const BladeFrame& f1, double lat, double ahead, int di,
                 int dj, CutResult& out) {
  const double res = terrain.resolution();
  SettleLine line(terrain, f1, lat, ahead, di, dj);
  if (!line.extend()) return;
  const double tanr = std::tan(soil.at(terrain.originX() + di * res, terrain.originY() + dj * res, 0.0).repose_rad);
  const double z0 = terrain.height(di, dj);
  if (!(z0 - terrain.height(line.i[0], line.j[0]) > (1.0 + kSettleSlack) * line.d[0] * tanr)) return;
  // Apex with K receiving nodes: z0 - H = sum_{m<K} (H - d_m tanr - z_m).
  double sum = 0.0;
  int K = 0;
  while (K < line.n || line.extend()) {
    const double zk = terrain.height(line.i[K], line.j[K]), rk = line.d[K] * tanr;
    const double h_try = (z0 + sum + rk + zk) / (K + 2);
    if (!(h_try - rk > zk)) break;
    sum += rk + zk;
    ++K;
  }
  if (K == 0) return;
  const double H = (z0 + sum) / (K + 1);
  double give = 0.0;
  double fill[kSettleNodes];
  for (int m = 0; m < K; ++m) {
    fill[m] = std::max(0.0, H - line.d[m] * tanr - terrain.height(line.i[m], line.j[m]));
    give += fill[m];
  }
  const double avail = terrain.loose(di, dj);
  const double scale = give > avail ? avail / give : 1.0;
  for (int m = 0; m < K; ++m) {
    if (!(fill[m] > 0.0)) continue;
    terrain.moveLoose(di, dj, line.i[m], line.j[m], fill[m] * scale);
    out.add(CellRect::inclusive(line.i[m], line.j[m], line.i[m], line.j[m]));
  }
}

/// Puts slice k's spoil (loose volume v, bank-equivalent c) ahead of the new edge and lets it
/// settle; spoil that would land outside the grid is counted as lost.
void depositSlice(TruthTerrain& terrain, const SoilField& soil, const BladeFrame& f1, int k, int slices, double v,
                  double c, CutResult& out) {
  const double res = terrain.resolution();
  const double lat = -f1.half_lat + (k + 0.5) * (2 * f1.half_lat / slices);
  int di = 0, dj = 0;
  double ahead = 0.0;
  if (!depositNode(terrain, f1, lat, ahead, di, dj) || !terrain.inside(di, dj)) {
    const double lost = c * res * res;
    terrain.addLost(lost);
    out.lost_m3 += lost;
    return;
  }
  terrain.addLoose(di, dj, v, c);
  out.deposited_m3 += c * res * res;
  out.add(CellRect::inclusive(di, dj, di, dj));
  settleSpoil(terrain, soil, f1, lat, ahead, di, dj, out);
}
}  // namespace

CutResult cutAndPush(TruthTerrain& terrain, const SoilField& soil, const Eigen::Isometry3d& T_old,
                     const Eigen::Isometry3d& T_new, const BladeGeometry& blade, int slices) {
  CutResult out;
  const BladeFrame f0 = frameOf(T_old, blade), f1 = frameOf(T_new, blade);
  if (!f1.ok || slices < 1) return out;
  const double forward = (f1.c - f0.c).dot(f1.n_h);
  if (forward < 0.0) return out;  // reversing: no backdrag model
  int i0 = 0, j0 = 0, i1 = -1, j1 = -1;
  if (!edgeBox(terrain, f0, f1, blade, i0, j0, i1, j1)) return out;
  std::vector<double> acc_v(slices, 0.0), acc_c(slices, 0.0);
  if (!carveSwept(terrain, soil, f0, f1, blade, slices, i0, j0, i1, j1, acc_v, acc_c, out)) return out;
  out.add(CellRect::inclusive(i0, j0, i1, j1));
  for (int k = 0; k < slices; ++k)
    if (!(acc_c[k] <= 0.0 && acc_v[k] <= 0.0)) depositSlice(terrain, soil, f1, k, slices, acc_v[k], acc_c[k], out);
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
  for (int j = j0; j <= j1; ++j) {
    const int a = terrain.firstLoose(j, i0, i1);
    if (a > i1) continue;
    const int b = terrain.lastLoose(j, a, i1);
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

CutResult relaxRegion(TruthTerrain& terrain, double tan_repose, int i0, int j0, int i1, int j1, int iterations) {
  CutResult out;
  i0 = std::max(0, i0);
  j0 = std::max(0, j0);
  i1 = std::min(terrain.nx() - 1, i1);
  j1 = std::min(terrain.ny() - 1, j1);
  if (i1 - i0 < 1 || j1 - j0 < 1) return out;
  const double max_step = terrain.resolution() * tan_repose;
  for (int it = 0; it < iterations; ++it) {
    SweepBox b = sweepBox(terrain, i0, j0, i1, j1);
    std::fill(b.mask, b.mask + static_cast<std::size_t>(b.w) * b.h, static_cast<unsigned char>(0));
    findLooseExtents(terrain, b);
    if (!sweepRows(terrain, max_step, b, out)) break;
  }
  return out;
}

}  // namespace terramap::sim
