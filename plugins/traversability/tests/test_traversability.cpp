// traversability: analytic surfaces (a plane of known slope, a plane with a checkerboard of
// known roughness, a step), the limits, unknown cells, an independent per-cell fit on random
// terrain over a moved map, bit-identity at 1, 2 and 4 threads, incremental = full pass, params.
#include "traversability.hpp"

#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/plugin_loader.hpp>

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <cstring>
#include <random>

using namespace terramap;
using terramap::plugins::Traversability;
using terramap::plugins::TraversabilityConfig;
using terramap::plugins::TraversabilityLayers;

namespace {
constexpr double kPi = 3.14159265358979323846;

struct Fixture {
  LayeredMap map;
  TraversabilityLayers l;
  Fixture(int r, int c, double res = 0.05, int tile = 16) : map(Geometry(res, Size(r, c)), MapOptions{tile, false}) {
    l.elevation = map.addLayer("elevation", "m");
    l.slope = map.addLayer("slope", "rad");
    l.roughness = map.addLayer("roughness", "m");
    l.step = map.addLayer("step_height", "m");
    l.traversability = map.addLayer("traversability", "1");
  }
  float at(LayerId id, int i, int j) const { return map.at(id, Index(i, j)); }
};

Traversability configured(std::map<std::string, ParamValue> p = {}) {
  Traversability f;
  const Params params = makeParams("trav", f.schema(), p);
  f.configure(params);
  params.throwIfReported();
  return f;
}

// z = z0 + tan(theta) * (cos(phi) x + sin(phi) y) at cell centres x = i res, y = j res.
void plane(Fixture& fx, double z0, double theta, double phi) {
  const double res = fx.map.geometry().resolution();
  const double t = std::tan(theta);
  for (int i = 0; i < fx.map.geometry().size().x(); ++i)
    for (int j = 0; j < fx.map.geometry().size().y(); ++j)
      fx.map.set(fx.l.elevation, Index(i, j),
                 static_cast<float>(z0 + t * (std::cos(phi) * i * res + std::sin(phi) * j * res)));
}

std::vector<float> layerBytes(const LayeredMap& m, LayerId id) {
  const Eigen::MatrixXf a = m.toMatrix(id);
  return std::vector<float>(a.data(), a.data() + a.size());
}
}  // namespace

// Tolerances: heights are float32, so a plane's cells carry rounding of up to half an ulp of
// their height (6e-8 relative); over a 13 x 13 window of 5 cm cells that moves the fitted
// slope by far less than 1e-5 rad and leaves an RMS residual far below 1e-6 m.
TEST(Traversability, PlaneOfKnownSlopeGivesThatSlopeAndZeroRoughness) {
  for (const double theta : {0.0, 0.1, 0.35, 0.8, 1.2})
    for (const double phi : {0.0, 0.7, 2.0, -1.3}) {
      Fixture fx(48, 40);
      plane(fx, 1.5, theta, phi);
      auto f = configured({{"plane_radius_m", 0.3}});  // 13 x 13 window
      f.run(fx.map, Executor(1), fx.l);
      // Every cell, the edges too: a clipped window of a plane is still that plane.
      for (int i = 0; i < 48; ++i)
        for (int j = 0; j < 40; ++j) {
          ASSERT_NEAR(fx.at(fx.l.slope, i, j), theta, 1e-5) << theta << " " << phi << " at " << i << "," << j;
          ASSERT_LT(fx.at(fx.l.roughness, i, j), 1e-6) << theta << " " << phi << " at " << i << "," << j;
          ASSERT_GE(fx.at(fx.l.roughness, i, j), 0.0f);
        }
    }
}

