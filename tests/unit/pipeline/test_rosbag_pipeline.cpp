// The `rosbag` source's settings and `outputs.mcap` in a pipeline (docs/ros2.md): what the YAML
// refuses, where, and a run writing one GridMap per `every` clouds plus the finished map.
#include <terramap/core/error.hpp>
#include <terramap/io/mcap.hpp>
#include <terramap/io/ros2_messages.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/pipeline/run.hpp>
#include <terramap/pipeline/source.hpp>

#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>

using namespace terramap;
namespace fs = std::filesystem;

namespace {

void expectHas(const std::string& msg, const std::string& part) {
  EXPECT_NE(msg.find(part), std::string::npos) << "expected '" << part << "' in:\n" << msg;
}

template <class F>
std::string configErrorOf(F&& f) {
  try {
    f();
  } catch (const ConfigError& e) {
    return e.what();
  }
  ADD_FAILURE() << "no ConfigError";
  return {};
}

fs::path scratch(const std::string& tag) {
  const fs::path d = fs::path(TERRAMAP_BINARY_DIR) / "test_tmp" / ("rosbag_pipeline_" + tag);
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

/// Five clouds of one point in frame lidar, tf map -> lidar at each stamp.
void writeBag(const std::string& path) {
  io::mcap::Writer w(path, "ros2", io::mcap::Compression::Zstd);
  auto channel = [&](const char* topic, const char* type) {
    return w.addChannel(topic, w.addSchema(type, "ros2msg", io::ros2::messageDefinition(type)), "cdr");
  };
  const auto tf = channel("/tf", "tf2_msgs/msg/TFMessage");
  const auto pts = channel("/points", "sensor_msgs/msg/PointCloud2");
  for (int k = 0; k < 5; ++k) {
    io::ros2::TransformStamped t;
    t.header.stamp = io::ros2::Time::fromSeconds(0.1 * k);
    t.header.frame_id = "map";
    t.child_frame_id = "lidar";
    t.translation = Eigen::Vector3d(0.1 * k, 0, 1);
    const auto tb = io::ros2::encodeTFMessage({t});
    const auto ns = static_cast<std::uint64_t>(t.header.stamp.nanoseconds());
    w.write(tf, ns, ns, tb.data(), tb.size());
    io::ros2::PointCloud2 c;
    c.header = t.header;
    c.header.frame_id = "lidar";
    c.width = 1;
    for (std::uint32_t f = 0; f < 3; ++f) c.fields.push_back({std::string(1, static_cast<char>('x' + f)), 4 * f, io::ros2::kFloat32, 1});
    c.point_step = 12;
    c.row_step = 12;
    const float p[3] = {0.5f, 0.0f, -1.0f};
    c.data.assign(reinterpret_cast<const std::uint8_t*>(p), reinterpret_cast<const std::uint8_t*>(p) + 12);
    const auto cb = io::ros2::encodePointCloud2(c);
    w.write(pts, ns, ns, cb.data(), cb.size());
  }
  w.close();
}

}  // namespace

TEST(RosbagPipeline, McapOutputSettingsAreCheckedWhereTheyAreWritten) {
  auto errorOf = [](const std::string& outputs) {
    return configErrorOf([&] { parsePipelineString("version: 1\npipeline: []\noutputs:\n  mcap: " + outputs + "\n", "p.yaml"); });
  };
  expectHas(errorOf("{topic: /m}"), "p.yaml:4:9: outputs.mcap.layers: is required");
  expectHas(errorOf("{layers: []}"), "outputs.mcap.layers: must name at least one layer");
  expectHas(errorOf("{layers: [elevation], topic: grid}"), "outputs.mcap.topic: must be an absolute ROS topic name");
  expectHas(errorOf("{layers: [elevation], compression: gzip}"), "outputs.mcap.compression: must be zstd, lz4 or none (got 'gzip')");
  expectHas(errorOf("{layers: [elevation], every: 0}"), "outputs.mcap.every");
  expectHas(errorOf("{layers: [elevation], file: ../x.mcap}"), "outputs.mcap.file: must be a file name in outputs.dir");
  expectHas(errorOf("{layers: [elevation], copy_cloud: true}"), "copy_clouds");  // did-you-mean
  expectHas(errorOf("[elevation]"), "outputs.mcap: must be a mapping");
}

TEST(RosbagPipeline, SourceSettingsAreCheckedBeforeTheBagIsRead) {
  const fs::path d = scratch("settings");
  writeBag((d / "b.mcap").string());
  auto errorOf = [&](const std::string& source) {
    return configErrorOf([&] {
      makeSource(parsePipelineString("version: 1\nsource: {type: rosbag, bag: b.mcap" + source + "}\npipeline: []\n", "p.yaml",
                                     d.string()));
    });
  };
  expectHas(errorOf(""), "source.cloud_topic is required for source type 'rosbag'");
  expectHas(errorOf(", cloud_topic: /points, pose_source: gps"), "must be 'tf' or 'odometry' (got 'gps')");
  expectHas(errorOf(", cloud_topic: /points, odometry_topic: /odom"), "only used with pose_source: odometry");
  expectHas(errorOf(", cloud_topic: /points, pose_source: odometry"), "source.odometry_topic is required");
  expectHas(errorOf(", cloud_topic: /points, map_frme: map"), "unknown key for source type 'rosbag' (did you mean 'map_frame'?)");
  expectHas(errorOf(", cloud_topic: /pointz"), "no messages on the cloud topic '/pointz'; the bag has /tf (tf2_msgs/msg/TFMessage), "
                                               "/points (sensor_msgs/msg/PointCloud2)");
  // The settings that fit: five clouds, each after its pose.
  auto src = makeSource(parsePipelineString("version: 1\nsource: {type: rosbag, bag: b.mcap, cloud_topic: /points}\npipeline: []\n",
                                            "p.yaml", d.string()));
  Event e;
  int clouds = 0, poses = 0;
  while (src->next(e)) {
    if (std::holds_alternative<Pose>(e)) ++poses;
    if (const auto* c = std::get_if<PointCloud>(&e)) {
      EXPECT_EQ(c->T_map_sensor.translation().x(), 0.1 * clouds);
      ++clouds;
    }
  }
  EXPECT_EQ(clouds, 5);
  EXPECT_EQ(poses, 5);
}

TEST(RosbagPipeline, AGridMapEveryNCloudsAndOneOfTheFinishedMap) {
  PluginRegistry::addTrustedPaths({TERRAMAP_TEST_PLUGIN_DIR});
  const fs::path d = scratch("run");
  writeBag((d / "b.mcap").string());
  const std::string head = "version: 1\nmap: {resolution: 0.1, size: [20, 20], tile: 16}\n"
                           "source: {type: rosbag, bag: b.mcap, cloud_topic: /points}\n"
                           "pipeline:\n  - {name: a, type: test_probe, params: {output_layer: a}}\n";
  RunOptions o;
  o.out_dir = (d / "out").string();
  const std::string e = configErrorOf([&] {
    runPipeline(parsePipelineString(head + "outputs: {mcap: {layers: [a, b]}}\n", "p.yaml", d.string()), o);
  });
  expectHas(e, "outputs.mcap.layers: no stage creates layer 'b'");
  EXPECT_FALSE(fs::exists(d / "out" / "map.mcap"));

  const RunResult r = runPipeline(
      parsePipelineString(head + "outputs: {snapshot: false, mcap: {layers: [a], every: 2, topic: /grid}}\n", "p.yaml", d.string()), o);
  EXPECT_NE(std::find(r.files.begin(), r.files.end(), (d / "out" / "map.mcap").string()), r.files.end());
  io::mcap::Reader reader((d / "out" / "map.mcap").string());
  io::mcap::Message m;
  std::vector<double> stamps;
  while (reader.next(m)) {
    EXPECT_EQ(reader.channelOf(m).topic, "/grid");
    const auto g = io::ros2::decodeGridMap(m.data.data(), m.data.size(), m.where);
    EXPECT_EQ(g.layers, std::vector<std::string>{"a"});
    stamps.push_back(g.header.stamp.seconds());
  }
  // After clouds 2 and 4 (stamps 0.1 and 0.3), then the finished map at the last stamp.
  EXPECT_EQ(stamps, (std::vector<double>{0.1, 0.3, 0.4}));
  // Nothing left behind but the outputs (no temporary).
  for (const auto& f : fs::directory_iterator(d / "out")) EXPECT_EQ(f.path().string().find(".tmp."), std::string::npos) << f.path();
}
