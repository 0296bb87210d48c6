#pragma once
/// \file
/// Point-cloud readers: PCD and PLY (through PCL, kept out of this header), KITTI velodyne
/// `.bin`, and LAS 1.0-1.4 point data formats 0-3 (parsed by hand: no Debian package reads LAS).
///
/// Conventions shared by every reader here:
/// - Coordinates are metres in the file's own frame (the sensor frame for PCD/PLY/KITTI, a
///   projected CRS such as UTM for LAS). Nothing is transformed, filtered or reordered:
///   NaN/inf points are returned as they are, because the fusion plugin drops *and counts*
///   them by reason (ARCHITECTURE.md section 6), which it cannot do if a reader hid them.
/// - `PointXYZI::intensity` keeps the source's scale (KITTI reflectance 0..1, LAS 0..65535,
///   PCD/PLY whatever the file holds) and is NaN when the file has no intensity field.
/// - Errors a user can cause (missing file, malformed content) throw terramap::InputError whose
///   message names the file and, where the format has one, the byte offset of the problem.
/// - Every function is reentrant: no shared state, safe to call from several threads at once.
#include <terramap/core/events.hpp>

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace terramap::io {

// ---- KITTI ------------------------------------------------------------------------------------

/// KITTI velodyne scan: packed little-endian float32 records {x, y, z, reflectance} (16 bytes).
/// Throws InputError if the file cannot be read or its size is not a multiple of 16 (the
/// message names the byte offset where the partial record starts: a truncated download is
/// refused instead of silently losing or inventing the last point).
std::vector<PointXYZI> readKittiBin(const std::string& path);

// ---- PCD / PLY (PCL) --------------------------------------------------------------------------

/// PCD (ASCII, binary or binary_compressed) via pcl::io::loadPCDFile.
/// Fields x, y, z are required (any numeric type; float64 is narrowed to float32); intensity
/// is taken from the first present field among "intensity", "scalar_intensity",
/// "reflectance", "remission", else NaN. Organised clouds are returned row-major (width*height).
/// The header is validated by terramap before PCL sees the file (PCL 1.13 crashes on some
/// headerless files and reads past short binary bodies): unknown keywords, FIELDS/SIZE/TYPE/
/// COUNT disagreeing, POINTS != WIDTH*HEIGHT, a binary body shorter than POINTS records or a
/// compressed body running past the end throw InputError naming the file and byte offset.
/// Throws InputError naming the file when PCL then refuses it or x/y/z are missing.
/// Note: PCL prints its own diagnostics to stderr before we throw; we do not silence PCL's
/// process-wide verbosity because that would change behaviour for the embedding application.
std::vector<PointXYZI> readPcd(const std::string& path);

/// PLY (ascii, binary_little_endian, binary_big_endian) vertices via PCL's PLYReader, same
/// field rules as readPcd. Before PCL parses a binary file we check that the header's vertex
/// count fits in the file (PCL would otherwise read past a truncated body); the message then
/// names the byte offset where the first incomplete vertex starts.
std::vector<PointXYZI> readPly(const std::string& path);

// ---- LAS --------------------------------------------------------------------------------------

/// The LAS public header block fields terramap uses (LAS 1.0-1.4; offsets are those of the
/// ASPRS specification, all little-endian).
struct LasHeader {
  std::uint8_t version_major = 0;  ///< byte 24
  std::uint8_t version_minor = 0;  ///< byte 25
  std::string system_identifier;   ///< bytes 26..57, trailing NULs removed
  std::string generating_software; ///< bytes 58..89
  std::uint16_t creation_day = 0;  ///< day of year, byte 90
  std::uint16_t creation_year = 0; ///< byte 92
  std::uint16_t header_size = 0;   ///< byte 94
  std::uint32_t offset_to_points = 0;  ///< byte 96: where the first point record starts
  std::uint32_t number_of_vlrs = 0;    ///< byte 100
  std::uint8_t point_format = 0;       ///< byte 104 (0..3 supported)
  std::uint16_t record_length = 0;     ///< byte 105 (>= the format's minimum; extra bytes skipped)
  /// Byte 107 (legacy 32-bit count), or the 64-bit count at byte 247 for LAS 1.4 files whose
  /// header carries it.
  std::uint64_t point_count = 0;
  std::array<std::uint64_t, 5> points_by_return{};  ///< byte 111 (or 255 for LAS 1.4)
  Eigen::Vector3d scale = Eigen::Vector3d::Zero();   ///< bytes 131/139/147: metres per unit
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();  ///< bytes 155/163/171: metres
  Eigen::Vector3d min = Eigen::Vector3d::Zero();     ///< header bounds, metres (as written;
  Eigen::Vector3d max = Eigen::Vector3d::Zero();     ///< not re-checked against the points)
  /// EPSG code of the projected (else geographic) CRS if the GeoKeyDirectory VLR
  /// (LASF_Projection / 34735) names one directly; empty otherwise (WKT CRS, user-defined, none).
  std::optional<int> epsg;
};

/// Where LasCloud's float origin is put.
enum class LasOriginMode {
  /// Centre of the header bounding box rounded to whole metres (default): keeps |p| small so
  /// float32 keeps ~0.03 mm over a 1 km site, and round numbers make the shift easy to read.
  BoundingBoxCentre,
  /// LasReadOptions::origin exactly (e.g. a worksite datum shared by several files).
  Explicit,
  /// (0, 0, 0): float points in absolute file coordinates. Only sensible for local CRSs;
  /// UTM northings (~1e6..1e7 m) lose decimetres in float32.
  Zero,
};

struct LasReadOptions {
  LasOriginMode origin_mode = LasOriginMode::BoundingBoxCentre;
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();  ///< used with LasOriginMode::Explicit
  /// Also fill LasCloud::positions with exact double coordinates (24 bytes more per point).
  bool keep_double_positions = false;
};

/// A LAS file's points. Absolute coordinate (file CRS, metres) of point i:
///   origin + (points[i].x, points[i].y, points[i].z)
/// Per-point attribute vectors are parallel to `points` (same size and order as the file).
struct LasCloud {
  std::string path;
  LasHeader header;
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  /// Float coordinates relative to `origin`; intensity = the 16-bit LAS intensity as float.
  std::vector<PointXYZI> points;
  /// ASPRS class (low 5 bits of the classification byte): 1 unclassified, 2 ground, ...
  std::vector<std::uint8_t> classification;
  /// High 3 bits of the classification byte: bit 0 synthetic, bit 1 key-point, bit 2 withheld.
  std::vector<std::uint8_t> class_flags;
  std::vector<std::uint8_t> return_number;      ///< 1-based, 0 when the writer left it unset
  std::vector<std::uint8_t> number_of_returns;
  /// GPS time (formats 1 and 3); empty for formats 0 and 2.
  std::vector<double> gps_time;
  /// Exact absolute coordinates; empty unless LasReadOptions::keep_double_positions.
  std::vector<Eigen::Vector3d> positions;

  std::size_t size() const { return points.size(); }
  /// Absolute position of point i from the float point (exact within float32 of the offset
  /// coordinate); use `positions` when the raw precision matters.
  Eigen::Vector3d absolute(std::size_t i) const {
    return origin + Eigen::Vector3d(points[i].x, points[i].y, points[i].z);
  }
  /// Points (relative to `origin`) whose ASPRS class equals `cls` (2 = ground), in file order.
  std::vector<PointXYZI> pointsOfClass(std::uint8_t cls) const;
};

/// Reads and validates only the public header (and the projection VLR).
/// Throws InputError naming the file and the byte offset of the offending field for: file
/// shorter than its header, signature other than "LASF", version other than 1.0-1.4, header
/// size below 227, point data offset before the header end or past the file end, a point data
/// format other than 0-3 (compressed LAZ is refused by name), a record length below the
/// format's minimum, non-finite or zero scale factors, non-finite offsets, variable length
/// records overrunning the point data, and a point count whose records do not fit in the file
/// (naming the byte offset of the first incomplete record).
LasHeader readLasHeader(const std::string& path);

/// Reads a whole LAS file (header + all point records) with readLasHeader's checks, so a
/// truncated file is refused before any point is decoded. Scale and offset are applied in
/// double precision, then the origin is subtracted before narrowing to float. Records are
/// streamed in chunks: peak memory is the output plus ~1 MB.
LasCloud readLas(const std::string& path, const LasReadOptions& options = {});

// ---- dispatch ---------------------------------------------------------------------------------

/// Any supported cloud file, for callers that do not care about the format.
struct CloudFile {
  std::string path;
  std::string format;  ///< "pcd", "ply", "kitti_bin" or "las"
  /// Absolute coordinate of a point = origin + point. Zero except for LAS, whose points are
  /// origin-shifted (see LasCloud) because projected coordinates do not fit float32.
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  std::vector<PointXYZI> points;
};

/// File extensions readPointCloud understands (lower case, with the dot).
const std::vector<std::string>& supportedCloudExtensions();

/// Reads a cloud by its (case-insensitive) extension: .pcd, .ply, .bin (KITTI), .las.
/// Throws InputError for an unknown extension (naming the supported ones) and whatever the
/// format's reader throws.
CloudFile readPointCloud(const std::string& path);

}  // namespace terramap::io
