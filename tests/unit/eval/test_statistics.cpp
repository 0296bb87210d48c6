// The one implementation of the evaluation statistics (eval/statistics.hpp) against values
// worked out by hand and against a brute-force definition of numpy's linear percentile.
#include <terramap/eval/statistics.hpp>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

using namespace terramap::eval;

TEST(Statistics, PercentilesInterpolateBetweenRanksLikeNumpy) {
  const std::vector<double> v{1, 2, 3, 4};
  EXPECT_DOUBLE_EQ(percentileSorted(v, 0), 1.0);
  EXPECT_DOUBLE_EQ(percentileSorted(v, 100), 4.0);
  EXPECT_DOUBLE_EQ(percentileSorted(v, 50), 2.5);   // numpy.percentile([1,2,3,4], 50)
  EXPECT_DOUBLE_EQ(percentileSorted(v, 95), 3.85);  // position 2.85
  EXPECT_DOUBLE_EQ(percentileSorted({7.0}, 95), 7.0);
  EXPECT_TRUE(std::isnan(percentileSorted({}, 50)));
  // Brute force: the value at fractional position p/100 (n - 1), for random data and p.
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-5, 5);
  for (int trial = 0; trial < 200; ++trial) {
    std::vector<double> x(1 + trial % 17);
    for (double& e : x) e = u(rng);
    std::sort(x.begin(), x.end());
    const double p = std::uniform_real_distribution<double>(0, 100)(rng);
    const double pos = p / 100 * (x.size() - 1);
    const std::size_t k = static_cast<std::size_t>(pos);
    const double want = k + 1 < x.size() ? x[k] * (1 - (pos - k)) + x[k + 1] * (pos - k) : x[k];
    EXPECT_NEAR(percentileSorted(x, p), want, 1e-12) << "p " << p << " n " << x.size();
  }
}

TEST(Statistics, ErrorStatsOfKnownErrors) {
  const ErrorStats s = errorStats({-2, 1, 1, 4});
  EXPECT_EQ(s.n, 4);
  EXPECT_DOUBLE_EQ(s.bias, 1.0);
  EXPECT_DOUBLE_EQ(s.rmse, std::sqrt((4 + 1 + 1 + 16) / 4.0));
  EXPECT_DOUBLE_EQ(s.std, std::sqrt((9 + 0 + 0 + 9) / 3.0));
  EXPECT_DOUBLE_EQ(s.p50, 1.0);
  EXPECT_DOUBLE_EQ(s.median_abs, 1.5);  // |e| = 1 1 2 4
  EXPECT_DOUBLE_EQ(s.p95_abs, 2 + 0.85 * 2);
  EXPECT_DOUBLE_EQ(s.max_abs, 4.0);
  EXPECT_DOUBLE_EQ(errorStats({3}).std, 0.0);
  const ErrorStats none = errorStats({});
  EXPECT_EQ(none.n, 0);
  EXPECT_TRUE(std::isnan(none.rmse) && std::isnan(none.bias) && std::isnan(none.max_abs));
}

TEST(Statistics, RocAucCountsPairsInOrderWithTiesAsHalf) {
  EXPECT_DOUBLE_EQ(rocAuc({3, 4}, {1, 2}), 1.0);
  EXPECT_DOUBLE_EQ(rocAuc({1, 2}, {3, 4}), 0.0);
  // Pairs (p, n): 2>1, 2=2 (½), 2<3, 5>1, 5>2, 5>3 → 4.5 of 6.
  EXPECT_DOUBLE_EQ(rocAuc({5, 2}, {1, 3, 2}), 4.5 / 6.0);
  EXPECT_DOUBLE_EQ(rocAuc({7, 7}, {7}), 0.5);
  EXPECT_TRUE(std::isnan(rocAuc({}, {1})));
  // Against the definition on random scores with many ties.
  std::vector<double> p, n;
  for (int k = 0; k < 200; ++k) (k % 3 ? n : p).push_back(static_cast<double>((k * 37) % 11));
  double u = 0;
  for (double a : p)
    for (double b : n) u += a > b ? 1.0 : a == b ? 0.5 : 0.0;
  EXPECT_DOUBLE_EQ(rocAuc(p, n), u / (p.size() * n.size()));
}
