#pragma once
/// \file
/// LayeredMap: named float32 layers over one Geometry, stored in square tiles.
///
/// - NaN means "unknown" in every layer unless the layer's fill value says otherwise.
/// - Storage is tile-major in *buffer* space: the map is a ring buffer, so a logical index
///   (see geometry.hpp) maps to buffer index (logical + start) mod size. A tile is a square
///   of `tileSize()` x `tileSize()` buffer cells (edge tiles are partial: see tileRect()).
///   Kernels run one task per tile (parallel.hpp) and so never share a cache line of output.
/// - Tiles are reference counted. `snapshot()` copies only the references; the first write to
///   a shared tile copies it (copy-on-write), so a snapshot stays consistent while the owner
///   keeps writing, and costs memory only for the tiles that change.
/// - Sparse mode: tiles are allocated on first write; an unallocated tile reads as the fill.
///   The tiles a sparse map holds count against the memory budget (memory_budget.hpp): at most
///   memoryBudget() / tileBytes() tiles over all layers. Past that, mutableTileData() throws
///   TileBudgetError and tryAllocateTile() returns false, so a kernel can drop what it cannot
///   store (lidar_fusion, blade_sweep and soil_erosion count it as "tile_budget") instead of the
///   process running out of memory. A tile that a move() resets completely, with no write to it
///   since, is freed again, so a sparse map moving with a machine holds the tiles near its data,
///   not every tile it ever touched. (Dense maps are checked once, in addLayer().)
///
/// Threading: const member functions may run concurrently with each other. Mutations of
/// *different* tiles (mutableTileData, set on cells of different tiles) may run concurrently;
/// everything else that mutates (addLayer, move, fill, ...) needs exclusive access.
/// A snapshot shares no mutable state with its source and may live on another thread.
#include <terramap/core/cell_rect.hpp>
#include <terramap/core/error.hpp>
#include <terramap/core/geometry.hpp>

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <atomic>
#include <memory>
#include <string>
#include <vector>

namespace terramap {

using LayerId = int;

struct LayerInfo {
  std::string name;
  std::string unit;   ///< SI unit, e.g. "m", "m^2", "s", "1" (dimensionless), "count"
  float fill = std::numeric_limits<float>::quiet_NaN();  ///< value of cells never written
};

struct MapOptions {
  int tile_size = 64;    ///< cells per tile edge, in [8, 1024]
  bool sparse = false;   ///< allocate tiles on first write
};

/// What LayeredMap::move() did.
struct MoveResult {
  Index shift_cells{0, 0};           ///< logical shift applied (cells, + = towards +x/+y)
  std::vector<CellRect> new_regions;  ///< *logical* index rectangles that came in (reset to fill)
};

class TERRAMAP_API LayeredMap {
 public:
  /// \throws ConfigError on a tile size out of [8, 1024].
  explicit LayeredMap(const Geometry& geometry, MapOptions options = {});

  const Geometry& geometry() const { return geometry_; }
  const MapOptions& options() const { return options_; }
  int tileSize() const { return options_.tile_size; }

  // ---- layers ------------------------------------------------------------------------------
  /// Adds a layer filled with `fill`. \throws LayerError if the name exists or is empty.
  LayerId addLayer(const std::string& name, const std::string& unit,
                   float fill = std::numeric_limits<float>::quiet_NaN());
  bool hasLayer(const std::string& name) const;
  /// \throws LayerError naming the missing layer and the closest existing names.
  LayerId layerId(const std::string& name) const;
  const LayerInfo& layerInfo(LayerId id) const;
  int layerCount() const { return static_cast<int>(layers_.size()); }
  std::vector<std::string> layerNames() const;

