// The simulator loop: controllers, machine dynamics, truth force, deformation, sensors.
#include <terramap/core/error.hpp>
#include <terramap/sim/excavator.hpp>
#include <terramap/sim/imu.hpp>
#include <terramap/sim/machine_contact.hpp>
#include <terramap/sim/simulator.hpp>
#include <terramap/sim/survey.hpp>
#include <terramap/sim/track_soil.hpp>

#include <tbb/task_group.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <exception>
#include <limits>
#include <mutex>
#include <thread>
#include <tuple>

namespace terramap::sim {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::uint64_t streamSeed(std::uint64_t seed, std::uint64_t a, std::uint64_t b) {
  return mixBits(seed ^ mixBits(a * 0x100000001b3ULL + b));
}

Eigen::Matrix<double, 6, 1> bodyTwist(const Eigen::Isometry3d& prev, const Eigen::Isometry3d& now, double dt) {
  Eigen::Matrix<double, 6, 1> tw = Eigen::Matrix<double, 6, 1>::Zero();
  if (dt <= 0) return tw;
  const Eigen::Vector3d v_map = (now.translation() - prev.translation()) / dt;
  tw.head<3>() = now.linear().transpose() * v_map;
  const Eigen::AngleAxisd aa(prev.linear().transpose() * now.linear());
  tw.tail<3>() = aa.axis() * aa.angle() / dt;
  return tw;
}

/// A force sensor's reading of F (base frame, N): Gaussian noise of absolute plus relative sigma.
Eigen::Vector3d noisyForce(const Eigen::Vector3d& F, const SensorSpec& fs, std::mt19937_64& rng) {
  const double sigma = fs.force_noise_abs_n + fs.force_noise_rel * F.norm();
  std::normal_distribution<double> N(0.0, 1.0);
  return F + Eigen::Vector3d(N(rng), N(rng), N(rng)) * sigma;
}

}  // namespace

struct Simulator::Machine {
  std::size_t index = 0;
  CompactTrackLoader ctl;
  CtlController controller;
  CtlCommand last_cmd;
  std::mt19937_64 noise_rng;
  std::normal_distribution<double> normal{0.0, 1.0};
  Eigen::Vector3d ou = Eigen::Vector3d::Zero();  // unit OU state per axis
  double edge_vn = 0, edge_vz = 0, edge_acc = 0;
  MachineTruth truth;
  Eigen::Isometry3d prev_base, prev_blade;          ///< truth at the previous period end
  /// The localisation: fed the true base pose at every physics step (producer side, in
  /// simulated-time order, so its draws do not depend on threads or the overlap).
  PoseEstimator estimator;
  struct Lidar {
    std::size_t sensor_index;
    LidarModel model;
    long next_scan = 0;
  };
  std::vector<Lidar> lidars;
  struct Imu {
    std::size_t sensor_index;
    ImuModel model;
    long stride;  ///< physics steps per sample
  };
  std::vector<Imu> imus;
  int force_sensor = -1;
  std::mt19937_64 force_rng;
  // Excavators: the manipulator, its controller and the soil in its bucket.
  std::unique_ptr<ExcavatorArm> arm;
  std::unique_ptr<DigDumpController> digger;
  BucketLoad bucket;
  double bucket_capacity_m3 = 0;
  double lip_vn = 0, lip_vz = 0, lip_acc = 0;
  std::mt19937_64 encoder_rng;
  // External controller: the levers the caller set last (Simulator::setLevers).
  bool external = false;
  CtlCommand external_drive;
  ArmCommand external_arm;
  long arm_steps = 0;  ///< replay: physics steps taken (time = steps * dt, no accumulated rounding)
  int arm_row = -1;    ///< replay: the log row last in force

  /// The replayed levers of physics step arm_steps (zero-order hold of the log's arm columns;
  /// rad/s in si units become levers of the joints' max rates; none before or after the log).
  ArmCommand replayArm(double dt) {
    ArmCommand c;
    const CommandLog& log = *ctl.spec().controller.replay;
    arm_row = log.rowAt(static_cast<double>(arm_steps++) * dt, arm_row);
    if (arm_row < 0 || log.arm.empty()) return c;
    const std::array<double, 4>& a = log.arm[static_cast<std::size_t>(arm_row)];
    for (int k = 0; k < 4; ++k)
      c.lever[k] = log.units == CommandLog::Units::Lever ? a[k] : a[k] / ctl.spec().arm->joints[k].max_rate_rps;
    return c;
  }

  Machine(std::size_t idx, const MachineSpec& spec, const TruthTerrain& terrain, std::uint64_t seed, double physics_hz)
      : index(idx), ctl(spec, terrain), controller(spec.controller, spec, streamSeed(seed, idx, 1)),
        noise_rng(streamSeed(seed, idx, 2)), estimator(spec.localisation, streamSeed(seed, idx, 3)),
        force_rng(streamSeed(seed, idx, 4)), encoder_rng(streamSeed(seed, idx, 5)) {
    truth.id = spec.id;
    external = spec.controller.type == ControllerSpec::Type::External;
    if (spec.arm) {
      arm = std::make_unique<ExcavatorArm>(*spec.arm);
      if (spec.controller.type == ControllerSpec::Type::DigDump)
        digger = std::make_unique<DigDumpController>(spec.controller.dig_dump);
      bucket_capacity_m3 = spec.arm->bucket_capacity_m3 > 0 ? spec.arm->bucket_capacity_m3 : arm->mesh().volume();
      truth.has_arm = true;
      truth.arm_q = arm->q();
      truth.T_map_bucket = ctl.T_map_base() * arm->T_base_bucket();
    }
    for (std::size_t s = 0; s < spec.sensors.size(); ++s) {
      const SensorSpec& ss = spec.sensors[s];
      if (ss.castsRays()) lidars.push_back({s, LidarModel(ss), 0});
      else if (ss.type == SensorSpec::Type::Force) force_sensor = static_cast<int>(s);
      else if (ss.type == SensorSpec::Type::Imu)
        imus.push_back({s, ImuModel(ss, spec.id + "/" + ss.id, streamSeed(seed, idx, 100 + s)),
                        std::max(1L, std::lround(physics_hz / ss.rate_hz))});
    }
    prev_base = ctl.T_map_base();
    prev_blade = ctl.T_map_blade();
    truth.T_map_base = prev_base;
    truth.T_map_blade = prev_blade;
    truth.cylinder_length_m = ctl.cylinderLengths();
    estimator.addTruth(0.0, prev_base);
    ImuSample none;
    for (Imu& u : imus) u.model.addLinkPose(0.0, linkPose(u.model.spec()), none);
  }

