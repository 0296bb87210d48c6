#pragma once
/// \file
/// The one implementation of the error statistics every evaluation reports (the blind-mapping
/// regions, the FEE extraction table, the truth section of `terramap run`'s report.json).
/// Percentiles are numpy's default ("linear": interpolated between the two nearest ranks).
/// Units are the caller's. Pure functions: safe from any thread.
#include <terramap/core/export.hpp>

#include <cstddef>
#include <limits>
#include <vector>

namespace terramap::eval {

/// The p-th percentile (p in [0, 100]) of an ascending vector, linearly interpolated; NaN when
/// the vector is empty.
TERRAMAP_API double percentileSorted(const std::vector<double>& sorted, double p);

/// Statistics of a set of errors e (estimate - truth). Every figure is NaN when n = 0.
struct ErrorStats {
  long n = 0;
  double bias = std::numeric_limits<double>::quiet_NaN();        ///< mean of e
  double rmse = std::numeric_limits<double>::quiet_NaN();        ///< sqrt(mean of e^2)
  double std = std::numeric_limits<double>::quiet_NaN();         ///< sample std of e (n - 1); 0 for n = 1
  double p5 = std::numeric_limits<double>::quiet_NaN();          ///< percentiles of e
  double p50 = std::numeric_limits<double>::quiet_NaN();
  double p95 = std::numeric_limits<double>::quiet_NaN();
  double median_abs = std::numeric_limits<double>::quiet_NaN();  ///< percentiles of |e|
  double p95_abs = std::numeric_limits<double>::quiet_NaN();
  double max_abs = std::numeric_limits<double>::quiet_NaN();
};

/// Sums run in the order given, so equal inputs give bit-equal figures.
TERRAMAP_API ErrorStats errorStats(std::vector<double> errors);

/// Area under the ROC curve of a score separating `positives` from `negatives`: the probability
/// that a random positive scores above a random negative, ties counting one half (the
/// Mann-Whitney U statistic over n_pos n_neg). 1 = perfect separation, 0.5 = none. NaN when
/// either set is empty. Non-finite scores must be removed by the caller.
TERRAMAP_API double rocAuc(std::vector<double> positives, std::vector<double> negatives);

}  // namespace terramap::eval
