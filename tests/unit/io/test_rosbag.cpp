// MCAP container, ROS 2 CDR messages and the rosbag source (io/mcap.hpp, io/ros2_messages.hpp,
// io/rosbag.hpp): round trips through terramap's own writer, and the error paths of the readers on
// files damaged byte by byte (each message names the file, the byte offset and the field).
// Interoperability with independent implementations is tests/ros2 (CTest Ros2.*).
#include <terramap/core/error.hpp>
#include <terramap/io/gridmap_mcap.hpp>
#include <terramap/io/mcap.hpp>
#include <terramap/io/ros2_messages.hpp>
#include <terramap/io/rosbag.hpp>

#include "io/mcap_bytes.hpp"
#include "memory_budget_scope.hpp"
#include "scratch_dir.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <fstream>

using namespace terramap;
using namespace terramap::io;
using ::testing::HasSubstr;

namespace {

class Rosbag : public ScratchDirTest {
 protected:
  Rosbag() : ScratchDirTest("rosbag_") {}
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
};

std::vector<std::uint8_t> readBytes(const std::string& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}
void writeBytes(const std::string& p, const std::vector<std::uint8_t>& b) {
  std::ofstream(p, std::ios::binary).write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
}

/// The message that `f` throws as E.
template <class E, class F>
std::string errorOf(F&& f) {
  try {
    f();
  } catch (const E& e) {
    return e.what();
  }
  ADD_FAILURE() << "no exception of the expected type";
  return {};
}

ros2::PointCloud2 xyzCloud(double stamp, const std::string& frame, const std::vector<PointXYZI>& pts) {
  ros2::PointCloud2 c;
  c.header.stamp = ros2::Time::fromSeconds(stamp);
  c.header.frame_id = frame;
  c.width = static_cast<std::uint32_t>(pts.size());
  const char* names[] = {"x", "y", "z", "intensity"};
  for (std::uint32_t k = 0; k < 4; ++k) c.fields.push_back({names[k], 4 * k, ros2::kFloat32, 1});
  c.point_step = 16;
  c.row_step = 16 * c.width;
  c.data.resize(16 * pts.size());
  std::memcpy(c.data.data(), pts.data(), c.data.size());
  return c;
}

ros2::TransformStamped tf(double t, const std::string& parent, const std::string& child, const Eigen::Vector3d& x,
                          double yaw = 0) {
  ros2::TransformStamped s;
  s.header.stamp = ros2::Time::fromSeconds(t);
  s.header.frame_id = parent;
  s.child_frame_id = child;
  s.translation = x;
  s.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()));
  return s;
}

/// A small rosbag2 file: static base_link -> lidar, map -> base_link at 1.0 and 2.0 s,
/// clouds at 0.5 (before the first transform), 1.5 and 2.0 s.
struct BagWriter {
  mcap::Writer w;
  std::map<std::string, std::uint16_t> channels;
  BagWriter(const std::string& p, mcap::Compression c = mcap::Compression::Zstd) : w(p, "ros2", c, 1024) {}
  void add(const std::string& topic, const std::string& type, double t, const std::vector<std::uint8_t>& data) {
    auto it = channels.find(topic);
    if (it == channels.end()) {
      const auto s = w.addSchema(type, "ros2msg", ros2::messageDefinition(type));
      it = channels.emplace(topic, w.addChannel(topic, s, "cdr")).first;
    }
    const auto ns = static_cast<std::uint64_t>(std::llround(t * 1e9));
    w.write(it->second, ns, ns, data.data(), data.size());
  }
};

