#include <terramap/io/trajectory.hpp>
#include <terramap/core/text.hpp>

#include <terramap/core/error.hpp>
#include <terramap/io/atomic_file.hpp>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>

namespace terramap::io {

namespace {

// A text file read line by line with the position for messages.
class LineReader {
 public:
  explicit LineReader(const std::string& path) : path_(path), in_(path) {
    if (!in_) throw InputError("cannot open '" + path + "': " + std::strerror(errno));
  }
  // Next non-blank, non-comment line split into whitespace tokens; false at the end.
  bool next(std::vector<std::string>& tokens) {
    std::string line;
    while (std::getline(in_, line)) {
      ++line_;
      const auto hash = line.find('#');
      if (hash != std::string::npos) line.resize(hash);
      tokens.clear();
      std::istringstream ls(line);
      std::string t;
      while (ls >> t) tokens.push_back(t);
      if (!tokens.empty()) return true;
    }
    if (in_.bad()) throw InputError("read error in '" + path_ + "' after line " + std::to_string(line_));
    return false;
  }
  std::string where() const { return path_ + ":" + std::to_string(line_); }
  [[noreturn]] void fail(const std::string& msg) const { throw InputError(where() + ": " + msg); }

  // Parses a token as a finite double (locale independent); `what` names it in messages.
  double number(const std::string& tok, const std::string& what) const {
    const char* b = tok.data();
    const char* e = b + tok.size();
    if (b != e && *b == '+') ++b;
    double v = 0.0;
    const auto [ptr, ec] = std::from_chars(b, e, v);
    if (ec == std::errc::result_out_of_range) fail(what + " '" + tok + "' is out of the double range");
    if (ec != std::errc() || ptr != e) fail(what + " '" + tok + "' is not a number");
    if (!std::isfinite(v)) fail(what + " is " + tok + " (NaN/inf is not a valid pose value)");
    return v;
  }

 private:
  std::string path_;
  std::ifstream in_;
  std::size_t line_ = 0;
};

// Checks and projects a rotation matrix read from a file.
Eigen::Matrix3d checkedRotation(const Eigen::Matrix3d& R, double tol, const LineReader& lr) {
  const double err = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  const double det = R.determinant();
  if (err > tol || det <= 0.0) {
    lr.fail("rotation is not orthonormal: max |R^T R - I| = " + formatNumber(err) + ", det = " + formatNumber(det) +
            " (tolerance " + formatNumber(tol) + ")");
  }
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
  return svd.matrixU() * svd.matrixV().transpose();
}

// Parses `count` numbers starting at tokens[first] into a 3x4 [R|t] (12) or 4x4 (16) pose.
Eigen::Isometry3d parseMatrixPose(const std::vector<std::string>& tokens, std::size_t first, std::size_t count,
                                  const TrajectoryReadOptions& opt, const LineReader& lr) {
  double v[16];
  for (std::size_t k = 0; k < count; ++k) {
    v[k] = lr.number(tokens[first + k], "value " + std::to_string(k + 1));
  }
  if (count == 16) {
    const double last[4] = {v[12], v[13], v[14], v[15]};
    const double want[4] = {0, 0, 0, 1};
    for (int k = 0; k < 4; ++k) {
      if (std::abs(last[k] - want[k]) > 1e-6) {
        lr.fail("bottom row of the 4x4 matrix is " + formatNumber(v[12]) + " " + formatNumber(v[13]) + " " + formatNumber(v[14]) + " " +
                formatNumber(v[15]) + ", expected 0 0 0 1");
      }
    }
  }
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) R(r, c) = v[4 * r + c];
    t[r] = v[4 * r + 3];
  }
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = checkedRotation(R, opt.rotation_tolerance, lr);
  T.translation() = t;
  return T;
}

}  // namespace

// ---- Trajectory -------------------------------------------------------------------------------

Trajectory::Trajectory(std::vector<StampedPose> poses, std::string source)
    : poses_(std::move(poses)), source_(std::move(source)) {
  rotations_.reserve(poses_.size());
  for (std::size_t i = 0; i < poses_.size(); ++i) {
    const StampedPose& p = poses_[i];
    if (!std::isfinite(p.stamp)) {
      throw InputError(source_ + ": pose " + std::to_string(i) + " has a non-finite stamp " + formatNumber(p.stamp));
    }
    if (i > 0 && !(p.stamp > poses_[i - 1].stamp)) {
      throw InputError(source_ + ": stamps must be strictly increasing, but pose " + std::to_string(i) + " has stamp " +
                       formatNumber(p.stamp) + " after " + formatNumber(poses_[i - 1].stamp));
    }
    const Eigen::Matrix3d R = p.T_world_body.linear();
    const double err = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
    if (!p.T_world_body.matrix().allFinite() || err > 1e-6 || R.determinant() <= 0.0) {
      throw InputError(source_ + ": pose " + std::to_string(i) + " (stamp " + formatNumber(p.stamp) +
                       ") is not a finite rigid transform (max |R^T R - I| = " + formatNumber(err) + ")");
    }
    rotations_.emplace_back(R);
  }
}

