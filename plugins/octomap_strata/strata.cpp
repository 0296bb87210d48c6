// Subsurface soil memory in an OctoMap tree (strata.hpp).
#include "strata.hpp"

#include <terramap/soil/belief.hpp>

#include <terramap/core/error.hpp>
#include <terramap/io/atomic_file.hpp>
#include <terramap/io/render.hpp>

#include <octomap/ColorOcTree.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>

namespace terramap::strata {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr int kP = soil::kSoilParamCount;
constexpr const char* kTreeId = "TerramapStrataTree";
// 2: columns hold float beliefs; 3: voxels their slab's ends; 4: whether estimates meet the prior;
// 5: that, for the removed voxels and the soil below apart
constexpr const char* kTrailer = "terramap_strata 5";
constexpr const char* kTrailerV4 = "terramap_strata 4";
constexpr const char* kTrailerV3 = "terramap_strata 3";

/// m, v ← prior N(m, v) × N(z, r) (soil/belief.hpp; the prior here is always finite).
void fuse(double& m, double& v, double z, double r) {
  const soil::Belief b = soil::fuseBelief({m, v}, z, r);
  m = b.mean;
  v = b.var;
}

SoilBelief nanBelief(SoilSource s) {
  SoilBelief b;
  b.mean.fill(kNaN);
  b.var.fill(kNaN);
  b.source = s;
  return b;
}

SoilBelief fromVoxel(const VoxelBelief& v) {
  SoilBelief b;
  for (int q = 0; q < kP; ++q) {
    b.mean[q] = v.mean[q];
    b.var[q] = v.var[q];
  }
  b.source = v.kind == VoxelBelief::kEstimated ? SoilSource::Removed : SoilSource::Predicted;
  return b;
}

VoxelBelief toVoxel(const SoilBelief& b, VoxelBelief::Kind kind) {
  VoxelBelief v;
  for (int q = 0; q < kP; ++q) {
    v.mean[q] = static_cast<float>(b.mean[q]);
    v.var[q] = static_cast<float>(b.var[q]);
  }
  v.kind = kind;
  return v;
}

template <typename T>
void put(std::ostream& o, const T& v) {
  o.write(reinterpret_cast<const char*>(&v), sizeof(T));
}
template <typename T>
bool get(std::istream& i, T& v) {
  return static_cast<bool>(i.read(reinterpret_cast<char*>(&v), sizeof(T)));
}

}  // namespace

bool VoxelBelief::operator==(const VoxelBelief& o) const {
  auto same = [](float a, float b) { return a == b || (std::isnan(a) && std::isnan(b)); };
  return kind == o.kind && mean == o.mean && var == o.var && same(top, o.top) && same(bottom, o.bottom);
}

const char* soilSourceName(SoilSource s) {
  switch (s) {
    case SoilSource::Outside: return "outside";
    case SoilSource::Air: return "air";
    case SoilSource::Prior: return "prior";
    case SoilSource::Inherited: return "inherited";
    case SoilSource::Removed: return "removed";
    case SoilSource::Predicted: return "predicted";
  }
  return "?";
}

StrataTree::StrataTree(double resolution) : octomap::OcTreeBaseImpl<StrataNode, octomap::AbstractOcTree>(resolution) {}

void StrataTree::setLeaf(const octomap::OcTreeKey& key, const VoxelBelief& value) {
  if (!root) {
    root = new StrataNode();
    ++tree_size;
  }
  StrataNode* node = root;
  for (int depth = static_cast<int>(tree_depth) - 1; depth >= 0; --depth) {
    const unsigned int pos = octomap::computeChildIdx(key, depth);
    if (!nodeChildExists(node, pos)) {
      // A leaf above the bottom is a pruned region: expand it so the other voxels keep its value.
      if (!nodeHasChildren(node) && node != root && node->getValue().kind != VoxelBelief::kNone) {
        expandNode(node);
      } else {
        createNodeChild(node, pos);
      }
    }
    node = getNodeChild(node, pos);
  }
  node->setValue(value);
}

void StrataTree::pruneAbove(const octomap::OcTreeKey& key) {
  if (!root) return;
  StrataNode* path[32];
  int n = 0;
  StrataNode* node = root;
  path[n++] = node;
  for (int depth = static_cast<int>(tree_depth) - 1; depth >= 0 && nodeHasChildren(node); --depth) {
    const unsigned int pos = octomap::computeChildIdx(key, depth);
    if (!nodeChildExists(node, pos)) break;
    node = getNodeChild(node, pos);
    path[n++] = node;
  }
  // path[n - 1] is the leaf (or the pruned region holding it): try its parents upwards.
  for (int k = n - 2; k >= 0; --k)
    if (!pruneNode(path[k])) break;
}

