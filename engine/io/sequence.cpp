#include <terramap/io/sequence.hpp>

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>
#include <terramap/io/readers.hpp>

#include "reader_detail.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace terramap::io {

namespace fs = std::filesystem;

namespace {

// Natural order: digit runs compare by value (then by length, so "01" < "1" stays a strict
// weak order), everything else byte-wise.
bool naturalLess(const std::string& a, const std::string& b) {
  std::size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    const bool da = std::isdigit(static_cast<unsigned char>(a[i])), db = std::isdigit(static_cast<unsigned char>(b[j]));
    if (da && db) {
      std::size_t ie = i, je = j;
      while (ie < a.size() && std::isdigit(static_cast<unsigned char>(a[ie]))) ++ie;
      while (je < b.size() && std::isdigit(static_cast<unsigned char>(b[je]))) ++je;
      std::size_t is = i, js = j;  // skip leading zeros for the value comparison
      while (is + 1 < ie && a[is] == '0') ++is;
      while (js + 1 < je && b[js] == '0') ++js;
      if (ie - is != je - js) return ie - is < je - js;
      const int c = a.compare(is, ie - is, b, js, je - js);
      if (c != 0) return c < 0;
      if (ie - i != je - j) return ie - i > je - j;  // more zeros first: "01" < "1"
      i = ie;
      j = je;
    } else {
      if (a[i] != b[j]) return static_cast<unsigned char>(a[i]) < static_cast<unsigned char>(b[j]);
      ++i;
      ++j;
    }
  }
  return a.size() - i < b.size() - j;
}

// Stem of "dir/1317384512.123456.pcd" -> "1317384512.123456".
std::string stemOf(const std::string& path) { return fs::path(path).stem().string(); }

}  // namespace

// ---- SequencePoses ----------------------------------------------------------------------------

SequencePoses SequencePoses::identity() { return SequencePoses(); }

SequencePoses SequencePoses::interpolated(Trajectory trajectory) {
  SequencePoses p;
  p.kind_ = Kind::Interpolated;
  p.source_ = trajectory.source();
  p.trajectory_ = std::move(trajectory);
  return p;
}

SequencePoses SequencePoses::perFrame(std::vector<Eigen::Isometry3d> poses, std::string source) {
  SequencePoses p;
  p.kind_ = Kind::PerFrame;
  p.frames_ = std::move(poses);
  p.source_ = std::move(source);
  return p;
}

PoseFileFormat parsePoseFileFormat(const std::string& name) {
  if (name == "auto") return PoseFileFormat::Auto;
  if (name == "tum") return PoseFileFormat::Tum;
  if (name == "kitti") return PoseFileFormat::KittiRows;
  if (name == "relative") return PoseFileFormat::Relative;
  const std::vector<std::string> known = {"auto", "tum", "kitti", "relative"};
  throw ConfigError("unknown pose file format '" + name + "'" + didYouMean(name, known) + "; known: " + joinStrings(known));
}

PoseFileFormat detectPoseFileFormat(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw InputError("cannot open pose file '" + path + "'");
  std::string line;
  std::size_t no = 0;
  while (std::getline(in, line)) {
    ++no;
    const auto hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    std::istringstream ls(line);
    std::vector<std::string> tok;
    for (std::string t; ls >> t;) tok.push_back(t);
    if (tok.empty()) continue;
    if (tok[0].find("->") != std::string::npos) return PoseFileFormat::Relative;
    std::size_t values = 0;
    while (values < tok.size() && tok[values].find('=') == std::string::npos) ++values;
    if (values == 8) return PoseFileFormat::Tum;
    if (values == 12) return PoseFileFormat::KittiRows;
    if (values == 16) return PoseFileFormat::Relative;
    throw InputError(path + ":" + std::to_string(no) + ": cannot tell the pose file format from a line of " +
                     std::to_string(values) + " values (TUM has 8, KITTI rows 12, 4x4 relative rows 16)");
  }
  throw InputError("pose file '" + path + "' has no pose lines");
}

SequencePoses loadSequencePoses(const std::string& path, PoseFileFormat format, const TrajectoryReadOptions& options) {
  if (format == PoseFileFormat::Auto) format = detectPoseFileFormat(path);
  switch (format) {
    case PoseFileFormat::Tum:
      return SequencePoses::interpolated(readTumTrajectory(path, options));
    case PoseFileFormat::KittiRows:
      return SequencePoses::perFrame(readKittiPoseRows(path, options), path);
    case PoseFileFormat::Relative:
      return SequencePoses::perFrame(chainRelativePoses(readRelativePoses(path, options)), path);
    case PoseFileFormat::Auto:
      break;
  }
  throw InternalError("unreachable pose file format");
}