TEST(Traversability, CheckerboardOnAPlaneGivesItsRoughnessAlongTheNormal) {
  // z = plane + a (-1)^(i+j). Over a full odd window the checkerboard is uncorrelated with the
  // offsets (each row's sum of di (-1)^di is 0), so the fit keeps the plane's gradient and
  // lifts it by the checkerboard's mean ±a/n: the vertical residuals' mean square is
  // a² (1 - 1/n²), and their distances along the normal are cos(theta) times that.
  const double a = 0.02, theta = 0.4, phi = 0.3;
  Fixture fx(40, 40);
  plane(fx, 0.5, theta, phi);
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 40; ++j)
      fx.map.set(fx.l.elevation, Index(i, j),
                 fx.map.at(fx.l.elevation, Index(i, j)) + static_cast<float>((i + j) % 2 ? -a : a));
  auto f = configured({{"plane_radius_m", 0.2}});  // k = 4, n = 81
  f.run(fx.map, Executor(1), fx.l);
  const double n = 81.0;
  const double expected = a * std::sqrt(1.0 - 1.0 / (n * n)) * std::cos(theta);
  for (int i = 4; i < 36; ++i)
    for (int j = 4; j < 36; ++j) {
      ASSERT_NEAR(fx.at(fx.l.roughness, i, j), expected, 1e-6) << i << "," << j;
      ASSERT_NEAR(fx.at(fx.l.slope, i, j), theta, 1e-5) << i << "," << j;
    }
}

TEST(Traversability, AStepGivesItsHeightWithinTheStepWindow) {
  Fixture fx(30, 40);
  const float h = 0.3f;
  for (int i = 0; i < 30; ++i)
    for (int j = 0; j < 40; ++j) fx.map.set(fx.l.elevation, Index(i, j), j < 20 ? 1.0f : 1.0f + h);
  auto f = configured({{"step_radius_m", 0.15}});  // ks = 3
  f.run(fx.map, Executor(1), fx.l);
  for (int i = 0; i < 30; ++i)
    for (int j = 0; j < 40; ++j) {
      // A cell sees the step when its window [j - 3, j + 3] holds both 19 and 20.
      const float want = (j >= 17 && j <= 22) ? (1.0f + h) - 1.0f : 0.0f;
      ASSERT_EQ(fx.at(fx.l.step, i, j), want) << i << "," << j;
    }
  // A diagonal step (across rows and columns) too: its height where the window straddles it.
  Fixture fd(30, 30);
  for (int i = 0; i < 30; ++i)
    for (int j = 0; j < 30; ++j) fd.map.set(fd.l.elevation, Index(i, j), i + j < 30 ? 0.0f : 0.25f);
  f.run(fd.map, Executor(1), fd.l);
  for (int i = 0; i < 30; ++i)
    for (int j = 0; j < 30; ++j) {
      // The window [i-3, i+3] x [j-3, j+3] (clipped) holds a cell with r + c >= 30 and one below.
      const int lo = std::max(0, i - 3) + std::max(0, j - 3), hi = std::min(29, i + 3) + std::min(29, j + 3);
      const float want = (lo < 30 && hi >= 30) ? 0.25f : 0.0f;
      ASSERT_EQ(fd.at(fd.l.step, i, j), want) << i << "," << j;
    }
}

