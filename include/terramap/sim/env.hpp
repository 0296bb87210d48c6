#pragma once
/// \file
/// The simulator as an environment for closed-loop control: the conventions of Gymnasium
/// (reset(seed) -> observation; step(action) -> observation, reward terms, terminated,
/// truncated, info) without depending on it. Python: `terramap.sim.Env`, docs/sim.md
/// ("Driving the simulator from your code").
///
/// Agents: the machines whose scenario controller is `{type: external}`, in scenario order; the
/// others keep their scripted controllers. Actions are the levers the machine takes, each in
/// [-1, 1] (no clipping: a value outside, NaN or a wrong count throws): a loader's left and right
/// track speed (times MachineSpec::max_speed_mps), blade lift, tilt and angle rates (times
/// joint_max_rate); an excavator adds its slew, boom, arm and bucket levers (times each joint's
/// max_rate_rps). A lever is held over the whole step (EnvOptions::frame_skip observation periods).
///
/// Observations: what the machine itself knows, one vector of doubles per agent whose layout
/// observationNames() gives (poses and twists from the localisation model, cylinder lengths and
/// velocities, track speeds, engine speed, the force sensor, each IMU's last sample, an
/// excavator's encoders, joint rates, efforts and bucket load); map frame in metres, body frames
/// in m/s and rad/s, quaternions (w, x, y, z). With EnvOptions::clouds, the step's LiDAR and
/// depth-camera clouds; with EnvOptions::truth, the simulator's MachineTruth (for reward shaping,
/// not a sensor).
///
/// Reward terms are measured quantities, never a hard-coded reward: per agent the bank volume
/// cut, the bucket's dug and dumped volumes, the distance driven and the mechanical work on the
/// soil and by the arm's actuators over the step; per environment, with a target surface, how
/// far the terrain over the target region still lies above or below it.
///
/// Reset keeps the initial terrain of the last build and copies it instead of sampling the
/// terrain again; everything else (soil field, machines, sensors, random streams) is built afresh
/// from the scenario and the seed, so an episode after reset(s) is bit-identical to one of a
/// new Env reset with s. Scenario overrides that change `terrain:` build it again.
///
/// Threading: an Env is not thread-safe; different Envs may step on different threads at once
/// (VectorEnv). Results do not depend on EnvOptions::threads.
#include <terramap/sim/simulator.hpp>

#include <tbb/partitioner.h>

#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace terramap::sim {

/// Where the terrain should end up, for the environment's task terms: a rectangle of the map
/// (x0..x1, y0..y1, m) whose target is `depth_m` below the initial surface, or with depth_m NaN
/// the map height `height_m`.
struct TargetSurface {
  double x0 = 0, y0 = 0, x1 = 0, y1 = 0;
  double depth_m = std::numeric_limits<double>::quiet_NaN();
  double height_m = std::numeric_limits<double>::quiet_NaN();
  /// terminated once the mean excess above the target over the region is at most this (m);
  /// NaN: never (the episode then ends by its time limit only).
  double tolerance_m = std::numeric_limits<double>::quiet_NaN();
  bool enabled() const { return x1 > x0 && y1 > y0; }
};

struct EnvOptions {
  int frame_skip = 1;  ///< observation periods per step (>= 1); the control period is frame_skip / observation_hz
  /// Episode length, s: a step that reaches it is truncated. NaN: the scenario's duration_s.
  double time_limit_s = std::numeric_limits<double>::quiet_NaN();
  /// Cast the LiDARs and depth cameras and return their clouds. false drops them from the
  /// scenario: no ray is cast (physics only); the other random streams are unchanged.
  bool clouds = false;
  bool truth = false;  ///< fill AgentObservation::truth
  TargetSurface target;
  /// The Simulator's executor threads (LiDAR casting, blade slices); 1 inside a VectorEnv.
  int threads = 1;
};

/// One agent's observation at the end of a step.
struct AgentObservation {
  std::string id;
  std::vector<double> vector;  ///< layout: Env::observationNames(agent)
  terramap::Observation raw;   ///< the period's Observation event (estimated poses, sensors)
  std::optional<JointState> joints;  ///< excavators
  std::vector<ImuSample> imu;        ///< every IMU sample of the step, time order
  std::vector<PointCloud> clouds;    ///< EnvOptions::clouds: the scans completed during the step
  std::optional<MachineTruth> truth; ///< EnvOptions::truth
};

