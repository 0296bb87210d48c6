#include <terramap/core/events.hpp>

namespace terramap {

const char* kindName(EventKind k) {
  switch (k) {
    case EventKind::PointCloud: return "point_cloud";
    case EventKind::Pose: return "pose";
    case EventKind::BladePose: return "blade_pose";
    case EventKind::Observation: return "observation";
    case EventKind::Tick: return "tick";
    case EventKind::Imu: return "imu";
    case EventKind::JointState: return "joint_state";
  }
  return "unknown";
}

EventMask eventMaskFromNames(const std::vector<std::string>& names, std::string* unknown) {
  EventMask m = 0;
  for (const auto& n : names) {
    bool found = false;
    for (EventKind k : {EventKind::PointCloud, EventKind::Pose, EventKind::BladePose, EventKind::Observation,
                        EventKind::Tick, EventKind::Imu, EventKind::JointState})
      if (n == kindName(k)) {
        m |= mask(k);
        found = true;
      }
    if (!found && unknown && unknown->empty()) *unknown = n;
  }
  return m;
}

}  // namespace terramap
