#pragma once
// Internal (engine/yaml, never installed): the one strict YAML reader behind pipeline files and
// simulator scenarios. Every problem is collected as "file:line:col: key.path: message" and
// thrown as one ConfigError by Diagnostics::throwIfAny(), so a user fixes a file in one pass
// instead of one error per run. Readers never throw on a bad value: they record it and leave the
// caller's default in place, so reading goes on to the next key.
// Not thread-safe: one Diagnostics per document, used by one thread. Linked into each library
// that reads YAML and hidden there (TERRAMAP_LOCAL), so no copy is exported.
#include <terramap/core/error.hpp>
#include <terramap/core/export.hpp>

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <set>
#include <string>
#include <vector>

namespace terramap::yaml {

/// Collects the errors of one document.
struct TERRAMAP_LOCAL Diagnostics {
  std::string file;  ///< as the user named it; first part of every message
  std::vector<std::string> errors;

  /// "file:line:col: path" (no line:col when the node has no mark, no path when it is empty).
  std::string at(const YAML::Node& n, const std::string& path) const;
  void error(const YAML::Node& n, const std::string& path, const std::string& msg) {
    errors.push_back(at(n, path) + ": " + msg);
  }
  std::size_t count() const { return errors.size(); }
  /// Throws one ConfigError listing every error, one per line, in the order found.
  void throwIfAny() const;
};

/// Parses `text`; a syntax error throws ConfigError "file:line:col: YAML syntax error: ...".
YAML::Node load(const std::string& text, const std::string& file);

/// "path.key", or "key" at the root.
std::string subPath(const std::string& path, const std::string& key);
/// How a value looked, for messages: 'text', a list, a mapping, nothing.
std::string show(const YAML::Node& n);

// Scalar conversions shared by every reader. Quoted scalars are strings, never numbers or
// booleans; numbers accept YAML's .inf/-.inf/.nan spellings. False when `n` is not that kind.
bool scalarDouble(const YAML::Node& n, double& out);
bool scalarLong(const YAML::Node& n, long& out);
bool scalarUnsigned(const YAML::Node& n, unsigned long long& out);
bool scalarBool(const YAML::Node& n, bool& out);

/// "must be in [lo, hi] (got v): out of range", the one wording for every range error.
std::string rangeMessage(const std::string& lo, const std::string& hi, const std::string& got);
/// A bound as messages show it (ostream's default precision: 0.0001, 1e+06, inf).
std::string showBound(double v);

/// The key of a mapping entry as a name. A key can be any YAML node (`{}: 1`, `? [a]`, an empty
/// `: 1`), and yaml-cpp's as<std::string>() throws YAML::BadConversion on those: they are
/// reported at `path` as an error instead and false is returned.
bool keyName(Diagnostics& d, const YAML::Node& key, const std::string& path, std::string& out);

/// Reports keys of `map` not in `known`, with did-you-mean and the known keys.
void checkKeys(Diagnostics& d, const YAML::Node& map, const std::string& path,
               const std::vector<std::string>& known);

// Reads `parent[key]` at `path.key`. False, `out` untouched, when the key is absent or the value
// is wrong (then an error is recorded). Numbers must be finite and inside [min, max].
bool getDouble(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
               double& out, double min, double max);
bool getInt(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
            int& out, int min, int max);
bool getBool(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
             bool& out);
bool getString(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
               std::string& out);
/// A list of strings; a single string is a one-item list.
bool getStrings(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
                std::vector<std::string>& out);
/// A list of `size` finite numbers (any length when size < 0).
bool getDoubles(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
                std::vector<double>& out, int size);

/// A mapping read key by key: every key asked for (has, num, child, ...) is known, and finish()
/// reports every other key of the mapping as unknown, with did-you-mean. Getters take the
/// default to return when the key is absent or wrong; a wrong value is recorded in the
/// Diagnostics. A reader over a missing or non-mapping node reads nothing and reports nothing
/// more (the error was recorded when it was made).
class TERRAMAP_LOCAL MapReader {
 public:
  /// `path`: key path of `node` ("" at the root). Records an error when `node` is not a mapping.
  MapReader(Diagnostics& d, const YAML::Node& node, std::string path);

  /// Records "file:line:col: path.key: msg" at `at`.
  void error(const YAML::Node& at, const std::string& key, const std::string& msg) const;
  /// Records an error about the mapping itself.
  void error(const std::string& msg) const;

  bool valid() const { return valid_; }
  /// Present and not null.
  bool has(const std::string& key);
  /// The node at `key` (undefined when absent).
  YAML::Node node(const std::string& key);
  const YAML::Node& self() const { return node_; }
  Diagnostics& diagnostics() const { return d_; }
  std::string join(const std::string& key) const { return subPath(path_, key); }

  /// A nested mapping; records "missing" or "must be a mapping" and returns an empty reader.
  MapReader child(const std::string& key);

  /// A number in [lo, hi] (infinities allowed when the range allows them; NaN never).
  double num(const std::string& key, double def, double lo = -INFINITY, double hi = INFINITY);
  /// As num(), but absence is an error too.
  double numRequired(const std::string& key, double def, double lo = -INFINITY, double hi = INFINITY);
  /// An angle given as `<base>_deg` or `<base>_rad` (not both); returns radians, checked against
  /// [lo_rad, hi_rad] (messages show the bounds in the unit the user wrote).
  double angle(const std::string& base, double def_rad, double lo_rad = -INFINITY, double hi_rad = INFINITY);
  int integer(const std::string& key, int def, int lo, int hi);
  unsigned long long unsignedInt(const std::string& key, unsigned long long def);
  bool boolean(const std::string& key, bool def);
  std::string str(const std::string& key, const std::string& def);
  /// As str(), but absence is an error too (then "" is returned).
  std::string strRequired(const std::string& key);
  /// A list of exactly `n_expected` numbers (any length when 0), e.g. [x, y, z].
  std::vector<double> vec(const std::string& key, const std::vector<double>& def, std::size_t n_expected);
  /// Numbers of the list `n` (reported at `key`, relative to this mapping); false and an error
  /// when `n` is not such a list.
  bool numList(const YAML::Node& n, const std::string& key, std::size_t n_expected, std::vector<double>& out) const;

  /// Reports every key of the mapping that was never asked for.
  void finish() const;

 private:
  /// The number at `n` (NaN refused), or false after recording why not.
  bool number(const YAML::Node& n, const std::string& key, double& out) const;

  Diagnostics& d_;
  const YAML::Node node_;  // const: operator[] never inserts
  std::string path_;
  bool valid_;
  std::set<std::string> asked_;
};

}  // namespace terramap::yaml
