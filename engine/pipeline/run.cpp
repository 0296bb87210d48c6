#include <terramap/pipeline/run.hpp>
#include <terramap/io/output_budget.hpp>

#include <terramap/core/memory_budget.hpp>
#include <terramap/core/text.hpp>
#include <terramap/io/atomic_file.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/io/gridmap_mcap.hpp>
#include <terramap/io/render.hpp>
#include <terramap/io/snapshot.hpp>
#include <terramap/pipeline/report.hpp>
#include <terramap/pipeline/source.hpp>

#include <nlohmann/json.hpp>

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <exception>
#include <filesystem>
#include <mutex>
#include <thread>

namespace terramap {

namespace fs = std::filesystem;

namespace {

/// Resident memory of this process in bytes (Linux /proc/self/statm), 0 where unknown.
std::uint64_t residentBytes() {
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return 0;
  unsigned long long size = 0, resident = 0;
  const int n = std::fscanf(f, "%llu %llu", &size, &resident);
  std::fclose(f);
  const long page = sysconf(_SC_PAGESIZE);
  return n == 2 && page > 0 ? static_cast<std::uint64_t>(resident) * static_cast<std::uint64_t>(page) : 0;
}

/// The report's "series": one entry at the first event at or after each multiple of
/// `every` seconds of event time (so a long run shows whether memory, drops or the error drift),
/// and a last one at the run's end, after finish() and the source's drops, so it matches the
/// report's totals. Disabled when `every` <= 0.
class SeriesRecorder {
 public:
  SeriesRecorder(double every, Engine& engine, Source& source, const RunOptions& options,
                 std::chrono::steady_clock::time_point t0)
      : every_(every), engine_(engine), source_(source), options_(options), t0_(t0) {}

  bool enabled() const { return every_ > 0; }

  void afterEvent(double t, long events) {
    if (!enabled()) return;
    last_t_ = t;
    if (std::isnan(next_)) next_ = (std::floor(t / every_) + 1) * every_;
    if (t >= next_) {
      sample(t, events);
      next_ = (std::floor(t / every_) + 1) * every_;
    }
  }

  /// The run's end; skipped when the last boundary entry already says exactly that.
  void atEnd(long events) {
    if (!enabled() || !std::isfinite(last_t_)) return;
    const std::size_t before = series_.size();
    sample(last_t_, events);
    if (before == 0) return;
    const nlohmann::json &a = series_[before - 1], &b = series_[before];
    if (a["events"] == b["events"] && a["dropped"] == b["dropped"] && a["records_total"] == b["records_total"])
      series_.erase(before);
  }

  nlohmann::json take() { return std::move(series_); }

 private:
  void sample(double t, long events) {
    const RunReport r = engine_.report();  // small: the records are in the spool
    std::map<std::string, long> dropped = r.source_dropped;
    long records = 0;
    for (const auto& st : r.stages) {
      for (const auto& [reason, count] : st.stats.dropped) dropped[reason] += count;
      records += st.records_total;
    }
    const LayeredMap& map = engine_.map();
    nlohmann::json entry = {
        {"t_s", t},
        {"wall_s", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count()},
        {"unix_time_s", std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count()},
        {"events", events},
        {"dropped", dropped},
        {"records_total", records},
        {"map_tiles_allocated", map.allocatedTiles()},
        {"map_center_m", {map.geometry().center().x(), map.geometry().center().y()}},
        {"rss_bytes", residentBytes()}};
    if (options_.truth_stats) {
      const std::string truth = options_.truth_stats(map, source_);
      if (!truth.empty()) entry["truth"] = nlohmann::json::parse(truth);
    }
    series_.push_back(std::move(entry));
  }