void writeSmallBag(const std::string& p, mcap::Compression c = mcap::Compression::Zstd) {
  BagWriter b(p, c);
  b.add("/tf_static", "tf2_msgs/msg/TFMessage", 0.0,
        ros2::encodeTFMessage({tf(0, "base_link", "lidar", {0.5, 0, 1.0}, M_PI / 2)}));
  const std::vector<PointXYZI> pts = {{1, 0, 0, 7}, {0, 2, 0, 8}};
  b.add("/points", "sensor_msgs/msg/PointCloud2", 0.5, ros2::encodePointCloud2(xyzCloud(0.5, "lidar", pts)));
  b.add("/tf", "tf2_msgs/msg/TFMessage", 1.0, ros2::encodeTFMessage({tf(1.0, "map", "base_link", {10, 0, 0})}));
  b.add("/points", "sensor_msgs/msg/PointCloud2", 1.5, ros2::encodePointCloud2(xyzCloud(1.5, "lidar", pts)));
  b.add("/tf", "tf2_msgs/msg/TFMessage", 2.0, ros2::encodeTFMessage({tf(2.0, "map", "base_link", {12, 0, 0}, M_PI)}));
  b.add("/points", "sensor_msgs/msg/PointCloud2", 2.0, ros2::encodePointCloud2(xyzCloud(2.0, "lidar", pts)));
  b.w.close();
}

RosbagSpec specOf(const std::string& p) {
  RosbagSpec s;
  s.path = p;
  s.cloud_topic = "/points";
  return s;
}

/// Offset of the first record with opcode `op` in the data section (walks the records).
std::size_t recordOffset(const std::vector<std::uint8_t>& b, std::uint8_t op) {
  std::size_t pos = 8;
  while (pos + 9 <= b.size()) {
    if (b[pos] == op) return pos;
    std::uint64_t len;
    std::memcpy(&len, &b[pos + 1], 8);
    pos += 9 + len;
  }
  ADD_FAILURE() << "no record of opcode " << int(op);
  return 0;
}

}  // namespace

TEST_F(Rosbag, McapRoundTripsInEveryCompression) {
  for (auto c : {mcap::Compression::None, mcap::Compression::Zstd, mcap::Compression::Lz4}) {
    const std::string p = path("rt.mcap");
    {
      mcap::Writer w(p, "ros2", c, 1024);
      const auto s = w.addSchema("x/msg/Y", "ros2msg", "int32 a\n");
      const auto ch = w.addChannel("/a", s, "cdr", {{"k", "v"}});
      for (std::uint8_t k = 0; k < 200; ++k) {
        const std::vector<std::uint8_t> data(50 + k, k);
        w.write(ch, 1000u * k, 1000u * k + 1, data.data(), data.size());
      }
      w.close();
    }
    mcap::Reader r(p);
    EXPECT_EQ(r.profile(), "ros2");
    mcap::Message m;
    int n = 0;
    while (r.next(m)) {
      ASSERT_EQ(m.data.size(), 50u + n);
      EXPECT_EQ(m.data.front(), n);
      EXPECT_EQ(m.log_time, 1000u * n);
      EXPECT_EQ(m.publish_time, 1000u * n + 1);
      EXPECT_EQ(m.sequence, static_cast<std::uint32_t>(n));
      EXPECT_EQ(r.channelOf(m).metadata.at("k"), "v");
      ++n;
    }
    EXPECT_EQ(n, 200);
    EXPECT_EQ(r.schemaOf(r.channels().at(1))->name, "x/msg/Y");
  }
}

