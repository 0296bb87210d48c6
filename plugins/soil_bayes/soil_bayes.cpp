// soil_bayes: per-cell Bayesian fusion of soil_pinn's estimates over the wedge ahead of the blade.
#include "soil_bayes.hpp"

#include <terramap/core/map_window.hpp>
#include <terramap/soil/prior_params.hpp>
#include <terramap/soil/soil_parameters.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

namespace terramap::plugins {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Layers, units and ranges: soil::kSoilParams (SoilEstimateRecord::Soil order).
constexpr const char* kDocs[SoilEstimateRecord::kCount] = {
    "cohesion c of the soil at the surface (posterior mean)",
    "internal friction angle phi (posterior mean)",
    "soil-blade adhesion c_a (posterior mean)",
    "soil-blade friction angle delta (posterior mean)",
    "unit weight gamma (posterior mean)"};
static_assert(int{SoilEstimateRecord::kCount} == int{soil::kSoilParamCount} &&
                  int{SoilEstimateRecord::kCa} == int{soil::kParamCa} &&
                  int{SoilEstimateRecord::kGamma} == int{soil::kParamGamma},
              "the record carries the soil in soil::SoilParam order");

std::string squared(const std::string& unit) { return unit.find('^') == std::string::npos ? unit + "^2" : "(" + unit + ")^2"; }

}  // namespace

double wedgeLength(double d_m, double d_res_m, double alpha_rad, double beta_rad) {
  const double d = d_m + (std::isfinite(d_res_m) ? d_res_m : 0.0);
  if (!std::isfinite(d) || !std::isfinite(alpha_rad) || !std::isfinite(beta_rad) || d <= 0.0) return kNaN;
  const double ca = std::cos(alpha_rad);
  const double ab = alpha_rad + beta_rad;
  if (ca <= 0.0 || ab >= 0.5 * 3.14159265358979323846) return kNaN;
  const double den = ca * (std::tan(ab) - std::tan(alpha_rad));
  return den > 0.0 ? d / den : kNaN;
}

ParamSchema SoilBayes::schema() const {
  const SoilBayesConfig d;
  ParamSchema s{
      param::real("c_s", d.c_s, 0.0, 50.0, "1",
                  "C_s: the estimate's variance grows by exp(C_s x / x_max) with the distance x into the wedge"),
      param::real("x_min_m", d.x_min_m, 0.0, 100.0, "m", "the wedge reaches at least this far ahead of the blade"),
      param::real("behind_m", d.behind_m, 0.0, 100.0, "m",
                  "the footprint also reaches this far behind the edge (the soil the edge passed through while "
                  "the estimate's force was measured)"),
      param::text("prior", "none", {"config", "none"},
                  "a cell's first estimate is taken as is (none: the estimator's variance already holds the "
                  "prior's where the force cannot tell the property) or fused with the prior_* beliefs "
                  "(config: knowledge of the site)"),
      param::real("cut_depth_m", d.cut_depth_m, 1e-3, 100.0, "m",
                  "a cut this much below the surface the soil was fused at inflates the variances "
                  "by exp(depth / cut_depth_m)"),
  };
  soil::addPriorParams(s, "in a cell no estimate reached yet (with prior: config)");
  return s;
}

void SoilBayes::configure(const Params& p) {
  cfg_.c_s = p.getDouble("c_s");
  cfg_.x_min_m = p.getDouble("x_min_m");
  cfg_.behind_m = p.getDouble("behind_m");
  cfg_.use_prior = p.getString("prior") == "config";
  cfg_.cut_depth_m = p.getDouble("cut_depth_m");
  soil::readPriorParams(p, cfg_.prior_mean, cfg_.prior_var);
}

std::vector<LayerSpec> SoilBayes::layers() const {
  std::vector<LayerSpec> out;
  for (int k = 0; k < SoilEstimateRecord::kCount; ++k) {
    const soil::SoilParamInfo& info = soil::kSoilParams[k];
    out.push_back({info.layer, LayerAccess::Create, info.unit, std::numeric_limits<float>::quiet_NaN(),
                   std::string(kDocs[k]) + "; NaN = no estimate reached the cell"});
    out.push_back({std::string(info.layer) + "_var", LayerAccess::Create, squared(info.unit),
                   std::numeric_limits<float>::quiet_NaN(),
                   std::string("posterior variance of ") + info.layer + "; NaN = no estimate reached the cell"});
  }
  out.push_back({"soil_n", LayerAccess::Create, "count", 0.0f, "soil estimates fused into the cell"});
  out.push_back({"soil_z", LayerAccess::Create, "m", std::numeric_limits<float>::quiet_NaN(),
                 "surface height the cell's soil estimate was fused or re-anchored at (a deeper cut inflates "
                 "the variances); NaN = no estimate"});
  out.push_back({"elevation", LayerAccess::Read, "", std::numeric_limits<float>::quiet_NaN(), ""});
  return out;
}

