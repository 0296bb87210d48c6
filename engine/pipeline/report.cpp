#include <terramap/pipeline/report.hpp>
#include <terramap/io/atomic_file.hpp>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>

#include <unistd.h>

namespace terramap {

namespace {

using nlohmann::json;

/// One record as it goes into the report: the object itself, or, when a plugin reported text
/// that is not JSON, wrapped so that it stays visible rather than lost.
json recordJson(const std::string& rec) {
  try {
    return json::parse(rec);
  } catch (const json::exception&) {
    return json{{"invalid_record", rec}};
  }
}

/// The report without the stages' records; `records` says, per stage, what to put there.
json reportJson(const RunReport& r, const std::string& extra_json, const std::function<json(std::size_t)>& records) {
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
  for (std::size_t i = 0; i < r.stages.size(); ++i) {
    const StageReport& s = r.stages[i];
    json st;
    st["name"] = s.name;
    st["type"] = s.type;
    st["version"] = s.version;
    st["wall_s"] = s.stats.wall_s;
    st["events"] = s.stats.events;
    st["dropped"] = s.stats.dropped;
    for (const auto& [k, v] : s.stats.dropped) total_dropped += v;
    st["counters"] = s.stats.counters;
    st["records"] = records(i);
    st["records_total"] = std::max<long>(s.records_total, static_cast<long>(s.stats.records.size()));
    stages.push_back(st);
  }
  j["stages"] = stages;
  j["dropped_total"] = total_dropped;
  if (!extra_json.empty()) {
    const json extra = json::parse(extra_json);
    for (auto it = extra.begin(); it != extra.end(); ++it) j[it.key()] = it.value();
  }
  return j;
}

std::string placeholder(std::size_t stage) { return "@@terramap-spooled-records-" + std::to_string(stage) + "@@"; }

[[noreturn]] void spoolFailed(const std::string& what, int err) {
  std::error_code ec;
  const std::string dir = std::filesystem::temp_directory_path(ec).string();
  throw OutputError("report records spool in '" + (ec ? std::string("/tmp") : dir) + "': " + what + ": " +
                    std::strerror(err));
}

}  // namespace

std::string reportToJson(const RunReport& r, const std::string& extra_json) {
  const json j = reportJson(r, extra_json, [&](std::size_t i) {
    json recs = json::array();
    for (const auto& rec : r.stages[i].stats.records) recs.push_back(recordJson(rec));
    return recs;
  });
  return j.dump(2) + "\n";
}

void writeReport(const RunReport& report, const std::string& path, const std::string& extra_json) {
  io::writeFileAtomically(path, reportToJson(report, extra_json));
}

// ---- spool -----------------------------------------------------------------------------------

RecordSpool::~RecordSpool() {
  for (File& f : files_)
    if (f.f) std::fclose(f.f);
}

void RecordSpool::add(std::size_t stage, const std::string& json_object) {
  if (files_.size() <= stage) files_.resize(stage + 1);
  File& file = files_[stage];
  if (!file.f) {
    std::error_code ec;
    std::filesystem::path dir = std::filesystem::temp_directory_path(ec);
    if (ec) dir = "/tmp";
    std::string name = (dir / "terramap-records-XXXXXX").string();
    const int fd = ::mkstemp(name.data());
    if (fd < 0) spoolFailed("cannot create a temporary file", errno);
    ::unlink(name.c_str());  // anonymous from now on: gone when closed, however the process ends
    file.f = ::fdopen(fd, "w+b");
    if (!file.f) {
      const int err = errno;
      ::close(fd);
      spoolFailed("cannot open the temporary file", err);
    }
  }
  // Length-prefixed: a plugin's record may hold any bytes, newlines included.
  const std::uint64_t n = json_object.size();
  if (std::fwrite(&n, sizeof n, 1, file.f) != 1 || (n && std::fwrite(json_object.data(), 1, n, file.f) != n))
    spoolFailed("cannot write", errno);
  ++file.count;
}

long RecordSpool::count(std::size_t stage) const { return stage < files_.size() ? files_[stage].count : 0; }

void RecordSpool::forEach(std::size_t stage, const std::function<void(const std::string&)>& fn) const {
  if (stage >= files_.size() || !files_[stage].f) return;
  std::FILE* f = files_[stage].f;
  if (std::fflush(f) != 0 || std::fseek(f, 0, SEEK_SET) != 0) spoolFailed("cannot read back", errno);
  std::string rec;
  for (long k = 0; k < files_[stage].count; ++k) {
    std::uint64_t n = 0;
    if (std::fread(&n, sizeof n, 1, f) != 1) spoolFailed("cannot read back", errno ? errno : EIO);
    rec.resize(n);
    if (n && std::fread(rec.data(), 1, n, f) != n) spoolFailed("cannot read back", errno ? errno : EIO);
    fn(rec);
  }
  if (std::fseek(f, 0, SEEK_END) != 0) spoolFailed("cannot seek", errno);  // later add()s append
}

void writeReport(const RunReport& report, const std::string& path, const std::string& extra_json,
                 const RecordSpool& spool) {
  // The report is dumped with a placeholder string where each stage's records go, and the text
  // is written around it while the records are streamed in, each dumped as nlohmann would dump
  // it in place (same indentation), so the file equals the in-memory writer's.
  const std::string text =
      reportJson(report, extra_json, [&](std::size_t i) { return json(placeholder(i)); }).dump(2) + "\n";
  io::AtomicFile out(path);
  auto put = [&](const std::string& s) { out.write(s.data(), s.size()); };
  std::size_t pos = 0;
  for (std::size_t i = 0; i < report.stages.size(); ++i) {
    const std::string mark = "\"" + placeholder(i) + "\"";
    const std::size_t at = text.find(mark, pos);
    TERRAMAP_CHECK(at != std::string::npos, "report placeholder missing");
    const std::size_t line = text.rfind('\n', at) + 1;
    const std::string indent(at - line - std::strlen("\"records\": "), ' ');
    out.write(text.data() + pos, at - pos);
    bool first = true;
    auto item = [&](const std::string& rec) {
      std::string dumped = recordJson(rec).dump(2);
      std::string shifted;
      shifted.reserve(dumped.size() + 64);
      for (char c : dumped) {
        shifted += c;
        if (c == '\n') shifted += indent + "  ";
      }
      put(std::string(first ? "[\n" : ",\n") + indent + "  " + shifted);
      first = false;
    };
    for (const auto& rec : report.stages[i].stats.records) item(rec);
    spool.forEach(i, item);
    put(first ? "[]" : "\n" + indent + "]");
    pos = at + mark.size();
  }
  put(text.substr(pos));
  out.commit();
}

}  // namespace terramap
