#pragma once
/// \file
/// soil_erosion: Mohr-Coulomb slip of loose soil between neighbouring cells (ALGORITHMS.md §H,
/// §L; paper Alg. 5, Eq. 10), run in a region of interest around the blade after every sweep.
///
/// Model, for a pair of neighbours at spacing r with height difference ΔH (higher cell a):
/// - only loose soil slips: Δh = min(ΔH, L[a]);
/// - a wedge of width r fails on a plane at α: W = γ_l r² (Δh - r tan α)/2, failure-plane length
///   L_f = r / cos α, factor of safety Fs(α) = (c_l L_f r + W cos α tan φ_l) / (W sin α), minimal at
///   tan α* = Δh / (r + sqrt(K (r² + Δh²) / (Δh tan φ_l + K))), K = 2 c_l / γ_l (for c_l = 0 this is
///   the angle-of-repose rule tan α* = Δh / r, Fs = tan φ_l r / Δh). The cohesion force carries the
///   wedge width r (the paper's Eq. 10 omits it; without it Fs is not dimensionless);
/// - slipping (Fs(α*) < 1 or still moving) soil accelerates at a = g (sin α* - cos α* tan φ_l)
///   - c_l L_f r g / W; its velocity is carried across sub-steps (semi-implicit Euler) and the
///   height moved per sub-step is Δh · v δt cos α* / r;
/// - a pair never overshoots: at most half the excess over the critical drop ΔH_c (the largest
///   stable difference, Fs(α*(ΔH_c)) = 1, at least r tan(min_slope)) moves, and the pair stops there;
/// - blade masks: no slip out of a cell under the swept volume (E), slip into one only up to
///   its swept-volume bottom (Z).
/// Layers: writes `elevation`, `loose` and `height_sigma` (a cell moved by dh gets
/// height_sigma = sqrt(sigma^2 + (dh/2)^2)). Height contract (docs/height_contract.md): where
/// lidar_fusion's layers exist (bound at start()), a moved cell's `variance` grows by the same
/// (dh/2)^2 (from height_sigma^2 if the LiDAR never measured it), `upper_bound` = elevation and
/// `is_upper_bound` = 0; `is_valid` is kept. Only cells with a known elevation ever move. Without
/// a `variance` layer nothing of this is written or created.
/// Parallel without races: 4-colour tiling of 2x2 blocks; a cell of colour k exchanges with its
/// neighbour along m̂ in the row direction and then in the column direction; colours run one
/// after another. Every cell is written by exactly one owner per colour, so the result does not
/// depend on the thread count (bit-identical at 1, 2, N threads).
#include <terramap/plugin/plugin.hpp>
#include <terramap/plugin/records/sweep_record.hpp>

#include <cstdint>
#include <utility>
#include <string>
#include <vector>

