#include "evaluation.hpp"

#include <terramap/eval/statistics.hpp>
#include <terramap/soil/fee.hpp>
#include <terramap/soil/pinn_sample.hpp>
#include <terramap/soil/soil_table.hpp>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>

namespace terramap::pinn {
namespace {

constexpr const char* kName[kSoilCount] = {"c", "phi", "ca", "delta", "gamma"};

// Σ‖F̂ − F_q‖ and its parts along x and z, for one force model (ForceGap).
struct GapSum {
  double e = 0, ex = 0, ez = 0;
  void add(const Eigen::Vector2d& pred, const Eigen::Vector2d& q) {
    e += (pred - q).norm();
    ex += std::abs(pred.x() - q.x());
    ez += std::abs(pred.y() - q.y());
  }
  ForceGap finish(double norm) const {
    if (!(norm > 0)) return {};
    return {100.0 * e / norm, 100.0 * ex / norm, 100.0 * ez / norm};
  }
};

// Index of blade_vz_map_mps in soil::obsFeatureNames(): the observed edge vertical speed.
constexpr int kObsBladeVzMap = soil::kObsFeatures - 1;

// The physics layer's force with a known soil on one geometry, term by term (ForceDecomposition's
// ladder): [0] paper F at β*, [1] + penetration when `descending`, [2] + adhesion on the face,
// [3] + inertia at edge speed v. All zero where the FEE is invalid (as the layer: only F^r there).
// `penetration_if_down` is the term a descending edge meets, so another gate's [1] is
// F[0] + that term where it says descending.
struct Ladder {
  std::array<Eigen::Vector2d, 4> F;
  Eigen::Vector2d fee_total = Eigen::Vector2d::Zero(), penetration = Eigen::Vector2d::Zero(),
                  inertia = Eigen::Vector2d::Zero(), penetration_if_down = Eigen::Vector2d::Zero();
  Eigen::Vector2d withGate(bool descending) const { return descending ? F[0] + penetration_if_down : F[0]; }
};
Ladder physicsLadder(const fee::Soil& s, const fee::Geometry& g, bool descending, double v, double edge_m) {
  Ladder l;
  l.F.fill(Eigen::Vector2d::Zero());
  if (!(g.d_m > 0) || !std::isfinite(g.d_m)) return l;
  const fee::Result r = fee::evaluateAtBetaMin(s, g);
  if (!r.valid()) return l;
  l.fee_total = r.F_total_N;
  l.penetration_if_down = {0.0, -fee::penetrationForce(s, g.d_m, g.w_m, edge_m)};
  if (descending) l.penetration = l.penetration_if_down;
  // The soil entering the wedge is brought to the blade's speed: mass flux γ/g d w v times v
  // (the blade pushes it forward).
  if (v > 0) l.inertia = {s.gamma_n_m3 / 9.80665 * g.d_m * g.w_m * v * v, 0.0};
  l.F[0] = r.F_N;
  l.F[1] = r.F_N + l.penetration;
  l.F[2] = r.F_total_N + l.penetration;
  l.F[3] = l.F[2] + l.inertia;
  return l;
}

struct DecompAccum {
  double norm = 0, norm_moving = 0;
  long rows = 0, moving = 0;
  GapSum a, b, c, a_moving, b_moving, c_moving, a_true_gate, b_true_gate;
  std::array<GapSum, 4> ladder_truth, ladder_mapped;
  GapSum wedge, penetration, inertia;
  double n_fee = 0, n_inertia = 0, n_penetration = 0;
  long observed_down = 0, observed_down_true = 0, true_down = 0;
  std::vector<double> ratio_d, ratio_w, ratio_q;
};

// Truth columns of the dataset are [c, phi, ca, delta, gamma] (eval::SoilDataset), SoilCol order.
struct Accum {
  SplitMetrics m;
  // Σ‖F̂ − F‖ of the estimator and of each baseline, Σ‖F‖ over the same steps.
  double ferr = 0, fnorm = 0, ferr_truth = 0, ferr_tg = 0, ferr_sim = 0, fnorm_tg = 0;
  double ferr_truth_min = 0, ferr_moving = 0, fnorm_moving = 0;
  double ferr_x = 0, ferr_z = 0;  // Σ|F̂x − Fx|, Σ|F̂z − Fz|
  // Rows with the noise-free force F_q: Σ‖F_q − F‖ over Σ‖F‖ (the floor), Σ‖F̂ − F_q‖ over Σ‖F_q‖.
  double qerr_floor = 0, qnorm_meas = 0, qerr_est = 0, qnorm = 0;
  long qrows = 0;
  long rows = 0, stalled_rows = 0;
  std::vector<std::array<double, 2>> forces;  // for the constant-force baseline
  std::vector<double> q_ratio;                // mapped Q / simulator's q, per sample
  DecompAccum dec;
  long input_measured = 0, input_beyond = 0;  // samples with an input distance, and beyond q
  double input_share = 0;                     // Σ share of the prior variance added
  // Per property, truth and estimate of every valid sample (the skill statistics).
  std::array<std::vector<double>, kSoilCount> truth, estimate;
};

// One sample's view of the dataset arrays (row r, the model's last P horizon steps).
struct SampleView {
  const float* theta;   // [P_model][6], raw
  const float* force;   // [P_model][2]
  const bool* moving;   // [P_model]
  fee::Soil soil;       // truth
  const float* truth_geometry;  // alpha, rho, d, w, q (NaN when unknown)
  const float* force_quiet;     // [P_model][2], the force without its noise (NaN rows or null when unknown)
  const float* obs;             // [P_model][kObsFeatures], the observation rows of the horizon
  const float* geometry_rows;   // [P_model][5] simulator's alpha, rho, d, w, q per row (null when unknown)
  const float* force_parts;     // [P_model][3][2] (null when unknown)
  const float* edge_vz;         // [P_model] (null when unknown)
  bool has_truth_geometry() const {
    return std::isfinite(truth_geometry[0]) && std::isfinite(truth_geometry[2]) && truth_geometry[2] > 0;
  }
};

double missBy(const Eigen::Vector2d& pred, double fx, double fz, bool valid) {
  return valid ? std::hypot(pred.x() - fx, pred.y() - fz) : std::hypot(fx, fz);
}

// One horizon row's contribution to the decomposition (rows with the noise-free force and the
// simulator's parts only).
void addDecompositionRow(DecompAccum& d, const SampleView& v, const SoilEstimate& e, int p, double edge_m) {
  if (!v.force_quiet || !v.force_parts || !v.geometry_rows) return;
  const Eigen::Vector2d q(v.force_quiet[p * 2], v.force_quiet[p * 2 + 1]);
  const float* parts = v.force_parts + p * 6;
  if (!q.allFinite() || !std::all_of(parts, parts + 6, [](float x) { return std::isfinite(x); })) return;
  const Eigen::Vector2d fee_part(parts[0], parts[1]), inertia_part(parts[2], parts[3]), pen_part(parts[4], parts[5]);
  const float* g = v.theta + p * 6;
  const fee::Geometry mapped{g[1], g[0], g[3], g[2], g[4]};
  const double speed = g[5];
  const float* tg = v.geometry_rows + p * 5;
  const fee::Geometry truth_geo{tg[0], tg[1], tg[2], tg[3], tg[4]};  // NaN depth: not cutting
  const bool down = v.obs[p * soil::kObsFeatures + kObsBladeVzMap] < 0.0f;
  const bool true_down = v.edge_vz && v.edge_vz[p] < 0.0f;
  const Ladder lt = physicsLadder(v.soil, truth_geo, down, speed, edge_m);
  const Ladder lm = physicsLadder(v.soil, mapped, down, speed, edge_m);
  const Eigen::Vector2d est(e.F[static_cast<std::size_t>(p)][0], e.F[static_cast<std::size_t>(p)][1]);
  const double norm = q.norm();
  d.norm += norm;
  ++d.rows;
  d.a.add(lt.F[1], q);
  d.b.add(lm.F[1], q);
  d.c.add(est, q);
  if (v.edge_vz && std::isfinite(v.edge_vz[p])) {
    d.a_true_gate.add(lt.withGate(true_down), q);
    d.b_true_gate.add(lm.withGate(true_down), q);
  }
  if (v.moving[p]) {
    d.norm_moving += norm;
    ++d.moving;
    d.a_moving.add(lt.F[1], q);
    d.b_moving.add(lm.F[1], q);
    d.c_moving.add(est, q);
  }
  for (int k = 0; k < 4; ++k) {
    d.ladder_truth[static_cast<std::size_t>(k)].add(lt.F[static_cast<std::size_t>(k)], q);
    d.ladder_mapped[static_cast<std::size_t>(k)].add(lm.F[static_cast<std::size_t>(k)], q);
  }
  d.wedge.add(lt.fee_total, fee_part);
  d.penetration.add(lt.penetration, pen_part);
  d.inertia.add(lt.inertia, inertia_part);
  d.n_fee += fee_part.norm();
  d.n_inertia += inertia_part.norm();
  d.n_penetration += pen_part.norm();
  d.observed_down += down;
  d.observed_down_true += down && true_down;
  d.true_down += true_down;
  if (truth_geo.d_m > 0 && mapped.d_m > 0) d.ratio_d.push_back(mapped.d_m / truth_geo.d_m);
  if (truth_geo.w_m > 0 && mapped.w_m > 0) d.ratio_w.push_back(mapped.w_m / truth_geo.w_m);
  if (truth_geo.q_n > 0 && std::isfinite(mapped.q_n)) d.ratio_q.push_back(mapped.q_n / truth_geo.q_n);
}

// The estimator's force error and the physics baselines over the horizon.
void addForceErrors(Accum& a, const SampleView& v, const SoilEstimate& e, int P, double edge_m) {
  for (int p = 0; p < P; ++p) addDecompositionRow(a.dec, v, e, p, edge_m);
  const bool tg_known = v.has_truth_geometry();
  const float* tg = v.truth_geometry;
  const fee::Geometry truth_geo{tg[0], tg[1], tg[2], tg[3], tg[4]};
  // Constant over the horizon: the simulator's geometry is logged once per sample.
  const fee::Result paper_tg = tg_known ? fee::evaluateAtBetaNominal(v.soil, truth_geo) : fee::Result{};
  const fee::Result sim_tg = tg_known ? fee::evaluateAtBetaMin(v.soil, truth_geo) : fee::Result{};
  for (int p = 0; p < P; ++p) {
    const double fx = v.force[p * 2], fz = v.force[p * 2 + 1];
    const double dx = e.F[static_cast<std::size_t>(p)][0] - fx, dz = e.F[static_cast<std::size_t>(p)][1] - fz;
    const double miss = std::hypot(dx, dz), norm = std::hypot(fx, fz);
    a.ferr += miss;
    a.ferr_x += std::abs(dx);
    a.ferr_z += std::abs(dz);
    a.fnorm += norm;
    a.forces.push_back({fx, fz});
    ++a.rows;
    const double qx = v.force_quiet ? v.force_quiet[p * 2] : NAN, qz = v.force_quiet ? v.force_quiet[p * 2 + 1] : NAN;
    if (std::isfinite(qx) && std::isfinite(qz)) {
      a.qerr_floor += std::hypot(qx - fx, qz - fz);
      a.qnorm_meas += norm;
      a.qerr_est += std::hypot(e.F[static_cast<std::size_t>(p)][0] - qx, e.F[static_cast<std::size_t>(p)][1] - qz);
      a.qnorm += std::hypot(qx, qz);
      ++a.qrows;
    }
    if (v.moving[p]) {
      a.ferr_moving += miss;
      a.fnorm_moving += norm;
    } else {
      ++a.stalled_rows;
    }
    const float* g = v.theta + p * 6;
    const fee::Geometry mapped{g[1], g[0], g[3], g[2], g[4]};
    const fee::Result fr = fee::evaluateAtBetaNominal(v.soil, mapped);
    a.ferr_truth += missBy(fr.F_N, fx, fz, fr.valid());
    const fee::Result fm = fee::evaluateAtBetaMin(v.soil, mapped);
    a.ferr_truth_min += missBy(fm.F_N, fx, fz, fm.valid());
    if (tg_known) {
      a.ferr_tg += missBy(paper_tg.F_N, fx, fz, paper_tg.valid());
      a.ferr_sim += missBy(sim_tg.F_total_N, fx, fz, sim_tg.valid());
      a.fnorm_tg += norm;
    }
  }
  if (tg_known) {
    ++a.m.truth_geometry_samples;
    if (tg[4] > 0) a.q_ratio.push_back(v.theta[(P - 1) * 6 + 4] / tg[4]);
  }
}

void addSoilErrors(Accum& a, Fig11Bin* bin, const fee::Soil& truth_soil, const SoilEstimate& e) {
  if (std::isfinite(e.input_d2)) {
    ++a.input_measured;
    a.input_beyond += e.input_share > 0;
    a.input_share += e.input_share;
  }
  const double truth[kSoilCount] = {truth_soil.c_pa, truth_soil.phi_rad, truth_soil.ca_pa, truth_soil.delta_rad,
                                    truth_soil.gamma_n_m3};
  for (int k = 0; k < kSoilCount; ++k) {
    a.truth[k].push_back(truth[k]);
    a.estimate[k].push_back(e.mean[k]);
    const double err = e.mean[k] - truth[k];
    a.m.mae[k] += std::abs(err);
    a.m.bias[k] += err;
    a.m.coverage_aleatoric[k] += std::abs(err) <= std::sqrt(e.var_aleatoric[k]);
    a.m.coverage_nullspace[k] += std::abs(err) <= std::sqrt(e.var_nullspace[k]);
    a.m.coverage_total[k] += std::abs(err) <= std::sqrt(e.var_total[k]);
    a.m.mean_var_aleatoric[k] += e.var_aleatoric[k];
    a.m.mean_var_epistemic[k] += e.var_epistemic[k];
    a.m.mean_var_total[k] += e.var_total[k];
    if (bin) {
      bin->truth[k] += truth[k];
      bin->mean[k] += e.mean[k];
      bin->sigma[k] += e.var_total[k];
    }
  }
}

/// Median of v (NaN when empty), as every evaluation reports percentiles (eval/statistics.hpp).
double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return eval::percentileSorted(v, 50.0);
}

/// `constant`: per property, the constant estimate the skill is measured against.
SplitMetrics finishSplit(int split, Accum& a, const std::array<double, kSoilCount>& constant) {
  SplitMetrics m = a.m;
  for (int k = 0; k < kSoilCount; ++k) {
    const PropertySkill s = propertySkill(a.truth[k], a.estimate[k], constant[k]);
    m.mae_constant[k] = s.mae_constant;
    m.correlation[k] = s.correlation;
  }
  m.split = eval::datasetSplitName(static_cast<eval::DatasetSplit>(split));
  auto pct = [](double err, double norm) { return norm > 0 ? 100.0 * err / norm : NAN; };
  m.force_error_pct = pct(a.ferr, a.fnorm);
  m.force_error_truth_fee_pct = pct(a.ferr_truth, a.fnorm);
  m.force_error_truth_fee_min_pct = pct(a.ferr_truth_min, a.fnorm);
  m.force_error_moving_pct = pct(a.ferr_moving, a.fnorm_moving);
  m.force_error_x_pct = pct(a.ferr_x, a.fnorm);
  m.force_error_z_pct = pct(a.ferr_z, a.fnorm);
  m.stalled_row_fraction = a.rows > 0 ? static_cast<double>(a.stalled_rows) / static_cast<double>(a.rows) : NAN;
  m.force_error_truth_geometry_pct = pct(a.ferr_tg, a.fnorm_tg);
  m.force_error_simulator_model_pct = pct(a.ferr_sim, a.fnorm_tg);
  m.force_error_noise_floor_pct = pct(a.qerr_floor, a.qnorm_meas);
  m.force_error_noise_free_pct = pct(a.qerr_est, a.qnorm);
  m.noise_free_rows = a.qrows;
  double mx = 0, mz = 0, em = 0;
  for (const auto& fv : a.forces) {
    mx += fv[0];
    mz += fv[1];
  }
  mx /= static_cast<double>(std::max<std::size_t>(1, a.forces.size()));
  mz /= static_cast<double>(std::max<std::size_t>(1, a.forces.size()));
  for (const auto& fv : a.forces) em += std::hypot(fv[0] - mx, fv[1] - mz);
  m.force_error_mean_pct = pct(em, a.fnorm);
  m.surcharge_ratio_median = median(a.q_ratio);
  const DecompAccum& d = a.dec;
  ForceDecomposition& fd = m.decomposition;
  fd.rows = d.rows;
  fd.moving_rows = d.moving;
  fd.truth_geometry = d.a.finish(d.norm);
  fd.mapped_geometry = d.b.finish(d.norm);
  fd.estimator = d.c.finish(d.norm);
  fd.truth_geometry_moving = d.a_moving.finish(d.norm_moving);
  fd.mapped_geometry_moving = d.b_moving.finish(d.norm_moving);
  fd.estimator_moving = d.c_moving.finish(d.norm_moving);
  fd.truth_geometry_true_gate = d.a_true_gate.finish(d.norm);
  fd.mapped_geometry_true_gate = d.b_true_gate.finish(d.norm);
  for (std::size_t k = 0; k < 4; ++k) {
    fd.ladder_truth[k] = d.ladder_truth[k].finish(d.norm);
    fd.ladder_mapped[k] = d.ladder_mapped[k].finish(d.norm);
  }
  fd.wedge_vs_slices = d.wedge.finish(d.norm);
  fd.penetration_term = d.penetration.finish(d.norm);
  fd.inertia_term = d.inertia.finish(d.norm);
  if (d.norm > 0) {
    fd.share_fee = d.n_fee / d.norm;
    fd.share_inertia = d.n_inertia / d.norm;
    fd.share_penetration = d.n_penetration / d.norm;
  }
  fd.observed_descending = d.observed_down;
  fd.observed_descending_true = d.observed_down_true;
  fd.true_descending = d.true_down;
  m.depth_ratio_row_median = median(d.ratio_d);
  m.width_ratio_row_median = median(d.ratio_w);
  m.surcharge_ratio_row_median = median(d.ratio_q);
  if (a.input_measured > 0) {
    m.input_beyond_fraction = static_cast<double>(a.input_beyond) / static_cast<double>(a.input_measured);
    m.input_share_mean = a.input_share / static_cast<double>(a.input_measured);
  }
  const double v = static_cast<double>(std::max<long>(1, m.valid));
  for (int k = 0; k < kSoilCount; ++k)
    for (auto* x : {&m.mae, &m.bias, &m.coverage_aleatoric, &m.coverage_nullspace, &m.coverage_total,
                    &m.mean_var_aleatoric, &m.mean_var_epistemic, &m.mean_var_total})
      (*x)[k] /= v;
  return m;
}

}  // namespace

