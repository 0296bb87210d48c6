#pragma once
/// \file
/// A rosbag2 recording in MCAP storage -> terramap::PointCloud events with the sensor's pose,
/// one cloud at a time. The pipeline wraps it as `source: {type: rosbag, ...}`
/// (docs/ros2.md, docs/pipelines.md).
///
/// Clouds: the `sensor_msgs/msg/PointCloud2` messages of one topic, in file order, each read by
/// ros2::cloudPoints (x/y/z float32 or float64, little-endian, organised or not, intensity
/// optional). The event's stamp is the message's header.stamp (seconds), its frame the header's
/// frame_id, its T_map_sensor the pose of that frame in the map frame at that stamp.
///
/// Poses, one of:
/// - PoseSource::Tf: `tf2_msgs/msg/TFMessage` on the tf topics (default /tf and /tf_static;
///   /tf_static's transforms hold at every time). T_map_sensor(t) is the chain of transforms from
///   the cloud's frame up through its parents to `map_frame`, each dynamic link interpolated at
///   t between its two nearest samples (translation linear, rotation slerp), as tf2's
///   lookupTransform(map_frame, cloud_frame, t) does.
/// - PoseSource::Odometry: `nav_msgs/msg/Odometry` on one topic: T_map_child(t) interpolated the
///   same way (its header.frame_id is the map frame; `map_frame`, when given, must equal it),
///   times the tf chain from the cloud's frame to the odometry's child frame (identity when they
///   are the same frame).
/// A cloud whose stamp lies outside a dynamic link's samples (tf2 would say "extrapolation") or
/// whose frame has no chain to the map frame at all yet is dropped and counted
/// ("rosbag_no_pose"); one whose stamp goes back in time is dropped as "rosbag_stamp_backwards".
///
/// Construction reads the whole file once (transforms and odometry kept, clouds only counted)
/// and checks the configuration against it: a missing topic, a topic of another message type or
/// encoding, a map frame no transform mentions are ConfigErrors naming the bag and what it
/// has. A cloud that cannot be read throws InputError naming the file, the topic, the message's
/// index on it and the field.
///
/// Memory: the transforms and odometry (checked against the budget as they grow), one chunk
/// and one cloud. Threading: one object per thread (next() advances a cursor).
#include <terramap/core/events.hpp>

#include <Eigen/Geometry>
#include <cstddef>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace terramap::io {

namespace mcap {
class Reader;
}

struct RosbagSpec {
  std::string path;         ///< the .mcap file
  std::string cloud_topic;  ///< e.g. "/velodyne_points"
  enum class PoseSource { Tf, Odometry } pose_source = PoseSource::Tf;
  std::string map_frame = "map";  ///< Tf: the root the chain ends at; Odometry: checked when not empty
  std::vector<std::string> tf_topics = {"/tf", "/tf_static"};
  std::string odometry_topic;  ///< PoseSource::Odometry
  /// The frame whose pose a Pose event carries (emitted before each cloud by the pipeline
  /// source); empty = the cloud's own frame (as the `sequence` source does).
  std::string base_frame;
  std::size_t max_clouds = std::numeric_limits<std::size_t>::max();
};

/// One cloud with its poses.
struct RosbagCloud {
  PointCloud cloud;
  Eigen::Isometry3d T_map_base = Eigen::Isometry3d::Identity();  ///< RosbagSpec::base_frame's pose
};

class RosbagSource {
 public:
  /// \throws ConfigError (topics, frames), InputError (a malformed file or message).
  explicit RosbagSource(RosbagSpec spec);
  ~RosbagSource();
  RosbagSource(const RosbagSource&) = delete;
  RosbagSource& operator=(const RosbagSource&) = delete;

  /// The next cloud that has a pose, or nothing at the end. \throws InputError.
  std::optional<RosbagCloud> next();
  /// Clouds on the cloud topic (up to max_clouds).
  std::size_t cloudCount() const { return clouds_total_; }
  /// Clouds read so far (emitted or dropped).
  std::size_t position() const { return clouds_seen_; }
  std::map<std::string, long> dropped() const { return dropped_; }

  /// T_target_source at `t` from the bag's transforms (tf2's lookupTransform); nothing when
  /// the chain is incomplete or `t` is outside a dynamic link's samples. For tests and tools.
  std::optional<Eigen::Isometry3d> lookup(const std::string& target, const std::string& source, double t) const;

 private:
  struct Link {
    std::string parent;
    bool is_static = false;
    std::vector<std::pair<double, Eigen::Isometry3d>> samples;  ///< sorted by time
  };
  std::optional<Eigen::Isometry3d> chainToRoot(const std::string& frame, const std::string& root, double t) const;
  std::optional<Eigen::Isometry3d> poseOf(const std::string& frame, double t) const;
  static std::optional<Eigen::Isometry3d> interpolate(const std::vector<std::pair<double, Eigen::Isometry3d>>& s,
                                                      double t);
  void addTransform(const std::string& parent, const std::string& child, bool is_static, double t,
                    const Eigen::Isometry3d& T, const std::string& where);
  void countBytes(std::size_t bytes);

  RosbagSpec spec_;
  std::unique_ptr<mcap::Reader> reader_;
  std::map<std::string, Link> links_;  ///< by child frame
  std::vector<std::pair<double, Eigen::Isometry3d>> odometry_;
  std::string odometry_frame_, odometry_child_;
  std::uint64_t kept_bytes_ = 0;
  std::size_t clouds_total_ = 0, clouds_seen_ = 0;
  double last_stamp_ = -std::numeric_limits<double>::infinity();
  std::map<std::string, long> dropped_;
};

}  // namespace terramap::io
