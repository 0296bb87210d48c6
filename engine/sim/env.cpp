// The simulator as an environment: agents, levers, observations, reward terms, kept-terrain reset.
#include <terramap/core/error.hpp>
#include <terramap/sim/env.hpp>
#include <terramap/sim/lidar.hpp>
#include <terramap/sim/world.hpp>

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <sstream>
#include <stdexcept>

namespace terramap::sim {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string fmt(double v) {
  std::ostringstream os;
  os.precision(6);
  os << v;
  return os.str();
}

/// `over` merged into `base`: mappings key by key, `machines` entries by their id, anything
/// else replaced. `path` names the place for errors.
YAML::Node mergeYaml(const YAML::Node& base, const YAML::Node& over, const std::string& path) {
  if (!base || !base.IsMap() || !over.IsMap()) return YAML::Clone(over);
  YAML::Node out = YAML::Clone(base);
  for (const auto& kv : over) {
    const std::string key = kv.first.as<std::string>();
    const std::string sub = path.empty() ? key : path + "." + key;
    if (key == "machines" && path.empty() && kv.second.IsSequence() && out["machines"] && out["machines"].IsSequence()) {
      YAML::Node machines = out["machines"];
      for (const YAML::Node& m : kv.second) {
        if (!m.IsMap() || !m["id"])
          throw ConfigError("overrides: " + sub + ": each entry needs the id of the machine it changes");
        const std::string id = m["id"].as<std::string>();
        bool found = false;
        std::string ids;
        for (std::size_t i = 0; i < machines.size(); ++i) {
          const std::string mid = machines[i]["id"] ? machines[i]["id"].as<std::string>() : "";
          ids += (ids.empty() ? "" : ", ") + mid;
          if (mid == id) {
            machines[i] = mergeYaml(machines[i], m, sub + "[" + id + "]");
            found = true;
          }
        }
        if (!found) throw ConfigError("overrides: " + sub + ": no machine '" + id + "' in the scenario (" + ids + ")");
      }
      continue;
    }
    if (out[key]) out[key] = mergeYaml(out[key], kv.second, sub);
    else out[key] = YAML::Clone(kv.second);
  }
  return out;
}

std::string dump(const YAML::Node& n) {
  if (!n) return "";
  YAML::Emitter e;
  e << n;
  return e.c_str();
}

/// What fixes the initial terrain in a scenario's YAML: `terrain:` and the seed its hills take.
std::string terrainKey(const std::string& yaml_text) {
  const YAML::Node root = YAML::Load(yaml_text);
  return dump(root["terrain"]) + "\n#seed " + dump(root["seed"]);
}

Eigen::Vector4d quatWxyz(const Eigen::Isometry3d& T) {
  const Eigen::Quaterniond q(T.linear());
  return {q.w(), q.x(), q.y(), q.z()};
}

void putPose(std::vector<double>& v, const Eigen::Isometry3d& T) {
  const Eigen::Vector3d p = T.translation();
  const Eigen::Vector4d q = quatWxyz(T);
  v.insert(v.end(), {p.x(), p.y(), p.z(), q[0], q[1], q[2], q[3]});
}

std::uint64_t nextSeed(std::uint64_t s) { return mixBits(s ^ 0x9e3779b97f4a7c15ULL); }

// The agent's observation vector from what the step delivered (Env::observationNames order):
// poses, twists, cylinders, tracks, engine, then the optional force, IMUs (each its last sample
// of the step, NaN before its first) and arm joints.
void observationVector(AgentObservation& o, bool force, const std::vector<std::string>& imu_frames, bool arm,
                       std::size_t size) {
  const terramap::Observation& ob = o.raw;
  std::vector<double>& v = o.vector;
  v.reserve(size);
  putPose(v, ob.T_map_base);
  for (int k = 0; k < 6; ++k) v.push_back(ob.twist_base[k]);
  putPose(v, ob.T_map_blade);
  v.insert(v.end(), ob.cylinder_length_m.begin(), ob.cylinder_length_m.end());
  v.insert(v.end(), ob.cylinder_velocity_mps.begin(), ob.cylinder_velocity_mps.end());
  v.insert(v.end(), ob.track_speed_mps.begin(), ob.track_speed_mps.end());
  v.push_back(ob.engine_speed_rpm);
  if (force) v.insert(v.end(), {ob.force_base_N.x(), ob.force_base_N.y(), ob.force_base_N.z()});
  for (const std::string& f : imu_frames) {
    const ImuSample* last = nullptr;
    for (const ImuSample& s : o.imu)
      if (s.frame == f) last = &s;
    if (last) {
      v.insert(v.end(), {last->accel_mps2.x(), last->accel_mps2.y(), last->accel_mps2.z()});
      v.insert(v.end(), {last->gyro_radps.x(), last->gyro_radps.y(), last->gyro_radps.z()});
    } else {
      v.insert(v.end(), 6, kNaN);
    }
  }
  if (arm) {
    const JointState js = o.joints.value_or(JointState{});
    v.insert(v.end(), js.position_rad.begin(), js.position_rad.end());
    v.insert(v.end(), js.velocity_radps.begin(), js.velocity_radps.end());
    v.insert(v.end(), js.effort_nm.begin(), js.effort_nm.end());
    v.push_back(js.bucket_load_kg);
  }
}

// The target surface's task terms over its rectangle of truth nodes; true when the ground left
// above the target is within the tolerance (the episode's success).
bool targetTerms(const TruthTerrain& T, const TargetSurface& tg, TaskTerms& task) {
  const double res = T.resolution();
  const int i0 = std::max(0, static_cast<int>(std::ceil((tg.x0 - T.originX()) / res)));
  const int i1 = std::min(T.nx() - 1, static_cast<int>(std::floor((tg.x1 - T.originX()) / res)));
  const int j0 = std::max(0, static_cast<int>(std::ceil((tg.y0 - T.originY()) / res)));
  const int j1 = std::min(T.ny() - 1, static_cast<int>(std::floor((tg.y1 - T.originY()) / res)));
  double above = 0, below = 0, cut = 0;
  long count = 0;
  for (int j = j0; j <= j1; ++j)
    for (int i = i0; i <= i1; ++i) {
      const double h = T.height(i, j);
      const double h0 = T.initialHeight(i, j);
      const double target = std::isnan(tg.depth_m) ? tg.height_m : h0 - tg.depth_m;
      above += std::max(0.0, h - target);
      below += std::max(0.0, target - h);
      cut += h0 - h;
      ++count;
    }
  if (count == 0) return false;
  task.target_above_m = above / static_cast<double>(count);
  task.target_below_m = below / static_cast<double>(count);
  task.cut_depth_mean_m = cut / static_cast<double>(count);
  return !std::isnan(tg.tolerance_m) && task.target_above_m <= tg.tolerance_m;
}


}  // namespace

