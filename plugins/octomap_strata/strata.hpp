#pragma once
/// \file
/// Subsurface soil memory (ALGORITHMS.md §K): an OctoMap tree whose voxels hold what the soil
/// estimator learned about the soil a blade removed, by depth, and a per-column prediction of
/// the soil still below the surface.
///
/// Frames and units: the map frame (x, y horizontal, z up), metres; soil vectors in
/// soil::SoilParam order [c, φ, c_a, δ, γ] in SI units (Pa, rad, Pa, rad, N/m³), variances in
/// their squares. NaN means "unknown" and is never replaced by a made-up value.
///
/// Model. A *column* is one voxel-wide vertical stack (x, y at the voxel resolution). It holds
///  - `top`: the bank surface (undisturbed soil, no loose) as far as the strata know it: the
///    lowest height a blade's edge has cut the column to; NaN until a sweep first cuts it;
///  - `initial`: the bank surface when a sweep first cut it (depths below it are the strata's
///    depths), taken from the sweep's fitted surface line at the cell;
///  - an inherited belief, anchored at the surface the last sweep that removed soil from the
///    column left (`anchor`): that sweep's estimate, filtered with the earlier ones (each carried
///    down to the new anchor with its variance inflated by exp(Δz / L)) unless
///    `filter_inheritance` is off.
/// Removed soil: a sweep removes, in every column it cut, the voxels whose centres lie between
/// the new surface (the swept volume's bottom, SweepMaskCell::sv_bottom_m) and `top`. When the
/// sweep's estimate arrives (it is published later, SoilEstimateRecord), those voxels take the
/// product of the prior and the estimate, N(μ, σ²) = prior × N(μ̂, σ̂²) (the estimate as is
/// with StrataConfig::use_prior off). Until then, and for good when the estimate is invalid or
/// never comes, they hold the belief predicted for them before the cut (kind Predicted).
/// Below the surface: soilAt(x, y, z) under `top` is the inherited estimate with its variance
/// inflated by depth below the anchor, N(μ̂, σ̂² · exp((anchor − z) / L)) with L =
/// `inflation_depth_m` (times the prior with StrataConfig::prior_below); a column no sweep cut
/// keeps the prior. The soil above (removed) is the best guess for the soil below, with a
/// confidence that fades with depth.
///
/// Storage: only removed voxels are stored in the tree (the prediction below is a closed form
/// of the column), so memory grows with the volume cut, not with the site; uniform regions
/// (eight children with equal beliefs, e.g. one sweep's slab) are pruned into their parent.
/// Columns outside the configured extent are ignored and counted.
///
/// Threading: const methods may run concurrently with each other (OctoMap's search is
/// read-only); any non-const call needs exclusive access. Not bit-dependent on threads: the
/// class itself is sequential.
#include <terramap/soil/soil_parameters.hpp>

#include <octomap/AbstractOcTree.h>
#include <octomap/OcTreeBaseImpl.h>
#include <octomap/OcTreeDataNode.h>

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <map>
#include <string>
#include <unordered_map>
#include <vector>

