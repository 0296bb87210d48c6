#pragma once
/// \file
/// What the soil estimator (`soil_pinn`, paper §2.1, Fig. 3; ALGORITHMS.md §F) reads for one
/// sweep, built the same way for the training dataset (`terramap dataset`) and at inference
/// (the plugin), so the two can never disagree on a feature. Torch-free.
///
/// One sample per blade sweep (SweepRecord, published by `blade_sweep`), anchored at the
/// sweep's last pose stamp t1:
///  - `obs` [T x kObsFeatures]: the machine's last T Observation events with stamp <= t1, oldest
///    first, each turned into the features named by obsFeatureNames() (raw SI units; the model
///    normalises). The measured force is never an input: it is the supervision.
///  - `theta_k` [P x kThetaK]: the known FEE parameters Θ_k = [ρ, α, w, d, Q, v] at the stamps of
///    the last P of those observations (the prediction horizon T_P), interpolated in time
///    between the sweep's steps (SweepStep; clamped to [t0, t1]); v is the cutting edge's speed
///    along the sweep direction t̂ (m/s) from the observation's blade twist.
///  - `force` [P x 2]: the measured force of the blade on the soil at those stamps, [along t̂,
///    up] in newtons (the paper's F frame: the sensor's soil-on-blade force negated and rotated
///    from the base frame into the map). NaN where the machine has no force sensor.
///
/// Units: rad, m, N, m/s, rpm as in Observation. Threading: an ObservationHistory is used by one
/// thread at a time; buildSample() is a pure function.
#include <terramap/core/events.hpp>
#include <terramap/plugin/records/sweep_record.hpp>

#include <cstddef>
#include <deque>
#include <string>
#include <vector>

namespace terramap::soil {

/// Observation features per time step (see obsFeatureNames()).
constexpr int kObsFeatures = 35;
/// Known FEE parameters per horizon step: rho, alpha, w, d, Q, v.
constexpr int kThetaK = 6;
enum ThetaK : int { kRho = 0, kAlpha, kWidth, kDepth, kSurcharge, kSpeed };

/// Names (with units) of the kObsFeatures observation features, in order:
/// base twist (6, body frame), base roll and pitch (2), blade pose in the base frame
/// (x, y, z, roll, pitch, yaw; 6), blade twist (6, blade frame), cylinder lengths (3) and
/// velocities (3), track speeds (2), engine speed (1), commanded actions (5), and the blade's
/// vertical speed in the map frame (1; from the blade's attitude and twist).
const std::vector<std::string>& obsFeatureNames();
/// Names of the kThetaK columns ("rho_rad", "alpha_rad", "w_m", "d_m", "q_n", "v_mps").
const std::vector<std::string>& thetaKNames();

/// True when the row's machine is held by the soil: its tracks turn (mean track speed above
/// 0.1 m/s) but its base moves forward at less than 0.2 of that, the simulator's own stall flag
/// (engine/sim/ctl.cpp) evaluated on the observed features. A held machine's force sensor reads
/// only what the tracks mobilise to hold it, not the soil's failure force the FEE describes,
/// so training leaves such rows out of the force terms (docs/soil_estimator.md). NaN speeds
/// never count as stalled. `features` holds kObsFeatures values in obsFeatureNames() order.
bool stalledRow(const float* features);

/// One observation reduced to what a sample needs.
struct ObsRow {
  double stamp = 0.0;
  float features[kObsFeatures] = {};
  Eigen::Vector3d force_map_N = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());  ///< blade on soil
  Eigen::Vector3d blade_velocity_map = Eigen::Vector3d::Zero();  ///< cutting edge velocity, map frame
};

/// The features of one Observation (NaN inputs stay NaN; the model decides what to do with
/// them). Pure.
ObsRow observationRow(const Observation& o);

/// The last `capacity` observations of one machine, in stamp order.
class ObservationHistory {
 public:
  explicit ObservationHistory(std::size_t capacity = 256) : capacity_(capacity) {}
  /// Appends; an observation older than the newest one is ignored (returns false), so a replayed
  /// or duplicated stream cannot scramble the history.
  bool push(const Observation& o);
  const std::deque<ObsRow>& rows() const { return rows_; }
  std::size_t capacity() const { return capacity_; }

 private:
  std::size_t capacity_;
  std::deque<ObsRow> rows_;
};

/// The cut's cross-section per horizon step (SweepStep::area_m2, depth2_m3): what a one-wedge
/// model needs to hold the FEE summed over slices across the blade.
constexpr int kProfile = 2;
enum Profile : int { kArea = 0, kDepth2 };

struct PinnSample {
  int T = 0, P = 0;
  std::vector<float> obs;      ///< T * kObsFeatures, row-major (time, feature)
  std::vector<float> theta_k;  ///< P * kThetaK
  /// P * kProfile: [Σ d ds (m²), Σ d² ds (m³)] interpolated as theta_k is; NaN where the sweep's
  /// steps have none (a record from before the field existed). Not a network input.
  std::vector<float> profile;
  std::vector<float> force;    ///< P * 2 (NaN without a force sensor)
  double t0 = 0.0, t1 = 0.0;   ///< the sweep's first and last stamps
  double anchor_stamp = 0.0;   ///< stamp of the last observation (end of the horizon)
  long sweep_index = 0;
  std::string machine_id;
};

/// Why a sweep gave no sample (the plugin counts these by name; the dataset reports them).
enum class SampleSkip { None, FeeInvalid, NoSteps, ShortHistory, StaleHistory, NonFiniteThetaK };
const char* sampleSkipName(SampleSkip s);

/// Builds the sample of `sweep` from `history` (that machine's observations), or says why not:
/// FeeInvalid (the record's fee_valid is false: nothing was cut), NoSteps (no SweepStep),
/// ShortHistory (fewer than T observations up to t1), StaleHistory (the newest observation up to
/// t1 is older than `max_gap_s` before t1, e.g. observations stopped), NonFiniteThetaK (a
/// horizon step had no finite ρ, α, w, d or Q at any sweep step). Requires 1 <= P <= T.
/// \throws std::invalid_argument on T < 1, P < 1 or P > T.
SampleSkip buildSample(const ObservationHistory& history, const SweepRecord& sweep, int T, int P,
                       PinnSample& out, double max_gap_s = 0.1);

/// The one wedge that holds the FEE summed over the slices across the blade (the FEE is linear
/// in Σ d ds and Σ d² ds for one α and ρ: docs/soil_estimator.md, "Where the error lived in the
/// soil map"): each of the `P` steps of `theta_k` (P * kThetaK) whose `profile` (P * kProfile)
/// holds a finite area A > 0 and Σ d² ds = D > 0 gets depth D / A (m) and width A² / D (m) in
/// place of the sweep's mean depth and cutting width; other steps are left as they are. Returns
/// how many steps changed. Pure; nothing throws.
int applySlicedGeometry(float* theta_k, const float* profile, int P);

}  // namespace terramap::soil
