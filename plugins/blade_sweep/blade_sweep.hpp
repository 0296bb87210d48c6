#pragma once
/// \file
/// blade_sweep: blind mapping with the blade's swept volume (ALGORITHMS.md §B, §C, §D, §L;
/// paper Alg. 1-3).
///
/// Between two update poses T0 -> T1 (the pose history in between included), the blade quad
/// sweeps a volume; every map cell whose centre lies under that volume's footprint gets the
/// lowest point of the volume above it (h^G, mask G); cells whose elevation is above it are
/// cut (set A, Δh = H - h^G). Before the cut, the FEE geometry (α, ρ, d, w, V_Q, Q) is fitted
/// on the surface ahead of every cut cell; then the cut soil is deposited on the first cell
/// outside the footprint along m̂ = normalize(λ n̂ + (1 - λ) t̂), swelling only its undisturbed
/// part, so that Σ[(H - L) + L/s] is conserved. The result is a SweepRecord
/// (terramap/plugin/records/sweep_record.hpp) published for later plugins.
///
/// Layers: `elevation` (written, must be provided by the map config or an earlier plugin),
/// `loose` (created, m, fill 0) and `height_sigma` (created, m, NaN = the blade never changed the
/// cell). The masks erosion needs travel in the record, not in layers.
///
/// Height contract (docs/height_contract.md): where lidar_fusion's layers exist (bound at
/// start(), so lidar_fusion must be an earlier stage; it always is, since it creates
/// `elevation`), every height change keeps them consistent, so LiDAR returns after a blind cut
/// are gated against the blade's uncertainty, not a stale one:
///  - cut cell: `variance` = height_sigma² (replaced: the old surface is gone), `is_valid` = 1,
///    `upper_bound` = elevation, `is_upper_bound` = 0;
///  - deposit on known ground: `variance` += the deposit's share of height_sigma² (the buried
///    surface is still the base), `is_valid` kept, `upper_bound` = elevation, `is_upper_bound` = 0;
///  - deposit on unknown ground (elevation stays NaN): a ray `upper_bound` there is cleared
///    (NaN, `is_upper_bound` = 0): the pile may now stand above it.
/// Without a `variance` layer (blind-only pipeline) none of this is written; the layer is not
/// created (nobody would read it, and `height_sigma` already carries the same sigma).
#include <terramap/plugin/plugin.hpp>
#include <terramap/core/map_window.hpp>
#include <terramap/plugin/records/sweep_record.hpp>

#include <Eigen/Geometry>
#include <array>
#include <limits>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

