// The built-in source that needs another module: `sequence` (terramap::io). The simulator's
// `sim` source lives above both libraries (terramap::eval, sim_source.hpp), so an embedder that
// links only terramap::pipeline pulls in neither the simulator nor HDF5.
#include <terramap/io/sequence.hpp>
#include <terramap/pipeline/source.hpp>

#include <cmath>

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
  q.folder = spec.resolvePath(sourceString(s, "clouds", true));
  if (const RawParam* r = setting(s, "extensions")) {
    if (auto p = std::get_if<std::vector<std::string>>(&r->value)) q.extensions = *p;
    else if (auto p1 = std::get_if<std::string>(&r->value)) q.extensions = {*p1};
    else throw ConfigError(r->where + ": must be a list of extensions like ['.bin']");
  }
  const std::string times = sourceString(s, "times", false);
  if (!times.empty()) q.times_file = spec.resolvePath(times);
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
  const std::string poses = sourceString(s, "poses", false);
  io::SequencePoses sp = io::SequencePoses::identity();
  if (!poses.empty())
    sp = io::loadSequencePoses(spec.resolvePath(poses),
                               io::parsePoseFileFormat(sourceString(s, "pose_format", false, "auto")));
  return std::make_unique<SequenceEventSource>(std::move(q), std::move(sp), sourceBool(s, "emit_poses", true));
}

}  // namespace

void registerModuleSources() {
  registerSource("sequence", makeSequence);
}

}  // namespace terramap
