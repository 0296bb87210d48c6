#include <terramap/pipeline/engine.hpp>
#include <terramap/io/output_budget.hpp>
#include <terramap/core/text.hpp>

#include <algorithm>
#include <filesystem>
#include <chrono>
#include <optional>
#include <set>

namespace terramap {

namespace {

std::string joinLines(const std::vector<std::string>& v) {
  std::string all;
  for (const auto& e : v) all += (all.empty() ? "" : "\n") + e;
  return all;
}

/// Converts what YAML gave into the type the schema declares, or explains why not.
bool coerce(const ParamSpec& spec, const RawParam& raw, ParamValue& out, std::string& why) {
  const ParamValue& v = raw.value;
  switch (spec.type) {
    case ParamType::Bool:
      if (std::holds_alternative<bool>(v)) { out = v; return true; }
      break;
    case ParamType::Int:
      if (std::holds_alternative<long>(v)) { out = v; return true; }
      break;
    case ParamType::Double:
      if (std::holds_alternative<double>(v)) { out = v; return true; }
      if (std::holds_alternative<long>(v)) { out = static_cast<double>(std::get<long>(v)); return true; }
      break;
    case ParamType::String:
      if (std::holds_alternative<std::string>(v)) { out = v; return true; }
      break;
    case ParamType::DoubleList:
      if (std::holds_alternative<std::vector<double>>(v)) { out = v; return true; }
      if (auto s = std::get_if<std::vector<std::string>>(&v); s && s->empty()) {
        out = std::vector<double>{};
        return true;
      }
      break;
    case ParamType::StringList:
      if (std::holds_alternative<std::vector<std::string>>(v)) { out = v; return true; }
      if (auto s = std::get_if<std::string>(&v)) { out = std::vector<std::string>{*s}; return true; }
      break;
  }
  why = "must be " + paramTypeWithArticle(spec.type) + " (got " + showParamValue(v) + ")";
  return false;
}

/// Re-throws what a plugin threw with `context` in front, keeping terramap's error type (as
/// plugin.hpp promises); anything else becomes a PluginError.
[[noreturn]] void rethrowFromPlugin(const std::exception& e, const std::string& context) {
  const std::string m = context + ": " + e.what();
  if (dynamic_cast<const ConfigError*>(&e)) throw ConfigError(m);
  if (dynamic_cast<const InputError*>(&e)) throw InputError(m);
  if (dynamic_cast<const LayerError*>(&e)) throw LayerError(m);
  if (dynamic_cast<const OutputError*>(&e)) throw OutputError(m);
  throw PluginError(m);
}

ParamSchema schemaOf(const std::string& owner, PluginHandle& plugin) {
  try {
    return plugin->schema();
  } catch (const std::exception& e) {
    throw PluginError(owner + ": plugin '" + plugin.type() + "' threw in schema(): " + e.what());
  }
}

/// The raw YAML values checked against the schema. A bad or missing value is an error; a bad
/// value of a parameter with a default leaves the default in `params`.
struct CheckedParams {
  Params params;
  std::vector<std::string> errors;
};

CheckedParams checkParams(const std::string& owner, const std::string& type, const ParamSchema& schema,
                          const std::map<std::string, RawParam>& raw, const std::string& base_dir) {
  std::vector<std::string> names;
  for (const auto& s : schema) names.push_back(s.name);
  CheckedParams out{Params(owner, schema), {}};
  auto& errors = out.errors;
  for (const auto& [key, r] : raw) {
    // A named copy of the binding: C++17 lambdas cannot capture structured bindings (clang refuses).
    const std::string& name = key;
    const auto it = std::find_if(schema.begin(), schema.end(), [&](const ParamSpec& s) { return s.name == name; });
    const std::string at = r.where.empty() ? owner + ".params." + key : r.where;
    if (it == schema.end()) {
      errors.push_back(at + ": unknown parameter '" + key + "' for plugin '" + type + "'" +
                       didYouMean(key, names) + "; known: [" + joinStrings(names) + "]");
      continue;
    }
    if (r.is_map) {
      errors.push_back(at + ": must be " + paramTypeWithArticle(it->type) + ", not a nested mapping");
      continue;
    }
    ParamValue v;
    std::string why;
    if (!coerce(*it, r, v, why)) {
      errors.push_back(at + ": " + why);
      if (it->default_value) out.params.set(key, *it->default_value);
      continue;
    }
    const std::string m = checkParamValue(*it, v);
    if (!m.empty()) {
      errors.push_back(at + ": " + m + (it->unit.empty() || it->unit == "1" ? "" : " [" + it->unit + "]"));
      if (it->default_value) out.params.set(key, *it->default_value);
      continue;
    }
    // Paths in a pipeline are relative to its file, not to wherever terramap was started.
    if (it->type == ParamType::String && it->unit == "path" && !base_dir.empty()) {
      const std::string& text = std::get<std::string>(v);
      if (!text.empty() && std::filesystem::path(text).is_relative())
        v = (std::filesystem::path(base_dir) / text).lexically_normal().string();
    }
    out.params.set(key, v, at);
  }
  for (const auto& s : schema) {
    if (raw.count(s.name)) continue;
    if (s.default_value) out.params.set(s.name, *s.default_value);
    else errors.push_back(owner + ".params: required parameter '" + s.name + "' is missing (" + s.doc + ")");
  }
  return out;
}

/// configure() with every problem it reports (Params::report) or throws as one ConfigError.
void configurePlugin(const std::string& owner, PluginHandle& plugin, const Params& params) {
  std::vector<std::string> errors;
  try {
    plugin->configure(params);
  } catch (const ConfigError& e) {
    errors = params.reported();
    errors.push_back(e.what());
  } catch (const std::exception& e) {
    throw PluginError(owner + ": plugin '" + plugin.type() + "' threw in configure(): " + e.what());
  }
  if (errors.empty()) errors = params.reported();
  if (!errors.empty()) throw ConfigError(joinLines(errors));
}

const char* kindKey(const Event& e) { return kindName(kindOf(e)); }

}  // namespace

Engine::Engine(const EngineOptions& options)
    : map_(options.geometry, options.map), executor_(options.threads) {
  report_.threads = options.threads;
  for (const auto& l : options.layers) map_.addLayer(l.name, l.unit, l.fill);
}

Engine::~Engine() = default;

PreparedStage Engine::prepare(const std::string& name, PluginHandle plugin,
                              const std::map<std::string, RawParam>& raw, const std::string& where,
                              const Geometry* map, const std::string& base_dir) {
  const std::string owner = where.empty() ? name : where;
  const ParamSchema schema = schemaOf(owner, plugin);
  CheckedParams checked = checkParams(owner, plugin.type(), schema, raw, base_dir);
  if (map) checked.params.setMapGeometry(*map);
  if (!checked.errors.empty()) throw ConfigError(joinLines(checked.errors));
  configurePlugin(owner, plugin, checked.params);
  PreparedStage st;
  st.name = name;
  try {
    st.layers = plugin->layers();
    st.events = plugin->events();
  } catch (const std::exception& e) {
    throw PluginError(owner + ": plugin '" + plugin.type() + "' threw while declaring layers/events: " + e.what());
  }
  st.params = std::move(checked.params);
  st.plugin = std::move(plugin);
  return st;
}

void Engine::checkLayers(const std::vector<std::string>& existing, const std::string& stage_name,
                         const std::vector<LayerSpec>& layers, std::vector<std::string>& errors,
                         std::vector<std::string>* out_new, bool report_missing) {
  std::vector<std::string> have = existing;
  std::vector<std::string> created;
  for (const auto& l : layers)
    if (l.access == LayerAccess::Create) {
      if (std::find(have.begin(), have.end(), l.name) != have.end())
        errors.push_back("stage '" + stage_name + "' creates layer '" + l.name +
                         "', which already exists (created by the map config or an earlier stage)");
      else {
        have.push_back(l.name);
        created.push_back(l.name);
      }
    }
  for (const auto& l : layers) {
    if (l.access == LayerAccess::Create || !report_missing) continue;
    if (std::find(have.begin(), have.end(), l.name) == have.end())
      errors.push_back("stage '" + stage_name + "' " + layerAccessName(l.access) + "s layer '" + l.name +
                       "' before any stage creates it" + didYouMean(l.name, have) +
                       " (add a stage that creates it earlier, or declare it under map.layers)");
  }
  if (out_new) *out_new = created;
}

std::vector<std::string> Engine::validate(const PipelineSpec& spec, const PluginRegistry& registry) {
  return validateStages(spec, registry, nullptr);
}

std::vector<std::string> Engine::validateWithoutLoading(const PipelineSpec& spec, const PluginRegistry& registry,
                                                        std::vector<std::string>& unchecked) {
  return validateStages(spec, registry, &unchecked);
}

std::vector<std::string> Engine::validateStages(const PipelineSpec& spec, const PluginRegistry& registry,
                                                std::vector<std::string>* unchecked) {
  std::vector<std::string> errors;
  std::vector<std::string> layers;
  for (const auto& l : spec.layers) {
    if (std::find(layers.begin(), layers.end(), l.name) != layers.end())
      errors.push_back(l.where + ": layer '" + l.name + "' declared twice");
    layers.push_back(l.name);
  }
  std::optional<Geometry> geometry;
  try {
    geometry = spec.geometry();
    LayeredMap probe(Geometry(spec.resolution, Size(1, 1)), spec.map_options);
  } catch (const Error& e) {
    errors.push_back(spec.file + ": map: " + e.what());
  }
  // One mistake, one message. A stage whose parameters are wrong is configured once more with
  // the defaults in place of the wrong values, only to learn its layers, so later stages that
  // read them are not reported as reading a layer nobody creates. After a stage whose layers
  // stay unknown (unknown type, refused library, configure() refusing), "reads layer X before
  // any stage creates it" would be a guess: from there on only checks that stay true are made.
  bool layers_known = true;
  bool cross_checks_skipped = false;
  for (size_t i = 0; i < spec.stages.size(); ++i) {
    const StageSpec& s = spec.stages[i];
    if (unchecked) {
      // From the file alone: nothing of the plugin runs (a pipeline file may not be trusted).
      const std::string owner = s.where.empty() ? s.name : s.where;
      PluginFileDescription f;
      try {
        f = registry.describe(s.type);
      } catch (const PluginError& e) {
        errors.push_back(s.type_where + ": " + e.what());
        layers_known = false;
        continue;
      }
      if (!f.description) {
        unchecked->push_back(s.type_where + ": stage '" + s.name + "': parameters and layers not checked: " +
                             f.path + ": " + f.missing + "; checking them means loading the plugin, which runs its "
                             "code: pass --load-plugins if you trust it");
        layers_known = false;
        continue;
      }
      CheckedParams checked = checkParams(owner, s.type, f.description->params, s.params, spec.base_dir);
      errors.insert(errors.end(), checked.errors.begin(), checked.errors.end());
      std::string why;
      const auto specs = layersFromDescription(*f.description, checked.params.values(), why);
      if (!specs) {
        unchecked->push_back(owner + ": stage '" + s.name + "': layers not checked: plugin '" + s.type + "': " + why +
                             (layers_known ? "; the later stages' layers are not checked either" : "") +
                             " (--load-plugins checks them by loading the plugins)");
        layers_known = false;
        continue;
      }
      cross_checks_skipped = true;
      std::vector<std::string> created, layer_errors;
      checkLayers(layers, s.name, *specs, layer_errors, &created, layers_known);
      if (checked.errors.empty())  // stand-in defaults only tell which layers it creates (below)
        for (auto& e : layer_errors) errors.push_back(s.where + ": " + e);
      layers.insert(layers.end(), created.begin(), created.end());
      continue;
    }
    PluginHandle h;
    try {
      h = registry.create(s.type);
    } catch (const PluginError& e) {
      errors.push_back(s.type_where + ": " + e.what());
      layers_known = false;
      continue;
    }
    const std::string owner = s.where.empty() ? s.name : s.where;
    try {
      const ParamSchema schema = schemaOf(owner, h);
      CheckedParams checked = checkParams(owner, h.type(), schema, s.params, spec.base_dir);
      if (geometry) checked.params.setMapGeometry(*geometry);
      if (checked.errors.empty()) {
        configurePlugin(owner, h, checked.params);
      } else {
        errors.insert(errors.end(), checked.errors.begin(), checked.errors.end());
        bool fallback_ok = false;
        try {
          h->configure(checked.params);
          fallback_ok = checked.params.reported().empty();
        } catch (...) {  // NOLINT: only asking whether the defaults configure; the errors are above
        }
        if (!fallback_ok) {
          layers_known = false;
          continue;
        }
      }
      // A stage configured with stand-in defaults only tells which layers it creates; its own
      // layer checks would be about values the user did not write.
      const bool stand_in = !checked.errors.empty();
      std::vector<LayerSpec> specs;
      try {
        specs = h->layers();
      } catch (const std::exception& e) {
        throw PluginError(owner + ": plugin '" + h.type() + "' threw while declaring layers: " + e.what());
      }
      std::vector<std::string> created;
      std::vector<std::string> layer_errors;
      checkLayers(layers, s.name, specs, layer_errors, &created, layers_known);
      if (!stand_in)
        for (auto& e : layer_errors) errors.push_back(s.where + ": " + e);
      layers.insert(layers.end(), created.begin(), created.end());
    } catch (const Error& e) {
      errors.push_back(e.what());
      layers_known = false;
    }
  }
  if (cross_checks_skipped)
    unchecked->push_back(spec.file + ": the plugins' own cross-parameter and map checks (their configure()) were not "
                         "run: they need the plugins' code (--load-plugins runs them)");
  if (layers_known) {
    for (const auto& l : spec.outputs.geotiff)
      if (std::find(layers.begin(), layers.end(), l) == layers.end())
        errors.push_back(spec.outputs.where + ": outputs.geotiff: no stage creates layer '" + l + "'" +
                         didYouMean(l, layers));
    for (const auto& l : spec.outputs.png)
      if (std::find(layers.begin(), layers.end(), l) == layers.end())
        errors.push_back(spec.outputs.where + ": outputs.png: no stage creates layer '" + l + "'" +
                         didYouMean(l, layers));
  }
  // The rasters are whole even when the map is sparse: a run must not play every event only
  // to find at the end that it cannot write them.
  if (geometry) {
    const auto check = [&](const char* key, const char* format, int scale) {
      try {
        io::requireRasterOutputBudget(*geometry, format, scale, spec.outputs.where + "." + key, false);
      } catch (const ConfigError& e) {
        errors.push_back(e.what());
      }
    };
    if (!spec.outputs.geotiff.empty()) check("geotiff", "geotiff", 1);
    if (spec.outputs.png_all || !spec.outputs.png.empty()) check("png", "png", io::runPngScale(*geometry));
  }
  return errors;
}

std::unique_ptr<Engine> Engine::fromSpec(const PipelineSpec& spec, const PluginRegistry& registry) {
  const auto errors = validate(spec, registry);
  if (!errors.empty()) throw ConfigError(joinLines(errors));
  return fromValidatedSpec(spec, registry);
}

std::unique_ptr<Engine> Engine::fromSpec(const PipelineSpec& spec) {
  return fromSpec(spec, PluginRegistry::forPipeline(spec.plugin_paths, spec.plugin_paths_where));
}

std::unique_ptr<Engine> Engine::fromValidatedSpec(const PipelineSpec& spec, const PluginRegistry& registry) {
  EngineOptions o;
  o.geometry = spec.geometry();
  o.map = spec.map_options;
  o.threads = spec.threads;
  o.layers = spec.layers;
  auto engine = std::make_unique<Engine>(o);
  for (const auto& s : spec.stages)
    engine->addStage(prepare(s.name, registry.create(s.type), s.params, s.where, &o.geometry, spec.base_dir));
  return engine;
}

void Engine::addStage(PreparedStage stage) {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::string> errors;
  for (const auto& s : stages_)
    if (s->prepared.name == stage.name) errors.push_back("duplicate stage name '" + stage.name + "'");
  std::vector<std::string> created;
  checkLayers(map_.layerNames(), stage.name, stage.layers, errors, &created);
  if (!errors.empty()) throw ConfigError(joinLines(errors));
  // From here on nothing may fail half-way: layers are added, and removed again if start() throws.
  LayeredMap before = map_.snapshot();
  for (const auto& l : stage.layers)
    if (l.access == LayerAccess::Create) map_.addLayer(l.name, l.unit, l.fill);
  auto st = std::make_unique<Stage>();
  st->prepared = std::move(stage);
  ProcessContext ctx(map_, executor_, bus_, st->stats, st->prepared.name);
  ctx.setTracker(&st->tracker);
  try {
    st->prepared.plugin->start(ctx);
  } catch (const std::exception& e) {
    map_ = std::move(before);
    rethrowFromPlugin(e, "stage '" + st->prepared.name + "' (" + st->prepared.plugin.type() + ") in start()");
  }
  st->started = true;
  stages_.push_back(std::move(st));
  drainRecords(stages_.size() - 1, *stages_.back());
}

void Engine::addStage(const std::string& name, PluginHandle plugin, const std::map<std::string, ParamValue>& params) {
  std::map<std::string, RawParam> raw;
  for (const auto& [k, v] : params) raw[k] = RawParam{v, name + ".params." + k, false};
  addStage(prepare(name, std::move(plugin), raw, {}, &map_.geometry()));
}

void Engine::push(const Event& event) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) throw ConfigError("Engine::push after finish()");
  const auto t0 = std::chrono::steady_clock::now();
  const EventKind kind = kindOf(event);
  const double stamp = stampOf(event);
  if (!any_event_) report_.first_stamp = stamp;
  any_event_ = true;
  report_.last_stamp = stamp;
  report_.events[kindKey(event)] += 1;
  for (std::size_t si = 0; si < stages_.size(); ++si) {
    Stage* st = stages_[si].get();
    if (!(st->prepared.events & static_cast<EventMask>(kind))) continue;
    ProcessContext ctx(map_, executor_, bus_, st->stats, st->prepared.name);
    ctx.setTracker(&st->tracker);
    ctx.setStamp(stamp);
    const auto s0 = std::chrono::steady_clock::now();
    // The context strings are built only when something failed: this loop runs per event.
    auto who = [&] { return "stage '" + st->prepared.name + "' (" + st->prepared.plugin.type() + ")"; };
    auto when = [&] { return std::string(" on ") + kindName(kind) + " at t=" + std::to_string(stamp); };
    try {
      st->prepared.plugin->process(ctx, event);
    } catch (const ConfigError& e) {
      throw ConfigError(who() + when() + ": " + e.what());
    } catch (const InputError& e) {
      throw InputError(who() + when() + ": " + e.what());
    } catch (const LayerError& e) {
      throw LayerError(who() + when() + ": " + e.what());
    } catch (const std::exception& e) {
      throw PluginError(who() + " threw" + when() + ": " + e.what());
    }
    st->tracker.mark(map_);
    st->stats.wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - s0).count();
    st->stats.events[kindName(kind)] += 1;
    drainRecords(si, *st);
  }
  report_.wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

