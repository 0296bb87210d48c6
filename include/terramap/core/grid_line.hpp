#pragma once
/// \file
/// GridLine: the cells a 2-D ray or segment crosses, in order (a DDA after Amanatides & Woo,
/// "A Fast Voxel Traversal Algorithm", 1987), one 4-connected step at a time.
///
/// Units and frames: *grid coordinates* (u, v), in cells, with u = (xmax - x) / resolution and
/// v = (ymax - y) / resolution, so u grows with the logical row index i and v with the column
/// index j (geometry.hpp). Cell (i, j) covers u in (i, i+1], v in (j, j+1]: a point on a
/// boundary belongs to the smaller index, as Geometry::indexAt has it. Directions are in cells
/// per unit of the line parameter t (a segment p0 -> p1 is t in [0, 1]).
///
/// The walk is not bounded by a map: it yields any integer index, also negative or past the
/// last row; the caller checks Geometry::contains() where that matters (leaving the map is
/// usually where a walk stops). Where the line passes exactly through a cell corner the row
/// step comes first (ties go to i), so the path stays 4-connected.
///
/// NaN: a GridLine holds no map values. Non-finite coordinates are refused by the factories
/// that take positions (segment()); the raw constructors take them unchecked, as they sit in
/// inner loops.
///
/// Threading: a small value type without shared state; copies may walk on any thread.
/// Throws: only segment(), InputError on a non-finite end point.
#include <terramap/core/error.hpp>
#include <terramap/core/geometry.hpp>

#include <cmath>
#include <limits>
#include <string>

namespace terramap {

class GridLine {
 public:
  /// A walk that starts in cell `cell` at grid point (u0, v0) (which must lie in that cell or
  /// on its boundary) and heads along (du, dv). The entry parameter of the first cell is 0.
  GridLine(const Index& cell, double u0, double v0, double du, double dv)
      : i_(cell.x()), j_(cell.y()), si_(du > 0 ? 1 : -1), sj_(dv > 0 ? 1 : -1),
        tdi_(du != 0 ? 1.0 / std::abs(du) : kInf), tdj_(dv != 0 ? 1.0 / std::abs(dv) : kInf),
        tmi_(du != 0 ? ((du > 0 ? i_ + 1 : i_) - u0) / du : kInf),
        tmj_(dv != 0 ? ((dv > 0 ? j_ + 1 : j_) - v0) / dv : kInf) {}

  /// A walk from the centre of `cell` along (du, dv) (e.g. soil pushed from a cell).
  static GridLine fromCellCentre(const Index& cell, double du, double dv) {
    return GridLine(cell, cell.x() + 0.5, cell.y() + 0.5, du, dv);
  }

  /// The walk along the segment p0 -> p1 (map-frame metres) over `geo`'s grid, starting in the
  /// cell that holds p0 (even if that cell is off the map); t in [0, 1] spans the segment, so
  /// the last cell is the one with exitParam() >= 1.
  /// \throws InputError if an end point is not finite.
  static GridLine segment(const Geometry& geo, const Position& p0, const Position& p1) {
    if (!p0.allFinite() || !p1.allFinite())
      throw InputError("GridLine::segment: non-finite end point (" + std::to_string(p0.x()) + ", " +
                       std::to_string(p0.y()) + ") -> (" + std::to_string(p1.x()) + ", " +
                       std::to_string(p1.y()) + ")");
    const double res = geo.resolution();
    const double xmax = geo.center().x() + 0.5 * geo.length().x();
    const double ymax = geo.center().y() + 0.5 * geo.length().y();
    const double u0 = (xmax - p0.x()) / res, v0 = (ymax - p0.y()) / res;
    const double u1 = (xmax - p1.x()) / res, v1 = (ymax - p1.y()) / res;
    // Cell (i, j) covers (i, i+1]: a start on a boundary belongs to the smaller index.
    const Index cell(static_cast<int>(std::ceil(u0)) - 1, static_cast<int>(std::ceil(v0)) - 1);
    return GridLine(cell, u0, v0, u1 - u0, v1 - v0);
  }

  /// Current cell (logical index; may be off the map).
  Index cell() const { return Index(i_, j_); }
  int row() const { return i_; }
  int col() const { return j_; }
  /// Line parameter at which the walk leaves the current cell (+inf for a zero direction).
  double exitParam() const { return tmi_ <= tmj_ ? tmi_ : tmj_; }

  enum class Axis { Row, Col };
  /// Moves to the next cell the line enters, one row or one column on; says which changed
  /// (walks that track tiles incrementally update only that axis).
  Axis step() {
    if (tmi_ <= tmj_) {
      i_ += si_;
      tmi_ += tdi_;
      return Axis::Row;
    }
    j_ += sj_;
    tmj_ += tdj_;
    return Axis::Col;
  }

 private:
  static constexpr double kInf = std::numeric_limits<double>::infinity();
  int i_, j_;
  int si_, sj_;        // step per axis (+1 / -1)
  double tdi_, tdj_;   // parameter length of one cell per axis
  double tmi_, tmj_;   // parameter of the next row / column boundary
};

}  // namespace terramap