const std::vector<std::string>& RewardTerms::names() {
  static const std::vector<std::string> n{"cut_bank_m3", "bucket_dug_bank_m3", "bucket_dumped_bank_m3",
                                          "distance_m", "blade_work_j", "arm_work_j"};
  return n;
}
std::vector<double> RewardTerms::toVector() const {
  return {cut_bank_m3, bucket_dug_bank_m3, bucket_dumped_bank_m3, distance_m, blade_work_j, arm_work_j};
}
const std::vector<std::string>& TaskTerms::names() {
  static const std::vector<std::string> n{"target_above_m", "target_below_m", "cut_depth_mean_m"};
  return n;
}
std::vector<double> TaskTerms::toVector() const { return {target_above_m, target_below_m, cut_depth_mean_m}; }

Env::Env(const Scenario& scenario, EnvOptions options) : Env(scenario, std::move(options), nullptr) {}

Env::Env(const Scenario& scenario, EnvOptions options, std::shared_ptr<const TruthTerrain> kept)
    : base_(scenario), opt_(std::move(options)), kept_(std::move(kept)) {
  if (opt_.frame_skip < 1) throw ConfigError("env: frame_skip must be >= 1 (got " + std::to_string(opt_.frame_skip) + ")");
  if (opt_.threads < 1) throw ConfigError("env: threads must be >= 1 (got " + std::to_string(opt_.threads) + ")");
  if (!std::isnan(opt_.time_limit_s) && !(opt_.time_limit_s > 0))
    throw ConfigError("env: time_limit_s must be > 0 (got " + fmt(opt_.time_limit_s) + ")");
  const TargetSurface& tg = opt_.target;
  if (tg.enabled() && std::isnan(tg.depth_m) && std::isnan(tg.height_m))
    throw ConfigError("env: the target surface needs depth_m (below the initial surface) or height_m (map height)");
  if (!base_.yaml_text.empty()) terrain_key_ = terrainKey(base_.yaml_text);
  seed_ = base_.seed;
  configure();
}

