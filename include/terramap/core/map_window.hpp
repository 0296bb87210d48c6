#pragma once
/// \file
/// MapWindow: a rectangle of *logical* map cells gathered into dense row-major arrays, and the
/// changed cells scattered back. The blind-mapping kernels (blade_sweep, soil_erosion) work on
/// a few thousand cells around the blade; copying them into a dense local array once costs
/// less than per-cell ring-buffer arithmetic, lets the kernels compute in double precision,
/// and writing back only changed cells keeps copy-on-write snapshots sharing untouched tiles.
///
/// Units and frames: cells are *logical* indices (geometry.hpp: row i grows towards -x, column
/// j towards -y); the dense arrays hold whatever the layer holds, converted to T (float32 →
/// double is exact). NaN (= unknown) is copied like any value; an unallocated sparse tile reads
/// as the layer's fill value.
///
/// Threading: gather() is const on the map and may run concurrently with other readers;
/// scatterChanged() mutates the map and needs the exclusive access a plugin has in process().
/// Throws: gather()/scatterChanged() throw LayerError on a bad layer id (LayeredMap::layerInfo);
/// scatterChanged() throws TileBudgetError when a sparse map cannot allocate a tile it needs
/// (ask tryAllocate() first); nothing else. The constructor clips instead of throwing: a window off the map is empty.
#include <terramap/core/layered_map.hpp>
#include <terramap/core/submap_iterator.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

namespace terramap {

class MapWindow {
 public:
  MapWindow() = default;
  /// Window [i0, i0+rows) x [j0, j0+cols) of logical indices, clipped to the map (may be empty).
  MapWindow(const LayeredMap& map, int i0, int j0, int rows, int cols) {
    const Size& sz = map.geometry().size();
    const int i1 = std::min(i0 + rows, sz.x()), j1 = std::min(j0 + cols, sz.y());
    i0_ = std::max(i0, 0);
    j0_ = std::max(j0, 0);
    rows_ = std::max(0, i1 - i0_);
    cols_ = std::max(0, j1 - j0_);
    T_ = map.tileSize();
    map_tile_cols_ = map.tileCols();
    const Index start = map.startIndex();
    // Per row/column: which tile row/column (as an index into the distinct ones met) and the
    // offset inside it (axisCell, submap_iterator.hpp).
    auto build = [&](int first, int n, int size, int st, std::vector<int>& tile, std::vector<int>& off,
                     std::vector<int>& distinct) {
      tile.resize(static_cast<size_t>(n));
      off.resize(static_cast<size_t>(n));
      for (int k = 0; k < n; ++k) {
        const AxisCell cell = axisCell(first + k, st, size, T_);
        const int t = cell.tile;
        auto it = std::find(distinct.begin(), distinct.end(), t);
        if (it == distinct.end()) {
          distinct.push_back(t);
          it = distinct.end() - 1;
        }
        tile[static_cast<size_t>(k)] = static_cast<int>(it - distinct.begin());
        off[static_cast<size_t>(k)] = cell.offset;
      }
    };
    build(i0_, rows_, sz.x(), start.x(), row_tile_, row_off_, tile_rows_);
    build(j0_, cols_, sz.y(), start.y(), col_tile_, col_off_, tile_cols_);
  }

  /// The window of the logical cells under the bounding box of `points` (map frame x, y, m),
  /// clipped to the map: what an oriented region (a blade's ROI, a soil wedge) needs gathered.
  /// The region's own test decides which cells of the window belong to it.
  static MapWindow covering(const LayeredMap& map, const std::vector<Eigen::Vector2d>& points) {
    const Geometry& geo = map.geometry();
    const double res = geo.resolution();
    const double xmax = geo.center().x() + 0.5 * geo.length().x(), ymax = geo.center().y() + 0.5 * geo.length().y();
    double umin = 1e300, umax = -1e300, vmin = 1e300, vmax = -1e300;
    for (const Eigen::Vector2d& p : points) {
      umin = std::min(umin, (xmax - p.x()) / res);
      umax = std::max(umax, (xmax - p.x()) / res);
      vmin = std::min(vmin, (ymax - p.y()) / res);
      vmax = std::max(vmax, (ymax - p.y()) / res);
    }
    if (points.empty() || !(umax - umin < 1e9) || !(vmax - vmin < 1e9)) return MapWindow();
    // Clamped before the cast: a region far off the map must not overflow int.
    const double lo_i = -1.0, hi_i = geo.size().x() + 1.0, lo_j = -1.0, hi_j = geo.size().y() + 1.0;
    const int i0 = static_cast<int>(std::floor(std::clamp(umin, lo_i, hi_i)));
    const int i1 = static_cast<int>(std::floor(std::clamp(umax, lo_i, hi_i)));
    const int j0 = static_cast<int>(std::floor(std::clamp(vmin, lo_j, hi_j)));
    const int j1 = static_cast<int>(std::floor(std::clamp(vmax, lo_j, hi_j)));
    return MapWindow(map, i0, j0, i1 - i0 + 1, j1 - j0 + 1);
  }