Strata::Strata(const StrataConfig& config) : cfg_(config), tree_(config.resolution_m > 0 ? config.resolution_m : 1.0) {
  if (!(cfg_.resolution_m > 0.0) || !std::isfinite(cfg_.resolution_m))
    throw ConfigError("octomap_strata: resolution_m must be above 0");
  for (int a = 0; a < 3; ++a) {
    if (!(cfg_.min_m[a] < cfg_.max_m[a]))
      throw ConfigError("octomap_strata: the extent is empty along " + std::string(1, "xyz"[a]) + " (min >= max)");
    octomap::key_type k;
    if (!tree_.coordToKeyChecked(cfg_.min_m[a], k) || !tree_.coordToKeyChecked(cfg_.max_m[a], k))
      throw ConfigError("octomap_strata: the extent along " + std::string(1, "xyz"[a]) +
                        " exceeds OctoMap's key range at this resolution (±" +
                        std::to_string(32767 * cfg_.resolution_m) + " m)");
  }
  if (!(cfg_.inflation_depth_m > 0.0)) throw ConfigError("octomap_strata: inflation_depth_m must be above 0");
  for (int q = 0; q < kP; ++q)
    if (!std::isfinite(cfg_.prior_mean[q]) || !(cfg_.prior_var[q] > 0.0) || !std::isfinite(cfg_.prior_var[q]))
      throw ConfigError(std::string("octomap_strata: the prior of ") + soil::kSoilParams[q].layer +
                        " needs a finite mean and a variance above 0");
  if (cfg_.max_pending_sweeps < 1) throw ConfigError("octomap_strata: max_pending_sweeps must be at least 1");
}

bool Strata::columnKey(double x, double y, std::uint32_t& key) const {
  if (!(x >= cfg_.min_m.x() && x < cfg_.max_m.x() && y >= cfg_.min_m.y() && y < cfg_.max_m.y())) return false;
  octomap::key_type kx, ky;
  if (!tree_.coordToKeyChecked(x, kx) || !tree_.coordToKeyChecked(y, ky)) return false;
  key = (static_cast<std::uint32_t>(kx) << 16) | ky;
  return true;
}

long Strata::levelOf(double z) const { return static_cast<long>(std::floor(z / cfg_.resolution_m - 0.5)); }

double Strata::levelZ(long level) const { return (static_cast<double>(level) + 0.5) * cfg_.resolution_m; }

octomap::OcTreeKey Strata::voxelKey(std::uint32_t column, long level) const {
  return octomap::OcTreeKey(static_cast<octomap::key_type>(column >> 16), static_cast<octomap::key_type>(column & 0xffffu),
                            static_cast<octomap::key_type>(level + static_cast<long>(tree_.keyOffset())));
}

Eigen::Vector2d Strata::columnCentre(std::uint32_t column) const {
  const long off = static_cast<long>(tree_.keyOffset());
  return {levelZ(static_cast<long>(column >> 16) - off), levelZ(static_cast<long>(column & 0xffffu) - off)};
}

SoilBelief Strata::predictBelow(const Column* c, double z) const {
  SoilBelief b;
  b.mean = cfg_.prior_mean;
  b.var = cfg_.prior_var;
  b.source = SoilSource::Prior;
  if (!c || c->inherit_sweep < 0) return b;
  const double f = std::exp(std::max(0.0, static_cast<double>(c->anchor) - z) / cfg_.inflation_depth_m);
  for (int q = 0; q < kP; ++q) {
    if (cfg_.prior_below) {
      fuse(b.mean[q], b.var[q], c->inherit_mean[q], c->inherit_var[q] * f);
    } else {
      b.mean[q] = c->inherit_mean[q];
      b.var[q] = static_cast<double>(c->inherit_var[q]) * f;
    }
  }
  b.source = SoilSource::Inherited;
  return b;
}

