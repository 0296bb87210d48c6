#pragma once
/// \file
/// A Gaussian belief of one soil property and the product-of-Gaussians update every soil map
/// layer uses (soil_bayes per cell, octomap_strata per voxel and column). Header-only, no state.
#include <cmath>
#include <limits>

namespace terramap::soil {

struct Belief {
  double mean = std::numeric_limits<double>::quiet_NaN();
  double var = std::numeric_limits<double>::quiet_NaN();
};

/// Product of the prior and the measurement N(z, r):
///   mean = (r μ⁻ + σ²⁻ z) / (σ²⁻ + r),   var = σ²⁻ r / (σ²⁻ + r).
/// A prior with a non-finite mean or a variance that is not finite and above 0 is "no prior":
/// the result is the measurement. A measurement that is not finite, or r ≤ 0, leaves the prior.
inline Belief fuseBelief(const Belief& prior, double z, double r) {
  if (!std::isfinite(z) || !std::isfinite(r) || r <= 0.0) return prior;
  if (!std::isfinite(prior.mean) || !std::isfinite(prior.var) || prior.var <= 0.0) return {z, r};
  const double s = prior.var + r;
  return {(r * prior.mean + prior.var * z) / s, prior.var * r / s};
}

}  // namespace terramap::soil
