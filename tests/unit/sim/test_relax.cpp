// relaxLoose (which sweeps only the bounding box of the loose soil) against a plain reference
// that sweeps every node of the grid, written from the model in docs/sim.md.
#include <gtest/gtest.h>

#include <terramap/sim/blade_physics.hpp>
#include <terramap/sim/world.hpp>

#include <cmath>
#include <random>
#include <vector>

using namespace terramap;
using namespace terramap::sim;

namespace {

/// One Jacobi sweep over the whole grid: on every edge between two nodes not under the blade,
/// loose soil slides from the higher node (if it has loose soil) by a quarter of the height
/// difference in excess of res * tan(repose); a node's outflows are scaled down to the loose
/// soil it has; moves are applied in raster order (x-edge then y-edge per node).
bool referenceSweep(TruthTerrain& t, const std::vector<char>& under_blade, double max_step) {
  const int nx = t.nx(), ny = t.ny();
  const std::size_t n = static_cast<std::size_t>(nx) * ny;
  std::vector<double> fx(n, 0.0), fy(n, 0.0), out(n, 0.0), L(n), H(n);
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) {
      L[t.index(i, j)] = t.loose(i, j);
      H[t.index(i, j)] = t.height(i, j);
    }
  bool moved = false;
  auto edge = [&](std::size_t a, std::size_t b, std::vector<double>& f) {
    if (under_blade[a] || under_blade[b] || !(L[a] > 0.0 || L[b] > 0.0)) return;
    const double dh = H[a] - H[b];
    const double ex = std::abs(dh) - max_step;
    const std::size_t giver = dh > 0 ? a : b;
    if (!(ex > 0) || !(L[giver] > 0.0)) return;
    f[a] = dh > 0 ? 0.25 * ex : -0.25 * ex;
    out[giver] += 0.25 * ex;
    moved = true;
  };
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) {
      const std::size_t a = t.index(i, j);
      if (i + 1 < nx) edge(a, a + 1, fx);
      if (j + 1 < ny) edge(a, a + nx, fy);
    }
  if (!moved) return false;
  for (std::size_t k = 0; k < n; ++k) out[k] = (out[k] > L[k] && out[k] > 0) ? L[k] / out[k] : 1.0;
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) {
      const std::size_t a = t.index(i, j);
      if (fx[a] > 0) t.moveLoose(i, j, i + 1, j, fx[a] * out[a]);
      else if (fx[a] < 0) t.moveLoose(i + 1, j, i, j, -fx[a] * out[a + 1]);
      if (fy[a] > 0) t.moveLoose(i, j, i, j + 1, fy[a] * out[a]);
      else if (fy[a] < 0) t.moveLoose(i, j + 1, i, j, -fy[a] * out[a + nx]);
    }
  return true;
}

}  // namespace

TEST(Relax, BoundingBoxSweepsEqualFullGridSweepsBitForBit) {
  TerrainSpec s;
  s.size_x_m = 4; s.size_y_m = 3; s.origin_x_m = -2; s.origin_y_m = -1.5; s.resolution_m = 0.02;
  s.bumps.push_back({0.6, 0.3, 0.1, 0.5});
  TruthTerrain fast = buildTerrain(s);
  // Loose piles ahead of an upright blade at the origin facing +x (all well inside the relax
  // box: 1.5 m ahead, 0.5 m to the sides), one of them against the blade face.
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> U(0, 1);
  for (int k = 0; k < 25; ++k) {
    int ci = 0, cj = 0;
    fast.nearestNode(0.1 + 0.9 * U(rng), -0.7 + 1.4 * U(rng), ci, cj);
    const int r = 1 + static_cast<int>(4 * U(rng));
    const double hgt = 0.02 + 0.1 * U(rng);
    for (int j = cj - r; j <= cj + r; ++j)
      for (int i = ci - r; i <= ci + r; ++i) fast.addLoose(i, j, hgt, hgt / 1.2);
  }
  int bi = 0, bj = 0;
  fast.nearestNode(0.02, 0.0, bi, bj);
  for (int j = bj - 40; j <= bj + 40; ++j) fast.addLoose(bi, j, 0.15, 0.12);
  TruthTerrain ref = fast;
  const TruthTerrain initial = fast;

  const SoilProperties soil = soilProperties(SoilFamily::Loam, 0.5);
  const SoilField field(soil, {});
  BladeGeometry g;
  const Eigen::Isometry3d T = Eigen::Isometry3d::Identity();  // edge centre at the origin
  // Nodes under the upright blade: |y| <= width/2 + res/2 and -2 res < x <= 0 (band behind the
  // edge: max(res, height * |horizontal z axis|) + res = 2 res for an upright blade).
  const double res = s.resolution_m;
  std::vector<char> under(static_cast<std::size_t>(ref.nx()) * ref.ny(), 0);
  for (int j = 0; j < ref.ny(); ++j)
    for (int i = 0; i < ref.nx(); ++i) {
      const Eigen::Vector2d p = ref.nodePosition(i, j);
      under[ref.index(i, j)] = std::abs(p.y()) <= 0.5 * g.width_m + 0.5 * res && p.x() <= 0.0 && p.x() > -2 * res;
    }
  const double max_step = res * std::tan(soil.repose_rad);
  for (int call = 0; call < 6; ++call) {
    relaxLoose(fast, field, T, g, 1.5, 0.5, 2);
    for (int it = 0; it < 2; ++it)
      if (!referenceSweep(ref, under, max_step)) break;
  }
  int moved_nodes = 0;
  for (int j = 0; j < ref.ny(); ++j)
    for (int i = 0; i < ref.nx(); ++i) {
      ASSERT_EQ(fast.loose(i, j), ref.loose(i, j)) << i << " " << j;
      ASSERT_EQ(fast.looseBank(i, j), ref.looseBank(i, j)) << i << " " << j;
      ASSERT_EQ(fast.height(i, j), ref.height(i, j)) << i << " " << j;
    }
  // The comparison is not vacuous: soil did slide, onto nodes that had none.
  int new_nodes = 0;
  for (int j = 0; j < ref.ny(); ++j)
    for (int i = 0; i < ref.nx(); ++i) {
      moved_nodes += ref.loose(i, j) != initial.loose(i, j);
      new_nodes += ref.loose(i, j) > 0.0 && initial.loose(i, j) == 0.0;
    }
  EXPECT_GT(moved_nodes, 500);
  EXPECT_GT(new_nodes, 100);
}
