#include <terramap/core/memory_budget.hpp>
#include <terramap/core/error.hpp>
#include <terramap/io/atomic_file.hpp>
#include <terramap/io/snapshot.hpp>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <iomanip>
#include <memory>
#include <sstream>

namespace terramap::io {

namespace fs = std::filesystem;

// ---- CRC-64/XZ (slicing by 8) -----------------------------------------------------------------
namespace {

constexpr std::uint64_t kCrcPoly = 0xC96C5795D7870F42ULL;  // ECMA-182, reflected

struct CrcTables {
  std::uint64_t t[8][256];
  CrcTables() {
    for (int i = 0; i < 256; ++i) {
      std::uint64_t c = static_cast<std::uint64_t>(i);
      for (int k = 0; k < 8; ++k) c = (c & 1) ? (c >> 1) ^ kCrcPoly : c >> 1;
      t[0][i] = c;
    }
    // t[s][i]: CRC of byte i followed by s zero bytes, so 8 bytes can be folded in one step.
    for (int i = 0; i < 256; ++i)
      for (int s = 1; s < 8; ++s) t[s][i] = (t[s - 1][i] >> 8) ^ t[0][t[s - 1][i] & 0xFF];
  }
};

const CrcTables& crcTables() {
  static const CrcTables tables;
  return tables;
}

}  // namespace

namespace {

/// One slicing-by-8 step: 8 bytes folded into the (pre-conditioned) register c.
inline std::uint64_t crcStep8(const std::uint64_t (&T)[8][256], std::uint64_t c, const unsigned char* p) {
  // Byte-wise assembly keeps this independent of host endianness (compilers make it one load).
  std::uint64_t w = 0;
  for (int k = 7; k >= 0; --k) w = (w << 8) | p[k];
  c ^= w;
  return T[7][c & 0xFF] ^ T[6][(c >> 8) & 0xFF] ^ T[5][(c >> 16) & 0xFF] ^ T[4][(c >> 24) & 0xFF] ^
         T[3][(c >> 32) & 0xFF] ^ T[2][(c >> 40) & 0xFF] ^ T[1][(c >> 48) & 0xFF] ^ T[0][c >> 56];
}

/// The table-driven CRC (one stream).
std::uint64_t crc64Serial(const unsigned char* p, std::size_t n, std::uint64_t crc) {
  const auto& T = crcTables().t;
  std::uint64_t c = ~crc;
  for (; n >= 8; p += 8, n -= 8) c = crcStep8(T, c, p);
  while (n-- > 0) c = T[0][(c ^ *p++) & 0xFF] ^ (c >> 8);
  return ~c;
}

/// a(x) b(x) mod P(x) in the reflected representation (bit 63 is x^0), as zlib's multmodp.
std::uint64_t mulModP(std::uint64_t a, std::uint64_t b) {
  std::uint64_t m = std::uint64_t{1} << 63, p = 0;
  for (;;) {
    if (a & m) {
      p ^= b;
      if ((a & (m - 1)) == 0) break;
    }
    m >>= 1;
    b = (b & 1) ? (b >> 1) ^ kCrcPoly : b >> 1;
  }
  return p;
}

/// x^(8 n) mod P: the operator that moves a CRC past n zero bytes (squarings of x^8).
std::uint64_t xPow8nModP(std::uint64_t n) {
  std::uint64_t p = std::uint64_t{1} << 63;  // x^0
  std::uint64_t sq = std::uint64_t{1} << (63 - 8);  // x^8
  while (n) {
    if (n & 1) p = mulModP(sq, p);
    n >>= 1;
    if (n) sq = mulModP(sq, sq);
  }
  return p;
}

}  // namespace

std::uint64_t crc64Combine(std::uint64_t crc_a, std::uint64_t crc_b, std::size_t len_b) {
  return mulModP(xPow8nModP(len_b), crc_a) ^ crc_b;
}

std::uint64_t crc64(const void* data, std::size_t n, std::uint64_t crc) {
  const auto* p = static_cast<const unsigned char*>(data);
  // Long inputs (a sealed episode is read through here, hundreds of MB) run as four
  // independent streams over consecutive quarters, interleaved in one loop: a single stream is
  // bound by the latency of its table look-ups (each step needs the previous register), four
  // keep the load ports busy (`build/bin/bench_readers --benchmark_filter=BM_Crc64`, 64 MB in
  // one call against the same bytes in 32 kB calls, one stream each: 4.65 against 1.41 GB/s on
  // the Xeon VM of 2026-11-27).
  // The quarters' CRCs are then combined (crc64Combine), so the value is the serial one.
  constexpr std::size_t kStreams = 4, kMinParallel = 1 << 16;
  if (n < kMinParallel) return crc64Serial(p, n, crc);
  const std::size_t quarter = (n / kStreams) & ~std::size_t{7};
  const auto& T = crcTables().t;
  std::uint64_t c[kStreams] = {~crc, ~std::uint64_t{0}, ~std::uint64_t{0}, ~std::uint64_t{0}};
  const unsigned char* q[kStreams] = {p, p + quarter, p + 2 * quarter, p + 3 * quarter};
  for (std::size_t off = 0; off < quarter; off += 8) {
    c[0] = crcStep8(T, c[0], q[0] + off);
    c[1] = crcStep8(T, c[1], q[1] + off);
    c[2] = crcStep8(T, c[2], q[2] + off);
    c[3] = crcStep8(T, c[3], q[3] + off);
  }
  std::uint64_t out = ~c[0];
  for (std::size_t s = 1; s + 1 < kStreams; ++s) out = crc64Combine(out, ~c[s], quarter);
  // The last stream also takes the remainder after the four quarters.
  const std::size_t tail = n - kStreams * quarter;
  const std::uint64_t last = crc64Serial(q[3] + quarter, tail, ~c[3]);
  return crc64Combine(out, last, quarter + tail);
}

namespace {

// ---- format constants -------------------------------------------------------------------------
constexpr char kMagic[4] = {'T', 'M', 'A', 'P'};
constexpr std::uint32_t kFlagSparse = 1u;
constexpr int kMaxSide = 1 << 20;
constexpr std::uint32_t kMaxLayers = 1024;
constexpr std::uint32_t kMaxStringBytes = 1024;
// Bounds the tile-pointer tables a (sparse) load allocates before any data is read:
// layers x tiles x 16 bytes <= 256 MiB.
constexpr long kMaxLayerTiles = 1L << 24;
constexpr std::size_t kTrailerBytes = 8;

bool hostIsLittleEndian() {
  const std::uint32_t one = 1;
  unsigned char b;
  std::memcpy(&b, &one, 1);
  return b == 1;
}

std::string hex64(std::uint64_t v) {
  std::ostringstream os;
  os << "0x" << std::hex << std::uppercase << std::setw(16) << std::setfill('0') << v;
  return os.str();
}

// ---- little-endian field access ---------------------------------------------------------------
void putU32(unsigned char* p, std::uint32_t v) {
  for (int k = 0; k < 4; ++k) p[k] = static_cast<unsigned char>(v >> (8 * k));
}
void putU64(unsigned char* p, std::uint64_t v) {
  for (int k = 0; k < 8; ++k) p[k] = static_cast<unsigned char>(v >> (8 * k));
}
void putF64(unsigned char* p, double v) {
  std::uint64_t u;
  std::memcpy(&u, &v, 8);
  putU64(p, u);
}
std::uint32_t getU32(const unsigned char* p) {
  std::uint32_t v = 0;
  for (int k = 3; k >= 0; --k) v = (v << 8) | p[k];
  return v;
}
std::uint64_t getU64(const unsigned char* p) {
  std::uint64_t v = 0;
  for (int k = 7; k >= 0; --k) v = (v << 8) | p[k];
  return v;
}
double getF64(const unsigned char* p) {
  const std::uint64_t u = getU64(p);
  double v;
  std::memcpy(&v, &u, 8);
  return v;
}
std::int32_t getI32(const unsigned char* p) {
  const std::uint32_t u = getU32(p);
  std::int32_t v;
  std::memcpy(&v, &u, 4);
  return v;
}
std::uint32_t floatBits(float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, 4);
  return u;
}
float bitsFloat(std::uint32_t u) {
  float f;
  std::memcpy(&f, &u, 4);
  return f;
}

/// Visits logical cells (li, c0 .. c0+n-1) as runs that are contiguous inside one buffer tile:
/// fn(tile_data_or_null, offset_in_tile, count). Handles the ring-buffer wrap.
template <class F>
void forEachRun(const LayeredMap& m, LayerId id, int li, int c0, int n, F&& fn) {
  const int R = m.geometry().size().x(), C = m.geometry().size().y(), T = m.tileSize();
  const Index start = m.startIndex();
  const int br = (li + start.x()) % R;
  int j = c0;
  const int end = c0 + n;
  while (j < end) {
    const int bc = (j + start.y()) % C;
    int run = std::min(end - j, C - bc);           // stop at the ring wrap
    run = std::min(run, (bc / T + 1) * T - bc);    // and at the tile edge
    const int t = m.tileOfBuffer(br, bc);
    const CellRect rect = m.tileRect(t);
    const float* d = m.tileData(id, t);
    fn(d, static_cast<std::size_t>((br - rect.r0) * T + (bc - rect.c0)), run);
    j += run;
  }
}

bool logicalTileTouchesAllocated(const LayeredMap& m, LayerId id, const CellRect& r) {
  bool any = false;
  for (int li = r.r0; li < r.r0 + r.rows && !any; ++li)
    forEachRun(m, id, li, r.c0, r.cols, [&](const float* d, std::size_t, int) { any = any || d; });
  return any;
}

// ---- encoder ----------------------------------------------------------------------------------
using Sink = std::function<void(const void*, std::size_t)>;

class Encoder {
 public:
  explicit Encoder(Sink sink) : sink_(std::move(sink)) {}
  void bytes(const void* p, std::size_t n) {
    crc_ = crc64(p, n, crc_);
    sink_(p, n);
    offset_ += n;
  }
  void u32(std::uint32_t v) {
    unsigned char b[4];
    putU32(b, v);
    bytes(b, 4);
  }
  void str(const std::string& s) {
    u32(static_cast<std::uint32_t>(s.size()));
    bytes(s.data(), s.size());
  }
  /// Floats verbatim (bit patterns, NaN payloads kept), little-endian.
  void floats(const float* p, std::size_t n) {
    if (little_) {
      bytes(p, n * 4);
      return;
    }
    scratch_.resize(n * 4);
    for (std::size_t i = 0; i < n; ++i) putU32(&scratch_[i * 4], floatBits(p[i]));
    bytes(scratch_.data(), scratch_.size());
  }
  std::uint64_t crc() const { return crc_; }
  std::uint64_t offset() const { return offset_; }