double Trajectory::startStamp() const {
  return poses_.empty() ? std::numeric_limits<double>::quiet_NaN() : poses_.front().stamp;
}
double Trajectory::endStamp() const {
  return poses_.empty() ? std::numeric_limits<double>::quiet_NaN() : poses_.back().stamp;
}
bool Trajectory::contains(double stamp) const {
  return !poses_.empty() && stamp >= poses_.front().stamp && stamp <= poses_.back().stamp;
}

std::optional<Eigen::Isometry3d> Trajectory::tryAt(double stamp) const {
  if (!contains(stamp)) return std::nullopt;
  // First pose with stamp > `stamp`; the bracket is [hi-1, hi].
  const auto it = std::upper_bound(poses_.begin(), poses_.end(), stamp,
                                   [](double s, const StampedPose& p) { return s < p.stamp; });
  const std::size_t hi = static_cast<std::size_t>(it - poses_.begin());
  if (hi == poses_.size()) return poses_.back().T_world_body;  // stamp == endStamp
  const std::size_t lo = hi - 1;
  const StampedPose& a = poses_[lo];
  const StampedPose& b = poses_[hi];
  if (stamp == a.stamp) return a.T_world_body;
  const double alpha = (stamp - a.stamp) / (b.stamp - a.stamp);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = rotations_[lo].slerp(alpha, rotations_[hi]).normalized().toRotationMatrix();
  T.translation() = (1.0 - alpha) * a.T_world_body.translation() + alpha * b.T_world_body.translation();
  return T;
}

Eigen::Isometry3d Trajectory::at(double stamp) const {
  if (auto T = tryAt(stamp)) return *T;
  if (poses_.empty()) throw InputError(source_ + ": cannot look up stamp " + formatNumber(stamp) + " in an empty trajectory");
  throw InputError(source_ + ": stamp " + formatNumber(stamp) + " s is outside the trajectory's range [" + formatNumber(startStamp()) +
                   ", " + formatNumber(endStamp()) + "] s (" + std::to_string(poses_.size()) +
                   " poses); poses are not extrapolated");
}

// ---- readers ----------------------------------------------------------------------------------

Trajectory readTumTrajectory(const std::string& path, const TrajectoryReadOptions& opt) {
  LineReader lr(path);
  std::vector<std::string> tok;
  std::vector<StampedPose> poses;
  double prev = -std::numeric_limits<double>::infinity();
  static const char* const kNames[8] = {"stamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw"};
  while (lr.next(tok)) {
    if (tok.size() != 8) {
      lr.fail("expected 8 values (stamp tx ty tz qx qy qz qw), found " + std::to_string(tok.size()));
    }
    double v[8];
    for (int k = 0; k < 8; ++k) v[k] = lr.number(tok[k], kNames[k]);
    if (!(v[0] > prev)) lr.fail("stamp " + tok[0] + " is not after the previous stamp " + formatNumber(prev));
    prev = v[0];
    Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);
    const double n = q.norm();
    if (std::abs(n - 1.0) > opt.quaternion_norm_tolerance) {
      lr.fail("quaternion (qx qy qz qw) = (" + tok[4] + " " + tok[5] + " " + tok[6] + " " + tok[7] + ") has norm " +
              formatNumber(n) + ", not 1 within " + formatNumber(opt.quaternion_norm_tolerance));
    }
    q.normalize();
    StampedPose p;
    p.stamp = v[0];
    p.T_world_body.linear() = q.toRotationMatrix();
    p.T_world_body.translation() = Eigen::Vector3d(v[1], v[2], v[3]);
    poses.push_back(p);
  }
  return Trajectory(std::move(poses), path);
}

std::vector<Eigen::Isometry3d> readKittiPoseRows(const std::string& path, const TrajectoryReadOptions& opt) {
  LineReader lr(path);
  std::vector<std::string> tok;
  std::vector<Eigen::Isometry3d> out;
  while (lr.next(tok)) {
    if (tok.size() != 12) {
      lr.fail("expected 12 values (3x4 [R|t] row-major), found " + std::to_string(tok.size()));
    }
    out.push_back(parseMatrixPose(tok, 0, 12, opt, lr));
  }
  return out;
}

