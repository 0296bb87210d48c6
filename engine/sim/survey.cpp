#include <terramap/sim/lidar.hpp>
#include <terramap/sim/survey.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

namespace terramap::sim {

std::vector<PointCloud> surveyClouds(const Scenario& sc, const TruthTerrain& terrain, double stamp) {
  std::vector<PointCloud> out;
  const SurveySpec& sv = sc.survey;
  if (!sv.enabled()) return out;
  const double x0 = terrain.originX(), y0 = terrain.originY();
  const double sx = (terrain.nx() - 1) * terrain.resolution(), sy = (terrain.ny() - 1) * terrain.resolution();
  const long ni = static_cast<long>(std::floor(sx / sv.spacing_m)), nj = static_cast<long>(std::floor(sy / sv.spacing_m));
  const int bi = static_cast<int>(std::ceil(sx / sv.block_m)), bj = static_cast<int>(std::ceil(sy / sv.block_m));
  // Counter-based noise keyed by the scenario seed and the point's grid index: independent of
  // the block layout's iteration order and of threads.
  const std::uint64_t key = mixBits(sc.seed ^ 0x5a17e7d0c0ffeeULL);
  for (int a = 0; a < bi; ++a)
    for (int b = 0; b < bj; ++b) {
      const long i0 = static_cast<long>(std::ceil(a * sv.block_m / sv.spacing_m));
      const long i1 = std::min(ni, static_cast<long>(std::ceil((a + 1) * sv.block_m / sv.spacing_m)));
      const long j0 = static_cast<long>(std::ceil(b * sv.block_m / sv.spacing_m));
      const long j1 = std::min(nj, static_cast<long>(std::ceil((b + 1) * sv.block_m / sv.spacing_m)));
      std::vector<Eigen::Vector3d> pts;
      pts.reserve(static_cast<std::size_t>(std::max(0L, (i1 - i0) * (j1 - j0))));
      double zmax = -std::numeric_limits<double>::infinity();
      for (long i = i0; i < i1; ++i)
        for (long j = j0; j < j1; ++j) {
          const std::uint64_t h = mixBits(key ^ mixBits(static_cast<std::uint64_t>(i) * 0x9e3779b97f4a7c15ULL +
                                                        static_cast<std::uint64_t>(j)));
          const double x = x0 + (static_cast<double>(i) + unitFromBits(h)) * sv.spacing_m;
          const double y = y0 + (static_cast<double>(j) + unitFromBits(mixBits(h + 1))) * sv.spacing_m;
          const double z = terrain.initialHeightAt(x, y);
          if (!std::isfinite(z)) continue;
          pts.emplace_back(x, y, z + sv.sigma_m * gaussianFromBits(mixBits(h + 2)));
          zmax = std::max(zmax, z);
        }
      if (pts.empty()) continue;
      PointCloud pc;
      pc.stamp = stamp;
      pc.frame = "survey";
      const Eigen::Vector3d s(x0 + 0.5 * (a * sv.block_m + std::min((a + 1) * sv.block_m, sx)),
                              y0 + 0.5 * (b * sv.block_m + std::min((b + 1) * sv.block_m, sy)), zmax + sv.height_m);
      pc.T_map_sensor = Eigen::Isometry3d::Identity();
      pc.T_map_sensor.translation() = s;
      pc.points.reserve(pts.size());
      for (const Eigen::Vector3d& p : pts) {
        const Eigen::Vector3d q = p - s;
        pc.points.push_back({static_cast<float>(q.x()), static_cast<float>(q.y()), static_cast<float>(q.z()), 1.0f});
      }
      out.push_back(std::move(pc));
    }
  return out;
}

}  // namespace terramap::sim
