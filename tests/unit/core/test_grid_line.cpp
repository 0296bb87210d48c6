// GridLine against brute force: the cells a segment crosses are exactly those whose open square
// it passes through (clipped per cell, Liang-Barsky), met in order of the line parameter.
#include <terramap/core/error.hpp>
#include <terramap/core/grid_line.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <utility>
#include <vector>

using namespace terramap;

namespace {

struct Hit {
  double t_in;
  int i, j;
};

// Parameter interval [ta, tb] of the segment (u0,v0)+t(du,dv), t in [0,1], inside cell (i,j)'s
// square [i, i+1] x [j, j+1]; false if the segment misses it or only grazes it (zero length).
bool clipCell(double u0, double v0, double du, double dv, int i, int j, double& ta) {
  double t0 = 0.0, t1 = 1.0;
  auto clip = [&](double p0, double dp, double lo, double hi) {
    if (dp == 0.0) {
      if (p0 <= lo || p0 >= hi) t1 = -1.0;
      return;
    }
    double a = (lo - p0) / dp, b = (hi - p0) / dp;
    if (a > b) std::swap(a, b);
    t0 = std::max(t0, a);
    t1 = std::min(t1, b);
  };
  clip(u0, du, i, i + 1.0);
  clip(v0, dv, j, j + 1.0);
  ta = t0;
  return t1 > t0;
}

std::vector<Hit> bruteForce(double u0, double v0, double u1, double v1) {
  const double du = u1 - u0, dv = v1 - v0;
  std::vector<Hit> hits;
  const int ilo = static_cast<int>(std::floor(std::min(u0, u1))) - 1;
  const int ihi = static_cast<int>(std::floor(std::max(u0, u1))) + 1;
  const int jlo = static_cast<int>(std::floor(std::min(v0, v1))) - 1;
  const int jhi = static_cast<int>(std::floor(std::max(v0, v1))) + 1;
  for (int i = ilo; i <= ihi; ++i)
    for (int j = jlo; j <= jhi; ++j) {
      double ta;
      if (clipCell(u0, v0, du, dv, i, j, ta)) hits.push_back({ta, i, j});
    }
  std::sort(hits.begin(), hits.end(), [](const Hit& a, const Hit& b) { return a.t_in < b.t_in; });
  return hits;
}

std::vector<std::pair<int, int>> walk(GridLine g) {
  std::vector<std::pair<int, int>> cells{{g.row(), g.col()}};
  for (int guard = 0; g.exitParam() < 1.0 && guard < 100000; ++guard) {
    g.step();
    cells.emplace_back(g.row(), g.col());
  }
  return cells;
}

// Map-frame position of grid point (u, v) of `geo`.
Position posOf(const Geometry& geo, double u, double v) {
  const double xmax = geo.center().x() + 0.5 * geo.length().x();
  const double ymax = geo.center().y() + 0.5 * geo.length().y();
  return Position(xmax - u * geo.resolution(), ymax - v * geo.resolution());
}

}  // namespace

TEST(GridLine, RandomSegmentsVisitExactlyTheCrossedCellsInOrder) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> pos(-30.0, 30.0), len(0.0, 25.0), ang(-M_PI, M_PI);
  for (int n = 0; n < 3000; ++n) {
    const double u0 = pos(rng), v0 = pos(rng);
    // Some segments shorter than a cell, some axis-parallel, most general.
    const double l = n % 5 == 0 ? 0.3 * len(rng) / 25.0 : len(rng);
    double a = ang(rng);
    if (n % 7 == 0) a = (n % 4) * M_PI / 2;
    const double u1 = u0 + l * std::cos(a), v1 = v0 + l * std::sin(a);
    const Index start(static_cast<int>(std::ceil(u0)) - 1, static_cast<int>(std::ceil(v0)) - 1);
    const auto got = walk(GridLine(start, u0, v0, u1 - u0, v1 - v0));
    const auto want = bruteForce(u0, v0, u1, v1);
    ASSERT_EQ(got.size(), want.size()) << "segment " << n << " (" << u0 << "," << v0 << ")->(" << u1 << "," << v1
                                       << ")";
    for (size_t k = 0; k < got.size(); ++k) {
      EXPECT_EQ(got[k].first, want[k].i) << "segment " << n << " cell " << k;
      EXPECT_EQ(got[k].second, want[k].j) << "segment " << n << " cell " << k;
    }
    // 4-connected, and as many steps as rows plus columns crossed.
    for (size_t k = 1; k < got.size(); ++k)
      EXPECT_EQ(std::abs(got[k].first - got[k - 1].first) + std::abs(got[k].second - got[k - 1].second), 1);
    EXPECT_EQ(static_cast<int>(got.size()) - 1, std::abs(got.back().first - got.front().first) +
                                                     std::abs(got.back().second - got.front().second));
  }
}