namespace terramap::plugins {

/// Parameters of the sweep kernels (the plugin's YAML params, in SI units).
struct SweepConfig {
  double min_translation_m = 0.2;     ///< edge travel that triggers an update (>= res·√2 applied)
  double min_rotation_rad = 0.17453292519943295;  ///< blade rotation that triggers an update
  double max_jump_m = 2.0;            ///< edge jump between two poses treated as a teleport
  int max_stations = 16;              ///< poses of the history used to build the mesh
  double max_station_rotation_rad = 0.03490658503988659;  ///< slerp stations closer than this
  double swell = 1.2;                 ///< s: loose thickness per undisturbed thickness
  double deposit_normal_weight = 0.5; ///< λ_n in m = λ n̂ + (1-λ) t̂
  double fit_length_m = 1.0;          ///< surface samples ahead of each cut cell
  double fit_distance_weight = 3.0;   ///< C_x (1/m): WLS weights exp(-C_x x)
  double depth_weight = 5.0;          ///< C_d (1/m): slice average weights exp(C_d d)
  double unit_weight_n_m3 = 14636.0;  ///< γ (undisturbed); γ_l = γ / s for Q
  double sigma_sv_m = 0.02;           ///< σ_SV: 1σ of the blade height (pose) during a sweep
  double min_cut_m = 1e-6;            ///< H - h^G above this is a cut
  /// The loose layer follows what the sensors show: the undisturbed surface under the loose soil
  /// is kept in the layer `loose_base` (map z), and at each update the loose thickness is
  /// re-read as elevation - loose_base, so soil a LiDAR sees lower (the bookkept pile is not
  /// there) or higher (the pile it cannot place, spread by the real blade) is loose soil the
  /// blade pushes and the surcharge counts. Off: the loose layer is the bookkeeping alone.
  bool loose_follows_elevation = false;
  /// Where the surcharge Q comes from. false: the loose soil the map holds in the region ahead of
  /// the edge (V_Q, paper Alg. 2). true: the soil the blade has cut since its pass began (bank
  /// volume, kept per machine by CarriedPile), up to what the blade can hold at the repose
  /// angle: the pile is hidden behind the blade from a mast LiDAR, and the map's copy of it
  /// leaks to the sides and behind (docs/soil_estimator.md, "The surcharge the map holds").
  bool surcharge_carried = false;
  double carried_repose_rad = 0.576;  ///< 33 deg: the pile's face, for the blade's capacity
  /// What the bookkeeping assumes of the soil cut beyond the blade's capacity. 0: it all spills
  /// (V_Q stays at the capacity). s in (0, 1]: V_Q = capacity + s x (cut - capacity), with the
  /// uniform's variance (cut - capacity)^2 / 12 added: the blade holds at least its capacity
  /// once filled and, without pick-up, at most what it cut since the pass began; how much
  /// spilled around its ends is not observed, and 0.5 is the middle of what the two bounds
  /// allow. Measured against the simulator's pile in docs/soil_estimator.md ("The pile beyond
  /// the blade's capacity").
  double carried_overflow_share = 0.0;
  /// The FEE depth is measured from the bank surface the map knew before the pile reached it
  /// (layer `bank_surface`), not from elevation - loose. A mast LiDAR sees the top of the real
  /// pile ahead of the blade, larger than the map's bookkept one, so elevation - loose there is
  /// the ground plus the pile the bookkeeping lacks (the cut looked deeper than it was: 1.6 times
  /// the simulator's cross-section in Fig. 12's dense strip), and re-reading the loose thickness
  /// from the elevation (loose_follows_elevation) ratchets the base down with every noisy reading
  /// below it (0.35 times). Bank soil never rises: on every sweep, each cell from the edge to
  /// `bank_reach_m` ahead that has no bank height yet and no loose soil takes its elevation then
  /// (the pile, about a metre long, has not reached it); a cut lowers it to the cut floor.
  bool bank_reference = false;
  /// The blade placed in a site survey's datum: the offset lidar_fusion estimated between the
  /// machine's poses and the survey (terramap.vertical_datum.v1) is subtracted from its blade
  /// heights, in place of the ground anchor, for a machine that has one.
  bool use_survey_datum = true;
  double bank_reach_m = 3.0;
};

/// Ground anchoring of the blade height (docs: plugins/blade_sweep/README.md, "Ground anchor").
/// A machine's tracks rest on the ground the map holds; GNSS/INS heights drift and carry a bias
/// of centimetres, the map under the tracks does not move with them. So on every `Pose` the
/// plugin compares the height the pose gives the track contact plane with the map under each
/// track half (its highest point, where a rigid track rests), low-passes the difference
/// (time constant `tau_s`, long against the pose's white noise, short against its drift) and
/// shifts every later blade pose of that machine by it. Differences beyond `max_m` (unknown or
/// stale map under the tracks) are ignored.
struct GroundAnchorConfig {
  bool enabled = true;
  double track_length_m = 1.9, track_gauge_m = 1.6;  ///< contact patch of the machine (m)
  double tau_s = 10.0;                               ///< low-pass time constant (s)
  double max_m = 0.15;                               ///< larger differences are ignored (m)
};

/// A triangle of the swept-volume surface, map frame (m).
struct Triangle {
  Eigen::Vector3d a, b, c;
};

/// Corners of the blade quad at pose T: edge right, edge left, top left, top right (map frame).
std::array<Eigen::Vector3d, 4> bladeCorners(const Eigen::Isometry3d& T_map_blade, const BladeGeometry& g);

/// Closed triangulated surface of the volume swept by the blade through `stations` (at least
/// one pose): both blade quads at every station plus the four ruled quads of each consecutive
/// pair (each split into two triangles). The union of the per-segment volumes is the swept
/// volume, so the lowest intersection of a vertical line with these triangles is its bottom.
std::vector<Triangle> sweptVolumeMesh(const std::vector<Eigen::Isometry3d>& stations,
                                      const BladeGeometry& g);

/// The ruled surface swept by the cutting edge alone (two triangles per pair of stations):
/// FEE depths are measured from it, so that soil lying on a raked blade's face above the edge
/// (which the full volume also cuts) does not pass for a shallower cut.
std::vector<Triangle> edgeSweepMesh(const std::vector<Eigen::Isometry3d>& stations, const BladeGeometry& g);

/// Stations for the mesh from a pose history: at most `max_stations` poses taken evenly (the
/// first and last always), with slerp-interpolated poses inserted where consecutive stations
/// rotate by more than `max_rotation_rad` (a triangulated ruled quad only follows a twisting
/// edge closely when the twist per segment is small).
std::vector<Eigen::Isometry3d> meshStations(const std::vector<Eigen::Isometry3d>& history, int max_stations,
                                            double max_rotation_rad);

/// Logical cells whose centres may lie under the triangles' footprint (clipped to the map).
CellRect footprintBlock(const std::vector<Triangle>& tris, const Geometry& geo);

/// For every cell centre of `block`, the lowest z where a vertical line through it meets a
/// triangle (exact, barycentric in the horizontal projection), or NaN if none does.
/// Vertical triangles (zero projected area) are skipped: a vertical line meets them only on a
/// set of measure zero, and their lowest points are shared with non-vertical neighbours.
/// Deterministic for any thread count (a min does not depend on the order).
void lowestIntersection(const std::vector<Triangle>& tris, const Geometry& geo, const CellRect& block,
                        std::vector<double>& z_low, const Executor& ex);

/// Layer ids the sweep touches. The last four are lidar_fusion's (the height contract,
/// docs/height_contract.md): -1 = the layer does not exist and is left alone (a blind-only
/// pipeline has none of them; `height_sigma` is then the only uncertainty).
struct SweepLayers {
  LayerId elevation = -1, loose = -1, sigma = -1;
  LayerId variance = -1, is_valid = -1, upper_bound = -1, is_upper_bound = -1;
  LayerId base = -1;  ///< loose_base (optional: SweepConfig::loose_follows_elevation)
  LayerId bank = -1;  ///< bank_surface (optional: SweepConfig::bank_reference)
  /// elevation, loose, height_sigma (must exist), and the contract layers the map has.
  /// \throws LayerError if one of the first three is missing.
  static SweepLayers of(const LayeredMap& map);
  /// MapWindow::tryAllocate for every layer a sweep may write (false: a sparse map's budget).
  bool allocate(LayeredMap& map, const MapWindow& win) const;
};

/// How a sweep changed a cell (the height contract's cases).
enum SweepChange : std::uint8_t { kSweepUnchanged = 0, kSweepCut = 1, kSweepDeposit = 2, kSweepDepositUnknown = 3 };

/// The elevation, loose and height-sigma layers over a window as gathered (H0, L0, S0) and as a
/// sweep, a bucket or a pour changes them (H, L, S, with `change` per cell): what every blind
/// update reads first and writes last.
struct SweepSoil {
  /// H0, L0, S0: the layers as the update starts (L0 already re-read from loose_base where the
  /// map keeps it); H, L, S: as the update leaves them. Lg, B0: loose and loose_base as gathered.
  std::vector<double> H0, L0, S0, H, L, S, Lg, B0;
  /// bank_surface as gathered (K0) and as the update leaves it (K); empty without the layer.
  std::vector<double> K0, K;
  std::vector<std::uint8_t> change;  ///< SweepChange per window cell
  /// Gathers the three layers over `win` (H, L, S start as copies; change all unchanged). Where
  /// the map has loose_base, a known cell's loose thickness becomes max(0, elevation - base).
  SweepSoil(const LayeredMap& map, const SweepLayers& ids, const MapWindow& win);
  /// Scatters the cells that changed and applies the height contract (docs/height_contract.md)
  /// to lidar_fusion's layers where `change` marks a cut or a deposit.
  void write(LayeredMap& map, const SweepLayers& ids, const MapWindow& win) const;
};

/// A tool given as a closed triangle mesh in its own frame (m): an excavator's bucket, in the
/// frame of JointState::T_map_bucket (origin at the bucket pivot, x toward the lip, y across,
/// z toward the bucket's back; the opening faces -z).
struct ToolMesh {
  std::vector<Triangle> faces;   ///< closed surface, tool frame
  Eigen::Vector3d lip = Eigen::Vector3d::Zero();  ///< where poured soil leaves the tool (tool frame)
  double width_m = 0;
  double volume_m3 = 0;  ///< the closed mesh's volume
  /// The prism of a convex profile (points (x, z), either orientation) extruded over
  /// [-width/2, width/2]; the lip is the profile vertex farthest along x.
  /// 	hrows ConfigError for fewer than three vertices or a width <= 0.
  static ToolMesh prism(const std::vector<Eigen::Vector2d>& profile, double width_m);
};

/// The bucket of the plugin's excavators (`bucket_*` params; TB235-class defaults).
struct BucketConfig {
  double length_m = 0.72, depth_m = 0.34, width_m = 0.6;  ///< default profile: docs/sim.md "Excavators"
  double pile_repose_rad = 0.6;    ///< loose soil of a dump pile settles to this slope
  double pile_reach_m = 1.5;       ///< how far from the pour point the pile may spread
  double min_load_drop_kg = 0.5;   ///< a drop of the bucket's load below this is noise, not a pour
  double capacity_m3 = 0;          ///< loose m^3 the bucket holds; 0 = its mesh's volume
  /// Bucket poses averaged over this many consecutive JointStates (centred, odd; 1 = none): the
  /// swept volume is a union, so the pose noise's extremes would widen and deepen the cut.
  int pose_window = 9;
  /// The default profile's mesh: (0, 0), (L, 0), (0.62 L, D), (0.12 L, 0.88 D) x width.
  ToolMesh mesh() const;
};

/// What a bucket sweep or pour did (volumes in m^3; bank = what the soil occupied in the ground,
/// loose soil counted at 1/swell).
struct BucketResult {
  double cut_volume_m3 = 0, cut_bank_m3 = 0;       ///< sweep: height removed, its bank equivalent
  double deposit_bank_m3 = 0, unknown_bank_m3 = 0, lost_bank_m3 = 0;  ///< pour: on known, unknown, off the map
  long cells_cut = 0, cells_unknown = 0, cells_deposit = 0;
  bool dropped = false;  ///< a sparse map had no room for the tiles (nothing written)
};

/// The bucket's swept volume over `poses` (T_map_bucket, at least two): stations interpolated so
/// no mesh vertex moves more than half a cell between two, each in turn cutting the cells whose
/// elevation lies above the mesh's bottom down to it (loose soil first), until `room_bank_m3`
/// (bank m^3 the bucket can still take) is used: the station that fills it cuts all its cells
/// by the same fraction, later ones nothing (a full bucket takes no more). Nothing is deposited:
/// the soil goes into the bucket (the caller carries cut_bank_m3). Unknown cells under it are
/// counted, not cut.
BucketResult runBucketSweep(LayeredMap& map, const SweepLayers& layers, const SweepConfig& cfg, const ToolMesh& tool,
                            const std::vector<Eigen::Isometry3d>& poses, double room_bank_m3, const Executor& ex);

/// Pours `bank_m3` of carried soil (swelled by cfg.swell) onto the cells within the tool's half
/// width of map point `at` (at least its own cell) and lets the loose soil slide toward
/// pile_repose_rad within pile_reach_m for at most `max_sweeps` Jacobi sweeps (loose soil moves
/// at most a cell per sweep; settlePile finishes the pile). Mass-conserving: Σ[(H − L) + L/s]
/// grows by bank_m3 less what fell off the map (lost_bank_m3).
BucketResult pourBucket(LayeredMap& map, const SweepLayers& layers, const SweepConfig& cfg, const BucketConfig& bucket,
                        const Eigen::Vector3d& at, double bank_m3, int max_sweeps);

/// Lets a pile's loose soil around `at` settle until no neighbouring pair of known cells is
/// steeper than pile_repose_rad by more than 0.1 mm per cell (or `max_sweeps`); returns the
/// sweeps run. Mass-conserving.
int settlePile(LayeredMap& map, const SweepLayers& layers, const BucketConfig& bucket, const Eigen::Vector3d& at,
               int max_sweeps);

/// Blade angle from the horizontal in the vertical plane along `t_hat`, measured through the
/// soil behind the edge (pi/2 upright, < pi/2 leaning back). NaN if the face is parallel to
/// the travel direction.
double bladeAngle(const Eigen::Isometry3d& T_map_blade, const Eigen::Vector2d& t_hat);

/// The soil a blade pushes, as blade_sweep's own bookkeeping knows it (SweepConfig::
/// surcharge_carried): the bank volume cut since the machine's pass began. A pass ends when a
/// sweep cuts nothing (the blade is out of the soil) or the edge moves against the blade's
/// normal (reversing): the pile stays where it was left and the next pass starts empty.
struct CarriedPile {
  double bank_m3 = 0.0;  ///< bank m³ cut since the pass began (capped at capacity / swell when carried_overflow_share is 0)
};

/// One complete swept-volume update on `map` (Alg. 1 lines 8-15 and Alg. 3): mesh, intersection,
/// FEE extraction, cut and deposit, per-step interpolation. `history` holds the poses from T0
/// (first) to T1 (last), at least two. Mutates the three layers; returns the record
/// (sweep_index and machine_id are left for the caller), or nullptr with the map unchanged when
/// a sparse map cannot allocate the tiles under the sweep within the memory budget
/// (LayeredMap::tryAllocateTile; the plugin counts it as dropped, reason "tile_budget").
/// With `pile` (and cfg.surcharge_carried) the record's V_Q and Q before and after the cut are
/// the carried pile's (loose volume = bank × swell, capped at the blade's capacity
/// width × height² / (2 tan carried_repose_rad), or beyond it by carried_overflow_share of the
/// excess); their variance is a quarter of the squared
/// difference to the mapped V_Q plus the mapped region's own. `pile` is updated.
std::shared_ptr<SweepRecord> runSweep(LayeredMap& map, const SweepLayers& layers, const SweepConfig& cfg,
                                      const std::vector<BladePose>& history, const Executor& ex,
                                      CarriedPile* pile = nullptr);

/// JSON object text of a record for the run report (mask and slices summarised by counts;
/// steps included when `with_steps`). NaN becomes null.
std::string sweepRecordJson(const SweepRecord& r, bool with_steps);

/// The plugin: keeps a pose history per machine_id and runs runSweep() when the blade edge has
/// moved more than the translation threshold or rotated more than the rotation threshold, and
/// at finish() for whatever motion is left over (counter `final_partial_sweeps`).
class BladeSweep : public Plugin {
 public:
  ParamSchema schema() const override;
  void configure(const Params& params) override;
  std::vector<LayerSpec> layers() const override;
  EventMask events() const override {
    return mask(EventKind::BladePose) | mask(EventKind::Pose) | mask(EventKind::JointState);
  }
  void start(ProcessContext& ctx) override;
  void process(ProcessContext& ctx, const Event& event) override;
  void finish(ProcessContext& ctx) override;

