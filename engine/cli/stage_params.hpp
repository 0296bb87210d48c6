#pragma once
// A pipeline stage's parameters as its plugin reads them (its schema's defaults filled in,
// checked): for the evaluation commands that need what a stage will do, e.g. the reference cut
// of a fee_index stage to recompute the index of a truth soil. Loads the plugin for its schema.
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/soil/fee_index.hpp>

#include <map>
#include <string>

namespace terramap::cli {

/// \throws PluginError (plugin not found), ConfigError (a value its schema refuses).
inline Params stageParams(const PipelineSpec& spec, const StageSpec& stage) {
  const PluginHandle h = PluginRegistry::forPipeline(spec.plugin_paths, spec.plugin_paths_where).create(stage.type);
  std::map<std::string, ParamValue> given;
  for (const auto& [k, v] : stage.params) given[k] = v.value;
  return makeParams(stage.name, h->schema(), given);
}

/// The reference cut of a fee_index stage.
inline soil::FeeIndexConfig feeIndexConfigOf(const PipelineSpec& spec, const StageSpec& stage) {
  const Params p = stageParams(spec, stage);
  soil::FeeIndexConfig c;
  c.geometry = {p.getDouble("alpha_rad"), p.getDouble("rho_rad"), p.getDouble("d_m"), p.getDouble("w_m"), p.getDouble("q_n")};
  c.beta_min = p.getString("beta") == "min";
  c.horizontal = p.getString("component") == "horizontal";
  return c;
}

}  // namespace terramap::cli