PropertySkill propertySkill(const std::vector<double>& truth, const std::vector<double>& estimate, double constant) {
  PropertySkill s;
  const std::size_t n = std::min(truth.size(), estimate.size());
  if (n == 0) return s;
  double mt = 0, me = 0, err = 0;
  for (std::size_t i = 0; i < n; ++i) {
    mt += truth[i];
    me += estimate[i];
    err += std::abs(constant - truth[i]);
  }
  s.mae_constant = err / static_cast<double>(n);
  mt /= static_cast<double>(n);
  me /= static_cast<double>(n);
  double stt = 0, see = 0, ste = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double dt = truth[i] - mt, de = estimate[i] - me;
    stt += dt * dt;
    see += de * de;
    ste += dt * de;
  }
  if (stt > 0 && see > 0) s.correlation = ste / std::sqrt(stt * see);
  return s;
}

namespace {
/// Ranks of v (1-based), ties given their mean rank.
std::vector<double> ranks(const std::vector<double>& v) {
  std::vector<std::size_t> order(v.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return v[a] < v[b]; });
  std::vector<double> r(v.size());
  for (std::size_t i = 0; i < order.size();) {
    std::size_t j = i + 1;
    while (j < order.size() && v[order[j]] == v[order[i]]) ++j;
    const double mean_rank = 0.5 * static_cast<double>(i + j - 1) + 1.0;
    for (std::size_t k = i; k < j; ++k) r[order[k]] = mean_rank;
    i = j;
  }
  return r;
}
}  // namespace

