#include <terramap/core/error.hpp>
#include <terramap/core/geometry.hpp>

#include <cmath>
#include <sstream>

namespace terramap {

Geometry::Geometry(double resolution, Size size, Position center)
    : resolution_(resolution), size_(size), center_(center) {
  if (!(resolution > 0.0) || !std::isfinite(resolution)) {
    std::ostringstream os;
    os << "map resolution must be a finite number > 0 (got " << resolution << ")";
    throw ConfigError(os.str());
  }
  if (size.x() <= 0 || size.y() <= 0) {
    std::ostringstream os;
    os << "map size must be positive in both directions (got [" << size.x() << ", " << size.y() << "])";
    throw ConfigError(os.str());
  }
  if (!center.allFinite()) throw ConfigError("map centre must be finite");
}

std::optional<Index> Geometry::indexAt(const Position& p) const {
  if (!p.allFinite()) return std::nullopt;
  const Eigen::Array2d half = length() * 0.5;
  // Distance from the (+x, +y) corner, in cells; index grows towards -x/-y.
  const double fi = (center_.x() + half.x() - p.x()) / resolution_;
  const double fj = (center_.y() + half.y() - p.y()) / resolution_;
  // A position exactly on the +x/+y edge (fi == 0) is outside: the box is half-open there.
  if (!(fi > 0.0) || !(fj > 0.0)) return std::nullopt;
  const double i = std::ceil(fi) - 1.0;
  const double j = std::ceil(fj) - 1.0;
  if (i >= size_.x() || j >= size_.y()) return std::nullopt;
  return Index(static_cast<int>(i), static_cast<int>(j));
}

Position Geometry::positionOf(const Index& idx) const {
  const Eigen::Array2d half = length() * 0.5;
  return Position(center_.x() + half.x() - (idx.x() + 0.5) * resolution_,
                  center_.y() + half.y() - (idx.y() + 0.5) * resolution_);
}

void Geometry::shiftCenterByCells(const Index& shift_cells) {
  center_ += shift_cells.cast<double>().matrix() * resolution_;
}

}  // namespace terramap
