// The excavator's manipulator (TERA Eq. 1 joints, static efforts, relief stalls), its bucket
// mesh cutting, carrying and pouring soil, and the dig-and-dump controller.
#include <terramap/core/error.hpp>
#include <terramap/sim/excavator.hpp>

#include <algorithm>
#include <cmath>

namespace terramap::sim {
namespace {

constexpr double kG = 9.80665;
/// rad/s: an Eq. 1 transient below this (and its rate below ~this x its frequency) has settled.
constexpr double kSettledRate = 1e-9;

Eigen::Vector2d dir(double a) { return {std::cos(a), std::sin(a)}; }
double cross2(const Eigen::Vector2d& a, const Eigen::Vector2d& b) { return a.x() * b.y() - a.y() * b.x(); }
double wrapPi(double a) { return std::remainder(a, 2.0 * M_PI); }

/// A point of the slew frame's (x, z) plane in 3D (y = 0).
Eigen::Vector3d inPlane(const Eigen::Vector2d& p) { return {p.x(), 0.0, p.y()}; }

}  // namespace

// ---------------------------------------------------------------------------------------------
// Bucket mesh

double BucketMesh::volume() const {
  double a = 0;
  for (std::size_t k = 0; k < profile.size(); ++k) a += cross2(profile[k], profile[(k + 1) % profile.size()]);
  return 0.5 * a * width_m;
}

Eigen::Vector3d BucketMesh::centroid() const {
  double a = 0, cx = 0, cz = 0;
  for (std::size_t k = 0; k < profile.size(); ++k) {
    const Eigen::Vector2d& p = profile[k];
    const Eigen::Vector2d& q = profile[(k + 1) % profile.size()];
    const double w = cross2(p, q);
    a += w;
    cx += (p.x() + q.x()) * w;
    cz += (p.y() + q.y()) * w;
  }
  return {cx / (3 * a), 0.0, cz / (3 * a)};
}

BucketMesh::SideWalls BucketMesh::sideWalls(const Eigen::Isometry3d& T_map_bucket, double res) const {
  SideWalls w;
  const Eigen::Vector3d n = T_map_bucket.linear().col(1);  // the side walls' normal
  const double nh = std::hypot(n.x(), n.y());
  if (!(nh > 1e-9)) return w;  // walls lying flat
  w.flat = false;
  w.normal = Eigen::Vector2d(n.x() / nh, n.y() / nh);
  w.centre = T_map_bucket.translation().head<2>();
  w.half = 0.5 * width_m * nh;
  w.extent = res * (std::abs(w.normal.x()) + std::abs(w.normal.y()));
  return w;
}

double BucketMesh::SideWalls::coverage(double x, double y, Eigen::Vector2d* to_wall) const {
  if (to_wall) to_wall->setZero();
  if (flat) return 1.0;
  // Horizontal distance inside the nearer wall.
  const double along = (x - centre.x()) * normal.x() + (y - centre.y()) * normal.y();
  const double inside = half - std::abs(along);
  // A node outside the wall whose cell the bucket still covers in part: its span is the wall's.
  if (inside < 0 && to_wall) *to_wall = (along > 0 ? -1.0 : 1.0) * (1e-9 - inside) * normal;
  return std::clamp(inside / extent + 0.5, 0.0, 1.0);
}

bool BucketMesh::verticalSpan(const Eigen::Isometry3d& T_map_bucket, double x, double y, double& z_lo,
                              double& z_hi) const {
  // The vertical line in the bucket frame is a + z d; every face of the prism is a half-space
  // g0 + g1 z >= 0 of it (Cyrus–Beck clipping).
  const Eigen::Matrix3d Rt = T_map_bucket.linear().transpose();
  const Eigen::Vector3d a = Rt * (Eigen::Vector3d(x, y, 0.0) - T_map_bucket.translation());
  const Eigen::Vector3d d = Rt.col(2);
  double lo = -1e300, hi = 1e300;
  auto clip = [&](double g0, double g1) {
    if (std::abs(g1) < 1e-12) return g0 >= 0;
    const double z = -g0 / g1;
    if (g1 > 0) lo = std::max(lo, z);
    else hi = std::min(hi, z);
    return lo <= hi;
  };
  const double hw = 0.5 * width_m;
  if (!clip(hw - a.y(), -d.y()) || !clip(hw + a.y(), d.y())) return false;
  const std::size_t n = profile.size();
  for (std::size_t k = 0; k < n; ++k) {
    const Eigen::Vector2d& p = profile[k];
    const Eigen::Vector2d e = profile[(k + 1) % n] - p;
    // Inside (left of the counter-clockwise edge): cross(e, b - p) >= 0 with b = (x, z).
    const double g0 = e.x() * (a.z() - p.y()) - e.y() * (a.x() - p.x());
    const double g1 = e.x() * d.z() - e.y() * d.x();
    if (!clip(g0, g1)) return false;
  }
  z_lo = lo;
  z_hi = hi;
  return true;
}

BucketMesh bucketMesh(const ArmSpec& spec) {
  BucketMesh m;
  m.width_m = spec.bucket_width_m;
  if (spec.bucket_profile.empty()) {
    const double L = spec.bucket_m, D = spec.bucket_depth_m;
    // Mouth from near the pivot to the lip, a floor sloping back from the lip, a rounded back.
    m.profile = {{0.0, 0.0}, {L, 0.0}, {0.62 * L, D}, {0.12 * L, 0.88 * D}};
  } else {
    m.profile = spec.bucket_profile;
  }
  const std::size_t n = m.profile.size();
  if (n < 3) throw ConfigError("arm.bucket.profile_m: a bucket profile needs at least three vertices");
  double area = 0;
  for (std::size_t k = 0; k < n; ++k) area += cross2(m.profile[k], m.profile[(k + 1) % n]);
  if (area < 0) std::reverse(m.profile.begin(), m.profile.end());
  for (std::size_t k = 0; k < n; ++k) {
    const Eigen::Vector2d e0 = m.profile[(k + 1) % n] - m.profile[k];
    const Eigen::Vector2d e1 = m.profile[(k + 2) % n] - m.profile[(k + 1) % n];
    if (!(cross2(e0, e1) > 0))
      throw ConfigError("arm.bucket.profile_m: the bucket profile must be convex with distinct vertices (vertex " +
                        std::to_string((k + 1) % n) + ")");
  }
  for (std::size_t k = 1; k < n; ++k)
    if (m.profile[k].x() > m.profile[static_cast<std::size_t>(m.lip)].x()) m.lip = static_cast<int>(k);
  return m;
}

double bucketHoldFraction(const Eigen::Vector3d& open_dir) {
  return std::clamp((open_dir.z() + 0.5) / 0.7, 0.0, 1.0);
}

// ---------------------------------------------------------------------------------------------
// Arm

ExcavatorArm::ExcavatorArm(const ArmSpec& spec) : spec_(spec), mesh_(bucketMesh(spec)) {
  for (int k = 0; k < 4; ++k) q_[k] = std::clamp(spec_.initial_rad[k], spec_.joints[k].min_rad, spec_.joints[k].max_rad);
  // The lip's soil-engaging frame: the floor runs from the lip to the next vertex (counter-
  // clockwise, i.e. towards the back); the face normal points into the bucket.
  const std::size_t n = mesh_.profile.size(), li = static_cast<std::size_t>(mesh_.lip);
  const Eigen::Vector2d lip = mesh_.profile[li], next = mesh_.profile[(li + 1) % n];
  const Eigen::Vector3d z = inPlane(next - lip).normalized();
  Eigen::Vector3d x(-z.z(), 0.0, z.x());
  if (x.dot(mesh_.centroid() - inPlane(lip)) < 0) x = -x;
  Eigen::Matrix3d R;
  R.col(0) = x;
  R.col(2) = z;
  R.col(1) = z.cross(x);
  T_bucket_lipBlade_.linear() = R;
  T_bucket_lipBlade_.translation() = inPlane(lip);
  floor_.width_m = mesh_.width_m;
  floor_.height_m = (next - lip).norm();
}

Eigen::Isometry3d ExcavatorArm::T_base_slew(const std::array<double, 4>& q) const {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(spec_.slew_x_m, 0.0, spec_.slew_z_m);
  T.linear() = Eigen::AngleAxisd(q[kSlew], Eigen::Vector3d::UnitZ()).toRotationMatrix();
  return T;
}

std::array<Eigen::Vector2d, 4> ExcavatorArm::chain(const std::array<double, 4>& q) const {
  const double a1 = q[kBoom], a2 = a1 + q[kArm], a3 = a2 + q[kBucket];
  std::array<Eigen::Vector2d, 4> c;
  c[0] = {spec_.boom_pivot_x_m, spec_.boom_pivot_z_m};
  c[1] = c[0] + spec_.boom_m * dir(a1);
  c[2] = c[1] + spec_.arm_m * dir(a2);
  const Eigen::Vector2d lip = mesh_.profile[static_cast<std::size_t>(mesh_.lip)];
  c[3] = c[2] + lip.x() * dir(a3) + lip.y() * dir(a3 + 0.5 * M_PI);
  return c;
}

Eigen::Isometry3d ExcavatorArm::T_base_bucket(const std::array<double, 4>& q) const {
  const double a3 = q[kBoom] + q[kArm] + q[kBucket];
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = inPlane(chain(q)[2]);
  // R_y(-a3): x -> (cos a3, 0, sin a3), z -> (-sin a3, 0, cos a3).
  T.linear() = Eigen::AngleAxisd(-a3, Eigen::Vector3d::UnitY()).toRotationMatrix();
  return T_base_slew(q) * T;
}

std::array<Eigen::Isometry3d, 4> ExcavatorArm::linkFrames(const std::array<double, 4>& q) const {
  const Eigen::Isometry3d S = T_base_slew(q);
  const std::array<Eigen::Vector2d, 4> c = chain(q);
  auto link = [&](const Eigen::Vector2d& pivot, double a) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation() = inPlane(pivot);
    T.linear() = Eigen::AngleAxisd(-a, Eigen::Vector3d::UnitY()).toRotationMatrix();
    return S * T;
  };
  return {S, link(c[0], q[kBoom]), link(c[1], q[kBoom] + q[kArm]), T_base_bucket(q)};
}

