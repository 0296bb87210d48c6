#include <terramap/soil/pinn_sample.hpp>
#include <terramap/soil/fee.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace terramap::soil {

const std::vector<std::string>& obsFeatureNames() {
  static const std::vector<std::string> names = {
      "base_vx_mps", "base_vy_mps", "base_vz_mps", "base_wx_radps", "base_wy_radps", "base_wz_radps",
      "base_roll_rad", "base_pitch_rad",
      "blade_x_m", "blade_y_m", "blade_z_m", "blade_roll_rad", "blade_pitch_rad", "blade_yaw_rad",
      "blade_vx_mps", "blade_vy_mps", "blade_vz_mps", "blade_wx_radps", "blade_wy_radps", "blade_wz_radps",
      "lift_cyl_m", "tilt_cyl_m", "angle_cyl_m", "lift_cyl_mps", "tilt_cyl_mps", "angle_cyl_mps",
      "track_left_mps", "track_right_mps", "engine_rpm",
      "cmd_track_left", "cmd_track_right", "cmd_lift", "cmd_tilt", "cmd_angle", "blade_vz_map_mps"};
  return names;
}

const std::vector<std::string>& thetaKNames() {
  static const std::vector<std::string> names = {"rho_rad", "alpha_rad", "w_m", "d_m", "q_n", "v_mps"};
  return names;
}

const char* sampleSkipName(SampleSkip s) {
  switch (s) {
    case SampleSkip::None: return "none";
    case SampleSkip::FeeInvalid: return "fee_invalid";
    case SampleSkip::NoSteps: return "no_steps";
    case SampleSkip::ShortHistory: return "short_history";
    case SampleSkip::StaleHistory: return "stale_history";
    case SampleSkip::NonFiniteThetaK: return "non_finite_theta_k";
  }
  return "unknown";
}

bool stalledRow(const float* f) {
  // Indices of base_vx_mps, track_left_mps, track_right_mps in obsFeatureNames().
  constexpr int kBaseVx = 0, kTrackLeft = 26, kTrackRight = 27;
  const float track = 0.5f * (f[kTrackLeft] + f[kTrackRight]);
  return track > 0.1f && f[kBaseVx] < 0.2f * track;
}

namespace {

// Roll, pitch, yaw of R = Rz(yaw) Ry(pitch) Rx(roll) (the scenario's sensor convention).
Eigen::Vector3d rollPitchYaw(const Eigen::Matrix3d& R) {
  const double pitch = std::asin(std::clamp(-R(2, 0), -1.0, 1.0));
  const double roll = std::atan2(R(2, 1), R(2, 2));
  const double yaw = std::atan2(R(1, 0), R(0, 0));
  return {roll, pitch, yaw};
}

}  // namespace

ObsRow observationRow(const Observation& o) {
  static_assert(kObsFeatures == 35, "obsFeatureNames() and observationRow() list the same features");
  ObsRow r;
  r.stamp = o.stamp;
  float* f = r.features;
  int k = 0;
  for (int i = 0; i < 6; ++i) f[k++] = static_cast<float>(o.twist_base[i]);
  const Eigen::Vector3d base_rpy = rollPitchYaw(o.T_map_base.linear());
  f[k++] = static_cast<float>(base_rpy.x());
  f[k++] = static_cast<float>(base_rpy.y());
  // Blade relative to the chassis, so the features do not depend on where on the site or in
  // which heading the machine works.
  const Eigen::Isometry3d T_base_blade = o.T_map_base.inverse() * o.T_map_blade;
  for (int i = 0; i < 3; ++i) f[k++] = static_cast<float>(T_base_blade.translation()[i]);
  const Eigen::Vector3d blade_rpy = rollPitchYaw(T_base_blade.linear());
  for (int i = 0; i < 3; ++i) f[k++] = static_cast<float>(blade_rpy[i]);
  for (int i = 0; i < 6; ++i) f[k++] = static_cast<float>(o.twist_blade[i]);
  for (double v : o.cylinder_length_m) f[k++] = static_cast<float>(v);
  for (double v : o.cylinder_velocity_mps) f[k++] = static_cast<float>(v);
  for (double v : o.track_speed_mps) f[k++] = static_cast<float>(v);
  f[k++] = static_cast<float>(o.engine_speed_rpm);
  for (double v : o.action) f[k++] = static_cast<float>(v);
  r.blade_velocity_map = o.T_map_blade.linear() * o.twist_blade.head<3>();
  // The edge's vertical speed in the map frame: whether it descends into the soil (and meets
  // the bearing resistance the penetration term models) is a product of the attitudes above and
  // the blade twist, which a small network learns poorly from the separate features.
  f[k++] = static_cast<float>(r.blade_velocity_map.z());
  // The sensor reports the soil's force on the blade in the base frame; the FEE's F is the
  // blade's force on the soil.
  r.force_map_N = -(o.T_map_base.linear() * o.force_base_N);
  return r;
}

bool ObservationHistory::push(const Observation& o) {
  if (!rows_.empty() && o.stamp < rows_.back().stamp) return false;
  rows_.push_back(observationRow(o));
  while (rows_.size() > capacity_) rows_.pop_front();
  return true;
}

