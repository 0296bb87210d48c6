// CellRect against brute force: membership, dense offsets and the covering box of add().
#include <terramap/core/cell_rect.hpp>

#include <gtest/gtest.h>

#include <climits>
#include <random>
#include <set>
#include <utility>

using namespace terramap;

namespace {
std::set<std::pair<int, int>> cellsOf(const CellRect& r) {
  std::set<std::pair<int, int>> s;
  for (int i = r.r0; i < r.r0 + r.rows; ++i)
    for (int j = r.c0; j < r.c0 + r.cols; ++j) s.insert({i, j});
  return s;
}
}  // namespace

TEST(CellRect, ContainsAndLocalMatchEnumeration) {
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> org(-20, 20), ext(-2, 12);
  for (int n = 0; n < 300; ++n) {
    const CellRect r{org(rng), org(rng), ext(rng), ext(rng)};
    const auto cells = cellsOf(r);
    EXPECT_EQ(r.cells(), static_cast<long>(cells.size()));
    EXPECT_EQ(r.empty(), cells.empty());
    long k = 0;
    for (const auto& [i, j] : cells) {  // std::set orders row-major, as local() counts
      EXPECT_TRUE(r.contains(i, j));
      EXPECT_EQ(r.local(i, j), k++);
    }
    for (int i = -25; i < 35; i += 3)
      for (int j = -25; j < 35; j += 2) EXPECT_EQ(r.contains(i, j), cells.count({i, j}) == 1) << i << "," << j;
    if (!r.empty()) {
      EXPECT_EQ(r.rowEnd(), r.r0 + r.rows);
      EXPECT_EQ(r.colEnd(), r.c0 + r.cols);
    }
  }
}

TEST(CellRect, AddGrowsToTheBoundingBoxAndIgnoresEmptyBoxes) {
  std::mt19937 rng(9);
  std::uniform_int_distribution<int> org(-30, 30), ext(-3, 10);
  for (int n = 0; n < 300; ++n) {
    CellRect acc;
    int i0 = INT_MAX, j0 = INT_MAX, i1 = INT_MIN, j1 = INT_MIN;  // inclusive bounds, brute force
    for (int k = 0; k < 5; ++k) {
      const CellRect b{org(rng), org(rng), ext(rng), ext(rng)};
      acc.add(b);
      for (const auto& [i, j] : cellsOf(b)) {
        i0 = std::min(i0, i);
        j0 = std::min(j0, j);
        i1 = std::max(i1, i);
        j1 = std::max(j1, j);
      }
    }
    if (i0 == INT_MAX) {
      EXPECT_TRUE(acc.empty());
    } else {
      EXPECT_EQ(acc, CellRect::inclusive(i0, j0, i1, j1));
    }
  }
}

TEST(CellRect, InclusiveBoxes) {
  EXPECT_EQ(CellRect::inclusive(2, 3, 4, 3), (CellRect{2, 3, 3, 1}));
  EXPECT_TRUE(CellRect::inclusive(0, 0, -1, -1).empty());  // the "nothing yet" box
  EXPECT_TRUE(CellRect::inclusive(5, 0, 4, 9).empty());
  EXPECT_TRUE(CellRect{}.empty());
  EXPECT_EQ(CellRect{}.cells(), 0);
  CellRect a = CellRect::inclusive(0, 0, 0, 0);
  a.add(CellRect::inclusive(3, -2, 3, -2));
  EXPECT_EQ(a, CellRect::inclusive(0, -2, 3, 0));
  a.add(CellRect{});
  EXPECT_EQ(a, CellRect::inclusive(0, -2, 3, 0));
}