long Strata::applyCut(long sweep, const std::vector<CellCut>& cells) {
  const double res = cfg_.resolution_m;
  // The columns this sweep cut, each once (a map cell may hold several columns, and with a
  // finer map several cells fall in one column): deepest new surface, highest old surface.
  struct Cut {
    double bottom = std::numeric_limits<double>::infinity();
    double old = -std::numeric_limits<double>::infinity();
  };
  std::map<std::uint32_t, Cut> cuts;
  for (const CellCut& cell : cells) {
    if (!std::isfinite(cell.new_surface_m)) continue;
    const double h = 0.5 * std::max(cell.cell_m, 0.0);
    // Columns whose centres lie in the cell; at least the one holding its centre.
    const long i0 = static_cast<long>(std::ceil((cell.position.x() - h) / res - 0.5));
    const long i1 = static_cast<long>(std::ceil((cell.position.x() + h) / res - 0.5)) - 1;
    const long j0 = static_cast<long>(std::ceil((cell.position.y() - h) / res - 0.5));
    const long j1 = static_cast<long>(std::ceil((cell.position.y() + h) / res - 0.5)) - 1;
    auto add = [&](double x, double y) {
      std::uint32_t key;
      if (!columnKey(x, y, key)) {
        ++counters_.columns_outside;
        return;
      }
      Cut& c = cuts[key];
      c.bottom = std::min(c.bottom, cell.new_surface_m);
      if (std::isfinite(cell.old_surface_m)) c.old = std::max(c.old, cell.old_surface_m);
    };
    if (i1 < i0 || j1 < j0) {
      add(cell.position.x(), cell.position.y());
      continue;
    }
    for (long i = i0; i <= i1; ++i)
      for (long j = j0; j <= j1; ++j) add((static_cast<double>(i) + 0.5) * res, (static_cast<double>(j) + 0.5) * res);
  }
  // Levels whose centres lie inside the extent's z range.
  const long level_min = levelOf(cfg_.min_m.z()) + (levelZ(levelOf(cfg_.min_m.z())) < cfg_.min_m.z() ? 1 : 0);
  const long level_max = levelOf(std::nextafter(cfg_.max_m.z(), -INFINITY));
  std::vector<PendingColumn> pend;
  long removed = 0;
  for (const auto& [key, cut] : cuts) {
    auto it = columns_.find(key);
    if (it == columns_.end()) {
      if (!std::isfinite(cut.old)) {
        ++counters_.columns_unknown_surface;  // first cut without a surface fit: top unknown
        continue;
      }
      Column c;
      c.top = c.initial = static_cast<float>(std::max(cut.old, cut.bottom));
      it = columns_.emplace(key, c).first;
    }
    Column& col = it->second;
    if (!(cut.bottom < col.top)) continue;
    // The voxels whose centres lie in (bottom, top].
    const long lo = std::max(levelOf(cut.bottom) + 1, level_min), hi = std::min(levelOf(col.top), level_max);
    if (lo <= hi) {
      for (long k = lo; k <= hi; ++k) {
        VoxelBelief v = toVoxel(predictBelow(&col, levelZ(k)), VoxelBelief::kPredicted);
        v.top = col.top;
        v.bottom = static_cast<float>(cut.bottom);
        tree_.setLeaf(voxelKey(key, k), v);
        ++removed;
      }
      pend.push_back({key, lo, hi, col.top, static_cast<float>(cut.bottom)});
    }
    col.top = static_cast<float>(cut.bottom);
  }
  counters_.voxels_removed += removed;
  if (!pend.empty()) {
    pending_[sweep] = std::move(pend);
    while (static_cast<int>(pending_.size()) > cfg_.max_pending_sweeps) {
      ++counters_.pending_evicted;  // its estimate never came: the voxels keep their prediction
      pending_.erase(pending_.begin());
    }
  }
  return removed;
}

