#pragma once
/// \file
/// Fast exact ray casting of many rays from one origin (one LiDAR scan) against the truth
/// terrain: a per-scan *polar horizon table* tells each ray where it can first touch the
/// surface, and only those stretches are tested cell by cell (TruthTerrain::castCells).
///
/// Why it is exact: the table is indexed by (azimuth bin, horizontal-range bin) around the
/// origin o and holds, over every pyramid block that has any point in that bin, an upper bound
/// of (zmax(block) - o_z) / s, s being the horizontal distance of a block point from o inside
/// the bin. A ray of horizontal slope m = d_z / |d_xy| stays in one azimuth bin; at a point of
/// horizontal distance s in a bin whose bound is < m its height o_z + m s is above every block
/// covering that point, hence above the surface. Such bins are skipped; the others are walked
/// exactly. So `cast` returns the same first hit as TruthTerrain::raycast (to rounding of the
/// per-cell quadratic, ~1e-15 relative), for any tilt of the sensor.
///
/// Azimuths use a pseudo-angle (monotonic in the true angle, no atan2); bins are dilated by a
/// tiny margin and bounds rounded up, so rounding can only make the table more conservative.
#include <terramap/core/parallel.hpp>
#include <terramap/sim/truth_terrain.hpp>

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <vector>

namespace terramap::sim {

class ScanCaster {
 public:
  ScanCaster() = default;

  /// Builds the table for rays from `origin` (map frame, m) reaching at most `max_range_m`
  /// (the ray parameter t, i.e. 3D distance, bounds the horizontal distance). Reuses the
  /// object's buffers, so keep one caster per sensor or per thread. Parts of the table are
  /// built on `exec` (serial if null); the table is a maximum, so it is bit-identical for any
  /// thread count. The terrain must outlive the caster and stay unchanged while casting.
  /// `min_slope` is a lower bound of d_z / |d_xy| over the rays that will be cast (-inf if
  /// unknown): blocks no such ray can descend onto are left out of the table, which keeps
  /// the build cheap near a LiDAR whose lowest beam points 20-30 deg down.
  void build(const TruthTerrain& terrain, const Eigen::Vector3d& origin, double max_range_m,
             double min_slope = -std::numeric_limits<double>::infinity(), const Executor* exec = nullptr);

  /// First intersection of origin + t d (|d| = 1, map frame) with the surface for
  /// t in [t_min, t_max] (t_min >= 0); NaN when it misses or leaves the grid. On a hit the cell is stored in
  /// *cell_i / *cell_j when non-null. Precondition: d_z / |d_xy| >= the build's `min_slope`
  /// (a steeper ray could pass through a block left out of the table). Thread-safe (const).
  double cast(const Eigen::Vector3d& d, double t_min, double t_max, int* cell_i = nullptr,
              int* cell_j = nullptr) const;

  /// False when the ray certainly misses: it does not descend and starts above the highest
  /// point of the terrain. A cheap pre-filter before batching (cast returns NaN for these too).
  bool mayHit(const Eigen::Vector3d& d) const { return d.z() < 0.0 || !(o_.z() > top_); }

  /// What a ray's result depends on: the table row `a` (its azimuth bin) up to range bin `r`
  /// (the table's entries there and the cells under them). A result stays what `cast` returns
  /// as long as the terrain changed nowhere those bins cover (changedRows): the walk reads
  /// nothing else. r = rangeBins() for a miss (the whole row), kAlways for a ray cast without
  /// the table (near-vertical, or beyond the table's reach), whose result is not kept.
  struct RayDep {
    int a = 0, r = 0;
  };
  static constexpr int kAlways = std::numeric_limits<int>::max();

  /// The same for n rays at once (t[k], cell_i[k], cell_j[k] for d[k]; cells are left unset
  /// on a miss). Faster than n calls of `cast`: the first candidate cells of a few rays are
  /// prefetched before any is walked. Results are identical to `cast`.
  /// With `dep`, also what each result depends on (see RayDep and changedRows).
  void castBatch(const Eigen::Vector3d* d, int n, double t_min, double t_max, double* t, int* cell_i,
                 int* cell_j, RayDep* dep = nullptr) const;

  /// For the table as last built, per azimuth row the first range bin that may cover a cell
  /// that changed since the terrain's revision `since` (TruthTerrain::blockRevision), or
  /// kAlways for a row nothing changed under. A result whose RayDep has r < first[a] is then
  /// the same, bit for bit, as a new cast of the same ray from the same origin: the row's
  /// entries up to r and the cells under them are unchanged (a table built from the same origin
  /// over the same terrain size has the same bins). Conservative: whole table blocks count as
  /// changed, widened by a bin on each side.
  void changedRows(std::uint64_t since, std::vector<int>& first) const;

  /// The next builds serve a sparse scan (a few hundred rays, e.g. a single-line scanner at
  /// 25 Hz): a coarser table, cheaper to build; the hits are the same (exact either way).
  void setSparse(bool sparse) { sparse_ = sparse; }

  /// Counters of the last build (for profiling and the docs): table size, blocks inserted.
  int azimuthBins() const { return na_; }
  int rangeBins() const { return nr_; }
  double rangeBinM() const { return ds_; }
  int blockLevel() const { return level_; }

 private:
  /// A ray after its table look-up: where its exact walk starts.
  struct Ray {
    enum Mode { Miss, Direct, Bins } mode = Miss;
    double t0 = 0, t1 = 0, ta = 0, dxy = 0, m = 0;
    double inv_d[2] = {0, 0};  ///< 1 / d.x(), 1 / d.y() (0 where the component is 0), from the grid clip
    int a = 0, r = 0, r_last = 0;
    int dep = kAlways;  ///< RayDep::r of a ray settled by prepare (Miss)
  };
  void prepare(const Eigen::Vector3d& d, double t_min, double t_max, Ray& ray) const;
  void prefetch(const Eigen::Vector3d& d, const Ray& ray) const;
  /// `dep_r`: the last range bin the result depends on (RayDep::r).
  double finish(const Eigen::Vector3d& d, const Ray& ray, int* cell_i, int* cell_j, int& dep_r) const;
  template <bool kDeps>
  void castBatchAs(const Eigen::Vector3d* d, int n, double t_min, double t_max, double* t, int* cell_i,
                   int* cell_j, RayDep* dep) const;
  /// build()'s last step: the group, running and row maxima of bound_ (rows on `exec`).
  void finishTable(const Executor* exec);

  const TruthTerrain* terrain_ = nullptr;
  Eigen::Vector3d o_ = Eigen::Vector3d::Zero();
  int na_ = 0, nr_ = 0, ng_ = 0, level_ = 0;
  double ds_ = 1, inv_ds_ = 1;
  double reach_ = 0;           ///< horizontal reach of the table (m)
  double inv_res_ = 1;         ///< 1 / terrain resolution (prefetch addresses only)
  double top_ = 0;             ///< highest point of the terrain (pyramid root)
  bool covers_grid_ = false;   ///< the table reaches every grid point (max range >= farthest corner)
  bool sparse_ = false;        ///< setSparse
  std::vector<float> bound_;      ///< [a * nr_ + r]: slope bound, -inf where no block
  std::vector<float> group_;      ///< [a * ng_ + g]: max of bound_ over kGroup range bins
  std::vector<float> prefix_;     ///< [a * nr_ + r]: max of bound_ over range bins 0..r
  std::vector<float> row_;        ///< [a]: max over the row
};

}  // namespace terramap::sim
