// Embeds an Engine: a pipeline from text, a few events, a snapshot read on this thread.
// Prints "cells=<n> mean=<m>" for the test to check, and the error for `source: {type: sim}`,
// which only terramap::eval registers.
#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/pipeline/source.hpp>

#include <cmath>
#include <cstdio>

int main() {
  using namespace terramap;
  const PipelineSpec spec = parsePipelineString(R"(version: 1
map: {resolution: 0.5, size: [16, 12], layers: [{name: elevation, unit: m, fill: 2.0}]}
threads: 2
source: {type: none}
pipeline:
  - {name: smooth, type: smooth_filter, params: {input_layer: elevation, output_layer: smooth, run_on: [tick]}}
)", "<embed>", ".");
  auto engine = Engine::fromSpec(spec, PluginRegistry{});
  for (int k = 0; k < 3; ++k) engine->push(Tick{0.1 * k});
  engine->finish();
  const auto snap = engine->snapshot();
  const Eigen::MatrixXf m = snap->toMatrix(snap->layerId("smooth"));
  std::printf("cells=%ld mean=%.6f\n", static_cast<long>(m.size()), static_cast<double>(m.mean()));

  PipelineSpec sim_spec = spec;
  sim_spec.source.type = "sim";
  try {
    makeSource(sim_spec);
    std::printf("sim source: available\n");
  } catch (const ConfigError& e) {
    std::printf("sim source: %s\n", e.what());
  }
  return std::isfinite(m.mean()) ? 0 : 1;
}