  /// The true pose of the link a sensor is mounted on.
  Eigen::Isometry3d linkPose(const SensorSpec& s) const {
    if (s.link == SensorSpec::Link::Base) return ctl.T_map_base();
    if (s.link == SensorSpec::Link::Blade) return ctl.T_map_blade();
    return mapLinks(ctl.T_map_base(), arm->q())[static_cast<int>(s.link) - static_cast<int>(SensorSpec::Link::Slew)];
  }

  /// What the machine knows of that link at physics time t, as observeMachine forms it: the
  /// localisation's base pose, then the blade through the cylinder lengths as their sensors read
  /// them, or an excavator's links through its encoders. The joint readings' white noise comes
  /// from `rng` (the scan's own stream): they take no draw from the observations' generators (the
  /// base pose estimate is taken as for a sensor on the base).
  Eigen::Isometry3d estimatedLinkPose(const SensorSpec& s, double t, std::mt19937_64& rng) {
    const Eigen::Isometry3d Te = estimator.estimate(t);
    if (s.link == SensorSpec::Link::Base) return Te;
    if (s.link == SensorSpec::Link::Blade) return Te * estimatedBaseBlade(estimator.cylinders(ctl.cylinderLengths(), rng));
    return mapLinks(Te, readEncoders(rng))[static_cast<int>(s.link) - static_cast<int>(SensorSpec::Link::Slew)];
  }

  /// The blade in the base frame as the machine knows it from cylinder lengths `cyl` (the
  /// perfect estimator keeps the joints: the inverse linkage would round them).
  Eigen::Isometry3d estimatedBaseBlade(const std::array<double, 3>& cyl) const {
    return ctl.T_base_blade(ctl.spec().localisation.perfect ? ctl.joints() : CompactTrackLoader::jointsFromCylinders(cyl));
  }

  /// The arm's joints as the encoders read them now: the truth plus white noise of
  /// ArmSpec::encoder_noise_rad drawn from `rng`.
  std::array<double, 4> readEncoders(std::mt19937_64& rng) const {
    std::normal_distribution<double> N(0.0, ctl.spec().arm->encoder_noise_rad);
    std::array<double, 4> q = arm->q();
    for (double& v : q) v += N(rng);
    return q;
  }

  /// An excavator's four link frames (slew, boom, arm, bucket) in the map for base pose T_map_base
  /// and joints q: the truth's with the true pose and joints, the JointState's with the estimates.
  std::array<Eigen::Isometry3d, 4> mapLinks(const Eigen::Isometry3d& T_map_base, const std::array<double, 4>& q) const {
    std::array<Eigen::Isometry3d, 4> links = arm->linkFrames(q);
    for (Eigen::Isometry3d& T : links) T = T_map_base * T;
    return links;
  }

  /// The encoders' and inclinometers' readings of this period into `truth` (base pose Tb).
  void measureArm(const Eigen::Isometry3d& Tb) {
    const ArmSpec& as = *ctl.spec().arm;
    std::normal_distribution<double> Ni(0.0, as.inclinometer_noise_rad);
    truth.arm_q_measured = readEncoders(encoder_rng);
    const Eigen::Isometry3d T_map_slew = Tb * arm->T_base_slew(truth.arm_q);
    const auto c = arm->chain(truth.arm_q);
    // Full-circle angles in the vertical plane through the upper structure's forward axis (an
    // inclinometer's plane of measurement), so a link pointing back reads beyond +-90 deg.
    const Eigen::Vector2d fwd = Eigen::Vector2d(T_map_slew.linear()(0, 0), T_map_slew.linear()(1, 0)).normalized();
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d d = T_map_slew.linear() * Eigen::Vector3d(c[k + 1].x() - c[k].x(), 0.0, c[k + 1].y() - c[k].y());
      truth.arm_inclination[k] = std::atan2(d.z(), d.x() * fwd.x() + d.y() * fwd.y());
      truth.arm_inclination_measured[k] = truth.arm_inclination[k] + Ni(encoder_rng);
    }
  }

  /// The JointState of period end `tp`: what the machine knows of its arm (the encoders, the
  /// estimated base pose Te), after measureArm.
  JointState jointState(double tp, const Eigen::Isometry3d& Te) const {
    JointState js;
    js.stamp = tp;
    js.machine_id = ctl.spec().id;
    js.position_rad = truth.arm_q_measured;
    js.velocity_radps = truth.arm_qd;
    js.effort_nm = truth.arm_torque_nm;
    js.T_map_link = mapLinks(Te, js.position_rad);
    js.T_map_bucket = js.T_map_link[3];
    js.bucket_load_kg = truth.bucket_load_kg;
    return js;
  }
};

/// A LiDAR scan that fell due: everything its cloud needs except the terrain.
struct Simulator::ScanRequest {
  std::size_t machine = 0, lidar = 0;
  std::size_t patches_before = 0;  ///< patches of the period to apply to the view first
  double stamp = 0;
  Eigen::Isometry3d T_true_sensor = Eigen::Isometry3d::Identity();  ///< where the rays start
  Eigen::Isometry3d T_map_sensor = Eigen::Isometry3d::Identity();   ///< the estimate the cloud carries
  std::uint64_t key = 0;
  /// Every machine's boxes at their true poses at the scan instant (empty when the scenario
  /// turns lidar_sees_machines off), captured here because with the overlap the physics has
  /// moved on by the time the scan is cast.
  std::shared_ptr<const std::vector<PlacedBox>> obstacles;
};