Eigen::Vector3d ExcavatorArm::lipInBase(const std::array<double, 4>& q) const {
  const Eigen::Vector2d lip = mesh_.profile[static_cast<std::size_t>(mesh_.lip)];
  return T_base_bucket(q) * inPlane(lip);
}

Eigen::Isometry3d ExcavatorArm::T_map_lipBlade(const Eigen::Isometry3d& T_map_base) const {
  return T_map_base * T_base_bucket(q_) * T_bucket_lipBlade_;
}

std::array<double, 4> ExcavatorArm::inverse(std::array<double, 4> q, double x, double z, double bucket_abs) const {
  const Eigen::Vector2d lip = mesh_.profile[static_cast<std::size_t>(mesh_.lip)];
  // The lip vertex in the bucket frame, rotated to the bucket's absolute angle (the same map
  // as chain()'s last link).
  const Eigen::Vector2d lip_off = lip.x() * dir(bucket_abs) + lip.y() * dir(bucket_abs + 0.5 * M_PI);
  const Eigen::Vector2d P = Eigen::Vector2d(x, z) - lip_off - Eigen::Vector2d(spec_.boom_pivot_x_m, spec_.boom_pivot_z_m);
  const double L1 = spec_.boom_m, L2 = spec_.arm_m;
  const double D = std::clamp(P.norm(), std::abs(L1 - L2) + 1e-6, L1 + L2 - 1e-6);
  const double c2 = std::clamp((D * D - L1 * L1 - L2 * L2) / (2 * L1 * L2), -1.0, 1.0);
  q[kArm] = -std::acos(c2);  // elbow up: the arm folds down from the boom
  q[kBoom] = std::atan2(P.y(), P.x()) - std::atan2(L2 * std::sin(q[kArm]), L1 + L2 * std::cos(q[kArm]));
  q[kBucket] = bucket_abs - q[kBoom] - q[kArm];
  q[kBucket] = wrapPi(q[kBucket] - 0.5 * (spec_.joints[kBucket].min_rad + spec_.joints[kBucket].max_rad)) +
               0.5 * (spec_.joints[kBucket].min_rad + spec_.joints[kBucket].max_rad);
  return q;
}