namespace terramap::strata {

using SoilVector = soil::SoilParamVector;

/// What a stored voxel holds: the belief about the soil that was removed from it.
struct VoxelBelief {
  enum Kind : std::uint8_t { kNone = 0, kEstimated = 1, kPredicted = 2 };
  std::array<float, soil::kSoilParamCount> mean{};
  std::array<float, soil::kSoilParamCount> var{};
  /// The slab of the sweep that removed this voxel, in its column (map z, m): from `top` (the
  /// column's surface before the sweep) down to `bottom` (the surface it left). A sweep's
  /// estimate is of that slab, which need not end on voxel faces: changeHeightAt places a change
  /// inside a voxel by them. Every voxel of the slab holds them, so a flat cut's slab stays
  /// uniform and prunes. NaN only in a default-constructed belief (Strata writes both).
  float top = std::numeric_limits<float>::quiet_NaN();
  float bottom = std::numeric_limits<float>::quiet_NaN();
  std::uint8_t kind = kNone;  ///< kEstimated: a sweep's estimate; kPredicted: none arrived
  std::uint8_t pad[3] = {0, 0, 0};  // written to .ot files as bytes: keep them defined
  bool operator==(const VoxelBelief& o) const;
};

class StrataNode : public octomap::OcTreeDataNode<VoxelBelief> {
 public:
  StrataNode() = default;
  explicit StrataNode(const VoxelBelief& v) : octomap::OcTreeDataNode<VoxelBelief>(v) {}
};

/// The OctoMap tree of removed voxels. Its `.ot` files carry the id "TerramapStrataTree";
/// they are read back by Strata::load (OctoMap's registry is not used: a plugin module may be
/// unloaded while the registry still points into it).
class StrataTree : public octomap::OcTreeBaseImpl<StrataNode, octomap::AbstractOcTree> {
 public:
  explicit StrataTree(double resolution);
  StrataTree* create() const override { return new StrataTree(resolution); }
  std::string getTreeType() const override { return "TerramapStrataTree"; }
  /// Sets the leaf at `key` (creating its path, expanding a pruned parent on the way).
  void setLeaf(const octomap::OcTreeKey& key, const VoxelBelief& value);
  /// Prunes the ancestors of the leaf at `key`, bottom up, while they are collapsible: the
  /// part of prune() a write can have changed, in O(depth) instead of the whole tree.
  void pruneAbove(const octomap::OcTreeKey& key);
  /// Key of the cell whose lower corner is at 0 (keys are offset by it).
  unsigned int keyOffset() const { return tree_max_val; }
};

/// Which part of the model answered a query.
enum class SoilSource {
  Outside,    ///< outside the extent: mean and variance NaN
  Air,        ///< above the initial surface of a cut column: nothing was ever there (NaN)
  Prior,      ///< a column no sweep cut (or below its extent): the configured prior
  Inherited,  ///< below the surface of a cut column: the depth-inflated inherited estimate
              ///< (× prior with prior_below)
  Removed,    ///< a removed voxel whose sweep's estimate arrived
  Predicted,  ///< a removed voxel whose sweep's estimate has not arrived or was invalid: the
              ///< prediction made for it before the cut
};
const char* soilSourceName(SoilSource s);

struct SoilBelief {
  SoilVector mean, var;
  SoilSource source = SoilSource::Outside;
};

struct StrataConfig {
  double resolution_m = 0.05;  ///< voxel edge (m)
  /// Extent in the map frame (m): columns and voxels outside are ignored (counted).
  Eigen::Vector3d min_m{-50, -50, -20}, max_m{50, 50, 20};
  double inflation_depth_m = 0.1;  ///< L: the inherited variance grows by e per L of depth
  SoilVector prior_mean{}, prior_var{};  ///< must be finite, variances > 0
  /// true: the removed voxels hold prior × N(μ̂, σ̂²) of their sweep's estimate; false: N(μ̂, σ̂²)
  /// as is. The prior still scales the change split's units and is the belief where no sweep cut.
  bool use_prior = true;
  /// Below a cut column: false: the inherited estimate with its variance inflated by depth,
  /// N(μ̂, σ̂² e^{Δz/L}) (the mean stays the soil above, the confidence fades); true: that times
  /// the prior (far down the prior's mean takes over).
  bool prior_below = false;
  int max_pending_sweeps = 256;    ///< sweeps waiting for their estimate; older ones resolve as Predicted
  /// true: a column's inherited belief filters every estimate that removed soil from it (the
  /// previous belief carried down to the new anchor with its variance × exp(Δz / L), times the
  /// new estimate); false: the last estimate alone.
  bool filter_inheritance = true;
};

/// Which soil properties (soil::SoilParam order) a computation reads.
using PropertyMask = std::array<bool, soil::kSoilParamCount>;

/// One cut cell of a sweep, as the strata need it (from SweepRecord's mask and slices).
struct CellCut {
  Eigen::Vector2d position = Eigen::Vector2d::Zero();  ///< cell centre, map frame
  double cell_m = 0;             ///< the map cell's edge (m); voxel columns inside it are cut
  double new_surface_m = 0;      ///< the surface the blade left (swept volume bottom), map z
  double old_surface_m = 0;      ///< the bank surface before the cut (fitted), map z; NaN = unknown
};

/// Counters of everything the model did or dropped (reasons are the map keys).
struct StrataCounters {
  long estimates_assigned = 0, estimates_invalid = 0, estimates_unmatched = 0, pending_evicted = 0;
  long voxels_removed = 0, columns_outside = 0, columns_unknown_surface = 0;
};

/// Memo of columns' estimated voxels for many changeHeightAt calls over one area (neighbouring
/// cells pool the same columns). One per thread; stale after any non-const call on the Strata.
struct VoxelCache {
  struct Voxel {
    long level;
    std::array<float, soil::kSoilParamCount> mean, var;
    float top, bottom;  ///< VoxelBelief::top, ::bottom
  };
  std::unordered_map<std::uint32_t, std::vector<Voxel>> columns;
};

class Strata {
 public:
  /// \throws ConfigError on a resolution <= 0, an empty extent, an extent beyond
  ///   OctoMap's key range, a non-positive L or prior variance.
  explicit Strata(const StrataConfig& config);