  double every_;
  Engine& engine_;
  Source& source_;
  const RunOptions& options_;
  std::chrono::steady_clock::time_point t0_;
  double next_ = NAN, last_t_ = NAN;
  nlohmann::json series_ = nlohmann::json::array();
};

/// Runs a source on a thread of its own, at most `capacity` events ahead of the stages: the
/// simulator computes the next events while the stages process these (each side keeps the
/// other's idle core busy). The events arrive in the source's order, so the results are the
/// same as without it. progress() is the one of the event last handed over. An exception of
/// the source is rethrown by next() at that point of the stream.
class PrefetchSource {
 public:
  PrefetchSource(Source& source, std::size_t capacity) : source_(source), capacity_(capacity) {
    thread_ = std::thread([this] { produce(); });
  }
  ~PrefetchSource() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    changed_.notify_all();
    thread_.join();
  }
  PrefetchSource(const PrefetchSource&) = delete;
  PrefetchSource& operator=(const PrefetchSource&) = delete;

  bool next(Event& e) {
    std::unique_lock<std::mutex> lock(mutex_);
    changed_.wait(lock, [&] { return !queue_.empty() || done_; });
    if (queue_.empty()) {
      if (error_) std::rethrow_exception(error_);
      return false;
    }
    e = std::move(queue_.front().event);
    progress_ = queue_.front().progress;
    queue_.pop_front();
    lock.unlock();
    changed_.notify_all();
    return true;
  }
  double progress() const { return progress_; }

 private:
  struct Item {
    Event event;
    double progress;
  };
  void produce() {
    try {
      while (true) {
        Item item;
        const bool more = source_.next(item.event);
        item.progress = source_.progress();
        std::unique_lock<std::mutex> lock(mutex_);
        if (!more) break;
        changed_.wait(lock, [&] { return queue_.size() < capacity_ || stop_; });
        if (stop_) break;
        queue_.push_back(std::move(item));
        lock.unlock();
        changed_.notify_all();
      }
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex_);
      error_ = std::current_exception();
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      done_ = true;
    }
    changed_.notify_all();
  }

  Source& source_;
  const std::size_t capacity_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<Item> queue_;
  bool done_ = false, stop_ = false;
  std::exception_ptr error_;
  double progress_ = -1.0;
  std::thread thread_;  // last: started once everything above exists
};

/// map.tif, the PNGs and the snapshot the outputs ask for; appends each file written to `files`.
void writeMapOutputs(const PipelineSpec& spec, const Engine& engine, const TruthComparison& truth,
                     std::vector<std::string>& files) {
  const LayeredMap& map = engine.map();
  const fs::path dir(spec.outputs.dir);
  if (!spec.outputs.geotiff.empty()) {
    io::GeoTiffOptions go;
    go.georef.epsg = spec.outputs.epsg;
    if (spec.outputs.origin.size() == 2) {
      go.georef.origin_easting = spec.outputs.origin[0];
      go.georef.origin_northing = spec.outputs.origin[1];
    }
    go.layer_docs = engine.layerDocs();
    const fs::path p = dir / "map.tif";
    io::writeGeoTiff(map, spec.outputs.geotiff, p, go);
    files.push_back(p.string());
  }
  std::vector<std::string> pngs = spec.outputs.png;
  if (spec.outputs.png_all) pngs = map.layerNames();
  auto rendered = [&](const std::string& l) { return std::find(pngs.begin(), pngs.end(), l) != pngs.end(); };
  for (const auto& layer : pngs) {
    io::RenderOptions ro;
    ro.scale = io::runPngScale(map.geometry());
    ro.nan_color = io::Rgba{128, 128, 128, 255};
    const std::string& unit = map.layerInfo(map.layerId(layer)).unit;
    // Heights read best hillshaded; everything else as a plain colour map.
    ro.hillshade = unit == "m" && layer.find("elevation") != std::string::npos && layer != "elevation_error";
    if (ro.hillshade) ro.ambient = 0.35;
    if (layer == "elevation_error") ro.colormap = "rdbu";  // symmetric around 0: white = no error
    // A truth picture and its estimate side by side are compared by eye: one colour range for
    // both (the union of their automatic ranges), so a colour means one value in either.
    const std::string partner = layer.rfind("truth_", 0) == 0 ? layer.substr(6) : "truth_" + layer;
    if (map.hasLayer(partner) && rendered(partner)) {
      const io::ValueRange a = io::renderRange(map, map.layerId(layer), ro);
      const io::ValueRange b = io::renderRange(map, map.layerId(partner), ro);
      const io::ValueRange u{std::min(a.min, b.min), std::max(a.max, b.max)};
      if (u.min < u.max) ro.range = u;
    }
    io::Annotation an;
    const auto cats = truth.categories.find(layer);
    if (cats != truth.categories.end() && !cats->second.empty()) {
      // Ids, not quantities: a legend of names, each swatch the colour of its id.
      an.categories = cats->second;
      float lo = cats->second.front().first, hi = lo;
      for (const auto& [v, name] : cats->second) lo = std::min(lo, v), hi = std::max(hi, v);
      ro.range = lo < hi ? io::ValueRange{lo, hi} : io::ValueRange{lo - 0.5f, lo + 0.5f};
    } else if (std::find(truth.layers.begin(), truth.layers.end(), layer) != truth.layers.end()) {
      an.caption = truth.caption;  // the elevation comparison's statistics, not a zone map's
    }
    if (layer == "elevation_error") an.title = "elevation_error: map - truth [cm]";
    // Soil pictures show where the truth's soil zones are (the run compared them, truth_report).
    const bool soil_layer = layer.rfind("soil_", 0) == 0 || layer.rfind("fee_index", 0) == 0;
    if (soil_layer && layer != "truth_soil_zone" && map.hasLayer("truth_soil_zone")) {
      an.outline_regions = "truth_soil_zone";
      an.caption = "white lines and names: the simulator's soil zones";
      // Each zone named on the map by its own name (the family and density are in the zone legend).
      if (const auto z = truth.categories.find("truth_soil_zone"); z != truth.categories.end())
        for (const auto& [v, name] : z->second) an.region_names.emplace_back(v, name.substr(0, name.find(" (")));
    }

    const fs::path p = dir / (layer + ".png");
    io::renderPng(map, layer, p, ro, an);
    files.push_back(p.string());
  }
  if (spec.outputs.snapshot) {
    const fs::path p = dir / "map.tmap";
    io::saveSnapshot(map, p);
    files.push_back(p.string());
  }
}