std::array<double, 4> ExcavatorArm::efforts(const std::array<double, 4>& q, const Eigen::Isometry3d& T_map_base,
                                            const Eigen::Vector3d& lip_force_map, double load_kg) const {
  const Eigen::Isometry3d T_map_slew = T_map_base * T_base_slew(q);
  const std::array<Eigen::Vector2d, 4> c = chain(q);
  std::array<Eigen::Vector3d, 4> p;
  for (int k = 0; k < 4; ++k) p[k] = T_map_slew * inPlane(c[k]);
  const Eigen::Vector3d g(0, 0, -kG);
  struct Body { Eigen::Vector3d r, F; int first_link; };
  // Link k's body hangs beyond joints 0..k (the upper structure's own weight acts on the slew only).
  const Body bodies[5] = {
      {T_map_slew.translation(), spec_.mass_kg[0] * g, 0},
      {0.5 * (p[0] + p[1]), spec_.mass_kg[1] * g, kBoom},
      {0.5 * (p[1] + p[2]), spec_.mass_kg[2] * g, kArm},
      {(T_map_base * T_base_bucket(q)) * mesh_.centroid(), (spec_.mass_kg[3] + load_kg) * g, kBucket},
      {p[3], lip_force_map, kBucket}};
  const Eigen::Vector3d lateral = T_map_slew.linear().col(1);
  std::array<double, 4> tau{};
  for (int j = 0; j < 4; ++j) {
    const Eigen::Vector3d axis = j == kSlew ? Eigen::Vector3d(T_map_slew.linear().col(2)) : Eigen::Vector3d(-lateral);
    const Eigen::Vector3d pivot = j == kSlew ? T_map_slew.translation() : p[j - 1];
    double ext = 0;
    for (const Body& b : bodies)
      if (b.first_link >= j) ext += axis.dot((b.r - pivot).cross(b.F));
    tau[j] = -ext;
  }
  return tau;
}

