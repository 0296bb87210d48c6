#pragma once
/// \file
/// lidar_fusion: elevation_mapping_cupy-class fusion of LiDAR point clouds into a 2.5D
/// elevation map on CPU cores (ALGORITHMS.md section A). The parameter table with the
/// elevation_mapping_cupy equivalents is in plugins/lidar_fusion/README.md.
///
/// Per cloud (PointCloud event, sensor pose T_map_sensor):
///  1. time: every known cell's `time_since_update` grows by dt = stamp - previous stamp and
///     every valid cell's `variance` by time_variance_m2_per_s * dt (also on Tick/Pose events);
///  2. motion: with follow_robot the map re-centres (ring buffer, LayeredMap::move) on the
///     latest Pose (base position) or, before any Pose arrived, on the sensor position;
///  3. gates, counted by reason: non_finite, too_close, too_far, too_high, outside_map;
///  4. noise: range_based v = (a + b*r)^2 or depth_squared v = k*z_s^2, floored at
///     min_variance_m2 (a noise-free model, a = b = 0 or k = 0, is a ConfigError);
///  5. points are binned per tile (a stable counting sort inside each fixed chunk of points;
///     the gates of 3-4 run as an AVX2 kernel where the CPU has it, bit-identical to the
///     scalar loop), one task per tile fuses its points in input order (clearing the previous
///     cloud's `hits` of the tile first): a Mahalanobis gate |z-h| > k*sqrt(v+v_p) marks an
///     outlier (variance += outlier_variance), otherwise a precision-weighted update (fused
///     variance floored at min_variance_m2); a cell whose variance exceeds max_variance is
///     forgotten;
///  6. visibility cleanup: one ray every `cleanup_ray_stride` points is walked through the
///     grid (exact column traversal, Amanatides-Woo); valid cells not hit by this cloud whose
///     surface lies above the ray lose validity (cleanup_step per ray) and gain variance, unknown
///     cells get an upper bound (min over rays of the ray height in the cell; a cell invalidated
///     by this cloud: min over the rays that passed under it). The walk jumps over blocks of
///     8 x 8 cells where no cell could change (no missed surface reaches the ray, and the
///     steeper rays walked before already bound every unknown cell below it). With
///     cleanup_walk = fan the rays are binned by azimuth and each bin is walked once along its
///     centre line, every ray of the bin acting on those cells (see CleanupWalk);
///  7. optional drift compensation (off by default).
///
/// Frames: `elevation` and `upper_bound` are map-frame z (metres). NaN = unknown.
/// Height contract (docs/height_contract.md): the seven layers are shared. blade_sweep and
/// soil_erosion write `variance` (their own sigma^2: replaced on a cut, added on a deposit or
/// slip), `is_valid` (1 on a cut) and `upper_bound` wherever they change `elevation`; the gate,
/// the update and the time growth read whatever `variance` holds, so returns after a blind cut
/// are gated against the blade's uncertainty. A variance below min_variance_m2 is read as the
/// floor; a finite elevation with a NaN variance is treated as unknown (re-initialised).
/// Only this plugin writes `time_since_update` and `hits`.
/// Determinism: every stage either writes per tile in a fixed order or reduces with exact
/// operations (integer counts, min) over fixed chunks, so layers are bit-identical for any
/// thread count. No float atomics. (Upper bounds are minima kept per worker thread and merged
/// per tile: min is exact and order-free, so which thread walked which ray does not matter.)
/// Threading: process() runs on the engine thread and parallelises with ctx.executor().
#include <terramap/plugin/plugin.hpp>
#include <terramap/plugin/records/vertical_datum_record.hpp>
#include "self_filter.hpp"

#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace terramap::plugins {