void Strata::resolve(long sweep, const std::vector<PendingColumn>& cols, const SoilVector* mean, const SoilVector* var) {
  bool valid = mean && var;
  for (int q = 0; valid && q < kP; ++q)
    valid = std::isfinite((*mean)[q]) && std::isfinite((*var)[q]) && (*var)[q] > 0.0;
  if (!valid) {
    ++counters_.estimates_invalid;
    return;
  }
  ++counters_.estimates_assigned;
  SoilBelief post;
  post.mean = cfg_.use_prior ? cfg_.prior_mean : *mean;
  post.var = cfg_.use_prior ? cfg_.prior_var : *var;
  if (cfg_.use_prior)
    for (int q = 0; q < kP; ++q) fuse(post.mean[q], post.var[q], (*mean)[q], (*var)[q]);
  VoxelBelief v = toVoxel(post, VoxelBelief::kEstimated);
  for (const PendingColumn& pc : cols) {
    v.top = pc.top;
    v.bottom = pc.bottom;
    for (long k = pc.lo; k <= pc.hi; ++k) tree_.setLeaf(voxelKey(pc.column, k), v);
    // After the whole column: a block of the slab collapses once all its voxels hold v.
    for (long k = pc.lo; k <= pc.hi; ++k) tree_.pruneAbove(voxelKey(pc.column, k));
    Column& col = columns_[pc.column];
    if (sweep > col.inherit_sweep) {
      if (cfg_.filter_inheritance && col.inherit_sweep >= 0) {
        // A Kalman filter down the column: the belief inherited so far, carried from its anchor
        // to the new one (variance × exp(Δz / L)), times the new estimate.
        const double f = std::exp(std::max(0.0, static_cast<double>(col.anchor) - pc.bottom) / cfg_.inflation_depth_m);
        for (int q = 0; q < kP; ++q) {
          double m = col.inherit_mean[q], v = col.inherit_var[q] * f;
          fuse(m, v, (*mean)[q], (*var)[q]);
          col.inherit_mean[q] = static_cast<float>(m);
          col.inherit_var[q] = static_cast<float>(v);
        }
      } else {
        for (int q = 0; q < kP; ++q) {
          col.inherit_mean[q] = static_cast<float>((*mean)[q]);
          col.inherit_var[q] = static_cast<float>((*var)[q]);
        }
      }
      col.inherit_sweep = sweep;
      col.anchor = pc.bottom;
    }
  }
}

long Strata::assignEstimate(long sweep, const SoilVector* mean, const SoilVector* var, std::vector<Eigen::Vector2d>* columns) {
  const auto it = pending_.find(sweep);
  if (it == pending_.end()) {
    ++counters_.estimates_unmatched;
    return 0;
  }
  long n = 0;
  for (const PendingColumn& pc : it->second) {
    n += pc.hi - pc.lo + 1;
    if (columns) columns->push_back(columnCentre(pc.column));
  }
  resolve(sweep, it->second, mean, var);
  pending_.erase(it);
  return n;
}

void Strata::flushPending() {
  for (const auto& [sweep, cols] : pending_) resolve(sweep, cols, nullptr, nullptr);
  pending_.clear();
}

SoilBelief Strata::soilAt(double x, double y, double z) const {
  std::uint32_t key;
  if (!columnKey(x, y, key) || !(z >= cfg_.min_m.z() && z < cfg_.max_m.z())) return nanBelief(SoilSource::Outside);
  const auto it = columns_.find(key);
  if (it == columns_.end()) return predictBelow(nullptr, z);
  const Column& c = it->second;
  if (z <= c.top) return predictBelow(&c, z);
  const StrataNode* n = tree_.search(x, y, z);
  if (n && n->getValue().kind != VoxelBelief::kNone) return fromVoxel(n->getValue());
  return nanBelief(SoilSource::Air);
}

SoilBelief Strata::expectedCut(double x, double y, double surface_z, double depth_m) const {
  std::uint32_t key;
  if (!columnKey(x, y, key)) return nanBelief(SoilSource::Outside);
  const auto it = columns_.find(key);
  const Column* c = it == columns_.end() ? nullptr : &it->second;
  if (!std::isfinite(surface_z)) {
    if (!c) return predictBelow(nullptr, 0.0);
    surface_z = c->top;
  }
  // Voxel centres in (surface - depth, surface]; at least the one just below the surface.
  const long k_hi = levelOf(surface_z);
  const long k_lo = std::min(levelOf(surface_z - depth_m) + 1, k_hi);
  SoilBelief out;
  out.mean.fill(0.0);
  SoilVector sd{};
  int n = 0;
  for (long k = k_lo; k <= k_hi; ++k) {
    const SoilBelief b = soilAt(x, y, levelZ(k));
    if (b.source == SoilSource::Outside || b.source == SoilSource::Air) continue;
    for (int q = 0; q < kP; ++q) {
      out.mean[q] += b.mean[q];
      sd[q] += std::sqrt(b.var[q]);
    }
    out.source = b.source;
    ++n;
  }
  if (n == 0) return nanBelief(SoilSource::Outside);
  for (int q = 0; q < kP; ++q) {
    out.mean[q] /= n;
    out.var[q] = (sd[q] / n) * (sd[q] / n);
  }
  return out;
}

double Strata::surfaceAt(double x, double y) const {
  std::uint32_t key;
  if (!columnKey(x, y, key)) return kNaN;
  const auto it = columns_.find(key);
  return it == columns_.end() ? kNaN : it->second.top;
}

