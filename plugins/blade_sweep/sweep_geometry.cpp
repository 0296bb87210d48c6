// Swept-volume mesh and its exact intersection with vertical lines through cell centres.
#include "blade_sweep.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace terramap::plugins {

namespace {
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Continuous grid coordinates: u grows towards -x, v towards -y, in cells; cell (i, j) covers
// [i, i+1) x [j, j+1) and its centre is (i + 0.5, j + 0.5) (geometry.hpp convention).
struct GridFrame {
  double xmax, ymax, inv_res;
  explicit GridFrame(const Geometry& g)
      : xmax(g.center().x() + 0.5 * g.length().x()),
        ymax(g.center().y() + 0.5 * g.length().y()),
        inv_res(1.0 / g.resolution()) {}
  double u(double x) const { return (xmax - x) * inv_res; }
  double v(double y) const { return (ymax - y) * inv_res; }
};
}  // namespace

std::array<Eigen::Vector3d, 4> bladeCorners(const Eigen::Isometry3d& T, const BladeGeometry& g) {
  const double hw = 0.5 * g.width_m;
  return {T * Eigen::Vector3d(0, -hw, 0), T * Eigen::Vector3d(0, hw, 0), T * Eigen::Vector3d(0, hw, g.height_m),
          T * Eigen::Vector3d(0, -hw, g.height_m)};
}

std::vector<Triangle> sweptVolumeMesh(const std::vector<Eigen::Isometry3d>& stations, const BladeGeometry& g) {
  std::vector<Triangle> tris;
  if (stations.empty()) return tris;
  tris.reserve(stations.size() * 2 + (stations.size() - 1) * 8);
  std::vector<std::array<Eigen::Vector3d, 4>> corners;
  corners.reserve(stations.size());
  for (const auto& T : stations) corners.push_back(bladeCorners(T, g));
  for (const auto& c : corners) {
    tris.push_back({c[0], c[1], c[2]});
    tris.push_back({c[0], c[2], c[3]});
  }
  for (size_t s = 0; s + 1 < corners.size(); ++s) {
    const auto& A = corners[s];
    const auto& B = corners[s + 1];
    for (int k = 0; k < 4; ++k) {
      const int k1 = (k + 1) % 4;
      tris.push_back({A[k], A[k1], B[k1]});
      tris.push_back({A[k], B[k1], B[k]});
    }
  }
  return tris;
}

std::vector<Triangle> edgeSweepMesh(const std::vector<Eigen::Isometry3d>& stations, const BladeGeometry& g) {
  std::vector<Triangle> tris;
  for (size_t s = 0; s + 1 < stations.size(); ++s) {
    const auto A = bladeCorners(stations[s], g);
    const auto B = bladeCorners(stations[s + 1], g);
    tris.push_back({A[0], A[1], B[1]});
    tris.push_back({A[0], B[1], B[0]});
  }
  return tris;
}

std::vector<Eigen::Isometry3d> meshStations(const std::vector<Eigen::Isometry3d>& history, int max_stations,
                                            double max_rotation_rad) {
  std::vector<Eigen::Isometry3d> picked;
  const size_t n = history.size();
  if (n == 0) return picked;
  const size_t m = std::max<size_t>(2, static_cast<size_t>(std::max(2, max_stations)));
  if (n <= m) {
    picked = history;
  } else {
    for (size_t k = 0; k < m; ++k) picked.push_back(history[(k * (n - 1) + (m - 1) / 2) / (m - 1)]);
    picked.front() = history.front();
    picked.back() = history.back();
  }
  std::vector<Eigen::Isometry3d> out;
  out.push_back(picked.front());
  for (size_t k = 1; k < picked.size(); ++k) {
    const Eigen::Isometry3d& A = picked[k - 1];
    const Eigen::Isometry3d& B = picked[k];
    const Eigen::Quaterniond qa(A.linear()), qb(B.linear());
    const double angle = qa.angularDistance(qb);
    int sub = 1;
    if (max_rotation_rad > 0 && angle > max_rotation_rad) sub = std::min(64, static_cast<int>(std::ceil(angle / max_rotation_rad)));
    for (int s = 1; s < sub; ++s) {
      const double t = static_cast<double>(s) / sub;
      Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
      T.linear() = qa.slerp(t, qb).toRotationMatrix();
      T.translation() = (1 - t) * A.translation() + t * B.translation();
      out.push_back(T);
    }
    out.push_back(B);
  }
  return out;
}

