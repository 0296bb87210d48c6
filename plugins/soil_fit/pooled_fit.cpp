#include "pooled_fit.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <limits>

namespace terramap::soil {
namespace {

constexpr int kN = kSoilParamCount;
using Vec = Eigen::Matrix<double, kN, 1>;
using Mat = Eigen::Matrix<double, kN, kN>;

// Parameters are solved for in span units u in [0, 1] (θ = lo + span u), so one damping and one
// step tolerance serve Pa and radians alike. With the interface bounded by the soil, u[c_a] and
// u[δ] are the ratios c_a / c and δ / φ instead.
Vec thetaOf(const Vec& u, bool bounded) {
  Vec t;
  for (int k = 0; k < kN; ++k) t[k] = kSoilParams[k].lo + (kSoilParams[k].hi - kSoilParams[k].lo) * u[k];
  if (bounded) {
    t[kParamCa] = std::clamp(u[kParamCa] * t[kParamC], kSoilParams[kParamCa].lo, kSoilParams[kParamCa].hi);
    t[kParamDelta] = std::clamp(u[kParamDelta] * t[kParamPhi], kSoilParams[kParamDelta].lo, kSoilParams[kParamDelta].hi);
  }
  return t;
}

Vec uOf(const Vec& t, bool bounded) {
  Vec u;
  for (int k = 0; k < kN; ++k) u[k] = std::clamp((t[k] - kSoilParams[k].lo) / (kSoilParams[k].hi - kSoilParams[k].lo), 0.0, 1.0);
  if (bounded) {
    u[kParamCa] = t[kParamC] > 0 ? std::clamp(t[kParamCa] / t[kParamC], 0.0, 1.0) : 0.5;
    u[kParamDelta] = t[kParamPhi] > 0 ? std::clamp(t[kParamDelta] / t[kParamPhi], 0.0, 1.0) : 0.5;
  }
  return u;
}

fee::Soil soilOf(const Vec& u, bool bounded) {
  const Vec t = thetaOf(u, bounded);
  SoilParamVector v{};
  for (int k = 0; k < kN; ++k) v[static_cast<std::size_t>(k)] = t[k];
  return toFee(v);
}

// A measured force component's noise scale: force_sigma_n, and force_sigma_rel of its size
// (a force sensor's and the soil's own fluctuation grow with the force).
double rowSigma(const PooledFitOptions& opt, double f) { return std::hypot(opt.force_sigma_n, opt.force_sigma_rel * f); }

// What a row's force takes from the soil's angles alone (β*, the FEE's N-factors, the bearing
// factors: functions of φ, δ, α and ρ) and its noise scales, kept between evaluations of one row
// set: the Jacobian's columns for c, c_a and γ, the gate's rounds and the final figures leave
// the angles as they were. Each value is the one fee computes from scratch, so the fit is bit for
// bit the same (PooledFitOptions::angle_cache false: refreshed at every evaluation).
struct AngleCache {
  double phi = std::numeric_limits<double>::quiet_NaN(), delta = std::numeric_limits<double>::quiet_NaN();
  struct Row {
    double beta = 0, sx = 0, sz = 0;
    fee::Factors n;
    fee::BearingFactors b;
  };
  std::vector<Row> rows;
};

// rowForce with the angles' part given: beta = fee::betaMin(s, row's geometry), n its factors,
// b = fee::bearingFactors(s.phi_rad).
RowForce rowForceWith(const fee::Soil& s, const FitRow& row, const PooledFitOptions& opt, double beta,
                      const fee::Factors& n, const fee::BearingFactors& b);

// Brings the cache to soil s: the rows' noise scales once, their angles' part unless φ and δ are
// the ones it holds.
void refresh(AngleCache& cache, const fee::Soil& s, const std::vector<FitRow>& rows, const PooledFitOptions& opt) {
  if (cache.rows.size() != rows.size()) {
    cache.rows.assign(rows.size(), {});
    for (std::size_t i = 0; i < rows.size(); ++i) {
      cache.rows[i].sx = rowSigma(opt, rows[i].fx_n);
      cache.rows[i].sz = rowSigma(opt, rows[i].fz_n);
    }
    cache.phi = cache.delta = std::numeric_limits<double>::quiet_NaN();
  }
  if (opt.angle_cache && s.phi_rad == cache.phi && s.delta_rad == cache.delta) return;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    AngleCache::Row& c = cache.rows[i];
    c.beta = fee::betaMin(s, rows[i].geometry);
    c.n = fee::factors(s, rows[i].geometry, c.beta);
    c.b = fee::bearingFactors(s.phi_rad);
  }
  cache.phi = s.phi_rad;
  cache.delta = s.delta_rad;
}

// Row i's force at s from a cache refreshed to s.
RowForce cachedForce(const AngleCache& cache, const fee::Soil& s, const std::vector<FitRow>& rows, std::size_t i,
                     const PooledFitOptions& opt) {
  const AngleCache::Row& c = cache.rows[i];
  return rowForceWith(s, rows[i], opt, c.beta, c.n, c.b);
}

// Residuals of every row at u, three per row in units of its noise scale (rowSigma): along x, and the
// vertical one with the penetration on (weighted by sqrt(w_i)) and off (sqrt(1 - w_i)), w_i the
// row's gate weight. A gate known for sure has w_i in {0, 1} and so one vertical residual.
void residuals(const std::vector<FitRow>& rows, const std::vector<double>& gate, const Vec& u,
               const PooledFitOptions& opt, AngleCache& cache, Eigen::VectorXd& r, int* valid_rows = nullptr) {
  const fee::Soil s = soilOf(u, opt.interface_bounded_by_soil);
  refresh(cache, s, rows, opt);
  r.resize(static_cast<Eigen::Index>(3 * rows.size()));
  int valid = 0;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const RowForce f = cachedForce(cache, s, rows, i, opt);
    valid += f.valid;
    const double w = gate[i];
    const double sx = cache.rows[i].sx, sz = cache.rows[i].sz;
    const double ez_off = (f.fee_n.y() - rows[i].fz_n) / sz;
    const double ez_on = (f.fee_n.y() - f.penetration_n - rows[i].fz_n) / sz;
    r[static_cast<Eigen::Index>(3 * i)] = (f.fee_n.x() - rows[i].fx_n) / sx;
    r[static_cast<Eigen::Index>(3 * i + 1)] = w > 0 ? std::sqrt(w) * ez_on : 0.0;
    r[static_cast<Eigen::Index>(3 * i + 2)] = w < 1 ? std::sqrt(1.0 - w) * ez_off : 0.0;
  }
  if (valid_rows) *valid_rows = valid;
}