  int i0() const { return i0_; }
  int j0() const { return j0_; }
  int rows() const { return rows_; }
  int cols() const { return cols_; }
  long size() const { return static_cast<long>(rows_) * cols_; }
  bool empty() const { return rows_ == 0 || cols_ == 0; }
  bool contains(int i, int j) const { return i >= i0_ && j >= j0_ && i < i0_ + rows_ && j < j0_ + cols_; }
  /// Dense index of logical cell (i, j); the cell must be inside.
  long local(int i, int j) const { return static_cast<long>(i - i0_) * cols_ + (j - j0_); }

  /// Copies layer `id` into `out` (resized to rows*cols, row-major). Unallocated sparse tiles
  /// read as the layer's fill value.
  template <class T>
  void gather(const LayeredMap& map, LayerId id, std::vector<T>& out) const {
    out.resize(static_cast<size_t>(size()));
    const float fill = map.layerInfo(id).fill;
    std::vector<const float*> tiles(tile_rows_.size() * tile_cols_.size());
    for (size_t a = 0; a < tile_rows_.size(); ++a)
      for (size_t b = 0; b < tile_cols_.size(); ++b)
        tiles[a * tile_cols_.size() + b] = map.tileData(id, tile_rows_[a] * map_tile_cols_ + tile_cols_[b]);
    for (int r = 0; r < rows_; ++r) {
      const size_t tr = static_cast<size_t>(row_tile_[static_cast<size_t>(r)]) * tile_cols_.size();
      const long ro = static_cast<long>(row_off_[static_cast<size_t>(r)]) * T_;
      T* dst = out.data() + static_cast<long>(r) * cols_;
      for (int c = 0; c < cols_; ++c) {
        const float* t = tiles[tr + static_cast<size_t>(col_tile_[static_cast<size_t>(c)])];
        dst[c] = static_cast<T>(t ? t[ro + col_off_[static_cast<size_t>(c)]] : fill);
      }
    }
  }

  /// LayeredMap::tryAllocateTile(t, layers) for every tile the window touches: true when all of
  /// them hold (or could allocate) those layers' tiles within the memory budget. On false some
  /// may have been allocated (holding the fill, so reads do not change). What a plugin that
  /// scatters into a sparse map asks before it changes anything, to drop the update whole
  /// rather than half of it. Needs the exclusive access scatterChanged() does.
  bool tryAllocate(LayeredMap& map, std::initializer_list<LayerId> layers) const {
    for (const int tr : tile_rows_)
      for (const int tc : tile_cols_)
        if (!map.tryAllocateTile(tr * map_tile_cols_ + tc, layers)) return false;
    return true;
  }

  /// Writes `after` into layer `id` for every cell whose float32 value differs (bitwise, so a
  /// NaN that stays NaN is no change) from `before`. Returns the number of cells written.
  template <class T>
  long scatterChanged(LayeredMap& map, LayerId id, const std::vector<T>& before,
                      const std::vector<T>& after) const {
    std::vector<float*> tiles(tile_rows_.size() * tile_cols_.size(), nullptr);
    long n = 0;
    for (int r = 0; r < rows_; ++r) {
      const size_t tr = static_cast<size_t>(row_tile_[static_cast<size_t>(r)]) * tile_cols_.size();
      const long ro = static_cast<long>(row_off_[static_cast<size_t>(r)]) * T_;
      for (int c = 0; c < cols_; ++c) {
        const size_t k = static_cast<size_t>(r) * static_cast<size_t>(cols_) + static_cast<size_t>(c);
        const float fa = static_cast<float>(after[k]), fb = static_cast<float>(before[k]);
        if (std::memcmp(&fa, &fb, sizeof(float)) == 0) continue;
        const size_t ti = tr + static_cast<size_t>(col_tile_[static_cast<size_t>(c)]);
        if (!tiles[ti]) {
          const size_t a = ti / tile_cols_.size(), b = ti % tile_cols_.size();
          tiles[ti] = map.mutableTileData(id, tile_rows_[a] * map_tile_cols_ + tile_cols_[b]);
        }
        tiles[ti][ro + col_off_[static_cast<size_t>(c)]] = fa;
        ++n;
      }
    }
    return n;
  }

 private:
  int i0_ = 0, j0_ = 0, rows_ = 0, cols_ = 0, T_ = 64, map_tile_cols_ = 1;
  std::vector<int> row_tile_, row_off_, col_tile_, col_off_;
  std::vector<int> tile_rows_, tile_cols_;  // distinct tile rows / columns met
};

}  // namespace terramap