/// How the visibility cleanup walks its rays (step 6 of the list above).
enum class CleanupWalk {
  /// Every ray along its own line through the grid (Amanatides-Woo), jumping over the blocks
  /// where no cell could change: each ray's own cells, at a cost per ray of the cells it reads.
  Exact,
  /// The rays binned by azimuth (bins narrow enough that a ray lies within
  /// cleanup_fan_lateral_cells of its bin's centre line at max_ray_length_m); each bin's rays
  /// walked together along its centre line, one read per cell for the whole bin: per cell, the
  /// lowest ray over it comes from the bin's rays sorted by reach (a suffix minimum of their
  /// slopes). A ray thus acts on the cells of a line within that lateral distance of its own.
  Fan,
};

enum class NoiseModel {
  RangeBased,    ///< sigma = a + b * range (LiDAR); variance = sigma^2
  DepthSquared,  ///< variance = k * z_s^2, z_s = sensor-frame z (depth for a camera)
};

/// All parameters of the fusion, SI units. Defaults are the plugin's schema defaults.
struct LidarFusionConfig {
  NoiseModel noise_model = NoiseModel::RangeBased;
  double range_noise_a_m = 0.02;          ///< sigma at zero range (m)
  double range_noise_b = 0.001;           ///< sigma growth per metre of range (m/m)
  double sensor_noise_factor = 0.05;      ///< depth_squared: k in v = k z_s^2 (1)
  /// Clouds whose frame matches one of these (shell patterns, fnmatch: "ctl1/cam", "*/cam*")
  /// take the depth_squared model whatever `noise_model` says: a depth camera beside a LiDAR in
  /// one fusion. The camera's points must be in its optical frame (z_s = depth), as the
  /// simulator's depth cameras deliver them.
  std::vector<std::string> depth_squared_frames;
  double min_range_m = 0.5;               ///< points closer to the sensor are dropped
  double max_range_m = 100.0;             ///< points farther are dropped
  double max_height_above_sensor_m = 1.0; ///< map-frame z above the sensor's z: dropped
  bool enable_ramped_height_range = true; ///< also drop z - z_s > max(d_xy - b, 0) * a + c
  double ramped_height_range_a = 0.3;     ///< slope (m/m)
  double ramped_height_range_b_m = 1.0;   ///< horizontal distance where the ramp starts (m)
  double ramped_height_range_c_m = 0.2;   ///< height allowed at the sensor (m)
  /// Variance floor (m^2) of every point and of every fused cell: no point or cell claims to
  /// know a height better than sigma = 1 mm. Why 1 mm: it is the range resolution of common
  /// LiDARs (Velodyne HDL-32E/64E 2 mm, Ouster OS1 1 mm; quantisation alone gives q/sqrt(12)),
  /// so a smaller fused sigma would be a claim the sensor cannot support; it is far below the
  /// 2 cm point noise (v_p = 4e-4), so it only binds after ~400 consistent points in one cell
  /// without time growth. Without it a cell could freeze (v -> 0: a new point's weight
  /// v/(v + v_p) -> 0, and a zero-noise point makes every later one an outlier) and two
  /// zero-variance points give 0/0 = NaN. Must be > 0 (ConfigError).
  double min_variance_m2 = 1e-6;
  double mahalanobis_thresh = 2.0;        ///< k in |z - h| > k sqrt(v + v_p)
  double outlier_variance_m2 = 0.01;      ///< added to a cell's variance per outlier (m^2)
  double max_variance_m2 = 100.0;         ///< a cell above this after an outlier is forgotten
  double time_variance_m2_per_s = 0.0005; ///< variance growth of valid cells (m^2/s)
  bool enable_visibility_cleanup = true;
  int cleanup_ray_stride = 1;             ///< walk the ray of every n-th point (by input index)
  double max_ray_length_m = 10.0;         ///< walk at most this far from the sensor (m)
  double cleanup_step = 0.1;              ///< is_valid lost per penetrating ray
  double cleanup_cos_thresh = 0.1;        ///< skip rays with |ray . normal| below this (grazing)
  double cleanup_end_margin_m = 0.3;      ///< stop the walk this far before the point (m)
  CleanupWalk cleanup_walk = CleanupWalk::Fan;  ///< fans, or each ray on its own line (see CleanupWalk)
  /// Fan walk: the largest distance (cells) between a ray and its bin's centre line, reached at
  /// max_ray_length_m (or the map's diagonal, if shorter); nearer the sensor it is smaller.
  double cleanup_fan_lateral_cells = 0.5;
  bool enable_drift_compensation = false;
  double drift_compensation_alpha = 0.1;            ///< fraction of the mean residual applied
  double drift_compensation_variance_inlier_m2 = 0.05;  ///< only cells below this variance vote
  double max_drift_m = 0.1;               ///< larger mean residuals are not applied (m)
  long min_height_drift_cnt = 100;        ///< minimum inlier points for a correction
  double position_noise_thresh_m = 0.01;  ///< sensor motion needed for a correction (m)
  double orientation_noise_thresh_rad = 0.01;  ///< or rotation needed (rad)
  bool follow_robot = false;              ///< re-centre the map on the robot (ring buffer)
  /// The vertical datum between a machine's poses and a site survey (records/
  /// vertical_datum_record.hpp): the survey's clouds (frame `survey_frame`) leave their heights
  /// in the layer `survey_z`; for a machine's cloud (frame "<machine>/<sensor>") the median of
  /// point height minus survey_z over the points within `datum_gate_m` of the current estimate
  /// (ground nothing has changed since the survey) updates the machine's offset, low-passed
  /// with `datum_tau_s` (the first update takes it whole); each later cloud of the machine is
  /// fused shifted down by it, into the survey's datum. No survey, or fewer than
  /// `datum_min_points` such points: no offset, the clouds are fused as they come.
  bool survey_datum = true;
  std::string survey_frame = "survey";
  double datum_tau_s = 3.0;
  double datum_gate_m = 0.08;
  long datum_min_points = 200;
  double datum_max_m = 0.3;               ///< larger offsets are not taken (m)
  /// Self-filter boxes (self_filter.hpp), 6 numbers per box [xmin, ymin, zmin, xmax, ymax, zmax]
  /// in the base frame (placed with each machine's latest Pose) or the blade frame (latest
  /// BladePose); empty = no filter. Points inside are dropped as `self`.
  std::vector<double> self_filter_base_m, self_filter_blade_m;
  /// The same on an excavator's links (slew, boom, arm, bucket frames of its JointState events).
  std::array<std::vector<double>, 4> self_filter_link_m;
  double self_filter_margin_m = 0.1;      ///< boxes grown by this on every side (m): 3-5 sigma of range noise plus the motion since the pose
};

