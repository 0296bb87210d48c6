#pragma once
/// \file
/// The per-sweep soil estimate the `soil_pinn` plugin publishes on the RecordBus (type
/// SoilEstimateRecord::kType) for the Bayesian layers (`soil_bayes`) and any later plugin:
/// the PINN ensemble's estimate of the soil parameters Θ_u = [c, φ, c_a, δ, γ] from one blade
/// sweep (a SweepRecord of `blade_sweep`) and the machine's observation history before it
/// (paper §2.1, ALGORITHMS.md §F).
///
/// Soil vectors (`mean`, `var_*`) are in SoilEstimateRecord::Soil order [c, φ, c_a, δ, γ] in SI
/// units: c and c_a in Pa, φ and δ in rad, γ in N/m³; variances in the squares of those units.
/// Frames and units as in sweep_record.hpp: positions in the map frame (x, y horizontal, z up),
/// metres, radians, seconds. Forces are the blade's force on the soil in the paper's F frame
/// [along t_hat, up], newtons.
///
/// Publication time: the record of a sweep is published once the observation at the sweep's
/// last pose (stamp >= t1) has reached the plugin (it may arrive after that pose's BladePose), or
/// at the end of the run; the RecordBus stamp is `stamp` (the end of the horizon). Several
/// records can be published in one event (several sweeps of a machine waited for the same
/// observation, or at finish()): a consumer that needs every estimate reads them with
/// `RecordBus::since(kType, last_sequence_seen)` (soil_bayes does).
///
/// NaN: a quantity that could not be computed is NaN, never a made-up 0. When `valid` is false
/// the estimate must not be fused: `invalid_reason` says why, and the numbers (if finite) are
/// what the network gave, kept for diagnosis only.
///
/// Threading: a record is immutable once published (shared as
/// `shared_ptr<const SoilEstimateRecord>`), so any number of readers may hold it on any thread.
/// No libtorch type crosses this header.
#include <terramap/plugin/records/sweep_record.hpp>

#include <Eigen/Geometry>

#include <array>
#include <limits>
#include <string>

namespace terramap {

struct SoilEstimateRecord {
  /// RecordBus type name. Bump the suffix when the layout changes incompatibly.
  static constexpr const char* kType = "terramap.soil_estimate.v1";

  /// Indices into the soil arrays (soil::SoilParam's order: soil/soil_parameters.hpp holds
  /// names, layer names, units and ranges).
  enum Soil : int { kC = 0, kPhi, kCa, kDelta, kGamma, kCount };
  using SoilVector = std::array<double, kCount>;
  static constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

  // ---- which sweep -----------------------------------------------------------------------
  long sweep_index = 0;        ///< SweepRecord::sweep_index of the sweep this estimate is for
  std::string machine_id;
  double t0 = 0.0, t1 = 0.0;   ///< the sweep's first and last pose stamps (s)
  /// Stamp of the last observation of the sample (end of the prediction horizon, <= t1 and
  /// within the sample's max gap of it), s. Also the RecordBus stamp.
  double stamp = 0.0;
  int history_T = 0;           ///< observation steps the model read
  int horizon_P = 0;           ///< horizon steps the FEE layer evaluated

  // ---- the sweep's geometry (copied from the SweepRecord; what the Bayesian layers need) --
  Eigen::Isometry3d T_map_blade1 = Eigen::Isometry3d::Identity();  ///< blade at t1
  Eigen::Vector2d t_hat = Eigen::Vector2d::UnitX();  ///< sweep direction (horizontal unit vector)
  double alpha_rad = kNaN;     ///< the sweep's fitted surface slope (SweepRecord::alpha_rad)
  double rho_rad = kNaN;       ///< alpha + blade angle (SweepRecord::rho_rad)
  double d_m = kNaN;           ///< the sweep's cut depth normal to the surface (SweepRecord::d_m)
  double w_m = kNaN;           ///< cut width (SweepRecord::w_m)
  /// Failure angle the FEE layer used at the last horizon step, the members' mean: the model's
  /// base angle (β* minimising N_γ, or Rankine's π/4 - φ/2 for models trained with
  /// `beta_base: nominal`) plus β_res, rad.
  double beta_rad = kNaN;
  double d_res_m = kNaN;       ///< depth residual added to d in the FEE (members' mean), m
  double beta_res_rad = kNaN;  ///< failure-angle residual (members' mean), rad

  // ---- the estimate ------------------------------------------------------------------------
  SoilVector mean{kNaN, kNaN, kNaN, kNaN, kNaN};           ///< members' mean estimate
  /// What the Bayesian layers fuse: var_nullspace + var_epistemic.
  SoilVector var_total{kNaN, kNaN, kNaN, kNaN, kNaN};
  /// Members' mean predicted variance exp(S_Θ) (the paper's Σ_Θ).
  SoilVector var_aleatoric{kNaN, kNaN, kNaN, kNaN, kNaN};
  /// max(var_aleatoric, diag Σ_n) per member (Eq. 7 nullspace inflation), averaged over members.
  SoilVector var_nullspace{kNaN, kNaN, kNaN, kNaN, kNaN};
  /// Spread of the members' estimates (population variance): the epistemic part.
  SoilVector var_epistemic{kNaN, kNaN, kNaN, kNaN, kNaN};
  std::array<double, 2> F_r{kNaN, kNaN};     ///< residual force (members' mean), N
  /// Predicted force at the end of the horizon (FEE + F_r, members' mean), N.
  std::array<double, 2> F_pred{kNaN, kNaN};
  /// Measured force at the end of the horizon (the sample's supervision), N; NaN without a
  /// force sensor. Not an input of the network: kept so consumers can judge the fit.
  std::array<double, 2> F_measured{kNaN, kNaN};

  int members = 0;             ///< ensemble size
  int valid_members = 0;       ///< members whose FEE was valid at at least one horizon step
  /// True when a majority of the members had a valid FEE and every mean and variance is finite.
  bool valid = false;
  /// Empty when valid; otherwise "fee_invalid_majority" (fewer than half the members found a
  /// valid FEE at any horizon step) or "non_finite_output" (a mean or variance is NaN or inf).
  std::string invalid_reason;
};

/// The record of an estimate for `sweep` before any estimate is in it: which sweep (index,
/// machine, t0, t1; stamp = t1) and the sweep's geometry copied, everything else as declared
/// (NaN, not valid). Every estimator of the bus starts its record from it.
inline SoilEstimateRecord soilEstimateRecordFor(const SweepRecord& sweep) {
  SoilEstimateRecord r;
  r.sweep_index = sweep.sweep_index;
  r.machine_id = sweep.machine_id;
  r.t0 = sweep.t0;
  r.t1 = sweep.t1;
  r.stamp = sweep.t1;
  r.T_map_blade1 = sweep.T_map_blade1;
  r.t_hat = sweep.t_hat;
  r.alpha_rad = sweep.alpha_rad;
  r.rho_rad = sweep.rho_rad;
  r.d_m = sweep.d_m;
  r.w_m = sweep.w_m;
  return r;
}

}  // namespace terramap
