// lidar_fusion on real recordings (the KITTI frames at TERRAMAP_KITTI_DIR, skipped without them;
// the LAS tile from the repository's data/):
//  - KITTI HDL-64E frames 0-4 (CC BY-NC-SA 3.0, via url-kaist/patchwork-plusplus) fused with
//    the helper-derived ICP poses, checked against frame 5's ground points (held out);
//  - PDAL's hexbin-crop.las airborne ground points (class 2) gridded by lidar_fusion and by
//    a direct per-cell median of the same points.
#include "kitti_data.hpp"
#include "lidar_fusion.hpp"

#include <terramap/eval/statistics.hpp>
#include <terramap/io/readers.hpp>
#include <terramap/io/trajectory.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>

using namespace terramap;
using namespace terramap::plugins;
using L = LidarFusionLayers;

namespace {

const std::string kKitti = terramap::test::kittiDir() + "/";

double quantile(std::vector<double> v, double q) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  const size_t k = static_cast<size_t>(q * static_cast<double>(v.size() - 1));
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  return v[k];
}

std::string frame(int k) {
  char b[32];
  std::snprintf(b, sizeof b, "%06d.bin", k);
  return kKitti + b;
}

/// Ground points of one scan, chosen from that scan alone (no map involved): on a 1 m grid
/// in the sensor frame, points within 0.10 m of their cell's lowest point, where that lowest
/// point lies within 0.5 m of the nominal ground plane (HDL-64E mounted 1.73 m up on KITTI's
/// car) and the range is 3-40 m (closer is the car itself, farther is sparse).
std::vector<Eigen::Vector3d> groundPoints(const std::vector<PointXYZI>& pts) {
  std::map<std::pair<int, int>, float> lowest;
  auto key = [](const PointXYZI& p) {
    return std::make_pair(static_cast<int>(std::floor(p.x)), static_cast<int>(std::floor(p.y)));
  };
  auto usable = [](const PointXYZI& p) {
    const double r = std::hypot(p.x, p.y);
    return std::isfinite(p.z) && r > 3.0 && r < 40.0;
  };
  for (const PointXYZI& p : pts) {
    if (!usable(p)) continue;
    auto [it, fresh] = lowest.emplace(key(p), p.z);
    if (!fresh) it->second = std::min(it->second, p.z);
  }
  std::vector<Eigen::Vector3d> out;
  for (const PointXYZI& p : pts) {
    if (!usable(p)) continue;
    const float lo = lowest[key(p)];
    if (std::abs(lo + 1.73f) < 0.5f && p.z - lo < 0.10f) out.emplace_back(p.x, p.y, p.z);
  }
  return out;
}

}  // namespace

