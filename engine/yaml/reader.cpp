#include "yaml/reader.hpp"

#include <terramap/core/memory_budget.hpp>
#include <terramap/core/text.hpp>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
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

namespace {

std::string markText(const std::string& file, const YAML::Mark& m) {
  return file + ":" + std::to_string(m.line + 1) + ":" + std::to_string(m.column + 1);
}

/// Every mapping key given twice, at any depth. yaml-cpp keeps both entries and a lookup finds
/// the first, so the second would be ignored without a word. Aliases can make a small text a
/// huge tree: the walk stops after `budget` nodes (what is left is then not checked).
void findDuplicateKeys(const YAML::Node& n, const std::string& path, const std::string& file, int depth,
                       long& budget, std::vector<std::string>& errors) {
  if (--budget < 0 || depth > 200) return;
  if (n.IsMap()) {
    std::vector<std::pair<std::string, YAML::Mark>> seen;
    for (const auto& kv : n) {
      if (!kv.first.IsScalar()) continue;  // reported by the readers as a key that is not a name
      const std::string key = kv.first.Scalar();
      const std::string sub = subPath(path, key);
      const auto it = std::find_if(seen.begin(), seen.end(), [&](const auto& s) { return s.first == key; });
      if (it != seen.end())
        errors.push_back(markText(file, kv.first.Mark()) + ": " + sub + ": key given twice (first at " +
                         markText(file, it->second) + ")");
      else
        seen.emplace_back(key, kv.first.Mark());
      findDuplicateKeys(kv.second, sub, file, depth + 1, budget, errors);
    }
  } else if (n.IsSequence()) {
    for (std::size_t i = 0; i < n.size(); ++i)
      findDuplicateKeys(n[i], path + "[" + std::to_string(i) + "]", file, depth + 1, budget, errors);
  }
}

}  // namespace

YAML::Node load(const std::string& text, const std::string& file) {
  // yaml-cpp's tree takes far more memory than the text (a 6 MB file took about 1 GB): the
  // text's size is checked against the budget before it is parsed.
  constexpr std::uint64_t kTreeBytesPerTextByte = 256;
  requireConfigBudget(saturatingProduct({text.size(), kTreeBytesPerTextByte}),
                      file + ": a YAML file of " + formatBytes(text.size()),
                      std::to_string(kTreeBytesPerTextByte) + " bytes of parse tree per byte of text");
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::ParserException& e) {
    std::ostringstream os;
    os << file << ":" << e.mark.line + 1 << ":" << e.mark.column + 1 << ": YAML syntax error: " << e.msg;
    throw ConfigError(os.str());
  }
  std::vector<std::string> errors;
  long budget = 16 * static_cast<long>(text.size()) + 1024;
  findDuplicateKeys(root, "", file, 0, budget, errors);
  if (!errors.empty()) throw ConfigError(joinStrings(errors, "\n"));
  return root;
}

std::string subPath(const std::string& path, const std::string& key) { return path.empty() ? key : path + "." + key; }

std::string show(const YAML::Node& n) {
  if (n.IsScalar()) return "'" + n.Scalar() + "'";
  if (n.IsSequence()) return "a list";
  if (n.IsMap()) return "a mapping";
  return "nothing";
}

namespace {
// Quoted scalars carry the "!" tag: the user asked for a string.
bool plainScalar(const YAML::Node& n) { return n.IsScalar() && n.Tag() != "!"; }
}  // namespace

bool scalarDouble(const YAML::Node& n, double& out) {
  if (!plainScalar(n)) return false;
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
  if (!plainScalar(n)) return false;
  const std::string s = n.Scalar();
  char* end = nullptr;
  errno = 0;
  out = std::strtol(s.c_str(), &end, 10);
  return end && *end == '\0' && !s.empty() && errno == 0;
}

bool scalarUnsigned(const YAML::Node& n, unsigned long long& out) {
  if (!plainScalar(n)) return false;
  const std::string s = n.Scalar();
  if (s.empty() || s[0] == '-') return false;  // strtoull would wrap "-1" around
  char* end = nullptr;
  errno = 0;
  out = std::strtoull(s.c_str(), &end, 10);
  return end && *end == '\0' && errno == 0;
}

bool scalarBool(const YAML::Node& n, bool& out) {
  if (!plainScalar(n)) return false;
  const std::string s = n.Scalar();
  if (s == "true" || s == "True" || s == "TRUE") { out = true; return true; }
  if (s == "false" || s == "False" || s == "FALSE") { out = false; return true; }
  return false;
}

std::string rangeMessage(const std::string& lo, const std::string& hi, const std::string& got) {
  return "must be in [" + lo + ", " + hi + "] (got " + got + "): out of range";
}