// The soft-L1 loss of one residual, 2 (sqrt(1 + e²) − 1): the row's negative log-likelihood
// under the loss's heavy-tailed noise, up to a constant.
double softL1(double e) { return 2.0 * (std::sqrt(1.0 + e * e) - 1.0); }

// The gate weights at u: each row's posterior probability that the edge descended, from its
// prior p_descending and how well the vertical force fits with and without the penetration.
void gateWeights(const std::vector<FitRow>& rows, const Vec& u, const PooledFitOptions& opt, AngleCache& cache,
                 std::vector<double>& gate) {
  const fee::Soil s = soilOf(u, opt.interface_bounded_by_soil);
  refresh(cache, s, rows, opt);
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const double p = std::clamp(rows[i].p_descending, 1e-3, 1.0 - 1e-3);
    const RowForce f = cachedForce(cache, s, rows, i, opt);
    const double sz = cache.rows[i].sz;
    const double l_on = std::log(p) - softL1((f.fee_n.y() - f.penetration_n - rows[i].fz_n) / sz);
    const double l_off = std::log(1.0 - p) - softL1((f.fee_n.y() - rows[i].fz_n) / sz);
    gate[i] = 1.0 / (1.0 + std::exp(std::clamp(l_off - l_on, -50.0, 50.0)));
  }
}

/// The prior in span units: centre and standard deviation per property.
struct Prior {
  Vec centre, sd;
};