Env::~Env() = default;
Env::Env(Env&&) noexcept = default;
Env& Env::operator=(Env&&) noexcept = default;

void Env::configure() {
  sc_ = base_;
  sc_.threads = opt_.threads;
  sc_.overlap_scans = false;  // the levers come between periods: nothing may run ahead
  sc_.duration_s = std::isnan(opt_.time_limit_s) ? base_.duration_s : opt_.time_limit_s;
  if (!opt_.clouds)
    for (MachineSpec& m : sc_.machines)
      m.sensors.erase(std::remove_if(m.sensors.begin(), m.sensors.end(), [](const SensorSpec& s) { return s.castsRays(); }),
                      m.sensors.end());
  agents_.clear();
  for (std::size_t i = 0; i < sc_.machines.size(); ++i) {
    const MachineSpec& m = sc_.machines[i];
    if (m.controller.type != ControllerSpec::Type::External) continue;
    Agent a;
    a.id = m.id;
    a.machine = i;
    a.arm = m.arm.has_value();
    a.action_names = {"left_track", "right_track", "blade_lift", "blade_tilt", "blade_angle"};
    if (a.arm) a.action_names.insert(a.action_names.end(), {"slew", "boom", "arm", "bucket"});
    auto& n = a.obs_names;
    for (const char* f : {"base", "blade"}) {
      for (const char* c : {"_x", "_y", "_z", "_qw", "_qx", "_qy", "_qz"}) n.push_back(std::string(f) + c);
      if (std::string(f) == "base")
        for (const char* c : {"_vx", "_vy", "_vz", "_wx", "_wy", "_wz"}) n.push_back(std::string(f) + c);
    }
    for (const char* c : {"cyl_lift_m", "cyl_tilt_m", "cyl_angle_m", "cyl_lift_mps", "cyl_tilt_mps", "cyl_angle_mps",
                          "track_left_mps", "track_right_mps", "engine_rpm"})
      n.push_back(c);
    for (const SensorSpec& s : m.sensors) {
      if (s.type == SensorSpec::Type::Force) {
        a.force = true;
        for (const char* c : {"_fx", "_fy", "_fz"}) n.push_back(s.id + c);
      } else if (s.type == SensorSpec::Type::Imu) {
        a.imu_frames.push_back(m.id + "/" + s.id);
        for (const char* c : {"_ax", "_ay", "_az", "_gx", "_gy", "_gz"}) n.push_back(s.id + c);
      }
    }
    if (a.arm) {
      for (const char* j : {"slew", "boom", "arm", "bucket"}) n.push_back(std::string(j) + "_rad");
      for (const char* j : {"slew", "boom", "arm", "bucket"}) n.push_back(std::string(j) + "_radps");
      for (const char* j : {"slew", "boom", "arm", "bucket"}) n.push_back(std::string(j) + "_nm");
      n.push_back("bucket_load_kg");
    }
    agents_.push_back(std::move(a));
  }
  if (agents_.empty())
    throw ConfigError((base_.source_path.empty() ? base_.name : base_.source_path) +
                      ": no machine has controller: {type: external}; the environment drives only those");
}

const Simulator& Env::simulator() const {
  if (!sim_) throw std::logic_error("env: call reset() before using the simulator");
  return *sim_;
}

