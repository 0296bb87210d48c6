#pragma once
/// \file
/// The per-sweep record the `blade_sweep` plugin publishes on the RecordBus (type
/// SweepRecord::kType) after every swept-volume update, and that later plugins consume in the
/// same event: `soil_erosion` (masks E/Z, deposit direction, ROI), the soil estimator
/// (`soil_pinn`: FEE geometry per step with variances) and `soil_bayes` (slices, wedge frame).
///
/// Frames and units: positions and directions are in the map frame (x, y horizontal, z up),
/// metres, radians, seconds, newtons, cubic metres. Directions named `*_hat` are horizontal unit
/// vectors (2D). A quantity that could not be computed is NaN (never a made-up 0), and a
/// variance is NaN exactly when its value is.
///
/// Positions (not cell indices) identify cells because the map is a ring buffer that may move
/// between the publication of a record and a later use of it; `Geometry::indexAt(position)`
/// recovers the cell while it is still on the map.
///
/// Threading: a record is immutable once published (shared as `shared_ptr<const SweepRecord>`),
/// so any number of readers may hold it on any thread.
#include <terramap/core/events.hpp>

#include <Eigen/Geometry>
#include <limits>
#include <string>
#include <vector>

namespace terramap {

/// One map cell under the swept volume's footprint (the paper's mask G, erosion's E and Z).
struct SweepMaskCell {
  Eigen::Vector2d position = Eigen::Vector2d::Zero();  ///< cell centre (map x, y)
  /// h^G: height (map z) of the lowest point of the swept volume above the cell centre. After
  /// the cut, a cut cell's elevation equals this value. Erosion lets soil flow into the cell
  /// only up to this height and never out of it (the blade is there).
  float sv_bottom_m = std::numeric_limits<float>::quiet_NaN();
  bool cut = false;  ///< member of the cut set A (its height was above sv_bottom_m)
};

/// One FEE slice: the surface line ahead of one cut cell (paper Alg. 2, per cell a).
/// The surface was sampled at position + k * slice_step_m * t_hat, k = 0..samples-1, on the
/// undisturbed surface (elevation - loose) before the cut.
struct SweepSlice {
  Eigen::Vector2d position = Eigen::Vector2d::Zero();  ///< centre of the cut cell a
  double cut_m = 0.0;            ///< Δh removed from the cell (m)
  /// Height (map z) of the cutting edge's path above the cell: the depth reference. NaN when
  /// only the blade face passed over the cell (soil lying on a raked face): no slice then.
  double cut_bottom_m = std::numeric_limits<double>::quiet_NaN();
  double lateral_m = 0.0;        ///< position along t_perp relative to the edge centre at T0
  double alpha_rad = std::numeric_limits<double>::quiet_NaN();  ///< fitted surface slope
  double rho_rad = std::numeric_limits<double>::quiet_NaN();    ///< alpha + blade angle
  double d_m = std::numeric_limits<double>::quiet_NaN();        ///< depth normal to the surface
  double surface_z_m = std::numeric_limits<double>::quiet_NaN();  ///< fitted surface at the cell
  double var_alpha = std::numeric_limits<double>::quiet_NaN();  ///< rad^2
  double var_d = std::numeric_limits<double>::quiet_NaN();      ///< m^2
  double residual_m = std::numeric_limits<double>::quiet_NaN(); ///< weighted RMS fit residual
  double weight = 0.0;           ///< averaging weight exp(C_d d) (0 when invalid)
  int samples = 0;               ///< surface points used in the fit
  bool valid = false;            ///< fit succeeded (>= 3 points, finite, d >= 0)
};

/// FEE geometry at one blade pose of the sweep (the pose history T_{0:1}; paper Alg. 1 l. 12).
/// alpha is the sweep's fitted slope; rho uses the blade angle of this pose; d and w are
/// measured at this pose against the slices' fitted surface lines (exact for a planar surface);
/// V_Q is interpolated linearly in time between its values before (T0) and after (T1) the cut.
struct SweepStep {
  double stamp = 0.0;
  double tau = 0.0;  ///< (stamp - t0) / (t1 - t0), in [0, 1]
  Eigen::Isometry3d T_map_blade = Eigen::Isometry3d::Identity();
  double alpha_rad = std::numeric_limits<double>::quiet_NaN();
  double rho_rad = std::numeric_limits<double>::quiet_NaN();
  double d_m = std::numeric_limits<double>::quiet_NaN();
  double w_m = std::numeric_limits<double>::quiet_NaN();
  /// The cut's cross-section at this pose, across the edge: the slices' depths (normal to their
  /// surface lines) averaged in one-cell bins along the edge, empty bins between cut ones
  /// interpolated, then Σ d res (area, m²) and Σ d² res (m³) over the bins. The FEE of slices
  /// that share α and ρ sums to that of one wedge at depth depth2/area and width area²/depth2
  /// (its γ term holds Σ d², its c terms Σ d); d_m and w_m, a mean and an extent, do not hold
  /// either when the depth varies across the blade (roll, uneven ground, partial contact).
  /// NaN where d_m is.
  double area_m2 = std::numeric_limits<double>::quiet_NaN();
  double depth2_m3 = std::numeric_limits<double>::quiet_NaN();
  double vq_m3 = std::numeric_limits<double>::quiet_NaN();  ///< surcharge (loose) volume ahead
  double q_n = std::numeric_limits<double>::quiet_NaN();    ///< surcharge weight gamma_l * V_Q
  double var_alpha = std::numeric_limits<double>::quiet_NaN();
  double var_rho = std::numeric_limits<double>::quiet_NaN();
  double var_d = std::numeric_limits<double>::quiet_NaN();
  double var_w = std::numeric_limits<double>::quiet_NaN();
  double var_vq = std::numeric_limits<double>::quiet_NaN();
  double var_q = std::numeric_limits<double>::quiet_NaN();
};

/// Everything one swept-volume update (T0 -> T1) measured and changed.
struct SweepRecord {
  /// RecordBus type name. Bump the suffix when the layout changes incompatibly.
  static constexpr const char* kType = "terramap.sweep.v2";