/// One observation period as the physics produced it.
struct Simulator::Period {
  long obs_step = 0, phys_step = 0;
  double t = 0;
  std::vector<PointCloud> clouds;           ///< serial mode: cast during the period
  std::vector<ScanRequest> scans;           ///< overlap mode: cast by the caller's side
  std::vector<TruthTerrain::Patch> patches; ///< overlap mode: terrain changes, in time order
  std::vector<Event> events;                ///< Pose, BladePose, Observation per machine, Tick
  std::vector<MachineTruth> truths;
  std::vector<CompactTrackLoader> ctls;     ///< overlap mode: the machines at the period's end
  std::uint64_t fee_invalid_slices = 0;
  double lost_m3 = 0, physics_wall_s = 0;
  bool end = false;                         ///< no period: the duration is over
  std::exception_ptr error;                 ///< the physics threw (rethrown by next())
};

/// The queue between the physics (producer tasks) and next() (consumer).
struct Simulator::Pipe {
  std::mutex mu;
  std::condition_variable cv;
  std::deque<Period> ring;
  std::size_t capacity = 12;
  bool queued = false;    ///< a producer task is enqueued or running
  bool running = false;   ///< a period is being produced (by a task or inline by next())
  bool finished = false;  ///< the end (or an error) is in the ring
  bool stopping = false;  ///< the destructor is waiting
  tbb::task_group tasks;  ///< the producer tasks (the destructor waits for them in the arena)
  // The kThreads executor (ThreadSanitizer builds): one producer thread runs the tasks that the
  // TBB backend would enqueue in the arena, one at a time, in request order.
  std::thread producer;
  int requested = 0;      ///< producer tasks asked for and not yet started (guarded by mu)
  // Patches the caller's side has applied, handed back for the physics to fill again: a fresh
  // patch zero-filled three new arrays (and faulted in their pages) before copying into them
  // (callgrind of `terramap run`: ~2 % of the demo's instructions). Guarded by pool_mu, not mu:
  // the producer takes one per scan, the consumer returns them per period.
  std::mutex pool_mu;
  std::vector<TruthTerrain::Patch> pool;
};

Simulator::Simulator(const Scenario& scenario, Executor::Backend backend)
    : Simulator(scenario, buildTerrain(scenario.terrain), backend) {}

Simulator::Simulator(const Scenario& scenario, TruthTerrain terrain, Executor::Backend backend)
    : sc_(scenario), terrain_(std::move(terrain)), soil_(scenario.default_soil, scenario.zones),
      exec_(scenario.threads, backend) {
  substeps_ = static_cast<int>(std::llround(sc_.physics_hz / sc_.observation_hz));
  if (substeps_ < 1) throw ConfigError(sc_.source_path + ": physics_hz must be >= observation_hz");
  double min_rate = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < sc_.machines.size(); ++i) {
    machines_.push_back(std::make_unique<Machine>(i, sc_.machines[i], terrain_, sc_.seed, sc_.physics_hz));
    view_truth_.push_back(machines_.back()->truth);
    for (const auto& L : machines_.back()->lidars)
      min_rate = std::min(min_rate, sc_.machines[i].sensors[L.sensor_index].rate_hz);
  }
  // Levers set by a caller between periods cannot reach physics that already ran ahead.
  const bool any_external = std::any_of(machines_.begin(), machines_.end(), [](const auto& m) { return m->external; });
  overlap_ = sc_.overlap_scans && exec_.threads() > 1 && std::isfinite(min_rate) && !any_external;
  if (overlap_) {
    view_ = std::make_unique<TruthTerrain>(terrain_);
    for (const auto& m : machines_) view_ctl_.push_back(m->ctl);
    pipe_ = std::make_unique<Pipe>();
    // Room for two scan periods: the physics can finish the next scan's periods while this
    // one is cast, and is never held up by a scan that takes longer than usual.
    const double per_scan = std::ceil(sc_.observation_hz / min_rate);
    pipe_->capacity = static_cast<std::size_t>(std::clamp(2.0 * per_scan, 4.0, 64.0));
  }
}

Simulator::~Simulator() {
  if (!pipe_) return;
  {
    std::lock_guard<std::mutex> lk(pipe_->mu);
    pipe_->stopping = true;
  }
  if (exec_.backend() == Executor::Backend::kThreads) {
    pipe_->cv.notify_all();
    if (pipe_->producer.joinable()) pipe_->producer.join();
    return;
  }
  // A producer task may still be running, or queued with no worker free to take it: wait in
  // the arena, where this thread runs a queued one itself (it sees `stopping` and returns).
  exec_.arena().execute([&] { pipe_->tasks.wait(); });
}

const CompactTrackLoader& Simulator::machine(std::size_t i) const {
  if (overlap_) return view_ctl_.at(i);
  return machines_.at(i)->ctl;
}
const MachineTruth& Simulator::machineTruth(std::size_t i) const { return view_truth_.at(i); }

void Simulator::setLevers(std::size_t i, const CtlCommand& drive, const ArmCommand& arm) {
  Machine& m = *machines_.at(i);
  if (!m.external)
    throw ConfigError("machine " + m.ctl.spec().id + " is not driven from outside (its controller is not external)");
  m.external_drive = drive;
  m.external_arm = arm;
}

