// The soil_erosion plugin: ROI around the blade, masks from the sweep record, map I/O.
#include "soil_erosion.hpp"

#include <terramap/core/map_window.hpp>

#include <cmath>
#include <limits>
#include <sstream>

namespace terramap::plugins {

namespace {
constexpr double kPi = 3.14159265358979323846;
}

ParamSchema SoilErosion::schema() const {
  const ErosionConfig d;
  return {
      param::real("cohesion_pa", d.cohesion_pa, 0.0, 1e6, "Pa", "c_l: cohesion of loose soil"),
      param::real("friction_rad", d.friction_rad, 0.0, 1.5, "rad", "phi_l: internal friction angle of loose soil"),
      param::real("unit_weight_n_m3", d.unit_weight_n_m3, 1.0, 1e5, "N/m^3", "gamma_l: unit weight of loose soil"),
      param::real("min_slope_rad", d.min_slope_rad, 0.0, 1.5, "rad", "drops below r tan(min_slope) never move"),
      param::real("dt_s", d.dt_s, 1e-4, 10.0, "s", "erosion sub-step"),
      param::integer("substeps", d.substeps, 1, 10000, "sub-steps per pass"),
      param::integer("passes", 1, 1, 1000, "passes per trigger"),
      param::boolean("carry_velocity", true, "carry the slip velocity across sub-steps (false: restart from rest)"),
      param::real("roi_along_m", 3.0, 0.0, 1000.0, "m", "ROI half-length along the blade normal"),
      param::real("roi_margin_m", 2.0, 0.0, 1000.0, "m", "ROI width = blade width + this margin"),
      param::text("trigger", "sweep", {"sweep", "sweep_and_tick"},
                  "erode after every sweep, or also on every Tick (around the latest sweep's pose)"),
      param::boolean("blade_mask", true, "keep soil from flowing out of / through the swept volume (E, Z masks)"),
  };
}

void SoilErosion::configure(const Params& p) {
  cfg_.cohesion_pa = p.getDouble("cohesion_pa");
  cfg_.friction_rad = p.getDouble("friction_rad");
  cfg_.unit_weight_n_m3 = p.getDouble("unit_weight_n_m3");
  cfg_.min_slope_rad = p.getDouble("min_slope_rad");
  cfg_.dt_s = p.getDouble("dt_s");
  cfg_.substeps = static_cast<int>(p.getInt("substeps"));
  cfg_.carry_velocity = p.getBool("carry_velocity");
  passes_ = static_cast<int>(p.getInt("passes"));
  roi_along_m_ = p.getDouble("roi_along_m");
  roi_margin_m_ = p.getDouble("roi_margin_m");
  on_tick_ = p.getString("trigger") == "sweep_and_tick";
  use_mask_ = p.getBool("blade_mask");
  if (cfg_.friction_rad >= 0.5 * kPi) p.fail("friction_rad", "must be below pi/2");
}

std::vector<LayerSpec> SoilErosion::layers() const {
  return {
      {"elevation", LayerAccess::Write, "", std::numeric_limits<float>::quiet_NaN(), ""},
      {"loose", LayerAccess::Write, "", std::numeric_limits<float>::quiet_NaN(), ""},
      {"height_sigma", LayerAccess::Write, "", std::numeric_limits<float>::quiet_NaN(), ""},
  };
}

void SoilErosion::start(ProcessContext& ctx) {
  elevation_ = ctx.map().layerId("elevation");
  loose_ = ctx.map().layerId("loose");
  sigma_ = ctx.map().layerId("height_sigma");
  auto optional = [&](const char* name) {
    return ctx.map().hasLayer(name) ? ctx.map().layerId(name) : LayerId(-1);
  };
  variance_ = optional("variance");
  upper_bound_ = optional("upper_bound");
  is_upper_bound_ = optional("is_upper_bound");
  // Validates the configuration against the map resolution once, before any event.
  ErosionSolver check(cfg_, ctx.map().geometry().resolution());
  ctx.addCounter("critical_drop_m", check.criticalDrop());
}

void SoilErosion::process(ProcessContext& ctx, const Event& event) {
  const Record* r = ctx.records().latest(SweepRecord::kType);
  if (!r) return;
  const bool is_tick = std::holds_alternative<Tick>(event);
  if (is_tick ? !on_tick_ : r->sequence <= last_sequence_) return;
  last_sequence_ = r->sequence;
  const auto rec = std::static_pointer_cast<const SweepRecord>(r->payload);
  erodeAround(ctx, *rec);
}

void SoilErosion::erodeAround(ProcessContext& ctx, const SweepRecord& rec) {
  LayeredMap& map = ctx.map();
  const Geometry& geo = map.geometry();
  const double res = geo.resolution();
  const ErosionSolver solver(cfg_, res);

  // Oriented ROI around the T1 edge centre.
  const Eigen::Vector2d c = rec.T_map_blade1.translation().head<2>();
  Eigen::Vector2d a = rec.T_map_blade1.linear().col(0).head<2>();
  if (a.norm() < 1e-9) a = rec.n_hat;
  a.normalize();
  const Eigen::Vector2d b(-a.y(), a.x());
  const double ha = roi_along_m_, hb = 0.5 * (roi_margin_m_ + rec.geometry.width_m);
  std::vector<Eigen::Vector2d> corners;
  for (int sa : {-1, 1})
    for (int sb : {-1, 1}) corners.push_back(c + sa * ha * a + sb * hb * b);
  const MapWindow win = MapWindow::covering(map, corners);
  if (win.empty()) {
    ctx.addCounter("passes_outside_map", 1);
    return;
  }
  // A sparse map at its memory budget: skip the slide whole (counted) rather than write half.
  if (!win.tryAllocate(map, {elevation_, loose_, sigma_, variance_, upper_bound_, is_upper_bound_})) {
    ctx.countDrop("tile_budget");
    return;
  }
  Scratch& sc = scratch_;
  std::vector<double>& H0 = sc.H0;
  std::vector<double>& L0 = sc.L0;
  std::vector<double>& S0 = sc.S0;
  win.gather(map, elevation_, H0);
  win.gather(map, loose_, L0);
  win.gather(map, sigma_, S0);
  ErosionGrid& g = sc.grid;
  g.resize(win.rows(), win.cols());
  for (int r = 0; r < win.rows(); ++r)
    for (int cc = 0; cc < win.cols(); ++cc) {
      const size_t k = g.at(r, cc);
      const Eigen::Vector2d p = geo.positionOf(Index(win.i0() + r, win.j0() + cc)) - c;
      const bool inside = std::abs(p.dot(a)) <= ha && std::abs(p.dot(b)) <= hb;
      g.H[k] = H0[k];
      g.L[k] = std::isfinite(L0[k]) ? std::max(0.0, L0[k]) : 0.0;
      g.active[k] = inside && std::isfinite(H0[k]) ? 1 : 0;
    }
  if (use_mask_) {
    for (const SweepMaskCell& m : rec.mask) {
      const auto idx = geo.indexAt(m.position);
      if (!idx || !win.contains(idx->x(), idx->y())) continue;
      const size_t k = static_cast<size_t>(win.local(idx->x(), idx->y()));
      g.blade[k] = 1;
      g.z_mask[k] = m.sv_bottom_m;
    }
  }
  const auto off = ErosionSolver::offsetsAlong(rec.m_hat);
  for (int p = 0; p < passes_; ++p) solver.pass(g, off.first, off.second, ctx.executor());
  passes_run_ += passes_;

  // Loose layer: write back where it was NaN only if soil arrived (NaN stays NaN otherwise).
  std::vector<double>& L1 = sc.L1;
  std::vector<double>& S1 = sc.S1;
  L1.resize(g.L.size());
  S1 = S0;
  double moved = 0;
  for (size_t k = 0; k < g.L.size(); ++k) {
    L1[k] = (!std::isfinite(L0[k]) && g.L[k] == 0.0) ? L0[k] : g.L[k];
    if (std::isfinite(H0[k]) && g.H[k] != H0[k]) {
      const double dh = g.H[k] - H0[k];
      const double s = std::isfinite(S0[k]) ? S0[k] : 0.0;
      S1[k] = std::sqrt(s * s + 0.25 * dh * dh);  // the slip model's own error: half the move
      moved += std::abs(dh);
    }
  }
  win.scatterChanged(map, elevation_, H0, g.H);
  win.scatterChanged(map, loose_, L0, L1);
  win.scatterChanged(map, sigma_, S0, S1);
  // Height contract (docs/height_contract.md) on lidar_fusion's layers, where they exist. A slip
  // moves the surface by dh relative to where it was, so the variance grows by the same
  // (dh/2)^2 height_sigma took (a cell the LiDAR never measured starts from its blind sigma);
  // the valid-cell convention upper_bound = elevation follows the move. is_valid is kept: the
  // surface is the old one, shifted by at most the slip, so what rays said of it still holds.
  if (variance_ >= 0) {
    std::vector<double>& V0 = sc.V0;
    std::vector<double>& V = sc.V;
    win.gather(map, variance_, V0);
    V = V0;
    for (size_t k = 0; k < V.size(); ++k) {
      if (!(std::isfinite(H0[k]) && g.H[k] != H0[k])) continue;
      const double s0 = std::isfinite(S0[k]) ? S0[k] : 0.0;
      const double base = std::isfinite(V0[k]) ? V0[k] : s0 * s0;
      V[k] = base + (S1[k] * S1[k] - s0 * s0);
    }
    win.scatterChanged(map, variance_, V0, V);
  }
  if (upper_bound_ >= 0 && is_upper_bound_ >= 0) {
    std::vector<double>& U0 = sc.U0;
    std::vector<double>& I0 = sc.I0;
    std::vector<double>& U = sc.U;
    std::vector<double>& I = sc.I;
    win.gather(map, upper_bound_, U0);
    win.gather(map, is_upper_bound_, I0);
    U = U0;
    I = I0;
    for (size_t k = 0; k < U.size(); ++k) {
      if (!(std::isfinite(H0[k]) && g.H[k] != H0[k])) continue;
      U[k] = g.H[k];
      I[k] = 0.0;
    }
    win.scatterChanged(map, upper_bound_, U0, U);
    win.scatterChanged(map, is_upper_bound_, I0, I);
  }
  ctx.addCounter("erosion_passes", passes_);
  ctx.addCounter("eroded_volume_m3", 0.5 * moved * res * res);
  ctx.addCounter("roi_cells", static_cast<double>(win.size()));
}

}  // namespace terramap::plugins
