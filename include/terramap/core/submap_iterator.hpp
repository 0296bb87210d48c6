#pragma once
/// \file
/// The cells of a logical rectangle of a LayeredMap, visited as per-tile contiguous spans.
///
/// A logical index maps to a ring-buffer index (logical + start) mod size, and buffer cells are
/// stored in square tiles, row-major with stride tileSize() (layered_map.hpp). So one logical
/// row of a rectangle is, in memory, a few runs: it breaks where the buffer wraps around and
/// where it crosses into the next tile. SubmapIterator hands out those runs (Span), so a kernel
/// can loop over plain pointers; axisCell() is the per-axis arithmetic behind it, for kernels
/// that keep their own per-row / per-column lookup tables.
///
/// Units and frames: logical cell indices (geometry.hpp) in, buffer tiles and offsets out; the
/// iterator reads no layer, so NaN means nothing to it. Order: row by row (increasing logical
/// i), and along a row by increasing logical j: the order of a row-major dense copy.
/// Threading: a value type over a const map; valid until the map moves (move() changes the
/// start index). Throws: nothing; the rectangle is clipped to the map (possibly to nothing).
#include <terramap/core/cell_rect.hpp>
#include <terramap/core/layered_map.hpp>

#include <algorithm>

namespace terramap {

/// Where logical index `logical` of one axis lives: buffer tile row (or column) and the
/// offset inside that tile, for a ring buffer of `size` cells starting at `start`, cut into
/// tiles of `tile_size`. Any integer `logical` and `start` (floor modulo).
struct AxisCell {
  int tile, offset;
};
inline AxisCell axisCell(int logical, int start, int size, int tile_size) {
  int b = (logical + start) % size;
  if (b < 0) b += size;
  const int t = b / tile_size;
  return {t, b - t * tile_size};
}

class SubmapIterator {
 public:
  /// One run: logical row `i`, columns [j, j + n), stored at tileData(layer, tile)[offset + k]
  /// for k in [0, n) (n >= 1).
  struct Span {
    int i, j, n;
    int tile;
    long offset;
  };

  /// The spans of logical rectangle `rect` (clipped to the map).
  SubmapIterator(const LayeredMap& map, CellRect rect) : map_(&map) {
    const Size& sz = map.geometry().size();
    const int i1 = std::min(rect.rowEnd(), sz.x()), j1 = std::min(rect.colEnd(), sz.y());
    rect_.r0 = std::max(rect.r0, 0);
    rect_.c0 = std::max(rect.c0, 0);
    rect_.rows = std::max(0, i1 - rect_.r0);
    rect_.cols = std::max(0, j1 - rect_.c0);
    i_ = rect_.r0;
    j_ = rect_.c0;
    if (!rect_.empty()) load();
  }

  /// The clipped rectangle.
  const CellRect& rect() const { return rect_; }
  bool done() const { return rect_.empty() || i_ >= rect_.rowEnd(); }
  /// The current span; only while !done().
  const Span& operator*() const { return span_; }
  const Span* operator->() const { return &span_; }
  SubmapIterator& operator++() {
    j_ += span_.n;
    if (j_ >= rect_.colEnd()) {
      j_ = rect_.c0;
      ++i_;
    }
    if (!done()) load();
    return *this;
  }

 private:
  void load() {
    const int T = map_->tileSize();
    const Size& sz = map_->geometry().size();
    const Index& st = map_->startIndex();
    const AxisCell r = axisCell(i_, st.x(), sz.x(), T), c = axisCell(j_, st.y(), sz.y(), T);
    // The run ends at the tile's right edge, at the buffer's right edge (wrap-around) or at the
    // rectangle's, whichever comes first.
    const int buffer_col = c.tile * T + c.offset;
    const int n = std::min({T - c.offset, sz.y() - buffer_col, rect_.colEnd() - j_});
    span_ = {i_, j_, n, r.tile * map_->tileCols() + c.tile, static_cast<long>(r.offset) * T + c.offset};
  }

  const LayeredMap* map_;
  CellRect rect_;
  int i_ = 0, j_ = 0;
  Span span_{0, 0, 0, 0, 0};
};

}  // namespace terramap