void ExcavatorArm::step(double dt, const ArmCommand& cmd, const Eigen::Isometry3d& T_map_base,
                        const Eigen::Vector3d& lip_force_map, double load_kg) {
  tau_ = efforts(q_, T_map_base, lip_force_map, load_kg);
  for (int k = 0; k < 4; ++k) {
    const ArmJointSpec& J = spec_.joints[k];
    const double target = std::clamp(cmd.lever[k], -1.0, 1.0) * J.max_rate_rps;
    const double delta = target - ss_[k];
    if (delta != 0.0) {
      // A change of the steady state starts its own Eq. 1 transient.
      e_[k] += delta * std::sin(J.phi);
      ed_[k] += delta * (J.eta * std::cos(J.phi) - J.beta * std::sin(J.phi));
      ss_[k] = target;
    }
    const double w0 = ss_[k] + e_[k];
    stalled_[k] = std::abs(tau_[k]) > J.max_torque_nm && tau_[k] * w0 > 0;
    if (stalled_[k]) {
      ss_[k] = e_[k] = ed_[k] = 0;
      qd_[k] = 0;
      continue;
    }
    // Exact advance of e'' + 2 beta e' + (eta^2 + beta^2) e = 0 over dt, and its integral.
    const double wn2 = J.eta * J.eta + J.beta * J.beta;
    double integral;
    if (wn2 > 0) {
      const double A = e_[k];
      const double decay = std::exp(-J.beta * dt);
      double e1, ed1;
      if (J.eta > 0) {
        const double B = (ed_[k] + J.beta * A) / J.eta;
        const double c = std::cos(J.eta * dt), s = std::sin(J.eta * dt);
        e1 = decay * (A * c + B * s);
        ed1 = decay * ((J.eta * B - J.beta * A) * c - (J.eta * A + J.beta * B) * s);
      } else {
        const double B = ed_[k] + J.beta * A;
        e1 = decay * (A + B * dt);
        ed1 = decay * (B - J.beta * (A + B * dt));
      }
      integral = -((ed1 - ed_[k]) + 2.0 * J.beta * (e1 - e_[k])) / wn2;
      e_[k] = e1;
      ed_[k] = ed1;
    } else {
      integral = e_[k] * dt;
    }
    // A joint told to stand whose transient has died away stands exactly (its valve closed):
    // the transient would otherwise decay forever, moving the joint by ever smaller amounts.
    if (ss_[k] == 0.0 && std::abs(e_[k]) < kSettledRate && std::abs(ed_[k]) < kSettledRate * (J.eta + J.beta + 1.0)) {
      e_[k] = ed_[k] = 0.0;
      integral = 0.0;
    }
    const double q0 = q_[k];
    q_[k] += ss_[k] * dt + integral;
    if (q_[k] < J.min_rad || q_[k] > J.max_rad) {
      q_[k] = std::clamp(q_[k], J.min_rad, J.max_rad);
      ss_[k] = e_[k] = ed_[k] = 0;
    }
    qd_[k] = (q_[k] - q0) / dt;
  }
}

