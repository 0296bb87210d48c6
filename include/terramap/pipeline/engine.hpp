#pragma once
/// \file
/// Engine: one LayeredMap, one TBB arena (Executor) and an ordered list of plugin stages.
///
/// Threading: push(), addStage(), editMap() and finish() must come from one thread at a time
/// (the engine's). snapshot() may be called from any thread at any time: it waits for the
/// event or edit in progress to finish and returns a consistent copy-on-write copy of the map
/// that the caller may keep and read while the engine goes on writing. Exercised under
/// ThreadSanitizer (Tsan.ThreadingContracts).
///
/// Failure atomicity: addStage()/fromSpec() validate before they change anything; when they
/// throw, the engine is exactly as it was (same stages, same layers, same data).
#include <terramap/core/events.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/core/parallel.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/plugin/plugin.hpp>

#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace terramap {

struct EngineOptions {
  Geometry geometry{0.05, Size(400, 400)};
  MapOptions map;
  int threads = 1;
  std::vector<LayerDecl> layers;  ///< layers that exist before any plugin
};

/// A stage ready to be added: an instantiated, configured plugin.
struct PreparedStage {
  std::string name;
  PluginHandle plugin;
  Params params;
  std::vector<LayerSpec> layers;
  EventMask events = 0;
};

/// Everything the run report carries (written as JSON by writeReport in report.hpp).
struct StageReport {
  std::string name, type, version;
  PluginStats stats;  ///< stats.records: the records still held (none with a record sink)
  long records_total = 0;  ///< every record the stage reported, held or handed to the sink
};
struct RunReport {
  std::vector<StageReport> stages;
  std::map<std::string, long> events;     ///< events pushed, by kind
  std::map<std::string, long> source_dropped;  ///< dropped by the source, by reason
  double wall_s = 0.0;                    ///< total time in push()
  double first_stamp = 0.0, last_stamp = 0.0;
  int threads = 1;
};

class TERRAMAP_API Engine {
 public:
  explicit Engine(const EngineOptions& options);
  ~Engine();
  Engine(const Engine&) = delete;
  Engine& operator=(const Engine&) = delete;

  /// Validates a whole pipeline and builds the engine. Every problem (unknown plugin types,
  /// refused libraries, unknown/mistyped/out-of-range params, configure() errors, duplicate
  /// names, a layer read before anyone writes it, a layer created twice) is collected and
  /// thrown as one ConfigError, one line each.
  static std::unique_ptr<Engine> fromSpec(const PipelineSpec& spec, const PluginRegistry& registry);
  /// fromSpec with the registry the YAML asks for: its `plugin_paths`, then
  /// TERRAMAP_PLUGIN_PATH, then the installed plugin folder (what `terramap run` uses).
  static std::unique_ptr<Engine> fromSpec(const PipelineSpec& spec);
  /// fromSpec without the up-front validate(), for callers that just ran validate() and got no
  /// errors (it would only repeat the work). Still throws if building fails.
  static std::unique_ptr<Engine> fromValidatedSpec(const PipelineSpec& spec, const PluginRegistry& registry);

  /// Checks a pipeline without building an engine; returns every problem (empty = valid).
  /// Loads each stage's plugin (runs its code) and configures it.
  static std::vector<std::string> validate(const PipelineSpec& spec, const PluginRegistry& registry);
  /// validate() without loading any plugin, for a pipeline file not yet trusted (`terramap
  /// validate`): each stage is checked against the description embedded in its plugin's file
  /// (plugin_schema.hpp). What that cannot check goes to `unchecked`, one line each: a stage
  /// whose plugin has no description of this build, a stage whose layers its description does not
  /// tell (the stages after it are then not checked for layers), and the plugins' own
  /// cross-parameter checks in configure(), which need their code. Returns every problem found.
  static std::vector<std::string> validateWithoutLoading(const PipelineSpec& spec, const PluginRegistry& registry,
                                                         std::vector<std::string>& unchecked);

  /// Checks `params` against the plugin's schema and configures it. Does not touch the engine.
  /// `map`: the geometry the stage will run on, shown to configure() (Params::mapGeometry) so
  /// map-dependent checks fail here rather than at run time. `base_dir`: relative values of path
  /// parameters (param::path) are taken relative to it (the pipeline file's folder; empty = as
  /// given, relative to the working directory).
  /// \throws ConfigError with every parameter problem.
  static PreparedStage prepare(const std::string& name, PluginHandle plugin,
                               const std::map<std::string, RawParam>& params, const std::string& where = {},
                               const Geometry* map = nullptr, const std::string& base_dir = {});

