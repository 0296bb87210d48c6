#pragma once
/// \file
/// The events that flow through an Engine. All stamps are seconds (double, any epoch, but
/// monotonically non-decreasing within a run). All transforms are `T_a_b`: they map
/// coordinates in frame b into frame a (p_a = T_a_b * p_b). Frames: `map` (the LayeredMap's
/// frame, z up), `sensor` (the LiDAR), `base` (vehicle chassis: x forward, y left, z up),
/// `blade` (see BladePose).
#include <terramap/core/error.hpp>

#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <limits>
#include <string>
#include <variant>
#include <vector>

namespace terramap {

/// One LiDAR return in the sensor frame (metres). NaN coordinates are allowed: the fusion
/// plugin drops and counts them. `intensity` is sensor-specific (KITTI reflectance 0..1,
/// LAS intensity 0..65535); NaN if the source has none.
struct PointXYZI {
  float x = 0, y = 0, z = 0, intensity = 0;
};

/// A point cloud in the sensor frame with the sensor pose in the map frame at `stamp`.
struct PointCloud {
  double stamp = 0.0;
  std::string frame = "sensor";
  Eigen::Isometry3d T_map_sensor = Eigen::Isometry3d::Identity();
  std::vector<PointXYZI> points;
};

/// Vehicle (base) pose in the map frame. Plugins that move the map with the robot take it.
struct Pose {
  double stamp = 0.0;
  std::string frame = "base";
  Eigen::Isometry3d T_map_base = Eigen::Isometry3d::Identity();
};

/// Geometry of a flat blade (ground-engaging tool), metres. Zero thickness.
struct BladeGeometry {
  double width_m = 1.85;   ///< along the cutting edge
  double height_m = 0.76;  ///< from the cutting edge up the blade face
};

/// Blade pose. Blade frame: origin at the centre of the cutting edge; x is the blade-face
/// normal pointing forward (the direction the blade pushes soil); y runs along the cutting
/// edge to the left; z runs up the blade face (for an upright blade, z is map-up).
/// The blade quad is {(0, y, z) : |y| <= width/2, 0 <= z <= height} in the blade frame.
struct BladePose {
  double stamp = 0.0;
  std::string machine_id;
  Eigen::Isometry3d T_map_blade = Eigen::Isometry3d::Identity();
  BladeGeometry geometry;
};

/// The vehicle's state and actions at one instant (60 Hz in the simulator), what the soil
/// estimator takes. Twists are [vx, vy, vz, wx, wy, wz] in the body's own frame (m/s, rad/s).
/// Indices in the 3-arrays: 0 = lift, 1 = tilt, 2 = angle cylinder. Tracks: 0 = left, 1 = right.
/// Unmeasured quantities are NaN.
struct Observation {
  double stamp = 0.0;
  std::string machine_id;
  Eigen::Isometry3d T_map_base = Eigen::Isometry3d::Identity();
  Eigen::Matrix<double, 6, 1> twist_base = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Isometry3d T_map_blade = Eigen::Isometry3d::Identity();
  Eigen::Matrix<double, 6, 1> twist_blade = Eigen::Matrix<double, 6, 1>::Zero();
  std::array<double, 3> cylinder_length_m{};
  std::array<double, 3> cylinder_velocity_mps{};
  std::array<double, 2> track_speed_mps{};
  double engine_speed_rpm = 0.0;
  /// Commanded actions: [left track speed, right track speed, lift rate, tilt rate, angle rate].
  std::array<double, 5> action{};
  /// Soil-on-blade force measured by the force sensor, newtons, in the base frame.
  Eigen::Vector3d force_base_N = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
};

/// A clock tick: lets plugins do periodic work (time-variance growth, erosion) between data.
struct Tick {
  double stamp = 0.0;
};

/// One inertial measurement, in the IMU's own frame (x, y, z of its case; right-handed).
/// `accel_mps2` is the specific force f = R_map_imu^T (a - g), g = (0, 0, -9.80665) m/s^2 in
/// the map frame, so an IMU at rest reads +9.81 m/s^2 along its up axis; `gyro_radps` the angular
/// rate. Both include the sensor's bias and noise. `stamp` is the instant measured (s): a
/// simulated sample may be delivered one sample period after it (docs/sim.md "IMUs"). NaN =
/// axis not measured.
struct ImuSample {
  double stamp = 0.0;
  std::string frame;  ///< "<machine>/<sensor id>" in the simulator
  Eigen::Vector3d accel_mps2 = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_radps = Eigen::Vector3d::Zero();
};

/// An excavator's manipulator as the machine itself knows it (TERA's JointState, end-effector
/// transform and bucket mass): joints in the order slew, boom, arm, bucket. `position_rad` is the
/// encoders' reading, `velocity_radps` the joint rates over the last physics step, `effort_nm`
/// each actuator's static effort (N·m, positive toward positive angles; from its pressures on a
/// real machine), `T_map_bucket` the bucket frame (at its pivot; x toward the lip, z toward its
/// back) from the localisation's base pose and the measured joints, `bucket_load_kg` the soil
/// in the bucket, `T_map_link` the four link frames the same way (slew = the upper structure on
/// the slew bearing; boom and arm at their pivots, x along the link; the bucket's frame as
/// T_map_bucket): where a self-filter places the arm's boxes. docs/sim.md "Excavators".
struct JointState {
  double stamp = 0.0;
  std::string machine_id;
  std::array<double, 4> position_rad{}, velocity_radps{}, effort_nm{};
  Eigen::Isometry3d T_map_bucket = Eigen::Isometry3d::Identity();
  std::array<Eigen::Isometry3d, 4> T_map_link{Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity(),
                                              Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity()};
  double bucket_load_kg = 0.0;
};

using Event = std::variant<PointCloud, Pose, BladePose, Observation, Tick, ImuSample, JointState>;

/// Event kinds as bits, so plugins can subscribe to several.
enum class EventKind : std::uint32_t {
  PointCloud = 1u << 0,
  Pose = 1u << 1,
  BladePose = 1u << 2,
  Observation = 1u << 3,
  Tick = 1u << 4,
  Imu = 1u << 5,
  JointState = 1u << 6,
};
using EventMask = std::uint32_t;
constexpr EventMask operator|(EventKind a, EventKind b) {
  return static_cast<EventMask>(a) | static_cast<EventMask>(b);
}
constexpr EventMask operator|(EventMask a, EventKind b) { return a | static_cast<EventMask>(b); }
constexpr EventMask mask(EventKind k) { return static_cast<EventMask>(k); }

/// Kind of an event (the variant's alternative as a bit).
inline EventKind kindOf(const Event& e) {
  return static_cast<EventKind>(1u << e.index());
}
/// Stamp of any event.
inline double stampOf(const Event& e) {
  return std::visit([](const auto& ev) { return ev.stamp; }, e);
}
/// Lower-case name of a kind ("point_cloud", "pose", "blade_pose", "observation", "tick", "imu",
/// "joint_state").
TERRAMAP_API const char* kindName(EventKind k);
/// The mask of kinds named in `names` (as kindName spells them). The first name that is not
/// a kind is stored in `*unknown` (if given) and the mask of the valid ones is returned.
TERRAMAP_API EventMask eventMaskFromNames(const std::vector<std::string>& names, std::string* unknown = nullptr);

}  // namespace terramap
