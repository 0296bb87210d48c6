#pragma once
/// \file
/// The map as a ROS 2 recording: an MCAP file (profile "ros2", what rosbag2 writes, so
/// `ros2 bag play`, Foxglove and @mcap/core read it) of `grid_map_msgs/msg/GridMap` messages,
/// one per map update, optionally with the clouds that made them. The pipeline's
/// `outputs: {mcap: {...}}` writes it (docs/ros2.md).
///
/// GridMap conventions (grid_map_ros's GridMapRosConverter::toMessage): header.frame_id the map
/// frame, header.stamp the update's event stamp; info.resolution (m), info.length_x = rows x
/// resolution, info.length_y = cols x resolution, info.pose the map centre (z 0, identity
/// orientation); `layers` the configured names; each data[k] a std_msgs/Float32MultiArray in
/// column-major order, layout.dim[0] = {"column_index", cols, rows x cols} and
/// dim[1] = {"row_index", rows, rows}, data_offset 0: value index i + j x rows is cell (i, j),
/// row i running along -x from the map's +x edge and column j along -y (terramap's index
/// convention is grid_map's); NaN = unknown, also for a layer no stage has created yet at that
/// update. outer/inner_start_index are 0: the data is written in logical order, the circular
/// buffer already unrolled. basic_layers is empty.
/// Clouds (copy_clouds): sensor_msgs/msg/PointCloud2 in the sensor frame (fields x, y, z,
/// intensity as FLOAT32, unorganised) and a tf2_msgs/msg/TFMessage on /tf with the sensor's
/// pose (map frame -> the cloud's frame) at the cloud's stamp, so a viewer places the cloud.
/// Every schema record carries its full ros2msg definition.
///
/// The file is written under a temporary name and renamed into place by close() (AtomicFile).
/// Threading: one writer per thread.
#include <terramap/core/events.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/io/mcap.hpp>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace terramap::io {

struct GridMapMcapOptions {
  std::vector<std::string> layers;  ///< written in this order (at least one)
  std::string topic = "/terramap/grid_map";
  std::string frame_id = "map";
  bool copy_clouds = false;
  std::string cloud_topic = "/terramap/points";
  mcap::Compression compression = mcap::Compression::Zstd;
};

/// Memory one GridMap message of `g` with `layers` layers takes while written: the layers'
/// values, their CDR encoding and the chunk they are compressed into.
std::uint64_t gridMapMcapWorkingBytes(const Geometry& g, std::size_t layers);

class GridMapMcapWriter {
 public:
  /// \throws OutputError when the temporary file cannot be created; ConfigError without layers.
  GridMapMcapWriter(const std::string& path, GridMapMcapOptions options);
  /// A GridMap of `map`'s configured layers at `stamp` (s). \throws OutputError.
  void writeMap(const LayeredMap& map, double stamp);
  /// The cloud and its pose (copy_clouds only; ignored otherwise). \throws OutputError.
  void writeCloud(const PointCloud& cloud);
  /// Completes and renames the file. \throws OutputError.
  void close();
  std::uint64_t mapMessages() const { return maps_; }

 private:
  GridMapMcapOptions options_;
  mcap::Writer writer_;
  std::uint16_t map_channel_ = 0, cloud_channel_ = 0, tf_channel_ = 0;
  std::uint64_t maps_ = 0;
};

}  // namespace terramap::io
