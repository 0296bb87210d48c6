#pragma once
/// \file
/// Recorded operator commands for `controller: {type: replay}` (docs/sim.md "Replaying
/// commands"): a CSV whose rows are a time and the five commands of a compact track loader,
/// held from a row's time to the next row's (zero-order hold, as a machine's controller sees a
/// logged lever), so a real machine's log (or a simulated episode's) can drive the simulator.
///
/// File: comment lines start with '#'; the first other line is the header
/// `t_s,left,right,lift,tilt,angle` (a loader), or with an excavator's four levers too
/// `t_s,left,right,lift,tilt,angle,slew,boom,arm,bucket` (lift, tilt, angle are then its plow's);
/// then one row per command change, t_s strictly increasing.
/// Units (`units:` in the scenario): `lever` (default) = TERA's normalised interface, every value
/// in [-1, 1], scaled by the machine's max_speed_mps (tracks) and joint max_rate (lift m/s, tilt
/// and angle rad/s); `si` = the commands themselves (m/s, m/s, rad/s: what an episode's
/// `action` dataset holds). Before the first row and after the last row's time plus
/// `hold_last_s` the commands are 0 (the machine stops).
#include <array>
#include <string>
#include <vector>

namespace terramap::sim {

struct CommandLog {
  enum class Units { Lever, Si } units = Units::Lever;
  std::vector<double> t;                   ///< s, strictly increasing
  std::vector<std::array<double, 5>> u;    ///< [left, right, lift, tilt, angle] per row
  /// [slew, boom, arm, bucket] per row (levers, or rad/s in si units); empty = a loader's log.
  std::vector<std::array<double, 4>> arm;
  double hold_last_s = 0;                  ///< how long the last row holds (s)
  std::string source;                      ///< file name, for messages
  /// The row in force at time `t` (zero-order hold), or -1 (before the first row, or after the
  /// last one's hold). `hint` speeds up monotonic queries (pass the previous result, or -1).
  int rowAt(double time, int hint = -1) const;
};

/// Reads a command CSV. Values are checked against `units` (levers in [-1, 1]).
/// \throws InputError naming the file and line (and column) of the first problem: a missing
/// or different header, a wrong number of values, a value that is not a finite number, a lever
/// outside [-1, 1], a time that does not increase.
CommandLog readCommandLog(const std::string& path, CommandLog::Units units);

/// Writes `log` as a command CSV (header, rows at full double precision), atomically.
/// \throws OutputError.
void writeCommandLog(const std::string& path, const CommandLog& log);

/// The commands an episode's machine was given (its `action` at the observation stamps, SI
/// units, and for an excavator its `arm/command_radps`), hold_last_s = one observation period.
/// \throws InputError (readEpisodeDataset's).
CommandLog episodeCommands(const std::string& episode_path, const std::string& machine_id);

}  // namespace terramap::sim