/// The schema (names, units, ranges, defaults) the YAML params are checked against.
ParamSchema lidarFusionSchema();
/// Converts validated params. \throws ConfigError (via params.fail) on inconsistent values,
/// e.g. min_range_m >= max_range_m.
LidarFusionConfig lidarFusionConfigFrom(const Params& params);

/// What one cloud did (also summed into the run report's counters).
struct FusionStats {
  long points_in = 0;
  long dropped_non_finite = 0, dropped_too_close = 0, dropped_too_far = 0, dropped_too_high = 0,
       dropped_outside_map = 0;
  long dropped_tile_budget = 0;  ///< points in a tile a sparse map could not allocate (memory budget)
  long points_fused = 0;     ///< points that updated a cell (including cell initialisations)
  long cells_fused = 0;      ///< distinct cells those points updated
  long outliers = 0;         ///< points rejected by the Mahalanobis gate
  long cells_forgotten = 0;  ///< cells reset because their variance exceeded max_variance
  long tiles_touched = 0;
  long rays = 0;             ///< rays walked
  long ray_cells = 0;        ///< cells the walks span (one per column crossing, plus the first)
  /// Of those, the cells the walks read (the rest lay in blocks skipped whole). The only figure
  /// that depends on the thread count (which worker walks which rays); not in the run report.
  long ray_cells_read = 0;
  long cells_penetrated = 0; ///< penetrating-ray updates applied to stale valid cells
  long cells_invalidated = 0;  ///< stale cells whose validity fell below 0.5
  long upper_bounds = 0;     ///< unknown cells given a ray upper bound (once per cell), plus
                             ///< rays over cells that this cloud's rays invalidated
  bool drift_applied = false;
  double drift_m = 0.0;      ///< correction added to the map's elevations (m)
  long drift_inliers = 0;
  long datum_points = 0;     ///< points on undisturbed surveyed ground (survey_datum)
  bool datum_updated = false;
  double datum_shift_m = 0;  ///< the machine's offset this cloud was fused shifted down by (m)
  long tile_budget_refusals = 0;  ///< tiles not written (points or ray bounds): the budget held no more
};

