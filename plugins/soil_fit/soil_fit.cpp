#include "soil_fit.hpp"

#include <terramap/soil/publish_estimate.hpp>

#include <cmath>
#include <limits>

namespace terramap::plugins {

std::vector<soil::FitRow> fitRows(const soil::PinnSample& s) {
  std::vector<soil::FitRow> rows;
  // The horizon is the last P observation rows of the sample's history.
  for (int p = 0; p < s.P; ++p) {
    const float* obs = s.obs.data() + static_cast<std::size_t>(s.T - s.P + p) * soil::kObsFeatures;
    const float* th = s.theta_k.data() + static_cast<std::size_t>(p) * soil::kThetaK;
    const float* f = s.force.data() + static_cast<std::size_t>(p) * 2;
    if (soil::stalledRow(obs) || !(th[soil::kDepth] > 0) || !std::isfinite(f[0]) || !std::isfinite(f[1])) continue;
    soil::FitRow r;
    r.geometry = {th[soil::kAlpha], th[soil::kRho], th[soil::kDepth], th[soil::kWidth], th[soil::kSurcharge]};
    r.descending = obs[soil::kObsFeatures - 1] < 0.0f;  // blade_vz_map_mps
    r.fx_n = f[0];
    r.fz_n = f[1];
    rows.push_back(r);
  }
  return rows;
}

long SweepWindow::add(const Eigen::Vector3d& edge, std::vector<soil::FitRow> rows) {
  entries_.push_back({next_, edge, std::move(rows)});
  return next_++;
}

std::vector<soil::FitRow> SweepWindow::rowsFor(long seq, int* sweeps) const {
  std::vector<soil::FitRow> rows;
  int n = 0;
  const Entry* self = nullptr;
  for (const Entry& e : entries_)
    if (e.seq == seq) self = &e;
  if (self != nullptr) {
    for (const Entry& e : entries_) {
      if (e.seq < seq - back_ || e.seq > seq + ahead_) continue;
      // Only the sweeps near this one: the soil changes across a site, and a pass that turned
      // away belongs to other ground.
      if ((e.edge.head<2>() - self->edge.head<2>()).norm() > reach_m_) continue;
      rows.insert(rows.end(), e.rows.begin(), e.rows.end());
      ++n;
    }
  }
  if (sweeps) *sweeps = n;
  return rows;
}

void SweepWindow::forgetBefore(long oldest_needed) {
  while (!entries_.empty() && entries_.front().seq < oldest_needed - back_) entries_.pop_front();
}

ParamSchema SoilFit::schema() const {
  const soil::PooledFitOptions d;
  return {param::integer("horizon", 10, 1, 1000, "observation rows per sweep (the sample's P)"),
          param::integer("window_sweeps", 10, 1, 1000, "the machine's sweeps fitted together (lookahead included)"),
          param::integer("lookahead_sweeps", 5, 0, 999,
                         "sweeps after each one in its window: its estimate waits for them (0: the last sweeps only)"),
          param::real("window_m", 2.0, 0.0, 1e4, "m", "only sweeps whose blade ended this close to this one's"),
          param::integer("min_rows", 10, 1, 100000, "fewer rows in the window: the estimate is invalid"),
          param::real("edge_thickness_m", d.edge_thickness_m, 0.0, 0.5, "m", "the penetration term's cutting edge"),
          param::real("force_sigma_n", d.force_sigma_n, 1.0, 1e7, "N", "a row's force residual scale (x and z)"),
          param::real("surcharge_gamma_ref_n_m3", 14636.0, 0.0, 1e5, "N/m^3",
                      "the unit weight blade_sweep weighed Q with; the pile is weighed with the fitted gamma (0: Q as mapped)"),
          param::real("prior_sd_fraction", d.prior_sd_fraction, 1e-3, 1e3, "1",
                      "prior standard deviation per property as a share of its range (centred in it)"),
          param::real("gamma_prior_n_m3", d.gamma_prior_n_m3, 0.0, 1e5, "N/m^3",
                      "centre of the unit weight's prior (0: the middle of its range, with prior_sd_fraction)"),
          param::real("gamma_prior_sd_n_m3", d.gamma_prior_sd_n_m3, 1.0, 1e5, "N/m^3",
                      "standard deviation of the unit weight's prior when gamma_prior_n_m3 > 0"),
          param::boolean("interface_bounded_by_soil", d.interface_bounded_by_soil,
                         "fit c_a = a c and delta = b phi with a, b in [0, 1] (adhesion <= cohesion, soil-metal "
                         "friction <= internal friction) instead of c_a and delta free in their ranges")};
}

void SoilFit::configure(const Params& p) {
  horizon_ = static_cast<int>(p.getInt("horizon"));
  window_sweeps_ = static_cast<int>(p.getInt("window_sweeps"));
  lookahead_sweeps_ = static_cast<int>(p.getInt("lookahead_sweeps"));
  if (lookahead_sweeps_ >= window_sweeps_)
    p.report("lookahead_sweeps", "must be less than window_sweeps (" + std::to_string(window_sweeps_) +
                                     "): the window holds the sweep itself too");
  window_m_ = p.getDouble("window_m");
  min_rows_ = static_cast<int>(p.getInt("min_rows"));
  opt_.edge_thickness_m = p.getDouble("edge_thickness_m");
  opt_.force_sigma_n = p.getDouble("force_sigma_n");
  opt_.prior_sd_fraction = p.getDouble("prior_sd_fraction");
  opt_.q_gamma_ref_n_m3 = p.getDouble("surcharge_gamma_ref_n_m3");
  opt_.interface_bounded_by_soil = p.getBool("interface_bounded_by_soil");
  opt_.gamma_prior_n_m3 = p.getDouble("gamma_prior_n_m3");
  opt_.gamma_prior_sd_n_m3 = p.getDouble("gamma_prior_sd_n_m3");
}

void SoilFit::start(ProcessContext& ctx) { pending_.start(ctx); }

void SoilFit::ingestSweep(ProcessContext& ctx, const SweepRecord& sweep) {
  soil::PinnSample sample;
  auto it = pending_.histories().find(sweep.machine_id);
  const soil::SampleSkip why = it == pending_.histories().end() ? soil::SampleSkip::ShortHistory
                                                      : soil::buildSample(it->second, sweep, horizon_, horizon_, sample);
  if (why != soil::SampleSkip::None) {
    ctx.countDrop(std::string("sweep_") + soil::sampleSkipName(why));
    return;
  }
  auto found = machines_.find(sweep.machine_id);
  if (found == machines_.end())
    found = machines_.emplace(sweep.machine_id, MachineState(SweepWindow(window_sweeps_, lookahead_sweeps_, window_m_))).first;
  MachineState& m = found->second;
  Waiting w;
  w.record = soilEstimateRecordFor(sweep);
  w.record.stamp = sample.anchor_stamp;
  w.record.history_T = sample.T;
  w.record.horizon_P = sample.P;
  w.record.members = 1;
  w.record.d_res_m = 0.0;
  w.record.beta_res_rad = 0.0;
  if (!sample.theta_k.empty()) {
    const float* th = sample.theta_k.data() + static_cast<std::size_t>(sample.P - 1) * soil::kThetaK;
    w.last_row.geometry = {th[soil::kAlpha], th[soil::kRho], th[soil::kDepth], th[soil::kWidth], th[soil::kSurcharge]};
    w.last_row.descending = sample.obs[static_cast<std::size_t>(sample.T) * soil::kObsFeatures - 1] < 0.0f;
    const std::size_t lf = static_cast<std::size_t>(sample.P - 1) * 2;
    w.last_row.fx_n = sample.force[lf];
    w.last_row.fz_n = sample.force[lf + 1];
    w.has_last_row = true;
  }
  w.seq = m.window.add(sweep.T_map_blade1.translation(), fitRows(sample));
  m.waiting.push_back(std::move(w));
  publishReady(ctx, m, false);
}

void SoilFit::publishReady(ProcessContext& ctx, MachineState& m, bool flush) {
  while (!m.waiting.empty() && (flush || m.window.complete(m.waiting.front().seq))) {
    publish(ctx, m, m.waiting.front());
    m.waiting.pop_front();
  }
  m.window.forgetBefore(m.waiting.empty() ? m.window.next() : m.waiting.front().seq);
}

void SoilFit::publish(ProcessContext& ctx, MachineState& m, Waiting& w) {
  int sweeps = 0;
  const std::vector<soil::FitRow> rows = m.window.rowsFor(w.seq, &sweeps);
  SoilEstimateRecord& r = w.record;
  if (static_cast<int>(rows.size()) < min_rows_) {
    r.invalid_reason = "too_few_rows";
  } else {
    // The machine's previous fit, or the middle of the ranges (fitPooled's start for NaN).
    soil::SoilParamVector start;
    start.fill(std::numeric_limits<double>::quiet_NaN());
    const soil::PooledFit fit = soil::fitPooled(rows, m.has_last ? m.last : start, opt_);
    ctx.addCounter("fit_iterations", fit.iterations);
    ctx.addCounter("fit_rows", fit.rows);
    m.last = fit.mean;
    m.has_last = true;
    bool finite = true;
    for (int k = 0; k < SoilEstimateRecord::kCount; ++k) {
      r.mean[k] = fit.mean[static_cast<std::size_t>(k)];
      const double var = fit.covariance(k, k) * sweeps;
      r.var_total[k] = r.var_aleatoric[k] = r.var_nullspace[k] = var;
      r.var_epistemic[k] = 0.0;
      finite = finite && std::isfinite(r.mean[k]) && std::isfinite(var);
    }
    const fee::Soil s = soil::toFee(fit.mean);
    if (w.has_last_row) {
      const fee::Geometry& g = w.last_row.geometry;
      r.beta_rad = fee::betaMin(s, g);
      Eigen::Vector2d f;
      soil::FitRow last = w.last_row;
      if (soil::modelForce(s, last, opt_.edge_thickness_m, f, opt_.q_gamma_ref_n_m3)) r.F_pred = {f.x(), f.y()};
      r.F_measured = {w.last_row.fx_n, w.last_row.fz_n};
    }
    r.F_r = {0.0, 0.0};
    r.valid_members = finite && fit.rows > 0 ? 1 : 0;
    if (!finite) r.invalid_reason = "non_finite_output";
    else if (fit.rows == 0) r.invalid_reason = "fee_invalid_majority";
  }
  r.valid = r.invalid_reason.empty();
  soil::publishEstimate(ctx, std::make_shared<const SoilEstimateRecord>(r));
}

void SoilFit::process(ProcessContext& ctx, const Event& event) {
  pending_.process(ctx, event, static_cast<std::size_t>(horizon_) + 64,
                   [&](const SweepRecord& s) { ingestSweep(ctx, s); });
}

void SoilFit::finish(ProcessContext& ctx) {
  pending_.finish(ctx, [&](const SweepRecord& s) { ingestSweep(ctx, s); });
  for (auto& [id, m] : machines_) publishReady(ctx, m, true);
}

}  // namespace terramap::plugins
