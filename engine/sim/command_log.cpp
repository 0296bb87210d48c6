// Recorded operator commands (replay controller) and episode exports.
#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>
#include <terramap/io/atomic_file.hpp>
#include <terramap/sim/command_log.hpp>
#include <terramap/sim/episode.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

namespace terramap::sim {
namespace {

constexpr const char* kHeader = "t_s,left,right,lift,tilt,angle";
constexpr const char* kHeaderArm = "t_s,left,right,lift,tilt,angle,slew,boom,arm,bucket";
constexpr const char* kColumns[10] = {"t_s", "left", "right", "lift", "tilt", "angle", "slew", "boom", "arm", "bucket"};

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r");
  if (b == std::string::npos) return "";
  const auto e = s.find_last_not_of(" \t\r");
  return s.substr(b, e - b + 1);
}

std::string formatRow(double t, const std::array<double, 5>& u, const std::array<double, 4>* arm) {
  char buf[512];
  int n = std::snprintf(buf, sizeof buf, "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g", t, u[0], u[1], u[2], u[3], u[4]);
  if (arm)
    n += std::snprintf(buf + n, sizeof buf - static_cast<std::size_t>(n), ",%.17g,%.17g,%.17g,%.17g", (*arm)[0],
                       (*arm)[1], (*arm)[2], (*arm)[3]);
  return std::string(buf, static_cast<std::size_t>(n)) + "\n";
}

}  // namespace

int CommandLog::rowAt(double time, int hint) const {
  if (t.empty() || !(time >= t.front())) return -1;
  if (time > t.back() + hold_last_s) return -1;
  int k = hint >= 0 && hint < static_cast<int>(t.size()) && t[hint] <= time ? hint : 0;
  while (k + 1 < static_cast<int>(t.size()) && t[k + 1] <= time) ++k;
  return k;
}

CommandLog readCommandLog(const std::string& path, CommandLog::Units units) {
  std::ifstream in(path);
  if (!in) throw InputError(path + ": cannot open the command log");
  CommandLog log;
  log.units = units;
  log.source = path;
  std::string line;
  int lineno = 0;
  bool header = false;
  std::size_t ncol = 6;
  auto fail = [&](const std::string& what) { throw InputError(path + ":" + std::to_string(lineno) + ": " + what); };
  while (std::getline(in, line)) {
    ++lineno;
    const std::string s = trim(line);
    if (s.empty() || s[0] == '#') continue;
    std::vector<std::string> cells;
    std::stringstream ss(s);
    std::string cell;
    while (std::getline(ss, cell, ',')) cells.push_back(trim(cell));
    if (!s.empty() && s.back() == ',') cells.push_back("");
    if (!header) {
      if ((cells.size() != 6 && cells.size() != 10) || !std::equal(cells.begin(), cells.end(), kColumns))
        fail("expected the header '" + std::string(kHeader) + "' (a loader) or '" + kHeaderArm + "' (an excavator), got '" +
             s + "'");
      header = true;
      ncol = cells.size();
      continue;
    }
    if (cells.size() != ncol)
      fail("expected " + std::to_string(ncol) + " values (" + (ncol == 6 ? kHeader : kHeaderArm) + "), got " +
           std::to_string(cells.size()));
    double v[10];
    for (std::size_t c = 0; c < ncol; ++c) {
      char* end = nullptr;
      v[c] = std::strtod(cells[c].c_str(), &end);
      if (cells[c].empty() || end != cells[c].c_str() + cells[c].size() || !std::isfinite(v[c]))
        fail("column '" + std::string(kColumns[c]) + "': '" + cells[c] + "' is not a finite number");
      if (c > 0 && units == CommandLog::Units::Lever && std::abs(v[c]) > 1.0)
        fail("column '" + std::string(kColumns[c]) + "': lever " + cells[c] + " outside [-1, 1] (units: lever)");
    }
    if (!log.t.empty() && !(v[0] > log.t.back()))
      fail("t_s " + cells[0] + " does not increase (the previous row's is " + formatNumber(log.t.back()) + ")");
    log.t.push_back(v[0]);
    log.u.push_back({v[1], v[2], v[3], v[4], v[5]});
    if (ncol == 10) log.arm.push_back({v[6], v[7], v[8], v[9]});
  }
  if (!header) throw InputError(path + ": no header line '" + std::string(kHeader) + "' (empty command log)");
  if (log.t.empty()) throw InputError(path + ": the command log has a header but no rows");
  // The last row holds for the typical row spacing, so a log sampled at a fixed rate ends one
  // period after its last stamp, as the commands it recorded did.
  log.hold_last_s = log.t.size() >= 2 ? (log.t.back() - log.t.front()) / static_cast<double>(log.t.size() - 1) : 0.0;
  return log;
}

void writeCommandLog(const std::string& path, const CommandLog& log) {
  std::string text = std::string("# terramap command log (docs/sim.md \"Replaying commands\"), units: ") +
                     (log.units == CommandLog::Units::Lever ? "lever" : "si") + "\n" +
                     (log.arm.empty() ? kHeader : kHeaderArm) + "\n";
  for (std::size_t k = 0; k < log.t.size(); ++k) text += formatRow(log.t[k], log.u[k], log.arm.empty() ? nullptr : &log.arm[k]);
  io::writeFileAtomically(path, text);
}

CommandLog episodeCommands(const std::string& episode_path, const std::string& machine_id) {
  const EpisodeFile file(episode_path);
  std::vector<std::uint64_t> dims;
  const std::string m = "/machines/" + machine_id;
  const std::vector<double> stamp = file.read(m + "/stamp", dims);
  const std::vector<double> action = file.read(m + "/action", dims);
  if (action.size() != 5 * stamp.size())
    throw InputError(episode_path + ": " + m + "/action has " + std::to_string(action.size()) + " values for " +
                     std::to_string(stamp.size()) + " stamps (expected 5 per stamp)");
  CommandLog log;
  log.units = CommandLog::Units::Si;
  log.source = episode_path;
  // An observation's action is the command of the physics step that ended at its stamp: it
  // took effect one physics step earlier, which the replay cannot know; it holds from the stamp.
  for (std::size_t k = 0; k < stamp.size(); ++k) {
    log.t.push_back(stamp[k]);
    log.u.push_back({action[5 * k], action[5 * k + 1], action[5 * k + 2], action[5 * k + 3], action[5 * k + 4]});
  }
  const std::string cmd = m + "/arm/command_radps";
  if (file.has(cmd)) {
    const std::vector<double> a = file.read(cmd, dims);
    if (a.size() != 4 * stamp.size())
      throw InputError(episode_path + ": " + cmd + " has " + std::to_string(a.size()) + " values for " +
                       std::to_string(stamp.size()) + " stamps (expected 4 per stamp)");
    for (std::size_t k = 0; k < stamp.size(); ++k) log.arm.push_back({a[4 * k], a[4 * k + 1], a[4 * k + 2], a[4 * k + 3]});
  }
  log.hold_last_s = stamp.size() >= 2 ? stamp[1] - stamp[0] : 0.0;
  return log;
}

}  // namespace terramap::sim