double rankCorrelation(const std::vector<double>& a, const std::vector<double>& b) {
  if (a.size() != b.size() || a.size() < 3) return NAN;
  return propertySkill(ranks(a), ranks(b), 0.0).correlation;  // Pearson of the ranks
}

std::vector<Fig11Trend> fig11Trends(const std::vector<Fig11Bin>& bins) {
  std::map<int, std::vector<const Fig11Bin*>> by_family;
  for (const Fig11Bin& b : bins)
    if (b.samples > 0) by_family[b.family].push_back(&b);
  std::vector<Fig11Trend> out;
  for (const auto& [family, rows] : by_family) {
    Fig11Trend t;
    t.family = family;
    t.bins = static_cast<int>(rows.size());
    for (int k = 0; k < kSoilCount; ++k) {
      std::vector<double> truth, mean;
      for (const Fig11Bin* b : rows) {
        truth.push_back(b->truth[k]);
        mean.push_back(b->mean[k]);
      }
      t.rank_correlation[k] = rankCorrelation(truth, mean);
    }
    out.push_back(t);
  }
  return out;
}

SoilEvaluation evaluateEstimator(const SoilEstimator& est, const TrainingData& data) {
  const long n = data.size();
  const int T = static_cast<int>(data.obs_raw.size(1)), P = static_cast<int>(data.theta_k.size(1));
  const int p0 = P - est.P();  // the model's horizon is the end of the stored one
  const long batch = 256;
  std::map<int, Accum> acc;
  std::map<std::pair<int, int>, Fig11Bin> bins;
  const float* obs = data.obs_raw.data_ptr<float>();
  const float* th = data.theta_k.data_ptr<float>();
  const float* f = data.force.data_ptr<float>();
  const float* tr = data.truth.data_ptr<float>();
  const float* tgeo = data.truth_geometry.data_ptr<float>();
  // Tensors built by hand (tests) may have no noise-free force: then no row counts.
  const float* fq = data.force_quiet.defined() ? data.force_quiet.data_ptr<float>() : nullptr;
  const bool* mv = data.moving.data_ptr<bool>();
  // Per-row truth (datasets since the decomposition; tensors built by hand may lack it).
  const float* tgr = data.truth_geometry_rows.defined() ? data.truth_geometry_rows.data_ptr<float>() : nullptr;
  const float* fparts = data.force_parts.defined() ? data.force_parts.data_ptr<float>() : nullptr;
  const float* evz = data.edge_vz.defined() ? data.edge_vz.data_ptr<float>() : nullptr;
  // The decomposition's penetration term uses the model's edge, or the simulator's default one.
  const double edge_m = est.members().front()->config().edge_thickness_m > 0
                            ? est.members().front()->config().edge_thickness_m
                            : 0.025;
  for (long b0 = 0; b0 < n; b0 += batch) {
    const long len = std::min(batch, n - b0);
    const std::vector<SoilEstimate> es = est.estimate(obs + b0 * T * soil::kObsFeatures, th + b0 * P * 6, len, T, P);
    for (long i = 0; i < len; ++i) {
      const long r = b0 + i;
      const std::size_t ru = static_cast<std::size_t>(r);
      const int split = data.split[ru];
      Accum& a = acc[split];
      ++a.m.samples;
      const SoilEstimate& e = es[static_cast<std::size_t>(i)];
      if (!e.valid) continue;
      ++a.m.valid;
      SampleView v{th + (r * P + p0) * 6,
                   f + (r * P + p0) * 2,
                   mv + r * P + p0,
                   {},
                   tgeo + r * 5,
                   fq ? fq + (r * P + p0) * 2 : nullptr,
                   obs + (r * T + (T - est.P())) * soil::kObsFeatures,
                   tgr ? tgr + (r * P + p0) * 5 : nullptr,
                   fparts ? fparts + (r * P + p0) * 6 : nullptr,
                   evz ? evz + r * P + p0 : nullptr};
      v.soil.c_pa = tr[r * 5 + 0];
      v.soil.phi_rad = tr[r * 5 + 1];
      v.soil.ca_pa = tr[r * 5 + 2];
      v.soil.delta_rad = tr[r * 5 + 3];
      v.soil.gamma_n_m3 = tr[r * 5 + 4];
      addForceErrors(a, v, e, est.P(), edge_m);
      Fig11Bin* bin = nullptr;
      if (split == static_cast<int>(eval::DatasetSplit::Test) || split == static_cast<int>(eval::DatasetSplit::HeldOut)) {
        const int fam = data.family[ru];
        const int idb = std::min(9, static_cast<int>(data.relative_density[ru] * 10));
        bin = &bins[{fam, idb}];
        bin->family = fam;
        bin->bin = idb;
        ++bin->samples;
      }
      addSoilErrors(a, bin, v.soil, e);
    }
  }
  SoilEvaluation out;
  // The constant the skill is measured against: what the training soils alone suggest.
  std::array<double, kSoilCount> constant;
  constant.fill(NAN);
  if (auto it = acc.find(static_cast<int>(eval::DatasetSplit::Train)); it != acc.end())
    for (int k = 0; k < kSoilCount; ++k) constant[k] = median(it->second.truth[k]);
  for (auto& [split, a] : acc) out.splits.push_back(finishSplit(split, a, constant));
  for (auto& [key, b] : bins) {
    for (int k = 0; k < kSoilCount; ++k) {
      b.truth[k] /= static_cast<double>(b.samples);
      b.mean[k] /= static_cast<double>(b.samples);
      b.sigma[k] = std::sqrt(b.sigma[k] / static_cast<double>(b.samples));
    }
    out.fig11.push_back(b);
  }
  out.fig11_trend = fig11Trends(out.fig11);
  const SplitMetrics* test = nullptr;
  const SplitMetrics* held = nullptr;
  for (const auto& m : out.splits) {
    if (m.split == "test") test = &m;
    if (m.split == "held_out") held = &m;
  }
  for (int k = 0; k < kSoilCount; ++k)
    out.epistemic_ratio[k] = test && held && test->mean_var_epistemic[k] > 0
                                 ? held->mean_var_epistemic[k] / test->mean_var_epistemic[k]
                                 : NAN;
  return out;
}