TEST(Traversability, TraversabilityFollowsTheLimitsAndIsMonotoneInThem) {
  // One term alone: a plane of slope theta with weight only on slope gives 1 - theta / critical.
  {
    Fixture fx(32, 32);
    plane(fx, 0.0, 0.2, 0.5);
    auto f = configured({{"critical_slope_rad", 0.5}, {"weight_roughness", 0.0}, {"weight_step", 0.0},
                         {"critical_step_m", 100.0}});
    f.run(fx.map, Executor(1), fx.l);
    EXPECT_NEAR(fx.at(fx.l.traversability, 16, 16), 1.0 - 0.2 / 0.5, 1e-5);
    // Past the critical slope: 0.
    auto g = configured({{"critical_slope_rad", 0.15}, {"weight_roughness", 0.0}, {"weight_step", 0.0},
                         {"critical_step_m", 100.0}});
    g.run(fx.map, Executor(1), fx.l);
    EXPECT_EQ(fx.at(fx.l.traversability, 16, 16), 0.0f);
  }
  // The weighted mean of the three terms, and any_critical_blocks.
  {
    Fixture fx(32, 32);
    plane(fx, 0.0, 0.1, 0.0);  // slope 0.1, roughness 0, step over 7 cells of 5 cm: 6 * 0.05 * tan(0.1)
    const double step = 6 * 0.05 * std::tan(0.1);
    auto f = configured({{"critical_slope_rad", 0.4}, {"critical_roughness_m", 0.05}, {"critical_step_m", 0.1},
                         {"weight_slope", 2.0}, {"weight_roughness", 1.0}, {"weight_step", 1.0}});
    f.run(fx.map, Executor(1), fx.l);
    const double want = (2.0 * (1 - 0.1 / 0.4) + 1.0 * 1.0 + 1.0 * (1 - step / 0.1)) / 4.0;
    EXPECT_NEAR(fx.at(fx.l.step, 16, 16), step, 1e-6);
    EXPECT_NEAR(fx.at(fx.l.traversability, 16, 16), want, 1e-5);
    // A step past its critical height: 0 with any_critical_blocks (the default), else the
    // mean of the other two terms.
    auto blocked = configured({{"critical_step_m", 0.02}});
    blocked.run(fx.map, Executor(1), fx.l);
    EXPECT_EQ(fx.at(fx.l.traversability, 16, 16), 0.0f);
    auto mean = configured({{"critical_step_m", 0.02}, {"any_critical_blocks", false}, {"critical_slope_rad", 0.4}});
    mean.run(fx.map, Executor(1), fx.l);
    EXPECT_NEAR(fx.at(fx.l.traversability, 16, 16), ((1 - 0.1 / 0.4) + 1.0 + 0.0) / 3.0, 1e-5);
  }
  // Monotone: raising any critical value never lowers any cell's traversability (random
  // terrain, both combination rules), and the values stay in [0, 1].
  Fixture fx(64, 64);
  std::mt19937 rng(11);
  std::normal_distribution<float> noise(0.f, 0.03f);
  for (int i = 0; i < 64; ++i)
    for (int j = 0; j < 64; ++j)
      fx.map.set(fx.l.elevation, Index(i, j),
                 static_cast<float>(0.4 * std::sin(i * 0.15) * std::cos(j * 0.1) + (j > 40 ? 0.15 : 0.0)) + noise(rng));
  const std::pair<const char*, double> limits[] = {
      {"critical_slope_rad", 0.3}, {"critical_roughness_m", 0.02}, {"critical_step_m", 0.1}};
  for (const bool blocks : {true, false})
    for (const auto& [which, base] : limits) {
      std::vector<float> last;
      long changed = 0;
      for (const double scale : {0.25, 0.5, 1.0, 2.0, 4.0}) {
        // The other two limits far away, so that this one decides where the default blocks.
        std::map<std::string, ParamValue> p = {{"any_critical_blocks", blocks}, {"critical_slope_rad", 1.5},
                                               {"critical_roughness_m", 1.0}, {"critical_step_m", 2.0}};
        p[which] = base * scale;
        auto f = configured(p);
        f.run(fx.map, Executor(1), fx.l);
        const std::vector<float> t = layerBytes(fx.map, fx.l.traversability);
        for (size_t c = 0; c < t.size(); ++c) {
          ASSERT_TRUE(t[c] >= 0.0f && t[c] <= 1.0f) << which << " cell " << c << " = " << t[c];
          if (!last.empty()) {
            ASSERT_GE(t[c], last[c]) << which << " x" << scale << " cell " << c;
            changed += t[c] > last[c];
          }
        }
        last = t;
      }
      // Not vacuous: the raises move most cells (4 raises of 4096 cells).
      EXPECT_GT(changed, 4000) << which << " blocks " << blocks;
    }
}

