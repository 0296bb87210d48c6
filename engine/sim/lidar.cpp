// Ray-cast LiDAR.
#include <terramap/sim/lidar.hpp>
#include <terramap/sim/scan_caster.hpp>

#include <algorithm>
#include <array>

#include <cmath>
#include <limits>
#include <type_traits>

namespace terramap::sim {

namespace {
/// Inlinable copy of mixBits for the per-ray loop (the exported one may be interposed).
inline std::uint64_t mix(std::uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}
}  // namespace

std::uint64_t mixBits(std::uint64_t x) { return mix(x); }

namespace {
/// Ziggurat tables (Marsaglia & Tsang 2000, "The ziggurat method for generating random
/// variables", 128 layers): layer i is accepted at once when |j| < k[i], j being a signed
/// 32-bit draw; w[i] scales j to x; f[i] = exp(-x_i^2 / 2).
struct Ziggurat {
  std::uint32_t k[128];
  double w[128], f[128];
  static constexpr double kR = 3.442619855899;  // right edge of the base layer
  Ziggurat() {
    const double m1 = 2147483648.0, vn = 9.91256303526217e-3;
    double dn = kR, tn = dn;
    const double q = vn / std::exp(-0.5 * dn * dn);
    k[0] = static_cast<std::uint32_t>((dn / q) * m1);
    k[1] = 0;
    w[0] = q / m1;
    w[127] = dn / m1;
    f[0] = 1.0;
    f[127] = std::exp(-0.5 * dn * dn);
    for (int i = 126; i >= 1; --i) {
      dn = std::sqrt(-2.0 * std::log(vn / dn + std::exp(-0.5 * dn * dn)));
      k[i + 1] = static_cast<std::uint32_t>((dn / tn) * m1);
      tn = dn;
      f[i] = std::exp(-0.5 * dn * dn);
      w[i] = dn / m1;
    }
  }
};
const Ziggurat& ziggurat() {
  static const Ziggurat z;
  return z;
}
}  // namespace

namespace {
/// gaussianFromBits, inlinable into the per-ray loop (the exported one may be interposed, and
/// a call through the PLT per returned point cost more than the common path's draw).
inline double gaussian(std::uint64_t h) {
  const Ziggurat& z = ziggurat();
  std::uint64_t s = h;
  for (int draw = 1;; ++draw) {
    const auto j = static_cast<std::int32_t>(static_cast<std::uint32_t>(s));
    const int i = static_cast<int>((s >> 32) & 127);
    const std::uint32_t aj = j < 0 ? static_cast<std::uint32_t>(-static_cast<std::int64_t>(j)) : static_cast<std::uint32_t>(j);
    const double x = j * z.w[i];
    if (aj < z.k[i]) return x;
    if (i == 0) {
      // Base layer: the tail beyond kR, by Marsaglia's exponential rejection.
      double xt, yt;
      do {
        s = mix(s + static_cast<std::uint64_t>(draw++));
        xt = -std::log(unitFromBits(s)) / Ziggurat::kR;
        s = mix(s + static_cast<std::uint64_t>(draw++));
        yt = -std::log(unitFromBits(s));
      } while (yt + yt < xt * xt);
      return j > 0 ? Ziggurat::kR + xt : -Ziggurat::kR - xt;
    }
    // Wedge of layer i: accept under the density.
    s = mix(s + static_cast<std::uint64_t>(draw));
    if (z.f[i] + unitFromBits(s) * (z.f[i - 1] - z.f[i]) < std::exp(-0.5 * x * x)) return x;
    s = mix(s ^ 0x632be59bd9b4e019ULL);
  }
}
}  // namespace

double gaussianFromBits(std::uint64_t h) { return gaussian(h); }

namespace {

/// The eight corners of box `b` in the sensor frame (rotation R of the sensor in the map), the
/// origin at the sensor: `cs` is the box centre there, R^T (b.centre - o).
std::array<Eigen::Vector3d, 8> sensorCorners(const PlacedBox& b, const Eigen::Vector3d& cs, const Eigen::Matrix3d& R) {
  const Eigen::Matrix3d Rs = R.transpose() * b.R;
  std::array<Eigen::Vector3d, 8> c;
  for (int k = 0; k < 8; ++k)
    c[k] = cs + Rs * Eigen::Vector3d((k & 1) ? b.half.x() : -b.half.x(), (k & 2) ? b.half.y() : -b.half.y(),
                                     (k & 4) ? b.half.z() : -b.half.z());
  return c;
}

/// The machines' boxes one scan can hit, with what culls them cheaply. A column's rays all lie
/// in the half-plane of its azimuth through the sensor's z axis, so a box whose bounding sphere
/// misses that half-plane cannot be hit by the column, and of those that meet it only the beams
/// whose elevation reaches the box's slice by that plane can (a beam range per box and column);
/// an upward ray cannot hit a box whose top is below the origin.
class ScanObstacles {
 public:
  /// Keeps the boxes within `max_range` of `o` (buffers reused from scan to scan).
  /// With `camera` (a depth camera's spec), also each box's pixel rectangle (cameraRow, hit).
  /// `beam_slopes`: a LiDAR's tan(beam elevation), ascending in beam order (null for a camera).
  void prepare(const std::vector<PlacedBox>* obstacles, const Eigen::Vector3d& o, const Eigen::Matrix3d& R,
               double max_range, const SensorSpec* camera = nullptr, double z_near = 0,
               const std::vector<double>* beam_slopes = nullptr) {
    slopes_ = beam_slopes;
    boxes_.clear();
    corners_.clear();
    cs_.clear();
    top_.clear();
    rect_.clear();
    camera_ = camera != nullptr;
    if (!obstacles) return;
    for (const PlacedBox& b : *obstacles) {
      if ((b.centre - o).norm() - b.radius > max_range) continue;
      boxes_.push_back(b);
      cs_.push_back(R.transpose() * (b.centre - o));  // sphere centre, sensor frame, origin-relative
      if (slopes_) corners_.push_back(sensorCorners(b, cs_.back(), R));
      top_.push_back(b.centre.z() + b.R.row(2).cwiseAbs().dot(b.half));
      if (camera) rect_.push_back(pixelRect(b, cs_.back(), R, *camera, z_near));
    }
    oz_ = o.z();
  }
  std::size_t size() const { return boxes_.size(); }

