// Machine–machine contact: separating-axis overlap of the machines' boxes, inelastic push-apart.
#include <terramap/sim/machine_contact.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

namespace terramap::sim {
namespace {

/// A box as the vertical prism over its horizontal projection.
struct Prism {
  std::vector<Eigen::Vector2d> hull;  ///< counter-clockwise
  Eigen::Vector2d centre;
  double radius = 0;                  ///< of the hull about centre
  double z0 = 0, z1 = 0;
};

double cross(const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
}

Prism prismOf(const PlacedBox& b) {
  std::vector<Eigen::Vector2d> pts;
  pts.reserve(8);
  Prism p;
  p.z0 = std::numeric_limits<double>::infinity();
  p.z1 = -p.z0;
  for (int k = 0; k < 8; ++k) {
    const Eigen::Vector3d s((k & 1) ? 1.0 : -1.0, (k & 2) ? 1.0 : -1.0, (k & 4) ? 1.0 : -1.0);
    const Eigen::Vector3d c = b.centre + b.R * s.cwiseProduct(b.half);
    pts.emplace_back(c.x(), c.y());
    p.z0 = std::min(p.z0, c.z());
    p.z1 = std::max(p.z1, c.z());
  }
  // Andrew's monotone chain (8 points).
  std::sort(pts.begin(), pts.end(), [](const Eigen::Vector2d& a, const Eigen::Vector2d& c) {
    return a.x() < c.x() || (a.x() == c.x() && a.y() < c.y());
  });
  std::vector<Eigen::Vector2d> h(16);
  int k = 0;
  for (const auto& q : pts) {
    while (k >= 2 && cross(h[k - 2], h[k - 1], q) <= 0) --k;
    h[k++] = q;
  }
  for (int i = static_cast<int>(pts.size()) - 2, t = k + 1; i >= 0; --i) {
    while (k >= t && cross(h[k - 2], h[k - 1], pts[i]) <= 0) --k;
    h[k++] = pts[i];
  }
  h.resize(std::max(1, k - 1));
  p.hull = std::move(h);
  p.centre = Eigen::Vector2d(b.centre.x(), b.centre.y());
  for (const auto& q : p.hull) p.radius = std::max(p.radius, (q - p.centre).norm());
  return p;
}

void project(const std::vector<Eigen::Vector2d>& hull, const Eigen::Vector2d& axis, double& lo, double& hi) {
  lo = std::numeric_limits<double>::infinity();
  hi = -lo;
  for (const auto& q : hull) {
    const double s = q.dot(axis);
    lo = std::min(lo, s);
    hi = std::max(hi, s);
  }
}

/// Separating-axis test of two convex hulls: the smallest overlap over the edge normals of both
/// (the minimum translation), its normal pointing from a to b; depth <= 0 when separated.
BoxOverlap prismOverlap(const Prism& a, const Prism& b) {
  BoxOverlap best;
  best.depth = std::numeric_limits<double>::infinity();
  for (const Prism* P : {&a, &b}) {
    const std::size_t n = P->hull.size();
    for (std::size_t i = 0; i < n; ++i) {
      const Eigen::Vector2d e = P->hull[(i + 1) % n] - P->hull[i];
      const double len = e.norm();
      if (!(len > 1e-12)) continue;
      Eigen::Vector2d axis(e.y() / len, -e.x() / len);
      double alo, ahi, blo, bhi;
      project(a.hull, axis, alo, ahi);
      project(b.hull, axis, blo, bhi);
      const double o = std::min(ahi, bhi) - std::max(alo, blo);
      if (o <= 0) return BoxOverlap{o, axis};
      if (o < best.depth) {
        best.depth = o;
        best.normal = (0.5 * (blo + bhi) >= 0.5 * (alo + ahi)) ? axis : Eigen::Vector2d(-axis);
      }
    }
  }
  return best;
}

BoxOverlap deepest(const std::vector<Prism>& a, const std::vector<Prism>& b) {
  BoxOverlap best;
  for (const Prism& p : a)
    for (const Prism& q : b) {
      if (p.z1 <= q.z0 || q.z1 <= p.z0) continue;
      const double r = p.radius + q.radius;
      if ((p.centre - q.centre).squaredNorm() >= r * r) continue;
      const BoxOverlap o = prismOverlap(p, q);
      if (o.depth > best.depth) best = o;
    }
  return best;
}

std::vector<Prism> prismsOf(const std::vector<PlacedBox>& boxes) {
  std::vector<Prism> out;
  out.reserve(boxes.size());
  for (const PlacedBox& b : boxes) out.push_back(prismOf(b));
  return out;
}

void shift(std::vector<Prism>& prisms, const Eigen::Vector2d& d) {
  for (Prism& p : prisms) {
    p.centre += d;
    for (auto& q : p.hull) q += d;
  }
}

Eigen::Vector2d heading(const CompactTrackLoader& m) { return {std::cos(m.yaw()), std::sin(m.yaw())}; }

}  // namespace

BoxOverlap deepestOverlap(const std::vector<PlacedBox>& a, const std::vector<PlacedBox>& b) {
  return deepest(prismsOf(a), prismsOf(b));
}

ContactStats resolveMachineContacts(std::vector<ContactBody>& bodies, const TruthTerrain& terrain, int iterations) {
  ContactStats st;
  const std::size_t n = bodies.size();
  if (n < 2) return st;
  // The prisms (hulls) only of machines near another: most steps of most scenarios have none.
  std::vector<std::vector<Prism>> prisms(n);
  std::vector<char> built(n, 0);
  std::vector<Eigen::Vector2d> centre(n);
  std::vector<double> reach(n, 0.0);
  for (std::size_t i = 0; i < n; ++i) {
    const CompactTrackLoader& m = *bodies[i].machine;
    centre[i] = Eigen::Vector2d(m.x(), m.y());
    for (const PlacedBox& b : bodies[i].boxes)
      reach[i] = std::max(reach[i], (b.centre.head<2>() - centre[i]).norm() + b.radius);
  }
  auto prismsFor = [&](std::size_t i) -> std::vector<Prism>& {
    if (!built[i]) {
      prisms[i] = prismsOf(bodies[i].boxes);
      built[i] = 1;
    }
    return prisms[i];
  };
  // A separation slightly beyond the overlap, so the pair does not touch again through rounding
  // in the next step's test (0.1 mm: far below anything a sensor resolves).
  constexpr double kSlop = 1e-4;
  for (int it = 0; it < iterations; ++it) {
    bool any = false;
    for (std::size_t i = 0; i < n; ++i)
      for (std::size_t j = i + 1; j < n; ++j) {
        const double r = reach[i] + reach[j];
        if ((centre[i] - centre[j]).squaredNorm() >= r * r) continue;  // broad phase
        const BoxOverlap o = deepest(prismsFor(i), prismsFor(j));
        if (!(o.depth > 0)) continue;
        any = true;
        ++st.contacts;
        st.max_depth_m = std::max(st.max_depth_m, o.depth);
        CompactTrackLoader& A = *bodies[i].machine;
        CompactTrackLoader& B = *bodies[j].machine;
        const Eigen::Vector2d& nv = o.normal;
        const Eigen::Vector2d fa = heading(A), fb = heading(B);
        const double ca = fa.dot(nv), cb = fb.dot(nv);
        const double ma = A.spec().mass_kg, mb = B.spec().mass_kg;
        const double wa = ca * ca / ma, wb = cb * cb / mb;
        const double d = o.depth + kSlop;
        // Approach speed along n (> 0: closing) and the inelastic impulse that removes it.
        const double u = A.speed() * ca - B.speed() * cb;
        Eigen::Vector2d da = Eigen::Vector2d::Zero(), db = Eigen::Vector2d::Zero();
        double va = A.speed(), vb = B.speed();
        if (std::abs(ca) >= 0.5 || std::abs(cb) >= 0.5) {
          // Each along its own heading, shares minimising the mass-weighted motion (the
          // position counterpart of the impulse below).
          const double lambda = d / (wa + wb);
          da = fa * (-lambda * ca / ma);
          db = fb * (lambda * cb / mb);
          if (u > 0) {
            const double J = u / (wa + wb);
            va -= J * ca / ma;
            vb += J * cb / mb;
          }
        } else {
          // Side-on on both sides: slid apart sideways by the mass ratio, approach stopped.
          da = nv * (-d * mb / (ma + mb));
          db = nv * (d * ma / (ma + mb));
          if (u > 0) {
            va = ca * A.speed() > 0 ? 0.0 : va;
            vb = cb * B.speed() < 0 ? 0.0 : vb;
          }
        }
        const Eigen::Vector2d pa(A.x(), A.y()), pb(B.x(), B.y());
        A.contactMove(da, va, terrain);
        B.contactMove(db, vb, terrain);
        // What the machines really moved (a move off the terrain is refused).
        const Eigen::Vector2d ma_d = Eigen::Vector2d(A.x(), A.y()) - pa, mb_d = Eigen::Vector2d(B.x(), B.y()) - pb;
        shift(prisms[i], ma_d);
        shift(prisms[j], mb_d);
        centre[i] += ma_d;
        centre[j] += mb_d;
        for (PlacedBox& b : bodies[i].boxes) b.centre.head<2>() += ma_d;
        for (PlacedBox& b : bodies[j].boxes) b.centre.head<2>() += mb_d;
      }
    if (!any) break;
  }
  return st;
}

}  // namespace terramap::sim
