#pragma once
/// \file
/// What the step files of lidar_fusion share (not installed): see lidar_fusion.hpp for the steps.

#include <algorithm>
#include <cmath>
#include <limits>

namespace terramap::plugins::lidar_fusion_internal {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
/// Side (cells) of the blocks the ray walk decides to skip or walk as a whole: small enough that
/// a ray high above the ground skips most of its path, large enough that the decision costs
/// little next to the cells it saves.
constexpr int kRayBlock = 8;
/// Where the cleanup's walk of a ray (sensor-relative end dx, dy, dz in m) ends, as a fraction
/// of the ray: the end margin and max_ray_length_m cut it. Not walked unless > 0 (NaN too);
/// L is set to the ray's length.
inline double rayWalkEnd(double dx, double dy, double dz, double margin, double max_len, double& L) {
  L = std::sqrt(dx * dx + dy * dy + dz * dz);
  if (!(L > 1e-9)) return 0.0;
  return std::min({1.0, (L - margin) / L, max_len / L});
}

}  // namespace terramap::plugins::lidar_fusion_internal