  /// The candidates of scan row `row` (a LiDAR's column, a camera's image row) whose first
  /// sensor-frame ray is `d0`: for all rays (`all`) and for upward rays (`up`); each sized size().
  /// Per candidate box q also the rays of the row that can reach it, [spans[q][0], spans[q][1]]:
  /// a LiDAR column's beams, a camera row's pixel columns.
  void row(int row, const Eigen::Vector3d& d0, std::vector<int>& all, int& n_all, std::vector<int>& up, int& n_up,
           std::vector<std::array<int, 2>>& spans) const {
    if (camera_) cameraRow(row, d0.y() / d0.z(), all, n_all, up, n_up, spans);
    else column(d0, all, n_all, up, n_up, spans);
  }

 private:
  /// A LiDAR column's candidates (see the class comment), each with the beams that can reach
  /// it: the box's slice by the column's plane is the convex hull of where its edges cross the
  /// plane; the column's rays run from the origin at their elevations within the half-plane
  /// ahead (along >= 0), so a beam reaches the slice iff its elevation lies within the angles
  /// the slice's part ahead spans from the origin (all of them if the slice holds the origin).
  void column(const Eigen::Vector3d& d0, std::vector<int>& all, int& n_all, std::vector<int>& up, int& n_up,
              std::vector<std::array<int, 2>>& spans) const {
    n_all = n_up = 0;
    const double hx = d0.x(), hy = d0.y(), hn = std::hypot(hx, hy);
    const double ux = hx / hn, uy = hy / hn;
    for (std::size_t q = 0; q < boxes_.size(); ++q) {
      const Eigen::Vector3d& cs = cs_[q];
      const double r = boxes_[q].radius;
      const double across = -uy * cs.x() + ux * cs.y(), along = ux * cs.x() + uy * cs.y();
      if (std::abs(across) > r || along < -r) continue;
      std::array<int, 2> span{0, std::numeric_limits<int>::max()};
      if (slopes_ && !slice(corners_[q], ux, uy, span)) continue;
      spans[q] = span;
      all[n_all++] = static_cast<int>(q);
      if (top_[q] >= oz_) up[n_up++] = static_cast<int>(q);
    }
  }

