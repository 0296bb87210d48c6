#pragma once
// Helpers shared by the blade_sweep tests: a small map with the three layers, blade poses from
// intuitive angles, and the soil-mass invariant computed independently of the plugin.
#include "blade_sweep.hpp"

#include <Eigen/Geometry>
#include <cmath>
#include <functional>

namespace terramap::plugins::test {

constexpr double kPi = 3.14159265358979323846;

struct TestMap {
  LayeredMap map;
  SweepLayers ids;
  TestMap(double res, int n, Position center = Position::Zero(), int tile = 64)
      : map(Geometry(res, Size(n, n), center), MapOptions{tile, false}) {
    ids.elevation = map.addLayer("elevation", "m");
    ids.loose = map.addLayer("loose", "m", 0.0f);
    ids.sigma = map.addLayer("height_sigma", "m");
  }
  void setElevation(const std::function<double(const Position&)>& f) {
    const Size n = map.geometry().size();
    Eigen::MatrixXf m(n.x(), n.y());
    for (int i = 0; i < n.x(); ++i)
      for (int j = 0; j < n.y(); ++j) m(i, j) = static_cast<float>(f(map.geometry().positionOf(Index(i, j))));
    map.fromMatrix(ids.elevation, m);
  }
  float H(int i, int j) const { return map.at(ids.elevation, Index(i, j)); }
  float L(int i, int j) const { return map.at(ids.loose, Index(i, j)); }
};

/// Blade rotation: heading of the blade normal `yaw` (about map z), then `roll` about the
/// normal (left end up for > 0), then `lean_back` (top of the face tilted backwards, > 0).
inline Eigen::Matrix3d bladeRotation(double yaw, double roll = 0.0, double lean_back = 0.0) {
  return (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()) *
          Eigen::AngleAxisd(-lean_back, Eigen::Vector3d::UnitY()))
      .toRotationMatrix();
}

inline BladePose bladePose(double stamp, const Eigen::Vector3d& edge_centre, const Eigen::Matrix3d& R,
                           double width = 1.85, double height = 0.76) {
  BladePose p;
  p.stamp = stamp;
  p.machine_id = "ctl";
  p.T_map_blade = Eigen::Isometry3d::Identity();
  p.T_map_blade.linear() = R;
  p.T_map_blade.translation() = edge_centre;
  p.geometry.width_m = width;
  p.geometry.height_m = height;
  return p;
}

/// Σ over cells of (H - L) + L/s where H is known, L/s where only L is (ALGORITHMS.md §D),
/// times the cell area: soil volume in undisturbed (bank) cubic metres. Summed in double.
inline double soilMass(const LayeredMap& m, const SweepLayers& ids, double swell) {
  const Eigen::MatrixXf H = m.toMatrix(ids.elevation), L = m.toMatrix(ids.loose);
  double sum = 0;
  for (int i = 0; i < H.rows(); ++i)
    for (int j = 0; j < H.cols(); ++j) {
      const double l = std::isfinite(L(i, j)) ? L(i, j) : 0.0;
      if (std::isfinite(H(i, j))) sum += (static_cast<double>(H(i, j)) - l) + l / swell;
      else sum += l / swell;
    }
  const double r = m.geometry().resolution();
  return sum * r * r;
}

/// A ProcessContext around a map for driving plugins directly.
struct Harness {
  Executor ex;
  RecordBus bus;
  PluginStats stats;
  ProcessContext ctx;
  Harness(LayeredMap& map, int threads) : ex(threads), ctx(map, ex, bus, stats, "blade") {}
};

}  // namespace terramap::plugins::test
