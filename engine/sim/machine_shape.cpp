#include <terramap/sim/machine_shape.hpp>

#include <algorithm>
#include <cmath>

namespace terramap::sim {

std::vector<ShapeBox> defaultCtlShape(double gauge_m, double track_length_m, double blade_width_m,
                                      double blade_height_m) {
  using F = ShapeBox::Frame;
  // CAT 299D3-class figures rounded from its spec sheet (height to the cab top 2.1 m, width over
  // the tracks 2.0 m, track width 0.45 m, ground clearance 0.35 m, length without a tool
  // 3.1 m); how they split into boxes is an estimate (docs/sim.md "Occlusion").
  const double tw = 0.45, half_gauge = 0.5 * gauge_m, tl = 0.5 * track_length_m + 0.25;  // idler and sprocket
  std::vector<ShapeBox> s;
  s.push_back({"track_left", F::Base, {-tl, half_gauge - 0.5 * tw, 0.0}, {tl, half_gauge + 0.5 * tw, 0.55}});
  s.push_back({"track_right", F::Base, {-tl, -half_gauge - 0.5 * tw, 0.0}, {tl, -half_gauge + 0.5 * tw, 0.55}});
  s.push_back({"body", F::Base, {-1.45, -half_gauge + 0.5 * tw, 0.35}, {0.75, half_gauge - 0.5 * tw, 1.20}});
  s.push_back({"cab", F::Base, {-0.90, -0.50, 1.20}, {0.60, 0.50, 2.05}});
  s.push_back({"arm_left", F::Base, {-1.25, half_gauge - 0.5 * tw, 0.90}, {0.95, half_gauge + 0.5 * tw, 1.30}});
  s.push_back({"arm_right", F::Base, {-1.25, -half_gauge - 0.5 * tw, 0.90}, {0.95, -half_gauge + 0.5 * tw, 1.30}});
  // The blade plate behind its face (x = 0 is the face, the cutting edge at z = 0).
  s.push_back({"blade", F::Blade, {-0.05, -0.5 * blade_width_m, 0.0}, {0.0, 0.5 * blade_width_m, blade_height_m}});
  return s;
}

std::vector<ShapeBox> defaultExcavatorShape(double gauge_m, double track_length_m, double track_width_m,
                                            double plow_width_m, double plow_height_m, double boom_m, double arm_m,
                                            const Eigen::Vector3d& bucket_min, const Eigen::Vector3d& bucket_max) {
  using F = ShapeBox::Frame;
  // TB235-2 figures rounded from its spec sheet (width over the tracks 1.55 m, height to the cab
  // top 2.5 m, tail swing radius 0.78 m); the split into boxes is an estimate. The slew frame's
  // origin is on the slew bearing, 0.55 m above the track contact plane (ArmSpec).
  const double half_gauge = 0.5 * gauge_m, tw = track_width_m, tl = 0.5 * track_length_m + 0.2;
  std::vector<ShapeBox> s;
  s.push_back({"track_left", F::Base, {-tl, half_gauge - 0.5 * tw, 0.0}, {tl, half_gauge + 0.5 * tw, 0.5}});
  s.push_back({"track_right", F::Base, {-tl, -half_gauge - 0.5 * tw, 0.0}, {tl, -half_gauge + 0.5 * tw, 0.5}});
  s.push_back({"house", F::Slew, {-0.78, -0.75, 0.0}, {0.45, 0.75, 0.65}});
  s.push_back({"cab", F::Slew, {-0.45, -0.05, 0.65}, {0.45, 0.75, 1.85}});
  s.push_back({"plow", F::Blade, {-0.05, -0.5 * plow_width_m, 0.0}, {0.0, 0.5 * plow_width_m, plow_height_m}});
  s.push_back({"boom", F::Boom, {0.0, -0.12, -0.17}, {boom_m, 0.12, 0.17}});
  s.push_back({"arm", F::Arm, {0.0, -0.09, -0.12}, {arm_m, 0.09, 0.12}});
  s.push_back({"bucket", F::Bucket, bucket_min, bucket_max});
  return s;
}

void placeShape(const std::vector<ShapeBox>& shape, const Eigen::Isometry3d& T_map_base,
                const Eigen::Isometry3d& T_map_blade, std::vector<PlacedBox>& out,
                const std::array<Eigen::Isometry3d, 4>* T_map_links) {
  for (const ShapeBox& b : shape) {
    const bool link = b.frame != ShapeBox::Frame::Base && b.frame != ShapeBox::Frame::Blade;
    if (link && !T_map_links) continue;
    const Eigen::Isometry3d& T = b.frame == ShapeBox::Frame::Base    ? T_map_base
                                 : b.frame == ShapeBox::Frame::Blade ? T_map_blade
                                 : (*T_map_links)[static_cast<int>(b.frame) - static_cast<int>(ShapeBox::Frame::Slew)];
    PlacedBox p;
    p.centre = T * (0.5 * (b.min + b.max));
    p.R = T.linear();
    p.half = 0.5 * (b.max - b.min);
    p.radius = p.half.norm();
    out.push_back(p);
  }
}

namespace {

/// Entry of the ray o + t d into box b if it is in [t_min, t_max] (the ray starting outside);
/// +inf otherwise. On a hit, *normal is the outward normal of the face entered.
double enterBox(const PlacedBox& b, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min, double t_max,
                Eigen::Vector3d* normal) {
  const double none = std::numeric_limits<double>::infinity();
  // Bounding sphere first: most rays pass far from most boxes.
  const Eigen::Vector3d oc = b.centre - o;
  const double tc = oc.dot(d);
  const double miss2 = oc.squaredNorm() - tc * tc;
  if (miss2 > b.radius * b.radius || tc + b.radius < t_min || tc - b.radius > t_max) return none;
  // Slabs in the box frame.
  const Eigen::Vector3d ob = b.R.transpose() * (-oc), db = b.R.transpose() * d;
  double t0 = -std::numeric_limits<double>::infinity(), t1 = std::numeric_limits<double>::infinity();
  int axis = -1;
  double sign = 0;
  bool inside = true;
  for (int k = 0; k < 3; ++k) {
    if (std::abs(ob[k]) > b.half[k]) inside = false;
    if (db[k] == 0.0) {
      if (std::abs(ob[k]) > b.half[k]) return none;  // parallel to and outside this slab
      continue;
    }
    double ta = (-b.half[k] - ob[k]) / db[k], tb = (b.half[k] - ob[k]) / db[k];
    double s = -1.0;  // entering through the -half face
    if (ta > tb) {
      std::swap(ta, tb);
      s = 1.0;
    }
    if (ta > t0) {
      t0 = ta;
      axis = k;
      sign = s;
    }
    t1 = std::min(t1, tb);
  }
  if (inside || axis < 0 || t0 > t1 || t0 < t_min || t0 > t_max) return none;
  if (normal) *normal = sign * b.R.col(axis);
  return t0;
}

}  // namespace

double firstBoxHit(const std::vector<PlacedBox>& boxes, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                   double t_min, double t_max, Eigen::Vector3d* normal) {
  double best = std::numeric_limits<double>::infinity();
  for (const PlacedBox& b : boxes) {
    Eigen::Vector3d n;
    const double t = enterBox(b, o, d, t_min, std::min(t_max, best), &n);
    if (t < best) {
      best = t;
      if (normal) *normal = n;
    }
  }
  return best;
}

double firstBoxHit(const PlacedBox* boxes, const int* idx, int n, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                   double t_min, double t_max, Eigen::Vector3d* normal) {
  double best = std::numeric_limits<double>::infinity();
  for (int q = 0; q < n; ++q) {
    Eigen::Vector3d nq;
    const double t = enterBox(boxes[idx[q]], o, d, t_min, std::min(t_max, best), &nq);
    if (t < best) {
      best = t;
      if (normal) *normal = nq;
    }
  }
  return best;
}

}  // namespace terramap::sim
