// `terramap run [PIPELINE.yaml]`: run a pipeline (the embedded demo without a file).
#include "command.hpp"

#include <terramap/core/text.hpp>
#include <terramap/eval/truth_report.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/run.hpp>

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <map>
#include <memory>
#include <vector>

namespace terramap::cli {
namespace {

struct RunArgs {
  std::string file;
  std::string out;
  std::vector<std::string> set;
  int threads = 0;
  bool quiet = false;
  bool no_progress = false;
};

/// A one-line progress bar on stderr, redrawn at most 10 times a second, only on a terminal.
class ProgressBar {
 public:
  explicit ProgressBar(bool enabled) : enabled_(enabled && isatty(fileno(stderr))) {}
  void update(double frac, long events) {
    if (!enabled_) return;
    const auto now = std::chrono::steady_clock::now();
    if (now - last_ < std::chrono::milliseconds(100) && frac < 1.0) return;
    last_ = now;
    const int width = 40;
    const int filled = frac < 0 ? 0 : static_cast<int>(frac * width + 0.5);
    std::string bar(static_cast<size_t>(filled), '#');
    bar.resize(width, '.');
    if (frac < 0) std::fprintf(stderr, "\r  %ld events", events);
    else std::fprintf(stderr, "\r  [%s] %5.1f%%  %ld events", bar.c_str(), 100.0 * frac, events);
    std::fflush(stderr);
    drawn_ = true;
  }
  ~ProgressBar() {
    if (drawn_) std::fprintf(stderr, "\n");
  }

 private:
  bool enabled_;
  bool drawn_ = false;
  std::chrono::steady_clock::time_point last_{};
};

/// "  dropped N (reason n = p %, ...)", largest first: the total alone hides whether the drops
/// are expected (the machine's own points) or a fault (points outside the map).
void printDrops(const std::map<std::string, long>& dropped) {
  long total = 0;
  for (const auto& [k, v] : dropped) total += v;
  if (total == 0) return;
  std::vector<std::pair<std::string, long>> by(dropped.begin(), dropped.end());
  std::stable_sort(by.begin(), by.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
  std::printf("  dropped %ld (", total);
  bool first = true;
  for (const auto& [reason, n] : by) {
    if (n == 0) continue;
    std::printf("%s%s %ld = %.1f %%", first ? "" : ", ", reason.c_str(), n, 100.0 * static_cast<double>(n) / total);
    first = false;
  }
  std::printf(")");
}

Registrar reg{Command{"run", [](CLI::App& app, std::function<int()>& run) {
  auto a = std::make_shared<RunArgs>();
  auto* sub = app.add_subcommand("run",
      "Run a pipeline: validate it, play its source through the plugins, write outputs\n"
      "(GeoTIFF, PNG, .tmap snapshot, report.json) to outputs.dir or --out.\n"
      "Without a file, runs the embedded demo pipeline (configs/demo.yaml) into ./out/demo.");
  sub->add_option("pipeline", a->file, "Pipeline YAML file (default: the embedded demo)");
  sub->add_option("--out,-o", a->out, "Output folder (overrides outputs.dir)");
  sub->add_option("--threads,-j", a->threads, "Worker threads (overrides `threads`)")->check(CLI::Range(1, 256));
  sub->add_option("--set", a->set,
                  "Stage parameter for this run, STAGE.KEY=VALUE, the value as YAML (repeatable; e.g. "
                  "--set bayes.prior=config --set lidar.max_range_m=20)");
  sub->add_flag("--quiet,-q", a->quiet, "Print nothing but warnings and errors");
  sub->add_flag("--no-progress", a->no_progress, "No progress bar (it is shown only on a terminal anyway)");
  sub->callback([&run, a] {
    run = [a]() -> int {
      PipelineSpec spec = a->file.empty()
          ? parsePipelineString(embeddedDemoPipeline(), "<embedded demo.yaml>", embeddedDemoBaseDir())
          : parsePipelineFile(a->file);
      applyParamOverrides(spec, a->set);
      RunOptions o;
      o.out_dir = a->out;
      // The demo's own outputs.dir is relative to its configs/ (in an installed package, a
      // folder the user may not write, shared by every user): it writes where it is run instead.
      if (a->file.empty() && o.out_dir.empty()) o.out_dir = "out/demo";
      o.threads = a->threads;
      o.compare_truth = eval::compareWithSourceTruth;
      o.truth_stats = eval::truthStatsJson;
      ProgressBar bar(!a->quiet && !a->no_progress);
      o.on_progress = [&bar](double f, long n) { bar.update(f, n); };
      const RunResult r = runPipeline(spec, o);
      bar.update(1.0, 0);
      if (!a->quiet) {
        long events = 0;
        for (const auto& [k, v] : r.report.events) events += v;
        std::printf("ran %s: %ld events in %.2f s on %d thread%s", spec.file.c_str(), events, r.report.wall_s,
                    r.report.threads, r.report.threads == 1 ? "" : "s");
        // The stages' time above; with the source (the simulator, a reader), per event second:
        if (std::isfinite(r.real_time_factor))
          std::printf(" (%.2f s with the source: %.1fx real time)", r.run_wall_s, r.real_time_factor);
        std::printf("\n");
        for (const auto& s : r.report.stages) {
          std::printf("  %-16s %-14s %8.3f s", s.name.c_str(), s.type.c_str(), s.stats.wall_s);
          printDrops(s.stats.dropped);
          std::printf("\n");
        }
        if (!r.report.source_dropped.empty()) {
          std::printf("  %-16s %-14s %10s", "(source)", "", "");
          printDrops(r.report.source_dropped);
          std::printf("\n");
        }
        for (const auto& f : r.files) std::printf("wrote %s\n", f.c_str());
        if (!r.removed_temporaries.empty())
          std::printf("removed %zu stale temporary file%s of dead processes from %s: %s\n", r.removed_temporaries.size(),
                      r.removed_temporaries.size() == 1 ? "" : "s", r.out_dir.c_str(),
                      joinStrings(r.removed_temporaries).c_str());
      }
      // After the summary so it is the last thing read; not silenced by --quiet, as an error
      // is not: a run that wrote pictures of nothing has most likely not done what was meant.
      for (const auto& layer : r.unknown_layers)
        std::fprintf(stderr,
                     "warning: output layer '%s' is entirely unknown (every cell NaN) at the end of the run: "
                     "no stage wrote a known value to it\n",
                     layer.c_str());
      return kOk;
    };
  });
}}};

}  // namespace
}  // namespace terramap::cli