  long sweep_index = 0;  ///< 1, 2, ... per plugin instance (all machines)
  std::string machine_id;
  double t0 = 0.0, t1 = 0.0;  ///< stamps of the sweep's first and last pose
  Eigen::Isometry3d T_map_blade0 = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_map_blade1 = Eigen::Isometry3d::Identity();
  BladeGeometry geometry;
  double resolution_m = 0.0;  ///< map resolution the record was computed on

  // ---- directions (horizontal unit vectors, map frame) ----------------------------------
  Eigen::Vector2d t_hat = Eigen::Vector2d::UnitX();   ///< sweep direction (edge-centre motion)
  Eigen::Vector2d t_perp = Eigen::Vector2d::UnitY();  ///< t_hat rotated +90 deg about z
  Eigen::Vector2d n_hat = Eigen::Vector2d::UnitX();   ///< blade normal at T0, horizontal part
  Eigen::Vector2d m_hat = Eigen::Vector2d::UnitX();   ///< deposit direction (Alg. 3)
  double travel_m = 0.0;     ///< edge-centre path length over the sweep
  double rotation_rad = 0.0; ///< rotation angle between the blade at T0 and at T1
  /// Blade-face angle from the horizontal, in the vertical plane along t_hat, measured
  /// through the soil behind the edge (pi/2 = upright; < pi/2 = top leans back). Mid-sweep pose.
  double blade_angle_rad = std::numeric_limits<double>::quiet_NaN();

  // ---- FEE geometry for the whole sweep (paper Alg. 2), NaN when nothing was cut ----------
  bool fee_valid = false;  ///< at least one valid slice with d > 0
  double alpha_rad = std::numeric_limits<double>::quiet_NaN();
  double rho_rad = std::numeric_limits<double>::quiet_NaN();
  double d_m = std::numeric_limits<double>::quiet_NaN();
  double w_m = std::numeric_limits<double>::quiet_NaN();  ///< cut extent across t_hat + one cell
  double vq0_m3 = std::numeric_limits<double>::quiet_NaN();  ///< loose volume ahead before the cut
  double vq1_m3 = std::numeric_limits<double>::quiet_NaN();  ///< ... after cut and deposit
  double q0_n = std::numeric_limits<double>::quiet_NaN();
  double q1_n = std::numeric_limits<double>::quiet_NaN();
  /// Variances: the d-weighted mixture of the slices (within-slice fit variance plus the
  /// spread between slices), i.e. the uncertainty of one representative slice.
  double var_alpha = std::numeric_limits<double>::quiet_NaN();
  double var_rho = std::numeric_limits<double>::quiet_NaN();
  double var_d = std::numeric_limits<double>::quiet_NaN();
  double var_w = std::numeric_limits<double>::quiet_NaN();  ///< (one cell)^2 / 12 quantisation
  double var_vq = std::numeric_limits<double>::quiet_NaN();
  double fit_residual_m = std::numeric_limits<double>::quiet_NaN();  ///< weighted mean over slices
  int slices_valid = 0, slices_invalid = 0;
  double slice_step_m = 0.0;  ///< spacing of the surface samples along t_hat
  double fit_length_m = 0.0;
  double loose_unit_weight_n_m3 = 0.0;  ///< gamma_l used for Q
  std::vector<SweepStep> steps;          ///< one per pose of the sweep, T0 first, T1 last

  // ---- cut and deposit (Alg. 3, mass-conserving) ----------------------------------------
  double swell = 1.2;
  double sigma_sv_m = 0.0;
  double cut_volume_m3 = 0.0;        ///< Σ Δh res^2 (loose and undisturbed)
  double cut_bank_volume_m3 = 0.0;   ///< undisturbed part (swells by s when deposited)
  double deposit_volume_m3 = 0.0;    ///< loose volume deposited on known cells
  /// Loose volume deposited on cells whose elevation is unknown (NaN): kept in the `loose`
  /// layer of those cells (their elevation stays NaN until a sensor sees them), not lost.
  double deposit_unknown_volume_m3 = 0.0;
  double lost_volume_m3 = 0.0;       ///< loose volume whose deposit cell lies off the map
  long cells_under_sv = 0;           ///< |G|
  long cells_cut = 0;                ///< |A|
  long cells_unknown_under_sv = 0;   ///< cells under the SV with NaN elevation (not cut)
  long cells_deposit = 0;            ///< distinct known deposit cells
  long cells_deposit_unknown = 0;    ///< deposits onto NaN-elevation cells
  long cells_lost = 0;               ///< cut cells whose deposit cell is off the map

  std::vector<SweepMaskCell> mask;   ///< G, in row-major logical order at publication time
  std::vector<SweepSlice> slices;    ///< one per cut cell, same order as the cut cells in mask
};

}  // namespace terramap
