#include "pooled_fit.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>

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

// Residuals of every row (x then z, in units of force_sigma_n) at u.
void residuals(const std::vector<FitRow>& rows, const Vec& u, const PooledFitOptions& opt, Eigen::VectorXd& r,
               int* valid_rows = nullptr) {
  const fee::Soil s = soilOf(u, opt.interface_bounded_by_soil);
  r.resize(static_cast<Eigen::Index>(2 * rows.size()));
  int valid = 0;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    Eigen::Vector2d f;
    valid += modelForce(s, rows[i], opt.edge_thickness_m, f, opt.q_gamma_ref_n_m3);
    r[static_cast<Eigen::Index>(2 * i)] = (f.x() - rows[i].fx_n) / opt.force_sigma_n;
    r[static_cast<Eigen::Index>(2 * i + 1)] = (f.y() - rows[i].fz_n) / opt.force_sigma_n;
  }
  if (valid_rows) *valid_rows = valid;
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
  return p;
}

// Soft-L1 cost 2 Σ (sqrt(1 + e²) − 1) of the rows plus the prior's ½ Σ ((u − centre)/sd)².
double cost(const Eigen::VectorXd& r, const Vec& u, const Prior& prior) {
  double c = 0;
  for (Eigen::Index i = 0; i < r.size(); ++i) c += 2.0 * (std::sqrt(1.0 + r[i] * r[i]) - 1.0);
  return c + 0.5 * ((u - prior.centre).array() / prior.sd.array()).square().sum();
}

}  // namespace

bool modelForce(const fee::Soil& s, const FitRow& row, double edge_thickness_m, Eigen::Vector2d& f,
                double q_gamma_ref_n_m3) {
  f.setZero();
  fee::Geometry g = row.geometry;
  if (q_gamma_ref_n_m3 > 0) g.q_n *= s.gamma_n_m3 / q_gamma_ref_n_m3;
  const fee::Result res = fee::evaluateAtBetaMin(s, g);
  if (!res.valid()) return false;
  f = res.F_total_N;
  if (row.descending) f.y() -= fee::penetrationForce(s, row.geometry.d_m, row.geometry.w_m, edge_thickness_m);
  return true;
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
  const Mat prior_info = prior.sd.array().square().inverse().matrix().asDiagonal();
  Eigen::VectorXd r, rt;
  Eigen::MatrixXd J(static_cast<Eigen::Index>(2 * rows.size()), kN);
  Mat JtWJ = Mat::Zero();
  residuals(rows, u, opt, r);
  double c = cost(r, u, prior);
  double lambda = 1e-2;
  constexpr double kStep = 1e-4;
  for (out.iterations = 0; out.iterations < opt.max_iterations && !rows.empty(); ++out.iterations) {
    // Forward differences, stepping inward at an upper bound.
    for (int k = 0; k < kN; ++k) {
      Vec up = u;
      const double h = u[k] + kStep > 1.0 ? -kStep : kStep;
      up[k] += h;
      residuals(rows, up, opt, rt);
      J.col(k) = (rt - r) / h;
    }
    // Iteratively reweighted least squares for the soft-L1 loss: weight 1 / sqrt(1 + e²).
    const Eigen::VectorXd w = (1.0 + r.array().square()).rsqrt();
    JtWJ = J.transpose() * w.asDiagonal() * J;
    const Vec g = J.transpose() * (w.array() * r.array()).matrix() + prior_info * (u - prior.centre);
    bool improved = false;
    for (int tries = 0; tries < 8 && !improved; ++tries) {
      Mat A = JtWJ + prior_info;
      A.diagonal() += lambda * A.diagonal();
      const Vec step = -A.ldlt().solve(g);
      const Vec un = (u + step).cwiseMax(0.0).cwiseMin(1.0);
      residuals(rows, un, opt, rt);
      const double cn = cost(rt, un, prior);
      if (cn < c) {
        const double moved = (un - u).cwiseAbs().maxCoeff();
        u = un;
        r = rt;
        c = cn;
        lambda = std::max(1e-6, lambda / 3.0);
        improved = true;
        if (moved < 1e-6) out.converged = true;
      } else {
        lambda *= 4.0;
      }
    }
    if (!improved || out.converged) {
      out.converged = true;
      break;
    }
  }
  residuals(rows, u, opt, r, &out.rows);
  const fee::Soil s = soilOf(u, bounded);
  out.mean = fromFee(s);
  out.rms_n = rows.empty() ? 0.0 : opt.force_sigma_n * std::sqrt(r.squaredNorm() / static_cast<double>(r.size()));
  // Gauss-Newton covariance in span units, then in SI: D (JᵀWJ + prior)⁻¹ D.
  const Mat info = JtWJ + prior_info;
  const Mat cov_u = info.inverse();
  // dθ/du at the solution (diagonal spans unless the interface is bounded by the soil), by
  // central differences inside the box.
  Mat D;
  for (int k = 0; k < kN; ++k) {
    Vec lo = u, hi = u;
    lo[k] = std::max(0.0, u[k] - 1e-6);
    hi[k] = std::min(1.0, u[k] + 1e-6);
    D.col(k) = (thetaOf(hi, bounded) - thetaOf(lo, bounded)) / (hi[k] - lo[k]);
  }
  // The rows scatter more than force_sigma_n says when the physics misses part of the force:
  // the covariance then takes the residuals' own scale (never below the assumed one).
  const double scale = std::max(1.0, (out.rms_n / opt.force_sigma_n) * (out.rms_n / opt.force_sigma_n));
  out.covariance = scale * D * cov_u * D.transpose();
  return out;
}

}  // namespace terramap::soil
