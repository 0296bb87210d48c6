#include <terramap/core/memory_budget.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>

#include "yaml_util.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

namespace terramap {

namespace fs = std::filesystem;

std::string PipelineSpec::resolvePath(const std::string& p) const {
  if (p.empty()) return p;
  fs::path path(p);
  if (path.is_absolute()) return path.lexically_normal().string();
  return (fs::path(base_dir) / path).lexically_normal().string();
}

namespace {

void parseMap(yaml::Diagnostics& d, const YAML::Node& m, PipelineSpec& spec) {
  if (!m) return;
  if (!m.IsMap()) {
    d.error(m, "map", "must be a mapping {resolution, size, center, tile, sparse, layers}");
    return;
  }
  yaml::checkKeys(d, m, "map", {"resolution", "size", "center", "tile", "sparse", "layers", "frame"});
  yaml::getDouble(d, m, "resolution", "map", spec.resolution, 1e-4, 1e3);
  std::vector<double> v;
  if (yaml::getDoubles(d, m, "size", "map", v, 2)) {
    if (v[0] < 1 || v[1] < 1 || v[0] > 100000 || v[1] > 100000 || v[0] != static_cast<int>(v[0]) ||
        v[1] != static_cast<int>(v[1]))
      d.error(m["size"], "map.size", "must be two whole numbers of cells in [1, 100000]");
    else
      spec.size = Size(static_cast<int>(v[0]), static_cast<int>(v[1]));
  }
  if (yaml::getDoubles(d, m, "center", "map", v, 2)) {
    if (!std::isfinite(v[0]) || !std::isfinite(v[1]) || std::abs(v[0]) > 1e9 || std::abs(v[1]) > 1e9)
      d.error(m["center"], "map.center", "must be finite coordinates within 1e9 m of the origin");
    else
      spec.center = Position(v[0], v[1]);
  }
  yaml::getInt(d, m, "tile", "map", spec.map_options.tile_size, 8, 1024);
  yaml::getBool(d, m, "sparse", "map", spec.map_options.sparse);
  if (m["size"] && !spec.map_options.sparse) {
    // Every dense layer holds every cell (4 bytes, tiles padded to whole tiles): refuse here,
    // with the line of map.size, what a stage would otherwise fail to allocate at run time.
    const std::uint64_t T = static_cast<std::uint64_t>(spec.map_options.tile_size);
    const std::uint64_t rows = (static_cast<std::uint64_t>(spec.size.x()) + T - 1) / T * T,
                        cols = (static_cast<std::uint64_t>(spec.size.y()) + T - 1) / T * T;
    const std::uint64_t bytes = saturatingProduct({rows, cols, sizeof(float)});
    if (bytes > memoryBudget())
      d.error(m["size"], "map.size",
              "a dense map of " + std::to_string(spec.size.x()) + " x " + std::to_string(spec.size.y()) + " cells needs " +
                  formatBytes(bytes) + " per layer, more than the memory budget of " + formatBytes(memoryBudget()) +
                  " (use a smaller map, map.sparse: true, or raise --memory-budget / TERRAMAP_MEMORY_BUDGET)");
  }
  std::string frame;
  yaml::getString(d, m, "frame", "map", frame);
  if (const YAML::Node ls = m["layers"]) {
    if (!ls.IsSequence()) {
      d.error(ls, "map.layers", "must be a list of {name, unit, fill}");
      return;
    }
    for (size_t i = 0; i < ls.size(); ++i) {
      const std::string p = "map.layers[" + std::to_string(i) + "]";
      LayerDecl l;
      l.where = d.at(ls[i], p);
      if (ls[i].IsScalar()) {
        l.name = ls[i].Scalar();
      } else if (ls[i].IsMap()) {
        yaml::checkKeys(d, ls[i], p, {"name", "unit", "fill"});
        if (!yaml::getString(d, ls[i], "name", p, l.name)) d.error(ls[i], p, "needs a name");
        yaml::getString(d, ls[i], "unit", p, l.unit);
        double f;
        if (ls[i]["fill"]) {
          if (ls[i]["fill"].IsScalar() && (ls[i]["fill"].Scalar() == ".nan" || ls[i]["fill"].Scalar() == "nan"))
            l.fill = std::numeric_limits<float>::quiet_NaN();
          else if (yaml::getDouble(d, ls[i], "fill", p, f, -1e30, 1e30))
            l.fill = static_cast<float>(f);
        }
      } else {
        d.error(ls[i], p, "must be a layer name or {name, unit, fill}");
        continue;
      }
      spec.layers.push_back(l);
    }
  }
}

void parseMcapOutput(yaml::Diagnostics& d, const YAML::Node& m, McapOutputSpec& out) {
  if (!m) return;
  out.where = d.at(m, "outputs.mcap");
  const std::string keys = "{layers, file, topic, frame_id, copy_clouds, cloud_topic, compression, every}";
  if (!m.IsMap()) {
    d.error(m, "outputs.mcap", "must be a mapping " + keys);
    return;
  }
  out.enabled = true;
  yaml::checkKeys(d, m, "outputs.mcap",
                  {"layers", "file", "topic", "frame_id", "copy_clouds", "cloud_topic", "compression", "every"});
  if (!m["layers"])
    d.error(m, "outputs.mcap.layers", "is required: the layers each GridMap message carries, e.g. [elevation, variance]");
  else if (yaml::getStrings(d, m, "layers", "outputs.mcap", out.layers) && out.layers.empty())
    d.error(m["layers"], "outputs.mcap.layers", "must name at least one layer");
  if (yaml::getString(d, m, "file", "outputs.mcap", out.file) &&
      (out.file.empty() || out.file.find('/') != std::string::npos || out.file == "." || out.file == ".."))
    d.error(m["file"], "outputs.mcap.file", "must be a file name in outputs.dir (got '" + out.file + "')");
  for (const char* key : {"topic", "cloud_topic"}) {
    std::string& t = std::string(key) == "topic" ? out.topic : out.cloud_topic;
    if (yaml::getString(d, m, key, "outputs.mcap", t) && (t.empty() || t[0] != '/'))
      d.error(m[key], std::string("outputs.mcap.") + key, "must be an absolute ROS topic name like /terramap/grid_map (got '" + t + "')");
  }
  if (yaml::getString(d, m, "frame_id", "outputs.mcap", out.frame_id) && out.frame_id.empty())
    d.error(m["frame_id"], "outputs.mcap.frame_id", "must not be empty");
  yaml::getBool(d, m, "copy_clouds", "outputs.mcap", out.copy_clouds);
  if (yaml::getString(d, m, "compression", "outputs.mcap", out.compression) && out.compression != "zstd" &&
      out.compression != "lz4" && out.compression != "none")
    d.error(m["compression"], "outputs.mcap.compression", "must be zstd, lz4 or none (got '" + out.compression + "')");
  yaml::getInt(d, m, "every", "outputs.mcap", out.every, 1, 1000000);
}

void parseOutputs(yaml::Diagnostics& d, const YAML::Node& o, PipelineSpec& spec) {
  if (!o) return;
  OutputSpec& out = spec.outputs;
  out.where = d.at(o, "outputs");
  if (!o.IsMap()) {
    d.error(o, "outputs", "must be a mapping {dir, geotiff, png, snapshot, report, epsg, origin, series_interval_s, mcap}");
    return;
  }
  yaml::checkKeys(d, o, "outputs", {"dir", "geotiff", "png", "snapshot", "report", "epsg", "origin", "series_interval_s", "mcap"});
  if (yaml::getString(d, o, "dir", "outputs", out.dir)) out.dir = spec.resolvePath(out.dir);
  yaml::getStrings(d, o, "geotiff", "outputs", out.geotiff);
  if (yaml::getStrings(d, o, "png", "outputs", out.png)) {
    if (out.png.size() == 1 && out.png[0] == "all") {
      out.png_all = true;
      out.png.clear();
    }
  }
  yaml::getBool(d, o, "snapshot", "outputs", out.snapshot);
  yaml::getBool(d, o, "report", "outputs", out.report);
  yaml::getInt(d, o, "epsg", "outputs", out.epsg, 1024, 999999);
  yaml::getDoubles(d, o, "origin", "outputs", out.origin, 2);
  yaml::getDouble(d, o, "series_interval_s", "outputs", out.series_interval_s, 0.0, 1e9);
  parseMcapOutput(d, o["mcap"], out.mcap);
  if (!out.origin.empty() && out.epsg == 0)
    d.error(o["origin"], "outputs.origin", "is only meaningful with outputs.epsg");
}

PipelineSpec parseRoot(yaml::Diagnostics& d, const YAML::Node& root, PipelineSpec spec) {
  if (!root.IsMap()) {
    d.error(root, "", "the pipeline file must be a YAML mapping with version, map, pipeline, ...");
    d.throwIfAny();
  }
  yaml::checkKeys(d, root, "",
                  {"version", "map", "threads", "source", "pipeline", "outputs", "plugin_paths", "name",
                   "description"});
  if (!root["version"]) d.error(root, "version", "is required (version: 1)");
  else if (yaml::getInt(d, root, "version", "", spec.version, 0, 1000) && spec.version != 1)
    d.error(root["version"], "version", "unsupported pipeline version " + std::to_string(spec.version) +
                                            " (this terramap reads version 1)");
  parseMap(d, root["map"], spec);
  yaml::getInt(d, root, "threads", "", spec.threads, 1, 256);
  if (yaml::getStrings(d, root, "plugin_paths", "", spec.plugin_paths)) {
    spec.plugin_paths_where = d.at(root["plugin_paths"], "plugin_paths");
    for (auto& p : spec.plugin_paths) p = spec.resolvePath(p);
  }

  if (const YAML::Node s = root["source"]) {
    spec.source.where = d.at(s, "source");
    if (!s.IsMap()) {
      d.error(s, "source", "must be a mapping with a `type`");
    } else {
      if (!yaml::getString(d, s, "type", "source", spec.source.type)) d.error(s, "source.type", "is required");
      for (const auto& kv : s) {
        std::string k;
        if (!yaml::keyName(d, kv.first, "source", k) || k == "type") continue;
        RawParam r = yaml::toRaw(d, kv.second, "source." + k);
        spec.source.settings[k] = r;
      }
    }
  }

  const YAML::Node p = root["pipeline"];
  if (!p) {
    d.error(root, "pipeline", "is required (a list of {name, type, params})");
  } else if (!p.IsSequence()) {
    d.error(p, "pipeline", "must be a list of {name, type, params}");
  } else {
    std::map<std::string, std::string> seen;
    for (size_t i = 0; i < p.size(); ++i) {
      const std::string path = "pipeline[" + std::to_string(i) + "]";
      const YAML::Node st = p[i];
      if (!st.IsMap()) {
        d.error(st, path, "must be a mapping {name, type, params}");
        continue;
      }
      yaml::checkKeys(d, st, path, {"name", "type", "params"});
      StageSpec stage;
      stage.where = d.at(st, path);
      if (!yaml::getString(d, st, "type", path, stage.type)) d.error(st, path + ".type", "is required");
      stage.type_where = d.at(st["type"], path + ".type");
      if (!yaml::getString(d, st, "name", path, stage.name)) stage.name = stage.type;
      if (auto it = seen.find(stage.name); it != seen.end())
        d.error(st["name"] ? st["name"] : st, path + ".name",
                "duplicate stage name '" + stage.name + "' (first used at " + it->second + ")");
      else
        seen[stage.name] = stage.where;
      stage.params = yaml::toRawMap(d, st["params"], path + ".params");
      spec.stages.push_back(std::move(stage));
    }
  }
  parseOutputs(d, root["outputs"], spec);
  d.throwIfAny();
  return spec;
}

PipelineSpec parseText(const std::string& text, const std::string& name, const std::string& base_dir) {
  yaml::Diagnostics d;
  d.file = name;
  const YAML::Node root = yaml::load(text, name);
  PipelineSpec spec;
  spec.file = name;
  spec.base_dir = base_dir;
  return parseRoot(d, root, spec);
}

}  // namespace

PipelineSpec parsePipelineFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ConfigError(path + ": cannot open pipeline file");
  std::stringstream ss;
  ss << in.rdbuf();
  const fs::path abs = fs::absolute(path);
  return parseText(ss.str(), path, abs.parent_path().string());
}

