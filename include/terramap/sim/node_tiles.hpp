#pragma once
/// \file
/// A per-node value over a terrain grid whose storage is allocated tile by tile on first write:
/// what the tracks touch is a few lanes of a large site, and a full-grid array (72 MB of doubles
/// for 60 m x 60 m at 2 cm) zero-filled at the first physics step cost the CTL simulator a
/// quarter of its speed in page faults. Not thread-safe for writers; readers may run beside
/// each other.
#include <cstddef>
#include <memory>
#include <vector>

namespace terramap::sim {

template <typename T>
class NodeTiles {
 public:
  static constexpr int kTile = 64;  ///< 64 x 64 nodes (1.28 m at 2 cm; 32 KB of doubles)

  /// nx x ny nodes, every value `fill` until written.
  NodeTiles(int nx = 0, int ny = 0, T fill = T{}) { reset(nx, ny, fill); }

  void reset(int nx, int ny, T fill) {
    fill_ = fill;
    tx_ = (nx + kTile - 1) / kTile;
    const int ty = (ny + kTile - 1) / kTile;
    tiles_.clear();
    tiles_.resize(static_cast<std::size_t>(tx_) * static_cast<std::size_t>(ty > 0 ? ty : 0));
  }

  bool empty() const { return tiles_.empty(); }
  /// The value at node (i, j) (0 <= i < nx, 0 <= j < ny): `fill` where nothing was written.
  T get(int i, int j) const {
    const auto& t = tiles_[tileIndex(i, j)];
    return t ? t[inTile(i, j)] : fill_;
  }
  /// Node (i, j)'s value in place, or null while its tile is unallocated (every value `fill`).
  /// Nodes i .. (i | 63) of row j follow it contiguously (one tile's row).
  const T* find(int i, int j) const {
    const auto& t = tiles_[tileIndex(i, j)];
    return t ? &t[inTile(i, j)] : nullptr;
  }
  /// A reference to node (i, j)'s value, allocating its tile (filled) on first use.
  T& at(int i, int j) {
    auto& t = tiles_[tileIndex(i, j)];
    if (!t) {
      t = std::make_unique<T[]>(kTile * kTile);
      for (int k = 0; k < kTile * kTile; ++k) t[k] = fill_;
    }
    return t[inTile(i, j)];
  }
  /// Tiles allocated so far (for tests and profiling).
  std::size_t allocatedTiles() const {
    std::size_t n = 0;
    for (const auto& t : tiles_) n += t != nullptr;
    return n;
  }

  NodeTiles(const NodeTiles& o) { *this = o; }
  NodeTiles& operator=(const NodeTiles& o) {
    if (this == &o) return *this;
    tx_ = o.tx_;
    fill_ = o.fill_;
    tiles_.clear();
    tiles_.resize(o.tiles_.size());
    for (std::size_t k = 0; k < o.tiles_.size(); ++k)
      if (o.tiles_[k]) {
        tiles_[k] = std::make_unique<T[]>(kTile * kTile);
        for (int q = 0; q < kTile * kTile; ++q) tiles_[k][q] = o.tiles_[k][q];
      }
    return *this;
  }
  NodeTiles(NodeTiles&&) noexcept = default;
  NodeTiles& operator=(NodeTiles&&) noexcept = default;

 private:
  std::size_t tileIndex(int i, int j) const {
    return static_cast<std::size_t>(j / kTile) * static_cast<std::size_t>(tx_) + static_cast<std::size_t>(i / kTile);
  }
  static std::size_t inTile(int i, int j) { return static_cast<std::size_t>((j % kTile) * kTile + (i % kTile)); }

  int tx_ = 0;  ///< tiles per row
  T fill_{};
  std::vector<std::unique_ptr<T[]>> tiles_;
};

}  // namespace terramap::sim
