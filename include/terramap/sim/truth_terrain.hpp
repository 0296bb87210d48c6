#pragma once
/// \file
/// The simulator's ground-truth terrain: a fine regular grid of height *nodes* (node (i, j) at
/// map position origin + (i, j) * resolution, i along x, j along y) with bilinear interpolation
/// between nodes. Independent of the mapper's LayeredMap on purpose: it is the reference the
/// mapper is measured against.
///
/// Each node stores three thicknesses (metres, double):
///  - U: height of the undisturbed (bank) soil surface,
///  - Lv: thickness of loose soil lying on top (surface H = U + Lv),
///  - Lc: the bank-equivalent thickness of that loose soil (Lc = Lv / swell of its origin).
/// Soil mass is proportional to sum(U + Lc) * res^2 (relative to any datum) and every change the
/// simulator makes moves (U, Lv, Lc) so that sum is conserved (tested).
///
/// Ray casting uses a max-height pyramid (quadtree of 2x2 node blocks) so rays skip empty
/// space; const members (ray casting included) are thread-safe; mutators are not (the simulator
/// mutates between scans, then calls `refreshPyramid` over the changed nodes before casting).
#include <terramap/sim/node_tiles.hpp>

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace terramap::sim {

/// A raster DEM read from disk: heights at cell centres, NaN = no data, row 0 = south (y min).
struct DemGrid {
  double x0_m = 0, y0_m = 0;  ///< centre of cell (0, 0) (south-west)
  double cell_m = 1;
  int nx = 0, ny = 0;
  std::vector<double> z;      ///< z[j * nx + i]
  /// Bilinear height at (x, y); NaN outside the cell-centre hull or next to a no-data cell.
  double heightAt(double x, double y) const;
};

/// Reads an ESRI ASCII grid (.asc: ncols, nrows, xllcorner|xllcenter, yllcorner|yllcenter,
/// cellsize, optional NODATA_value, then rows north to south).
/// \throws InputError naming the file and line on any malformed header or value.
DemGrid readEsriAscii(const std::string& path);

class TruthTerrain {
 public:
  /// \throws std::invalid_argument for non-positive resolution or fewer than 2x2 nodes.
  TruthTerrain(double origin_x_m, double origin_y_m, double resolution_m, int nx, int ny,
               double height_m = 0.0);

  int nx() const { return nx_; }
  int ny() const { return ny_; }
  double resolution() const { return res_; }
  double originX() const { return ox_; }
  double originY() const { return oy_; }
  double maxX() const { return ox_ + (nx_ - 1) * res_; }
  double maxY() const { return oy_ + (ny_ - 1) * res_; }
  std::size_t index(int i, int j) const { return static_cast<std::size_t>(j) * nx_ + i; }
  bool inside(int i, int j) const { return i >= 0 && j >= 0 && i < nx_ && j < ny_; }
  Eigen::Vector2d nodePosition(int i, int j) const { return {ox_ + i * res_, oy_ + j * res_}; }

  /// Surface height H = U + Lv of a node.
  double height(int i, int j) const { return h_[index(i, j)]; }
  double undisturbed(int i, int j) const { return u_[index(i, j)]; }
  double loose(int i, int j) const { return lv_[index(i, j)]; }
  double looseBank(int i, int j) const { return lc_[index(i, j)]; }
  /// Initial surface height (soil layers by depth are measured from it).
  double initialHeight(int i, int j) const { return h0_[index(i, j)]; }

  /// Sets the undisturbed height and clears loose soil (terrain construction only).
  void setUndisturbed(int i, int j, double h);
  /// Records the current surface as the initial surface (call once after construction).
  void captureInitial();

  // Mass-moving primitives used by the deformation model (no pyramid refresh).
  /// Removes the layer [z_lo, z_hi] ∩ column from node (i, j). Returns the removed bank-equivalent
  /// thickness split into (undisturbed part, loose part's Lv, loose part's Lc).
  struct Removed { double bank_u = 0, loose_v = 0, loose_c = 0; };
  Removed removeBetween(int i, int j, double z_lo, double z_hi);
  /// Adds loose soil: Lv += v, Lc += c.
  void addLoose(int i, int j, double v, double c);
  /// Presses the surface of node (i, j) down by dz >= 0 (a track's sinkage): loose soil first
  /// compacts towards its bank density (Lv shrinks, Lc and so the mass stay), the rest is bank
  /// soil compacted beyond its in-situ density (U drops; its volume is added to
  /// compactedVolume(), so bankVolume() + lostVolume() + compactedVolume() stays constant).
  void compact(int i, int j, double dz);
  /// Bank volume pressed out of the terrain by compact() (m^3): the mass it had is still there,
  /// denser.
  double compactedVolume() const { return compacted_m3_; }
  /// Bank thickness compact() has pressed out of U at a point (m, >= 0; bilinear between nodes,
  /// 0 where nothing was pressed, NaN off the grid): U + pressed is the bank surface as only the
  /// tools left it (an evaluation tells a blade's cut from a track's rut with it). Not carried
  /// by capturePatch / applyPatch (the LiDAR view does not need it).
  double pressedAt(double x, double y) const;
  /// Moves a loose thickness dv (<= Lv) from a to b keeping a's Lc/Lv ratio.
  void moveLoose(int ia, int ja, int ib, int jb, double dv) { moveLooseAt(index(ia, ja), index(ib, jb), dv); }
  /// The same between nodes given by index(i, j) (the relaxation's inner loop has them).
  void moveLooseAt(std::size_t a, std::size_t b, double dv) {
    // Inline: the relaxation and the spoil settling call it for every moving edge.
    if (!(dv > 0.0) || lv_[a] <= 0.0) return;
    dv = std::min(dv, lv_[a]);
    const double dc = (dv == lv_[a]) ? lc_[a] : dv * (lc_[a] / lv_[a]);
    lv_[a] -= dv;
    lc_[a] -= dc;
    lv_[b] += dv;
    lc_[b] += dc;
    h_[a] = u_[a] + lv_[a];
    h_[b] = u_[b] + lv_[b];
    loose_run_[b >> kLooseRunShift] = 1;
  }
  /// The first node i in [a, b] of row j with loose soil (Lv > 0), b + 1 if none; the last
  /// one, a - 1 if none. The same node as testing every Lv in turn, but runs of nodes that never
  /// held loose soil since construction are skipped on a flag per run: the relaxation looks for
  /// the loose soil in a box of ~10^4 nodes around each blade every step, where most nodes have
  /// none, and reading their Lv was most of its memory traffic.
  int firstLoose(int j, int a, int b) const;
  int lastLoose(int j, int a, int b) const;

  /// Bilinear surface height at a map position; NaN outside the grid.
  double heightAt(double x, double y) const;
  double undisturbedAt(double x, double y) const;
  /// Bilinear loose thickness Lv and its bank equivalent Lc; NaN outside.
  double looseAt(double x, double y) const { return bilinear(lv_, x, y); }
  double looseBankAt(double x, double y) const { return bilinear(lc_, x, y); }
  /// Nearest node to a map position (may be outside the grid: check inside()).
  void nearestNode(double x, double y, int& i, int& j) const {
    i = static_cast<int>(std::floor((x - ox_) / res_ + 0.5));
    j = static_cast<int>(std::floor((y - oy_) / res_ + 0.5));
  }
  double initialHeightAt(double x, double y) const;
  /// Surface gradient (dH/dx, dH/dy) of the bilinear surface; NaN outside.
  Eigen::Vector2d gradientAt(double x, double y) const;

  /// First intersection of the ray o + t d (|d| = 1) with the bilinear surface for
  /// t in [t_min, t_max]; NaN when it misses or leaves the grid. Exact for the bilinear
  /// surface (per-cell quadratic), so a plane is hit exactly. Thread-safe.
  double raycast(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min, double t_max) const;
  /// Same surface test restricted to the cells the ray crosses for t in [t_a, t_b], walked in
  /// order with a 2D DDA (no pyramid descent): the fast path once a caller knows the ray is
  /// clear of the surface before t_a (see ScanCaster). [t_a, t_b] must lie inside the grid's
  /// xy extent (clip first). Returns NaN when no hit; on a hit stores the cell (cell (ci, cj)
  /// spans nodes ci..ci+1, cj..cj+1) in *cell_i / *cell_j when non-null. Thread-safe.
  double castCells(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_a, double t_b,
                   int* cell_i = nullptr, int* cell_j = nullptr) const;
  /// The same with the ray's reciprocals 1 / d.x() and 1 / d.y() given (0 where that component
  /// is 0), as a caller that clipped the ray to the grid already has them: bit-identical, two
  /// divisions fewer per ray.
  double castCells(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double inv_dx, double inv_dy, double t_a,
                   double t_b, int* cell_i, int* cell_j) const;
  /// Clips [t0, t1] to the part of the ray o + t d whose xy lies in the grid extent; false if
  /// nothing is left.
  bool clipToGrid(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double& t0, double& t1) const;
  /// Surface gradient (dH/dx, dH/dy) of one cell's bilinear patch at map (x, y) (which should
  /// lie in or on that cell): the normal at a ray hit without re-locating the cell. Inline: a
  /// scan calls it for every point it returns.
  Eigen::Vector2d cellGradient(int ci, int cj, double x, double y) const {
    const double u = (x - (ox_ + ci * res_)) / res_, v = (y - (oy_ + cj * res_)) / res_;
    const std::size_t k = index(ci, cj);
    const double z00 = h_[k], z10 = h_[k + 1], z01 = h_[k + nx_], z11 = h_[k + nx_ + 1];
    const double c = z00 - z10 - z01 + z11;
    return {((z10 - z00) + c * v) / res_, ((z01 - z00) + c * u) / res_};
  }

  /// Max-height pyramid, read-only (ScanCaster builds on it). Level 0 = cells ((nx-1) x
  /// (ny-1)); level l block (bx, by) covers cells [bx 2^l, (bx+1) 2^l) x [by 2^l, (by+1) 2^l)
  /// (clipped). Values are upper bounds of the bilinear surface over the block, rounded up to
  /// float. Valid after refreshPyramid() over every changed node.
  int pyramidLevels() const { return static_cast<int>(levels_.size()); }
  int pyramidWidth(int level) const { return levels_[level].w; }
  int pyramidHeight(int level) const { return levels_[level].h; }
  const float* pyramidMax(int level) const { return levels_[level].zmax.data(); }

  /// Brute-force reference (marches every cell along the ray, no pyramid): tests only.
  double raycastReference(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min,
                          double t_max) const;

  /// Rebuilds the max pyramid over the node box [i0, i1] x [j0, j1] (clamped), or all. Not
  /// while rays are being cast.
  void refreshPyramid(int i0, int j0, int i1, int j1);
  void refreshPyramid() { refreshPyramid(0, 0, nx_ - 1, ny_ - 1); }

  /// Which parts changed, for whoever keeps something derived from the terrain: an episode's
  /// snapshots rewrite only the chunks that changed, a ray caster that keeps hits from an earlier
  /// scan re-casts only the rays over changed cells (LidarModel). Every refreshPyramid stamps the
  /// blocks of kRevisionBlock x kRevisionBlock *cells* (cell (ci, cj) spans nodes ci..ci+1,
  /// cj..cj+1; the blocks are the pyramid's level-4 blocks) that touch its node box with a new
  /// revision; since every change must be followed by a refreshPyramid over it (the contract
  /// above, which the simulator keeps before any scan and in Simulator::truth()), a block whose
  /// stamp is <= r holds the cells (heights and pyramid maxima) it held when revision() was r.
  /// Conservative: a whole block counts as changed when any of its cells may have (revision 0 =
  /// the terrain as constructed). Not thread-safe against refreshPyramid.
  static constexpr int kRevisionBlock = 16;
  std::uint64_t revision() const { return revision_; }
  /// Whether the node box [i0, i1] x [j0, j1] (inclusive, clamped) may differ from what it was
  /// when revision() returned r (the blocks of the cells touching it).
  bool changedSince(std::uint64_t r, int i0, int j0, int i1, int j1) const;
  /// The stamps themselves, row-major, revisionWidth() blocks per row.
  int revisionWidth() const { return rev_w_; }
  int revisionHeight() const { return rev_h_; }
  std::uint64_t blockRevision(int bx, int by) const { return block_rev_[static_cast<std::size_t>(by) * rev_w_ + bx]; }
  /// Unique per object and per state copied into it: a copy, a move or an assignment gets a
  /// new id, so (instanceId(), revision()) names the contents of the grid for any cache.
  std::uint64_t instanceId() const { return id_.value; }

  /// Sum over nodes of (U + Lc) * res^2, relative to `datum` (m^3 of bank soil).
  double bankVolume(double datum = 0.0) const;
  /// Bank volume that left the grid (deposits that would land outside), m^3.
  double lostVolume() const { return lost_m3_; }
  void addLost(double m3) { lost_m3_ += m3; }

  /// The state of a node box [i0, i1] x [j0, j1] (inclusive) at one instant: what another
  /// copy of the terrain needs to catch up with the changes made inside that box (the
  /// simulator's LiDAR view follows its physics terrain this way). Units as the node arrays.
  struct Patch {
    int i0 = 0, j0 = 0, i1 = -1, j1 = -1;
    /// Row-major over the box (H = U + Lv is derived). They may be longer than the box (a
    /// reused patch keeps its largest size, so refilling it never zero-fills): the first
    /// nodes() entries are the patch.
    std::vector<double> u, lv, lc;
    double lost_m3 = 0, compacted_m3 = 0;
    std::size_t nodes() const {
      return i1 < i0 || j1 < j0 ? 0 : static_cast<std::size_t>(i1 - i0 + 1) * static_cast<std::size_t>(j1 - j0 + 1);
    }
  };
  /// Copies the box (clamped to the grid) and the lost volume into `out` (reusing its buffers,
  /// which only grow).
  void capturePatch(int i0, int j0, int i1, int j1, Patch& out) const;
  /// Overwrites the patch's box with its values (bit for bit; H recomputed as U + Lv, as every
  /// mutator keeps it) and sets the lost volume. The
  /// pyramid is not refreshed: call refreshPyramid over the box before casting. The terrain
  /// must have the grid the patch was captured on. Not thread-safe.
  void applyPatch(const Patch& p);

  const std::vector<double>& undisturbedData() const { return u_; }
  const std::vector<double>& looseData() const { return lv_; }
  const std::vector<double>& looseBankData() const { return lc_; }
  /// Surface H = U + Lv per node (kept equal to the sum, bit for bit, by every mutator).
  const std::vector<double>& heightData() const { return h_; }

 private:
  double cellHit(int ci, int cj, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t0,
                 double t1) const;
  double cellHitZ(int ci, int cj, double z00, double z10, double z01, double z11, const Eigen::Vector3d& o,
                  const Eigen::Vector3d& d, double t0, double t1) const;
  // Defined here so the physics' many surface look-ups inline it. `node(i, j)` is the value at
  // node (i, j); NaN off the grid.
  template <typename Node>
  double bilinearAt(double x, double y, Node node) const {
    const double fx = (x - ox_) / res_, fy = (y - oy_) / res_;
    if (!(fx >= 0 && fy >= 0 && fx <= nx_ - 1 && fy <= ny_ - 1)) return std::numeric_limits<double>::quiet_NaN();
    const int i = std::min(static_cast<int>(fx), nx_ - 2), j = std::min(static_cast<int>(fy), ny_ - 2);
    const double u = fx - i, v = fy - j;
    return (1 - u) * (1 - v) * node(i, j) + u * (1 - v) * node(i + 1, j) + (1 - u) * v * node(i, j + 1) +
           u * v * node(i + 1, j + 1);
  }
  double bilinear(const std::vector<double>& a, double x, double y) const {
    return bilinearAt(x, y, [this, &a](int i, int j) { return a[index(i, j)]; });
  }
  double nodeMaxCell(int ci, int cj) const;
  /// The cells [c0, c1] x [r0, r1] touching the node box [i0, i1] x [j0, j1] (either corner
  /// order, clamped); false if there are none.
  bool cellsTouching(int i0, int j0, int i1, int j1, int& c0, int& r0, int& c1, int& r1) const;

  double ox_, oy_, res_;
  int nx_, ny_;
  std::vector<double> u_, lv_, lc_;
  // Surface U + Lv, stored once more so ray casting touches one array (two cache lines per
  // cell instead of four): memory latency, not arithmetic, bounds a LiDAR scan.
  std::vector<double> h_;
  std::vector<float> h0_;
  // Per run of 2^kLooseRunShift consecutive nodes (of the row-major arrays, so a run may span
  // two rows): 0 while no node of the run has held loose soil, 1 once one may have (set by every
  // mutator that can make an Lv positive, never cleared: firstLoose / lastLoose skip 0 runs).
  static constexpr int kLooseRunShift = 3;
  std::vector<std::uint8_t> loose_run_;
  // Pyramid of max surface heights over *cells* (cell (ci, cj) spans nodes ci..ci+1).
  // Level 0 = cells (nx-1) x (ny-1); level l covers 2^l x 2^l cells. Stored conservatively
  // (rounded up to float).
  struct Level { int w = 0, h = 0; std::vector<float> zmax; };
  std::vector<Level> levels_;
  std::uint64_t revision_ = 0;
  int rev_w_ = 0, rev_h_ = 0;              ///< revision blocks per row, per column
  std::vector<std::uint64_t> block_rev_;  ///< per revision block, the revision of its last refresh
  /// A fresh id on construction, copy, move and assignment (instanceId()).
  struct InstanceId {
    std::uint64_t value;
    InstanceId() : value(next()) {}
    InstanceId(const InstanceId&) : value(next()) {}
    InstanceId& operator=(const InstanceId&) {
      value = next();
      return *this;
    }
    static std::uint64_t next();
  } id_;
  double lost_m3_ = 0.0;
  double compacted_m3_ = 0.0;
  NodeTiles<double> pressed_;  ///< per node, what compact() took from U (tiles allocated where it did)
};

}  // namespace terramap::sim