StepResult Env::reset(std::optional<std::uint64_t> seed, const std::string& overrides_yaml) {
  bool rebuilt = false;
  if (!overrides_yaml.empty()) {
    if (base_.yaml_text.empty())
      throw ConfigError("env: scenario overrides need a scenario read from YAML (this one has no text)");
    YAML::Node over;
    try {
      over = YAML::Load(overrides_yaml);
    } catch (const YAML::Exception& e) {
      throw ConfigError(std::string("overrides: not YAML: ") + e.what());
    }
    if (!over.IsMap()) throw ConfigError("overrides: expected a mapping of scenario keys (got: " + overrides_yaml + ")");
    const std::string text = dump(mergeYaml(YAML::Load(base_.yaml_text), over, ""));
    const std::filesystem::path src(base_.source_path);
    Scenario sc = parseScenario(text, (base_.source_path.empty() ? base_.name : base_.source_path) + " (with overrides)",
                                src.has_parent_path() ? src.parent_path().string() : ".");
    sc.source_path = base_.source_path;
    const std::string key = terrainKey(text);
    if (key != terrain_key_) {
      kept_.reset();
      terrain_key_ = key;
    }
    // Agents may change (a machine made external): configure() on a copy first, so a bad
    // override leaves the environment as it was.
    Scenario old = std::move(base_);
    base_ = std::move(sc);
    try {
      configure();
    } catch (...) {
      base_ = std::move(old);
      configure();
      throw;
    }
  }
  if (!kept_) {
    kept_ = std::make_shared<const TruthTerrain>(buildTerrain(base_.terrain));
    rebuilt = true;
  }
  if (seed) seed_ = *seed;
  else if (seeded_) seed_ = nextSeed(seed_);
  seeded_ = true;
  sc_.seed = seed_;
  sim_.reset();  // free the old world before the copy
  sim_ = std::make_unique<Simulator>(sc_, TruthTerrain(*kept_));
  done_ = false;
  steps_ = 0;
  StepResult r = advance(true);
  r.info.rebuilt_terrain = rebuilt;
  done_ = r.terminated || r.truncated;
  return r;
}

void Env::applyLevers(const double* a) {
  std::size_t off = 0;
  for (const Agent& ag : agents_) {
    const MachineSpec& m = sc_.machines[ag.machine];
    CtlCommand c;
    c.v_left = a[off] * m.max_speed_mps;
    c.v_right = a[off + 1] * m.max_speed_mps;
    for (int k = 0; k < 3; ++k) c.joint_rate[k] = a[off + 2 + k] * m.joint_max_rate[k];
    ArmCommand arm;
    if (ag.arm)
      for (int k = 0; k < 4; ++k) arm.lever[k] = a[off + 5 + k];
    sim_->setLevers(ag.machine, c, arm);
    off += ag.action_names.size();
  }
}

StepResult Env::step(const std::vector<std::vector<double>>& actions) {
  if (actions.size() != agents_.size())
    throw std::invalid_argument("env: " + std::to_string(actions.size()) + " actions for " + std::to_string(agents_.size()) +
                                " agents");
  std::vector<double> flat;
  for (std::size_t a = 0; a < agents_.size(); ++a) {
    if (actions[a].size() != agents_[a].action_names.size())
      throw std::invalid_argument("env: agent " + agents_[a].id + " takes " + std::to_string(agents_[a].action_names.size()) +
                                  " levers, got " + std::to_string(actions[a].size()));
    flat.insert(flat.end(), actions[a].begin(), actions[a].end());
  }
  return step(flat.data(), flat.size());
}

StepResult Env::step(const double* actions, std::size_t n) {
  if (!sim_) throw std::logic_error("env: call reset() before step()");
  if (done_) throw std::logic_error("env: the episode has ended (terminated or truncated): call reset()");
  std::size_t width = 0;
  for (const Agent& a : agents_) width += a.action_names.size();
  if (n != width) throw std::invalid_argument("env: expected " + std::to_string(width) + " lever values, got " + std::to_string(n));
  std::size_t off = 0;
  for (const Agent& a : agents_) {
    for (std::size_t k = 0; k < a.action_names.size(); ++k) {
      const double v = actions[off + k];
      if (!(v >= -1.0 && v <= 1.0))
        throw std::invalid_argument("env: agent " + a.id + " lever " + std::to_string(k) + " (" + a.action_names[k] +
                                    ") = " + fmt(v) + ": levers lie in [-1, 1]");
    }
    off += a.action_names.size();
  }
  applyLevers(actions);
  ++steps_;
  StepResult r = advance(false);
  done_ = r.terminated || r.truncated;
  return r;
}

