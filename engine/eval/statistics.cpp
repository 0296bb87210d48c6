#include <terramap/eval/statistics.hpp>

#include <algorithm>
#include <cmath>

namespace terramap::eval {

double percentileSorted(const std::vector<double>& v, double p) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  const double pos = p / 100.0 * static_cast<double>(v.size() - 1);
  const std::size_t lo = static_cast<std::size_t>(std::floor(pos));
  const std::size_t hi = std::min(lo + 1, v.size() - 1);
  return v[lo] + (pos - static_cast<double>(lo)) * (v[hi] - v[lo]);
}

ErrorStats errorStats(std::vector<double> e) {
  ErrorStats r;
  r.n = static_cast<long>(e.size());
  if (e.empty()) return r;
  double s = 0, ss = 0;
  std::vector<double> a(e.size());
  for (std::size_t k = 0; k < e.size(); ++k) {
    s += e[k];
    ss += e[k] * e[k];
    a[k] = std::abs(e[k]);
  }
  const double n = static_cast<double>(e.size());
  r.bias = s / n;
  r.rmse = std::sqrt(ss / n);
  double var = 0;
  for (double x : e) var += (x - r.bias) * (x - r.bias);
  r.std = e.size() > 1 ? std::sqrt(var / (n - 1)) : 0.0;
  std::sort(e.begin(), e.end());
  r.p5 = percentileSorted(e, 5);
  r.p50 = percentileSorted(e, 50);
  r.p95 = percentileSorted(e, 95);
  std::sort(a.begin(), a.end());
  r.median_abs = percentileSorted(a, 50);
  r.p95_abs = percentileSorted(a, 95);
  r.max_abs = a.back();
  return r;
}

double rocAuc(std::vector<double> positives, std::vector<double> negatives) {
  if (positives.empty() || negatives.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::sort(positives.begin(), positives.end());
  std::sort(negatives.begin(), negatives.end());
  // For each positive: the negatives below it, and half those equal to it (two pointers).
  double u = 0.0;
  std::size_t below = 0, upto = 0;
  for (double p : positives) {
    while (below < negatives.size() && negatives[below] < p) ++below;
    if (upto < below) upto = below;
    while (upto < negatives.size() && negatives[upto] <= p) ++upto;
    u += static_cast<double>(below) + 0.5 * static_cast<double>(upto - below);
  }
  return u / (static_cast<double>(positives.size()) * static_cast<double>(negatives.size()));
}

}  // namespace terramap::eval
