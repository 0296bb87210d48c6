// lidar_fusion's parameters: the schema, the config read from it, and configure().
#include "lidar_fusion.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>

#include <cmath>
#include <limits>
#include <string>
#include <utility>

namespace terramap::plugins {

// ---- parameters ------------------------------------------------------------------------------

ParamSchema lidarFusionSchema() {
  const double inf = std::numeric_limits<double>::infinity();
  return {
      param::text("sensor_noise", "range_based", {"range_based", "depth_squared"},
                  "noise model: range_based sigma = a + b*range (LiDAR); depth_squared v = k*z_s^2 "
                  "(camera, z_s = sensor-frame z)"),
      param::real("range_noise_a_m", 0.02, 0.0, 10.0, "m", "range_based: sigma at zero range"),
      param::real("range_noise_b", 0.001, 0.0, 1.0, "m/m", "range_based: sigma growth per metre of range"),
      param::real("sensor_noise_factor", 0.05, 0.0, 100.0, "1", "depth_squared: k in v = k*z_s^2"),
      param::texts("depth_squared_frames", {},
                   "clouds whose frame matches one of these shell patterns (e.g. '*/cam') use depth_squared "
                   "whatever sensor_noise says: a depth camera (points in its optical frame) beside a LiDAR"),
      param::real("min_range_m", 0.5, 0.0, inf, "m", "drop points closer to the sensor"),
      param::real("max_range_m", 100.0, 0.0, inf, "m", "drop points farther from the sensor"),
      param::real("max_height_above_sensor_m", 1.0, -inf, inf, "m",
                  "drop points higher than this above the sensor (map-frame z)"),
      param::boolean("enable_ramped_height_range", true,
                     "also drop z - z_sensor > max(d_xy - b, 0)*a + c (ceiling near the robot)"),
      param::real("ramped_height_range_a", 0.3, 0.0, inf, "m/m", "ramp slope"),
      param::real("ramped_height_range_b_m", 1.0, 0.0, inf, "m", "horizontal distance where the ramp starts"),
      param::real("ramped_height_range_c_m", 0.2, -inf, inf, "m", "height allowed next to the sensor"),
      param::real("min_variance_m2", 1e-6, 0.0, 1.0, "m^2",
                  "variance floor of every point and every fused cell (must be > 0)"),
      param::real("mahalanobis_thresh", 2.0, 0.0, inf, "1",
                  "outlier if |z - h| > k*sqrt(v_cell + v_point)"),
      param::real("outlier_variance_m2", 0.01, 0.0, inf, "m^2", "added to a cell's variance per outlier"),
      param::real("max_variance_m2", 100.0, 0.0, inf, "m^2",
                  "a cell whose variance exceeds this after an outlier is forgotten"),
      param::real("time_variance_m2_per_s", 0.0005, 0.0, inf, "m^2/s", "variance growth of valid cells"),
      param::boolean("enable_visibility_cleanup", true, "walk rays: clear stale cells, bound unknown ones"),
      param::integer("cleanup_ray_stride", 1, 1, 1000000, "walk the ray of every n-th point"),
      param::real("max_ray_length_m", 10.0, 0.0, inf, "m", "walk at most this far from the sensor"),
      param::real("cleanup_step", 0.1, 0.0, 1.0, "1", "is_valid lost per penetrating ray"),
      param::real("cleanup_cos_thresh", 0.1, 0.0, 1.0, "1",
                  "ignore rays whose |cos| to the surface normal is below this (grazing)"),
      param::real("cleanup_end_margin_m", 0.3, 0.0, inf, "m", "stop each walk this far before its point"),
      param::text("cleanup_walk", "fan", {"exact", "fan"},
                  "exact: each ray along its own line; fan: rays binned by azimuth, each bin walked once along "
                  "its centre line (within cleanup_fan_lateral_cells of every ray of the bin)"),
      param::real("cleanup_fan_lateral_cells", 0.5, 0.0, 8.0, "cells",
                  "fan walk: largest distance between a ray and its bin's centre line, at max_ray_length_m"),
      param::boolean("enable_drift_compensation", false, "shift the map by the mean inlier residual"),
      param::real("drift_compensation_alpha", 0.1, 0.0, 1.0, "1", "fraction of the mean residual applied"),
      param::real("drift_compensation_variance_inlier_m2", 0.05, 0.0, inf, "m^2",
                  "only cells with a variance below this vote"),
      param::real("max_drift_m", 0.1, 0.0, inf, "m", "larger mean residuals are not applied"),
      param::integer("min_height_drift_cnt", 100, 1, 1000000000, "minimum inlier points for a correction"),
      param::real("position_noise_thresh_m", 0.01, 0.0, inf, "m",
                  "sensor translation since the last cloud needed for a correction"),
      param::real("orientation_noise_thresh_rad", 0.01, 0.0, inf, "rad",
                  "or sensor rotation since the last cloud"),
      param::reals("self_filter_base_m", {}, -1, -100.0, 100.0, "m",
                   "self-filter boxes in the base frame, [xmin, ymin, zmin, xmax, ymax, zmax] per box"),
      param::reals("self_filter_blade_m", {}, -1, -100.0, 100.0, "m",
                   "self-filter boxes in the blade frame, 6 numbers per box"),
      param::reals("self_filter_slew_m", {}, -1, -100.0, 100.0, "m",
                   "self-filter boxes on an excavator's upper structure (JointState slew frame), 6 numbers per box"),
      param::reals("self_filter_boom_m", {}, -1, -100.0, 100.0, "m", "the same in the boom frame"),
      param::reals("self_filter_arm_m", {}, -1, -100.0, 100.0, "m", "the same in the arm frame"),
      param::reals("self_filter_bucket_m", {}, -1, -100.0, 100.0, "m", "the same in the bucket frame"),
      param::real("self_filter_margin_m", 0.1, 0.0, 10.0, "m", "self-filter boxes grown by this on every side"),
      param::boolean("survey_datum", true,
                     "bring each machine's clouds into the datum of a site survey (clouds of frame survey_frame): "
                     "the median height of its points over undisturbed surveyed ground, low-passed"),
      param::text("survey_frame", "survey", {}, "frame of the survey's clouds"),
      param::real("datum_tau_s", 3.0, 0.0, 1e6, "s", "survey_datum: low-pass time constant of the offset"),
      param::real("datum_gate_m", 0.08, 0.001, 10.0, "m",
                  "survey_datum: points further than this from survey + offset are ground that changed"),
      param::integer("datum_min_points", 200, 1, 1000000000, "survey_datum: fewer points: no update"),
      param::real("datum_max_m", 0.3, 0.0, 100.0, "m", "survey_datum: larger offsets are not taken"),
      param::boolean("follow_robot", false,
                     "re-centre the map on each Pose (or, before any Pose, on the sensor)"),
  };
}

namespace {
// {key, message} if the noise model claims noise-free points (a point of variance 0 makes its
// cell certain: no later point can move it, and two such points give 0/0), else {"", ""}.
std::pair<std::string, std::string> noiseModelProblem(const LidarFusionConfig& c) {
  if (!(c.min_variance_m2 > 0.0) || !std::isfinite(c.min_variance_m2))
    return {"min_variance_m2", "must be > 0 and finite (got " + formatNumber(c.min_variance_m2) + ")"};
  if (c.noise_model == NoiseModel::RangeBased && c.range_noise_a_m == 0.0 && c.range_noise_b == 0.0)
    return {"range_noise_a_m", "range_noise_a_m = 0 and range_noise_b = 0 under sensor_noise: range_based model a "
                               "noise-free LiDAR; give the sensor's range noise (e.g. range_noise_a_m: 0.02)"};
  if ((c.noise_model == NoiseModel::DepthSquared || !c.depth_squared_frames.empty()) && c.sensor_noise_factor == 0.0)
    return {"sensor_noise_factor", "sensor_noise_factor = 0 under sensor_noise: depth_squared models a noise-free "
                                   "sensor; give k in v = k*z_s^2 (e.g. 0.05)"};
  return {};
}
}  // namespace

LidarFusionConfig lidarFusionConfigFrom(const Params& p) {
  LidarFusionConfig c;
  c.noise_model = p.getString("sensor_noise") == "depth_squared" ? NoiseModel::DepthSquared
                                                                 : NoiseModel::RangeBased;
  c.range_noise_a_m = p.getDouble("range_noise_a_m");
  c.range_noise_b = p.getDouble("range_noise_b");
  c.sensor_noise_factor = p.getDouble("sensor_noise_factor");
  c.depth_squared_frames = p.getStrings("depth_squared_frames");
  c.min_range_m = p.getDouble("min_range_m");
  c.max_range_m = p.getDouble("max_range_m");
  c.max_height_above_sensor_m = p.getDouble("max_height_above_sensor_m");
  c.enable_ramped_height_range = p.getBool("enable_ramped_height_range");
  c.ramped_height_range_a = p.getDouble("ramped_height_range_a");
  c.ramped_height_range_b_m = p.getDouble("ramped_height_range_b_m");
  c.ramped_height_range_c_m = p.getDouble("ramped_height_range_c_m");
  c.min_variance_m2 = p.getDouble("min_variance_m2");
  c.mahalanobis_thresh = p.getDouble("mahalanobis_thresh");
  c.outlier_variance_m2 = p.getDouble("outlier_variance_m2");
  c.max_variance_m2 = p.getDouble("max_variance_m2");
  c.time_variance_m2_per_s = p.getDouble("time_variance_m2_per_s");
  c.enable_visibility_cleanup = p.getBool("enable_visibility_cleanup");
  c.cleanup_ray_stride = static_cast<int>(p.getInt("cleanup_ray_stride"));
  c.max_ray_length_m = p.getDouble("max_ray_length_m");
  c.cleanup_step = p.getDouble("cleanup_step");
  c.cleanup_cos_thresh = p.getDouble("cleanup_cos_thresh");
  c.cleanup_end_margin_m = p.getDouble("cleanup_end_margin_m");
  c.cleanup_walk = p.getString("cleanup_walk") == "fan" ? CleanupWalk::Fan : CleanupWalk::Exact;
  c.cleanup_fan_lateral_cells = p.getDouble("cleanup_fan_lateral_cells");
  c.enable_drift_compensation = p.getBool("enable_drift_compensation");
  c.survey_datum = p.getBool("survey_datum");
  c.survey_frame = p.getString("survey_frame");
  c.datum_tau_s = p.getDouble("datum_tau_s");
  c.datum_gate_m = p.getDouble("datum_gate_m");
  c.datum_min_points = p.getInt("datum_min_points");
  c.datum_max_m = p.getDouble("datum_max_m");
  c.drift_compensation_alpha = p.getDouble("drift_compensation_alpha");
  c.drift_compensation_variance_inlier_m2 = p.getDouble("drift_compensation_variance_inlier_m2");
  c.max_drift_m = p.getDouble("max_drift_m");
  c.min_height_drift_cnt = p.getInt("min_height_drift_cnt");
  c.position_noise_thresh_m = p.getDouble("position_noise_thresh_m");
  c.orientation_noise_thresh_rad = p.getDouble("orientation_noise_thresh_rad");
  c.follow_robot = p.getBool("follow_robot");
  c.self_filter_base_m = p.getDoubles("self_filter_base_m");
  c.self_filter_blade_m = p.getDoubles("self_filter_blade_m");
  const char* link_keys[4] = {"self_filter_slew_m", "self_filter_boom_m", "self_filter_arm_m", "self_filter_bucket_m"};
  for (int k = 0; k < 4; ++k) c.self_filter_link_m[k] = p.getDoubles(link_keys[k]);
  c.self_filter_margin_m = p.getDouble("self_filter_margin_m");
  if (!(c.min_range_m < c.max_range_m))
    p.fail("min_range_m", "must be smaller than max_range_m (" + formatNumber(c.max_range_m) + "), got " +
                              formatNumber(c.min_range_m));
  if (const auto why = noiseModelProblem(c); !why.first.empty()) p.fail(why.first, why.second);
  return c;
}

void LidarFusion::configure(const LidarFusionConfig& c) {
  auto bad = [](const std::string& key, const std::string& msg) {
    throw ConfigError("lidar_fusion: " + key + ": " + msg);
  };
  auto finiteNonNeg = [&](const char* key, double v) {
    if (!(v >= 0.0) || std::isnan(v)) bad(key, "must be >= 0 (got " + formatNumber(v) + ")");
  };
  finiteNonNeg("range_noise_a_m", c.range_noise_a_m);
  finiteNonNeg("range_noise_b", c.range_noise_b);
  finiteNonNeg("sensor_noise_factor", c.sensor_noise_factor);
  finiteNonNeg("min_range_m", c.min_range_m);
  finiteNonNeg("mahalanobis_thresh", c.mahalanobis_thresh);
  finiteNonNeg("outlier_variance_m2", c.outlier_variance_m2);
  finiteNonNeg("max_variance_m2", c.max_variance_m2);
  finiteNonNeg("time_variance_m2_per_s", c.time_variance_m2_per_s);
  finiteNonNeg("max_ray_length_m", c.max_ray_length_m);
  finiteNonNeg("cleanup_end_margin_m", c.cleanup_end_margin_m);
  if (!(c.min_range_m < c.max_range_m))
    bad("min_range_m", "must be smaller than max_range_m (" + formatNumber(c.max_range_m) + "), got " + formatNumber(c.min_range_m));
  if (const auto why = noiseModelProblem(c); !why.first.empty()) bad(why.first, why.second);
  if (c.cleanup_ray_stride < 1) bad("cleanup_ray_stride", "must be >= 1 (got " + formatNumber(c.cleanup_ray_stride) + ")");
  if (!(c.cleanup_step >= 0.0 && c.cleanup_step <= 1.0))
    bad("cleanup_step", "must be in [0, 1] (got " + formatNumber(c.cleanup_step) + ")");
  if (!(c.cleanup_cos_thresh >= 0.0 && c.cleanup_cos_thresh <= 1.0))
    bad("cleanup_cos_thresh", "must be in [0, 1] (got " + formatNumber(c.cleanup_cos_thresh) + ")");
  if (!(c.cleanup_fan_lateral_cells > 0.0 && c.cleanup_fan_lateral_cells <= 8.0))
    bad("cleanup_fan_lateral_cells", "must be in (0, 8] (got " + formatNumber(c.cleanup_fan_lateral_cells) + ")");
  if (!(c.drift_compensation_alpha >= 0.0 && c.drift_compensation_alpha <= 1.0))
    bad("drift_compensation_alpha", "must be in [0, 1] (got " + formatNumber(c.drift_compensation_alpha) + ")");
  self_filter_.configure(c.self_filter_base_m, c.self_filter_blade_m, c.self_filter_margin_m, "self_filter_base_m",
                         "self_filter_blade_m");
  self_filter_.configureLinks(c.self_filter_link_m,
                              {"self_filter_slew_m", "self_filter_boom_m", "self_filter_arm_m", "self_filter_bucket_m"});
  config_ = c;
}

}  // namespace terramap::plugins
