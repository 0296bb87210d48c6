#pragma once
/// \file
/// Grid geometry and the index <-> position convention.
///
/// Convention (the same as ANYbotics/grid_map, so users can move between the two):
/// - The map frame is right-handed, x forward, y left, z up; positions are metres in the map frame.
/// - The grid has `size.x()` rows and `size.y()` columns. Index (0, 0) is the cell with the
///   *largest* x and *largest* y; the row index i grows towards -x, the column index j towards -y.
/// - The cell with index (i, j) has its centre at
///     x = center.x + length.x/2 - (i + 0.5) * resolution
///     y = center.y + length.y/2 - (j + 0.5) * resolution
///   where length = size * resolution.
/// - A position on a cell boundary belongs to the cell with the smaller index (towards +x/+y);
///   the map covers the half-open box [xmin, xmax) x [ymin, ymax) mirrored accordingly:
///   positions with x == xmax or y == ymax are outside, x == xmin inside.
/// These are *logical* indices. The ring buffer that lets the map move stores cells at
/// shifted "buffer" indices; only LayeredMap deals with that.
#include <Eigen/Core>
#include <optional>

#include <terramap/core/error.hpp>

namespace terramap {

using Index = Eigen::Array2i;    ///< (row i, column j), logical
using Size = Eigen::Array2i;     ///< (rows, columns)
using Position = Eigen::Vector2d;  ///< (x, y) metres in the map frame

class TERRAMAP_API Geometry {
 public:
  Geometry() = default;
  /// \param resolution cell edge in metres, > 0.
  /// \param size rows x columns, each > 0.
  /// \param center map centre in the map frame (metres).
  /// \throws ConfigError if resolution <= 0 or not finite, or a size is <= 0.
  Geometry(double resolution, Size size, Position center = Position::Zero());

  double resolution() const { return resolution_; }
  const Size& size() const { return size_; }
  const Position& center() const { return center_; }
  /// Extent in metres (size * resolution).
  Eigen::Array2d length() const { return size_.cast<double>() * resolution_; }
  long cellCount() const { return static_cast<long>(size_.x()) * size_.y(); }

  /// Logical index of the cell that contains `p`, or nullopt if `p` is outside (or NaN).
  std::optional<Index> indexAt(const Position& p) const;
  /// Centre of cell `idx` (no bounds check; valid for any integer index, also outside).
  Position positionOf(const Index& idx) const;
  bool contains(const Index& idx) const {
    return idx.x() >= 0 && idx.y() >= 0 && idx.x() < size_.x() && idx.y() < size_.y();
  }
  bool contains(const Position& p) const { return indexAt(p).has_value(); }

  /// Moves the centre by a whole number of cells (what LayeredMap::move does to the geometry).
  void shiftCenterByCells(const Index& shift_cells);

  bool operator==(const Geometry& o) const {
    return resolution_ == o.resolution_ && (size_ == o.size_).all() && center_ == o.center_;
  }
  bool operator!=(const Geometry& o) const { return !(*this == o); }

 private:
  double resolution_ = 1.0;
  Size size_{0, 0};
  Position center_ = Position::Zero();
};

}  // namespace terramap