// ---------------------------------------------------------------------------------------------
// Bucket and terrain

namespace {

/// Node box of the mesh's map footprint at T (one node of margin), clamped; false if empty.
bool meshBox(const TruthTerrain& t, const BucketMesh& m, const Eigen::Isometry3d& T, int& i0, int& j0, int& i1, int& j1) {
  double xmin = 1e300, xmax = -1e300, ymin = 1e300, ymax = -1e300;
  for (const Eigen::Vector2d& v : m.profile)
    for (double s : {-0.5, 0.5}) {
      const Eigen::Vector3d p = T * Eigen::Vector3d(v.x(), s * m.width_m, v.y());
      xmin = std::min(xmin, p.x()); xmax = std::max(xmax, p.x());
      ymin = std::min(ymin, p.y()); ymax = std::max(ymax, p.y());
    }
  const double r = t.resolution();
  i0 = std::max(0, static_cast<int>(std::floor((xmin - t.originX()) / r)) - 1);
  j0 = std::max(0, static_cast<int>(std::floor((ymin - t.originY()) / r)) - 1);
  i1 = std::min(t.nx() - 1, static_cast<int>(std::ceil((xmax - t.originX()) / r)) + 1);
  j1 = std::min(t.ny() - 1, static_cast<int>(std::ceil((ymax - t.originY()) / r)) + 1);
  return i0 <= i1 && j0 <= j1;
}

}  // namespace

CutResult bucketDig(TruthTerrain& terrain, const SoilField& soil, const BucketMesh& mesh,
                    const Eigen::Isometry3d& T_map_bucket, double room_loose_m3, BucketLoad& load) {
  CutResult out;
  int i0, j0, i1, j1;
  if (!meshBox(terrain, mesh, T_map_bucket, i0, j0, i1, j1)) return out;
  const double a = terrain.resolution() * terrain.resolution();
  const BucketMesh::SideWalls walls = mesh.sideWalls(T_map_bucket, terrain.resolution());
  for (int j = j0; j <= j1; ++j)
    for (int i = i0; i <= i1; ++i) {
      if (!(load.loose_m3 < room_loose_m3)) return out;
      const Eigen::Vector2d p = terrain.nodePosition(i, j);
      double zlo, zhi;
      // A node near a side wall gives the share of its cell the bucket covers (its layer's top
      // part): a node counts its whole cell, and taken whole or not at all by where it stands, a
      // bucket as wide as a whole number of nodes, square to the grid, took a row of nodes too
      // many or too few by rounding.
      Eigen::Vector2d to_wall;
      const double cover = walls.coverage(p.x(), p.y(), &to_wall);
      if (!(cover > 0)) continue;
      if (!mesh.verticalSpan(T_map_bucket, p.x() + to_wall.x(), p.y() + to_wall.y(), zlo, zhi)) continue;
      const double H = terrain.height(i, j), U = terrain.undisturbed(i, j), Lv = terrain.loose(i, j);
      double top = std::min(H, zhi);
      if (!(top > zlo)) continue;
      zlo = top - (top - zlo) * cover;
      const SoilProperties& sp = soil.at(p.x(), p.y(), std::max(0.0, terrain.initialHeight(i, j) - 0.5 * (zlo + top)));
      // Loose volume this layer would add to the bucket: bank soil swells, loose soil is loose.
      const double loose_part = std::min(Lv, std::max(0.0, top - std::max(zlo, U)));
      const double bank_part = std::max(0.0, std::min(top, U) - zlo);
      const double adds = (bank_part * sp.swell + loose_part) * a;
      const double room = room_loose_m3 - load.loose_m3;
      if (adds > room) top = zlo + (top - zlo) * (room / adds);  // the last layer that fits
      const TruthTerrain::Removed r = terrain.removeBetween(i, j, zlo, top);
      const double bank = (r.bank_u + r.loose_c) * a;
      if (!(bank > 0)) continue;
      load.bank_m3 += bank;
      load.loose_m3 += (r.bank_u * sp.swell + r.loose_v) * a;
      load.mass_kg += bank * sp.fee.gamma_n_m3 / kG;
      out.cut_bank_m3 += r.bank_u * a;
      out.moved_loose_m3 += r.loose_c * a;
      out.add(CellRect::inclusive(i, j, i, j));
    }
  return out;
}