/// Layer names the plugin creates.
struct LidarFusionLayers {
  static constexpr const char* kElevation = "elevation";            ///< m, map-frame z; NaN unknown
  static constexpr const char* kVariance = "variance";              ///< m^2; NaN unknown; blind writers too
  static constexpr const char* kIsValid = "is_valid";               ///< 1 valid .. 0 unknown
  static constexpr const char* kTimeSinceUpdate = "time_since_update";  ///< s; NaN never
  static constexpr const char* kUpperBound = "upper_bound";         ///< m; NaN none
  static constexpr const char* kIsUpperBound = "is_upper_bound";    ///< 1 if bound from rays
  static constexpr const char* kHits = "hits";                      ///< points fused this cloud
  static constexpr const char* kSurveyZ = "survey_z";               ///< m; survey's height; NaN none
};

class LidarFusion : public Plugin {
 public:
  LidarFusion() = default;

  ParamSchema schema() const override { return lidarFusionSchema(); }
  void configure(const Params& params) override { configure(lidarFusionConfigFrom(params)); }
  /// Creates the seven layers (see LidarFusionLayers) with their units and fill values.
  std::vector<LayerSpec> layers() const override;
  EventMask events() const override;
  void start(ProcessContext& ctx) override;
  /// PointCloud: drop self points (self-filter), fuse; Pose: follow the robot (if enabled),
  /// place the base boxes, advance time; BladePose: place the blade boxes; Tick: advance time.
  /// \throws InputError on a non-finite sensor pose or a stamp that goes backwards.
  void process(ProcessContext& ctx, const Event& event) override;
  void finish(ProcessContext& ctx) override;

  // ---- direct API (embedders, tests, benchmarks) -------------------------------------------
  /// Uses `config` instead of YAML params. \throws ConfigError as lidarFusionConfigFrom does.
  void configure(const LidarFusionConfig& config);
  const LidarFusionConfig& config() const { return config_; }
  /// Adds the layers to `map` if missing and binds to them (what the host + start() do).
  void attach(LayeredMap& map);
  /// Fuses one cloud into the attached map with `executor` (steps 1-7 above).
  /// \throws InputError if the pose is not finite; LayerError if not attached to `map`.
  FusionStats fuse(LayeredMap& map, const Executor& executor, const PointCloud& cloud);
  /// Advances time to `stamp` (time_since_update and variance growth). Earlier stamps throw
  /// InputError; the first stamp only sets the clock.
  void advanceTime(LayeredMap& map, const Executor& executor, double stamp);
  /// Follow-robot motion to a base position (no-op unless follow_robot).
  void followTo(LayeredMap& map, const Eigen::Vector3d& position);
  /// Gate the points with the portable scalar loop even where the AVX2 kernel could run
  /// (x86-64 CPUs with AVX2 use it by default). Both give bit-identical results (tested);
  /// this exists for that test and for benchmarking the difference.
  void forceScalarGates(bool on) { force_scalar_gates_ = on; }
  /// Walk every cell of every ray (every column of every fan bin's line) instead of jumping over
  /// the blocks where no cell could change (the cleanup's block skipping, on by default). Both
  /// give bit-identical layers and counters other than ray_cells_read (tested); this exists for
  /// that test and for benchmarking.
  void forceCellByCellWalk(bool on) { force_cell_walk_ = on; }
  /// Totals over every cloud so far.
  const FusionStats& totals() const { return totals_; }