TEST(Traversability, UnknownCellsStayUnknownAndTooFewNeighboursGiveNoFit) {
  Fixture fx(32, 32);
  plane(fx, 0.0, 0.3, 1.0);
  fx.map.set(fx.l.elevation, Index(10, 10), NAN);
  auto f = configured({{"plane_radius_m", 0.1}, {"step_radius_m", 0.1}, {"min_points", 6}});  // 5 x 5 windows
  f.run(fx.map, Executor(1), fx.l);
  // The unknown cell: unknown in every output.
  for (LayerId id : {fx.l.slope, fx.l.roughness, fx.l.step, fx.l.traversability})
    EXPECT_TRUE(std::isnan(fx.at(id, 10, 10))) << fx.map.layerInfo(id).name;
  // Its neighbours fit the plane without it: the hole does not spread.
  EXPECT_NEAR(fx.at(fx.l.slope, 10, 11), 0.3, 1e-5);
  EXPECT_NEAR(fx.at(fx.l.slope, 9, 9), 0.3, 1e-5);
  EXPECT_FALSE(std::isnan(fx.at(fx.l.traversability, 11, 10)));

  // An island: exactly min_points known cells, not collinear, then one fewer.
  Fixture fi(20, 20);
  const int cells[6][2] = {{8, 8}, {8, 9}, {9, 8}, {9, 10}, {10, 9}, {10, 10}};
  for (const auto& c : cells) fi.map.set(fi.l.elevation, Index(c[0], c[1]), 0.01f * c[0] + 0.02f * c[1]);
  f.run(fi.map, Executor(1), fi.l);
  EXPECT_NEAR(fi.at(fi.l.slope, 9, 8), std::atan(std::hypot(0.01, 0.02) / 0.05), 1e-5);  // 6 known: a fit
  EXPECT_LT(fi.at(fi.l.roughness, 9, 8), 1e-6);
  fi.map.set(fi.l.elevation, Index(10, 10), NAN);
  f.run(fi.map, Executor(1), fi.l);
  EXPECT_TRUE(std::isnan(fi.at(fi.l.slope, 9, 8)));  // 5 known < min_points 6
  EXPECT_TRUE(std::isnan(fi.at(fi.l.roughness, 9, 8)));
  EXPECT_TRUE(std::isnan(fi.at(fi.l.traversability, 9, 8)));
  EXPECT_FLOAT_EQ(fi.at(fi.l.step, 9, 8), (0.01f * 9 + 0.02f * 10) - (0.01f * 8 + 0.02f * 8));  // still a step
  auto three = configured({{"plane_radius_m", 0.1}, {"min_points", 3}});
  three.run(fi.map, Executor(1), fi.l);
  EXPECT_FALSE(std::isnan(fi.at(fi.l.slope, 9, 8)));

  // Collinear known cells (one row): no plane, whatever their number.
  Fixture fc(20, 20);
  for (int j = 0; j < 20; ++j) fc.map.set(fc.l.elevation, Index(7, j), 0.1f * j);
  three.run(fc.map, Executor(1), fc.l);
  for (int j = 0; j < 20; ++j) {
    EXPECT_TRUE(std::isnan(fc.at(fc.l.slope, 7, j))) << j;
    EXPECT_FALSE(std::isnan(fc.at(fc.l.step, 7, j))) << j;
  }
  // Outside the data, nothing.
  EXPECT_TRUE(std::isnan(fc.at(fc.l.step, 3, 3)));
}

namespace {
// An independent per-cell reference: gather the window's known cells in metres and solve the
// least-squares plane with Eigen's QR, the roughness from the explicit residuals.
struct Ref {
  double slope = NAN, rough = NAN, step = NAN;
};
Ref reference(const Eigen::MatrixXf& z, int i, int j, int k, int ks, double res, long min_points) {
  Ref r;
  if (!std::isfinite(z(i, j))) return r;
  const int R = static_cast<int>(z.rows()), C = static_cast<int>(z.cols());
  float mx = -INFINITY, mn = INFINITY;
  for (int a = std::max(0, i - ks); a <= std::min(R - 1, i + ks); ++a)
    for (int b = std::max(0, j - ks); b <= std::min(C - 1, j + ks); ++b)
      if (std::isfinite(z(a, b))) mx = std::max(mx, z(a, b)), mn = std::min(mn, z(a, b));
  r.step = mx - mn;
  std::vector<Eigen::Vector3d> pts;
  for (int a = std::max(0, i - k); a <= std::min(R - 1, i + k); ++a)
    for (int b = std::max(0, j - k); b <= std::min(C - 1, j + k); ++b)
      if (std::isfinite(z(a, b))) pts.emplace_back((a - i) * res, (b - j) * res, z(a, b));
  if (static_cast<long>(pts.size()) < min_points) return r;
  Eigen::MatrixXd A(pts.size(), 3);
  Eigen::VectorXd y(pts.size());
  for (size_t p = 0; p < pts.size(); ++p) {
    const auto e = static_cast<Eigen::Index>(p);
    A(e, 0) = 1.0, A(e, 1) = pts[p].x(), A(e, 2) = pts[p].y();
    y(e) = pts[p].z();
  }
  const Eigen::Vector3d beta = A.colPivHouseholderQr().solve(y);
  const double g = std::hypot(beta(1), beta(2));
  r.slope = std::atan(g);
  r.rough = std::sqrt((A * beta - y).squaredNorm() / static_cast<double>(pts.size())) * std::cos(r.slope);
  return r;
}
}  // namespace

