// Compact track loader: drive, blade joints, pose from track contact; its controllers.
#include <terramap/core/error.hpp>
#include <terramap/sim/ctl.hpp>
#include <terramap/sim/track_soil.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

namespace terramap::sim {
namespace {

constexpr double kG = 9.80665;

double wrapAngle(double a) {
  a = std::fmod(a + M_PI, 2 * M_PI);
  if (a < 0) a += 2 * M_PI;
  return a - M_PI;
}

// Linearised linkage: cylinder length = base + lever * joint.
constexpr double kCylBase[3] = {0.95, 0.40, 0.45};
constexpr double kCylLever[3] = {0.60, 0.30, 0.35};

/// One track half sinking over dt into the rut its soil lets it press: `Z` (m) is how deep the
/// tracks have pressed the ground under it (the static Bekker sinkage of that soil under the mean
/// ground pressure, pressed into the terrain at once by Simulator::pressTracks), `z` and `vz` how
/// far the support has sunk so far and how fast (m, m/s, down positive). A quarter of the mass
/// mk (kg) on the soil's loading curve: having pressed the soil z deep, the soil carries
/// W_k (z / Z)^n (Bekker's p = k z^n, which is W_k at the static sinkage Z; M. G. Bekker,
/// *Introduction to Terrain-Vehicle Systems*, 1969; n of the soil, J. Y. Wong, *Theory of Ground
/// Vehicles*, terrain-value table), so a support placed on unpressed ground starts falling freely
/// and slows as the soil takes its weight. Pressing soil is plastic work the rut does not give
/// back (unloaded, sand springs back by a small fraction of its sinkage: Wong, "response to
/// repetitive loading"), so the support must not bounce: the soil's resistance to being pressed
/// at a rate is a damper of the least strength at which the support, linearised at rest
/// (stiffness n W_k / Z), does not oscillate: critical damping, 2 m_k sqrt(n g / Z). A shallower
/// rut (firmer ground ahead) lifts the support at once (the ground carries it), as does any
/// change of the terrain's shape (the caller adds z to the unpressed surface, which it follows
/// as before). Sub-steps keep the stiff dense soils (Z of a few tenths of a millimetre) stable.
/// Returns the mean vertical force of the ground over the step (N).
double sinkSupport(double& z, double& vz, double Z, double n, double mk, double dt) {
  const double Wk = mk * kG;
  if (!(Z > 1e-6) || z >= Z) {  // no rut (rigid, or no soil model): kinematic; or at its bottom
    z = std::max(0.0, std::min(z, Z));
    vz = 0;
    return Wk;
  }
  const double w = std::sqrt(n * kG / Z), c = 2.0 * mk * w;
  const int N = std::clamp(static_cast<int>(std::ceil(w * dt / 0.1)), 1, 256);
  const double hdt = dt / N;
  double F_sum = 0;
  for (int s = 0; s < N; ++s) {
    const double F = std::max(0.0, Wk * std::pow(std::max(0.0, z) / Z, n) + c * vz);
    vz += hdt * (kG - F / mk);
    z += hdt * vz;
    F_sum += F;
    if (z >= Z) {  // on the rut's bottom: the soil holds the weight there (plastic)
      z = Z;
      vz = 0;
    }
  }
  return F_sum / N;
}

}  // namespace

CompactTrackLoader::CompactTrackLoader(const MachineSpec& spec, const TruthTerrain& terrain)
    : spec_(spec), x_(spec.x_m), y_(spec.y_m), yaw_(spec.yaw_rad), rpm_(spec.engine_rated_rpm),
      normal_n_(spec.mass_kg * kG) {
  for (int k = 0; k < 3; ++k) q_[k] = std::clamp(q_[k], spec.joint_min[k], spec.joint_max[k]);
  placeOnTerrain(terrain);
}

Eigen::Isometry3d CompactTrackLoader::T_base_blade(const std::array<double, 3>& q) const {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(spec_.blade_mount_x_m, 0.0, q[0]);
  T.linear() = (Eigen::AngleAxisd(q[2], Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(q[1], Eigen::Vector3d::UnitX()) *
                Eigen::AngleAxisd(-(M_PI / 2 - spec_.rake_rad), Eigen::Vector3d::UnitY()))
                   .toRotationMatrix();
  return T;
}

std::array<double, 3> CompactTrackLoader::cylinderLengths() const {
  std::array<double, 3> l{};
  for (int k = 0; k < 3; ++k) l[k] = kCylBase[k] + kCylLever[k] * q_[k];
  return l;
}

std::array<double, 3> CompactTrackLoader::jointsFromCylinders(const std::array<double, 3>& L) {
  std::array<double, 3> q{};
  for (int k = 0; k < 3; ++k) q[k] = (L[k] - kCylBase[k]) / kCylLever[k];
  return q;
}

double CompactTrackLoader::cylinderLever(int k) { return kCylLever[k]; }

std::array<double, 3> CompactTrackLoader::cylinderVelocities() const {
  std::array<double, 3> v{};
  for (int k = 0; k < 3; ++k) v[k] = kCylLever[k] * qd_[k];
  return v;
}

std::array<double, 4> CompactTrackLoader::supportGap() const {
  std::array<double, 4> g{};
  for (int k = 0; k < 4; ++k) g[k] = std::max(0.0, rut_z_[k] - sup_z_[k]);
  return g;
}

void CompactTrackLoader::contactMove(const Eigen::Vector2d& d, double v, const TruthTerrain& terrain) {
  const double ox = x_, oy = y_;
  const Eigen::Isometry3d before = T_map_base_;
  x_ += d.x();
  y_ += d.y();
  v_ = v;
  placeOnTerrain(terrain, nullptr, 0.0);
  if (T_map_base_.translation().x() != x_ || T_map_base_.translation().y() != y_) {
    x_ = ox;
    y_ = oy;
    v_ = 0;
    T_map_base_ = before;
  }
}

void CompactTrackLoader::placeOnTerrain(const TruthTerrain& terrain, const CtlLoad* load, double dt) {
  const double c = std::cos(yaw_), s = std::sin(yaw_);
  const double L = spec_.track_length_m, B = spec_.track_gauge_m;
  // Support height of each track half: the highest terrain point under it (the track rests on it).
  // With the soil model also the highest of the surface with the ruts the tracks pressed added
  // back: the ground's shape, which the track follows as before, while it sinks into the ruts
  // over time (sinkSupport).
  const bool settle = spec_.track_soil && sup_ready_;
  double z[2][2], zu[2][2];  // [front/rear][left/right]
  bool ok = true;
  for (int fr = 0; fr < 2; ++fr) {
    for (int lr = 0; lr < 2; ++lr) {
      const double ly = lr == 0 ? 0.5 * B : -0.5 * B;
      double zmax = -1e300, umax = -1e300;
      for (int m = 0; m < 5; ++m) {
        const double lx = (fr == 0 ? 1.0 : -1.0) * (0.5 * L) * (m + 0.5) / 5.0;
        const double px = x_ + c * lx - s * ly, py = y_ + s * lx + c * ly;
        const double h = terrain.heightAt(px, py);
        if (std::isnan(h)) ok = false;
        else zmax = std::max(zmax, h);
        if (settle) umax = std::max(umax, h + terrain.pressedAt(px, py));
      }
      z[fr][lr] = zmax;
      zu[fr][lr] = settle ? std::max(umax, zmax) : zmax;
    }
  }
  if (!ok) return;  // caller reverts the move
  if (settle) {
    double N = 0;
    for (int k = 0; k < 4; ++k) {
      const double h = z[k / 2][k % 2], u = zu[k / 2][k % 2];
      rut_z_[k] = u - h;
      if (load && dt > 0) {
        N += sinkSupport(sup_z_[k], sup_vz_[k], u - h, load->support_n[k], 0.25 * spec_.mass_kg, dt);
      } else {
        // Moved without time passing (a contact): sunk as far as before, at most to the rut.
        sup_z_[k] = std::min(sup_z_[k], u - h);
      }
      z[k / 2][k % 2] = u - sup_z_[k];
    }
    if (load && dt > 0) normal_n_ = N;
  } else {
    // Kinematic (no soil model, or the first placement): on the ground, fully sunk.
    for (int k = 0; k < 4; ++k) {
      rut_z_[k] = 0;
      sup_z_[k] = 0;
      sup_vz_[k] = 0;
    }
    sup_ready_ = true;
    normal_n_ = spec_.mass_kg * kG;
  }
  const double z0 = 0.25 * (z[0][0] + z[0][1] + z[1][0] + z[1][1]);
  const double px = (0.5 * (z[0][0] + z[0][1]) - 0.5 * (z[1][0] + z[1][1])) / (0.5 * L);
  const double py = (0.5 * (z[0][0] + z[1][0]) - 0.5 * (z[0][1] + z[1][1])) / B;
  const double pitch = -std::atan(px);
  const double roll = std::atan(py * std::cos(pitch));
  T_map_base_.setIdentity();
  T_map_base_.translation() = Eigen::Vector3d(x_, y_, z0);
  T_map_base_.linear() = (Eigen::AngleAxisd(yaw_, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                          Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                             .toRotationMatrix();
}

double CompactTrackLoader::soilTraction(double dt, double v_d, double f_lim, double downhill_n, double shear_k_m) const {
  // The share rises steeply near zero slip (L / 2K per unit slip): an explicit step goes
  // unstable at low drive speeds, so the new speed v* = v + dt/m (F(v*) - downhill) is solved
  // by bisection (the left side minus the right rises in v*) and F is taken there.
  const double m = spec_.mass_kg, v_ref = std::max(std::abs(v_d), 0.05);
  auto force = [&](double v) {
    return f_lim * janosiShare(std::clamp((v_d - v) / v_ref, -1.0, 1.0), spec_.track_length_m, shear_k_m);
  };
  const double reach = dt / m * (f_lim + std::abs(downhill_n));
  double lo = v_ - reach - 1e-9, hi = v_ + reach + 1e-9;
  for (int it = 0; it < 60; ++it) {
    const double mid = 0.5 * (lo + hi);
    if (mid - v_ - dt / m * (force(mid) - downhill_n) > 0) hi = mid;
    else lo = mid;
  }
  return force(0.5 * (lo + hi));
}

double CompactTrackLoader::step(double dt, const CtlCommand& cmd, const CtlLoad& load, const TruthTerrain& terrain) {
  // Blade joints: damped velocity response (poles -beta +- i eta, TERA Eq. 1) or first order.
  for (int k = 0; k < 3; ++k) {
    double r = std::clamp(cmd.joint_rate[k], -spec_.joint_max_rate[k], spec_.joint_max_rate[k]);
    const bool blocked = (k == 0 && load.up_n > spec_.lift_down_force_n);
    if (blocked) r = std::max(r, 0.0);
    if (spec_.joint_beta > 0) {
      const double wn2 = spec_.joint_beta * spec_.joint_beta + spec_.joint_eta * spec_.joint_eta;
      qdd_[k] += dt * (wn2 * (r - qd_[k]) - 2.0 * spec_.joint_beta * qdd_[k]);
      qd_[k] += dt * qdd_[k];
    } else {
      qd_[k] += (r - qd_[k]) * std::min(1.0, dt / spec_.joint_tau_s);
    }
    if (blocked && qd_[k] < 0) {  // the soil carries the blade: the lift cannot push it deeper
      qd_[k] = 0;
      qdd_[k] = 0;
    }
    q_[k] += qd_[k] * dt;
    if (q_[k] < spec_.joint_min[k] || q_[k] > spec_.joint_max[k]) {
      q_[k] = std::clamp(q_[k], spec_.joint_min[k], spec_.joint_max[k]);
      qd_[k] = 0;
      qdd_[k] = 0;
    }
  }
  // Drive: track speeds follow their commands (hydrostatic drive lag).
  const double a = std::min(1.0, dt / std::max(spec_.drive_time_constant_s, 1e-9));
  vt_[0] += (std::clamp(cmd.v_left, -spec_.max_speed_mps, spec_.max_speed_mps) - vt_[0]) * a;
  vt_[1] += (std::clamp(cmd.v_right, -spec_.max_speed_mps, spec_.max_speed_mps) - vt_[1]) * a;
  const double v_d = 0.5 * (vt_[0] + vt_[1]);
  const double w_d = (vt_[1] - vt_[0]) / spec_.track_gauge_m;
  const Eigen::Vector3d fwd = T_map_base_.linear().col(0);
  const double uphill = std::asin(std::clamp(fwd.z(), -1.0, 1.0));
  const double W = spec_.mass_kg * kG;
  const double m = spec_.mass_kg;
  double f_lim, f_trac;
  if (spec_.track_soil) {
    // The ground's normal force, not the weight: less while the tracks still sink (falling onto
    // their ruts), and the cohesive share in proportion (a track half in the air grips nothing).
    const double carried = std::clamp(normal_n_ / W, 0.0, 1.0);
    f_lim = std::min(2.0 * spec_.track_width_m * spec_.track_length_m * load.ground_cohesion_pa * carried +
                         normal_n_ * std::cos(uphill) * load.ground_tan_phi,
                     spec_.max_drive_force_n);
    f_trac = soilTraction(dt, v_d, f_lim, W * std::sin(uphill), load.shear_k_m);
  } else {
    f_lim = std::min(spec_.traction_coefficient * W * std::cos(uphill), spec_.max_drive_force_n);
    // Tractive force saturates with slip (0.1 m/s of slip mobilises all of it).
    f_trac = f_lim * std::clamp((v_d - v_) / 0.1, -1.0, 1.0);
  }
  const double v_trial = v_ + dt / m * (f_trac - W * std::sin(uphill));
  const double roll_res = spec_.rolling_resistance * W + (spec_.track_soil ? load.compaction_n + load.bulldozing_n : 0.0);
  double v_new = 0, applied = 0;
  if (v_trial > 0) {
    const double resist = roll_res + load.resist_n;
    v_new = std::max(0.0, v_trial - dt * resist / m);
    // If the resistances stopped the machine, only what was needed to stop it was mobilised.
    applied = v_new > 0 ? load.resist_n : std::clamp(m * v_trial / dt - roll_res, 0.0, load.resist_n);
  } else if (v_trial < 0) {
    v_new = std::min(0.0, v_trial + dt * roll_res / m);
  }
  accel_ = (v_new - v_) / dt;
  v_ = v_new;
  omega_ += (w_d - omega_) * std::min(1.0, dt / std::max(spec_.yaw_time_constant_s, 1e-9));
  const double ox = x_, oy = y_, oyaw = yaw_;
  const double vh = v_ * std::cos(uphill);
  x_ += vh * std::cos(yaw_) * dt;
  y_ += vh * std::sin(yaw_) * dt;
  yaw_ = wrapAngle(yaw_ + omega_ * dt);
  const Eigen::Isometry3d before = T_map_base_;
  placeOnTerrain(terrain, &load, dt);
  if (T_map_base_.translation().x() != x_ || T_map_base_.translation().y() != y_) {
    // Left the terrain: stay where we were.
    x_ = ox;
    y_ = oy;
    yaw_ = oyaw;
    v_ = 0;
    omega_ = 0;
    T_map_base_ = before;
  }
  stalled_ = v_d > 0.1 && v_ < 0.2 * v_d && load.resist_n > 0;
  rpm_ = spec_.engine_rated_rpm - spec_.engine_droop_rpm * (f_lim > 0 ? std::abs(f_trac) / f_lim : 0.0);
  return applied;
}

// ---- controller -----------------------------------------------------------------------------

CtlController::CtlController(const ControllerSpec& spec, const MachineSpec& machine, std::uint64_t seed)
    : spec_(spec), gauge_(machine.track_gauge_m), heading0_(machine.yaw_rad), rng_(seed),
      joint_max_rate_(machine.joint_max_rate), max_speed_(machine.max_speed_mps) {
  if (spec.type == ControllerSpec::Type::Replay && (!spec.replay || spec.replay->t.empty()))
    throw ConfigError("machine " + machine.id + ": a replay controller needs its command log (" +
                      (spec.replay_path.empty() ? std::string("no file given") : spec.replay_path) +
                      "); loadScenario reads it");
  speed_ = spec.speed_mps.initial;
  depth_ = spec.depth_m.initial;
  roll_ = spec.roll_rad.initial;
  blade_yaw_ = spec.yaw_rad.initial;
  heading_ = heading0_ + spec.heading_rad.initial;
  if (spec.type == ControllerSpec::Type::Route) {
    speed_ = spec.route_speed_mps;
    depth_ = spec.route_depth_m;
    roll_ = blade_yaw_ = 0;
    heading_ = spec.route_heading_rad;
  }
}

double CtlController::walk(const RandomWalk& w, double x, double dt) {
  if (w.sigma <= 0 || w.max <= w.min) return std::clamp(x, w.min, w.max);
  x += w.sigma * std::sqrt(dt) * normal_(rng_);
  const double span = w.max - w.min;
  for (int k = 0; k < 4 && (x < w.min || x > w.max); ++k) {  // reflect at the bounds
    if (x < w.min) x = 2 * w.min - x;
    if (x > w.max) x = 2 * w.max - x;
  }
  (void)span;
  return std::clamp(x, w.min, w.max);
}

int CtlController::laneOf(int pass) const {
  const int n = spec_.route_passes;
  if (!spec_.route_loop || n < 2) return spec_.route_loop ? 0 : pass;
  // Back and forth over the lanes, so consecutive passes stay one spacing apart (a jump from
  // the last lane back to the first would drive the machine across every lane cutting).
  const int period = 2 * (n - 1);
  const int k = pass % period;
  return k < n ? k : period - k;
}

CtlCommand CtlController::replay(double dt) {
  // The command of the physics step that starts at steps_ * dt (zero-order hold).
  const double t = static_cast<double>(steps_++) * dt;
  CtlCommand c;
  const CommandLog& log = *spec_.replay;
  replay_row_ = log.rowAt(t, replay_row_);
  // Set-points are a scripted controller's; a replay logs the mean track command as its speed.
  depth_ = roll_ = blade_yaw_ = heading_ = std::numeric_limits<double>::quiet_NaN();
  speed_ = 0;
  if (replay_row_ < 0) return c;  // before the log or after it: stand still
  const std::array<double, 5>& u = log.u[static_cast<std::size_t>(replay_row_)];
  const bool lever = log.units == CommandLog::Units::Lever;
  c.v_left = lever ? u[0] * max_speed_ : u[0];
  c.v_right = lever ? u[1] * max_speed_ : u[1];
  for (int k = 0; k < 3; ++k) c.joint_rate[k] = lever ? u[2 + k] * joint_max_rate_[k] : u[2 + k];
  speed_ = 0.5 * (c.v_left + c.v_right);
  return c;
}

CtlCommand CtlController::update(double dt, const CompactTrackLoader& m) {
  if (spec_.type == ControllerSpec::Type::Replay) return replay(dt);
  // An excavator's undercarriage and plow stay where they are while it digs (the arm has its
  // own controller, DigDumpController).
  if (spec_.type == ControllerSpec::Type::DigDump) return CtlCommand{};
  double omega_cmd = 0, v_cmd = 0;
  const Eigen::Vector2d p(m.x(), m.y());
  if (spec_.type == ControllerSpec::Type::RandomWalk) {
    speed_ = walk(spec_.speed_mps, speed_, dt);
    depth_ = walk(spec_.depth_m, depth_, dt);
    roll_ = walk(spec_.roll_rad, roll_, dt);
    blade_yaw_ = walk(spec_.yaw_rad, blade_yaw_, dt);
    const double rel = walk(spec_.heading_rad, heading_ - heading0_, dt);
    heading_ = heading0_ + rel;
    omega_cmd = std::clamp(1.5 * wrapAngle(heading_ - m.yaw()), -0.6, 0.6);
    v_cmd = speed_;
  } else {
    const Eigen::Vector2d dir(std::cos(spec_.route_heading_rad), std::sin(spec_.route_heading_rad));
    const Eigen::Vector2d left(-dir.y(), dir.x());
    if (!finished_) {
      const int lane = laneOf(reversing_ ? pass_ + 1 : pass_);
      const Eigen::Vector2d A = spec_.route_start + left * (spec_.route_spacing_m * lane);
      const double along = (p - A).dot(dir);
      if (!reversing_) {
        const Eigen::Vector2d P = A + dir * (along + 1.5);
        heading_ = std::atan2(P.y() - p.y(), P.x() - p.x());
        v_cmd = spec_.route_speed_mps;
        depth_ = spec_.route_depth_m;
        if (spec_.route_grade)
          grade_target_ = std::max(spec_.grade_lowest_m, spec_.grade_first_m + pass_ * spec_.grade_step_m);
        // Stuck (at a pile of its own spoil, the blade already raised): back off and go on.
        const bool give_up = spec_.stall_give_up_s > 0 && slow_time_ > spec_.stall_give_up_s;
        if (along >= spec_.route_length_m || give_up) {
          if (!spec_.route_loop && pass_ + 1 >= spec_.route_passes) finished_ = true;
          else reversing_ = true;
        }
      } else {
        const Eigen::Vector2d P = A + dir * (along - 2.0);
        heading_ = std::atan2(p.y() - P.y(), p.x() - P.x());
        v_cmd = -spec_.route_return_speed_mps;
        depth_ = -0.2;
        grade_target_.reset();
        if (along <= -0.5) {
          reversing_ = false;
          ++pass_;
        }
      }
      speed_ = std::abs(v_cmd);
      omega_cmd = std::clamp(1.5 * wrapAngle(heading_ - m.yaw()), -0.6, 0.6);
    }
    if (finished_) {
      grade_target_.reset();
      v_cmd = 0;
      depth_ = -0.2;
      speed_ = 0;
    }
  }
  // Speed tracking failed for long enough: raise the blade until the machine moves again.
  if (v_cmd > 0.05 && m.speed() < spec_.stall_ratio * v_cmd) slow_time_ += dt;
  else slow_time_ = 0;
  if (slow_time_ > spec_.stall_time_s) raise_ += spec_.raise_rate_mps * dt;
  else raise_ -= 0.5 * spec_.raise_rate_mps * dt;
  raise_ = std::clamp(raise_, 0.0, 0.6);

  CtlCommand c;
  c.v_left = v_cmd - omega_cmd * gauge_ / 2;
  c.v_right = v_cmd + omega_cmd * gauge_ / 2;
  const std::array<double, 3> q = m.joints();
  if (grade_target_) {
    // Cut to grade: the lift that puts the edge at the target height (lift is the edge's height
    // above the contact plane, so a change of lift moves the edge by as much).
    const double edge_z = m.T_map_blade().translation().z();
    c.joint_rate[0] = 3.0 * ((*grade_target_ - edge_z) + raise_);
  } else {
    c.joint_rate[0] = 3.0 * ((-depth_ + raise_) - q[0]);
  }
  c.joint_rate[1] = 4.0 * (roll_ - q[1]);
  c.joint_rate[2] = 4.0 * (blade_yaw_ - q[2]);
  for (int k = 0; k < 3; ++k) c.joint_rate[k] = std::clamp(c.joint_rate[k], -joint_max_rate_[k], joint_max_rate_[k]);
  return c;
}

}  // namespace terramap::sim