TEST_F(Rosbag, DamagedMcapFilesNameTheFileAndByte) {
  const std::string good = path("good.mcap");
  writeSmallBag(good, mcap::Compression::None);
  const auto bytes = readBytes(good);
  auto readAll = [](const std::string& p) {
    mcap::Reader r(p);
    mcap::Message m;
    while (r.next(m)) {
    }
  };
  const std::string bad = path("bad.mcap");
  // Cut short: the trailing magic is missing.
  writeBytes(bad, std::vector<std::uint8_t>(bytes.begin(), bytes.begin() + static_cast<long>(bytes.size() / 2)));
  EXPECT_THAT(errorOf<InputError>([&] { readAll(bad); }), HasSubstr("does not end with the MCAP magic"));
  // Not MCAP at all.
  auto b = bytes;
  b[1] = 'X';
  writeBytes(bad, b);
  EXPECT_THAT(errorOf<InputError>([&] { readAll(bad); }), HasSubstr(bad + ": byte 0: not an MCAP file"));
  // A chunk's records changed: its CRC says so.
  const std::size_t chunk = recordOffset(bytes, 0x06);
  b = bytes;
  b[chunk + 9 + 8 + 8 + 8 + 4 + 4 + 8 + 20] ^= 0xFF;
  writeBytes(bad, b);
  EXPECT_THAT(errorOf<InputError>([&] { readAll(bad); }),
              HasSubstr("Chunk record at byte " + std::to_string(chunk) + ": CRC-32 of the uncompressed records"));
  // A record length running past the end of the file.
  b = bytes;
  const std::uint64_t huge = 1ull << 40;
  std::memcpy(&b[chunk + 1], &huge, 8);
  writeBytes(bad, b);
  EXPECT_THAT(errorOf<InputError>([&] { readAll(bad); }),
              HasSubstr("byte " + std::to_string(chunk) + ": record (opcode 0x06) of length 1099511627776 runs past"));
  // A message on a channel nobody defined (the first message's channel id changed).
  b = bytes;
  const std::size_t records = chunk + 9 + 8 + 8 + 8 + 4 + 4 + 8;  // after the chunk's fields
  b[records + 9] = 99;
  std::uint32_t crc0 = 0;
  std::memcpy(&b[chunk + 9 + 24], &crc0, 4);  // CRC 0 = not checked, so the record check speaks
  writeBytes(bad, b);
  EXPECT_THAT(errorOf<InputError>([&] { readAll(bad); }),
              HasSubstr("record at uncompressed byte 0: Message on channel 99, which no Channel record before it defines"));
}

TEST_F(Rosbag, ARefusedFileIsClosed) {
  // Found by fuzz_rosbag: a header the reader refused left its file open, and a long run ran out
  // of descriptors. Every refusal, early or late in the constructor, must close the file.
  const std::string good = path("good.mcap");
  writeSmallBag(good, mcap::Compression::None);
  auto bytes = readBytes(good);
  bytes[16] = 0x7F;  // the Header record's length (its top byte): past the file's end
  writeBytes(path("bad_length.mcap"), bytes);
  bytes = readBytes(good);
  bytes[20] = 0x7F;  // the Header's profile string length (its top byte): past the record's end
  writeBytes(path("bad_profile.mcap"), bytes);
  auto openFiles = [] {
    return std::distance(std::filesystem::directory_iterator("/proc/self/fd"), std::filesystem::directory_iterator{});
  };
  const auto before = openFiles();
  for (int k = 0; k < 20; ++k)
    for (const char* name : {"bad_length.mcap", "bad_profile.mcap"})
      EXPECT_THROW(mcap::Reader r(path(name)), InputError);
  EXPECT_EQ(openFiles(), before);
}

TEST_F(Rosbag, ChunkSizesBeyondTheBudgetAreRefusedBeforeAllocating) {
  const std::string good = path("good.mcap");
  writeSmallBag(good, mcap::Compression::Zstd);
  auto b = readBytes(good);
  const std::size_t chunk = recordOffset(b, 0x06);
  // uncompressed_size claims more than zstd can expand the chunk to.
  const std::uint64_t claim = 1ull << 36;
  std::memcpy(&b[chunk + 9 + 16], &claim, 8);
  writeBytes(path("bad.mcap"), b);
  mcap::Reader r(path("bad.mcap"));
  mcap::Message m;
  EXPECT_THAT(errorOf<InputError>([&] { r.next(m); }), HasSubstr("uncompressed_size 68719476736"));
  // Within what zstd can do but past the budget: the budget's message.
  test::MemoryBudgetScope budget(100);
  mcap::Reader r2(good);
  EXPECT_THAT(errorOf<InputError>([&] { r2.next(m); }), HasSubstr("more than the memory budget"));
}