TEST(Traversability, MatchesAnIndependentPerCellFitOnRandomTerrainAcrossTheRingSeam) {
  // Rough random terrain with holes on a map moved so that tiles straddle the ring's seam:
  // every cell against the brute-force reference (slope and roughness to 1e-5, step exactly).
  Fixture fx(70, 58, 0.05, 16);
  fx.map.move(Position(0.37, -0.81));
  std::mt19937 rng(5);
  std::normal_distribution<float> n(0.f, 0.05f);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (int i = 0; i < 70; ++i)
    for (int j = 0; j < 58; ++j)
      fx.map.set(fx.l.elevation, Index(i, j),
                 u(rng) < 0.15f ? NAN : static_cast<float>(12.0 + 0.3 * std::sin(0.2 * i) + 0.02 * j) + n(rng));
  // A region with too few known cells for a fit.
  for (int i = 30; i < 47; ++i)
    for (int j = 16; j < 41; ++j)
      if ((i + 2 * j) % 11) fx.map.set(fx.l.elevation, Index(i, j), NAN);
  auto f = configured({{"plane_radius_m", 0.15}, {"step_radius_m", 0.1}, {"min_points", 8}});
  f.run(fx.map, Executor(2), fx.l);
  const Eigen::MatrixXf z = fx.map.toMatrix(fx.l.elevation);
  long fits = 0, nofit = 0;
  for (int i = 0; i < 70; ++i)
    for (int j = 0; j < 58; ++j) {
      const Ref r = reference(z, i, j, 3, 2, 0.05, 8);
      const float s = fx.at(fx.l.slope, i, j), ro = fx.at(fx.l.roughness, i, j), st = fx.at(fx.l.step, i, j);
      ASSERT_EQ(std::isnan(s), std::isnan(r.slope)) << i << "," << j;
      ASSERT_EQ(std::isnan(st), std::isnan(r.step)) << i << "," << j;
      if (!std::isnan(r.step)) {
        ASSERT_EQ(st, static_cast<float>(r.step)) << i << "," << j;
      }
      if (std::isnan(r.slope)) {
        nofit += std::isfinite(z(i, j)) ? 1 : 0;
        continue;
      }
      ++fits;
      ASSERT_NEAR(s, r.slope, 1e-5) << i << "," << j;
      ASSERT_NEAR(ro, r.rough, 1e-5) << i << "," << j;
    }
  EXPECT_GT(fits, 3000);
  EXPECT_GT(nofit, 10);  // the sparse region (16 of its ~38 known cells)
}

