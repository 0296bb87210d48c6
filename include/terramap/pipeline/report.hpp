#pragma once
/// \file
/// The JSON run report: events by kind, wall time per stage, points dropped by reason
/// (per stage and by the source), each stage's counters and records.
#include <terramap/pipeline/engine.hpp>

#include <cstdio>
#include <functional>
#include <string>
#include <vector>

namespace terramap {

/// The report as JSON text (pretty-printed). `extra_json` (a JSON object text, may be empty)
/// is merged at the top level, e.g. output file names.
TERRAMAP_API std::string reportToJson(const RunReport& report, const std::string& extra_json = {});
/// Writes it atomically. \throws OutputError.
TERRAMAP_API void writeReport(const RunReport& report, const std::string& path, const std::string& extra_json = {});

/// Stages' report records kept on disk during a run instead of in memory (an Engine record sink:
/// Engine::setRecordSink(spool.sink())), to be written into report.json at the end. One
/// anonymous temporary file per stage in the temporary folder (TMPDIR, else /tmp), unlinked at
/// creation, so nothing is left behind whatever way the process ends. Not thread-safe (the
/// engine's thread).
class TERRAMAP_API RecordSpool {
 public:
  RecordSpool() = default;
  ~RecordSpool();
  RecordSpool(const RecordSpool&) = delete;
  RecordSpool& operator=(const RecordSpool&) = delete;

  /// Appends one record of stage `stage`. \throws OutputError when the temporary file cannot be
  /// created or written (e.g. a full disk), naming the folder.
  void add(std::size_t stage, const std::string& json_object);
  /// What Engine::setRecordSink takes; the spool must outlive the engine's use of it.
  Engine::RecordSink sink() {
    return [this](std::size_t stage, const std::string& json) { add(stage, json); };
  }
  /// Records of `stage` so far.
  long count(std::size_t stage) const;
  /// Calls `fn` on every record of `stage` in the order added, reading them back one at a time.
  /// \throws OutputError on a read error.
  void forEach(std::size_t stage, const std::function<void(const std::string&)>& fn) const;

 private:
  struct File {
    std::FILE* f = nullptr;
    long count = 0;
  };
  std::vector<File> files_;
};

/// writeReport with each stage's records written from `spool` (after any the report holds)
/// as they are read back, so the report's size is not held in memory at once. The text equals
/// what writeReport gives for the same records held in the report. \throws OutputError.
TERRAMAP_API void writeReport(const RunReport& report, const std::string& path, const std::string& extra_json,
                              const RecordSpool& spool);

}  // namespace terramap