namespace {
nlohmann::ordered_json gapJson(const ForceGap& g) {
  auto num = [](double x) { return std::isfinite(x) ? nlohmann::ordered_json(x) : nlohmann::ordered_json(); };
  return {{"pct", num(g.total)}, {"along_x_pct", num(g.x)}, {"along_z_pct", num(g.z)}};
}

constexpr const char* kLadderNames[4] = {"paper_F_beta_min", "plus_penetration_observed_descent",
                                         "plus_face_adhesion_F_total", "plus_inertia"};

nlohmann::ordered_json decompositionJson(const ForceDecomposition& d) {
  auto num = [](double x) { return std::isfinite(x) ? nlohmann::ordered_json(x) : nlohmann::ordered_json(); };
  nlohmann::ordered_json j;
  j["rows"] = d.rows;
  j["moving_rows"] = d.moving_rows;
  j["a_truth_soil_truth_geometry"] = gapJson(d.truth_geometry);
  j["b_truth_soil_mapped_geometry"] = gapJson(d.mapped_geometry);
  j["c_estimator"] = gapJson(d.estimator);
  j["a_with_true_gate"] = gapJson(d.truth_geometry_true_gate);
  j["b_with_true_gate"] = gapJson(d.mapped_geometry_true_gate);
  j["moving"] = {{"a_truth_soil_truth_geometry", gapJson(d.truth_geometry_moving)},
                 {"b_truth_soil_mapped_geometry", gapJson(d.mapped_geometry_moving)},
                 {"c_estimator", gapJson(d.estimator_moving)}};
  for (std::size_t k = 0; k < 4; ++k) {
    j["ladder_truth_geometry"][kLadderNames[k]] = gapJson(d.ladder_truth[k]);
    j["ladder_mapped_geometry"][kLadderNames[k]] = gapJson(d.ladder_mapped[k]);
  }
  j["part_by_part"] = {{"one_wedge_F_total_vs_fee_over_slices", gapJson(d.wedge_vs_slices)},
                       {"penetration_term_vs_simulator", gapJson(d.penetration_term)},
                       {"inertia_term_vs_simulator", gapJson(d.inertia_term)}};
  j["simulator_part_share"] = {{"fee_over_slices", num(d.share_fee)},
                               {"inertia", num(d.share_inertia)},
                               {"penetration", num(d.share_penetration)}};
  j["rows_observed_descending"] = d.observed_descending;
  j["rows_observed_descending_truly"] = d.observed_descending_true;
  j["rows_truly_descending"] = d.true_descending;
  return j;
}
}  // namespace

