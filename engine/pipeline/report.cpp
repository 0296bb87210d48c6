#include <terramap/pipeline/report.hpp>
#include <terramap/io/atomic_file.hpp>

#include <nlohmann/json.hpp>

namespace terramap {

std::string reportToJson(const RunReport& r, const std::string& extra_json) {
  using nlohmann::json;
  json j;
  j["terramap_version"] = "0.1.0";
  j["threads"] = r.threads;
  j["wall_s"] = r.wall_s;
  j["first_stamp"] = r.first_stamp;
  j["last_stamp"] = r.last_stamp;
  j["events"] = r.events;
  j["source_dropped"] = r.source_dropped;
  long total_dropped = 0;
  for (const auto& [k, v] : r.source_dropped) total_dropped += v;
  json stages = json::array();
  for (const auto& s : r.stages) {
    json st;
    st["name"] = s.name;
    st["type"] = s.type;
    st["version"] = s.version;
    st["wall_s"] = s.stats.wall_s;
    st["events"] = s.stats.events;
    st["dropped"] = s.stats.dropped;
    for (const auto& [k, v] : s.stats.dropped) total_dropped += v;
    st["counters"] = s.stats.counters;
    json recs = json::array();
    for (const auto& rec : s.stats.records) {
      try {
        recs.push_back(json::parse(rec));
      } catch (const json::exception&) {
        recs.push_back(json{{"invalid_record", rec}});  // keep it visible rather than lose it
      }
    }
    st["records"] = recs;
    stages.push_back(st);
  }
  j["stages"] = stages;
  j["dropped_total"] = total_dropped;
  if (!extra_json.empty()) {
    const json extra = json::parse(extra_json);
    for (auto it = extra.begin(); it != extra.end(); ++it) j[it.key()] = it.value();
  }
  return j.dump(2) + "\n";
}

void writeReport(const RunReport& report, const std::string& path, const std::string& extra_json) {
  io::writeFileAtomically(path, reportToJson(report, extra_json));
}

}  // namespace terramap