  // ---- tiles (buffer space) ----------------------------------------------------------------
  int tileRows() const { return tile_rows_; }
  int tileCols() const { return tile_cols_; }
  int tileCount() const { return tile_rows_ * tile_cols_; }
  /// Buffer-space rectangle of tile `t` (row-major tile numbering).
  CellRect tileRect(int t) const { return tileRectOf(geometry_.size(), options_.tile_size, t); }
  /// The tiling itself: rectangle of tile `t` of a size.x() x size.y() cell grid cut into
  /// tile_size squares, row-major, clipped at the far edges (the .tmap format uses it too).
  static CellRect tileRectOf(const Size& size, int tile_size, int t);
  /// Tile that holds buffer cell (r, c).
  int tileOfBuffer(int r, int c) const {
    return (r / options_.tile_size) * tile_cols_ + c / options_.tile_size;
  }
  /// Read-only tile data, row-major with stride tileSize(); nullptr if not allocated (sparse),
  /// in which case every cell reads as the layer's fill.
  const float* tileData(LayerId id, int t) const;
  /// Writable tile data; allocates (sparse) or un-shares (copy-on-write) as needed.
  /// \throws TileBudgetError when allocating the tile would take the map past the memory
  /// budget (sparse maps); nothing changes then.
  float* mutableTileData(LayerId id, int t);
  /// Allocates tile `t` of each of `layers` that is not allocated yet, all or none: true when
  /// they fit the memory budget with the tiles the map already holds (or need nothing), false,
  /// allocating none, when they do not. A kernel that writes tile `t` of these layers calls it
  /// first and drops the tile's data on false; its mutableTileData() calls then allocate nothing.
  /// Newly allocated tiles hold the layer's fill (reading them is unchanged). Threading: as
  /// mutableTileData (different tiles concurrently). Negative ids (a layer the caller's map
  /// does not have) are skipped. \throws LayerError on an id >= layerCount().
  bool tryAllocateTile(int t, std::initializer_list<LayerId> layers);
  /// Bytes of one tile of one layer: tileSize()^2 x 4.
  std::uint64_t tileBytes() const {
    return static_cast<std::uint64_t>(options_.tile_size) * static_cast<std::uint64_t>(options_.tile_size) * sizeof(float);
  }
  /// Tiles (ascending) holding a cell within `cells` cells (Chebyshev, logical) of a cell of
  /// one of `tiles`: the output tiles a kernel of half-width `cells` reaches from changed input
  /// tiles (ProcessContext::changedTiles). Grown cyclically over the ring buffer, one tile more
  /// where the ring's partial last tile is narrower than `cells`; never too few, sometimes more.
  std::vector<int> tilesWithin(const std::vector<int>& tiles, int cells) const;
  bool tileAllocated(LayerId id, int t) const { return tileData(id, t) != nullptr; }
  /// How many times tile `t` of layer `id` was handed out for writing (mutableTileData, and
  /// so set/fill/writeLayer/move) or reset: equal counts at two moments mean the tile was not
  /// written in between. What ChangeTracker (plugin.hpp) compares; copied with the map.
  std::uint64_t tileWrites(LayerId id, int t) const;
  /// Number of allocated tiles over all layers (memory = this * tileBytes()). Tiles a snapshot
  /// still shares after this map replaced them (copy-on-write) are the snapshot's, not counted.
  long allocatedTiles() const { return allocated_.get(); }

  // ---- index mapping -----------------------------------------------------------------------
  const Index& startIndex() const { return start_; }
  Index bufferIndex(const Index& logical) const;
  Index logicalIndex(const Index& buffer) const;

  // ---- cells (logical indices; bounds-checked, for tests and light use) ---------------------
  /// \throws LayerError on a bad layer id, std::out_of_range on an index outside the map.
  float at(LayerId id, const Index& logical) const;
  void set(LayerId id, const Index& logical, float value);

  // ---- whole layers ------------------------------------------------------------------------
  /// Sets every cell. In a sparse map, filling with the layer's fill value frees its tiles;
  /// another value needs all of them (\throws TileBudgetError beyond the memory budget, the
  /// layer unchanged).
  void fill(LayerId id, float value);
  /// Copies layer `id` into `dst`, a caller-owned column-major buffer of rows x cols floats in
  /// logical order: dst[i + j * rows] is cell (i, j). `rows`, `cols` must equal geometry().size().
  /// The map never allocates or frees the buffer (see abi.hpp, "Memory rule of the boundary").
  /// \throws LayerError on a bad id or a size that differs from the geometry.
  void readLayer(LayerId id, float* dst, long rows, long cols) const;
  /// Writes `src` (same layout as readLayer) into layer `id`.
  /// \throws LayerError on a bad id or a size that differs from the geometry; TileBudgetError
  /// when a sparse map cannot hold every tile of the layer (the layer unchanged).
  void writeLayer(LayerId id, const float* src, long rows, long cols);
  /// Layer as a rows x cols matrix in logical order (row i, column j). Inline and local to the
  /// calling library or plugin (TERRAMAP_LOCAL): the matrix is allocated by the build that
  /// frees it, whatever its compile flags. \throws LayerError on a bad id.
  TERRAMAP_LOCAL Eigen::MatrixXf toMatrix(LayerId id) const {
    Eigen::MatrixXf m(geometry_.size().x(), geometry_.size().y());
    readLayer(id, m.data(), m.rows(), m.cols());
    return m;
  }
  /// \throws LayerError on a bad id or if the matrix size differs from the geometry.
  TERRAMAP_LOCAL void fromMatrix(LayerId id, const Eigen::MatrixXf& m) {
    writeLayer(id, m.data(), m.rows(), m.cols());
  }

