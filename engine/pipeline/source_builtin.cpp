// The built-in source that needs another module: `sequence` (terramap::io). The simulator's
// `sim` source lives above both libraries (terramap::eval, sim_source.hpp), so an embedder that
// links only terramap::pipeline pulls in neither the simulator nor HDF5.
#include <terramap/io/rosbag.hpp>
#include <terramap/io/sequence.hpp>
#include <terramap/pipeline/source.hpp>

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>

namespace terramap {

namespace {

const RawParam* setting(const SourceSpec& s, const std::string& key) {
  auto it = s.settings.find(key);
  return it == s.settings.end() ? nullptr : &it->second;
}

std::vector<double> sourceDoubles(const SourceSpec& s, const std::string& key, size_t n) {
  const RawParam* r = setting(s, key);
  if (!r) return {};
  auto p = std::get_if<std::vector<double>>(&r->value);
  if (!p || p->size() != n)
    throw ConfigError(r->where + ": must be a list of " + std::to_string(n) + " numbers");
  for (double v : *p)
    if (!std::isfinite(v)) throw ConfigError(r->where + ": must be finite numbers");
  return *p;
}

long sourceCount(const SourceSpec& s, const std::string& key, long def, long min) {
  const RawParam* r = setting(s, key);
  if (!r) return def;
  auto p = std::get_if<long>(&r->value);
  if (!p || *p < min)
    throw ConfigError(r->where + ": must be an integer >= " + std::to_string(min));
  return *p;
}

bool sourceBool(const SourceSpec& s, const std::string& key, bool def) {
  const RawParam* r = setting(s, key);
  if (!r) return def;
  auto p = std::get_if<bool>(&r->value);
  if (!p) throw ConfigError(r->where + ": must be true or false");
  return *p;
}

/// [x, y, z, roll, pitch, yaw] (m, degrees) -> isometry.
Eigen::Isometry3d poseFromList(const std::vector<double>& v) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  if (v.empty()) return T;
  const double d = M_PI / 180.0;
  T.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  T.linear() = (Eigen::AngleAxisd(v[5] * d, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(v[4] * d, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(v[3] * d, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  return T;
}

/// A path of the source, resolved against the pipeline file's folder. It may begin with one of
/// terramap's own environment variables, `${TERRAMAP_NAME}` or `${TERRAMAP_NAME:-default}`, so
/// data that cannot ship with a pipeline (the KITTI frames' licence keeps them out of the
/// repository) is found through one setting: the variable's value when set and not empty (a
/// relative value from the current folder, as a shell user means it), else the default
/// (relative to the pipeline file, like any path). Only TERRAMAP_* names: a configuration file
/// does not get to read the rest of the environment into paths and messages.
std::string sourcePath(const PipelineSpec& spec, const std::string& key, bool required) {
  const std::string v = sourceString(spec.source, key, required);
  const std::size_t open = v.find("${");
  if (open == std::string::npos) return spec.resolvePath(v);
  const std::string& where = setting(spec.source, key)->where;
  const std::string form = "${TERRAMAP_NAME} or ${TERRAMAP_NAME:-default}";
  const std::size_t close = v.find('}', open);
  if (open != 0 || close == std::string::npos || v.find("${", close) != std::string::npos)
    throw ConfigError(where + ": a variable may only begin the path, as " + form + " (got '" + v + "')");
  const std::string inner = v.substr(2, close - 2), rest = v.substr(close + 1);
  const std::size_t dash = inner.find(":-");
  const std::string name = inner.substr(0, dash);
  bool valid = name.size() > 9 && name.compare(0, 9, "TERRAMAP_") == 0;
  for (char c : name) valid = valid && (std::isupper(static_cast<unsigned char>(c)) || std::isdigit(static_cast<unsigned char>(c)) || c == '_');
  if (!valid)
    throw ConfigError(where + ": only terramap's own variables may begin a path, as " + form + " (got '" + name + "')");
  namespace fs = std::filesystem;
  const char* env = std::getenv(name.c_str());
  const bool set = env && *env;
  if (!set && dash == std::string::npos)
    throw ConfigError(where + ": " + name + " is not set and '" + v + "' gives no default");
  const std::string path = set ? fs::absolute(fs::path(std::string(env) + rest)).lexically_normal().string()
                               : spec.resolvePath(inner.substr(dash + 2) + rest);
  // Said here, where the setting that chose the path is known, rather than by the reader.
  std::error_code ec;
  if (!fs::exists(path, ec))
    throw ConfigError(where + ": '" + path + "' does not exist (" +
                      (set ? name + " is '" + env + "'" : name + " is not set, so the default was used") + ")");
  return path;
}

/// Folder of clouds + poses. Optionally emits a Pose event (sensor pose) before each cloud,
/// so stages that follow the robot can move the map first.
class SequenceEventSource : public Source {
 public:
  SequenceEventSource(io::SequenceSpec spec, io::SequencePoses poses, bool emit_poses)
      : seq_(std::move(spec), std::move(poses)), emit_poses_(emit_poses) {}
  bool next(Event& e) override {
    if (pending_) {
      e = std::move(*pending_);
      pending_.reset();
      return true;
    }
    auto pc = seq_.next();
    if (!pc) return false;
    if (emit_poses_) {
      Pose p;
      p.stamp = pc->stamp;
      p.T_map_base = seq_.pose(seq_.position() - 1);
      e = p;
      pending_ = Event(std::move(*pc));
      return true;
    }
    e = std::move(*pc);
    return true;
  }
  double progress() const override {
    return seq_.size() ? static_cast<double>(seq_.position()) / static_cast<double>(seq_.size()) : 1.0;
  }

 private:
  io::SequenceSource seq_;
  bool emit_poses_;
  std::optional<Event> pending_;
};

std::unique_ptr<Source> makeSequence(const PipelineSpec& spec) {
  const SourceSpec& s = spec.source;
  checkSourceKeys(s, {"clouds", "poses", "pose_format", "extensions", "times", "period_s", "start_stamp_s",
                      "first", "stride", "max_frames", "frame_index", "T_body_sensor", "T_map_world",
                      "emit_poses"});
  io::SequenceSpec q;
  q.folder = sourcePath(spec, "clouds", true);
  if (const RawParam* r = setting(s, "extensions")) {
    if (auto p = std::get_if<std::vector<std::string>>(&r->value)) q.extensions = *p;
    else if (auto p1 = std::get_if<std::string>(&r->value)) q.extensions = {*p1};
    else throw ConfigError(r->where + ": must be a list of extensions like ['.bin']");
  }
  q.times_file = sourcePath(spec, "times", false);
  q.period_s = sourceDouble(s, "period_s", false, 0.1);
  if (!(q.period_s > 0)) throw ConfigError(setting(s, "period_s")->where + ": must be > 0");
  q.start_stamp_s = sourceDouble(s, "start_stamp_s", false, 0.0);
  q.first = static_cast<size_t>(sourceCount(s, "first", 0, 0));
  q.stride = static_cast<size_t>(sourceCount(s, "stride", 1, 1));
  q.max_frames = static_cast<size_t>(sourceCount(s, "max_frames", static_cast<long>(1) << 40, 1));
  const std::string fi = sourceString(s, "frame_index", false, "position");
  if (fi == "position") q.frame_index = io::FrameIndex::Position;
  else if (fi == "file_name") q.frame_index = io::FrameIndex::FileNameNumber;
  else throw ConfigError(setting(s, "frame_index")->where + ": must be 'position' or 'file_name' (got '" + fi + "')");
  q.T_body_sensor = poseFromList(sourceDoubles(s, "T_body_sensor", 6));
  q.T_map_world = poseFromList(sourceDoubles(s, "T_map_world", 6));
  const std::string poses = sourcePath(spec, "poses", false);
  io::SequencePoses sp = io::SequencePoses::identity();
  if (!poses.empty())
    sp = io::loadSequencePoses(poses,
                               io::parsePoseFileFormat(sourceString(s, "pose_format", false, "auto")));
  return std::make_unique<SequenceEventSource>(std::move(q), std::move(sp), sourceBool(s, "emit_poses", true));
}

/// A rosbag2 MCAP file's clouds with their poses (io/rosbag.hpp); a Pose event before each cloud
/// unless emit_poses is false, as the sequence source does.
class RosbagEventSource : public Source {
 public:
  RosbagEventSource(io::RosbagSpec spec, bool emit_poses) : bag_(std::move(spec)), emit_poses_(emit_poses) {}
  bool next(Event& e) override {
    if (pending_) {
      e = std::move(*pending_);
      pending_.reset();
      return true;
    }
    auto c = bag_.next();
    if (!c) return false;
    if (emit_poses_) {
      Pose p;
      p.stamp = c->cloud.stamp;
      p.T_map_base = c->T_map_base;
      e = p;
      pending_ = Event(std::move(c->cloud));
      return true;
    }
    e = std::move(c->cloud);
    return true;
  }
  double progress() const override {
    return bag_.cloudCount() ? static_cast<double>(bag_.position()) / static_cast<double>(bag_.cloudCount()) : 1.0;
  }
  std::map<std::string, long> dropped() const override { return bag_.dropped(); }

 private:
  io::RosbagSource bag_;
  bool emit_poses_;
  std::optional<Event> pending_;
};

std::unique_ptr<Source> makeRosbag(const PipelineSpec& spec) {
  const SourceSpec& s = spec.source;
  checkSourceKeys(s, {"bag", "cloud_topic", "pose_source", "map_frame", "tf_topics", "odometry_topic", "base_frame",
                      "max_clouds", "emit_poses"});
  io::RosbagSpec q;
  q.path = sourcePath(spec, "bag", true);
  q.cloud_topic = sourceString(s, "cloud_topic", true);
  const std::string ps = sourceString(s, "pose_source", false, "tf");
  if (ps == "tf") q.pose_source = io::RosbagSpec::PoseSource::Tf;
  else if (ps == "odometry") q.pose_source = io::RosbagSpec::PoseSource::Odometry;
  else throw ConfigError(setting(s, "pose_source")->where + ": must be 'tf' or 'odometry' (got '" + ps + "')");
  const bool odom = q.pose_source == io::RosbagSpec::PoseSource::Odometry;
  // With odometry the map frame is the odometry's own; a map_frame given is checked against it.
  q.map_frame = sourceString(s, "map_frame", false, odom ? "" : "map");
  if (const RawParam* r = setting(s, "tf_topics")) {
    if (auto p = std::get_if<std::vector<std::string>>(&r->value)) q.tf_topics = *p;
    else if (auto p1 = std::get_if<std::string>(&r->value)) q.tf_topics = {*p1};
    else throw ConfigError(r->where + ": must be a list of topics like [/tf, /tf_static]");
  }
  q.odometry_topic = sourceString(s, "odometry_topic", odom);
  if (!odom && setting(s, "odometry_topic"))
    throw ConfigError(setting(s, "odometry_topic")->where + ": only used with pose_source: odometry");
  q.base_frame = sourceString(s, "base_frame", false);
  q.max_clouds = static_cast<size_t>(sourceCount(s, "max_clouds", static_cast<long>(1) << 40, 1));
  try {
    return std::make_unique<RosbagEventSource>(std::move(q), sourceBool(s, "emit_poses", true));
  } catch (const ConfigError& e) {
    throw ConfigError(s.where + ": " + e.what());
  }
}

}  // namespace

void registerModuleSources() {
  registerSource("sequence", makeSequence);
  registerSource("rosbag", makeRosbag);
}

}  // namespace terramap
