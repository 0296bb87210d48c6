// ScanCaster (per-scan polar horizon table + exact cell walk) against the brute-force reference.
#include <gtest/gtest.h>

#include <terramap/sim/scan_caster.hpp>
#include <terramap/sim/truth_terrain.hpp>
#include <terramap/sim/world.hpp>

#include <cmath>
#include <limits>
#include <random>

using namespace terramap;
using namespace terramap::sim;

namespace {

TruthTerrain roughTerrain(std::uint64_t seed) {
  TerrainSpec s;
  s.size_x_m = 6; s.size_y_m = 4; s.resolution_m = 0.02; s.origin_x_m = -3; s.origin_y_m = -2;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> U(0, 1);
  // Sharp bumps and dips (sigma down to 5 cm) so rays graze, pass over and re-enter.
  for (int k = 0; k < 60; ++k)
    s.bumps.push_back({-3 + U(rng) * 6, -2 + U(rng) * 4, (U(rng) - 0.4) * 0.8, 0.05 + U(rng) * 0.4});
  return buildTerrain(s);
}

}  // namespace

TEST(ScanCaster, AgreesWithBruteForceFromManyOrigins) {
  // Dense and sparse tables (ScanCaster::setSparse) alike.
  const TruthTerrain t = roughTerrain(7);
  std::mt19937_64 rng(21);
  std::uniform_real_distribution<double> U(-1, 1);
  const std::vector<Eigen::Vector3d> origins = {
      {0.1, 0.2, 1.5},    // above the middle
      {-2.9, -1.9, 0.9},  // near a corner
      {2.0, 1.0, 0.05},   // low, among the bumps (terrain above the origin nearby)
      {-4.5, 3.0, 2.0},   // outside the grid
      {0.0, 0.0, 0.0}};
  int hits = 0, misses = 0, compared = 0;
  for (const Eigen::Vector3d& o : origins) {
    for (double max_range : {40.0, 2.5}) {  // table over the whole grid / only part of it
      // Directions: random (up and down), near-vertical and horizontal ones.
      std::vector<Eigen::Vector3d> dirs;
      for (int k = 0; k < 200; ++k) dirs.push_back(Eigen::Vector3d(U(rng), U(rng), U(rng) - 0.3).normalized());
      for (int k = 0; k < 20; ++k) dirs.push_back(Eigen::Vector3d(1e-10 * U(rng), 1e-10 * U(rng), -1).normalized());
      dirs.push_back({0, 0, -1});
      dirs.push_back({1, 0, 0});
      dirs.push_back({0, -1, 0});
      double min_slope = std::numeric_limits<double>::infinity();
      for (const auto& d : dirs) {
        const double dxy = std::hypot(d.x(), d.y());
        if (dxy >= 1e-9) min_slope = std::min(min_slope, d.z() / dxy);
      }
      for (const double slope_bound : {-std::numeric_limits<double>::infinity(), min_slope})
      for (const bool sparse : {false, true}) {  // the coarser table of a scan of few rays too
        ScanCaster sc;
        sc.setSparse(sparse);
        sc.build(t, o, max_range, slope_bound);
        EXPECT_EQ(sc.azimuthBins(), sparse ? 256 : 1024);
        EXPECT_EQ(sc.blockLevel(), sparse ? 5 : 4);
        for (const double t_min : {0.0, 0.3}) {
          for (const auto& d : dirs) {
            const double a = sc.cast(d, t_min, max_range);
            const double b = t.raycastReference(o, d, t_min, max_range);
            ASSERT_EQ(std::isnan(a), std::isnan(b)) << o.transpose() << " | " << d.transpose() << " " << a << " " << b;
            ++compared;
            if (std::isnan(a)) { ++misses; continue; }
            ++hits;
            ASSERT_NEAR(a, b, 1e-12 * std::max(1.0, b)) << o.transpose() << " | " << d.transpose();
          }
        }
      }
    }
  }
  EXPECT_GT(hits, 1000);
  EXPECT_GT(misses, 1000);
  EXPECT_EQ(compared, hits + misses);
}

