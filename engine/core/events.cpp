#include <terramap/core/events.hpp>

namespace terramap {

const char* kindName(EventKind k) {
  switch (k) {
    case EventKind::PointCloud: return "point_cloud";
    case EventKind::Pose: return "pose";
    case EventKind::BladePose: return "blade_pose";
    case EventKind::Observation: return "observation";
    case EventKind::Tick: return "tick";
  }
  return "unknown";
}

}  // namespace terramap
