#include "soil_fit.hpp"

#include <terramap/soil/publish_estimate.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <iterator>
#include <limits>

namespace terramap::plugins {

soil::FitRow fitRow(const soil::PinnSample& s, int p, double blade_width_m, double gate_speed_sigma_mps) {
  const float* obs = s.obs.data() + static_cast<std::size_t>(s.T - s.P + p) * soil::kObsFeatures;
  const float* th = s.theta_k.data() + static_cast<std::size_t>(p) * soil::kThetaK;
  const float* f = s.force.data() + static_cast<std::size_t>(p) * 2;
  soil::FitRow r;
  r.geometry = {th[soil::kAlpha], th[soil::kRho], th[soil::kDepth], th[soil::kWidth], th[soil::kSurcharge]};
  if (s.profile.size() == static_cast<std::size_t>(s.P) * soil::kProfile) {
    r.area_m2 = s.profile[static_cast<std::size_t>(p) * soil::kProfile + soil::kArea];
    r.depth2_m3 = s.profile[static_cast<std::size_t>(p) * soil::kProfile + soil::kDepth2];
  }
  r.blade_width_m = blade_width_m;
  const double vz = obs[soil::kObsFeatures - 1];  // blade_vz_map_mps
  r.p_descending = gate_speed_sigma_mps > 0 ? 0.5 * std::erfc(vz / (gate_speed_sigma_mps * std::sqrt(2.0)))
                                            : (vz < 0.0 ? 1.0 : 0.0);
  r.fx_n = f[0];
  r.fz_n = f[1];
  return r;
}

std::vector<soil::FitRow> fitRows(const soil::PinnSample& s, double blade_width_m, double gate_speed_sigma_mps) {
  std::vector<soil::FitRow> rows;
  // The horizon is the last P observation rows of the sample's history.
  for (int p = 0; p < s.P; ++p) {
    const float* obs = s.obs.data() + static_cast<std::size_t>(s.T - s.P + p) * soil::kObsFeatures;
    const float* th = s.theta_k.data() + static_cast<std::size_t>(p) * soil::kThetaK;
    const float* f = s.force.data() + static_cast<std::size_t>(p) * 2;
    if (soil::stalledRow(obs) || !(th[soil::kDepth] > 0) || !std::isfinite(f[0]) || !std::isfinite(f[1])) continue;
    rows.push_back(fitRow(s, p, blade_width_m, gate_speed_sigma_mps));
  }
  return rows;
}

long SweepWindow::add(const Eigen::Vector3d& edge, std::vector<soil::FitRow> rows) {
  entries_.push_back({next_, edge, std::move(rows)});
  return next_++;
}

std::vector<soil::FitRow> SweepWindow::rowsIn(long seq, int from, int to, int* sweeps) const {
  std::vector<soil::FitRow> rows;
  int n = 0;
  const Entry* self = nullptr;
  for (const Entry& e : entries_)
    if (e.seq == seq) self = &e;
  if (self != nullptr) {
    for (const Entry& e : entries_) {
      if (e.seq < seq + std::max(from, -back_) || e.seq > seq + std::min(to, ahead_)) continue;
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

WindowChoice fitWindow(const SweepWindow& window, long seq, int window_sweeps, int lookahead_sweeps, double edge_margin,
                       int min_rows, const std::vector<soil::SoilParamVector>& starts, const soil::PooledFitOptions& opt,
                       const Executor* executor, int short_sweeps) {
  // The candidate windows: the centred one, and with edge_margin > 0 the ones ending and
  // starting at this sweep.
  std::vector<std::pair<int, int>> windows{{-(window_sweeps - 1 - lookahead_sweeps), lookahead_sweeps}};
  if (edge_margin > 0) {
    windows.push_back({-(window_sweeps - 1), 0});
    windows.push_back({0, window_sweeps - 1});
    if (short_sweeps > 1 && short_sweeps < window_sweeps) {
      windows.push_back({-(short_sweeps - 1), 0});
      windows.push_back({0, short_sweeps - 1});
    }
  }
  int n_own = 0;
  const std::vector<soil::FitRow> own = edge_margin > 0 ? window.rowsIn(seq, 0, 0, &n_own) : std::vector<soil::FitRow>{};
  std::vector<std::vector<soil::FitRow>> rows(windows.size());
  std::vector<int> sweeps(windows.size(), 0);
  std::vector<char> fitted(windows.size(), 1);
  for (std::size_t k = 0; k < windows.size(); ++k) {
    rows[k] = window.rowsIn(seq, windows[k].first, windows[k].second, &sweeps[k]);
    fitted[k] = static_cast<int>(rows[k].size()) >= min_rows;
    // A short window holds a subset of the long one on its side (the same end, the same reach):
    // as many sweeps means the same rows (at a pass's ends), a fit the long one already makes and
    // that would lose to it on the tie.
    if (k >= 3 && sweeps[k] == sweeps[k - 2]) fitted[k] = 0;
  }
  // Every window from every start is one independent fit: they run in parallel, and the choice
  // below reads them in a fixed order, so the result is the same for any thread count.
  const std::vector<soil::SoilParamVector> all = soil::multiStarts(starts);
  const int n_starts = static_cast<int>(all.size());
  std::vector<soil::PooledFit> fits(windows.size() * all.size());
  const auto fitOne = [&](int i) {
    const std::size_t k = static_cast<std::size_t>(i / n_starts);
    if (fitted[k])
      fits[static_cast<std::size_t>(i)] = soil::fitPooled(rows[k], all[static_cast<std::size_t>(i % n_starts)], opt);
  };
  const int n_fits = static_cast<int>(fits.size());
  if (executor != nullptr) executor->forEach(n_fits, fitOne);
  else
    for (int i = 0; i < n_fits; ++i) fitOne(i);
  WindowChoice out;
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k < windows.size(); ++k) {
    if (!fitted[k]) continue;
    out.fits += n_starts;
    std::vector<soil::PooledFit> of_window(std::make_move_iterator(fits.begin() + static_cast<long>(k * all.size())),
                                           std::make_move_iterator(fits.begin() + static_cast<long>((k + 1) * all.size())));
    soil::PooledFit f = soil::leastCost(of_window);
    // How well the window's soil explains this sweep's own rows: at a soil boundary the window
    // on the sweep's side holds its soil, the centred one a blend (every window is judged on the
    // same rows, so the pile and machine state they share do not favour one). A side window
    // must beat the centred one clearly (edge_margin): inside one soil they differ by noise.
    double score = own.empty() ? f.cost / static_cast<double>(rows[k].size()) : soil::rowsCost(own, f.mean, opt);
    if (k > 0) score /= edge_margin;
    if (score < best) {
      best = score;
      out.fit = std::move(f);
      out.sweeps = sweeps[k];
      out.rows = rows[k].size();
      out.chosen = static_cast<int>(k);
    }
  }
  if (out.chosen >= 0) out.fitted = std::move(rows[static_cast<std::size_t>(out.chosen)]);
  return out;
}

bool phiAtBound(double phi_rad, double var_phi, double sd_k) {
  const auto& range = soil::kSoilParams[soil::kParamPhi];
  const double margin = std::max(0.01 * (range.hi - range.lo), sd_k * std::sqrt(std::max(0.0, var_phi)));
  return phi_rad < range.lo + margin || phi_rad > range.hi - margin;
}

bool phiUninformative(double var_phi, double k) {
  if (!(k > 0)) return false;
  const auto& range = soil::kSoilParams[soil::kParamPhi];
  return std::sqrt(std::max(0.0, var_phi)) > k * (range.hi - range.lo) / std::sqrt(12.0);
}

bool phiEndInsideProfile(const std::vector<soil::FitRow>& rows, const soil::PooledFit& fit, double sd_k,
                         double variance_inflation, const soil::PooledFitOptions& opt) {
  const auto& range = soil::kSoilParams[soil::kParamPhi];
  const double phi = fit.mean[soil::kParamPhi];
  soil::PooledFitOptions held = opt;
  held.fixed_phi_rad = phi - range.lo < range.hi - phi ? range.lo : range.hi;
  const soil::PooledFit wall = soil::fitPooled(rows, fit.mean, held);
  const double rise = soil::rowsCost(rows, wall.mean, opt) - soil::rowsCost(rows, fit.mean, opt);
  return rise <= sd_k * sd_k * fit.residual_scale * (variance_inflation > 0 ? variance_inflation : 1.0);
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
          param::real("force_sigma_rel", d.force_sigma_rel, 0.0, 10.0, "1",
                      "... plus this share of the measured force component (in quadrature)"),
          param::real("surcharge_gamma_ref_n_m3", 14636.0, 0.0, 1e5, "N/m^3",
                      "the unit weight blade_sweep weighed Q with; the pile is weighed with the fitted gamma (0: Q as mapped)"),
          param::real("prior_sd_fraction", d.prior_sd_fraction, 1e-3, 1e3, "1",
                      "prior standard deviation per property as a share of its range (centred in it)"),
          param::real("gamma_prior_n_m3", d.gamma_prior_n_m3, 0.0, 1e5, "N/m^3",
                      "centre of the unit weight's prior (0: the middle of its range, with prior_sd_fraction)"),
          param::real("gamma_prior_sd_n_m3", d.gamma_prior_sd_n_m3, 1.0, 1e5, "N/m^3",
                      "standard deviation of the unit weight's prior when gamma_prior_n_m3 > 0"),
          param::boolean("edge_preserving", true,
                         "fit each sweep with the window before it, the centred one and the one after it and keep the "
                         "best-fitting (the estimate waits window_sweeps - 1 sweeps)"),
          param::real("variance_inflation", 1.5, 0.0, 1e6, "1",
                      "factor on the fit's variance before soil_bayes fuses it as independent (a cell takes 1.4-2 "
                      "estimates of overlapping windows; 0: the sweeps in the window)"),
          param::boolean("phi_bound_invalid", true,
                         "an estimate whose phi sits within 1 % of an end of its range is not fused (phi_at_bound)"),
          param::real("phi_bound_sd", 1.0, 0.0, 10.0, "1",
                      "phi_bound_invalid: phi within this many of its standard deviations of an end of its range is at "
                      "the bound too (at least 1 % of the range)"),
          param::real("phi_uninformative_sd", 1.0, 0.0, 10.0, "1",
                      "an estimate whose published phi standard deviation exceeds this many times that of a uniform "
                      "belief over phi's range (its width / sqrt 12) tells less than the range and is not fused "
                      "(phi_uninformative); 0 = off"),
          param::boolean("phi_bound_profile", false,
                         "phi_bound_sd: an estimate near the end by its Gaussian is at the bound only if the rows' "
                         "cost with phi held at the end rises by less than that many sigma (profile likelihood)"),
          param::integer("short_window_sweeps", 5, 0, 1000,
                         "edge_preserving: also the windows of this many sweeps ending and starting at the sweep "
                         "(strips shorter than window_sweeps; 0 or >= window_sweeps: none)"),
          param::real("edge_margin", 0.7, 0.01, 1.0, "1",
                      "edge_preserving: a side window replaces the centred one only if its cost per row is below this "
                      "share of the centred one's"),
          param::boolean("cross_section", d.cross_section,
                         "the FEE of the slices across the blade (one wedge holding the cut's sum of d and d^2) and the "
                         "penetration over the cutting width, not one wedge at the mean depth over the extent"),
          param::boolean("surcharge_share", d.surcharge_share,
                         "only the pile ahead of the cutting width loads the wedge; the rest is pushed along the ground"),
          param::real("pile_friction", d.pile_friction, 0.0, 5.0, "1",
                      "surcharge_share: horizontal force per newton of pile pushed without cutting (tan 33 deg)"),
          param::boolean("gate_mixture", d.gate_mixture,
                         "whether the edge descended is a latent switch per row, decided by the force with the observed "
                         "vertical speed as its prior (false: the sign of the observed speed)"),
          param::real("gate_speed_sigma_mps", 0.05, 0.0, 10.0, "m/s",
                      "the observed edge vertical speed's uncertainty for the gate's prior (0: its sign)"),
          param::boolean("truncated_covariance", d.truncated_covariance,
                         "a property the fit leaves on an end of its range (c = 0) publishes the second moment of "
                         "the Gaussian posterior truncated there, and the others only what that end leaves free "
                         "(false: the untruncated Gauss-Newton covariance)"),
          param::real("cohesionless_prior_mass", d.cohesionless_prior_mass, 0.0, 0.999, "1",
                      "truncated_covariance: the prior's mass on c exactly 0 (a cohesionless soil); a fit on c's "
                      "zero end keeps that share of its posterior at c = 0, where phi has only its conditional "
                      "spread (0: the truncated Gaussian alone)"),
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
  opt_.force_sigma_rel = p.getDouble("force_sigma_rel");
  opt_.prior_sd_fraction = p.getDouble("prior_sd_fraction");
  opt_.q_gamma_ref_n_m3 = p.getDouble("surcharge_gamma_ref_n_m3");
  opt_.interface_bounded_by_soil = p.getBool("interface_bounded_by_soil");
  opt_.gamma_prior_n_m3 = p.getDouble("gamma_prior_n_m3");
  opt_.gamma_prior_sd_n_m3 = p.getDouble("gamma_prior_sd_n_m3");
  opt_.cross_section = p.getBool("cross_section");
  opt_.surcharge_share = p.getBool("surcharge_share");
  opt_.pile_friction = p.getDouble("pile_friction");
  opt_.gate_mixture = p.getBool("gate_mixture");
  opt_.truncated_covariance = p.getBool("truncated_covariance");
  opt_.cohesionless_prior_mass = p.getDouble("cohesionless_prior_mass");
  gate_speed_sigma_mps_ = p.getDouble("gate_speed_sigma_mps");
  edge_preserving_ = p.getBool("edge_preserving");
  edge_margin_ = p.getDouble("edge_margin");
  phi_bound_invalid_ = p.getBool("phi_bound_invalid");
  phi_bound_sd_ = p.getDouble("phi_bound_sd");
  phi_bound_profile_ = p.getBool("phi_bound_profile");
  phi_uninformative_sd_ = p.getDouble("phi_uninformative_sd");
  short_window_sweeps_ = static_cast<int>(p.getInt("short_window_sweeps"));
  variance_inflation_ = p.getDouble("variance_inflation");
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
    found = machines_.emplace(sweep.machine_id,
                              MachineState(edge_preserving_ ? SweepWindow::keeping(window_sweeps_ - 1, window_sweeps_ - 1, window_m_)
                                                            : SweepWindow(window_sweeps_, lookahead_sweeps_, window_m_)))
                .first;
  MachineState& m = found->second;
  Waiting w;
  w.record = soilEstimateRecordFor(sweep);
  w.record.stamp = sample.anchor_stamp;
  w.record.history_T = sample.T;
  w.record.horizon_P = sample.P;
  w.record.members = 1;
  w.record.d_res_m = 0.0;
  w.record.beta_res_rad = 0.0;
  std::vector<soil::FitRow> rows = fitRows(sample, sweep.geometry.width_m, gate_speed_sigma_mps_);
  if (!sample.theta_k.empty()) {
    // The sweep's last row as it is, for β* and the predicted force (a stalled or uncut last
    // row is no fit row but still the geometry the estimate is published for).
    w.last_row = fitRow(sample, sample.P - 1, sweep.geometry.width_m, gate_speed_sigma_mps_);
    w.has_last_row = true;
  }
  w.seq = m.window.add(sweep.T_map_blade1.translation(), std::move(rows));
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
  // The machine's previous fit, or the middle of the ranges (fitPooled's start for NaN).
  soil::SoilParamVector start;
  start.fill(std::numeric_limits<double>::quiet_NaN());
  std::vector<soil::SoilParamVector> starts{start};
  if (m.has_last) starts.push_back(m.last);
  const WindowChoice fit = fitWindow(m.window, w.seq, window_sweeps_, lookahead_sweeps_, edge_preserving_ ? edge_margin_ : 0.0,
                                     min_rows_, starts, opt_, &ctx.executor(), short_window_sweeps_);
  const int sweeps = fit.sweeps;
  const std::size_t n_rows = fit.rows;
  static constexpr const char* kWindowCounter[] = {"window_centred", "window_before", "window_after",
                                                   "window_before_short", "window_after_short"};
  if (edge_preserving_ && n_rows > 0) ctx.addCounter(kWindowCounter[fit.chosen], 1);
  SoilEstimateRecord& r = w.record;
  if (n_rows == 0) {
    r.invalid_reason = "too_few_rows";
  } else {
    ctx.addCounter("fit_iterations", fit.fit.iterations);
    ctx.addCounter("fit_rows", fit.fit.rows);
    if (fit.fit.truncated_at_c_zero) ctx.addCounter("fits_truncated_at_c_zero", 1);
    m.last = fit.fit.mean;
    m.has_last = true;
    bool finite = true;
    // φ at an end of its range: the fit ran along the c-φ valley into the box's wall (a window
    // the soil does not explain, most often across a soil boundary), and its curvature there
    // says nothing of how far the other side of the valley lies: not a measurement.
    const double phi = fit.fit.mean[soil::kParamPhi];
    bool bounded_phi = phiAtBound(phi, fit.fit.covariance(soil::kParamPhi, soil::kParamPhi), phi_bound_sd_);
    // Near the end by the Gaussian only: the profile decides (a soil whose φ lies near the end,
    // as a dense gravel's 43-45 deg, keeps its estimate where the rows rule the end out).
    if (bounded_phi && phi_bound_profile_ && !phiAtBound(phi, 0.0, 0.0))
      bounded_phi = phiEndInsideProfile(fit.fitted, fit.fit, phi_bound_sd_, variance_inflation_, opt_);
    if (bounded_phi) ctx.addCounter("estimates_at_phi_bound", 1);
    for (int k = 0; k < SoilEstimateRecord::kCount; ++k) {
      r.mean[k] = fit.fit.mean[static_cast<std::size_t>(k)];
      const double var = fit.fit.covariance(k, k) * (variance_inflation_ > 0 ? variance_inflation_ : sweeps);
      r.var_total[k] = r.var_aleatoric[k] = r.var_nullspace[k] = var;
      r.var_epistemic[k] = 0.0;
      finite = finite && std::isfinite(r.mean[k]) && std::isfinite(var);
    }
    const fee::Soil s = soil::toFee(fit.fit.mean);
    if (w.has_last_row) {
      const fee::Geometry& g = w.last_row.geometry;
      r.beta_rad = fee::betaMin(s, g);
      Eigen::Vector2d f;
      soil::FitRow last = w.last_row;
      if (soil::modelForce(s, last, opt_, f)) r.F_pred = {f.x(), f.y()};
      r.F_measured = {w.last_row.fx_n, w.last_row.fz_n};
    }
    r.F_r = {0.0, 0.0};
    r.valid_members = finite && fit.fit.rows > 0 ? 1 : 0;
    // As wide as the range or wider: a cell taking it would read its mean as a measurement.
    const bool uninformative = phiUninformative(r.var_total[SoilEstimateRecord::kPhi], phi_uninformative_sd_);
    if (uninformative) ctx.addCounter("estimates_phi_uninformative", 1);
    if (!finite) r.invalid_reason = "non_finite_output";
    else if (bounded_phi && phi_bound_invalid_) r.invalid_reason = "phi_at_bound";
    else if (uninformative) r.invalid_reason = "phi_uninformative";
    else if (fit.fit.rows == 0) r.invalid_reason = "fee_invalid_majority";
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