double Strata::initialSurfaceAt(double x, double y) const {
  std::uint32_t key;
  if (!columnKey(x, y, key)) return kNaN;
  const auto it = columns_.find(key);
  return it == columns_.end() ? kNaN : it->second.initial;
}

std::vector<std::pair<double, VoxelBelief>> Strata::columnVoxels(double x, double y) const {
  std::vector<std::pair<double, VoxelBelief>> out;
  std::uint32_t key;
  if (!columnKey(x, y, key)) return out;
  const auto it = columns_.find(key);
  if (it == columns_.end()) return out;
  // Removed voxels lie between the surface and the first surface (at most: the extent's z
  // range clips them, and the search then finds nothing there).
  const long off = static_cast<long>(tree_.keyOffset());
  for (long k = levelOf(it->second.initial); k > levelOf(it->second.top); --k) {
    if (k + off < 0 || k + off > 0xffff) continue;
    const StrataNode* n = tree_.search(voxelKey(key, k));
    if (n && n->getValue().kind != VoxelBelief::kNone) out.emplace_back(levelZ(k), n->getValue());
  }
  return out;
}

namespace {

/// One voxel level of the pooled columns, for changeHeightAt: its centre, its voxels' mean
/// belief in prior units (means / prior sd) with the precision it claims (1 / mean of variance /
/// prior variance), and the mean top and bottom of the slabs that removed it.
struct Level {
  double z = 0;
  std::array<double, kP> mean{}, weight{};
  double top = 0, bottom = 0;
};

/// Precision-weighted prefix sums over the levels, per property: the squared deviation of a run
/// of levels from its mean, and its mean, in O(1).
class WeightedRuns {
 public:
  WeightedRuns(const std::vector<Level>& levels, const PropertyMask& use)
      : use_(use), w0_(levels.size() + 1), w1_(levels.size() + 1), w2_(levels.size() + 1) {
    w0_[0].fill(0.0);
    w1_[0].fill(0.0);
    w2_[0].fill(0.0);
    for (std::size_t i = 0; i < levels.size(); ++i)
      for (int q = 0; q < kP; ++q) {
        const double w = levels[i].weight[q], v = levels[i].mean[q];
        w0_[i + 1][q] = w0_[i][q] + w;
        w1_[i + 1][q] = w1_[i][q] + w * v;
        w2_[i + 1][q] = w2_[i][q] + w * v * v;
      }
  }
  /// Levels [a, b): the weighted squared deviation from the run's mean, summed over the
  /// properties in use.
  double sse(int a, int b) const {
    double e = 0.0;
    for (int q = 0; q < kP; ++q) {
      if (!use_[q]) continue;
      const double d0 = diff(w0_, a, b, q), d1 = diff(w1_, a, b, q), d2 = diff(w2_, a, b, q);
      e += std::max(0.0, d2 - d1 * d1 / d0);
    }
    return e;
  }
  /// Levels [a, b): the weighted mean of property q.
  double mean(int a, int b, int q) const { return diff(w1_, a, b, q) / diff(w0_, a, b, q); }
  bool uses(int q) const { return use_[q]; }