TEST_F(Rosbag, CloudLayoutsAreReadOrRefusedNamingTheField) {
  // float64 x/y/z, uint16 intensity, organised 2 x 2 with row padding.
  ros2::PointCloud2 c;
  c.height = 2;
  c.width = 2;
  c.fields = {{"z", 16, ros2::kFloat64, 1}, {"x", 0, ros2::kFloat64, 1}, {"y", 8, ros2::kFloat64, 1}, {"intensity", 24, ros2::kUint16, 1}};
  c.point_step = 32;
  c.row_step = 72;
  c.data.assign(144, 0);
  for (int i = 0; i < 4; ++i) {
    const std::size_t o = (i / 2) * 72 + (i % 2) * 32;
    const double xyz[3] = {i + 0.5, -i - 0.25, 2.0 * i};
    std::memcpy(&c.data[o], xyz, 24);
    const std::uint16_t v = static_cast<std::uint16_t>(100 + i);
    std::memcpy(&c.data[o + 24], &v, 2);
  }
  const auto bytes = ros2::encodePointCloud2(c);
  const auto back = ros2::decodePointCloud2(bytes.data(), bytes.size(), "w");
  const auto pts = ros2::cloudPoints(back, "w");
  ASSERT_EQ(pts.size(), 4u);
  EXPECT_EQ(pts[3].x, 3.5f);
  EXPECT_EQ(pts[3].y, -3.25f);
  EXPECT_EQ(pts[3].z, 6.0f);
  EXPECT_EQ(pts[3].intensity, 103.0f);
  // No intensity field: NaN.
  auto d = back;
  d.fields.pop_back();
  EXPECT_TRUE(std::isnan(ros2::cloudPoints(d, "w")[0].intensity));
  // Refusals.
  d = back;
  d.is_bigendian = true;
  EXPECT_THAT(errorOf<InputError>([&] { ros2::cloudPoints(d, "bag.mcap: topic '/p' message 3"); }),
              HasSubstr("bag.mcap: topic '/p' message 3: is_bigendian is true"));
  d = back;
  d.fields[1].datatype = ros2::kInt16;
  EXPECT_THAT(errorOf<InputError>([&] { ros2::cloudPoints(d, "w"); }),
              HasSubstr("field 'x' is 1 x INT16; x, y and z must each be one FLOAT32 or FLOAT64"));
  d = back;
  d.fields.erase(d.fields.begin());
  EXPECT_THAT(errorOf<InputError>([&] { ros2::cloudPoints(d, "w"); }), HasSubstr("no field 'z'"));
  d = back;
  d.fields[0].offset = 30;
  EXPECT_THAT(errorOf<InputError>([&] { ros2::cloudPoints(d, "w"); }),
              HasSubstr("field 'z' at offset 30 (FLOAT64) does not fit in point_step 32"));
  d = back;
  d.data.resize(100);
  EXPECT_THAT(errorOf<InputError>([&] { ros2::cloudPoints(d, "w"); }),
              HasSubstr("data holds 100 bytes, row_step 72 x height 2 needs 144"));
  // A truncated message: the field that runs out is named.
  EXPECT_THAT(errorOf<InputError>([&] { ros2::decodePointCloud2(bytes.data(), bytes.size() - 1, "m"); }),
              HasSubstr("m: field 'is_dense' at byte " + std::to_string(bytes.size() - 1) + " runs past the message's"));
  EXPECT_THAT(errorOf<InputError>([&] { ros2::decodePointCloud2(bytes.data(), 60, "m"); }),
              HasSubstr("m: sequence 'fields' claims 4 elements, more than the 28 bytes left can hold"));
  // Big-endian CDR encapsulation.
  auto be = bytes;
  be[1] = 0x00;
  EXPECT_THAT(errorOf<InputError>([&] { ros2::decodePointCloud2(be.data(), be.size(), "m"); }),
              HasSubstr("big-endian CDR"));
}

