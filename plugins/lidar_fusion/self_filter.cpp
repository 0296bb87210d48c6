#include "self_filter.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>

namespace terramap::plugins {

namespace {
void readBoxes(const std::vector<double>& v, SelfFilterBox::Frame frame, double margin, const std::string& key,
               std::vector<SelfFilterBox>& out) {
  if (v.size() % 6 != 0)
    throw ConfigError("lidar_fusion: " + key + " has " + std::to_string(v.size()) +
                      " numbers; give 6 per box: [xmin, ymin, zmin, xmax, ymax, zmax, ...] in metres");
  for (std::size_t k = 0; k < v.size(); k += 6) {
    SelfFilterBox b;
    b.frame = frame;
    b.min = Eigen::Vector3d(v[k], v[k + 1], v[k + 2]) - Eigen::Vector3d::Constant(margin);
    b.max = Eigen::Vector3d(v[k + 3], v[k + 4], v[k + 5]) + Eigen::Vector3d::Constant(margin);
    if (!(Eigen::Vector3d(v[k], v[k + 1], v[k + 2]).array() < Eigen::Vector3d(v[k + 3], v[k + 4], v[k + 5]).array()).all())
      throw ConfigError("lidar_fusion: " + key + " box " + std::to_string(k / 6) + ": every min (numbers " +
                        std::to_string(k + 1) + "-" + std::to_string(k + 3) + ") must be below its max");
    out.push_back(b);
  }
}
}  // namespace

void SelfFilter::configure(const std::vector<double>& base_m, const std::vector<double>& blade_m, double margin_m,
                           const std::string& base_key, const std::string& blade_key) {
  if (!(margin_m >= 0.0) || !std::isfinite(margin_m))
    throw ConfigError("lidar_fusion: self_filter_margin_m must be >= 0 and finite (got " + formatNumber(margin_m) + ")");
  boxes_.clear();
  margin_m_ = margin_m;
  readBoxes(base_m, SelfFilterBox::Frame::Base, margin_m, base_key, boxes_);
  readBoxes(blade_m, SelfFilterBox::Frame::Blade, margin_m, blade_key, boxes_);
}

void SelfFilter::configureLinks(const std::array<std::vector<double>, 4>& link_m, const std::array<std::string, 4>& keys) {
  for (int k = 0; k < 4; ++k)
    readBoxes(link_m[k], static_cast<SelfFilterBox::Frame>(static_cast<int>(SelfFilterBox::Frame::Slew) + k), margin_m_,
              keys[k], boxes_);
}

bool SelfFilter::placed() const {
  for (const SelfFilterBox& b : boxes_) {
    if (b.frame == SelfFilterBox::Frame::Base && base_.empty()) return false;
    if (b.frame == SelfFilterBox::Frame::Blade && blade_.empty()) return false;
  }
  return true;
}

std::size_t SelfFilter::apply(const PointCloud& in, PointCloud& out) const {
  out.stamp = in.stamp;
  out.frame = in.frame;
  out.T_map_sensor = in.T_map_sensor;
  out.points.clear();
  out.points.reserve(in.points.size());
  // Every placed box as sensor -> box-frame transform, so a point costs one affine map per box.
  struct Placed {
    Eigen::Matrix3d R;
    Eigen::Vector3d t, min, max;
  };
  std::vector<Placed> placed;
  for (const SelfFilterBox& b : boxes_) {
    if (b.frame == SelfFilterBox::Frame::Base || b.frame == SelfFilterBox::Frame::Blade) {
      for (const auto& [id, T] : b.frame == SelfFilterBox::Frame::Base ? base_ : blade_) {
        const Eigen::Isometry3d A = T.inverse() * in.T_map_sensor;
        placed.push_back({A.linear(), A.translation(), b.min, b.max});
      }
      continue;
    }
    const int link = static_cast<int>(b.frame) - static_cast<int>(SelfFilterBox::Frame::Slew);
    for (const auto& [id, L] : links_) {
      const Eigen::Isometry3d A = L[link].inverse() * in.T_map_sensor;
      placed.push_back({A.linear(), A.translation(), b.min, b.max});
    }
  }
  std::size_t dropped = 0;
  for (const PointXYZI& p : in.points) {
    const Eigen::Vector3d ps(p.x, p.y, p.z);
    bool inside = false;
    for (const Placed& q : placed) {
      const Eigen::Vector3d pb = q.R * ps + q.t;
      if ((pb.array() >= q.min.array()).all() && (pb.array() <= q.max.array()).all()) {
        inside = true;
        break;
      }
    }
    if (inside) ++dropped;
    else out.points.push_back(p);
  }
  return dropped;
}

}  // namespace terramap::plugins