// ---- SequenceSource ---------------------------------------------------------------------------

namespace {

/// Refuses a spec that cannot select or stamp anything; returns its extensions lower-case with
/// a leading dot (all readable ones when it names none).
std::vector<std::string> checkSequenceSpec(const SequenceSpec& spec) {
  const std::string& folder = spec.folder;
  std::error_code ec;
  if (folder.empty() || !fs::is_directory(folder, ec)) {
    throw ConfigError("sequence folder '" + folder + "' does not exist or is not a directory");
  }
  if (spec.stride == 0) throw ConfigError("sequence '" + folder + "': stride must be >= 1");
  if (spec.stamps_from_file_names && (!std::isfinite(spec.file_name_stamp_scale) || spec.file_name_stamp_scale <= 0)) {
    throw ConfigError("sequence '" + folder + "': file name stamp scale " + formatNumber(spec.file_name_stamp_scale) +
                      " must be positive and finite");
  }
  if (spec.times_file.empty() && !spec.stamps_from_file_names &&
      (!std::isfinite(spec.period_s) || spec.period_s <= 0 || !std::isfinite(spec.start_stamp_s))) {
    throw ConfigError("sequence '" + folder + "': period " + formatNumber(spec.period_s) + " s must be positive and start stamp " +
                      formatNumber(spec.start_stamp_s) + " s finite");
  }
  std::vector<std::string> exts = spec.extensions.empty() ? supportedCloudExtensions() : spec.extensions;
  for (auto& e : exts) {
    std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (!e.empty() && e[0] != '.') e.insert(e.begin(), '.');
    const auto& known = supportedCloudExtensions();
    if (std::find(known.begin(), known.end(), e) == known.end()) {
      throw ConfigError("sequence '" + folder + "': extension '" + e + "' cannot be read" + didYouMean(e, known) +
                        "; supported: " + joinStrings(known));
    }
  }
  return exts;
}

/// The folder's files with one of `exts`, in natural order.
std::vector<std::string> listFrameFiles(const std::string& folder, const std::vector<std::string>& exts) {
  std::error_code ec;
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(folder)) {
    if (!entry.is_regular_file(ec)) continue;
    const std::string ext = detail::lowerExtension(entry.path().string());
    if (std::find(exts.begin(), exts.end(), ext) != exts.end()) names.push_back(entry.path().filename().string());
  }
  if (names.empty()) {
    throw ConfigError("sequence folder '" + folder + "' has no files with extension " + joinStrings(exts, ", "));
  }
  std::sort(names.begin(), names.end(), naturalLess);
  return names;
}

/// Each file's frame number: its position, or the number its name is.
std::vector<std::size_t> frameIndices(const SequenceSpec& spec, const std::vector<std::string>& names) {
  std::vector<std::size_t> index(names.size());
  for (std::size_t p = 0; p < names.size(); ++p) {
    if (spec.frame_index == FrameIndex::Position) {
      index[p] = p;
      continue;
    }
    const std::string stem = stemOf(names[p]);
    std::size_t v = 0;
    const auto [ptr, err] = std::from_chars(stem.data(), stem.data() + stem.size(), v);
    if (err != std::errc() || ptr != stem.data() + stem.size()) {
      throw InputError("sequence '" + spec.folder + "': file name '" + names[p] +
                       "' is not a frame number (frame index from file names)");
    }
    index[p] = v;
  }
  return index;
}

/// Positions of the files emitted: from `first`, every `stride`-th, at most `max_frames`.
std::vector<std::size_t> selectFrames(const SequenceSpec& spec, std::size_t files) {
  std::vector<std::size_t> selected;
  for (std::size_t p = spec.first; p < files && selected.size() < spec.max_frames; p += spec.stride) {
    selected.push_back(p);
  }
  if (selected.empty()) {
    throw ConfigError("sequence '" + spec.folder + "': first = " + std::to_string(spec.first) + " selects nothing of the " +
                      std::to_string(files) + " files");
  }
  return selected;
}