/// Measured quantities of one agent over one step (reward terms).
struct RewardTerms {
  double cut_bank_m3 = 0;            ///< bank volume the blade and bucket cut
  double bucket_dug_bank_m3 = 0;     ///< excavators: bank-equivalent volume into the bucket
  double bucket_dumped_bank_m3 = 0;  ///< excavators: bank-equivalent volume poured out
  double distance_m = 0;             ///< path length of the base (truth, per observation period)
  /// Work the blade did against the soil's force (-F_soil . displacement of the cutting edge,
  /// per observation period, J; negative when the soil pushed the blade along).
  double blade_work_j = 0;
  double arm_work_j = 0;             ///< excavators: sum over joints of |torque * rate| * dt, J
  static const std::vector<std::string>& names();  ///< in the order of toVector()
  std::vector<double> toVector() const;
};

/// The environment's task quantities at the end of a step (NaN without a target).
struct TaskTerms {
  double target_above_m = std::numeric_limits<double>::quiet_NaN();  ///< mean max(0, h - target) over the region
  double target_below_m = std::numeric_limits<double>::quiet_NaN();  ///< mean max(0, target - h)
  double cut_depth_mean_m = std::numeric_limits<double>::quiet_NaN(); ///< mean (initial - h) over the region
  static const std::vector<std::string>& names();
  std::vector<double> toVector() const;
};

struct StepInfo {
  double t = 0;             ///< simulated time at the end of the step, s
  long episode_step = 0;    ///< steps since reset
  std::uint64_t seed = 0;   ///< the episode's seed
  bool rebuilt_terrain = false;  ///< reset only: the overrides changed the terrain, it was built again
};

struct StepResult {
  std::vector<AgentObservation> observation;  ///< one per agent
  std::vector<RewardTerms> rewards;           ///< one per agent
  TaskTerms task;
  bool terminated = false;  ///< the target was reached (TargetSurface::tolerance_m)
  bool truncated = false;   ///< the time limit was reached
  StepInfo info;
};

class Env {
 public:
  /// \throws ConfigError when no machine has an external controller or an option is out of range.
  Env(const Scenario& scenario, EnvOptions options = {});
  ~Env();
  Env(Env&&) noexcept;
  Env& operator=(Env&&) noexcept;

  /// Starts an episode: the world restored from the kept initial state, then one observation
  /// period with every lever at 0 (the sensors have produced nothing before it). Without a seed
  /// the next one of the sequence (a hash of the last; the scenario's seed at first).
  /// `overrides_yaml`: a YAML mapping merged into the scenario's YAML for this and later episodes
  /// (mappings merge key by key, `machines` entries by their `id`, anything else replaces).
  /// \throws ConfigError for overrides that make the scenario invalid (message of loadScenario).
  StepResult reset(std::optional<std::uint64_t> seed = std::nullopt, const std::string& overrides_yaml = "");
  /// One step with the levers `actions[agent]` (actionNames order). \throws std::invalid_argument
  /// naming the agent, lever and value for a wrong count, NaN or a value outside [-1, 1];
  /// std::logic_error before reset() or after the episode ended.
  StepResult step(const std::vector<std::vector<double>>& actions);
  /// The same from one flat array of sum(actionSize) values, agents in order.
  StepResult step(const double* actions, std::size_t n);

  std::size_t agentCount() const { return agents_.size(); }
  const std::string& agentId(std::size_t a) const { return agents_.at(a).id; }
  const std::vector<std::string>& actionNames(std::size_t a) const { return agents_.at(a).action_names; }
  const std::vector<std::string>& observationNames(std::size_t a) const { return agents_.at(a).obs_names; }
  std::size_t actionSize(std::size_t a) const { return actionNames(a).size(); }
  std::size_t observationSize(std::size_t a) const { return observationNames(a).size(); }
  const EnvOptions& options() const { return opt_; }
  /// The scenario of the current episode (after overrides and the options' changes).
  const Scenario& scenario() const { return sc_; }
  /// The running simulator (truth terrain, machines). \throws std::logic_error before reset().
  const Simulator& simulator() const;
  bool needsReset() const { return !sim_ || done_; }