void Simulator::physicsStep(double dt, bool relax) {
  // The changes every track has seen are no longer needed.
  if (prints_.size() != machines_.size()) prints_.resize(machines_.size());
  std::size_t oldest = changes_.size();
  for (const auto& mp : prints_)
    for (const TrackPrint& pr : mp)
      if (pr.valid) oldest = std::min(oldest, pr.seen);
  if (oldest > 0) {
    changes_.erase(changes_.begin(), changes_.begin() + static_cast<std::ptrdiff_t>(oldest));
    for (auto& mp : prints_)
      for (TrackPrint& pr : mp)
        if (pr.valid) pr.seen -= oldest;
  }
  for (auto& mp : machines_) {
    Machine& m = *mp;
    const MachineSpec& spec = m.ctl.spec();
    m.last_cmd = m.external ? m.external_drive : m.controller.update(dt, m.ctl);
    const Eigen::Isometry3d T_old = m.ctl.T_map_blade();
    const BladeForce bf = bladeSoilForce(terrain_, soil_, T_old, spec.blade, spec.edge_thickness_m, spec.blade_slices,
                                         m.edge_vn, m.edge_vz, m.edge_acc, overlap_ ? nullptr : &exec_);
    const Eigen::Vector3d fwd = m.ctl.T_map_base().linear().col(0);
    const Eigen::Vector3d fwd_h = Eigen::Vector3d(fwd.x(), fwd.y(), 0).normalized();
    const Eigen::Vector3d resisting = bf.fee_map + bf.inertia_map;
    CtlLoad load;
    load.resist_n = std::max(0.0, -resisting.dot(fwd_h));
    load.up_n = bf.fee_map.z() + bf.penetration_map.z();
    if (spec.track_soil) groundUnder(m, load);
    const double applied = m.ctl.step(dt, m.last_cmd, load, terrain_);
    if (spec.track_soil) pressTracks(m);
    const double mob = load.resist_n > 0 ? applied / load.resist_n : (m.ctl.speed() > 0 ? 1.0 : 0.0);
    Eigen::Vector3d F = mob * resisting + bf.penetration_map;
    // Coloured (Ornstein-Uhlenbeck) noise of the soil response, only while in contact.
    const double tau = spec.force_noise_tau_s;
    for (int a = 0; a < 3; ++a)
      m.ou[a] += -m.ou[a] * dt / tau + std::sqrt(2.0 * dt / tau) * m.normal(m.noise_rng);
    m.truth.force_quiet_map_N = F;
    m.truth.force_fee_map_N = mob * bf.fee_map;
    m.truth.force_inertia_map_N = mob * bf.inertia_map;
    m.truth.force_penetration_map_N = bf.penetration_map;
    m.truth.mobilised = mob;
    m.truth.edge_vz_mps = m.edge_vz;
    if (F.squaredNorm() > 0) F += m.ou * (spec.force_noise_abs_n + spec.force_noise_rel * F.norm());
    m.truth.force_map_N = F;
    m.truth.fee = bf.truth;
    m.truth.stalled = m.ctl.stalled();
    p_fee_invalid_ += static_cast<std::uint64_t>(bf.truth.invalid_slices);
    const Eigen::Isometry3d T_new = m.ctl.T_map_blade();
    const CutResult cut = cutAndPush(terrain_, soil_, T_old, T_new, spec.blade, spec.blade_slices);
    m.truth.cut_bank_m3 += cut.cut_bank_m3;
    markDirty(cut);
    if (relax) markDirty(relaxLoose(terrain_, soil_, T_new, spec.blade, 1.5, 0.5, 2));
    const Eigen::Vector3d dv = (T_new.translation() - T_old.translation()) / dt;
    const double vn = dv.dot(bf.push_dir);
    m.edge_acc = (vn - m.edge_vn) / dt;
    m.edge_vn = vn;
    m.edge_vz = dv.z();
    if (m.arm) armStep(m, dt);
  }
  if (sc_.machines_collide && machines_.size() > 1) {
    // Machines collide (machine_contact.hpp): once all have moved, overlaps are pushed apart.
    std::vector<ContactBody> bodies(machines_.size());
    for (std::size_t i = 0; i < machines_.size(); ++i) {
      Machine& m = *machines_[i];
      bodies[i].machine = &m.ctl;
      if (!m.arm) {
        placeShape(m.ctl.spec().shape, m.ctl.T_map_base(), m.ctl.T_map_blade(), bodies[i].boxes);
        continue;
      }
      const std::array<Eigen::Isometry3d, 4> links = m.mapLinks(m.ctl.T_map_base(), m.arm->q());
      placeShape(m.ctl.spec().shape, m.ctl.T_map_base(), m.ctl.T_map_blade(), bodies[i].boxes, &links);
    }
    resolveMachineContacts(bodies, terrain_);
  }
}

void Simulator::armStep(Machine& m, double dt) {
  const ArmSpec& as = *m.ctl.spec().arm;
  const Eigen::Isometry3d T_base = m.ctl.T_map_base();
  const ArmCommand cmd =
      m.digger     ? m.digger->update(dt, *m.arm, T_base, terrain_, m.bucket, m.bucket_capacity_m3)
      : m.external ? m.external_arm
                   : m.replayArm(dt);
  const Eigen::Isometry3d T_lip_old = m.arm->T_map_lipBlade(T_base);
  const BladeForce bf = bladeSoilForce(terrain_, soil_, T_lip_old, m.arm->floorBlade(), as.edge_thickness_m,
                                       as.bucket_slices, m.lip_vn, m.lip_vz, m.lip_acc);
  const Eigen::Vector3d F = bf.fee_map + bf.inertia_map + bf.penetration_map;
  m.arm->step(dt, cmd, T_base, F, m.bucket.mass_kg);
  // The bucket at its new pose takes what its mesh overlaps while it has room, then pours out
  // over the lip what it cannot hold at its new attitude.
  const Eigen::Isometry3d T_bucket = T_base * m.arm->T_base_bucket();
  const double hold = m.bucket_capacity_m3 * bucketHoldFraction(-T_bucket.linear().col(2));
  const CutResult dug = bucketDig(terrain_, soil_, m.arm->mesh(), T_bucket, hold, m.bucket);
  markDirty(dug);
  MachineTruth& tr = m.truth;
  tr.bucket_dug_bank_m3 += dug.cut_bank_m3 + dug.moved_loose_m3;
  tr.cut_bank_m3 += dug.cut_bank_m3;
  const Eigen::Isometry3d T_lip_new = m.arm->T_map_lipBlade(T_base);
  if (m.bucket.loose_m3 > hold) {
    const double bank_before = m.bucket.bank_m3;
    const CutResult poured = bucketPour(terrain_, soil_, T_lip_new.translation(), 0.5 * as.bucket_width_m, 1.0,
                                        std::min(m.bucket.loose_m3 - hold, as.pour_rate_m3ps * dt), m.bucket);
    markDirty(poured);
    tr.bucket_dumped_bank_m3 += bank_before - m.bucket.bank_m3;
  }
  const Eigen::Vector3d dv = (T_lip_new.translation() - T_lip_old.translation()) / dt;
  const double vn = dv.dot(bf.push_dir);
  m.lip_acc = (vn - m.lip_vn) / dt;
  m.lip_vn = vn;
  m.lip_vz = dv.z();
  tr.arm_q = m.arm->q();
  tr.arm_qd = m.arm->qd();
  tr.arm_torque_nm = m.arm->torque();
  tr.arm_lever = cmd.lever;
  tr.arm_stalled = 0;
  for (int k = 0; k < 4; ++k) tr.arm_stalled |= static_cast<std::uint8_t>(m.arm->stalled()[k] ? 1 << k : 0);
  tr.arm_phase = m.digger ? static_cast<int>(m.digger->phase()) : -1;
  tr.arm_cycle = m.digger ? m.digger->cycle() : 0;
  tr.T_map_bucket = T_bucket;
  tr.bucket_force_map_N = F;
  tr.bucket_load_kg = m.bucket.mass_kg;
  tr.bucket_load_m3 = m.bucket.loose_m3;
  tr.bucket_bank_m3 = m.bucket.bank_m3;
}

