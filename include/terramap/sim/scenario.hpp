#pragma once
/// \file
/// A simulator scenario (TERA-style YAML): truth terrain, soil zones, machines with their
/// sensors, duration and seed. `loadScenario` validates everything before a simulation starts
/// and reports every mistake at once: one ConfigError with a line "file:line:col: key.path:
/// message" per mistake; unknown keys come with a did-you-mean. The YAML schema is documented in docs/sim.md; configs/scenarios/ has examples.
/// Units: metres, seconds, radians in the structs (YAML takes *_deg keys for angles).
#include <terramap/core/events.hpp>
#include <terramap/sim/command_log.hpp>
#include <terramap/sim/dem.hpp>
#include <terramap/sim/localisation.hpp>
#include <terramap/sim/machine_shape.hpp>
#include <terramap/soil/soil_table.hpp>

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace terramap::sim {

// The soil table lives in terramap::soil (the estimator shares it); the simulator's scenarios
// and truth speak of its families and properties directly.
using soil::parseSoilFamily;
using soil::SoilFamily;
using soil::soilFamilyName;
using soil::soilFamilyNames;
using soil::SoilProperties;
using soil::soilProperties;

/// One Gaussian bump of the truth terrain: h += amplitude * exp(-|p - c|^2 / (2 sigma^2)).
struct GaussianBump {
  double x_m = 0, y_m = 0, amplitude_m = 0, sigma_m = 1;
};

/// Truth terrain: a regular grid of height nodes (node (i, j) at origin + (i, j) * resolution)
/// with bilinear interpolation between nodes.
struct TerrainSpec {
  double origin_x_m = 0, origin_y_m = 0;  ///< map position of node (0, 0)
  double size_x_m = 20, size_y_m = 20;    ///< extent; nodes = round(size / resolution) + 1
  double resolution_m = 0.02;             ///< node spacing, <= 0.02 m per ALGORITHMS.md §J
  double base_height_m = 0;
  double slope_x = 0, slope_y = 0;        ///< plane term dh/dx, dh/dy added to the base
  /// Explicit bumps (from YAML `hills.list`) plus `hills.count` random ones drawn from the
  /// ranges below with `hills.seed` (already expanded by loadScenario, so `bumps` is complete).
  std::vector<GaussianBump> bumps;
  /// DEM added to the analytic surface (dem.path empty = none): ESRI ASCII, GeoTIFF or LAS
  /// ground points (dem.hpp), in the map frame after subtracting the geo origin. It is
  /// resampled bilinearly onto the node grid; nodes outside the DEM are an error.
  DemSpec dem;
  /// The DEM as loaded by loadScenario (which needs its extent), so buildTerrain does not read
  /// the file again; buildTerrain loads `dem` itself when this is null.
  std::shared_ptr<const DemGrid> dem_grid;
  /// World (E, N, Z) of map (0, 0, 0) the DEM was shifted by (zero without a DEM).
  Eigen::Vector3d dem_geo_origin = Eigen::Vector3d::Zero();
  double snapshot_interval_s = 1.0;  ///< truth heightmaps written every this many seconds
};

/// Where a soil zone applies. A zone with no region applies everywhere (in its depth range).
struct SoilZone {
  std::string name;
  SoilProperties soil;
  enum class Region { Everywhere, StripX, StripY, Polygon } region = Region::Everywhere;
  double lo_m = 0, hi_m = 0;                 ///< strip bounds (x or y) for StripX/StripY
  std::vector<Eigen::Vector2d> polygon;      ///< map xy, any orientation, not self-intersecting
  /// Depth range below the *initial* surface (m, positive down) where the zone applies, at map
  /// (0, 0); with a dip both bounds shift by depth_dip · (x, y) (a tilted stratum: m per m).
  double depth_min_m = 0, depth_max_m = std::numeric_limits<double>::infinity();
  Eigen::Vector2d depth_dip = Eigen::Vector2d::Zero();
  /// Depth (m below the initial surface) of the zone's top / bottom at map (x, y).
  double depthMinAt(double x, double y) const { return depth_min_m + depth_dip.x() * x + depth_dip.y() * y; }
  double depthMaxAt(double x, double y) const { return depth_max_m + depth_dip.x() * x + depth_dip.y() * y; }
};

/// A scalar set-point that drifts as a reflected random walk (paper §3.1):
/// x += sigma * sqrt(dt) * N(0, 1), reflected into [min, max]; sigma = 0 keeps it constant.
struct RandomWalk {
  double initial = 0, min = 0, max = 0, sigma = 0;  ///< sigma in units per sqrt(second)
};

/// One revolute joint of an excavator's manipulator (TERA Eq. 1: the joint rate answers a
/// change Δ of its steady-state rate ω_ss = lever · max_rate with the transient
/// Δ sin(η t + φ) e^{-β t}; docs/sim.md "Excavators").
struct ArmJointSpec {
  double min_rad = -M_PI, max_rad = M_PI;
  double max_rate_rps = 1.0;     ///< steady-state rate at full lever, rad/s
  double max_torque_nm = 1e5;    ///< hydraulic relief: beyond it the joint cannot lift its load
  double eta = 20, beta = 6, phi = 0;  ///< TERA's values (Eq. 1: frequency, decay, phase)
};

/// The manipulator of an excavator (Takeuchi TB235-class defaults, TERA's example machine):
/// slew, boom, arm and bucket joints, [0..3] in every array. Geometry in the *slew* frame (the
/// upper structure: origin on the slew axis at the slew bearing, x forward along the boom's
/// plane, z up): the boom pivots about the slew frame's y axis at (boom_pivot_x_m, 0,
/// boom_pivot_z_m); every link is a straight line from its pivot to the next (boom pivot to
/// arm pivot, arm pivot to bucket pivot, bucket pivot to the bucket's cutting edge, the lip).
/// Joint angles: slew = yaw of the upper structure relative to the base (rad, left positive);
/// boom = the boom line above the slew frame's horizontal; arm = the arm line relative to the
/// boom line; bucket = the pivot→lip line relative to the arm line (positive raises, i.e.
/// opens; curling the bucket in is negative).
struct ArmSpec {
  double slew_x_m = -0.2, slew_z_m = 0.55;        ///< slew axis in the base frame
  double boom_pivot_x_m = 0.45, boom_pivot_z_m = 0.75;
  double boom_m = 2.55, arm_m = 1.35, bucket_m = 0.72;
  /// Bucket: a closed mesh, the prism of a convex profile (x along pivot→lip, z toward its back,
  /// metres in the bucket frame; the opening faces -z) extruded over the width. Empty = the
  /// default profile from bucket_m and bucket_depth_m (docs/sim.md).
  std::vector<Eigen::Vector2d> bucket_profile;
  double bucket_width_m = 0.6, bucket_depth_m = 0.34;
  /// Heaped capacity (m^3 of loose soil); 0 = the mesh's own volume.
  double bucket_capacity_m3 = 0;
  double pour_rate_m3ps = 0.25;   ///< how fast soil beyond what the bucket can hold pours out
  double edge_thickness_m = 0.02; ///< bearing area of the lip (penetration resistance)
  int bucket_slices = 9;          ///< FEE slices across the bucket width
  std::array<double, 4> mass_kg{900, 210, 105, 95};  ///< upper structure, boom, arm, bucket
  std::array<ArmJointSpec, 4> joints{{
      {-M_PI, M_PI, 1.0, 2.0e4, 20, 6, 0},                           // slew (9.5 rpm)
      {-55 * M_PI / 180, 65 * M_PI / 180, 0.55, 5.2e4, 20, 6, 0},    // boom
      {-155 * M_PI / 180, -30 * M_PI / 180, 0.75, 3.2e4, 20, 6, 0},  // arm
      {-200 * M_PI / 180, 30 * M_PI / 180, 1.1, 1.6e4, 20, 6, 0}}};  // bucket
  std::array<double, 4> initial_rad{0, 20 * M_PI / 180, -100 * M_PI / 180, -110 * M_PI / 180};
  /// Joint encoders / inclinometers: 1σ white noise of the measured joint angles (rad).
  double encoder_noise_rad = 0.1 * M_PI / 180;
  /// Inclinometers on boom, arm and bucket (link angle to gravity): 1σ white noise (rad).
  double inclinometer_noise_rad = 0.2 * M_PI / 180;
};

/// The dig-and-dump cycle (controller type dig_dump; an excavator only): dig at `dig` (map xy) by
/// lowering the lip `depth_m` below the surface there and dragging it `drag_m` towards the
/// machine, curl, lift, slew to `dump` (map xy), open the bucket over it, slew back. Each
/// cycle digs `advance_m` further from the machine (a trench grows outwards).
struct DigDumpSpec {
  Eigen::Vector2d dig{3.5, 0}, dump{0, 3.5};
  double depth_m = 0.25, drag_m = 1.0, advance_m = 0.15;
  double carry_height_m = 1.0;   ///< lip above the dig surface while slewing
  int cycles = 0;                ///< 0 = as many as the duration allows
};

/// Controller of a machine.
struct ControllerSpec {
  /// External: the levers come from the caller (Simulator::setLevers, sim/env.hpp), held
  /// between calls; without a caller (`terramap sim`) the machine stands still.
  enum class Type { RandomWalk, Route, Replay, DigDump, External } type = Type::RandomWalk;
  DigDumpSpec dig_dump;  ///< type DigDump (excavators)
  // Replay (type Replay): recorded commands (command_log.hpp), read by loadScenario from
  // `replay_path` (the YAML's `file`, resolved against the scenario's folder) in `replay_units`.
  std::string replay_path;
  CommandLog::Units replay_units = CommandLog::Units::Lever;
  std::shared_ptr<const CommandLog> replay;
  // Random-walk set-points (type RandomWalk).
  RandomWalk speed_mps{0.8, 0.3, 1.4, 0.15};
  RandomWalk depth_m{0.08, 0.0, 0.2, 0.03};       ///< blade edge below the track contact plane
  RandomWalk roll_rad{0, -0.08, 0.08, 0.03};      ///< blade roll relative to the chassis
  RandomWalk yaw_rad{0, -0.2, 0.2, 0.05};         ///< blade angle relative to the chassis
  RandomWalk heading_rad{0, -0.5, 0.5, 0.1};      ///< chassis heading relative to the start
  // Route (type Route): parallel passes; each pass drives forward from its start along
  // `heading` for `length` with the blade at `depth`, then reverses with the blade raised and
  // shifts by `spacing` (to the left of the heading) for the next pass. With `route_loop` the
  // passes never end: after the last lane the lanes are taken in reverse order, then forward
  // again (lanes 0, 1, .., n-1, n-2, .., 1, 0, 1, ..), so a long run stays on the terrain.
  Eigen::Vector2d route_start{0, 0};
  double route_heading_rad = 0, route_length_m = 10, route_spacing_m = 1.6;
  int route_passes = 3;
  bool route_loop = false;
  double route_depth_m = 0.1, route_speed_mps = 0.8, route_return_speed_mps = 1.2;
  /// Route only, cut to grade (GNSS machine control): with `route_grade`, forward passes hold the
  /// cutting edge at the map height grade_first_m + k * grade_step_m on pass k (0-based), never
  /// below grade_lowest_m, instead of `route_depth_m` below the tracks; repeated passes down one
  /// lane then deepen it whatever loose soil the tracks ride on.
  bool route_grade = false;
  double grade_first_m = -0.1, grade_step_m = -0.1, grade_lowest_m = -1.0;
  /// Raise the blade when the measured speed stays below `stall_ratio` * set-point for
  /// `stall_time_s` (speed tracking failed): rate of the raise, m/s.
  double stall_ratio = 0.5, stall_time_s = 0.3, raise_rate_mps = 0.15;
  /// Route only: after this long (s) of failed speed tracking in a forward pass, the pass is
  /// given up (the machine reverses and takes the next lane), as an operator backs off a pile the
  /// machine cannot push; 0 (the default) = never, the machine keeps pushing.
  double stall_give_up_s = 0.0;
};

/// A sensor mounted on a machine. Pose offset T_base_sensor from `offset` (m) and
/// `rotation_deg` (roll, pitch, yaw applied as Rz(yaw) * Ry(pitch) * Rx(roll)). There is no
/// pose sensor: every pose the mapper receives comes from the machine's `localisation`.
struct SensorSpec {
  std::string id;
  enum class Type { Lidar, Force, DepthCamera, Imu } type = Type::Lidar;
  Eigen::Isometry3d T_base_sensor = Eigen::Isometry3d::Identity();
  // LiDAR: `beams` rows at elevations spread evenly over [vfov_min, vfov_max] (one beam: the
  // mean), `columns` azimuths over hfov (centred on the sensor x axis), one scan per 1/rate.
  int beams = 64, columns = 1024;
  double vfov_min_rad = -22.5 * M_PI / 180, vfov_max_rad = 22.5 * M_PI / 180;
  double hfov_rad = 2 * M_PI;
  double rate_hz = 10;
  double min_range_m = 0.3, max_range_m = 60;
  double range_noise_m = 0.02;  ///< 1-sigma Gaussian range noise
  double dropout = 0.0;         ///< probability a return is lost (returned as NaN point)
  bool keep_dropouts = false;   ///< emit NaN points for misses/dropouts (organized cloud)
  // Depth camera (type DepthCamera; docs/sim.md "Depth cameras"): a pinhole of `width` x
  // `height` pixels whose pixel (u, v) (u right, v down, 0-based, pixel centres) looks along
  // ((u - cx) / fx, (v - cy) / fy, 1) in the *optical* frame (x right, y down, z along the view
  // axis). The mount (T_base_sensor as read from offset/rotation) places the camera *body*
  // (x forward, y left, z up, as a LiDAR); loadScenario appends the body-to-optical rotation, so
  // for a camera T_base_sensor, the cloud's T_map_sensor and its points are in the optical
  // frame. The cloud is organised row-major (row v = 0 first) when keep_dropouts is set.
  // Depth is the optical z, kept in [min_range_m, max_range_m] (what a depth camera's range
  // means); noise sigma = depth_noise_abs_m + depth_noise_k * z^2 moves a point along its ray
  // (stereo / structured light: the disparity error maps to depth squared); `dropout` as above.
  int width = 424, height = 240;
  double fx = 0, fy = 0, cx = 0, cy = 0;       ///< pixels
  double depth_noise_abs_m = 0.001;            ///< m
  double depth_noise_k = 0.005;                ///< 1/m (sigma 2 cm at 2 m)
  // IMU (type Imu; docs/sim.md "IMUs"): on `link`, with T_base_sensor read as T_link_sensor,
  // sampled every physics_hz / rate_hz physics steps (a whole number). The continuous-time noise
  // model of Kalibr / the IEEE standard: white noise of the given densities and biases that
  // start at N(0, bias_sigma^2) per axis and random-walk with the given densities. Defaults: an
  // ADIS16448-class MEMS unit (its datasheet densities).
  /// The frame an IMU, a LiDAR or a depth camera hangs on (`link:`; a force sensor is always
  /// the base's); T_base_sensor is then read as T_link_sensor. Slew, Boom, Arm, Bucket: an
  /// excavator's link frames (ExcavatorArm::linkFrames; TERA's IMUs on chassis, boom, arm and
  /// bucket, its camera on the cab = slew). A ray-cast sensor on a moving link is posed by the
  /// link's true frame at the scan; its cloud carries the machine's estimate of that frame (the
  /// localisation's base pose and the joints as the encoders or cylinder sensors read them).
  enum class Link { Base, Blade, Slew, Boom, Arm, Bucket } link = Link::Base;
  double accel_noise_density = 2.0e-3;  ///< m/s^2/sqrt(Hz)
  double gyro_noise_density = 1.7e-4;   ///< rad/s/sqrt(Hz)
  double accel_bias_walk = 3.0e-3;      ///< m/s^3/sqrt(Hz)
  double gyro_bias_walk = 2.0e-5;       ///< rad/s^2/sqrt(Hz)
  double accel_bias_sigma = 0.05;       ///< m/s^2, initial bias (1 sigma per axis)
  double gyro_bias_sigma = 0.002;       ///< rad/s
  // Force sensor noise: sigma = abs + rel * |F|.
  double force_noise_abs_n = 100, force_noise_rel = 0.02;
  /// A LiDAR or a depth camera: keep each ray's terrain hit and, while the sensor stays where
  /// it was (bit for bit), cast again only the rays over terrain that changed since
  /// (LidarModel::scan). The clouds are the same either way; off only to measure the cost.
  bool reuse_casts = true;
  /// A LiDAR or a depth camera: a sensor whose cloud is ray-cast (LidarModel).
  bool castsRays() const { return type == Type::Lidar || type == Type::DepthCamera; }
};

/// The scenario's name of a link (`link:` of a sensor, the episode's `link` attributes).
const char* linkName(SensorSpec::Link link);

/// A compact track loader (CAT 299-class defaults: ALGORITHMS.md §L; docs/sim.md), or with
/// `arm` an excavator: the same tracked undercarriage and dozer blade (the excavator's plow,
/// held where the controller leaves it) carrying a slewing upper structure with a manipulator.
struct MachineSpec {
  std::string id;
  double x_m = 0, y_m = 0, yaw_rad = 0;  ///< initial pose of the base frame
  BladeGeometry blade;                   ///< 1.85 m x 0.76 m
  double rake_rad = 80 * M_PI / 180;     ///< blade face to horizontal through the soil
  double blade_mount_x_m = 1.9;          ///< cutting-edge centre ahead of the base origin
  double mass_kg = 5200;
  double track_gauge_m = 1.6, track_length_m = 1.9;
  double traction_coefficient = 0.75;    ///< max tractive force = coeff * weight * cos(pitch)
  double max_drive_force_n = 42000;      ///< hydrostatic drive limit
  double rolling_resistance = 0.04;      ///< fraction of weight (the running gear's own losses)
  /// Track–soil interaction (YAML vehicle.track_soil: bekker; docs/sim.md "Track–soil
  /// interaction"): the tractive limit becomes A c + W cos(pitch) tan(phi) of the soil under
  /// the machine (instead of traction_coefficient W), mobilised with slip by Janosi–Hanamoto,
  /// the Bekker compaction resistance adds to rolling_resistance, and each track presses its
  /// static sinkage into the truth terrain (ruts). On for every tracked machine (CTL and
  /// excavator) unless the scenario says `track_soil: none` (the ablation: fixed traction
  /// coefficient, no ruts).
  bool track_soil = true;
  double track_width_m = 0.45;           ///< one track's width (CAT 299-class: 450 mm)
  double max_speed_mps = 2.5;
  double drive_time_constant_s = 0.2;    ///< track speed response to its command
  double yaw_time_constant_s = 0.25;
  // Blade joints: [lift (m, edge height above the contact plane), tilt (rad, roll), angle (rad, yaw)].
  std::array<double, 3> joint_min{-0.35, -0.26, -0.52}, joint_max{0.9, 0.26, 0.52};
  std::array<double, 3> joint_max_rate{0.5, 0.5, 0.6};
  /// Joint velocity response (TERA Eq. 1 with phi = -pi/2): each joint's rate follows its
  /// command as a damped second-order system whose step response is
  /// 1 - exp(-beta t) cos(eta t) scaled; beta = 0 selects a first-order lag with time
  /// constant `joint_tau_s`.
  double joint_eta = 20, joint_beta = 6, joint_tau_s = 0.08;
  /// Downward force the lift can apply before the blade is pushed up (N).
  double lift_down_force_n = 26000;
  double edge_thickness_m = 0.025;  ///< bearing area of the cutting edge (penetration resistance)
  int blade_slices = 37;            ///< FEE slices across the blade width
  /// Coloured (Ornstein-Uhlenbeck) force noise of the truth physics: sigma = abs + rel |F|.
  double force_noise_abs_n = 150, force_noise_rel = 0.05, force_noise_tau_s = 0.15;
  double engine_rated_rpm = 2500, engine_droop_rpm = 450;
  ControllerSpec controller;
  std::vector<SensorSpec> sensors;
  /// How the poses the mapper receives (base, each cloud's sensor, blade) differ from the truth
  /// (YAML `localisation:`; the scenario-wide one, else RTK-GNSS + IMU, when absent).
  LocalisationSpec localisation = LocalisationSpec::rtkImu();
  /// `type: excavator`: the manipulator (absent for a compact track loader).
  std::optional<ArmSpec> arm;
  /// Solid boxes the simulated LiDARs see (machine_shape.hpp); defaultCtlShape() of the track
  /// and blade dimensions unless the scenario gives `shape:`.
  std::vector<ShapeBox> shape;
};

/// A survey of the site before the work starts (drone photogrammetry, a total-station or
/// terrestrial-scanner DEM): the initial truth surface sampled every `spacing_m` (each point
/// jittered uniformly within its square, so a map grid never aliases with it) with Gaussian
/// height noise `sigma_m`, delivered as PointClouds of frame "survey" with the first observation
/// period, one cloud per `block_m` square whose sensor sits `height_m` above the square's highest
/// point (so a range-limited fusion still reaches the corners; keep sqrt(2) block_m / 2 and
/// height_m within the fusion's max range). Real machines start on surveyed sites; without it
/// the ground the machine starts on is unknown to a mast LiDAR (its lowest beam reaches the
/// ground several metres ahead) until the machine has driven past it. Off (spacing_m = 0) by
/// default; the points are the same bits for a seed whatever the thread count.
struct SurveySpec {
  double spacing_m = 0;    ///< 0 = no survey
  double sigma_m = 0.02;   ///< 1σ height noise of a survey point
  double height_m = 15;    ///< survey sensor above the block's highest point
  double block_m = 10;     ///< side of the square one cloud covers
  bool enabled() const { return spacing_m > 0; }
};

struct Scenario {
  std::string name;
  std::string source_path;  ///< file it was loaded from ("" if from a string)
  std::string yaml_text;    ///< the verbatim YAML (stored in the episode)
  std::uint64_t seed = 1;
  double duration_s = 10;
  double physics_hz = 240;      ///< internal step (multiple of observation_hz)
  double observation_hz = 60;   ///< Observation/Pose/BladePose events and next() step
  int threads = 2;              ///< LiDAR ray-casting threads (results independent of it)
  /// With threads >= 2: run the physics ahead while LiDAR scans are cast (results identical;
  /// costs a second copy of the truth terrain). See Simulator.
  bool overlap_scans = true;
  /// The LiDARs see the machines (their own and the others): rays stop on them and return
  /// points there. `lidar_sees_machines: false` casts against the terrain only (ablation).
  bool lidar_sees_machines = true;
  /// Machines collide (machine_contact.hpp): their boxes are kept apart. `machines_collide:
  /// false` lets them pass through each other (ablation).
  bool machines_collide = true;
  TerrainSpec terrain;
  SoilProperties default_soil = soilProperties(SoilFamily::Loam, 0.5);
  std::vector<SoilZone> zones;  ///< later zones override earlier ones
  /// Top-level `localisation:`: the default of machines without their own (rtk_imu if absent).
  LocalisationSpec localisation = LocalisationSpec::rtkImu();
  std::vector<MachineSpec> machines;
  SurveySpec survey;  ///< top-level `survey:` (off when absent)
};

/// Loads and validates a scenario file. Relative paths inside (DEM) resolve against the
/// file's folder. \throws ConfigError (every mistake of the YAML, one per line) or, when the
/// YAML has none, InputError for a DEM that cannot be read.
/// Ablations on a loaded scenario: every machine's localisation replaced by `name` ("perfect"
/// or "rtk_imu"; "" leaves them). \throws ConfigError naming `what` on another name.
void overrideLocalisation(Scenario& sc, const std::string& name, const std::string& what);
/// Ablation: every machine's track–soil model set to `model` ("bekker", the default, or "none":
/// fixed traction coefficient, no ruts; "" leaves them). \throws ConfigError naming `what`.
void overrideTrackSoil(Scenario& sc, const std::string& model, const std::string& what);

Scenario loadScenario(const std::string& yaml_path);
/// Same from a YAML string; `name_for_errors` stands in for the file name in messages and
/// relative paths resolve against `base_dir`.
Scenario parseScenario(const std::string& yaml_text, const std::string& name_for_errors,
                       const std::string& base_dir = ".");

/// LiDAR presets by name ("vlp32", "os1_64", "os1_128", "single_line"): beams, fov, columns.
/// Returns false for an unknown name. Used by loadScenario for `preset:`.
bool applyLidarPreset(const std::string& name, SensorSpec& s);
std::vector<std::string> lidarPresetNames();

}  // namespace terramap::sim