PipelineSpec parsePipelineString(const std::string& yaml, const std::string& name, const std::string& base_dir) {
  return parseText(yaml, name, base_dir);
}

void applyParamOverrides(PipelineSpec& spec, const std::vector<std::string>& overrides) {
  yaml::Diagnostics diag;  // every malformed override, thrown at once
  for (const std::string& ov : overrides) {
    const std::string where = "--set " + ov;
    const auto eq = ov.find('=');
    const auto dot = ov.find('.');
    if (eq == std::string::npos || dot == std::string::npos || dot > eq || dot == 0 || dot + 1 == eq) {
      diag.errors.push_back(where + ": expected STAGE.KEY=VALUE (e.g. --set bayes.prior=config)");
      continue;
    }
    const std::string stage = ov.substr(0, dot), key = ov.substr(dot + 1, eq - dot - 1), text = ov.substr(eq + 1);
    auto it = std::find_if(spec.stages.begin(), spec.stages.end(), [&](const StageSpec& s) { return s.name == stage; });
    if (it == spec.stages.end()) {
      std::string names;
      for (const StageSpec& s : spec.stages) names += (names.empty() ? "" : ", ") + s.name;
      diag.errors.push_back(where + ": no stage named '" + stage + "' (the pipeline's: " + names + ")");
      continue;
    }
    YAML::Node n;
    try {
      n = yaml::load(text.empty() ? std::string("\"\"") : text, where);
    } catch (const ConfigError& e) {
      diag.errors.push_back(e.what());
      continue;
    }
    RawParam r = yaml::toRaw(diag, n, key);
    if (r.is_map) {
      diag.errors.push_back(where + ": the value must be a scalar or a list of scalars");
      continue;
    }
    r.where = where;  // what the stage's schema names in its messages
    it->params[key] = r;
  }
  diag.throwIfAny();
}

}  // namespace terramap