TEST(LidarFusionRealData, KittiFramesZeroToFourPredictFrameFiveGround) {
  TERRAMAP_SKIP_WITHOUT_KITTI();
  // Poses: row k of DERIVED_icp_relative_poses.txt maps frame k into frame k-1; chained,
  // element k is T_0_k, so the map frame is frame 0's sensor frame (z up, ground ~ -1.73 m).
  const auto rel = io::readRelativePoses(kKitti + "DERIVED_icp_relative_poses.txt");
  ASSERT_EQ(rel.size(), 5u);
  const std::vector<Eigen::Isometry3d> T_0 = io::chainRelativePoses(rel);
  ASSERT_EQ(T_0.size(), 6u);
  EXPECT_NEAR(T_0[5].translation().x(), 0.682 + 0.696 + 0.716 + 0.731 + 0.745, 0.05);

  // 0.2 m cells, 100 m x 100 m around the middle of the drive.
  LayeredMap map(Geometry(0.2, Size(500, 500), Position(1.75, 0.0)), MapOptions{64, false});
  LidarFusion f;
  LidarFusionConfig c;  // defaults: range_based, cleanup every 4th ray, ramp on
  f.configure(c);
  f.attach(map);
  Executor ex(2);
  long fused = 0, lost_cells = 0;
  for (int k = 0; k < 5; ++k) {
    PointCloud pc;
    pc.stamp = 0.1 * k;
    pc.T_map_sensor = T_0[static_cast<size_t>(k)];
    pc.points = io::readKittiBin(frame(k));
    f.advanceTime(map, ex, pc.stamp);
    const FusionStats s = f.fuse(map, ex, pc);
    EXPECT_GT(s.points_fused, 80000) << "frame " << k;
    lost_cells += s.cells_forgotten + s.cells_invalidated;
    fused += s.points_fused;
  }

  const std::vector<PointXYZI> f5 = io::readKittiBin(frame(5));
  const std::vector<Eigen::Vector3d> ground = groundPoints(f5);
  ASSERT_GT(ground.size(), 20000u);
  const LayerId E = map.layerId(L::kElevation);
  std::vector<double> dz;
  long inside = 0;
  for (const Eigen::Vector3d& ps : ground) {
    const Eigen::Vector3d pm = T_0[5] * ps;
    const auto idx = map.geometry().indexAt(pm.head<2>());
    if (!idx) continue;
    ++inside;
    const float h = map.at(E, *idx);
    if (!std::isnan(h)) dz.push_back(std::abs(pm.z() - h));
  }
  const double coverage = static_cast<double>(dz.size()) / static_cast<double>(inside);
  const double med = quantile(dz, 0.5), p90 = quantile(dz, 0.9);
  std::printf("[ KITTI    ] fused %ld points from frames 0-4; frame 5: %zu ground points, %ld in map, "
              "coverage %.3f, median |dz| %.4f m, p90 |dz| %.4f m\n",
              fused, ground.size(), inside, coverage, med, p90);
  // Bounds from the noise model: a held-out ground point differs from its fused cell by its
  // own range noise (HDL-64E, 0.02 m 1-sigma), the pose error (the ICP residual, ~0.03 m,
  // SOURCE.txt) and the fused cell's own noise (a mean of several returns: below the point's),
  // sigma = sqrt(0.02^2 + 0.03^2 + 0.02^2) = 0.041 m (the range noise counted whole, although
  // it is mostly horizontal on the ground), plus the height change inside a 0.2 m cell, at
  // most 0.2 * 3 % = 0.006 m on a cambered road. So |dz| is half-normal: median 0.674 sigma +
  // 0.006 = 0.034 m, p90 1.645 sigma + 0.006 = 0.074 m. A broken transform, index or fusion
  // formula lands at decimetres to metres.
  const double sigma = std::sqrt(0.02 * 0.02 + 0.03 * 0.03 + 0.02 * 0.02), relief = 0.2 * 0.03;
  EXPECT_LT(med, 0.674 * sigma + relief);
  EXPECT_LT(p90, 1.645 * sigma + relief);
  // Coverage, from the geometry of the returns: a cell is known once a return has been fused
  // into it, and only forgetting (variance over max_variance_m2) and invalidation by the
  // visibility cleanup make it unknown again (both counted in FusionStats). Returns 3-40 m out
  // and below the sensor pass every gate (min/max range 0.5/100 m, height 1 m, the ramp allows
  // 0.2 m at least), so: the cells such returns of frames 0-4 hit, still unknown at the end, are
  // at most the cells forgotten or invalidated; and frame 5's ground finds a height only in
  // cells some return hit (any return: the gates can only remove).
  std::vector<char> hit_any(static_cast<size_t>(500 * 500), 0), hit_safe(static_cast<size_t>(500 * 500), 0);
  for (int k = 0; k < 5; ++k) {
    const Eigen::Isometry3d& T = T_0[static_cast<size_t>(k)];
    for (const PointXYZI& p : io::readKittiBin(frame(k))) {
      if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) continue;
      const Eigen::Vector3d pm = T * Eigen::Vector3d(p.x, p.y, p.z);
      const auto idx = map.geometry().indexAt(pm.head<2>());
      if (!idx) continue;
      const size_t c = static_cast<size_t>(idx->x() * 500 + idx->y());
      hit_any[c] = 1;
      const double r = std::sqrt(double(p.x) * p.x + double(p.y) * p.y + double(p.z) * p.z);
      if (r >= 3.0 && r <= 40.0 && pm.z() < T.translation().z()) hit_safe[c] = 1;
    }
  }
  const Eigen::MatrixXf Em = map.toMatrix(E);
  long unknown_hit = 0, safe_cells = 0;
  for (int i = 0; i < 500; ++i)
    for (int j = 0; j < 500; ++j) {
      if (!hit_safe[static_cast<size_t>(i * 500 + j)]) continue;
      ++safe_cells;
      unknown_hit += std::isnan(Em(i, j)) ? 1 : 0;
    }
  EXPECT_GT(safe_cells, 10000);
  EXPECT_LE(unknown_hit, lost_cells) << "cells hit by gate-safe returns but unknown";
  long seen = 0;
  for (const Eigen::Vector3d& ps : ground) {
    const auto idx = map.geometry().indexAt((T_0[5] * ps).head<2>());
    if (idx) seen += hit_any[static_cast<size_t>(idx->x() * 500 + idx->y())];
  }
  EXPECT_LE(static_cast<long>(dz.size()), seen) << "coverage " << coverage << " of " << inside;
  std::printf("[ KITTI    ] cells hit by gate-safe returns %ld, unknown %ld (forgotten + invalidated %ld); "
              "frame-5 ground points in hit cells %ld, with a height %zu\n", safe_cells, unknown_hit, lost_cells, seen, dz.size());
}

