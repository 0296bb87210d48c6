// roughness: the standard deviation of elevation in a square window around each cell, the
// model plugin to copy (docs/plugins.md). What it shows:
// - a schema with units and docs, every cross-check reported at once (Params::report), and
//   checks against the map's geometry (Params::mapGeometry) so `terramap validate` finds them;
// - layers with a unit and a one-line doc (what NaN means);
// - one task per output tile (ctx.executor().forEach), reading through core's MapWindow, in a
//   fixed summation order: bit-identical for any thread count;
// - incremental updates: only the tiles within the window of a changed input tile are
//   recomputed (ctx.changedTiles, LayeredMap::tilesWithin). A cell's value depends on its
//   window only, so the result has the same bits as recomputing the whole map.
#include <terramap/core/map_window.hpp>
#include <terramap/plugin/abi.hpp>

#include <cmath>
#include <sstream>

namespace {
using namespace terramap;

std::string text(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

/// The logical rectangles (1 to 4) that a buffer-space tile rectangle covers: the ring buffer
/// may wrap inside it along either axis.
std::vector<CellRect> logicalPieces(const LayeredMap& map, const CellRect& b) {
  const Size& n = map.geometry().size();
  auto split = [](int first_buffer, int count, int start, int size) {
    // buffer index -> logical index (buffer - start) mod size, contiguous until it wraps.
    const int l0 = ((first_buffer - start) % size + size) % size;
    const int head = std::min(count, size - l0);
    std::vector<std::pair<int, int>> runs{{l0, head}};
    if (head < count) runs.emplace_back(0, count - head);
    return runs;
  };
  std::vector<CellRect> out;
  for (const auto& [i0, rows] : split(b.r0, b.rows, map.startIndex().x(), n.x()))
    for (const auto& [j0, cols] : split(b.c0, b.cols, map.startIndex().y(), n.y()))
      out.push_back(CellRect{i0, j0, rows, cols});
  return out;
}

class Roughness : public Plugin {
 public:
  ParamSchema schema() const override {
    return {param::text("input_layer", "elevation", {}, "elevation layer to read (m)"),
            param::text("output_layer", "roughness", {}, "layer to create (m)"),
            param::real("window_m", 0.25, 0.0, 100.0, "m", "half-width of the square window"),
            param::real("min_valid_fraction", 0.5, 0.0, 1.0, "1",
                        "fraction of the window's cells that must be known to output a value"),
            param::texts("run_on", {"point_cloud"}, "event kinds after which to update")};
  }

  void configure(const Params& p) override {
    in_ = p.getString("input_layer");
    out_ = p.getString("output_layer");
    window_m_ = p.getDouble("window_m");
    min_valid_ = p.getDouble("min_valid_fraction");
    std::string unknown;
    events_ = eventMaskFromNames(p.getStrings("run_on"), &unknown);
    // report(), not fail(): the user sees every problem of this stage in one run of validate.
    if (in_ == out_) p.report("output_layer", "must differ from input_layer ('" + in_ + "')");
    if (!unknown.empty()) p.report("run_on", "unknown event kind '" + unknown + "'");
    if (const Geometry* g = p.mapGeometry()) {
      if (window_m_ < g->resolution())
        p.report("window_m", "must be at least the map's resolution (" + text(g->resolution()) + " m, got " +
                                 text(window_m_) + " m): a window of one cell has no spread");
      const int w = halfWidth(g->resolution());
      if (2 * w + 1 > std::min(g->size().x(), g->size().y()))
        p.report("window_m", "the window (" + std::to_string(2 * w + 1) + " cells across) does not fit in the map (" +
                                 std::to_string(g->size().x()) + " x " + std::to_string(g->size().y()) + " cells)");
    }
  }

  std::vector<LayerSpec> layers() const override {
    return {LayerSpec{in_, LayerAccess::Read, "", 0.0f, ""},
            LayerSpec{out_, LayerAccess::Create, "m", std::numeric_limits<float>::quiet_NaN(),
                      "standard deviation of " + in_ + " within window_m; NaN where too few cells are known"}};
  }
  EventMask events() const override { return events_; }

  void start(ProcessContext& ctx) override {
    in_id_ = ctx.map().layerId(in_);
    out_id_ = ctx.map().layerId(out_);
    ctx.trackChanges(in_id_);
  }

  void process(ProcessContext& ctx, const Event&) override {
    LayeredMap& map = ctx.map();
    const int w = halfWidth(map.geometry().resolution());
    const std::vector<int> tiles = map.tilesWithin(ctx.changedTiles(in_id_), w);
    ctx.executor().forEach(static_cast<int>(tiles.size()),
                           [&](int n) { updateTile(map, tiles[static_cast<size_t>(n)], w); });
    ctx.addCounter("tiles_updated", static_cast<double>(tiles.size()));
  }

 private:
  int halfWidth(double resolution) const { return static_cast<int>(std::floor(window_m_ / resolution + 1e-9)); }

  void updateTile(LayeredMap& map, int t, int w) const {
    const CellRect b = map.tileRect(t);
    float* out = map.mutableTileData(out_id_, t);
    const int T = map.tileSize();
    const double need = min_valid_ * (2 * w + 1) * (2 * w + 1);
    std::vector<double> z;
    for (const CellRect& piece : logicalPieces(map, b)) {
      // The piece grown by the window, clipped to the map: one gather, then plain array reads.
      const MapWindow win(map, piece.r0 - w, piece.c0 - w, piece.rows + 2 * w, piece.cols + 2 * w);
      win.gather(map, in_id_, z);
      for (int i = piece.r0; i < piece.r0 + piece.rows; ++i)
        for (int j = piece.c0; j < piece.c0 + piece.cols; ++j) {
          double s = 0, s2 = 0;
          long n = 0;
          for (int ii = std::max(i - w, win.i0()); ii < std::min(i + w + 1, win.i0() + win.rows()); ++ii)
            for (int jj = std::max(j - w, win.j0()); jj < std::min(j + w + 1, win.j0() + win.cols()); ++jj) {
              const double v = z[static_cast<size_t>(win.local(ii, jj))];
              if (!std::isfinite(v)) continue;
              s += v;
              s2 += v * v;
              ++n;
            }
          float r = std::numeric_limits<float>::quiet_NaN();
          if (n > 0 && n >= need) r = static_cast<float>(std::sqrt(std::max(0.0, s2 / n - (s / n) * (s / n))));
          const Index buf = map.bufferIndex(Index(i, j));
          out[(buf.x() - b.r0) * T + (buf.y() - b.c0)] = r;
        }
    }
  }

  std::string in_, out_;
  double window_m_ = 0.25, min_valid_ = 0.5;
  EventMask events_ = 0;
  LayerId in_id_ = -1, out_id_ = -1;
};
}  // namespace

TERRAMAP_PLUGIN(Roughness, "roughness", "0.1.0", "example: standard deviation of elevation in a window")