std::vector<double> readStampFile(const std::string& path) {
  LineReader lr(path);
  std::vector<std::string> tok;
  std::vector<double> out;
  while (lr.next(tok)) {
    if (tok.size() != 1) lr.fail("expected 1 stamp, found " + std::to_string(tok.size()) + " values");
    const double s = lr.number(tok[0], "stamp");
    if (!out.empty() && !(s > out.back())) lr.fail("stamp " + tok[0] + " is not after the previous stamp " + formatNumber(out.back()));
    out.push_back(s);
  }
  return out;
}

Trajectory readKittiTrajectory(const std::string& poses_path, const std::string& times_path,
                               const TrajectoryReadOptions& opt) {
  const auto rows = readKittiPoseRows(poses_path, opt);
  const auto stamps = readStampFile(times_path);
  if (rows.size() != stamps.size()) {
    throw InputError("KITTI poses '" + poses_path + "' have " + std::to_string(rows.size()) + " rows but times '" +
                     times_path + "' has " + std::to_string(stamps.size()) + " stamps; they must match line by line");
  }
  std::vector<StampedPose> poses(rows.size());
  for (std::size_t k = 0; k < rows.size(); ++k) poses[k] = {stamps[k], rows[k]};
  return Trajectory(std::move(poses), poses_path);
}

Trajectory readKittiTrajectory(const std::string& poses_path, double period_s, double start_stamp_s,
                               const TrajectoryReadOptions& opt) {
  if (!std::isfinite(period_s) || period_s <= 0.0) {
    throw ConfigError("KITTI poses '" + poses_path + "': period " + formatNumber(period_s) + " s must be positive and finite");
  }
  if (!std::isfinite(start_stamp_s)) {
    throw ConfigError("KITTI poses '" + poses_path + "': start stamp " + formatNumber(start_stamp_s) + " s must be finite");
  }
  const auto rows = readKittiPoseRows(poses_path, opt);
  std::vector<StampedPose> poses(rows.size());
  // start + k * period (not repeated addition) so frame k's stamp has no accumulated rounding.
  for (std::size_t k = 0; k < rows.size(); ++k) poses[k] = {start_stamp_s + static_cast<double>(k) * period_s, rows[k]};
  return Trajectory(std::move(poses), poses_path);
}

std::vector<RelativePose> readRelativePoses(const std::string& path, const TrajectoryReadOptions& opt) {
  LineReader lr(path);
  std::vector<std::string> tok;
  std::vector<RelativePose> out;
  while (lr.next(tok)) {
    RelativePose rp;
    std::size_t first = 0;
    const auto arrow = tok[0].find("->");
    if (arrow != std::string::npos) {
      auto index = [&](const std::string& s) {
        int v = 0;
        const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
        if (ec != std::errc() || ptr != s.data() + s.size() || s.empty() || v < 0) {
          lr.fail("label '" + tok[0] + "' is not of the form <prev>-><cur> with frame numbers");
        }
        return v;
      };
      rp.prev = index(tok[0].substr(0, arrow));
      rp.cur = index(tok[0].substr(arrow + 2));
      // In 64 bits: prev + 1 overflows an int for the largest frame number a label can hold.
      if (std::int64_t{rp.cur} != std::int64_t{rp.prev} + 1)
        lr.fail("label '" + tok[0] + "' must relate consecutive frames (cur = prev + 1)");
      first = 1;
    } else {
      rp.prev = out.empty() ? 0 : out.back().cur;
      if (rp.prev == std::numeric_limits<int>::max())
        lr.fail("frame " + std::to_string(rp.prev) + " is the last frame number a row can have; no row may follow it");
      rp.cur = rp.prev + 1;
    }
    std::size_t count = 0;
    while (first + count < tok.size() && tok[first + count].find('=') == std::string::npos) ++count;
    if (count != 12 && count != 16) {
      lr.fail("expected 12 (3x4) or 16 (4x4) matrix values, found " + std::to_string(count));
    }
    for (std::size_t k = first + count; k < tok.size(); ++k) {
      const auto eq = tok[k].find('=');
      if (eq == std::string::npos) lr.fail("token '" + tok[k] + "' after the matrix is not key=value");
      if (tok[k].compare(0, eq, "res") == 0) rp.residual_m = lr.number(tok[k].substr(eq + 1), "residual");
    }
    rp.T_prev_cur = parseMatrixPose(tok, first, count, opt, lr);
    if (!out.empty() && rp.prev != out.back().cur) {
      lr.fail("row relates frames " + std::to_string(rp.prev) + "->" + std::to_string(rp.cur) + " but the previous row ended at frame " +
              std::to_string(out.back().cur) + " (rows must be consecutive)");
    }
    out.push_back(rp);
  }
  return out;
}

