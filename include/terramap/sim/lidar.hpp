#pragma once
/// \file
/// Ray-cast LiDAR against the truth terrain: multi-beam spinning sensors (32/64/128-beam
/// presets) and single-line scanners, with Gaussian range noise and random dropouts; and depth
/// cameras (SensorSpec::Type::DepthCamera: a pinhole whose points are in the optical frame,
/// row-major, depth noise growing with depth squared, depth range on the optical z).
/// Rays are cast from one sensor pose per scan (the cloud is motion-compensated, as most
/// drivers deliver it). Points are in the sensor frame, column-major (all beams of column 0,
/// then column 1, ...); misses and dropouts are omitted unless keep_dropouts (then NaN).
/// Noise is a counter-based hash of (key, ray index), so the cloud is bit-identical for any
/// thread count and chunking. Intensity = |cos(incidence)| (Lambertian, 0..1).
#include <terramap/core/events.hpp>
#include <terramap/core/parallel.hpp>
#include <terramap/sim/machine_shape.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/sim/truth_terrain.hpp>

#include <cstdint>
#include <memory>
#include <vector>

namespace terramap::sim {

/// splitmix64 finaliser: the counter-based generator behind all per-ray noise.
std::uint64_t mixBits(std::uint64_t x);
/// Uniform (0, 1) from a 64-bit hash.
inline double unitFromBits(std::uint64_t h) { return (static_cast<double>(h >> 11) + 0.5) * (1.0 / 9007199254740992.0); }
/// Standard normal deviate from a 64-bit hash (Marsaglia-Tsang ziggurat, 128 layers): ~99 % of
/// draws cost a table look-up and a multiply; the rest draw further bits from mixBits(h + k).
/// Deterministic in `h`, thread-safe.
double gaussianFromBits(std::uint64_t h);

class LidarModel {
 public:
  explicit LidarModel(const SensorSpec& spec);
  ~LidarModel();
  LidarModel(LidarModel&&) noexcept;
  LidarModel& operator=(LidarModel&&) noexcept;
  const SensorSpec& spec() const { return spec_; }
  std::size_t raysPerScan() const { return dirs_.size(); }
  /// Largest ray length t a scan can return (m): max_range_m for a LiDAR; for a depth camera
  /// the maximum depth over the smallest optical z of its rays (the image corner).
  double maxRayLength() const { return t_max_; }
  /// Unit ray directions in the sensor frame, in output order.
  const std::vector<Eigen::Vector3d>& directions() const { return dirs_; }

  /// Casts every ray against the terrain's ray-casting view (TruthTerrain::refreshPyramid) and
  /// the machines' boxes (`obstacles`, map frame, may be null or empty): the nearer hit wins, so
  /// a machine returns points on itself and hides the ground behind it. `noise_key` must differ
  /// per scan (e.g. hash of seed, sensor, scan index). Runs on `exec` in fixed chunks of columns
  /// (serial if null). Returns the number of hits. One scan at a time per model (it reuses the
  /// model's buffers); different models may scan concurrently.
  ///
  /// With spec().reuse_casts, a sensor that scans from the same pose (bit for bit) as in its
  /// previous scan, over the same terrain object, keeps every ray's terrain hit; in its next
  /// scan from that pose, a ray whose table row and cells are unchanged since
  /// (TruthTerrain::blockRevision, ScanCaster::changedRows) takes its kept hit instead of
  /// a new cast. The result is identical (tested); a parked sensor or one on a standing
  /// excavator skips most of its casts, one that moves keeps nothing (and pays nothing for it).
  /// The boxes, dropouts and noise are drawn anew every scan.
  std::size_t scan(const TruthTerrain& terrain, const Eigen::Isometry3d& T_map_sensor, std::uint64_t noise_key,
                   const Executor* exec, std::vector<PointXYZI>& out,
                   const std::vector<PlacedBox>* obstacles = nullptr) const;
  /// Rays of the last scan that took their kept terrain hit instead of a cast (reuse_casts).
  std::size_t keptLastScan() const;

 private:
  /// Lower bound of d_z / |d_xy| over all rays once rotated into the map (ScanCaster input).
  double minSlope(const Eigen::Matrix3d& R_map_sensor) const;
  /// Where a ray stopped: ray length t (m, NaN = nothing), on a machine box (its normal) or on
  /// the terrain (the cell (ci, cj) hit).
  struct RayHit {
    double t;
    bool on_machine;
    int ci, cj;
    Eigen::Vector3d normal;
  };
  /// The point ray k (ds sensor frame, dm map frame) returns from `hit`: a camera's depth range,
  /// the dropout, the Lambertian intensity and the range or depth noise, drawn from the hash of
  /// (noise_key, k). Appends it, or a NaN point with keep_dropouts, to `pts`.
  void emitPoint(const TruthTerrain& terrain, const Eigen::Vector3d& o, const Eigen::Vector3d& ds,
                 const Eigen::Vector3d& dm, const RayHit& hit, std::uint64_t noise_key, std::size_t k,
                 std::vector<PointXYZI>& pts) const;

  /// What one scan's chunks share, and the scratch of one chunk's row (scan()'s steps).
  struct ScanJob;
  struct RowScratch;
  /// Builds the horizon table for this scan unless the kept one still holds, and says whether
  /// the kept hits may serve it (`still`: the sensor has not moved, so it keeps this scan's).
  bool prepareCasts(const TruthTerrain& terrain, const Eigen::Isometry3d& T_map_sensor, const Executor* exec,
                    bool& still) const;
  /// The points of the rows of chunk `ch` into its part (kKeep: the sensor keeps its hits).
  template <bool kKeep>
  void scanChunk(const ScanJob& job, int ch) const;
  /// Row c's terrain hits into rs: kept hits where they hold, the other rays cast as one batch.
  template <bool kKeep>
  void castRow(const ScanJob& job, int c, RowScratch& rs, std::size_t& used) const;
  /// Row c's points from its terrain hits and the machines' boxes.
  void emitRow(const ScanJob& job, int c, RowScratch& rs, std::vector<PointXYZI>& pts) const;
  /// The parts in chunk order into `out`; the number of hits (non-NaN points).
  std::size_t gatherParts(int chunks, std::vector<PointXYZI>& out) const;

  SensorSpec spec_;
  std::vector<Eigen::Vector3d> dirs_;
  std::vector<double> elevations_;  ///< beam elevations (rad); empty for a depth camera
  std::vector<double> beam_slopes_;  ///< their tangents (the machine boxes' per-beam culling)
  int B_ = 0, C_ = 0;               ///< rays per chunked row (beams / pixels of an image row), rows
  bool camera_ = false;
  double t_max_ = 0;
  double z_near_ = 0;               ///< depth camera: least depth of a ray hit (m)
  struct Scratch;                   ///< horizon table and per-chunk outputs, reused per scan
  std::unique_ptr<Scratch> scratch_;
  int columns_per_chunk_ = 16;
};

}  // namespace terramap::sim