// soil_pinn publishes on Observation and BladePose events (and at finish); blade_sweep on
// BladePose and Pose.
EventMask SoilBayes::events() const {
  return EventKind::Observation | EventKind::BladePose | EventKind::Pose;
}

void SoilBayes::start(ProcessContext& ctx) {
  LayeredMap& map = ctx.map();
  for (std::size_t k = 0; k < mean_.size(); ++k) {
    mean_[k] = map.layerId(soil::kSoilParams[k].layer);
    var_[k] = map.layerId(std::string(soil::kSoilParams[k].layer) + "_var");
  }
  n_ = map.layerId("soil_n");
  z_ = map.layerId("soil_z");
  elevation_ = map.layerId("elevation");
  loose_ = map.hasLayer("loose") ? map.layerId("loose") : LayerId(-1);
  // Records published before this stage existed are not ours.
  const Record* e = ctx.records().latest(SoilEstimateRecord::kType);
  last_estimate_ = e ? e->sequence : 0;
  const Record* s = ctx.records().latest(SweepRecord::kType);
  last_sweep_ = s ? s->sequence : 0;
}

void SoilBayes::process(ProcessContext& ctx, const Event&) { collect(ctx); }

void SoilBayes::finish(ProcessContext& ctx) { collect(ctx); }

void SoilBayes::collect(ProcessContext& ctx) {
  // Cuts first: an estimate published in this event describes the surface after its sweep.
  const RecordBus::Since sweeps = ctx.records().since(SweepRecord::kType, last_sweep_);
  if (sweeps.missed > 0) ctx.countDrop("sweep_missed", sweeps.missed);
  for (const Record& r : sweeps.records) {
    last_sweep_ = r.sequence;
    const long n = applyCut(ctx, *std::static_pointer_cast<const SweepRecord>(r.payload));
    ctx.addCounter("cells_cut_inflated", static_cast<double>(n));
  }
  const RecordBus::Since est = ctx.records().since(SoilEstimateRecord::kType, last_estimate_);
  if (est.missed > 0) ctx.countDrop("estimate_missed", est.missed);
  for (const Record& r : est.records) {
    last_estimate_ = r.sequence;
    const auto& e = *std::static_pointer_cast<const SoilEstimateRecord>(r.payload);
    if (!e.valid) {
      ctx.countDrop("estimate_invalid");
      continue;
    }
    const long cells = fuse(ctx, e);
    if (cells == 0) {
      ctx.countDrop("estimate_outside_map");
      continue;
    }
    ctx.addCounter("estimates_fused", 1);
    ctx.addCounter("cells_fused", static_cast<double>(cells));
  }
}

