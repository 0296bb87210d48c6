#pragma once
/// \file
/// The simulator: terramap's stand-in for Vortex Studio / TERA. A pull API: each `next()`
/// advances one observation period (1/observation_hz, 60 Hz by default) of physics sub-steps
/// and appends that period's events in time order:
///   PointCloud  (when a LiDAR or depth-camera scan completes; frame "<machine>/<sensor>",
///                stamp = scan time; rays cast from the true sensor pose, T_map_sensor = the
///                estimated base pose at the stamp * T_base_sensor)
///   ImuSample   (per IMU at its rate; frame "<machine>/<sensor>", stamp = the instant it
///                measures, which may lie up to one sample period before the period's start:
///                sim/imu.hpp)
///   Pose        (per machine: the estimated base pose; frame "base" with one machine,
///                "<machine>/base" with several)
///   BladePose   (per machine: estimated base * blade from the measured cylinder lengths)
///   Observation (per machine: the same estimated poses and their twists, measured cylinder
///                lengths, true cylinder velocities and track speeds, commanded actions,
///                force sensor reading or NaN without a force sensor)
///   JointState  (per excavator: the encoders' joint angles, joint rates and efforts, the bucket
///                pose from the estimated base and the measured joints, the soil in the bucket)
///   Tick        (end of the period)
/// The estimates come from one PoseEstimator per machine (MachineSpec::localisation), fed the
/// true base pose at every physics step; `localisation: perfect` makes every event the truth.
/// MachineTruth is always the truth.
/// Everything random comes from per-stream seeded generators or counter hashes, never thread
/// timing: the same scenario and seed give a bit-identical event stream for any thread count.
/// Not thread-safe (one Simulator per thread); LiDAR ray casting runs on its own Executor.
///
/// With `threads` >= 2 and a LiDAR, the physics runs ahead of the caller (up to two scan
/// periods, as tasks on the Simulator's executor) while the caller's thread casts the scans
/// on a second copy of the terrain that is brought, by patches of the changed node boxes, to
/// the exact instant of each scan: the two stages overlap instead of alternating, and every
/// output (events, truth(), machineTruth(), machine()) is still that of the period next()
/// returned, bit-identical to the serial order. The physics keeps running on the executor's
/// worker between next() calls, until it is two scan periods ahead. It costs a second copy of
/// the truth terrain; `overlap_scans: false` in the scenario turns it off.
#include <terramap/core/events.hpp>
#include <terramap/core/parallel.hpp>
#include <terramap/sim/blade_physics.hpp>
#include <terramap/sim/ctl.hpp>
#include <terramap/sim/excavator.hpp>
#include <terramap/sim/lidar.hpp>
#include <terramap/sim/localisation.hpp>
#include <terramap/sim/node_tiles.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/truth_terrain.hpp>
#include <terramap/sim/world.hpp>

#include <array>
#include <memory>
#include <random>
#include <vector>