 private:
  static double diff(const std::vector<std::array<double, kP>>& v, int a, int b, int q) {
    return v[static_cast<std::size_t>(b)][q] - v[static_cast<std::size_t>(a)][q];
  }
  PropertyMask use_;
  std::vector<std::array<double, kP>> w0_, w1_, w2_;
};

/// The split of the levels (top first) into two runs of at least `min_voxels` each with the least
/// weighted squared deviation; -1 when there is no spread or it explains less than `min_gain`.
int bestSplit(const WeightedRuns& runs, int n, int min_voxels, double min_gain) {
  const double total = runs.sse(0, n);
  if (!(total > 1e-12)) return -1;
  double best = std::numeric_limits<double>::infinity();
  int split = -1;
  for (int s = min_voxels; s <= n - min_voxels; ++s) {
    const double e = runs.sse(0, s) + runs.sse(s, n);
    if (e < best) {
      best = e;
      split = s;
    }
  }
  return split < 0 || 1.0 - best / total < min_gain ? -1 : split;
}

/// Where the change lies, given the split (header, changeHeightAt): between the slabs of the
/// levels beside it, then moved into a mixed one.
double placeChange(const std::vector<Level>& levels, const WeightedRuns& runs, int split, double res) {
  const int n = static_cast<int>(levels.size()), ka = split - 1, kb = split;
  const Level &up = levels[static_cast<std::size_t>(ka)], &down = levels[static_cast<std::size_t>(kb)];
  const double face = 0.5 * (up.z + down.z);
  // Where the sweeps above the split ended and those below began. In one column both lie within
  // half a voxel of the face (a slab holds its voxels' centres and not its neighbours'); pooled
  // columns can pull the means further, hence the clamp.
  const double z = std::clamp(0.5 * (up.bottom + down.top), face - 0.5 * res, face + 0.5 * res);
  // Mixed slabs: a sweep that cut across the change estimates a mix of the two soils, and the
  // split gives its level to one side. Each level beside the split is read as a linear mix of
  // the two runs' soils (each run's mean without that level; the fraction is the projection on
  // the line between them), the other soil filling the bottom of the upper level's slab and the
  // top of the lower level's: the change moves into that slab by the fraction. Within a voxel
  // of the face (the two levels' extent).
  double num_a = 0, num_b = 0, den = 0;
  for (int q = 0; q < kP; ++q) {
    if (!runs.uses(q)) continue;
    const double U = ka > 0 ? runs.mean(0, ka, q) : up.mean[q];
    const double D = kb + 1 < n ? runs.mean(kb + 1, n, q) : down.mean[q];
    num_a += (up.mean[q] - U) * (D - U);
    num_b += (down.mean[q] - D) * (U - D);
    den += (D - U) * (D - U);
  }
  if (!(den > 1e-12)) return z;
  const double fa = std::clamp(num_a / den, 0.0, 1.0), fb = std::clamp(num_b / den, 0.0, 1.0);
  return std::clamp(z + fa * (up.top - up.bottom) - fb * (down.top - down.bottom), face - res, face + res);
}

}  // namespace

double Strata::changeHeightAt(double x, double y, int min_voxels, double min_gain, double radius_m, VoxelCache* cache,
                              const PropertyMask* properties) const {
  std::uint32_t key0;
  if (!columnKey(x, y, key0)) return kNaN;
  const double res = cfg_.resolution_m;
  struct Sums {
    std::array<double, kP> mean{}, var{};
    double top = 0, bottom = 0;
    int n = 0;
  };
  // The levels of the columns within radius_m, pooled: level (z key), top first.
  std::map<long, Sums, std::greater<long>> sums;
  const int reach = static_cast<int>(std::floor(std::max(0.0, radius_m) / res));
  const Eigen::Vector2d centre = columnCentre(key0);
  for (int a = -reach; a <= reach; ++a)
    for (int b = -reach; b <= reach; ++b) {
      if ((a * a + b * b) * res * res > radius_m * radius_m + 1e-12) continue;
      // The column's estimated voxels, from the cache when there is one.
      const double nx = centre.x() + a * res, ny = centre.y() + b * res;
      std::uint32_t key;
      if (!columnKey(nx, ny, key)) continue;
      std::vector<VoxelCache::Voxel> local;
      const std::vector<VoxelCache::Voxel>* list = &local;
      auto fill = [&](std::vector<VoxelCache::Voxel>& v) {
        for (const auto& [z, b] : columnVoxels(nx, ny))
          if (b.kind == VoxelBelief::kEstimated) v.push_back({levelOf(z), b.mean, b.var, b.top, b.bottom});
      };
      if (cache) {
        auto it = cache->columns.find(key);
        if (it == cache->columns.end()) {
          it = cache->columns.emplace(key, std::vector<VoxelCache::Voxel>{}).first;
          fill(it->second);
        }
        list = &it->second;
      } else {
        fill(local);
      }
      for (const VoxelCache::Voxel& v : *list) {
        Sums& l = sums[v.level];
        for (int q = 0; q < kP; ++q) {
          l.mean[q] += v.mean[q] / std::sqrt(cfg_.prior_var[q]);
          l.var[q] += v.var[q] / cfg_.prior_var[q];
        }
        l.top += v.top;
        l.bottom += v.bottom;
        ++l.n;
      }
    }
  std::vector<Level> levels;
  levels.reserve(sums.size());
  for (const auto& [k, l] : sums) {
    Level e;
    e.z = levelZ(k);
    for (int q = 0; q < kP; ++q) {
      e.mean[q] = l.mean[q] / l.n;
      e.weight[q] = l.n / std::max(1e-12, l.var[q]);
    }
    e.top = l.top / l.n;
    e.bottom = l.bottom / l.n;
    levels.push_back(e);
  }
  const int n = static_cast<int>(levels.size());
  min_voxels = std::max(1, min_voxels);
  if (n < 2 * min_voxels) return kNaN;
  static constexpr PropertyMask kAll{true, true, true, true, true};
  const WeightedRuns runs(levels, properties ? *properties : kAll);
  const int split = bestSplit(runs, n, min_voxels, min_gain);
  return split < 0 ? kNaN : placeChange(levels, runs, split, cfg_.resolution_m);
}

