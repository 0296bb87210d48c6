#pragma once
/// \file
/// The plugin interface. A plugin is a class derived from terramap::Plugin, exported with
/// TERRAMAP_PLUGIN (abi.hpp) from a shared library built by terramap_add_plugin().
///
/// Life cycle, driven by the host (pipeline/engine.hpp):
///   schema() -> configure(params) -> layers() -> [host creates layers] -> start(ctx)
///   -> process(ctx, event) for each event whose kind is in events() -> finish(ctx).
/// configure() must not touch any map: the host calls it while validating a pipeline.
/// Everything runs on the engine's thread; a plugin parallelises inside process() with
/// ctx.executor() (never with its own threads or global TBB limits).
/// Anything a plugin throws is caught by the host and re-thrown naming the plugin instance: a
/// terramap ConfigError, InputError, LayerError or OutputError keeps its type (in configure(),
/// start(), process() and finish()), anything else becomes a PluginError.
#include <terramap/core/events.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/core/parallel.hpp>
#include <terramap/plugin/params.hpp>

#include <cstddef>
#include <deque>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace terramap {

/// How a plugin uses a layer. The pipeline validator checks that every Read/Write layer was
/// created by the map config or an earlier plugin, and that no layer is created twice.
enum class LayerAccess { Read, Write, Create };
TERRAMAP_API const char* layerAccessName(LayerAccess a);

struct LayerSpec {
  std::string name;
  LayerAccess access = LayerAccess::Read;
  std::string unit;  ///< Create only: SI unit ("m", "m^2", "s", "1", "count", "Pa", ...)
  float fill = std::numeric_limits<float>::quiet_NaN();  ///< Create only: value of unwritten cells
  std::string doc;   ///< Create only: one line of meaning (what NaN means, frame, ...)
};

/// Counters one plugin instance reports (the run report's per-plugin section).
struct PluginStats {
  std::map<std::string, long> dropped;    ///< points/items dropped, by reason
  std::map<std::string, double> counters; ///< free-form metrics (cells updated, ...)
  std::vector<std::string> records;       ///< JSON objects (one per record) for the report
  std::map<std::string, long> events;     ///< events processed by kind
  double wall_s = 0.0;                    ///< time inside process()
};

/// A typed record one plugin publishes for later plugins in the same event (e.g. the blade
/// plugin's per-sweep record the soil estimator consumes). Typed by a string so it works
/// across plugin libraries; `payload` holds a T that both sides know from a public header.
struct Record {
  std::string type;      ///< e.g. "terramap.sweep.v2"
  long sequence = 0;     ///< increases with every publish of this type
  double stamp = 0.0;
  std::shared_ptr<const void> payload;
};

/// The records of one pipeline run, by type. Engine thread only.
class TERRAMAP_API RecordBus {
 public:
  /// Records kept per type for since(): a stage that runs once per event sees every record
  /// published before it in that event (publishers emit at most a few per event) and several
  /// events back; older ones are released so their payloads do not pile up in a long run.
  static constexpr std::size_t kHistory = 32;

  template <class T>
  void publish(const std::string& type, double stamp, std::shared_ptr<const T> payload) {
    publishErased(type, stamp, std::static_pointer_cast<const void>(std::move(payload)));
  }
  /// Latest record of `type`, or nullptr. The caller must know the payload type. The pointer
  /// is valid until the next publish of `type`.
  const Record* latest(const std::string& type) const;
  template <class T>
  std::shared_ptr<const T> latestAs(const std::string& type) const {
    const Record* r = latest(type);
    return r ? std::static_pointer_cast<const T>(r->payload) : nullptr;
  }

  /// What since() returns: the records still kept, oldest first, and how many newer than the
  /// asked sequence are no longer kept (more than kHistory were published since).
  struct Since {
    std::vector<Record> records;
    long missed = 0;
  };
  /// Every record of `type` with a sequence above `after` (a consumer passes the last sequence
  /// it handled, 0 at first). For a consumer that must see each record once, also when a
  /// publisher emits several in one event (soil_bayes reading soil_pinn's estimates).
  Since since(const std::string& type, long after) const;

 private:
  void publishErased(const std::string& type, double stamp, std::shared_ptr<const void> p);
  std::map<std::string, std::deque<Record>> history_;  // back() is the latest
};

