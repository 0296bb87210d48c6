#pragma once
/// \file
/// lidar_fusion's self-filter: drops the points that lie on the machines themselves (chassis,
/// tracks, cab, lift arms, blade), as elevation_mapping_cupy does with its robot boxes, so the
/// machine is not fused into the map as a mound that moves with it. Boxes are axis-aligned in
/// the base frame (placed with every machine's latest `Pose`) or in the blade frame (placed with
/// every machine's latest `BladePose`), grown by a margin that covers the motion between the
/// pose and the scan and the pose error. A point inside any placed box is dropped and counted
/// under the drop reason `self`. Frames and units: metres; base = centre of the track contact
/// plane (x forward, z up), blade = cutting-edge centre (x the face normal). Thread-safe once
/// configured (apply() is const; the poses are set from the plugin's event thread).
#include <terramap/core/events.hpp>

#include <Eigen/Geometry>

#include <array>
#include <map>
#include <string>
#include <vector>

namespace terramap::plugins {

struct SelfFilterBox {
  /// Slew, Boom, Arm, Bucket: an excavator's link frames (JointState::T_map_link, in that order).
  enum class Frame { Base, Blade, Slew, Boom, Arm, Bucket } frame = Frame::Base;
  Eigen::Vector3d min = Eigen::Vector3d::Zero(), max = Eigen::Vector3d::Zero();
};

class SelfFilter {
 public:
  /// `base_m` / `blade_m`: 6 numbers per box, [xmin, ymin, zmin, xmax, ymax, zmax] in that frame.
  /// \throws ConfigError naming `key` when a list is not a multiple of 6, a min is not below its
  ///   max, or the margin is negative.
  void configure(const std::vector<double>& base_m, const std::vector<double>& blade_m, double margin_m,
                 const std::string& base_key, const std::string& blade_key);
  /// Adds boxes on an excavator's links (6 numbers per box in that link's frame, `keys` naming
  /// the four lists in messages), grown by the margin configure() was given; placed with every
  /// machine's latest JointState. Call after configure(). \throws ConfigError as configure().
  void configureLinks(const std::array<std::vector<double>, 4>& link_m, const std::array<std::string, 4>& keys);
  bool enabled() const { return !boxes_.empty(); }
  /// True once every frame the boxes use has a pose (a base box needs a Pose, a blade box a
  /// BladePose): before that, lidar_fusion drops whole clouds (`self_no_pose`). Link boxes do not
  /// wait (a pipeline may have no excavator): an excavator's are placed from its first JointState.
  bool placed() const;
  const std::vector<SelfFilterBox>& boxes() const { return boxes_; }

  /// The latest base pose of the machine whose Pose frame is `frame` ("base" or "<id>/base").
  void setBasePose(const std::string& frame, const Eigen::Isometry3d& T_map_base) { base_[frame] = T_map_base; }
  /// The latest blade pose of machine `machine_id`.
  void setBladePose(const std::string& machine_id, const Eigen::Isometry3d& T_map_blade) {
    blade_[machine_id] = T_map_blade;
  }

  /// The latest link frames (slew, boom, arm, bucket) of excavator `machine_id`.
  void setLinkPoses(const std::string& machine_id, const std::array<Eigen::Isometry3d, 4>& T_map_link) {
    links_[machine_id] = T_map_link;
  }

  /// Copies `in`'s points that lie outside every placed box into `out` (same order, same
  /// stamp, frame and pose) and returns how many it dropped. Boxes of a frame no pose has been
  /// received for yet are not placed. NaN points pass through (the gates count them).
  std::size_t apply(const PointCloud& in, PointCloud& out) const;

 private:
  std::vector<SelfFilterBox> boxes_;
  std::map<std::string, Eigen::Isometry3d> base_, blade_;
  std::map<std::string, std::array<Eigen::Isometry3d, 4>> links_;
  double margin_m_ = 0;
};

}  // namespace terramap::plugins