 private:
  Sink sink_;
  std::uint64_t crc_ = 0;
  std::uint64_t offset_ = 0;
  bool little_ = hostIsLittleEndian();
  std::vector<unsigned char> scratch_;
};

void encode(const LayeredMap& map, const Sink& sink, const std::string& name_for_errors) {
  const Geometry& g = map.geometry();
  const int T = map.tileSize();
  const int R = g.size().x(), C = g.size().y();
  const int tile_cols = (C + T - 1) / T;
  const int tile_count = ((R + T - 1) / T) * tile_cols;
  const bool sparse = map.options().sparse;
  if (R > kMaxSide || C > kMaxSide || map.layerCount() > static_cast<int>(kMaxLayers))
    throw OutputError("cannot write '" + name_for_errors + "': map of " + std::to_string(R) + "x" +
                      std::to_string(C) + " cells and " + std::to_string(map.layerCount()) +
                      " layers exceeds the snapshot format's limits (2^20 cells a side, 1024 layers)");

  // Plan first: the header carries the total length, so it must be known before writing.
  std::vector<std::vector<int>> stored(static_cast<std::size_t>(map.layerCount()));
  std::uint64_t length = kSnapshotHeaderBytes + kTrailerBytes;
  for (LayerId id = 0; id < map.layerCount(); ++id) {
    const LayerInfo& info = map.layerInfo(id);
    for (const std::string* s : {&info.name, &info.unit})
      if (s->size() > kMaxStringBytes)
        throw OutputError("cannot write '" + name_for_errors + "': layer '" + info.name.substr(0, 64) +
                          "' has a name or unit longer than 1024 bytes");
    length += 16 + info.name.size() + info.unit.size();
    auto& tiles = stored[static_cast<std::size_t>(id)];
    for (int k = 0; k < tile_count; ++k) {
      const CellRect r = LayeredMap::tileRectOf(g.size(), T, k);
      if (sparse && !logicalTileTouchesAllocated(map, id, r)) continue;
      tiles.push_back(k);
      length += 4 + static_cast<std::uint64_t>(r.cells()) * 4;
    }
  }

  Encoder enc(sink);
  unsigned char h[kSnapshotHeaderBytes] = {};
  std::memcpy(h, kMagic, 4);
  putU32(h + 4, kSnapshotFormatVersion);
  putU64(h + 8, length);
  putF64(h + 16, g.resolution());
  putU32(h + 24, static_cast<std::uint32_t>(R));
  putU32(h + 28, static_cast<std::uint32_t>(C));
  putF64(h + 32, g.center().x());
  putF64(h + 40, g.center().y());
  putU32(h + 48, static_cast<std::uint32_t>(T));
  putU32(h + 52, sparse ? kFlagSparse : 0u);
  putU32(h + 56, static_cast<std::uint32_t>(map.layerCount()));
  putU32(h + 60, 0);
  putU64(h + 64, crc64(h, 64));
  enc.bytes(h, sizeof h);

  std::vector<float> row(static_cast<std::size_t>(T));
  for (LayerId id = 0; id < map.layerCount(); ++id) {
    const LayerInfo& info = map.layerInfo(id);
    enc.str(info.name);
    enc.str(info.unit);
    enc.u32(floatBits(info.fill));
    const auto& tiles = stored[static_cast<std::size_t>(id)];
    enc.u32(static_cast<std::uint32_t>(tiles.size()));
    for (const int k : tiles) {
      enc.u32(static_cast<std::uint32_t>(k));
      const CellRect r = LayeredMap::tileRectOf(g.size(), T, k);
      for (int li = r.r0; li < r.r0 + r.rows; ++li) {
        float* out = row.data();
        forEachRun(map, id, li, r.c0, r.cols, [&](const float* d, std::size_t off, int n) {
          if (d) {
            std::memcpy(out, d + off, static_cast<std::size_t>(n) * 4);
          } else {
            const std::uint32_t bits = floatBits(info.fill);
            for (int q = 0; q < n; ++q) std::memcpy(out + q, &bits, 4);
          }
          out += n;
        });
        enc.floats(row.data(), static_cast<std::size_t>(r.cols));
      }
    }
  }
  unsigned char trailer[8];
  putU64(trailer, enc.crc());
  TERRAMAP_CHECK(enc.offset() + 8 == length, "snapshot length plan and bytes written disagree");
  sink(trailer, 8);
}

// ---- decoder ----------------------------------------------------------------------------------
class Decoder {
 public:
  Decoder(const unsigned char* p, std::size_t n, const std::string& name) : p_(p), name_(name) { (void)n; }