std::string evaluationJson(const SoilEvaluation& e) {
  nlohmann::ordered_json j;
  for (const auto& m : e.splits) {
    nlohmann::ordered_json s;
    s["samples"] = m.samples;
    s["valid"] = m.valid;
    s["force_error_pct"] = m.force_error_pct;
    s["force_error_moving_rows_pct"] = m.force_error_moving_pct;
    s["force_error_along_x_pct"] = m.force_error_x_pct;
    s["force_error_along_z_pct"] = m.force_error_z_pct;
    s["stalled_row_fraction"] = m.stalled_row_fraction;
    s["force_error_truth_soil_fee_pct"] = m.force_error_truth_fee_pct;
    s["force_error_truth_soil_fee_beta_min_pct"] = m.force_error_truth_fee_min_pct;
    s["force_error_constant_mean_pct"] = m.force_error_mean_pct;
    s["force_error_truth_soil_truth_geometry_pct"] = m.force_error_truth_geometry_pct;
    s["force_error_truth_soil_simulator_model_pct"] = m.force_error_simulator_model_pct;
    s["truth_geometry_samples"] = m.truth_geometry_samples;
    // null for datasets written before the noise-free force was kept
    auto num = [](double x) { return std::isfinite(x) ? nlohmann::ordered_json(x) : nlohmann::ordered_json(); };
    s["force_error_noise_floor_pct"] = num(m.force_error_noise_floor_pct);
    s["force_error_against_noise_free_pct"] = num(m.force_error_noise_free_pct);
    s["noise_free_rows"] = m.noise_free_rows;
    s["mapped_over_simulator_surcharge_median"] = m.surcharge_ratio_median;
    s["mapped_over_simulator_row_median"] = {{"depth", num(m.depth_ratio_row_median)},
                                             {"width", num(m.width_ratio_row_median)},
                                             {"surcharge", num(m.surcharge_ratio_row_median)}};
    s["force_decomposition"] = decompositionJson(m.decomposition);
    if (std::isfinite(m.input_beyond_fraction)) {
      s["input_beyond_training_q99_fraction"] = m.input_beyond_fraction;
      s["input_prior_share_mean"] = m.input_share_mean;
    }
    for (int k = 0; k < kSoilCount; ++k) {
      nlohmann::ordered_json p;
      p["mae"] = m.mae[k];
      p["bias"] = m.bias[k];
      p["mae_constant_train_median"] = std::isfinite(m.mae_constant[k]) ? nlohmann::ordered_json(m.mae_constant[k])
                                                                        : nlohmann::ordered_json();
      p["correlation_with_truth"] = std::isfinite(m.correlation[k]) ? nlohmann::ordered_json(m.correlation[k])
                                                                    : nlohmann::ordered_json();
      p["coverage_1sigma_aleatoric"] = m.coverage_aleatoric[k];
      p["coverage_1sigma_nullspace"] = m.coverage_nullspace[k];
      p["coverage_1sigma_total"] = m.coverage_total[k];
      p["mean_var_aleatoric"] = m.mean_var_aleatoric[k];
      p["mean_var_epistemic"] = m.mean_var_epistemic[k];
      p["mean_var_total"] = m.mean_var_total[k];
      s["properties"][kName[k]] = p;
    }
    j["splits"][m.split] = s;
  }
  // Fig. 11's trend per family (null where the truth or the estimate is flat across the bins).
  for (const Fig11Trend& t : e.fig11_trend) {
    nlohmann::ordered_json f;
    f["bins"] = t.bins;
    for (int k = 0; k < kSoilCount; ++k)
      f["rank_correlation"][kName[k]] = std::isfinite(t.rank_correlation[k]) ? nlohmann::ordered_json(t.rank_correlation[k])
                                                                              : nlohmann::ordered_json();
    j["fig11_trend"][soil::soilFamilyName(static_cast<soil::SoilFamily>(t.family))] = f;
  }
  for (int k = 0; k < kSoilCount; ++k)
    j["epistemic_variance_ratio_held_out_over_test"][kName[k]] =
        std::isfinite(e.epistemic_ratio[k]) ? nlohmann::ordered_json(e.epistemic_ratio[k]) : nlohmann::ordered_json();
  return j.dump(2);
}