/// outputs.mcap's writer, its layers checked against the map the stages made and its messages
/// against the memory budget before the first event; null when the output is off.
std::unique_ptr<io::GridMapMcapWriter> openGridMapOutput(const PipelineSpec& spec, const Engine& engine) {
  const McapOutputSpec& m = spec.outputs.mcap;
  if (!m.enabled) return nullptr;
  const LayeredMap& map = engine.map();
  const std::vector<std::string> names = map.layerNames();
  std::string errors;
  for (const auto& l : m.layers)
    if (!map.hasLayer(l))
      errors += (errors.empty() ? "" : "\n") + m.where + ".layers: no stage creates layer '" + l + "'" + didYouMean(l, names) +
                "; layers: " + joinStrings(names);
  if (!errors.empty()) throw ConfigError(errors);
  const Geometry& g = map.geometry();
  requireConfigBudget(io::gridMapMcapWorkingBytes(g, m.layers.size()), m.where + ": one GridMap message",
                      std::to_string(g.size().x()) + " x " + std::to_string(g.size().y()) + " cells x " +
                          std::to_string(m.layers.size()) + " layers");
  io::GridMapMcapOptions o;
  o.layers = m.layers;
  o.topic = m.topic;
  o.frame_id = m.frame_id;
  o.copy_clouds = m.copy_clouds;
  o.cloud_topic = m.cloud_topic;
  o.compression = io::mcap::parseCompression(m.compression, m.where + ".compression");
  return std::make_unique<io::GridMapMcapWriter>((fs::path(spec.outputs.dir) / m.file).string(), std::move(o));
}

/// True when some cell of `layer` is known (not NaN). Unallocated tiles read as the fill.
bool anyKnownCell(const LayeredMap& map, const std::string& layer) {
  const LayerId id = map.layerId(layer);
  const bool fill_known = !std::isnan(map.layerInfo(id).fill);
  const int stride = map.tileSize();
  for (int t = 0; t < map.tileCount(); ++t) {
    const float* d = map.tileData(id, t);
    if (!d) {
      if (fill_known) return true;
      continue;
    }
    const CellRect rect = map.tileRect(t);
    for (int r = 0; r < rect.rows; ++r)
      for (int c = 0; c < rect.cols; ++c)
        if (!std::isnan(d[r * stride + c])) return true;
  }
  return false;
}

