#include <terramap/core/error.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/core/text.hpp>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace terramap {

namespace {
int floorMod(int a, int n) {
  const int r = a % n;
  return r < 0 ? r + n : r;
}
}  // namespace

LayeredMap::LayeredMap(const Geometry& geometry, MapOptions options)
    : geometry_(geometry), options_(options) {
  if (options_.tile_size < 8 || options_.tile_size > 1024) {
    std::ostringstream os;
    os << "map tile size must be in [8, 1024] (got " << options_.tile_size << ")";
    throw ConfigError(os.str());
  }
  if (geometry_.size().x() <= 0 || geometry_.size().y() <= 0)
    throw ConfigError("map geometry has no cells");
  const int T = options_.tile_size;
  tile_rows_ = (geometry_.size().x() + T - 1) / T;
  tile_cols_ = (geometry_.size().y() + T - 1) / T;
}

LayeredMap::TilePtr LayeredMap::newTile(float fill) const {
  const size_t n = static_cast<size_t>(options_.tile_size) * options_.tile_size;
  TilePtr t(new float[n]);
  std::fill(t.get(), t.get() + n, fill);
  return t;
}

LayerId LayeredMap::addLayer(const std::string& name, const std::string& unit, float fill) {
  if (name.empty()) throw LayerError("layer name must not be empty");
  if (hasLayer(name)) throw LayerError("layer '" + name + "' already exists");
  {
    // A dense layer allocates every tile now: refuse a map the budget cannot hold before the
    // first byte (a sparse layer allocates only its pointer table; tiles come as data does).
    const std::uint64_t T = static_cast<std::uint64_t>(options_.tile_size);
    const std::uint64_t per_layer = options_.sparse ? saturatingProduct({static_cast<std::uint64_t>(tileCount()), sizeof(TilePtr)})
                                                    : saturatingProduct({static_cast<std::uint64_t>(tileCount()), T * T, sizeof(float)});
    const std::uint64_t n = layers_.size() + 1;
    requireConfigBudget(saturatingProduct({per_layer, n}),
                        "map of " + std::to_string(geometry_.size().x()) + " x " + std::to_string(geometry_.size().y()) +
                            " cells (map.size), adding layer '" + name + "'",
                        std::to_string(n) + (options_.sparse ? " sparse layers' tile tables" : " dense layers of 4-byte cells"));
  }
  std::vector<TilePtr> tiles(static_cast<size_t>(tileCount()));
  if (!options_.sparse)
    for (auto& t : tiles) t = newTile(fill);
  layers_.push_back(LayerInfo{name, unit, fill});
  tiles_.push_back(std::move(tiles));
  owned_.emplace_back(static_cast<size_t>(tileCount()), generation_.get());
  writes_.emplace_back(static_cast<size_t>(tileCount()), 0);
  written_.emplace_back(static_cast<size_t>(tileCount()), Extent{0, 0, 0, 0});
  if (!options_.sparse) allocated_.value.fetch_add(tileCount(), std::memory_order_relaxed);
  return static_cast<LayerId>(layers_.size() - 1);
}

bool LayeredMap::hasLayer(const std::string& name) const {
  return std::any_of(layers_.begin(), layers_.end(), [&](const LayerInfo& l) { return l.name == name; });
}

LayerId LayeredMap::layerId(const std::string& name) const {
  for (size_t i = 0; i < layers_.size(); ++i)
    if (layers_[i].name == name) return static_cast<LayerId>(i);
  const auto names = layerNames();
  throw LayerError("no layer '" + name + "' in the map" + didYouMean(name, names) + "; layers: [" +
                   joinStrings(names) + "]");
}

const LayerInfo& LayeredMap::layerInfo(LayerId id) const {
  if (id < 0 || id >= layerCount()) throw LayerError("bad layer id " + std::to_string(id));
  return layers_[static_cast<size_t>(id)];
}

std::vector<std::string> LayeredMap::layerNames() const {
  std::vector<std::string> out;
  out.reserve(layers_.size());
  for (const auto& l : layers_) out.push_back(l.name);
  return out;
}

