#include <terramap/pipeline/run.hpp>

#include <terramap/io/geotiff.hpp>
#include <terramap/io/render.hpp>
#include <terramap/io/snapshot.hpp>
#include <terramap/pipeline/report.hpp>
#include <terramap/pipeline/source.hpp>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>

namespace terramap {

namespace fs = std::filesystem;

RunResult runPipeline(const PipelineSpec& spec_in, const RunOptions& options) {
  PipelineSpec spec = spec_in;
  if (options.threads > 0) spec.threads = options.threads;
  if (!options.out_dir.empty()) spec.outputs.dir = options.out_dir;
  PluginRegistry registry(spec.plugin_paths);
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

  const auto t0 = std::chrono::steady_clock::now();
  long n = 0;
  Event e;
  while (source->next(e)) {
    engine->push(e);
    ++n;
    if (options.on_progress) options.on_progress(source->progress(), n);
  }
  engine->finish();
  for (const auto& [reason, count] : source->dropped()) engine->countSourceDrop(reason, count);
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
  res.report = engine->report();
  std::error_code ec;
  fs::create_directories(spec.outputs.dir, ec);
  if (ec) throw OutputError(spec.outputs.dir + ": cannot create output folder: " + ec.message());
  const LayeredMap& map = engine->map();
  const fs::path dir(spec.outputs.dir);
  if (!spec.outputs.geotiff.empty()) {
    io::GeoTiffOptions go;
    go.georef.epsg = spec.outputs.epsg;
    if (spec.outputs.origin.size() == 2) {
      go.georef.origin_easting = spec.outputs.origin[0];
      go.georef.origin_northing = spec.outputs.origin[1];
    }
    go.layer_docs = engine->layerDocs();
    const fs::path p = dir / "map.tif";
    io::writeGeoTiff(map, spec.outputs.geotiff, p, go);
    res.files.push_back(p.string());
  }
  std::vector<std::string> pngs = spec.outputs.png;
  if (spec.outputs.png_all) pngs = map.layerNames();
  for (const auto& layer : pngs) {
    io::RenderOptions ro;
    ro.scale = std::max(1, 800 / std::max(map.geometry().size().x(), map.geometry().size().y()));
    ro.nan_color = io::Rgba{128, 128, 128, 255};
    const std::string& unit = map.layerInfo(map.layerId(layer)).unit;
    // Heights read best hillshaded; everything else as a plain colour map.
    ro.hillshade = unit == "m" && layer.find("elevation") != std::string::npos && layer != "elevation_error";
    if (ro.hillshade) ro.ambient = 0.35;
    if (layer == "elevation_error") ro.colormap = "rdbu";  // symmetric around 0: white = no error
    io::Annotation an;
    if (std::find(truth.layers.begin(), truth.layers.end(), layer) != truth.layers.end()) an.caption = truth.caption;
    if (layer == "elevation_error") an.title = "elevation_error: map - truth [cm]";
    const fs::path p = dir / (layer + ".png");
    io::renderPng(map, layer, p, ro, an);
    res.files.push_back(p.string());
  }
  if (spec.outputs.snapshot) {
    const fs::path p = dir / "map.tmap";
    io::saveSnapshot(map, p);
    res.files.push_back(p.string());
  }
  if (spec.outputs.report) {
    const fs::path p = dir / "report.json";
    nlohmann::json extra;
    extra["pipeline"] = spec.file;
    if (!truth.json.empty()) extra["truth"] = nlohmann::json::parse(truth.json);
    extra["events_total"] = n;
    extra["run_wall_s"] = run_s;
    extra["map"] = {{"resolution_m", map.geometry().resolution()},
                    {"size", {map.geometry().size().x(), map.geometry().size().y()}},
                    {"center_m", {map.geometry().center().x(), map.geometry().center().y()}},
                    {"layers", map.layerNames()}};
    std::vector<std::string> files = res.files;
    files.push_back(p.string());
    extra["files"] = files;
    writeReport(res.report, p.string(), extra.dump());
    res.files.push_back(p.string());
  }
  return res;
}

}  // namespace terramap