TEST_F(Rosbag, TfChainsAreInterpolatedAtTheCloudStamp) {
  const std::string p = path("bag.mcap");
  writeSmallBag(p);
  RosbagSource src(specOf(p));
  EXPECT_EQ(src.cloudCount(), 3u);
  // Between the samples: translation halfway, yaw halfway (slerp), times the static extrinsic.
  const auto T = src.lookup("map", "lidar", 1.5);
  ASSERT_TRUE(T);
  const Eigen::Isometry3d T_map_base = Eigen::Translation3d(11, 0, 0) * Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ());
  const Eigen::Isometry3d T_base_lidar = Eigen::Translation3d(0.5, 0, 1.0) * Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ());
  EXPECT_TRUE(T->isApprox(T_map_base * T_base_lidar, 1e-12)) << T->matrix();
  EXPECT_FALSE(src.lookup("map", "lidar", 0.5));  // before the first map -> base_link sample
  EXPECT_FALSE(src.lookup("map", "lidar", 2.5));  // after the last
  // The first cloud has no pose yet: dropped and counted; the others come with theirs.
  auto c = src.next();
  ASSERT_TRUE(c);
  EXPECT_EQ(c->cloud.stamp, 1.5);
  EXPECT_EQ(c->cloud.frame, "lidar");
  EXPECT_TRUE(c->cloud.T_map_sensor.isApprox(T_map_base * T_base_lidar, 1e-12));
  ASSERT_EQ(c->cloud.points.size(), 2u);
  EXPECT_EQ(c->cloud.points[1].y, 2.0f);
  EXPECT_EQ(c->cloud.points[1].intensity, 8.0f);
  c = src.next();
  ASSERT_TRUE(c);
  EXPECT_EQ(c->cloud.stamp, 2.0);
  EXPECT_FALSE(src.next());
  EXPECT_EQ(src.dropped(), (std::map<std::string, long>{{"rosbag_no_pose", 1}}));
}

TEST_F(Rosbag, OdometryPosesTimesTheExtrinsic) {
  const std::string p = path("odom.mcap");
  {
    BagWriter b(p);
    b.add("/tf_static", "tf2_msgs/msg/TFMessage", 0.0, ros2::encodeTFMessage({tf(0, "base_link", "lidar", {0.5, 0, 1.0})}));
    for (double t : {1.0, 2.0}) {
      ros2::Odometry o;
      o.header.stamp = ros2::Time::fromSeconds(t);
      o.header.frame_id = "odom";
      o.child_frame_id = "base_link";
      o.position = {t, 2 * t, 0};
      b.add("/odom", "nav_msgs/msg/Odometry", t, ros2::encodeOdometry(o));
    }
    b.add("/points", "sensor_msgs/msg/PointCloud2", 1.25, ros2::encodePointCloud2(xyzCloud(1.25, "lidar", {{1, 1, 1, 1}})));
    b.w.close();
  }
  RosbagSpec s = specOf(p);
  s.pose_source = RosbagSpec::PoseSource::Odometry;
  s.odometry_topic = "/odom";
  s.map_frame = "";
  s.base_frame = "base_link";
  RosbagSource src(s);
  const auto c = src.next();
  ASSERT_TRUE(c);
  EXPECT_TRUE(c->cloud.T_map_sensor.translation().isApprox(Eigen::Vector3d(1.75, 2.5, 1.0), 1e-12));
  EXPECT_TRUE(c->T_map_base.translation().isApprox(Eigen::Vector3d(1.25, 2.5, 0.0), 1e-12));
  // A map_frame that is not the odometry's frame.
  s.map_frame = "map";
  EXPECT_THAT(errorOf<ConfigError>([&] { RosbagSource bad(s); }),
              HasSubstr("the odometry is in frame 'odom', the source's map_frame is 'map'"));
}