/// Which tiles of some layers were written since a stage last ran, for plugins that update
/// incrementally. A stage asks for it in start() (ProcessContext::trackChanges); the host then
/// remembers every tile's write count (LayeredMap::tileWrites) of those layers at the end of
/// each of the stage's process() calls, so a write by anyone afterwards shows.
/// Conservative: a tile written with the same values counts as changed, and every tile counts
/// as changed on the stage's first call and after the map moved. Engine thread only.
class TERRAMAP_API ChangeTracker {
 public:
  /// Starts tracking layer `id` (idempotent).
  void track(LayerId id);
  bool tracks(LayerId id) const;
  /// Buffer-space tiles of `id` (ascending) written since the last mark(): every tile before
  /// the first mark(), after a map move, or if `id` is not tracked.
  std::vector<int> changed(const LayeredMap& map, LayerId id) const;
  /// Remembers the state of every tracked layer (the host calls it after each process()).
  void mark(const LayeredMap& map);

 private:
  struct Layer {
    LayerId id = -1;
    std::vector<std::uint64_t> writes;
  };
  std::vector<Layer> layers_;
  bool marked_ = false;
  Index start_{0, 0};
  Position center_{0.0, 0.0};
};

/// What a plugin sees while it runs.
class TERRAMAP_API ProcessContext {
 public:
  ProcessContext(LayeredMap& map, const Executor& executor, RecordBus& bus, PluginStats& stats,
                 std::string instance_name)
      : map_(map), executor_(executor), bus_(bus), stats_(stats), name_(std::move(instance_name)) {}

  LayeredMap& map() { return map_; }
  const LayeredMap& map() const { return map_; }
  const Executor& executor() const { return executor_; }
  RecordBus& records() { return bus_; }
  /// The instance name from the pipeline YAML (for messages).
  const std::string& name() const { return name_; }
  /// Stamp of the event being processed (seconds).
  double stamp() const { return stamp_; }
  void setStamp(double s) { stamp_ = s; }

  /// Counts `n` items dropped for `reason` (snake_case, e.g. "nan", "out_of_map").
  void countDrop(const std::string& reason, long n = 1) { stats_.dropped[reason] += n; }
  /// Adds to a metric.
  void addCounter(const std::string& name, double v) { stats_.counters[name] += v; }
  /// Appends a JSON object text to the run report (must be a valid JSON object).
  void reportRecord(std::string json_object) { stats_.records.push_back(std::move(json_object)); }
  PluginStats& stats() { return stats_; }

  /// In start(): asks the host to tell this stage which tiles of `id` changed between calls.
  /// \throws InternalError outside a host that tracks changes (a context made by hand).
  void trackChanges(LayerId id) {
    TERRAMAP_CHECK(tracker_ != nullptr, "trackChanges() needs a host that tracks changes");
    tracker_->track(id);
  }
  /// Buffer-space tiles of `id` written since the end of this stage's previous process()
  /// call (its own writes in that call excluded): every tile on the first call, after a map
  /// move, and for a layer not asked for with trackChanges(). Ascending tile numbers.
  std::vector<int> changedTiles(LayerId id) const {
    if (!tracker_) {
      std::vector<int> all(static_cast<size_t>(map_.tileCount()));
      for (int t = 0; t < map_.tileCount(); ++t) all[static_cast<size_t>(t)] = t;
      return all;
    }
    return tracker_->changed(map_, id);
  }
  /// Host side.
  void setTracker(ChangeTracker* tracker) { tracker_ = tracker; }

 private:
  LayeredMap& map_;
  const Executor& executor_;
  RecordBus& bus_;
  PluginStats& stats_;
  std::string name_;
  double stamp_ = 0.0;
  ChangeTracker* tracker_ = nullptr;
};

class TERRAMAP_API Plugin {
 public:
  virtual ~Plugin();
  /// The parameters this plugin takes. Every key not listed is refused.
  virtual ParamSchema schema() const = 0;
  /// Reads validated params; cross-parameter checks go through params.report() (all of them
  /// reach the user at once) or params.fail() (stops at the first).
  virtual void configure(const Params& params) = 0;
  /// Layers read, written and created (may depend on params, e.g. an input layer name).
  virtual std::vector<LayerSpec> layers() const = 0;
  /// Event kinds process() takes (EventKind bits).
  virtual EventMask events() const = 0;
  /// Once, after the layers exist and before the first event: look up layer ids here.
  virtual void start(ProcessContext& /*ctx*/) {}
  virtual void process(ProcessContext& ctx, const Event& event) = 0;
  /// Once, after the last event.
  virtual void finish(ProcessContext& /*ctx*/) {}
};

}  // namespace terramap