  /// Appends a stage: checks its layers against the current map, creates its layers, calls
  /// start(). \throws ConfigError / LayerError / PluginError, or the Error start() threw (same
  /// type, stage named); on throw nothing changed.
  void addStage(PreparedStage stage);
  /// Convenience: prepare + addStage with params given as values.
  void addStage(const std::string& name, PluginHandle plugin, const std::map<std::string, ParamValue>& params = {});

  /// Runs, in pipeline order, every stage that takes this event's kind.
  /// \throws PluginError (or the Error the plugin threw, re-thrown with the stage named).
  void push(const Event& event);
  /// Calls finish() on every stage (once).
  /// \throws the Error a plugin threw (ConfigError, InputError, LayerError, OutputError) with
  /// the stage named, or PluginError for anything else.
  void finish();

  /// A consistent copy of the map (copy-on-write), safe to read on any thread.
  std::shared_ptr<const LayeredMap> snapshot() const;
  /// Direct access for the engine's own thread (not while push() runs elsewhere, and not
  /// while another thread may call snapshot(): use editMap() then).
  const LayeredMap& map() const { return map_; }
  LayeredMap& mutableMap() { return map_; }
  /// Runs `edit` on the map under the engine's lock, so other threads' snapshot() calls see the
  /// map before or after the edit, never half of it (an embedder writing a prior or clearing a
  /// region while a planner reads snapshots). Engine thread, between push() calls.
  void editMap(const std::function<void(LayeredMap&)>& edit) {
    std::lock_guard<std::mutex> lock(mutex_);
    edit(map_);
  }
  const Executor& executor() const { return executor_; }
  RecordBus& records() { return bus_; }

  std::vector<std::string> stageNames() const;
  /// Layer name -> LayerSpec::doc of every layer a stage created (for exports' metadata).
  std::map<std::string, std::string> layerDocs() const;
  RunReport report() const;
  /// For sources that drop input themselves (e.g. unreadable frames they skip by design).
  void countSourceDrop(const std::string& reason, long n);

  /// Where the stages' report records (ProcessContext::reportRecord) go instead of being held
  /// in memory: `sink(stage_index, json_object)` is called, in order, right after the start(),
  /// process() or finish() call that reported them, and the engine keeps only their count
  /// (StageReport::records_total). A run of hours reports tens of thousands of per-sweep records
  /// (~5 kB each); held, they grow the process by tens of MB an hour (docs/reliability.md,
  /// "Soak"). Unset (the default): records are held and returned by report(). Engine thread;
  /// set before the first event. What the sink throws propagates out of push()/finish().
  using RecordSink = std::function<void(std::size_t stage_index, const std::string& json_object)>;
  void setRecordSink(RecordSink sink);

 private:
  struct Stage {
    PreparedStage prepared;
    PluginStats stats;
    ChangeTracker tracker;  // tiles the stage has not seen yet (ProcessContext::changedTiles)
    bool started = false;
    long records_sunk = 0;  // records handed to the sink (the held ones are in stats.records)
  };
  /// Hands the records `st` holds to the sink, if there is one.
  void drainRecords(std::size_t index, Stage& st);
  static void checkLayers(const std::vector<std::string>& existing, const std::string& stage_name,
                          const std::vector<LayerSpec>& layers, std::vector<std::string>& errors,
                          std::vector<std::string>* out_new = nullptr, bool report_missing = true);
  /// validate() (unchecked == nullptr: loads the plugins) or validateWithoutLoading().
  static std::vector<std::string> validateStages(const PipelineSpec& spec, const PluginRegistry& registry,
                                                 std::vector<std::string>* unchecked);

  mutable std::mutex mutex_;
  LayeredMap map_;
  Executor executor_;
  std::vector<std::unique_ptr<Stage>> stages_;
  RecordBus bus_;  // after stages_: records are destroyed before the plugins that made them
  RunReport report_;
  RecordSink record_sink_;
  bool finished_ = false;
  bool any_event_ = false;
};

}  // namespace terramap