namespace {
/// A markdown table after a blank line and `intro`: one row per split, one column per property
/// (its display unit in the header when `units`); `cell(split, property)` formats an entry.
template <class Cell>
void propertyTable(std::ostringstream& os, const SoilEvaluation& e, const char* intro, bool units, Cell cell) {
  os << "\n" << intro << "\n\n| split |";
  for (int k = 0; k < kSoilCount; ++k) {
    os << " " << kName[k];
    if (units) os << " (" << soil::kSoilDisplay[k].unit << ")";
    os << " |";
  }
  os << "\n|---|";
  for (int k = 0; k < kSoilCount; ++k) os << "---|";
  os << "\n";
  for (const auto& m : e.splits) {
    os << "| " << m.split << " |";
    for (int k = 0; k < kSoilCount; ++k) os << " " << cell(m, k) << " |";
    os << "\n";
  }
}
}  // namespace

std::string decompositionMarkdown(const SoilEvaluation& e) {
  std::ostringstream os;
  char buf[512];
  auto cell = [](const ForceGap& g) {
    char c[64];
    std::snprintf(c, sizeof c, "%.1f (%.1f / %.1f)", g.total, g.x, g.z);
    return std::string(c);
  };
  os << "\nWhere the force error lives, against the noise-free force (% of Σ‖F_q‖, along x / z in brackets): "
        "(a) the physics layer (paper F at β* + penetration where the edge is observed descending) with the truth "
        "soil on the simulator's geometry of each row, (b) the same on the mapped geometry, (c) the estimator:\n\n"
        "| split | rows (moving) | (a) truth geometry | (b) mapped geometry | (c) estimator | (b) − (a) | (c) − (b) | "
        "(a) / (b) / (c) on moving rows | (a) / (b) with the edge's true descent as the gate |\n"
        "|---|---|---|---|---|---|---|---|---|\n";
  for (const auto& m : e.splits) {
    const ForceDecomposition& d = m.decomposition;
    if (d.rows == 0) continue;
    std::snprintf(buf, sizeof buf, "| %s | %ld (%ld) | %s | %s | %s | %+.1f | %+.1f | %.1f / %.1f / %.1f | %s / %s |\n",
                  m.split.c_str(), d.rows, d.moving_rows, cell(d.truth_geometry).c_str(), cell(d.mapped_geometry).c_str(),
                  cell(d.estimator).c_str(), d.mapped_geometry.total - d.truth_geometry.total,
                  d.estimator.total - d.mapped_geometry.total, d.truth_geometry_moving.total,
                  d.mapped_geometry_moving.total, d.estimator_moving.total, cell(d.truth_geometry_true_gate).c_str(),
                  cell(d.mapped_geometry_true_gate).c_str());
    os << buf;
  }
  os << "\nThe physics term by term with the truth soil (truth geometry | mapped geometry), and each modelled term "
        "against the simulator's own part on the truth geometry:\n\n"
        "| split | paper F at β* | + penetration (observed descent) | + face adhesion (F_total) | + inertia | "
        "one wedge vs FEE over slices | penetration term | inertia term | simulator's parts FEE / inertia / "
        "penetration (share of Σ‖F_q‖) | rows observed descending (truly) / truly descending | mapped / simulator's d, "
        "w, Q (row medians) |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const auto& m : e.splits) {
    const ForceDecomposition& d = m.decomposition;
    if (d.rows == 0) continue;
    os << "| " << m.split << " |";
    for (std::size_t k = 0; k < 4; ++k) {
      std::snprintf(buf, sizeof buf, " %.1f (%.1f / %.1f) \\| %.1f (%.1f / %.1f) |", d.ladder_truth[k].total,
                    d.ladder_truth[k].x, d.ladder_truth[k].z, d.ladder_mapped[k].total, d.ladder_mapped[k].x,
                    d.ladder_mapped[k].z);
      os << buf;
    }
    std::snprintf(buf, sizeof buf, " %s | %s | %s | %.2f / %.2f / %.2f | %ld (%ld) / %ld | %.2f, %.2f, %.2f |\n",
                  cell(d.wedge_vs_slices).c_str(), cell(d.penetration_term).c_str(), cell(d.inertia_term).c_str(),
                  d.share_fee, d.share_inertia, d.share_penetration, d.observed_descending, d.observed_descending_true,
                  d.true_descending, m.depth_ratio_row_median, m.width_ratio_row_median, m.surcharge_ratio_row_median);
    os << buf;
  }
  return os.str();
}