TEST(LidarFusionRealData, LasHexbinGroundIsThePerCellMeanWithinASigmaOfTheMedian) {
  const io::LasCloud las = io::readLas(std::string(TERRAMAP_DATA_DIR) + "/las_hexbin/hexbin-crop.las");
  const std::vector<PointXYZI> ground = las.pointsOfClass(2);
  ASSERT_EQ(ground.size(), 35318u);  // SOURCE.txt
  // 2 m cells over the 293 m x 201 m site (points are relative to the rounded bbox centre).
  const Geometry g(2.0, Size(152, 104));
  LayeredMap map(g, MapOptions{32, false});
  LidarFusion f;
  LidarFusionConfig c;
  c.enable_visibility_cleanup = false;  // a nadir gridding, not a scan: no rays
  c.enable_ramped_height_range = false;
  c.max_range_m = 5000.0;
  c.range_noise_b = 0.0;
  // The per-point variance must cover the relief inside a 2 m cell of mountain terrain
  // (slopes up to ~30 deg: ~1 m), not only the sensor noise, or the gate would call the
  // uphill half of a cell an outlier. sigma = 0.5 m -> gate 2 * sqrt(2) * 0.5 = 1.41 m.
  c.range_noise_a_m = 0.5;
  f.configure(c);
  f.attach(map);
  // The sensor sits at the origin of the points with its gates opened, so the points enter
  // unchanged (an identity pose keeps their float32 heights exact).
  c.min_range_m = 0.0;
  c.max_height_above_sensor_m = 1e9;
  f.configure(c);
  PointCloud pc;
  pc.points = ground;
  Executor ex(2);
  const FusionStats s = f.fuse(map, ex, pc);
  EXPECT_EQ(s.dropped_outside_map, 0);

  // Direct per-cell median of the same points (independent of the plugin).
  std::map<std::pair<int, int>, std::vector<double>> cells;
  for (const PointXYZI& p : pc.points) {
    const auto idx = g.indexAt(Position(p.x, p.y));
    ASSERT_TRUE(idx.has_value());
    cells[{idx->x(), idx->y()}].push_back(p.z);
  }
  const Eigen::MatrixXf E = map.toMatrix(map.layerId(L::kElevation));
  long known = 0, small_cells = 0, outside_range = 0;
  std::vector<double> diffs;
  double worst_small = 0.0;
  for (int i = 0; i < g.size().x(); ++i)
    for (int j = 0; j < g.size().y(); ++j) {
      auto it = cells.find({i, j});
      const bool has = it != cells.end();
      ASSERT_EQ(has, !std::isnan(E(i, j))) << "known-cell sets differ at " << i << "," << j;
      if (!has) continue;
      ++known;
      std::vector<double>& v = it->second;
      const std::vector<double> in_order = v;
      std::sort(v.begin(), v.end());
      const size_t n = v.size();
      const double median = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
      diffs.push_back(std::abs(E(i, j) - median));
      // Whatever the gate rejected, a cell is a weighted mean of some of its own points, so it
      // lies within their range (float32 heights of up to ~50 m: 4e-6 m of rounding per
      // operation, at most a few per point).
      if (E(i, j) < v.front() - 1e-4 || E(i, j) > v.back() + 1e-4) ++outside_range;
      // One point: the cell is that point. Two points (equal weights): the mean (= the
      // median) unless they differ by more than the gate k sqrt(v + v) = 2 sqrt(0.5) m, in
      // which case the second is an outlier and the cell keeps the first (input order).
      if (n <= 2) {
        ++small_cells;
        double expect = in_order[0];
        if (n == 2 && std::abs(in_order[1] - in_order[0]) <= 2.0 * std::sqrt(0.5)) expect = median;
        worst_small = std::max(worst_small, std::abs(E(i, j) - expect));
      }
    }
  const double mdn = quantile(diffs, 0.5), p95 = quantile(diffs, 0.95);
  std::printf("[ LAS      ] %ld known cells (%ld with <= 2 points), outliers %ld, |fused - median|: "
              "median %.4f m, p95 %.4f m, max error vs the hand rule over <=2-point cells %.2e m\n",
              known, small_cells, s.outliers, mdn, p95, worst_small);
  EXPECT_LT(worst_small, 1e-4);
  EXPECT_EQ(outside_range, 0);

  // With the gate opened (k large) nothing is rejected and equal point variances make the
  // sequential precision-weighted fusion the plain mean of the cell's points: every cell
  // equals the mean of its points (float rounding: n points, a few operations each, 4e-6 m
  // apiece at these heights: 1e-5 m per point is ample), and so lies within one standard
  // deviation of their median (|mean - median| <= sigma for any sample): the fused grid is the
  // mean grid, not the median grid, and differs from it by the relief inside the cell.
  LayeredMap open_map(g, MapOptions{32, false});
  LidarFusion fo;
  c.mahalanobis_thresh = 1e6;
  fo.configure(c);
  fo.attach(open_map);
  const FusionStats so = fo.fuse(open_map, ex, pc);
  EXPECT_EQ(so.outliers, 0);
  const Eigen::MatrixXf Eo = open_map.toMatrix(open_map.layerId(L::kElevation));
  long not_mean = 0, beyond_sigma = 0;
  for (const auto& [ij, v] : cells) {
    double sum = 0, sq = 0;
    for (double z : v) sum += z;
    const double mean = sum / static_cast<double>(v.size());
    for (double z : v) sq += (z - mean) * (z - mean);
    const double sd = std::sqrt(sq / static_cast<double>(v.size()));
    const size_t n = v.size();
    const double median = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);  // v sorted above
    const double e = Eo(ij.first, ij.second);
    if (std::abs(e - mean) > 1e-5 * static_cast<double>(n)) ++not_mean;
    if (std::abs(e - median) > sd + 1e-5 * static_cast<double>(n)) ++beyond_sigma;
  }
  EXPECT_EQ(not_mean, 0);
  EXPECT_EQ(beyond_sigma, 0);
}