/// The layers the outputs write (GeoTIFF bands and PNGs, each once) that hold no known cell.
std::vector<std::string> unknownOutputLayers(const PipelineSpec& spec, const LayeredMap& map) {
  std::vector<std::string> layers = spec.outputs.geotiff;
  const std::vector<std::string> pngs = spec.outputs.png_all ? map.layerNames() : spec.outputs.png;
  for (const auto& l : pngs)
    if (std::find(layers.begin(), layers.end(), l) == layers.end()) layers.push_back(l);
  std::vector<std::string> unknown;
  for (const auto& l : layers)
    if (map.hasLayer(l) && !anyKnownCell(map, l)) unknown.push_back(l);
  return unknown;
}

/// report.json: the engine's report with the run's own facts (pipeline, truth, events, wall
/// time, map, files, warnings, series), the spooled records streamed in; its path joins res.files.
void writeRunReport(const PipelineSpec& spec, const LayeredMap& map, const TruthComparison& truth, long n,
                    SeriesRecorder& series, RecordSpool& spool, RunResult& res) {
  const fs::path dir(spec.outputs.dir);
  const double run_s = res.run_wall_s;
  const fs::path p = dir / "report.json";
  nlohmann::json extra;
  extra["pipeline"] = spec.file;
  if (!truth.json.empty()) extra["truth"] = nlohmann::json::parse(truth.json);
  extra["events_total"] = n;
  extra["run_wall_s"] = run_s;
  if (std::isfinite(res.real_time_factor)) extra["real_time_factor"] = res.real_time_factor;
  extra["map"] = {{"resolution_m", map.geometry().resolution()},
                  {"size", {map.geometry().size().x(), map.geometry().size().y()}},
                  {"center_m", {map.geometry().center().x(), map.geometry().center().y()}},
                  {"layers", map.layerNames()}};
  std::vector<std::string> files = res.files;
  files.push_back(p.string());
  extra["files"] = files;
  if (!res.unknown_layers.empty()) {
    nlohmann::json w = nlohmann::json::array();
    for (const auto& l : res.unknown_layers)
      w.push_back({{"kind", "layer_all_unknown"}, {"layer", l}});
    extra["warnings"] = w;
  }
  if (series.enabled()) {
    extra["series_interval_s"] = spec.outputs.series_interval_s;
    extra["series"] = series.take();
  }
  writeReport(res.report, p.string(), extra.dump(), spool);
  res.files.push_back(p.string());
}

}  // namespace

