#pragma once
/// \file
/// The JSON run report: events by kind, wall time per stage, points dropped by reason
/// (per stage and by the source), each stage's counters and records.
#include <terramap/pipeline/engine.hpp>

#include <string>

namespace terramap {

/// The report as JSON text (pretty-printed). `extra_json` (a JSON object text, may be empty)
/// is merged at the top level, e.g. output file names.
TERRAMAP_API std::string reportToJson(const RunReport& report, const std::string& extra_json = {});
/// Writes it atomically. \throws OutputError.
TERRAMAP_API void writeReport(const RunReport& report, const std::string& path, const std::string& extra_json = {});

}  // namespace terramap