namespace {

struct WalkRun {
  std::vector<Eigen::MatrixXf> layers;
  FusionStats totals;
  std::vector<FusionStats> per_scan;
};

/// The KITTI frames driven forward and back (0..5, 4..0) into a 20 m map that follows the
/// sensor, cleanup on every ray: stale cells, unknown cells and cells seen from elsewhere meet
/// the rays of every scan.
WalkRun kittiDrive(int threads, bool cell_by_cell, CleanupWalk walk = CleanupWalk::Exact, int stride = 1) {
  const std::vector<Eigen::Isometry3d> T0 =
      io::chainRelativePoses(io::readRelativePoses(kKitti + "DERIVED_icp_relative_poses.txt"));
  LayeredMap map(Geometry(0.05, Size(400, 400)), MapOptions{64, false});
  LidarFusion f;
  LidarFusionConfig c;
  c.follow_robot = true;
  c.cleanup_ray_stride = stride;
  c.cleanup_walk = walk;
  f.configure(c);
  f.forceCellByCellWalk(cell_by_cell);
  f.attach(map);
  Executor ex(threads);
  WalkRun r;
  const int order[] = {0, 1, 2, 3, 4, 5, 4, 3, 2, 1, 0};
  for (int k = 0; k < 11; ++k) {
    PointCloud pc;
    pc.stamp = 0.1 * k;
    pc.T_map_sensor = Eigen::Translation3d(0.0, 0.0, 1.73) * T0[static_cast<size_t>(order[k])];
    pc.points = io::readKittiBin(frame(order[k]));
    f.advanceTime(map, ex, pc.stamp);
    f.followTo(map, pc.T_map_sensor.translation());
    r.per_scan.push_back(f.fuse(map, ex, pc));
  }
  for (const char* name : {L::kElevation, L::kVariance, L::kIsValid, L::kTimeSinceUpdate, L::kUpperBound,
                           L::kIsUpperBound, L::kHits})
    r.layers.push_back(map.toMatrix(map.layerId(name)));
  r.totals = f.totals();
  return r;
}

bool sameBits(const Eigen::MatrixXf& a, const Eigen::MatrixXf& b) {
  return a.rows() == b.rows() && a.cols() == b.cols() &&
         std::memcmp(a.data(), b.data(), sizeof(float) * static_cast<size_t>(a.size())) == 0;
}

}  // namespace