Prior priorOf(const PooledFitOptions& opt) {
  Prior p;
  p.centre.setConstant(0.5);
  p.sd.setConstant(opt.prior_sd_fraction);
  if (opt.gamma_prior_n_m3 > 0) {
    const double span = kSoilParams[kParamGamma].hi - kSoilParams[kParamGamma].lo;
    p.centre[kParamGamma] = (opt.gamma_prior_n_m3 - kSoilParams[kParamGamma].lo) / span;
    p.sd[kParamGamma] = opt.gamma_prior_sd_n_m3 / span;
  }
  if (std::isfinite(opt.fixed_phi_rad)) {
    const double span = kSoilParams[kParamPhi].hi - kSoilParams[kParamPhi].lo;
    p.centre[kParamPhi] = std::clamp((opt.fixed_phi_rad - kSoilParams[kParamPhi].lo) / span, 0.0, 1.0);
    p.sd[kParamPhi] = 1e-6;
  }
  return p;
}

// Q(a) / pdf(a) for a >= 0, the Mills ratio (the asymptotic 1/a (1 - 1/a² + 3/a⁴) past 30, where
// pdf and Q near the smallest double).
double millsRatio(double a) {
  if (a > 30.0) {
    const double i2 = 1.0 / (a * a);
    return (1.0 - i2 + 3.0 * i2 * i2) / a;
  }
  return 0.5 * std::erfc(a / std::sqrt(2.0)) * std::sqrt(2.0 * M_PI) * std::exp(0.5 * a * a);
}

// E[(x - end)²] / σ² of N(μ, σ²) truncated to the side of `end` it does not lie on, a = |μ -
// end| / σ: 1 - a / R(a) + a², R the Mills ratio. Past a = 30 the terms cancel to ~2/a² beyond
// what R's series holds: the moment's own series 2/a² (1 - 5/a² + 37/a⁴) there (relative error
// below 1e-6; the direct sum keeps 10 digits up to it).
double truncatedSecondMoment(double a) {
  if (!(a > 0.0)) return 1.0;
  if (a > 30.0) {
    const double i2 = 1.0 / (a * a);
    return 2.0 * i2 * (1.0 - 5.0 * i2 + 37.0 * i2 * i2);
  }
  return 1.0 - a / millsRatio(a) + a * a;
}

// The covariance (span units, unscaled) of a fit on c's zero end truncated there
// (PooledFitOptions::truncated_covariance, cohesionless_prior_mass): `grad` the cost's gradient
// at u, `scale` the residuals' factor the covariance takes afterwards. false off the end (cov_u
// as it was); `spike` the posterior's weight on c = 0 exactly (0 without one).
bool truncateAtCZero(Mat& cov_u, const Vec& u, const Vec& grad, const Prior& prior, double scale,
                     const PooledFitOptions& opt, double& spike) {
  const double s_cc = cov_u(kParamC, kParamC);
  if (!(u[kParamC] <= 0.0 && grad[kParamC] > 0.0 && s_cc > 0.0)) return false;
  const double a = std::sqrt(s_cc / scale) * grad[kParamC];
  double ratio = std::clamp(truncatedSecondMoment(a), 0.0, 1.0);
  if (opt.cohesionless_prior_mass > 0.0) {
    // The spike at c = 0 keeps the other properties' conditional spread only (ratio 0). Its
    // weight against the slab's is its prior mass against the slab's evidence relative to the
    // posterior's height at 0: the slab prior's density at 0 (its Gaussian truncated to the
    // range) times the profile's mass inside, sqrt(2 pi) σ Q(a) e^(a²/2) = σ R(a).
    const double pi0 = std::min(opt.cohesionless_prior_mass, 1.0 - 1e-12);
    const double sd = prior.sd[kParamC], z0 = -prior.centre[kParamC] / sd, z1 = (1.0 - prior.centre[kParamC]) / sd;
    const double inside = 0.5 * (std::erfc(z0 / std::sqrt(2.0)) - std::erfc(z1 / std::sqrt(2.0)));
    const double slab_at_0 = std::exp(-0.5 * z0 * z0) / (sd * std::sqrt(2.0 * M_PI)) / inside;
    const double slab = (1.0 - pi0) / pi0 * slab_at_0 * std::sqrt(s_cc * scale) * millsRatio(a);
    spike = 1.0 / (1.0 + slab);
    ratio *= slab / (1.0 + slab);
  }
  const Vec col = cov_u.col(kParamC);
  cov_u -= (1.0 - ratio) * (col * col.transpose()) / s_cc;
  return true;
}