namespace {

// Linear interpolation of one SweepStep field at `stamp` (clamped to the steps' span) over the
// steps where that field is finite; NaN when none is.
template <class Get>
double interpolateStep(const std::vector<SweepStep>& steps, double stamp, Get get) {
  const SweepStep* before = nullptr;
  const SweepStep* after = nullptr;
  for (const SweepStep& s : steps) {
    if (!std::isfinite(get(s))) continue;
    if (s.stamp <= stamp) before = &s;
    if (s.stamp >= stamp && after == nullptr) after = &s;
  }
  if (before == nullptr && after == nullptr) return std::numeric_limits<double>::quiet_NaN();
  if (before == nullptr) return get(*after);
  if (after == nullptr || after == before || after->stamp <= before->stamp) return get(*before);
  const double u = (stamp - before->stamp) / (after->stamp - before->stamp);
  return (1.0 - u) * get(*before) + u * get(*after);
}

}  // namespace

SampleSkip buildSample(const ObservationHistory& history, const SweepRecord& sweep, int T, int P,
                       PinnSample& out, double max_gap_s) {
  if (T < 1 || P < 1 || P > T) throw std::invalid_argument("buildSample: need 1 <= P <= T");
  if (!sweep.fee_valid) return SampleSkip::FeeInvalid;
  if (sweep.steps.empty()) return SampleSkip::NoSteps;
  const auto& rows = history.rows();
  // The newest observation not after the sweep's last pose (the same instant in the simulator,
  // where poses and observations share the 60 Hz clock).
  auto end = std::upper_bound(rows.begin(), rows.end(), sweep.t1 + 1e-9,
                              [](double t, const ObsRow& r) { return t < r.stamp; });
  const long available = static_cast<long>(end - rows.begin());
  if (available < T) return SampleSkip::ShortHistory;
  const ObsRow& last = *(end - 1);
  if (sweep.t1 - last.stamp > max_gap_s) return SampleSkip::StaleHistory;

  PinnSample s;
  s.T = T;
  s.P = P;
  s.obs.resize(static_cast<std::size_t>(T) * kObsFeatures);
  s.theta_k.resize(static_cast<std::size_t>(P) * kThetaK);
  s.force.resize(static_cast<std::size_t>(P) * 2);
  s.profile.resize(static_cast<std::size_t>(P) * kProfile);
  const auto first = end - T;
  for (int t = 0; t < T; ++t) {
    const ObsRow& r = *(first + t);
    std::copy(r.features, r.features + kObsFeatures, s.obs.begin() + static_cast<long>(t) * kObsFeatures);
  }
  const Eigen::Vector2d t_hat = sweep.t_hat;
  for (int p = 0; p < P; ++p) {
    const ObsRow& r = *(end - P + p);
    float* th = s.theta_k.data() + static_cast<long>(p) * kThetaK;
    const double vals[5] = {
        interpolateStep(sweep.steps, r.stamp, [](const SweepStep& x) { return x.rho_rad; }),
        interpolateStep(sweep.steps, r.stamp, [](const SweepStep& x) { return x.alpha_rad; }),
        interpolateStep(sweep.steps, r.stamp, [](const SweepStep& x) { return x.w_m; }),
        interpolateStep(sweep.steps, r.stamp, [](const SweepStep& x) { return x.d_m; }),
        interpolateStep(sweep.steps, r.stamp, [](const SweepStep& x) { return x.q_n; })};
    for (int i = 0; i < 5; ++i) {
      if (!std::isfinite(vals[i])) return SampleSkip::NonFiniteThetaK;
      th[i] = static_cast<float>(vals[i]);
    }
    th[kSpeed] = static_cast<float>(r.blade_velocity_map.head<2>().dot(t_hat));
    float* pr = s.profile.data() + static_cast<long>(p) * kProfile;
    pr[kArea] = static_cast<float>(interpolateStep(sweep.steps, r.stamp, [](const SweepStep& x) { return x.area_m2; }));
    pr[kDepth2] = static_cast<float>(interpolateStep(sweep.steps, r.stamp, [](const SweepStep& x) { return x.depth2_m3; }));
    s.force[static_cast<std::size_t>(p) * 2] = static_cast<float>(r.force_map_N.head<2>().dot(t_hat));
    s.force[static_cast<std::size_t>(p) * 2 + 1] = static_cast<float>(r.force_map_N.z());
  }
  s.t0 = sweep.t0;
  s.t1 = sweep.t1;
  s.anchor_stamp = last.stamp;
  s.sweep_index = sweep.sweep_index;
  s.machine_id = sweep.machine_id;
  out = std::move(s);
  return SampleSkip::None;
}

int applySlicedGeometry(float* theta_k, const float* profile, int P) {
  int changed = 0;
  for (int p = 0; p < P; ++p) {
    double d = 0, w = 0;
    if (!fee::slicedWedge(profile[p * kProfile + kArea], profile[p * kProfile + kDepth2], d, w)) continue;
    float* th = theta_k + p * kThetaK;
    th[kDepth] = static_cast<float>(d);
    th[kWidth] = static_cast<float>(w);
    ++changed;
  }
  return changed;
}

}  // namespace terramap::soil
