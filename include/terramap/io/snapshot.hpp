#pragma once
/// \file
/// Map snapshots (`.tmap`): a self-describing, checksummed binary copy of a LayeredMap that
/// loads back bit for bit (NaN payloads included).
///
/// ## Byte layout, format version 1
/// All integers and floats are little-endian (whatever the host); floats are IEEE-754.
/// There is no JSON or text anywhere: every field has a fixed type and offset.
///
/// | offset | size | type   | field                                                          |
/// |-------:|-----:|--------|----------------------------------------------------------------|
/// |      0 |    4 | char   | magic `TMAP`                                                   |
/// |      4 |    4 | u32    | format version (1)                                             |
/// |      8 |    8 | u64    | file length in bytes, including the final checksum            |
/// |     16 |    8 | f64    | resolution, metres per cell (finite, > 0)                      |
/// |     24 |    4 | i32    | rows R = size.x (row i grows towards -x), 1 .. 2^20           |
/// |     28 |    4 | i32    | columns C = size.y (column j grows towards -y), 1 .. 2^20     |
/// |     32 |    8 | f64    | centre x, metres in the map frame                              |
/// |     40 |    8 | f64    | centre y, metres in the map frame                              |
/// |     48 |    4 | i32    | tile size T, cells per tile edge, 8 .. 1024                    |
/// |     52 |    4 | u32    | flags: bit 0 = sparse map; all other bits must be 0            |
/// |     56 |    4 | u32    | layer count, 0 .. 1024                                         |
/// |     60 |    4 | u32    | reserved, 0                                                    |
/// |     64 |    8 | u64    | CRC-64/XZ of bytes [0, 64) (header checksum)                   |
/// |     72 |      |        | layer records, in layer-id order                               |
/// |  end-8 |    8 | u64    | CRC-64/XZ of bytes [0, end-8) (file checksum)                  |
///
/// Layer record: u32 name length (1 .. 1024), the name bytes (UTF-8, no terminator);
/// u32 unit length (0 .. 1024), the unit bytes; u32 fill value (the float32's bit pattern);
/// u32 number K of stored tiles; then K tiles, each a u32 tile index followed by that tile's
/// cells as float32, row-major, only the cells inside the map (edge tiles are partial).
///
/// Tiles are *logical*: tile k = tr * ceil(C/T) + tc covers logical rows
/// [tr*T, min(R, tr*T+T)) and columns [tc*T, min(C, tc*T+T)), in the index convention of
/// geometry.hpp. The ring-buffer start index is deliberately **not** stored: a snapshot is the
/// map as its users see it (logical indices + geometry), so a loaded map has startIndex() ==
/// (0, 0) and identical geometry, options, layer names/units/fills and cell bits. This keeps
/// the format independent of how far the map has scrolled.
/// Tile indices in a record are strictly increasing. A dense map stores every tile (so the
/// file size bounds the memory a load allocates); a sparse map stores exactly the logical
/// tiles that overlap an allocated (buffer) tile of that layer; the others read as the fill.
/// For a map that never moved this reproduces the allocated tile set exactly.
///
/// CRC-64/XZ is CRC-64 with the ECMA-182 polynomial, reflected (0xC96C5795D7870F42),
/// init and final xor all ones; check value crc64("123456789") = 0x995DC9BBDF1939FA.
/// The header has its own checksum so that a damaged length or size field is reported as
/// damage, not as a (misleading) truncation.
///
/// Threading: saving reads the map through const accessors only; it must not run while
/// another thread mutates the same map. Save `map.snapshot()` (a cheap copy-on-write copy)
/// to keep mapping while a snapshot is written. Loading touches no shared state.
#include <terramap/core/layered_map.hpp>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace terramap::io {

inline constexpr std::uint32_t kSnapshotFormatVersion = 1;
inline constexpr std::size_t kSnapshotHeaderBytes = 72;

/// CRC-64/XZ, continuable like zlib's crc32: crc64(b, nb, crc64(a, na)) == crc64(a+b).
std::uint64_t crc64(const void* data, std::size_t n, std::uint64_t crc = 0);
/// The CRC of a followed by b from crc64(a) and crc64(b) (b len_b bytes long), as zlib's
/// crc32_combine: crc64Combine(crc64(a, na), crc64(b, nb), nb) == crc64(a+b). O(log len_b).
std::uint64_t crc64Combine(std::uint64_t crc_a, std::uint64_t crc_b, std::size_t len_b);

/// Writes `map` to `path` atomically (atomic_file.hpp): the old file stays intact on failure.
/// \throws OutputError naming the path and the system error; OutputError if a layer name or
///         unit is longer than 1024 bytes.
void saveSnapshot(const LayeredMap& map, const std::filesystem::path& path);

/// Reads a snapshot written by saveSnapshot (any terramap version that writes format 1).
/// The whole file is read into memory first, checksums are verified before anything is
/// built, and every size is checked before allocating.
/// \throws InputError naming the file and the reason: cannot open; bad magic; unsupported
///   format version (found and supported named); "truncated at byte N, expected M"; checksum
///   mismatch (expected and found values); trailing data; absurd or inconsistent sizes with
///   the byte offset of the offending field.
LayeredMap loadSnapshot(const std::filesystem::path& path);

/// In-memory twins of the above (for sending a map over a socket, and for tests).
/// `name` is used in error messages in place of a file name.
std::vector<unsigned char> encodeSnapshot(const LayeredMap& map);
LayeredMap decodeSnapshot(const unsigned char* bytes, std::size_t n, const std::string& name);

/// What a snapshot holds, without its cell data (for `terramap export` and tooling).
struct SnapshotInfo {
  std::uint32_t version = 0;
  std::uint64_t file_bytes = 0;
  std::uint64_t checksum = 0;          ///< the file checksum (last 8 bytes)
  Geometry geometry;
  MapOptions options;
  std::vector<LayerInfo> layers;
  std::vector<long> stored_tiles;      ///< per layer, tiles present in the file
};
/// Validates the whole file (checksums included) like loadSnapshot. \throws InputError.
SnapshotInfo readSnapshotInfo(const std::filesystem::path& path);

}  // namespace terramap::io