TEST(Traversability, BitIdenticalAtOneTwoAndFourThreadsOnAMovedMap) {
  // Many small tiles (323 tasks), so that the threads of a run share them out differently from
  // the serial order; both executor backends.
  auto run = [](const Executor& ex) {
    Fixture fx(300, 260, 0.05, 16);
    std::mt19937 rng(3);
    std::normal_distribution<float> n(0, 0.1f);
    for (int i = 0; i < 300; ++i)
      for (int j = 0; j < 260; ++j) fx.map.set(fx.l.elevation, Index(i, j), (i * 7 + j) % 13 == 0 ? NAN : 5.0f + n(rng));
    fx.map.move(Position(0.7, -1.1));
    for (int i = 0; i < 300; ++i)
      for (int j = 0; j < 260; ++j)
        if (std::isnan(fx.map.at(fx.l.elevation, Index(i, j))) && (i + j) % 3) fx.map.set(fx.l.elevation, Index(i, j), n(rng));
    configured({{"plane_radius_m", 0.25}, {"step_radius_m", 0.2}}).run(fx.map, ex, fx.l);
    std::vector<float> all;
    for (LayerId id : {fx.l.slope, fx.l.roughness, fx.l.step, fx.l.traversability}) {
      const auto v = layerBytes(fx.map, id);
      all.insert(all.end(), v.begin(), v.end());
    }
    return all;
  };
  const auto a = run(Executor(1));
  const size_t bytes = sizeof(float) * a.size();
  EXPECT_EQ(std::memcmp(a.data(), run(Executor(2)).data(), bytes), 0);
  EXPECT_EQ(std::memcmp(a.data(), run(Executor(4)).data(), bytes), 0);
  EXPECT_EQ(std::memcmp(a.data(), run(Executor(2, Executor::Backend::kThreads)).data(), bytes), 0);
  EXPECT_EQ(std::memcmp(a.data(), run(Executor(4, Executor::Backend::kThreads)).data(), bytes), 0);
  long finite = 0;
  for (float v : a) finite += std::isfinite(v);
  EXPECT_GT(finite, static_cast<long>(a.size()) / 2);  // not vacuous
}

TEST(Traversability, Avx2AndBaselinePathsGiveTheSameBits) {
  if (!Traversability::avx2Available()) GTEST_SKIP() << "no AVX2 on this CPU: only the baseline path runs";
  auto run = [](bool avx2) {
    Fixture fx(130, 150, 0.04, 64);
    std::mt19937 rng(8);
    std::normal_distribution<float> n(0, 0.05f);
    std::uniform_real_distribution<float> u(0.f, 1.f);
    for (int i = 0; i < 130; ++i)
      for (int j = 0; j < 150; ++j)
        fx.map.set(fx.l.elevation, Index(i, j), u(rng) < 0.1f ? NAN : 40.0f + 0.02f * i + (j > 70 ? 0.2f : 0.f) + n(rng));
    auto f = configured();
    f.setAllowAvx2(avx2);
    f.run(fx.map, Executor(1), fx.l);
    std::vector<float> all;
    for (LayerId id : {fx.l.slope, fx.l.roughness, fx.l.step, fx.l.traversability}) {
      const auto v = layerBytes(fx.map, id);
      all.insert(all.end(), v.begin(), v.end());
    }
    return all;
  };
  const auto a = run(false), b = run(true);
  EXPECT_EQ(std::memcmp(a.data(), b.data(), sizeof(float) * a.size()), 0);
}

TEST(Traversability, ChangedTilesRecomputeToTheBitsOfAWholePass) {
  Fixture fx(96, 96, 0.05, 16);
  plane(fx, 2.0, 0.2, 0.4);
  auto f = configured({{"plane_radius_m", 0.2}, {"step_radius_m", 0.15}});
  f.run(fx.map, Executor(2), fx.l);
  // A bump in one tile; recompute only the tiles it reaches.
  for (int i = 40; i < 44; ++i)
    for (int j = 50; j < 53; ++j) fx.map.set(fx.l.elevation, Index(i, j), fx.map.at(fx.l.elevation, Index(i, j)) + 0.3f);
  const int t = fx.map.tileOfBuffer(fx.map.bufferIndex(Index(41, 51)).x(), fx.map.bufferIndex(Index(41, 51)).y());
  const std::vector<int> tiles = f.affectedTiles(fx.map, {t});
  EXPECT_LT(tiles.size(), static_cast<size_t>(fx.map.tileCount()));
  f.runTiles(fx.map, Executor(2), fx.l, tiles);
  Fixture full(96, 96, 0.05, 16);
  full.map.fromMatrix(full.l.elevation, fx.map.toMatrix(fx.l.elevation));
  f.run(full.map, Executor(1), full.l);
  for (auto [a, b] : {std::pair{fx.l.slope, full.l.slope}, {fx.l.roughness, full.l.roughness}, {fx.l.step, full.l.step},
                      {fx.l.traversability, full.l.traversability}}) {
    const auto x = layerBytes(fx.map, a), y = layerBytes(full.map, b);
    EXPECT_EQ(std::memcmp(x.data(), y.data(), sizeof(float) * x.size()), 0) << fx.map.layerInfo(a).name;
  }
  EXPECT_GT(fx.at(fx.l.step, 41, 51), 0.25f);  // the bump is in the outputs
}

