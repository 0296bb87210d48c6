#pragma once
/// \file
/// The soil fitted jointly to the force of many horizon rows (docs/soil_estimator.md, "Where the
/// error lives"): one sweep's force cannot tell φ from c (they trade along the FEE's null
/// space), but rows of different depth, surcharge and edge motion in one soil can. Pure
/// functions, no state: safe from any thread at once. Nothing here throws.
///
/// The physics (rowForce) sums the FEE over the slices across the blade through the cut's
/// cross-section, loads the wedge with the pile over the cutting width and pushes the rest, and
/// adds the edge's penetration resistance where the edge descends, a latent switch per row
/// decided by the force (docs/soil_estimator.md, "Where the error lived in the soil map").
/// Forces are the blade's on the soil in the sample frame [along t̂, up], newtons; soil vectors
/// in soil::SoilParam order [c (Pa), φ (rad), c_a (Pa), δ (rad), γ (N/m³)].
#include <terramap/soil/fee.hpp>
#include <terramap/soil/soil_parameters.hpp>

#include <Eigen/Core>

#include <limits>
#include <vector>

namespace terramap::soil {

/// One horizon row: the mapped geometry, how likely the edge was descending, the measured force.
struct FitRow {
  /// α, ρ, the mean depth d, the cutting width w (the extent of the cut across t̂) and the
  /// surcharge Q as blade_sweep measured them.
  fee::Geometry geometry;
  /// The cut's cross-section (SweepStep::area_m2, depth2_m3): Σ d ds (m²) and Σ d² ds (m³).
  /// NaN: the one wedge takes d and w as they are.
  double area_m2 = std::numeric_limits<double>::quiet_NaN();
  double depth2_m3 = std::numeric_limits<double>::quiet_NaN();
  /// The blade's width (m); 0: the surcharge is taken over the cutting width whole.
  double blade_width_m = 0;
  /// Probability that the edge was descending (the penetration term acts): from the observed
  /// vertical speed, or 0 / 1 for a gate known exactly.
  double p_descending = 0;
  double fx_n = 0, fz_n = 0;
};

struct PooledFitOptions {
  double edge_thickness_m = 0.025;  ///< penetration term's edge (the simulator's default)
  /// Standard deviation of a row's force residual along x and z (N): the noise the rows are
  /// weighed with, and the scale of the robust (Cauchy-like, soft-L1) loss.
  double force_sigma_n = 1500.0;
  /// ... and a share of the measured force itself: a row's noise scale is
  /// hypot(force_sigma_n, force_sigma_rel |F|) per component (so rows of a dense soil, with
  /// forces of tens of kN, do not outweigh those of a loose one, and windows of either compare).
  double force_sigma_rel = 0.06;
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
  /// The slices across the blade summed (the FEE is linear in Σ d ds and Σ d² ds for one α and
  /// ρ): one wedge at depth depth2/area and width area²/depth2, and the penetration over the
  /// cutting width at the cut's mean vertical depth (area / (w cos α)); rows without a
  /// cross-section keep d and w.
  bool cross_section = true;
  /// The pile lies across the whole blade, and only the part ahead of the cutting width loads
  /// the failing wedge (Q w / blade width); the rest is pushed along the ground, a horizontal
  /// force pile_friction times its weight (the simulator's slices that push without cutting).
  bool surcharge_share = true;
  double pile_friction = 0.6494;  ///< tan 33°: loose soil sliding on the ground ahead
  /// Whether the edge descended is not known for sure from the observed vertical speed (the
  /// penetration term, tens of kN in a dense clay, switches with its sign): each row's gate is a
  /// latent switch with prior p_descending, decided by the force itself (expectation-
  /// maximisation over the switch, gate_iterations rounds). false: descending where p >= 0.5.
  bool gate_mixture = true;
  int gate_iterations = 4;
  /// Finite: φ is held at this value (rad; its prior's standard deviation 1e-6 of its span about
  /// it) and the other properties fitted: the cost's profile along φ.
  double fixed_phi_rad = std::numeric_limits<double>::quiet_NaN();
  /// Keep each row's β*, FEE and bearing factors while φ and δ stay put (the Jacobian's c, c_a
  /// and γ columns): the same fit bit for bit, at about half the time. false: every residual
  /// evaluates them afresh (for testing that).
  bool angle_cache = true;
  /// A fit left on c's zero end (a sand's, most often) has a posterior truncated there, not the
  /// untruncated Gaussian its curvature gives: the published covariance is the truncated
  /// posterior's second moment about the fit. Along c, with a = how far below 0 the
  /// unconstrained optimum lies in its own standard deviations (a = sqrt(Σcc / s) g_c, g the
  /// cost's gradient at the end, s the residuals' scale), that moment is Σcc (1 - a λ(a) + a²),
  /// λ the inverse Mills ratio: Σcc where the optimum sits on the end (a = 0), → 0 as it lies far below. What moves
  /// with c shrinks alike (Σ - (1 - m/Σcc) Σ:c Σc: / Σcc), so φ keeps only part of its spread
  /// along the c-φ valley (and with cohesionless_prior_mass, only what c = 0 leaves free).
  /// false: the untruncated Gauss-Newton covariance.
  bool truncated_covariance = true;
  /// truncated_covariance: the prior's mass on c exactly 0, a cohesionless soil (the soil
  /// table's sand and gravel: two families of four), beside the rest spread over c's range as
  /// its prior says. A fit on c's zero end is then a mixture: the spike, where the other
  /// properties keep only what c = 0 leaves free (their conditional covariance), and the
  /// truncated slab above; their weights are the prior's mass against each one's evidence, and
  /// the slab's is diluted by how little of c's range its profile covers (σ_c over the range),
  /// so a fit pushed onto the end reads as a cohesionless soil. 0: the truncated slab alone.
  double cohesionless_prior_mass = 0.5;
};
struct PooledFit {
  SoilParamVector mean{};                 ///< the fitted soil, inside kSoilParams' ranges
  /// Gauss-Newton covariance (SI units², prior included), scaled by (rms_n / force_sigma_n)² when
  /// the residuals scatter more than the assumed force_sigma_n (never scaled down); truncated
  /// at c's zero end when the fit sits on it (PooledFitOptions::truncated_covariance).
  Eigen::Matrix<double, 5, 5> covariance = Eigen::Matrix<double, 5, 5>::Zero();
  int rows = 0;                           ///< rows with a valid FEE at the solution
  int iterations = 0;
  bool converged = false;
  double rms_n = 0;                       ///< root mean square of the force residuals at the solution (each row's gated), N
  double cost = 0;                        ///< the minimised robust cost, prior included (to compare starts)
  /// The factor the covariance took from the residuals' scatter, max(1, χ² per residual).
  double residual_scale = 1;
  /// The covariance was truncated at c = 0: the fit sits there with the cost still falling below
  /// it (PooledFitOptions::truncated_covariance).
  bool truncated_at_c_zero = false;
  /// The posterior's weight on c = 0 exactly (PooledFitOptions::cohesionless_prior_mass), 0 when
  /// the fit is not on c's zero end.
  double cohesionless_weight = 0;
};

/// The row's modelled force with soil `s`: FEE plus the pushed pile in `fee_n` (blade on soil,
/// [along t̂, up], N) and the penetration resistance the edge meets if it descends, `penetration_n`
/// (>= 0; it adds -penetration_n to the vertical force). valid is false (both zero) where the
/// FEE is invalid.
struct RowForce {
  Eigen::Vector2d fee_n = Eigen::Vector2d::Zero();
  double penetration_n = 0;
  bool valid = false;
};
RowForce rowForce(const fee::Soil& s, const FitRow& row, const PooledFitOptions& opt);
/// The force as a gate at p_descending >= 0.5 takes it ({0, 0} and false where the FEE is invalid).
bool modelForce(const fee::Soil& s, const FitRow& row, const PooledFitOptions& opt, Eigen::Vector2d& f);

/// Fits the soil to `rows` from `start` (clamped into the ranges; a NaN property starts in the
/// middle of its range): bounded Levenberg-Marquardt
/// on the robust residuals in span-normalised parameters, forward-difference Jacobian.
/// An empty row set returns the prior (converged false).
PooledFit fitPooled(const std::vector<FitRow>& rows, const SoilParamVector& start, const PooledFitOptions& opt = {});
/// The robust cost of `rows` (no prior) under soil `soil`, each row's gate at its posterior for
/// that soil (gate_mixture) or at p_descending >= 0.5: how well that soil explains those rows.
double rowsCost(const std::vector<FitRow>& rows, const SoilParamVector& soil, const PooledFitOptions& opt = {});

/// fitPooled from each of `starts` and from the corners of the (c, φ) trade, c high with φ low
/// and c low with φ high (the FEE's c and φ trade along a valley with more than one minimum: a
/// fit warm-started from a loose soil's estimate can settle on the wrong side when the blade
/// enters a dense one); the fit of least cost.
PooledFit fitPooledMultiStart(const std::vector<FitRow>& rows, const std::vector<SoilParamVector>& starts,
                              const PooledFitOptions& opt = {});
/// The starts fitPooledMultiStart fits from, in its order: `starts`, then the two corners.
std::vector<SoilParamVector> multiStarts(const std::vector<SoilParamVector>& starts);
/// Of fits from multiStarts' starts, in its order, the one fitPooledMultiStart keeps (the first
/// of least cost), moved out of `fits`. \pre fits is not empty.
PooledFit leastCost(std::vector<PooledFit>& fits);

}  // namespace terramap::soil