TEST_F(Rosbag, ConfigurationsTheBagCannotServeAreRefusedNamingWhatItHas) {
  const std::string p = path("bag.mcap");
  writeSmallBag(p);
  RosbagSpec s = specOf(p);
  s.cloud_topic = "/velodyne_points";
  EXPECT_THAT(errorOf<ConfigError>([&] { RosbagSource b(s); }),
              HasSubstr("no messages on the cloud topic '/velodyne_points'; the bag has /tf_static (tf2_msgs/msg/TFMessage), "
                        "/points (sensor_msgs/msg/PointCloud2), /tf (tf2_msgs/msg/TFMessage)"));
  s = specOf(p);
  s.cloud_topic = "/tf";
  EXPECT_THAT(errorOf<ConfigError>([&] { RosbagSource b(s); }),
              HasSubstr("topic '/tf' carries 'tf2_msgs/msg/TFMessage', not sensor_msgs/msg/PointCloud2"));
  s = specOf(p);
  s.map_frame = "mapp";
  EXPECT_THAT(errorOf<ConfigError>([&] { RosbagSource b(s); }),
              HasSubstr("map_frame 'mapp' is in none of the bag's transforms (did you mean 'map'?); its frames: base_link, lidar, map"));
}

TEST_F(Rosbag, ABadCloudNamesTheTopicAndItsIndex) {
  const std::string p = path("bag.mcap");
  {
    BagWriter b(p);
    b.add("/tf", "tf2_msgs/msg/TFMessage", 0.0, ros2::encodeTFMessage({tf(0, "map", "lidar", {0, 0, 0})}));
    b.add("/tf", "tf2_msgs/msg/TFMessage", 9.0, ros2::encodeTFMessage({tf(9, "map", "lidar", {0, 0, 0})}));
    auto c = xyzCloud(1, "lidar", {{1, 2, 3, 4}});
    b.add("/points", "sensor_msgs/msg/PointCloud2", 1, ros2::encodePointCloud2(c));
    c.is_bigendian = true;
    b.add("/points", "sensor_msgs/msg/PointCloud2", 2, ros2::encodePointCloud2(c));
    b.w.close();
  }
  RosbagSource src(specOf(p));
  ASSERT_TRUE(src.next());
  const std::string e = errorOf<InputError>([&] { src.next(); });
  EXPECT_THAT(e, HasSubstr(p + ": chunk at byte "));
  EXPECT_THAT(e, HasSubstr("topic '/points' message 1: is_bigendian is true"));
}

TEST_F(Rosbag, GridMapMessagesFollowGridMapsLayout) {
  LayeredMap map(Geometry(0.5, Size(3, 2), Position(1.0, -2.0)));
  const LayerId el = map.addLayer("elevation", "m");
  map.set(el, Index(2, 1), 4.5f);  // row 2, column 1
  const std::string p = path("map.mcap");
  GridMapMcapOptions o;
  o.layers = {"elevation", "later"};
  {
    GridMapMcapWriter w(p, o);
    w.writeMap(map, 1.25);
    w.close();
  }
  mcap::Reader r(p);
  mcap::Message m;
  ASSERT_TRUE(r.next(m));
  EXPECT_EQ(r.schemaOf(r.channelOf(m))->name, "grid_map_msgs/msg/GridMap");
  EXPECT_EQ(r.channelOf(m).topic, "/terramap/grid_map");
  const auto g = ros2::decodeGridMap(m.data.data(), m.data.size(), "m");
  EXPECT_EQ(g.header.frame_id, "map");
  EXPECT_EQ(g.header.stamp.sec, 1);
  EXPECT_EQ(g.header.stamp.nanosec, 250000000u);
  EXPECT_EQ(g.rows, 3u);
  EXPECT_EQ(g.cols, 2u);
  EXPECT_EQ(g.length_x, 1.5);
  EXPECT_EQ(g.length_y, 1.0);
  EXPECT_EQ(g.position, Eigen::Vector3d(1.0, -2.0, 0.0));
  ASSERT_EQ(g.data.size(), 2u);
  // Column-major: cell (i, j) at i + j * rows.
  EXPECT_EQ(g.data[0][2 + 1 * 3], 4.5f);
  EXPECT_EQ(std::count_if(g.data[0].begin(), g.data[0].end(), [](float v) { return std::isnan(v); }), 5);
  // A layer the map does not have (yet) is all unknown.
  EXPECT_TRUE(std::all_of(g.data[1].begin(), g.data[1].end(), [](float v) { return std::isnan(v); }));
  EXPECT_FALSE(r.next(m));
}