namespace {

/// Soil under a map point at the current surface (depth below the initial surface, >= 0).
const SoilProperties& surfaceSoil(const TruthTerrain& t, const SoilField& soil, double x, double y) {
  const double depth = std::max(0.0, t.initialHeightAt(x, y) - t.heightAt(x, y));
  return soil.at(x, y, std::isfinite(depth) ? depth : 0.0);
}

double trackPressure(const MachineSpec& s) { return s.mass_kg * 9.80665 / (2.0 * s.track_width_m * s.track_length_m); }

}  // namespace

void Simulator::groundUnder(const Machine& m, CtlLoad& load) const {
  trackGround(terrain_, soil_, m.ctl, load);
}

void Simulator::pressTracks(Machine& m) {
  const MachineSpec& spec = m.ctl.spec();
  if (track_.empty()) track_.reset(terrain_.nx(), terrain_.ny(), TrackNode{});
  const double c = std::cos(m.ctl.yaw()), sn = std::sin(m.ctl.yaw());
  const double hl = 0.5 * spec.track_length_m, hb = 0.5 * spec.track_width_m, res = terrain_.resolution();
  const double p = trackPressure(spec);
  for (int side = 0; side < 2; ++side) {
    const double off = (side == 0 ? 0.5 : -0.5) * spec.track_gauge_m;
    const double cx = m.ctl.x() - sn * off, cy = m.ctl.y() + c * off;  // the track's centre
    const double ex = std::abs(c) * hl + std::abs(sn) * hb, ey = std::abs(sn) * hl + std::abs(c) * hb;
    const int i0 = std::max(0, static_cast<int>(std::floor((cx - ex - terrain_.originX()) / res)));
    const int i1 = std::min(terrain_.nx() - 1, static_cast<int>(std::ceil((cx + ex - terrain_.originX()) / res)));
    const int j0 = std::max(0, static_cast<int>(std::floor((cy - ey - terrain_.originY()) / res)));
    const int j1 = std::min(terrain_.ny() - 1, static_cast<int>(std::ceil((cy + ey - terrain_.originY()) / res)));
    // The nodes actually pressed, not the track's box: driving on, only a strip at the track's
    // front sinks each step, and the box made every step's LiDAR-view patch 50 % larger.
    int ci0 = i1 + 1, ci1 = i0 - 1, cj0 = j1 + 1, cj1 = j0 - 1;
    // A node under the track whose surface is not where the tracks left it. It sinks by the
    // static sinkage in all, however often the tracks pass at this pressure, and one whose
    // surface something else moved (loose soil sliding on or off) keeps what it was pressed.
    // Only when its surface fell below the pressed layer (the blade cut it away) is the fresh
    // soil beneath pressed anew.
    auto press = [&](int i, int j, double h, const Eigen::Vector2d& q) {
      TrackNode& tn = track_.at(i, j);
      if (h < tn.left_h - tn.pressed) tn.pressed = 0.0;
      const SoilProperties& sp = surfaceSoil(terrain_, soil_, q.x(), q.y());
      const double z = bekkerSinkage(terramechanics(sp.family, sp.relative_density), p, spec.track_width_m);
      const double dz = z - tn.pressed;
      if (dz > 0) {
        terrain_.compact(i, j, dz);
        tn.pressed = z;
        ci0 = std::min(ci0, i);
        ci1 = std::max(ci1, i);
        cj0 = std::min(cj0, j);
        cj1 = std::max(cj1, j);
      }
      tn.left_h = terrain_.height(i, j);
    };
    const double* H = terrain_.heightData().data();
    // The surface changes since this track's last press that were not its own (its own left
    // every node it pressed at its new surface), near its footprint's box.
    const int source = static_cast<int>(m.index) * 2 + side;
    TrackPrint& pr = prints_[m.index][static_cast<std::size_t>(side)];
    thread_local std::vector<CellRect> others;
    others.clear();
    if (pr.valid)
      for (std::size_t k = pr.seen; k < changes_.size(); ++k) {
        const Change& ch = changes_[k];
        if (ch.source == source) continue;
        // One node of margin: a cheap guard, the skip below must never rest on a box too tight.
        const CellRect b = CellRect::inclusive(ch.box.r0 - 1, ch.box.c0 - 1, ch.box.rowEnd(), ch.box.colEnd());
        if (b.rowEnd() <= i0 || b.r0 > i1 || b.colEnd() <= j0 || b.c0 > j1) continue;
        others.push_back(b);
      }
    thread_local std::vector<std::pair<int, int>> rows;
    rows.assign(static_cast<std::size_t>(std::max(0, j1 - j0 + 1)), {1, 0});
    // The nodes [a, b] of row j, as the whole box was walked: one tile row at a time, a node whose
    // surface is where the tracks left it needs no work, so that test, on contiguous memory,
    // comes first; the others are pressed (every node of [a, b] is under the track).
    auto visit = [&](int j, const double* hrow, int a, int b) {
      for (int i = a; i <= b;) {
        const int i_start = i, run_end = std::min(b, i | (NodeTiles<TrackNode>::kTile - 1));
        const TrackNode* left = track_.find(i, j);  // null: no node of this tile row pressed yet
        for (; i <= run_end; ++i) {
          if (left && hrow[i] == left[i - i_start].left_h) continue;
          press(i, j, hrow[i], terrain_.nodePosition(i, j));
        }
      }
    };
    for (int j = j0; j <= j1; ++j) {
      const double* hrow = H + terrain_.index(0, j);
      // Only the part of the row that can lie under the track is looked at: the footprint is a
      // rectangle, so on a row it covers one interval of nodes, found analytically and widened
      // by two nodes, then narrowed by the exact test from both ends. The test is monotone in
      // i (each rounding is), so the nodes between the first and last that pass all pass: the
      // same nodes, in the same order, as testing every node of the track's box.
      const double ry = terrain_.nodePosition(i0, j).y() - cy;
      double xlo = -1e300, xhi = 1e300;  // dx = node x - cx where both constraints can hold
      auto clip = [&](double coef, double off, double lim) {  // -lim <= coef dx + off <= lim
        if (std::abs(coef) < 1e-9) return;  // dx plays no part: left to the exact test
        double a = (-lim - off) / coef, b = (lim - off) / coef;
        if (a > b) std::swap(a, b);
        xlo = std::max(xlo, a);
        xhi = std::min(xhi, b);
      };
      clip(c, sn * ry, hl);
      clip(-sn, c * ry, hb);
      if (xlo > xhi) continue;
      const double fa = std::floor((cx + xlo - terrain_.originX()) / res) - 2;
      const double fb = std::ceil((cx + xhi - terrain_.originX()) / res) + 2;
      int lo = fa <= i0 ? i0 : static_cast<int>(std::min(fa, static_cast<double>(i1 + 1)));
      int hi = fb >= i1 ? i1 : static_cast<int>(std::max(fb, static_cast<double>(i0 - 1)));
      auto under = [&](int i) {
        const Eigen::Vector2d q = terrain_.nodePosition(i, j);
        const double dx = q.x() - cx, dy = q.y() - cy;
        return std::abs(c * dx + sn * dy) <= hl && std::abs(-sn * dx + c * dy) <= hb;
      };
      while (lo <= hi && !under(lo)) ++lo;
      while (hi >= lo && !under(hi)) --hi;
      if (lo > hi) continue;
      rows[static_cast<std::size_t>(j - j0)] = {lo, hi};
      // Under the track at its last press too, and changed by no one else since: left_h equals
      // the surface, every such node would be skipped.
      int olo = 1, ohi = 0;
      if (pr.valid && j >= pr.j0 && j - pr.j0 < static_cast<int>(pr.rows.size())) {
        std::tie(olo, ohi) = pr.rows[static_cast<std::size_t>(j - pr.j0)];
        for (const CellRect& b : others)
          if (j >= b.c0 && j < b.colEnd() && b.r0 <= hi && b.rowEnd() > lo) {
            olo = 1;
            ohi = 0;
            break;
          }
      }
      if (olo > ohi || ohi < lo || olo > hi) {
        visit(j, hrow, lo, hi);
      } else {
        visit(j, hrow, lo, olo - 1);
        visit(j, hrow, ohi + 1, hi);
      }
    }
    if (ci1 >= ci0) {
      dirty_.add(CellRect::inclusive(ci0, cj0, ci1, cj1));
      noteChange(CellRect::inclusive(ci0, cj0, ci1, cj1), source);
    }
    pr.valid = true;
    pr.j0 = j0;
    pr.rows.swap(rows);
    pr.seen = changes_.size();
  }
}