namespace terramap::plugins {

struct ErosionConfig {
  double cohesion_pa = 25.0;       ///< c_l
  double friction_rad = 0.26;      ///< φ_l
  double unit_weight_n_m3 = 12197; ///< γ_l
  double min_slope_rad = 0.05;     ///< drops below r tan(min_slope) never move
  double dt_s = 0.1;               ///< sub-step δt
  int substeps = 20;               ///< sub-steps per pass
  bool carry_velocity = true;      ///< false restarts slip from rest every sub-step (reference kernel)
  double gravity = 9.80665;
};

/// The dense grid a pass works on (row-major rows x cols, row = logical i, column = logical j).
struct ErosionGrid {
  int rows = 0, cols = 0;
  std::vector<double> H;        ///< elevation (m); NaN = unknown (inactive)
  std::vector<double> L;        ///< loose thickness (m), >= 0
  std::vector<std::uint8_t> active;  ///< 1 = may exchange (inside the ROI and H known)
  std::vector<std::uint8_t> blade;   ///< E: under the swept volume
  std::vector<double> z_mask;        ///< Z: swept-volume bottom where blade = 1
  /// A pass's slip velocities along i and j (m/s), zeroed when a pass starts. Kept here with the
  /// grid so a grid reused from pass to pass allocates nothing.
  std::vector<double> vi, vj;
  /// Resets H/L to `rows` x `cols` and the masks to "active, unmasked" (reusing the vectors'
  /// memory when the grid is reused).
  void resize(int r, int c);
  size_t at(int i, int j) const { return static_cast<size_t>(i) * static_cast<size_t>(cols) + static_cast<size_t>(j); }
};

class ErosionSolver {
 public:
  /// \throws ConfigError if the configuration is out of range (see the plugin schema).
  ErosionSolver(const ErosionConfig& cfg, double resolution_m);
  const ErosionConfig& config() const { return cfg_; }
  double resolution() const { return r_; }
  /// ΔH_c: the largest height difference between neighbours that does not slip (m).
  double criticalDrop() const { return dh_crit_; }
  /// tan α* for a drop `dh` (closed form, header comment).
  double failureTan(double dh) const;
  /// Fs(α*) for a drop `dh` (+inf for dh <= 0).
  double safetyFactor(double dh) const;
  /// Fs at an arbitrary failure angle (for tests and tools).
  double safetyFactorAt(double dh, double alpha_rad) const;
  /// Neighbour offsets (di, dj) in logical index space that point along m̂ (map frame):
  /// i grows towards -x and j towards -y (geometry.hpp).
  static std::pair<int, int> offsetsAlong(const Eigen::Vector2d& m_hat);
  /// One pass: `substeps` sub-steps of the four colours. Velocities start at rest.
  void pass(ErosionGrid& g, int di, int dj, const Executor& ex) const;
  /// The same pass, plain loops (the reference the parallel kernel is tested against).
  void passSerial(ErosionGrid& g, int di, int dj) const;

 private:
  bool colour(ErosionGrid& g, int pr, int pc, int di, int dj, int row_begin, int row_end, int col_begin,
              int col_end) const;
  /// True if soil moved or the pair still carries a velocity.
  bool exchange(ErosionGrid& g, size_t o, size_t n, double& v) const;
  ErosionConfig cfg_;
  double r_, tan_phi_, K_, dh_crit_;
};

/// The plugin: after each new sweep record (and on Tick if `trigger: sweep_and_tick`), runs
/// `passes` erosion passes in the ROI around the blade's T1 pose: ±roi_along_m along the blade
/// normal and ±(roi_margin_m + blade width)/2 across it.
class SoilErosion : public Plugin {
 public:
  ParamSchema schema() const override;
  void configure(const Params& params) override;
  std::vector<LayerSpec> layers() const override;
  EventMask events() const override { return EventKind::BladePose | EventKind::Tick; }
  void start(ProcessContext& ctx) override;
  void process(ProcessContext& ctx, const Event& event) override;

  /// One or more passes around `rec`'s T1 pose on the context's map (what process() runs).
  /// One call at a time per plugin object: it works in the object's buffers (scratch_).
  void erodeAround(ProcessContext& ctx, const SweepRecord& rec);
  long passesRun() const { return passes_run_; }

 private:
  ErosionConfig cfg_;
  double roi_along_m_ = 3.0, roi_margin_m_ = 2.0;
  bool on_tick_ = false, use_mask_ = true;
  int passes_ = 1;
  LayerId elevation_ = -1, loose_ = -1, sigma_ = -1;
  // lidar_fusion's layers (height contract), -1 where the map has none (blind-only pipeline)
  LayerId variance_ = -1, upper_bound_ = -1, is_upper_bound_ = -1;
  long last_sequence_ = 0;
  long passes_run_ = 0;
  /// erodeAround's buffers, kept from call to call: fresh ones each call made every pass fault
  /// its pages in anew wherever malloc returns freed memory to the system (a process that had not
  /// freed larger blocks before: BM_SoilErosion run alone took 3.1 against 0.9 ms a pass).
  struct Scratch {
    ErosionGrid grid;
    std::vector<double> H0, L0, S0, L1, S1, V0, V, U0, I0, U, I;
  } scratch_;
};

}  // namespace terramap::plugins
