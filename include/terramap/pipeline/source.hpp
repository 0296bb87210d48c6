#pragma once
/// \file
/// Sources produce the events of a run in time order. The YAML `source:` picks one:
///   {type: none}                                    no events (a pipeline of map-only stages)
///   {type: sequence, clouds: DIR, poses: FILE, ...} a folder of clouds + a trajectory
///   {type: sim, scenario: FILE}                     the simulator's streams, live
/// Each type checks its own keys (unknown key -> ConfigError with file:line:col, did-you-mean).
#include <terramap/core/events.hpp>
#include <terramap/core/geometry.hpp>

#include <Eigen/Core>
#include <terramap/pipeline/pipeline_spec.hpp>

#include <functional>
#include <map>
#include <memory>
#include <string>

namespace terramap {

/// Threading: runPipeline with two threads or more calls next() and progress() on a thread of
/// its own, ahead of the stages (never two calls at once, always from that one thread);
/// dropped() and truth() are called on the caller's thread once next() has returned false, or
/// between events when a report series compares the map with the truth (then next() runs on the
/// caller's thread too). A source that shares state with a RunOptions callback must guard it.
class TERRAMAP_API Source {
 public:
  virtual ~Source();
  /// Fills `e` with the next event; false at the end. \throws InputError on bad data.
  virtual bool next(Event& e) = 0;
  /// Fraction done in [0, 1], or a negative number if unknown (for the progress bar).
  virtual double progress() const { return -1.0; }
  /// Items the source itself dropped, by reason (go into the run report).
  virtual std::map<std::string, long> dropped() const { return {}; }
  /// Ground truth of a map layer *now*, if this source knows it (the simulator knows
  /// `elevation`): fills `out`, a caller-owned g.size().x() x g.size().y() view, in logical
  /// order (NaN where unknown) and returns true. The runner uses it to write error layers,
  /// pictures and statistics. `out` is a view so that no matrix allocated by the source is
  /// freed by the caller's build (abi.hpp, "Memory rule of the boundary").
  virtual bool truth(const std::string& /*layer*/, const Geometry& /*g*/, Eigen::Ref<Eigen::MatrixXf> /*out*/) const {
    return false;
  }
};

using SourceFactory = std::function<std::unique_ptr<Source>(const PipelineSpec& spec)>;
/// Registers a source type (the built-in ones are registered at load time).
TERRAMAP_API void registerSource(const std::string& type, SourceFactory factory);
/// The types known.
TERRAMAP_API std::vector<std::string> sourceTypes();
/// \throws ConfigError for an unknown type (did-you-mean) or bad settings.
TERRAMAP_API std::unique_ptr<Source> makeSource(const PipelineSpec& spec);

/// Helper for source factories: fails on settings keys not in `known`, all at once.
TERRAMAP_API void checkSourceKeys(const SourceSpec& s, const std::vector<std::string>& known);
/// Typed getters for source settings; `required` false returns `def` when absent.
TERRAMAP_API std::string sourceString(const SourceSpec& s, const std::string& key, bool required,
                                      const std::string& def = {});
TERRAMAP_API double sourceDouble(const SourceSpec& s, const std::string& key, bool required, double def = 0.0);

}  // namespace terramap
