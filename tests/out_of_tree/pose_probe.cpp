// An out-of-tree plugin that reads the fields of every pose-carrying event the host hands it and
// reports what it read. Built with other SIMD flags than the host, it sees the host's memory
// through its own idea of the events' layout: if Eigen's alignment were not pinned,
// Isometry3d members (and the variant's index) would sit at other offsets, and the rotations
// read would not be rotations. The test compares this report between builds with different
// flags and checks that every rotation read is orthonormal.
#include <terramap/plugin/abi.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

namespace {

double rotationError(const Eigen::Isometry3d& T) {
  const Eigen::Matrix3d R = T.linear();
  const double bottom = (T.matrix().row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff();
  return std::max((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff(), bottom);
}

class PoseProbe : public terramap::Plugin {
 public:
  terramap::ParamSchema schema() const override { return {}; }
  void configure(const terramap::Params&) override {}
  std::vector<terramap::LayerSpec> layers() const override { return {}; }
  terramap::EventMask events() const override {
    using terramap::EventKind;
    return EventKind::Pose | EventKind::BladePose | EventKind::Observation;
  }
  void process(terramap::ProcessContext&, const terramap::Event& event) override {
    if (const auto* p = std::get_if<terramap::Pose>(&event)) {
      add(p->stamp, p->T_map_base);
      frames_ += p->frame == "base" ? 0 : 1;
    } else if (const auto* b = std::get_if<terramap::BladePose>(&event)) {
      add(b->stamp, b->T_map_blade);
      width_sum_ += b->geometry.width_m;
    } else if (const auto* o = std::get_if<terramap::Observation>(&event)) {
      add(o->stamp, o->T_map_base);
      add(o->stamp, o->T_map_blade);
      twist_sum_ += o->twist_base.sum() + o->twist_blade.sum();
      force_sum_ += std::isfinite(o->force_base_N.x()) ? o->force_base_N.norm() : 0.0;
    } else {
      ++unexpected_;
    }
  }
  void finish(terramap::ProcessContext& ctx) override {
    char buf[512];
    std::snprintf(buf, sizeof buf,
                  "{\"type\": \"pose_probe\", \"poses\": %ld, \"unexpected\": %ld, \"frames_wrong\": %ld, "
                  "\"max_rotation_error\": %.3e, \"translation_sum\": %.17g, \"stamp_sum\": %.17g, "
                  "\"twist_sum\": %.17g, \"force_sum\": %.17g, \"width_sum\": %.17g}",
                  poses_, unexpected_, frames_, max_rot_err_, translation_sum_, stamp_sum_, twist_sum_,
                  force_sum_, width_sum_);
    ctx.reportRecord(buf);
  }

 private:
  void add(double stamp, const Eigen::Isometry3d& T) {
    ++poses_;
    stamp_sum_ += stamp;
    translation_sum_ += T.translation().sum();
    const double e = rotationError(T);
    max_rot_err_ = std::isfinite(e) ? std::max(max_rot_err_, e) : INFINITY;
  }
  long poses_ = 0, unexpected_ = 0, frames_ = 0;
  double max_rot_err_ = 0, translation_sum_ = 0, stamp_sum_ = 0, twist_sum_ = 0, force_sum_ = 0, width_sum_ = 0;
};

}  // namespace

TERRAMAP_PLUGIN(PoseProbe, "pose_probe", "0.1.0", "out-of-tree test: reads every pose-carrying event")