void Simulator::refreshPyramid(TruthTerrain& terrain, Box& dirty) {
  if (dirty.empty()) return;
  terrain.refreshPyramid(dirty.r0, dirty.c0, dirty.rowEnd() - 1, dirty.colEnd() - 1);
  dirty = Box{};
}

bool Simulator::durationOver() const {
  return static_cast<double>(p_obs_step_) * (1.0 / sc_.observation_hz) >= sc_.duration_s - 1e-9;
}

// Called with pipe_->mu held.
void Simulator::enqueueProducer() {
  if (exec_.backend() == Executor::Backend::kTbb) {
    exec_.arena().enqueue(pipe_->tasks.defer([this] { produceTask(); }));
    return;
  }
  ++pipe_->requested;
  pipe_->cv.notify_all();
  if (pipe_->producer.joinable()) return;
  pipe_->producer = std::thread([this] {
    std::unique_lock<std::mutex> lk(pipe_->mu);
    for (;;) {
      pipe_->cv.wait(lk, [this] { return pipe_->requested > 0 || pipe_->stopping; });
      if (pipe_->stopping) {
        pipe_->queued = false;
        pipe_->cv.notify_all();
        return;
      }
      --pipe_->requested;
      lk.unlock();
      produceTask();  // takes pipe_->mu itself at its end
      lk.lock();
    }
  });
}

const TruthTerrain& Simulator::truth() const {
  // The ray-casting pyramid is brought up to date lazily (only scans and callers need it).
  auto* self = const_cast<Simulator*>(this);
  if (overlap_) {
    refreshPyramid(*self->view_, self->view_dirty_);
    return *view_;
  }
  refreshPyramid(self->terrain_, self->dirty_);
  return terrain_;
}

PointCloud Simulator::runScan(const ScanRequest& q, const TruthTerrain& terrain) {
  Machine& m = *machines_[q.machine];
  auto& L = m.lidars[q.lidar];
  const SensorSpec& ss = m.ctl.spec().sensors[L.sensor_index];
  PointCloud pc;
  pc.stamp = q.stamp;
  pc.frame = m.ctl.spec().id + "/" + ss.id;
  pc.T_map_sensor = q.T_map_sensor;
  // Cast from where the sensor really is; the cloud carries where the machine thinks it is.
  const std::size_t hits = L.model.scan(terrain, q.T_true_sensor, q.key, &exec_, pc.points, q.obstacles.get());
  stats_.rays += L.model.raysPerScan();
  stats_.rays_kept += L.model.keptLastScan();
  stats_.points += hits;
  ++stats_.scans;
  return pc;
}

void Simulator::cutPatch(Period& rec) {
  if (dirty_.empty()) return;
  TruthTerrain::Patch patch;
  {
    std::lock_guard<std::mutex> lk(pipe_->pool_mu);
    if (!pipe_->pool.empty()) {
      patch = std::move(pipe_->pool.back());
      pipe_->pool.pop_back();
    }
  }
  terrain_.capturePatch(dirty_.r0, dirty_.c0, dirty_.rowEnd() - 1, dirty_.colEnd() - 1, patch);
  rec.patches.push_back(std::move(patch));
  dirty_ = Box{};
}

