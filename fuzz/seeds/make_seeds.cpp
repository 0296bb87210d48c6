// fuzz-seeds OUT_DIR: writes small valid files of every format the fuzz targets read into
// OUT_DIR/<target>/ (scripts/fuzz.sh adds the YAML of configs/ and tests/). Formats terramap
// writes itself (.tmap, GeoTIFF) come from its own writers, episodes from the episode writer's
// HDF5 helpers; the rest are built here byte by byte after the format descriptions, covering
// the variants the readers distinguish (ASCII/binary bodies, organised clouds, LAS versions and
// point formats, labelled rows, ...). Kept small (most well under 4 KiB): libFuzzer mutates
// small inputs much faster.
#include <terramap/core/layered_map.hpp>
#include <terramap/io/file_seal.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/io/mcap.hpp>
#include <terramap/io/ros2_messages.hpp>
#include <terramap/io/snapshot.hpp>
#include "sim/h5_detail.hpp"

#include <hdf5.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>
#include <type_traits>
#include <vector>

namespace fs = std::filesystem;
using Bytes = std::vector<unsigned char>;

namespace {

fs::path g_out;

fs::path target(const std::string& name) {
  const fs::path d = g_out / name;
  fs::create_directories(d);
  return d;
}

void put(const std::string& tgt, const std::string& name, const Bytes& b) {
  std::ofstream f(target(tgt) / name, std::ios::binary);
  f.write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
}
void put(const std::string& tgt, const std::string& name, const std::string& s) { put(tgt, name, Bytes(s.begin(), s.end())); }

template <class T>
void append(Bytes& b, T v) {
  static_assert(std::is_arithmetic_v<T>, "text goes through appendText");
  unsigned char raw[sizeof(T)];
  std::memcpy(raw, &v, sizeof(T));  // little-endian host, like the formats
  b.insert(b.end(), raw, raw + sizeof(T));
}
template <class T>
void appendBigEndian(Bytes& b, T v) {
  unsigned char raw[sizeof(T)];
  std::memcpy(raw, &v, sizeof(T));
  for (std::size_t i = sizeof(T); i-- > 0;) b.push_back(raw[i]);
}
void appendText(Bytes& b, const std::string& s) { b.insert(b.end(), s.begin(), s.end()); }

struct P { float x, y, z, i; };
const P kPoints[] = {{1.5f, -2.0f, 0.25f, 0.1f}, {3.0f, 0.5f, -0.75f, 0.9f}, {-4.25f, 1.0f, 2.0f, 0.5f},
                     {0.0f, 0.0f, 0.0f, 0.0f}, {10.0f, -10.0f, 1.0f, 1.0f}, {2.0f, 2.0f, 2.0f, 0.3f}};

// ---- point clouds -------------------------------------------------------------------------------

void pcd() {
  const std::string head4 = "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity\n"
                            "SIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n";
  std::string ascii = head4 + "WIDTH 6\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 6\nDATA ascii\n";
  for (const P& p : kPoints) ascii += std::to_string(p.x) + " " + std::to_string(p.y) + " " + std::to_string(p.z) + " " + std::to_string(p.i) + "\n";
  put("fuzz_pcd", "ascii.pcd", ascii);

  Bytes bin;
  appendText(bin, head4 + "WIDTH 3\nHEIGHT 2\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 6\nDATA binary\n");
  for (const P& p : kPoints) { append(bin, p.x); append(bin, p.y); append(bin, p.z); append(bin, p.i); }
  put("fuzz_pcd", "binary_organised.pcd", bin);

  // Mixed types and counts: double coordinates, a 2-value field, an 8-bit "reflectance".
  Bytes mixed;
  appendText(mixed, "VERSION .7\nFIELDS x y z normal reflectance\nSIZE 8 8 8 4 1\nTYPE F F F F U\nCOUNT 1 1 1 2 1\n"
                "WIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA binary\n");
  for (int k = 0; k < 2; ++k) {
    append(mixed, double(kPoints[k].x)); append(mixed, double(kPoints[k].y)); append(mixed, double(kPoints[k].z));
    append(mixed, 0.0f); append(mixed, 1.0f); mixed.push_back(static_cast<unsigned char>(40 * k + 7));
  }
  put("fuzz_pcd", "binary_mixed_types.pcd", mixed);
  put("fuzz_pcd", "ascii_integer_fields.pcd",
      "VERSION .7\nFIELDS x y z remission\nSIZE 2 2 2 1\nTYPE I I I U\nCOUNT 1 1 1 1\nWIDTH 2\nPOINTS 2\nDATA ascii\n"
      "1 -2 3 200\n-4 5 -6 17\n");

  // binary_compressed: the fields one after the other (x of every point, then y, ...), LZF
  // coded as literal runs (control byte n < 32 = the next n + 1 bytes as they are).
  Bytes soa;
  for (int f = 0; f < 4; ++f)
    for (const P& p : kPoints) append(soa, f == 0 ? p.x : f == 1 ? p.y : f == 2 ? p.z : p.i);
  Bytes lzf;
  for (std::size_t at = 0; at < soa.size(); at += 32) {
    const std::size_t n = std::min<std::size_t>(32, soa.size() - at);
    lzf.push_back(static_cast<unsigned char>(n - 1));
    lzf.insert(lzf.end(), soa.begin() + static_cast<long>(at), soa.begin() + static_cast<long>(at + n));
  }
  Bytes comp;
  appendText(comp, head4 + "WIDTH 6\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 6\nDATA binary_compressed\n");
  append(comp, static_cast<std::uint32_t>(lzf.size()));
  append(comp, static_cast<std::uint32_t>(soa.size()));
  comp.insert(comp.end(), lzf.begin(), lzf.end());
  put("fuzz_pcd", "binary_compressed.pcd", comp);
}

void ply() {
  std::string ascii = "ply\nformat ascii 1.0\ncomment terramap fuzz seed\nelement vertex 6\nproperty float x\n"
                      "property float y\nproperty float z\nproperty float intensity\nelement face 1\n"
                      "property list uchar int vertex_indices\nend_header\n";
  for (const P& p : kPoints) ascii += std::to_string(p.x) + " " + std::to_string(p.y) + " " + std::to_string(p.z) + " " + std::to_string(p.i) + "\n";
  ascii += "3 0 1 2\n";
  put("fuzz_ply", "ascii_with_face.ply", ascii);

  const std::string head = "element vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
                           "property uchar red\nproperty double scalar_intensity\nend_header\n";
  Bytes le, be;
  appendText(le, "ply\nformat binary_little_endian 1.0\n" + head);
  appendText(be, "ply\nformat binary_big_endian 1.0\n" + head);
  for (const P& p : kPoints) {
    append(le, p.x); append(le, p.y); append(le, p.z); le.push_back(200); append(le, double(p.i));
    appendBigEndian(be, p.x); appendBigEndian(be, p.y); appendBigEndian(be, p.z); be.push_back(200);
    appendBigEndian(be, double(p.i));
  }
  put("fuzz_ply", "binary_le.ply", le);
  put("fuzz_ply", "binary_be.ply", be);
  // An element before the vertices shifts where they start.
  Bytes pre;
  appendText(pre, "ply\nformat binary_little_endian 1.0\nelement camera 1\nproperty float view_px\n"
              "element vertex 2\nproperty double x\nproperty double y\nproperty double z\nend_header\n");
  append(pre, 1.0f);
  for (int k = 0; k < 2; ++k) { append(pre, double(kPoints[k].x)); append(pre, double(kPoints[k].y)); append(pre, double(kPoints[k].z)); }
  put("fuzz_ply", "binary_element_before_vertex.ply", pre);
  // Organised (obj_info num_cols x num_rows) and CRLF line ends, which PCL reads differently.
  put("fuzz_ply", "ascii_organised_crlf.ply",
      "ply\r\nformat ascii 1.0\r\nobj_info num_cols 3\r\nobj_info num_rows 2\r\nelement vertex 6\r\n"
      "property float x\r\nproperty float y\r\nproperty float z\r\nend_header\r\n"
      "1 2 3\r\n4 5 6\r\n7 8 9\r\n1 1 1\r\n2 2 2\r\n3 3 3\r\n");
}

void kittiBin() {
  Bytes b;
  for (const P& p : kPoints) { append(b, p.x); append(b, p.y); append(b, p.z); append(b, p.i); }
  put("fuzz_kitti_bin", "six_points.bin", b);
  put("fuzz_kitti_bin", "empty.bin", Bytes{});
}

// LAS public header (ASPRS LAS 1.2 / 1.4 field offsets), then optional VLRs and the records.
Bytes lasFile(int minor, int format, bool geokeys, std::uint8_t ground_class) {
  const int header_size = minor >= 4 ? 375 : 227;
  const int record = format == 0 ? 20 : format == 1 ? 28 : format == 2 ? 26 : 34;
  Bytes vlr;
  if (geokeys) {
    Bytes keys;
    for (std::uint16_t v : {1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 32632}) append(keys, v);
    append(vlr, std::uint16_t(0));
    std::string user = "LASF_Projection";
    user.resize(16, '\0');
    appendText(vlr, user);
    append(vlr, std::uint16_t(34735));
    append(vlr, static_cast<std::uint16_t>(keys.size()));
    std::string desc = "GeoKeyDirectoryTag";
    desc.resize(32, '\0');
    appendText(vlr, desc);
    vlr.insert(vlr.end(), keys.begin(), keys.end());
  }
  const std::uint32_t n = 6;
  Bytes h(static_cast<std::size_t>(header_size), 0);
  std::memcpy(&h[0], "LASF", 4);
  h[24] = 1;
  h[25] = static_cast<unsigned char>(minor);
  std::memcpy(&h[26], "terramap fuzz seed", 18);
  std::memcpy(&h[58], "make_seeds", 10);
  auto set = [&](std::size_t at, auto v) { std::memcpy(&h[at], &v, sizeof v); };
  set(90, std::uint16_t(200));
  set(92, std::uint16_t(2026));
  set(94, static_cast<std::uint16_t>(header_size));
  set(96, static_cast<std::uint32_t>(header_size + vlr.size()));
  set(100, std::uint32_t(geokeys ? 1 : 0));
  h[104] = static_cast<unsigned char>(format);
  set(105, static_cast<std::uint16_t>(record));
  set(107, n);
  set(111, n);
  const double scale = 0.001, offset[3] = {500000.0, 4000000.0, 100.0};
  for (int a = 0; a < 3; ++a) {
    set(131 + 8 * a, scale);
    set(155 + 8 * a, offset[a]);
  }
  double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
  for (const P& p : kPoints) {
    const double c[3] = {offset[0] + p.x, offset[1] + p.y, offset[2] + p.z};
    for (int a = 0; a < 3; ++a) { lo[a] = std::min(lo[a], c[a]); hi[a] = std::max(hi[a], c[a]); }
  }
  for (int a = 0; a < 3; ++a) {
    set(179 + 16 * a, hi[a]);
    set(187 + 16 * a, lo[a]);
  }
  if (minor >= 4) {
    set(247, std::uint64_t(n));
    set(255, std::uint64_t(n));
  }
  Bytes out = h;
  out.insert(out.end(), vlr.begin(), vlr.end());
  int k = 0;
  for (const P& p : kPoints) {
    Bytes r;
    append(r, static_cast<std::int32_t>(std::lround(p.x / scale)));
    append(r, static_cast<std::int32_t>(std::lround(p.y / scale)));
    append(r, static_cast<std::int32_t>(std::lround(p.z / scale)));
    append(r, static_cast<std::uint16_t>(p.i * 65535));
    r.push_back(static_cast<unsigned char>(1 | (1 << 3)));          // return 1 of 1
    r.push_back(k % 3 == 2 ? std::uint8_t(1) : ground_class);       // mostly ground
    r.push_back(0);                                                  // scan angle
    r.push_back(0);                                                  // user data
    append(r, std::uint16_t(1));                                     // point source
    if (format == 1 || format == 3) append(r, 1000.0 + k);           // GPS time
    if (format >= 2) for (int c = 0; c < 3; ++c) append(r, std::uint16_t(1000 * c));  // RGB
    r.resize(static_cast<std::size_t>(record), 0);
    out.insert(out.end(), r.begin(), r.end());
    ++k;
  }
  return out;
}

void las() {
  put("fuzz_las", "las12_format1_geokeys.las", lasFile(2, 1, true, 2));
  put("fuzz_las", "las10_format0.las", lasFile(0, 0, false, 2));
  put("fuzz_las", "las14_format3.las", lasFile(4, 3, true, 2));
  put("fuzz_las", "las13_format2_no_ground.las", lasFile(3, 2, false, 1));
}

// ---- trajectories -----------------------------------------------------------------------------

void trajectories() {
  put("fuzz_trajectory_tum", "tum.txt",
      "# timestamp tx ty tz qx qy qz qw\n"
      "1305031102.1758 1.3405 0.6266 1.6575 0.6574 0.6126 -0.2949 -0.3248\n"
      "1305031102.2758 1.3303 0.6256 1.6464 0.6579 0.6161 -0.2932 -0.3189\n"
      "\n"
      "1305031102.3758 1.3160 0.6254 1.6302 0.6609 0.6199 -0.2893 -0.3086  # comment\n"
      "+1305031102.4758 1.3 0.62 1.62 0 0 0 1\n");
  const std::string rows = "1 0 0 0 0 1 0 0 0 0 1 0\n"
                           "9.999978e-01 5.272628e-04 -2.066935e-03 -4.690294e-02 -5.296506e-04 9.999992e-01 "
                           "-1.154865e-03 -2.839928e-02 2.066324e-03 1.155958e-03 9.999971e-01 8.586941e-01\n"
                           "0 -1 0 1.5 1 0 0 -2 0 0 1 0.25\n";
  put("fuzz_trajectory_kitti", "poses_only.txt", rows);
  put("fuzz_trajectory_kitti", "poses_and_times.txt", rows + "\n%%\n0.000000e+00\n1.036896e-01\n2.073793e-01\n");
  put("fuzz_trajectory_relative", "labelled_3x4.txt",
      "0->1 1 0 0 0.5 0 1 0 0 0 0 1 0 res=0.01\n"
      "1->2 0 -1 0 0.5 1 0 0 0 0 0 1 0 res=0.02 fitness=0.9\n");
  put("fuzz_trajectory_relative", "unlabelled_4x4.txt",
      "# frame-to-frame ICP\n1 0 0 0.1 0 1 0 0 0 0 1 0 0 0 0 1\n1 0 0 0.1 0 1 0 0 0 0 1 0.01 0 0 0 1\n");
}

// ---- DEMs ---------------------------------------------------------------------------------------

void demAscii() {
  put("fuzz_dem_ascii", "corner_nodata.asc",
      "ncols 4\nnrows 3\nxllcorner 100.0\nyllcorner 200.0\ncellsize 0.5\nNODATA_value -9999\n"
      "1.0 1.5 2.0 2.5\n1.1 -9999 2.1 2.6\n1.2 1.7 2.2 2.7\n");
  put("fuzz_dem_ascii", "center_no_nodata.asc",
      "NCOLS 3\r\nNROWS 2\r\nXLLCENTER -1.5\r\nYLLCENTER 0\r\nCELLSIZE 1\r\n-0.5 +0.25 1e-2\r\n3 .5 -4\r\n");
}

terramap::LayeredMap smallMap(bool sparse) {
  using namespace terramap;
  MapOptions opt;
  opt.tile_size = 8;
  opt.sparse = sparse;
  LayeredMap map(Geometry(0.5, Size(12, 10), Position(1.0, -2.0)), opt);
  const LayerId e = map.addLayer("elevation", "m", std::nanf(""));
  const LayerId v = map.addLayer("variance", "m^2", 0.0f);
  for (int i = 0; i < 12; ++i)
    for (int j = 0; j < 10; ++j) {
      if (sparse && i > 5) continue;  // leaves tiles unallocated
      if ((i + j) % 7 != 3) map.set(e, Index(i, j), 0.1f * i - 0.05f * j);
      map.set(v, Index(i, j), 0.01f * (i + 1));
    }
  return map;
}

void geotiff() {
  using namespace terramap;
  const fs::path d = target("fuzz_geotiff");
  const LayeredMap map = smallMap(false);
  io::writeGeoTiff(map, {"elevation"}, d / "local_crs.tif");
  io::GeoTiffOptions plain;
  plain.compress = false;
  io::writeGeoTiff(map, {"elevation", "variance"}, d / "two_bands_uncompressed.tif", plain);
  io::GeoTiffOptions utm;
  utm.georef.epsg = 32632;
  utm.georef.origin_easting = 500000;
  utm.georef.origin_northing = 5000000;
  io::writeGeoTiff(map, {"elevation"}, d / "utm32632.tif", utm);
}

void tmap() {
  using namespace terramap;
  const fs::path d = target("fuzz_tmap");
  io::saveSnapshot(smallMap(false), d / "dense.tmap");
  io::saveSnapshot(smallMap(true), d / "sparse.tmap");
  LayeredMap empty(Geometry(1.0, Size(3, 2)), MapOptions{});
  io::saveSnapshot(empty, d / "no_layers.tmap");
}

// ---- rosbag2 (MCAP) -------------------------------------------------------------------------------

// A bag the rosbag source maps (tf map -> lidar, two clouds of two points on /points) in each chunk
// compression, written by terramap's MCAP writer with small chunks so there are several; the
// uncompressed one lets the fuzzer change message fields directly.
void rosbags() {
  using namespace terramap::io;
  const fs::path d = target("fuzz_rosbag");
  for (auto [c, name] : {std::pair{mcap::Compression::None, "none.mcap"}, {mcap::Compression::Zstd, "zstd.mcap"},
                         {mcap::Compression::Lz4, "lz4.mcap"}}) {
    mcap::Writer w((d / name).string(), "ros2", c, 256);
    auto channel = [&](const char* topic, const char* type) {
      return w.addChannel(topic, w.addSchema(type, "ros2msg", ros2::messageDefinition(type)), "cdr");
    };
    const auto tf = channel("/tf", "tf2_msgs/msg/TFMessage");
    const auto pts = channel("/points", "sensor_msgs/msg/PointCloud2");
    for (int k = 0; k < 2; ++k) {
      ros2::TransformStamped t;
      t.header.stamp.sec = k;
      t.header.frame_id = "map";
      t.child_frame_id = "lidar";
      t.translation = Eigen::Vector3d(k, 0, 1);
      const auto tb = ros2::encodeTFMessage({t});
      w.write(tf, 1000000000ull * k, 1000000000ull * k, tb.data(), tb.size());
      ros2::PointCloud2 p;
      p.header = t.header;
      p.header.frame_id = "lidar";
      p.width = 2;
      const char* names[] = {"x", "y", "z", "intensity"};
      for (std::uint32_t f = 0; f < 4; ++f) p.fields.push_back({names[f], 4 * f, ros2::kFloat32, 1});
      p.point_step = 16;
      p.row_step = 32;
      const float v[8] = {1, 2, 3, 4, 5, 6, 7, 8};
      p.data.assign(reinterpret_cast<const std::uint8_t*>(v), reinterpret_cast<const std::uint8_t*>(v) + 32);
      const auto pb = ros2::encodePointCloud2(p);
      w.write(pts, 1000000000ull * k, 1000000000ull * k, pb.data(), pb.size());
    }
    w.close();
  }
}

// ---- episodes -----------------------------------------------------------------------------------

// Rows appended over time, as the episode writer's appenders store them: unlimited first
// dimension, chunks of a few rows, shuffle + gzip.
void h5Appendable(hid_t parent, const char* name, hid_t type, const void* data, const std::vector<hsize_t>& dims) {
  std::vector<hsize_t> maxd = dims, chunk = dims;
  maxd[0] = H5S_UNLIMITED;
  chunk[0] = 4;
  const hid_t space = H5Screate_simple(static_cast<int>(dims.size()), dims.data(), maxd.data());
  const hid_t dcpl = H5Pcreate(H5P_DATASET_CREATE);
  H5Pset_chunk(dcpl, static_cast<int>(chunk.size()), chunk.data());
  H5Pset_shuffle(dcpl);
  H5Pset_deflate(dcpl, 1);
  const hid_t ds = H5Dcreate2(parent, name, type, space, H5P_DEFAULT, dcpl, H5P_DEFAULT);
  H5Dwrite(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data);
  H5Dclose(ds);
  H5Pclose(dcpl);
  H5Sclose(space);
}

// The datasets fuzz_episode_h5 reads, laid out as docs/sim.md describes, in a file of a few KiB
// (a simulated episode is over a megabyte: its appenders allocate 4096-row chunks). The arrays
// go through the episode writer's own helper (engine/sim/h5_detail.hpp).
void tinyEpisode(const fs::path& path, int gzip) {
  using terramap::h5detail::writeArray;
  const std::string where = path.string();
  // Sealed as the episode writer seals (io/file_seal.hpp): an unsealed seed would never get past
  // the reader's seal check, and neither would anything the fuzzer derives from it.
  const hid_t fcpl = H5Pcreate(H5P_FILE_CREATE);
  H5Pset_userblock(fcpl, terramap::io::kSealBytes);
  const hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, fcpl, H5P_DEFAULT);
  H5Pclose(fcpl);
  terramap::h5detail::attrString(f, "format", "terramap-sim-episode");
  terramap::h5detail::attrU64(f, "version", 2);
  const hid_t terrain = terramap::h5detail::makeGroup(f, "terrain", where);
  const float height[2][3][4] = {{{0, 1, 2, 3}, {4, 5, 6, 7}, {8, 9, 10, 11}}, {{1, 1, 1, 1}, {2, 2, 2, 2}, {3, 3, 3, 3}}};
  writeArray(terrain, "height", H5T_NATIVE_FLOAT, height, {2, 3, 4}, gzip, where);
  const double stamps[2] = {0.0, 0.5};
  writeArray(terrain, "snapshot_stamp", H5T_NATIVE_DOUBLE, stamps, {2}, 0, where);
  H5Gclose(terrain);
  const hid_t machines = terramap::h5detail::makeGroup(f, "machines", where);
  const hid_t m = terramap::h5detail::makeGroup(machines, "ctl1", where);
  double T[2][4][4] = {};
  for (auto& t : T)
    for (int k = 0; k < 4; ++k) t[k][k] = 1.0;
  T[1][0][3] = 0.25;
  if (gzip > 0) h5Appendable(m, "T_map_base", H5T_NATIVE_DOUBLE, T, {2, 4, 4});
  else writeArray(m, "T_map_base", H5T_NATIVE_DOUBLE, T, {2, 4, 4}, 0, where);
  const hid_t truth = terramap::h5detail::makeGroup(m, "truth", where);
  const std::uint8_t stalled[2] = {0, 1};
  writeArray(truth, "stalled", H5T_NATIVE_UINT8, stalled, {2}, 0, where);
  H5Gclose(truth);
  H5Gclose(m);
  H5Gclose(machines);
  H5Fclose(f);
  terramap::io::sealFile(path);
}

void episodes() {
  const fs::path d = target("fuzz_episode_h5");
  tinyEpisode(d / "tiny_contiguous.h5", 0);
  tinyEpisode(d / "tiny_chunked_gzip.h5", 1);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: fuzz-seeds OUT_DIR\n";
    return 2;
  }
  g_out = argv[1];
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  pcd();
  ply();
  kittiBin();
  las();
  trajectories();
  demAscii();
  geotiff();
  tmap();
  rosbags();
  episodes();
  return 0;
}
