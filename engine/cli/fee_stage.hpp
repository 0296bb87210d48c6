#pragma once
// The reference cut of a pipeline's fee_index stage: its parameters, defaults from the plugin's
// own schema (loads the plugin to read it). For the evaluation commands that recompute the
// index of a truth soil the way the stage would.
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/soil/fee_index.hpp>

#include <map>
#include <string>

namespace terramap::cli {

inline soil::FeeIndexConfig feeIndexConfigOf(const PipelineSpec& spec, const StageSpec& stage) {
  const PluginHandle h = PluginRegistry(spec.plugin_paths).create("fee_index");
  std::map<std::string, ParamValue> given;
  for (const auto& [k, v] : stage.params) given[k] = v.value;
  const Params p = makeParams(stage.name, h->schema(), given);
  soil::FeeIndexConfig c;
  c.geometry = {p.getDouble("alpha_rad"), p.getDouble("rho_rad"), p.getDouble("d_m"), p.getDouble("w_m"), p.getDouble("q_n")};
  c.beta_min = p.getString("beta") == "min";
  c.horizontal = p.getString("component") == "horizontal";
  return c;
}

}  // namespace terramap::cli