void Simulator::scheduleScans(Period& rec, double t) {
  std::shared_ptr<std::vector<PlacedBox>> obstacles;  // built once, for the first scan due at t
  for (auto& mp : machines_) {
    Machine& m = *mp;
    for (std::size_t li = 0; li < m.lidars.size(); ++li) {
      auto& L = m.lidars[li];
      const SensorSpec& ss = m.ctl.spec().sensors[L.sensor_index];
      if (t + 1e-9 < static_cast<double>(L.next_scan) / ss.rate_hz) continue;
      ScanRequest q;
      q.machine = m.index;
      q.lidar = li;
      q.stamp = t;
      q.key = streamSeed(sc_.seed, 1000 + m.index * 64 + L.sensor_index, static_cast<std::uint64_t>(L.next_scan));
      q.T_true_sensor = m.linkPose(ss) * ss.T_base_sensor;
      std::mt19937_64 joint_rng(streamSeed(q.key, 1, 0));  // draws only for a sensor off the base
      q.T_map_sensor = m.estimatedLinkPose(ss, t, joint_rng) * ss.T_base_sensor;
      if (sc_.lidar_sees_machines && !obstacles) {
        obstacles = std::make_shared<std::vector<PlacedBox>>();
        for (const auto& other : machines_) {
          if (!other->arm) {
            placeShape(other->ctl.spec().shape, other->ctl.T_map_base(), other->ctl.T_map_blade(), *obstacles);
            continue;
          }
          const std::array<Eigen::Isometry3d, 4> links = other->mapLinks(other->ctl.T_map_base(), other->arm->q());
          placeShape(other->ctl.spec().shape, other->ctl.T_map_base(), other->ctl.T_map_blade(), *obstacles, &links);
        }
      }
      q.obstacles = obstacles;
      ++L.next_scan;
      if (overlap_) {
        // The scan is cast later on the view, brought to this instant by the patches before it.
        cutPatch(rec);
        q.patches_before = rec.patches.size();
        rec.scans.push_back(q);
      } else {
        const auto w1 = std::chrono::steady_clock::now();
        refreshPyramid(terrain_, dirty_);
        rec.clouds.push_back(runScan(q, terrain_));
        stats_.lidar_wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - w1).count();
      }
    }
  }
}

void Simulator::observeMachine(Machine& m, Period& rec, double tp, bool single) {
  const double period = 1.0 / sc_.observation_hz;
  const MachineSpec& spec = m.ctl.spec();
  const Eigen::Isometry3d Tb = m.ctl.T_map_base(), Tbl = m.ctl.T_map_blade();
  m.truth.T_map_base = Tb;
  m.truth.T_map_blade = Tbl;
  m.truth.twist_base = bodyTwist(m.prev_base, Tb, period);
  m.truth.twist_blade = bodyTwist(m.prev_blade, Tbl, period);
  m.truth.cylinder_length_m = m.ctl.cylinderLengths();
  m.truth.force_base_N = Tb.linear().transpose() * m.truth.force_map_N;
  // An external machine's set-points are its caller's, unknown here.
  m.truth.setpoints = m.external ? std::array<double, 5>{kNaN, kNaN, kNaN, kNaN, kNaN} : m.controller.setpoints();
  m.truth.raise_offset_m = m.controller.raiseOffset();
  if (m.arm) m.measureArm(Tb);
  // What the machine itself knows: the localisation's base pose and the blade through the
  // measured cylinder lengths and the joint kinematics. The perfect estimator keeps the joints
  // (the inverse linkage would round them).
  const Eigen::Isometry3d Te = m.estimator.estimate(tp);
  const std::array<double, 3> cyl = m.estimator.cylinders(m.truth.cylinder_length_m);
  const Eigen::Isometry3d Tble = Te * m.estimatedBaseBlade(cyl);
  Pose pose;
  pose.stamp = tp;
  pose.frame = single ? "base" : spec.id + "/base";
  pose.T_map_base = Te;
  BladePose bp;
  bp.stamp = tp;
  bp.machine_id = spec.id;
  bp.T_map_blade = Tble;
  bp.geometry = spec.blade;
  Observation ob;
  ob.stamp = tp;
  ob.machine_id = spec.id;
  ob.T_map_base = Te;
  // The machine's own velocities come from its inertial navigation (the true twist over the
  // period with its noise), not from differencing two pose estimates: their white noise, a few
  // millimetres at 60 Hz, would make a velocity noise of ~0.5 m/s (docs/sim.md, Localisation).
  ob.twist_base = m.estimator.twist(m.truth.twist_base);
  ob.T_map_blade = Tble;
  ob.twist_blade = m.estimator.twist(m.truth.twist_blade);
  ob.cylinder_length_m = cyl;
  ob.cylinder_velocity_mps = m.ctl.cylinderVelocities();
  const auto ts = m.ctl.trackSpeeds();
  ob.track_speed_mps = {ts[0], ts[1]};
  ob.engine_speed_rpm = m.ctl.engineRpm();
  ob.action = {m.last_cmd.v_left, m.last_cmd.v_right, m.last_cmd.joint_rate[0], m.last_cmd.joint_rate[1],
               m.last_cmd.joint_rate[2]};
  if (m.force_sensor >= 0) ob.force_base_N = noisyForce(m.truth.force_base_N, spec.sensors[m.force_sensor], m.force_rng);
  m.prev_base = Tb;
  m.prev_blade = Tbl;
  rec.events.emplace_back(std::move(pose));
  rec.events.emplace_back(std::move(bp));
  rec.events.emplace_back(std::move(ob));
  if (m.arm) rec.events.emplace_back(m.jointState(tp, Te));
  rec.truths.push_back(m.truth);
  if (overlap_) rec.ctls.push_back(m.ctl);
}

void Simulator::sampleImus(Period& rec, double t) {
  for (auto& mp : machines_)
    for (auto& u : mp->imus) {
      if (p_phys_step_ % u.stride != 0) continue;
      ImuSample sample;
      // The sample of the previous IMU instant (central differences need this pose); consume()
      // sorts the period's events by stamp, so it lands in time order within the period.
      if (u.model.addLinkPose(t, mp->linkPose(u.model.spec()), sample)) rec.events.emplace_back(std::move(sample));
    }
}

