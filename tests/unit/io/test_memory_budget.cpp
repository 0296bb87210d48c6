// Bounded memory on any input (include/terramap/core/memory_budget.hpp): sizes read from files
// are checked against what the file can hold and against the memory budget before anything is
// allocated, so a forged header is an InputError naming the file and the field, never
// std::bad_alloc. Each reader is given a small real file and a budget below what it needs (the
// budget check alone must refuse it), or a header that declares more than the file holds.
#include <terramap/core/error.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/io/readers.hpp>
#include <terramap/io/snapshot.hpp>
#include <terramap/sim/truth_terrain.hpp>

#include <gdal_priv.h>

#include <cstdint>
#include <limits>

#include "scratch_dir.hpp"
#include "test_readers_util.hpp"

using namespace terramap;
using namespace terramap::test;

namespace {

/// Sets the budget for one test and restores the previous one.
struct BudgetScope {
  std::uint64_t saved = memoryBudget();
  explicit BudgetScope(std::uint64_t b) { setMemoryBudget(b); }
  ~BudgetScope() { setMemoryBudget(saved); }
};

class MemoryBudget : public ScratchDirTest {
 protected:
  MemoryBudget() : ScratchDirTest("budget_") {}
  std::string file(const std::string& name) const { return (dir_ / name).string(); }
};

/// A binary PCD of n points (x y z intensity float32).
std::string binaryPcd(std::uint64_t declared, std::uint64_t stored) {
  std::string s = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH " +
                  std::to_string(declared) + "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " + std::to_string(declared) +
                  "\nDATA binary\n";
  s.append(stored * 16, '\0');
  return s;
}

}  // namespace

TEST(MemoryBudgetCore, SizesParseAndProductsSaturate) {
  EXPECT_EQ(parseByteSize("4G", "x"), 4ull << 30);
  EXPECT_EQ(parseByteSize("512M", "x"), 512ull << 20);
  EXPECT_EQ(parseByteSize("1.5GiB", "x"), 3ull << 29);
  EXPECT_EQ(parseByteSize("1048576", "x"), 1ull << 20);
  expectErrorWith<ConfigError>([] { parseByteSize("lots", "--memory-budget"); }, {"--memory-budget", "'lots'"});
  expectErrorWith<ConfigError>([] { parseByteSize("0", "--memory-budget"); }, {"--memory-budget", "'0'"});
  expectErrorWith<ConfigError>([] { parseByteSize("-4G", "x"); }, {"'-4G'"});
  EXPECT_EQ(saturatingProduct({100000, 100000, 4}), 40000000000ull);
  EXPECT_EQ(saturatingProduct({1ull << 40, 1ull << 30}), std::numeric_limits<std::uint64_t>::max());
  EXPECT_EQ(saturatingProduct({1ull << 63, 0}), 0u);
  EXPECT_EQ(formatBytes(40000000000ull), "37.3 GiB");
  EXPECT_THROW(setMemoryBudget(0), ConfigError);
}

TEST_F(MemoryBudget, PcdWithinTheFileButOverTheBudgetIsRefused) {
  spitText(file("a.pcd"), binaryPcd(1000, 1000));
  EXPECT_EQ(io::readPcd(file("a.pcd")).size(), 1000u);
  BudgetScope b(1000 * 16);  // the file's data, but not PCL's buffer plus the converted points
  expectErrorWith([&] { io::readPcd(file("a.pcd")); }, {"a.pcd", "POINTS 1000", "memory budget"});
}

TEST_F(MemoryBudget, PcdHeaderLargerThanTheFileIsRefusedBeforeAllocating) {
  // WIDTH x HEIGHT = 2^32 x 2^32 wraps to 0 in 64-bit arithmetic: must not match POINTS 0.
  std::string s = binaryPcd(0, 0);
  s.replace(s.find("WIDTH 0"), 7, "WIDTH 4294967296");
  s.replace(s.find("HEIGHT 1"), 8, "HEIGHT 4294967296");
  spitText(file("wrap.pcd"), s);
  expectErrorWith([&] { io::readPcd(file("wrap.pcd")); }, {"wrap.pcd", "POINTS 0", "WIDTH x HEIGHT"});
  spitText(file("big.pcd"), binaryPcd(100000000000ull, 3));
  EXPECT_THROW(io::readPcd(file("big.pcd")), InputError);
}