  [[noreturn]] void fail(std::size_t offset, const std::string& what) const {
    std::ostringstream os;
    os << "snapshot '" << name_ << "': byte " << offset << ": " << what;
    throw InputError(os.str());
  }
  void need(std::size_t count, const char* what) const {
    if (count > body_end_ || pos_ > body_end_ - count)
      fail(pos_, std::string("record runs past the end of the data while reading ") + what);
  }
  std::uint32_t u32(const char* what) {
    need(4, what);
    const std::uint32_t v = getU32(p_ + pos_);
    pos_ += 4;
    return v;
  }
  std::string str(std::uint32_t max, bool allow_empty, const char* what) {
    const std::size_t at = pos_;
    const std::uint32_t len = u32(what);
    if (len > max || (!allow_empty && len == 0))
      fail(at, std::string(what) + " length " + std::to_string(len) + " is outside [" +
                   (allow_empty ? "0" : "1") + ", " + std::to_string(max) + "]");
    need(len, what);
    std::string s(reinterpret_cast<const char*>(p_ + pos_), len);
    pos_ += len;
    return s;
  }
  void floats(float* out, std::size_t n) {
    need(n * 4, "tile cells");
    if (little_) {
      std::memcpy(out, p_ + pos_, n * 4);
    } else {
      for (std::size_t i = 0; i < n; ++i) out[i] = bitsFloat(getU32(p_ + pos_ + 4 * i));
    }
    pos_ += n * 4;
  }
  void skip(std::size_t count, const char* what) {
    need(count, what);
    pos_ += count;
  }
  std::size_t pos() const { return pos_; }
  void setBodyEnd(std::size_t e) { body_end_ = e; }
  std::size_t bodyEnd() const { return body_end_; }

