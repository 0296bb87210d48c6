// Ray-cast LiDAR.
#include <terramap/sim/lidar.hpp>

#include <cmath>
#include <limits>

namespace terramap::sim {

std::uint64_t mixBits(std::uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

LidarModel::LidarModel(const SensorSpec& spec) : spec_(spec) {
  const int B = spec.beams, C = spec.columns;
  dirs_.reserve(static_cast<std::size_t>(B) * C);
  const bool full_circle = spec.hfov_rad >= 2 * M_PI - 1e-9;
  for (int c = 0; c < C; ++c) {
    // Azimuth centred on the sensor x axis; a full circle does not repeat its first column.
    double az;
    if (C == 1) az = 0.0;
    else if (full_circle) az = -M_PI + (c + 0.5) * (2 * M_PI / C);
    else az = -0.5 * spec.hfov_rad + c * spec.hfov_rad / (C - 1);
    for (int b = 0; b < B; ++b) {
      const double el = B == 1 ? 0.5 * (spec.vfov_min_rad + spec.vfov_max_rad)
                               : spec.vfov_min_rad + b * (spec.vfov_max_rad - spec.vfov_min_rad) / (B - 1);
      dirs_.emplace_back(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
    }
  }
}

std::size_t LidarModel::scan(const TruthTerrain& terrain, const Eigen::Isometry3d& T_map_sensor, std::uint64_t noise_key,
                             const Executor* exec, std::vector<PointXYZI>& out) const {
  const int B = spec_.beams, C = spec_.columns;
  const int chunks = (C + columns_per_chunk_ - 1) / columns_per_chunk_;
  std::vector<std::vector<PointXYZI>> parts(chunks);
  const Eigen::Vector3d o = T_map_sensor.translation();
  const Eigen::Matrix3d R = T_map_sensor.linear();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  auto work = [&](int ch) {
    std::vector<PointXYZI>& pts = parts[ch];
    const int c0 = ch * columns_per_chunk_, c1 = std::min(C, c0 + columns_per_chunk_);
    pts.reserve(static_cast<std::size_t>(c1 - c0) * B);
    for (int c = c0; c < c1; ++c) {
      for (int b = 0; b < B; ++b) {
        const std::size_t k = static_cast<std::size_t>(c) * B + b;
        const Eigen::Vector3d& ds = dirs_[k];
        const Eigen::Vector3d dm = R * ds;
        double t = terrain.raycast(o, dm, spec_.min_range_m, spec_.max_range_m);
        const std::uint64_t h = mixBits(noise_key ^ mixBits(k));
        bool hit = !std::isnan(t);
        if (hit && spec_.dropout > 0 && unitFromBits(mixBits(h ^ 0xd1b54a32d192ed03ULL)) < spec_.dropout) hit = false;
        if (!hit) {
          if (spec_.keep_dropouts) pts.push_back({nan, nan, nan, nan});
          continue;
        }
        if (spec_.range_noise_m > 0) {
          const double u1 = unitFromBits(h), u2 = unitFromBits(mixBits(h + 1));
          t += spec_.range_noise_m * std::sqrt(-2.0 * std::log(u1)) * std::cos(2 * M_PI * u2);
        }
        const Eigen::Vector3d p = o + dm * t;
        const Eigen::Vector2d g = terrain.gradientAt(p.x(), p.y());
        float inten = nan;
        if (!std::isnan(g.x())) {
          const Eigen::Vector3d n = Eigen::Vector3d(-g.x(), -g.y(), 1.0).normalized();
          inten = static_cast<float>(std::abs(n.dot(dm)));
        }
        pts.push_back({static_cast<float>(ds.x() * t), static_cast<float>(ds.y() * t), static_cast<float>(ds.z() * t), inten});
      }
    }
  };
  if (exec) exec->forEach(chunks, work);
  else serialForEach(chunks, work);
  std::size_t total = 0, hits = 0;
  for (const auto& p : parts) total += p.size();
  out.clear();
  out.reserve(total);
  for (const auto& p : parts) {
    for (const PointXYZI& q : p) {
      if (!std::isnan(q.x)) ++hits;
      out.push_back(q);
    }
  }
  return hits;
}

}  // namespace terramap::sim
