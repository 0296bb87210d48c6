#include "yaml_util.hpp"

#include <terramap/core/text.hpp>

#include <cmath>
#include <sstream>

namespace terramap::yaml {

std::string Diagnostics::at(const YAML::Node& n, const std::string& path) const {
  std::ostringstream os;
  os << file;
  if (n.IsDefined() && n.Mark().line >= 0) os << ":" << n.Mark().line + 1 << ":" << n.Mark().column + 1;
  if (!path.empty()) os << ": " << path;
  return os.str();
}

void Diagnostics::throwIfAny() const {
  if (errors.empty()) return;
  std::string all;
  for (const auto& e : errors) all += (all.empty() ? "" : "\n") + e;
  throw ConfigError(all);
}

void checkKeys(Diagnostics& d, const YAML::Node& map, const std::string& path,
               const std::vector<std::string>& known) {
  if (!map.IsMap()) return;
  for (const auto& kv : map) {
    const std::string k = kv.first.as<std::string>();
    bool ok = false;
    for (const auto& n : known) ok = ok || n == k;
    if (!ok)
      d.error(kv.first, path.empty() ? k : path + "." + k,
              "unknown key" + didYouMean(k, known) + "; known keys: " + joinStrings(known));
  }
}

namespace {
std::string sub(const std::string& path, const std::string& key) { return path.empty() ? key : path + "." + key; }

bool scalarDouble(const YAML::Node& n, double& out) {
  if (!n.IsScalar() || n.Tag() == "!") return false;
  const std::string s = n.Scalar();
  if (s == ".nan" || s == ".NaN" || s == ".NAN") { out = std::nan(""); return true; }
  if (s == ".inf" || s == "+.inf") { out = INFINITY; return true; }
  if (s == "-.inf") { out = -INFINITY; return true; }
  char* end = nullptr;
  errno = 0;
  out = std::strtod(s.c_str(), &end);
  return end && *end == '\0' && !s.empty() && errno == 0;
}
bool scalarLong(const YAML::Node& n, long& out) {
  if (!n.IsScalar() || n.Tag() == "!") return false;
  const std::string s = n.Scalar();
  char* end = nullptr;
  errno = 0;
  out = std::strtol(s.c_str(), &end, 10);
  return end && *end == '\0' && !s.empty() && errno == 0;
}
bool scalarBool(const YAML::Node& n, bool& out) {
  if (!n.IsScalar() || n.Tag() == "!") return false;
  const std::string s = n.Scalar();
  if (s == "true" || s == "True" || s == "TRUE") { out = true; return true; }
  if (s == "false" || s == "False" || s == "FALSE") { out = false; return true; }
  return false;
}
std::string show(const YAML::Node& n) {
  if (n.IsScalar()) return "'" + n.Scalar() + "'";
  if (n.IsSequence()) return "a list";
  if (n.IsMap()) return "a mapping";
  return "nothing";
}
}  // namespace

bool getDouble(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
               double& out, double min, double max) {
  const YAML::Node n = parent[key];
  if (!n) return false;
  double v;
  if (!scalarDouble(n, v)) {
    d.error(n, sub(path, key), "must be a number (got " + show(n) + ")");
    return false;
  }
  if (!std::isfinite(v) || v < min || v > max) {
    std::ostringstream os;
    os << "must be in [" << min << ", " << max << "] (got " << n.Scalar() << ")";
    d.error(n, sub(path, key), os.str());
    return false;
  }
  out = v;
  return true;
}

bool getInt(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path, int& out,
            int min, int max) {
  const YAML::Node n = parent[key];
  if (!n) return false;
  long v;
  if (!scalarLong(n, v)) {
    d.error(n, sub(path, key), "must be an integer (got " + show(n) + ")");
    return false;
  }
  if (v < min || v > max) {
    d.error(n, sub(path, key),
            "must be in [" + std::to_string(min) + ", " + std::to_string(max) + "] (got " + n.Scalar() + ")");
    return false;
  }
  out = static_cast<int>(v);
  return true;
}

bool getBool(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
             bool& out) {
  const YAML::Node n = parent[key];
  if (!n) return false;
  if (!scalarBool(n, out)) {
    d.error(n, sub(path, key), "must be true or false (got " + show(n) + ")");
    return false;
  }
  return true;
}

bool getString(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
               std::string& out) {
  const YAML::Node n = parent[key];
  if (!n) return false;
  if (!n.IsScalar()) {
    d.error(n, sub(path, key), "must be a string (got " + show(n) + ")");
    return false;
  }
  out = n.Scalar();
  return true;
}

bool getStrings(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
                std::vector<std::string>& out) {
  const YAML::Node n = parent[key];
  if (!n) return false;
  if (n.IsScalar()) {  // a single string is a one-item list
    out = {n.Scalar()};
    return true;
  }
  if (!n.IsSequence()) {
    d.error(n, sub(path, key), "must be a list of strings (got " + show(n) + ")");
    return false;
  }
  out.clear();
  for (size_t i = 0; i < n.size(); ++i) {
    if (!n[i].IsScalar()) {
      d.error(n[i], sub(path, key) + "[" + std::to_string(i) + "]", "must be a string");
      return false;
    }
    out.push_back(n[i].Scalar());
  }
  return true;
}

bool getDoubles(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
                std::vector<double>& out, int size) {
  const YAML::Node n = parent[key];
  if (!n) return false;
  if (!n.IsSequence() || (size >= 0 && static_cast<int>(n.size()) != size)) {
    d.error(n, sub(path, key),
            "must be a list of " + (size >= 0 ? std::to_string(size) + " " : std::string()) + "numbers (got " +
                show(n) + (n.IsSequence() ? " of " + std::to_string(n.size()) : std::string()) + ")");
    return false;
  }
  out.clear();
  for (size_t i = 0; i < n.size(); ++i) {
    double v;
    if (!scalarDouble(n[i], v) || !std::isfinite(v)) {
      d.error(n[i], sub(path, key) + "[" + std::to_string(i) + "]", "must be a finite number (got " + show(n[i]) + ")");
      return false;
    }
    out.push_back(v);
  }
  return true;
}

RawParam toRaw(Diagnostics& d, const YAML::Node& n, const std::string& path) {
  RawParam r;
  r.where = d.at(n, path);
  if (n.IsScalar()) {
    bool b;
    long l;
    double x;
    if (scalarBool(n, b)) r.value = b;
    else if (scalarLong(n, l)) r.value = l;
    else if (scalarDouble(n, x)) r.value = x;
    else r.value = n.Scalar();
    return r;
  }
  if (n.IsSequence()) {
    std::vector<double> nums;
    std::vector<std::string> strs;
    bool all_num = true;
    for (const auto& it : n) {
      double x;
      if (!it.IsScalar()) {
        r.is_map = true;  // nested structures are never valid plugin params
        return r;
      }
      if (scalarDouble(it, x)) nums.push_back(x);
      else all_num = false;
      strs.push_back(it.Scalar());
    }
    if (all_num && !nums.empty()) r.value = nums;
    else r.value = strs;
    return r;
  }
  if (n.IsNull()) {
    r.value = std::string();
    return r;
  }
  r.is_map = true;
  return r;
}

std::map<std::string, RawParam> toRawMap(Diagnostics& d, const YAML::Node& n, const std::string& path) {
  std::map<std::string, RawParam> out;
  if (!n) return out;
  if (!n.IsMap()) {
    d.error(n, path, "must be a mapping of key: value");
    return out;
  }
  for (const auto& kv : n) {
    const std::string k = kv.first.as<std::string>();
    RawParam r = toRaw(d, kv.second, sub(path, k));
    r.where = d.at(kv.first, sub(path, k));  // the key's position: what a reader looks for
    out[k] = r;
  }
  return out;
}

}  // namespace terramap::yaml