double Strata::changeDepthAt(double x, double y, int min_voxels, double min_gain, double radius_m) const {
  return initialSurfaceAt(x, y) - changeHeightAt(x, y, min_voxels, min_gain, radius_m);
}

std::size_t Strata::memoryBytes() const {
  std::size_t pend = 0;
  for (const auto& [s, v] : pending_) pend += v.capacity() * sizeof(PendingColumn) + 48;
  return tree_.memoryUsage() + columns_.size() * (sizeof(Column) + sizeof(std::uint32_t) + 16) +
         columns_.bucket_count() * sizeof(void*) + pend;
}

void Strata::save(const std::filesystem::path& path) const {
  std::ostringstream o(std::ios::binary);
  if (!tree_.write(o)) throw OutputError(path.string() + ": could not serialise the strata tree");
  o << '\n' << kTrailer << '\n';
  put(o, cfg_.resolution_m);
  for (int a = 0; a < 3; ++a) put(o, cfg_.min_m[a]);
  for (int a = 0; a < 3; ++a) put(o, cfg_.max_m[a]);
  put(o, cfg_.inflation_depth_m);
  for (int q = 0; q < kP; ++q) put(o, cfg_.prior_mean[q]);
  for (int q = 0; q < kP; ++q) put(o, cfg_.prior_var[q]);
  put(o, static_cast<std::uint8_t>(cfg_.use_prior));
  put(o, static_cast<std::uint8_t>(cfg_.prior_below));
  std::vector<std::uint32_t> keys;
  keys.reserve(columns_.size());
  for (const auto& [k, c] : columns_) keys.push_back(k);
  std::sort(keys.begin(), keys.end());
  put(o, static_cast<std::uint64_t>(keys.size()));
  for (std::uint32_t k : keys) {
    const Column& c = columns_.at(k);
    put(o, k);
    put(o, c.top);
    put(o, c.initial);
    put(o, c.anchor);
    put(o, static_cast<std::int64_t>(c.inherit_sweep));
    for (int q = 0; q < kP; ++q) put(o, c.inherit_mean[q]);
    for (int q = 0; q < kP; ++q) put(o, c.inherit_var[q]);
  }
  io::writeFileAtomically(path, o.str());
}

