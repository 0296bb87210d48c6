// `terramap export` end to end: runs the built CLI binary on snapshots written here.
#include "scratch_dir.hpp"
#include <terramap/core/layered_map.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/io/snapshot.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include <sys/wait.h>
#include <unistd.h>

namespace fs = std::filesystem;
using namespace terramap;
namespace tio = terramap::io;

namespace {

struct Result {
  int code = -1;
  std::string out;  // stdout + stderr
};

const fs::path kBinary = fs::path(TERRAMAP_BINARY_DIR) / "bin" / "terramap";

Result terramap(const std::string& args) {
  Result r;
  FILE* p = ::popen(("'" + kBinary.string() + "' " + args + " 2>&1").c_str(), "r");
  if (!p) return r;
  char buf[4096];
  std::size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) r.out.append(buf, n);
  const int status = ::pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

class ExportCli : public ScratchDirTest {
 protected:
  ExportCli() : ScratchDirTest("export_cli_") {}
  void SetUp() override {
    if (!fs::exists(kBinary)) GTEST_SKIP() << "build the 'terramap' target first (" << kBinary << ")";
    ScratchDirTest::SetUp();
    LayeredMap m(Geometry(0.5, Size(6, 4), Position(1.0, 2.0)), MapOptions{8, false});
    const LayerId e = m.addLayer("elevation", "m");
    const LayerId v = m.addLayer("variance", "m^2");
    for (int i = 0; i < 6; ++i)
      for (int j = 0; j < 4; ++j) {
        m.set(e, Index(i, j), static_cast<float>(i + 10 * j));
        m.set(v, Index(i, j), 0.01f * static_cast<float>(i));
      }
    snap_ = dir_ / "map.tmap";
    tio::saveSnapshot(m, snap_);
  }
  std::string q(const fs::path& p) const { return "'" + p.string() + "'"; }
  fs::path snap_;
};

TEST_F(ExportCli, GeoTiffWithDefaultNameAndEpsg) {
  Result r = terramap("export " + q(snap_) + " --layer elevation --layer variance --format geotiff");
  ASSERT_EQ(r.code, 0) << r.out;
  const fs::path tif = dir_ / "map.tif";
  ASSERT_TRUE(fs::exists(tif)) << r.out;
  tio::Raster t = tio::readRaster(tif);
  EXPECT_EQ(t.width, 6);
  EXPECT_EQ(t.height, 4);
  ASSERT_EQ(t.bands.size(), 2u);
  EXPECT_EQ(t.bands[1].description, "variance");
  EXPECT_EQ(t.bands[0].values(0, 0), 5.f);  // north-west = (i = 5, j = 0)
  EXPECT_TRUE(t.crs_local);

  r = terramap("export " + q(snap_) + " -l elevation --epsg 32632 --origin 500000 5200000 --out " + q(dir_ / "utm.tif"));
  ASSERT_EQ(r.code, 0) << r.out;  // format inferred from .tif
  t = tio::readRaster(dir_ / "utm.tif");
  EXPECT_EQ(t.epsg, 32632);
  EXPECT_DOUBLE_EQ((*t.geotransform)[0], 500000.0 + 1.0 - 1.5);
  EXPECT_DOUBLE_EQ((*t.geotransform)[3], 5200000.0 + 2.0 + 1.0);
}

TEST_F(ExportCli, PngSingleAndSeveralLayers) {
  Result r = terramap("export " + q(snap_) + " --layer elevation --format png --hillshade --scale 3 --raw --out " +
                      q(dir_ / "e.png"));
  ASSERT_EQ(r.code, 0) << r.out;
  tio::Raster p = tio::readRaster(dir_ / "e.png");
  EXPECT_EQ(p.width, 18);
  EXPECT_EQ(p.height, 12);
  EXPECT_EQ(p.bands.size(), 4u);
  // Without --raw the picture explains itself: title, colour bar, scale bar around the map.
  r = terramap("export " + q(snap_) + " --layer elevation --format png --hillshade --scale 3 --out " +
               q(dir_ / "annotated.png"));
  ASSERT_EQ(r.code, 0) << r.out;
  const tio::Raster a = tio::readRaster(dir_ / "annotated.png");
  EXPECT_GT(a.width, 18 + 100);
  EXPECT_GT(a.height, 12 + 60);

  r = terramap("export " + q(snap_) + " --layer elevation --layer variance --format png --colormap rdbu --out " +
               q(dir_ / "renders"));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(fs::exists(dir_ / "renders" / "elevation.png"));
  EXPECT_TRUE(fs::exists(dir_ / "renders" / "variance.png"));

  r = terramap("export " + q(snap_) + " --layer variance --format png --range 0 0.05 --colormap grey --raw");
  ASSERT_EQ(r.code, 0) << r.out;
  p = tio::readRaster(dir_ / "map_variance.png");
  // Column 0 = smallest x = i = 5, variance 0.05 -> white at the fixed range's top.
  EXPECT_EQ(p.bands[0].values(0, 0), 255.f);
  EXPECT_EQ(p.bands[0].values(0, 5), 0.f);  // i = 0, variance 0
}

TEST_F(ExportCli, ErrorsMapToDocumentedExitCodes) {
  // 4: input (missing, corrupt)
  Result r = terramap("export " + q(dir_ / "none.tmap") + " --layer elevation --format geotiff");
  EXPECT_EQ(r.code, 4) << r.out;
  {
    std::fstream f(snap_, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(200);
    f.put('\x55');
  }
  r = terramap("export " + q(snap_) + " --layer elevation --format geotiff");
  EXPECT_EQ(r.code, 4) << r.out;
  EXPECT_NE(r.out.find("checksum mismatch"), std::string::npos) << r.out;
  SetUp();  // a fresh, intact snapshot
  // 6: unknown layer, with a suggestion
  r = terramap("export " + q(snap_) + " --layer elevaton --format png");
  EXPECT_EQ(r.code, 6) << r.out;
  EXPECT_NE(r.out.find("elevation"), std::string::npos) << r.out;
  // 3: bad values
  r = terramap("export " + q(snap_) + " --layer elevation --format png --colormap viridus");
  EXPECT_EQ(r.code, 3) << r.out;
  r = terramap("export " + q(snap_) + " --layer elevation --format geotiff --epsg 4326 --origin 0 0");
  EXPECT_EQ(r.code, 3) << r.out;
  r = terramap("export " + q(snap_) + " --layer elevation --format png --range 5 1");
  EXPECT_EQ(r.code, 3) << r.out;
  // 2: usage
  r = terramap("export " + q(snap_) + " --layer elevation --format geotiff --colormap rdbu");
  EXPECT_EQ(r.code, 2) << r.out;
  r = terramap("export " + q(snap_) + " --layer elevation --format geotiff --epsg 32632");
  EXPECT_EQ(r.code, 2) << r.out;
  r = terramap("export " + q(snap_) + " --layer elevation");
  EXPECT_EQ(r.code, 2) << r.out;
  r = terramap("export " + q(snap_) + " --format png");
  EXPECT_EQ(r.code, 2) << r.out;
  r = terramap("export " + q(snap_) + " -l elevation -l variance --format png --out " + q(dir_ / "two.png"));
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_FALSE(fs::exists(dir_ / "two.png"));
  // 7: cannot write
  r = terramap("export " + q(snap_) + " --layer elevation --format geotiff --out " + q(dir_ / "no" / "x.tif"));
  EXPECT_EQ(r.code, 7) << r.out;
  // Nothing half-written anywhere.
  for (const auto& e : fs::directory_iterator(dir_))
    EXPECT_EQ(e.path().filename().string().find(".tmp."), std::string::npos) << e.path();
}

TEST_F(ExportCli, HelpDocumentsEveryOption) {
  const Result r = terramap("export --help");
  EXPECT_EQ(r.code, 0);
  for (const char* opt : {"--layer", "--format", "--out", "--colormap", "--hillshade", "--range", "--epsg", "--origin",
                          "--scale", "--azimuth", "--altitude", "Exit codes", "north-up"})
    EXPECT_NE(r.out.find(opt), std::string::npos) << opt;
}

}  // namespace
