#pragma once
/// \file
/// The solid shape of a machine for the simulated LiDAR: oriented boxes fixed in the base frame
/// (chassis and cab, tracks, lift arms) or in the blade frame (the blade plate), placed at the
/// machine's *true* pose at the scan instant. Rays that reach a box before the terrain return a
/// point on the machine (the mapper must filter them: lidar_fusion's `self_filter`), and the
/// blade hides the ground behind it, which is why blind mapping exists.
///
/// Frames (scenario.hpp, ctl.hpp): base = centre of the track contact plane, x forward, y left,
/// z up; blade = cutting-edge centre, x the face normal (forward), y along the edge to the left,
/// z up the face. Dimensions in metres. Not thread-safe to build; the casting is const.
#include <Eigen/Geometry>

#include <array>

#include <limits>
#include <string>
#include <vector>

namespace terramap::sim {

/// One box of a machine's shape, axis-aligned in its frame.
struct ShapeBox {
  std::string name;                 ///< for messages and docs ("body", "track_left", ...)
  /// Base and Blade on every machine; Slew (the upper structure), Boom, Arm and Bucket on an
  /// excavator (frames of ExcavatorArm::linkFrames, sim/excavator.hpp).
  enum class Frame { Base, Blade, Slew, Boom, Arm, Bucket } frame = Frame::Base;
  Eigen::Vector3d min = Eigen::Vector3d::Zero(), max = Eigen::Vector3d::Zero();  ///< corners, m
};

/// A compact track loader with a dozer blade (CAT 299-class estimates; docs/sim.md "Occlusion").
/// `gauge_m`, `track_length_m`, blade width and height come from the machine spec so the shape
/// follows them.
std::vector<ShapeBox> defaultCtlShape(double gauge_m, double track_length_m, double blade_width_m,
                                      double blade_height_m);

/// A compact excavator (Takeuchi TB235-class estimates): tracks on the base, the plow in the
/// blade frame, the house and cab on the slew frame, boom and arm as boxes along their lines, the
/// bucket as its mesh's bounding box (`bucket_*`: the bucket frame's extents, m).
std::vector<ShapeBox> defaultExcavatorShape(double gauge_m, double track_length_m, double track_width_m,
                                            double plow_width_m, double plow_height_m, double boom_m, double arm_m,
                                            const Eigen::Vector3d& bucket_min, const Eigen::Vector3d& bucket_max);

/// A box placed in the map frame: centre, rotation (columns = box axes) and half extents.
struct PlacedBox {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d half = Eigen::Vector3d::Zero();
  double radius = 0;  ///< of the bounding sphere (|half|)
};

/// The boxes of one machine at (true) base and blade poses and, for an excavator, its link poses
/// (slew, boom, arm, bucket; boxes of those frames are left out when `T_map_links` is null).
void placeShape(const std::vector<ShapeBox>& shape, const Eigen::Isometry3d& T_map_base,
                const Eigen::Isometry3d& T_map_blade, std::vector<PlacedBox>& out,
                const std::array<Eigen::Isometry3d, 4>* T_map_links = nullptr);

/// First entry of the ray o + t d (|d| = 1) into any box for t in [t_min, t_max]; +inf when
/// none. A ray that starts inside a box ignores that box (a sensor mounted on the machine sees
/// out of its own housing). On a hit, *normal is the outward normal of the face entered.
/// Thread-safe (const inputs).
double firstBoxHit(const std::vector<PlacedBox>& boxes, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                   double t_min, double t_max, Eigen::Vector3d* normal);
/// The same over the boxes boxes[idx[0..n-1]] (a caller's pre-culled candidates).
double firstBoxHit(const PlacedBox* boxes, const int* idx, int n, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                   double t_min, double t_max, Eigen::Vector3d* normal);

}  // namespace terramap::sim
