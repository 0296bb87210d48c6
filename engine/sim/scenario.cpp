// Scenario YAML loading and validation (schema in docs/sim.md). Every mistake is collected by
// the shared strict reader (engine/yaml) and reported at once; a section with a wrong value goes
// on with its default so the keys after it are still checked.
#include "yaml/reader.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/excavator.hpp>
#include <terramap/sim/truth_terrain.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <set>
#include <sstream>

namespace terramap::sim {
namespace {

using yaml::MapReader;
namespace fs = std::filesystem;

constexpr double kDeg = M_PI / 180.0;

struct Ctx {
  std::string file;
  std::string base_dir;
  yaml::Diagnostics diag;
  // A DEM that could not be read: thrown (as the InputError it is) only when the YAML itself has
  // no errors, so the user first sees every mistake in the file.
  std::exception_ptr dem_failure;
};

SoilProperties readSoil(MapReader& r) {
  const std::string fam = r.strRequired("family");
  SoilFamily f{};
  if (r.has("family") && r.node("family").IsScalar() && !parseSoilFamily(fam, f))
    r.error(r.node("family"), "family", "unknown soil family '" + fam + "'" + didYouMean(fam, soilFamilyNames()) +
                                            " (known: " + joinStrings(soilFamilyNames()) + ")");
  const bool has_frac = r.has("relative_density"), has_pct = r.has("relative_density_pct");
  if (has_frac && has_pct)
    r.error(r.node("relative_density"), "relative_density",
            "give relative_density (0..1) or relative_density_pct, not both");
  double id = 0.5;
  if (has_frac) id = r.num("relative_density", 0.5, 0.0, 1.0);
  else if (has_pct) id = r.num("relative_density_pct", 50.0, 0.0, 100.0) / 100.0;
  else r.error(r.self(), "relative_density", "missing (relative density I_d in [0, 1], or relative_density_pct)");
  return soilProperties(f, id);
}

/// [min, max] at `key` scaled by `scale`, inside [min_allowed, max_allowed] (already scaled);
/// lo and hi stay as they were when the key is absent or wrong.
void readRange(MapReader& r, const std::string& key, double& lo, double& hi, double min_allowed, double max_allowed,
               double scale = 1.0) {
  if (!r.has(key)) return;
  const YAML::Node n = r.node(key);
  std::vector<double> v;
  if (!r.numList(n, key, 2, v)) return;
  const double a = v[0] * scale, b = v[1] * scale;
  if (!(a <= b)) {
    r.error(n, key, "expected [min, max] with min <= max");
    return;
  }
  if (a < min_allowed || b > max_allowed) {
    std::ostringstream os;
    os << "range must lie within [" << min_allowed / scale << ", " << max_allowed / scale << "]";
    r.error(n, key, os.str());
    return;
  }
  lo = a;
  hi = b;
}

RandomWalk readWalk(MapReader& parent, const std::string& key, RandomWalk def, double scale, double lo, double hi) {
  if (!parent.has(key)) return def;
  MapReader r = parent.child(key);
  RandomWalk w = def;
  readRange(r, "range", w.min, w.max, lo, hi, scale);
  w.initial = r.num("initial", def.initial / scale, lo / scale, hi / scale) * scale;
  w.sigma = r.num("sigma", def.sigma / scale, 0.0, 1e6) * scale;
  if (w.initial < w.min || w.initial > w.max) r.error(r.self(), "initial", "initial value outside range");
  r.finish();
  return w;
}

Eigen::Isometry3d readMount(MapReader& r) {
  const auto off = r.vec("offset_m", {0, 0, 0}, 3);
  const auto rot = r.vec("rotation_deg", {0, 0, 0}, 3);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(off[0], off[1], off[2]);
  T.linear() = (Eigen::AngleAxisd(rot[2] * kDeg, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(rot[1] * kDeg, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(rot[0] * kDeg, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  return T;
}

void readLidar(MapReader& r, SensorSpec& s) {
  if (r.has("preset")) {
    const std::string p = r.strRequired("preset");
    if (!applyLidarPreset(p, s))
      r.error(r.node("preset"), "preset", "unknown LiDAR preset '" + p + "'" + didYouMean(p, lidarPresetNames()) +
                                              " (known: " + joinStrings(lidarPresetNames()) + ")");
  }
  s.beams = r.integer("beams", s.beams, 1, 512);
  s.columns = r.integer("columns", s.columns, 1, 8192);
  double lo = s.vfov_min_rad, hi = s.vfov_max_rad;
  readRange(r, "vertical_fov_deg", lo, hi, -M_PI / 2, M_PI / 2, kDeg);
  s.vfov_min_rad = lo;
  s.vfov_max_rad = hi;
  s.hfov_rad = r.num("horizontal_fov_deg", s.hfov_rad / kDeg, 0.0, 360.0) * kDeg;
  s.rate_hz = r.num("rate_hz", s.rate_hz, 0.1, 1000.0);
  double rmin = s.min_range_m, rmax = s.max_range_m;
  readRange(r, "range_m", rmin, rmax, 0.0, 1e4);
  s.min_range_m = rmin;
  s.max_range_m = rmax;
  s.range_noise_m = r.num("range_noise_m", s.range_noise_m, 0.0, 10.0);
  s.dropout = r.num("dropout", s.dropout, 0.0, 1.0);
  s.keep_dropouts = r.boolean("keep_dropouts", s.keep_dropouts);
}

// The camera body (x forward, y left, z up) to the optical frame (x right, y down, z forward):
// the columns are the optical axes in body coordinates.
Eigen::Matrix3d bodyFromOptical() {
  Eigen::Matrix3d R;
  R << 0, 0, 1,  //
      -1, 0, 0,  //
      0, -1, 0;
  return R;
}

void readDepthCamera(MapReader& r, SensorSpec& s) {
  // Defaults: an Intel RealSense D435-class stereo camera in its 424 x 240 mode (87 deg
  // horizontal field of view, 0.3-10 m, 15 Hz), square pixels, principal point at the centre.
  s.width = r.integer("width", 424, 2, 4096);
  s.height = r.integer("height", 240, 2, 4096);
  const double hfov = r.num("horizontal_fov_deg", 87.0, 1.0, 170.0) * kDeg;
  const double f_default = 0.5 * s.width / std::tan(0.5 * hfov);
  if (r.has("fx") && r.has("horizontal_fov_deg"))
    r.error(r.node("fx"), "fx", "give either fx (pixels) or horizontal_fov_deg, not both");
  s.fx = r.num("fx", f_default, 1e-3, 1e6);
  s.fy = r.num("fy", s.fx, 1e-3, 1e6);
  s.cx = r.num("cx", 0.5 * (s.width - 1), -1e5, 1e5);
  s.cy = r.num("cy", 0.5 * (s.height - 1), -1e5, 1e5);
  s.rate_hz = r.num("rate_hz", 15.0, 0.1, 1000.0);
  double rmin = 0.3, rmax = 10.0;
  readRange(r, "depth_range_m", rmin, rmax, 0.0, 1e3);
  if (!(rmax > 0)) r.error(r.node("depth_range_m"), "depth_range_m", "the maximum depth must be > 0");
  s.min_range_m = rmin;
  s.max_range_m = rmax;
  s.depth_noise_abs_m = r.num("noise_abs_m", s.depth_noise_abs_m, 0.0, 10.0);
  s.depth_noise_k = r.num("noise_k_per_m", s.depth_noise_k, 0.0, 10.0);
  s.dropout = r.num("dropout", 0.0, 0.0, 1.0);
  s.keep_dropouts = r.boolean("keep_dropouts", s.keep_dropouts);
  s.T_base_sensor.linear() = s.T_base_sensor.linear() * bodyFromOptical();
}

/// The frames an IMU or a shape box can hang on, in the order of SensorSpec::Link and
/// ShapeBox::Frame: a loader's base and blade, and an excavator's four links besides.
std::vector<std::string> linkNames(bool excavator) {
  std::vector<std::string> names;
  const int n = excavator ? static_cast<int>(SensorSpec::Link::Bucket) + 1 : static_cast<int>(SensorSpec::Link::Slew);
  for (int k = 0; k < n; ++k) names.emplace_back(linkName(static_cast<SensorSpec::Link>(k)));
  return names;
}

/// The frame a sensor hangs on (`link`, default base), for IMUs, LiDARs and depth cameras.
void readLink(MapReader& r, SensorSpec& s, bool excavator) {
  const std::string link = r.str("link", "base");
  const std::vector<std::string> links = linkNames(excavator);
  const auto it = std::find(links.begin(), links.end(), link);
  if (it != links.end()) s.link = static_cast<SensorSpec::Link>(it - links.begin());
  else r.error(r.node("link"), "link", "unknown link '" + link + "' (known: " + joinStrings(links) + ")" + didYouMean(link, links));
}

void readImu(MapReader& r, SensorSpec& s, double physics_hz, bool excavator) {
  s.rate_hz = r.num("rate_hz", 120.0, 0.1, 10000.0);
  const double ratio = physics_hz / s.rate_hz;
  if (std::abs(ratio - std::round(ratio)) > 1e-9 || ratio < 1)
    r.error(r.node("rate_hz"), "rate_hz", "physics_hz (" + formatNumber(physics_hz) + ") must be a whole multiple of an IMU's rate_hz");
  s.accel_noise_density = r.num("accel_noise_density", s.accel_noise_density, 0.0, 10.0);
  s.gyro_noise_density = r.num("gyro_noise_density", s.gyro_noise_density, 0.0, 10.0);
  s.accel_bias_walk = r.num("accel_bias_walk", s.accel_bias_walk, 0.0, 10.0);
  s.gyro_bias_walk = r.num("gyro_bias_walk", s.gyro_bias_walk, 0.0, 10.0);
  s.accel_bias_sigma = r.num("accel_bias_sigma", s.accel_bias_sigma, 0.0, 100.0);
  s.gyro_bias_sigma = r.num("gyro_bias_sigma", s.gyro_bias_sigma, 0.0, 10.0);
}

SensorSpec readSensor(MapReader& r, double physics_hz, bool excavator) {
  SensorSpec s;
  s.id = r.strRequired("id");
  const std::string type = r.strRequired("type");
  const std::vector<std::string> types{"lidar", "force", "depth_camera", "imu"};
  if (type == "lidar") s.type = SensorSpec::Type::Lidar;
  else if (type == "force") s.type = SensorSpec::Type::Force;
  else if (type == "depth_camera") s.type = SensorSpec::Type::DepthCamera;
  else if (type == "imu") s.type = SensorSpec::Type::Imu;
  else if (type == "pose") {
    // Its noise was a second, inconsistent pose model (white noise on the Pose event only);
    // refused rather than silently ignored so no scenario believes it still applies.
    r.error(r.node("type"), "type",
            "the 'pose' sensor was replaced by the machine's 'localisation:' key (every pose the mapper "
            "receives comes from it; see docs/sim.md \"Localisation\"): remove this sensor");
    return s;
  } else {
    // The other keys depend on the type: checking them against a guess would only add noise.
    if (r.has("type")) r.error(r.node("type"), "type", "unknown sensor type '" + type + "'" + didYouMean(type, types));
    return s;
  }
  s.T_base_sensor = readMount(r);
  if (s.type != SensorSpec::Type::Force) readLink(r, s, excavator);
  if (s.type == SensorSpec::Type::Lidar) {
    readLidar(r, s);
  } else if (s.type == SensorSpec::Type::DepthCamera) {
    readDepthCamera(r, s);
  } else if (s.type == SensorSpec::Type::Imu) {
    readImu(r, s, physics_hz, excavator);
  } else {
    s.force_noise_abs_n = r.num("noise_abs_n", s.force_noise_abs_n, 0.0, 1e7);
    s.force_noise_rel = r.num("noise_rel", s.force_noise_rel, 0.0, 10.0);
  }
  r.finish();
  return s;
}

ControllerSpec readController(MapReader& r, const std::string& base_dir) {
  ControllerSpec c;
  const std::string type = r.str("type", "random_walk");
  if (type == "replay") {
    c.type = ControllerSpec::Type::Replay;
    fs::path p(r.strRequired("file"));
    if (p.is_relative()) p = fs::path(base_dir) / p;
    c.replay_path = p.lexically_normal().string();
    const std::string units = r.str("units", "lever");
    if (units != "lever" && units != "si")
      r.error(r.node("units"), "units", "unknown units '" + units + "' (lever: every value in [-1, 1]; si: m/s and rad/s)" +
                                            didYouMean(units, {"lever", "si"}));
    c.replay_units = units == "si" ? CommandLog::Units::Si : CommandLog::Units::Lever;
    r.finish();  // the log itself is read once the YAML has no mistakes (parseImpl)
    return c;
  }
  if (type == "external") {
    // Driven through the environment API (sim/env.hpp): it has no keys of its own.
    c.type = ControllerSpec::Type::External;
    r.finish();
    return c;
  }
  if (type == "dig_dump") {
    c.type = ControllerSpec::Type::DigDump;
    DigDumpSpec& d = c.dig_dump;
    const auto dig = r.vec("dig_m", {d.dig.x(), d.dig.y()}, 2);
    const auto dump = r.vec("dump_m", {d.dump.x(), d.dump.y()}, 2);
    if (dig.size() == 2) d.dig = {dig[0], dig[1]};
    if (dump.size() == 2) d.dump = {dump[0], dump[1]};
    d.depth_m = r.num("depth_m", d.depth_m, 0.0, 3.0);
    d.drag_m = r.num("drag_m", d.drag_m, 0.0, 5.0);
    d.advance_m = r.num("advance_m", d.advance_m, 0.0, 5.0);
    d.carry_height_m = r.num("carry_height_m", d.carry_height_m, 0.0, 5.0);
    d.cycles = r.integer("cycles", d.cycles, 0, 100000);
    r.finish();
    return c;
  }
  if (type == "random_walk") {
    c.type = ControllerSpec::Type::RandomWalk;
    c.speed_mps = readWalk(r, "speed_mps", c.speed_mps, 1.0, 0.0, 5.0);
    c.depth_m = readWalk(r, "depth_m", c.depth_m, 1.0, -1.0, 1.0);
    c.roll_rad = readWalk(r, "roll_deg", c.roll_rad, kDeg, -45 * kDeg, 45 * kDeg);
    c.yaw_rad = readWalk(r, "yaw_deg", c.yaw_rad, kDeg, -60 * kDeg, 60 * kDeg);
    c.heading_rad = readWalk(r, "heading_deg", c.heading_rad, kDeg, -M_PI, M_PI);
  } else if (type == "route") {
    c.type = ControllerSpec::Type::Route;
    const auto st = r.vec("start_m", {0, 0}, 2);
    c.route_start = {st[0], st[1]};
    c.route_heading_rad = r.angle("heading", 0.0, -2 * M_PI, 2 * M_PI);
    c.route_length_m = r.num("length_m", c.route_length_m, 0.5, 1e4);
    c.route_spacing_m = r.num("spacing_m", c.route_spacing_m, -100.0, 100.0);
    c.route_passes = r.integer("passes", c.route_passes, 1, 1000);
    c.route_loop = r.boolean("loop", c.route_loop);
    c.route_depth_m = r.num("depth_m", c.route_depth_m, -1.0, 1.0);
    c.route_speed_mps = r.num("speed_mps", c.route_speed_mps, 0.05, 5.0);
    c.route_return_speed_mps = r.num("return_speed_mps", c.route_return_speed_mps, 0.05, 5.0);
    if (r.has("grade")) {
      MapReader g = r.child("grade");
      c.route_grade = true;
      c.grade_first_m = g.num("first_m", c.grade_first_m, -1e4, 1e4);
      c.grade_step_m = g.num("step_m", c.grade_step_m, -10.0, 10.0);
      c.grade_lowest_m = g.num("lowest_m", c.grade_lowest_m, -1e4, 1e4);
      g.finish();
    }
  } else {
    // As for sensors: the keys depend on the type, so they are not checked against a guess.
    r.error(r.node("type"), "type", "unknown controller type '" + type + "'" + didYouMean(type, {"random_walk", "route", "replay", "dig_dump", "external"}));
    return c;
  }
  if (r.has("stall")) {
    MapReader s = r.child("stall");
    c.stall_ratio = s.num("ratio", c.stall_ratio, 0.0, 1.0);
    c.stall_time_s = s.num("time_s", c.stall_time_s, 0.0, 100.0);
    c.stall_give_up_s = s.num("give_up_s", c.stall_give_up_s, 0.0, 1e6);
    c.raise_rate_mps = s.num("raise_rate_mps", c.raise_rate_mps, 0.0, 5.0);
    s.finish();
  }
  r.finish();
  return c;
}

void readBlade(MapReader& b, MachineSpec& m) {
  m.blade.width_m = b.num("width_m", m.blade.width_m, 0.1, 10.0);
  m.blade.height_m = b.num("height_m", m.blade.height_m, 0.05, 5.0);
  m.rake_rad = b.angle("rake", m.rake_rad, 30 * kDeg, 120 * kDeg);
  m.blade_mount_x_m = b.num("mount_x_m", m.blade_mount_x_m, 0.5, 10.0);
  m.blade_slices = b.integer("slices", m.blade_slices, 1, 1000);
  m.edge_thickness_m = b.num("edge_thickness_m", m.edge_thickness_m, 0.0, 0.5);
  b.finish();
}

/// A track-soil model's name: true for bekker, false for none, nothing for any other.
std::optional<bool> trackSoilModel(const std::string& name) {
  if (name == "bekker") return true;
  if (name == "none") return false;
  return std::nullopt;
}

void readVehicle(MapReader& v, MachineSpec& m) {
  m.mass_kg = v.num("mass_kg", m.mass_kg, 100.0, 1e6);
  m.track_gauge_m = v.num("track_gauge_m", m.track_gauge_m, 0.3, 10.0);
  m.track_length_m = v.num("track_length_m", m.track_length_m, 0.3, 10.0);
  m.traction_coefficient = v.num("traction_coefficient", m.traction_coefficient, 0.0, 2.0);
  m.max_drive_force_n = v.num("max_drive_force_n", m.max_drive_force_n, 0.0, 1e7);
  m.rolling_resistance = v.num("rolling_resistance", m.rolling_resistance, 0.0, 1.0);
  const std::string ts = v.str("track_soil", m.track_soil ? "bekker" : "none");
  if (const std::optional<bool> on = trackSoilModel(ts)) m.track_soil = *on;
  else v.error(v.node("track_soil"), "track_soil", "unknown model '" + ts + "' (none, bekker)" + didYouMean(ts, {"none", "bekker"}));
  m.track_width_m = v.num("track_width_m", m.track_width_m, 0.05, 5.0);
  m.max_speed_mps = v.num("max_speed_mps", m.max_speed_mps, 0.1, 20.0);
  m.drive_time_constant_s = v.num("drive_time_constant_s", m.drive_time_constant_s, 0.0, 10.0);
  m.yaw_time_constant_s = v.num("yaw_time_constant_s", m.yaw_time_constant_s, 0.0, 10.0);
  m.engine_rated_rpm = v.num("engine_rated_rpm", m.engine_rated_rpm, 100.0, 1e4);
  m.engine_droop_rpm = v.num("engine_droop_rpm", m.engine_droop_rpm, 0.0, 1e4);
  v.finish();
}

void readJoints(MapReader& j, MachineSpec& m) {
  readRange(j, "lift_m", m.joint_min[0], m.joint_max[0], -2.0, 3.0);
  readRange(j, "tilt_deg", m.joint_min[1], m.joint_max[1], -M_PI / 3, M_PI / 3, kDeg);
  readRange(j, "angle_deg", m.joint_min[2], m.joint_max[2], -M_PI / 3, M_PI / 3, kDeg);
  if (j.has("max_rate")) {
    const auto v = j.vec("max_rate", {}, 3);
    if (v.size() == 3) {
      if (!(v[0] > 0 && v[1] > 0 && v[2] > 0))
        j.error(j.node("max_rate"), "max_rate", "rates must be > 0 ([m/s, rad/s, rad/s])");
      else
        for (int k = 0; k < 3; ++k) m.joint_max_rate[k] = v[k];
    }
  }
  m.joint_eta = j.num("eta", m.joint_eta, 0.0, 1000.0);
  m.joint_beta = j.num("beta", m.joint_beta, 0.0, 1000.0);
  m.joint_tau_s = j.num("tau_s", m.joint_tau_s, 1e-3, 10.0);
  m.lift_down_force_n = j.num("lift_down_force_n", m.lift_down_force_n, 0.0, 1e7);
  j.finish();
}

void readSensors(MapReader& r, MachineSpec& m, double physics_hz) {
  const YAML::Node ss = r.node("sensors");
  if (!ss.IsSequence()) {
    r.error(ss, "sensors", "expected a list of sensors");
    return;
  }
  std::set<std::string> ids;
  for (std::size_t k = 0; k < ss.size(); ++k) {
    MapReader sr(r.diagnostics(), ss[k], r.join("sensors[" + std::to_string(k) + "]"));
    SensorSpec s = readSensor(sr, physics_hz, m.arm.has_value());
    if (!s.id.empty() && !ids.insert(s.id).second) sr.error(ss[k]["id"], "id", "duplicate sensor id '" + s.id + "'");
    m.sensors.push_back(std::move(s));
  }
}

/// Three per-axis sigmas at `key` (>= 0 and finite), scaled into `out`; unchanged when absent.
void readAxes(MapReader& r, const std::string& key, double scale, std::array<AxisError, 3>& out,
              double AxisError::*field) {
  if (!r.has(key)) return;
  const std::vector<double> v = r.vec(key, {}, 3);
  if (v.size() != 3) return;
  for (int k = 0; k < 3; ++k) {
    if (!(v[k] >= 0.0) || !std::isfinite(v[k])) {
      std::ostringstream os;
      os << "sigmas must be >= 0 and finite (got " << v[k] << " at [" << k << "])";
      r.error(r.node(key), key, os.str());
      return;
    }
  }
  for (int k = 0; k < 3; ++k) out[k].*field = v[k] * scale;
}

/// `localisation: perfect | rtk_imu | {overrides of rtk_imu}` at `key` (`def` when absent).
LocalisationSpec readLocalisation(MapReader& parent, const LocalisationSpec& def) {
  const std::string key = "localisation";
  if (!parent.has(key)) return def;
  const YAML::Node n = parent.node(key);
  const std::vector<std::string> presets{"perfect", "rtk_imu"};
  if (n.IsScalar()) {
    const std::string v = n.Scalar();
    if (v == "perfect") return LocalisationSpec::none();
    if (v == "rtk_imu") return LocalisationSpec::rtkImu();
    parent.error(n, key, "unknown localisation '" + v + "'" + didYouMean(v, presets) +
                             " (known: perfect, rtk_imu, or a map of overrides of rtk_imu)");
    return def;
  }
  MapReader r = parent.child(key);
  if (!r.valid()) return def;
  // A map always starts from rtk_imu (not from a scenario-wide map): what a machine's key says
  // does not depend on another section.
  LocalisationSpec s = LocalisationSpec::rtkImu();
  readAxes(r, "position_white_m", 1.0, s.position, &AxisError::white);
  readAxes(r, "position_bias_m", 1.0, s.position, &AxisError::bias);
  readAxes(r, "position_random_walk_m", 1.0, s.position, &AxisError::random_walk);
  readAxes(r, "attitude_white_deg", kDeg, s.attitude, &AxisError::white);
  readAxes(r, "attitude_bias_deg", kDeg, s.attitude, &AxisError::bias);
  readAxes(r, "attitude_random_walk_deg", kDeg, s.attitude, &AxisError::random_walk);
  s.latency_s = r.num("latency_s", s.latency_s, 0.0, 10.0);
  s.drift_time_constant_s = r.num("drift_time_constant_s", s.drift_time_constant_s, 1e-3, INFINITY);
  s.cylinder_white_m = r.num("cylinder_white_m", s.cylinder_white_m, 0.0, 1.0);
  s.cylinder_bias_m = r.num("cylinder_bias_m", s.cylinder_bias_m, 0.0, 1.0);
  s.velocity_white_mps = r.num("velocity_white_mps", s.velocity_white_mps, 0.0, 10.0);
  s.angular_rate_white_radps = kDeg * r.num("angular_rate_white_degps", s.angular_rate_white_radps / kDeg, 0.0, 100.0);
  r.finish();
  return s;
}

/// `shape:` a list of {name, frame: base|blade (an excavator also slew|boom|arm|bucket), min: [x,
/// y, z], max: [x, y, z]} replacing the default boxes ([] = a machine the LiDARs cannot see).
/// The arm must be read before (it decides the frames allowed).
void readShape(MapReader& r, MachineSpec& m) {
  const YAML::Node list = r.node("shape");
  if (!list.IsSequence()) {
    r.error(list, "shape", "expected a list of boxes {name, frame: base|blade, min: [x, y, z], max: [x, y, z]}");
    return;
  }
  m.shape.clear();
  for (std::size_t k = 0; k < list.size(); ++k) {
    MapReader b(r.diagnostics(), list[k], r.join("shape[" + std::to_string(k) + "]"));
    if (!b.valid()) continue;
    ShapeBox box;
    box.name = b.str("name", "box" + std::to_string(k));
    const std::string frame = b.str("frame", "base");
    const std::vector<std::string> frames = linkNames(m.arm.has_value());
    const auto it = std::find(frames.begin(), frames.end(), frame);
    if (it != frames.end())
      box.frame = static_cast<ShapeBox::Frame>(it - frames.begin());
    else
      b.error(b.node("frame"), "frame", "must be " + joinStrings(frames) + " (got '" + frame + "')" + didYouMean(frame, frames));
    const std::vector<double> lo = b.vec("min", {}, 3), hi = b.vec("max", {}, 3);
    if (lo.size() == 3 && hi.size() == 3) {
      box.min = Eigen::Vector3d(lo[0], lo[1], lo[2]);
      box.max = Eigen::Vector3d(hi[0], hi[1], hi[2]);
      if (!(box.min.array() < box.max.array()).all() || !box.min.allFinite() || !box.max.allFinite() ||
          box.min.cwiseAbs().maxCoeff() > 100 || box.max.cwiseAbs().maxCoeff() > 100)
        b.error(b.node("max"), "max", "every coordinate must be finite, within 100 m and larger than min's");
    } else {
      b.error(list[k], "min", "min and max are required, three numbers each (metres in the box's frame)");
    }
    b.finish();
    m.shape.push_back(box);
  }
}

/// `arm:` of an excavator (ArmSpec; docs/sim.md "Excavators").
void readArm(MapReader& r, ArmSpec& a) {
  if (r.has("slew")) {
    MapReader s = r.child("slew");
    a.slew_x_m = s.num("x_m", a.slew_x_m, -10.0, 10.0);
    a.slew_z_m = s.num("z_m", a.slew_z_m, 0.0, 10.0);
    s.finish();
  }
  const auto bp = r.vec("boom_pivot_m", {a.boom_pivot_x_m, a.boom_pivot_z_m}, 2);
  if (bp.size() == 2) {
    a.boom_pivot_x_m = bp[0];
    a.boom_pivot_z_m = bp[1];
  }
  a.boom_m = r.num("boom_m", a.boom_m, 0.2, 30.0);
  a.arm_m = r.num("arm_m", a.arm_m, 0.2, 30.0);
  if (r.has("bucket")) {
    MapReader b = r.child("bucket");
    a.bucket_m = b.num("length_m", a.bucket_m, 0.1, 5.0);
    a.bucket_depth_m = b.num("depth_m", a.bucket_depth_m, 0.05, 5.0);
    a.bucket_width_m = b.num("width_m", a.bucket_width_m, 0.1, 5.0);
    a.bucket_capacity_m3 = b.num("capacity_m3", a.bucket_capacity_m3, 0.0, 50.0);
    a.pour_rate_m3ps = b.num("pour_rate_m3ps", a.pour_rate_m3ps, 1e-3, 100.0);
    a.edge_thickness_m = b.num("edge_thickness_m", a.edge_thickness_m, 0.0, 0.5);
    a.bucket_slices = b.integer("slices", a.bucket_slices, 1, 200);
    if (b.has("profile_m")) {
      const YAML::Node list = b.node("profile_m");
      if (!list.IsSequence() || list.size() < 3) {
        b.error(list, "profile_m", "expected a list of at least three [x, z] vertices (bucket frame, m)");
      } else {
        for (std::size_t k = 0; k < list.size(); ++k) {
          std::vector<double> v;
          if (b.numList(list[k], "profile_m[" + std::to_string(k) + "]", 2, v)) a.bucket_profile.emplace_back(v[0], v[1]);
        }
      }
    }
    b.finish();
  }
  const auto masses = r.vec("masses_kg", {a.mass_kg[0], a.mass_kg[1], a.mass_kg[2], a.mass_kg[3]}, 4);
  if (masses.size() == 4) {
    if (!std::all_of(masses.begin(), masses.end(), [](double m) { return m >= 0 && m < 1e6; }))
      r.error(r.node("masses_kg"), "masses_kg", "masses must lie in [0, 1e6) kg ([upper structure, boom, arm, bucket])");
    else
      for (int k = 0; k < 4; ++k) a.mass_kg[k] = masses[k];
  }
  if (r.has("joints")) {
    MapReader j = r.child("joints");
    const char* names[4] = {"slew", "boom", "arm", "bucket"};
    for (int k = 0; k < 4; ++k) {
      if (!j.has(names[k])) continue;
      MapReader jr = j.child(names[k]);
      ArmJointSpec& J = a.joints[k];
      readRange(jr, "range_deg", J.min_rad, J.max_rad, -2 * M_PI, 2 * M_PI, kDeg);
      J.max_rate_rps = jr.angle("max_rate", J.max_rate_rps, 1e-3, 20.0);
      J.max_torque_nm = jr.num("max_torque_nm", J.max_torque_nm, 0.0, 1e9);
      J.eta = jr.num("eta", J.eta, 0.0, 1000.0);
      J.beta = jr.num("beta", J.beta, 0.0, 1000.0);
      J.phi = jr.angle("phi", J.phi, -M_PI, M_PI);
      a.initial_rad[k] = jr.angle("initial", a.initial_rad[k], -2 * M_PI, 2 * M_PI);
      jr.finish();
    }
    j.finish();
  }
  a.encoder_noise_rad = r.angle("encoder_noise", a.encoder_noise_rad, 0.0, 0.5);
  a.inclinometer_noise_rad = r.angle("inclinometer_noise", a.inclinometer_noise_rad, 0.0, 0.5);
  r.finish();
}

/// A compact excavator's undercarriage and plow (Takeuchi TB235-class) before its YAML keys.
void excavatorDefaults(MachineSpec& m) {
  m.mass_kg = 3500;
  m.track_gauge_m = 1.25;
  m.track_length_m = 1.85;
  m.track_width_m = 0.3;
  m.max_speed_mps = 1.3;
  m.max_drive_force_n = 30000;
  m.blade.width_m = 1.55;
  m.blade.height_m = 0.35;
  m.blade_mount_x_m = 1.25;
  m.rake_rad = 90 * kDeg;
  m.blade_slices = 15;
}

MachineSpec readMachine(MapReader& r, const LocalisationSpec& default_localisation, double physics_hz,
                        const std::string& base_dir) {
  MachineSpec m;
  m.localisation = readLocalisation(r, default_localisation);
  m.id = r.strRequired("id");
  const std::string type = r.str("type", "ctl");
  if (type == "excavator") {
    excavatorDefaults(m);
    m.arm = ArmSpec{};
  } else if (type != "ctl") {
    r.error(r.node("type"), "type",
            "unknown machine type '" + type + "' (known: ctl, excavator)" + didYouMean(type, {"ctl", "excavator"}));
  }
  if (r.has("pose")) {
    MapReader p = r.child("pose");
    m.x_m = p.num("x_m", 0.0);
    m.y_m = p.num("y_m", 0.0);
    m.yaw_rad = p.angle("yaw", 0.0, -2 * M_PI, 2 * M_PI);
    p.finish();
  }
  if (r.has("blade")) {
    MapReader b = r.child("blade");
    readBlade(b, m);
  }
  if (r.has("vehicle")) {
    MapReader v = r.child("vehicle");
    readVehicle(v, m);
  }
  if (r.has("joints")) {
    MapReader j = r.child("joints");
    readJoints(j, m);
  }
  if (r.has("force_noise")) {
    MapReader f = r.child("force_noise");
    m.force_noise_abs_n = f.num("abs_n", m.force_noise_abs_n, 0.0, 1e7);
    m.force_noise_rel = f.num("rel", m.force_noise_rel, 0.0, 10.0);
    m.force_noise_tau_s = f.num("tau_s", m.force_noise_tau_s, 1e-3, 100.0);
    f.finish();
  }
  if (r.has("controller")) {
    MapReader c = r.child("controller");
    if (c.valid()) m.controller = readController(c, base_dir);
  }
  std::vector<Eigen::Vector2d> bucket_profile;  ///< the bucket mesh's, for its shape box (empty if bad)
  if (m.arm) {
    if (r.has("arm")) {
      MapReader a = r.child("arm");
      if (a.valid()) readArm(a, *m.arm);
    }
    if (m.controller.type != ControllerSpec::Type::DigDump && m.controller.type != ControllerSpec::Type::Replay &&
        m.controller.type != ControllerSpec::Type::External)
      r.error(r.has("controller") ? r.node("controller") : r.self(), "controller",
              "an excavator needs the dig_dump controller (controller: {type: dig_dump, dig_m: [x, y], dump_m: [x, y]}), "
              "a replay of its levers (controller: {type: replay, file: ...}) or an external one (controller: {type: "
              "external}, driven through the environment API)");
    if (m.controller.type == ControllerSpec::Type::DigDump) {
      // The dig and dump points must lie within the arm's reach around the slew axis (the lip
      // held straight out: boom pivot + boom + arm + bucket).
      const ArmSpec& a = *m.arm;
      const double reach = a.boom_pivot_x_m + a.boom_m + a.arm_m + a.bucket_m;
      const Eigen::Vector2d axis(m.x_m + std::cos(m.yaw_rad) * a.slew_x_m, m.y_m + std::sin(m.yaw_rad) * a.slew_x_m);
      MapReader c = r.child("controller");
      auto cm = [](double v) {  // metres to the centimetre, for the message
        char b[32];
        std::snprintf(b, sizeof b, "%.2f", v);
        return std::string(b);
      };
      for (const auto& [key, p] : {std::pair<const char*, Eigen::Vector2d>{"dig_m", m.controller.dig_dump.dig},
                                   std::pair<const char*, Eigen::Vector2d>{"dump_m", m.controller.dig_dump.dump}}) {
        const double d = (p - axis).norm();
        if (d > reach || d < 1.0)
          c.error(c.has(key) ? c.node(key) : c.self(), key,
                  "[" + formatNumber(p.x()) + ", " + formatNumber(p.y()) + "] is " + cm(d) +
                      " m from the excavator's slew axis; the arm reaches from 1 m to " + cm(reach) + " m");
      }
    }
    try {
      bucket_profile = bucketMesh(*m.arm).profile;
    } catch (const ConfigError& e) {
      if (m.arm->bucket_profile.size() >= 3) r.error(r.node("arm"), "arm.bucket.profile_m", e.what());
    }
  } else {
    if (r.has("arm")) r.error(r.node("arm"), "arm", "only a machine of type excavator has an arm");
    if (m.controller.type == ControllerSpec::Type::DigDump)
      r.error(r.node("controller"), "controller", "dig_dump drives an excavator's arm (this machine is a ctl)");
  }
  if (r.has("sensors")) readSensors(r, m, physics_hz);
  if (m.arm) {
    // The bucket's box: its mesh's extent in the bucket frame.
    Eigen::Vector3d lo(1e9, -0.5 * m.arm->bucket_width_m, 1e9), hi(-1e9, 0.5 * m.arm->bucket_width_m, -1e9);
    for (const Eigen::Vector2d& v : bucket_profile) {
      lo.x() = std::min(lo.x(), v.x()); lo.z() = std::min(lo.z(), v.y());
      hi.x() = std::max(hi.x(), v.x()); hi.z() = std::max(hi.z(), v.y());
    }
    if (bucket_profile.empty()) {  // a bad profile, reported above: any box will do until then
      lo = Eigen::Vector3d(0, -0.3, 0);
      hi = Eigen::Vector3d(0.7, 0.3, 0.3);
    }
    m.shape = defaultExcavatorShape(m.track_gauge_m, m.track_length_m, m.track_width_m, m.blade.width_m,
                                    m.blade.height_m, m.arm->boom_m, m.arm->arm_m, lo, hi);
  } else {
    m.shape = defaultCtlShape(m.track_gauge_m, m.track_length_m, m.blade.width_m, m.blade.height_m);
  }
  if (r.has("shape")) readShape(r, m);
  r.finish();
  return m;
}

/// The DEM's format: explicit, else from the file's extension.
std::string readDemFormat(MapReader& d, const fs::path& p, DemSpec& dem) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  std::string fmt = ext == ".tif" || ext == ".tiff" ? "geotiff" : ext == ".las" ? "las" : "esri_ascii";
  const std::vector<std::string> formats = {"esri_ascii", "geotiff", "las"};
  if (d.has("format")) {
    const std::string given = d.str("format", fmt);
    if (std::find(formats.begin(), formats.end(), given) == formats.end())
      d.error(d.node("format"), "format", "unsupported DEM format '" + given + "' (supported: " + joinStrings(formats) +
                                              ")" + didYouMean(given, formats));
    else
      fmt = given;
  }
  dem.format = fmt == "geotiff" ? DemFormat::GeoTiff : fmt == "las" ? DemFormat::Las : DemFormat::EsriAscii;
  return fmt;
}

void readGeoOrigin(MapReader& d, DemSpec& dem) {
  const YAML::Node n = d.node("geo_origin");
  if (n.IsScalar() && n.Scalar() == "auto") {
    dem.origin_mode = GeoOriginMode::Auto;
    return;
  }
  if (!n.IsSequence() || (n.size() != 2 && n.size() != 3)) {
    d.error(n, "geo_origin", "expected 'auto' or a list [easting, northing] or [easting, northing, height] (m)");
    return;
  }
  std::vector<double> v;
  if (!d.numList(n, "geo_origin", n.size(), v)) return;
  if (!std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); })) {
    d.error(n, "geo_origin", "coordinates must be finite");
    return;
  }
  dem.origin_mode = GeoOriginMode::Explicit;
  dem.geo_origin = Eigen::Vector3d(v[0], v[1], v.size() == 3 ? v[2] : 0.0);
}

/// The keys that apply to one format only, and the band (a 1-based number or a description).
void readDemFormatOptions(MapReader& d, DemSpec& dem, const std::string& fmt) {
  auto onlyFor = [&](const char* key, DemFormat f, const char* fname) {
    if (d.has(key) && dem.format != f)
      d.error(d.node(key), key, std::string("applies to format ") + fname + " only (format is " + fmt + ")");
  };
  onlyFor("band", DemFormat::GeoTiff, "geotiff");
  onlyFor("cell_m", DemFormat::Las, "las");
  onlyFor("statistic", DemFormat::Las, "las");
  onlyFor("ground_class", DemFormat::Las, "las");
  if (d.has("band")) {
    const YAML::Node n = d.node("band");
    long as_number = 0;
    if (yaml::scalarLong(n, as_number)) dem.band = d.integer("band", 1, 1, 65535);
    else if (n.IsScalar()) dem.band_name = n.Scalar();
    else d.error(n, "band", "expected a band number (1-based) or a band description");
  }
  dem.cell_m = d.num("cell_m", dem.cell_m, 1e-3, 1e4);
  if (d.has("statistic")) {
    const std::string st = d.str("statistic", "median");
    if (st != "median" && st != "mean")
      d.error(d.node("statistic"), "statistic",
              "unknown statistic '" + st + "' (median or mean)" + didYouMean(st, {"median", "mean"}));
    dem.statistic = st == "mean" ? DemStatistic::Mean : DemStatistic::Median;
  }
  dem.ground_class = d.integer("ground_class", dem.ground_class, 0, 31);
}

void readDemSpec(MapReader& d, DemSpec& dem, const Ctx& ctx) {
  const std::string file = d.strRequired("file");
  fs::path p(file);
  if (p.is_relative()) p = fs::path(ctx.base_dir) / p;
  dem.path = p.lexically_normal().string();
  const std::string fmt = readDemFormat(d, p, dem);
  if (d.has("geo_origin")) readGeoOrigin(d, dem);
  if (d.has("fill_holes")) dem.fill_holes = d.boolean("fill_holes", false);
  readDemFormatOptions(d, dem, fmt);
  d.finish();
}

/// Reads the DEM now (its extent is needed for the terrain and buildTerrain reuses the grid),
/// unless the YAML already has errors. True when the extent is known.
bool loadDemExtent(TerrainSpec& t, Ctx& ctx) {
  if (ctx.diag.count() > 0) return false;  // the file is refused anyway; a LAS can take seconds
  try {
    auto g = std::make_shared<DemGrid>(loadDem(t.dem, &t.dem_geo_origin));  // InputError names the file
    t.origin_x_m = g->x0_m;
    t.origin_y_m = g->y0_m;
    t.size_x_m = (g->nx - 1) * g->cell_m;
    t.size_y_m = (g->ny - 1) * g->cell_m;
    t.dem_grid = std::move(g);
    return true;
  } catch (const Error&) {
    ctx.dem_failure = std::current_exception();
    return false;
  }
}

/// A count for a message: digits while the double holds a whole number exactly, else
/// scientific notation (1.39e+64 nodes); converting such a double to an integer is undefined.
std::string countText(double v) {
  char b[48];
  std::snprintf(b, sizeof b, std::abs(v) < 9.0e15 ? "%.0f" : "%.3g", v);
  return b;
}

/// size_m / origin_m, around what a DEM gave; refuses a terrain too large to allocate.
void readExtent(MapReader& r, TerrainSpec& t, bool dem_given, bool dem_extent) {
  if (r.has("size_m")) {
    const auto s = r.vec("size_m", {}, 2);
    if (s.size() == 2 && !(s[0] > 0 && s[1] > 0)) r.error(r.node("size_m"), "size_m", "sizes must be > 0");
    else if (s.size() == 2) {
      t.size_x_m = s[0];
      t.size_y_m = s[1];
    }
  } else if (!dem_given) {
    r.error(r.self(), "size_m", "missing (terrain extent [x, y] in metres, or a dem)");
  }
  if (r.has("origin_m")) {
    const auto o = r.vec("origin_m", {}, 2);
    if (o.size() == 2) {
      t.origin_x_m = o[0];
      t.origin_y_m = o[1];
    }
  } else if (!dem_extent) {
    t.origin_x_m = -t.size_x_m / 2;
    t.origin_y_m = -t.size_y_m / 2;
  }
  if (dem_given && !dem_extent) return;  // the DEM's extent is unknown: nothing to measure
  const double nodes = (t.size_x_m / t.resolution_m + 1) * (t.size_y_m / t.resolution_m + 1);
  // ~45 bytes per node (U, Lv, Lc, H in double, the initial surface and the pyramid in float).
  if (nodes > 5e7)
    r.error(r.self(), "size_m", "terrain too large: " + countText(nodes) + " nodes (~" + countText(nodes * 45 / 1e9) +
                                    " GB; limit 5e7 nodes): choose a smaller size_m (and origin_m) or a coarser resolution_m" +
                                    (t.dem.path.empty() ? "" : " (a DEM alone sets the extent to the whole file)"));
}

void readHills(MapReader& h, TerrainSpec& t, unsigned long long scenario_seed) {
  const int count = h.integer("count", 0, 0, 100000);
  double alo = -0.2, ahi = 0.3, slo = 1.0, shi = 4.0;
  readRange(h, "amplitude_m", alo, ahi, -100.0, 100.0);
  readRange(h, "sigma_m", slo, shi, 1e-3, 1e4);
  if (slo <= 0) h.error(h.node("sigma_m"), "sigma_m", "sigma must be > 0");
  const unsigned long long seed = h.unsignedInt("seed", scenario_seed);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  for (int k = 0; k < count; ++k) {
    GaussianBump b;
    b.x_m = t.origin_x_m + U(rng) * t.size_x_m;
    b.y_m = t.origin_y_m + U(rng) * t.size_y_m;
    b.amplitude_m = alo + U(rng) * (ahi - alo);
    b.sigma_m = slo + U(rng) * (shi - slo);
    t.bumps.push_back(b);
  }
  if (h.has("list")) {
    const YAML::Node l = h.node("list");
    if (!l.IsSequence()) h.error(l, "list", "expected a list of {x_m, y_m, amplitude_m, sigma_m}");
    for (std::size_t k = 0; l.IsSequence() && k < l.size(); ++k) {
      MapReader b(h.diagnostics(), l[k], h.join("list[" + std::to_string(k) + "]"));
      GaussianBump g;
      g.x_m = b.numRequired("x_m", 0.0);
      g.y_m = b.numRequired("y_m", 0.0);
      g.amplitude_m = b.numRequired("amplitude_m", 0.0);
      g.sigma_m = b.numRequired("sigma_m", 1.0, 1e-6, 1e6);
      b.finish();
      t.bumps.push_back(g);
    }
  }
  h.finish();
}

/// True when the terrain's extent is known (not when a DEM could not be read).
bool readTerrain(MapReader& r, Scenario& sc, Ctx& ctx) {
  TerrainSpec& t = sc.terrain;
  t.resolution_m = r.num("resolution_m", t.resolution_m, 1e-3, 0.02);
  t.base_height_m = r.num("base_height_m", t.base_height_m);
  const auto slope = r.vec("slope", {0, 0}, 2);
  t.slope_x = slope[0];
  t.slope_y = slope[1];
  t.snapshot_interval_s = r.num("snapshot_interval_s", t.snapshot_interval_s, 1e-3, 1e6);
  const bool dem_given = r.has("dem");
  bool dem_extent = false;
  if (dem_given) {
    MapReader d = r.child("dem");
    if (d.valid()) {
      readDemSpec(d, t.dem, ctx);
      dem_extent = loadDemExtent(t, ctx);
    }
  }
  readExtent(r, t, dem_given, dem_extent);
  if (r.has("hills")) {
    MapReader h = r.child("hills");
    readHills(h, t, sc.seed);
  }
  r.finish();
  return !dem_given || dem_extent;
}

void readStrip(MapReader& s, SoilZone& zone) {
  const std::string axis = s.strRequired("axis");
  if (axis == "x") zone.region = SoilZone::Region::StripX;
  else if (axis == "y") zone.region = SoilZone::Region::StripY;
  else if (s.has("axis")) s.error(s.node("axis"), "axis", "expected 'x' or 'y'");
  double lo = 0, hi = 0;
  if (!s.has("range_m")) s.error(s.self(), "range_m", "missing [min, max]");
  readRange(s, "range_m", lo, hi, -1e9, 1e9);
  zone.lo_m = lo;
  zone.hi_m = hi;
  s.finish();
}

void readPolygon(MapReader& z, SoilZone& zone) {
  const YAML::Node p = z.node("polygon");
  if (!p.IsSequence() || p.size() < 3) {
    z.error(p, "polygon", "expected a list of at least 3 [x, y] points");
    return;
  }
  for (std::size_t q = 0; q < p.size(); ++q) {
    std::vector<double> v;
    if (z.numList(p[q], "polygon[" + std::to_string(q) + "]", 2, v)) zone.polygon.emplace_back(v[0], v[1]);
  }
  zone.region = SoilZone::Region::Polygon;
}

SoilZone readZone(MapReader& z, std::size_t k) {
  SoilZone zone;
  zone.name = z.str("name", "zone" + std::to_string(k));
  zone.soil = readSoil(z);
  int regions = 0;
  if (z.has("strip")) {
    ++regions;
    MapReader s = z.child("strip");
    readStrip(s, zone);
  }
  if (z.has("polygon")) {
    ++regions;
    readPolygon(z, zone);
  }
  if (regions > 1) z.error(z.self(), "polygon", "give one region (strip or polygon), not both");
  readRange(z, "depth_m", zone.depth_min_m, zone.depth_max_m, 0.0, INFINITY);
  if (z.has("depth_dip")) {
    std::vector<double> v;
    if (z.numList(z.node("depth_dip"), "depth_dip", 2, v)) zone.depth_dip = {v[0], v[1]};
  }
  z.finish();
  return zone;
}

void readSoilSection(MapReader& r, Scenario& sc) {
  if (r.has("default")) {
    MapReader d = r.child("default");
    if (d.valid()) sc.default_soil = readSoil(d);
    d.finish();
  }
  if (r.has("zones")) {
    const YAML::Node zs = r.node("zones");
    if (!zs.IsSequence()) r.error(zs, "zones", "expected a list of zones");
    for (std::size_t k = 0; zs.IsSequence() && k < zs.size(); ++k) {
      MapReader z(r.diagnostics(), zs[k], r.join("zones[" + std::to_string(k) + "]"));
      if (z.valid()) sc.zones.push_back(readZone(z, k));
    }
  }
  r.finish();
}

void readMachines(MapReader& r, Scenario& sc, bool extent_known, const std::string& base_dir) {
  const YAML::Node ms = r.node("machines");
  if (!ms.IsDefined() || ms.IsNull()) {
    r.error(r.self(), "machines", "missing (a list of at least one machine)");
    return;
  }
  if (!ms.IsSequence() || ms.size() == 0) {
    r.error(ms, "machines", "expected a list of at least one machine");
    return;
  }
  std::set<std::string> ids;
  for (std::size_t k = 0; k < ms.size(); ++k) {
    MapReader mr(r.diagnostics(), ms[k], "machines[" + std::to_string(k) + "]");
    if (!mr.valid()) continue;
    MachineSpec m = readMachine(mr, sc.localisation, sc.physics_hz, base_dir);
    if (!m.id.empty() && !ids.insert(m.id).second) mr.error(ms[k]["id"], "id", "duplicate machine id '" + m.id + "'");
    const TerrainSpec& t = sc.terrain;
    if (extent_known && (m.x_m < t.origin_x_m || m.x_m > t.origin_x_m + t.size_x_m || m.y_m < t.origin_y_m ||
                         m.y_m > t.origin_y_m + t.size_y_m))
      mr.error(ms[k]["pose"].IsDefined() ? ms[k]["pose"] : ms[k], "pose", "machine starts outside the terrain");
    sc.machines.push_back(std::move(m));
  }
}

Scenario parseImpl(const std::string& text, Ctx& ctx) {
  const YAML::Node root = yaml::load(text, ctx.file);
  if (!root.IsMap()) throw ConfigError(ctx.file + ": a scenario must be a YAML mapping");
  ctx.diag.file = ctx.file;
  MapReader r(ctx.diag, root, "");
  Scenario sc;
  sc.yaml_text = text;
  const int version = r.integer("version", 1, 1, 1);
  (void)version;
  sc.name = r.str("name", fs::path(ctx.file).stem().string());
  sc.seed = r.unsignedInt("seed", 1);
  sc.duration_s = r.num("duration_s", sc.duration_s, 1e-3, 1e6);
  sc.observation_hz = r.num("observation_hz", sc.observation_hz, 1.0, 1000.0);
  sc.physics_hz = r.num("physics_hz", sc.physics_hz, 1.0, 10000.0);
  const double ratio = sc.physics_hz / sc.observation_hz;
  if (std::abs(ratio - std::round(ratio)) > 1e-9 || ratio < 1)
    r.error(r.node("physics_hz"), "physics_hz", "must be a whole multiple of observation_hz");
  sc.threads = r.integer("threads", sc.threads, 1, 256);
  sc.overlap_scans = r.boolean("overlap_scans", sc.overlap_scans);
  sc.lidar_sees_machines = r.boolean("lidar_sees_machines", sc.lidar_sees_machines);
  sc.machines_collide = r.boolean("machines_collide", sc.machines_collide);
  bool extent_known = false;
  {
    MapReader t = r.child("terrain");
    if (t.valid()) extent_known = readTerrain(t, sc, ctx);
  }
  if (r.has("soil")) {
    MapReader s = r.child("soil");
    readSoilSection(s, sc);
  }
  sc.localisation = readLocalisation(r, sc.localisation);
  if (r.has("survey")) {
    MapReader v = r.child("survey");
    sc.survey.spacing_m = v.num("spacing_m", 0.025, 1e-3, 10.0);
    sc.survey.sigma_m = v.num("sigma_m", sc.survey.sigma_m, 0.0, 10.0);
    sc.survey.height_m = v.num("height_m", sc.survey.height_m, 0.5, 1000.0);
    sc.survey.block_m = v.num("block_m", sc.survey.block_m, 0.5, 1000.0);
    v.finish();
  }
  readMachines(r, sc, extent_known, ctx.base_dir);
  r.finish();
  ctx.diag.throwIfAny();
  if (ctx.dem_failure) std::rethrow_exception(ctx.dem_failure);
  for (MachineSpec& m : sc.machines)
    if (m.controller.type == ControllerSpec::Type::Replay)
      m.controller.replay = std::make_shared<const CommandLog>(readCommandLog(m.controller.replay_path, m.controller.replay_units));
  return sc;
}

}  // namespace

void overrideLocalisation(Scenario& sc, const std::string& name, const std::string& what) {
  if (name.empty()) return;
  LocalisationSpec spec;
  if (name == "perfect") spec = LocalisationSpec::none();
  else if (name == "rtk_imu") spec = LocalisationSpec::rtkImu();
  else throw ConfigError(what + ": '" + name + "' is not a localisation (perfect or rtk_imu)" + didYouMean(name, {"perfect", "rtk_imu"}));
  for (MachineSpec& m : sc.machines) m.localisation = spec;
}

void overrideTrackSoil(Scenario& sc, const std::string& model, const std::string& what) {
  if (model.empty()) return;
  const std::optional<bool> on = trackSoilModel(model);
  if (!on) throw ConfigError(what + ": '" + model + "' is not a track-soil model (bekker or none)" + didYouMean(model, {"bekker", "none"}));
  for (MachineSpec& m : sc.machines) m.track_soil = *on;
}

Scenario parseScenario(const std::string& yaml_text, const std::string& name_for_errors, const std::string& base_dir) {
  Ctx ctx{name_for_errors, base_dir, {}, nullptr};
  return parseImpl(yaml_text, ctx);
}

Scenario loadScenario(const std::string& yaml_path) {
  std::ifstream in(yaml_path, std::ios::binary);
  if (!in) throw ConfigError(yaml_path + ": cannot open scenario file");
  std::ostringstream os;
  os << in.rdbuf();
  fs::path p(yaml_path);
  Ctx ctx{yaml_path, p.has_parent_path() ? p.parent_path().string() : ".", {}, nullptr};
  Scenario sc = parseImpl(os.str(), ctx);
  sc.source_path = yaml_path;
  return sc;
}

bool applyLidarPreset(const std::string& name, SensorSpec& s) {
  if (name == "vlp32") {  // Velodyne VLP-32C-like: 32 beams, -25..+15 deg, 0.2 deg at 10 Hz
    s.beams = 32; s.columns = 1800; s.vfov_min_rad = -25 * kDeg; s.vfov_max_rad = 15 * kDeg;
    s.hfov_rad = 2 * M_PI; s.rate_hz = 10; s.max_range_m = 100; s.range_noise_m = 0.03;
  } else if (name == "os1_64") {  // Ouster OS1-64-like: 64 beams, +-22.5 deg, 1024 columns
    s.beams = 64; s.columns = 1024; s.vfov_min_rad = -22.5 * kDeg; s.vfov_max_rad = 22.5 * kDeg;
    s.hfov_rad = 2 * M_PI; s.rate_hz = 10; s.max_range_m = 90; s.range_noise_m = 0.02;
  } else if (name == "os1_128") {
    s.beams = 128; s.columns = 1024; s.vfov_min_rad = -22.5 * kDeg; s.vfov_max_rad = 22.5 * kDeg;
    s.hfov_rad = 2 * M_PI; s.rate_hz = 10; s.max_range_m = 90; s.range_noise_m = 0.02;
  } else if (name == "single_line") {  // SICK-style 2D scanner: 270 deg, 0.5 deg, 25 Hz
    s.beams = 1; s.columns = 541; s.vfov_min_rad = 0; s.vfov_max_rad = 0;
    s.hfov_rad = 270 * kDeg; s.rate_hz = 25; s.max_range_m = 30; s.range_noise_m = 0.01;
  } else {
    return false;
  }
  return true;
}

std::vector<std::string> lidarPresetNames() { return {"vlp32", "os1_64", "os1_128", "single_line"}; }

const char* linkName(SensorSpec::Link link) {
  static const char* const kNames[] = {"base", "blade", "slew", "boom", "arm", "bucket"};
  return kNames[static_cast<int>(link)];
}

}  // namespace terramap::sim