/// The stamp a file name is, times the spec's scale.
double stampFromFileName(const SequenceSpec& spec, const std::string& name) {
  const std::string stem = stemOf(name);
  const char* b = stem.data();
  const char* e = b + stem.size();
  // Integers (e.g. nanoseconds) are scaled in long double so 19-digit stamps keep their
  // microseconds; the result is rounded to double once.
  long double value = 0;
  unsigned long long integer = 0;
  const auto ri = std::from_chars(b, e, integer);
  if (ri.ec == std::errc() && ri.ptr == e) {
    value = static_cast<long double>(integer);
  } else {
    double d = 0;
    const auto rd = std::from_chars(b, e, d);
    if (rd.ec != std::errc() || rd.ptr != e || !std::isfinite(d)) {
      throw InputError("sequence '" + spec.folder + "': file name '" + name + "' is not a stamp (stamps from file names)");
    }
    value = d;
  }
  return static_cast<double>(value * static_cast<long double>(spec.file_name_stamp_scale));
}

/// A frame's stamp: from the times file, from its name, or from the period.
double frameStamp(const SequenceSpec& spec, const std::vector<double>& times, const std::string& name,
                  std::size_t index) {
  if (!spec.times_file.empty()) {
    if (index >= times.size()) {
      throw ConfigError("sequence '" + spec.folder + "': times file '" + spec.times_file + "' has " +
                        std::to_string(times.size()) + " stamps, no stamp for frame " + std::to_string(index) +
                        " ('" + name + "')");
    }
    return times[index];
  }
  if (spec.stamps_from_file_names) return stampFromFileName(spec, name);
  return spec.start_stamp_s + static_cast<double>(index) * spec.period_s;
}

/// T_world_body of a frame at stamp s.
Eigen::Isometry3d framePose(const SequenceSpec& spec, const SequencePoses& poses, const std::string& name,
                            std::size_t index, double s) {
  switch (poses.kind()) {
    case SequencePoses::Kind::Identity:
      break;
    case SequencePoses::Kind::Interpolated: {
      auto T = poses.trajectory().tryAt(s);
      if (!T) {
        throw InputError("sequence '" + spec.folder + "': frame '" + name + "' at stamp " + formatNumber(s) +
                         " s is outside the trajectory '" + poses.source() + "' [" + formatNumber(poses.trajectory().startStamp()) +
                         ", " + formatNumber(poses.trajectory().endStamp()) + "] s");
      }
      return *T;
    }
    case SequencePoses::Kind::PerFrame:
      if (index >= poses.frames().size()) {
        throw ConfigError("sequence '" + spec.folder + "': poses '" + poses.source() + "' have " +
                          std::to_string(poses.frames().size()) + " frames, none for frame " + std::to_string(index) +
                          " ('" + name + "')");
      }
      return poses.frames()[index];
  }
  return Eigen::Isometry3d::Identity();
}

}  // namespace

SequenceSource::SequenceSource(SequenceSpec spec, SequencePoses poses) : spec_(std::move(spec)) {
  const std::string& folder = spec_.folder;
  const std::vector<std::string> exts = checkSequenceSpec(spec_);
  const std::vector<std::string> names = listFrameFiles(folder, exts);
  const std::vector<std::size_t> index = frameIndices(spec_, names);
  const std::vector<std::size_t> selected = selectFrames(spec_, names.size());
  std::vector<double> times;
  if (!spec_.times_file.empty()) times = readStampFile(spec_.times_file);
  for (std::size_t p : selected) {
    const std::string path = (fs::path(folder) / names[p]).string();
    const double s = frameStamp(spec_, times, names[p], index[p]);
    if (!stamps_.empty() && !(s > stamps_.back())) {
      throw InputError("sequence '" + folder + "': stamp " + formatNumber(s) + " s of '" + path + "' is not after " + formatNumber(stamps_.back()) +
                       " s of '" + files_.back() + "' (files are emitted in name order)");
    }
    const Eigen::Isometry3d T_world_body = framePose(spec_, poses, names[p], index[p], s);
    files_.push_back(path);
    stamps_.push_back(s);
    poses_.push_back(spec_.T_map_world * T_world_body * spec_.T_body_sensor);
  }
}

PointCloud SequenceSource::load(std::size_t k) const {
  CloudFile cf = readPointCloud(files_.at(k));
  PointCloud pc;
  pc.stamp = stamps_[k];
  pc.frame = spec_.frame;
  pc.T_map_sensor = poses_[k] * Eigen::Translation3d(cf.origin);
  pc.points = std::move(cf.points);
  return pc;
}

std::optional<PointCloud> SequenceSource::next() {
  if (cursor_ >= files_.size()) return std::nullopt;
  PointCloud pc = load(cursor_);
  ++cursor_;  // only after a successful read, so a caller may retry or report the same frame
  return pc;
}

}  // namespace terramap::io