CellRect LayeredMap::tileRectOf(const Size& size, int tile_size, int t) {
  const int T = tile_size;
  const int tile_cols = (size.y() + T - 1) / T;
  const int tr = t / tile_cols, tc = t % tile_cols;
  CellRect r;
  r.r0 = tr * T;
  r.c0 = tc * T;
  r.rows = std::min(T, size.x() - r.r0);
  r.cols = std::min(T, size.y() - r.c0);
  return r;
}

const float* LayeredMap::tileData(LayerId id, int t) const {
  return tiles_[static_cast<size_t>(id)][static_cast<size_t>(t)].get();
}

bool LayeredMap::reserveTiles(long n) {
  const std::uint64_t limit = memoryBudget() / tileBytes();
  long cur = allocated_.get();
  do {
    if (static_cast<std::uint64_t>(cur + n) > limit) return false;
  } while (!allocated_.value.compare_exchange_weak(cur, cur + n, std::memory_order_relaxed));
  return true;
}

bool LayeredMap::tryAllocateTile(int t, std::initializer_list<LayerId> ids) {
  long missing = 0;
  for (auto it = ids.begin(); it != ids.end(); ++it) {
    if (*it < 0) continue;
    layerInfo(*it);
    if (tiles_[static_cast<size_t>(*it)][static_cast<size_t>(t)]) continue;
    if (std::find(ids.begin(), it, *it) == it) ++missing;  // a layer named twice is one tile
  }
  if (missing == 0) return true;
  if (!reserveTiles(missing)) return false;
  long made = 0;
  try {
    for (const LayerId id : ids) {
      if (id < 0) continue;
      TilePtr& tile = tiles_[static_cast<size_t>(id)][static_cast<size_t>(t)];
      if (tile) continue;
      tile = newTile(layers_[static_cast<size_t>(id)].fill);
      ++made;
      owned_[static_cast<size_t>(id)][static_cast<size_t>(t)] = generation_.get();
      written_[static_cast<size_t>(id)][static_cast<size_t>(t)] = Extent{0, 0, 0, 0};  // all fill
    }
  } catch (...) {
    allocated_.value.fetch_sub(missing - made, std::memory_order_relaxed);
    throw;
  }
  return true;
}

TileBudgetError LayeredMap::budgetError(LayerId id, long more) const {
  std::ostringstream os;
  os << "sparse map of " << geometry_.size().x() << " x " << geometry_.size().y() << " cells: " << more
     << " more tile" << (more == 1 ? "" : "s") << " of layer '" << layers_[static_cast<size_t>(id)].name
     << "' would take it to " << allocatedTiles() + more << " tiles of " << tileBytes()
     << " bytes, more than the memory budget of " << formatBytes(memoryBudget())
     << " holds (raise --memory-budget / TERRAMAP_MEMORY_BUDGET, or use a smaller map or fewer layers)";
  return TileBudgetError(os.str());
}

void LayeredMap::allocateLayer(LayerId id) {
  std::vector<TilePtr>& tiles = tiles_[static_cast<size_t>(id)];
  const long missing = static_cast<long>(std::count(tiles.begin(), tiles.end(), nullptr));
  if (missing == 0) return;
  if (!reserveTiles(missing)) throw budgetError(id, missing);
  long made = 0;
  try {
    for (int t = 0; t < tileCount(); ++t) {
      TilePtr& tile = tiles[static_cast<size_t>(t)];
      if (tile) continue;
      tile = newTile(layers_[static_cast<size_t>(id)].fill);
      ++made;
      owned_[static_cast<size_t>(id)][static_cast<size_t>(t)] = generation_.get();
      written_[static_cast<size_t>(id)][static_cast<size_t>(t)] = Extent{0, 0, 0, 0};
    }
  } catch (...) {
    allocated_.value.fetch_sub(missing - made, std::memory_order_relaxed);
    throw;
  }
}

