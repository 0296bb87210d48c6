// Truth terrain from a GeoTIFF (written here through terramap::io) and from LAS ground points
// (the real airborne PDAL sample), gridding and hole filling.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/io/readers.hpp>
#include <terramap/sim/dem.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/world.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>

using namespace terramap;
using namespace terramap::sim;
namespace fs = std::filesystem;

namespace {

const std::string kLas = std::string(TERRAMAP_DATA_DIR) + "/las_hexbin/hexbin-crop.las";

double field(double x, double y) { return 0.2 * x - 0.1 * y + 0.05 * std::sin(3 * x) * std::cos(2 * y); }

/// A 40 x 30-cell map (10 cm) centred at (1, -0.5): bands "count" (1) and "elevation" (2).
LayeredMap elevationMap(double offset) {
  LayeredMap m(Geometry(0.1, Size(40, 30), Position(1.0, -0.5)));
  const LayerId c = m.addLayer("count", "", 0.f);
  const LayerId e = m.addLayer("elevation", "m");
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 30; ++j) {
      const Position p = m.geometry().positionOf(Index(i, j));
      m.set(e, Index(i, j), static_cast<float>(offset + field(p.x(), p.y())));
      m.set(c, Index(i, j), 3.f);
    }
  return m;
}

/// Independent bilinear interpolation of the map's float cells at (x, y) (cell centres at
/// xmin + (k + 0.5) res), through the map's own index convention.
double bilinearOfMap(const LayeredMap& m, double x, double y) {
  const Geometry& g = m.geometry();
  const double res = g.resolution();
  const double xmin = g.center().x() - 0.5 * g.length().x(), ymin = g.center().y() - 0.5 * g.length().y();
  const double fx = (x - xmin) / res - 0.5, fy = (y - ymin) / res - 0.5;
  const int kx = std::clamp(static_cast<int>(std::floor(fx)), 0, g.size().x() - 2);
  const int ky = std::clamp(static_cast<int>(std::floor(fy)), 0, g.size().y() - 2);
  const double u = fx - kx, v = fy - ky;
  const LayerId e = m.layerId("elevation");
  auto at = [&](int ax, int ay) {  // ax counts cells from the west, ay from the south
    return static_cast<double>(m.at(e, Index(g.size().x() - 1 - ax, g.size().y() - 1 - ay)));
  };
  return (1 - u) * (1 - v) * at(kx, ky) + u * (1 - v) * at(kx + 1, ky) + (1 - u) * v * at(kx, ky + 1) +
         u * v * at(kx + 1, ky + 1);
}

std::string scenarioWithDem(const std::string& dem_yaml, const std::string& extent = "") {
  return "version: 1\nseed: 1\nduration_s: 1\nterrain: {resolution_m: 0.02, " + extent + "dem: " + dem_yaml +
         "}\nmachines:\n  - id: m1\n";
}