// Soft-L1 cost 2 Σ (sqrt(1 + e²) − 1) of the rows plus the prior's ½ Σ ((u − centre)/sd)².
double cost(const Eigen::VectorXd& r, const Vec& u, const Prior& prior) {
  double c = 0;
  for (Eigen::Index i = 0; i < r.size(); ++i) c += 2.0 * (std::sqrt(1.0 + r[i] * r[i]) - 1.0);
  return c + 0.5 * ((u - prior.centre).array() / prior.sd.array()).square().sum();
}

}  // namespace

namespace {

RowForce rowForceWith(const fee::Soil& s, const FitRow& row, const PooledFitOptions& opt, double beta,
                      const fee::Factors& n, const fee::BearingFactors& b) {
  RowForce out;
  fee::Geometry g = row.geometry;
  const double w_cut = g.w_m;
  double q = g.q_n;
  if (opt.q_gamma_ref_n_m3 > 0) q *= s.gamma_n_m3 / opt.q_gamma_ref_n_m3;
  double pushed = 0.0;
  if (opt.surcharge_share && row.blade_width_m > 0 && w_cut > 0) {
    const double share = std::clamp(w_cut / row.blade_width_m, 0.0, 1.0);
    pushed = (1.0 - share) * q;
    q *= share;
  }
  g.q_n = q;
  // The mean vertical depth over the cutting width: what the edge is buried by.
  double depth_v = g.d_m;
  if (opt.cross_section && w_cut > 0 && fee::slicedWedge(row.area_m2, row.depth2_m3, g.d_m, g.w_m))
    depth_v = row.area_m2 / (w_cut * std::cos(g.alpha_rad));
  // β* and the factors hang on the angles only, which slicing the cut and sharing the pile
  // leave as they are (fee::evaluateAtBetaMin's own steps, with its β* and factors given).
  const fee::Result res = fee::evaluateWith(s, g, beta, n);
  if (!res.valid()) return out;
  out.fee_n = res.F_total_N;
  out.fee_n.x() += opt.pile_friction * pushed;
  out.penetration_n = fee::penetrationWith(s, depth_v, w_cut, opt.edge_thickness_m, b).force_n;
  out.valid = true;
  return out;
}

}  // namespace

RowForce rowForce(const fee::Soil& s, const FitRow& row, const PooledFitOptions& opt) {
  const double beta = fee::betaMin(s, row.geometry);
  return rowForceWith(s, row, opt, beta, fee::factors(s, row.geometry, beta), fee::bearingFactors(s.phi_rad));
}

bool modelForce(const fee::Soil& s, const FitRow& row, const PooledFitOptions& opt, Eigen::Vector2d& f) {
  const RowForce r = rowForce(s, row, opt);
  f = r.fee_n;
  if (row.p_descending >= 0.5) f.y() -= r.penetration_n;
  return r.valid;
}