float* LayeredMap::mutableTileData(LayerId id, int t) {
  TilePtr& tile = tiles_[static_cast<size_t>(id)][static_cast<size_t>(t)];
  std::uint64_t& owned = owned_[static_cast<size_t>(id)][static_cast<size_t>(t)];
  if (!tile) {
    if (!reserveTiles(1)) throw budgetError(id, 1);
    try {
      tile = newTile(layers_[static_cast<size_t>(id)].fill);
    } catch (...) {
      allocated_.value.fetch_sub(1, std::memory_order_relaxed);
      throw;
    }
    owned = generation_.get();
  } else if (owned != generation_.get()) {
    // Possibly shared with a copy taken since this map last made the tile its own: copy before
    // writing. (A snapshot already dropped costs one needless copy; reading its reference
    // count instead would race with the thread dropping it.)
    const size_t n = static_cast<size_t>(options_.tile_size) * options_.tile_size;
    TilePtr copy(new float[n]);
    std::copy(tile.get(), tile.get() + n, copy.get());
    tile = std::move(copy);
    owned = generation_.get();
  }
  ++writes_[static_cast<size_t>(id)][static_cast<size_t>(t)];
  const CellRect r = tileRect(t);
  written_[static_cast<size_t>(id)][static_cast<size_t>(t)] =
      Extent{0, static_cast<std::int16_t>(r.rows), 0, static_cast<std::int16_t>(r.cols)};
  return tile.get();
}

std::vector<int> LayeredMap::tilesWithin(const std::vector<int>& tiles, int cells) const {
  const int TR = tile_rows_, TC = tile_cols_, T = options_.tile_size;
  // A logical neighbour d cells away is the buffer cell d away modulo the ring (or cut off at
  // the map's edge), so growing cyclically over tiles is never too small. `cells` cells span
  // ceil(cells / T) tiles, one more when they can cross a partial last tile narrower than that.
  auto reach = [&](int n, int count) {
    const int m = (cells + T - 1) / T + (n % T != 0 && n % T < cells ? 1 : 0);
    return std::min(m, count);
  };
  const int mr = reach(geometry_.size().x(), TR), mc = reach(geometry_.size().y(), TC);
  std::vector<char> hit(static_cast<size_t>(tileCount()), 0);
  for (const int t : tiles) {
    const int tr = t / TC, tc = t % TC;
    for (int dr = -mr; dr <= mr; ++dr)
      for (int dc = -mc; dc <= mc; ++dc)
        hit[static_cast<size_t>(((tr + dr) % TR + TR) % TR * TC + ((tc + dc) % TC + TC) % TC)] = 1;
  }
  std::vector<int> out;
  for (int t = 0; t < tileCount(); ++t)
    if (hit[static_cast<size_t>(t)]) out.push_back(t);
  return out;
}

std::uint64_t LayeredMap::tileWrites(LayerId id, int t) const {
  layerInfo(id);
  return writes_[static_cast<size_t>(id)][static_cast<size_t>(t)];
}

Index LayeredMap::bufferIndex(const Index& logical) const {
  return Index(floorMod(logical.x() + start_.x(), geometry_.size().x()),
               floorMod(logical.y() + start_.y(), geometry_.size().y()));
}

Index LayeredMap::logicalIndex(const Index& buffer) const {
  return Index(floorMod(buffer.x() - start_.x(), geometry_.size().x()),
               floorMod(buffer.y() - start_.y(), geometry_.size().y()));
}

namespace {
void checkIndex(const Geometry& g, const Index& idx) {
  if (!g.contains(idx)) {
    std::ostringstream os;
    os << "cell index (" << idx.x() << ", " << idx.y() << ") is outside the map of size ["
       << g.size().x() << ", " << g.size().y() << "]";
    throw std::out_of_range(os.str());
  }
}
}  // namespace

float LayeredMap::at(LayerId id, const Index& logical) const {
  layerInfo(id);
  checkIndex(geometry_, logical);
  const Index b = bufferIndex(logical);
  const int t = tileOfBuffer(b.x(), b.y());
  const float* d = tileData(id, t);
  if (!d) return layers_[static_cast<size_t>(id)].fill;
  const CellRect r = tileRect(t);
  return d[(b.x() - r.r0) * options_.tile_size + (b.y() - r.c0)];
}

void LayeredMap::set(LayerId id, const Index& logical, float value) {
  layerInfo(id);
  checkIndex(geometry_, logical);
  const Index b = bufferIndex(logical);
  const int t = tileOfBuffer(b.x(), b.y());
  float* d = mutableTileData(id, t);
  const CellRect r = tileRect(t);
  d[(b.x() - r.r0) * options_.tile_size + (b.y() - r.c0)] = value;
}

