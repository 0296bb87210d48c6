#pragma once
/// \file
/// Compact track loader model (CAT 299-class): tracked differential drive whose pose comes
/// from track contact with the truth terrain, three blade joints (lift, tilt, angle) with
/// limits and a damped velocity response, a traction limit that makes the machine stall when
/// the soil resists more than the tracks can push, and the controllers that drive it
/// (random-walk set-points or scripted parallel passes). Deterministic; not thread-safe.
///
/// Frames: base = chassis at the centre of the track contact plane (x forward, y left, z up).
/// The blade hangs from the base: T_base_blade = Trans(mount_x, 0, lift) * Rz(angle) *
/// Rx(tilt) * Ry(-(pi/2 - rake)), so lift is the cutting-edge height above the contact plane
/// (negative = below, i.e. cutting) and an upright blade (rake 90 deg) has the blade frame
/// parallel to the base frame.
#include <terramap/core/events.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/truth_terrain.hpp>

#include <Eigen/Geometry>
#include <array>
#include <optional>
#include <random>

namespace terramap::sim {

/// What the controller asks for.
struct CtlCommand {
  double v_left = 0, v_right = 0;        ///< track speed commands, m/s
  std::array<double, 3> joint_rate{};    ///< lift (m/s), tilt (rad/s), angle (rad/s)
};

/// Load of the soil on the blade seen by the vehicle (from bladeSoilForce).
struct CtlLoad {
  double resist_n = 0;   ///< soil resistance against forward motion at full mobilisation (>= 0)
  double up_n = 0;       ///< upward soil force on the blade (N; > lift_down_force stops descent)
  /// The ground under the tracks, with MachineSpec::track_soil (else unused): Mohr–Coulomb
  /// limit of the tractive effort (N, before the slope's cos), compaction resistance of both
  /// tracks (N) and the shear deformation modulus K (m).
  double ground_cohesion_pa = 0, ground_tan_phi = 0, compaction_n = 0, shear_k_m = 0.025;
  /// Bulldozing resistance of both tracks' leading edges (N; track_soil.hpp).
  double bulldozing_n = 0;
  /// The soil under each track half's centre, with MachineSpec::track_soil: its static Bekker
  /// sinkage under the machine's mean ground pressure (m; informative: the halves sink into the
  /// ruts the terrain records) and the exponent n of its pressure–sinkage curve, in the order
  /// front-left, front-right, rear-left, rear-right (docs/sim.md "Track–soil interaction").
  std::array<double, 4> support_sinkage_m{}, support_n{1, 1, 1, 1};
};

class CompactTrackLoader {
 public:
  CompactTrackLoader(const MachineSpec& spec, const TruthTerrain& terrain);

  /// Advances by dt: joints, drive, pose from track contact. Returns the soil resistance that
  /// was actually applied (N, <= load.resist_n; less when the machine was not pushing).
  double step(double dt, const CtlCommand& cmd, const CtlLoad& load, const TruthTerrain& terrain);

  const MachineSpec& spec() const { return spec_; }
  Eigen::Isometry3d T_map_base() const { return T_map_base_; }
  Eigen::Isometry3d T_base_blade() const { return T_base_blade(q_); }
  /// The blade pose for joints q (lift m, tilt rad, angle rad), same kinematics as above.
  Eigen::Isometry3d T_base_blade(const std::array<double, 3>& q) const;
  Eigen::Isometry3d T_map_blade() const { return T_map_base_ * T_base_blade(); }
  double x() const { return x_; }
  double y() const { return y_; }
  double yaw() const { return yaw_; }
  double speed() const { return v_; }                    ///< forward ground speed, m/s
  double acceleration() const { return accel_; }
  double yawRate() const { return omega_; }
  std::array<double, 2> trackSpeeds() const { return {vt_[0], vt_[1]}; }
  std::array<double, 3> joints() const { return q_; }
  std::array<double, 3> jointRates() const { return qd_; }
  std::array<double, 3> cylinderLengths() const;         ///< linearised linkage, m
  std::array<double, 3> cylinderVelocities() const;      ///< m/s
  /// The joints (lift m, tilt rad, angle rad) whose cylinders have lengths L (m): the inverse of
  /// cylinderLengths()'s linkage, not clamped to the joint limits (a measured length may lie
  /// outside them). How the machine's own controller would read its blade.
  static std::array<double, 3> jointsFromCylinders(const std::array<double, 3>& L);
  /// d(cylinder length k)/d(joint k) (m per m for the lift, m per rad for tilt and angle).
  static double cylinderLever(int k);
  double engineRpm() const { return rpm_; }
  bool stalled() const { return stalled_; }
  /// Commanded trackspeed mean (what the drive is trying to reach).
  double driveSpeed() const { return 0.5 * (vt_[0] + vt_[1]); }
  /// The ground's vertical force on the tracks (N): the machine's weight once settled, less while
  /// a track half still sinks into its rut (falling onto it) and more while it is braked there.
  /// Its Mohr–Coulomb share W tan(phi) of the traction limit uses this force (TERA §IV-A: the
  /// excavator slows entering sand as "the reduction in the normal forces resulting in sinking").
  double groundNormalForce() const { return normal_n_; }
  /// How far each track half (front-left, front-right, rear-left, rear-right) still stands above
  /// the bottom of the rut under it (m, > 0 while it sinks; 0 once it rests there).
  std::array<double, 4> supportGap() const;
  /// A contact with another machine (machine_contact.hpp): moves the base by `d` (map x, y, m)
  /// and sets the forward speed to `v` (m/s); the pose is taken again from the terrain, the
  /// supports keeping their heights unless the ground under them is higher. A move off the
  /// terrain is refused (the machine stays and stops).
  void contactMove(const Eigen::Vector2d& d, double v, const TruthTerrain& terrain);

