#include "scratch_dir.hpp"
#include <terramap/core/error.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/io/snapshot.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <unistd.h>

namespace fs = std::filesystem;
using namespace terramap;
namespace tio = terramap::io;

namespace {

float fromBits(std::uint32_t u) {
  float f;
  std::memcpy(&f, &u, 4);
  return f;
}
std::uint32_t bitsOf(float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, 4);
  return u;
}

/// Values that a careless encoder would change: NaNs with payloads (quiet and signalling,
/// both signs), -0, infinities, subnormals, plus ordinary numbers.
float trickyValue(std::mt19937& rng) {
  static const std::uint32_t kSpecial[] = {0x7FC12345u, 0xFFC00001u, 0x7F800001u, 0x7FA0BEEFu, 0x80000000u,
                                           0x7F800000u, 0xFF800000u, 0x00000001u, 0x807FFFFFu};
  const unsigned pick = rng() % 24;
  if (pick < 9) return fromBits(kSpecial[pick]);
  return std::uniform_real_distribution<float>(-50.f, 50.f)(rng);
}

/// Bitwise equality of two maps through the public, logical API.
void expectSameMap(const LayeredMap& a, const LayeredMap& b) {
  ASSERT_EQ(a.geometry(), b.geometry());
  EXPECT_EQ(std::memcmp(&a.geometry().center(), &b.geometry().center(), sizeof(Position)), 0);
  EXPECT_EQ(a.options().tile_size, b.options().tile_size);
  EXPECT_EQ(a.options().sparse, b.options().sparse);
  ASSERT_EQ(a.layerCount(), b.layerCount());
  for (LayerId id = 0; id < a.layerCount(); ++id) {
    EXPECT_EQ(a.layerInfo(id).name, b.layerInfo(id).name);
    EXPECT_EQ(a.layerInfo(id).unit, b.layerInfo(id).unit);
    EXPECT_EQ(bitsOf(a.layerInfo(id).fill), bitsOf(b.layerInfo(id).fill));
    const Eigen::MatrixXf ma = a.toMatrix(id), mb = b.toMatrix(id);
    ASSERT_EQ(ma.size(), mb.size());
    EXPECT_EQ(0, std::memcmp(ma.data(), mb.data(), sizeof(float) * static_cast<std::size_t>(ma.size())))
        << "layer " << a.layerInfo(id).name;
  }
}

/// 37 x 53 cells with 16-cell tiles: partial edge tiles in both directions.
LayeredMap makeDenseMap(std::uint32_t seed) {
  LayeredMap m(Geometry(0.05, Size(37, 53), Position(12.34, -5.678)), MapOptions{16, false});
  const LayerId e = m.addLayer("elevation", "m");
  const LayerId c = m.addLayer("count", "count", 0.f);
  m.addLayer("weird_fill", "1", fromBits(0x7FC0ABCDu));
  std::mt19937 rng(seed);
  Eigen::MatrixXf ev(37, 53), cv(37, 53);
  for (int i = 0; i < 37; ++i)
    for (int j = 0; j < 53; ++j) {
      ev(i, j) = trickyValue(rng);
      cv(i, j) = static_cast<float>(rng() % 100);
    }
  m.fromMatrix(e, ev);
  m.fromMatrix(c, cv);
  return m;
}

