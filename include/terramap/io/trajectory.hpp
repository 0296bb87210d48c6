#pragma once
/// \file
/// Pose trajectories: TUM files, KITTI pose rows (+ times file or fixed period), relative-pose
/// chains (e.g. frame-to-frame ICP), and interpolation at arbitrary stamps.
///
/// Frames: a trajectory maps a moving `body` frame into a fixed `world` frame, T_world_body
/// (p_world = T_world_body * p_body). For KITTI ground truth, world = the first camera frame
/// and body = camera 0 (not the velodyne: compose with the calibration Tr on the right).
/// Stamps are seconds, strictly increasing. Rotations are kept exactly orthonormal.
///
/// Every reader refuses what it cannot trust with terramap::InputError naming `file:line`:
/// wrong number of values, non-numeric tokens, NaN/inf, quaternions whose norm is off by more
/// than the tolerance (closer ones are normalised: files print 6-9 digits), rotation matrices
/// that are not orthonormal with determinant +1 within tolerance (closer ones are projected to
/// the nearest rotation), non-increasing stamps. '#' starts a comment; blank lines are skipped.
/// Readers are reentrant; a Trajectory is immutable after construction, so const use from
/// several threads is safe.
#include <Eigen/Geometry>
#include <cstddef>
#include <limits>
#include <optional>
#include <string>
#include <vector>

namespace terramap::io {

/// One pose at one instant.
struct StampedPose {
  double stamp = 0.0;  ///< seconds
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();
};

/// Tolerances for the rotation checks. Defaults accept files printed with 6 significant
/// digits (KITTI, TUM tools) and refuse anything that is not a rotation at all.
struct TrajectoryReadOptions {
  /// |‖q‖ − 1| above this is refused; at or below it q is normalised.
  double quaternion_norm_tolerance = 1e-3;
  /// max |(RᵀR − I)_ij| above this (or det R <= 0) is refused; at or below it R is replaced
  /// by the nearest rotation (SVD projection).
  double rotation_tolerance = 1e-4;
};

/// Time-ordered poses with interpolation.
class Trajectory {
 public:
  Trajectory() = default;
  /// \param source names the origin (usually a file path) in error messages.
  /// Throws InputError if a stamp is not finite or stamps are not strictly increasing
  /// (naming the source and the index), or if a rotation is not orthonormal (1e-6).
  explicit Trajectory(std::vector<StampedPose> poses, std::string source = "trajectory");

  const std::vector<StampedPose>& poses() const { return poses_; }
  const std::string& source() const { return source_; }
  std::size_t size() const { return poses_.size(); }
  bool empty() const { return poses_.empty(); }
  /// First/last stamp; NaN when empty.
  double startStamp() const;
  double endStamp() const;
  /// True if `stamp` lies in [startStamp, endStamp] (a one-pose trajectory contains only its stamp).
  bool contains(double stamp) const;

  /// Pose at `stamp`: linear interpolation of the translation and spherical (shortest-arc
  /// slerp) interpolation of the rotation between the two bracketing poses; exact at the
  /// stored stamps. O(log n).
  /// Throws InputError naming the source, the stamp and the covered range when `stamp` is
  /// outside [startStamp, endStamp] or NaN: extrapolating a pose silently misplaces a whole
  /// cloud, so the caller must decide (e.g. skip the frame, or extend the trajectory).
  Eigen::Isometry3d at(double stamp) const;
  /// Same as at() but empty instead of throwing when `stamp` is not covered.
  std::optional<Eigen::Isometry3d> tryAt(double stamp) const;

