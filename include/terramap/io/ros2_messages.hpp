#pragma once
/// \file
/// The ROS 2 messages terramap reads from and writes to rosbag2/MCAP files, in their wire form:
/// CDR as ROS 2 serialises it (XCDR1, little-endian, the 4-byte encapsulation header 00 01 00 00;
/// each primitive aligned to its size counted from the byte after that header; strings as a
/// u32 length including the NUL, sequences as a u32 count). No ROS installation is needed.
///
/// Read: sensor_msgs/msg/PointCloud2, tf2_msgs/msg/TFMessage, nav_msgs/msg/Odometry.
/// Written: the same three (tests write bags with them) and grid_map_msgs/msg/GridMap.
/// Units are the messages' own: metres, seconds + nanoseconds, unit quaternions (x, y, z, w).
///
/// Decoders throw InputError naming `where` (the caller passes the file, topic and message
/// index) and the field that runs past the message's end or is malformed (a big-endian
/// encapsulation, a string without its NUL). Every function is reentrant.
#include <terramap/core/events.hpp>

#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <vector>

namespace terramap::io::ros2 {

struct Time {
  std::int32_t sec = 0;
  std::uint32_t nanosec = 0;
  /// sec + nanosec / 1e9 (the division rounds once, so 100000000 ns is exactly the double 0.1).
  double seconds() const { return static_cast<double>(sec) + static_cast<double>(nanosec) / 1e9; }
  std::int64_t nanoseconds() const { return static_cast<std::int64_t>(sec) * 1000000000 + nanosec; }
  /// The nearest Time to `s` seconds (s >= 0 expected; nanosec in [0, 1e9)).
  static Time fromSeconds(double s);
};

struct Header {
  Time stamp;
  std::string frame_id;
};

/// sensor_msgs/msg/PointField's datatype constants.
enum PointFieldType : std::uint8_t { kInt8 = 1, kUint8 = 2, kInt16 = 3, kUint16 = 4, kInt32 = 5, kUint32 = 6, kFloat32 = 7, kFloat64 = 8 };

struct PointField {
  std::string name;
  std::uint32_t offset = 0;
  std::uint8_t datatype = kFloat32;
  std::uint32_t count = 1;
};

struct PointCloud2 {
  Header header;
  std::uint32_t height = 1, width = 0;
  std::vector<PointField> fields;
  bool is_bigendian = false;
  std::uint32_t point_step = 0, row_step = 0;
  std::vector<std::uint8_t> data;
  bool is_dense = false;
};

struct TransformStamped {
  Header header;  ///< header.frame_id = the parent frame
  std::string child_frame_id;
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  /// T_parent_child.
  Eigen::Isometry3d transform() const;
};

struct Odometry {
  Header header;  ///< header.frame_id = the frame the pose is in (e.g. "odom" or "map")
  std::string child_frame_id;  ///< the body frame (e.g. "base_link")
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
  std::array<double, 36> pose_covariance{};
  Eigen::Vector3d linear = Eigen::Vector3d::Zero(), angular = Eigen::Vector3d::Zero();  ///< twist in child frame
  std::array<double, 36> twist_covariance{};
  /// T_frame_child.
  Eigen::Isometry3d pose() const;
};

/// grid_map_msgs/msg/GridMap as grid_map's GridMapRosConverter::toMessage fills it: every layer
/// a std_msgs/Float32MultiArray, column-major (Eigen's default), layout.dim[0] = {"column_index",
/// cols, rows * cols}, dim[1] = {"row_index", rows, rows}, data_offset 0. Row i runs along -x
/// from the map's +x edge, column j along -y (terramap's own index convention, geometry.hpp,
/// which is grid_map's). NaN = unknown.
struct GridMapMsg {
  Header header;
  double resolution = 0, length_x = 0, length_y = 0;  ///< metres; length_x = rows * resolution
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  ///< the map's centre in header.frame_id
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
  std::vector<std::string> layers, basic_layers;
  std::uint32_t rows = 0, cols = 0;
  std::vector<std::vector<float>> data;  ///< per layer, rows * cols values, column-major
  std::uint16_t outer_start_index = 0, inner_start_index = 0;
};

PointCloud2 decodePointCloud2(const std::uint8_t* p, std::size_t n, const std::string& where);
std::vector<TransformStamped> decodeTFMessage(const std::uint8_t* p, std::size_t n, const std::string& where);
Odometry decodeOdometry(const std::uint8_t* p, std::size_t n, const std::string& where);
GridMapMsg decodeGridMap(const std::uint8_t* p, std::size_t n, const std::string& where);

std::vector<std::uint8_t> encodePointCloud2(const PointCloud2& m);
std::vector<std::uint8_t> encodeTFMessage(const std::vector<TransformStamped>& m);
std::vector<std::uint8_t> encodeOdometry(const Odometry& m);
std::vector<std::uint8_t> encodeGridMap(const GridMapMsg& m);

/// The points of a cloud in its own frame (header.frame_id), row by row for an organised cloud
/// (height > 1), NaN points kept. Accepted: little-endian data whose fields x, y and z are each
/// one float32 or float64; intensity from the first field named "intensity", "reflectance" or
/// "i" (any numeric type, count 1), else NaN; other fields are skipped.
/// \throws InputError naming `where` and the field: big-endian data, x/y/z missing or of
///   another type or count, a field past point_step, width * point_step > row_step, data
///   shorter than row_step * height.
std::vector<PointXYZI> cloudPoints(const PointCloud2& cloud, const std::string& where);

/// The ros2msg definitions rosbag2 stores in an MCAP schema record: the message's own text,
/// then each type it uses after a line of 80 '=' and "MSG: package/Type". Keys are the full
/// names ("sensor_msgs/msg/PointCloud2", "tf2_msgs/msg/TFMessage", "nav_msgs/msg/Odometry",
/// "grid_map_msgs/msg/GridMap"). \throws InternalError for another name.
const std::string& messageDefinition(const std::string& type);

}  // namespace terramap::io::ros2