void Simulator::producePeriod(Period& rec) {
  const double dt = 1.0 / sc_.physics_hz;
  for (int s = 0; s < substeps_; ++s) {
    // Loose soil relaxes once per observation period (2 Jacobi sweeps: spreads 2.4 m/s at 60 Hz
    // and 2 cm, faster than the blade moves).
    const auto w0 = std::chrono::steady_clock::now();
    physicsStep(dt, s == substeps_ - 1);
    p_physics_wall_s_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
    ++p_phys_step_;
    const double t = static_cast<double>(p_phys_step_) / sc_.physics_hz;
    for (auto& mp : machines_) mp->estimator.addTruth(t, mp->ctl.T_map_base());
    sampleImus(rec, t);
    scheduleScans(rec, t);
  }
  ++p_obs_step_;
  const double tp = static_cast<double>(p_phys_step_) / sc_.physics_hz;
  if (overlap_) cutPatch(rec);
  for (auto& mp : machines_) observeMachine(*mp, rec, tp, machines_.size() == 1);
  rec.events.emplace_back(Tick{tp});
  rec.obs_step = p_obs_step_;
  rec.phys_step = p_phys_step_;
  rec.t = tp;
  rec.lost_m3 = terrain_.lostVolume();
  rec.fee_invalid_slices = p_fee_invalid_;
  rec.physics_wall_s = p_physics_wall_s_;
}

bool Simulator::produceOne() {
  {
    std::lock_guard<std::mutex> lk(pipe_->mu);
    if (pipe_->running || pipe_->finished || pipe_->stopping || pipe_->ring.size() >= pipe_->capacity) return false;
    pipe_->running = true;
  }
  // Only one producer at a time (the claim above), in period order: the physics is the same
  // whoever runs it.
  Period rec;
  try {
    if (durationOver()) rec.end = true;
    else producePeriod(rec);
  } catch (...) {
    rec.error = std::current_exception();
    rec.end = true;
  }
  std::lock_guard<std::mutex> lk(pipe_->mu);
  if (rec.end) pipe_->finished = true;
  pipe_->ring.push_back(std::move(rec));
  pipe_->running = false;
  pipe_->cv.notify_all();
  return true;
}

void Simulator::produceTask() {
  // One period per task: a task picked up by the caller's thread while it waits inside a scan
  // holds that scan up by one period of physics at most.
  const bool produced = produceOne();
  std::lock_guard<std::mutex> lk(pipe_->mu);
  if (produced && !pipe_->finished && !pipe_->stopping && pipe_->ring.size() < pipe_->capacity)
    enqueueProducer();
  else pipe_->queued = false;
  pipe_->cv.notify_all();
}

void Simulator::consume(Period& rec, std::vector<Event>& out) {
  if (overlap_) {
    // Bring the view to each scan's instant, cast, then to the period's end.
    const auto w1 = std::chrono::steady_clock::now();
    std::size_t applied = 0;
    auto applyUpTo = [&](std::size_t n) {
      for (; applied < n; ++applied) {
        const TruthTerrain::Patch& p = rec.patches[applied];
        view_->applyPatch(p);
        view_dirty_.add(CellRect::inclusive(p.i0, p.j0, p.i1, p.j1));
        ++stats_.patches;
        stats_.patch_nodes += p.nodes();
      }
    };
    for (const ScanRequest& q : rec.scans) {
      applyUpTo(q.patches_before);
      refreshPyramid(*view_, view_dirty_);
      rec.clouds.push_back(runScan(q, *view_));
    }
    applyUpTo(rec.patches.size());
    {
      std::lock_guard<std::mutex> lk(pipe_->pool_mu);
      for (TruthTerrain::Patch& p : rec.patches) pipe_->pool.push_back(std::move(p));
    }
    rec.patches.clear();
    view_ctl_ = std::move(rec.ctls);
    stats_.lidar_wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - w1).count();
  }
  t_ = rec.t;
  obs_step_ = rec.obs_step;
  phys_step_ = rec.phys_step;
  view_truth_ = std::move(rec.truths);
  stats_.fee_invalid_slices = rec.fee_invalid_slices;
  stats_.lost_m3 = rec.lost_m3;
  stats_.physics_wall_s = rec.physics_wall_s;
  std::vector<Event> ev;
  ev.reserve(rec.clouds.size() + rec.events.size());
  for (auto& c : rec.clouds) ev.emplace_back(std::move(c));
  for (auto& e : rec.events) ev.push_back(std::move(e));
  std::stable_sort(ev.begin(), ev.end(), [](const Event& a, const Event& b) { return stampOf(a) < stampOf(b); });
  for (auto& e : ev) out.push_back(std::move(e));
}

bool Simulator::next(std::vector<Event>& out) {
  if (done_) return false;
  if (!overlap_) {
    if (durationOver()) {
      done_ = true;
      return false;
    }
    Period rec;
    producePeriod(rec);
    consume(rec, out);
    appendSurvey(out);
    return true;
  }
  Period rec;
  {
    std::unique_lock<std::mutex> lk(pipe_->mu);
    while (pipe_->ring.empty()) {
      if (!pipe_->running && !pipe_->finished) {
        // Nobody is producing (no task yet, or the executor's worker is busy elsewhere, e.g. in
        // another arena): produce this period here rather than wait for one.
        lk.unlock();
        const auto w0 = std::chrono::steady_clock::now();
        produceOne();
        stats_.wait_wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
        lk.lock();
        continue;
      }
      const auto w0 = std::chrono::steady_clock::now();
      pipe_->cv.wait(lk);
      stats_.wait_wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
    }
    rec = std::move(pipe_->ring.front());
    pipe_->ring.pop_front();
    if (!pipe_->queued && !pipe_->finished && !pipe_->stopping) {
      pipe_->queued = true;
      enqueueProducer();
    }
  }
  if (rec.error) {
    done_ = true;
    std::rethrow_exception(rec.error);
  }
  if (rec.end) {
    done_ = true;
    return false;
  }
  consume(rec, out);
  appendSurvey(out);
  return true;
}

void Simulator::appendSurvey(std::vector<Event>& out) {
  if (survey_sent_) return;
  survey_sent_ = true;
  if (!sc_.survey.enabled() || out.empty()) return;
  // The initial surface never changes, so reading it while the physics runs ahead is safe.
  for (PointCloud& pc : surveyClouds(sc_, terrain_, stampOf(out.back()))) {
    stats_.survey_points += pc.points.size();
    out.emplace_back(std::move(pc));
  }
}

}  // namespace terramap::sim