namespace terramap::sim {

/// Per-machine truth at the end of the latest observation period (what the episode logs).
struct MachineTruth {
  std::string id;
  Eigen::Isometry3d T_map_base = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_map_blade = Eigen::Isometry3d::Identity();
  /// Body-frame [v, omega] over the last observation period (m/s, rad/s).
  Eigen::Matrix<double, 6, 1> twist_base = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> twist_blade = Eigen::Matrix<double, 6, 1>::Zero();
  std::array<double, 3> cylinder_length_m{};  ///< true lift, tilt, angle cylinder lengths, m
  /// Soil-on-blade force of the truth physics (mobilised FEE + inertia + penetration +
  /// coloured noise), map frame and base frame, N.
  Eigen::Vector3d force_map_N = Eigen::Vector3d::Zero();
  Eigen::Vector3d force_base_N = Eigen::Vector3d::Zero();
  /// force_map_N without its coloured noise (MachineSpec::force_noise_*), map frame, N: what a
  /// model of the soil's force could at best predict. The noise is unpredictable from anything
  /// the machine observes, so an estimator's error against the measured force cannot fall below
  /// that of this force (docs/soil_estimator.md, "The force noise floor").
  Eigen::Vector3d force_quiet_map_N = Eigen::Vector3d::Zero();
  /// force_quiet_map_N in its parts (map frame, N, soil on blade; they sum to it): the FEE
  /// summed over the blade's slices (pushed piles included) and the soil's inertia, both as far
  /// as the vehicle mobilised them, and the edge's penetration resistance. For diagnosis only
  /// (where an estimator's physics misses the force: docs/soil_estimator.md).
  Eigen::Vector3d force_fee_map_N = Eigen::Vector3d::Zero();
  Eigen::Vector3d force_inertia_map_N = Eigen::Vector3d::Zero();
  Eigen::Vector3d force_penetration_map_N = Eigen::Vector3d::Zero();
  double mobilised = 0;                 ///< share of fee + inertia the vehicle mobilised, [0, 1]
  double edge_vz_mps = 0;               ///< cutting edge's vertical speed the force saw (< 0 descends)
  FeeTruth fee;                         ///< truth FEE geometry and soil of the cut
  bool stalled = false;
  std::array<double, 5> setpoints{};    ///< speed, depth, roll, blade yaw, heading
  double raise_offset_m = 0;
  double cut_bank_m3 = 0;               ///< cumulative bank volume cut by this machine
  // Excavators (MachineSpec::arm) only, zero otherwise: the manipulator (sim/excavator.hpp).
  bool has_arm = false;
  std::array<double, 4> arm_q{}, arm_qd{}, arm_torque_nm{};  ///< slew, boom, arm, bucket: rad, rad/s, N·m
  std::array<double, 4> arm_q_measured{};  ///< the encoders: arm_q + white noise (ArmSpec::encoder_noise_rad)
  std::array<double, 4> arm_lever{};       ///< the levers commanded, [-1, 1]
  /// Inclinometers on boom, arm and bucket: each link line's angle above the map's horizontal,
  /// full circle in the vertical plane through the upper structure's forward axis (rad; the
  /// bucket's line runs from its pivot to the lip), true and measured (+ white noise
  /// of ArmSpec::inclinometer_noise_rad): what a real machine reads with respect to gravity.
  std::array<double, 3> arm_inclination{}, arm_inclination_measured{};
  std::uint8_t arm_stalled = 0;            ///< bit k: joint k stopped by its relief in the last step
  int arm_phase = -1;                      ///< DigDumpController::Phase, -1 without one
  int arm_cycle = 0;                       ///< dig-and-dump cycles completed
  Eigen::Isometry3d T_map_bucket = Eigen::Isometry3d::Identity();  ///< bucket frame (at its pivot)
  Eigen::Vector3d bucket_force_map_N = Eigen::Vector3d::Zero();    ///< soil on the bucket's lip
  double bucket_load_kg = 0, bucket_load_m3 = 0;  ///< soil in the bucket: mass, loose volume
  double bucket_bank_m3 = 0;                      ///< the same soil's bank-equivalent volume
  double bucket_dug_bank_m3 = 0, bucket_dumped_bank_m3 = 0;  ///< cumulative, bank-equivalent
};

class Simulator {
 public:
  /// Builds the world. `backend` runs the scans' chunks and, with overlap_scans, the physics
  /// ahead of the caller (Executor::Backend; the events are the same bits either way).
  /// \throws InputError (DEM) or ConfigError (inconsistent scenario).
  explicit Simulator(const Scenario& scenario, Executor::Backend backend = Executor::kDefaultBackend);
  /// The same on `terrain`, a copy of buildTerrain(scenario.terrain) the caller kept (an
  /// environment's reset, sim/env.hpp: the terrain is not sampled again). The caller vouches that
  /// it is that scenario's terrain in its initial state; everything else is built afresh.
  Simulator(const Scenario& scenario, TruthTerrain terrain, Executor::Backend backend = Executor::kDefaultBackend);
  ~Simulator();
  Simulator(const Simulator&) = delete;
  Simulator& operator=(const Simulator&) = delete;