 private:
  const unsigned char* p_;
  std::string name_;
  std::size_t pos_ = kSnapshotHeaderBytes;
  std::size_t body_end_ = 0;
  bool little_ = hostIsLittleEndian();
};

struct Decoded {
  SnapshotInfo info;
  std::unique_ptr<LayeredMap> map;  // null when only the info was asked for
};

[[noreturn]] void refuse(const std::string& name, const std::string& what) {
  throw InputError("snapshot '" + name + "': " + what);
}

[[noreturn]] void refuseTruncated(const std::string& name, std::size_t n, std::uint64_t expected, bool at_least) {
  std::ostringstream os;
  os << "snapshot '" << name << "' is truncated at byte " << n << ", expected " << (at_least ? "at least " : "")
     << expected << " bytes";
  throw InputError(os.str());
}

/// Magic and version: what kind of file is this at all? Returns the version.
std::uint32_t checkMagicAndVersion(const unsigned char* p, std::size_t n, const std::string& name) {
  if (n < 4 || std::memcmp(p, kMagic, 4) != 0) {
    if (n == 0 || (n < 4 && std::memcmp(p, kMagic, n) == 0)) refuseTruncated(name, n, kSnapshotHeaderBytes, true);
    std::ostringstream os;
    os << "'" << name << "' is not a terramap snapshot: bad magic";
    for (std::size_t i = 0; i < std::min<std::size_t>(n, 4); ++i)
      os << (i ? " " : " ") << std::hex << std::setw(2) << std::setfill('0') << static_cast<int>(p[i]);
    os << " at byte 0 (expected \"TMAP\" = 54 4d 41 50)";
    throw InputError(os.str());
  }
  if (n < 8) refuseTruncated(name, n, kSnapshotHeaderBytes, true);
  const std::uint32_t version = getU32(p + 4);
  if (version != kSnapshotFormatVersion) {
    std::string what = "unsupported snapshot format version " + std::to_string(version) + " (this build reads version " +
                       std::to_string(kSnapshotFormatVersion) + ")";
    // A flipped bit in the version field looks like a version this build does not know. If the
    // version-1 header checksum does not hold either, say so: it is more likely damage.
    if (n >= kSnapshotHeaderBytes && getU64(p + 64) != crc64(p, 64))
      what += ", or a damaged header: header checksum mismatch: expected " + hex64(getU64(p + 64)) +
              " (stored at byte 64), found " + hex64(crc64(p, 64));
    refuse(name, what);
  }
  if (n < kSnapshotHeaderBytes) refuseTruncated(name, n, kSnapshotHeaderBytes, true);
  return version;
}

/// Header checksum, then the length it declares, then the file checksum: nothing after this
/// reads a byte that is not covered by a checksum that holds. Returns the file checksum.
std::uint64_t checkLengthAndChecksums(const unsigned char* p, std::size_t n, const std::string& name) {
  const std::uint64_t header_stored = getU64(p + 64), header_found = crc64(p, 64);
  if (header_stored != header_found)
    refuse(name, "header checksum mismatch (bytes 0-63): expected " + hex64(header_stored) +
                     " (stored at byte 64), found " + hex64(header_found) + "; the file is damaged");
  const std::uint64_t length = getU64(p + 8);
  if (length < kSnapshotHeaderBytes + kTrailerBytes)
    refuse(name, "byte 8: declared file length " + std::to_string(length) + " is smaller than the " +
                     std::to_string(kSnapshotHeaderBytes + kTrailerBytes) + "-byte minimum");
  if (n < length) refuseTruncated(name, n, length, false);
  if (n > length)
    refuse(name, "has " + std::to_string(n) + " bytes, expected " + std::to_string(length) +
                     ": trailing data after byte " + std::to_string(length));
  const std::uint64_t file_stored = getU64(p + n - 8), file_found = crc64(p, n - 8);
  if (file_stored != file_found)
    refuse(name, "checksum mismatch (bytes 0-" + std::to_string(n - 9) + "): expected " + hex64(file_stored) +
                     " (stored at byte " + std::to_string(n - 8) + "), found " + hex64(file_found) +
                     "; the file is damaged");
  return file_stored;
}

/// The map's shape from the header, every field range-checked before anything is allocated.
struct MapShape {
  Geometry geometry;
  MapOptions options;
  std::uint32_t layers = 0;
  long tile_count = 0;
};

MapShape checkGeometry(const Decoder& dec, const unsigned char* p, std::uint64_t length) {
  const double res = getF64(p + 16);
  const std::int32_t R = getI32(p + 24), C = getI32(p + 28);
  const double cx = getF64(p + 32), cy = getF64(p + 40);
  const std::int32_t T = getI32(p + 48);
  const std::uint32_t flags = getU32(p + 52), layers = getU32(p + 56), reserved = getU32(p + 60);
  if (!(res > 0.0) || !std::isfinite(res)) dec.fail(16, "resolution " + std::to_string(res) + " is not a finite number > 0");
  if (R < 1 || R > kMaxSide) dec.fail(24, "row count " + std::to_string(R) + " is outside [1, 2^20]");
  if (C < 1 || C > kMaxSide) dec.fail(28, "column count " + std::to_string(C) + " is outside [1, 2^20]");
  if (!std::isfinite(cx)) dec.fail(32, "centre x is not finite");
  if (!std::isfinite(cy)) dec.fail(40, "centre y is not finite");
  if (T < 8 || T > 1024) dec.fail(48, "tile size " + std::to_string(T) + " is outside [8, 1024]");
  if ((flags & ~kFlagSparse) != 0) dec.fail(52, "unknown flag bits " + hex64(flags & ~kFlagSparse));
  if (layers > kMaxLayers) dec.fail(56, "layer count " + std::to_string(layers) + " exceeds 1024");
  if (reserved != 0) dec.fail(60, "reserved field is " + std::to_string(reserved) + ", expected 0");
  const bool sparse = (flags & kFlagSparse) != 0;
  const int tile_cols = (C + T - 1) / T;
  const long tile_count = static_cast<long>((R + T - 1) / T) * tile_cols;
  if (tile_count * static_cast<long>(std::max<std::uint32_t>(layers, 1)) > kMaxLayerTiles)
    dec.fail(24, std::to_string(layers) + " layers of " + std::to_string(tile_count) +
                     " tiles exceed the loader's limit of 2^24 layer tiles");
  // A dense map stores every cell, so its data must be in the file (checked up front so a
  // forged header cannot make us allocate more than the file could describe).
  const std::uint64_t cells = static_cast<std::uint64_t>(R) * static_cast<std::uint64_t>(C);
  if (!sparse && layers > 0 && saturatingProduct({cells, 4, layers}) > length)
    dec.fail(24, "dense map of " + std::to_string(R) + "x" + std::to_string(C) + " cells and " +
                     std::to_string(layers) + " layers needs more data than the file's " + std::to_string(length) +
                     " bytes");
  MapShape shape;
  shape.geometry = Geometry(res, Size(R, C), Position(cx, cy));
  shape.options.tile_size = T;
  shape.options.sparse = sparse;
  shape.layers = layers;
  shape.tile_count = tile_count;
  return shape;
}

/// One layer record: name, unit, fill, then its tiles in increasing index order (into `map`
/// when given, else only checked and skipped). Returns the number of tiles stored.
long decodeLayer(Decoder& dec, const MapShape& shape, SnapshotInfo& info, LayeredMap* map) {
  const std::size_t record_at = dec.pos();
  LayerInfo li;
  li.name = dec.str(kMaxStringBytes, false, "layer name");
  li.unit = dec.str(kMaxStringBytes, true, "layer unit");
  li.fill = bitsFloat(dec.u32("fill value"));
  for (const auto& prev : info.layers)
    if (prev.name == li.name) dec.fail(record_at, "layer '" + li.name + "' appears twice");
  const long tile_count = shape.tile_count;
  const std::size_t count_at = dec.pos();
  const std::uint32_t k_count = dec.u32("tile count");
  if (k_count > static_cast<std::uint64_t>(tile_count))
    dec.fail(count_at, "layer '" + li.name + "' stores " + std::to_string(k_count) + " tiles, the map has " +
                           std::to_string(tile_count));
  if (!shape.options.sparse && k_count != static_cast<std::uint64_t>(tile_count))
    dec.fail(count_at, "dense layer '" + li.name + "' stores " + std::to_string(k_count) + " of " +
                           std::to_string(tile_count) + " tiles");
  const int T = shape.options.tile_size;
  LayerId id = -1;
  if (map) id = map->addLayer(li.name, li.unit, li.fill);
  long prev_k = -1;
  for (std::uint32_t q = 0; q < k_count; ++q) {
    const std::size_t tile_at = dec.pos();
    const std::uint32_t k = dec.u32("tile index");
    if (static_cast<long>(k) >= tile_count || static_cast<long>(k) <= prev_k)
      dec.fail(tile_at, "tile index " + std::to_string(k) + " of layer '" + li.name +
                            "' is out of range or not increasing (previous " + std::to_string(prev_k) +
                            ", tile count " + std::to_string(tile_count) + ")");
    prev_k = k;
    const CellRect r = LayeredMap::tileRectOf(shape.geometry.size(), T, static_cast<int>(k));
    if (!map) {
      dec.skip(static_cast<std::size_t>(r.cells()) * 4, "tile cells");
      continue;
    }
    // A fresh map has start index 0, so logical tile k *is* buffer tile k.
    float* d = map->mutableTileData(id, static_cast<int>(k));
    for (int rr = 0; rr < r.rows; ++rr) dec.floats(d + static_cast<std::size_t>(rr) * T, static_cast<std::size_t>(r.cols));
  }
  info.layers.push_back(li);
  return static_cast<long>(k_count);
}

Decoded decode(const unsigned char* p, std::size_t n, const std::string& name, bool build_map) {
  const std::uint32_t version = checkMagicAndVersion(p, n, name);
  const std::uint64_t checksum = checkLengthAndChecksums(p, n, name);
  const std::uint64_t length = n;  // checkLengthAndChecksums: the declared length is the size
  Decoder dec(p, n, name);
  dec.setBodyEnd(n - 8);
  const MapShape shape = checkGeometry(dec, p, length);
  Decoded out;
  SnapshotInfo& info = out.info;
  info.version = version;
  info.file_bytes = length;
  info.checksum = checksum;
  info.geometry = shape.geometry;
  info.options = shape.options;
  if (build_map) out.map = std::make_unique<LayeredMap>(info.geometry, info.options);
  for (std::uint32_t l = 0; l < shape.layers; ++l)
    info.stored_tiles.push_back(decodeLayer(dec, shape, info, out.map.get()));
  if (dec.pos() != dec.bodyEnd())
    dec.fail(dec.pos(), std::to_string(dec.bodyEnd() - dec.pos()) + " unexpected bytes after the last layer record");
  return out;
}

std::vector<unsigned char> readWholeFile(const fs::path& path) {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) {
    const int e = errno;
    throw InputError("cannot open snapshot '" + path.string() + "': " + std::strerror(e));
  }
  std::error_code ec;
  const auto size = fs::file_size(path, ec);
  std::vector<unsigned char> bytes;
  // The decoded map holds at most what the file describes (dense layers are checked against the
  // file's length, sparse tiles are stored cell by cell): the file and the map, twice its size.
  if (!ec) requireInputBudget(saturatingProduct({size, 2}), "snapshot '" + path.string() + "'", "the file and the map decoded from it");
  if (!ec) bytes.reserve(static_cast<std::size_t>(size));
  unsigned char buf[1 << 16];
  for (;;) {
    const std::size_t got = std::fread(buf, 1, sizeof buf, f.get());
    bytes.insert(bytes.end(), buf, buf + got);
    if (got < sizeof buf) {
      if (std::ferror(f.get())) {
        const int e = errno;
        throw InputError("cannot read snapshot '" + path.string() + "' at byte " + std::to_string(bytes.size()) +
                         ": " + std::strerror(e));
      }
      break;
    }
  }
  return bytes;
}

}  // namespace

std::vector<unsigned char> encodeSnapshot(const LayeredMap& map) {
  std::vector<unsigned char> out;
  encode(
      map,
      [&](const void* p, std::size_t n) {
        const auto* b = static_cast<const unsigned char*>(p);
        out.insert(out.end(), b, b + n);
      },
      "<memory>");
  return out;
}

LayeredMap decodeSnapshot(const unsigned char* bytes, std::size_t n, const std::string& name) {
  Decoded d = decode(bytes, n, name, true);
  return std::move(*d.map);
}

void saveSnapshot(const LayeredMap& map, const fs::path& path) {
  AtomicFile file(path);
  encode(map, [&](const void* p, std::size_t n) { file.write(p, n); }, path.string());
  file.commit();
}

LayeredMap loadSnapshot(const fs::path& path) {
  const std::vector<unsigned char> bytes = readWholeFile(path);
  return decodeSnapshot(bytes.data(), bytes.size(), path.string());
}

SnapshotInfo readSnapshotInfo(const fs::path& path) {
  const std::vector<unsigned char> bytes = readWholeFile(path);
  return decode(bytes.data(), bytes.size(), path.string(), false).info;
}

}  // namespace terramap::io