std::string showBound(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

bool keyName(Diagnostics& d, const YAML::Node& key, const std::string& path, std::string& out) {
  if (!key.IsScalar()) {
    d.error(key, path, "a key must be a name, not " + (key.IsNull() ? std::string("empty") : show(key)));
    return false;
  }
  out = key.Scalar();
  return true;
}

void checkKeys(Diagnostics& d, const YAML::Node& map, const std::string& path,
               const std::vector<std::string>& known) {
  if (!map.IsMap()) return;
  for (const auto& kv : map) {
    std::string k;
    if (!keyName(d, kv.first, path, k)) continue;
    bool ok = false;
    for (const auto& n : known) ok = ok || n == k;
    if (!ok)
      d.error(kv.first, subPath(path, k), "unknown key" + didYouMean(k, known) + "; known keys: " + joinStrings(known));
  }
}

bool getDouble(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
               double& out, double min, double max) {
  const YAML::Node n = parent[key];
  if (!n) return false;
  double v;
  if (!scalarDouble(n, v)) {
    d.error(n, subPath(path, key), "must be a number (got " + show(n) + ")");
    return false;
  }
  if (!std::isfinite(v) || v < min || v > max) {
    d.error(n, subPath(path, key), rangeMessage(showBound(min), showBound(max), n.Scalar()));
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
    d.error(n, subPath(path, key), "must be an integer (got " + show(n) + ")");
    return false;
  }
  if (v < min || v > max) {
    d.error(n, subPath(path, key), rangeMessage(std::to_string(min), std::to_string(max), n.Scalar()));
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
    d.error(n, subPath(path, key), "must be true or false (got " + show(n) + ")");
    return false;
  }
  return true;
}

bool getString(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
               std::string& out) {
  const YAML::Node n = parent[key];
  if (!n) return false;
  if (!n.IsScalar()) {
    d.error(n, subPath(path, key), "must be a string (got " + show(n) + ")");
    return false;
  }
  out = n.Scalar();
  return true;
}

bool getStrings(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
                std::vector<std::string>& out) {
  const YAML::Node n = parent[key];
  if (!n) return false;
  if (n.IsScalar()) {
    out = {n.Scalar()};
    return true;
  }
  if (!n.IsSequence()) {
    d.error(n, subPath(path, key), "must be a list of strings (got " + show(n) + ")");
    return false;
  }
  out.clear();
  for (size_t i = 0; i < n.size(); ++i) {
    if (!n[i].IsScalar()) {
      d.error(n[i], subPath(path, key) + "[" + std::to_string(i) + "]", "must be a string");
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
    d.error(n, subPath(path, key),
            "must be a list of " + (size >= 0 ? std::to_string(size) + " " : std::string()) + "numbers (got " +
                show(n) + (n.IsSequence() ? " of " + std::to_string(n.size()) : std::string()) + ")");
    return false;
  }
  out.clear();
  for (size_t i = 0; i < n.size(); ++i) {
    double v;
    if (!scalarDouble(n[i], v) || !std::isfinite(v)) {
      d.error(n[i], subPath(path, key) + "[" + std::to_string(i) + "]",
              "must be a finite number (got " + show(n[i]) + ")");
      return false;
    }
    out.push_back(v);
  }
  return true;
}

// ---- MapReader ---------------------------------------------------------------------------------

MapReader::MapReader(Diagnostics& d, const YAML::Node& node, std::string path)
    : d_(d), node_(node), path_(std::move(path)), valid_(node.IsMap()) {
  // An undefined node was reported where it was looked up (missing key); anything else is here.
  if (!valid_ && node_.IsDefined()) d_.error(node_, path_, "must be a mapping (got " + show(node_) + ")");
}

void MapReader::error(const YAML::Node& at, const std::string& key, const std::string& msg) const {
  d_.error(at.IsDefined() ? at : node_, join(key), msg);
}

void MapReader::error(const std::string& msg) const { d_.error(node_, path_, msg); }

bool MapReader::has(const std::string& key) {
  asked_.insert(key);
  if (!valid_) return false;
  const YAML::Node n = node_[key];
  return n.IsDefined() && !n.IsNull();
}

YAML::Node MapReader::node(const std::string& key) {
  asked_.insert(key);
  if (!valid_) return YAML::Node(YAML::NodeType::Undefined);
  return node_[key];
}

MapReader MapReader::child(const std::string& key) {
  asked_.insert(key);
  const YAML::Node n = valid_ ? node_[key] : YAML::Node(YAML::NodeType::Undefined);
  if (valid_ && (!n.IsDefined() || n.IsNull())) {
    error(node_, key, "missing");
    return MapReader(d_, YAML::Node(YAML::NodeType::Undefined), join(key));
  }
  return MapReader(d_, n, join(key));
}

bool MapReader::number(const YAML::Node& n, const std::string& key, double& out) const {
  double v;
  if (!scalarDouble(n, v) || std::isnan(v)) {
    error(n, key, "must be a number (got " + show(n) + ")");
    return false;
  }
  out = v;
  return true;
}

double MapReader::num(const std::string& key, double def, double lo, double hi) {
  if (!has(key)) return def;
  return numRequired(key, def, lo, hi);
}

double MapReader::numRequired(const std::string& key, double def, double lo, double hi) {
  if (!has(key)) {
    if (valid_) error(node_, key, "missing required number");
    return def;
  }
  const YAML::Node n = node(key);
  double v;
  if (!number(n, key, v)) return def;
  if (!(v >= lo && v <= hi)) {
    error(n, key, rangeMessage(showBound(lo), showBound(hi), n.Scalar()));
    return def;
  }
  return v;
}

double MapReader::angle(const std::string& base, double def_rad, double lo_rad, double hi_rad) {
  const std::string deg_key = base + "_deg", rad_key = base + "_rad";
  const bool deg = has(deg_key), rad = has(rad_key);
  if (deg && rad) {
    error(node(deg_key), deg_key, "give either " + deg_key + " or " + rad_key + ", not both");
    return def_rad;
  }
  if (!deg && !rad) return def_rad;
  const std::string& key = deg ? deg_key : rad_key;
  const YAML::Node n = node(key);
  double v;
  if (!number(n, key, v)) return def_rad;
  // Checked in radians, as computed, so a bound written in degrees is not lost to rounding.
  const double v_rad = deg ? v * M_PI / 180.0 : v;
  if (!(v_rad >= lo_rad && v_rad <= hi_rad)) {
    const double unit = deg ? 180.0 / M_PI : 1.0;
    error(n, key, rangeMessage(showBound(lo_rad * unit), showBound(hi_rad * unit), n.Scalar()));
    return def_rad;
  }
  return v_rad;
}

int MapReader::integer(const std::string& key, int def, int lo, int hi) {
  int v = def;
  if (has(key)) getInt(d_, node_, key, path_, v, lo, hi);
  return v;
}

unsigned long long MapReader::unsignedInt(const std::string& key, unsigned long long def) {
  if (!has(key)) return def;
  const YAML::Node n = node(key);
  unsigned long long v;
  if (!scalarUnsigned(n, v)) {
    error(n, key, "must be a non-negative integer (got " + show(n) + ")");
    return def;
  }
  return v;
}

bool MapReader::boolean(const std::string& key, bool def) {
  bool v = def;
  if (has(key)) getBool(d_, node_, key, path_, v);
  return v;
}

std::string MapReader::str(const std::string& key, const std::string& def) {
  std::string v = def;
  if (has(key)) getString(d_, node_, key, path_, v);
  return v;
}

std::string MapReader::strRequired(const std::string& key) {
  if (!has(key)) {
    if (valid_) error(node_, key, "missing required string");
    return std::string();
  }
  return str(key, std::string());
}

std::vector<double> MapReader::vec(const std::string& key, const std::vector<double>& def, std::size_t n_expected) {
  if (!has(key)) return def;
  std::vector<double> out;
  return numList(node(key), key, n_expected, out) ? out : def;
}

bool MapReader::numList(const YAML::Node& n, const std::string& key, std::size_t n_expected,
                        std::vector<double>& out) const {
  if (!n.IsSequence() || (n_expected && n.size() != n_expected)) {
    error(n, key,
          "must be a list of " + (n_expected ? std::to_string(n_expected) + " " : std::string()) + "numbers (got " +
              show(n) + (n.IsSequence() ? " of " + std::to_string(n.size()) : std::string()) + ")");
    return false;
  }
  out.clear();
  for (std::size_t i = 0; i < n.size(); ++i) {
    double v;
    if (!number(n[i], key + "[" + std::to_string(i) + "]", v)) return false;
    out.push_back(v);
  }
  return true;
}

void MapReader::finish() const {
  if (!valid_) return;
  const std::vector<std::string> known(asked_.begin(), asked_.end());
  for (const auto& kv : node_) {
    std::string k;
    if (!keyName(d_, kv.first, path_, k)) continue;
    if (!asked_.count(k))
      error(kv.first, k, "unknown key" + didYouMean(k, known) + "; known keys: " + joinStrings(known));
  }
}

}  // namespace terramap::yaml
