// LAS 1.0-1.4 reader for point data record formats 0-3, written from the ASPRS LAS
// specification (1.2 R2 and 1.4 R15): public header block, variable length records (only the
// GeoKeyDirectory is interpreted), point data records.
#include <terramap/io/readers.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/core/text.hpp>

#include "reader_detail.hpp"

#include <algorithm>
#include <cmath>

namespace terramap::io {

namespace {

constexpr std::uint16_t kMinHeaderSize = 227;        // LAS 1.0-1.2 public header block
constexpr std::uint16_t kLas14HeaderSize = 375;      // carries the 64-bit point count
constexpr std::uint16_t kMinRecordLength[4] = {20, 28, 26, 34};
constexpr std::size_t kVlrHeaderSize = 54;
constexpr std::uint16_t kGeoKeyDirectoryRecord = 34735;

[[noreturn]] void fail(const std::string& path, std::uint64_t offset, const std::string& msg) {
  throw InputError("LAS file '" + path + "' at byte offset " + std::to_string(offset) + ": " + msg);
}

std::string fixedString(const unsigned char* p, std::size_t n) {
  std::string s(reinterpret_cast<const char*>(p), n);
  const auto nul = s.find('\0');
  if (nul != std::string::npos) s.resize(nul);
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

// Reads exactly n bytes at `offset`; a short read means the file is shorter than the header
// claims, so it is reported at the first missing byte.
void readAt(std::FILE* f, const std::string& path, std::uint64_t offset, unsigned char* dst, std::size_t n) {
  if (std::fseek(f, static_cast<long>(offset), SEEK_SET) != 0) fail(path, offset, "cannot seek");
  const std::size_t got = std::fread(dst, 1, n, f);
  if (got != n) fail(path, offset + got, "unexpected end of file (needed " + std::to_string(n) + " bytes from offset " + std::to_string(offset) + ")");
}

std::optional<int> parseGeoKeys(const std::vector<unsigned char>& d) {
  // GeoKeyDirectoryTag: u16 {version, revision, minor, number_of_keys} then number_of_keys
  // entries {key_id, tiff_tag_location, count, value_offset}; location 0 = value inline.
  if (d.size() < 8) return std::nullopt;
  const std::size_t keys = detail::loadU16(&d[6]);
  std::optional<int> projected, geographic;
  for (std::size_t k = 0; k < keys && 8 + 8 * k + 8 <= d.size(); ++k) {
    const unsigned char* e = &d[8 + 8 * k];
    const std::uint16_t id = detail::loadU16(e), loc = detail::loadU16(e + 2), value = detail::loadU16(e + 6);
    if (loc != 0 || value == 0 || value == 32767) continue;  // 32767 = user-defined
    if (id == 3072) projected = value;                       // ProjectedCSTypeGeoKey
    if (id == 2048) geographic = value;                      // GeographicTypeGeoKey
  }
  return projected ? projected : geographic;
}

/// Reads the public header's bytes (up to the LAS 1.4 size) and checks the signature and that
/// the minimum header is there.
void readSignedHeader(std::FILE* f, const std::string& path, std::uint64_t file_size, unsigned char* h) {
  const std::size_t have = static_cast<std::size_t>(std::min<std::uint64_t>(file_size, kLas14HeaderSize));
  readAt(f, path, 0, h, have);
  if (have < 4) fail(path, have, "file is " + std::to_string(file_size) + " bytes, too short for a LAS signature");
  if (std::memcmp(h, "LASF", 4) != 0) {
    fail(path, 0, "file signature is '" + fixedString(h, 4) + "' (hex " + [&] {
      char buf[16];
      std::snprintf(buf, sizeof buf, "%02x%02x%02x%02x", h[0], h[1], h[2], h[3]);
      return std::string(buf);
    }() + "), expected 'LASF': not a LAS file");
  }
  if (have < kMinHeaderSize) {
    fail(path, have, "truncated public header: the file has " + std::to_string(file_size) +
                         " bytes, a LAS header needs at least " + std::to_string(kMinHeaderSize));
  }
}

/// Version, sizes and offsets, and the point format, each checked as it is read.
void readLayoutFields(const unsigned char* h, const std::string& path, std::uint64_t file_size, LasHeader& hd) {
  hd.version_major = h[24];
  hd.version_minor = h[25];
  if (hd.version_major != 1 || hd.version_minor > 4) {
    fail(path, 24, "unsupported LAS version " + std::to_string(hd.version_major) + "." +
                       std::to_string(hd.version_minor) + " (supported: 1.0 to 1.4)");
  }
  hd.system_identifier = fixedString(h + 26, 32);
  hd.generating_software = fixedString(h + 58, 32);
  hd.creation_day = detail::loadU16(h + 90);
  hd.creation_year = detail::loadU16(h + 92);
  hd.header_size = detail::loadU16(h + 94);
  if (hd.header_size < kMinHeaderSize) {
    fail(path, 94, "header size " + std::to_string(hd.header_size) + " is below the minimum " +
                       std::to_string(kMinHeaderSize));
  }
  if (hd.header_size > file_size) {
    fail(path, file_size, "truncated public header: header size (byte 94) is " + std::to_string(hd.header_size) +
                              " but the file has only " + std::to_string(file_size) + " bytes");
  }
  hd.offset_to_points = detail::loadU32(h + 96);
  if (hd.offset_to_points < hd.header_size) {
    fail(path, 96, "offset to point data " + std::to_string(hd.offset_to_points) +
                       " lies inside the public header (header size " + std::to_string(hd.header_size) + ")");
  }
  if (hd.offset_to_points > file_size) {
    fail(path, 96, "offset to point data " + std::to_string(hd.offset_to_points) + " is past the end of the file (" +
                       std::to_string(file_size) + " bytes)");
  }
  hd.number_of_vlrs = detail::loadU32(h + 100);
  const std::uint8_t raw_format = h[104];
  if (raw_format & 0xC0) {
    fail(path, 104, "point data format byte " + std::to_string(raw_format) +
                        " has the compression bits set: this is a LAZ file; decompress it (e.g. laszip) first");
  }
  hd.point_format = raw_format;
  if (hd.point_format > 3) {
    fail(path, 104, "unsupported point data format " + std::to_string(hd.point_format) + " (supported: 0 to 3)");
  }
  hd.record_length = detail::loadU16(h + 105);
  if (hd.record_length < kMinRecordLength[hd.point_format]) {
    fail(path, 105, "point record length " + std::to_string(hd.record_length) + " is smaller than the " +
                        std::to_string(kMinRecordLength[hd.point_format]) + " bytes point format " +
                        std::to_string(hd.point_format) + " needs");
  }
}

/// Point counts, scales, offsets and bounds (the 64-bit counts of LAS 1.4 where present).
void readCountsAndScales(const unsigned char* h, const std::string& path, LasHeader& hd) {
  hd.point_count = detail::loadU32(h + 107);
  for (int r = 0; r < 5; ++r) hd.points_by_return[r] = detail::loadU32(h + 111 + 4 * r);
  for (int a = 0; a < 3; ++a) {
    hd.scale[a] = detail::loadF64(h + 131 + 8 * a);
    hd.offset[a] = detail::loadF64(h + 155 + 8 * a);
    hd.max[a] = detail::loadF64(h + 179 + 16 * a);
    hd.min[a] = detail::loadF64(h + 187 + 16 * a);
  }
  for (int a = 0; a < 3; ++a) {
    if (!std::isfinite(hd.scale[a]) || hd.scale[a] == 0.0) {
      fail(path, 131 + 8 * a, std::string("scale factor ") + "xyz"[a] + " = " + formatNumber(hd.scale[a]) + " is not a finite non-zero number");
    }
    if (!std::isfinite(hd.offset[a])) {
      fail(path, 155 + 8 * a, std::string("offset ") + "xyz"[a] + " = " + formatNumber(hd.offset[a]) + " is not finite");
    }
  }
  if (hd.version_minor >= 4 && hd.header_size >= kLas14HeaderSize) {
    const std::uint64_t count64 = detail::loadU64(h + 247);
    if (hd.point_count != 0 && hd.point_count != count64) {
      fail(path, 247, "64-bit point count " + std::to_string(count64) + " disagrees with the legacy count " +
                          std::to_string(hd.point_count) + " at byte 107");
    }
    hd.point_count = count64;
    for (int r = 0; r < 5; ++r) hd.points_by_return[r] = detail::loadU64(h + 255 + 8 * r);
  }
}

/// Variable length records between the header and the points: only the GeoKeyDirectory is
/// interpreted, but every VLR header must fit, or the point offset is not trustworthy.
void readVlrs(std::FILE* f, const std::string& path, LasHeader& hd) {
  std::uint64_t at = hd.header_size;
  for (std::uint32_t v = 0; v < hd.number_of_vlrs; ++v) {
    if (at + kVlrHeaderSize > hd.offset_to_points) {
      fail(path, at, "variable length record " + std::to_string(v) + " of " + std::to_string(hd.number_of_vlrs) +
                         " (count at byte 100) overruns the point data offset " + std::to_string(hd.offset_to_points));
    }
    unsigned char vh[kVlrHeaderSize];
    readAt(f, path, at, vh, kVlrHeaderSize);
    const std::string user = fixedString(vh + 2, 16);
    const std::uint16_t record_id = detail::loadU16(vh + 18);
    const std::uint16_t length = detail::loadU16(vh + 20);
    const std::uint64_t data_at = at + kVlrHeaderSize;
    if (data_at + length > hd.offset_to_points) {
      fail(path, at + 20, "variable length record " + std::to_string(v) + " ('" + user + "' " + std::to_string(record_id) +
                              ") of " + std::to_string(length) + " bytes overruns the point data offset " +
                              std::to_string(hd.offset_to_points));
    }
    if (user == "LASF_Projection" && record_id == kGeoKeyDirectoryRecord) {
      std::vector<unsigned char> d(length);
      if (length) readAt(f, path, data_at, d.data(), length);
      hd.epsg = parseGeoKeys(d);
    }
    at = data_at + length;
  }
}

/// Every declared point record must be in the file.
void checkPointRecordsFit(const std::string& path, std::uint64_t file_size, const LasHeader& hd) {
  const std::uint64_t body = file_size - hd.offset_to_points;
  const std::uint64_t fits = body / hd.record_length;
  if (hd.point_count > fits) {
    const std::uint64_t first_incomplete = hd.offset_to_points + fits * hd.record_length;
    fail(path, first_incomplete,
         "point count " + std::to_string(hd.point_count) + " (header) needs " +
             std::to_string(saturatingProduct({hd.point_count, hd.record_length})) + " bytes of " + std::to_string(hd.record_length) +
             "-byte records from offset " + std::to_string(hd.offset_to_points) + ", but the file ends at byte " +
             std::to_string(file_size) + ": record " + std::to_string(fits) + " is incomplete or missing");
  }
}

LasHeader parseHeader(std::FILE* f, const std::string& path, std::uint64_t file_size) {
  unsigned char h[kLas14HeaderSize] = {};
  readSignedHeader(f, path, file_size, h);
  LasHeader hd;
  readLayoutFields(h, path, file_size, hd);
  readCountsAndScales(h, path, hd);
  readVlrs(f, path, hd);
  checkPointRecordsFit(path, file_size, hd);
  return hd;
}

Eigen::Vector3d chooseOrigin(const LasHeader& hd, const LasReadOptions& opt, const unsigned char* first_record) {
  switch (opt.origin_mode) {
    case LasOriginMode::Explicit:
      return opt.origin;
    case LasOriginMode::Zero:
      return Eigen::Vector3d::Zero();
    case LasOriginMode::BoundingBoxCentre:
      break;
  }
  const bool box_ok = hd.min.allFinite() && hd.max.allFinite() && (hd.max.array() >= hd.min.array()).all();
  Eigen::Vector3d c;
  if (box_ok) {
    c = 0.5 * (hd.min + hd.max);
  } else if (first_record) {
    // Some writers leave the bounds at zero; any real point is an equally good datum.
    for (int a = 0; a < 3; ++a) c[a] = detail::loadI32(first_record + 4 * a) * hd.scale[a] + hd.offset[a];
  } else {
    c.setZero();
  }
  return c.array().round().matrix();
}

}  // namespace

std::vector<PointXYZI> LasCloud::pointsOfClass(std::uint8_t cls) const {
  std::vector<PointXYZI> out;
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (classification[i] == cls) out.push_back(points[i]);
  }
  return out;
}

LasHeader readLasHeader(const std::string& path) {
  detail::FileCloser fc{detail::openForRead(path, "LAS file")};
  return parseHeader(fc.f, path, detail::fileSize(fc.f, path));
}

LasCloud readLas(const std::string& path, const LasReadOptions& options) {
  detail::FileCloser fc{detail::openForRead(path, "LAS file")};
  const std::uint64_t file_size = detail::fileSize(fc.f, path);
  LasCloud cloud;
  cloud.path = path;
  cloud.header = parseHeader(fc.f, path, file_size);
  const LasHeader& hd = cloud.header;
  const std::size_t n = static_cast<std::size_t>(hd.point_count);
  const std::size_t len = hd.record_length;
  const bool has_gps = hd.point_format == 1 || hd.point_format == 3;

  // Per point: 16 (x, y, z, intensity) + 4 (class, flags, return, returns) + 8 (GPS time) + 24
  // (double positions) bytes, refused before anything is allocated.
  const std::uint64_t per_point = 20 + (has_gps ? 8 : 0) + (options.keep_double_positions ? 24 : 0);
  requireInputBudget(saturatingProduct({hd.point_count, per_point}),
                     "LAS file '" + path + "': point count " + std::to_string(hd.point_count),
                     std::to_string(hd.point_count) + " points x " + std::to_string(per_point) + " bytes");
  cloud.points.resize(n);
  cloud.classification.resize(n);
  cloud.class_flags.resize(n);
  cloud.return_number.resize(n);
  cloud.number_of_returns.resize(n);
  if (has_gps) cloud.gps_time.resize(n);
  if (options.keep_double_positions) cloud.positions.resize(n);

  // Stream the records in chunks: memory stays bounded by the output, not twice the file.
  constexpr std::size_t kChunkRecords = 1 << 15;
  std::vector<unsigned char> buf(std::min(n, kChunkRecords) * len);
  bool origin_set = false;
  for (std::size_t start = 0; start < n; start += kChunkRecords) {
    const std::size_t m = std::min(kChunkRecords, n - start);
    readAt(fc.f, path, hd.offset_to_points + static_cast<std::uint64_t>(start) * len, buf.data(), m * len);
    if (!origin_set) {
      cloud.origin = chooseOrigin(hd, options, buf.data());
      origin_set = true;
    }
    const Eigen::Vector3d& o = cloud.origin;
    for (std::size_t k = 0; k < m; ++k) {
      const unsigned char* r = buf.data() + k * len;
      const std::size_t i = start + k;
      const double x = detail::loadI32(r) * hd.scale.x() + hd.offset.x();
      const double y = detail::loadI32(r + 4) * hd.scale.y() + hd.offset.y();
      const double z = detail::loadI32(r + 8) * hd.scale.z() + hd.offset.z();
      PointXYZI& p = cloud.points[i];
      p.x = static_cast<float>(x - o.x());
      p.y = static_cast<float>(y - o.y());
      p.z = static_cast<float>(z - o.z());
      p.intensity = static_cast<float>(detail::loadU16(r + 12));
      const std::uint8_t returns = r[14];
      cloud.return_number[i] = returns & 0x07;
      cloud.number_of_returns[i] = (returns >> 3) & 0x07;
      cloud.classification[i] = r[15] & 0x1F;
      cloud.class_flags[i] = r[15] >> 5;
      if (has_gps) cloud.gps_time[i] = detail::loadF64(r + 20);
      if (options.keep_double_positions) cloud.positions[i] = Eigen::Vector3d(x, y, z);
    }
  }
  if (!origin_set) cloud.origin = chooseOrigin(hd, options, nullptr);
  return cloud;
}

}  // namespace terramap::io
