#include <terramap/core/error.hpp>
#include <terramap/core/geometry.hpp>

#include <gtest/gtest.h>

#include <cmath>

using namespace terramap;

TEST(Geometry, IndexZeroIsTheCellWithLargestXAndY) {
  // 4 x 6 cells of 0.5 m centred at (10, 20): x in [9, 11), y in [18.5, 21.5).
  Geometry g(0.5, Size(4, 6), Position(10, 20));
  const Position p00 = g.positionOf(Index(0, 0));
  EXPECT_DOUBLE_EQ(p00.x(), 10.75);
  EXPECT_DOUBLE_EQ(p00.y(), 21.25);
  const Position plast = g.positionOf(Index(3, 5));
  EXPECT_DOUBLE_EQ(plast.x(), 9.25);
  EXPECT_DOUBLE_EQ(plast.y(), 18.75);
}

TEST(Geometry, IndexPositionRoundTripForEveryCell) {
  Geometry g(0.05, Size(37, 53), Position(-3.2, 7.9));
  for (int i = 0; i < 37; ++i)
    for (int j = 0; j < 53; ++j) {
      const auto idx = g.indexAt(g.positionOf(Index(i, j)));
      ASSERT_TRUE(idx.has_value());
      EXPECT_EQ(idx->x(), i);
      EXPECT_EQ(idx->y(), j);
    }
}

TEST(Geometry, BoundariesAreHalfOpenTowardsSmallerIndex) {
  Geometry g(1.0, Size(2, 2), Position(0, 0));  // x, y in [-1, 1)
  // On the +x/+y edge: outside.
  EXPECT_FALSE(g.indexAt(Position(1.0, 0.5)).has_value());
  EXPECT_FALSE(g.indexAt(Position(0.5, 1.0)).has_value());
  // On the -x/-y edge: inside, last index.
  auto idx = g.indexAt(Position(-1.0, -1.0));
  ASSERT_TRUE(idx);
  EXPECT_EQ(idx->x(), 1);
  EXPECT_EQ(idx->y(), 1);
  // On the internal boundary x = 0: the cell with the smaller index (towards +x).
  idx = g.indexAt(Position(0.0, 0.5));
  ASSERT_TRUE(idx);
  EXPECT_EQ(idx->x(), 0);
  EXPECT_EQ(idx->y(), 0);
  EXPECT_FALSE(g.indexAt(Position(-1.0001, 0)).has_value());
  EXPECT_FALSE(g.indexAt(Position(NAN, 0)).has_value());
  EXPECT_FALSE(g.indexAt(Position(0, INFINITY)).has_value());
}

TEST(Geometry, RefusesBadConstruction) {
  EXPECT_THROW(Geometry(0.0, Size(2, 2)), ConfigError);
  EXPECT_THROW(Geometry(-1.0, Size(2, 2)), ConfigError);
  EXPECT_THROW(Geometry(NAN, Size(2, 2)), ConfigError);
  EXPECT_THROW(Geometry(1.0, Size(0, 2)), ConfigError);
  try {
    Geometry(0.1, Size(3, -1));
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("[3, -1]"), std::string::npos) << e.what();
  }
}