TEST(ScanCaster, BatchEqualsSingleCastsAndReportsTheHitCell) {
  const TruthTerrain t = roughTerrain(3);
  const Eigen::Vector3d o(0.3, -0.4, 1.2);
  ScanCaster sc;
  sc.build(t, o, 30.0);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> U(-1, 1);
  std::vector<Eigen::Vector3d> dirs;
  for (int k = 0; k < 301; ++k) dirs.push_back(Eigen::Vector3d(U(rng), U(rng), U(rng) - 0.5).normalized());
  std::vector<double> tb(dirs.size());
  std::vector<int> ib(dirs.size(), -1), jb(dirs.size(), -1);
  sc.castBatch(dirs.data(), static_cast<int>(dirs.size()), 0.2, 30.0, tb.data(), ib.data(), jb.data());
  int hits = 0;
  for (std::size_t k = 0; k < dirs.size(); ++k) {
    int i = -1, j = -1;
    const double ts = sc.cast(dirs[k], 0.2, 30.0, &i, &j);
    ASSERT_EQ(std::isnan(ts), std::isnan(tb[k]));
    if (std::isnan(ts)) continue;
    ++hits;
    EXPECT_EQ(ts, tb[k]);  // bit-identical
    EXPECT_EQ(i, ib[k]);
    EXPECT_EQ(j, jb[k]);
    // The hit point lies in (or on the border of) the reported cell and on the surface.
    const Eigen::Vector3d p = o + dirs[k] * ts;
    const double u = (p.x() - t.originX()) / t.resolution() - i, v = (p.y() - t.originY()) / t.resolution() - j;
    EXPECT_GE(u, -1e-6);
    EXPECT_LE(u, 1 + 1e-6);
    EXPECT_GE(v, -1e-6);
    EXPECT_LE(v, 1 + 1e-6);
    EXPECT_NEAR(p.z(), t.heightAt(p.x(), p.y()), 1e-9);
  }
  EXPECT_GT(hits, 100);
}

TEST(ScanCaster, SeesTerrainChangesAfterARebuild) {
  TruthTerrain t = roughTerrain(11);
  const Eigen::Vector3d o(0, 0, 2.0);
  const Eigen::Vector3d d = Eigen::Vector3d(1, 0.2, -1.2).normalized();
  ScanCaster sc;
  sc.build(t, o, 20.0);
  const double before = sc.cast(d, 0, 20);
  ASSERT_FALSE(std::isnan(before));
  // Raise a wall across the ray halfway to the old hit; the pyramid and table are rebuilt.
  const Eigen::Vector3d mid = o + d * (0.5 * before);
  int ci = 0, cj = 0;
  t.nearestNode(mid.x(), mid.y(), ci, cj);
  for (int j = cj - 5; j <= cj + 5; ++j)
    for (int i = ci - 5; i <= ci + 5; ++i) t.addLoose(i, j, 3.0, 2.5);
  t.refreshPyramid(ci - 5, cj - 5, ci + 5, cj + 5);
  sc.build(t, o, 20.0);
  const double after = sc.cast(d, 0, 20);
  EXPECT_LT(after, 0.55 * before);
  EXPECT_NEAR(after, t.raycastReference(o, d, 0, 20), 1e-12);
}

TEST(ScanCaster, TableBuiltInQuadrantTasksEqualsTheSerialOne) {
  // With an executor the table is filled by four azimuth-quadrant tasks that each walk only the
  // blocks near their side of the origin: the casts must be bit-identical to the serial build's
  // and exact, for origins inside, on block boundaries and outside the grid on every side.
  const TruthTerrain t = roughTerrain(11);
  Executor ex(2);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> U(-1, 1);
  std::vector<Eigen::Vector3d> dirs;
  for (int k = 0; k < 400; ++k) dirs.push_back(Eigen::Vector3d(U(rng), U(rng), U(rng) - 0.5).normalized());
  // Rays grazing the quadrant boundaries (the origin's axes).
  for (const double e : {0.0, 1e-7, -1e-7})
    for (const Eigen::Vector3d& a : {Eigen::Vector3d(1, e, -0.2), Eigen::Vector3d(-1, e, -0.2), Eigen::Vector3d(e, 1, -0.2),
                                     Eigen::Vector3d(e, -1, -0.2)})
      dirs.push_back(a.normalized());
  const double bs = 0.32;  // 16 cells of 2 cm: the table's block size here
  const std::vector<Eigen::Vector3d> origins = {
      {0.1, 0.2, 1.2},  {-3 + 5 * bs, -2 + 3 * bs, 0.8},  // on a block corner
      {-4.0, 0.3, 1.0}, {4.0, -0.3, 1.0}, {0.5, -3.5, 1.0}, {-0.5, 3.5, 1.0}, {-5, -4, 2.0}, {5, 4, 0.4}};
  int hits = 0;
  for (const Eigen::Vector3d& o : origins) {
    for (const double max_range : {40.0, 2.0}) {
      ScanCaster serial, quads;
      serial.build(t, o, max_range);
      quads.build(t, o, max_range, -std::numeric_limits<double>::infinity(), &ex);
      for (const auto& d : dirs) {
        const double a = serial.cast(d, 0.0, max_range), b = quads.cast(d, 0.0, max_range);
        const double r = t.raycastReference(o, d, 0.0, max_range);
        ASSERT_EQ(std::isnan(a), std::isnan(b)) << o.transpose() << " | " << d.transpose();
        ASSERT_EQ(std::isnan(a), std::isnan(r)) << o.transpose() << " | " << d.transpose();
        if (std::isnan(a)) continue;
        ++hits;
        ASSERT_EQ(a, b) << o.transpose() << " | " << d.transpose();
        ASSERT_NEAR(a, r, 1e-12 * std::max(1.0, r));
      }
    }
  }
  EXPECT_GT(hits, 1000);
}
