#pragma once
// Internal: a strict YAML mapping reader that reports "file:line:col: key.path: message" and
// rejects unknown keys with a did-you-mean. Not part of the public API.
#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace terramap::sim::detail {

class MapReader {
 public:
  MapReader(const YAML::Node& node, std::string file, std::string path)
      : node_(node), file_(std::move(file)), path_(std::move(path)) {
    if (!node_.IsMap()) fail(node_, "expected a mapping");
  }

  [[noreturn]] void fail(const YAML::Node& at, const std::string& key, const std::string& msg) const {
    throw ConfigError(where(at) + ": " + join(key) + ": " + msg);
  }
  [[noreturn]] void fail(const YAML::Node& at, const std::string& msg) const {
    throw ConfigError(where(at) + ": " + (path_.empty() ? std::string("(root)") : path_) + ": " + msg);
  }

  bool has(const std::string& key) {
    allowed_.insert(key);
    return node_[key].IsDefined() && !node_[key].IsNull();
  }
  YAML::Node node(const std::string& key) {
    allowed_.insert(key);
    return node_[key];  // const overload: undefined node when absent
  }
  const YAML::Node& self() const { return node_; }
  const std::string& file() const { return file_; }
  std::string join(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }

  MapReader child(const std::string& key) {
    allowed_.insert(key);
    YAML::Node n = node_[key];
    if (!n.IsMap()) fail(n.IsDefined() ? n : node_, key, n.IsDefined() ? "expected a mapping" : "missing");
    return MapReader(n, file_, join(key));
  }

  double num(const std::string& key, double def, double lo = -INFINITY, double hi = INFINITY) {
    if (!has(key)) return def;
    return numRequired(key, lo, hi);
  }
  double numRequired(const std::string& key, double lo = -INFINITY, double hi = INFINITY) {
    allowed_.insert(key);
    YAML::Node n = node_[key];
    if (!n.IsDefined() || n.IsNull()) fail(node_, key, "missing required number");
    return checkRange(n, key, scalarNumber(n, key), lo, hi);
  }
  /// Angle: accepts `<base>_deg` (degrees) or `<base>_rad`; returns radians.
  double angle(const std::string& base, double def_rad, double lo_rad = -INFINITY, double hi_rad = INFINITY) {
    const bool d = has(base + "_deg"), r = has(base + "_rad");
    if (d && r) fail(node(base + "_deg"), base + "_deg", "give either " + base + "_deg or " + base + "_rad, not both");
    if (d) {
      YAML::Node n = node(base + "_deg");
      return checkRange(n, base + "_deg", scalarNumber(n, base + "_deg") * M_PI / 180.0, lo_rad, hi_rad);
    }
    if (r) {
      YAML::Node n = node(base + "_rad");
      return checkRange(n, base + "_rad", scalarNumber(n, base + "_rad"), lo_rad, hi_rad);
    }
    return def_rad;
  }
  int integer(const std::string& key, int def, int lo, int hi) {
    if (!has(key)) return def;
    YAML::Node n = node(key);
    long long v = 0;
    try {
      v = n.as<long long>();
    } catch (const YAML::Exception&) {
      fail(n, key, "expected an integer, got '" + scalarText(n) + "'");
    }
    if (v < lo || v > hi)
      fail(n, key, "value " + std::to_string(v) + " out of range [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    return static_cast<int>(v);
  }
  unsigned long long unsignedInt(const std::string& key, unsigned long long def) {
    if (!has(key)) return def;
    YAML::Node n = node(key);
    try {
      const std::string s = n.as<std::string>();
      if (s.empty() || s[0] == '-') throw YAML::Exception(YAML::Mark(), "neg");
      return n.as<unsigned long long>();
    } catch (const YAML::Exception&) {
      fail(n, key, "expected a non-negative integer, got '" + scalarText(n) + "'");
    }
  }
  bool boolean(const std::string& key, bool def) {
    if (!has(key)) return def;
    YAML::Node n = node(key);
    try {
      return n.as<bool>();
    } catch (const YAML::Exception&) {
      fail(n, key, "expected true or false, got '" + scalarText(n) + "'");
    }
  }
  std::string str(const std::string& key, const std::string& def) {
    if (!has(key)) return def;
    return strRequired(key);
  }
  std::string strRequired(const std::string& key) {
    allowed_.insert(key);
    YAML::Node n = node_[key];
    if (!n.IsDefined() || n.IsNull()) fail(node_, key, "missing required string");
    if (!n.IsScalar()) fail(n, key, "expected a string");
    return n.Scalar();
  }
  /// A fixed-length numeric list, e.g. [x, y, z].
  std::vector<double> vec(const std::string& key, const std::vector<double>& def, size_t n_expected) {
    if (!has(key)) return def;
    YAML::Node n = node(key);
    return numList(n, key, n_expected);
  }
  std::vector<double> numList(const YAML::Node& n, const std::string& key, size_t n_expected) const {
    if (!n.IsSequence() || (n_expected && n.size() != n_expected))
      fail(n, key, "expected a list of " + std::to_string(n_expected) + " numbers");
    std::vector<double> out;
    for (size_t i = 0; i < n.size(); ++i) out.push_back(scalarNumber(n[i], key + "[" + std::to_string(i) + "]"));
    return out;
  }
  double scalarNumber(const YAML::Node& n, const std::string& key) const {
    if (!n.IsScalar()) fail(n, key, "expected a number");
    const std::string& s = n.Scalar();
    if (s == "inf" || s == ".inf" || s == "+.inf") return INFINITY;
    if (s == "-inf" || s == "-.inf") return -INFINITY;
    try {
      size_t used = 0;
      const double v = std::stod(s, &used);
      if (used != s.size()) throw std::invalid_argument(s);
      if (std::isnan(v)) throw std::invalid_argument(s);
      return v;
    } catch (const std::exception&) {
      fail(n, key, "expected a number, got '" + s + "'");
    }
  }
  double checkRange(const YAML::Node& n, const std::string& key, double v, double lo, double hi) const {
    if (!(v >= lo && v <= hi)) {
      std::ostringstream os;
      os << "value " << v << " out of range [" << lo << ", " << hi << "]";
      fail(n, key, os.str());
    }
    return v;
  }

  /// Throws on the first key that was never asked for.
  void finish() const {
    std::vector<std::string> known(allowed_.begin(), allowed_.end());
    for (auto it = node_.begin(); it != node_.end(); ++it) {
      const std::string k = it->first.Scalar();
      if (!allowed_.count(k)) fail(it->first, k, "unknown key" + didYouMean(k, known));
    }
  }

  std::string where(const YAML::Node& n) const {
    const YAML::Mark m = n.Mark();
    if (m.is_null()) return file_;
    return file_ + ":" + std::to_string(m.line + 1) + ":" + std::to_string(m.column + 1);
  }

 private:
  static std::string scalarText(const YAML::Node& n) { return n.IsScalar() ? n.Scalar() : std::string("<non-scalar>"); }
  const YAML::Node node_;  // const: operator[] never inserts
  std::string file_, path_;
  std::set<std::string> allowed_;
};

}  // namespace terramap::sim::detail