long SoilBayes::fuse(ProcessContext& ctx, const SoilEstimateRecord& est) {
  LayeredMap& map = ctx.map();
  const Geometry& geo = map.geometry();
  const double x_max = wedgeLength(est.d_m, est.d_res_m, est.alpha_rad, est.beta_rad);
  const double x_lim = std::isfinite(x_max) ? std::max(x_max, cfg_.x_min_m) : cfg_.x_min_m;
  const double x_scale = std::isfinite(x_max) ? x_max : cfg_.x_min_m;
  const double half_w = 0.5 * est.w_m;
  if (!(x_lim > 0.0) || !(half_w > 0.0)) return 0;
  Eigen::Vector2d t = est.t_hat;
  if (!(t.norm() > 1e-9)) return 0;
  t.normalize();
  const Eigen::Vector2d tp(-t.y(), t.x());
  const Eigen::Vector2d c = est.T_map_blade1.translation().head<2>();
  const MapWindow win =
      MapWindow::covering(map, {c - cfg_.behind_m * t + half_w * tp, c - cfg_.behind_m * t - half_w * tp,
                                c + x_lim * t + half_w * tp, c + x_lim * t - half_w * tp});
  if (win.empty()) return 0;
  if (!win.tryAllocate(map, {mean_[0], mean_[1], mean_[2], mean_[3], mean_[4], var_[0], var_[1], var_[2], var_[3],
                             var_[4], n_, z_})) {
    ctx.countDrop("tile_budget");
    return 0;
  }
  constexpr std::size_t K = SoilEstimateRecord::kCount;
  std::array<std::vector<double>, K> M0, V0, M, V;
  std::vector<double> N0, Z0, H;
  for (std::size_t k = 0; k < K; ++k) {
    win.gather(map, mean_[k], M0[k]);
    win.gather(map, var_[k], V0[k]);
    M[k] = M0[k];
    V[k] = V0[k];
  }
  win.gather(map, n_, N0);
  win.gather(map, z_, Z0);
  win.gather(map, elevation_, H);
  if (loose_ >= 0) {  // the bank surface: under the loose soil pushed ahead of the blade
    std::vector<double> L;
    win.gather(map, loose_, L);
    for (std::size_t k = 0; k < H.size(); ++k)
      if (std::isfinite(L[k])) H[k] -= std::max(0.0, L[k]);
  }
  std::vector<double> N = N0, Z = Z0;
  // Which cells are in the wedge, and how far in: decided once per cell, so a cell is fused
  // once whatever the wedge's orientation.
  std::vector<double> x_of(static_cast<std::size_t>(win.size()), kNaN);
  long cells = 0;
  for (int r = 0; r < win.rows(); ++r)
    for (int cc = 0; cc < win.cols(); ++cc) {
      const Eigen::Vector2d p = geo.positionOf(Index(win.i0() + r, win.j0() + cc)) - c;
      const double x = p.dot(t), y = p.dot(tp);
      if (x >= -cfg_.behind_m && x < x_lim && std::abs(y) <= half_w) {
        x_of[static_cast<std::size_t>(win.local(win.i0() + r, win.j0() + cc))] = std::abs(x);
        ++cells;
      }
    }
  if (cells == 0) return 0;
  // Per cell and property: independent of every other cell, so rows may run in any order.
  const SoilBayesConfig& cfg = cfg_;
  ctx.executor().forEach(win.rows(), [&](int r) {
    for (int cc = 0; cc < win.cols(); ++cc) {
      const std::size_t k = static_cast<std::size_t>(r) * static_cast<std::size_t>(win.cols()) + static_cast<std::size_t>(cc);
      const double x = x_of[k];
      if (!std::isfinite(x)) continue;
      const double inflate = std::exp(cfg.c_s * x / x_scale);
      for (std::size_t q = 0; q < K; ++q) {
        Belief prior{M[q][k], V[q][k]};
        if (!(std::isfinite(prior.mean) && std::isfinite(prior.var)) && cfg.use_prior)
          prior = {cfg.prior_mean[q], cfg.prior_var[q]};
        const Belief post = fuseBelief(prior, est.mean[q], est.var_total[q] * inflate);
        M[q][k] = post.mean;
        V[q][k] = post.var;
      }
      N[k] = (std::isfinite(N[k]) ? N[k] : 0.0) + 1.0;
      Z[k] = H[k];
    }
  });
  for (std::size_t k = 0; k < K; ++k) {
    win.scatterChanged(map, mean_[k], M0[k], M[k]);
    win.scatterChanged(map, var_[k], V0[k], V[k]);
  }
  win.scatterChanged(map, n_, N0, N);
  win.scatterChanged(map, z_, Z0, Z);
  return cells;
}

long SoilBayes::applyCut(ProcessContext& ctx, const SweepRecord& sweep) {
  LayeredMap& map = ctx.map();
  const Geometry& geo = map.geometry();
  long inflated = 0;
  for (const SweepMaskCell& m : sweep.mask) {
    if (!m.cut) continue;
    const auto idx = geo.indexAt(m.position);
    if (!idx) continue;
    const float z = map.at(z_, *idx);
    const float l = loose_ >= 0 ? map.at(loose_, *idx) : 0.0f;
    const float h = map.at(elevation_, *idx) - (std::isfinite(l) ? std::max(0.0f, l) : 0.0f);
    if (!std::isfinite(z) || !std::isfinite(h)) continue;
    const double depth = static_cast<double>(z) - static_cast<double>(h);
    if (depth <= cfg_.cut_depth_m) continue;
    const double f = std::exp(depth / cfg_.cut_depth_m);
    for (const LayerId id : var_) {
      const float v = map.at(id, *idx);
      if (std::isfinite(v)) map.set(id, *idx, static_cast<float>(v * f));
    }
    map.set(z_, *idx, h);
    ++inflated;
  }
  return inflated;
}

}  // namespace terramap::plugins
