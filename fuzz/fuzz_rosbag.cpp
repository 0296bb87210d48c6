// libFuzzer target: the rosbag2/MCAP readers (io/mcap.hpp, io/ros2_messages.hpp, io/rosbag.hpp).
// Each input is read twice: every message through mcap::Reader, decoded by its schema's name
// (PointCloud2 also to points, TFMessage, Odometry, GridMap); then as the `rosbag` source reads a
// bag (cloud topic /points, poses from /tf and /tf_static to frame map), every cloud pulled.
#include "fuzz_support.hpp"

#include <terramap/io/mcap.hpp>
#include <terramap/io/ros2_messages.hpp>
#include <terramap/io/rosbag.hpp>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace terramap::io;
  static terramap::fuzz::ScratchFile file("rosbag", ".mcap");
  const std::string& path = file.write(data, size);
  terramap::fuzz::expectInputErrorsOnly([&] {
    mcap::Reader r(path);
    mcap::Message m;
    while (r.next(m)) {
      const mcap::Schema* s = r.schemaOf(r.channelOf(m));
      if (!s) continue;
      if (s->name == "sensor_msgs/msg/PointCloud2")
        ros2::cloudPoints(ros2::decodePointCloud2(m.data.data(), m.data.size(), m.where), m.where);
      else if (s->name == "tf2_msgs/msg/TFMessage")
        ros2::decodeTFMessage(m.data.data(), m.data.size(), m.where);
      else if (s->name == "nav_msgs/msg/Odometry")
        ros2::decodeOdometry(m.data.data(), m.data.size(), m.where);
      else if (s->name == "grid_map_msgs/msg/GridMap")
        ros2::decodeGridMap(m.data.data(), m.data.size(), m.where);
    }
  });
  terramap::fuzz::expectInputErrorsOnly([&] {
    RosbagSpec spec;
    spec.path = path;
    spec.cloud_topic = "/points";
    RosbagSource bag(spec);
    while (bag.next()) {
    }
  });
  return 0;
}
