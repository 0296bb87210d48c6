#pragma once
/// \file
/// The excavator's manipulator (TERA's 4-DoF arm: slew, boom, arm, bucket) and its bucket, the
/// dig-and-dump controller that drives it. The undercarriage and dozer blade (TERA's "plow")
/// are a CompactTrackLoader; ExcavatorArm rides on its base frame. docs/sim.md "Excavators".
///
/// Joint response: TERA Eq. 1, ω(t) = ω_ss (1 + sin(η t + φ) e^{-β t}) for a step of the
/// steady-state rate ω_ss = lever · max_rate from rest, generalised by superposition: every
/// change Δ of ω_ss starts a transient Δ sin(η t' + φ) e^{-β t'} (t' since that change), so any
/// piecewise-constant lever sequence is followed exactly (the state (e, ė) of the summed
/// transients is advanced in closed form: no dependence on the physics step).
///
/// Joint torques: the static effort each actuator supplies (N·m about its axis, positive toward
/// positive joint angles) to hold the links beyond it against gravity, the soil in the bucket
/// and the soil's force on the bucket's lip. A joint whose effort would exceed its
/// max_torque_nm while moving against that load stalls (hydraulic relief): it stops for the
/// step and restarts from rest.
///
/// The bucket is a closed mesh: the prism of a convex profile extruded over its width (bucket
/// frame: origin at the bucket pivot, x toward the lip, y across, z toward the bucket's back;
/// the opening faces -z). Soil the mesh overlaps is taken into the bucket while it has room;
/// how much it holds depends on how its opening faces (a bucket opening downwards holds
/// nothing), and what it cannot hold pours out over the lip at a limited rate (so a dump
/// builds a pile). Every move conserves the soil's mass: terrain + lost + compacted + in the
/// buckets is constant (tested). Deterministic; not thread-safe.
#include <terramap/sim/blade_physics.hpp>
#include <terramap/sim/ctl.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/truth_terrain.hpp>

#include <Eigen/Geometry>
#include <array>
#include <vector>

namespace terramap::sim {

/// Joint indices of ArmSpec::joints and every per-joint array.
enum ArmJoint { kSlew = 0, kBoom = 1, kArm = 2, kBucket = 3 };

/// The operator's four levers, each in [-1, 1] (TERA's normalised interface): slew, boom, arm,
/// bucket; the steady-state joint rate is lever · max_rate.
struct ArmCommand {
  std::array<double, 4> lever{};
};

/// Soil in a bucket: bank-equivalent volume (what it occupied in the ground, m^3), its loose
/// volume in the bucket (m^3) and mass (kg).
struct BucketLoad {
  double bank_m3 = 0, loose_m3 = 0, mass_kg = 0;
};

/// The bucket mesh: a convex profile (counter-clockwise in the bucket frame's (x, z)) extruded
/// over [-width/2, width/2] in y.
struct BucketMesh {
  std::vector<Eigen::Vector2d> profile;
  double width_m = 0.6;
  int lip = 0;  ///< index of the cutting-edge vertex (the one farthest along x)