  const StrataConfig& config() const { return cfg_; }

  /// A sweep cut these cells: the voxels between the new surface and the column's surface are
  /// removed and wait for sweep `sweep`'s estimate. Returns the number of voxels removed.
  long applyCut(long sweep, const std::vector<CellCut>& cells);
  /// Sweep `sweep`'s estimate: its removed voxels take prior × N(mean, var) (N(mean, var) without
  /// use_prior), the columns it cut inherit it. `mean`/`var` null or not finite = no valid
  /// estimate: the voxels keep their prediction. Returns the voxels written (0 when no pending
  /// sweep has that index); appends the centres of the columns the sweep cut to `columns` when
  /// given.
  long assignEstimate(long sweep, const SoilVector* mean, const SoilVector* var,
                      std::vector<Eigen::Vector2d>* columns = nullptr);
  /// Resolves every pending sweep as without estimate (end of a run).
  void flushPending();

  /// The belief about the soil at (x, y, z) (header). Safe to call concurrently.
  SoilBelief soilAt(double x, double y, double z) const;
  /// The soil a cut of `depth_m` below `surface_z` would remove at (x, y): the mean of soilAt
  /// over the voxel centres in (surface_z − depth_m, surface_z] and the square of the mean
  /// standard deviation (the errors of one column are one estimate's: fully correlated).
  /// Source is the deepest-reaching part's. NaN surface = the column's own top (or NaN if none).
  SoilBelief expectedCut(double x, double y, double surface_z, double depth_m) const;

  /// The column's bank surface / its surface at the first cut (map z); NaN = never cut.
  double surfaceAt(double x, double y) const;
  double initialSurfaceAt(double x, double y) const;
  /// Height (map z) of the strongest change in the removed soil around (x, y): the removed voxels
  /// carrying estimates of the columns whose centres lie within `radius_m` of the column's
  /// (the column itself at 0) are averaged per voxel level (one sweep's estimate covers the
  /// blade's width and 0.2 m of travel, so neighbours add other sweeps' estimates of the same
  /// depth); the levels, top to bottom, are split into two runs (at least `min_voxels` levels
  /// each) minimising the squared deviation from each run's mean, in units of the prior
  /// standard deviation, summed over the properties, each level's weighted by its precision
  /// (1 / its voxels' mean variance in prior units; the runs' means weighted alike), so a noisy
  /// estimate moves the split less than a sure one. NaN with fewer than 2 × min_voxels
  /// levels, or when the best split explains less than `min_gain` of the spread. The height
  /// returned is where the sweeps changed, not a voxel face: a sweep's estimate is of the slab it
  /// cut (a few cm, not a voxel). It is halfway between the mean surface the sweeps of the
  /// lowest level above the split left (VoxelBelief::bottom) and the mean surface the sweeps of
  /// the highest level below it started from (VoxelBelief::top); they coincide when one sweep
  /// followed the other, and differ by a slab no voxel centre lay in; clamped to within half a
  /// voxel of the face between the two levels (where one column's slabs must end). Then a level
  /// beside the split whose soil lies between the two runs' (a sweep that cut across the change)
  /// moves it into that level's slab by the fraction of the other run's soil it holds (linear
  /// mix, the projection on the line between the runs' means), within a voxel of the face.
  /// `properties` (null = all five): the properties the split and the mix read; one the
  /// estimator cannot tell adds only its noise to the squared deviations (configs/strata.yaml).
  double changeHeightAt(double x, double y, int min_voxels = 1, double min_gain = 0.5, double radius_m = 0.0,
                        struct VoxelCache* cache = nullptr, const PropertyMask* properties = nullptr) const;
  /// changeHeightAt as a depth below the column's initial surface (NaN if either is NaN).
  double changeDepthAt(double x, double y, int min_voxels = 1, double min_gain = 0.5, double radius_m = 0.0) const;
  /// Removed voxel centres of the column, top (shallowest) first, with their beliefs.
  std::vector<std::pair<double, VoxelBelief>> columnVoxels(double x, double y) const;