TEST(Traversability, ALayerIdTheMapDoesNotHaveIsALayerError) {
  Fixture fx(20, 20);
  TraversabilityLayers bad = fx.l;
  bad.step = -1;
  EXPECT_THROW(configured().run(fx.map, Executor(1), bad), LayerError);
  bad = fx.l;
  bad.elevation = 99;
  EXPECT_THROW(configured().run(fx.map, Executor(2), bad), LayerError);
}

TEST(Traversability, BadParamsAreRefused) {
  EXPECT_THROW(configured({{"slope_layer", std::string("elevation")}}), ConfigError);
  EXPECT_THROW(configured({{"step_layer", std::string("slope")}}), ConfigError);
  EXPECT_THROW(configured({{"min_points", 2L}}), ConfigError);
  EXPECT_THROW(configured({{"critical_slope_rad", 2.0}}), ConfigError);
  EXPECT_THROW(configured({{"critical_step_m", 0.0}}), ConfigError);
  EXPECT_THROW(configured({{"weight_slope", 0.0}, {"weight_roughness", 0.0}, {"weight_step", 0.0}}), ConfigError);
  EXPECT_THROW(configured({{"run_on", std::vector<std::string>{"lidar"}}}), ConfigError);
}

TEST(Traversability, MapDependentChecksReachValidate) {
  const auto spec = parsePipelineString(R"(version: 1
map: {resolution: 0.1, size: [20, 20], tile: 16, layers: [elevation]}
pipeline:
  - {name: t, type: traversability, params: {plane_radius_m: 0.05, min_points: 100}}
  - {name: u, type: traversability, params: {step_radius_m: 1.5, slope_layer: s2, roughness_layer: r2, step_layer: h2, traversability_layer: t2}}
)", "p.yaml", ".");
  const auto errs = Engine::validate(spec, PluginRegistry{});
  std::string all;
  for (const auto& e : errs) all += e + "\n";
  EXPECT_NE(all.find("p.yaml:4:46: pipeline[0].params.plane_radius_m: must be at least the map's resolution (0.1 m, got 0.05 m)"),
            std::string::npos)
      << all;
  EXPECT_NE(all.find("pipeline[0].params.min_points: 100 is more than the plane window holds (3 x 3 = 9 cells at 0.1 m)"),
            std::string::npos)
      << all;
  EXPECT_NE(all.find("pipeline[1].params.step_radius_m: the window (31 cells across) does not fit in the map (20 x 20 cells)"),
            std::string::npos)
      << all;
}

TEST(Traversability, LoadsThroughTheHostAndRunsInAnEngine) {
  EngineOptions o;
  o.geometry = Geometry(0.1, Size(32, 32));
  o.map.tile_size = 16;
  o.layers = {LayerDecl{"elevation", "m", 1.0f, ""}};
  Engine e(o);
  e.addStage("t", PluginRegistry::createFromFile(std::string(TERRAMAP_PLUGIN_DIR) + "/traversability.so"),
             {{"run_on", std::vector<std::string>{"tick"}}});
  e.push(Tick{0});
  const LayeredMap& m = e.map();
  EXPECT_FLOAT_EQ(m.at(m.layerId("slope"), Index(16, 16)), 0.0f);
  EXPECT_FLOAT_EQ(m.at(m.layerId("roughness"), Index(16, 16)), 0.0f);
  EXPECT_FLOAT_EQ(m.at(m.layerId("step_height"), Index(16, 16)), 0.0f);
  EXPECT_FLOAT_EQ(m.at(m.layerId("traversability"), Index(16, 16)), 1.0f);
  EXPECT_EQ(m.layerInfo(m.layerId("slope")).unit, "rad");
  EXPECT_EQ(e.report().stages[0].stats.counters.at("passes"), 1.0);
  EXPECT_EQ(e.report().stages[0].stats.counters.at("cells_fitted"), 32.0 * 32.0);
}