TEST(GridLine, SegmentFromPositionsFollowsTheGeometryConvention) {
  const Geometry geo(0.05, Size(40, 60), Position(1.0, -2.0));
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-5.0, 45.0), v(-5.0, 65.0);
  for (int n = 0; n < 500; ++n) {
    const double u0 = u(rng), v0 = v(rng), u1 = u(rng), v1 = v(rng);
    const Position p0 = posOf(geo, u0, v0), p1 = posOf(geo, u1, v1);
    const GridLine g = GridLine::segment(geo, p0, p1);
    // The start cell is the one Geometry::indexAt gives (when on the map).
    if (const auto idx = geo.indexAt(p0)) {
      EXPECT_EQ(g.row(), idx->x());
      EXPECT_EQ(g.col(), idx->y());
    }
    // The end cell too (cells off the map included: the walk is unbounded).
    const auto cells = walk(g);
    if (const auto idx = geo.indexAt(p1)) {
      EXPECT_EQ(cells.back().first, idx->x()) << n;
      EXPECT_EQ(cells.back().second, idx->y()) << n;
    }
    // Against brute force in the grid coordinates the factory computed (metres round).
    const double xmax = geo.center().x() + 0.5 * geo.length().x();
    const double ymax = geo.center().y() + 0.5 * geo.length().y();
    const auto want = bruteForce((xmax - p0.x()) / geo.resolution(), (ymax - p0.y()) / geo.resolution(),
                                 (xmax - p1.x()) / geo.resolution(), (ymax - p1.y()) / geo.resolution());
    ASSERT_EQ(cells.size(), want.size()) << n;
    for (size_t k = 0; k < cells.size(); ++k) EXPECT_EQ(cells[k], std::make_pair(want[k].i, want[k].j)) << n;
  }
}

TEST(GridLine, EdgesAndDegenerateCases) {
  // A zero-length segment stays in its cell; a zero direction never leaves it.
  GridLine still(Index(3, 4), 3.5, 4.5, 0.0, 0.0);
  EXPECT_TRUE(std::isinf(still.exitParam()));
  EXPECT_EQ(walk(still).size(), 1u);
  // From a cell centre: the first boundary is half a cell away along each axis.
  const GridLine c = GridLine::fromCellCentre(Index(-2, 7), 2.0, 0.0);
  EXPECT_DOUBLE_EQ(c.exitParam(), 0.25);
  GridLine d = GridLine::fromCellCentre(Index(0, 0), -1.0, 0.0);
  d.step();
  EXPECT_EQ(d.row(), -1);  // walks off the map without complaint
  // A corner crossed exactly: rows first, still 4-connected.
  GridLine diag = GridLine::fromCellCentre(Index(0, 0), 1.0, 1.0);
  EXPECT_EQ(diag.step(), GridLine::Axis::Row);
  EXPECT_EQ(diag.cell().x(), 1);
  EXPECT_EQ(diag.cell().y(), 0);
  EXPECT_EQ(diag.step(), GridLine::Axis::Col);
  EXPECT_EQ(diag.cell().x(), 1);
  EXPECT_EQ(diag.cell().y(), 1);
  // A start exactly on a boundary belongs to the smaller index (geometry.hpp).
  const Geometry geo(0.5, Size(10, 10));
  const GridLine b = GridLine::segment(geo, posOf(geo, 3.0, 4.25), posOf(geo, 1.2, 4.25));
  EXPECT_EQ(b.row(), 2);
  EXPECT_EQ(walk(b).size(), 2u);  // rows 2 and 1
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(GridLine::segment(geo, Position(nan, 0.0), Position(1.0, 1.0)), InputError);
  EXPECT_THROW(GridLine::segment(geo, Position(0.0, 0.0), Position(1.0, INFINITY)), InputError);
}