  // ---- motion ------------------------------------------------------------------------------
  /// Re-centres the map on the cell-aligned position nearest `new_center` by shifting the ring
  /// buffer (no data copy). Cells that leave are forgotten; cells that come in are reset to
  /// each layer's fill and reported as logical rectangles.
  MoveResult move(const Position& new_center);

  // ---- snapshots ---------------------------------------------------------------------------
  /// A consistent copy sharing tiles copy-on-write; O(layers x tiles) pointer copies.
  LayeredMap snapshot() const { return *this; }

  /// Copies share every tile; after a copy both maps treat all their tiles as shared and copy
  /// each one before its first write (the copy-on-write is decided by generations this map owns,
  /// never by a reference count another thread may be dropping: that would be a data race with
  /// the other thread's last reads). Taking the copy must not overlap this map's writes.
  LayeredMap(const LayeredMap& other) = default;
  LayeredMap& operator=(const LayeredMap& other) = default;
  LayeredMap(LayeredMap&& other) noexcept = default;
  LayeredMap& operator=(LayeredMap&& other) noexcept = default;
  ~LayeredMap() = default;

 private:
  using TilePtr = std::shared_ptr<float[]>;
  TilePtr newTile(float fill) const;
  void resetLogicalRect(const CellRect& logical);
  /// Counts `n` more tiles if the budget holds them (false otherwise). Thread-safe.
  bool reserveTiles(long n);
  /// Allocates every missing tile of layer `id`, or none. \throws TileBudgetError.
  void allocateLayer(LayerId id);
  TileBudgetError budgetError(LayerId id, long more) const;

  Geometry geometry_;
  MapOptions options_;
  int tile_rows_ = 0, tile_cols_ = 0;
  Index start_{0, 0};
  std::vector<LayerInfo> layers_;
  std::vector<std::vector<TilePtr>> tiles_;  // [layer][tile]
  // [layer][tile]; tasks writing different tiles touch different elements, so no race.
  std::vector<std::vector<std::uint64_t>> writes_;
  // Copy-on-write bookkeeping: a tile is this map's own (writable in place) when owned_ equals
  // generation_; every copy of the map (snapshot) bumps the generation of both, so all tiles
  // then count as shared. [layer][tile], like writes_.
  /// The map's copy-on-write generation. Copying it (copying the map) moves the source past
  /// every stamp it handed out and starts the copy past them too; atomic because copying a
  /// const map (two readers copying one shared snapshot) bumps it.
  struct Generation {
    mutable std::atomic<std::uint64_t> value{1};
    Generation() = default;
    Generation(const Generation& o) : value(o.value.fetch_add(1, std::memory_order_relaxed) + 1) {}
    Generation& operator=(const Generation& o) {
      value.store(o.value.fetch_add(1, std::memory_order_relaxed) + 1, std::memory_order_relaxed);
      return *this;
    }
    Generation(Generation&& o) noexcept : value(o.value.load(std::memory_order_relaxed)) {}
    Generation& operator=(Generation&& o) noexcept {
      value.store(o.value.load(std::memory_order_relaxed), std::memory_order_relaxed);
      return *this;
    }
    std::uint64_t get() const { return value.load(std::memory_order_relaxed); }
  };
  Generation generation_;
  std::vector<std::vector<std::uint64_t>> owned_;
  /// Allocated tiles over all layers; atomic because tasks allocating different tiles add to it
  /// concurrently. Copies take the value (a copy holds the same tiles).
  struct TileCount {
    std::atomic<long> value{0};
    TileCount() = default;
    TileCount(const TileCount& o) : value(o.get()) {}
    TileCount& operator=(const TileCount& o) {
      value.store(o.get(), std::memory_order_relaxed);
      return *this;
    }
    TileCount(TileCount&& o) noexcept : value(o.get()) {}
    TileCount& operator=(TileCount&& o) noexcept {
      value.store(o.get(), std::memory_order_relaxed);
      return *this;
    }
    long get() const { return value.load(std::memory_order_relaxed); }
  };
  TileCount allocated_;
  /// Per [layer][tile], the part of the tile (rows r0..r1, columns c0..c1, tile-relative,
  /// half-open) that may hold something other than the fill: the whole tile once handed out for
  /// writing, shrunk as move() resets rows or columns from its edges; empty = the tile can be
  /// freed. Only sparse maps free tiles. Tasks writing different tiles touch different elements.
  using Extent = std::array<std::int16_t, 4>;
  std::vector<std::vector<Extent>> written_;
};

}  // namespace terramap