  /// The mesh's volume (m^3): the profile's area times the width.
  double volume() const;
  /// Centroid of the profile in the bucket frame (y = 0).
  Eigen::Vector3d centroid() const;
  /// Where the map's vertical line through (x, y) runs inside the mesh at pose T_map_bucket:
  /// [z_lo, z_hi] (map heights); false when it misses the mesh.
  bool verticalSpan(const Eigen::Isometry3d& T_map_bucket, double x, double y, double& z_lo, double& z_hi) const;
  /// The bucket's side walls at one pose, seen from above, for the share of a node's cell
  /// between them (sideWalls()).
  struct SideWalls {
    Eigen::Vector2d centre = Eigen::Vector2d::Zero(), normal = Eigen::Vector2d::UnitY();  ///< unit, horizontal
    double half = 0, extent = 1;  ///< half the width between the walls; a cell's extent along `normal`
    bool flat = true;             ///< walls lying flat: no side in the projection (every share 1)
    /// Share (0..1) of the cell around (x, y) between the walls (linear across its extent).
    /// `to_wall` (if given): the horizontal shift that brings a point outside the walls onto the
    /// nearer one (zero inside), where its cell's covered part takes its span.
    double coverage(double x, double y, Eigen::Vector2d* to_wall = nullptr) const;
  };
  /// The side walls at T_map_bucket for cells of side `res`: a node counts its whole cell, so
  /// without the share a node on a side wall is taken whole or not at all.
  SideWalls sideWalls(const Eigen::Isometry3d& T_map_bucket, double res) const;
};

/// The mesh of an arm spec (its profile, or the default one from bucket_m and bucket_depth_m).
/// \throws ConfigError if a given profile is not convex or has fewer than three vertices.
BucketMesh bucketMesh(const ArmSpec& spec);

class ExcavatorArm {
 public:
  explicit ExcavatorArm(const ArmSpec& spec);

  /// Advances the joints by dt under the levers; the efforts are those of the given load
  /// (soil force on the lip, map frame, N; mass in the bucket, kg) at the current pose, and
  /// decide the stalls. T_map_base is the base pose the arm rides on.
  void step(double dt, const ArmCommand& cmd, const Eigen::Isometry3d& T_map_base, const Eigen::Vector3d& lip_force_map,
            double load_kg);

  const ArmSpec& spec() const { return spec_; }
  const BucketMesh& mesh() const { return mesh_; }
  std::array<double, 4> q() const { return q_; }
  /// Joint rates over the last step (rad/s): the mean, so q advanced by qd * dt.
  std::array<double, 4> qd() const { return qd_; }
  /// Actuator efforts of the last step's load (N·m).
  std::array<double, 4> torque() const { return tau_; }
  /// Which joints the relief stopped in the last step.
  std::array<bool, 4> stalled() const { return stalled_; }

  /// The slew frame in the base frame for joints q.
  Eigen::Isometry3d T_base_slew(const std::array<double, 4>& q) const;
  /// The bucket frame (at the bucket pivot) in the base frame for joints q.
  Eigen::Isometry3d T_base_bucket(const std::array<double, 4>& q) const;
  Eigen::Isometry3d T_base_bucket() const { return T_base_bucket(q_); }
  /// The four link frames in the base frame for joints q: slew (T_base_slew), boom (at its pivot,
  /// x along the boom line, y the slew frame's y), arm (at its pivot, x along the arm line) and
  /// bucket (T_base_bucket). What the shape boxes, the IMUs' links and JointState use.
  std::array<Eigen::Isometry3d, 4> linkFrames(const std::array<double, 4>& q) const;
  /// The lip (centre of the cutting edge) in the base frame.
  Eigen::Vector3d lipInBase(const std::array<double, 4>& q) const;
  /// Pivots of boom, arm and bucket and the lip in the slew frame's (x, z) plane.
  std::array<Eigen::Vector2d, 4> chain(const std::array<double, 4>& q) const;
  /// Boom, arm and bucket angles that put the lip at (x, z) of the slew frame with the
  /// pivot→lip line at `bucket_abs` (rad above the horizontal); an unreachable point is moved
  /// onto the reachable ring. Slew is left as given in `q`; nothing is clamped to the limits.
  std::array<double, 4> inverse(std::array<double, 4> q, double x, double z, double bucket_abs) const;
  /// The efforts (N·m) at joints q for the load (see step()).
  std::array<double, 4> efforts(const std::array<double, 4>& q, const Eigen::Isometry3d& T_map_base,
                                const Eigen::Vector3d& lip_force_map, double load_kg) const;
  /// The lip's soil-engaging frame, as a blade (core/events.hpp's blade frame: x = normal of
  /// the bucket floor into the bucket, z along the floor from the lip into the bucket), and
  /// the floor as a blade (bucket width x floor length): what bladeSoilForce evaluates.
  Eigen::Isometry3d T_map_lipBlade(const Eigen::Isometry3d& T_map_base) const;
  BladeGeometry floorBlade() const { return floor_; }