class SnapshotTest : public ScratchDirTest {
 protected:
  SnapshotTest() : ScratchDirTest("snapshot_") {}
  static std::vector<unsigned char> slurp(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::vector<unsigned char>(std::istreambuf_iterator<char>(in), {});
  }
  static void spit(const fs::path& p, const std::vector<unsigned char>& b) {
    std::ofstream out(p, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
  }
  /// Expects decode to throw InputError and returns its message.
  static std::string decodeError(const std::vector<unsigned char>& b, const std::string& name = "mem.tmap") {
    try {
      tio::decodeSnapshot(b.data(), b.size(), name);
    } catch (const InputError& e) {
      return e.what();
    }
    ADD_FAILURE() << "decode accepted a bad snapshot";
    return {};
  }
};

std::uint32_t rd32(const std::vector<unsigned char>& b, std::size_t at) {
  return static_cast<std::uint32_t>(b[at]) | static_cast<std::uint32_t>(b[at + 1]) << 8 |
         static_cast<std::uint32_t>(b[at + 2]) << 16 | static_cast<std::uint32_t>(b[at + 3]) << 24;
}
std::uint64_t rd64(const std::vector<unsigned char>& b, std::size_t at) {
  return static_cast<std::uint64_t>(rd32(b, at)) | static_cast<std::uint64_t>(rd32(b, at + 4)) << 32;
}
void wr32(std::vector<unsigned char>& b, std::size_t at, std::uint32_t v) {
  for (int k = 0; k < 4; ++k) b[at + k] = static_cast<unsigned char>(v >> (8 * k));
}
void wr64(std::vector<unsigned char>& b, std::size_t at, std::uint64_t v) {
  for (int k = 0; k < 8; ++k) b[at + k] = static_cast<unsigned char>(v >> (8 * k));
}
/// Re-seals a hand-edited file: both checksums recomputed, so only the semantic checks remain.
void reseal(std::vector<unsigned char>& b) {
  wr64(b, 64, tio::crc64(b.data(), 64));
  wr64(b, b.size() - 8, tio::crc64(b.data(), b.size() - 8));
}

// ---- checksum ---------------------------------------------------------------------------------

TEST(Crc64, MatchesPublishedCheckValueAndContinues) {
  const std::string s = "123456789";
  EXPECT_EQ(tio::crc64(s.data(), s.size()), 0x995DC9BBDF1939FAULL);  // CRC-64/XZ catalogue value
  EXPECT_EQ(tio::crc64(nullptr, 0), 0u);
  // Continuation across every split point, including splits inside the 8-byte fast path.
  std::string long_text;
  for (int i = 0; i < 100; ++i) long_text += static_cast<char>('a' + i % 26);
  const std::uint64_t whole = tio::crc64(long_text.data(), long_text.size());
  for (std::size_t cut = 0; cut <= long_text.size(); ++cut)
    EXPECT_EQ(tio::crc64(long_text.data() + cut, long_text.size() - cut, tio::crc64(long_text.data(), cut)), whole);
}

TEST(Crc64, CombineJoinsTwoCrcs) {
  const std::string a = "1234", b = "56789";
  EXPECT_EQ(tio::crc64Combine(tio::crc64(a.data(), a.size()), tio::crc64(b.data(), b.size()), b.size()),
            0x995DC9BBDF1939FAULL);
  EXPECT_EQ(tio::crc64Combine(tio::crc64(a.data(), a.size()), 0, 0), tio::crc64(a.data(), a.size()));
}

TEST(Crc64, LongInputsInInterleavedStreamsEqualTheByteSerialCrc) {
  // Inputs of 64 kB and more run as four interleaved streams combined at the end: against the
  // same bytes fed in 4 kB pieces (each below the threshold, so one serial stream), for lengths
  // around the quarters' 8-byte rounding and start addresses off 8-byte alignment.
  std::vector<unsigned char> buf((1 << 18) + 64);
  std::uint64_t x = 0x9e3779b97f4a7c15ULL;
  for (unsigned char& c : buf) {
    x ^= x << 13, x ^= x >> 7, x ^= x << 17;
    c = static_cast<unsigned char>(x);
  }
  for (const std::size_t n : {std::size_t{1} << 16, (std::size_t{1} << 16) + 1, (std::size_t{1} << 16) + 31,
                              std::size_t{200001}, std::size_t{1} << 18})
    for (const std::size_t start : {std::size_t{0}, std::size_t{3}, std::size_t{7}}) {
      const unsigned char* p = buf.data() + start;
      for (const std::uint64_t seed : {std::uint64_t{0}, std::uint64_t{0x0123456789abcdefULL}}) {
        std::uint64_t serial = seed;
        for (std::size_t at = 0; at < n; at += 4096) serial = tio::crc64(p + at, std::min<std::size_t>(4096, n - at), serial);
        EXPECT_EQ(tio::crc64(p, n, seed), serial) << n << " bytes from " << start << ", seed " << seed;
      }
    }
}

// ---- round trips ------------------------------------------------------------------------------

TEST_F(SnapshotTest, DenseRoundTripIsBitExact) {
  const LayeredMap m = makeDenseMap(1);
  const fs::path p = dir_ / "dense.tmap";
  tio::saveSnapshot(m, p);
  const LayeredMap back = tio::loadSnapshot(p);
  expectSameMap(m, back);
  EXPECT_EQ(back.allocatedTiles(), m.allocatedTiles());
  // The NaN payloads made it through (not just "some NaN").
  const LayerId e = back.layerId("elevation");
  const Eigen::MatrixXf mm = m.toMatrix(e);
  int payload_nans = 0;
  for (int k = 0; k < mm.size(); ++k) payload_nans += bitsOf(mm.data()[k]) == 0x7FC12345u;
  EXPECT_GT(payload_nans, 0);
}

TEST_F(SnapshotTest, SaveIsDeterministicAndMatchesEncode) {
  const LayeredMap m = makeDenseMap(2);
  const fs::path p = dir_ / "a.tmap";
  tio::saveSnapshot(m, p);
  EXPECT_EQ(slurp(p), tio::encodeSnapshot(m));
  EXPECT_EQ(tio::encodeSnapshot(m), tio::encodeSnapshot(m.snapshot()));
}

TEST_F(SnapshotTest, HeaderFieldsSitAtTheDocumentedOffsets) {
  const LayeredMap m = makeDenseMap(3);
  const std::vector<unsigned char> b = tio::encodeSnapshot(m);
  ASSERT_GE(b.size(), 80u);
  EXPECT_EQ(std::string(b.begin(), b.begin() + 4), "TMAP");
  EXPECT_EQ(rd32(b, 4), 1u);
  EXPECT_EQ(rd64(b, 8), b.size());
  double res, cx, cy;
  const std::uint64_t r64 = rd64(b, 16), x64 = rd64(b, 32), y64 = rd64(b, 40);
  std::memcpy(&res, &r64, 8);
  std::memcpy(&cx, &x64, 8);
  std::memcpy(&cy, &y64, 8);
  EXPECT_EQ(res, 0.05);
  EXPECT_EQ(rd32(b, 24), 37u);
  EXPECT_EQ(rd32(b, 28), 53u);
  EXPECT_EQ(cx, 12.34);
  EXPECT_EQ(cy, -5.678);
  EXPECT_EQ(rd32(b, 48), 16u);
  EXPECT_EQ(rd32(b, 52), 0u);  // dense
  EXPECT_EQ(rd32(b, 56), 3u);
  EXPECT_EQ(rd64(b, 64), tio::crc64(b.data(), 64));
  EXPECT_EQ(rd64(b, b.size() - 8), tio::crc64(b.data(), b.size() - 8));
  // First layer record: "elevation", "m", NaN fill, all 3 x 4 tiles, tile 0 first.
  EXPECT_EQ(rd32(b, 72), 9u);
  EXPECT_EQ(std::string(b.begin() + 76, b.begin() + 85), "elevation");
  EXPECT_EQ(rd32(b, 85), 1u);
  EXPECT_EQ(b[89], 'm');
  EXPECT_EQ(rd32(b, 90), bitsOf(std::numeric_limits<float>::quiet_NaN()));
  EXPECT_EQ(rd32(b, 94), 12u);
  EXPECT_EQ(rd32(b, 98), 0u);
  // Cell (0, 0) then (0, 1) of the first tile, little-endian float32.
  const Eigen::MatrixXf ev = m.toMatrix(0);
  EXPECT_EQ(rd32(b, 102), bitsOf(ev(0, 0)));
  EXPECT_EQ(rd32(b, 106), bitsOf(ev(0, 1)));
  // Total size: header + 3 records (names, units, fill, count) + 12 tile indices each + 3 x cells + crc.
  const std::size_t expect = 72 + (16 + 9 + 1) + (16 + 5 + 5) + (16 + 10 + 1) + 3 * 12 * 4 + 3 * 37 * 53 * 4 + 8;
  EXPECT_EQ(b.size(), expect);
}

TEST_F(SnapshotTest, SparseRoundTripKeepsTheAllocatedTiles) {
  LayeredMap m(Geometry(0.1, Size(100, 70), Position(3.0, 4.0)), MapOptions{16, true});
  const LayerId e = m.addLayer("elevation", "m");
  const LayerId v = m.addLayer("variance", "m^2", 1.0f);
  m.set(e, Index(0, 0), 1.5f);
  m.set(e, Index(99, 69), fromBits(0x7FC00042u));
  m.set(e, Index(50, 33), -0.0f);
  m.set(v, Index(17, 17), 0.25f);
  ASSERT_EQ(m.allocatedTiles(), 4);
  const fs::path p = dir_ / "sparse.tmap";
  tio::saveSnapshot(m, p);
  const LayeredMap back = tio::loadSnapshot(p);
  expectSameMap(m, back);
  EXPECT_EQ(back.allocatedTiles(), 4);
  for (LayerId id : {e, v})
    for (int t = 0; t < m.tileCount(); ++t) EXPECT_EQ(back.tileAllocated(id, t), m.tileAllocated(id, t)) << t;
  // Only 4 tiles of data are stored: far smaller than the dense 2 x 100 x 70 floats.
  EXPECT_LT(fs::file_size(p), 4u * 16 * 16 * 4 + 200);
  const tio::SnapshotInfo info = tio::readSnapshotInfo(p);
  EXPECT_EQ(info.stored_tiles, (std::vector<long>{3, 1}));
  EXPECT_TRUE(info.options.sparse);
  EXPECT_EQ(info.file_bytes, fs::file_size(p));
}

TEST_F(SnapshotTest, MovedDenseMapRoundTripsInLogicalOrder) {
  LayeredMap m = makeDenseMap(4);
  m.move(m.geometry().center() + Position(5 * 0.05, -7 * 0.05));
  m.move(m.geometry().center() + Position(-2 * 0.05, 20 * 0.05));
  ASSERT_FALSE((m.startIndex() == 0).all());
  std::mt19937 rng(9);
  for (int k = 0; k < 300; ++k) m.set(0, Index(static_cast<int>(rng() % 37), static_cast<int>(rng() % 53)), trickyValue(rng));
  const fs::path p = dir_ / "moved.tmap";
  tio::saveSnapshot(m, p);
  const LayeredMap back = tio::loadSnapshot(p);
  expectSameMap(m, back);
  EXPECT_TRUE((back.startIndex() == 0).all());  // documented: the ring start is not stored
  // Positions still find the same values (geometry and logical order agree).
  const Position q = m.geometry().positionOf(Index(11, 41));
  const auto idx = back.geometry().indexAt(q);
  ASSERT_TRUE(idx.has_value());
  EXPECT_EQ(bitsOf(back.at(0, *idx)), bitsOf(m.at(0, Index(11, 41))));
}

TEST_F(SnapshotTest, MovedSparseMapRoundTrips) {
  LayeredMap m(Geometry(0.2, Size(64, 48), Position(0, 0)), MapOptions{16, true});
  const LayerId e = m.addLayer("elevation", "m");
  for (int i = 0; i < 64; i += 7) m.set(e, Index(i, (i * 5) % 48), static_cast<float>(i) * 0.5f);
  m.move(Position(0.2 * 9, -0.2 * 13));
  for (int i = 0; i < 64; i += 5) m.set(e, Index(i, (i * 3) % 48), fromBits(0xFFC01234u));
  ASSERT_FALSE((m.startIndex() == 0).all());
  const LayeredMap back = tio::decodeSnapshot(tio::encodeSnapshot(m).data(), tio::encodeSnapshot(m).size(), "mem");
  expectSameMap(m, back);
  EXPECT_LE(back.allocatedTiles(), back.tileCount());
}

TEST_F(SnapshotTest, MapWithoutLayersAndMinimalMap) {
  const LayeredMap empty(Geometry(1.0, Size(1, 1)), MapOptions{8, false});
  const auto b = tio::encodeSnapshot(empty);
  EXPECT_EQ(b.size(), 80u);
  expectSameMap(empty, tio::decodeSnapshot(b.data(), b.size(), "empty"));
}

// ---- refusals ---------------------------------------------------------------------------------

TEST_F(SnapshotTest, RefusesBadMagic) {
  auto b = tio::encodeSnapshot(makeDenseMap(5));
  b[1] = 'X';
  const std::string msg = decodeError(b, "bad.tmap");
  EXPECT_NE(msg.find("not a terramap snapshot"), std::string::npos) << msg;
  EXPECT_NE(msg.find("bad.tmap"), std::string::npos) << msg;
  const std::vector<unsigned char> text = {'h', 'e', 'l', 'l', 'o', '\n'};
  EXPECT_NE(decodeError(text).find("bad magic"), std::string::npos);
}

TEST_F(SnapshotTest, RefusesUnsupportedVersion) {
  auto b = tio::encodeSnapshot(makeDenseMap(5));
  wr32(b, 4, 2);
  reseal(b);
  const std::string msg = decodeError(b);
  EXPECT_NE(msg.find("unsupported snapshot format version 2"), std::string::npos) << msg;
  EXPECT_NE(msg.find("reads version 1"), std::string::npos) << msg;
  EXPECT_EQ(msg.find("damaged"), std::string::npos) << msg;  // the header checksum holds
}

TEST_F(SnapshotTest, RefusesFileTruncatedByOneByte) {
  const LayeredMap m = makeDenseMap(6);
  const fs::path p = dir_ / "cut.tmap";
  tio::saveSnapshot(m, p);
  auto b = slurp(p);
  const std::size_t full = b.size();
  b.pop_back();
  spit(p, b);
  try {
    tio::loadSnapshot(p);
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    const std::string msg = e.what();
    const std::string want = "truncated at byte " + std::to_string(full - 1) + ", expected " + std::to_string(full);
    EXPECT_NE(msg.find(want), std::string::npos) << msg;
    EXPECT_NE(msg.find(p.string()), std::string::npos) << msg;
  }
  // Every shorter prefix is refused as well (headers included).
  for (std::size_t n : {std::size_t{0}, std::size_t{3}, std::size_t{7}, std::size_t{40}, std::size_t{71},
                        std::size_t{72}, full / 2, full - 8})
    EXPECT_NE(decodeError(std::vector<unsigned char>(b.begin(), b.begin() + static_cast<long>(n))).find("truncated"),
              std::string::npos)
        << n;
}

TEST_F(SnapshotTest, RefusesEveryFlippedByte) {
  LayeredMap m(Geometry(0.5, Size(9, 10), Position(1, 2)), MapOptions{8, false});
  const LayerId e = m.addLayer("h", "m");
  m.set(e, Index(3, 4), 2.5f);
  const auto good = tio::encodeSnapshot(m);
  for (std::size_t at = 0; at < good.size(); ++at) {
    for (unsigned char mask : {0x01, 0x80}) {
      auto b = good;
      b[at] ^= mask;
      const std::string msg = decodeError(b, "flip.tmap");
      if (at >= 4) {  // bytes 0-3 are the magic: "not a terramap snapshot"
        EXPECT_NE(msg.find("checksum mismatch"), std::string::npos) << "byte " << at << ": " << msg;
      } else {
        EXPECT_NE(msg.find("bad magic"), std::string::npos) << "byte " << at << ": " << msg;
      }
    }
  }
}

TEST_F(SnapshotTest, ChecksumMessageNamesFileExpectedAndFound) {
  const LayeredMap m = makeDenseMap(7);
  const fs::path p = dir_ / "damaged.tmap";
  tio::saveSnapshot(m, p);
  auto b = slurp(p);
  const std::uint64_t stored = rd64(b, b.size() - 8);
  b[5000] ^= 0x10;
  const std::uint64_t found = tio::crc64(b.data(), b.size() - 8);
  spit(p, b);
  try {
    tio::loadSnapshot(p);
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    const std::string msg = e.what();
    char hex[2][32];
    std::snprintf(hex[0], sizeof hex[0], "0x%016llX", static_cast<unsigned long long>(stored));
    std::snprintf(hex[1], sizeof hex[1], "0x%016llX", static_cast<unsigned long long>(found));
    EXPECT_NE(msg.find(p.string()), std::string::npos) << msg;
    EXPECT_NE(msg.find(std::string("expected ") + hex[0]), std::string::npos) << msg;
    EXPECT_NE(msg.find(std::string("found ") + hex[1]), std::string::npos) << msg;
  }
}

TEST_F(SnapshotTest, RefusesTrailingData) {
  auto b = tio::encodeSnapshot(makeDenseMap(8));
  b.push_back(0);
  EXPECT_NE(decodeError(b).find("trailing data"), std::string::npos);
}

TEST_F(SnapshotTest, RefusesAbsurdSizesEvenWithValidChecksums) {
  const auto good = tio::encodeSnapshot(makeDenseMap(9));
  struct Case {
    std::size_t at;
    std::uint32_t value;
    const char* expect;
  };
  const Case cases[] = {
      {24, 1u << 30, "byte 24: row count"},
      {28, 0, "byte 28: column count"},
      {48, 4, "byte 48: tile size"},
      {48, 4096, "byte 48: tile size"},
      {52, 6, "byte 52: unknown flag"},
      {56, 5000, "byte 56: layer count"},
      {60, 1, "byte 60: reserved"},
      {72, 0xFFFFFFFFu, "byte 72: layer name length"},
      {72, 0, "byte 72: layer name length"},
  };
  for (const Case& c : cases) {
    auto b = good;
    wr32(b, c.at, c.value);
    reseal(b);
    const std::string msg = decodeError(b);
    EXPECT_NE(msg.find(c.expect), std::string::npos) << msg;
  }
  {  // A dense header claiming far more cells than the file holds.
    auto b = good;
    wr32(b, 24, 1u << 19);
    wr32(b, 28, 1u << 19);
    wr32(b, 48, 1024);
    reseal(b);
    EXPECT_NE(decodeError(b).find("needs more data than the file"), std::string::npos);
  }
  {  // A sparse header with 2^34 tiles: refused before allocating tile tables.
    auto b = good;
    wr32(b, 24, 1u << 20);
    wr32(b, 28, 1u << 20);
    wr32(b, 48, 8);
    wr32(b, 52, 1);
    reseal(b);
    EXPECT_NE(decodeError(b).find("limit of 2^24 layer tiles"), std::string::npos);
  }
  {  // Non-finite resolution.
    auto b = good;
    wr64(b, 16, 0x7FF0000000000000ULL);
    reseal(b);
    EXPECT_NE(decodeError(b).find("byte 16: resolution"), std::string::npos);
  }
}

TEST_F(SnapshotTest, RefusesInconsistentTileRecords) {
  LayeredMap m(Geometry(0.1, Size(40, 40)), MapOptions{16, true});
  const LayerId e = m.addLayer("e", "m");
  m.set(e, Index(0, 0), 1.f);
  m.set(e, Index(39, 39), 2.f);
  const auto good = tio::encodeSnapshot(m);
  // Record: name len @72, "e" @76, unit len @77, "m" @81, fill @82, count @86, tile idx @90.
  ASSERT_EQ(rd32(good, 86), 2u);
  ASSERT_EQ(rd32(good, 90), 0u);
  {
    auto b = good;
    wr32(b, 90, 9);  // past the 3 x 3 tiles
    reseal(b);
    EXPECT_NE(decodeError(b).find("byte 90: tile index 9"), std::string::npos);
  }
  {
    auto b = good;
    wr32(b, 86, 3);  // claims a third tile that is not there
    reseal(b);
    EXPECT_NE(decodeError(b).find("runs past the end"), std::string::npos);
  }
  {
    auto b = good;
    const std::size_t second = 90 + 4 + 16 * 16 * 4;
    ASSERT_EQ(rd32(b, second), 8u);
    wr32(b, second, 0);  // repeats tile 0
    reseal(b);
    EXPECT_NE(decodeError(b).find("not increasing"), std::string::npos);
  }
}

TEST_F(SnapshotTest, MissingFileAndUnwritableTarget) {
  try {
    tio::loadSnapshot(dir_ / "nope.tmap");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("No such file or directory"), std::string::npos) << e.what();
  }
  EXPECT_THROW(tio::saveSnapshot(makeDenseMap(1), dir_ / "missing_dir" / "x.tmap"), OutputError);
}

}  // namespace
