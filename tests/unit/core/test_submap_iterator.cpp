// SubmapIterator against brute force (LayeredMap::bufferIndex, tileOfBuffer, tileRect, at):
// random rectangles on moved ring buffers (rows and columns that wrap), partial edge tiles,
// rectangles clipped at or entirely off the map, and empty ones.
#include <terramap/core/submap_iterator.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

using namespace terramap;

namespace {
struct Where {
  int tile;
  long offset;
};
Where bruteForce(const LayeredMap& m, int i, int j) {
  const Index b = m.bufferIndex(Index(i, j));
  const int t = m.tileOfBuffer(b.x(), b.y());
  const CellRect r = m.tileRect(t);
  return {t, static_cast<long>(b.x() - r.r0) * m.tileSize() + (b.y() - r.c0)};
}
}  // namespace

TEST(SubmapIterator, SpansCoverTheRectangleInRowMajorOrderAtTheRightCells) {
  std::mt19937 rng(21);
  for (int trial = 0; trial < 12; ++trial) {
    LayeredMap m(Geometry(0.1, Size(37 + trial, 50 - trial)), MapOptions{8 + (trial % 3) * 4, false});
    const LayerId id = m.addLayer("a", "m");
    std::uniform_real_distribution<double> c(-3.0, 3.0);
    m.move(Position(c(rng), c(rng)));
    const int R = m.geometry().size().x(), C = m.geometry().size().y();
    for (int i = 0; i < R; ++i)
      for (int j = 0; j < C; ++j) m.set(id, Index(i, j), static_cast<float>(i * 1000 + j));
    std::uniform_int_distribution<int> org(-8, 55), ext(-2, 40);
    for (int n = 0; n < 150; ++n) {
      const CellRect want{org(rng), org(rng), ext(rng), ext(rng)};
      std::vector<std::pair<int, int>> cells;  // (i, j) in visiting order
      int prev_i = -1, prev_end = -1, prev_tile = -1;
      long prev_off_end = -1;
      for (SubmapIterator it(m, want); !it.done(); ++it) {
        const auto& s = *it;
        ASSERT_GE(s.n, 1);
        const float* data = m.tileData(id, s.tile);
        ASSERT_NE(data, nullptr);
        for (int k = 0; k < s.n; ++k) {
          const Where w = bruteForce(m, s.i, s.j + k);
          EXPECT_EQ(w.tile, s.tile) << s.i << "," << s.j + k;
          EXPECT_EQ(w.offset, s.offset + k) << s.i << "," << s.j + k;
          EXPECT_EQ(data[s.offset + k], m.at(id, Index(s.i, s.j + k)));
          cells.emplace_back(s.i, s.j + k);
        }
        // Maximal runs: a row's next span starts in another tile or where the buffer wraps.
        if (s.i == prev_i && s.j == prev_end) {
          EXPECT_TRUE(s.tile != prev_tile || s.offset != prev_off_end);
        }
        prev_i = s.i;
        prev_end = s.j + s.n;
        prev_tile = s.tile;
        prev_off_end = s.offset + s.n;
      }
      std::vector<std::pair<int, int>> expect;
      for (int i = std::max(want.r0, 0); i < std::min(want.rowEnd(), R); ++i)
        for (int j = std::max(want.c0, 0); j < std::min(want.colEnd(), C); ++j) expect.emplace_back(i, j);
      EXPECT_EQ(cells, expect) << "rect " << want.r0 << "," << want.c0 << " " << want.rows << "x" << want.cols;
    }
  }
}

TEST(SubmapIterator, EmptyAndOffMapRectangles) {
  LayeredMap m(Geometry(0.1, Size(20, 20)), MapOptions{8, true});
  for (const CellRect& r : {CellRect{}, CellRect{0, 0, 0, 5}, CellRect{3, 3, 5, -1}, CellRect{-10, 0, 5, 5},
                            CellRect{20, 0, 3, 3}, CellRect{0, 25, 3, 3}}) {
    SubmapIterator it(m, r);
    EXPECT_TRUE(it.done());
    EXPECT_TRUE(it.rect().empty());
  }
  // The whole map, unmoved: one span per tile row per tile.
  int spans = 0;
  for (SubmapIterator it(m, CellRect{-5, -5, 100, 100}); !it.done(); ++it) ++spans;
  EXPECT_EQ(spans, 20 * 3);
}

TEST(AxisCell, FloorModuloOfAnyStart) {
  for (int start : {-45, -7, 0, 3, 19, 64})
    for (int k = -30; k < 60; ++k) {
      const AxisCell a = axisCell(k, start, 19, 8);
      const int b = ((k + start) % 19 + 19) % 19;
      EXPECT_EQ(a.tile, b / 8);
      EXPECT_EQ(a.offset, b % 8);
    }
}