CellRect footprintBlock(const std::vector<Triangle>& tris, const Geometry& geo) {
  CellRect b;
  if (tris.empty()) return b;
  const GridFrame f(geo);
  double umin = std::numeric_limits<double>::infinity(), umax = -umin, vmin = umin, vmax = -umin;
  for (const auto& t : tris)
    for (const Eigen::Vector3d* p : {&t.a, &t.b, &t.c}) {
      umin = std::min(umin, f.u(p->x()));
      umax = std::max(umax, f.u(p->x()));
      vmin = std::min(vmin, f.v(p->y()));
      vmax = std::max(vmax, f.v(p->y()));
    }
  if (!std::isfinite(umin) || !std::isfinite(umax) || !std::isfinite(vmin) || !std::isfinite(vmax)) return b;
  // Cells whose centres i + 0.5 lie in [umin, umax], with one cell of slack for rounding.
  const double lim = 4.0 * std::max(geo.size().x(), geo.size().y());
  const int i0 = static_cast<int>(std::floor(std::max(umin - 0.5, -lim))) - 1;
  const int i1 = static_cast<int>(std::floor(std::min(umax - 0.5, lim))) + 1;
  const int j0 = static_cast<int>(std::floor(std::max(vmin - 0.5, -lim))) - 1;
  const int j1 = static_cast<int>(std::floor(std::min(vmax - 0.5, lim))) + 1;
  b.r0 = std::max(0, i0);
  b.c0 = std::max(0, j0);
  b.rows = std::min(geo.size().x() - 1, i1) - b.r0 + 1;
  b.cols = std::min(geo.size().y() - 1, j1) - b.c0 + 1;
  if (b.rows < 0) b.rows = 0;
  if (b.cols < 0) b.cols = 0;
  return b;
}

void lowestIntersection(const std::vector<Triangle>& tris, const Geometry& geo, const CellRect& block,
                        std::vector<double>& z_low, const Executor& ex) {
  z_low.assign(static_cast<size_t>(std::max<long>(0, static_cast<long>(block.rows) * block.cols)), kNaN);
  if (block.empty() || tris.empty()) return;
  const GridFrame f(geo);
  // Triangles in grid coordinates with precomputed barycentric terms; vertical ones dropped.
  struct GT {
    double ua, va, ub, vb, uc, vc, za, zb, zc, inv_area;
    double umin, umax, vmin, vmax;
  };
  std::vector<GT> gts;
  gts.reserve(tris.size());
  for (const auto& t : tris) {
    GT g{f.u(t.a.x()), f.v(t.a.y()), f.u(t.b.x()), f.v(t.b.y()), f.u(t.c.x()), f.v(t.c.y()),
         t.a.z(), t.b.z(), t.c.z(), 0, 0, 0, 0, 0};
    const double area = (g.ub - g.ua) * (g.vc - g.va) - (g.uc - g.ua) * (g.vb - g.va);
    // Projected area below 1e-9 cell^2: the triangle stands vertical (or is a sliver).
    if (!(std::abs(area) > 1e-9)) continue;
    g.inv_area = 1.0 / area;
    g.umin = std::min({g.ua, g.ub, g.uc});
    g.umax = std::max({g.ua, g.ub, g.uc});
    g.vmin = std::min({g.va, g.vb, g.vc});
    g.vmax = std::max({g.va, g.vb, g.vc});
    gts.push_back(g);
  }
  // Tolerance on barycentric coordinates: a centre exactly on a shared edge belongs to both
  // triangles (the min is the same), a centre on the outer boundary counts as inside.
  constexpr double kEps = 1e-12;
  const int bands = std::min(block.rows, std::max(1, ex.threads() * 4));
  ex.forEach(bands, [&](int band) {
    const int r0 = block.rows * band / bands, r1 = block.rows * (band + 1) / bands;
    const double ub0 = block.r0 + r0 + 0.5, ub1 = block.r0 + r1 - 0.5;
    for (const GT& g : gts) {
      if (g.umax < ub0 - 1e-9 || g.umin > ub1 + 1e-9) continue;
      const int ia = std::max(block.r0 + r0, static_cast<int>(std::ceil(g.umin - 0.5 - 1e-9)));
      const int ib = std::min(block.r0 + r1 - 1, static_cast<int>(std::floor(g.umax - 0.5 + 1e-9)));
      const int ja = std::max(block.c0, static_cast<int>(std::ceil(g.vmin - 0.5 - 1e-9)));
      const int jb = std::min(block.c0 + block.cols - 1, static_cast<int>(std::floor(g.vmax - 0.5 + 1e-9)));
      for (int i = ia; i <= ib; ++i) {
        const double pu = i + 0.5;
        for (int j = ja; j <= jb; ++j) {
          const double pv = j + 0.5;
          const double w0 = ((g.ub - pu) * (g.vc - pv) - (g.uc - pu) * (g.vb - pv)) * g.inv_area;
          const double w1 = ((g.uc - pu) * (g.va - pv) - (g.ua - pu) * (g.vc - pv)) * g.inv_area;
          const double w2 = 1.0 - w0 - w1;
          if (w0 < -kEps || w1 < -kEps || w2 < -kEps) continue;
          const double z = w0 * g.za + w1 * g.zb + w2 * g.zc;
          double& zl = z_low[static_cast<size_t>(block.local(i, j))];
          if (!(zl <= z)) zl = z;  // NaN-aware min
        }
      }
    }
  });
}

double bladeAngle(const Eigen::Isometry3d& T, const Eigen::Vector2d& t_hat) {
  const Eigen::Vector3d p(t_hat.x(), t_hat.y(), 0.0);
  const Eigen::Vector3d q = p.cross(Eigen::Vector3d::UnitZ());  // normal of the vertical slice plane
  const Eigen::Vector3d n3 = T.linear().col(0);
  Eigen::Vector3d v = q.cross(n3);  // the face's line in the slice plane
  if (v.norm() < 1e-9) return kNaN;
  if (v.z() < 0) v = -v;
  return std::atan2(v.z(), -(v.x() * p.x() + v.y() * p.y()));
}

}  // namespace terramap::plugins