 private:
  /// The pose from track contact. Kinematic (each track half on the highest ground under it)
  /// without track_soil; with it each half follows the ground's shape with the tracks' ruts
  /// added back and sinks into the ruts over `dt` through the Bekker soil under it (ctl.cpp,
  /// sinkSupport; none without `load` or for dt = 0).
  void placeOnTerrain(const TruthTerrain& terrain, const CtlLoad* load = nullptr, double dt = 0);
  /// Track–soil traction (MachineSpec::track_soil): the force the tracks exert this step, the
  /// Mohr–Coulomb limit f_lim (N) mobilised by the Janosi–Hanamoto slip at the new speed, with
  /// the slope's pull `downhill_n` (N, W sin(pitch)) and the soil's shear modulus K (m).
  double soilTraction(double dt, double v_d, double f_lim, double downhill_n, double shear_k_m) const;

  MachineSpec spec_;
  double x_, y_, yaw_;
  double v_ = 0, accel_ = 0, omega_ = 0;
  std::array<double, 2> vt_{0, 0};
  std::array<double, 3> q_{0.2, 0, 0}, qd_{0, 0, 0}, qdd_{0, 0, 0};
  double rpm_;
  bool stalled_ = false;
  Eigen::Isometry3d T_map_base_ = Eigen::Isometry3d::Identity();
  // How far each track half (front-left, front-right, rear-left, rear-right) has sunk into the
  // ground and how fast it sinks (m, m/s, down positive), and how deep the ruts under it are (m).
  std::array<double, 4> sup_z_{}, sup_vz_{}, rut_z_{};
  bool sup_ready_ = false;
  double normal_n_ = 0;  ///< set by the constructor to the weight
};

/// The machine's controller: random-walk set-points (paper §3.1), scripted parallel passes, or
/// the replay of recorded commands (command_log.hpp: levers scaled by the machine's maximum
/// track speed and joint rates, or SI commands, passed through as they are).
/// Blade height and roll are controlled relative to the track contact plane (what the machine
/// itself can measure); speed tracking failure raises the blade (not in a replay: the recorded
/// operator did what the log says).
class CtlController {
 public:
  CtlController(const ControllerSpec& spec, const MachineSpec& machine, std::uint64_t seed);
  CtlCommand update(double dt, const CompactTrackLoader& m);

  /// Current set-points (for logging): speed m/s, depth m, roll rad, blade yaw rad, heading rad.
  std::array<double, 5> setpoints() const { return {speed_, depth_, roll_, blade_yaw_, heading_}; }
  double raiseOffset() const { return raise_; }
  bool finished() const { return finished_; }

 private:
  double walk(const RandomWalk& w, double x, double dt);
  /// Route lane of pass `pass` (0-based): the pass itself, or with route_loop back and forth.
  int laneOf(int pass) const;
  ControllerSpec spec_;
  double gauge_;
  double heading0_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  double speed_, depth_, roll_, blade_yaw_, heading_;
  double raise_ = 0, slow_time_ = 0;
  // Route state.
  int pass_ = 0;
  bool reversing_ = false, finished_ = false;
  std::optional<double> grade_target_;  ///< edge height held on a forward pass (route grade)
  std::array<double, 3> joint_max_rate_;
  double max_speed_;
  // Replay state: physics steps taken (time = steps * dt, no accumulated rounding) and the
  // last row found.
  long steps_ = 0;
  int replay_row_ = -1;
  CtlCommand replay(double dt);
};

}  // namespace terramap::sim
