#pragma once
// Internal: the pipeline's own additions to the shared strict reader (engine/yaml): plugin
// params and source settings as RawParam, checked later against each plugin's declared params.
#include "yaml/reader.hpp"

#include <terramap/pipeline/pipeline_spec.hpp>

#include <map>
#include <string>

namespace terramap::yaml {

/// Converts any YAML value into a RawParam (scalars by their look: bool, integer, number,
/// string; quoted scalars stay strings; sequences of numbers or strings).
RawParam toRaw(Diagnostics& d, const YAML::Node& n, const std::string& path);
/// A whole mapping of loose settings.
std::map<std::string, RawParam> toRawMap(Diagnostics& d, const YAML::Node& n, const std::string& path);

}  // namespace terramap::yaml