PooledFit fitPooled(const std::vector<FitRow>& rows, const SoilParamVector& start, const PooledFitOptions& opt) {
  PooledFit out;
  const bool bounded = opt.interface_bounded_by_soil;
  Vec u, t0;
  for (int k = 0; k < kN; ++k) t0[k] = start[static_cast<std::size_t>(k)];
  u = uOf(t0, bounded);
  for (int k = 0; k < kN; ++k)
    if (!std::isfinite(t0[k])) u[k] = 0.5;
  const Prior prior = priorOf(opt);
  if (std::isfinite(opt.fixed_phi_rad)) u[kParamPhi] = prior.centre[kParamPhi];
  const Mat prior_info = prior.sd.array().square().inverse().matrix().asDiagonal();
  // The gate: the prior's hard decision, or (gate_mixture) its probability, refined below.
  std::vector<double> gate(rows.size());
  for (std::size_t i = 0; i < rows.size(); ++i)
    gate[i] = opt.gate_mixture ? std::clamp(rows[i].p_descending, 0.0, 1.0) : (rows[i].p_descending >= 0.5 ? 1.0 : 0.0);
  Eigen::VectorXd r, rt;
  AngleCache cache;
  Eigen::MatrixXd J(static_cast<Eigen::Index>(3 * rows.size()), kN);
  Mat JtWJ = Mat::Zero();
  Vec grad = Vec::Zero();  // the cost's gradient where JtWJ was taken (the truncation's distance)
  constexpr double kStep = 1e-4;
  const int rounds = opt.gate_mixture ? std::max(1, opt.gate_iterations) : 1;
  for (int round = 0; round < rounds && !rows.empty(); ++round) {
    if (opt.gate_mixture && round > 0) {
      const std::vector<double> before = gate;
      gateWeights(rows, u, opt, cache, gate);
      double moved = 0.0;
      for (std::size_t i = 0; i < gate.size(); ++i) moved = std::max(moved, std::abs(gate[i] - before[i]));
      if (moved < 1e-3) break;
    }
    residuals(rows, gate, u, opt, cache, r);
    double c = cost(r, u, prior);
    double lambda = 1e-2;
    bool converged = false;
    for (int it = 0; it < opt.max_iterations; ++it, ++out.iterations) {
      // Forward differences, stepping inward at an upper bound; c, c_a and γ first, which keep
      // the angles' part of every row (AngleCache).
      for (int k : {kParamC, kParamCa, kParamGamma, kParamPhi, kParamDelta}) {
        Vec up = u;
        const double h = u[k] + kStep > 1.0 ? -kStep : kStep;
        up[k] += h;
        residuals(rows, gate, up, opt, cache, rt);
        J.col(k) = (rt - r) / h;
      }
      // Iteratively reweighted least squares for the soft-L1 loss: weight 1 / sqrt(1 + e²).
      const Eigen::VectorXd w = (1.0 + r.array().square()).rsqrt();
      JtWJ = J.transpose() * w.asDiagonal() * J;
      const Vec g = J.transpose() * (w.array() * r.array()).matrix() + prior_info * (u - prior.centre);
      grad = g;
      bool improved = false;
      for (int tries = 0; tries < 8 && !improved; ++tries) {
        Mat A = JtWJ + prior_info;
        A.diagonal() += lambda * A.diagonal();
        const Vec step = -A.ldlt().solve(g);
        const Vec un = (u + step).cwiseMax(0.0).cwiseMin(1.0);
        residuals(rows, gate, un, opt, cache, rt);
        const double cn = cost(rt, un, prior);
        if (cn < c) {
          const double moved = (un - u).cwiseAbs().maxCoeff();
          u = un;
          r = rt;
          c = cn;
          lambda = std::max(1e-6, lambda / 3.0);
          improved = true;
          if (moved < 1e-6) converged = true;
        } else {
          lambda *= 4.0;
        }
      }
      if (!improved || converged) {
        converged = true;
        break;
      }
    }
    out.converged = converged;
  }
  residuals(rows, gate, u, opt, cache, r, &out.rows);
  out.cost = cost(r, u, prior);
  const fee::Soil s = soilOf(u, bounded);
  out.mean = fromFee(s);
  // Per row, its x residual and the vertical one of its gate (the weighted pair's root sum of
  // squares), so a row counts twice whatever its gate: in units of each row's noise scale for
  // the covariance's scale, and in newtons for rms_n.
  double ss = 0.0, ss_n = 0.0;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const auto b = static_cast<Eigen::Index>(3 * i);
    ss += r[b] * r[b] + r[b + 1] * r[b + 1] + r[b + 2] * r[b + 2];
    const RowForce f = cachedForce(cache, s, rows, i, opt);  // refreshed to s by the residuals above
    const double ex = f.fee_n.x() - rows[i].fx_n, ez_off = f.fee_n.y() - rows[i].fz_n, ez_on = ez_off - f.penetration_n;
    ss_n += ex * ex + gate[i] * ez_on * ez_on + (1.0 - gate[i]) * ez_off * ez_off;
  }
  const double chi = rows.empty() ? 0.0 : std::sqrt(ss / static_cast<double>(2 * rows.size()));
  out.rms_n = rows.empty() ? 0.0 : std::sqrt(ss_n / static_cast<double>(2 * rows.size()));
  // Gauss-Newton covariance in span units, then in SI: D (JᵀWJ + prior)⁻¹ D.
  const Mat info = JtWJ + prior_info;
  Mat cov_u = info.inverse();
  // The scale below multiplies the curvature's inverse; the gradient's distance to the
  // unconstrained optimum is measured in that scaled standard deviation.
  const double scale = std::max(1.0, chi * chi);
  // On c's zero end with the cost still falling below it (the projected steps leave it exactly
  // there). Only there: truncating at every end the fit sits on (φ's, the interface's ratios at
  // c_a = c or δ = φ) cost the loam strip's AUC 0.995 -> 0.979 (docs/soil_estimator.md, "Fits on
  // c's zero end").
  if (opt.truncated_covariance && !rows.empty())
    out.truncated_at_c_zero = truncateAtCZero(cov_u, u, grad, prior, scale, opt, out.cohesionless_weight);
  // dθ/du at the solution (diagonal spans unless the interface is bounded by the soil), by
  // central differences inside the box.
  Mat D;
  for (int k = 0; k < kN; ++k) {
    Vec lo = u, hi = u;
    lo[k] = std::max(0.0, u[k] - 1e-6);
    hi[k] = std::min(1.0, u[k] + 1e-6);
    D.col(k) = (thetaOf(hi, bounded) - thetaOf(lo, bounded)) / (hi[k] - lo[k]);
  }
  // The rows scatter more than their noise scale says when the physics misses part of the
  // force: the covariance takes the residuals' own scale (never below the assumed one).
  out.covariance = scale * D * cov_u * D.transpose();
  out.residual_scale = scale;
  return out;
}