  const SweepConfig& config() const { return cfg_; }
  long sweeps() const { return sweeps_; }

 private:
  struct MachineState {
    std::vector<BladePose> history;  // T0 first
    CarriedPile pile;
  };
  struct Anchor {
    bool init = false;
    double offset_m = 0, stamp = 0;
  };
  /// The anchor update of one Pose (see GroundAnchorConfig).
  void anchorToGround(ProcessContext& ctx, const Pose& pose);
  GroundAnchorConfig anchor_cfg_;
  std::map<std::string, Anchor> anchors_;  // by machine id ("" = the Pose frame "base")
  SweepConfig cfg_;
  bool report_steps_ = true;
  SweepLayers ids_;
  /// Runs the sweep of `st.history` (>= 2 poses), reports and publishes its record, and keeps
  /// the last pose as the next sweep's T0.
  void sweepHistory(ProcessContext& ctx, MachineState& st, const std::string& machine_id, double stamp);
  std::map<std::string, MachineState> machines_;
  long sweeps_ = 0;

  // Excavator buckets (JointState events; docs in the README, "Buckets").
  struct BucketState {
    std::vector<Eigen::Isometry3d> raw;    ///< the latest received poses (the smoothing window)
    std::vector<Eigen::Isometry3d> poses;  ///< smoothed, since the last bucket sweep (first = its start)
    bool pile_pending = false;             ///< poured since the pile last settled, at `pile_at`
    Eigen::Vector3d pile_at = Eigen::Vector3d::Zero();
    double carried_bank_m3 = 0;            ///< soil cut and not yet poured
    double last_load_kg = std::numeric_limits<double>::quiet_NaN();
  };
  void processJointState(ProcessContext& ctx, const JointState& js);
  /// Appends the smoothed pose of the window's centre (or, when `flush`, of every pose left,
  /// with the window shrinking at the end) to st.poses; sweeps when the lip has moved enough.
  void advanceBucket(ProcessContext& ctx, BucketState& st, bool flush);
  void sweepBucket(ProcessContext& ctx, BucketState& st);
  void settleBucketPile(ProcessContext& ctx, BucketState& st);
  /// Pours the share of the carried soil the load's drop to `load_kg` stands for, at `lip`.
  void pourShare(ProcessContext& ctx, BucketState& st, const Eigen::Vector3d& lip, double load_kg);
  /// The ground anchor's height correction of machine `machine_id` (m; 0 without one).
  double anchorOffset(const std::string& machine_id) const;
  /// The height correction of a machine's tool poses: minus its survey datum offset where
  /// lidar_fusion published one (use_survey_datum), else its ground anchor.
  double heightCorrection(ProcessContext& ctx, const std::string& machine_id);
  std::set<std::string> datum_machines_;  // machines whose tools took a datum offset
  BucketConfig bucket_cfg_;
  ToolMesh tool_;
  std::map<std::string, BucketState> buckets_;
};

}  // namespace terramap::plugins