std::string errorOf(const std::string& yaml) {
  try {
    const Scenario sc = parseScenario(yaml, "s.yaml");
    buildTerrain(sc.terrain);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(DemGridding, MedianMeanAndBorderAssignmentAreHandComputable) {
  // Cells of 1 m centred at x = 0, 1, 2 and y = 0, 1.
  const std::vector<Eigen::Vector3d> pts = {
      {0.1, 0.1, 5.0}, {-0.2, 0.3, 1.0}, {0.4, -0.4, 3.0},  // cell (0, 0): median 3, mean 3
      {1.0, 0.0, 2.0}, {1.2, 0.2, 4.0},                      // cell (1, 0): even count, median 3, mean 3
      {1.5, 0.0, 10.0},                                       // on the 1|2 border -> cell (2, 0)
      {2.0, 1.2, 7.0}, {2.1, 0.9, 9.0}, {1.9, 1.1, 2.0}, {2.2, 1.0, 1.0},  // cell (2, 1): median 4.5, mean 4.75
      {9.0, 9.0, 99.0}};                                      // outside: ignored
  const DemGrid med = gridPoints(pts, 0.0, 0.0, 1.0, 3, 2, DemStatistic::Median);
  const DemGrid mean = gridPoints(pts, 0.0, 0.0, 1.0, 3, 2, DemStatistic::Mean);
  EXPECT_DOUBLE_EQ(med.z[0], 3.0);
  EXPECT_DOUBLE_EQ(med.z[1], 3.0);
  EXPECT_DOUBLE_EQ(med.z[2], 10.0);
  EXPECT_TRUE(std::isnan(med.z[3]));
  EXPECT_TRUE(std::isnan(med.z[4]));
  EXPECT_DOUBLE_EQ(med.z[5], 4.5);
  EXPECT_DOUBLE_EQ(mean.z[0], 3.0);
  EXPECT_DOUBLE_EQ(mean.z[1], 3.0);
  EXPECT_DOUBLE_EQ(mean.z[5], 4.75);
}

TEST(DemGridding, HolesAreFilledByDirectionalInverseDistance) {
  // 3 x 3, centre missing: axis neighbours at distance 1 (weight 1), diagonals at sqrt 2 (1/2).
  DemGrid g;
  g.nx = 3; g.ny = 3; g.cell_m = 1;
  g.z = {1, 2, 3, 4, NAN, 6, 7, 8, 9.5};
  EXPECT_EQ(fillDemHoles(g, "t"), 1u);
  EXPECT_NEAR(g.z[4], ((2 + 4 + 6 + 8) + 0.5 * (1 + 3 + 7 + 9.5)) / 6.0, 1e-12);
  // A hole seeing no data along its 8 lines is filled in a later pass from filled cells:
  // 5 x 3 with data only at (0, 0); (2, 1)'s lines reach (1, 0) but never (0, 0).
  DemGrid h;
  h.nx = 5; h.ny = 3; h.cell_m = 1;
  h.z.assign(15, NAN);
  h.z[0] = 2.0;
  EXPECT_EQ(fillDemHoles(h, "t"), 14u);
  for (double v : h.z) EXPECT_DOUBLE_EQ(v, 2.0);  // a convex combination of 2.0 only
  DemGrid empty;
  empty.nx = 2; empty.ny = 2; empty.z.assign(4, NAN);
  EXPECT_THROW(fillDemHoles(empty, "t"), InputError);
}

// Found by fuzz_las (docs/reliability.md, "Fuzzing"): filling searched from every hole along its
// 8 lines, cells x line length per pass, so a sparse grid took hours (the fuzzer's LAS grids its
// 6 ground points into 1476394 x 12 cells). Now linear per pass; same sums, so same values.
TEST(DemGridding, HoleFillingIsLinearOnASparseGrid) {
  DemGrid g;
  g.nx = 2000; g.ny = 1500; g.cell_m = 1;
  g.z.assign(static_cast<std::size_t>(g.nx) * g.ny, NAN);
  g.z[777] = -1.25;
  g.z[static_cast<std::size_t>(1499) * 2000 + 1999] = -1.25;
  EXPECT_EQ(fillDemHoles(g, "t"), g.z.size() - 2);
  for (double v : g.z) ASSERT_NEAR(v, -1.25, 1e-12);  // convex combinations of -1.25
}

// fuzz_las's finding, rebuilt here field by field (docs/reliability.md, "Fuzzing"): the LAS 1.4
// point-format-3 seed of fuzz/seeds/make_seeds.cpp (6 synthetic points, 4 of them ground, UTM
// 32N GeoKeys) with one byte of one ground point's x mutated, so that x reaches 1476 km past
// the others while the header's extent still says 15 m.
std::string writeSparseGroundLas(const fs::path& path) {
  std::string b;
  auto raw = [&](const void* p, std::size_t n) { b.append(static_cast<const char*>(p), n); };
  auto u8 = [&](std::uint8_t v) { raw(&v, 1); };
  auto u16 = [&](std::uint16_t v) { raw(&v, 2); };
  auto u32 = [&](std::uint32_t v) { raw(&v, 4); };
  auto u64 = [&](std::uint64_t v) { raw(&v, 8); };
  auto i32 = [&](std::int32_t v) { raw(&v, 4); };
  auto f64 = [&](double v) { raw(&v, 8); };
  auto text = [&](const std::string& t, std::size_t n) { b.append(t); b.append(n - t.size(), '\0'); };
  // Public header, 375 bytes.
  text("LASF", 4);
  u16(0);                   // file source id
  u16(0);                   // global encoding
  text("", 16);             // GUID
  u8(1);
  u8(4);                    // version 1.4
  text("terramap fuzz seed", 32);
  text("make_seeds", 32);
  u16(200);
  u16(2026);                // creation day, year
  u16(375);                 // header size
  u32(453);                 // offset to the points: header + one 78-byte VLR
  u32(1);                   // VLRs
  u8(3);                    // point format 3
  u16(34);                  // record length
  u32(6);                   // legacy point count
  for (std::uint32_t v : {6u, 0u, 0u, 0u, 0u}) u32(v);
  for (int k = 0; k < 3; ++k) f64(0.001);  // scale
  f64(500000.0);
  f64(4000000.0);
  f64(100.0);               // offset
  for (double v : {500010.0, 499995.75, 4000002.0, 3999990.0, 102.0, 99.25}) f64(v);  // max/min x, y, z
  u64(0);
  u64(0);
  u32(0);                   // waveform, EVLR start, EVLR count
  u64(6);                   // point count
  for (int k = 0; k < 15; ++k) u64(k == 0 ? 6 : 0);
  // GeoKeyDirectoryTag VLR: ProjectedCSTypeGeoKey 32632 (UTM 32N).
  u16(0);
  text("LASF_Projection", 16);
  u16(34735);
  u16(24);
  text("GeoKeyDirectoryTag", 32);
  for (std::uint16_t v : {1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 32632}) u16(v);
  // Points: x, y, z (scaled ints), intensity, return bits, class, scan angle, user data, source
  // id, GPS time, RGB. The fourth is the mutated one (x 1476395008).
  struct P {
    std::int32_t x, y, z;
    std::uint16_t intensity;
    std::uint8_t cls;
    std::uint16_t green;
  };
  const P pts[6] = {{1500, -2000, 250, 6553, 2, 1000},  {3000, 500, -750, 58981, 2, 1000},
                    {-4250, 1000, 2000, 32767, 1, 1000}, {1476395008, 0, 0, 0, 2, 776},
                    {10000, -10000, 1000, 65535, 2, 1000}, {2000, 2000, 2000, 19660, 1, 1000}};
  for (int k = 0; k < 6; ++k) {
    i32(pts[k].x);
    i32(pts[k].y);
    i32(pts[k].z);
    u16(pts[k].intensity);
    u8(9);
    u8(pts[k].cls);
    u8(0);
    u8(0);
    u16(1);
    f64(1000.0 + k);
    u16(0);
    u16(pts[k].green);
    u16(2000);
  }
  EXPECT_EQ(b.size(), 657u);
  std::ofstream(path, std::ios::binary).write(b.data(), static_cast<std::streamsize>(b.size()));
  return path.string();
}

// Same input: the grid and the filling are sized against the memory budget before allocating
// (the grid alone took 141 MB, the filling 405 MB more, on 6 points).
TEST(DemInputs, SparseLasGroundPointsAreCheckedAgainstTheBudget) {
  struct BudgetScope {
    std::uint64_t saved = memoryBudget();
    explicit BudgetScope(std::uint64_t b) { setMemoryBudget(b); }
    ~BudgetScope() { setMemoryBudget(saved); }
  } budget(64ull << 20);
  DemSpec spec;
  const fs::path dir = fs::path(TERRAMAP_BINARY_DIR) / "sim_test_dem";
  fs::create_directories(dir);
  spec.path = writeSparseGroundLas(dir / "las_dem_sparse_ground.las");
  spec.format = DemFormat::Las;
  try {
    loadDem(spec);
    ADD_FAILURE() << "expected an InputError";
  } catch (const InputError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("1476394 x 12 cells"), std::string::npos) << m;
    EXPECT_NE(m.find("memory budget"), std::string::npos) << m;
  }
}

TEST(DemInputs, GeoTiffWrittenFromALayeredMapBecomesTheTruthSurface) {
  const fs::path dir = fs::path(TERRAMAP_BINARY_DIR) / "sim_test_dem";
  fs::create_directories(dir);
  const fs::path tif = dir / "local.tif";
  const LayeredMap m = elevationMap(0.0);
  io::writeGeoTiff(m, {"count", "elevation"}, tif);
  // Local CRS: the map frame is kept (geo origin 0). Extent = the hull of the cell centres.
  const Scenario sc = parseScenario(scenarioWithDem("{file: " + tif.string() + ", band: elevation}"), "s.yaml");
  EXPECT_EQ(sc.terrain.dem.format, DemFormat::GeoTiff);
  EXPECT_NEAR(sc.terrain.origin_x_m, 1.0 - 2.0 + 0.05, 1e-12);
  EXPECT_NEAR(sc.terrain.origin_y_m, -0.5 - 1.5 + 0.05, 1e-12);
  EXPECT_NEAR(sc.terrain.size_x_m, 3.9, 1e-9);
  EXPECT_NEAR(sc.terrain.size_y_m, 2.9, 1e-9);
  EXPECT_TRUE(sc.terrain.dem_geo_origin.isZero());
  const TruthTerrain t = buildTerrain(sc.terrain);
  ASSERT_EQ(t.nx(), 196);
  ASSERT_EQ(t.ny(), 146);
  double worst = 0;
  for (int j = 0; j < t.ny(); j += 7)
    for (int i = 0; i < t.nx(); i += 5) {
      const Eigen::Vector2d p = t.nodePosition(i, j);
      worst = std::max(worst, std::abs(t.height(i, j) - bilinearOfMap(m, p.x(), p.y())));
    }
  EXPECT_LT(worst, 1e-9);
  // Band by number, and errors that name the file.
  const Scenario sc1 = parseScenario(scenarioWithDem("{file: " + tif.string() + ", band: 1}"), "s.yaml");
  EXPECT_NEAR(buildTerrain(sc1.terrain).height(10, 10), 3.0, 1e-12);
  std::string e = errorOf(scenarioWithDem("{file: " + tif.string() + ", band: 3}"));
  EXPECT_NE(e.find("band 3 out of range"), std::string::npos) << e;
  EXPECT_NE(e.find("local.tif"), std::string::npos) << e;
  e = errorOf(scenarioWithDem("{file: " + tif.string() + ", band: height}"));
  EXPECT_NE(e.find("no band named 'height'"), std::string::npos) << e;
  e = errorOf(scenarioWithDem("{file: " + tif.string() + ", cell_m: 2}"));
  EXPECT_NE(e.find("terrain.dem.cell_m: applies to format las only"), std::string::npos) << e;
}

TEST(DemInputs, GeoTiffHolesFailOrAreFilledOnRequest) {
  const fs::path dir = fs::path(TERRAMAP_BINARY_DIR) / "sim_test_dem";
  fs::create_directories(dir);
  const fs::path tif = dir / "holes.tif";
  LayeredMap m = elevationMap(0.0);
  m.set(m.layerId("elevation"), Index(20, 15), NAN);
  io::writeGeoTiff(m, {"elevation"}, tif);
  const std::string e = errorOf(scenarioWithDem("{file: " + tif.string() + "}"));
  EXPECT_NE(e.find("DEM has no data at terrain node"), std::string::npos) << e;
  const Scenario sc = parseScenario(scenarioWithDem("{file: " + tif.string() + ", fill_holes: true}"), "s.yaml");
  const TruthTerrain t = buildTerrain(sc.terrain);
  const Position c = m.geometry().positionOf(Index(20, 15));
  int i = 0, j = 0;
  t.nearestNode(c.x(), c.y(), i, j);
  // The filled cell is an inverse-distance mean of its 8 neighbours' values: close to the field.
  EXPECT_NEAR(t.height(i, j), field(c.x(), c.y()), 0.01);
}

TEST(DemInputs, GeoreferencedGeoTiffIsShiftedToItsRoundedCentre) {
  const fs::path dir = fs::path(TERRAMAP_BINARY_DIR) / "sim_test_dem";
  fs::create_directories(dir);
  const fs::path tif = dir / "utm.tif";
  const LayeredMap m = elevationMap(3100.0);
  io::GeoTiffOptions opt;
  opt.georef.epsg = 32642;  // WGS 84 / UTM 42N
  opt.georef.origin_easting = 393900.3;
  opt.georef.origin_northing = 3689100.6;
  io::writeGeoTiff(m, {"elevation"}, tif, opt);
  const Scenario sc = parseScenario(scenarioWithDem("{file: " + tif.string() + "}", "size_m: [1, 1], origin_m: [0, 0], "),
                                    "s.yaml");
  // Raster extent: easting 393900.3 + [-1, 3], northing 3689100.6 + [-2, 1]; heights 3100 +- 0.6.
  const Eigen::Vector3d o = sc.terrain.dem_geo_origin;
  EXPECT_DOUBLE_EQ(o.x(), std::round(393900.3 + 1.0));
  EXPECT_DOUBLE_EQ(o.y(), std::round(3689100.6 - 0.5));
  EXPECT_DOUBLE_EQ(o.z(), 3100.0);
  const TruthTerrain t = buildTerrain(sc.terrain);
  for (int j = 0; j < t.ny(); j += 10)
    for (int i = 0; i < t.nx(); i += 10) {
      // Map (x, y) = world - origin; the raster's own map frame is world - (393900.3, 3689100.6).
      const Eigen::Vector2d p = t.nodePosition(i, j);
      const double xr = p.x() + o.x() - 393900.3, yr = p.y() + o.y() - 3689100.6;
      ASSERT_NEAR(t.height(i, j) + o.z(), bilinearOfMap(m, xr, yr), 1e-6) << i << " " << j;
    }
}

TEST(DemInputs, LasGroundPointsGiveMediansPerCellAndFilledHoles) {
  ASSERT_TRUE(fs::exists(kLas)) << kLas;
  const std::string yaml = scenarioWithDem("{file: " + kLas + ", cell_m: 4}", "size_m: [24, 16], origin_m: [-12, -8], ");
  const Scenario sc = parseScenario(yaml, "s.yaml");
  EXPECT_EQ(sc.terrain.dem.format, DemFormat::Las);
  // Default geo origin: the header box centre rounded to metres (PDAL sample, UTM 42N):
  // x (393775.823 + 394069.238) / 2, y (3689071.943 + 3689273.095) / 2, z (3107.863 + 3209.321) / 2.
  const Eigen::Vector3d o = sc.terrain.dem_geo_origin;
  EXPECT_DOUBLE_EQ(o.x(), 393923.0);
  EXPECT_DOUBLE_EQ(o.y(), 3689173.0);
  EXPECT_DOUBLE_EQ(o.z(), 3159.0);
  const TruthTerrain t = buildTerrain(sc.terrain);
  // Direct computation from the points: ground points within each 4 m cell centred on
  // multiples of 4 m (map frame), median of their heights.
  io::LasReadOptions ro;
  ro.keep_double_positions = true;
  const io::LasCloud cloud = io::readLas(kLas, ro);
  // The holes of the whole file's grid, unfilled, against the points: a cell with a ground
  // return strictly inside it has a value; a cell with none inside or on its border is NaN
  // (NaN marks "no ground returns"; a point exactly on a border may go either way, so cells
  // whose only points lie on a border are not judged).
  DemSpec raw_spec = sc.terrain.dem;
  raw_spec.fill_holes = false;
  const DemGrid raw = loadDem(raw_spec);
  const DemGrid filled = loadDem(sc.terrain.dem);
  ASSERT_EQ(raw.nx, filled.nx);
  ASSERT_EQ(raw.ny, filled.ny);
  ASSERT_NEAR(raw.x0_m, filled.x0_m, 0.0);
  std::vector<int> inside(raw.z.size(), 0), near(raw.z.size(), 0);
  for (std::size_t k = 0; k < cloud.size(); ++k) {
    if (cloud.classification[k] != 2) continue;
    const Eigen::Vector3d p = cloud.positions[k] - o;
    // The cells whose centres are within a cell of the point (judged by distance below).
    const int ci = static_cast<int>(std::lround((p.x() - raw.x0_m) / raw.cell_m));
    const int cj = static_cast<int>(std::lround((p.y() - raw.y0_m) / raw.cell_m));
    for (int gj = std::max(0, cj - 1); gj <= std::min(raw.ny - 1, cj + 1); ++gj)
      for (int gi = std::max(0, ci - 1); gi <= std::min(raw.nx - 1, ci + 1); ++gi) {
        const double dx = std::abs(p.x() - (raw.x0_m + gi * raw.cell_m)), dy = std::abs(p.y() - (raw.y0_m + gj * raw.cell_m));
        const std::size_t c = static_cast<std::size_t>(gj) * raw.nx + gi;
        if (dx < 0.5 * raw.cell_m - 1e-9 && dy < 0.5 * raw.cell_m - 1e-9) ++inside[c];
        if (dx <= 0.5 * raw.cell_m + 1e-9 && dy <= 0.5 * raw.cell_m + 1e-9) ++near[c];
      }
  }
  int raw_holes = 0, raw_data = 0;
  for (std::size_t c = 0; c < raw.z.size(); ++c) {
    if (inside[c] > 0) {
      EXPECT_FALSE(std::isnan(raw.z[c])) << "cell " << c << " has " << inside[c] << " ground returns";
      ++raw_data;
    } else if (near[c] == 0) {
      EXPECT_TRUE(std::isnan(raw.z[c])) << "cell " << c << " has no ground return but height " << raw.z[c];
      ++raw_holes;
    }
  }
  EXPECT_GT(raw_holes, 0);  // the sample has gaps (buildings, water, sparse returns)
  EXPECT_GT(raw_data, raw_holes);
  // Filling changes the holes only, and each hole that sees data along one of the 8 grid
  // directions takes an inverse-distance mean of the first data cells seen, so it lies within
  // their range (holes seeing none are filled in later passes from filled cells: finite).
  for (int gj = 0; gj < raw.ny; ++gj)
    for (int gi = 0; gi < raw.nx; ++gi) {
      const std::size_t c = static_cast<std::size_t>(gj) * raw.nx + gi;
      if (!std::isnan(raw.z[c])) {
        EXPECT_EQ(filled.z[c], raw.z[c]);
        continue;
      }
      ASSERT_TRUE(std::isfinite(filled.z[c]));
      double lo = INFINITY, hi = -INFINITY;
      for (int di = -1; di <= 1; ++di)
        for (int dj = -1; dj <= 1; ++dj) {
          if (di == 0 && dj == 0) continue;
          for (int a = gi + di, b = gj + dj; a >= 0 && b >= 0 && a < raw.nx && b < raw.ny; a += di, b += dj) {
            const double v = raw.z[static_cast<std::size_t>(b) * raw.nx + a];
            if (std::isnan(v)) continue;
            lo = std::min(lo, v);
            hi = std::max(hi, v);
            break;
          }
        }
      if (lo > hi) continue;  // sees no data cell: a later pass
      EXPECT_GE(filled.z[c], lo - 1e-9) << gi << " " << gj;
      EXPECT_LE(filled.z[c], hi + 1e-9) << gi << " " << gj;
    }
  // The truth terrain at the cell centres, over the extent above (all data) and over one across
  // the north-east edge of the sample's hull (holes: the 4 m cells at (40, 32), (44, 32), ...).
  int checked = 0, holes = 0;
  auto checkNodes = [&](const TruthTerrain& t, int x0, int y0, int x1, int y1) {
    for (int cy = y0; cy <= y1; cy += 4)
      for (int cx = x0; cx <= x1; cx += 4) {
        std::vector<double> z;
        for (std::size_t k = 0; k < cloud.size(); ++k) {
          if (cloud.classification[k] != 2) continue;
          const Eigen::Vector3d p = cloud.positions[k] - o;
          if (std::abs(p.x() - cx) < 2.0 && std::abs(p.y() - cy) < 2.0) z.push_back(p.z());
        }
        int i = 0, j = 0;
        t.nearestNode(cx, cy, i, j);
        ASSERT_TRUE(t.inside(i, j)) << cx << " " << cy;
        ASSERT_NEAR(t.nodePosition(i, j).x(), cx, 1e-9);
        ASSERT_NEAR(t.nodePosition(i, j).y(), cy, 1e-9);
        if (z.empty()) {
          // Filled hole: the node sits on the cell centre, so it is the filled cell's value (whose
          // range against the data cells it sees is checked above), and the unfilled grid has NaN.
          const int gi = static_cast<int>(std::lround((cx - filled.x0_m) / 4.0));
          const int gj = static_cast<int>(std::lround((cy - filled.y0_m) / 4.0));
          EXPECT_TRUE(std::isnan(raw.z[static_cast<std::size_t>(gj) * raw.nx + gi])) << cx << " " << cy;
          EXPECT_NEAR(t.height(i, j), filled.z[static_cast<std::size_t>(gj) * filled.nx + gi], 1e-9) << cx << " " << cy;
          ++holes;
          continue;
        }
        std::sort(z.begin(), z.end());
        const std::size_t n = z.size();
        const double median = n % 2 ? z[n / 2] : 0.5 * (z[n / 2 - 1] + z[n / 2]);
        EXPECT_NEAR(t.height(i, j), median, 1e-9) << cx << " " << cy << " n " << n;
        ++checked;
      }
  };
  checkNodes(t, -12, -8, 12, 8);
  EXPECT_EQ(checked, 7 * 5);  // the sample is dense around its centre: no hole
  std::string yaml_edge = scenarioWithDem("{file: " + kLas + ", cell_m: 4}", "size_m: [24, 16], origin_m: [36, 28], ");
  yaml_edge.replace(yaml_edge.find("  - id: m1"), 10, "  - {id: m1, pose: {x_m: 48, y_m: 36}}");
  const TruthTerrain t_edge = buildTerrain(parseScenario(yaml_edge, "s.yaml").terrain);
  checkNodes(t_edge, 36, 28, 60, 44);
  EXPECT_EQ(checked + holes, 2 * 7 * 5);
  EXPECT_GT(holes, 5);           // the edge extent has both: holes
  EXPECT_GT(checked, 7 * 5);     // and data cells
  // Between cell centres the surface is the bilinear blend of the four cells.
  const double a = t.height(50, 50);
  EXPECT_TRUE(std::isfinite(a));
  // The whole file at 2 cm would be ~150 M nodes: refused with advice, before any allocation.
  const std::string e = errorOf(scenarioWithDem("{file: " + kLas + "}"));
  EXPECT_NE(e.find("terrain too large"), std::string::npos) << e;
  EXPECT_NE(e.find("a DEM alone sets the extent"), std::string::npos) << e;
  // No point of the requested class.
  const std::string e2 = errorOf(scenarioWithDem("{file: " + kLas + ", ground_class: 9}", "size_m: [4, 4], "));
  EXPECT_NE(e2.find("no points of class 9"), std::string::npos) << e2;
  EXPECT_NE(e2.find("hexbin-crop.las"), std::string::npos) << e2;
}

TEST(DemInputs, LasMeanStatisticAndExplicitOrigin) {
  const std::string yaml = scenarioWithDem(
      "{file: " + kLas + ", cell_m: 5, statistic: mean, geo_origin: [393900, 3689150, 3150]}",
      "size_m: [10, 10], origin_m: [-5, -5], ");
  const Scenario sc = parseScenario(yaml, "s.yaml");
  EXPECT_TRUE(sc.terrain.dem_geo_origin.isApprox(Eigen::Vector3d(393900, 3689150, 3150)));
  const TruthTerrain t = buildTerrain(sc.terrain);
  io::LasReadOptions ro;
  ro.keep_double_positions = true;
  const io::LasCloud cloud = io::readLas(kLas, ro);
  double s = 0;
  int n = 0;
  for (std::size_t k = 0; k < cloud.size(); ++k) {
    if (cloud.classification[k] != 2) continue;
    const Eigen::Vector3d p = cloud.positions[k] - Eigen::Vector3d(393900, 3689150, 3150);
    if (std::abs(p.x()) < 2.5 && std::abs(p.y()) < 2.5) { s += p.z(); ++n; }
  }
  ASSERT_GT(n, 3);
  int i = 0, j = 0;
  t.nearestNode(0.0, 0.0, i, j);
  EXPECT_NEAR(t.height(i, j), s / n, 1e-9);
  const std::string e = errorOf(scenarioWithDem("{file: " + kLas + ", statistic: mode}", "size_m: [4, 4], "));
  EXPECT_NE(e.find("terrain.dem.statistic: unknown statistic 'mode'"), std::string::npos) << e;
}