double rowsCost(const std::vector<FitRow>& rows, const SoilParamVector& soil, const PooledFitOptions& opt) {
  Vec t;
  for (int k = 0; k < kN; ++k) t[k] = soil[static_cast<std::size_t>(k)];
  const Vec u = uOf(t, opt.interface_bounded_by_soil);
  std::vector<double> gate(rows.size());
  AngleCache cache;
  if (opt.gate_mixture) {
    gateWeights(rows, u, opt, cache, gate);
  } else {
    for (std::size_t i = 0; i < rows.size(); ++i) gate[i] = rows[i].p_descending >= 0.5 ? 1.0 : 0.0;
  }
  Eigen::VectorXd r;
  residuals(rows, gate, u, opt, cache, r);
  double c = 0;
  for (Eigen::Index i = 0; i < r.size(); ++i) c += softL1(r[i]);
  return c;
}

std::vector<SoilParamVector> multiStarts(const std::vector<SoilParamVector>& starts) {
  std::vector<SoilParamVector> all = starts;
  SoilParamVector corner;
  corner.fill(std::numeric_limits<double>::quiet_NaN());  // the other properties start in the middle
  const auto at = [](int k, double f) { return kSoilParams[k].lo + f * (kSoilParams[k].hi - kSoilParams[k].lo); };
  corner[kParamC] = at(kParamC, 0.8);
  corner[kParamPhi] = at(kParamPhi, 0.25);
  all.push_back(corner);
  corner[kParamC] = at(kParamC, 0.1);
  corner[kParamPhi] = at(kParamPhi, 0.7);
  all.push_back(corner);
  return all;
}

PooledFit leastCost(std::vector<PooledFit>& fits) {
  std::size_t best = 0;
  for (std::size_t i = 1; i < fits.size(); ++i)
    if (fits[i].cost < fits[best].cost) best = i;
  return std::move(fits[best]);
}

PooledFit fitPooledMultiStart(const std::vector<FitRow>& rows, const std::vector<SoilParamVector>& starts,
                              const PooledFitOptions& opt) {
  std::vector<PooledFit> fits;
  for (const SoilParamVector& s0 : multiStarts(starts)) fits.push_back(fitPooled(rows, s0, opt));
  return leastCost(fits);
}

}  // namespace terramap::soil