  /// Appends the events of the next observation period (time order); false (and nothing
  /// appended) once the duration is over. \throws whatever the physics threw (with the overlap,
  /// at the period it was computing; every later call returns false).
  bool next(std::vector<Event>& out);

  /// The levers of machine i, whose controller is External, held from the next physics step
  /// until set again: track speeds (m/s) and blade joint rates (lift m/s, tilt and angle rad/s),
  /// each clamped by the machine to its maxima, and an excavator's four arm levers in [-1, 1]
  /// (ignored for a loader). A scenario with an external machine never runs the physics ahead
  /// (overlap_scans is ignored), so the levers set between two next() calls act from the first
  /// physics step of the next period. \throws std::out_of_range for a bad i, ConfigError for a
  /// machine with another controller.
  void setLevers(std::size_t i, const CtlCommand& drive, const ArmCommand& arm = {});

  double time() const { return t_; }
  long step() const { return obs_step_; }
  const Scenario& scenario() const { return sc_; }
  /// The truth terrain now (its ray-casting pyramid is brought up to date lazily here).
  const TruthTerrain& truth() const;
  const SoilField& soil() const { return soil_; }
  std::size_t machineCount() const { return machines_.size(); }
  const CompactTrackLoader& machine(std::size_t i) const;
  const MachineTruth& machineTruth(std::size_t i) const;

  struct Stats {
    std::uint64_t rays = 0, points = 0, scans = 0, fee_invalid_slices = 0;
    /// Of `rays`, those that took the terrain hit kept from their sensor's previous scan
    /// (SensorSpec::reuse_casts: the sensor had not moved and the terrain under them had not changed).
    std::uint64_t rays_kept = 0;
    double lost_m3 = 0;
    /// Wall-clock seconds spent in the machine and soil physics, and in the LiDAR (pyramid
    /// refresh + ray casting; with the overlap also applying the physics' patches to the
    /// view), since construction. For profiling only: never part of an
    /// episode (they vary run to run).
    double physics_wall_s = 0, lidar_wall_s = 0;
    /// With the overlap: wall seconds next() spent waiting for the physics or computing a
    /// period itself (near 0 when the scans, not the physics, set the pace), and the terrain
    /// patches handed over (count, nodes).
    double wait_wall_s = 0;
    std::uint64_t patches = 0, patch_nodes = 0;
    std::uint64_t survey_points = 0;  ///< points of the scenario's survey (survey.hpp), sent once
  };
  const Stats& stats() const { return stats_; }