 private:
  /// A penetrating ray (visibility cleanup): tile, offset in the tile, ray z, kind.
  struct Item {
    std::int32_t tile;
    std::uint32_t off;
    float z;
    float aux;
  };
  /// A gated point, already binned: offset in its tile, map-frame z, variance.
  struct PointItem {
    std::uint32_t off;
    float z;
    float var;
  };
  /// One fixed chunk of kChunk input points after step 1: its points sorted by tile (stable),
  /// with per-tile ranges, and the ray ends it contributes to the cleanup.
  struct PointChunk {
    std::vector<PointItem> items;      // sorted by tile, input order within a tile
    std::vector<PointItem> scratch;    // kept points in input order (sized for all of the chunk)
    std::vector<std::int32_t> tiles;   // tile of each scratch item
    std::vector<std::int32_t> start;   // tile -> first item; size tiles + 1
    std::vector<float> ray_ends;       // xyz (sensor-relative, map frame) per walked ray
    std::array<long, 5> drops{};       // non_finite, too_close, too_far, too_high, outside_map
  };
  void bindLayers(const LayeredMap& map);
  void buildIndexTables(const LayeredMap& map);
  void preparePoints(const LayeredMap& map, const Executor& ex, const PointCloud& cloud, const Eigen::Isometry3d& T);
  /// survey_datum: the machine's offset from this cloud's points on surveyed ground (before
  /// fusion; the points are already shifted by the current offset).
  void measureDatum(LayeredMap& map, const Executor& ex, const std::string& machine, double stamp, FusionStats& st);
  /// survey_datum: the survey's heights of the cells this (survey) cloud hit.
  void recordSurvey(LayeredMap& map);
  static void sortChunkByTile(PointChunk& ch, int m, int ntiles);
  /// Whether `frame` matches one of config_.depth_squared_frames.
  bool depthSquaredFrame(const std::string& frame) const;
  void binItems(const Executor& ex, std::vector<std::vector<Item>>& chunks, int ntiles);
  void driftCompensation(LayeredMap& map, const Executor& ex, const Eigen::Isometry3d& T,
                         FusionStats& st);
  void fuseTiles(LayeredMap& map, const Executor& ex, FusionStats& st);
  std::vector<char> tilesRefusedByBudget(LayeredMap& map) const;
  void clearPreviousHits(LayeredMap& map, int t) const;
  bool layoutHitLists(int ntiles);
  void cleanup(LayeredMap& map, const Executor& ex, const Eigen::Vector3d& sensor,
               FusionStats& st);
  void accumulate(const FusionStats& st);