TEST(LidarFusionRealData, BlockSkippingRayWalkMatchesTheCellByCellWalkBitForBit) {
  TERRAMAP_SKIP_WITHOUT_KITTI();
  // The cleanup jumps over 8 x 8 blocks where no cell could change; walking every cell instead
  // must give the same layers and counters, at 1 and 2 threads (the workers then split the
  // octants, and each slot skips on its own bounds).
  const WalkRun cells = kittiDrive(2, true);
  for (int threads : {1, 2}) {
    const WalkRun blocks = kittiDrive(threads, false);
    for (size_t l = 0; l < cells.layers.size(); ++l)
      EXPECT_TRUE(sameBits(cells.layers[l], blocks.layers[l])) << threads << " threads, layer " << l;
    for (size_t k = 0; k < cells.per_scan.size(); ++k) {
      const FusionStats &a = cells.per_scan[k], &b = blocks.per_scan[k];
      EXPECT_EQ(a.rays, b.rays) << "scan " << k;
      EXPECT_EQ(a.ray_cells, b.ray_cells) << "scan " << k;
      EXPECT_EQ(a.cells_penetrated, b.cells_penetrated) << "scan " << k;
      EXPECT_EQ(a.cells_invalidated, b.cells_invalidated) << "scan " << k;
      EXPECT_EQ(a.upper_bounds, b.upper_bounds) << "scan " << k;
    }
    // The skipping did happen, and saved most of the reads.
    EXPECT_EQ(cells.totals.ray_cells_read, cells.totals.ray_cells);
    EXPECT_LT(blocks.totals.ray_cells_read, blocks.totals.ray_cells / 3) << threads << " threads";
  }
  // Not vacuous: rays bounded unknown cells and passed under stale ones, invalidating some.
  EXPECT_GT(cells.totals.upper_bounds, 10000);
  EXPECT_GT(cells.totals.cells_penetrated, 1000);
  EXPECT_GT(cells.totals.cells_invalidated, 10);
}

