#pragma once
/// \file
/// A folder of point-cloud files + poses -> terramap::PointCloud events, one at a time.
/// The pipeline wraps it as the YAML `source: {type: sequence, ...}`.
///
/// Construction lists the folder, assigns every frame its stamp and pose and validates all of
/// it (so a bad times file or a trajectory that does not cover frame 900 fails before the
/// run, not after an hour); clouds themselves are read lazily, one per next()/load() call,
/// so memory holds one cloud regardless of the sequence length.
///
/// Frames and poses:
///   T_map_sensor(k) = T_map_world * T_world_body(k) * T_body_sensor
/// where T_world_body(k) comes from SequencePoses (interpolated at the frame's stamp, or
/// per-frame by index, or identity). For LAS files, whose points are origin-shifted
/// (CloudFile::origin), the origin is folded into the event's pose: the event's
/// T_map_sensor = T_map_sensor(k) * Translation(origin), so map coordinates are exact.
///
/// Threading: a SequenceSource is not shared between threads (next() advances a cursor);
/// load(k) is const and may be called concurrently.
#include <terramap/core/events.hpp>
#include <terramap/io/trajectory.hpp>

#include <Eigen/Geometry>
#include <cstddef>
#include <limits>
#include <optional>
#include <string>
#include <vector>

namespace terramap::io {

/// Where each frame's body pose comes from.
class SequencePoses {
 public:
  enum class Kind { Identity, Interpolated, PerFrame };
  /// Every frame at T_world_body = I (clouds already in the world frame, e.g. LAS tiles).
  static SequencePoses identity();
  /// T_world_body(stamp of frame k) from a stamped trajectory (TUM, KITTI + times).
  static SequencePoses interpolated(Trajectory trajectory);
  /// T_world_body of frame k = poses[k] where k is the frame's index (see FrameIndex);
  /// e.g. KITTI pose rows or chainRelativePoses(). `source` names them in errors.
  static SequencePoses perFrame(std::vector<Eigen::Isometry3d> poses, std::string source);

  Kind kind() const { return kind_; }
  const Trajectory& trajectory() const { return trajectory_; }
  const std::vector<Eigen::Isometry3d>& frames() const { return frames_; }
  const std::string& source() const { return source_; }

 private:
  Kind kind_ = Kind::Identity;
  Trajectory trajectory_;
  std::vector<Eigen::Isometry3d> frames_;
  std::string source_;
};

/// Pose file formats loadSequencePoses understands.
enum class PoseFileFormat {
  Auto,      ///< from the first data line: 8 values -> Tum, 12 -> KittiRows, `a->b` or 16 -> Relative
  Tum,       ///< readTumTrajectory, interpolated at frame stamps
  KittiRows, ///< readKittiPoseRows, per frame
  Relative,  ///< readRelativePoses + chainRelativePoses, per frame (T_0_k)
};
/// Parses "auto", "tum", "kitti", "relative"; ConfigError (with did-you-mean) otherwise.
PoseFileFormat parsePoseFileFormat(const std::string& name);
/// Format of a pose file decided as PoseFileFormat::Auto describes; InputError naming
/// file:line if the first data line fits none.
PoseFileFormat detectPoseFileFormat(const std::string& path);
/// Loads a pose file as SequencePoses (InputError from the readers).
SequencePoses loadSequencePoses(const std::string& path, PoseFileFormat format = PoseFileFormat::Auto,
                                const TrajectoryReadOptions& options = {});

/// How frame k is numbered for per-frame poses and times files.
enum class FrameIndex {
  Position,        ///< position in the sorted listing of the folder (0, 1, 2, ...)
  FileNameNumber,  ///< the integer the file stem spells (KITTI "000123.bin" -> 123)
};

struct SequenceSpec {
  std::string folder;
  /// Lower-case extensions with the dot; empty = every extension readPointCloud supports.
  /// Matching is case-insensitive; other files in the folder are ignored (e.g. README, .txt).
  std::vector<std::string> extensions;
  /// Files are ordered by name with digit runs compared as numbers ("2.pcd" < "10.pcd");
  /// zero-padded names sort as plain lexicographic order would.

  // Stamps (seconds), first that applies:
  std::string times_file;            ///< line k = stamp of frame index k (readStampFile)
  bool stamps_from_file_names = false;  ///< the stem is a number (e.g. "1317384512.123456.pcd")
  double file_name_stamp_scale = 1.0;   ///< stem number * scale = seconds (1e-9 for nanoseconds)
  double period_s = 0.1;             ///< otherwise stamp = start_stamp_s + index * period_s
  double start_stamp_s = 0.0;

  FrameIndex frame_index = FrameIndex::Position;
  /// Selection after sorting: positions first, first + stride, ... (at most max_frames).
  std::size_t first = 0;
  std::size_t stride = 1;
  std::size_t max_frames = std::numeric_limits<std::size_t>::max();

  std::string frame = "sensor";  ///< PointCloud::frame of the events
  Eigen::Isometry3d T_map_world = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_body_sensor = Eigen::Isometry3d::Identity();  ///< extrinsic calibration
};

class SequenceSource {
 public:
  /// Throws ConfigError for a missing folder, a folder without matching files, bad
  /// period/stride/scale, a per-frame pose list or times file too short for a frame index;
  /// InputError for unreadable stamp files, a file name that is not a number when stamps or
  /// indices come from names, non-increasing stamps (naming both files), or a trajectory that
  /// does not cover a frame's stamp (naming the file and the stamp).
  SequenceSource(SequenceSpec spec, SequencePoses poses);

  std::size_t size() const { return files_.size(); }
  /// Selected files in emission order (full paths).
  const std::vector<std::string>& files() const { return files_; }
  double stamp(std::size_t k) const { return stamps_.at(k); }
  /// T_map_sensor of frame k (before any LAS origin shift).
  const Eigen::Isometry3d& pose(std::size_t k) const { return poses_.at(k); }
  /// Reads frame k (InputError from the reader).
  PointCloud load(std::size_t k) const;

  /// The next frame in order, or nothing at the end. Reads one file.
  std::optional<PointCloud> next();
  std::size_t position() const { return cursor_; }
  void rewind() { cursor_ = 0; }

 private:
  SequenceSpec spec_;
  std::vector<std::string> files_;
  std::vector<double> stamps_;
  std::vector<Eigen::Isometry3d> poses_;
  std::size_t cursor_ = 0;
};

}  // namespace terramap::io
