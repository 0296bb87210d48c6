// The simulator loop: controllers, machine dynamics, truth force, deformation, sensors.
#include <terramap/core/error.hpp>
#include <terramap/sim/simulator.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>

namespace terramap::sim {
namespace {

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
  Eigen::Isometry3d prev_base, prev_blade;
  struct Lidar {
    std::size_t sensor_index;
    LidarModel model;
    long next_scan = 0;
  };
  std::vector<Lidar> lidars;
  int pose_sensor = -1, force_sensor = -1;
  std::mt19937_64 pose_rng, force_rng;
  std::vector<PointCloud> pending;  // clouds captured during the current period

  Machine(std::size_t idx, const MachineSpec& spec, const TruthTerrain& terrain, std::uint64_t seed)
      : index(idx), ctl(spec, terrain), controller(spec.controller, spec, streamSeed(seed, idx, 1)),
        noise_rng(streamSeed(seed, idx, 2)), pose_rng(streamSeed(seed, idx, 3)), force_rng(streamSeed(seed, idx, 4)) {
    truth.id = spec.id;
    for (std::size_t s = 0; s < spec.sensors.size(); ++s) {
      const SensorSpec& ss = spec.sensors[s];
      if (ss.type == SensorSpec::Type::Lidar) lidars.push_back({s, LidarModel(ss), 0});
      else if (ss.type == SensorSpec::Type::Pose) pose_sensor = static_cast<int>(s);
      else force_sensor = static_cast<int>(s);
    }
    prev_base = ctl.T_map_base();
    prev_blade = ctl.T_map_blade();
    truth.T_map_base = prev_base;
    truth.T_map_blade = prev_blade;
  }
};

Simulator::Simulator(const Scenario& scenario)
    : sc_(scenario), terrain_(buildTerrain(scenario.terrain)), soil_(scenario.default_soil, scenario.zones),
      exec_(scenario.threads) {
  substeps_ = static_cast<int>(std::llround(sc_.physics_hz / sc_.observation_hz));
  if (substeps_ < 1) throw ConfigError(sc_.source_path + ": physics_hz must be >= observation_hz");
  for (std::size_t i = 0; i < sc_.machines.size(); ++i)
    machines_.push_back(std::make_unique<Machine>(i, sc_.machines[i], terrain_, sc_.seed));
}

Simulator::~Simulator() = default;

const CompactTrackLoader& Simulator::machine(std::size_t i) const { return machines_.at(i)->ctl; }
const MachineTruth& Simulator::machineTruth(std::size_t i) const { return machines_.at(i)->truth; }

void Simulator::physicsStep(double dt, bool relax) {
  for (auto& mp : machines_) {
    Machine& m = *mp;
    const MachineSpec& spec = m.ctl.spec();
    m.last_cmd = m.controller.update(dt, m.ctl);
    const Eigen::Isometry3d T_old = m.ctl.T_map_blade();
    const BladeForce bf = bladeSoilForce(terrain_, soil_, T_old, spec.blade, spec.edge_thickness_m, spec.blade_slices,
                                         m.edge_vn, m.edge_vz, m.edge_acc, &exec_);
    const Eigen::Vector3d fwd = m.ctl.T_map_base().linear().col(0);
    const Eigen::Vector3d fwd_h = Eigen::Vector3d(fwd.x(), fwd.y(), 0).normalized();
    const Eigen::Vector3d resisting = bf.fee_map + bf.inertia_map;
    CtlLoad load;
    load.resist_n = std::max(0.0, -resisting.dot(fwd_h));
    load.up_n = bf.fee_map.z() + bf.penetration_map.z();
    const double applied = m.ctl.step(dt, m.last_cmd, load, terrain_);
    const double mob = load.resist_n > 0 ? applied / load.resist_n : (m.ctl.speed() > 0 ? 1.0 : 0.0);
    Eigen::Vector3d F = mob * resisting + bf.penetration_map;
    // Coloured (Ornstein-Uhlenbeck) noise of the soil response, only while in contact.
    const double tau = spec.force_noise_tau_s;
    for (int a = 0; a < 3; ++a)
      m.ou[a] += -m.ou[a] * dt / tau + std::sqrt(2.0 * dt / tau) * m.normal(m.noise_rng);
    if (F.squaredNorm() > 0) F += m.ou * (spec.force_noise_abs_n + spec.force_noise_rel * F.norm());
    m.truth.force_map_N = F;
    m.truth.fee = bf.truth;
    m.truth.stalled = m.ctl.stalled();
    stats_.fee_invalid_slices += static_cast<std::uint64_t>(bf.truth.invalid_slices);
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
  }
}

void Simulator::markDirty(const CutResult& r) {
  if (r.i1 < r.i0) return;
  if (dirty_i1_ < dirty_i0_) {
    dirty_i0_ = r.i0; dirty_j0_ = r.j0; dirty_i1_ = r.i1; dirty_j1_ = r.j1;
    return;
  }
  dirty_i0_ = std::min(dirty_i0_, r.i0); dirty_j0_ = std::min(dirty_j0_, r.j0);
  dirty_i1_ = std::max(dirty_i1_, r.i1); dirty_j1_ = std::max(dirty_j1_, r.j1);
}

void Simulator::refreshDirty() {
  if (dirty_i1_ < dirty_i0_) return;
  terrain_.refreshPyramid(dirty_i0_, dirty_j0_, dirty_i1_, dirty_j1_);
  dirty_i0_ = 0; dirty_j0_ = 0; dirty_i1_ = -1; dirty_j1_ = -1;
}

bool Simulator::next(std::vector<Event>& out) {
  const double period = 1.0 / sc_.observation_hz;
  if (obs_step_ * period >= sc_.duration_s - 1e-9) return false;
  const double dt = 1.0 / sc_.physics_hz;
  std::vector<Event> ev;
  for (int s = 0; s < substeps_; ++s) {
    // Loose soil relaxes once per observation period (2 Jacobi sweeps: spreads 2.4 m/s at 60 Hz
    // and 2 cm, faster than the blade moves).
    const auto w0 = std::chrono::steady_clock::now();
    physicsStep(dt, s == substeps_ - 1);
    stats_.physics_wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
    ++phys_step_;
    const double t = static_cast<double>(phys_step_) / sc_.physics_hz;
    // LiDAR scans that are due.
    for (auto& mp : machines_) {
      Machine& m = *mp;
      for (auto& L : m.lidars) {
        const SensorSpec& ss = m.ctl.spec().sensors[L.sensor_index];
        if (t + 1e-9 < static_cast<double>(L.next_scan) / ss.rate_hz) continue;
        const auto w1 = std::chrono::steady_clock::now();
        refreshDirty();
        PointCloud pc;
        pc.stamp = t;
        pc.frame = m.ctl.spec().id + "/" + ss.id;
        pc.T_map_sensor = m.ctl.T_map_base() * ss.T_base_sensor;
        const std::uint64_t key = streamSeed(sc_.seed, 1000 + m.index * 64 + L.sensor_index, static_cast<std::uint64_t>(L.next_scan));
        const std::size_t hits = L.model.scan(terrain_, pc.T_map_sensor, key, &exec_, pc.points);
        stats_.rays += L.model.raysPerScan();
        stats_.points += hits;
        ++stats_.scans;
        ++L.next_scan;
        ev.emplace_back(std::move(pc));
        stats_.lidar_wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - w1).count();
      }
    }
  }
  ++obs_step_;
  t_ = static_cast<double>(phys_step_) / sc_.physics_hz;
  const bool single = machines_.size() == 1;
  for (auto& mp : machines_) {
    Machine& m = *mp;
    const MachineSpec& spec = m.ctl.spec();
    const Eigen::Isometry3d Tb = m.ctl.T_map_base(), Tbl = m.ctl.T_map_blade();
    m.truth.T_map_base = Tb;
    m.truth.T_map_blade = Tbl;
    m.truth.force_base_N = Tb.linear().transpose() * m.truth.force_map_N;
    m.truth.setpoints = m.controller.setpoints();
    m.truth.raise_offset_m = m.controller.raiseOffset();
    // Pose (noisy if a pose sensor exists).
    Pose pose;
    pose.stamp = t_;
    pose.frame = single ? "base" : spec.id + "/base";
    pose.T_map_base = Tb;
    if (m.pose_sensor >= 0) {
      const SensorSpec& ps = spec.sensors[m.pose_sensor];
      std::normal_distribution<double> N(0.0, 1.0);
      const Eigen::Vector3d dp(N(m.pose_rng) * ps.position_noise_m, N(m.pose_rng) * ps.position_noise_m,
                               N(m.pose_rng) * ps.position_noise_m);
      const double droll = N(m.pose_rng) * ps.tilt_noise_rad, dpitch = N(m.pose_rng) * ps.tilt_noise_rad,
                   dyaw = N(m.pose_rng) * ps.yaw_noise_rad;
      pose.T_map_base.translation() += dp;
      pose.T_map_base.linear() = (Eigen::AngleAxisd(dyaw, Eigen::Vector3d::UnitZ()) *
                                  Eigen::AngleAxisd(dpitch, Eigen::Vector3d::UnitY()) *
                                  Eigen::AngleAxisd(droll, Eigen::Vector3d::UnitX()))
                                     .toRotationMatrix() *
                                 Tb.linear();
    }
    BladePose bp;
    bp.stamp = t_;
    bp.machine_id = spec.id;
    bp.T_map_blade = Tbl;
    bp.geometry = spec.blade;
    Observation ob;
    ob.stamp = t_;
    ob.machine_id = spec.id;
    ob.T_map_base = Tb;
    ob.twist_base = bodyTwist(m.prev_base, Tb, period);
    ob.T_map_blade = Tbl;
    ob.twist_blade = bodyTwist(m.prev_blade, Tbl, period);
    ob.cylinder_length_m = m.ctl.cylinderLengths();
    ob.cylinder_velocity_mps = m.ctl.cylinderVelocities();
    const auto ts = m.ctl.trackSpeeds();
    ob.track_speed_mps = {ts[0], ts[1]};
    ob.engine_speed_rpm = m.ctl.engineRpm();
    ob.action = {m.last_cmd.v_left, m.last_cmd.v_right, m.last_cmd.joint_rate[0], m.last_cmd.joint_rate[1],
                 m.last_cmd.joint_rate[2]};
    if (m.force_sensor >= 0) {
      const SensorSpec& fs = spec.sensors[m.force_sensor];
      const Eigen::Vector3d& F = m.truth.force_base_N;
      const double sigma = fs.force_noise_abs_n + fs.force_noise_rel * F.norm();
      std::normal_distribution<double> N(0.0, 1.0);
      ob.force_base_N = F + Eigen::Vector3d(N(m.force_rng), N(m.force_rng), N(m.force_rng)) * sigma;
    }
    m.prev_base = Tb;
    m.prev_blade = Tbl;
    ev.emplace_back(std::move(pose));
    ev.emplace_back(std::move(bp));
    ev.emplace_back(std::move(ob));
  }
  stats_.lost_m3 = terrain_.lostVolume();
  ev.emplace_back(Tick{t_});
  std::stable_sort(ev.begin(), ev.end(), [](const Event& a, const Event& b) { return stampOf(a) < stampOf(b); });
  for (auto& e : ev) out.push_back(std::move(e));
  return true;
}

}  // namespace terramap::sim
