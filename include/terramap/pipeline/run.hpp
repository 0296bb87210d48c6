#pragma once
/// \file
/// Running a whole pipeline file: validate, build the engine, play the source through it,
/// finish, write the outputs (GeoTIFF, PNG, snapshot, JSON report) into `outputs.dir`.
#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>

#include <functional>
#include <limits>
#include <map>
#include <string>
#include <vector>

namespace terramap {

class Source;

/// What a comparison of the finished map with the source's truth produced.
struct TruthComparison {
  std::string json;                 ///< a JSON object for report.json's "truth"; empty = none
  std::vector<std::string> layers;  ///< layers it added to the map (exported with the others)
  std::string caption;              ///< one line of its statistics, under those layers' pictures
  /// Categorical layers among `layers` (e.g. truth_soil_zone): each value with its name, drawn
  /// as a legend instead of a colour bar and without `caption`.
  std::map<std::string, std::vector<std::pair<float, std::string>>> categories;
};

struct RunOptions {
  /// Overrides outputs.dir when not empty.
  std::string out_dir;
  /// Overrides `threads` when > 0.
  int threads = 0;
  /// Called after each event with the source's progress in [0, 1] (or < 0 if unknown) and
  /// the number of events so far. Runs on the calling thread.
  std::function<void(double progress, long events)> on_progress;
  /// Called after each event with the map as the stages left it and the event's stamp (s), for
  /// callers that look at the map while it is built (eval-strata samples it at pass starts).
  /// Runs on the calling thread, between events; the map must not be kept past the call.
  std::function<void(const LayeredMap& map, double stamp)> on_event;
  /// After the last event: compares the map with the source's truth, when the source has one
  /// (the simulator), adding error layers to the map. The CLI sets it to
  /// terramap::eval::compareWithSourceTruth (eval/truth_report.hpp); unset = no comparison, so
  /// the pipeline library needs no evaluation code. Runs on the calling thread.
  std::function<TruthComparison(LayeredMap& map, const Source& source)> compare_truth;
  /// For report.json's "series" (outputs.series_interval_s): the map's error against the
  /// source's truth now, as a JSON object text, without changing the map; empty = none. The
  /// CLI sets it to terramap::eval::truthStatsJson. Runs on the calling thread, between events.
  std::function<std::string(const LayeredMap& map, const Source& source)> truth_stats;
};

struct RunResult {
  RunReport report;
  std::vector<std::string> files;  ///< every file written
  std::string out_dir;
  /// Temporaries of killed terramap processes removed from out_dir before the run
  /// (io::removeStaleTemporaries()).
  std::vector<std::string> removed_temporaries;
  /// RunOptions::compare_truth's JSON (report.json's "truth"), empty without one.
  std::string truth_json;
  /// Wall seconds of the event loop (source and stages, not the outputs; report.json's
  /// run_wall_s) and event seconds it covered per wall second (report.json's real_time_factor:
  /// (last stamp - first stamp) / run_wall_s; NaN with fewer than two stamps). For a simulator
  /// source, how many times faster than real time the whole pipeline ran.
  double run_wall_s = 0.0;
  double real_time_factor = std::numeric_limits<double>::quiet_NaN();
  /// Output layers (GeoTIFF bands, PNGs) without one known cell (all NaN) after the run: a
  /// picture or band of nothing usually means a stage never saw data (a source that missed the
  /// map, a wrong layer name), so the CLI warns and report.json lists them under "warnings".
  std::vector<std::string> unknown_layers;
};

/// Memory stays bounded over long runs: the stages' report records are spooled to an anonymous
/// temporary file (RecordSpool) and written into report.json at the end, so RunResult::report
/// holds their counts (StageReport::records_total), not the records.
/// With `threads` >= 2 the source runs on a thread of its own, up to 64 events ahead of the
/// stages (the events reach them in the source's order, so results do not change), except when
/// outputs.series_interval_s and RunOptions::truth_stats compare the map with the source's
/// truth between events. A source's exception is rethrown where it happened in the stream;
/// on_progress gets the progress of the event just processed.
/// \throws ConfigError (invalid pipeline: every problem at once), InputError (bad data),
///   PluginError, LayerError, OutputError. Outputs are written only after a complete run.
TERRAMAP_API RunResult runPipeline(const PipelineSpec& spec, const RunOptions& options = {});

/// The demo pipeline compiled into the binary (configs/demo.yaml at build time), with its
/// relative paths resolved against `base_dir`.
TERRAMAP_API std::string embeddedDemoPipeline();
/// Folder the demo's relative paths (scenario, model) resolve against: the source tree's
/// configs/ for the build tree's library, else the installed PREFIX/share/terramap/configs
/// (found relative to the library, so any install prefix works without the checkout).
TERRAMAP_API std::string embeddedDemoBaseDir();

}  // namespace terramap
