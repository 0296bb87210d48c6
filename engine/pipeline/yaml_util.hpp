#pragma once
// Internal: yaml-cpp helpers that keep file:line:col for every message.
#include <terramap/core/error.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>

#include <yaml-cpp/yaml.h>

#include <set>
#include <string>
#include <vector>

namespace terramap::yaml {

/// Collects errors; throwIfAny() throws one ConfigError with all of them.
struct Diagnostics {
  std::string file;
  std::vector<std::string> errors;
  std::string at(const YAML::Node& n, const std::string& path) const;
  void error(const YAML::Node& n, const std::string& path, const std::string& msg) {
    errors.push_back(at(n, path) + ": " + msg);
  }
  void throwIfAny() const;
};

/// Reports keys of `map` not in `known`, with did-you-mean.
void checkKeys(Diagnostics& d, const YAML::Node& map, const std::string& path,
               const std::vector<std::string>& known);

bool getDouble(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
               double& out, double min, double max);
bool getInt(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
            int& out, int min, int max);
bool getBool(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
             bool& out);
bool getString(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
               std::string& out);
bool getStrings(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
                std::vector<std::string>& out);
bool getDoubles(Diagnostics& d, const YAML::Node& parent, const std::string& key, const std::string& path,
                std::vector<double>& out, int size);

/// Converts any YAML value into a RawParam (scalars by their look: bool, integer, number,
/// string; quoted scalars stay strings; sequences of numbers or strings).
RawParam toRaw(Diagnostics& d, const YAML::Node& n, const std::string& path);
/// A whole mapping of loose settings.
std::map<std::string, RawParam> toRawMap(Diagnostics& d, const YAML::Node& n, const std::string& path);

}  // namespace terramap::yaml