std::vector<Eigen::Isometry3d> chainRelativePoses(const std::vector<RelativePose>& rel) {
  std::vector<Eigen::Isometry3d> out;
  out.reserve(rel.size() + 1);
  out.push_back(Eigen::Isometry3d::Identity());
  for (std::size_t k = 0; k < rel.size(); ++k) {
    if (std::int64_t{rel[k].cur} != std::int64_t{rel[k].prev} + 1 || (k > 0 && rel[k].prev != rel[k - 1].cur)) {
      throw InputError("relative pose " + std::to_string(k) + " relates frames " + std::to_string(rel[k].prev) + "->" +
                       std::to_string(rel[k].cur) + ": rows must be consecutive frames to be chained");
    }
    Eigen::Isometry3d T = out.back() * rel[k].T_prev_cur;
    // Re-project onto SO(3): products of many rotations drift away from orthonormality.
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(T.linear(), Eigen::ComputeFullU | Eigen::ComputeFullV);
    T.linear() = svd.matrixU() * svd.matrixV().transpose();
    out.push_back(T);
  }
  return out;
}

void writeTumTrajectory(const std::string& path, const Trajectory& traj, const std::string& comment) {
  std::string text = comment.empty() ? std::string() : "# " + comment + "\n";
  char buf[320];
  for (const StampedPose& p : traj.poses()) {
    const Eigen::Quaterniond q(p.T_world_body.linear());
    const Eigen::Vector3d& t = p.T_world_body.translation();
    std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", p.stamp, t.x(), t.y(), t.z(), q.x(),
                  q.y(), q.z(), q.w());
    text += buf;
  }
  writeFileAtomically(path, text);
}

PathAlignment parsePathAlignment(const std::string& name, const std::string& what) {
  if (name == "none") return PathAlignment::None;
  if (name == "se2") return PathAlignment::Se2;
  if (name == "se3") return PathAlignment::Se3;
  throw ConfigError(what + ": unknown alignment '" + name + "' (known: none, se2, se3)");
}

PathComparison comparePaths(const Trajectory& path, const Trajectory& reference, PathAlignment alignment) {
  std::vector<double> stamps;
  std::vector<Eigen::Vector3d> p, r;
  for (const StampedPose& sp : path.poses()) {
    const std::optional<Eigen::Isometry3d> ref = reference.tryAt(sp.stamp);
    if (!ref) continue;
    stamps.push_back(sp.stamp);
    p.push_back(sp.T_world_body.translation());
    r.push_back(ref->translation());
  }
  const std::size_t n = p.size();
  if (n < 2)
    throw InputError(path.source() + " and " + reference.source() + ": " + std::to_string(n) +
                     " stamp(s) of the path lie within the reference's span [" + formatNumber(reference.startStamp()) +
                     ", " + formatNumber(reference.endStamp()) + "] s; at least 2 are needed to compare them");
  PathComparison out;
  out.pairs = n;
  out.start_stamp = stamps.front();
  out.end_stamp = stamps.back();
  if (alignment != PathAlignment::None) {
    const int dim = alignment == PathAlignment::Se2 ? 2 : 3;
    Eigen::MatrixXd src(dim, static_cast<Eigen::Index>(n)), dst(dim, static_cast<Eigen::Index>(n));
    for (std::size_t k = 0; k < n; ++k) {
      src.col(static_cast<Eigen::Index>(k)) = p[k].head(dim);
      dst.col(static_cast<Eigen::Index>(k)) = r[k].head(dim);
    }
    const Eigen::VectorXd spread = (src.colwise() - src.rowwise().mean()).rowwise().norm();
    if (!(spread.maxCoeff() > 0.0))
      throw InputError(path.source() + ": every paired position is the same point; an alignment is undefined "
                       "(compare with alignment none)");
    const Eigen::MatrixXd T = Eigen::umeyama(src, dst, false);
    Eigen::Isometry3d A = Eigen::Isometry3d::Identity();
    A.linear().topLeftCorner(dim, dim) = T.topLeftCorner(dim, dim);
    A.translation().head(dim) = T.topRightCorner(dim, 1);
    out.T_reference_path = A;
    for (Eigen::Vector3d& q : p) q = A * q;
  }
  double sum2 = 0, sum2_xy = 0, sum = 0;
  for (std::size_t k = 0; k < n; ++k) {
    const Eigen::Vector3d e = p[k] - r[k];
    const double d = e.norm();
    sum2 += d * d;
    sum2_xy += e.head<2>().squaredNorm();
    sum += d;
    out.max_m = std::max(out.max_m, d);
    if (k > 0) {
      out.length_m += (p[k] - p[k - 1]).norm();
      out.reference_length_m += (r[k] - r[k - 1]).norm();
    }
  }
  out.rmse_m = std::sqrt(sum2 / static_cast<double>(n));
  out.rmse_xy_m = std::sqrt(sum2_xy / static_cast<double>(n));
  out.mean_m = sum / static_cast<double>(n);
  out.final_m = (p.back() - r.back()).norm();
  return out;
}

}  // namespace terramap::io
