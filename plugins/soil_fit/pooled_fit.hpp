#pragma once
/// \file
/// The soil fitted jointly to the force of many horizon rows (docs/soil_estimator.md, "Where the
/// error lives"): one sweep's force cannot tell φ from c (they trade along the FEE's null
/// space), but rows of different depth, surcharge and edge motion in one soil can. Pure
/// functions, no state: safe from any thread at once. Nothing here throws.
///
/// The physics is the estimator's layer made as complete as the decomposition of `eval-soil`
/// found worth: F_total of the FEE at β* (fee::evaluateAtBetaMin) plus, on rows whose edge the
/// observations show descending, the edge's penetration resistance (fee::penetrationForce).
/// Forces are the blade's on the soil in the sample frame [along t̂, up], newtons; soil vectors
/// in soil::SoilParam order [c (Pa), φ (rad), c_a (Pa), δ (rad), γ (N/m³)].
#include <terramap/soil/fee.hpp>
#include <terramap/soil/soil_parameters.hpp>

#include <Eigen/Core>

#include <vector>

namespace terramap::soil {

/// One horizon row: the mapped geometry, whether the edge was seen descending, the measured force.
struct FitRow {
  fee::Geometry geometry;
  bool descending = false;
  double fx_n = 0, fz_n = 0;
};

struct PooledFitOptions {
  double edge_thickness_m = 0.025;  ///< penetration term's edge (the simulator's default)
  /// Standard deviation of a row's force residual along x and z (N): the noise the rows are
  /// weighed with, and the scale of the robust (Cauchy-like, soft-L1) loss.
  double force_sigma_n = 1500.0;
  /// Prior N(middle, (span * prior_sd_fraction)²) per property, counted once per fit: it decides
  /// only what the rows leave free (γ against c, c_a against c).
  double prior_sd_fraction = 0.5;
  /// > 0: γ's prior is N(gamma_prior_n_m3, gamma_prior_sd_n_m3²) instead (N/m³). The force hardly
  /// holds γ (fitted per episode on the simulator's own geometry its correlation with the truth is
  /// 0.33, and a constant is 3.7 times closer: docs/soil_estimator.md), so a wide prior lets γ take
  /// up whatever the physics misses (the mapped pile's missing weight); soils weigh 14–21 kN/m³.
  double gamma_prior_n_m3 = 0.0;
  double gamma_prior_sd_n_m3 = 2000.0;
  int max_iterations = 40;
  /// > 0: the unit weight the rows' surcharge was computed with (blade_sweep's
  /// unit_weight_n_m3); the pile is then weighed with the fitted γ, Q γ / q_gamma_ref_n_m3.
  double q_gamma_ref_n_m3 = 0.0;
  /// The soil-blade interface bounded by the soil (McKyes 1985, Soil Cutting and Tillage §2; Wong,
  /// Theory of Ground Vehicles §2): adhesion is not larger than cohesion and the soil-metal
  /// friction angle not larger than the internal one, so c_a = a c and δ = b φ with a, b in [0, 1]
  /// are fitted instead of c_a and δ free in their ranges. The rows hardly tell c_a or δ apart from
  /// c and φ; free, they sit at the prior's middle (c_a 15 kPa on a sand with c = 0), which the
  /// FEE index then reads as strength. Both are still clamped into kSoilParams' ranges.
  bool interface_bounded_by_soil = true;
};

struct PooledFit {
  SoilParamVector mean{};                 ///< the fitted soil, inside kSoilParams' ranges
  /// Gauss-Newton covariance (SI units², prior included), scaled by (rms_n / force_sigma_n)² when
  /// the residuals scatter more than the assumed force_sigma_n (never scaled down).
  Eigen::Matrix<double, 5, 5> covariance = Eigen::Matrix<double, 5, 5>::Zero();
  int rows = 0;                           ///< rows with a valid FEE at the solution
  int iterations = 0;
  bool converged = false;
  double rms_n = 0;                       ///< root mean square of the force residuals at the solution, N
};

/// The row's modelled force with soil `s` ({0, 0} and false where the FEE is invalid).
bool modelForce(const fee::Soil& s, const FitRow& row, double edge_thickness_m, Eigen::Vector2d& f,
                double q_gamma_ref_n_m3 = 0.0);

/// Fits the soil to `rows` from `start` (clamped into the ranges; a NaN property starts in the
/// middle of its range): bounded Levenberg-Marquardt
/// on the robust residuals in span-normalised parameters, forward-difference Jacobian.
/// An empty row set returns the prior (converged false).
PooledFit fitPooled(const std::vector<FitRow>& rows, const SoilParamVector& start, const PooledFitOptions& opt = {});

}  // namespace terramap::soil
