#pragma once
/// \file
/// The simulator's truth soil-tool physics, independent of the mapper's code:
///  - `bladeSoilForce`: FEE (paper Eq. 1 with adhesion along the face, i.e. fee::Result::F_total_N,
///    and the minimum-N_gamma failure angle beta*) evaluated per slice across the blade width on
///    the truth terrain with that slice's soil, plus penetration resistance of the cutting edge
///    (Terzaghi strip bearing capacity on the edge area) and inertia of the soil being cut and of
///    the surcharge. Coloured noise is added by the Simulator, not here (this is deterministic).
///  - `cutAndPush`: the truth deformation: the cutting edge carves every node it crossed during a
///    step down to the edge height (up to the blade top: soil above spills over), the removed soil
///    (bank soil swelled by its own swell factor) is deposited as loose soil just ahead of the
///    blade, slice by slice; `relaxLoose` lets loose soil slide to its angle of repose around the
///    blade but never through it. All three conserve sum(U + Lc) exactly up to rounding.
/// Frames: map (z up); blade frame as in core/events.hpp (x = face normal forward, y along the
/// edge to the left, z up the face). Forces in newtons, map frame, *soil on blade*.
#include <terramap/core/cell_rect.hpp>
#include <terramap/core/events.hpp>
#include <terramap/core/parallel.hpp>
#include <terramap/sim/truth_terrain.hpp>
#include <terramap/sim/world.hpp>

#include <Eigen/Geometry>

#include <algorithm>

namespace terramap::sim {

/// Truth FEE quantities of one step, summarised over the slices that cut (depth-weighted means;
/// NaN when no slice cuts). Sums (w, Q) are totals over cutting slices.
struct FeeTruth {
  double alpha_rad = NAN, rho_rad = NAN, depth_m = NAN, width_m = 0, q_n = 0;
  double c_pa = NAN, phi_rad = NAN, gamma_n_m3 = NAN, ca_pa = NAN, delta_rad = NAN;
  double beta_rad = NAN;
  /// The cut's cross-section over the cutting slices: Σ d ds (m²) and Σ d² ds (m³), d normal to
  /// the surface. The FEE is linear in both (γ d² w N_γ and (c N_c + c_a N_ca) d w per slice),
  /// so a one-wedge model holds the slices' sum at depth depth2/area and width area²/depth2;
  /// depth_m × width_m does not when the depth varies across the blade.
  double area_m2 = 0, depth2_m3 = 0;
  /// Surcharge (N) ahead of the slices that push a loose pile without cutting (their force is
  /// the pile's, q tan(repose), along the push direction).
  double q_pushed_n = 0;
  int cutting_slices = 0;
  int invalid_slices = 0;  ///< slices whose FEE inputs failed a validity rule (force omitted)
};

struct BladeForce {
  /// FEE part of the soil-on-blade force (map frame, N) if the blade keeps moving at the
  /// current speed; the vehicle model scales it by how much of it is mobilised.
  Eigen::Vector3d fee_map = Eigen::Vector3d::Zero();
  Eigen::Vector3d inertia_map = Eigen::Vector3d::Zero();      ///< soil acceleration (moving only)
  Eigen::Vector3d penetration_map = Eigen::Vector3d::Zero();  ///< edge bearing (descending only)
  /// Horizontal unit push direction (blade normal projected on the ground plane).
  Eigen::Vector3d push_dir = Eigen::Vector3d::UnitX();
  FeeTruth truth;
};

/// Evaluates the truth soil force on a blade at pose T_map_blade.
/// \param normal_speed_mps blade speed along push_dir (only > 0 moves soil)
/// \param edge_vz_mps vertical speed of the cutting edge (< 0 = descending into the soil)
/// \param accel_mps2 blade acceleration along push_dir (surcharge inertia)
/// \param slices number of slices across the width (>= 1)
/// \param exec optional executor: the slices are evaluated on it (nullptr = inline); the
///        per-slice results are summed serially in slice order, so the result is bit-identical
///        for any thread count.
BladeForce bladeSoilForce(const TruthTerrain& terrain, const SoilField& soil, const Eigen::Isometry3d& T_map_blade,
                          const BladeGeometry& blade, double edge_thickness_m, int slices,
                          double normal_speed_mps, double edge_vz_mps, double accel_mps2,
                          const Executor* exec = nullptr);


/// Result of one cut-and-push step (volumes in m^3 of bank-equivalent soil) and the box of
/// truth-terrain nodes (i = x index, j = y index) that changed (for pyramid refreshes and the simulator's terrain patches).
struct CutResult : CellRect {
  double cut_bank_m3 = 0;       ///< undisturbed soil cut
  double moved_loose_m3 = 0;    ///< loose soil (already cut) pushed again, bank-equivalent
  double deposited_m3 = 0;      ///< bank-equivalent deposited (= cut + moved - lost)
  double lost_m3 = 0;           ///< would have landed outside the grid (also added to terrain.lostVolume())
};

/// Moves the blade from T_old to T_new (one physics step) through the truth terrain.
/// Only forward motion (along the new face normal) cuts; the blade does not backdrag.
CutResult cutAndPush(TruthTerrain& terrain, const SoilField& soil, const Eigen::Isometry3d& T_old,
                     const Eigen::Isometry3d& T_new, const BladeGeometry& blade, int slices);

/// Lets loose soil slide toward its angle of repose inside a box around the blade (Jacobi
/// sweeps: every edge flux is computed from one snapshot, outflow limited to the loose soil a
/// node has, so the result does not depend on iteration order). Nodes under the blade (a band
/// one node thick or more behind the edge) neither give nor take soil, so nothing flows
/// through the blade. Returns the changed node box. Serial (a sweep is too small to pay for
/// row-parallel hand-offs).
CutResult relaxLoose(TruthTerrain& terrain, const SoilField& soil, const Eigen::Isometry3d& T_map_blade,
                     const BladeGeometry& blade, double ahead_m, double side_m, int iterations);

/// The same sliding with no blade, over the node box [i0, i1] x [j0, j1] (clamped to the grid),
/// at most `iterations` Jacobi sweeps (stops early once nothing moves); `tan_repose` of the loose
/// soil. What a bucket's pile settles with. Returns the changed node box.
CutResult relaxRegion(TruthTerrain& terrain, double tan_repose, int i0, int j0, int i1, int j1, int iterations);

}  // namespace terramap::sim