StepResult Env::advance(bool zero_levers) {
  if (zero_levers) {
    const std::vector<double> zeros([this] {
      std::size_t w = 0;
      for (const Agent& a : agents_) w += a.action_names.size();
      return w;
    }(), 0.0);
    applyLevers(zeros.data());
  }
  StepResult r;
  r.observation.resize(agents_.size());
  r.rewards.resize(agents_.size());
  std::vector<MachineTruth> before;
  for (const Agent& a : agents_) before.push_back(sim_->machineTruth(a.machine));
  std::vector<Eigen::Isometry3d> prev_base, prev_blade;
  for (const MachineTruth& t : before) {
    prev_base.push_back(t.T_map_base);
    prev_blade.push_back(t.T_map_blade);
  }
  const double period = 1.0 / sc_.observation_hz;
  const int periods = zero_levers ? 1 : opt_.frame_skip;
  bool ended = false;
  for (int p = 0; p < periods && !ended; ++p) {
    events_.clear();
    if (!sim_->next(events_)) {
      ended = true;
      break;
    }
    for (Event& e : events_) {
      if (auto* ob = std::get_if<terramap::Observation>(&e)) {
        for (std::size_t a = 0; a < agents_.size(); ++a)
          if (agents_[a].id == ob->machine_id) r.observation[a].raw = std::move(*ob);
      } else if (auto* js = std::get_if<JointState>(&e)) {
        for (std::size_t a = 0; a < agents_.size(); ++a)
          if (agents_[a].id == js->machine_id) r.observation[a].joints = std::move(*js);
      } else if (auto* imu = std::get_if<ImuSample>(&e)) {
        for (std::size_t a = 0; a < agents_.size(); ++a)
          for (const std::string& f : agents_[a].imu_frames)
            if (f == imu->frame) r.observation[a].imu.push_back(*imu);
      } else if (auto* pc = std::get_if<PointCloud>(&e)) {
        for (std::size_t a = 0; a < agents_.size(); ++a) {
          const std::string& id = agents_[a].id;
          if (pc->frame.size() > id.size() && pc->frame.compare(0, id.size(), id) == 0 && pc->frame[id.size()] == '/')
            r.observation[a].clouds.push_back(std::move(*pc));
        }
      }
    }
    // Per-period terms from the truth at the period's end.
    for (std::size_t a = 0; a < agents_.size(); ++a) {
      const MachineTruth& t = sim_->machineTruth(agents_[a].machine);
      RewardTerms& w = r.rewards[a];
      w.distance_m += (t.T_map_base.translation() - prev_base[a].translation()).norm();
      w.blade_work_j += -t.force_map_N.dot(t.T_map_blade.translation() - prev_blade[a].translation());
      if (t.has_arm)
        for (int k = 0; k < 4; ++k) w.arm_work_j += std::abs(t.arm_torque_nm[k] * t.arm_qd[k]) * period;
      prev_base[a] = t.T_map_base;
      prev_blade[a] = t.T_map_blade;
    }
  }
  for (std::size_t a = 0; a < agents_.size(); ++a) {
    const Agent& ag = agents_[a];
    const MachineTruth& t = sim_->machineTruth(ag.machine);
    RewardTerms& w = r.rewards[a];
    w.cut_bank_m3 = t.cut_bank_m3 - before[a].cut_bank_m3;
    w.bucket_dug_bank_m3 = t.bucket_dug_bank_m3 - before[a].bucket_dug_bank_m3;
    w.bucket_dumped_bank_m3 = t.bucket_dumped_bank_m3 - before[a].bucket_dumped_bank_m3;
    AgentObservation& o = r.observation[a];
    o.id = ag.id;
    observationVector(o, ag.force, ag.imu_frames, ag.arm, ag.obs_names.size());
    if (opt_.truth) o.truth = t;
  }
  if (opt_.target.enabled()) r.terminated = targetTerms(sim_->truth(), opt_.target, r.task);
  r.truncated = ended || sim_->time() >= sc_.duration_s - 1e-9;
  r.info.t = sim_->time();
  r.info.episode_step = steps_;
  r.info.seed = seed_;
  return r;
}

}  // namespace terramap::sim