 private:
  std::vector<StampedPose> poses_;
  std::vector<Eigen::Quaterniond> rotations_;  // cached for slerp, parallel to poses_
  std::string source_;
};

/// TUM RGB-D format: one pose per line, `stamp tx ty tz qx qy qz qw` (seconds, metres,
/// Hamilton quaternion, scalar last), T_world_body.
Trajectory readTumTrajectory(const std::string& path, const TrajectoryReadOptions& options = {});

/// Writes `traj` as a TUM file (`stamp tx ty tz qx qy qz qw`, full double precision, so
/// readTumTrajectory gives the same stamps back), atomically; `comment` (may be empty) becomes
/// a leading '#' line. \throws OutputError.
void writeTumTrajectory(const std::string& path, const Trajectory& traj, const std::string& comment = "");

/// KITTI odometry poses: one pose per line, 12 numbers = the 3x4 matrix [R | t] row-major
/// (T_world_body of frame k on line k). No stamps.
std::vector<Eigen::Isometry3d> readKittiPoseRows(const std::string& path, const TrajectoryReadOptions& options = {});

/// One stamp (seconds) per line, e.g. KITTI `times.txt`. Strictly increasing, finite.
std::vector<double> readStampFile(const std::string& path);

/// KITTI poses stamped from a times file (line k of each file = frame k). Throws InputError
/// naming both files when their counts differ.
Trajectory readKittiTrajectory(const std::string& poses_path, const std::string& times_path,
                               const TrajectoryReadOptions& options = {});
/// KITTI poses stamped at start_stamp_s + k * period_s (KITTI velodyne: 0.1 s).
/// Throws ConfigError if period_s is not a positive finite number.
Trajectory readKittiTrajectory(const std::string& poses_path, double period_s, double start_stamp_s = 0.0,
                               const TrajectoryReadOptions& options = {});

/// One relative pose: T_prev_cur maps points of frame `cur` into frame `prev`.
struct RelativePose {
  int prev = 0;
  int cur = 1;
  Eigen::Isometry3d T_prev_cur = Eigen::Isometry3d::Identity();
  /// Registration residual in metres if the file gives one (`res=`), else NaN.
  double residual_m = std::numeric_limits<double>::quiet_NaN();
};

/// Relative-pose rows, e.g. the KITTI frames' DERIVED_icp_relative_poses.txt (data/README.md):
/// `[prev->cur] n1 .. n12|n16 [key=value ...]`, where the numbers are the 3x4 or 4x4
/// row-major T_prev_cur (row i maps frame i into frame i-1). The optional `a->b` label must
/// satisfy b == a + 1; without labels row k (0-based) is frame k -> k+1. Rows must be
/// consecutive (each row's prev is the previous row's cur). A 4x4 matrix must end 0 0 0 1.
/// Of the trailing key=value tokens only `res` (residual, metres) is read; others are ignored.
std::vector<RelativePose> readRelativePoses(const std::string& path, const TrajectoryReadOptions& options = {});

/// Chains relative poses into absolute ones: element k is T_p_{p+k} where p = rel[0].prev
/// (element 0 is the identity), T_p_{i} = T_p_{i-1} * T_{i-1}_{i}. Returns {I} for an empty
/// input. Throws InputError if the rows are not consecutive.
std::vector<Eigen::Isometry3d> chainRelativePoses(const std::vector<RelativePose>& rel);

/// How comparePaths aligns a path to its reference before measuring: not at all, by the rigid
/// motion in the horizontal plane (rotation about z and an xy shift; heights compared as they
/// are) or by a rigid 3D motion, each the least-squares fit over the paired positions
/// (Umeyama's method without scale, Eigen::umeyama).
enum class PathAlignment { None, Se2, Se3 };
/// "none", "se2", "se3". 	hrows ConfigError naming `what` and the known names otherwise.
PathAlignment parsePathAlignment(const std::string& name, const std::string& what);

/// A path against a reference path (e.g. a replayed or simulated machine against the logged
/// one; TERA's real-versus-simulated comparison). Distances in metres.
struct PathComparison {
  std::size_t pairs = 0;              ///< path poses inside the reference's time span
  double start_stamp = 0, end_stamp = 0;
  double length_m = 0;                ///< the path's length over the paired poses
  double reference_length_m = 0;      ///< the reference's, interpolated at the same stamps
  double rmse_m = 0, mean_m = 0, max_m = 0, final_m = 0;  ///< 3D position errors after alignment
  double rmse_xy_m = 0;               ///< horizontal part
  Eigen::Isometry3d T_reference_path = Eigen::Isometry3d::Identity();  ///< the alignment applied
};

/// Pairs every pose of `path` whose stamp lies in the reference's span with the reference
/// interpolated there (Trajectory::at), aligns (`alignment`) and measures the position errors.
/// 	hrows InputError naming both sources when fewer than 2 stamps pair (the spans do not
/// overlap) or, for Se2/Se3, when the paired positions are all the same point.
PathComparison comparePaths(const Trajectory& path, const Trajectory& reference, PathAlignment alignment);

}  // namespace terramap::io
