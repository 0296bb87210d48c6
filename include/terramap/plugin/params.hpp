#pragma once
/// \file
/// Plugin parameters: a declared schema (name, type, default, range, unit, doc) and the
/// validated values the host hands to Plugin::configure(). The host checks the YAML against
/// the schema before anything runs: unknown keys (with did-you-mean), wrong types, values out
/// of range or not among the choices — all reported at once with file:line:col and key path.
#include <terramap/core/error.hpp>
#include <terramap/core/geometry.hpp>

#include <limits>
#include <map>
#include <optional>
#include <string>
#include <variant>
#include <vector>

namespace terramap {

enum class ParamType { Bool, Int, Double, String, DoubleList, StringList };
TERRAMAP_API const char* paramTypeName(ParamType t);

using ParamValue =
    std::variant<bool, long, double, std::string, std::vector<double>, std::vector<std::string>>;

/// One declared parameter. A spec without `default_value` is required.
struct ParamSpec {
  std::string name;   ///< snake_case, with a unit suffix where ambiguous (depth_m)
  ParamType type = ParamType::Double;
  std::optional<ParamValue> default_value;
  double min = -std::numeric_limits<double>::infinity();  ///< inclusive; numbers and list items
  double max = std::numeric_limits<double>::infinity();   ///< inclusive
  std::string unit;   ///< SI unit or "1"
  std::string doc;    ///< one line for `terramap plugins --params` and READMEs
  std::vector<std::string> choices;  ///< allowed strings (String/StringList), empty = any
  int list_size = -1;                ///< required list length, -1 = any
};

/// Fluent builders for a readable schema:
///   ParamSchema s{ param::real("sigma_m", 0.05, 0.0, 10.0, "m", "Gaussian sigma") };
namespace param {
TERRAMAP_API ParamSpec real(std::string name, double def, double min, double max, std::string unit,
                            std::string doc);
TERRAMAP_API ParamSpec realRequired(std::string name, double min, double max, std::string unit,
                                    std::string doc);
TERRAMAP_API ParamSpec integer(std::string name, long def, long min, long max, std::string doc);
TERRAMAP_API ParamSpec boolean(std::string name, bool def, std::string doc);
TERRAMAP_API ParamSpec text(std::string name, std::string def, std::vector<std::string> choices,
                            std::string doc);
TERRAMAP_API ParamSpec reals(std::string name, std::vector<double> def, int size, double min, double max,
                             std::string unit, std::string doc);
TERRAMAP_API ParamSpec texts(std::string name, std::vector<std::string> def, std::string doc);
/// A file or folder path (a String whose unit is "path"). In a pipeline, the host makes a
/// relative value absolute against the pipeline file's folder before configure(), like every
/// other path of the file; makeParams and an embedder's own values are left as given.
TERRAMAP_API ParamSpec path(std::string name, std::string def, std::string doc);
}  // namespace param

using ParamSchema = std::vector<ParamSpec>;

/// Validated parameter values (defaults filled in) with where each came from.
/// Getters throw InternalError on a name the schema does not declare or a type mismatch:
/// that is a plugin bug, not a user error.
class TERRAMAP_API Params {
 public:
  Params() = default;
  Params(std::string owner, ParamSchema schema) : owner_(std::move(owner)), schema_(std::move(schema)) {}

  bool getBool(const std::string& name) const;
  long getInt(const std::string& name) const;
  double getDouble(const std::string& name) const;
  const std::string& getString(const std::string& name) const;
  const std::vector<double>& getDoubles(const std::string& name) const;
  const std::vector<std::string>& getStrings(const std::string& name) const;
  /// True if the user wrote the key (false when the default is used).
  bool isSet(const std::string& name) const { return where_.count(name) > 0; }

  /// Where a key was written ("pipeline.yaml:12:20: pipeline[1].params.sigma_m"), or the
  /// owner's path if it took its default. For plugins' own cross-parameter checks.
  std::string where(const std::string& name) const;
  /// Throws ConfigError "<where(name)>: <message>". Stops configure() at the first problem;
  /// prefer report() for cross-parameter checks so the user sees all of them at once.
  [[noreturn]] void fail(const std::string& name, const std::string& message) const;
  /// Records "<where(name)>: <message>" and returns: configure() goes on checking, and the host
  /// throws one ConfigError with every reported line (plus a ConfigError configure() threw)
  /// after configure() returns.
  void report(const std::string& name, const std::string& message) const;
  /// What report() collected, in order (host side).
  const std::vector<std::string>& reported() const { return reported_; }
  /// For callers of configure() other than the host (tests, embedders without an Engine):
  /// \throws ConfigError with every reported line, if any.
  void throwIfReported() const;

  /// The geometry of the map the stage will run on, when the host knows it (`terramap
  /// validate`, Engine::fromSpec, Engine::addStage): for checks that depend on the map, e.g. a
  /// window of more cells than the map has or a radius below one cell. nullptr when unknown
  /// (a plugin prepared on its own); such checks are then skipped, not failed.
  const Geometry* mapGeometry() const { return map_geometry_ ? &*map_geometry_ : nullptr; }
  /// Host side.
  void setMapGeometry(const Geometry& g) { map_geometry_ = g; }

  /// Host side: store a value (already checked against the schema).
  void set(const std::string& name, ParamValue v, std::string where = {});
  const ParamSchema& schema() const { return schema_; }
  const std::string& owner() const { return owner_; }
  const std::map<std::string, ParamValue>& values() const { return values_; }

 private:
  const ParamValue& value(const std::string& name) const;
  std::string owner_;
  ParamSchema schema_;
  std::map<std::string, ParamValue> values_;
  std::map<std::string, std::string> where_;
  mutable std::vector<std::string> reported_;
  std::optional<Geometry> map_geometry_;
};

/// Fills every default of `schema` into a Params (for tests and embedders that skip YAML).
/// \throws ConfigError if a required parameter (no default) is missing from `overrides`,
/// an override is not in the schema, or it fails the type/range/choice checks.
TERRAMAP_API Params makeParams(const std::string& owner, const ParamSchema& schema,
                               const std::map<std::string, ParamValue>& overrides = {});

/// A value as a user would have written it in YAML: 3, 0.5, true, 'abc', [1, 2], ['a'].
TERRAMAP_API std::string showParamValue(const ParamValue& v);

/// "a"/"an" + the type name, for messages ("must be an integer").
TERRAMAP_API std::string paramTypeWithArticle(ParamType t);

/// Checks one value against its spec; returns "" if fine, else a message such as
/// "must be in [0, 10] (got 12)".
TERRAMAP_API std::string checkParamValue(const ParamSpec& spec, const ParamValue& v);

}  // namespace terramap
