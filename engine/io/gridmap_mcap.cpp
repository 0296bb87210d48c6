#include <terramap/io/gridmap_mcap.hpp>

#include <terramap/core/error.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/io/ros2_messages.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>

namespace terramap::io {

namespace {

std::uint64_t nanoseconds(double stamp) {
  return stamp > 0 ? static_cast<std::uint64_t>(std::llround(stamp * 1e9)) : 0;
}

/// The cloud message's fields: x, y, z, intensity, FLOAT32 each, 16 bytes a point.
std::vector<ros2::PointField> xyziFields() {
  std::vector<ros2::PointField> f;
  const char* names[] = {"x", "y", "z", "intensity"};
  for (std::uint32_t k = 0; k < 4; ++k) f.push_back({names[k], 4 * k, ros2::kFloat32, 1});
  return f;
}

}  // namespace

std::uint64_t gridMapMcapWorkingBytes(const Geometry& g, std::size_t layers) {
  const std::uint64_t values = saturatingProduct({static_cast<std::uint64_t>(g.size().x()),
                                                  static_cast<std::uint64_t>(g.size().y()), layers, sizeof(float)});
  // The values, their encoding, the open chunk holding it and the compressed chunk.
  return saturatingProduct({values, 4});
}

GridMapMcapWriter::GridMapMcapWriter(const std::string& path, GridMapMcapOptions options)
    : options_(std::move(options)), writer_(path, "ros2", options_.compression) {
  if (options_.layers.empty()) throw ConfigError(path + ": an MCAP GridMap output needs at least one layer");
  const std::string type = "grid_map_msgs/msg/GridMap";
  const auto schema = writer_.addSchema(type, "ros2msg", ros2::messageDefinition(type));
  map_channel_ = writer_.addChannel(options_.topic, schema, "cdr");
  if (options_.copy_clouds) {
    const std::string ct = "sensor_msgs/msg/PointCloud2", tt = "tf2_msgs/msg/TFMessage";
    cloud_channel_ = writer_.addChannel(options_.cloud_topic, writer_.addSchema(ct, "ros2msg", ros2::messageDefinition(ct)), "cdr");
    tf_channel_ = writer_.addChannel("/tf", writer_.addSchema(tt, "ros2msg", ros2::messageDefinition(tt)), "cdr");
  }
}

void GridMapMcapWriter::writeMap(const LayeredMap& map, double stamp) {
  const Geometry& g = map.geometry();
  ros2::GridMapMsg m;
  m.header.stamp = ros2::Time::fromSeconds(stamp);
  m.header.frame_id = options_.frame_id;
  m.resolution = g.resolution();
  m.rows = static_cast<std::uint32_t>(g.size().x());
  m.cols = static_cast<std::uint32_t>(g.size().y());
  m.length_x = m.rows * g.resolution();
  m.length_y = m.cols * g.resolution();
  m.position = Eigen::Vector3d(g.center().x(), g.center().y(), 0.0);
  m.layers = options_.layers;
  const std::size_t cells = static_cast<std::size_t>(m.rows) * m.cols;
  m.data.resize(m.layers.size());
  for (std::size_t k = 0; k < m.layers.size(); ++k) {
    m.data[k].assign(cells, std::numeric_limits<float>::quiet_NaN());
    if (map.hasLayer(m.layers[k])) map.readLayer(map.layerId(m.layers[k]), m.data[k].data(), m.rows, m.cols);
  }
  const std::vector<std::uint8_t> bytes = ros2::encodeGridMap(m);
  const std::uint64_t t = nanoseconds(stamp);
  writer_.write(map_channel_, t, t, bytes.data(), bytes.size());
  ++maps_;
}

void GridMapMcapWriter::writeCloud(const PointCloud& cloud) {
  if (!options_.copy_clouds) return;
  ros2::PointCloud2 c;
  c.header.stamp = ros2::Time::fromSeconds(cloud.stamp);
  c.header.frame_id = cloud.frame;
  c.height = 1;
  c.width = static_cast<std::uint32_t>(cloud.points.size());
  c.fields = xyziFields();
  c.point_step = 16;
  c.row_step = c.width * 16;
  c.data.resize(cloud.points.size() * 16);
  for (std::size_t i = 0; i < cloud.points.size(); ++i) {
    const PointXYZI& p = cloud.points[i];
    const float v[4] = {p.x, p.y, p.z, p.intensity};
    std::memcpy(c.data.data() + 16 * i, v, 16);
  }
  c.is_dense = std::all_of(cloud.points.begin(), cloud.points.end(),
                           [](const PointXYZI& p) { return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z); });
  const std::uint64_t t = nanoseconds(cloud.stamp);
  ros2::TransformStamped tf;
  tf.header.stamp = c.header.stamp;
  tf.header.frame_id = options_.frame_id;
  tf.child_frame_id = cloud.frame;
  tf.translation = cloud.T_map_sensor.translation();
  tf.rotation = Eigen::Quaterniond(cloud.T_map_sensor.rotation());
  const auto tf_bytes = ros2::encodeTFMessage({tf});
  writer_.write(tf_channel_, t, t, tf_bytes.data(), tf_bytes.size());
  const auto bytes = ros2::encodePointCloud2(c);
  writer_.write(cloud_channel_, t, t, bytes.data(), bytes.size());
}

void GridMapMcapWriter::close() { writer_.close(); }

}  // namespace terramap::io
