#include <terramap/io/rosbag.hpp>

#include <terramap/core/error.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/core/text.hpp>
#include <terramap/io/mcap.hpp>
#include <terramap/io/ros2_messages.hpp>

#include <algorithm>
#include <set>

namespace terramap::io {

namespace {

constexpr const char* kCloudType = "sensor_msgs/msg/PointCloud2";
constexpr const char* kTfType = "tf2_msgs/msg/TFMessage";
constexpr const char* kOdomType = "nav_msgs/msg/Odometry";

/// "topic (type)" of every channel, for messages that say what the bag has.
std::string topicsOf(const mcap::Reader& r) {
  std::string s;
  for (const auto& [id, c] : r.channels()) {
    const mcap::Schema* sc = r.schemaOf(c);
    s += (s.empty() ? "" : ", ") + c.topic + " (" + (sc ? sc->name : "no schema") + ")";
  }
  return s.empty() ? "no topics" : s;
}

std::string messageWhere(const std::string& topic, std::size_t index, const mcap::Message& m) {
  return m.where + ": topic '" + topic + "' message " + std::to_string(index);
}

}  // namespace

RosbagSource::~RosbagSource() = default;

void RosbagSource::countBytes(std::size_t bytes) {
  kept_bytes_ += bytes;
  requireInputBudget(kept_bytes_, spec_.path + ": the transforms and odometry kept for interpolation",
                     std::to_string(kept_bytes_) + " bytes so far");
}

void RosbagSource::addTransform(const std::string& parent, const std::string& child, bool is_static, double t,
                                const Eigen::Isometry3d& T, const std::string& where) {
  if (parent.empty() || child.empty())
    throw InputError(where + ": a transform with an empty frame id (parent '" + parent + "', child '" + child + "')");
  if (parent == child) throw InputError(where + ": a transform from frame '" + child + "' to itself");
  Link& l = links_[child];
  if (l.parent.empty()) {
    l.parent = parent;
    l.is_static = is_static;
  } else if (l.parent != parent) {
    throw InputError(where + ": frame '" + child + "' has parent '" + parent + "' here but '" + l.parent +
                     "' before (a tf tree gives each frame one parent)");
  }
  if (is_static) {
    // The latest static transform of a link replaces the earlier ones, as tf2's static buffer does.
    l.is_static = true;
    l.samples.assign(1, {0.0, T});
    return;
  }
  if (l.is_static) return;  // a link published as static stays static
  countBytes(sizeof(std::pair<double, Eigen::Isometry3d>));
  l.samples.emplace_back(t, T);
}

RosbagSource::RosbagSource(RosbagSpec spec) : spec_(std::move(spec)) {
  reader_ = std::make_unique<mcap::Reader>(spec_.path);
  mcap::Reader& r = *reader_;
  const bool odom = spec_.pose_source == RosbagSpec::PoseSource::Odometry;
  const std::set<std::string> tf_topics(spec_.tf_topics.begin(), spec_.tf_topics.end());
  std::map<std::string, std::size_t> seen;  // messages per topic, for the index in messages
  std::map<std::uint16_t, int> role;        // channel -> 0 other, 1 cloud, 2 tf, 3 tf_static, 4 odometry
  std::set<std::string> frames;
  auto roleOf = [&](const mcap::Channel& c) {
    auto it = role.find(c.id);
    if (it != role.end()) return it->second;
    const mcap::Schema* s = r.schemaOf(c);
    const std::string type = s ? s->name : "";
    int k = 0;
    const char* want = nullptr;
    if (c.topic == spec_.cloud_topic) k = 1, want = kCloudType;
    else if (tf_topics.count(c.topic)) k = c.topic == "/tf_static" ? 3 : 2, want = kTfType;
    else if (odom && c.topic == spec_.odometry_topic) k = 4, want = kOdomType;
    if (want && type != want)
      throw ConfigError(spec_.path + ": topic '" + c.topic + "' carries " + (type.empty() ? "no schema" : "'" + type + "'") +
                        ", not " + want);
    if (want && c.message_encoding != "cdr")
      throw ConfigError(spec_.path + ": topic '" + c.topic + "' is encoded as '" + c.message_encoding +
                        "', not 'cdr' (ROS 2)");
    role[c.id] = k;
    return k;
  };
  mcap::Message m;
  while (r.next(m)) {
    const mcap::Channel& c = r.channelOf(m);
    const int k = roleOf(c);
    if (k == 0) continue;
    const std::size_t index = seen[c.topic]++;
    if (k == 1) {
      if (clouds_total_ < spec_.max_clouds) ++clouds_total_;
      continue;
    }
    const std::string where = messageWhere(c.topic, index, m);
    if (k == 2 || k == 3) {
      for (const auto& t : ros2::decodeTFMessage(m.data.data(), m.data.size(), where)) {
        addTransform(t.header.frame_id, t.child_frame_id, k == 3, t.header.stamp.seconds(), t.transform(), where);
        frames.insert(t.header.frame_id);
        frames.insert(t.child_frame_id);
      }
      continue;
    }
    const ros2::Odometry o = ros2::decodeOdometry(m.data.data(), m.data.size(), where);
    if (odometry_.empty()) {
      odometry_frame_ = o.header.frame_id;
      odometry_child_ = o.child_frame_id;
      if (!spec_.map_frame.empty() && odometry_frame_ != spec_.map_frame)
        throw ConfigError(where + ": the odometry is in frame '" + odometry_frame_ + "', the source's map_frame is '" +
                          spec_.map_frame + "' (set map_frame to it, or leave map_frame out)");
    } else if (o.header.frame_id != odometry_frame_ || o.child_frame_id != odometry_child_) {
      throw InputError(where + ": odometry of '" + o.child_frame_id + "' in '" + o.header.frame_id + "', earlier of '" +
                       odometry_child_ + "' in '" + odometry_frame_ + "'");
    }
    countBytes(sizeof(std::pair<double, Eigen::Isometry3d>));
    odometry_.emplace_back(o.header.stamp.seconds(), o.pose());
  }
  if (!seen.count(spec_.cloud_topic))
    throw ConfigError(spec_.path + ": no messages on the cloud topic '" + spec_.cloud_topic + "'; the bag has " + topicsOf(r));
  if (odom && !seen.count(spec_.odometry_topic))
    throw ConfigError(spec_.path + ": no messages on the odometry topic '" + spec_.odometry_topic + "'; the bag has " +
                      topicsOf(r));
  if (!odom) {
    bool any_tf = false;
    for (const auto& t : spec_.tf_topics) any_tf = any_tf || seen.count(t);
    if (!any_tf)
      throw ConfigError(spec_.path + ": no messages on the tf topics [" + joinStrings(spec_.tf_topics) + "]; the bag has " +
                        topicsOf(r) + " (or take poses from an odometry topic)");
    if (!frames.count(spec_.map_frame)) {
      std::vector<std::string> known(frames.begin(), frames.end());
      throw ConfigError(spec_.path + ": map_frame '" + spec_.map_frame + "' is in none of the bag's transforms" +
                        didYouMean(spec_.map_frame, known) + "; its frames: " + joinStrings(known));
    }
  }
  // Samples in time order (a bag's messages are in receive order, not always in stamp order).
  auto byTime = [](const auto& a, const auto& b) { return a.first < b.first; };
  for (auto& [child, l] : links_) std::stable_sort(l.samples.begin(), l.samples.end(), byTime);
  std::stable_sort(odometry_.begin(), odometry_.end(), byTime);
  r.rewind();
}

std::optional<Eigen::Isometry3d> RosbagSource::interpolate(const std::vector<std::pair<double, Eigen::Isometry3d>>& s,
                                                           double t) {
  if (s.empty() || t < s.front().first || t > s.back().first) return std::nullopt;
  auto hi = std::lower_bound(s.begin(), s.end(), t, [](const auto& a, double v) { return a.first < v; });
  if (hi->first == t) return hi->second;  // exact: no arithmetic, so a recorded pose comes back bit for bit
  auto lo = hi - 1;
  const double a = (t - lo->first) / (hi->first - lo->first);
  const Eigen::Quaterniond q0(lo->second.linear()), q1(hi->second.linear());
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = q0.slerp(a, q1).toRotationMatrix();
  T.translation() = (1 - a) * lo->second.translation() + a * hi->second.translation();
  return T;
}

std::optional<Eigen::Isometry3d> RosbagSource::chainToRoot(const std::string& frame, const std::string& root,
                                                           double t) const {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  std::string f = frame;
  bool first = true;
  for (std::size_t depth = 0; f != root; ++depth) {
    auto it = links_.find(f);
    if (it == links_.end() || depth > links_.size()) return std::nullopt;  // no parent, or a loop
    const Link& l = it->second;
    std::optional<Eigen::Isometry3d> step = l.is_static ? std::optional<Eigen::Isometry3d>(l.samples.front().second)
                                                        : interpolate(l.samples, t);
    if (!step) return std::nullopt;
    // The first link alone is returned as recorded (no multiplication by the identity).
    T = first ? *step : *step * T;
    first = false;
    f = l.parent;
  }
  return T;
}

std::optional<Eigen::Isometry3d> RosbagSource::poseOf(const std::string& frame, double t) const {
  if (spec_.pose_source == RosbagSpec::PoseSource::Tf) return chainToRoot(frame, spec_.map_frame, t);
  const auto T_map_child = interpolate(odometry_, t);
  if (!T_map_child) return std::nullopt;
  if (frame == odometry_child_) return T_map_child;
  const auto T_child_frame = chainToRoot(frame, odometry_child_, t);
  if (!T_child_frame) return std::nullopt;
  return *T_map_child * *T_child_frame;
}

std::optional<Eigen::Isometry3d> RosbagSource::lookup(const std::string& target, const std::string& source, double t) const {
  if (target == source) return Eigen::Isometry3d::Identity();
  return chainToRoot(source, target, t);
}

std::optional<RosbagCloud> RosbagSource::next() {
  mcap::Message m;
  while (clouds_seen_ < clouds_total_ && reader_->next(m)) {
    const mcap::Channel& c = reader_->channelOf(m);
    if (c.topic != spec_.cloud_topic) continue;
    const std::size_t index = clouds_seen_++;
    const std::string where = messageWhere(c.topic, index, m);
    ros2::PointCloud2 msg = ros2::decodePointCloud2(m.data.data(), m.data.size(), where);
    const double t = msg.header.stamp.seconds();
    if (t < last_stamp_) {
      ++dropped_["rosbag_stamp_backwards"];
      continue;
    }
    const std::string& frame = msg.header.frame_id;
    const auto T_map_sensor = poseOf(frame, t);
    const std::string base = spec_.base_frame.empty() ? frame : spec_.base_frame;
    const auto T_map_base = base == frame ? T_map_sensor : poseOf(base, t);
    if (!T_map_sensor || !T_map_base) {
      ++dropped_["rosbag_no_pose"];
      continue;
    }
    RosbagCloud out;
    out.cloud.points = ros2::cloudPoints(msg, where);
    out.cloud.stamp = t;
    out.cloud.frame = frame;
    out.cloud.T_map_sensor = *T_map_sensor;
    out.T_map_base = *T_map_base;
    last_stamp_ = t;
    return out;
  }
  return std::nullopt;
}

}  // namespace terramap::io