std::string evaluationMarkdown(const SoilEvaluation& e) {
  std::ostringstream os;
  char buf[256];
  os << "| split | samples (valid) | force error % (along x / z) | noise floor % (error against the noise-free force %) | ... moving rows % (stalled rows) | FEE with truth soil % | ... at β* % | ... and truth geometry % | simulator's F_total at β* % | constant force % | mapped Q / sim. Q (median) |";
  for (int k = 0; k < kSoilCount; ++k) os << " " << kName[k] << " MAE (" << soil::kSoilDisplay[k].unit << ") |";
  os << "\n|---|---|---|---|---|---|---|---|---|---|---|";
  for (int k = 0; k < kSoilCount; ++k) os << "---|";
  os << "\n";
  for (const auto& m : e.splits) {
    std::snprintf(buf, sizeof buf, "| %s | %ld (%ld) | %.1f (%.1f / %.1f) | %.1f (%.1f) | %.1f (%.1f %%) | %.1f | %.1f | %.1f | %.1f | %.1f | %.2f |",
                  m.split.c_str(), m.samples, m.valid, m.force_error_pct, m.force_error_x_pct, m.force_error_z_pct,
                  m.force_error_noise_floor_pct, m.force_error_noise_free_pct, m.force_error_moving_pct,
                  100.0 * m.stalled_row_fraction, m.force_error_truth_fee_pct, m.force_error_truth_fee_min_pct,
                  m.force_error_truth_geometry_pct,
                  m.force_error_simulator_model_pct, m.force_error_mean_pct, m.surcharge_ratio_median);
    os << buf;
    for (int k = 0; k < kSoilCount; ++k) {
      std::snprintf(buf, sizeof buf, " %.2f |", m.mae[k] * soil::kSoilDisplay[k].scale);
      os << buf;
    }
    os << "\n";
  }
  os << decompositionMarkdown(e);
  propertyTable(os, e,
                "Skill: MAE of the estimates / of a constant (the training split's median truth), and the correlation "
                "of estimate with truth:",
                true, [](const SplitMetrics& m, int k) {
                  char cell[64];
                  std::snprintf(cell, sizeof cell, "%.2f / %.2f, r %.2f", m.mae[k] * soil::kSoilDisplay[k].scale,
                                m.mae_constant[k] * soil::kSoilDisplay[k].scale, m.correlation[k]);
                  return std::string(cell);
                });
  propertyTable(os, e, "Fraction of truth within ±1σ (aleatoric / nullspace-inflated / total with epistemic):", false,
                [](const SplitMetrics& m, int k) {
                  char cell[64];
                  std::snprintf(cell, sizeof cell, "%.2f / %.2f / %.2f", m.coverage_aleatoric[k], m.coverage_nullspace[k],
                                m.coverage_total[k]);
                  return std::string(cell);
                });
  if (std::any_of(e.splits.begin(), e.splits.end(), [](const SplitMetrics& m) { return std::isfinite(m.input_beyond_fraction); })) {
    os << "\nInputs beyond the training split's 99th percentile of input distance (mean share of the prior variance added):";
    for (const auto& m : e.splits) {
      std::snprintf(buf, sizeof buf, " %s %.3f (%.3f)", m.split.c_str(), m.input_beyond_fraction, m.input_share_mean);
      os << buf;
    }
    os << "\n";
  }
  if (!e.fig11_trend.empty()) {
    os << "\nFig. 11's trend (test and held-out splits): per family, the rank correlation of the estimate's bin means "
          "with the truth's over the relative-density bins (— where the truth or the estimate is flat):\n\n| family | bins |";
    for (int k = 0; k < kSoilCount; ++k) os << " " << kName[k] << " |";
    os << "\n|---|---|";
    for (int k = 0; k < kSoilCount; ++k) os << "---|";
    os << "\n";
    for (const Fig11Trend& t : e.fig11_trend) {
      os << "| " << soil::soilFamilyName(static_cast<soil::SoilFamily>(t.family)) << " | " << t.bins << " |";
      for (int k = 0; k < kSoilCount; ++k) {
        if (std::isfinite(t.rank_correlation[k]))
          std::snprintf(buf, sizeof buf, " %+.2f |", t.rank_correlation[k]);
        else
          std::snprintf(buf, sizeof buf, " — |");
        os << buf;
      }
      os << "\n";
    }
  }
  os << "\nEpistemic variance, held-out over test:";
  for (int k = 0; k < kSoilCount; ++k) {
    std::snprintf(buf, sizeof buf, " %s %.2f", kName[k], e.epistemic_ratio[k]);
    os << buf;
  }
  os << "\n";
  return os.str();
}