 private:
  struct Machine;
  struct ScanRequest;
  struct Period;
  struct Pipe;
  using Box = CellRect;
  void physicsStep(double dt, bool relax);
  void markDirty(const CutResult& r) {
    dirty_.add(r);
    noteChange(r, -1);
  }
  /// Brings `terrain`'s ray-casting pyramid up to date over `dirty` and empties it.
  static void refreshPyramid(TruthTerrain& terrain, Box& dirty);
  bool durationOver() const;  ///< the physics has produced every period of the duration
  void enqueueProducer();
  /// One observation period: physics substeps with their due scans, then every machine's events.
  void producePeriod(Period& rec);
  /// Moves the terrain changed since the last patch (dirty_) into `rec` as a patch.
  void cutPatch(Period& rec);
  /// The LiDAR scans due at physics time `t`: queued in `rec` (overlap) or cast now.
  void scheduleScans(Period& rec, double t);
  /// Feeds every IMU the pose of physics step p_phys_step_ (time t) when it falls on its rate.
  void sampleImus(Period& rec, double t);
  /// Track–soil interaction (MachineSpec::track_soil): the ground under the machine into `load`,
  /// and each track's sinkage pressed into the terrain under its footprint.
  void groundUnder(const Machine& m, CtlLoad& load) const;
  /// An excavator's manipulator for one physics step: controller, soil force on the bucket,
  /// joints, then the bucket digging the terrain and pouring what it cannot hold.
  void armStep(Machine& m, double dt);
  void pressTracks(Machine& m);
  /// Per node under the tracks: the surface they left it at (NaN: never pressed) and the sinkage
  /// pressed into it since its surface last fell below the pressed layer.
  struct TrackNode {
    double left_h = std::numeric_limits<double>::quiet_NaN();
    double pressed = 0.0;
  };
  NodeTiles<TrackNode> track_;
  // What lets pressTracks skip the nodes it would find unchanged. After a track's press, every
  // node of its footprint has left_h == its surface; until something changes that surface, the
  // node is skipped. So the next press of that track need only visit the nodes its footprint
  // gained and the rows where someone else changed the terrain since (changes_), not the whole
  // footprint (two arrays read per node: with eight environments on two cores, the largest part
  // of a step's memory traffic).
  struct TrackPrint {
    bool valid = false;                    ///< pressed at least once
    int j0 = 0;                            ///< the first row of `rows`
    std::vector<std::pair<int, int>> rows; ///< per row, the nodes [first, last] under it (first > last: none)
    std::size_t seen = 0;                  ///< changes_ entries already there after its last press
  };
  std::vector<std::array<TrackPrint, 2>> prints_;  ///< per machine, per track
  struct Change {
    CellRect box;  ///< nodes whose surface changed (CellRect: r0 = first i, c0 = first j)
    int source;    ///< the track that pressed them (machine * 2 + side), -1: anything else
  };
  std::vector<Change> changes_;  ///< since the oldest TrackPrint::seen (trimmed every physics step)
  void noteChange(const CellRect& r, int source) {
    if (!r.empty()) changes_.push_back({r, source});
  }
  /// A machine's truth and its Pose, BladePose and Observation at period end `tp`, into `rec`.
  void observeMachine(Machine& m, Period& rec, double tp, bool single);
  bool produceOne();
  void produceTask();
  void consume(Period& rec, std::vector<Event>& out);
  /// With the first period's events: the survey clouds (after the machines' first poses, so a
  /// fusion stage's self-filter is placed), stamped like the period's last event.
  void appendSurvey(std::vector<Event>& out);
  PointCloud runScan(const ScanRequest& q, const TruthTerrain& terrain);

  Scenario sc_;
  TruthTerrain terrain_;  ///< the physics' terrain (ahead of the caller's period when overlapping)
  SoilField soil_;
  Executor exec_;
  std::vector<std::unique_ptr<Machine>> machines_;
  int substeps_ = 4;
  // Producer side (the physics): its own step counters and cumulative figures.
  long p_obs_step_ = 0, p_phys_step_ = 0;
  double p_physics_wall_s_ = 0;
  std::uint64_t p_fee_invalid_ = 0;
  /// Nodes changed since the last pyramid refresh (serial mode) or the last patch (overlap).
  Box dirty_;
  // Caller side: what the last next() delivered.
  double t_ = 0;
  long obs_step_ = 0, phys_step_ = 0;
  bool done_ = false;
  bool survey_sent_ = false;
  std::vector<MachineTruth> view_truth_;
  Stats stats_;
  // Overlap mode (threads >= 2, LiDAR present, Scenario::overlap_scans): the physics runs
  // ahead as tasks on exec_ and the caller's side keeps `view_`, a copy of the terrain brought
  // to each scan's instant by patches, for the scans and for truth().
  bool overlap_ = false;
  std::unique_ptr<TruthTerrain> view_;
  Box view_dirty_;
  std::vector<CompactTrackLoader> view_ctl_;
  std::unique_ptr<Pipe> pipe_;
};

}  // namespace terramap::sim