  /// The beams [span[0], span[1]] whose rays in the column of unit direction (ux, uy) can reach
  /// the box of corners `c` (sensor frame); false when none can.
  bool slice(const std::array<Eigen::Vector3d, 8>& c, double ux, double uy, std::array<int, 2>& span) const {
    double ac[8], al[8];
    for (int k = 0; k < 8; ++k) {
      ac[k] = -uy * c[k].x() + ux * c[k].y();
      al[k] = ux * c[k].x() + uy * c[k].y();
    }
    // Where the box's edges cross the plane (along, z); a corner on it counts as a crossing.
    double pa[12], pz[12];
    int n = 0;
    for (int k = 0; k < 8; ++k)
      for (int bit = 1; bit < 8; bit <<= 1) {
        const int j = k | bit;
        if (j == k) continue;
        if ((ac[k] > 0 && ac[j] > 0) || (ac[k] < 0 && ac[j] < 0)) continue;
        const double f = ac[k] == ac[j] ? 0.0 : ac[k] / (ac[k] - ac[j]);
        pa[n] = al[k] + f * (al[j] - al[k]);
        pz[n] = c[k].z() + f * (c[j].z() - c[k].z());
        if (++n == 12) break;
      }
    if (n == 0) return false;
    // The slice's slopes (z / along, monotonic in the elevation angle) from the origin over its
    // part ahead: the points ahead, and where the hull crosses along = 0 (between pairs of
    // points on either side), straight up or down.
    constexpr double kEps = 1e-9;
    double lo = INFINITY, hi = -INFINITY, zlo0 = INFINITY, zhi0 = -INFINITY;
    for (int k = 0; k < n; ++k) {
      if (pa[k] > 0) {
        const double m = pz[k] / pa[k];
        lo = std::min(lo, m);
        hi = std::max(hi, m);
      }
      if (pa[k] <= 0)
        for (int j = 0; j < n; ++j)
          if (pa[j] >= 0 && (pa[k] < 0 || pa[j] > 0)) {
            const double z = pa[j] == pa[k] ? pz[k] : pz[k] + (pz[j] - pz[k]) * (-pa[k] / (pa[j] - pa[k]));
            zlo0 = std::min(zlo0, z);
            zhi0 = std::max(zhi0, z);
          }
    }
    if (zlo0 <= zhi0) {
      if (zlo0 <= kEps && zhi0 >= -kEps) return true;  // the slice holds the origin: every beam
      if (zlo0 > 0) hi = INFINITY;
      else lo = -INFINITY;
    }
    if (!(lo <= hi)) return false;  // wholly behind
    // A hair wider than the slopes against rounding.
    const auto first = std::lower_bound(slopes_->begin(), slopes_->end(), lo - kEps * (1.0 + std::abs(lo)));
    const auto last = std::upper_bound(slopes_->begin(), slopes_->end(), hi + kEps * (1.0 + std::abs(hi)));
    if (first == last) return false;
    span = {static_cast<int>(first - slopes_->begin()), static_cast<int>(last - slopes_->begin()) - 1};
    return true;
  }

  /// The candidates of a depth camera's image row v, whose rays are (x, a, 1) in the optical
  /// frame (a = (v - cy) / fy): the boxes whose pixel rectangle spans the row and whose bounding
  /// sphere meets the row's half-plane (normal (0, -1, a) through the origin, z > 0). The plane
  /// test culls the boxes that reach behind the camera (the machine it rides on), which get the
  /// whole image as their rectangle.
  void cameraRow(int v, double a, std::vector<int>& all, int& n_all, std::vector<int>& up, int& n_up,
                 std::vector<std::array<int, 2>>& spans) const {
    n_all = n_up = 0;
    const double inv = 1.0 / std::sqrt(1.0 + a * a);
    for (std::size_t q = 0; q < boxes_.size(); ++q) {
      if (v < rect_[q][2] || v > rect_[q][3]) continue;
      const Eigen::Vector3d& cs = cs_[q];
      const double r = boxes_[q].radius;
      if (std::abs(a * cs.z() - cs.y()) * inv > r || cs.z() < -r) continue;
      spans[q] = {rect_[q][0], rect_[q][1]};
      all[n_all++] = static_cast<int>(q);
      if (top_[q] >= oz_) up[n_up++] = static_cast<int>(q);
    }
  }