  LidarFusionConfig config_;
  SelfFilter self_filter_;
  PointCloud filtered_;  // the cloud without self points (reused)
  // layer ids (elevation, variance, is_valid, time, upper_bound, is_upper_bound, hits)
  LayerId elev_ = -1, var_ = -1, valid_ = -1, time_ = -1, ub_ = -1, isub_ = -1, hits_ = -1;
  const LayeredMap* bound_map_ = nullptr;
  // buffer row/column -> (tile row or column, local offset) lookup, rebuilt when the map moves
  std::vector<std::int32_t> row_tile_, row_local_, col_tile_, col_local_;
  Index tables_start_{-1, -1};
  // scratch reused between clouds
  std::vector<PointChunk> point_chunks_;
  std::vector<int> tile_points_;   // tile -> points binned this cloud
  std::vector<int> active_tiles_;  // tiles with binned points, ascending
  std::vector<int> task_tiles_;    // active tiles plus tiles whose hits must be cleared
  // Cells whose `hits` the previous cloud set (distinct tile offsets), per tile t:
  // prev_hit_offs_[prev_hit_start_[t] .. + prev_hit_count_[t]). Double-buffered with the
  // current cloud's lists.
  std::vector<int> hit_start_, hit_count_, prev_hit_start_, prev_hit_count_;
  std::vector<std::uint32_t> hit_offs_, prev_hit_offs_;
  /// Visibility cleanup, per worker slot of the executor's arena: the lowest ray height seen
  /// over each unknown cell of the tiles this slot's rays crossed (+inf = none). Buffers are
  /// allocated on first use and kept; phase B merges them per tile (min) and resets them.
  struct RayMinSlot {
    std::vector<std::unique_ptr<float[]>> tiles;  // per tile: tileSize^2 floats, or null
    std::vector<float*> active;                   // per tile: the buffer if touched this cloud
    std::vector<int> list;                        // tiles touched this cloud
    // Per block (kRayBlock^2 cells of a tile): an upper bound on the largest minimum this slot
    // holds over the block's unknown cells (-inf: no unknown cell; +inf: one may have none
    // yet), and whether a ray lowered a minimum there since it was computed.
    std::vector<float> block_max;
    std::vector<std::uint8_t> block_dirty;
    // Per block, computed by the slot the first time one of its rays enters the block (NaN
    // until then): the highest surface a ray could find stale there (known cells this cloud
    // did not hit; -inf none).
    std::vector<float> block_kmax;
  };
  std::vector<RayMinSlot> ray_min_;
  int ray_min_tile_cells_ = 0;
  std::vector<float> nan_tile_;  // stands in for unallocated elevation tiles during the walk
  // visibility cleanup: ray tasks (rays [begin, end) of a point chunk) and their penetration
  // items (one list per task, in task order = input order), binned per tile
  struct RayTask {
    int begin, end;  // rays [begin, end) of ray_order_
  };
  // The rays of the cloud (sensor-relative xyz, map frame), steepest descent first: where low
  // rays have already bounded a block's unknown cells, the higher ones skip it (walkRayTask).
  std::vector<float> ray_order_;
  std::vector<std::uint16_t> ray_keys_;  // sort bucket per ray (scratch)
  std::vector<int> ray_sector_start_;    // first ray task of each azimuth octant; one past the end last
  // Blocks of the ray walk, per logical row (column): the tile's row (column) part, the block's
  // row (column) part of its index inside the tile, and the logical bounds [lo, hi) of the
  // block's rows (columns). One record, read together on entering a block.
  struct AxisBlock {
    std::int32_t tile, blk, lo, hi;
  };
  std::vector<AxisBlock> row_blocks_, col_blocks_;
  /// What a walk task reads in its loop, copied to locals (through `this` the compiler would
  /// reload them every step): the block and index tables, the layer views, the slot's buffers.
  struct WalkLocals {
    const std::int32_t *row_local, *col_local;
    const AxisBlock *row_blocks, *col_blocks;
    int blocks_per_tile;
    unsigned rows, cols;
    const float* const* elev;
    float* const* active;  ///< the slot's minimum buffers per tile (null: none yet)
    std::uint8_t* dirty;   ///< the slot's per-block flags
  };
  int blocks_per_tile_ = 0;
  std::vector<RayTask> ray_tasks_;
  std::vector<std::vector<Item>> ray_chunks_;
  /// What the cleanup's ray walk reads: per-tile layer views (elevation never null: an
  /// unallocated tile points at nan_tile_), the grid size and the sensor in grid coordinates.
  struct RayWalkView {
    std::vector<const float*> elev, var, hits;
    int rows = 0, cols = 0, tile_side = 0, tile_cells = 0;
    double res = 0, u0 = 0, v0 = 0, sensor_z = 0;
  };
  // The steps of cleanup(): views, ray tasks, phase A per task (the walk), phase B.
  RayWalkView rayWalkView(const LayeredMap& map, const Eigen::Vector3d& sensor);
  void prepareRaySlots(int slots, int ntiles, int tile_cells);
  void prepareRayTasks();
  void prepareRayBlocks(const LayeredMap& map);
  float blockMax(const RayWalkView& view, const RayMinSlot& mins, std::int32_t tile, int block) const;
  void blockSurface(const RayWalkView& view, RayMinSlot& mins, std::int32_t tile, int block) const;
  inline bool blockUnchanged(const RayWalkView& view, RayMinSlot& mins, std::int32_t tile, int block, double zlow, bool refresh) const;
  float* minTile(RayMinSlot& mins, std::int32_t tile) const;
  WalkLocals walkLocals(const RayWalkView& view, RayMinSlot& mins) const;
  inline void lowerMinimum(RayMinSlot& mins, const WalkLocals& tab, std::int32_t tile, int blk, std::uint32_t off,
                           double z) const;
  std::array<long, 3> walkRayTask(const RayWalkView& view, RayMinSlot& mins, int task);
  void staleCell(const RayWalkView& view, int i, int j, std::int32_t tile, std::uint32_t off, float h, double zhi,
                 double dirx, double diry, double dirz, std::vector<Item>& items) const;
  void applyRayResults(LayeredMap& map, const Executor& ex, FusionStats& st);
  /// The surface's gradient (dz/dx, dz/dy) at cell (i, j) of height h: central differences,
  /// one-sided at unknown neighbours, 0 where both are unknown.
  std::array<double, 2> surfaceGradient(const RayWalkView& view, int i, int j, float h) const;
  double staleBelow(const RayWalkView& view, std::int32_t tile, std::uint32_t off, float h) const;
  bool notGrazing(double gx, double gy, double dirx, double diry, double dirz) const;
  // The fan walk (CleanupWalk::Fan): the rays binned by azimuth face and centre-line slot, in
  // input order within a bin (a stable counting sort over the point chunks), each with what the
  // walk needs: horizontal reach R (m), slope s = dz / rho (m/m), horizontal length rho (m),
  // the walk's end t_end on the ray (0..1), the direction and the ray's index (sort tie-break).
  struct FanRay {
    double R, s, rho, t_end;
    float dx, dy, dz;
    std::uint32_t seq;
  };
  void prepareFan(const LayeredMap& map, const Executor& ex);
  std::array<long, 3> walkFanTask(const RayWalkView& view, RayMinSlot& mins, int task, std::vector<double>& scratch);
  void staleFanCell(const RayWalkView& view, int i, int j, std::int32_t tile, std::uint32_t off, float h,
                    const FanRay* rays, int p, int q, int n, double z, double da, double db,
                    std::vector<Item>& items) const;
  std::vector<FanRay> fan_rays_;
  std::vector<std::uint32_t> fan_keys_;         // bin per ray of the chunks (scratch; ~0u: not walked)
  std::vector<double> fan_ends_;                // the walk's end per ray of the chunks (scratch; rayWalkEnd)
  std::vector<std::vector<int>> fan_hist_;      // per point chunk: rays per bin, then its first slot
  std::vector<int> fan_bin_start_;              // bin -> first ray in fan_rays_; size bins + 1
  int fan_slots_ = 0;                           // centre-line slots per face (4 faces)
  std::vector<int> bin_start_;     // tile -> first binned item; size tiles + 1
  std::vector<Item> binned_;
  std::vector<int> ray_tiles_;     // tiles with binned ray items, ascending
  std::vector<char> tile_known_;   // buffer tiles that may hold known cells (time pass)
  bool force_scalar_gates_ = false;
  bool force_cell_walk_ = false;
  bool have_stamp_ = false;
  double last_stamp_ = 0.0;
  bool have_pose_ = false;         // a Pose event arrived (follow it rather than the sensor)
  bool have_prev_sensor_ = false;
  Eigen::Isometry3d prev_T_map_sensor_ = Eigen::Isometry3d::Identity();
  FusionStats totals_;
  LayerId survey_z_ = -1;
  std::map<std::string, VerticalDatumRecord::Machine> datum_;  // by machine id
  long clouds_ = 0;
  double fuse_wall_s_ = 0.0;
};

}  // namespace terramap::plugins