void LayeredMap::fill(LayerId id, float value) {
  const float fill_value = layerInfo(id).fill;
  const bool to_fill = value == fill_value || (std::isnan(value) && std::isnan(fill_value));
  // Every tile or none: a sparse layer filled with another value needs all its tiles.
  if (options_.sparse && !to_fill) allocateLayer(id);
  for (int t = 0; t < tileCount(); ++t) {
    if (options_.sparse && to_fill) {
      TilePtr& tile = tiles_[static_cast<size_t>(id)][static_cast<size_t>(t)];
      if (tile) allocated_.value.fetch_sub(1, std::memory_order_relaxed);
      tile.reset();
      ++writes_[static_cast<size_t>(id)][static_cast<size_t>(t)];
      continue;
    }
    float* d = mutableTileData(id, t);
    std::fill(d, d + static_cast<size_t>(options_.tile_size) * options_.tile_size, value);
  }
}

namespace {
void checkLayerBuffer(const LayerInfo& info, const Size& size, long rows, long cols) {
  if (rows == size.x() && cols == size.y()) return;
  std::ostringstream os;
  os << "matrix of " << rows << "x" << cols << " does not fit layer '" << info.name << "' of "
     << size.x() << "x" << size.y();
  throw LayerError(os.str());
}
}  // namespace

void LayeredMap::readLayer(LayerId id, float* dst, long rows, long cols) const {
  const LayerInfo& info = layerInfo(id);
  checkLayerBuffer(info, geometry_.size(), rows, cols);
  const int R = geometry_.size().x(), C = geometry_.size().y(), T = options_.tile_size;
  Eigen::Map<Eigen::MatrixXf> m(dst, R, C);
  for (int t = 0; t < tileCount(); ++t) {
    const CellRect r = tileRect(t);
    const float* d = tileData(id, t);
    for (int br = r.r0; br < r.r0 + r.rows; ++br) {
      const int li = floorMod(br - start_.x(), R);
      for (int bc = r.c0; bc < r.c0 + r.cols; ++bc) {
        const int lj = floorMod(bc - start_.y(), C);
        m(li, lj) = d ? d[(br - r.r0) * T + (bc - r.c0)] : info.fill;
      }
    }
  }
}

void LayeredMap::writeLayer(LayerId id, const float* src, long rows, long cols) {
  checkLayerBuffer(layerInfo(id), geometry_.size(), rows, cols);
  allocateLayer(id);  // every tile or none (a sparse map at its budget stays as it was)
  const int R = geometry_.size().x(), C = geometry_.size().y(), T = options_.tile_size;
  const Eigen::Map<const Eigen::MatrixXf> m(src, R, C);
  for (int t = 0; t < tileCount(); ++t) {
    const CellRect r = tileRect(t);
    float* d = mutableTileData(id, t);
    for (int br = r.r0; br < r.r0 + r.rows; ++br) {
      const int li = floorMod(br - start_.x(), R);
      for (int bc = r.c0; bc < r.c0 + r.cols; ++bc)
        d[(br - r.r0) * T + (bc - r.c0)] = m(li, floorMod(bc - start_.y(), C));
    }
  }
}

