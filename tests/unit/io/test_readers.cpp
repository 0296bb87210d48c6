// Point-cloud readers against the real recordings (data/ in the repository; the KITTI frames at
// TERRAMAP_KITTI_DIR, skipped without them) and against malformed files generated here. Expectations come from independent parsing in the test (fread,
// header text) or from the data's SOURCE.txt, never from the reader under test.
#include <terramap/io/readers.hpp>

#include "kitti_data.hpp"
#include "test_readers_util.hpp"

#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <iostream>

namespace terramap::io {
namespace {

using test::dataPath;
using test::expectErrorWith;
using test::slurp;
using test::spit;
using test::spitText;
using test::TempDir;

const std::string kKitti0 = test::kittiPath("000000.bin");
const std::string kLas = dataPath("las_hexbin/hexbin-crop.las");
const std::string kPlySource = dataPath("gicp_pair/source.ply");

float floatAt(const std::vector<unsigned char>& b, std::size_t off) {
  float v;
  std::memcpy(&v, &b[off], 4);  // host is little-endian (x86/arm64), like the files
  return v;
}

// ---- KITTI ------------------------------------------------------------------------------------

TEST(KittiReader, RealFrameCountAndFirstPointMatchRawBytes) {
  TERRAMAP_SKIP_WITHOUT_KITTI();
  // Independent read of the first record and the size with plain stdio.
  std::FILE* f = std::fopen(kKitti0.c_str(), "rb");
  ASSERT_NE(f, nullptr);
  float first[4];
  ASSERT_EQ(std::fread(first, sizeof(float), 4, f), 4u);
  std::fseek(f, -16, SEEK_END);
  float last[4];
  ASSERT_EQ(std::fread(last, sizeof(float), 4, f), 4u);
  const long size = std::ftell(f);
  std::fclose(f);

  const auto pts = readKittiBin(kKitti0);
  ASSERT_EQ(pts.size(), static_cast<std::size_t>(size / 16));
  EXPECT_EQ(pts.size(), 124668u);  // SOURCE.txt: parsed point counts per frame
  EXPECT_EQ(pts[0].x, first[0]);
  EXPECT_EQ(pts[0].y, first[1]);
  EXPECT_EQ(pts[0].z, first[2]);
  EXPECT_EQ(pts[0].intensity, first[3]);
  EXPECT_EQ(pts.back().x, last[0]);
  EXPECT_EQ(pts.back().intensity, last[3]);
  // Plausibility of the sensor frame: an HDL-64E sees ~120 m at most, reflectance in [0, 1].
  for (const auto& p : pts) {
    ASSERT_LT(std::abs(p.x), 130.f);
    ASSERT_GE(p.intensity, 0.f);
    ASSERT_LE(p.intensity, 1.f);
  }
}

TEST(KittiReader, AllSixFramesHaveTheDocumentedCounts) {
  TERRAMAP_SKIP_WITHOUT_KITTI();
  const std::size_t expected[6] = {124668, 124605, 124478, 124167, 123969, 123924};
  for (int i = 0; i < 6; ++i) {
    char name[64];
    std::snprintf(name, sizeof name, "%06d.bin", i);
    EXPECT_EQ(readKittiBin(test::kittiPath(name)).size(), expected[i]) << name;
  }
}

TEST(KittiReader, TruncatedFileNamesFileAndPartialRecordOffset) {
  TERRAMAP_SKIP_WITHOUT_KITTI();
  TempDir dir("kitti");
  auto bytes = slurp(kKitti0);
  bytes.resize(16 * 1000 + 7);
  const std::string bad = dir.file("truncated.bin");
  spit(bad, bytes);
  expectErrorWith([&] { readKittiBin(bad); }, {bad, "byte offset 16000", "16007", "multiple of 16"});
}

TEST(KittiReader, EmptyFileIsAnEmptyCloudAndMissingFileIsAnError) {
  TempDir dir("kitti");
  spit(dir.file("empty.bin"), {});
  EXPECT_TRUE(readKittiBin(dir.file("empty.bin")).empty());
  expectErrorWith([&] { readKittiBin(dir.file("nope.bin")); }, {dir.file("nope.bin"), "cannot open"});
}

// ---- LAS --------------------------------------------------------------------------------------

TEST(LasReader, RealHeaderFields) {
  const auto raw = slurp(kLas);
  std::uint32_t count_raw;
  std::memcpy(&count_raw, &raw[107], 4);
  const LasHeader h = readLasHeader(kLas);
  EXPECT_EQ(h.version_major, 1);
  EXPECT_EQ(h.version_minor, 2);
  EXPECT_EQ(h.point_format, 1);
  EXPECT_EQ(h.record_length, 28);
  EXPECT_EQ(h.header_size, 227);
  EXPECT_EQ(h.point_count, count_raw);
  EXPECT_EQ(h.point_count, 38367u);
  EXPECT_EQ(h.system_identifier, "ALIRT");
  EXPECT_EQ(h.generating_software, "AA2010-CPED");
  EXPECT_EQ(h.offset_to_points + static_cast<std::uint64_t>(h.point_count) * h.record_length, raw.size());
  // SOURCE.txt: z 3107.86..3209.32 m, ~293 x 201 m.
  EXPECT_NEAR(h.min.z(), 3107.86, 0.01);
  EXPECT_NEAR(h.max.z(), 3209.32, 0.01);
  EXPECT_NEAR(h.max.x() - h.min.x(), 293.0, 1.0);
  EXPECT_NEAR(h.max.y() - h.min.y(), 201.0, 1.0);
  ASSERT_TRUE(h.epsg.has_value());
  EXPECT_EQ(*h.epsg, 32642);  // WGS 84 / UTM zone 42N
}

TEST(LasReader, RealPointsClassesAndPrecision) {
  LasReadOptions opt;
  opt.keep_double_positions = true;
  const LasCloud c = readLas(kLas, opt);
  ASSERT_EQ(c.size(), 38367u);
  ASSERT_EQ(c.classification.size(), c.size());
  ASSERT_EQ(c.gps_time.size(), c.size());  // format 1 carries GPS time
  std::size_t ground = 0, unclassified = 0;
  for (auto cls : c.classification) {
    ground += cls == 2;
    unclassified += cls == 1;
  }
  EXPECT_EQ(ground, 35318u);
  EXPECT_EQ(unclassified, 3049u);
  EXPECT_EQ(c.pointsOfClass(2).size(), 35318u);

  // The origin is the rounded bounding-box centre, so relative coordinates stay small and the
  // float cloud reproduces the exact coordinates far below the 1 mm quantisation.
  const LasHeader& h = c.header;
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(c.origin[a], 0.5 * (h.min[a] + h.max[a]), 0.5);
  double worst = 0;
  for (std::size_t i = 0; i < c.size(); ++i) {
    const Eigen::Vector3d& p = c.positions[i];
    // The writer's bounds are not on the scale grid (max y ends ...4961, the last point at
    // ...5122), so allow one quantisation step.
    ASSERT_TRUE((p.array() >= (h.min - h.scale).array()).all() && (p.array() <= (h.max + h.scale).array()).all()) << i;
    worst = std::max(worst, (c.absolute(i) - p).cwiseAbs().maxCoeff());
    ASSERT_LE(std::abs(c.points[i].x), 200.f);
  }
  EXPECT_LT(worst, 1e-4);
  // Independent decode of record 0 from the raw bytes: X*scale + offset.
  const auto raw = slurp(kLas);
  std::int32_t X;
  std::memcpy(&X, &raw[h.offset_to_points], 4);
  double sx, ox;
  std::memcpy(&sx, &raw[131], 8);
  std::memcpy(&ox, &raw[155], 8);
  EXPECT_EQ(c.positions[0].x(), X * sx + ox);
  std::uint16_t inten;
  std::memcpy(&inten, &raw[h.offset_to_points + 12], 2);
  EXPECT_EQ(c.points[0].intensity, static_cast<float>(inten));
}

// Builds a LAS 1.2 file by hand: header + one VLR-free body, `format` 0..3, with `extra`
// bytes per record beyond the format's minimum.
std::vector<unsigned char> makeLas(int format, int extra, const std::vector<std::array<std::int32_t, 3>>& xyz,
                                   const std::vector<std::uint8_t>& cls) {
  const int min_len[4] = {20, 28, 26, 34};
  const int len = min_len[format] + extra;
  std::vector<unsigned char> b(227 + len * xyz.size(), 0);
  auto put = [&](std::size_t off, const void* v, std::size_t n) { std::memcpy(&b[off], v, n); };
  std::memcpy(&b[0], "LASF", 4);
  b[24] = 1;
  b[25] = 2;
  const std::uint16_t hs = 227;
  const std::uint32_t off = 227, n = static_cast<std::uint32_t>(xyz.size());
  const std::uint16_t rl = static_cast<std::uint16_t>(len);
  put(94, &hs, 2);
  put(96, &off, 4);
  b[104] = static_cast<unsigned char>(format);
  put(105, &rl, 2);
  put(107, &n, 4);
  const double scale[3] = {0.01, 0.01, 0.001}, offs[3] = {500000.0, 4000000.0, 100.0};
  for (int a = 0; a < 3; ++a) {
    put(131 + 8 * a, &scale[a], 8);
    put(155 + 8 * a, &offs[a], 8);
  }
  const double mx[3] = {500010.0, 4000010.0, 110.0}, mn[3] = {499990.0, 3999990.0, 90.0};
  for (int a = 0; a < 3; ++a) {
    put(179 + 16 * a, &mx[a], 8);
    put(187 + 16 * a, &mn[a], 8);
  }
  for (std::size_t i = 0; i < xyz.size(); ++i) {
    const std::size_t r = 227 + i * len;
    put(r, xyz[i].data(), 12);
    const std::uint16_t inten = static_cast<std::uint16_t>(100 * i + 7);
    put(r + 12, &inten, 2);
    b[r + 14] = static_cast<unsigned char>((2 << 3) | 1);  // return 1 of 2
    b[r + 15] = cls[i];
    if (format == 1 || format == 3) {
      const double t = 1000.5 + static_cast<double>(i);
      put(r + 20, &t, 8);
    }
    if (extra > 0) b[r + min_len[format]] = 0xAB;  // extra bytes must be skipped
  }
  return b;
}

TEST(LasReader, HandBuiltFilesOfEveryFormat) {
  TempDir dir("las");
  const std::vector<std::array<std::int32_t, 3>> xyz = {{0, 0, 0}, {123, -456, 789}, {-1000, 1000, -5000}};
  const std::vector<std::uint8_t> cls = {2, 1, static_cast<std::uint8_t>(2 | 0x80)};  // withheld ground
  for (int format = 0; format <= 3; ++format) {
    for (int extra : {0, 5}) {
      const std::string path = dir.file("f" + std::to_string(format) + "_" + std::to_string(extra) + ".las");
      spit(path, makeLas(format, extra, xyz, cls));
      LasReadOptions opt;
      opt.keep_double_positions = true;
      const LasCloud c = readLas(path, opt);
      ASSERT_EQ(c.size(), 3u);
      EXPECT_EQ(c.origin, Eigen::Vector3d(500000.0, 4000000.0, 100.0));
      // Hand-computed: X*0.01 + 500000 etc.
      EXPECT_DOUBLE_EQ(c.positions[1].x(), 500001.23);
      EXPECT_DOUBLE_EQ(c.positions[1].y(), 3999995.44);
      EXPECT_DOUBLE_EQ(c.positions[1].z(), 100.789);
      EXPECT_FLOAT_EQ(c.points[1].x, 1.23f);
      EXPECT_FLOAT_EQ(c.points[1].y, -4.56f);
      EXPECT_FLOAT_EQ(c.points[1].z, 0.789f);
      EXPECT_FLOAT_EQ(c.points[2].z, -5.0f);
      EXPECT_EQ(c.points[2].intensity, 207.f);
      EXPECT_EQ(c.classification, (std::vector<std::uint8_t>{2, 1, 2}));
      EXPECT_EQ(c.class_flags, (std::vector<std::uint8_t>{0, 0, 4}));
      EXPECT_EQ(c.return_number[0], 1);
      EXPECT_EQ(c.number_of_returns[0], 2);
      if (format == 1 || format == 3) {
        ASSERT_EQ(c.gps_time.size(), 3u);
        EXPECT_EQ(c.gps_time[2], 1002.5);
      } else {
        EXPECT_TRUE(c.gps_time.empty());
      }
    }
  }
  // Explicit and zero origins.
  const std::string path = dir.file("f0_0.las");
  LasReadOptions opt;
  opt.origin_mode = LasOriginMode::Explicit;
  opt.origin = Eigen::Vector3d(500001.0, 3999995.0, 100.0);
  EXPECT_FLOAT_EQ(readLas(path, opt).points[1].y, 0.44f);
  opt.origin_mode = LasOriginMode::Zero;
  EXPECT_FLOAT_EQ(readLas(path, opt).points[0].x, 500000.f);
}

TEST(LasReader, MalformedFilesNameFileAndByteOffset) {
  TempDir dir("las_bad");
  const auto good = slurp(kLas);
  const std::uint32_t points_at = 1733;  // offset to point data of the real file (byte 96)

  {  // truncated in the middle of record 100
    auto b = good;
    b.resize(points_at + 28 * 100 + 13);
    const std::string p = dir.file("truncated.las");
    spit(p, b);
    expectErrorWith([&] { readLas(p); }, {p, "byte offset " + std::to_string(points_at + 28 * 100), "38367"});
    // The header alone is fine: readLasHeader also checks the count against the size.
    expectErrorWith([&] { readLasHeader(p); }, {p, "record 100"});
  }
  {  // truncated inside the public header
    auto b = good;
    b.resize(100);
    const std::string p = dir.file("short_header.las");
    spit(p, b);
    expectErrorWith([&] { readLas(p); }, {p, "byte offset 100", "truncated public header"});
  }
  {  // wrong signature
    auto b = good;
    std::memcpy(&b[0], "LASX", 4);
    const std::string p = dir.file("signature.las");
    spit(p, b);
    expectErrorWith([&] { readLas(p); }, {p, "byte offset 0", "LASX", "LASF"});
  }
  {  // count beyond the file
    auto b = good;
    const std::uint32_t n = 38368;
    std::memcpy(&b[107], &n, 4);
    const std::string p = dir.file("count.las");
    spit(p, b);
    expectErrorWith([&] { readLas(p); }, {p, "byte offset " + std::to_string(good.size()), "38368", "record 38367"});
  }
  {  // unsupported version
    auto b = good;
    b[24] = 2;
    const std::string p = dir.file("version.las");
    spit(p, b);
    expectErrorWith([&] { readLas(p); }, {p, "byte offset 24", "version 2.2"});
  }
  {  // unsupported format and LAZ
    auto b = good;
    b[104] = 6;
    const std::string p = dir.file("format.las");
    spit(p, b);
    expectErrorWith([&] { readLas(p); }, {p, "byte offset 104", "format 6"});
    b[104] = 0x81;
    spit(p, b);
    expectErrorWith([&] { readLas(p); }, {p, "byte offset 104", "LAZ"});
  }
  {  // record length too small for format 1
    auto b = good;
    const std::uint16_t rl = 20;
    std::memcpy(&b[105], &rl, 2);
    const std::string p = dir.file("reclen.las");
    spit(p, b);
    expectErrorWith([&] { readLas(p); }, {p, "byte offset 105", "record length 20", "28"});
  }
  {  // point offset past the end
    auto b = good;
    const std::uint32_t o = static_cast<std::uint32_t>(good.size() + 10);
    std::memcpy(&b[96], &o, 4);
    const std::string p = dir.file("offset.las");
    spit(p, b);
    expectErrorWith([&] { readLas(p); }, {p, "byte offset 96", "past the end"});
  }
  {  // zero scale
    auto b = good;
    const double z = 0.0;
    std::memcpy(&b[147], &z, 8);
    const std::string p = dir.file("scale.las");
    spit(p, b);
    expectErrorWith([&] { readLas(p); }, {p, "byte offset 147", "scale factor z"});
  }
}

// ---- PLY --------------------------------------------------------------------------------------

struct PlyHeaderInfo {
  std::size_t vertices = 0;
  std::size_t body = 0;
};
PlyHeaderInfo parsePlyHeader(const std::vector<unsigned char>& b) {
  const std::string text(b.begin(), b.begin() + std::min<std::size_t>(b.size(), 2048));
  PlyHeaderInfo h;
  const auto v = text.find("element vertex ");
  h.vertices = std::stoul(text.substr(v + 15));
  h.body = text.find("end_header\n") + 11;
  return h;
}

TEST(PlyReader, RealScanCountAndFirstPointMatchHeaderAndBytes) {
  const auto raw = slurp(kPlySource);
  const PlyHeaderInfo h = parsePlyHeader(raw);
  EXPECT_EQ(h.vertices, 69792u);  // SOURCE.txt
  const auto pts = readPly(kPlySource);
  ASSERT_EQ(pts.size(), h.vertices);
  // float x, y, z, scalar_intensity little-endian, 16 bytes per vertex.
  EXPECT_EQ(pts[0].x, floatAt(raw, h.body));
  EXPECT_EQ(pts[0].y, floatAt(raw, h.body + 4));
  EXPECT_EQ(pts[0].z, floatAt(raw, h.body + 8));
  EXPECT_EQ(pts[0].intensity, floatAt(raw, h.body + 12));
  const std::size_t last = h.body + 16 * (h.vertices - 1);
  EXPECT_EQ(pts.back().z, floatAt(raw, last + 8));
  EXPECT_EQ(readPly(dataPath("gicp_pair/target.ply")).size(), 69088u);
}

TEST(PlyReader, TruncatedBinaryBodyNamesOffset) {
  TempDir dir("ply");
  auto raw = slurp(kPlySource);
  const PlyHeaderInfo h = parsePlyHeader(raw);
  raw.resize(h.body + 16 * 500 + 3);
  const std::string p = dir.file("cut.ply");
  spit(p, raw);
  expectErrorWith([&] { readPly(p); }, {p, "byte offset " + std::to_string(h.body + 16 * 500), "69792"});
}

TEST(PlyReader, AsciiWithoutIntensityGivesNaN) {
  TempDir dir("ply");
  const std::string p = dir.file("a.ply");
  spitText(p,
           "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
           "end_header\n1 2 3\n-4.5 5.25 6\n");
  const auto pts = readPly(p);
  ASSERT_EQ(pts.size(), 2u);
  EXPECT_EQ(pts[1].x, -4.5f);
  EXPECT_EQ(pts[1].y, 5.25f);
  EXPECT_TRUE(std::isnan(pts[0].intensity));
}

// ---- PCD --------------------------------------------------------------------------------------

TEST(PcdReader, AsciiWithIntensityDoublesAndNaN) {
  TempDir dir("pcd");
  const std::string p = dir.file("a.pcd");
  spitText(p,
           "# .PCD v0.7 - Point Cloud Data file format\n"
           "VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 8 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
           "WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n"
           "1.5 -2 3.25 0.5\n"
           "10 20 30 255\n"
           "nan nan nan 7\n");
  const auto pts = readPcd(p);
  ASSERT_EQ(pts.size(), 3u);
  EXPECT_EQ(pts[0].x, 1.5f);
  EXPECT_EQ(pts[0].y, -2.f);
  EXPECT_EQ(pts[0].z, 3.25f);  // float64 field narrowed
  EXPECT_EQ(pts[0].intensity, 0.5f);
  EXPECT_EQ(pts[1].intensity, 255.f);
  EXPECT_TRUE(std::isnan(pts[2].x));  // NaN points are kept for the fusion to count
  EXPECT_EQ(pts[2].intensity, 7.f);

  const std::string q = dir.file("noint.pcd");
  spitText(q,
           "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
           "WIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n0 0 1\n2 3 4\n");
  const auto qs = readPcd(q);
  ASSERT_EQ(qs.size(), 2u);
  EXPECT_EQ(qs[1].z, 4.f);
  EXPECT_TRUE(std::isnan(qs[1].intensity));
}

TEST(PcdReader, MissingXyzAndMissingFileAreInputErrors) {
  TempDir dir("pcd");
  const std::string p = dir.file("rgb.pcd");
  spitText(p, "VERSION 0.7\nFIELDS a b\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2\n");
  expectErrorWith([&] { readPcd(p); }, {p, "no x, y and z", "a, b"});
  expectErrorWith([&] { readPcd(dir.file("none.pcd")); }, {dir.file("none.pcd"), "cannot open"});
}

TEST(PcdReader, BinaryBodyIsCheckedBeforePclReadsIt) {
  TempDir dir("pcd_bin");
  const std::string head =
      "VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
      "WIDTH 50\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 50\nDATA binary\n";
  std::vector<unsigned char> bytes(head.begin(), head.end());
  for (int i = 0; i < 50; ++i) {
    const float v[4] = {static_cast<float>(i), -0.5f * i, 0.25f, 3.0f};
    const auto* b = reinterpret_cast<const unsigned char*>(v);
    bytes.insert(bytes.end(), b, b + 16);
  }
  const std::string p = dir.file("b.pcd");
  spit(p, bytes);
  const auto pts = readPcd(p);
  ASSERT_EQ(pts.size(), 50u);
  EXPECT_EQ(pts[49].x, 49.f);
  EXPECT_EQ(pts[49].y, -24.5f);
  EXPECT_EQ(pts[49].intensity, 3.f);

  bytes.resize(head.size() + 16 * 20 + 9);
  spit(p, bytes);
  expectErrorWith([&] { readPcd(p); }, {p, "byte offset " + std::to_string(head.size() + 16 * 20), "point 20"});
  // PCL 1.13 crashes on files without a PCD header; ours refuses them first.
  spitText(p, "hello world\n");
  expectErrorWith([&] { readPcd(p); }, {p, "byte offset 0", "'hello'"});
  spitText(p, "VERSION 0.7\nFIELDS x y z\nSIZE 4 4\nTYPE F F F\nWIDTH 1\nPOINTS 1\nDATA ascii\n1 2 3\n");
  expectErrorWith([&] { readPcd(p); }, {p, "byte offset 25", "2 SIZE values for 3 FIELDS"});
  // ASCII bodies: PCL zero-fills short lines and non-numbers with only a warning.
  const std::string ascii = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nPOINTS 2\nDATA ascii\n";
  spitText(p, ascii + "1 2 3\n4 5\n");
  expectErrorWith([&] { readPcd(p); }, {p, "byte offset " + std::to_string(ascii.size() + 6), "line 9 has 2 values, expected 3"});
  spitText(p, ascii + "1 2 3\n4 five 6\n");
  expectErrorWith([&] { readPcd(p); }, {p, "byte offset " + std::to_string(ascii.size() + 8), "line 9", "'five'"});
  spitText(p, ascii + "1 2 3\n");
  expectErrorWith([&] { readPcd(p); }, {p, "1 points", "POINTS 2"});
  spitText(p, "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nPOINTS 3\nDATA ascii\n1 2 3\n");
  expectErrorWith([&] { readPcd(p); }, {p, "POINTS 3 differs from WIDTH x HEIGHT = 2"});
}

TEST(PlyReader, AsciiWithFewerVerticesThanDeclaredIsRefused) {
  TempDir dir("ply_bad");
  const std::string p = dir.file("short.ply");
  spitText(p, "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n");
  expectErrorWith([&] { readPly(p); }, {p, "ends after 1 vertex lines, the header declares 3"});
  // PCL would read the non-number as NaN; we refuse it with its line and offset.
  const std::string head = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  spitText(p, head + "1 2 3\n4 x 6\n");
  expectErrorWith([&] { readPly(p); }, {p, "byte offset " + std::to_string(head.size() + 8), "line 9", "'x' is not a number"});
  spitText(p, head + "1 2 3\n4 nan -inf\n");  // spelled-out NaN/inf are values, kept for the fusion to count
  EXPECT_TRUE(std::isnan(readPly(p)[1].y));
  spitText(p, "not a ply\n");
  expectErrorWith([&] { readPly(p); }, {p, "byte offset 0", "'ply' magic"});
}

// Found by fuzz_ply (docs/reliability.md, "Fuzzing"): PCL sizes a vertex list property by the
// first vertex's list and aborts on an assertion when a later list is longer.
TEST(PlyReader, VertexListPropertiesAreRefusedBeforePclSeesThem) {
  TempDir dir("ply_list");
  const std::string p = dir.file("list.ply");
  // The fuzzer's input, minimised: the second vertex's list (64 ints) outgrows the first (0).
  const unsigned char minimised[] = "ply\nformat binary_big_endian 1.0\nelement vertex 6\n"
                                    "property list uchar int e\nend_header\n\x00\x40\x00\x00\x00\x00";
  spit(p, std::vector<unsigned char>(minimised, minimised + sizeof minimised - 1));
  expectErrorWith([&] { readPly(p); }, {p, "byte offset 50", "vertex property 'e' is a list"});
  spitText(p, "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
              "property list uchar float n\nend_header\n1 2 3 1 0.5\n4 5 6 3 1 2 3\n");
  expectErrorWith([&] { readPly(p); }, {p, "byte offset 89", "vertex property 'n' is a list"});
  // Lists on other elements (faces) are PCL's business and stay accepted.
  spitText(p, "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
  EXPECT_EQ(readPly(p).size(), 3u);
}

// Found by fuzz_ply: the header is split into lines as PCL splits it. PCL takes the first four
// bytes as the magic whatever the fourth is, so "plyr obj_info" holds an obj_info line, and
// PCL's obj_info callback asserts that the line starts with the word (here a space).
TEST(PlyReader, HeaderIsReadAsPclReadsIt) {
  TempDir dir("ply_hdr");
  const std::string p = dir.file("h.ply");
  spitText(p, "plyr obj_info\nend_header\n");  // minimised
  expectErrorWith([&] { readPly(p); }, {p, "byte offset 4", "'obj_info' does not start its line"});
  // The header ends at the first line whose first word is end_header, not at the first
  // occurrence of the text: the vertex element after this comment is checked.
  const std::string vertex3 = "element vertex 2\nproperty float x\nproperty float y\nproperty float z\n";
  spitText(p, "ply\nformat ascii 1.0\ncomment not the end_header\n" + vertex3 + "end_header\n1 2 3\n4 x 6\n");
  expectErrorWith([&] { readPly(p); }, {p, "'x' is not a number"});
  // obj_info num_cols x num_rows sizes PCL's buffer (51 GB here, for 3 vertices): it must be the
  // vertex count.
  spitText(p, "ply\nformat ascii 1.0\nobj_info num_cols 1431655766\nobj_info num_rows 3\n" + vertex3 +
                  "end_header\n1 2 3\n4 5 6\n");
  expectErrorWith([&] { readPly(p); }, {p, "byte offset 50", "1431655766 x 3 differs from the 2 vertices"});
  spitText(p, "ply\nformat ascii 1.0\nobj_info num_cols 2\nobj_info num_rows 1\n" + vertex3 + "end_header\n1 2 3\n4 5 6\n");
  EXPECT_EQ(readPly(p).size(), 2u);
  spitText(p, "ply\r\nformat ascii 1.0\r\nelement vertex 2\r\nproperty float x\r\nproperty float y\r\n"
              "property float z\r\nend_header\r\n1 2 3\r\n4 5 6\r\n");  // CRLF, as PCL reads it
  EXPECT_EQ(readPly(p).size(), 2u);
}

// Found by fuzz_pcd: PCL acts on every occurrence of a header keyword (each POINTS resizes its
// buffer: 44073700 x 29 bytes here, 443 GB in the fuzzer's first find) and goes on reading
// header lines after DATA, so the body's first line can be more header.
TEST(PcdReader, RepeatedKeywordsAndHeaderLinesAfterDataAreRefused) {
  TempDir dir("pcd_dup");
  const std::string p = dir.file("dup.pcd");
  const char repeated[] =
      "FIELDS x y z \x00 0\nPOINTS 44073700\nSIZE 8 8 8 4 1\nTYPE F F F F U\nWIDTH 2\nPOINTS 2\nDATA binary\n"
      "\x00?/\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\x00\x00\x00\x00\x00\x00\x00\x0f"
      "\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7\xb7NNNNNNWINscWIDT5\nPON";  // minimised
  spit(p, std::vector<unsigned char>(repeated, repeated + sizeof repeated - 1));
  expectErrorWith([&] { readPcd(p); }, {p, "byte offset 71", "'POINTS' appears again (first at byte offset 17)"});
  const char after_data[] = "FIELDS x y z i\nSIZE 4 4 4 4\nTYPE F F F F\nWIDTH 2\nDATA binary\nDATA\xcd\xcc .\n"
                            "POINTS 184467407@\x9a\xffVNT\n";  // minimised
  spit(p, std::vector<unsigned char>(after_data, after_data + sizeof after_data - 1));
  expectErrorWith([&] { readPcd(p); }, {p, "byte offset 61", "starts with 'DATA...'"});
  // A comment line after DATA is skipped by PCL too, so the check looks past it.
  const std::string head = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nPOINTS 1\nDATA ascii\n";
  spitText(p, head + "# c\nPOINTS 9\n");
  expectErrorWith([&] { readPcd(p); }, {p, "byte offset " + std::to_string(head.size() + 4), "starts with 'POINTS...'"});
}

// Found by fuzz_pcd: PCL skips only empty header lines; one of whitespace ends its header, so
// as the first line PCL 1.13 reads no fields and dereferences null (SEGV), and further down it
// silently drops the rest of the header (an empty cloud where the header declares points).
TEST(PcdReader, WhitespaceOnlyHeaderLinesAreRefused) {
  TempDir dir("pcd_ws");
  const std::string p = dir.file("ws.pcd");
  spitText(p, "\r\nFIELDS x y z n\nSIZE 4 2 2 1\nTYPE I I I U\nWIDTH 2\nDATA ascii\n4 5 6 1\n4 5 6 1");  // minimised
  expectErrorWith([&] { readPcd(p); }, {p, "byte offset 0", "only whitespace"});
  const std::string head = "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n";
  spitText(p, head + " \nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n4 5 6\n");
  expectErrorWith([&] { readPcd(p); }, {p, "byte offset " + std::to_string(head.size()), "only whitespace"});
  // Empty lines are skipped by PCL as well, so they stay accepted.
  spitText(p, "\n" + head + "\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n4 5 6\n");
  EXPECT_EQ(readPcd(p).size(), 1u);
}

// ---- dispatch + throughput --------------------------------------------------------------------

TEST(ReadPointCloud, DispatchesByExtension) {
  TempDir dir("dispatch");
  // A KITTI scan of two records made here (the real frames are checked by KittiReader.*).
  const float records[8] = {1.f, 2.f, 3.f, 0.5f, -4.f, 5.f, -6.f, 0.25f};
  std::vector<unsigned char> bin(sizeof records);
  std::memcpy(bin.data(), records, sizeof records);
  spit(dir.file("000000.bin"), bin);
  const CloudFile k = readPointCloud(dir.file("000000.bin"));
  EXPECT_EQ(k.format, "kitti_bin");
  ASSERT_EQ(k.points.size(), 2u);
  EXPECT_EQ(k.points[1].z, -6.f);
  EXPECT_EQ(k.origin, Eigen::Vector3d::Zero());
  const CloudFile l = readPointCloud(kLas);
  EXPECT_EQ(l.format, "las");
  EXPECT_EQ(l.points.size(), 38367u);
  EXPECT_NE(l.origin, Eigen::Vector3d::Zero());
  EXPECT_EQ(readPointCloud(kPlySource).points.size(), 69792u);
  spitText(dir.file("x.PCD"), "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n");
  EXPECT_EQ(readPointCloud(dir.file("x.PCD")).format, "pcd");
  expectErrorWith([&] { readPointCloud(dir.file("cloud.laz")); }, {"cloud.laz", "'.laz'", "did you mean '.las'", ".pcd"});
}

// Reader throughput is measured by benchmarks/bench_readers.cpp, not in the unit suite.

}  // namespace
}  // namespace terramap::io