CutResult bucketPour(TruthTerrain& terrain, const SoilField& soil, const Eigen::Vector3d& at, double radius_m,
                     double settle_m, double loose_m3, BucketLoad& load) {
  CutResult out;
  if (!(loose_m3 > 0) || !(load.loose_m3 > 0)) return out;
  const double frac = std::min(1.0, loose_m3 / load.loose_m3);
  const double bank = frac == 1.0 ? load.bank_m3 : load.bank_m3 * frac;
  const double loose = frac == 1.0 ? load.loose_m3 : loose_m3;
  const double mass = frac == 1.0 ? load.mass_kg : load.mass_kg * frac;
  load.bank_m3 -= bank;
  load.loose_m3 -= loose;
  load.mass_kg -= mass;
  const double res = terrain.resolution(), a = res * res;
  const int rn = std::max(0, static_cast<int>(std::floor(radius_m / res)));
  int ic, jc;
  terrain.nearestNode(at.x(), at.y(), ic, jc);
  std::vector<std::pair<int, int>> disc;
  for (int dj = -rn; dj <= rn; ++dj)
    for (int di = -rn; di <= rn; ++di)
      if ((di * di + dj * dj) * a <= radius_m * radius_m + 1e-12 && terrain.inside(ic + di, jc + dj))
        disc.emplace_back(ic + di, jc + dj);
  if (disc.empty()) {
    terrain.addLost(bank);
    out.lost_m3 = bank;
    return out;
  }
  const double v = loose / (a * disc.size()), c = bank / (a * disc.size());
  for (const auto& [i, j] : disc) {
    terrain.addLoose(i, j, v, c);
    out.add(CellRect::inclusive(i, j, i, j));
  }
  out.deposited_m3 = bank;
  const int sn = static_cast<int>(std::ceil(settle_m / res));
  const double h0 = terrain.initialHeightAt(at.x(), at.y());
  const double tanr = std::tan(soil.at(at.x(), at.y(), std::isnan(h0) ? 0.0 : std::max(0.0, h0 - at.z())).repose_rad);
  out.add(relaxRegion(terrain, tanr, ic - sn, jc - sn, ic + sn, jc + sn, 3));
  return out;
}

// ---------------------------------------------------------------------------------------------
// Dig-and-dump controller

namespace {
constexpr double kDeg = M_PI / 180;
constexpr double kBucketDig = -80 * kDeg, kBucketDragEnd = -125 * kDeg, kBucketCurled = -200 * kDeg,
                 kBucketOpen = -30 * kDeg, kBucketReach = -60 * kDeg;
/// Lift: the bucket angle the inverse kinematics is given lies at most this far (rad) from the
/// bucket's own toward curled (its lever saturates at that error anyway).
constexpr double kLiftCurlStep = 0.3;
constexpr double kSlewDeadband = 0.02 * kDeg;
}  // namespace

const char* DigDumpController::phaseName(Phase p) {
  switch (p) {
    case Phase::SwingToDig: return "swing_to_dig";
    case Phase::Penetrate: return "penetrate";
    case Phase::Drag: return "drag";
    case Phase::Curl: return "curl";
    case Phase::Lift: return "lift";
    case Phase::SwingToDump: return "swing_to_dump";
    case Phase::Dump: return "dump";
    case Phase::Done: return "done";
  }
  return "?";
}