  const StrataTree& tree() const { return tree_; }
  const StrataCounters& counters() const { return counters_; }
  std::size_t columns() const { return columns_.size(); }
  std::size_t pendingSweeps() const { return pending_.size(); }
  /// Tree nodes and an estimate of the bytes the tree and the columns hold.
  std::size_t nodes() const { return tree_.size(); }
  std::size_t memoryBytes() const;
  /// Prunes uniform regions of the whole tree (assignEstimate prunes above what it wrote).
  void prune() { tree_.prune(); }

  /// Writes the whole model atomically: an OctoMap `.ot` (id TerramapStrataTree) followed by a
  /// terramap trailer with the configuration and the columns. \throws OutputError.
  void save(const std::filesystem::path& path) const;
  /// Reads a file written by save(). \throws InputError naming the file and what is wrong.
  static Strata load(const std::filesystem::path& path);
  /// Writes an octovis-readable ColorOcTree: every removed voxel, and the prediction of every cut
  /// column down to `below_m` under its surface, occupied and coloured by `param` over
  /// [lo, hi] (soil::kSoilParams' range when lo >= hi) with the viridis map. \throws OutputError.
  void exportColorOt(const std::filesystem::path& path, int param, double below_m, double lo = 0, double hi = 0) const;

 private:
  struct Column {
    float top = std::numeric_limits<float>::quiet_NaN();
    float initial = std::numeric_limits<float>::quiet_NaN();
    float anchor = std::numeric_limits<float>::quiet_NaN();
    long inherit_sweep = -1;  ///< sweep whose estimate the column inherited (-1 = none)
    // float, like the voxels: a column is ~60 bytes instead of ~100 (4 M columns at 1 ha, 5 cm).
    std::array<float, soil::kSoilParamCount> inherit_mean{}, inherit_var{};
  };
  struct PendingColumn {
    std::uint32_t column;
    long lo, hi;   ///< removed voxel levels, inclusive
    float top;     ///< the column's surface before the sweep
    float bottom;  ///< the surface the sweep left (the anchor for inheritance)
  };
  // Columns are keyed by their OctoMap x and y keys ((kx << 16) | ky); a *level* is a voxel's
  // z index without OctoMap's offset: its centre is at (level + 0.5) · resolution.
  bool columnKey(double x, double y, std::uint32_t& key) const;
  long levelOf(double z) const;  ///< the highest level whose centre is at or below z
  double levelZ(long level) const;
  octomap::OcTreeKey voxelKey(std::uint32_t column, long level) const;
  Eigen::Vector2d columnCentre(std::uint32_t column) const;
  SoilBelief predictBelow(const Column* c, double z) const;
  void resolve(long sweep, const std::vector<PendingColumn>& cols, const SoilVector* mean, const SoilVector* var);

  StrataConfig cfg_;
  StrataTree tree_;
  std::unordered_map<std::uint32_t, Column> columns_;
  std::map<long, std::vector<PendingColumn>> pending_;
  StrataCounters counters_;
};

}  // namespace terramap::strata