TEST(LidarFusionRealData, FanWalkActsOnNearlyTheCellsOfTheExactWalkWithAFractionOfTheReads) {
  TERRAMAP_SKIP_WITHOUT_KITTI();
  // The same drive, every ray, with the fan walk: each azimuth bin's rays walked together along
  // its centre line, within half a cell of each ray at 10 m. It must land where the exact walk
  // lands (the same rays, the same cells spanned, nearly the same cells cleaned and bounded, to
  // the same heights) for a small part of its reads, bit for bit at 1 and 2 threads.
  const WalkRun exact = kittiDrive(2, false);
  const WalkRun fan = kittiDrive(2, false, CleanupWalk::Fan);
  // Bit for bit at 1 thread, and without the block skipping (every column of every bin's line).
  for (const WalkRun& other : {kittiDrive(1, false, CleanupWalk::Fan), kittiDrive(2, true, CleanupWalk::Fan)}) {
    for (size_t l = 0; l < fan.layers.size(); ++l) EXPECT_TRUE(sameBits(fan.layers[l], other.layers[l])) << "layer " << l;
    EXPECT_EQ(fan.totals.cells_penetrated, other.totals.cells_penetrated);
    EXPECT_EQ(fan.totals.cells_invalidated, other.totals.cells_invalidated);
    EXPECT_EQ(fan.totals.upper_bounds, other.totals.upper_bounds);
    EXPECT_EQ(fan.totals.ray_cells, other.totals.ray_cells);
  }

  const FusionStats &e = exact.totals, &f = fan.totals;
  EXPECT_EQ(f.rays, e.rays);
  EXPECT_NEAR(static_cast<double>(f.ray_cells) / e.ray_cells, 1.0, 1e-4);
  EXPECT_LT(f.ray_cells_read, e.ray_cells_read / 8);
  EXPECT_NEAR(static_cast<double>(f.cells_penetrated) / e.cells_penetrated, 1.0, 0.02);
  EXPECT_NEAR(static_cast<double>(f.cells_invalidated) / e.cells_invalidated, 1.0, 0.03);
  EXPECT_NEAR(static_cast<double>(f.upper_bounds) / e.upper_bounds, 1.0, 0.005);

  // The final map, cell by cell, against the exact walk's: known in both, and bounded (unknown
  // with an upper bound) in both, with bounds close.
  struct Agreement {
    double known, bounded, median, p90;
  };
  auto agreement = [&](const WalkRun& r) {
    const Eigen::MatrixXf &e0 = exact.layers[0], &e1 = r.layers[0], &u0 = exact.layers[4], &u1 = r.layers[4];
    long known_e = 0, known_both = 0, bound_e = 0, bound_both = 0;
    std::vector<double> diff;
    for (Eigen::Index k = 0; k < e0.size(); ++k) {
      const bool ke = !std::isnan(e0(k)), kr = !std::isnan(e1(k));
      known_e += ke;
      known_both += ke && kr;
      const bool be = !ke && !std::isnan(u0(k)), br = !kr && !std::isnan(u1(k));
      bound_e += be;
      if (be && br) {
        ++bound_both;
        diff.push_back(std::abs(static_cast<double>(u0(k)) - u1(k)));
      }
    }
    EXPECT_GT(bound_e, 10000);
    std::sort(diff.begin(), diff.end());
    return Agreement{static_cast<double>(known_both) / known_e, static_cast<double>(bound_both) / bound_e,
                     eval::percentileSorted(diff, 50.0), eval::percentileSorted(diff, 90.0)};  // NaN if none: fails
  };
  const Agreement a = agreement(fan);
  EXPECT_GT(a.known, 0.999);
  EXPECT_GT(a.bounded, 0.995);
  EXPECT_LT(a.median, 0.003) << "median |upper bound difference| (m)";
  EXPECT_LT(a.p90, 0.02) << "90th percentile (m)";
  std::printf("fan/exact: penetrated %ld/%ld, invalidated %ld/%ld, bounds %ld/%ld, reads %ld/%ld; known in both %.5f, "
              "bounded in both %.5f, |bound difference| median %.4f m, p90 %.4f m\n",
              f.cells_penetrated, e.cells_penetrated, f.cells_invalidated, e.cells_invalidated, f.upper_bounds,
              e.upper_bounds, f.ray_cells_read, e.ray_cells_read, a.known, a.bounded, a.median, a.p90);
  // The exact walk on every 4th ray (the default before the fan walk) lands much further from
  // every ray than the fan walk does.
  const WalkRun fourth = kittiDrive(2, false, CleanupWalk::Exact, 4);
  const Agreement a4 = agreement(fourth);
  std::printf("exact every 4th ray/exact: penetrated %ld, invalidated %ld, bounds %ld; bounded in both %.5f, "
              "|bound difference| median %.4f m, p90 %.4f m\n",
              fourth.totals.cells_penetrated, fourth.totals.cells_invalidated, fourth.totals.upper_bounds, a4.bounded,
              a4.median, a4.p90);
  EXPECT_LT(fourth.totals.cells_invalidated, e.cells_invalidated / 2);
  EXPECT_GT(a4.p90, 3 * a.p90);
}