Strata Strata::load(const std::filesystem::path& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw InputError(path.string() + ": cannot open");
  const auto bad = [&](const std::string& what) { return InputError(path.string() + ": " + what); };
  std::string line;
  if (!std::getline(f, line) || line.rfind("# Octomap OcTree file", 0) != 0)
    throw bad("not an OctoMap .ot file (the first line must be '# Octomap OcTree file')");
  std::string id;
  double res = 0;
  long size = -1;
  while (std::getline(f, line)) {
    if (!line.empty() && line[0] == '#') continue;
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (word == "data") break;
    if (word == "id") ls >> id;
    else if (word == "res") ls >> res;
    else if (word == "size") ls >> size;
    else throw bad("unknown header line '" + line + "'");
  }
  if (id != kTreeId) throw bad("holds a tree of type '" + id + "', not " + kTreeId + " (written by octomap_strata)");
  if (!(res > 0) || size < 0) throw bad("header without a valid 'res' and 'size'");
  StrataConfig cfg;
  cfg.resolution_m = res;
  cfg.prior_mean.fill(0.0);
  cfg.prior_var.fill(1.0);
  cfg.min_m = Eigen::Vector3d::Constant(-res);  // placeholders within any key range: the
  cfg.max_m = Eigen::Vector3d::Constant(res);   // trailer holds the real extent
  Strata s(cfg);
  if (size > 0) {
    s.tree_.readData(f);
    if (!f) throw bad("truncated tree data");
    if (static_cast<long>(s.tree_.size()) != size)
      throw bad("the tree holds " + std::to_string(s.tree_.size()) + " nodes, the header says " + std::to_string(size));
  }
  while (std::getline(f, line) && line.empty()) {
  }
  if (line != kTrailer && line != kTrailerV4 && line != kTrailerV3)
    throw bad("no '" + std::string(kTrailer) + "' trailer after the tree (not written by octomap_strata?)");
  bool ok = get(f, cfg.resolution_m);
  for (int a = 0; a < 3; ++a) ok = ok && get(f, cfg.min_m[a]);
  for (int a = 0; a < 3; ++a) ok = ok && get(f, cfg.max_m[a]);
  ok = ok && get(f, cfg.inflation_depth_m);
  for (int q = 0; q < kP; ++q) ok = ok && get(f, cfg.prior_mean[q]);
  for (int q = 0; q < kP; ++q) ok = ok && get(f, cfg.prior_var[q]);
  // Format 3 always fused the prior, format 4 in both places or neither.
  std::uint8_t use_prior = 1;
  if (line != kTrailerV3) ok = ok && get(f, use_prior);
  std::uint8_t prior_below = use_prior;
  if (line == kTrailer) ok = ok && get(f, prior_below);
  if (use_prior > 1 || prior_below > 1) throw bad("the trailer's prior flags are not 0 or 1");
  cfg.use_prior = use_prior == 1;
  cfg.prior_below = prior_below == 1;
  std::uint64_t n = 0;
  ok = ok && get(f, n);
  if (!ok) throw bad("truncated configuration trailer");
  if (cfg.resolution_m != res) throw bad("the trailer's resolution differs from the header's");
  try {
    Strata probe(cfg);  // validates the stored configuration
  } catch (const ConfigError& e) {
    throw bad(std::string("stored configuration is invalid: ") + e.what());
  }
  s.cfg_ = cfg;
  for (std::uint64_t i = 0; i < n; ++i) {
    std::uint32_t k;
    Column c;
    std::int64_t sweep;
    ok = get(f, k) && get(f, c.top) && get(f, c.initial) && get(f, c.anchor) && get(f, sweep);
    for (int q = 0; ok && q < kP; ++q) ok = get(f, c.inherit_mean[q]);
    for (int q = 0; ok && q < kP; ++q) ok = get(f, c.inherit_var[q]);
    if (!ok) throw bad("truncated after " + std::to_string(i) + " of " + std::to_string(n) + " columns");
    c.inherit_sweep = static_cast<long>(sweep);
    s.columns_[k] = c;
  }
  return s;
}

void Strata::exportColorOt(const std::filesystem::path& path, int param, double below_m, double lo, double hi) const {
  if (param < 0 || param >= kP) throw ConfigError("octomap_strata: no soil parameter " + std::to_string(param));
  if (!(lo < hi)) {
    lo = soil::kSoilParams[param].lo;
    hi = soil::kSoilParams[param].hi;
  }
  const io::Colormap cmap = io::Colormap::byName("viridis");
  const double res = cfg_.resolution_m;
  octomap::ColorOcTree ct(res);
  auto paint = [&](const octomap::OcTreeKey& k, double value) {
    octomap::ColorOcTreeNode* n = ct.updateNode(k, true);
    const io::Rgba c = cmap.at((value - lo) / (hi - lo));
    n->setColor(c.r, c.g, c.b);
  };
  for (auto it = tree_.begin_leafs(), end = tree_.end_leafs(); it != end; ++it) {
    if (it->getValue().kind == VoxelBelief::kNone) continue;
    const double value = it->getValue().mean[param];
    // A pruned leaf stands for several voxels: paint each.
    const int span = 1 << (tree_.getTreeDepth() - it.getDepth());
    const octomap::OcTreeKey base = it.getIndexKey();
    for (int a = 0; a < span; ++a)
      for (int b = 0; b < span; ++b)
        for (int c = 0; c < span; ++c) {
          octomap::OcTreeKey k(static_cast<octomap::key_type>(base[0] + a), static_cast<octomap::key_type>(base[1] + b),
                               static_cast<octomap::key_type>(base[2] + c));
          paint(k, value);
        }
  }
  std::vector<std::uint32_t> keys;
  for (const auto& [k, c] : columns_) keys.push_back(k);
  std::sort(keys.begin(), keys.end());
  for (std::uint32_t key : keys) {
    const Column& c = columns_.at(key);
    for (long k = levelOf(c.top); k > levelOf(c.top - below_m); --k) {
      const double z = levelZ(k);
      if (z >= cfg_.min_m.z() && z < cfg_.max_m.z()) paint(voxelKey(key, k), predictBelow(&c, z).mean[param]);
    }
  }
  ct.updateInnerOccupancy();
  std::ostringstream o(std::ios::binary);
  if (!ct.write(o)) throw OutputError(path.string() + ": could not serialise the ColorOcTree");
  io::writeFileAtomically(path, o.str());
}

}  // namespace terramap::strata
