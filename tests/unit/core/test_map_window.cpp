// MapWindow against brute force (LayeredMap::at / set): random rectangles, a ring buffer that
// has moved (windows that wrap around the buffer edge), windows clipped at the map edge, empty
// windows, sparse tiles that read as the fill, and write-back of changed cells only.
#include <terramap/core/map_window.hpp>

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <random>
#include <set>
#include <vector>

using namespace terramap;

namespace {
float valueFor(int i, int j) { return static_cast<float>(i * 1000 + j); }

bool sameBits(float a, float b) { return std::memcmp(&a, &b, sizeof(float)) == 0; }
}  // namespace

TEST(MapWindow, GatherMatchesCellReadsOnAMovedRingBuffer) {
  std::mt19937 rng(3);
  for (bool sparse : {false, true}) {
    LayeredMap m(Geometry(0.1, Size(53, 41)), MapOptions{8, sparse});
    const LayerId id = m.addLayer("a", "m");
    const LayerId z = m.addLayer("zero_fill", "1", 0.0f);
    // Move twice so the logical origin sits inside a tile and the buffer wraps both ways.
    m.move(Position(1.33, -0.71));
    m.move(Position(0.42, -2.05));
    std::uniform_int_distribution<int> cell(0, 52 * 41);
    for (int n = 0; n < 300; ++n) {  // some cells known, the rest unknown (and unallocated)
      const int c = cell(rng);
      if (c / 41 < 53) m.set(id, Index(c / 41, c % 41), valueFor(c / 41, c % 41));
    }
    std::uniform_int_distribution<int> start(-10, 60), extent(0, 30);
    for (int n = 0; n < 400; ++n) {
      const int i0 = start(rng), j0 = start(rng), rows = extent(rng), cols = extent(rng);
      const MapWindow w(m, i0, j0, rows, cols);
      // Clipped to the map.
      const int ci0 = std::max(i0, 0), cj0 = std::max(j0, 0);
      const int ci1 = std::min(i0 + rows, 53), cj1 = std::min(j0 + cols, 41);
      ASSERT_EQ(w.rows(), std::max(0, ci1 - ci0));
      ASSERT_EQ(w.cols(), std::max(0, cj1 - cj0));
      EXPECT_EQ(w.empty(), w.size() == 0);
      std::vector<double> a;
      std::vector<float> b;
      w.gather(m, id, a);
      w.gather(m, z, b);
      ASSERT_EQ(static_cast<long>(a.size()), w.size());
      for (int i = ci0; i < ci1; ++i)
        for (int j = cj0; j < cj1; ++j) {
          ASSERT_TRUE(w.contains(i, j));
          const float want = m.at(id, Index(i, j));
          const double got = a[static_cast<size_t>(w.local(i, j))];
          if (std::isnan(want))
            EXPECT_TRUE(std::isnan(got)) << i << "," << j;
          else
            EXPECT_EQ(got, static_cast<double>(want)) << i << "," << j;
          EXPECT_EQ(b[static_cast<size_t>(w.local(i, j))], m.at(z, Index(i, j)));
        }
      EXPECT_FALSE(w.contains(ci0 - 1, cj0));
      EXPECT_FALSE(w.contains(ci0, ci1 > ci0 ? cj1 : cj0 - 1));
    }
  }
}

TEST(MapWindow, ScatterWritesChangedCellsOnlyAndKeepsSnapshotsSharing) {
  LayeredMap m(Geometry(0.1, Size(64, 64)), MapOptions{16, true});
  const LayerId id = m.addLayer("a", "m");
  m.move(Position(0.85, 0.37));
  const MapWindow w(m, 10, 20, 25, 30);  // spans 3 x 3 tiles of the buffer
  std::vector<double> before, after;
  w.gather(m, id, before);
  after = before;
  // Unchanged NaN stays unwritten; three changed cells, one of them set to NaN on a cell that
  // already held a number.
  m.set(id, Index(12, 22), 1.0f);
  w.gather(m, id, before);
  after = before;
  after[static_cast<size_t>(w.local(11, 21))] = 2.5;
  after[static_cast<size_t>(w.local(34, 49))] = -1.0;
  after[static_cast<size_t>(w.local(12, 22))] = std::nan("");
  const LayeredMap snap = m.snapshot();
  const long allocated = m.allocatedTiles();
  EXPECT_EQ(w.scatterChanged(m, id, before, after), 3);
  EXPECT_EQ(m.at(id, Index(11, 21)), 2.5f);
  EXPECT_EQ(m.at(id, Index(34, 49)), -1.0f);
  EXPECT_TRUE(std::isnan(m.at(id, Index(12, 22))));
  EXPECT_TRUE(sameBits(snap.at(id, Index(12, 22)), 1.0f));
  // Brute force: every other cell of the map is as before.
  for (int i = 0; i < 64; ++i)
    for (int j = 0; j < 64; ++j) {
      if ((i == 11 && j == 21) || (i == 34 && j == 49) || (i == 12 && j == 22)) continue;
      EXPECT_TRUE(sameBits(m.at(id, Index(i, j)), snap.at(id, Index(i, j)))) << i << "," << j;
    }
  // Only the tiles holding the written cells were copied or allocated; every other tile is still
  // the snapshot's own memory (shared, not copied).
  std::set<int> written;
  for (const Index& c : {Index(11, 21), Index(34, 49), Index(12, 22)}) {
    const Index b = m.bufferIndex(c);
    written.insert(m.tileOfBuffer(b.x(), b.y()));
  }
  int differing = 0;
  for (int t = 0; t < m.tileCount(); ++t) {
    if (written.count(t)) continue;
    EXPECT_EQ(m.tileData(id, t), snap.tileData(id, t)) << "tile " << t << " was copied or allocated";
    differing += m.tileData(id, t) != snap.tileData(id, t);
  }
  EXPECT_EQ(differing, 0);
  for (int t : written) EXPECT_NE(m.tileData(id, t), snap.tileData(id, t)) << "written tile " << t << " still shared";
  EXPECT_LE(m.allocatedTiles(), allocated + 2);
  EXPECT_EQ(w.scatterChanged(m, id, after, after), 0);
}

TEST(MapWindow, EmptyAndOffMapWindows) {
  LayeredMap m(Geometry(0.1, Size(20, 20)), MapOptions{8, false});
  const LayerId id = m.addLayer("a", "m");
  for (const auto& r : std::vector<std::array<int, 4>>{{0, 0, 0, 5}, {0, 0, 5, 0}, {-10, 0, 5, 5}, {25, 3, 4, 4},
                                                       {3, 20, 4, 4}, {-3, -3, 2, 2}}) {
    const MapWindow w(m, r[0], r[1], r[2], r[3]);
    EXPECT_TRUE(w.empty());
    std::vector<float> v{1.0f};
    w.gather(m, id, v);
    EXPECT_TRUE(v.empty());
    EXPECT_EQ(w.scatterChanged(m, id, v, v), 0);
  }
  const MapWindow whole(m, -5, -5, 100, 100);
  EXPECT_EQ(whole.rows(), 20);
  EXPECT_EQ(whole.cols(), 20);
  std::vector<float> v;
  EXPECT_THROW(whole.gather(m, 7, v), LayerError);
}