std::string fig11Csv(const SoilEvaluation& e) {
  std::ostringstream os;
  os << "family,id_bin,samples";
  for (int k = 0; k < kSoilCount; ++k) os << "," << kName[k] << "_truth," << kName[k] << "_mean," << kName[k] << "_sigma";
  os << "\n";
  char buf[64];
  for (const auto& b : e.fig11) {
    os << soil::soilFamilyName(static_cast<soil::SoilFamily>(b.family)) << "," << b.bin << "," << b.samples;
    for (int k = 0; k < kSoilCount; ++k) {
      std::snprintf(buf, sizeof buf, ",%.6g,%.6g,%.6g", b.truth[k], b.mean[k], b.sigma[k]);
      os << buf;
    }
    os << "\n";
  }
  return os.str();
}

io::Image fig11Chart(const SoilEvaluation& e, const std::string& caption) {
  // Colour-blind-safe family colours (Okabe-Ito).
  const io::Rgba colours[4] = {{213, 94, 0, 255}, {0, 114, 178, 255}, {230, 159, 0, 255}, {0, 158, 115, 255}};
  std::vector<io::ChartPanel> panels(kSoilCount);
  for (int k = 0; k < kSoilCount; ++k) {
    io::ChartPanel& p = panels[static_cast<std::size_t>(k)];
    p.title = std::string(kName[k]);
    p.x_label = "relative density I_d (bin centre)";
    p.y_label = soil::kSoilDisplay[k].unit;
    for (int fam = 0; fam < 4; ++fam) {
      const std::string name = soil::soilFamilyName(static_cast<soil::SoilFamily>(fam));
      io::ChartSeries est{name + ": estimate +-1 sigma", colours[fam], {}, {}, {}, false};
      io::ChartSeries truth{name + ": truth", colours[fam], {}, {}, {}, true};
      for (const Fig11Bin& b : e.fig11) {
        if (b.family != fam) continue;
        const double x = (b.bin + 0.5) / 10.0, scale = soil::kSoilDisplay[k].scale;
        // A small offset per family so the bars of one bin do not hide each other.
        est.x.push_back(x + 0.012 * (fam - 1.5));
        est.y.push_back(b.mean[k] * scale);
        est.y_err.push_back(b.sigma[k] * scale);
        truth.x.push_back(x);
        truth.y.push_back(b.truth[k] * scale);
      }
      if (!est.x.empty()) {
        p.series.push_back(truth);
        p.series.push_back(est);
      }
    }
  }
  io::ChartOptions o;
  o.title = "Soil estimates against the truth by relative density (test and held-out splits)";
  o.caption = caption;
  return io::renderChart(panels, o);
}

}  // namespace terramap::pinn