 private:
  friend class VectorEnv;
  struct Agent {
    std::string id;
    std::size_t machine = 0;
    bool arm = false;
    std::vector<std::string> action_names, obs_names;
    std::vector<std::string> imu_frames;  ///< "<machine>/<sensor>" per IMU, vector order
    bool force = false;
  };
  Env(const Scenario& scenario, EnvOptions options, std::shared_ptr<const TruthTerrain> kept);
  void configure();  ///< sc_ from base_ and options; the agents
  StepResult advance(bool zero_levers);
  void applyLevers(const double* a);
  Scenario base_;       ///< as given, with the overrides merged
  Scenario sc_;         ///< what the simulator runs
  EnvOptions opt_;
  std::string terrain_key_;  ///< the terrain YAML the kept terrain was built from
  std::shared_ptr<const TruthTerrain> kept_;
  std::unique_ptr<Simulator> sim_;
  std::vector<Agent> agents_;
  std::uint64_t seed_ = 0;
  bool seeded_ = false, done_ = false;
  long steps_ = 0;
  std::vector<Event> events_;  ///< scratch
};

/// Options of a VectorEnv: the environments' options and the worker threads.
struct VectorEnvOptions {
  EnvOptions env;
  int threads = 1;  ///< TBB arena slots stepping the environments (results do not depend on it)
};

/// N environments of one scenario stepped together, one TBB task per environment. Environment k
/// is seeded seed + k at reset(seed) and resets itself when its episode ends (terminated or
/// truncated) with the next seed of its own sequence, returning the new episode's first
/// observation (the ended one's last is in finalObservation(k)): environment k of any batch
/// size and thread count gives the bits of an Env driven alone with the same seeds.
/// Batched arrays are row-major [N][...] per agent. Not thread-safe.
class VectorEnv {
 public:
  VectorEnv(const Scenario& scenario, int n, VectorEnvOptions options = {});
  ~VectorEnv();
  int size() const { return static_cast<int>(envs_.size()); }
  const Env& env(int k) const { return *envs_.at(static_cast<std::size_t>(k)); }
  std::size_t agentCount() const { return envs_.front()->agentCount(); }
  std::size_t actionWidth() const { return action_width_; }  ///< sum of the agents' action sizes

  /// Resets every environment (k with seed + k; without a seed each continues its sequence).
  void reset(std::optional<std::uint64_t> seed = std::nullopt);
  /// Steps every environment with actions[k * actionWidth() ...]. \throws std::invalid_argument
  /// (naming the environment) for a bad action, before any environment moved; std::logic_error
  /// before reset(). An exception of the physics in one environment is rethrown once the step's
  /// tasks have finished or been skipped, so some environments may have stepped and others not:
  /// call reset() before stepping again (not enforced).
  void step(const double* actions, std::size_t n);

  /// Agent a's observations, [N][observationSize(a)].
  const std::vector<double>& observations(std::size_t a) const { return obs_.at(a); }
  /// Agent a's reward terms, [N][RewardTerms::names().size()].
  const std::vector<double>& rewards(std::size_t a) const { return rew_.at(a); }
  const std::vector<double>& task() const { return task_; }  ///< [N][TaskTerms::names().size()]
  const std::vector<std::uint8_t>& terminated() const { return terminated_; }
  const std::vector<std::uint8_t>& truncated() const { return truncated_; }
  const std::vector<double>& times() const { return t_; }  ///< simulated time of each env, s
  /// The full result of env k's last step (clouds, IMU samples, truth), before any autoreset.
  const StepResult& finalObservation(int k) const { return final_.at(static_cast<std::size_t>(k)); }
  const StepResult& last(int k) const { return last_.at(static_cast<std::size_t>(k)); }

 private:
  void gather(int k, const StepResult& r);
  template <class F>
  void forEachEnv(F&& f);
  std::vector<std::unique_ptr<Env>> envs_;
  std::unique_ptr<Executor> exec_;
  std::unique_ptr<tbb::affinity_partitioner> affinity_;
  std::size_t action_width_ = 0;
  std::vector<std::vector<double>> obs_, rew_;
  std::vector<double> task_, t_;
  std::vector<std::uint8_t> terminated_, truncated_;
  std::vector<StepResult> last_, final_;
};

}  // namespace terramap::sim