void LayeredMap::resetLogicalRect(const CellRect& logical) {
  const int R = geometry_.size().x(), C = geometry_.size().y(), T = options_.tile_size;
  // The logical rectangle wraps around the ring buffer into at most 2 x 2 buffer rectangles;
  // each is reset tile by tile in row spans (std::fill), not cell by cell.
  auto spans = [](int start, int len, int n) {
    std::vector<std::pair<int, int>> out;  // (buffer start, length)
    const int first = std::min(len, n - start);
    out.emplace_back(start, first);
    if (len > first) out.emplace_back(0, len - first);
    return out;
  };
  const Index b0 = bufferIndex(Index(logical.r0, logical.c0));
  for (const auto& [br, nr] : spans(b0.x(), logical.rows, R))
    for (const auto& [bc, nc] : spans(b0.y(), logical.cols, C)) {
      for (int tr = br / T; tr * T < br + nr; ++tr)
        for (int tc = bc / T; tc * T < bc + nc; ++tc) {
          const int t = tr * tile_cols_ + tc;
          const int r_lo = std::max(br, tr * T), r_hi = std::min(br + nr, (tr + 1) * T);
          const int c_lo = std::max(bc, tc * T), c_hi = std::min(bc + nc, (tc + 1) * T);
          // The reset rectangle relative to the tile.
          const int a_r0 = r_lo - tr * T, a_r1 = r_hi - tr * T, a_c0 = c_lo - tc * T, a_c1 = c_hi - tc * T;
          for (size_t l = 0; l < layers_.size(); ++l) {
            // Unallocated sparse tiles already read as the fill: do not allocate them.
            TilePtr& tile = tiles_[l][static_cast<size_t>(t)];
            if (!tile) continue;
            Extent w = written_[l][static_cast<size_t>(t)];
            const bool covers_rows = a_r0 <= w[0] && a_r1 >= w[1], covers_cols = a_c0 <= w[2] && a_c1 >= w[3];
            if (options_.sparse && ((covers_rows && covers_cols) || w[0] >= w[1] || w[2] >= w[3])) {
              // Nothing but the fill left in it: give the memory back (it reads the same).
              tile.reset();
              allocated_.value.fetch_sub(1, std::memory_order_relaxed);
              ++writes_[l][static_cast<size_t>(t)];
              continue;
            }
            float* d = mutableTileData(static_cast<LayerId>(l), t);
            for (int r = r_lo; r < r_hi; ++r)
              std::fill(d + (r - tr * T) * T + (c_lo - tc * T), d + (r - tr * T) * T + (c_hi - tc * T),
                        layers_[l].fill);
            // A move resets whole rows or columns of the map, so a band reaching across the part
            // still written and over one of its edges trims it to a smaller rectangle.
            if (covers_cols) {
              if (a_r0 <= w[0] && a_r1 > w[0]) w[0] = static_cast<std::int16_t>(a_r1);
              else if (a_r1 >= w[1] && a_r0 < w[1]) w[1] = static_cast<std::int16_t>(a_r0);
            } else if (covers_rows) {
              if (a_c0 <= w[2] && a_c1 > w[2]) w[2] = static_cast<std::int16_t>(a_c1);
              else if (a_c1 >= w[3] && a_c0 < w[3]) w[3] = static_cast<std::int16_t>(a_c0);
            }
            written_[l][static_cast<size_t>(t)] = w;
          }
        }
    }
}

MoveResult LayeredMap::move(const Position& new_center) {
  if (!new_center.allFinite()) throw ConfigError("LayeredMap::move: target centre is not finite");
  MoveResult res;
  const double res_m = geometry_.resolution();
  const Eigen::Vector2d d = (new_center - geometry_.center()) / res_m;
  const Index s(static_cast<int>(std::lround(d.x())), static_cast<int>(std::lround(d.y())));
  res.shift_cells = s;
  if ((s == 0).all()) return res;
  const int R = geometry_.size().x(), C = geometry_.size().y();
  // Physical cell at old logical i now has logical i + s (index grows towards -x), so the
  // buffer start moves by -s and logical rows [0, s) (s > 0) or [R + s, R) (s < 0) are new.
  CellRect rows_in, cols_in;
  if (std::abs(s.x()) >= R || std::abs(s.y()) >= C) {
    rows_in = CellRect{0, 0, R, C};
  } else {
    if (s.x() > 0) rows_in = CellRect{0, 0, s.x(), C};
    if (s.x() < 0) rows_in = CellRect{R + s.x(), 0, -s.x(), C};
    // Columns band, minus the rows already reported.
    const int r_lo = s.x() > 0 ? s.x() : 0;
    const int r_hi = s.x() < 0 ? R + s.x() : R;
    if (s.y() > 0) cols_in = CellRect{r_lo, 0, r_hi - r_lo, s.y()};
    if (s.y() < 0) cols_in = CellRect{r_lo, C + s.y(), r_hi - r_lo, -s.y()};
  }
  start_ = Index(floorMod(start_.x() - s.x(), R), floorMod(start_.y() - s.y(), C));
  geometry_.shiftCenterByCells(s);
  for (const CellRect& r : {rows_in, cols_in}) {
    if (r.empty()) continue;
    resetLogicalRect(r);
    res.new_regions.push_back(r);
  }
  return res;
}

}  // namespace terramap