TEST_F(MemoryBudget, PlyVertexCountOverTheBudgetIsRefused) {
  std::string s = "ply\nformat binary_little_endian 1.0\nelement vertex 500\nproperty float x\nproperty float y\n"
                  "property float z\nend_header\n";
  s.append(500 * 12, '\0');
  spitText(file("a.ply"), s);
  EXPECT_EQ(io::readPly(file("a.ply")).size(), 500u);
  BudgetScope b(500 * 16);
  expectErrorWith([&] { io::readPly(file("a.ply")); }, {"a.ply", "element vertex 500", "memory budget"});
}

TEST_F(MemoryBudget, KittiScanOverTheBudgetIsRefused) {
  spit(file("a.bin"), std::vector<unsigned char>(64 * 16, 0));
  EXPECT_EQ(io::readKittiBin(file("a.bin")).size(), 64u);
  BudgetScope b(63 * 16);
  expectErrorWith([&] { io::readKittiBin(file("a.bin")); }, {"a.bin", "64 points", "memory budget"});
}

TEST_F(MemoryBudget, EsriAsciiHeaderLargerThanTheFileIsRefused) {
  // The case: ncols 100000 nrows 100000 and three values (80 GB of doubles).
  spitText(file("dem.asc"), "ncols 100000\nnrows 100000\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2 3\n");
  expectErrorWith([&] { sim::readEsriAscii(file("dem.asc")); }, {"dem.asc", "ncols 100000", "can hold at most"});
  spitText(file("far.asc"), "ncols 2\nnrows 2\nxllcorner 1e300\nyllcorner 0\ncellsize 1\n1 2\n3 4\n");
  expectErrorWith([&] { sim::readEsriAscii(file("far.asc")); }, {"far.asc:3", "xllcorner", "plausible magnitude"});
  spitText(file("frac.asc"), "ncols 2.5\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n3 4\n");
  expectErrorWith([&] { sim::readEsriAscii(file("frac.asc")); }, {"frac.asc:1", "ncols", "whole number"});
  spitText(file("ok.asc"), "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2 3\n4 5 6\n");
  EXPECT_EQ(sim::readEsriAscii(file("ok.asc")).z.size(), 6u);
  BudgetScope b(6 * 8 - 1);
  expectErrorWith([&] { sim::readEsriAscii(file("ok.asc")); }, {"ok.asc", "ncols 3 x nrows 2", "memory budget"});
}

TEST_F(MemoryBudget, CompressedRasterDeclaringAHugeSizeIsRefusedBeforeDecoding) {
  // A tiled, sparse GeoTIFF of 200000 x 200000 cells that GDAL writes in a few megabytes (its
  // tile index): reading it whole as float32 would take 149 GiB.
  GDALAllRegister();
  GDALDriver* drv = GetGDALDriverManager()->GetDriverByName("GTiff");
  ASSERT_NE(drv, nullptr);
  char** opts = nullptr;
  opts = CSLSetNameValue(opts, "TILED", "YES");
  opts = CSLSetNameValue(opts, "COMPRESS", "DEFLATE");
  opts = CSLSetNameValue(opts, "SPARSE_OK", "TRUE");
  opts = CSLSetNameValue(opts, "BIGTIFF", "YES");
  GDALDataset* ds = drv->Create(file("huge.tif").c_str(), 200000, 200000, 1, GDT_Float32, opts);
  CSLDestroy(opts);
  ASSERT_NE(ds, nullptr);
  GDALClose(ds);
  EXPECT_LT(std::filesystem::file_size(file("huge.tif")), 1u << 24);
  expectErrorWith([&] { io::readRaster(file("huge.tif")); }, {"huge.tif", "200000 x 200000", "memory budget"});
}

TEST_F(MemoryBudget, SnapshotOverTheBudgetIsRefused) {
  LayeredMap m(Geometry(0.1, Size(64, 64), Position::Zero()));
  m.addLayer("elevation", "m");
  io::saveSnapshot(m, file("m.tmap"));
  EXPECT_EQ(io::loadSnapshot(file("m.tmap")).layerCount(), 1);
  BudgetScope b(64 * 64 * 4);
  expectErrorWith([&] { io::loadSnapshot(file("m.tmap")); }, {"m.tmap", "memory budget"});
}