 public:
  /// First box entry of the ray o + t dm in [t_min, t_max] among its row's candidates (row()):
  /// only those whose span (row()) holds the ray's index `u` in the row (its beam, its pixel
  /// column), gathered in `px` (scratch sized size()). +inf when none.
  double hit(const Eigen::Vector3d& o, const Eigen::Vector3d& dm, double t_min, double t_max, const std::vector<int>& all,
             int n_all, const std::vector<int>& up, int n_up, int u, std::vector<int>& px,
             const std::vector<std::array<int, 2>>& spans, Eigen::Vector3d* normal) const {
    const bool upward = dm.z() >= 0.0;
    const int* idx = upward ? up.data() : all.data();
    const int n_row = upward ? n_up : n_all;
    int n = 0;
    for (int k = 0; k < n_row; ++k)
      if (u >= spans[idx[k]][0] && u <= spans[idx[k]][1]) px[n++] = idx[k];
    idx = px.data();
    if (n == 0) return std::numeric_limits<double>::infinity();
    return firstBoxHit(boxes_.data(), idx, n, o, dm, t_min, t_max, normal);
  }

 private:
  /// Pixel rectangle [u0, u1, v0, v1] (inclusive, 1 px margin) that holds every pixel whose
  /// ray can enter the box at a depth z >= z_near: the projection of the convex body
  /// box ∩ {z >= z_near} is the hull of its projected vertices (the corners in front and the
  /// edges' crossings of z = z_near). A scan's rays reach no nearer than min_range along the
  /// ray, hence z >= min_range * (least optical z of a ray): that is z_near. Empty (u0 > u1)
  /// when the box lies wholly nearer.
  static std::array<int, 4> pixelRect(const PlacedBox& b, const Eigen::Vector3d& cs, const Eigen::Matrix3d& R,
                                      const SensorSpec& cam, double z_near) {
    const std::array<Eigen::Vector3d, 8> c = sensorCorners(b, cs, R);
    double u0 = 1e300, u1 = -1e300, v0 = 1e300, v1 = -1e300;
    auto add = [&](const Eigen::Vector3d& p) {
      const double u = cam.fx * p.x() / p.z() + cam.cx, v = cam.fy * p.y() / p.z() + cam.cy;
      u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
    };
    for (int k = 0; k < 8; ++k) {
      if (c[k].z() >= z_near) add(c[k]);
      for (int bit = 1; bit < 8; bit <<= 1) {  // the edges from k to its neighbours above it
        const int j = k | bit;
        if (j == k) continue;
        const double zk = c[k].z() - z_near, zj = c[j].z() - z_near;
        if ((zk < 0) != (zj < 0)) add(c[k] + (c[j] - c[k]) * (zk / (zk - zj)));
      }
    }
    if (u0 > u1) return {1, 0, 1, 0};
    auto lo = [](double x) { return static_cast<int>(std::max(-1e9, std::floor(x) - 1)); };
    auto hi = [](double x) { return static_cast<int>(std::min(1e9, std::ceil(x) + 1)); };
    return {lo(u0), hi(u1), lo(v0), hi(v1)};
  }