RunResult runPipeline(const PipelineSpec& spec_in, const RunOptions& options) {
  PipelineSpec spec = spec_in;
  if (options.threads > 0) spec.threads = options.threads;
  if (!options.out_dir.empty()) spec.outputs.dir = options.out_dir;
  PluginRegistry registry = PluginRegistry::forPipeline(spec.plugin_paths, spec.plugin_paths_where);
  // Everything that can be checked is checked before the first event: the pipeline (every
  // problem at once) and the source's settings.
  std::vector<std::string> errors = Engine::validate(spec, registry);
  std::unique_ptr<Source> source;
  try {
    source = makeSource(spec);
  } catch (const ConfigError& e) {
    errors.push_back(e.what());
  }
  if (!errors.empty()) {
    std::string all;
    for (const auto& e : errors) all += (all.empty() ? "" : "\n") + e;
    throw ConfigError(all);
  }
  auto engine = Engine::fromValidatedSpec(spec, registry);  // validated just above
  // The outputs are written last; whether their folder can take them is learnt now, not after
  // the whole run. A killed run's temporaries are swept from it (only terramap's, of dead
  // processes, only that folder).
  try {
    io::requireWritableFolder(spec.outputs.dir);
  } catch (const OutputError& e) {
    throw OutputError(std::string(e.what()) + " (refused before the first event)");
  }
  std::vector<std::string> removed_temporaries;
  for (const auto& p : io::removeStaleTemporaries(spec.outputs.dir)) removed_temporaries.push_back(p.string());
  // A source that knows the truth adds pictures the file does not list (truth_elevation.png,
  // elevation_error.png) and compares whole rasters: checked now, as validate checks the
  // listed outputs, so a big sparse map is not refused only after the whole run.
  if (options.compare_truth) {
    Eigen::MatrixXf one(1, 1);
    if (source->truth("elevation", Geometry(spec.resolution, Size(1, 1), spec.center), one))
      io::requireRasterOutputBudget(spec.geometry(), "png", io::runPngScale(spec.geometry()),
                                    spec.file + ": the source's truth pictures and error layers", false);
  }

  std::unique_ptr<io::GridMapMcapWriter> gridmaps = openGridMapOutput(spec, *engine);

  // Records go to disk as they come (an hour reports ~15,000 sweeps of ~5 kB): held, they
  // would grow the process for as long as it runs.
  RecordSpool spool;
  engine->setRecordSink(spool.sink());

  const auto t0 = std::chrono::steady_clock::now();
  long n = 0;
  double last_stamp = 0.0;
  Event e;
  SeriesRecorder series(spec.outputs.series_interval_s, *engine, *source, options, t0);
  {
    // The source runs ahead on its own thread unless the run has one thread or its series
    // compares the map with the source's truth between events (the source must be at the
    // event being processed then).
    std::unique_ptr<PrefetchSource> ahead;
    if (spec.threads > 1 && !(series.enabled() && options.truth_stats)) ahead = std::make_unique<PrefetchSource>(*source, 64);
    auto pull = [&](Event& ev) { return ahead ? ahead->next(ev) : source->next(ev); };
    long clouds = 0;
    while (pull(e)) {
      engine->push(e);
      ++n;
      last_stamp = stampOf(e);
      if (gridmaps && std::holds_alternative<PointCloud>(e)) {
        gridmaps->writeCloud(std::get<PointCloud>(e));
        if (++clouds % spec.outputs.mcap.every == 0) gridmaps->writeMap(engine->map(), last_stamp);
      }
      series.afterEvent(stampOf(e), n);
      if (options.on_progress) options.on_progress(ahead ? ahead->progress() : source->progress(), n);
      if (options.on_event) options.on_event(engine->map(), stampOf(e));
    }
  }
  engine->finish();
  for (const auto& [reason, count] : source->dropped()) engine->countSourceDrop(reason, count);
  series.atEnd(n);
  const double run_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

  // Sources that know the truth (the simulator) get error layers and statistics.
  TruthComparison truth;
  if (options.compare_truth) truth = options.compare_truth(engine->mutableMap(), *source);
  for (const std::string& layer : truth.layers) {
    auto& tif = spec.outputs.geotiff;
    if (!tif.empty() && std::find(tif.begin(), tif.end(), layer) == tif.end()) tif.push_back(layer);
    if (!spec.outputs.png_all) spec.outputs.png.push_back(layer);
  }

  RunResult res;
  res.out_dir = spec.outputs.dir;
  res.removed_temporaries = std::move(removed_temporaries);
  res.report = engine->report();
  res.truth_json = truth.json;
  res.run_wall_s = run_s;
  {
    const double span = res.report.last_stamp - res.report.first_stamp;
    if (std::isfinite(span) && span > 0 && run_s > 0) res.real_time_factor = span / run_s;
  }
  std::error_code ec;
  fs::create_directories(spec.outputs.dir, ec);
  if (ec) throw OutputError(spec.outputs.dir + ": cannot create output folder: " + ec.message());
  const LayeredMap& map = engine->map();
  writeMapOutputs(spec, *engine, truth, res.files);
  if (gridmaps) {
    // The finished map too: stages that work only at the end (on_finish) show in this one.
    gridmaps->writeMap(map, last_stamp);
    gridmaps->close();
    res.files.push_back((fs::path(spec.outputs.dir) / spec.outputs.mcap.file).string());
  }
  res.unknown_layers = unknownOutputLayers(spec, map);
  if (spec.outputs.report) writeRunReport(spec, map, truth, n, series, spool, res);
  return res;
}

}  // namespace terramap