DigDumpController::DigDumpController(const DigDumpSpec& spec) : spec_(spec) {}

double DigDumpController::lever(const ExcavatorArm& arm, int k, double target) const {
  const ArmJointSpec& J = arm.spec().joints[k];
  double err = std::clamp(target, J.min_rad, J.max_rad) - arm.q()[k];
  if (k == kSlew) {
    err = wrapPi(err);
    // Within 0.02 deg the swing is left alone (its brake holds it), as an operator's
    // swing lever rests while the arm digs: without this the hold crept by ever smaller
    // corrections, and a camera on the cab never stood still (docs/sim.md "Sensors on links").
    if (std::abs(err) < kSlewDeadband) return 0.0;
  }
  constexpr double kP = 2.5;  // 1/s: a 0.1 rad error asks for 0.25 rad/s
  return std::clamp(kP * err / J.max_rate_rps, -1.0, 1.0);
}

void DigDumpController::startCycle(const ExcavatorArm& arm, const Eigen::Isometry3d& T_map_base,
                                   const TruthTerrain& terrain) {
  const ArmSpec& s = arm.spec();
  const Eigen::Vector3d axis = T_map_base * Eigen::Vector3d(s.slew_x_m, 0, s.slew_z_m);
  const Eigen::Vector2d out_dir = (spec_.dig - axis.head<2>()).normalized();
  const Eigen::Vector2d dig = spec_.dig + out_dir * (spec_.advance_m * cycle_);
  r_dig_ = (dig - axis.head<2>()).norm();
  r_end_ = std::max(0.5, r_dig_ - spec_.drag_m);
  r_dump_ = (spec_.dump - axis.head<2>()).norm();
  const Eigen::Vector3d dig_b = T_map_base.inverse() * Eigen::Vector3d(dig.x(), dig.y(), axis.z());
  const Eigen::Vector3d dump_b = T_map_base.inverse() * Eigen::Vector3d(spec_.dump.x(), spec_.dump.y(), axis.z());
  yaw_dig_ = std::atan2(dig_b.y(), dig_b.x() - s.slew_x_m);
  yaw_dump_ = std::atan2(dump_b.y(), dump_b.x() - s.slew_x_m);
  const double h = terrain.heightAt(dig.x(), dig.y());
  z_surface_ = (std::isfinite(h) ? h : axis.z() - s.slew_z_m) - axis.z();  // relative to the slew origin
  z_bottom_ = z_surface_ - spec_.depth_m;
  lip_r_ = r_dig_;
  lip_z_ = z_surface_ + 0.4;
  enter(Phase::SwingToDig);
}

