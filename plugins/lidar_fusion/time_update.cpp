// lidar_fusion's time update (variance and age grow with the stamp) and the map's motion
// with the robot.
#include "lidar_fusion.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>

#include <cmath>

namespace terramap::plugins {

// ---- time and motion -------------------------------------------------------------------------

void LidarFusion::advanceTime(LayeredMap& map, const Executor& ex, double stamp) {
  if (!std::isfinite(stamp)) throw InputError("lidar_fusion: event stamp is not finite");
  if (!have_stamp_) {
    have_stamp_ = true;
    last_stamp_ = stamp;
    return;
  }
  if (stamp < last_stamp_)
    throw InputError("lidar_fusion: event stamp " + formatNumber(stamp) + " s is earlier than the previous " +
                     formatNumber(last_stamp_) + " s (events must be time-ordered)");
  const double dt = stamp - last_stamp_;
  last_stamp_ = stamp;
  if (dt == 0.0 || bound_map_ == nullptr) return;
  const float fdt = static_cast<float>(dt);
  const float dv = static_cast<float>(config_.time_variance_m2_per_s * dt);
  const int n = static_cast<int>(map.tileSize()) * map.tileSize();
  std::vector<int> tiles;
  for (int t = 0; t < map.tileCount(); ++t)
    if (tile_known_[static_cast<size_t>(t)]) tiles.push_back(t);
  ex.forEach(static_cast<int>(tiles.size()), [&](int k) {
    const int t = tiles[static_cast<size_t>(k)];
    // NaN + x stays NaN: unknown cells need no branch, and the loops vectorise.
    if (map.tileData(time_, t)) {
      float* tm = map.mutableTileData(time_, t);
      for (int c = 0; c < n; ++c) tm[c] += fdt;
    }
    if (dv != 0.0f && map.tileData(var_, t)) {
      float* v = map.mutableTileData(var_, t);
      for (int c = 0; c < n; ++c) v[c] += dv;
    }
  });
}

void LidarFusion::followTo(LayeredMap& map, const Eigen::Vector3d& position) {
  if (!config_.follow_robot) return;
  if (!position.allFinite()) throw InputError("lidar_fusion: follow_robot position is not finite");
  map.move(Position(position.x(), position.y()));
}

}  // namespace terramap::plugins