  bool camera_ = false;
  const std::vector<double>* slopes_ = nullptr;  ///< a LiDAR's tan(beam elevation), ascending
  std::vector<PlacedBox> boxes_;
  std::vector<std::array<Eigen::Vector3d, 8>> corners_;  ///< a LiDAR scan's: each box's, sensor frame
  std::vector<std::array<int, 4>> rect_;
  std::vector<Eigen::Vector3d> cs_;
  std::vector<double> top_;
  double oz_ = 0;
};

}  // namespace

/// Scans of fewer rays build a coarser horizon table (ScanCaster::setSparse).
constexpr std::size_t kSparseRays = 4096;

struct LidarModel::Scratch {
  ScanCaster caster;
  std::vector<std::vector<PointXYZI>> parts;
  ScanObstacles obstacles;  // the machines' boxes within reach of this scan
  /// The last scan's terrain hits (spec().reuse_casts), per ray, kept when the sensor scanned
  /// from the same pose as the scan before (a sensor that moves keeps nothing, and pays
  /// nothing for it): `valid` when the last scan, from `pose` over the terrain `terrain_id` at
  /// `revision`, kept them (for the rays with a RayDep below kAlways). The same pose over the
  /// same terrain object gives a table of the same shape, so the RayDeps index the same bins.
  struct Kept {
    bool valid = false, scanned = false;  // hits kept; `pose` and `terrain_id` are the last scan's
    std::uint64_t terrain_id = 0, revision = 0;
    Eigen::Matrix4d pose;
    std::vector<double> t;
    std::vector<int> ci, cj;
    std::vector<ScanCaster::RayDep> dep;
    std::vector<int> first_change;  // this scan's ScanCaster::changedRows since `revision`
    std::vector<std::size_t> used;  // per chunk of the last scan, rays that took their kept hit
  } kept;
};

LidarModel::~LidarModel() = default;
LidarModel::LidarModel(LidarModel&&) noexcept = default;
LidarModel& LidarModel::operator=(LidarModel&&) noexcept = default;

std::size_t LidarModel::keptLastScan() const {
  std::size_t n = 0;
  for (std::size_t u : scratch_->kept.used) n += u;
  return n;
}

LidarModel::LidarModel(const SensorSpec& spec) : spec_(spec), scratch_(std::make_unique<Scratch>()) {
  if (spec.type == SensorSpec::Type::DepthCamera) {
    // Row-major image: a "column" of the scan is an image row, its "beams" the row's pixels.
    camera_ = true;
    B_ = spec.width;
    C_ = spec.height;
    dirs_.reserve(static_cast<std::size_t>(B_) * C_);
    double min_z = 1.0;
    for (int v = 0; v < C_; ++v)
      for (int u = 0; u < B_; ++u) {
        const Eigen::Vector3d d = Eigen::Vector3d((u - spec.cx) / spec.fx, (v - spec.cy) / spec.fy, 1.0).normalized();
        dirs_.push_back(d);
        min_z = std::min(min_z, d.z());
      }
    t_max_ = spec.max_range_m / min_z;
    // Ray hits lie at t >= min_range, so at depth z >= min_range * min_z (a hair less for rounding).
    z_near_ = std::max(1e-6, 0.999 * spec.min_range_m * min_z);
    return;
  }
  const int B = spec.beams, C = spec.columns;
  B_ = B;
  C_ = C;
  t_max_ = spec.max_range_m;
  dirs_.reserve(static_cast<std::size_t>(B) * C);
  const bool full_circle = spec.hfov_rad >= 2 * M_PI - 1e-9;
  for (int c = 0; c < C; ++c) {
    // Azimuth centred on the sensor x axis; a full circle does not repeat its first column.
    double az;
    if (C == 1) az = 0.0;
    else if (full_circle) az = -M_PI + (c + 0.5) * (2 * M_PI / C);
    else az = -0.5 * spec.hfov_rad + c * spec.hfov_rad / (C - 1);
    for (int b = 0; b < B; ++b) {
      const double el = B == 1 ? 0.5 * (spec.vfov_min_rad + spec.vfov_max_rad)
                               : spec.vfov_min_rad + b * (spec.vfov_max_rad - spec.vfov_min_rad) / (B - 1);
      dirs_.emplace_back(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
      if (c == 0) {
        elevations_.push_back(el);
        beam_slopes_.push_back(std::tan(el));
      }
    }
  }
}

double LidarModel::minSlope(const Eigen::Matrix3d& R_map_sensor) const {
  // A direction (cos e cos a, cos e sin a, sin e) maps to d_z = r20 cos e cos a + r21 cos e sin a
  // + r22 sin e >= r22 sin e - cos e |(r20, r21)| for every azimuth a; d_z / |d_xy| rises with
  // d_z. A small margin covers rounding of the rotated directions.
  const double rh = std::hypot(R_map_sensor(2, 0), R_map_sensor(2, 1));
  double dz_min = 1.0;
  if (camera_) {
    // A pinhole's rays share no elevation: the exact minimum over them (one dot product a ray).
    const Eigen::RowVector3d r2 = R_map_sensor.row(2);
    for (const Eigen::Vector3d& d : dirs_) dz_min = std::min(dz_min, r2.dot(d));
  }
  for (double e : elevations_) dz_min = std::min(dz_min, R_map_sensor(2, 2) * std::sin(e) - std::cos(e) * rh);
  dz_min -= 1e-9;
  if (dz_min <= -1.0 + 1e-12) return -std::numeric_limits<double>::infinity();
  return dz_min / std::sqrt(1.0 - dz_min * dz_min);
}

// Forced inline: as a call per ray it cost scan() 21 % more instructions (callgrind,
// BM_SimRealtimeDepthCameraImus/1: 1.85 G before the split, 2.25 G as a call).
__attribute__((always_inline)) inline void LidarModel::emitPoint(const TruthTerrain& terrain, const Eigen::Vector3d& o, const Eigen::Vector3d& ds,
                           const Eigen::Vector3d& dm, const RayHit& hit, std::uint64_t noise_key, std::size_t k,
                           std::vector<PointXYZI>& pts) const {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  double t = hit.t;
  if (camera_ && !std::isnan(t)) {
    const double z = ds.z() * t;  // depth: the optical z
    if (z < spec_.min_range_m || z > spec_.max_range_m) t = std::numeric_limits<double>::quiet_NaN();
  }
  if (std::isnan(t)) {
    if (spec_.keep_dropouts) pts.push_back({nan, nan, nan, nan});
    return;
  }
  const std::uint64_t h = mix(noise_key ^ mix(k));  // the ray's draws: dropout, then noise
  if (spec_.dropout > 0 && unitFromBits(mix(h ^ 0xd1b54a32d192ed03ULL)) < spec_.dropout) {
    if (spec_.keep_dropouts) pts.push_back({nan, nan, nan, nan});
    return;
  }
  // Lambertian intensity from the normal of the surface that was hit (noise-free point).
  float inten;
  if (hit.on_machine) {
    inten = static_cast<float>(std::abs(dm.dot(hit.normal)));
  } else {
    const Eigen::Vector3d p = o + dm * t;
    const Eigen::Vector2d g = terrain.cellGradient(hit.ci, hit.cj, p.x(), p.y());
    inten = static_cast<float>(std::abs(dm.z() - g.x() * dm.x() - g.y() * dm.y()) /
                               std::sqrt(1.0 + g.x() * g.x() + g.y() * g.y()));
  }
  if (camera_) {
    // Depth noise sigma(z) along the ray: z -> z + sigma n moves the point by sigma n / d_z.
    const double z = ds.z() * t;
    const double sigma = spec_.depth_noise_abs_m + spec_.depth_noise_k * z * z;
    if (sigma > 0) t += sigma * gaussian(h) / ds.z();
  } else if (spec_.range_noise_m > 0) {
    t += spec_.range_noise_m * gaussian(h);
  }
  pts.push_back({static_cast<float>(ds.x() * t), static_cast<float>(ds.y() * t), static_cast<float>(ds.z() * t), inten});
}

struct LidarModel::ScanJob {
  const TruthTerrain& terrain;
  Eigen::Vector3d o;
  Eigen::Matrix3d R;
  std::uint64_t noise_key;
  bool reuse;  // the kept hits may serve this scan (Kept::first_change filled)
};

/// Per chunk, reused from row to row: a row's rays in the map frame and terrain hits, the batch
/// of rays to cast, and the machines' boxes the row can reach.
struct LidarModel::RowScratch {
  RowScratch(int B, std::size_t nbox)
      : dm(B), t(B), ci(B), cj(B), dm_may(B), t_may(B), ci_may(B), cj_may(B), dep_may(B), may_idx(B), cand(nbox),
        cand_up(nbox), px(nbox), spans(nbox) {}
  std::vector<Eigen::Vector3d> dm;
  std::vector<double> t;
  std::vector<int> ci, cj;
  std::vector<Eigen::Vector3d> dm_may;
  std::vector<double> t_may;
  std::vector<int> ci_may, cj_may;
  std::vector<ScanCaster::RayDep> dep_may;
  std::vector<int> may_idx;
  std::vector<int> cand, cand_up, px;
  std::vector<std::array<int, 2>> spans;
  int n_cand = 0, n_up = 0;
};

bool LidarModel::prepareCasts(const TruthTerrain& terrain, const Eigen::Isometry3d& T_map_sensor, const Executor* exec,
                              bool& still) const {
  Scratch::Kept& kept = scratch_->kept;
  // `still`: the sensor has not moved since its last scan, over the same terrain object (so the
  // same rays and the same table bins). Such a sensor keeps this scan's hits for the next, and
  // takes those the last scan kept; the table needs a rebuild only if the terrain changed.
  still = spec_.reuse_casts && kept.scanned && kept.terrain_id == terrain.instanceId() &&
          kept.pose == T_map_sensor.matrix();
  const bool reuse = still && kept.valid;
  kept.valid = false;  // until this scan completes
  // One horizon table per scan (the ray-casting view is frozen while the scan is cast); the
  // model keeps its buffers, so a scan allocates nothing after the first.
  ScanCaster& caster = scratch_->caster;
  if (!(reuse && kept.revision == terrain.revision())) {
    caster.setSparse(dirs_.size() < kSparseRays);
    caster.build(terrain, T_map_sensor.translation(), t_max_, minSlope(T_map_sensor.linear()), exec);
  }
  if (reuse) caster.changedRows(kept.revision, kept.first_change);
  if (still) {
    kept.t.resize(dirs_.size());
    kept.ci.resize(dirs_.size());
    kept.cj.resize(dirs_.size());
    kept.dep.resize(dirs_.size());
  }
  return reuse;
}

template <bool kKeep>
void LidarModel::castRow(const ScanJob& job, int c, RowScratch& rs, std::size_t& used) const {
  const ScanCaster& cast = scratch_->caster;
  Scratch::Kept& kept = scratch_->kept;
  const int B = B_;
  const std::size_t k0 = static_cast<std::size_t>(c) * B;
  // Rays that cannot hit (upwards from above the terrain: half of a spinning LiDAR's) are
  // settled here, and so are the rays whose kept hit holds; the rest are cast as one batch.
  int n_may = 0;
  for (int b = 0; b < B; ++b) {
    rs.dm[b] = job.R * dirs_[k0 + b];
    rs.t[b] = std::numeric_limits<double>::quiet_NaN();
    if (cast.mayHit(rs.dm[b])) {
      if (kKeep && job.reuse) {
        const ScanCaster::RayDep dep = kept.dep[k0 + b];
        if (dep.r < kept.first_change[static_cast<std::size_t>(dep.a)]) {
          rs.t[b] = kept.t[k0 + b];
          rs.ci[b] = kept.ci[k0 + b];
          rs.cj[b] = kept.cj[k0 + b];
          ++used;
          continue;
        }
      }
      rs.dm_may[n_may] = rs.dm[b];
      rs.may_idx[n_may++] = b;
    } else if (kKeep) {
      // Not cast (above the terrain's top, not descending): nothing kept to reuse should the
      // top rise. (A kept result does not depend on the top otherwise: such a ray misses.)
      kept.dep[k0 + b].r = ScanCaster::kAlways;
    }
  }
  // A camera's minimum depth bounds t from below too (t >= z); depth itself is checked below.
  cast.castBatch(rs.dm_may.data(), n_may, spec_.min_range_m, t_max_, rs.t_may.data(), rs.ci_may.data(),
                 rs.cj_may.data(), kKeep ? rs.dep_may.data() : nullptr);
  for (int q = 0; q < n_may; ++q) {
    const int b = rs.may_idx[q];
    rs.t[b] = rs.t_may[q];
    rs.ci[b] = rs.ci_may[q];
    rs.cj[b] = rs.cj_may[q];
    if (kKeep) {
      kept.t[k0 + b] = rs.t_may[q];
      kept.ci[k0 + b] = rs.ci_may[q];
      kept.cj[k0 + b] = rs.cj_may[q];
      kept.dep[k0 + b] = rs.dep_may[q];
    }
  }
}

void LidarModel::emitRow(const ScanJob& job, int c, RowScratch& rs, std::vector<PointXYZI>& pts) const {
  const ScanObstacles& boxes = scratch_->obstacles;
  const std::size_t k0 = static_cast<std::size_t>(c) * B_;
  for (int b = 0; b < B_; ++b) {
    RayHit hit;  // the normal is written only on a machine hit, and read only then
    hit.t = rs.t[b];
    hit.on_machine = false;
    hit.ci = rs.ci[b];
    hit.cj = rs.cj[b];
    // A machine in front of the terrain hit (or in a ray that misses the terrain) wins.
    const double t_box = boxes.hit(job.o, rs.dm[b], spec_.min_range_m, std::isnan(hit.t) ? t_max_ : hit.t, rs.cand,
                                   rs.n_cand, rs.cand_up, rs.n_up, b, rs.px, rs.spans, &hit.normal);
    if (t_box < std::numeric_limits<double>::infinity()) {
      hit.t = t_box;
      hit.on_machine = true;
    }
    emitPoint(job.terrain, job.o, dirs_[k0 + b], rs.dm[b], hit, job.noise_key, k0 + b, pts);
  }
}

template <bool kKeep>
void LidarModel::scanChunk(const ScanJob& job, int ch) const {
  const ScanObstacles& boxes = scratch_->obstacles;
  std::vector<PointXYZI>& pts = scratch_->parts[static_cast<std::size_t>(ch)];
  pts.clear();
  const int c0 = ch * columns_per_chunk_, c1 = std::min(C_, c0 + columns_per_chunk_);
  pts.reserve(static_cast<std::size_t>(c1 - c0) * B_);
  RowScratch rs(B_, boxes.size());
  std::size_t used = 0;
  for (int c = c0; c < c1; ++c) {
    // Boxes this row can reach; of those, the ones an upward ray can reach.
    rs.n_cand = rs.n_up = 0;
    if (boxes.size() > 0)
      boxes.row(c, dirs_[static_cast<std::size_t>(c) * B_], rs.cand, rs.n_cand, rs.cand_up, rs.n_up, rs.spans);
    castRow<kKeep>(job, c, rs, used);
    emitRow(job, c, rs, pts);
  }
  scratch_->kept.used[static_cast<std::size_t>(ch)] = used;
}

std::size_t LidarModel::gatherParts(int chunks, std::vector<PointXYZI>& out) const {
  const std::vector<std::vector<PointXYZI>>& parts = scratch_->parts;
  std::size_t total = 0, hits = 0;
  for (int ch = 0; ch < chunks; ++ch) total += parts[static_cast<std::size_t>(ch)].size();
  out.clear();
  out.reserve(total);
  for (int ch = 0; ch < chunks; ++ch) {
    for (const PointXYZI& q : parts[static_cast<std::size_t>(ch)]) {
      if (!std::isnan(q.x)) ++hits;
      out.push_back(q);
    }
  }
  return hits;
}

std::size_t LidarModel::scan(const TruthTerrain& terrain, const Eigen::Isometry3d& T_map_sensor, std::uint64_t noise_key,
                             const Executor* exec, std::vector<PointXYZI>& out,
                             const std::vector<PlacedBox>* obstacles) const {
  const int chunks = (C_ + columns_per_chunk_ - 1) / columns_per_chunk_;
  bool still = false;
  const bool reuse = prepareCasts(terrain, T_map_sensor, exec, still);
  Scratch::Kept& kept = scratch_->kept;
  kept.used.assign(static_cast<std::size_t>(chunks), 0);
  if (static_cast<int>(scratch_->parts.size()) < chunks) scratch_->parts.resize(chunks);
  const ScanJob job{terrain, T_map_sensor.translation(), T_map_sensor.linear(), noise_key, reuse};
  scratch_->obstacles.prepare(obstacles, job.o, job.R, t_max_, camera_ ? &spec_ : nullptr, z_near_,
                              camera_ ? nullptr : &beam_slopes_);
  // Instantiated with and without keeping hits, so a sensor that moves (most LiDAR scans) runs
  // the loop without the kept-hit tests and stores.
  auto work = [&](int ch) {
    if (still) scanChunk<true>(job, ch);
    else scanChunk<false>(job, ch);
  };
  if (exec) exec->forEach(chunks, work);
  else serialForEach(chunks, work);
  kept.scanned = true;
  kept.terrain_id = terrain.instanceId();
  kept.pose = T_map_sensor.matrix();
  if (still) {
    kept.valid = true;
    kept.revision = terrain.revision();
  }
  return gatherParts(chunks, out);
}

}  // namespace terramap::sim