ArmCommand DigDumpController::update(double dt, const ExcavatorArm& arm, const Eigen::Isometry3d& T_map_base,
                                     const TruthTerrain& terrain, const BucketLoad& load, double capacity_m3) {
  ArmCommand cmd;
  if (!started_) {
    startCycle(arm, T_map_base, terrain);
    started_ = true;
  }
  phase_t_ += dt;
  if (phase_ == Phase::Done) return cmd;
  const std::array<double, 4> q = arm.q();
  const Eigen::Vector3d lip = arm.lipInBase(q) - arm.T_base_slew(q).translation();
  const Eigen::Vector3d lip_s = Eigen::AngleAxisd(-q[kSlew], Eigen::Vector3d::UnitZ()) * lip;  // slew frame
  const double lip_err = std::hypot(lip_s.x() - lip_r_, lip_s.z() - lip_z_);
  double yaw = yaw_dig_, bucket = kBucketReach;
  auto moveTo = [&](double& v, double goal, double rate) {
    v += std::clamp(goal - v, -rate * dt, rate * dt);
    return v == goal;
  };
  switch (phase_) {
    case Phase::SwingToDig: {
      moveTo(lip_r_, r_dig_, 1.0);
      moveTo(lip_z_, z_surface_ + 0.4, 1.0);
      const bool there = std::abs(wrapPi(q[kSlew] - yaw_dig_)) < 2 * kDeg && lip_err < 0.08;
      if (there || phase_t_ > 10) enter(Phase::Penetrate);
      break;
    }
    case Phase::Penetrate: {
      bucket = kBucketDig;
      const bool reached = moveTo(lip_z_, z_bottom_, 0.4);
      if ((reached && lip_err < 0.06) || phase_t_ > 4) enter(Phase::Drag);
      break;
    }
    case Phase::Drag: {
      const bool reached = moveTo(lip_r_, r_end_, 0.5);
      const double progress = (r_dig_ - lip_r_) / std::max(1e-6, r_dig_ - r_end_);
      bucket = kBucketDig + (kBucketDragEnd - kBucketDig) * std::clamp(progress, 0.0, 1.0);
      const bool full = load.loose_m3 >= 0.95 * capacity_m3;
      if ((reached && lip_err < 0.08) || full || phase_t_ > spec_.drag_m / 0.5 + 4) {
        curl_hold_ = {q[kBoom], q[kArm]};
        enter(Phase::Curl);
      }
      break;
    }
    case Phase::Curl: {
      // The bucket turns about its own pivot (boom and arm hold where the drag left them):
      // curling about the lip instead would drive the pivot, and the bucket's back, into the
      // trench floor.
      const bool curled = std::abs(q[kBoom] + q[kArm] + q[kBucket] - kBucketCurled) < 5 * kDeg;
      if (curled || phase_t_ > 3) {
        lip_r_ = lip_s.x();
        lip_z_ = lip_s.z();
        enter(Phase::Lift);
        break;
      }
      ArmCommand hold;
      hold.lever[kSlew] = lever(arm, kSlew, yaw_dig_);
      hold.lever[kBoom] = lever(arm, kBoom, curl_hold_[0]);
      hold.lever[kArm] = lever(arm, kArm, curl_hold_[1]);
      hold.lever[kBucket] = lever(arm, kBucket, kBucketCurled - curl_hold_[0] - curl_hold_[1]);
      return hold;
    }
    case Phase::Lift: {
      // Toward the curled angle from where the bucket is: a curl the soil stalled (the curl phase
      // timed out) must not make the lift's inverse kinematics place the pivot for a curled
      // bucket, which drove the pivot, and the full bucket, down through the trench wall.
      const double now = q[kBoom] + q[kArm] + q[kBucket], left = kBucketCurled - now;
      bucket = std::abs(left) <= kLiftCurlStep ? kBucketCurled : now + std::copysign(kLiftCurlStep, left);
      if ((moveTo(lip_z_, z_surface_ + spec_.carry_height_m, 0.8) && lip_err < 0.1) || phase_t_ > 5)
        enter(Phase::SwingToDump);
      break;
    }
    case Phase::SwingToDump: {
      yaw = yaw_dump_;
      bucket = kBucketCurled;
      moveTo(lip_r_, r_dump_, 1.0);
      if ((std::abs(wrapPi(q[kSlew] - yaw_dump_)) < 3 * kDeg && lip_err < 0.1) || phase_t_ > 10) enter(Phase::Dump);
      break;
    }
    case Phase::Dump:
      yaw = yaw_dump_;
      bucket = kBucketOpen;
      if ((load.loose_m3 < 0.02 * capacity_m3 && phase_t_ > 1.0) || phase_t_ > 6) {
        ++cycle_;
        if (spec_.cycles > 0 && cycle_ >= spec_.cycles) {
          enter(Phase::Done);
          return cmd;
        }
        startCycle(arm, T_map_base, terrain);
        lip_z_ = std::max(lip_z_, lip_s.z());
        lip_r_ = lip_s.x();
      }
      break;
    case Phase::Done: break;
  }
  // A dump that just started the next cycle heads for the dig at once.
  if (phase_ == Phase::SwingToDig) yaw = yaw_dig_;
  std::array<double, 4> target = arm.inverse(q, lip_r_, lip_z_, bucket);
  target[kSlew] = yaw;
  for (int k = 0; k < 4; ++k) cmd.lever[k] = lever(arm, k, target[k]);
  return cmd;
}

}  // namespace terramap::sim