 private:
  ArmSpec spec_;
  BucketMesh mesh_;
  BladeGeometry floor_;
  Eigen::Isometry3d T_bucket_lipBlade_ = Eigen::Isometry3d::Identity();
  std::array<double, 4> q_{}, qd_{}, tau_{};
  std::array<double, 4> ss_{}, e_{}, ed_{};  ///< steady-state rate and summed transient (e, de/dt)
  std::array<bool, 4> stalled_{};
};

/// Fraction of its capacity a bucket can hold with its opening facing `open_dir` (unit, map):
/// 1 when it faces up by 0.2 (z) or more, 0 when it faces down by 0.5 or more, linear between.
double bucketHoldFraction(const Eigen::Vector3d& open_dir);

/// Takes the soil the mesh overlaps at T_map_bucket into `load`, node by node in raster order,
/// until its loose volume reaches `room_loose_m3` (what is left in the ground stays). Returns
/// the changed node box and the bank volume taken (cut_bank_m3 = undisturbed, moved_loose_m3 =
/// loose, bank-equivalent).
CutResult bucketDig(TruthTerrain& terrain, const SoilField& soil, const BucketMesh& mesh,
                    const Eigen::Isometry3d& T_map_bucket, double room_loose_m3, BucketLoad& load);

/// Pours `loose_m3` (<= load.loose_m3) of the load onto the terrain around map point `at`
/// (over a disc of `radius_m`) and lets it settle to its angle of repose within `settle_m`;
/// soil that would land outside the grid is lost (counted). Returns the changed box.
CutResult bucketPour(TruthTerrain& terrain, const SoilField& soil, const Eigen::Vector3d& at, double radius_m,
                     double settle_m, double loose_m3, BucketLoad& load);

/// The dig-and-dump cycle (DigDumpSpec): the lip follows a path in the slew plane through
/// inverse kinematics, each joint led by a proportional lever on its angle error. The surface
/// it digs at is read from the truth terrain when each cycle starts (the operator's eye).
class DigDumpController {
 public:
  enum class Phase { SwingToDig, Penetrate, Drag, Curl, Lift, SwingToDump, Dump, Done };
  explicit DigDumpController(const DigDumpSpec& spec);
  ArmCommand update(double dt, const ExcavatorArm& arm, const Eigen::Isometry3d& T_map_base,
                    const TruthTerrain& terrain, const BucketLoad& load, double capacity_m3);
  Phase phase() const { return phase_; }
  int cycle() const { return cycle_; }
  static const char* phaseName(Phase p);

 private:
  /// Lever for joint k toward angle target (rad), proportional with saturation.
  double lever(const ExcavatorArm& arm, int k, double target) const;
  void startCycle(const ExcavatorArm& arm, const Eigen::Isometry3d& T_map_base, const TruthTerrain& terrain);
  void enter(Phase p) { phase_ = p; phase_t_ = 0; }
  DigDumpSpec spec_;
  Phase phase_ = Phase::SwingToDig;
  double phase_t_ = 0;
  int cycle_ = 0;
  bool started_ = false;
  // The cycle's plan in the slew frame: dig radius and azimuths, the dig surface and bottom.
  double r_dig_ = 0, r_end_ = 0, r_dump_ = 0, yaw_dig_ = 0, yaw_dump_ = 0, z_surface_ = 0, z_bottom_ = 0;
  double lip_r_ = 0, lip_z_ = 0;  ///< the lip's moving target (slew-frame x, z)
  std::array<double, 2> curl_hold_{};  ///< boom and arm held while the bucket curls
};

}  // namespace terramap::sim