void Engine::finish() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return;
  finished_ = true;
  for (std::size_t si = 0; si < stages_.size(); ++si) {
    Stage* st = stages_[si].get();
    ProcessContext ctx(map_, executor_, bus_, st->stats, st->prepared.name);
    ctx.setTracker(&st->tracker);
    ctx.setStamp(report_.last_stamp);
    const auto s0 = std::chrono::steady_clock::now();
    try {
      st->prepared.plugin->finish(ctx);
      st->stats.wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - s0).count();
    } catch (const std::exception& e) {
      rethrowFromPlugin(e, "stage '" + st->prepared.name + "' (" + st->prepared.plugin.type() + ") in finish()");
    }
    drainRecords(si, *st);
  }
}

void Engine::setRecordSink(RecordSink sink) {
  std::lock_guard<std::mutex> lock(mutex_);
  record_sink_ = std::move(sink);
  for (std::size_t si = 0; si < stages_.size(); ++si) drainRecords(si, *stages_[si]);
}

void Engine::drainRecords(std::size_t index, Stage& st) {
  if (!record_sink_) return;
  std::vector<std::string>& held = st.stats.records;
  std::size_t k = 0;
  try {
    for (; k < held.size(); ++k) {
      record_sink_(index, held[k]);
      ++st.records_sunk;
    }
  } catch (...) {
    held.erase(held.begin(), held.begin() + static_cast<std::ptrdiff_t>(k));  // each record goes out once
    throw;
  }
  held.clear();
}

std::shared_ptr<const LayeredMap> Engine::snapshot() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return std::make_shared<const LayeredMap>(map_.snapshot());
}

std::vector<std::string> Engine::stageNames() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::string> out;
  for (const auto& s : stages_) out.push_back(s->prepared.name);
  return out;
}

std::map<std::string, std::string> Engine::layerDocs() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::map<std::string, std::string> out;
  for (const auto& s : stages_)
    for (const auto& l : s->prepared.layers)
      if (l.access == LayerAccess::Create) out[l.name] = l.doc;
  return out;
}

RunReport Engine::report() const {
  std::lock_guard<std::mutex> lock(mutex_);
  RunReport r = report_;
  for (const auto& s : stages_)
    r.stages.push_back(StageReport{s->prepared.name, s->prepared.plugin.type(), s->prepared.plugin.version(), s->stats,
                                   s->records_sunk + static_cast<long>(s->stats.records.size())});
  return r;
}

void Engine::countSourceDrop(const std::string& reason, long n) {
  std::lock_guard<std::mutex> lock(mutex_);
  report_.source_dropped[reason] += n;
}

}  // namespace terramap
