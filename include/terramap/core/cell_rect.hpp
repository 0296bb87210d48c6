#pragma once
/// \file
/// CellRect: the one box of grid cells in terramap (tiles, map windows, regions that came in on
/// a move, swept footprints, the simulator's changed nodes).
///
/// Half-open: rows [r0, r0 + rows) x columns [c0, c0 + cols). Any size <= 0 is empty; a
/// default CellRect is empty. The index space (logical, ring-buffer, simulator node) is the
/// one of whoever hands the box out, and is said there; a CellRect never wraps around.
/// Threading: a plain value type. Throws: nothing.
#include <algorithm>

namespace terramap {

struct CellRect {
  int r0 = 0, c0 = 0, rows = 0, cols = 0;

  /// The box of rows [i0, i1] x columns [j0, j1], both ends included (empty if i1 < i0 or
  /// j1 < j0), for code that tracks first and last indices.
  static CellRect inclusive(int i0, int j0, int i1, int j1) { return {i0, j0, i1 - i0 + 1, j1 - j0 + 1}; }

  long cells() const { return empty() ? 0L : static_cast<long>(rows) * cols; }
  bool empty() const { return rows <= 0 || cols <= 0; }
  /// One past the last row / column.
  int rowEnd() const { return r0 + rows; }
  int colEnd() const { return c0 + cols; }
  bool contains(int i, int j) const { return i >= r0 && j >= c0 && i < r0 + rows && j < c0 + cols; }
  /// Row-major offset of cell (i, j) in a dense rows x cols array of the box; (i, j) must be inside.
  long local(int i, int j) const { return static_cast<long>(i - r0) * cols + (j - c0); }
  /// Grows the box to the smallest one that also covers `b` (nothing if `b` is empty).
  void add(const CellRect& b) {
    if (b.empty()) return;
    if (empty()) {
      *this = b;
      return;
    }
    const int re = std::max(rowEnd(), b.rowEnd()), ce = std::max(colEnd(), b.colEnd());
    r0 = std::min(r0, b.r0);
    c0 = std::min(c0, b.c0);
    rows = re - r0;
    cols = ce - c0;
  }
  bool operator==(const CellRect& o) const {
    return r0 == o.r0 && c0 == o.c0 && rows == o.rows && cols == o.cols;
  }
  bool operator!=(const CellRect& o) const { return !(*this == o); }
};

}  // namespace terramap
